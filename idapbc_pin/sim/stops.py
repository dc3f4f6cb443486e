"""`Stops`: the early stops of `simulate`, rows whose verdict is known before the horizon ends.

A row stops once it has rested in the success box for the success window (`stop_settled`), once
it enters its loop's terminal set (`stop_converged`, `idapbc_pin.sim.terminal`), or once it leaves a
given box (`stop_outside`); `idapbc_pin.sim.integrate.simulate` documents what each stop means for
the record.
"""

from __future__ import annotations

import numpy as np

from ..model.boxes import in_box
from .metrics import at_target, window_samples

__all__ = ["Stops"]


class Stops:
    """`simulate`'s early stops: rows whose verdict is known stop being integrated (`done`, (N,)
    bool). With `settled`, a row that has rested in the success box (DESIGN §4,
    `idapbc_pin.sim.metrics.at_target`) at `needed` consecutive record samples, the samples its
    success test reads; with `terminal` (a `TerminalSet`), a row inside it (`converged`, (N,) bool);
    with `box` ((lo, hi) of x, `in_box`), a row that has left it (`left`, (N,) bool).
    Rows are tested from step `first` on."""

    def __init__(self, system, n_rows: int, steps: list[int], dt: float, settled: bool, terminal=None, enough: int | None = None,
                 box=None, first: int = 0):
        self.system, self.terminal, self.first = system, terminal, int(first)
        self.box = box
        self.left = np.zeros(n_rows, bool)
        self.needed = window_samples(np.asarray(steps, float) * dt) if settled else None
        self.run_length, self.done = np.zeros(n_rows, int), np.zeros(n_rows, bool)
        self.converged = np.zeros(n_rows, bool)
        self.enough = enough

    @classmethod
    def build(cls, system, n_rows: int, steps: list[int], dt: float, settled: bool, terminal, enough, box, start: float):
        """The stops `simulate` asks for, or None when it asks for none (`start`: from this time on, s)."""
        settled = settled and cls.applies(steps)
        if not (settled or terminal is not None or box is not None):
            return None
        return cls(system, n_rows, steps, dt, settled, terminal, enough, box, int(np.ceil(start / dt - 1e-9)))

    def decided(self) -> bool:
        """Whether `enough` rows have stopped (never, without `enough`)."""
        return self.enough is not None and int(self.done.sum()) >= self.enough

    @staticmethod
    def applies(steps: list[int]) -> bool:
        """The rest count needs an evenly spaced record (the window is counted in samples)."""
        gaps = np.diff(steps)
        return gaps.size > 0 and bool(np.all(gaps == gaps[0]))

    def stop(self, q, v, x, live):
        """Mark the live rows (q, v (N, nq), x (N, n) of every row, `live` their indices) whose
        verdict is now known as done. Returns (len(live),) bool: stopped."""
        stopped = np.zeros(live.size, bool)
        if self.box is not None:
            out = ~in_box(self.system, x[live], self.box)
            self.left[live[out]] = True
            stopped |= out
        if self.needed is not None:
            inside = at_target(q[live], v[live], self.system)
            self.run_length[live] = np.where(inside, self.run_length[live] + 1, 0)
            stopped |= self.run_length[live] >= self.needed
        if self.terminal is not None:
            converged = self.terminal.contains(q[live], v[live])
            self.converged[live[converged]] = True
            stopped |= converged
        self.done[live[stopped]] = True
        return stopped

    def batch_of_one_padded(self, rhs):
        """`rhs` evaluated on two copies of a lone row once rows have stopped: a batch of one takes
        other BLAS kernels (gemv, not gemm) whose rounding differs, and without the stop that row
        would still be in a batch with the stopped ones."""

        def padded(q, v, held=None):
            if q.shape[0] != 1 or not self.done.any():
                return rhs(q, v, held)
            out = rhs(np.repeat(q, 2, axis=0), np.repeat(v, 2, axis=0), None if held is None else np.repeat(held, 2, axis=0))
            return tuple(None if o is None else o[:1] for o in out)

        return padded

"""Closed-loop evaluation of a run: region of attraction of Neural IDA-PBC next to LQR.

`evaluate_run` simulates the true plant (DESIGN §4) from the same uniform states of the training
domain and of its half-size box under the learned controller and the LQR baseline (Q = I, R = I),
and writes ``evaluation.json`` into the run directory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..sim.simulate import LQRController, RoaResult, roa
from .._io import write_json as _write_json
from ..training.run import Run

__all__ = ["Evaluation", "evaluate_run", "format_evaluation"]


@dataclass(frozen=True)
class Evaluation:
    """ROA results per box ("domain", "half"), for the controllers "NIDA-PBC" and "LQR"."""

    run: Run
    results: dict[str, RoaResult]

    def record(self) -> dict:
        """JSON-ready summary: per box and controller, success rate and medians."""
        out = {}
        for box, res in self.results.items():
            out[box] = {
                name: {
                    "success_rate": s.success_rate,
                    "median_settling_time": _num(s.median_settling_time),
                    "median_offset": _num(s.median_offset),
                    "median_peak_input": _num(s.median_peak_input),
                    "diverged": s.n_diverged,
                    "wall_time": s.wall_time,
                }
                for name, s in res.scores.items()
            }
            out[box]["n"] = int(res.x0.shape[0])
            out[box]["seed"] = res.seed
            out[box]["T"] = res.T
        return out


def _num(v: float):
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


def evaluate_run(run: Run, n: int = 200, T: float = 20.0, dt: float = 0.01, seed: int = 0, rho: float | None = None, boxes=("domain", "half")) -> Evaluation:
    """ROA of the run's controller (optionally with extra damping ρ) and LQR on `n` states per box."""
    ctrl = run.controller if rho is None else run.controller.with_damping(rho)
    controllers = {"NIDA-PBC": ctrl, "LQR": LQRController(run.system)}
    results = {box: roa(run.system, controllers, n=n, box=box, seed=seed, T=T, dt=dt) for box in boxes}
    evaluation = Evaluation(run, results)
    record = evaluation.record()
    record["rho"] = ctrl.rho
    _write_json(run.path / "evaluation.json", record)
    return evaluation


def format_evaluation(evaluation: Evaluation) -> str:
    """The ROA tables, one per box."""
    return "\n\n".join(res.table() for res in evaluation.results.values())

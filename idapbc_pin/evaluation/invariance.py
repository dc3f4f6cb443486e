"""How much of the box any certificate of this closed loop could cover: the invariant share.

The sampled certificate (`idapbc_pin.certificate`, DESIGN §4) certifies a sublevel set {V < c} that
lies inside the training box and on which V decreases along the loop. Such a set is forward
invariant: every trajectory that starts in it stays in it, hence **never leaves the box**, and
reaches x*. So, whatever V is (H_d, LQR's δᵀSδ, or any other function), its certified share is at
most the share of box states whose trajectory both succeeds and never leaves the box. That share is
measured here by simulation, for the very law the certificate judges (effort limits included):

    invariant share(s) = P[ x0 ~ U(box):  x(t) ∈ x* + s·(box − x*) for all t ≤ T,  and success ]

with angles wrapped. s = 1 is the ceiling of the certificate as defined; s > 1 shows what a
certificate that may leave the training box (but not s times it) could reach. An estimate from
finitely many states and a finite horizon, not a bound proven for every state.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from ..model.boxes import in_box
from ..sim.integrate import simulate
from ..sim.metrics import success
from ..sim.states import uniform_states
from ..sim.trajectory import Trajectory

__all__ = ["InvariantShare", "box_invariant_share", "invariant_share", "stays_inside"]


def stays_inside(traj: Trajectory, system, scale: float = 1.0, box=None) -> np.ndarray:
    """(N,) bool: every recorded state of each trajectory lies in x* + scale·(domain − x*), or in
    `box` = (lo, hi) when given (angles wrapped about x*), and the trajectory did not diverge."""
    if not scale > 0:
        raise ValueError(f"scale must be > 0, got {scale}")
    if box is None:
        x_star = np.asarray(system.x_star, float)
        box = tuple(x_star + scale * (np.asarray(b, float) - x_star) for b in system.domain)
    return in_box(system, traj.x, box).all(axis=1) & ~traj.diverged


@dataclass(frozen=True)
class InvariantShare:
    """Per controller: the success rate from `n` uniform domain states, and for each box scale s the
    share that succeeds without ever leaving x* + s·(domain − x*) (fractions in [0, 1])."""

    system: str
    n: int
    seed: int
    T: float
    scales: tuple[float, ...]
    success: Mapping[str, float]
    inside: Mapping[str, tuple[float, ...]]

    def table(self) -> str:
        head = " | ".join(f"succeeds, never leaves {s:g}× the box" for s in self.scales)
        lines = [f"{self.system}: {self.n} uniform states of the training box (seed {self.seed}), T = {self.T:g} s",
                 f"| controller | succeeds | {head} |", "|---" * (2 + len(self.scales)) + "|"]
        for name, rate in self.success.items():
            cells = " | ".join(f"{100 * v:.1f} %" for v in self.inside[name])
            lines.append(f"| {name} | {100 * rate:.1f} % | {cells} |")
        return "\n".join(lines)


def invariant_share(
    system,
    controllers: Mapping[str, object],
    n: int = 500,
    seed: int = 5,
    scales: Sequence[float] = (1.0, 2.0, 4.0),
    T: float = 20.0,
    limits: bool = True,
    chunk: int = 250,
) -> InvariantShare:
    """Simulate every controller from the same `n` uniform domain states (the judge of `simulate`,
    effort limits applied unless `limits=False`) and measure its invariant share at each scale.

    Trajectories are simulated `chunk` states at a time and kept at every control tick (2 ms), so a
    state that pokes out of the box between two recorded samples is missed by at most one tick.
    """
    scales = tuple(float(s) for s in scales)
    x0 = uniform_states(system, n, "domain", seed)
    rates, inside = {}, {}
    for name, ctrl in controllers.items():
        ok, ins = [], []
        for start in range(0, n, chunk):
            traj = simulate(system, ctrl, x0[start : start + chunk], T=T, limits=limits, stop_converged=True)
            good = success(traj, system)
            ok.append(good)
            ins.append(np.stack([good & stays_inside(traj, system, s) for s in scales], axis=1))
        rates[name] = float(np.concatenate(ok).mean())
        inside[name] = tuple(float(v) for v in np.concatenate(ins).mean(axis=0))
    return InvariantShare(system=system.name, n=n, seed=seed, T=T, scales=scales, success=rates, inside=inside)


def box_invariant_share(system, controllers: Mapping[str, object], box, n: int = 200, seed: int = 5,
                        T: float = 20.0, limits: bool = True) -> dict[str, float]:
    """{controller: share of `n` uniform domain states whose trajectory succeeds without leaving
    `box` = (lo, hi)} (the ceiling of any certified set in that box). Rows stop once they rest in
    the success box or enter the terminal set, or once they leave `box` (`simulate`): the verdicts
    are those of the full horizon."""
    x0 = uniform_states(system, n, "domain", seed)
    shares = {}
    for name, ctrl in controllers.items():
        traj = simulate(system, ctrl, x0, T=T, limits=limits, stop_settled=True, stop_converged=True, stop_outside=box)
        shares[name] = float(np.mean(success(traj, system) & stays_inside(traj, system, box=box)))
    return shares

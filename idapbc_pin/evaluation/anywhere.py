"""The global evaluation of a run (DESIGN §4, "From anywhere"): its state feedback from any state.

Two views of the same question, each beside saturated LQR and the energy-pumping law with its LQR
catch, under the effort limits:

* **from the torus**: `n` start states from anywhere on the torus, moving (`sim.states.anywhere_states`:
  the first exactly hanging at rest, the others every angle from the full circle and every speed
  U(−1, 1) rad/s), T = 10 s: holds at x* and the time to x* (`evaluation.swingup`);
* **the uptime test** of the RealAIGym global policy leaderboard (`evaluation.uptime`): 60-s
  episodes with 15 resets, each a 0.2-s PID drive towards a random posture that leaves the robot
  moving (or, with ``reset="put"``, the state put there at rest), scored by the share of time with
  the tip up, with each law's peak speed over the joints' ratings.

Only state feedbacks take part: a manoeuvre read by a clock from a command at rest has no meaning
after a reset. The result goes to the run directory as ``anywhere.json``.
"""

from __future__ import annotations

from dataclasses import dataclass

from .swingup import DT, SwingupResult, evaluate_swingup
from .uptime import DRIVE_T, UPTIME_EPISODES, UPTIME_RESETS, UPTIME_T, UptimeResult, uptime_test

__all__ = ["ANYWHERE_FILE", "AnywhereResult", "anywhere_controllers", "evaluate_run_anywhere"]

#: The run directory's file of the global evaluation.
ANYWHERE_FILE = "anywhere.json"


@dataclass(frozen=True, eq=False)
class AnywhereResult:
    """The run's state feedback and the references from the torus (`torus`) and in the uptime test (`uptime`)."""

    torus: SwingupResult
    uptime: UptimeResult

    def table(self) -> str:
        """Both tables, each under a line that says what it measured."""
        N, T = self.torus.states.shape[0], self.torus.T
        E = self.uptime.steps.shape[0]
        return "\n".join([
            f"from {N} states anywhere on the torus (the first hanging at rest; every angle from the full circle, speeds U(−1, 1) rad/s), "
            f"T = {T:g} s:", self.torus.table(), "",
            f"uptime test: {E} episodes of {self.uptime.T:g} s, {self.uptime.resets} resets "
            + ("to postures at rest from the full circle " if self.uptime.reset == "put" else
               f"by a {DRIVE_T:g}-s PID drive towards postures from the full circle, released moving, as the leaderboard's own test ") +
            f"(±{self.uptime.jitter:g} s of jitter); the share of time with the tip up; speeds over the URDF ratings outside the drives and the 0.5 s after each:", self.uptime.table()])

    def to_dict(self) -> dict:
        """JSON-ready: both results."""
        return {"torus": self.torus.to_dict(), "uptime": self.uptime.to_dict()}


def anywhere_controllers(run) -> dict:
    """The laws judged from anywhere: the run's state feedback ("NIDA-PBC": its networks with the
    outer laws the run keeps, the swing-up law among them), saturated LQR, and the energy pump with
    its LQR catch."""
    from ..control.baseline import LQRController
    from ..control.energy_pump import EnergyPumpLaw

    return {"NIDA-PBC": run.controller, "LQR": LQRController(run.system), "energy pump + LQR": EnergyPumpLaw(run.system)}


def evaluate_run_anywhere(run, n: int = 20, T: float = 10.0, seed: int = 0, episodes: int = UPTIME_EPISODES, workers: int = 1,
                          judge: str = "pinocchio", uptime_T: float | None = None, resets: int | None = None,
                          reset: str = "drive") -> AnywhereResult:
    """The global evaluation of `run` (module docstring): `n` states from the torus over `T` s and
    `episodes` uptime episodes of `uptime_T` s with `resets` resets (None: the leaderboard's 60 s
    and 15, each reset as `reset` says: `uptime.RESETS`), both drawn with `seed`, on the judge plant
    (``"pinocchio"``, or ``"mujoco"``: `sim.mujoco_plant.mujoco_judge`); written to ``anywhere.json``
    in the run directory."""
    from .._io import write_json
    from .closed_loop import _judged

    plant = _judged(run.system, judge, {})
    laws = anywhere_controllers(run)
    torus = evaluate_swingup(plant, laws, n=n, T=T, dt=DT, seed=seed, workers=workers, starts="anywhere")
    uptime = uptime_test(plant, laws, episodes=episodes, seed=seed, dt=DT, workers=workers,
                         T=UPTIME_T if uptime_T is None else uptime_T, resets=UPTIME_RESETS if resets is None else resets, reset=reset)
    result = AnywhereResult(torus=torus, uptime=uptime)
    write_json(run.path / ANYWHERE_FILE, result.to_dict() | {"judge": judge, "swing_up_law": bool(getattr(run, "uses_swing_up", False))})
    return result

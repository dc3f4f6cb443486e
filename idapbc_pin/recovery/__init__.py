"""The stages and the run's outer laws: where a weak actuator's limits bind (reach) or the robot
rests far from x* (swing-up), a law fitted to plans within the limits (`idapbc_pin.trajectory`, the
floor below) acts where the IDA-PBC law does not reach, kept only where a gate sees it help.

* `box_law`: `BoxFallback`, the linear law outside the training box (the run's own outer law), and
  `box_gate`, the gate after training that decides whether a run uses it.
* `law`: `RecoveryLaw`, the fitted law and where it acts; `library_law`: `LibraryLaw`, the labelled
  paths themselves read at the nearest point, judged beside the fits. The laws reach the controller only through
  `idapbc_pin.control.controller.OuterLaw` (``apply(x, u, energy) -> u``).
* `config`: `RecoveryConfig` and `SwingUpConfig`, every number of the stages (TOML files for the CLI).
* The reach stage: `fit` (the recovery law from labels), `gate` (keep it or not), `stage`
  (`recover`), `again` (`refit`, `regate`: without plans), `trigger` (`limits_bind`, `auto_recover`: `train`'s default),
  `governor_margin` (`catch_margin`: the governor's energy margin a kept law's catches need).
* The swing-up stage: `swing_law` (`SwingUpLaw`, acting where the posture leaves the training box,
  around the run's own outer law), `swing_boxes` (the kept boxes where the run's law keeps control)
  and `swing_stage` (`swing_up`: its labels, fit, DAgger rounds, gate and manoeuvre).

The law modules import nothing of the stages, so the run directory can load them.
"""

from ..trajectory import SwingManoeuvre, TrackingLaw  # re-exported: the plan-based laws a run may keep
from .box_law import BoxFallback
from .config import RecoveryConfig, SwingUpConfig
from .governor_margin import catch_margin
from .law import RecoveryLaw
from .library_law import LibraryLaw
from .again import refit, regate
from .stage import recover
from .swing_law import SwingUpLaw
from .swing_stage import swing_up
from .trigger import auto_recover, limits_bind

__all__ = ["BoxFallback", "LibraryLaw", "RecoveryConfig", "RecoveryLaw", "SwingManoeuvre", "SwingUpConfig", "SwingUpLaw", "TrackingLaw", "auto_recover", "catch_margin", "limits_bind",
           "recover", "refit", "regate", "swing_up"]

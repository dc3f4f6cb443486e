"""The recovery stage and the run's outer laws: where a weak actuator's limits bind, a law fitted to
torque plans within the limits replaces the IDA-PBC law outside an inner set, kept only where a gate
sees it help.

* `box_law`: `BoxFallback`, the linear law outside the training box (the run's own outer law), and
  `box_gate`, the gate after training that decides whether a run uses it.
* `law`: `RecoveryLaw`, the fitted law and where it acts. Both laws reach the controller only through
  `idapbc_pin.control.controller.OuterLaw` (``apply(x, u, energy) -> u``).
* `config`: `RecoveryConfig`, every number of the stage (a TOML file for the CLI).
* `ilqr` (batched iLQR within box limits on the plant's own dynamics), `plans` (torque plans within
  the limits: iLQR candidates and their tracking, or the cross-entropy search), `fit` (the law from
  labels), `gate` (keep it or not), `chunks` (finished chunks of plans a killed stage reads back),
  `stage` (`recover`, `refit`, `regate`), `trigger` (`limits_bind`, `auto_recover`: `train`'s default).
* Swing-up, the same machinery from the resting posture: `swing_law` (`SwingUpLaw`, acting where the
  posture leaves the training box, around the run's own outer law), `swing_tracks` (nominal plans
  from rest and their time-varying LQR) with `tracking_law` (`TrackingLaw`: a nominal read at the
  nearest point) and `manoeuvre` (`SwingManoeuvre`: a nominal read by time, from a command at rest),
  `swing_stage` (`swing_up`, its labels, fit, DAgger rounds and gate; `SwingUpConfig` in `config`).

The law modules import nothing of this package's stage, so the run directory can load them.
"""

from .box_law import BoxFallback
from .config import RecoveryConfig, SwingUpConfig
from .law import RecoveryLaw
from .manoeuvre import SwingManoeuvre
from .stage import recover, refit, regate
from .swing_law import SwingUpLaw
from .swing_stage import swing_up
from .tracking_law import TrackingLaw
from .trigger import auto_recover, limits_bind

__all__ = ["BoxFallback", "RecoveryConfig", "RecoveryLaw", "SwingManoeuvre", "SwingUpConfig", "SwingUpLaw", "TrackingLaw", "auto_recover", "limits_bind",
           "recover", "refit", "regate", "swing_up"]

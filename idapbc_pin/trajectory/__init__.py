"""The trajectory floor: plans within the limits, their tracking, manoeuvres and the fitting of state
feedbacks to them (DESIGN §3). It plans; the stages in `idapbc_pin.recovery` (reach, swing-up)
decide which starts to plan from and which law to keep, and this floor knows nothing of them.

* `ilqr`: batched iLQR within box limits on the plant's own dynamics (`ilqr_plans`).
* `plans`: torque plans from many starts (iLQR candidates tracked by their time-varying LQR, or the
  cross-entropy search) and the laws that play them then hand over (`PlanThenLaw`, `TrackThenLaw`).
* `tracks`: nominal plans from the resting posture and their time-varying LQR; `tracking_law`
  (`TrackingLaw`: a nominal read at the nearest point, no clock) and `manoeuvre` (`SwingManoeuvre`:
  a nominal read by time from a command at rest); `kept_box`: the box a law leaves to the run's law.
* `holds`: how many starts each of several laws holds at x* (the judgement every plan-based law
  shares); `fit`: the least-squares MLP fit of a state feedback to labels (`fit_mlp`).
* `chunks`: finished chunks of plans that a killed stage reads back.

The law modules (`tracking_law`, `manoeuvre`, `kept_box`) import nothing of the planning, so the run
directory can load them.
"""

from .fit import fit_mlp
from .ilqr import ILQRSettings, ilqr_plans
from .manoeuvre import SwingManoeuvre
from .plans import PlanSettings, PlanThenLaw, TrackThenLaw, plan_candidates, search_plans
from .tracking_law import TrackingLaw

__all__ = ["ILQRSettings", "PlanSettings", "PlanThenLaw", "SwingManoeuvre", "TrackThenLaw", "TrackingLaw", "fit_mlp", "ilqr_plans",
           "plan_candidates", "search_plans"]

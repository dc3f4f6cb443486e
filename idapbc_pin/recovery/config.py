"""`RecoveryConfig`: every number of the recovery stage, a frozen dataclass read from the Python API or
from a TOML file (`idapbc-pin recover RUN --config recovery.toml`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from .._settings import Settings
from ..errors import IdapbcError
from ..trajectory.plans import PlanSettings

__all__ = ["FORMS", "RecoveryConfig", "START_BOXES", "SwingUpConfig", "TEACHERS"]


#: Boxes the recovery law's start states may be drawn from (`RecoveryConfig.start_box`).
START_BOXES = ("half", "domain")
#: Feedback laws that label the starts they bring to x* and catch every plan (`RecoveryConfig.teacher`).
TEACHERS = ("lqr", "run")
#: Forms of the fitted law (`RecoveryConfig.form`, `RecoveryLaw.residual`).
FORMS = ("direct", "residual")


@dataclass(frozen=True)
class RecoveryConfig(Settings):
    """How `recover` fits and gates a recovery law (`idapbc-pin recover --config FILE` reads it from a
    TOML file's ``[recovery]`` table; `from_file`).

    Attributes
    ----------
    starts : start states labelled by the teacher or plans, uniform in `start_box`.
    start_box : where the starts and the DAgger starts are drawn: ``"domain"`` (the training box,
        which holds the half box too) or ``"half"`` (the half box alone; `auto_recover` then moves
        to the training box where saturated LQR leaves room only there).
    teacher : the feedback law that runs from each start first, labels the starts it brings to x*,
        and takes over from every plan after its horizon: ``"run"`` (the run's own law as the gate
        judges it, without an earlier recovery law) or ``"lqr"`` (saturated LQR, Q = I, R = I). With
        "run" the fitted law imitates the IDA-PBC law where that law already reaches x*, and the plans
        only have to reach that law's basin.
    plan_seed : seed of those start states and of the plans' searches.
    dagger : DAgger rounds after the first fit.
    dagger_starts : starts of the fitted law per DAgger round, uniform in `start_box`.
    width : width of the MLP's two tanh layers.
    steps : Adam steps of each fit.
    batch : labels per minibatch of each fit.
    fit_seed : seed of each fit's initial weights and minibatches.
    fits : laws fitted to the final labels (seeds fit_seed, fit_seed + 1, …), each judged by the gate
        on the same states; the one it keeps with the most successes is the run's (`choose_fit`): a
        fit's seed alone moves the basin.
    library : also judge, beside the fits, the labelled paths read at the nearest point with the
        gains of a time-varying LQR along each (`stage.label_library`). The library is judged first,
        from the first labels: where the gate keeps it, no law is fitted (unless `always_fit`), nor
        where it brings `margin` or more fewer gate states to x* than the run's law.
    always_fit : fit, DAgger and judge the fits even where the gate judges the library alone first.
    library_speed : the weight of the momenta in the library's nearest-point distance (positions
        weigh 1; momenta are divided by M_ii(x*) first).
    library_every : of the library's points outside the smallest inner box, every `library_every`-th
        knot is kept (the exported controller searches every point each call).
    gate_states : states of the gate (half from the half box, half from the training box).
    inner_scales : candidate scales r of the inner box r·s where the IDA-PBC law keeps control.
    margin : successes the best candidate must add to the run's law on the gate's states to be kept.
    near_states : further gate states from the near box (scale NEAR_SCALE of the training box), not
        counted in the margin: a candidate must keep the run's law's successes there (0: no near box).
    half_loss : half-box and near-box gate states a candidate may lose against the run's law and stay
        eligible, so that the recovery law does not shrink the basin the IDA-PBC law already has
        (0: no loss at all). None is forgiven in the half box where the run's law brings all of its
        gate states there.
    confirm_states : where the run's law brings all of the half-box gate states to x*, half-box
        states of their own from which a law the rule keeps must bring no more than `half_loss`
        fewer to x* than the run's law (`gate._Confirmation`; 0: no such check).
    workers : processes that search the plans, fit the laws and run the gate's simulations (0: one
        per available core, at most 16). The count changes the time only, never a plan, label, law
        or verdict.
    ray : None (`workers` processes), or run that work as Ray tasks: ``"auto"`` (a local instance,
        or $RAY_ADDRESS's cluster) or a cluster's address; the back-end changes the time only.
    plan : the search of the plans (`plans.PlanSettings`: iLQR by default).
    judge_T : horizon of the rollouts that judge a start (the teacher's, each plan's, each DAgger
        round's), s: at least 8 (6 s of labels, then the 2 s success window). A start not brought
        to x* by then gets a plan, or none; the gate and every evaluation still judge over 20 s.
    stop_when_lost : end the DAgger rounds, before labelling, when the first fit brings none of the
        first round's starts to x* and fewer than half of them end in the near box (`ends_near`; the
        gate then judges that law).
    form : ``"direct"`` (the MLP's output is the input, ū tanh(MLP)) or ``"residual"`` (the MLP
        corrects the IDA-PBC law's own input; `fit`, docs/stages.md).
    levels : quantiles of H_d over the half box giving the levels c the gate tries, with the same
        rule, when it keeps no inner box: the IDA-PBC law then keeps {H_d ≤ c} (`RecoveryLaw.level`).
        Empty: the inner boxes alone.
    """

    _what, _table, _fix = "recovery config", "recovery", "see RecoveryConfig's fields"

    starts: int = 200
    start_box: str = "domain"
    teacher: str = "run"
    plan_seed: int = 101
    dagger: int = 1
    dagger_starts: int = 30
    width: int = 128
    steps: int = 4500
    batch: int = 1024
    fit_seed: int = 0
    fits: int = 2
    library: bool = True
    always_fit: bool = False
    library_speed: float = 0.3
    library_every: int = 2
    gate_states: int = 100
    near_states: int = 100
    inner_scales: tuple = (0.25, 0.5)
    margin: int = 3
    half_loss: int = 2
    confirm_states: int = 200
    workers: int = 0
    ray: str | None = None
    plan: PlanSettings = field(default_factory=PlanSettings)
    judge_T: float = 10.0
    stop_when_lost: bool = True
    levels: tuple = (0.1, 0.25, 0.5)
    form: str = "direct"

    def __post_init__(self):
        checks = [
            (self.starts >= 1 and self.dagger_starts >= 1 and self.gate_states >= 2 and min(self.near_states, self.confirm_states) >= 0,
             "starts, dagger_starts must be ≥ 1, gate_states ≥ 2, near_states and confirm_states ≥ 0"),
            (self.dagger >= 0 and self.workers >= 0 and min(self.width, self.steps, self.fits, self.batch) >= 1, "dagger, workers ≥ 0, width, steps, batch and fits ≥ 1"),
            (len(self.inner_scales) >= 1 and all(0 <= r <= 1 for r in self.inner_scales), "inner_scales must be scales in [0, 1]"),
            (self.half_loss >= 0 and all(0 < q < 1 for q in self.levels), "half_loss must be ≥ 0 and levels quantiles in (0, 1)"),
            (self.library_speed >= 0 and self.library_every >= 1, "library_speed must be ≥ 0 and library_every ≥ 1"),
            (self.start_box in START_BOXES, f"start_box must be one of {', '.join(START_BOXES)}"),
            (self.teacher in TEACHERS, f"teacher must be one of {', '.join(TEACHERS)}"),
            (self.form in FORMS, f"form must be one of {', '.join(FORMS)}"),
            (self.judge_T >= 8.0, "judge_T must be ≥ 8 s (6 s of labels, then the success window)"),
            (self.ray is None or (isinstance(self.ray, str) and self.ray.strip() != ""), "ray must be \"auto\" or a cluster address"),
        ]
        for ok, what in checks:
            if not ok:
                raise IdapbcError(f"bad recovery setting: {what}. Fix: pass valid values.")


@dataclass(frozen=True)
class SwingUpConfig(Settings):
    """How `swing_up` fits and gates a swing-up law (`idapbc-pin train --swing-up --swing-config FILE`
    reads it from a TOML file's ``[swing_up]`` table; `from_file`).

    Attributes
    ----------
    starts : near-resting start states labelled by plans (`sim.states.resting_states`, seed
        `plan_seed`; the first exactly at rest).
    plan_seed : seed of those starts (and, + 300 + r, of DAgger round r's).
    horizon : length of each plan from a start, s; the run's law catches after it.
    ilqr_iterations : iterations of each iLQR solve.
    dagger : DAgger rounds after the first fit.
    dagger_starts : near-resting starts of the fitted law per DAgger round.
    stop_when_lost : end the DAgger rounds, before labelling, when the first fit holds none of the
        first round's starts (the gate then judges that law): on the zoo acrobot, where the plans
        reach x* from few starts, the rounds cost three minutes and the gate kept no law.
    width, steps, batch, fit_seed : the MLP's width, and the fit's Adam steps, minibatch and seed.
    circle : beside each set of near-resting starts (the labels', each DAgger round's, the gate's),
        round(circle × its count) more states at rest with every angle from the full circle
        (`sim.states.circle_states`, seed + 1 of the set's); 0 (the default): near-resting starts
        only, since on the zoo pendubot a law fitted with them held no more states from the circle.
    gate_states : near-resting states of the gate (a seed of their own), judged by "holds" over `judge_T`.
    box_states : states of the gate from the half box and the training box (half each), judged over
        20 s: the law is kept only if it loses at most `box_loss` of those the run's law brings to x*.
    margin : near-resting states the law must hold beyond the run's law to be kept.
    time_margin : s; a law that holds as many as the run's law is kept where its median time to x*
        over the gate's swing-up states is this much sooner; candidates within it of the fastest
        count as equally fast.
    box_loss : see `box_states`.
    inner_scales : kept boxes r·s (every component) the gate tries beside the box's angles and
        `kept_momenta` (`swing_stage.kept_boxes`); none by default: a law acting through the box's postures
        at speed held fewer swing-ups than one that leaves every posture of the box to the run's law.
    kept_momenta : the kept box's momenta, as a multiple of the training box's (0: not read): beyond
        them the swing-up law acts even in the box's postures, where the run's law, trained at low
        speed, would command torques that pump energy (a push through the top at speed can then spin
        a link up without bound).
    judge_T : horizon of every swing-up rollout (the teacher's, the plans', DAgger's, the gate's), s.
    always_fit : label, fit and DAgger even where a tracking law already holds every near-resting
        start of its own (by default those steps are skipped there: the tracking laws, the manoeuvre
        and the anywhere library cover the swing-up, and the fits cost most of the stage's time).
    tracks : tracking laws (`trajectory.tracks`: nominal plans from the exact resting posture,
        each tracked from the nearest point by a time-varying LQR) the gate judges beside the fits; 0:
        none.
    funnels : radii ϱ (`TrackingLaw.funnel`: the weighted distance to the nominal's nearest point,
        1 per rad) within which a tracking law acts; where the gate keeps no law, it judges each
        tracking law within each of them (beyond ϱ the run's law keeps the paths of its own box that
        swing far out); empty: none.
    track_iterations : iterations of the iLQR solves of those nominals.
    track_share : share of the effort limits the nominals use (the rest is the feedback's).
    manoeuvre : also judge each nominal as a manoeuvre from rest, tracked in time
        (`trajectory.manoeuvre`), and keep the best where it holds `margin` more than the run's law, or
        as many and scores higher from the exact resting state (RealAIGym v2; sooner at x* without a URDF tip).
    manoeuvre_horizons : lengths (s) of further nominal plans from rest, tried as manoeuvres only
        (beside those of `horizon`, which the tracking laws read too): a short swing-up scores
        better where the robot can do it (the v2 score prices time, torque and speed).
    library : postures at rest from the full circle (and the resting posture) that the anywhere step
        plans from (`recovery.anywhere_stage`, `trajectory.library`): a library of short plans read
        at the nearest point, kept as the swing-up law where it brings the robot up from anywhere
        up faster and loses nothing near hanging or in the box; 0: no anywhere step.
    library_moving : states anywhere and moving, every joint's speed up to its URDF rating
        (`sim.states.moving_states`), that the library plans from beside its postures at rest: the
        uptime test releases the robot at speed, and a law read at the nearest knot of plans from
        rest brakes to rest before it swings up; 0: postures at rest only.
    library_released : states as the uptime test's reset drive releases them
        (`sim.drive.drive_release_states`: a 0.2-s PID drive from x* at rest or from moving states
        towards a posture from the full circle) that the library plans from beside the others; 0: none.
    gate_moving : states anywhere and moving (`sim.states.moving_states`: every speed up to its
        joint's rating) of the anywhere gate, judged with the law as deployed (speed governor on).
    gate_released : states as the reset drive releases them (`sim.drive.drive_release_states`) that
        the anywhere gate judges beside its `gate_moving` states, counted with them; 0: none.
    library_share : share of the effort limits the library's plans use: less than the nominals'
        `track_share`, so that the gains keep room to recover from a push or a poor knot.
    library_horizon : length of each of the library's plans, s.
    library_longer : lengths (s) of further plans, tried in turn from the starts that no shorter plan
        brings up (`trajectory.library.horizon_nominals`); where they give more, the gate judges a
        second library with every nominal beside the first (`anywhere_stage`); empty: none.
    library_iterations : iterations of the iLQR solves of the library's plans.
    library_refine : further iterations of the two cheapest `library_horizon` plans of each start
        none of whose plans ends with its tip at `library_tip` (0: none): the end pin at x* takes
        more iterations than the swing (`trajectory.library`).
    library_tip : the tip's normalised height (0 hanging, 1 at x*; `sim.leaderboard.tip_share`) at
        which each `library_horizon` plan must end (0: not read): a plan cut short of x* leaves the
        last of its swing-up to the catch, which is slow. The `library_longer` plans, a fallback
        for the starts the short ones cannot bring up, are not held to it.
    speed_limits : bound every actuated joint's speed in the nominals, manoeuvres and library plans by
        its URDF `<limit velocity>`, the motor's rated speed (`trajectory.ilqr`'s speed term; set
        `[recovery.plan] speed_limits` too for the reach stage's plans).
    workers, ray : as `RecoveryConfig`'s: processes (0: one per core) or Ray tasks; the time only.
    """

    _what, _table, _fix = "swing-up config", "swing_up", "see SwingUpConfig's fields"

    starts: int = 40
    plan_seed: int = 211
    horizon: float = 4.0
    ilqr_iterations: int = 12
    dagger: int = 2
    dagger_starts: int = 30
    stop_when_lost: bool = True
    circle: float = 0.0
    width: int = 128
    steps: int = 4500
    batch: int = 1024
    fit_seed: int = 0
    gate_states: int = 20
    box_states: int = 100
    margin: int = 2
    time_margin: float = 0.25
    box_loss: int = 2
    inner_scales: tuple = ()
    kept_momenta: float = 5.0
    judge_T: float = 10.0
    tracks: int = 2
    funnels: tuple = (0.5, 1.0)
    always_fit: bool = False
    track_iterations: int = 80
    track_share: float = 0.8
    manoeuvre: bool = True
    manoeuvre_horizons: tuple = (1.5, 2.0)
    library: int = 128
    library_moving: int = 64
    library_released: int = 64
    gate_moving: int = 40
    gate_released: int = 40
    library_share: float = 0.6
    library_horizon: float = 1.0
    library_longer: tuple = (2.0,)
    library_iterations: int = 40
    library_refine: int = 160
    library_tip: float = 0.98
    speed_limits: bool = False
    workers: int = 0
    ray: str | None = None

    def __post_init__(self):
        ok = (all(0 < r <= 1 for r in self.inner_scales) and all(0 < r < float("inf") for r in self.funnels) and 0 < self.track_share <= 1 and 0 < self.library_share <= 1
              and min(self.starts, self.dagger_starts, self.gate_states, self.gate_moving, self.width, self.steps, self.batch, self.ilqr_iterations, self.track_iterations, self.library_iterations) >= 1
              and min(self.dagger, self.box_states, self.margin, self.box_loss, self.workers, self.fit_seed, self.plan_seed, self.tracks, self.library, self.library_moving, self.library_released, self.gate_released, self.library_refine) >= 0
              and 0 <= self.library_tip <= 1
              and 0 < self.library_horizon <= self.judge_T - 2.0 and all(0 < h <= self.judge_T - 2.0 for h in self.library_longer) and self.time_margin >= 0
              and self.horizon > 0 and self.judge_T >= self.horizon + 2.0 and 0 <= self.circle <= 10 and self.kept_momenta >= 0
              and all(0 < h <= self.judge_T - 2.0 for h in self.manoeuvre_horizons))
        if not ok:
            raise IdapbcError("bad swing-up setting: starts, dagger_starts, gate_states, gate_moving, width, steps, batch, ilqr_iterations, track_iterations and library_iterations "
                              "must be ≥ 1, the other counts and seeds ≥ 0, inner_scales, track_share and library_share in (0, 1], library_tip in [0, 1], funnels finite and > 0, circle in [0, 10], kept_momenta ≥ 0, horizon, "
                              "manoeuvre_horizons, library_horizon and library_longer > 0 and judge_T ≥ each of them + 2 s. Fix: pass valid values.")

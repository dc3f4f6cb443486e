"""Tracking laws from the resting posture (`trajectory.tracks`, `trajectory.tracking_law`): the
time-varying LQR is the discrete LQR where the plan rests at x*, the law reproduces its plan and
gains to first order in the run's coordinates (q, p), and it acts only outside its kept box. The
manoeuvre (`trajectory.manoeuvre`) interpolates the plan's inputs between the knots' midpoints without a
step, follows its plan from its own start, then hands over."""

import numpy as np
import pytest
import scipy.linalg

import idapbc_pin as ip
from idapbc_pin.trajectory.ilqr import _knot_jacobians, rollout
from idapbc_pin.recovery.swing_law import swing_law_from_arrays
from idapbc_pin.trajectory.plans import PLAN_STEP
from idapbc_pin.trajectory.tracks import KNOT, TRACK_Q, TRACK_R, dense_plan, reaches, tracking_law, tvlqr_gains
from idapbc_pin.trajectory.tracking_law import TrackingLaw


@pytest.fixture(scope="module")
def pendubot():
    return ip.load_system("pendubot", effort={"shoulder": 8.0})


def _plan(system, K: int = 12, seed: int = 0, substeps: int = 1):
    """A short plan: random inputs within a third of the limit from a state near x*, its rollout (RK4,
    `substeps` steps per knot) and random gains: (U (K, m), Z (K + 1, n) in (q, v), G (K, m, n))."""
    rng = np.random.default_rng(seed)
    nq = system.nq
    U = rng.uniform(-1, 1, (K, system.m)) * system.effort / 3
    z0 = np.r_[np.asarray(system.x_star[:nq]) + rng.uniform(-1, 1, nq), rng.uniform(-1, 1, nq)]
    Z = rollout(system, z0[None], U[None], KNOT, substeps)[0]
    return U, Z, rng.normal(size=(K, system.m, 2 * nq))


def test_the_tracking_gains_where_the_plan_rests_at_x_star_are_the_discrete_lqr_gains(pendubot):
    """Far from its end, the time-varying LQR along a plan that stays at x* with u = u* converges to
    the stationary gain of the discrete Riccati equation (scipy's solver, an independent reference)."""
    system, nq = pendubot, pendubot.nq
    K = 600
    z_star = np.r_[np.asarray(system.x_star[:nq]), np.zeros(nq)]
    U, Z = np.zeros((K, system.m)), np.tile(z_star, (K + 1, 1))
    G = tvlqr_gains(system, U, Z)
    A, B = (a[0] for a in _knot_jacobians(system, z_star[None], U[:1], KNOT))
    Q = np.diag(np.r_[np.full(nq, TRACK_Q), np.full(nq, 0.1 * TRACK_Q)]) * KNOT
    R = TRACK_R * KNOT * np.eye(system.m)
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    gain = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    np.testing.assert_allclose(G[0], -gain, rtol=1e-6, atol=1e-9)
    assert np.abs(np.linalg.eigvals(A + B @ G[0])).max() < 1  # the loop it closes is stable


def test_the_tracking_law_follows_its_plan_and_gains_to_first_order_in_q_and_p(pendubot):
    system, nq = pendubot, pendubot.nq
    U, Z, G = _plan(system)
    law = tracking_law(system, U, Z, G, 0.3, np.zeros(system.n))  # a null kept box: it acts everywhere
    x_nominal = system.state_from(Z[:-1, :nq], Z[:-1, nq:])
    np.testing.assert_allclose(law.X, x_nominal, atol=1e-12)
    np.testing.assert_allclose(law.apply(x_nominal, np.zeros((len(U), system.m))), U, atol=1e-12)  # on the plan: its inputs
    rng = np.random.default_rng(1)
    k = 5
    e = rng.normal(size=2 * nq)
    errors = []
    for eps in (1e-3, 5e-4):
        z = Z[k] + eps * e
        x = system.state_from(z[None, :nq], z[None, nq:])
        assert law.nearest(x)[0][0] == k
        errors.append(np.abs(law.law(x)[0] - (U[k] + G[k] @ (eps * e))).max())
    assert errors[0] < 1e-3 * np.abs(G[k] @ e).max()  # second order: small against the first-order term
    assert 3.0 < errors[0] / errors[1] < 5.0  # and it quarters as the step halves


def test_a_dense_nominal_passes_through_the_knots_and_its_motion_within_a_knot_is_no_error(pendubot):
    """Every r-th tick of the dense plan is a knot of the plan; between them it is the plant's own
    motion under the held input (the judge's 2-ms RK4). Read from the nearest point, the dense law
    gives the plan's input on every tick of the nominal; the law on the knots alone reads the motion
    within a knot as an error and pushes against it."""
    system, nq = pendubot, pendubot.nq
    U, Z, G = _plan(system, substeps=int(round(KNOT / PLAN_STEP)))
    Ud, Zd, Gd = dense_plan(system, U, Z, G)
    r = int(round(KNOT / PLAN_STEP))
    assert Ud.shape == (len(U) * r, system.m) and Zd.shape == (len(U) * r + 1, 2 * nq) and Gd.shape == (len(U) * r, *G.shape[1:])
    np.testing.assert_array_equal(Zd[::r], Z)
    np.testing.assert_array_equal(Ud[::r], U)
    mid = rollout(system, Z[3:4], np.repeat(U[3][None, None], r // 2, axis=1), PLAN_STEP, 1)[0, -1]
    np.testing.assert_allclose(Zd[3 * r + r // 2], mid, rtol=1e-12, atol=1e-12)
    box = np.zeros(system.n)
    dense, knots = tracking_law(system, U, Z, G, 0.3, box, dense=True), tracking_law(system, U, Z, G, 0.3, box)
    x = system.state_from(Zd[:-1, :nq], Zd[:-1, nq:])
    np.testing.assert_allclose(dense.apply(x, np.zeros((len(x), system.m))), np.clip(Ud, -system.effort, system.effort), atol=1e-9)
    off = np.abs(knots.apply(x, np.zeros((len(x), system.m))) - np.clip(Ud, -system.effort, system.effort)).max()
    assert off > 1e-3  # the knots-only law departs from the plan's input within a knot


def test_a_plan_reaches_when_it_ends_within_the_training_box_s_angles(pendubot):
    system, nq = pendubot, pendubot.nq
    lo, hi = (np.asarray(b, float) for b in system.domain)
    star = np.r_[np.asarray(system.x_star[:nq]), np.zeros(nq)]
    half = 0.5 * (hi - lo)[:nq]
    ends = np.stack([star, star + np.r_[0.9 * half, 50.0, -50.0], star + np.r_[2 * np.pi, -4 * np.pi, 0, 0],
                     star + np.r_[1.1 * half[0], 0, 0, 0], star + np.r_[np.pi, 0, 0, 0]])
    assert reaches(system, ends).tolist() == [True, True, True, False, False]  # speeds not read; whole turns are no distance


def test_a_tracking_law_acts_outside_its_kept_box_within_the_limits_and_round_trips(pendubot):
    system = pendubot
    U, Z, G = _plan(system, seed=2)
    lo, hi = system.domain
    box = np.where(system.angle_mask, (hi - lo) / 2, np.inf)
    law = tracking_law(system, U, 50.0 * Z, 50.0 * G, 1.0, box)  # large gains and states: it saturates somewhere
    rng = np.random.default_rng(3)
    x = system.x_star + rng.uniform(-1, 1, (500, system.n)) * np.r_[np.full(system.nq, 3.0), np.full(system.nq, 5.0)]
    u = law.apply(x, np.full((len(x), system.m), 123.0))
    out = law.outside(x)
    assert 0 < out.sum() < len(x)
    np.testing.assert_array_equal(u[~out], 123.0)
    assert np.abs(u[out]).max() <= system.effort.max() * (1 + 1e-12) and (np.abs(u[out]) >= system.effort * (1 - 1e-12)).any()
    back = swing_law_from_arrays(law.arrays())
    assert isinstance(back, TrackingLaw)
    np.testing.assert_array_equal(back.apply(x, u), law.apply(x, u))
    bad = law.arrays() | {"K": law.K[:, :, :-1]}
    with pytest.raises(ValueError, match="do not fit together"):
        TrackingLaw.from_arrays(bad)


def test_a_tracking_law_with_a_funnel_acts_only_near_its_nominal_and_round_trips(pendubot):
    """With a funnel ϱ the law acts where the state is outside the kept box *and* within ϱ of its
    nearest nominal point (the weighted distance, by hand); elsewhere the run's law's u passes
    through. Its arrays carry ϱ, and arrays saved without one read as no funnel."""
    system = pendubot
    U, Z, G = _plan(system, seed=2)
    lo, hi = system.domain
    box = np.where(system.angle_mask, (hi - lo) / 2, np.inf)
    plain = tracking_law(system, U, Z, G, 1.0, box)
    rng = np.random.default_rng(5)
    x = system.x_star + rng.uniform(-1, 1, (600, system.n)) * np.r_[np.full(system.nq, 3.0), np.full(system.nq, 5.0)]
    _, d = plain.nearest(x)
    dist = np.sqrt(((d * plain.weight) ** 2).sum(axis=1))
    rho = float(np.median(dist[plain.outside(x)]))
    law = plain.with_funnel(rho)
    expected = plain.outside(x) & (dist <= rho)
    assert 0 < expected.sum() < plain.outside(x).sum()
    np.testing.assert_array_equal(law.outside(x), expected)
    u = law.apply(x, np.full((len(x), system.m), 123.0))
    np.testing.assert_array_equal(u[~expected], 123.0)
    np.testing.assert_array_equal(u[expected], plain.law(x[expected]))
    np.testing.assert_array_equal(law.outside(x.reshape(3, 200, -1)), expected.reshape(3, 200))  # any leading shape
    back = swing_law_from_arrays(law.arrays())
    assert back.funnel == rho
    np.testing.assert_array_equal(back.apply(x, u), law.apply(x, u))
    old = {k: v for k, v in law.arrays().items() if k != "funnel"}
    assert TrackingLaw.from_arrays(old).funnel == np.inf
    with pytest.raises(ValueError, match="funnel must be positive"):
        TrackingLaw.from_arrays(law.arrays() | {"funnel": np.array(0.0)})
    assert law.to_json()["funnel"] == rho and plain.to_json()["funnel"] is None


def test_the_region_test_at_the_states_of_the_last_call_is_not_computed_again(pendubot, monkeypatch):
    """`outside` called again with the same states (as `reads_networks` and `apply` are in one tick)
    searches no nearest point and returns what a fresh law computes; changed states, even in place, and
    another funnel (`with_funnel`) are computed afresh."""
    system = pendubot
    U, Z, G = _plan(system, seed=2)
    lo, hi = system.domain
    box = np.where(system.angle_mask, (hi - lo) / 2, np.inf)
    plain = tracking_law(system, U, Z, G, 1.0, box)
    x = system.x_star + np.random.default_rng(6).uniform(-3, 3, (50, system.n))
    _, d = plain.nearest(x)
    rho = float(np.median(np.sqrt(((d * plain.weight) ** 2).sum(axis=1))[plain.outside(x)]))
    law = plain.with_funnel(rho)
    searches = []
    nearest = TrackingLaw.nearest
    monkeypatch.setattr(TrackingLaw, "nearest", lambda self, y: searches.append(len(y)) or nearest(self, y))
    first = law.outside(x)
    first[:] = True  # the caller's copy: the memo keeps its own
    again = law.outside(x)
    assert len(searches) == 1
    fresh = tracking_law(system, U, Z, G, 1.0, box).with_funnel(rho)
    np.testing.assert_array_equal(again, fresh.outside(x))
    assert 0 < again.sum() < len(x)
    x[0] = system.x_star  # changed in place: inside the kept box now
    assert not law.outside(x)[0] and len(searches) == 3
    np.testing.assert_array_equal(law.with_funnel(0.1).outside(x), fresh.with_funnel(0.1).outside(x))
    np.testing.assert_array_equal(law.apply(x, np.zeros((len(x), 1))), fresh.apply(x, np.zeros((len(x), 1))))


def test_on_its_nominal_a_manoeuvre_interpolates_the_plan_s_inputs_without_a_step_at_a_knot(pendubot):
    """At the nominal state interpolated between two knots, the manoeuvre's input is the plan's
    inputs interpolated between the knots' midpoints (the feedback reads no error): continuous
    through a knot, U_0 over the first half knot and the last input over the last half knot."""
    from idapbc_pin.trajectory.manoeuvre import SwingManoeuvre

    system, nq = pendubot, pendubot.nq
    U, Z, _ = _plan(system, K=20, seed=4)
    G = tvlqr_gains(system, U, Z)
    end = system.state_from(Z[-1:, :nq], Z[-1:, nq:])[0]
    manoeuvre = SwingManoeuvre(tracking_law(system, U, Z, G, 1.0, np.zeros(system.n)), end, KNOT)
    X = manoeuvre.track.X
    effort = float(system.effort[0])
    on = lambda k, a: X[k] + a * ((X[k + 1] if k + 1 < len(X) else end) - X[k])  # noqa: E731
    for k, a, expected in ((3, 0.5, U[3]), (3, 0.8, 0.7 * U[3] + 0.3 * U[4]), (7, 0.25, 0.25 * U[6] + 0.75 * U[7]), (0, 0.2, U[0]), (19, 0.9, U[19])):
        np.testing.assert_allclose(manoeuvre.inputs(on(k, a), (k + a) * KNOT), np.clip(expected, -effort, effort)[None], atol=1e-9)
    eps = 1e-7
    before, after = manoeuvre.inputs(X[10], 10 * KNOT - eps), manoeuvre.inputs(X[10], 10 * KNOT)
    assert np.abs(before - after).max() < 1e-4 * max(1.0, np.abs(U).max())


def test_a_manoeuvre_from_its_own_start_follows_its_plan_then_hands_over(pendubot):
    """Tracked in time from the plan's first state by its own time-varying LQR, the manoeuvre stays on
    its nominal (the law sampled every 2 ms against the nominal interpolated between the 20 ms knots;
    the plan and the judge both integrate by RK4 at 2 ms); after the plan the law it hands over to
    acts; a fresh law starts again at t = 0."""
    from idapbc_pin.trajectory.manoeuvre import SwingManoeuvre
    from idapbc_pin.sim.integrate import simulate

    system, nq = pendubot, pendubot.nq
    U, Z, _ = _plan(system, K=40, seed=4, substeps=int(round(KNOT / 0.002)))
    G = tvlqr_gains(system, U, Z)
    end = system.state_from(Z[-1:, :nq], Z[-1:, nq:])[0]
    manoeuvre = SwingManoeuvre(tracking_law(system, U, Z, G, 1.0, np.zeros(system.n)), end, KNOT)
    after = lambda x: np.full((len(np.atleast_2d(x)), system.m), 0.25)  # noqa: E731
    x0 = system.state_from(Z[:1, :nq], Z[:1, nq:])
    traj = simulate(system, manoeuvre.law(after), x0, T=manoeuvre.duration + 0.1, dt=0.002, limits=False, stop_settled=False)
    per = int(round(KNOT / 0.002))
    q_knots = traj.q[0, : len(U) * per + 1 : per]
    excursion = np.abs(Z[:, :nq] - Z[0, :nq]).max()
    assert excursion > 1.0  # the nominal moves by more than a radian; the loop stays within 0.3 % of that
    np.testing.assert_allclose(q_knots, Z[:, :nq], atol=3e-3 * excursion)
    # at each knot's midpoint its inputs are the plan's, but for the last knots, where the gains pull towards x* (the end cost)
    np.testing.assert_allclose(traj.u[0, per // 2 : 30 * per : per], U[:30], atol=0.05 * float(system.effort[0]))
    np.testing.assert_allclose(traj.u[0, len(U) * per + 1 :], 0.25)  # then the law after it
    law = manoeuvre.law(after)
    np.testing.assert_allclose(law(x0), U[:1], atol=1e-9)  # at its first state: its first input (held over the first half knot)
    back = SwingManoeuvre.from_arrays(manoeuvre.arrays())
    assert back.knot == KNOT and np.array_equal(back.track.K, manoeuvre.track.K) and np.array_equal(back.end, end)
    with pytest.raises(ValueError, match="knot"):
        SwingManoeuvre.from_arrays(manoeuvre.track.arrays())


def test_the_manoeuvre_picked_holds_nearly_the_most_and_scores_best_from_rest_and_is_kept_only_if_it_does_better(monkeypatch):
    """`choose_manoeuvre`'s rule, read from its judgements (stubbed: the rule, not the simulations, is
    under test): among the manoeuvres holding ≥ `PICK_SHARE` of the most any holds, the best v2 from
    rest; kept where it holds `margin` more than the run's law, or as many and scores higher from rest;
    without a URDF tip (no score) the sooner settled ranks first."""
    import math

    from idapbc_pin.trajectory import manoeuvre as mod
    from idapbc_pin.trajectory.holds import Judged
    from idapbc_pin.recovery.config import SwingUpConfig

    class Stub:
        def __init__(self, i):
            self.i = i

        def law(self, after):
            return self.i

    nan = math.nan
    judged_beyond_rest = []

    def choose(picked, run, own, config=SwingUpConfig()):
        """`picked`: each manoeuvre's holds of the 20 near-resting starts and its verdict from rest."""
        x_pick, x_gate = np.zeros((20, 4)), np.ones((20, 4))

        def judge(system, laws, x0, config, score=False):
            if x0[0, 0] == 1.0:  # the gate: the run's law, then the manoeuvre picked
                return [run, own]
            if len(x0) == 1:  # each from exact rest, scored
                return [Judged(min(1, picked[i].held), picked[i].rest_time, picked[i].rest_score) for i in laws]
            judged_beyond_rest.extend(laws)
            return [Judged(picked[i].held - min(1, picked[i].held), nan, nan) for i in laws]

        monkeypatch.setattr(mod, "judge_starts", judge)
        return mod.choose_manoeuvre(None, None, [Stub(i) for i in range(len(picked))], x_pick, x_gate, config)

    picked = [Judged(20, 4.0, 0.30), Judged(18, 3.0, 0.55), Judged(17, 2.0, 0.70), Judged(5, 2.0, 0.90)]
    best, entry = choose(picked, run=Judged(20, 5.0, 0.20), own=Judged(20, 3.0, 0.55))
    assert mod.PICK_SHARE == 0.9 and entry["choice"] == 1 and best == 1  # 18 ≥ 0.9 · 20 > 17: the best score among 20, 18
    assert entry["used"] and entry["picked_score"] == [0.30, 0.55, 0.70, 0.90] and entry["rest_score"] == {"run": 0.20, "manoeuvre": 0.55}
    assert choose(picked, run=Judged(20, 5.0, 0.60), own=Judged(20, 3.0, 0.55))[0] is None  # as many held, a lower score: not kept
    assert choose(picked, run=Judged(18, 5.0, 0.60), own=Judged(19, 3.0, 0.55))[0] is None  # 2 more needed where it scores lower
    assert choose(picked, run=Judged(18, 5.0, 0.60), own=Judged(19, 3.0, 0.55))[1]["held"] == 19
    assert choose(picked, run=Judged(15, 5.0, 0.60), own=Judged(17, 3.0, 0.10))[0] == 1  # margin more held: kept
    no_tip = [Judged(20, 4.0, nan), Judged(19, 3.0, nan), Judged(20, nan, nan)]
    best, entry = choose(no_tip, run=Judged(19, 5.0, nan), own=Judged(19, 3.0, nan))
    assert best == 1 and entry["picked_score"] == [None, None, None] and entry["rest_score"]["run"] is None  # sooner settled
    assert choose(no_tip, run=Judged(19, 2.0, nan), own=Judged(19, 3.0, nan))[0] is None
    # judged best from rest first, two at a time (two workers): once one holds all 20 and every one
    # ranked as high is judged, the lower ranked are not judged beyond rest (they could not be picked)
    ties = [Judged(20, 4.0, 0.30), Judged(20, 3.0, 0.80), Judged(20, 2.0, 0.80), Judged(12, 2.0, 0.90), Judged(20, 2.0, 0.50)]
    judged_beyond_rest.clear()
    best, entry = choose(ties, run=Judged(20, 5.0, 0.20), own=Judged(20, 3.0, 0.80), config=SwingUpConfig(workers=2))
    assert best == 1 and entry["picked"] == [None, 20, 20, 12, 20] and sorted(judged_beyond_rest) == [1, 2, 3, 4]
    assert entry["picked_score"] == [0.30, 0.80, 0.80, 0.90, 0.50]  # every one from rest


def test_a_library_reads_each_nominal_at_its_own_knots(pendubot, monkeypatch):
    """`nominals_law` puts every knot of every nominal into one `TrackingLaw`: at a knot of either
    nominal the law reads that nominal's own input (its distance is zero there); no nominal, no law.
    The starts are the resting posture and postures at rest from the circle."""
    from idapbc_pin.model.resting import resting_configuration
    from idapbc_pin.trajectory import library

    plans = [_plan(pendubot, seed=s)[:2] for s in (1, 2)]
    box = np.full(pendubot.n, np.inf)
    law = library.nominals_law(pendubot, plans, box, speed_weight=0.3)
    assert law.X.shape == (24, pendubot.n) and law.K.shape == (24, pendubot.m, pendubot.n)
    for k, (U, Z) in enumerate(plans):
        alone = tracking_law(pendubot, U, Z, tvlqr_gains(pendubot, U, Z), 0.3, box)
        np.testing.assert_allclose(law.law(alone.X), np.clip(U, -pendubot.effort, pendubot.effort), rtol=0, atol=1e-12)
        np.testing.assert_array_equal(law.K[12 * k: 12 * (k + 1)], alone.K)
    assert library.nominals_law(pendubot, [], box, speed_weight=0.3) is None
    starts = library.library_starts(pendubot, 5, seed=3)
    q, v = pendubot.split(starts)
    assert starts.shape == (6, pendubot.n) and (v == 0).all()
    np.testing.assert_array_equal(q[0], resting_configuration(pendubot))


def test_a_longer_horizon_plans_only_the_starts_no_shorter_plan_brings_up(pendubot, monkeypatch):
    """`horizon_nominals`: every start is planned with the first horizon; each further horizon plans
    only the starts still without a nominal (its own warm-start seed), and a start keeps the nominal
    of the first horizon that gave it one. The refining and the tip apply to the first horizon only."""
    from idapbc_pin.trajectory import library

    starts = np.arange(5.0)[:, None] * np.ones(pendubot.n)
    calls = []

    def planned(system, catch, x, horizon, share, iterations, judge_T, seed, workers, progress, speed=0.0, refine=0, tip=0.0):
        calls.append((horizon, x[:, 0].tolist(), seed, refine, tip))
        reached = {1.0: (1, 3), 2.0: (0, 3, 4), 3.0: (0, 2)}[horizon]  # the starts (by index) a plan of each horizon brings up
        return [(horizon, int(s)) if int(s) in reached else None for s in x[:, 0]]

    monkeypatch.setattr(library, "library_nominals", planned)
    found, passes = library.horizon_nominals(pendubot, None, starts, (1.0, 2.0, 3.0), 1.0, 1, 3.0, seed=7, refine=5, tip=0.9)
    assert found == [(2.0, 0), (1.0, 1), (3.0, 2), (1.0, 3), (2.0, 4)] and passes == [1, 0, 2, 0, 1]
    assert calls == [(1.0, [0, 1, 2, 3, 4], 7, 5, 0.9), (2.0, [0, 2, 4], 7 + library.RETRY_SEED, 0, 0.0), (3.0, [2], 7 + 2 * library.RETRY_SEED, 0, 0.0)]
    calls.clear()
    assert library.horizon_nominals(pendubot, None, starts[[1, 3]], (1.0, 2.0), 1.0, 1, 3.0, seed=7, refine=5, tip=0.9) == ([(1.0, 1), (1.0, 3)], [0, 0])
    assert len(calls) == 1  # every start brought up: no longer plans
    assert library.horizon_nominals(pendubot, None, starts[[2]], (1.0, 2.0), 1.0, 1, 3.0, seed=7, refine=5, tip=0.9) == ([None], [-1])


def test_the_tracking_laws_tree_finds_the_same_nearest_point_as_every_point():
    from idapbc_pin.trajectory.tracking_law import _TREE_FROM, TrackingLaw, _brute_nearest

    rng = np.random.default_rng(7)
    P, n, m = 4 * _TREE_FROM, 4, 1
    mask = np.array([True, True, False, False])
    X = rng.uniform(-4, 4, (P, n)) * [1, 1, 2, 2]
    law = TrackingLaw(X, np.zeros((P, m)), np.zeros((P, m, n)), np.array([1.0, 0.7, 0.3, 0.2]), np.zeros(n), np.ones(m), mask,
                      np.full(n, np.inf))
    x = np.concatenate([rng.uniform(-10, 10, (3000, n)), X[::5] + 1e-3 * rng.normal(size=(P // 5 + 1, n)), 1e3 * rng.normal(size=(20, n))])
    np.testing.assert_array_equal(law.nearest(x)[0], _brute_nearest(x, X, law.weight, mask))


def test_a_joined_law_reads_whichever_law_has_the_nearer_knot(pendubot):
    """`TrackingLaw.join`: over the knots of both laws, each state gets the input of the law whose
    nearest knot is nearer (the distance of each law alone, by hand), with the first's weights and box."""
    box = np.full(pendubot.n, np.inf)
    a, b = (tracking_law(pendubot, U, Z, G, 0.3, box) for U, Z, G in (_plan(pendubot, seed=s) for s in (4, 5)))
    joined = TrackingLaw.join([a, b])
    assert len(joined.X) == len(a.X) + len(b.X) and joined.inner is None
    np.testing.assert_array_equal(joined.weight, a.weight)
    rng = np.random.default_rng(2)
    x = np.concatenate([a.X, b.X]) + 0.05 * rng.normal(size=(len(a.X) + len(b.X), pendubot.n))

    def distance(law):
        k, d = law.nearest(x)
        return ((d * a.weight) ** 2).sum(axis=1)

    np.testing.assert_allclose(joined.law(x), np.where((distance(a) <= distance(b))[:, None], a.law(x), b.law(x)), rtol=0, atol=1e-12)


def test_the_anywhere_step_joins_the_manoeuvre_and_the_tracking_law_it_would_replace(pendubot, monkeypatch):
    """The anywhere gate judges the library of the short plans, joined by the knots of the run's
    manoeuvre (else of its swing-up law, where that is a tracking law), and where a longer horizon
    gave more, the library of all plans, joined by both (each where the run has one); a run with
    neither is judged on the libraries alone. The step keeps the library the gate picks, and the
    entry says which knots joined it, and how many."""
    from types import SimpleNamespace

    from idapbc_pin.recovery import anywhere_stage
    from idapbc_pin.recovery.config import SwingUpConfig

    box = np.full(pendubot.n, np.inf)
    short, longer, own, fast = (tracking_law(pendubot, U, Z, G, 0.1, box) for U, Z, G in (_plan(pendubot, seed=s) for s in (6, 9, 7, 8)))
    fast = fast.with_box(box)
    judged = []
    monkeypatch.setattr(anywhere_stage, "library_law", lambda *args, **kw: ([(short, [1.0]), (longer, [1.0, 2.0])], [1, 1], 2))
    cases = ((own.with_inner(None), SimpleNamespace(track=fast), [fast, own], ["manoeuvre", "tracking law"], 1),
             (None, SimpleNamespace(track=fast), [fast], ["manoeuvre"], 0), (own.with_inner(None), None, [own], ["tracking law"], 1), (None, None, [], None, 0))
    for fallback, manoeuvre, joined, sources, pick in cases:
        now = SimpleNamespace(controller=SimpleNamespace(fallback=fallback), manoeuvre=manoeuvre)
        monkeypatch.setattr(anywhere_stage, "resolve_run", lambda path: now)
        monkeypatch.setattr(anywhere_stage, "anywhere_gate", lambda run, current, laws, config: judged.append(laws) or {"used": True, "library": pick})
        kept, entry = anywhere_stage.run_anywhere_step(SimpleNamespace(path=None), pendubot, None, box, SwingUpConfig(), progress=False)
        each = [joined[:1], joined]  # the short library's knots from hanging, the longer one's
        assert entry.get("joined", 0) == sum(len(j.X) for j in each[pick]) and entry.get("joined_from") == (sources if pick else (sources or [])[:1] or None)
        assert kept is judged[-1][pick]
        assert entry["nominals"] == 2 and entry["by_horizon"] == [1, 1] and entry["horizon"] == [1.0, 2.0] and entry["libraries"] == [[1.0], [1.0, 2.0]]
        for library, law, extra in zip((short, longer), judged[-1], each):
            np.testing.assert_array_equal(law.X, np.concatenate([library.X, *[j.X for j in extra]]))


def test_of_two_libraries_the_anywhere_gate_takes_the_longer_one_only_by_a_margin():
    """`_preferred`: the first library the rule keeps, unless a later one it keeps has its tip up for a
    share `ANYWHERE_MARGIN` larger; a tie or a smaller lead keeps the first; none kept: the largest share."""
    from idapbc_pin.recovery.anywhere_stage import ANYWHERE_MARGIN, _preferred

    assert _preferred([True, True], [0.70, 0.70]) == 0 and _preferred([True, True], [0.70, 0.70 + ANYWHERE_MARGIN / 2]) == 0
    assert _preferred([True, True], [0.50, 0.50 + 2 * ANYWHERE_MARGIN]) == 1
    assert _preferred([False, True], [0.90, 0.30]) == 1 and _preferred([True, False], [0.30, 0.90]) == 0
    assert _preferred([False, False], [0.30, 0.40]) == 1 and _preferred([False, False], [0.40, 0.40]) == 0


def test_the_library_starts_at_rest_round_the_circle_then_moving_at_up_to_the_joints_ratings(pendubot):
    """`library_starts` with `moving`: the starts at rest as without it, then that many states whose
    speeds reach beyond the ±1 rad/s of the anywhere states and stay within the URDF ratings."""
    from idapbc_pin.sim.metrics import joint_ratings
    from idapbc_pin.sim.states import ANYWHERE_SPEED
    from idapbc_pin.trajectory.library import library_starts

    rest = library_starts(pendubot, 4, seed=3)
    starts = library_starts(pendubot, 4, seed=3, moving=6)
    assert starts.shape == (11, 4)
    np.testing.assert_array_equal(starts[:5], rest)
    v = pendubot.split(starts)[1]  # (q, v): the speeds
    assert np.abs(v[:5]).max() < 1e-12 and (np.abs(v[5:]) > 0).all()
    assert np.abs(v[5:]).max() > ANYWHERE_SPEED and (np.abs(v[5:]) <= joint_ratings(pendubot) * (1 + 1e-9)).all()


def test_the_library_starts_end_with_the_states_the_reset_drive_releases(pendubot):
    """`library_starts` with `released`: the starts at rest and moving as without it, then that many
    states as the uptime test's reset drive leaves them (`drive_release_states` with seed + 2), moving."""
    from idapbc_pin.sim.drive import drive_release_states
    from idapbc_pin.trajectory.library import library_starts

    before = library_starts(pendubot, 4, seed=3, moving=2)
    starts = library_starts(pendubot, 4, seed=3, moving=2, released=3)
    assert starts.shape == (10, 4)
    np.testing.assert_array_equal(starts[:7], before)
    np.testing.assert_array_equal(starts[7:], drive_release_states(pendubot, 3, 5))
    assert (np.abs(pendubot.split(starts[7:])[1]).max(axis=1) > 1.0).all()


def test_the_anywhere_gate_judges_the_deployed_law_from_moving_states_at_up_to_the_ratings(pendubot, monkeypatch):
    """`anywhere_gate`: its states from anywhere are `gate_moving` moving states (`moving_states`,
    speeds up to the ratings) after `gate_states` near-resting ones, the same for every law judged."""
    from types import SimpleNamespace

    from idapbc_pin.recovery import anywhere_stage
    from idapbc_pin.recovery.config import SwingUpConfig
    from idapbc_pin.sim.drive import drive_release_states
    from idapbc_pin.sim.metrics import joint_ratings
    from idapbc_pin.sim.states import ANYWHERE_SPEED, moving_states, resting_states

    jobs = []

    def judged(worker, job_list, workers, ray):
        jobs.extend(job_list)
        return [(np.zeros(len(x0), bool), np.full(len(x0), np.nan), np.zeros(len(x0))) for _, _, x0, _ in job_list]

    monkeypatch.setattr(anywhere_stage, "process_map", judged)
    teacher = SimpleNamespace(fallback=None, with_fallback=lambda law: ("deployed", law))
    run = SimpleNamespace(system=pendubot, config=SimpleNamespace(seed=2), box_controller=teacher)
    library = SimpleNamespace(with_inner=lambda inner: "library")
    config = SwingUpConfig(gate_states=3, gate_moving=5, gate_released=0, box_states=0, workers=1)
    gate = anywhere_stage.anywhere_gate(run, "current", library, config)
    assert gate["states"]["near"] == 3 and gate["states"]["anywhere"] == 5 and [law for _, law, _, _ in jobs] == ["current", ("deployed", "library")]
    seed = anywhere_stage.ANYWHERE_GATE_SEED + 2
    for _, _, x0, _ in jobs:
        np.testing.assert_array_equal(x0, np.concatenate([resting_states(pendubot, 3, seed), moving_states(pendubot, 5, seed + 1)]))
    v = pendubot.split(jobs[0][2][3:])[1]
    assert np.abs(v).max() > ANYWHERE_SPEED and (np.abs(v) <= joint_ratings(pendubot) * (1 + 1e-9)).all()
    jobs.clear()
    gate = anywhere_stage.anywhere_gate(run, "current", library, config.replace(gate_released=2))  # with the drive's release states after them
    assert gate["states"]["anywhere"] == 7
    released = drive_release_states(pendubot, 2, seed + 3)
    for _, _, x0, _ in jobs:
        np.testing.assert_array_equal(x0, np.concatenate([resting_states(pendubot, 3, seed), moving_states(pendubot, 5, seed + 1), released]))


@pytest.mark.parametrize("lost, kept", [(0, True), (1, True), (2, False)])
def test_a_library_up_longer_is_kept_though_it_holds_one_moving_state_fewer_never_two(pendubot, monkeypatch, lost, kept):
    """`anywhere_gate`'s rule: a library with its tip up for a share `ANYWHERE_MARGIN` larger may hold
    `LIBRARY_LOSS` fewer states from anywhere than the law it replaces, not more."""
    from types import SimpleNamespace

    from idapbc_pin.recovery import anywhere_stage
    from idapbc_pin.recovery.config import SwingUpConfig

    assert anywhere_stage.LIBRARY_LOSS == 1
    near, moving = 3, 6
    shares = {"current": 0.3, "library": 0.3 + 2 * anywhere_stage.ANYWHERE_MARGIN}
    held = {"current": np.ones(near + moving, bool), "library": np.r_[np.ones(near + moving - lost, bool), np.zeros(lost, bool)]}

    def judged(worker, job_list, workers, ray):
        return [(held[law], np.full(near + moving, 2.0), np.full(near + moving, shares[law])) for _, law, _, _ in job_list]

    monkeypatch.setattr(anywhere_stage, "process_map", judged)
    teacher = SimpleNamespace(fallback=None, with_fallback=lambda law: law)
    run = SimpleNamespace(system=pendubot, config=SimpleNamespace(seed=0), box_controller=teacher)
    gate = anywhere_stage.anywhere_gate(run, "current", SimpleNamespace(with_inner=lambda inner: "library"),
                                        SwingUpConfig(gate_states=near, gate_moving=moving, gate_released=0, box_states=0, workers=1))
    assert gate["anywhere"] == [moving, moving - lost] and gate["near"] == [near, near] and gate["used"] == kept


def test_judging_starts_stops_settled_rows_without_changing_holds_or_times(pendubot):
    """`judge_starts`: without a score the rows settled in the success box stop early; the holds, the
    first start's settling time and the median time to x* equal those of the full horizon (a score
    asks for it), and a start that never settles counts as ∞ in the median."""
    from types import SimpleNamespace

    from idapbc_pin.control.baseline import LQRController
    from idapbc_pin.sim.integrate import simulate
    from idapbc_pin.sim.metrics import holds, settling_time
    from idapbc_pin.trajectory.holds import judge_starts

    system = pendubot
    rng = np.random.default_rng(0)
    x0 = system.x_star + rng.uniform(-0.05, 0.05, (6, system.n))
    x0[-2:] = system.x_star + np.r_[np.pi, np.zeros(system.n - 1)]  # hanging at rest: LQR never gets up
    config = SimpleNamespace(judge_T=4.0, workers=1, ray=None)
    lqr = LQRController(system)
    fast, full = judge_starts(system, [lqr], x0, config)[0], judge_starts(system, [lqr], x0, config, score=True)[0]
    traj = simulate(system, lqr, x0, T=4.0, dt=PLAN_STEP)
    times = settling_time(traj, system)
    assert fast.held == full.held == int(holds(traj, system).sum()) == 4
    assert fast.rest_time == full.rest_time == times[0]
    assert fast.median_time == full.median_time == np.median(np.where(np.isnan(times), np.inf, times))
    assert np.isfinite(fast.median_time)


def test_a_library_plan_that_leaves_the_swing_up_to_its_catch_is_no_nominal(monkeypatch):
    """A library nominal must swing up by itself (`reaches`): a 0.1-s plan from hanging cannot, and
    the energy pump that catches it then swings the reaction wheel up, so the plan holds at x* over
    `judge_T`. Kept, its knots would steer states towards its end near hanging, where the law then
    holds them. With the reach rule lifted the same plan is a nominal, so the rule is what refuses it."""
    from idapbc_pin.control.energy_pump import EnergyPumpLaw
    from idapbc_pin.trajectory import library

    wheel = ip.load_system("reaction_wheel")
    start = library.library_starts(wheel, 0, seed=0)  # the resting posture alone: hanging at rest
    job = (wheel, EnergyPumpLaw(wheel), start, 0.1, 1.0, 2, 0, 0.0, 8.0, 0, 0.0)
    assert library._chunk_nominals(job) == [None]
    monkeypatch.setattr(library, "reaches", lambda system, z_end: np.ones(len(z_end), bool))
    (found,) = library._chunk_nominals(job)
    assert found is not None and not reaches(wheel, found[1][-1:])[0]


def test_refining_a_starts_cheapest_plans_brings_their_end_nearer_x_star():
    """`_chunk_nominals`' refine: iLQR stopped after a few iterations leaves a plan's end short of its
    pin at x*; further iterations of each start's cheapest plans bring the nominal's end nearer (the
    reaction wheel from the first of three postures at rest: 3 iterations, then 30 more)."""
    from idapbc_pin.control.energy_pump import EnergyPumpLaw
    from idapbc_pin.model.angles import wrap_angles
    from idapbc_pin.trajectory import library

    wheel = ip.load_system("reaction_wheel")
    starts = library.library_starts(wheel, 3, seed=0)[1:2]
    ends = []
    for refine in (0, 30):
        (found,) = library._chunk_nominals((wheel, EnergyPumpLaw(wheel), starts, 1.0, 0.6, 3, refine, 0.0, 8.0, 0, 0.0))
        ends.append(np.abs(wrap_angles(found[1][-1, :wheel.nq] - wheel.x_star[:wheel.nq], np.ones(wheel.nq, bool))).max())
    assert ends[1] < ends[0] - 0.1


def test_only_the_starts_whose_plans_all_end_short_of_the_tip_are_refined(monkeypatch):
    """`_chunk_nominals`' refine with a tip: the second iLQR solve takes the `REFINE_KEEP` cheapest
    plans of exactly the starts none of whose first plans ends with the tip at `tip`, and no other."""
    from idapbc_pin.control.energy_pump import EnergyPumpLaw
    from idapbc_pin.sim.leaderboard import tip_share
    from idapbc_pin.trajectory import library

    wheel = ip.load_system("reaction_wheel")
    starts = library.library_starts(wheel, 5, seed=0)
    calls, solve = [], library.ilqr_plans

    def spy(system, x0, U0, *args, **kwargs):
        out = solve(system, x0, U0, *args, **kwargs)
        calls.append((x0.copy(), out[1]))
        return out

    monkeypatch.setattr(library, "ilqr_plans", spy)
    library._chunk_nominals((wheel, EnergyPumpLaw(wheel), starts, 1.0, 0.6, 3, 4, 0.98, 8.0, 0, 0.0))
    (x_first, Z_first), (x_refined, _) = calls
    w = len(x_first) // len(starts)
    short = (tip_share(wheel, Z_first[:, -1, :wheel.nq]) < 0.98).reshape(len(starts), w).all(axis=1)
    assert 0 < short.sum() < len(starts)  # the case holds both kinds of start
    np.testing.assert_array_equal(x_refined, np.repeat(starts[short], library.REFINE_KEEP, axis=0))


def test_a_library_plan_cut_short_of_x_star_is_no_nominal_where_its_tip_must_end_up():
    """`_chunk_nominals`' tip: the reaction wheel's 1-s plan from a posture at rest, stopped after 3
    iterations, ends short of x* with the tip below 0.98 of its upright height; its catch holds,
    so without the rule it is a nominal, and with `library_tip` 0.98 it is not."""
    from idapbc_pin.control.energy_pump import EnergyPumpLaw
    from idapbc_pin.sim.leaderboard import tip_share
    from idapbc_pin.trajectory import library

    wheel = ip.load_system("reaction_wheel")
    starts = library.library_starts(wheel, 3, seed=0)[1:2]
    job = lambda tip: (wheel, EnergyPumpLaw(wheel), starts, 1.0, 0.6, 3, 0, tip, 8.0, 0, 0.0)  # noqa: E731
    (found,) = library._chunk_nominals(job(0.0))
    assert found is not None and tip_share(wheel, found[1][-1, :wheel.nq]) < 0.98
    assert library._chunk_nominals(job(0.98)) == [None]


def test_only_plans_that_end_up_are_rolled_out_and_the_nominals_are_those_of_judging_every_plan(monkeypatch):
    """`_chunk_nominals` rolls out only the plans whose own end passes the checks (`reaches`, `sound`,
    the tip): the rollouts decide nothing for the others. Its nominals are those of rolling out
    every plan and then applying the same checks (the reaction wheel from five postures at rest,
    3 iterations: some plans end short and some do not)."""
    from idapbc_pin.control.energy_pump import EnergyPumpLaw
    from idapbc_pin.sim.leaderboard import tip_share
    from idapbc_pin.trajectory import library

    wheel = ip.load_system("reaction_wheel")
    starts, catch = library.library_starts(wheel, 5, seed=0), EnergyPumpLaw(wheel)
    plans, judged = [], []
    solve, roll = library.ilqr_plans, library.simulate
    monkeypatch.setattr(library, "ilqr_plans", lambda *a, **k: plans.append(solve(*a, **k)) or plans[-1])
    monkeypatch.setattr(library, "simulate", lambda system, law, x0, **k: judged.append(x0.copy()) or roll(system, law, x0, **k))
    found = library._chunk_nominals((wheel, catch, starts, 1.0, 0.6, 3, 0, 0.98, 8.0, 0, 0.0))
    ((U, Z, gains, cost),), (x_judged,) = plans, judged
    ends = reaches(wheel, Z[:, -1]) & (tip_share(wheel, Z[:, -1, :wheel.nq]) >= 0.98)
    assert 0 < ends.sum() < len(ends)  # the case holds both kinds of plan
    w = len(U) // len(starts)
    x0 = np.repeat(starts, w, axis=0)
    np.testing.assert_array_equal(x_judged, x0[ends])
    every = roll(wheel, library.TrackThenLaw(U, Z, gains, library.KNOT, catch, wheel), x0, T=8.0, dt=library.PLAN_STEP, stop_settled=True)
    held = library.holds(every, wheel) & ends
    for s, nominal in enumerate(found):
        rows = [i for i in range(s * w, (s + 1) * w) if held[i]]
        if not rows:
            assert nominal is None
        else:
            best = min(rows, key=lambda i: (cost[i], i))
            np.testing.assert_array_equal(nominal[0], U[best])


@pytest.mark.parametrize("field, value", [("library_tip", 1.5), ("library_tip", -0.1), ("library_refine", -1), ("library_released", -1), ("gate_released", -1)])
def test_a_library_tip_outside_0_1_or_a_negative_refine_is_a_bad_setting(field, value):
    from idapbc_pin.recovery.config import SwingUpConfig

    with pytest.raises(ip.IdapbcError, match="bad swing-up setting.*library_tip in \\[0, 1\\]"):
        SwingUpConfig(**{field: value})


def test_a_plan_whose_rollout_blew_up_is_no_nominal_though_its_catch_holds(monkeypatch):
    """iLQR can hand back a rollout that blew up (states of 1e55); its inputs, clipped to the limits,
    can still leave a catch that swings up by itself to hold at x*, and its time-varying LQR then
    overflows. `nominal_plans` keeps only plans whose states stay finite and within the simulator's
    divergence bound (`sound`): here of two plans the catch holds both, and the blown-up one is refused."""
    from idapbc_pin.recovery.config import SwingUpConfig
    from idapbc_pin.trajectory import tracks

    wheel = ip.load_system("reaction_wheel")
    config = SwingUpConfig(horizon=0.2)
    K = int(round(config.horizon / tracks.KNOT))
    Z = np.zeros((2, K + 1, wheel.n))
    Z[1, K // 2, 0] = 1e55  # the second plan's rollout blew up midway
    U, gains = np.zeros((2, K, wheel.m)), np.zeros((2, K, wheel.m, wheel.n))
    monkeypatch.setattr(tracks, "warm_starts", lambda K, bound, seed, **kw: np.zeros((2, K, wheel.m)))
    monkeypatch.setattr(tracks, "ilqr_plans", lambda *args, **kw: (U, Z, gains, np.array([2.0, 1.0])))
    monkeypatch.setattr(tracks, "simulate", lambda *args, **kw: None)
    monkeypatch.setattr(tracks, "holds", lambda traj, system: np.ones(2, bool))  # the catch holds after either
    x_rest = tracks.resting_states(wheel, 1)[0]
    assert [cost for _, _, cost in tracks.nominal_plans(wheel, None, x_rest, config)] == [2.0]
    assert np.array_equal(tracks.sound(Z), [True, False])
    monkeypatch.setattr(tracks, "sound", lambda Z: np.ones(len(Z), bool))
    assert [cost for _, _, cost in tracks.nominal_plans(wheel, None, x_rest, config)] == [1.0, 2.0]  # the rule is what refuses it

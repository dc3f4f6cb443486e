"""The global evaluation (DESIGN §4, "From anywhere"): the uptime test's schedule, postures and
score, checked against the leaderboard's definition and against a plain loop over episodes, and the
start states from anywhere on the torus."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.evaluation import uptime as uptime_module
from idapbc_pin.evaluation.swingup import swingup_states
from idapbc_pin.evaluation.uptime import reset_postures, reset_schedule, uptime_test
from idapbc_pin.sim.leaderboard import tip_up
from idapbc_pin.model.resting import resting_configuration
from idapbc_pin.sim.integrate import simulate

URDF = Path(__file__).resolve().parents[1] / "urdf" / "realaigym_double_pendulum.urdf"


@pytest.fixture(scope="module")
def pendubot():
    return ip.load_system(str(URDF), actuated=["shoulder"], target={"shoulder": math.pi})


def test_the_schedule_is_the_leaderboards():
    """15 resets at k·60/16 s ± 1 s (k = 1 … 15), on the 2 ms grid, in order, the same for the same
    generator state; over many episodes the jitter spans ±1 s."""
    rng = np.random.default_rng(3)
    steps = np.stack([reset_schedule(rng) for _ in range(200)])
    assert steps.shape == (200, 15) and steps.dtype.kind == "i"
    offset = steps * 0.002 - 3.75 * np.arange(1, 16)
    assert np.abs(offset).max() <= 1.0 + 1e-3 and offset.min() < -0.95 and offset.max() > 0.95
    assert (np.diff(steps, axis=1) > 0).all()
    np.testing.assert_array_equal(reset_schedule(np.random.default_rng(9)), reset_schedule(np.random.default_rng(9)))


def test_reset_postures_are_at_rest_from_the_whole_circle():
    system = ip.load_system("cartpole")
    x = reset_postures(system, np.random.default_rng(0), 500)
    q, v = system.split(x)
    assert (v == 0).all() and (q[:, 0] == resting_configuration(system)[0]).all()  # the cart stays where it rests
    d = q[:, 1] - system.x_star[1]
    assert np.abs(d).max() <= math.pi and d.min() < -3.0 and d.max() > 3.0


def test_the_tip_is_up_at_the_target_and_down_hanging_and_off_the_rail(pendubot):
    q_star = np.asarray(pendubot.x_star)[:2]
    assert tip_up(pendubot, np.stack([q_star, resting_configuration(pendubot)])).tolist() == [True, False]
    # the leaderboard's threshold: 0.9 of the upright height above the pivot (links 0.2 + 0.3 m)
    h = lambda a: -0.2 * math.cos(a) - 0.3 * math.cos(a)  # both links in line at angle a from hanging
    below, above = math.acos(0.9 * 0.5 / 0.5) - 0.01, math.acos(0.9 * 0.5 / 0.5) + 0.01
    assert h(math.pi - above) < 0.45 < h(math.pi - below)
    assert tip_up(pendubot, np.array([[math.pi - below, 0.0], [math.pi - above, 0.0]])).tolist() == [True, False]
    cart = ip.load_system("cartpole")
    off = np.asarray(cart.x_star)[:2].copy()
    off[0] = cart.joints[0].upper + 0.1
    assert tip_up(cart, np.stack([np.asarray(cart.x_star)[:2], off])).tolist() == [True, False]


def _uptime_by_loop(system, law, steps, states, K, dt):
    """Each episode on its own, segment by segment, each segment exactly its own length."""
    out = []
    for e in range(steps.shape[0]):
        bounds = [0, *steps[e].tolist(), K]
        x = system.state_from(resting_configuration(system)[None], np.zeros((1, system.nq)))
        up = []
        for j in range(len(bounds) - 1):
            x0 = x if j == 0 else states[e, j - 1][None]
            L = bounds[j + 1] - bounds[j]
            traj = simulate(system, law, x0, T=L * dt, dt=dt)
            up.append(tip_up(system, traj.q[0, :L]) & ~traj.diverged[0])
        out.append(np.concatenate(up).mean())
    return np.array(out)


def test_uptime_equals_a_plain_loop_over_episodes_and_segments(pendubot):
    """The batched segments (every episode's segment j together, to the longest) give each episode's
    uptime as one rollout per segment of its own length does."""
    laws = {"LQR": LQRController(pendubot)}
    res = uptime_test(pendubot, laws, episodes=3, seed=1, T=6.0, resets=3, jitter=0.5)
    assert res.steps.shape == (3, 3) and res.states.shape == (3, 3, 4)
    ref = _uptime_by_loop(pendubot, laws["LQR"], res.steps, res.states, 3000, 0.002)
    np.testing.assert_allclose(res.uptime["LQR"], ref, rtol=0, atol=1.5 / 3000)  # at most a sample's rounding
    assert res.uptime["LQR"].max() > 0  # some reset lands where LQR catches it
    again = uptime_test(pendubot, laws, episodes=3, seed=1, T=6.0, resets=3, jitter=0.5)
    np.testing.assert_array_equal(again.uptime["LQR"], res.uptime["LQR"])
    assert "| LQR |" in res.table() and set(res.to_dict()["mean"]) == {"LQR"}


def test_no_input_never_gets_up_and_a_jitter_past_half_the_spacing_is_refused(pendubot):
    """u = 0 from hanging with no reset: uptime 0; resets that could swap order are refused."""
    zero = lambda x: np.zeros((len(x), 1))
    res = uptime_test(pendubot, {"zero": zero}, episodes=2, seed=0, T=4.0, resets=0, jitter=0.0)
    assert res.uptime["zero"].tolist() == [0.0, 0.0]
    with pytest.raises(ValueError, match="jitter"):
        uptime_test(pendubot, {"zero": zero}, episodes=1, T=4.0, resets=3, jitter=0.6)


def test_anywhere_states_move_from_the_whole_circle():
    """The first hanging at rest; the others' postures are the circle's (same seed), with speeds U(−1, 1)."""
    system = ip.load_system("pendubot")
    x = swingup_states(system, n=300, seed=5, starts="anywhere")
    q, v = system.split(x)
    q_c, v_c = system.split(swingup_states(system, n=300, seed=5, starts="circle"))
    np.testing.assert_array_equal(q, q_c)
    assert (v[0] == 0).all() and (v_c == 0).all()
    assert np.abs(v[1:]).max() <= 1.0 and v[1:].min() < -0.95 and v[1:].max() > 0.95


def test_the_uptime_constants_are_the_leaderboards():
    assert (uptime_module.UPTIME_T, uptime_module.UPTIME_RESETS, uptime_module.UPTIME_JITTER, uptime_module.UPTIME_EPISODES) == (60.0, 15, 1.0, 5)


def test_a_drive_reset_holds_a_posture_against_gravity_and_pushes_towards_the_drawn_one(pendubot):
    """The leaderboard's reset: PD + gravity compensation on every joint within its URDF limit. Aimed
    at the posture it starts in, at rest, it holds it (∇U from Pinocchio's generalised gravity);
    aimed at hanging from upright, it swings the shoulder down and leaves the robot moving."""
    from idapbc_pin.evaluation.uptime import DRIVE_T, _drive, drive_bound

    np.testing.assert_array_equal(drive_bound(pendubot), [6.0, 6.0])  # both joints' URDF effort, the passive one too
    q0 = np.array([[1.0, 0.5], [-2.0, 1.2]])
    assert np.abs(pendubot.plant.gravity(q0)).max() < 6.0  # compensable within the limit
    x0 = pendubot.state_from(q0, np.zeros_like(q0))
    qs, x = _drive(pendubot, x0, q0, int(round(DRIVE_T / 0.002)), 0.002)
    q, v = pendubot.split(x)
    assert qs.shape == (2, 100, 2) and np.abs(q - q0).max() < 1e-6 and np.abs(v).max() < 1e-5
    up = np.asarray(pendubot.x_star)[None, :2]
    qs, x = _drive(pendubot, pendubot.state_from(up, np.zeros_like(up)), np.zeros_like(up), 100, 0.002)
    q, v = pendubot.split(x)
    assert ((q - up) * (0.0 - up) >= 0).all() and np.abs(q - up).max() > 0.1 and np.abs(v).max() > 1.0


def test_uptime_with_drive_resets_is_recorded_reproducible_and_differs_from_put(pendubot):
    laws = {"LQR": LQRController(pendubot)}
    kw = dict(episodes=2, seed=1, T=6.0, resets=3, jitter=0.5)
    drive = uptime_test(pendubot, laws, reset="drive", **kw)
    again = uptime_test(pendubot, laws, reset="drive", **kw)
    put = uptime_test(pendubot, laws, **kw)
    np.testing.assert_array_equal(drive.uptime["LQR"], again.uptime["LQR"])
    assert drive.reset == "drive" and drive.to_dict()["reset"] == "drive" and put.reset == "put"
    assert not np.array_equal(drive.uptime["LQR"], put.uptime["LQR"])
    with pytest.raises(ValueError, match="reset"):
        uptime_test(pendubot, laws, reset="teleport", **kw)

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
    res = uptime_test(pendubot, laws, episodes=3, seed=1, T=6.0, resets=3, jitter=0.5, reset="put")
    assert res.steps.shape == (3, 3) and res.states.shape == (3, 3, 4)
    ref = _uptime_by_loop(pendubot, laws["LQR"], res.steps, res.states, 3000, 0.002)
    np.testing.assert_allclose(res.uptime["LQR"], ref, rtol=0, atol=1.5 / 3000)  # at most a sample's rounding
    assert res.uptime["LQR"].max() > 0  # some reset lands where LQR catches it
    again = uptime_test(pendubot, laws, episodes=3, seed=1, T=6.0, resets=3, jitter=0.5, reset="put")
    np.testing.assert_array_equal(again.uptime["LQR"], res.uptime["LQR"])
    assert "| LQR |" in res.table() and set(res.to_dict()["mean"]) == {"LQR"}


def test_no_input_never_gets_up_and_a_jitter_past_half_the_spacing_is_refused(pendubot):
    """u = 0 from hanging with no reset: uptime 0; resets that could swap order are refused."""
    zero = lambda x: np.zeros((len(x), 1))
    res = uptime_test(pendubot, {"zero": zero}, episodes=2, seed=0, T=4.0, resets=0, jitter=0.0)  # no reset: the drive never runs
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


def test_moving_states_reach_every_joint_s_rating_from_the_whole_circle():
    """Every row moving: postures from the full circle, each joint's speed U(−v̄, v̄) with v̄ its URDF
    rating (30 rad/s on the zoo pendubot), the same for the same seed."""
    system = ip.load_system("pendubot")
    x = swingup_states(system, n=400, seed=2, starts="moving")
    q, v = system.split(x)
    d = q - np.asarray(system.x_star)[:2]
    assert np.abs(d).max() <= math.pi and d.min() < -3.0 and d.max() > 3.0
    assert np.abs(v).max() <= 30.0 and (np.abs(v) > 27.0).any(axis=0).all() and (v != 0).all()
    np.testing.assert_array_equal(swingup_states(system, n=400, seed=2, starts="moving"), x)


def test_the_uptime_constants_are_the_leaderboards():
    assert (uptime_module.UPTIME_T, uptime_module.UPTIME_RESETS, uptime_module.UPTIME_JITTER, uptime_module.UPTIME_EPISODES) == (60.0, 15, 1.0, 5)
    assert (uptime_module.DRIVE_T, uptime_module.DRIVE_KP, uptime_module.DRIVE_KI, uptime_module.DRIVE_KD, uptime_module.PID_DT) == (0.2, 10.0, 0.1, 1.0, 0.001)
    assert uptime_module.RESETS[0] == "drive"  # the leaderboard's reset is the default


def test_a_drive_reset_holds_a_posture_against_gravity_and_pushes_towards_the_drawn_one(pendubot):
    """The leaderboard's reset: PID + gravity compensation on every joint within its URDF limit. Aimed
    at the posture it starts in, at rest, it holds it (∇U from Pinocchio's generalised gravity);
    aimed at hanging from upright, it swings the shoulder down and leaves the robot moving."""
    from idapbc_pin.sim.drive import DRIVE_T, drive_bound, pid_drive as _drive

    np.testing.assert_array_equal(drive_bound(pendubot), [6.0, 6.0])  # both joints' URDF effort, the passive one too
    q0 = np.array([[1.0, 0.5], [-2.0, 1.2]])
    assert np.abs(pendubot.plant.gravity(q0)).max() < 6.0  # compensable within the limit
    x0 = pendubot.state_from(q0, np.zeros_like(q0))
    xs, x = _drive(pendubot, x0, q0, int(round(DRIVE_T / 0.002)), 0.002)
    q, v = pendubot.split(x)
    assert xs.shape == (2, 100, 4) and np.abs(q - q0).max() < 1e-6 and np.abs(v).max() < 1e-5
    up = np.asarray(pendubot.x_star)[None, :2]
    xs, x = _drive(pendubot, pendubot.state_from(up, np.zeros_like(up)), np.zeros_like(up), 100, 0.002)
    q, v = pendubot.split(x)
    assert ((q - up) * (0.0 - up) >= 0).all() and np.abs(q - up).max() > 0.1 and np.abs(v).max() > 1.0


def _pid_drive_by_hand(system, x, targets, ticks, dt, starts=None):
    """One episode's drives in a row, a plain loop over steps: the leaderboard's point PID (kp 10,
    ki 0.1, kd 1 with a 1-ms step, errors not wrapped and kept across the drives, no derivative on
    its first two calls), clipped to ±6 N·m, plus ∇U(q), clipped again; RK4 with the torque held.
    `starts`: per drive, the state (q, v) it starts from, or None to go on from where the last ended."""
    errors = []
    q, v = (a[0].copy() for a in system.split(x[None]))
    for target, start in zip(targets, starts or [None] * len(targets)):
        if start is not None:
            q, v = start[0].copy(), start[1].copy()
        for _ in range(ticks):
            e = target - q
            errors.append(e)
            d = (errors[-1] - errors[-2]) / 0.001 if len(errors) > 2 else np.zeros_like(e)
            pid = 10.0 * e + 0.1 * np.sum(errors, axis=0) * 0.001 + 1.0 * d
            tau = np.clip(np.clip(pid, -6.0, 6.0) + system.plant.gravity(q[None])[0], -6.0, 6.0)
            acc = lambda q_, v_: system.forward_dynamics(q_[None], v_[None], tau[None])[0]
            k1q, k1v = v, acc(q, v)
            k2q, k2v = v + 0.5 * dt * k1v, acc(q + 0.5 * dt * k1q, v + 0.5 * dt * k1v)
            k3q, k3v = v + 0.5 * dt * k2v, acc(q + 0.5 * dt * k2q, v + 0.5 * dt * k2v)
            k4q, k4v = v + dt * k3v, acc(q + dt * k3q, v + dt * k3v)
            q, v = q + dt / 6 * (k1q + 2 * k2q + 2 * k3q + k4q), v + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
    return q, v


def test_the_drive_is_the_leaderboards_pid_with_its_memory_kept_across_resets(pendubot):
    """Two drives in a row through one `_PID` memory equal the plain loop above; a fresh memory for
    the second drive (the integral and the derivative's first step forgotten) does not."""
    from idapbc_pin.sim.drive import DrivePID as _PID, pid_drive as _drive

    x0 = pendubot.state_from(np.array([[0.3, -0.2]]), np.array([[2.0, -1.0]]))
    targets = [np.array([[2.5, -1.0]]), np.array([[-2.0, 0.5]])]
    pid = _PID(np.zeros((1, 2)), np.zeros((1, 2)))
    x = x0
    for target in targets:
        _, x = _drive(pendubot, x, target, 100, 0.002, pid)
    q_ref, v_ref = _pid_drive_by_hand(pendubot, x0[0], [t[0] for t in targets], 100, 0.002)
    q, v = pendubot.split(x)
    np.testing.assert_allclose(q[0], q_ref, atol=1e-9)
    np.testing.assert_allclose(v[0], v_ref, atol=1e-8)
    _, x_half = _drive(pendubot, x0, targets[0], 100, 0.002)
    _, x_fresh = _drive(pendubot, x_half, targets[1], 100, 0.002)
    assert np.abs(x_fresh - x).max() > 1e-5  # far above the 1e-8 agreement above


def test_the_uptime_test_reads_speeds_outside_the_drives(pendubot):
    """A law that spins the shoulder at full effort forever runs past the 20 rad/s rating: its peak
    speed / rating is > 1 and it spends time above the rating; LQR, resting or catching, reads
    below the rating wherever the speeds count (the drives and the 0.5 s after them left out)."""
    spin = lambda x: np.full((len(np.atleast_2d(x)), 1), 6.0)
    res = uptime_test(pendubot, {"spin": spin, "LQR": LQRController(pendubot)}, episodes=2, seed=1, T=8.0, resets=2, jitter=0.5)
    assert res.reset == "drive"
    assert res.speed["spin"].max() > 1.0 and res.over_rating["spin"].max() > 0.2
    assert res.speed["LQR"].max() < res.speed["spin"].max()
    assert "peak speed / rating" in res.table() and set(res.to_dict()["time_over_rating"]) == {"spin", "LQR"}


def test_uptime_with_drive_resets_is_recorded_reproducible_and_differs_from_put(pendubot):
    laws = {"LQR": LQRController(pendubot)}
    kw = dict(episodes=2, seed=1, T=6.0, resets=3, jitter=0.5)
    drive = uptime_test(pendubot, laws, **kw)
    again = uptime_test(pendubot, laws, reset="drive", **kw)
    put = uptime_test(pendubot, laws, reset="put", **kw)
    np.testing.assert_array_equal(drive.uptime["LQR"], again.uptime["LQR"])
    assert drive.reset == "drive" and drive.to_dict()["reset"] == "drive" and put.reset == "put"
    assert not np.array_equal(drive.uptime["LQR"], put.uptime["LQR"])
    with pytest.raises(ValueError, match="reset"):
        uptime_test(pendubot, laws, reset="teleport", **kw)

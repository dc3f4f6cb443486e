"""The states the uptime test's reset drive releases (`sim.drive.drive_release_states`): where a plain
per-step loop of upstream's PID drive ends, moving, deterministic per seed."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.sim.drive import DRIVE_T, drive_release_states, pid_drive
from idapbc_pin.sim.states import moving_states

from .test_uptime import _pid_drive_by_hand

URDF = Path(__file__).resolve().parents[1] / "urdf" / "realaigym_double_pendulum.urdf"


@pytest.fixture(scope="module")
def acrobot():
    return ip.load_system(str(URDF), actuated=["elbow"], target={"shoulder": math.pi})


def _by_hand(system, q0, v0, drives, dt=0.002):
    """Drives in a row as a plain loop over steps, one state (`tests.test_uptime._pid_drive_by_hand`):
    for each (start or None, target), the state set to `start` (q, v) where given, DRIVE_T s each."""
    x0 = system.state_from(q0[None], v0[None])[0]
    return _pid_drive_by_hand(system, x0, [t for _, t in drives], int(round(DRIVE_T / dt)), dt, [s for s, _ in drives])


def _postures(rng, n):
    """The release states' draw of n drive targets: x*'s shoulder π + U(−π, π) and elbow U(−π, π),
    brought within π of hanging (0, 0)."""
    q = np.array([math.pi, 0.0]) + rng.uniform(-math.pi, math.pi, (n, 2))
    return (q + math.pi) % (2 * math.pi) - math.pi


def test_release_states_are_where_a_plain_loop_of_the_drive_ends(acrobot):
    """Each row: an earlier drive from x* at rest fills the PID's memory, then the drive from x* at
    rest (the first half) or from a moving state (the rest) towards a posture of its own; the batched
    drive ends where the plain loop does."""
    n, seed = 3, 5
    x = drive_release_states(acrobot, n, seed)
    rng = np.random.default_rng(seed)
    earlier, targets = _postures(rng, n), _postures(rng, n)
    up = (np.array([math.pi, 0.0]), np.zeros(2))
    q_m, v_m = acrobot.split(moving_states(acrobot, 1, seed + 1))
    starts = [up, up, (q_m[0], v_m[0])]
    q, v = acrobot.split(x)
    for i in range(n):
        q_ref, v_ref = _by_hand(acrobot, *up, [(None, earlier[i]), (starts[i], targets[i])])
        np.testing.assert_allclose(q[i], q_ref, atol=1e-9)
        np.testing.assert_allclose(v[i], v_ref, atol=1e-7)


def test_release_states_are_moving_deterministic_and_read_the_drive_s_memory(acrobot):
    x = drive_release_states(acrobot, 8, seed=2)
    q, v = acrobot.split(x)
    assert x.shape == (8, 4) and np.isfinite(x).all()
    assert (np.abs(v).max(axis=1) > 1.0).all()  # released moving, every row
    np.testing.assert_array_equal(drive_release_states(acrobot, 8, seed=2), x)
    assert np.abs(drive_release_states(acrobot, 8, seed=3) - x).max() > 0.1
    # without the earlier drive's memory (a fresh PID: no derivative kick on the first step) it ends elsewhere
    rng = np.random.default_rng(2)
    _postures(rng, 8)
    targets = _postures(rng, 8)
    up = acrobot.state_from(np.tile([math.pi, 0.0], (4, 1)), np.zeros((4, 2)))
    _, fresh = pid_drive(acrobot, up, targets[:4], int(round(DRIVE_T / 0.002)), 0.002)
    assert np.abs(fresh - x[:4]).max() > 1e-3
    with pytest.raises(ip.IdapbcError):
        drive_release_states(acrobot, 0)

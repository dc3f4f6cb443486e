"""The terminal set (`idapbc_pin.sim.terminal`): a rollout that enters it stays in the success box and
tends to x*, so `simulate(stop_converged=True)` stops it there with the verdicts of the full horizon
(issue 56: same states, same verdicts)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.model.angles import wrap_angles
from idapbc_pin.sim.integrate import loop_terminal_set, simulate
from idapbc_pin.sim.metrics import SUCCESS_TOL, at_target, equilibrium_offset, peak_input, settled, settling_time, success
from idapbc_pin.sim.states import uniform_states

REFERENCE = Path(__file__).parent / "data" / "reference_run"
SYSTEMS = ["pendubot", "acrobot", "cartpole", "furuta", "reaction_wheel", "cart_double_pendulum", "paper_cartpole", "paper_double_pendulum"]


def _shell(terminal, n: int, seed: int) -> np.ndarray:
    """n states z on the boundary zᵀPz = c, as (n, 2nq) offsets from (q*, 0)."""
    d = np.random.default_rng(seed).standard_normal((n, terminal.P.shape[0]))
    z = d / np.sqrt(np.einsum("ni,ij,nj->n", d, terminal.P, d))[:, None]
    return np.sqrt(terminal.c) * z


@pytest.mark.parametrize("name", SYSTEMS)
def test_from_the_boundary_of_lqrs_terminal_set_the_loop_stays_in_the_success_box_and_tends_to_x_star(name):
    system = ip.load_system(name)
    lqr = LQRController(system)
    terminal = loop_terminal_set(system, lqr)
    assert terminal is not None and terminal.c > 0
    nq = system.nq
    z = _shell(terminal, 24, seed=1)
    q0 = terminal.q_star + z[:, :nq]
    traj = simulate(system, lqr, system.state_from(q0, z[:, nq:]), T=6.0)  # no stop: every tick recorded
    assert at_target(traj.q, traj.v, system).all()  # inside the success box at every sample
    V = np.stack([terminal.value(traj.q[:, k], traj.v[:, k]) for k in range(traj.t.size)], axis=1)
    assert (V <= terminal.c * (1 + 1e-9)).all()  # never leaves the set
    assert (V[:, -1] < 0.5 * V[:, 0]).all()  # and falls towards x*


def test_no_terminal_set_where_the_loop_is_unstable_at_x_star_or_holds_it_elsewhere():
    system = ip.load_system("pendubot")  # upright: unstable without feedback
    assert loop_terminal_set(system, lambda x: np.zeros((len(x), system.m))) is None
    lqr = LQRController(system)
    assert loop_terminal_set(system, lambda x: lqr(x) + 0.5) is None  # x* is no longer a fixed point


def test_rollouts_stopped_in_the_terminal_set_get_the_verdicts_of_the_full_horizon():
    run = ip.load_run(REFERENCE)
    system = run.system
    for ctrl in (run.controller, LQRController(system)):
        for box in ("domain", "half"):
            x0 = uniform_states(system, 16, box, 7)
            full = simulate(system, ctrl, x0, T=10.0)
            cut = simulate(system, ctrl, x0, T=10.0, stop_converged=True)
            assert not full.converged.any() and cut.converged.any()
            np.testing.assert_array_equal(success(cut, system), success(full, system))
            np.testing.assert_array_equal(settled(cut), settled(full))
            np.testing.assert_array_equal(cut.diverged, full.diverged)
            np.testing.assert_allclose(settling_time(cut, system), settling_time(full, system), equal_nan=True)
            np.testing.assert_allclose(peak_input(cut), peak_input(full), rtol=1e-9)
            # from the sample where a row stopped, its full rollout stays in the success box (a row
            # that stops within the last SUCCESS_WINDOW s fails on both horizons alike, as above)
            held = (cut.x == cut.x[:, -1:]).all(axis=2)  # (N, T_k): the sample repeats the row's last one
            since_stop = np.flip(np.logical_and.accumulate(np.flip(held, axis=1), axis=1), axis=1)
            assert at_target(full.q, full.v, system)[since_stop & cut.converged[:, None]].all()
            # a converged row's offset is its limit, x*; the full horizon ends within the success box of it
            assert (equilibrium_offset(cut, system)[cut.converged] == 0).all()
            dq = wrap_angles(full.q[cut.converged, -1] - np.asarray(system.x_star)[: system.nq], system.angle_mask[: system.nq])
            assert np.abs(dq).max(initial=0) < SUCCESS_TOL


def test_roa_with_and_without_the_stop_scores_the_same_states_alike():
    system = ip.load_system("cartpole")
    ctrls = {"LQR": LQRController(system)}
    a = ip.roa(system, ctrls, n=24, T=10.0, stop_converged=False).scores["LQR"]
    b = ip.roa(system, ctrls, n=24, T=10.0).scores["LQR"]
    np.testing.assert_array_equal(a.success, b.success)
    np.testing.assert_allclose(a.settling_time, b.settling_time, equal_nan=True)

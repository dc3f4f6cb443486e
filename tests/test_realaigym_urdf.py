"""`urdf/realaigym_double_pendulum.urdf` is the RealAIGym double pendulum (design C.1, model 1.1).

The reference is the benchmark's own closed-form model, written out here independently from the
published parameters (double_pendulum repo, data/system_identification/identified_parameters/
design_C.1/model_1.1/model_parameters.yml) and the "UnderactuatedLecture" formulas of its
src/python/double_pendulum/model/plant.py, in which I1, I2 are inertias about the joint axes:

    M = [[I1 + I2 + m2 l1² + 2 m2 l1 r2 cos q2,  I2 + m2 l1 r2 cos q2],
         [I2 + m2 l1 r2 cos q2,                  I2                 ]]
    U = −m1 g r1 cos q1 − m2 g (l1 cos q1 + r2 cos(q1 + q2))      (q = 0 hanging down)

Checked: M(q) to 1e-10 relative, the gravity torque ∇U(q), the potential up to a constant, the
accelerations with Coriolis terms and torques, the hanging and upright equilibria for both
actuations, the 6 N·m effort limit and the default domain; and MuJoCo on the same file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import idapbc_pin as ip

URDF = Path(__file__).resolve().parents[1] / "urdf" / "realaigym_double_pendulum.urdf"

# design C.1, model 1.1 (I about the joint axis; b = cf = Ir = 0)
M1, M2 = 0.5234602302310271, 0.6255677234174437
L1 = 0.2
R1, R2 = 0.2, 0.25569305436052964
I1, I2 = 0.031887199591513114, 0.05086984812807257
G = 9.81
UPRIGHT = np.pi


def ref_mass_matrix(q: np.ndarray) -> np.ndarray:
    c2 = np.cos(q[:, 1])
    h = M2 * L1 * R2 * c2
    out = np.empty((q.shape[0], 2, 2))
    out[:, 0, 0] = I1 + I2 + M2 * L1**2 + 2 * h
    out[:, 0, 1] = out[:, 1, 0] = I2 + h
    out[:, 1, 1] = I2
    return out


def ref_potential(q: np.ndarray) -> np.ndarray:
    q1, q12 = q[:, 0], q[:, 0] + q[:, 1]
    return -M1 * G * R1 * np.cos(q1) - M2 * G * (L1 * np.cos(q1) + R2 * np.cos(q12))


def ref_grad_potential(q: np.ndarray) -> np.ndarray:
    """∇U (the benchmark's gravity vector with the opposite sign: its G = −∇U)."""
    q1, q12 = q[:, 0], q[:, 0] + q[:, 1]
    s2 = M2 * G * R2 * np.sin(q12)
    return np.stack([(M1 * R1 + M2 * L1) * G * np.sin(q1) + s2, s2], axis=1)


def ref_coriolis_times_v(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """C(q, v) v from the Christoffel symbols of ref_mass_matrix (only ∂M/∂q2 ≠ 0)."""
    h = M2 * L1 * R2 * np.sin(q[:, 1])
    v1, v2 = v[:, 0], v[:, 1]
    return np.stack([-h * (2 * v1 * v2 + v2**2), h * v1**2], axis=1)


def ref_acceleration(q, v, tau):
    rhs = tau - ref_coriolis_times_v(q, v) - ref_grad_potential(q)  # b = cf = 0
    return np.linalg.solve(ref_mass_matrix(q), rhs[..., None])[..., 0]


def _states(k=24, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2 * np.pi, 2 * np.pi, (k, 2))
    q[:4] = [[0.0, 0.0], [np.pi, 0.0], [0.3, -1.2], [np.pi / 2, np.pi]]
    v = rng.uniform(-8.0, 8.0, (k, 2))
    tau = rng.uniform(-6.0, 6.0, (k, 2))
    return q, v, tau


@pytest.fixture(scope="module", params=["shoulder", "elbow"], ids=["pendubot", "acrobot"])
def system(request):
    return ip.load_system(str(URDF), actuated=[request.param], target={"shoulder": UPRIGHT})


def test_inertias_are_centre_of_mass_values_that_stay_positive():
    assert I1 - M1 * R1**2 > 0 and I2 - M2 * R2**2 > 0


def test_mass_matrix_matches_the_benchmark_closed_form(system):
    q, _, _ = _states()
    M_ref = ref_mass_matrix(q)
    M = system.mass_matrix(q)
    scale = np.abs(M_ref).max(axis=(1, 2), keepdims=True)
    np.testing.assert_array_less(np.abs(M - M_ref) / scale, 1e-10)


def test_gravity_and_potential_match(system):
    q, _, _ = _states()
    np.testing.assert_allclose(system.plant.gravity(q), ref_grad_potential(q), rtol=1e-10, atol=1e-12)
    # the drift at rest is (0, −∇U)
    x = np.concatenate([q, np.zeros_like(q)], axis=1)
    np.testing.assert_allclose(system.f(x)[:, 2:], -ref_grad_potential(q), rtol=1e-10, atol=1e-12)
    U, U_ref = system.potential(q), ref_potential(q)
    np.testing.assert_allclose(U - U[0], U_ref - U_ref[0], rtol=0, atol=1e-12)


def test_accelerations_match_with_coriolis_and_torque(system):
    q, v, tau = _states(seed=1)
    a_ref = ref_acceleration(q, v, tau)
    np.testing.assert_allclose(system.forward_dynamics(q, v, tau), a_ref, rtol=1e-9, atol=1e-9 * np.abs(a_ref).max())


def test_hanging_and_upright_are_equilibria(system):
    for q_eq in ([0.0, 0.0], [UPRIGHT, 0.0], [UPRIGHT, UPRIGHT], [0.0, UPRIGHT]):
        x = np.array(q_eq + [0.0, 0.0])
        np.testing.assert_allclose(system.f(x), 0.0, atol=1e-12)
        np.testing.assert_allclose(system.equilibrium_residual(x), 0.0, atol=1e-12)
    np.testing.assert_array_equal(system.x_star, [UPRIGHT, 0.0, 0.0, 0.0])


def test_upright_is_unstable_and_hanging_is_stable(system):
    def eig(q_eq):
        x = np.array(q_eq + [0.0, 0.0])
        return np.linalg.eigvals(system.df_dx(x)).real

    assert eig([UPRIGHT, 0.0]).max() > 1.0
    assert np.abs(eig([0.0, 0.0])).max() < 1e-8  # undamped: a centre (purely imaginary)


def test_effort_limit_damping_and_domain(system):
    np.testing.assert_array_equal(system.effort, [6.0])
    np.testing.assert_array_equal(system.plant.damping, [0.0, 0.0])
    lo, hi = system.domain
    # joint limits ±100 rad: the default ±π/2 box around the upright target is not clipped
    np.testing.assert_allclose(lo[:2], [UPRIGHT - np.pi / 2, -np.pi / 2])
    np.testing.assert_allclose(hi[:2], [UPRIGHT + np.pi / 2, np.pi / 2])
    M_star = ref_mass_matrix(np.array([[UPRIGHT, 0.0]]))[0]
    np.testing.assert_allclose(hi[2:], np.diag(M_star), rtol=1e-12)


def test_mujoco_agrees_on_the_same_urdf():
    pytest.importorskip("mujoco", reason="the MuJoCo reference needs `pip install mujoco`")
    import mujoco

    from idapbc_pin.sim._mujoco import full_mass_matrix, mujoco_model

    model = mujoco_model(URDF)
    joints = [model.joint(name) for name in ("shoulder", "elbow")]
    qpos = np.array([j.qposadr[0] for j in joints])
    dof = np.array([j.dofadr[0] for j in joints])
    assert np.all(model.dof_damping == 0) and np.all(model.dof_armature == 0) and np.all(model.dof_frictionloss == 0)
    q, v, tau = _states(seed=2)
    for qk, vk, tk in zip(q, v, tau):
        data = mujoco.MjData(model)
        data.qpos[qpos], data.qvel[dof], data.qfrc_applied[dof] = qk, vk, tk
        mujoco.mj_forward(model, data)
        M = full_mass_matrix(model, data)[np.ix_(dof, dof)]
        np.testing.assert_allclose(M, ref_mass_matrix(qk[None])[0], rtol=1e-10, atol=1e-12)
        a_ref = ref_acceleration(qk[None], vk[None], tk[None])[0]
        np.testing.assert_allclose(data.qacc[dof], a_ref, rtol=1e-9, atol=1e-9 * np.abs(a_ref).max())

"""The port-Hamiltonian model from Pinocchio is exact: checked against independent references.

* f against Pinocchio's own forward dynamics (`aba`, Articulated-Body Algorithm) with ṗ = Ṁv + Ma,
  Ṁv taken from RNEA derivatives, zoo-wide on 1000 states;
* the rows of f the controller reads (`f_rows`) against the same reference;
* ∂f/∂x against central differences of f;
* the paper's analytic systems against autograd of their formulas;
* the example-robot-data double pendulum variants against each other.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import torch

import idapbc_pin as ip
from idapbc_pin.model.analytic import analytic_names
from idapbc_pin.model.system import EQUILIBRIUM_TOL
from idapbc_pin.model.zoo import zoo_names

from .conftest import sample_domain


def _f_reference_aba(system, x):
    """ẋ = (v, Ṁv + M a) with a from `pin.aba` and Ṁv = Σ_j (∂M/∂q_j v_j) v from RNEA derivatives."""
    plant = system.plant
    model, data = plant.model, plant.data
    q, p = x[:, : system.nq], x[:, system.nq :]
    out = np.empty_like(x)
    for k, qc in enumerate(plant.config(q)):
        M = pin.crba(model, data, qc)
        v = np.linalg.solve(M, p[k])
        a = pin.aba(model, data, qc, v, -plant.damping * v)
        dtau_dq = pin.computeRNEADerivatives(model, data, qc, np.zeros(system.nv), v)[0]
        W = dtau_dq - pin.computeGeneralizedGravityDerivatives(model, data, qc)
        out[k] = np.concatenate([v, W @ v + M @ a])
    return out


def _rel(err, ref):
    return np.linalg.norm(err.reshape(len(err), -1), axis=1) / np.maximum(np.linalg.norm(ref.reshape(len(ref), -1), axis=1), 1e-12)


def _central_jacobian(system, x, h=1e-6):
    J = np.empty((len(x), system.n, system.n))
    for i in range(system.n):
        e = np.zeros(system.n)
        e[i] = h
        J[:, :, i] = (system.f(x + e) - system.f(x - e)) / (2 * h)
    return J


URDF_SYSTEMS = zoo_names() + ["erd:double_pendulum", "erd:double_pendulum_continuous", "erd:double_pendulum_simple"]


def _load(name):
    return ip.load_system(name, actuated=["joint1"] if name.startswith("erd:") else None)


@pytest.mark.parametrize("name", URDF_SYSTEMS)
def test_f_equals_pinocchio_forward_dynamics(name):
    system = _load(name)
    x = sample_domain(system, 1000, seed=1)
    rel = _rel(system.f(x) - _f_reference_aba(system, x), _f_reference_aba(system, x))
    assert rel.max() <= 1e-10


@pytest.mark.parametrize("name", URDF_SYSTEMS + analytic_names())
def test_df_dx_matches_central_differences(name):
    system = _load(name)
    x = sample_domain(system, 1000, seed=2)
    f, J = system.f_and_df_dx(x)
    np.testing.assert_allclose(f, system.f(x), rtol=1e-13, atol=1e-13)
    assert _rel(J - _central_jacobian(system, x), J).max() <= 1e-6


@pytest.mark.parametrize("name", URDF_SYSTEMS + analytic_names())
def test_rows_of_f_are_those_of_f(name):
    """`f_rows` (the controller's input rows) gives f's rows: f's own values when every row is asked
    for (each robot here has a joint whose row needs the Coriolis term), and the ABA reference's on
    the input rows and each joint's rows alone, where the momentum row of a joint that hangs from
    the fixed base skips (Cᵀv)_j = ∂T/∂q_j, zero there."""
    system = _load(name)
    x = sample_domain(system, 1000, seed=5)
    f = system.f(x)
    ref = _f_reference_aba(system, x) if name in URDF_SYSTEMS else f
    np.testing.assert_array_equal(system.f_rows(x, np.arange(system.n)), f)
    inputs = np.flatnonzero(system.actuated_mask)
    for rows in [inputs] + [np.array([j, system.nq + j]) for j in range(system.nq)]:
        got = system.f_rows(x, rows)
        assert got.shape == (len(x), len(rows))
        assert _rel(got - ref[:, rows], ref[:, rows]).max() <= 1e-10, rows
        assert np.abs(got - f[:, rows]).max() <= 1e-12 * max(np.abs(f[:, rows]).max(), 1.0), rows
    np.testing.assert_array_equal(system.f_rows(x[0], inputs), system.f_rows(x[:1], inputs)[0])


@pytest.mark.parametrize("name", URDF_SYSTEMS)
def test_hamiltonian_and_state_maps(name):
    """H = ½vᵀMv + U, (q, v) ↔ (q, p) round trip, M symmetric positive definite."""
    system = _load(name)
    x = sample_domain(system, 50, seed=3)
    q, v = system.split(x)
    np.testing.assert_allclose(system.state_from(q, v), x, rtol=1e-12, atol=1e-12)
    M = system.mass_matrix(q)
    np.testing.assert_allclose(M, np.swapaxes(M, 1, 2), atol=1e-14)
    assert np.linalg.eigvalsh(M).min() > 0
    kinetic = 0.5 * np.einsum("ni,nij,nj->n", v, M, v)
    np.testing.assert_allclose(system.hamiltonian(x), kinetic + system.potential(q), rtol=1e-12)


def test_f_is_the_hamiltonian_gradient_flow():
    """q̇ = ∂H/∂p and ṗ = −∂H/∂q − Dv, with ∂H from central differences of `hamiltonian`."""
    system = ip.load_system("furuta")
    x = sample_domain(system, 50, seed=4)
    h = 1e-6
    grad = np.stack(
        [(system.hamiltonian(x + h * e) - system.hamiltonian(x - h * e)) / (2 * h) for e in np.eye(system.n)], axis=1
    )
    nq = system.nq
    _, v = system.split(x)
    expected = np.concatenate([grad[:, nq:], -grad[:, :nq] - system.plant.damping * v], axis=1)
    np.testing.assert_allclose(system.f(x), expected, rtol=1e-6, atol=1e-6)


def test_example_robot_data_double_pendulum_variants_agree():
    """Revolute (nq = 2) and continuous (nq = 4, cos/sin) versions of the same robot are the same plant."""
    rev = ip.load_system("erd:double_pendulum", actuated=["joint1"])
    cont = ip.load_system("erd:double_pendulum_continuous", actuated=["joint1"])
    assert rev.plant.model.nq == 2 and cont.plant.model.nq == 4 and rev.nq == cont.nq == 2
    assert [j.kind for j in cont.joints] == ["continuous", "continuous"]
    x = sample_domain(rev, 200, seed=5) * 3.0  # angles beyond ±π exercise the cos/sin map
    np.testing.assert_allclose(cont.f(x), rev.f(x), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(cont.df_dx(x), rev.df_dx(x), rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(cont.hamiltonian(x), rev.hamiltonian(x), rtol=1e-12, atol=1e-12)
    cfg = cont.plant.config(x[:, :2])
    ref = np.stack([pin.integrate(cont.plant.model, pin.neutral(cont.plant.model), qk) for qk in x[:, :2]])
    np.testing.assert_allclose(cfg, ref, atol=1e-14)


# ------------------------------------------------------------------ paper systems (§V) vs autograd
G = 9.81


def _paper_mech_torch(name):
    if name == "paper_double_pendulum":
        m1 = m2 = l1 = l2 = 1.0

        def M(q):
            c = 0.5 * m2 * l1 * l2 * torch.cos(q[0] - q[1])
            return torch.stack([torch.stack([(m1 + m2) * l1**2 + 0 * c, c]), torch.stack([c, m2 * l2**2 + 0 * c])])

        def U(q):
            return m2 * G * (l1 * (1 + torch.cos(q[0])) + l2 * (1 + torch.cos(q[1]))) + m1 * G * l1 * (1 + torch.cos(q[0]))

    else:
        m1 = m2 = l2 = 1.0

        def M(q):
            c = 0.5 * m2 * l2 * torch.cos(q[1])
            return torch.stack([torch.stack([m1 + m2 + 0 * c, c]), torch.stack([c, m2 * l2**2 + 0 * c])])

        def U(q):
            return m2 * G * l2 * (1 + torch.cos(q[1]))

    def f(x):
        if not x.requires_grad:
            x = x.clone().requires_grad_(True)
        q, p = x[:2], x[2:]
        H = 0.5 * p @ torch.linalg.solve(M(q), p) + U(q)
        dH = torch.autograd.grad(H, x, create_graph=True)[0]
        return torch.cat([dH[2:], -dH[:2]])

    return f


@pytest.mark.parametrize("name", ["paper_double_pendulum", "paper_cartpole"])
def test_paper_mechanical_systems_match_autograd_of_their_formulas(name):
    system = ip.load_system(name)
    f_torch = _paper_mech_torch(name)
    x = sample_domain(system, 40, seed=6) * 2.0
    for xk, fk, Jk in zip(x, *system.f_and_df_dx(x)):
        xt = torch.tensor(xk, dtype=torch.float64)
        np.testing.assert_allclose(fk, f_torch(xt).detach().numpy(), rtol=1e-12, atol=1e-12)
        J_ref = torch.autograd.functional.jacobian(f_torch, xt).numpy()
        np.testing.assert_allclose(Jk, J_ref, rtol=1e-11, atol=1e-11)
    # the plant the controller is judged on integrates the same equations
    q, v = system.split(x)
    a = system.forward_dynamics(q, v, np.zeros_like(q))
    h = 1e-6
    Mdot_v = np.einsum("nij,nj->ni", (system.mass_matrix(q + h * v) - system.mass_matrix(q - h * v)) / (2 * h), v)
    p_dot = Mdot_v + np.einsum("nij,nj->ni", system.mass_matrix(q), a)
    np.testing.assert_allclose(p_dot, system.f(x)[:, 2:], rtol=1e-7, atol=1e-7)


def test_paper_mass_spring_damper_matches_its_formula():
    system = ip.load_system("paper_mass_spring_damper")
    m = k = 1.0
    b = 0.5

    def f_torch(x):
        q, p = x[0], x[1]
        A = torch.stack([torch.stack([0 * q, 1 + 0 * q]), torch.stack([-(k + 0.5 * q**2) / m, -b * p * (1 + torch.abs(p)) / m])])
        return A @ x

    np.testing.assert_allclose(system.x_star, [0.5, 0.0])
    x = sample_domain(system, 40, seed=7)
    for xk, fk, Jk in zip(x, *system.f_and_df_dx(x)):
        xt = torch.tensor(xk, dtype=torch.float64)
        np.testing.assert_allclose(fk, f_torch(xt).numpy(), rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(Jk, torch.autograd.functional.jacobian(f_torch, xt).numpy(), rtol=1e-12, atol=1e-12)
    assert np.allclose(system.g(x[0]), [[0.0], [1.0]])
    np.testing.assert_allclose(system.equilibrium_residual(), [0.0])


@pytest.mark.parametrize("name", zoo_names() + analytic_names())
def test_input_matrix_and_annihilator(name):
    """g⊥ g = 0, G = [gᵀ; g⊥] invertible, B selects the actuated joints."""
    system = ip.load_system(name)
    x = sample_domain(system, 5, seed=8)
    g, gp, Gm = system.g(x), system.g_perp(x), system.G(x)
    assert g.shape == (5, system.n, system.m) and gp.shape == (5, system.n - system.m, system.n)
    np.testing.assert_array_equal(gp @ g, 0.0)
    assert np.all(np.abs(np.linalg.det(Gm)) > 0.5)
    for col, joint in enumerate(system.actuated):
        assert system.B[system.coordinate_names.index(joint), col] == 1.0
    assert np.all(np.abs(system.equilibrium_residual()) <= EQUILIBRIUM_TOL)

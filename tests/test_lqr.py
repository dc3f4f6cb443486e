"""LQR and the LQR anchor A_cl = (J - R)P (DESIGN §2, "Local exactness: an LQR anchor")."""

import dataclasses

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from idapbc_pin.control.linear import (
    LinearAnchor,
    controllability_rank,
    is_stabilisable,
    lqr,
    lqr_anchor,
    uncontrollable_eigenvalues,
)

FAST = settings(max_examples=25, deadline=None)


# --------------------------------------------------------------------------------------------
# Systems
# --------------------------------------------------------------------------------------------
def double_integrator():
    return np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]])


def mechanical(M, Kq, Dm, actuated):
    """Linearisation at x* of x = (q, p): q̇ = M⁻¹p, ṗ = -Kq q - Dm M⁻¹p + B_u u; and g⊥."""
    nq = M.shape[0]
    Minv = np.linalg.inv(M)
    A = np.block([[np.zeros((nq, nq)), Minv], [-Kq, -Dm @ Minv]])
    I = np.eye(nq)
    unact = [i for i in range(nq) if i not in actuated]
    B = np.vstack([np.zeros((nq, len(actuated))), I[:, actuated]])
    g_perp = np.block([[I, np.zeros((nq, nq))], [np.zeros((len(unact), nq)), I[unact, :]]])
    return A, B, g_perp


def cartpole():
    """Cartpole of the paper (m1 = m2 = l2 = 1, g = 9.81), pole upright, force on the cart.

    q = (cart position s, pole angle θ from upright); M = [[m1+m2, m2 l cosθ], [m2 l cosθ, m2 l²]],
    U = m2 g l cosθ, so ∂²U/∂q² = diag(0, -m2 g l) at θ = 0.
    """
    M = np.array([[2.0, 1.0], [1.0, 1.0]])
    Kq = np.diag([0.0, -9.81])
    return mechanical(M, Kq, np.zeros((2, 2)), actuated=[0])


def random_system(seed, n, m):
    rng = np.random.default_rng(seed)
    return rng.standard_normal((n, n)), rng.standard_normal((n, m))


def random_mechanical(seed, nq, n_act):
    rng = np.random.default_rng(seed)
    G = rng.standard_normal((nq, nq))
    M = G @ G.T + 0.5 * np.eye(nq)
    S = rng.standard_normal((nq, nq))
    Kq = S + S.T  # indefinite: unstable potential allowed
    Dm = np.diag(rng.uniform(0.0, 0.5, nq))
    actuated = sorted(rng.choice(nq, size=n_act, replace=False).tolist())
    return mechanical(M, Kq, Dm, actuated)


def assert_anchor(an: LinearAnchor, A, B, rtol=1e-9):
    A_cl = A - B @ an.K
    np.testing.assert_allclose(an.A_cl, A_cl, rtol=0, atol=1e-14 * np.abs(A_cl).max())
    assert np.linalg.eigvals(an.A_cl).real.max() < 0, "A_cl must be Hurwitz"
    np.testing.assert_array_equal(an.J + an.J.T, 0.0)
    np.testing.assert_array_equal(an.P, an.P.T)
    np.testing.assert_array_equal(an.R, an.R.T)
    assert np.linalg.eigvalsh(an.P).min() > 0, "P ≻ 0"
    assert np.linalg.eigvalsh(an.R).min() > 0, "R ≻ 0"
    err = np.abs((an.J - an.R) @ an.P - an.A_cl).max()
    assert err <= rtol * np.abs(an.A_cl).max(), f"(J - R)P ≠ A_cl: {err:.3g}"


# --------------------------------------------------------------------------------------------
# LQR
# --------------------------------------------------------------------------------------------
def test_double_integrator_matches_closed_form():
    # ARE with Q = I, R = 1: S = [[√3, 1], [1, √3]], K = [1, √3].
    A, B = double_integrator()
    K, S = lqr(A, B, np.eye(2), np.eye(1))
    r3 = np.sqrt(3.0)
    np.testing.assert_allclose(K, [[1.0, r3]], rtol=1e-12)
    np.testing.assert_allclose(S, [[r3, 1.0], [1.0, r3]], rtol=1e-12)


@FAST
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 6), data=st.data())
def test_lqr_solves_the_riccati_equation_and_stabilises(seed, n, data):
    m = data.draw(st.integers(1, n))
    A, B = random_system(seed, n, m)
    Q, R = np.eye(n), np.diag(np.random.default_rng(seed + 1).uniform(0.5, 2.0, m))
    K, S = lqr(A, B, Q, R)
    assert K.shape == (m, n) and S.shape == (n, n)
    scale = max(1.0, np.abs(S).max() ** 2 * np.abs(B).max() ** 2)
    res = A.T @ S + S @ A - S @ B @ np.linalg.solve(R, B.T @ S) + Q
    assert np.abs(res).max() < 1e-8 * scale
    np.testing.assert_allclose(K, np.linalg.solve(R, B.T @ S), atol=1e-12 * max(1.0, np.abs(K).max()))
    assert np.linalg.eigvals(A - B @ K).real.max() < 0


def test_unstabilisable_input_raises_with_the_offending_mode():
    A = np.diag([1.5, -1.0])
    B = np.array([[0.0], [1.0]])  # the unstable mode +1.5 is not reachable
    with pytest.raises(ValueError, match=r"not stabilisable.*\+1\.5"):
        lqr(A, B, np.eye(2), np.eye(1))
    with pytest.raises(ValueError, match="not stabilisable"):
        lqr_anchor(A, B)


def test_cartpole_without_input_is_not_stabilisable():
    A, _, _ = cartpole()
    with pytest.raises(ValueError, match="not stabilisable"):
        lqr(A, np.zeros((4, 1)), np.eye(4), np.eye(1))


def test_stabilisable_but_uncontrollable_system_is_accepted():
    A = np.diag([-1.0, 1.0])
    B = np.array([[0.0], [1.0]])
    assert controllability_rank(A, B) == 1
    np.testing.assert_allclose(uncontrollable_eigenvalues(A, B), [-1.0])
    assert is_stabilisable(A, B)
    assert_anchor(lqr_anchor(A, B), A, B)


def test_bad_weights_raise():
    A, B = double_integrator()
    with pytest.raises(ValueError, match="R must be symmetric positive definite"):
        lqr(A, B, np.eye(2), np.zeros((1, 1)))
    with pytest.raises(ValueError, match="Q must be symmetric positive semidefinite"):
        lqr(A, B, -np.eye(2), np.eye(1))
    with pytest.raises(ValueError, match="shape"):
        lqr(A, B, np.eye(3), np.eye(1))


# --------------------------------------------------------------------------------------------
# Controllability
# --------------------------------------------------------------------------------------------
@FAST
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 7), data=st.data())
def test_controllability_rank_of_a_hidden_kalman_decomposition(seed, n, data):
    """A = T [[A11, A12], [0, A22]] Tᵀ, B = T [B1; 0] (T orthogonal): the rank is dim A11."""
    r = data.draw(st.integers(0, n))
    m = data.draw(st.integers(1, 3))
    rng = np.random.default_rng(seed)
    T, _ = np.linalg.qr(rng.standard_normal((n, n)))
    Ab = rng.standard_normal((n, n))
    Ab[r:, :r] = 0.0
    Bb = np.zeros((n, m))
    Bb[:r] = rng.standard_normal((r, m))
    A, B = T @ Ab @ T.T, T @ Bb
    assert controllability_rank(A, B) == r
    # invariant to the units of the inputs and of time
    assert controllability_rank(A, 1e-8 * B) == r
    assert controllability_rank(1e3 * A, B) == r
    lam = uncontrollable_eigenvalues(A, B)
    np.testing.assert_allclose(np.sort_complex(lam), np.sort_complex(np.linalg.eigvals(Ab[r:, r:])), atol=1e-8)


def test_controllability_rank_where_the_krylov_matrix_is_badly_scaled():
    # chain of 8 integrators with gains 30: [B, AB, …] has columns from 1 to 30⁷ ≈ 2e10.
    n = 8
    A = 30.0 * np.eye(n, k=-1)
    B = np.eye(n)[:, :1]
    assert controllability_rank(A, B) == n
    A2 = A.copy()
    A2[4, 3] = 0.0  # cut the chain: only the first 4 states are reachable
    assert controllability_rank(A2, B) == 4


# --------------------------------------------------------------------------------------------
# Anchor
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("P_mode", ["riccati", "lyapunov"])
@pytest.mark.parametrize("system", ["double_integrator", "cartpole"])
def test_anchor_is_an_exact_ph_form_of_the_lqr_loop(system, P_mode):
    if system == "double_integrator":
        A, B = double_integrator()
        g_perp = None
    else:
        A, B, g_perp = cartpole()
    an = lqr_anchor(A, B, P_mode=P_mode)
    assert_anchor(an, A, B)
    if P_mode == "riccati":
        K, S = lqr(A, B, np.eye(A.shape[0]), np.eye(B.shape[1]))
        np.testing.assert_array_equal(an.P, S)
        Qp = np.eye(A.shape[0]) + an.K.T @ an.K
        np.testing.assert_allclose(an.A_cl.T @ an.P + an.P @ an.A_cl, -Qp, atol=1e-9 * np.abs(Qp).max())
    else:
        np.testing.assert_allclose(an.A_cl.T @ an.P + an.P @ an.A_cl, -np.eye(A.shape[0]), atol=1e-9)
    if g_perp is not None:
        # g⊥(A_cl - A) = -g⊥BK = 0: the linearised mismatch vanishes (∂μ/∂x(x*) = 0)
        np.testing.assert_allclose(g_perp @ (an.A_cl - A), 0.0, atol=1e-12 * np.abs(an.K).max())


def test_cartpole_lyapunov_P_is_badly_conditioned_riccati_less_so():
    A, B, _ = cartpole()
    cond = {mode: np.linalg.cond(lqr_anchor(A, B, P_mode=mode).P) for mode in ("riccati", "lyapunov")}
    assert cond["lyapunov"] > 1e3  # DESIGN: λ(P) from 0.11 to 565
    assert np.isfinite(cond["riccati"])


@FAST
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 6), data=st.data())
def test_anchor_on_random_stabilisable_systems(seed, n, data):
    m = data.draw(st.integers(1, n))
    P_mode = data.draw(st.sampled_from(["riccati", "lyapunov"]))
    A, B = random_system(seed, n, m)
    an = lqr_anchor(A, B, P_mode=P_mode)
    assume(np.linalg.cond(an.P) < 1e6)
    assert_anchor(an, A, B)


@FAST
@given(seed=st.integers(0, 2**31 - 1), nq=st.integers(2, 4), data=st.data())
def test_anchor_leaves_the_unactuated_rows_of_a_mechanical_system_unchanged(seed, nq, data):
    n_act = data.draw(st.integers(1, nq - 1))
    A, B, g_perp = random_mechanical(seed, nq, n_act)
    assume(is_stabilisable(A, B, margin=1e-6))
    an = lqr_anchor(A, B, P_mode=data.draw(st.sampled_from(["riccati", "lyapunov"])))
    assume(np.linalg.cond(an.P) < 1e6)
    assert_anchor(an, A, B)
    np.testing.assert_array_equal(g_perp @ B, 0.0)
    np.testing.assert_allclose(g_perp @ (an.A_cl - A), 0.0, atol=1e-12 * max(1.0, np.abs(an.K).max()))


@pytest.mark.parametrize("scale", [0.01, 7.0, "unit"])
def test_scaling_P_scales_J_and_R_inversely_and_keeps_the_loop(scale):
    A, B, _ = cartpole()
    base = lqr_anchor(A, B)
    an = lqr_anchor(A, B, scale=scale)
    c = 1.0 / np.linalg.eigvalsh(base.P).max() if scale == "unit" else scale
    np.testing.assert_allclose(an.P, c * base.P, rtol=1e-12)
    np.testing.assert_allclose(an.R, base.R / c, rtol=1e-9, atol=1e-12 * np.abs(base.R / c).max())
    np.testing.assert_allclose(an.A_cl, base.A_cl, rtol=1e-12)
    assert_anchor(an, A, B)
    if scale == "unit":
        assert np.isclose(np.linalg.eigvalsh(an.P).max(), 1.0)


def test_anchor_rejects_bad_options_and_semidefinite_damping():
    A, B = double_integrator()
    with pytest.raises(ValueError, match="P_mode"):
        lqr_anchor(A, B, P_mode="lqr")
    with pytest.raises(ValueError, match="scale"):
        lqr_anchor(A, B, scale=-1.0)
    with pytest.raises(ValueError, match="scale"):
        lqr_anchor(A, B, scale="max")
    # Q ⪰ 0 singular: the Lyapunov P is fine but R = ½P⁻¹QP⁻¹ is singular.
    with pytest.raises(ValueError, match="singular"):
        lqr_anchor(A, B, Q=np.diag([1.0, 0.0]), P_mode="lyapunov")


def test_linear_anchor_is_immutable():
    A, B = double_integrator()
    an = lqr_anchor(A, B)
    with pytest.raises(dataclasses.FrozenInstanceError):
        an.P = np.eye(2)
    with pytest.raises(ValueError):
        an.P[0, 0] = 1.0
    assert an.n == 2 and an.eigenvalues.real.max() < 0

"""The networks satisfy the paper's structural conditions (i)–(iii) for any weights.

Conditions (Proposition 3 of the paper, prop:vanishing_mu): (i) J_d skew, R_d ≻ 0, ∇²H_d ≻ 0 everywhere;
(ii) H_d > 0 away from x*; (iii) H_d(x*) = 0, ∇H_d(x*) = 0. Anchored forms additionally take the
LQR anchor's values at x* (DESIGN §2), so the closed loop linearises to A - BK.
"""

import io
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from idapbc_pin.control.linear import lqr_anchor
from idapbc_pin.control.damping import DampingNet
from idapbc_pin.control.energy import EnergyNet
from idapbc_pin.control.icnn import ICNN
from idapbc_pin.control.interconnection import InterconnectionNet
from idapbc_pin.control.layers import psi
from idapbc_pin.control.structure import lower_tri, n_lower, n_skew, skew, unskew

FAST = settings(max_examples=25, deadline=None)
f64 = torch.float64

seeds = st.integers(0, 2**31 - 1)
dims = st.sampled_from([2, 4, 6])
widths = st.sampled_from([8, 16, 32])
depths = st.integers(1, 3)
weight_scales = st.sampled_from([0.5, 1.0, 2.0])


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------
def gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def randomise_(module: torch.nn.Module, seed: int, scale: float = 1.0) -> torch.nn.Module:
    """Overwrite every parameter with N(0, scale²/fan_in) (fan_in = last dimension)."""
    g = gen(seed)
    with torch.no_grad():
        for p in module.parameters():
            fan_in = p.shape[-1] if p.ndim else 1
            p.copy_(torch.randn(p.shape, generator=g, dtype=p.dtype) * scale / math.sqrt(fan_in))
    return module


def random_x_star(seed: int, n: int, dtype=f64) -> torch.Tensor:
    return torch.randn(n, generator=gen(seed + 1), dtype=dtype)


def points_away(x_star: torch.Tensor, seed: int, N: int = 16) -> torch.Tensor:
    """N states x* + r d with ‖d‖ = 1 and r ∈ [0.01, 3]."""
    g = gen(seed + 2)
    d = torch.randn(N, x_star.numel(), generator=g, dtype=x_star.dtype)
    r = 0.01 + 3.0 * torch.rand(N, 1, generator=g, dtype=x_star.dtype)
    return x_star + r * d / d.norm(dim=-1, keepdim=True)


def random_spd(seed: int, n: int) -> torch.Tensor:
    G = torch.randn(n, n, generator=gen(seed + 3), dtype=f64)
    return G @ G.T + 0.1 * torch.eye(n, dtype=f64)


def random_metric(seed: int, n: int, boxed: bool) -> torch.Tensor | None:
    """Box half-widths s > 0 spanning about two decades (light links: momenta ~1e-2), or None."""
    return torch.exp(1.5 * torch.randn(n, generator=gen(seed + 7), dtype=f64)) if boxed else None


def random_skew(seed: int, n: int) -> torch.Tensor:
    G = torch.randn(n, n, generator=gen(seed + 4), dtype=f64)
    return G - G.T


def hessian(H: EnergyNet, x: torch.Tensor) -> torch.Tensor:
    """∇²H_d at one state x (n,) -> (n, n)."""
    return torch.autograd.functional.hessian(lambda y: H(y.unsqueeze(0))[0], x)


def closed_loop(H, J, R):
    """x (n,) -> ẋ = (J_d(x) - R_d(x)) ∇H_d(x), (n,)."""

    def f(x):
        X = x.unsqueeze(0)
        g = H.grad(X, create_graph=True)
        return ((J(X) - R(X)) @ g.unsqueeze(-1)).reshape(-1)

    return f


# --------------------------------------------------------------------------------------------
# Index maps
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 2, 3, 6])
def test_skew_and_lower_maps(n):
    v = torch.randn(5, n_skew(n), dtype=f64)
    J = skew(v, n)
    assert J.shape == (5, n, n)
    assert torch.equal(J, -J.transpose(-1, -2))
    assert torch.equal(unskew(J), v)
    w = torch.randn(3, 5, n_lower(n), dtype=f64)
    L = lower_tri(w, n)
    assert torch.equal(L, torch.tril(L))
    assert torch.equal(torch.diagonal(L, dim1=-2, dim2=-1), w[..., :n])
    i, j = torch.tril_indices(n, n, -1)
    assert torch.equal(L[..., i, j], w[..., n:])
    Ls = lower_tri(w[..., n:], n, strict=True)
    assert torch.equal(Ls, torch.tril(L, -1))
    with pytest.raises(ValueError, match="last dimension"):
        skew(torch.zeros(n_skew(n) + 1), n)


def test_psi_is_zero_flat_and_convex_at_zero():
    s = torch.tensor([0.0], dtype=f64, requires_grad=True)
    (d1,) = torch.autograd.grad(psi(s).sum(), s, create_graph=True)
    (d2,) = torch.autograd.grad(d1.sum(), s)
    assert psi(s).item() == 0.0 and d1.item() == 0.0 and d2.item() == 1.0
    t = torch.linspace(0, 100, 101, dtype=f64)
    assert (psi(t[1:]) > 0).all() and (torch.diff(psi(t)) > 0).all()


# --------------------------------------------------------------------------------------------
# ICNN
# --------------------------------------------------------------------------------------------
@FAST
@given(seed=seeds, n=dims, width=widths, depth=depths, scale=weight_scales)
def test_icnn_is_convex_for_any_weights(seed, n, width, depth, scale):
    net = randomise_(ICNN(n, width, depth, dtype=f64), seed, scale)
    g = gen(seed)
    a, b = torch.randn(2, 64, n, generator=g, dtype=f64)
    t = torch.rand(64, 1, generator=g, dtype=f64)
    # Jensen along random chords
    assert (net(t * a + (1 - t) * b) <= t[:, 0] * net(a) + (1 - t[:, 0]) * net(b) + 1e-12).all()
    Hs = torch.autograd.functional.hessian(lambda u: net(u), a[0])
    assert torch.linalg.eigvalsh(Hs).min() >= -1e-12


@FAST
@given(seed=seeds, n=dims, width=widths, depth=depths, affine=st.booleans())
def test_icnn_explicit_gradient_matches_autograd_including_its_weight_derivatives(seed, n, width, depth, affine):
    net = randomise_(ICNN(n, width, depth, affine_out=affine, dtype=f64), seed)
    u = torch.randn(7, n, generator=gen(seed), dtype=f64, requires_grad=True)
    h, g = net.value_and_grad(u)
    (g_auto,) = torch.autograd.grad(net(u).sum(), u, create_graph=True)
    torch.testing.assert_close(h, net(u), rtol=0, atol=1e-14)
    torch.testing.assert_close(g, g_auto, rtol=0, atol=1e-13)
    c = torch.randn(7, n, generator=gen(seed + 9), dtype=f64)
    params = list(net.parameters())
    d_explicit = torch.autograd.grad((g * c).sum(), params, allow_unused=True, materialize_grads=True)
    d_auto = torch.autograd.grad((g_auto * c).sum(), params, allow_unused=True, materialize_grads=True)
    for a, b in zip(d_explicit, d_auto):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)


@FAST
@given(seed=seeds, n=dims, width=widths, depth=depths, scale=weight_scales, affine=st.booleans())
def test_icnn_bregman_divergence_is_exactly_zero_at_zero_and_nonnegative(seed, n, width, depth, scale, affine):
    net = randomise_(ICNN(n, width, depth, affine_out=affine, dtype=f64), seed, scale)
    zero = torch.zeros(1, n, dtype=f64)
    assert net.bregman(zero).item() == 0.0  # exactly, whatever the size of Ĥ(0)
    u = torch.randn(32, n, generator=gen(seed), dtype=f64)
    D = net.bregman(u)
    h0, g0 = net.value_and_grad(zero[0])
    reference = net(u) - h0 - u @ g0
    torch.testing.assert_close(D, reference, rtol=1e-9, atol=1e-12 * (1 + h0.abs().item()))
    assert (D >= 0).all()


# --------------------------------------------------------------------------------------------
# H_d
# --------------------------------------------------------------------------------------------
@FAST
@given(seed=seeds, n=dims, width=widths, depth=depths, scale=weight_scales)
def test_free_energy_satisfies_conditions_i_to_iii_for_random_weights(seed, n, width, depth, scale):
    x_star = random_x_star(seed, n)
    H = randomise_(EnergyNet(x_star, width, depth, eps=1e-3), seed, scale)
    # (iii) H_d(x*) = 0, ∇H_d(x*) = 0
    Hs, gs = H.value_and_grad(x_star.unsqueeze(0))
    assert Hs.abs().max() < 1e-12 and gs.abs().max() < 1e-12
    # (ii) H_d > 0 away from x*, indeed H_d ≥ ε‖x - x*‖²
    x = points_away(x_star, seed)
    Hx = H(x)
    assert Hx.shape == (16,)
    assert (Hx > 0).all()
    assert (Hx >= 1e-3 * ((x - x_star) ** 2).sum(-1) * (1 - 1e-9)).all()
    # (i) ∇²H_d ⪰ 2εI ≻ 0
    for xi in x[:3]:
        assert torch.linalg.eigvalsh(hessian(H, xi)).min() >= 2e-3 * (1 - 1e-6)


@FAST
@given(seed=seeds, n=dims, width=widths, depth=depths, scale=weight_scales, mapped=st.booleans())
def test_anchored_energy_has_hessian_P_at_x_star_and_stays_convex(seed, n, width, depth, scale, mapped):
    """(i)–(iii) and ∇²H_d(x*) = P, with the ICNN fed (x − x*)/s or the anchor-metric input S P (x − x*)."""
    x_star = random_x_star(seed, n)
    P = random_spd(seed, n)
    W = torch.diag(random_metric(seed, n, True)) @ P if mapped else None
    H = randomise_(EnergyNet(x_star, width, depth, P=P, input_map=W), seed, scale)
    assert H.form == "anchored"
    Hs, gs = H.value_and_grad(x_star.unsqueeze(0))
    assert Hs.abs().max() < 1e-12 and gs.abs().max() < 1e-12
    torch.testing.assert_close(hessian(H, x_star), P, rtol=0, atol=1e-10 * P.abs().max().item())
    x = points_away(x_star, seed)
    assert (H(x) > 0).all()
    lam_P = torch.linalg.eigvalsh(P).min()
    for xi in x[:3]:
        assert torch.linalg.eigvalsh(hessian(H, xi)).min() >= lam_P * (1 - 1e-6)  # ∇²H_d ⪰ P


def test_energy_is_radially_unbounded_and_works_without_grad_mode():
    x_star = torch.tensor([0.3, -0.2, 1.0, 0.0], dtype=f64)
    H = EnergyNet(x_star, 16, 2)
    with torch.no_grad():
        big = H(x_star + torch.tensor([[100.0, 0, 0, 0]], dtype=f64))
        g = H.grad(x_star.unsqueeze(0) + 1.0)
    assert big.item() > 1e-3 * 100.0**2 and g.shape == (1, 4) and not g.requires_grad


# --------------------------------------------------------------------------------------------
# J_d
# --------------------------------------------------------------------------------------------
@FAST
@given(seed=seeds, n=dims, width=widths, depth=depths, scale=weight_scales, anchored=st.booleans(), boxed=st.booleans())
def test_interconnection_is_skew_and_anchored_at_J0(seed, n, width, depth, scale, anchored, boxed):
    x_star = random_x_star(seed, n)
    J0 = random_skew(seed, n) if anchored else None
    J = randomise_(InterconnectionNet(x_star, width, depth, J0=J0, metric=random_metric(seed, n, boxed)), seed, scale)
    x = points_away(x_star, seed)
    Jx = J(x)
    assert Jx.shape == (16, n, n)
    assert torch.equal(Jx, -Jx.transpose(-1, -2))  # J_d + J_dᵀ = 0 exactly
    if anchored:
        torch.testing.assert_close(J(x_star.unsqueeze(0))[0], J0, rtol=0, atol=1e-12)


# --------------------------------------------------------------------------------------------
# R_d
# --------------------------------------------------------------------------------------------
@FAST
@given(seed=seeds, n=dims, width=widths, depth=depths, scale=weight_scales, anchored=st.booleans(), boxed=st.booleans())
def test_damping_is_positive_definite_even_with_rho_zero(seed, n, width, depth, scale, anchored, boxed):
    x_star = random_x_star(seed, n)
    R0 = random_spd(seed, n) if anchored else None
    R = randomise_(DampingNet(x_star, width, depth, R0=R0, rho=0.0, metric=random_metric(seed, n, boxed)), seed, scale)
    x = points_away(x_star, seed)
    Rx = R(x)
    assert Rx.shape == (16, n, n)
    assert torch.equal(Rx, Rx.transpose(-1, -2))
    L = R.cholesky_factor(x)
    assert torch.equal(L, torch.tril(L)) and (torch.diagonal(L, dim1=-2, dim2=-1) > 0).all()
    assert torch.equal(Rx, L @ L.transpose(-1, -2))  # ρ = 0: R_d = L Lᵀ, L nonsingular ⇒ R_d ≻ 0
    assert (torch.linalg.svdvals(L)[..., -1] > 0).all()
    # eigvalsh resolves λ_min only to its backward error, about n·eps·‖R_d‖₂: random weights of
    # scale 2 reach ‖R_d‖ ~ 1e3 with λ_min ~ 1e-15, which no float64 eigensolver can sign
    floor = n * torch.finfo(f64).eps * torch.linalg.matrix_norm(Rx, 2)
    assert (R.min_eig(x) > -floor).all()
    if anchored:
        torch.testing.assert_close(R(x_star.unsqueeze(0))[0], R0, rtol=0, atol=1e-12 * R0.abs().max().item())


@FAST
@given(seed=seeds, n=dims, anchored=st.booleans(), boxed=st.booleans())
def test_bounded_structure_keeps_its_boundary_values_outside_the_box_and_stays_skew_and_positive_definite(seed, n, anchored, boxed):
    """With input_bound = 1 the networks of J_d and R_d see the state clamped to the box x* ± x_scale:
    outside it they repeat their value at the nearest boundary point; inside nothing changes."""
    x_star = random_x_star(seed, n)
    s = torch.exp(torch.randn(n, generator=gen(seed + 9), dtype=f64))
    kw = dict(x_scale=s, metric=random_metric(seed, n, boxed))
    J0, R0 = (random_skew(seed, n), random_spd(seed, n)) if anchored else (None, None)
    J_b = randomise_(InterconnectionNet(x_star, 16, 2, J0=J0, input_bound=1.0, **kw), seed)
    R_b = randomise_(DampingNet(x_star, 16, 2, R0=R0, input_bound=1.0, **kw), seed)
    J_free = InterconnectionNet(x_star, 16, 2, J0=J0, **kw)
    R_free = DampingNet(x_star, 16, 2, R0=R0, **kw)
    J_free.load_state_dict(J_b.state_dict(), strict=False)
    R_free.load_state_dict(R_b.state_dict(), strict=False)
    x = x_star + 4 * s * torch.randn(32, n, generator=gen(seed + 10), dtype=f64)  # mostly outside the box
    on_box = x_star + ((x - x_star) / s).clamp(-1, 1) * s
    torch.testing.assert_close(J_b(x), J_free(on_box), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(R_b(x), R_free(on_box), rtol=1e-12, atol=1e-12)
    assert torch.equal(J_b(x), -J_b(x).transpose(-1, -2)) and (R_b.min_eig(x) > 0).all()
    inside = x_star + 0.9 * s * (2 * torch.rand(8, n, generator=gen(seed + 11), dtype=f64) - 1)
    torch.testing.assert_close(J_b(inside), J_free(inside), rtol=0, atol=0)
    torch.testing.assert_close(R_b(inside), R_free(inside), rtol=0, atol=0)


@FAST
@given(seed=seeds, n=dims, rho=st.floats(0.0, 10.0), anchored=st.booleans())
def test_with_rho_adds_exactly_rho_S_and_shares_the_weights(seed, n, rho, anchored):
    x_star = random_x_star(seed, n)
    mask = torch.arange(n) >= n // 2  # the momentum rows, say all actuated
    R0 = random_spd(seed, n) if anchored else None
    R = randomise_(DampingNet(x_star, 16, 2, R0=R0, rho=0.5, pattern="actuated", actuated=mask), seed)
    x = points_away(x_star, seed)
    before = R(x)
    R2 = R.with_rho(rho)
    S = torch.diag(mask.to(f64)).expand(16, n, n)
    torch.testing.assert_close(R2(x) - before, (rho - 0.5) * S, rtol=0, atol=1e-12 * (1 + rho))
    assert R.rho.item() == 0.5 and R2.rho.item() == rho  # the original is untouched
    assert all(a is b for a, b in zip(R.parameters(), R2.parameters()))
    with torch.no_grad():
        next(R.parameters()).add_(0.1)  # training one trains the other
    torch.testing.assert_close(R2(x) - R(x), (rho - 0.5) * S, rtol=0, atol=1e-12 * (1 + rho))
    assert R2.state_dict()["rho"].item() == rho


def test_full_pattern_damping_has_floor_rho():
    x_star = torch.zeros(4, dtype=f64)
    R = randomise_(DampingNet(x_star, 16, 2, rho=0.7), 0, 3.0)
    x = points_away(x_star, 0, 64)
    assert (R.min_eig(x) >= 0.7 - 1e-12).all()


# --------------------------------------------------------------------------------------------
# The LQR anchor: closed-loop linearisation is the LQR loop, for any weights
# --------------------------------------------------------------------------------------------
@FAST
@given(seed=seeds, n=dims, width=widths, depth=depths, scale=weight_scales, data=st.data())
def test_anchored_closed_loop_jacobian_at_x_star_is_A_minus_BK(seed, n, width, depth, scale, data):
    m = data.draw(st.integers(1, n))
    rng = np.random.default_rng(seed)
    A, B = rng.standard_normal((n, n)), rng.standard_normal((n, m))
    an = lqr_anchor(A, B, P_mode=data.draw(st.sampled_from(["riccati", "lyapunov"])), scale="unit")
    x_star = random_x_star(seed, n)
    s = random_metric(seed, n, data.draw(st.booleans()))  # scaling = "box" or "none"
    W = torch.diag(random_metric(seed, n, True)) @ torch.as_tensor(an.P) if data.draw(st.booleans()) else None  # energy_input
    H = randomise_(EnergyNet(x_star, width, depth, P=an.P, input_map=W), seed, scale)
    J = randomise_(InterconnectionNet(x_star, width, depth, J0=an.J, metric=s), seed + 5, scale)
    R = randomise_(DampingNet(x_star, width, depth, R0=an.R, metric=s), seed + 6, scale)
    f = closed_loop(H, J, R)
    assert f(x_star).abs().max() < 1e-12  # x* is an equilibrium of the closed loop
    jac = torch.autograd.functional.jacobian(f, x_star)
    A_cl = torch.as_tensor(A - B @ an.K)
    torch.testing.assert_close(jac, A_cl, rtol=0, atol=1e-8 * max(1.0, A_cl.abs().max().item()))


def test_training_path_differentiates_the_closed_loop_jacobian_w_r_t_all_weights():
    """Third order: ∂/∂θ ‖∂/∂x[(J_d - R_d)∇H_d]‖² reaches every parameter (both forms)."""
    n = 4
    x_star = torch.tensor([0.1, 0.0, -0.3, 0.2], dtype=f64)
    an = lqr_anchor(np.eye(n, k=1), np.eye(n)[:, -1:])
    for P, J0, R0 in [(None, None, None), (an.P, an.J, an.R)]:
        torch.manual_seed(0)
        nets = EnergyNet(x_star, 8, 2, P=P), InterconnectionNet(x_star, 8, 2, J0=J0), DampingNet(x_star, 8, 2, R0=R0)
        x = (x_star + torch.rand(32, n, dtype=f64)).requires_grad_(True)
        H, J, R = nets
        g = H.grad(x, create_graph=True)
        fx = ((J(x) - R(x)) @ g.unsqueeze(-1)).squeeze(-1)
        jac = torch.stack([torch.autograd.grad(fx[:, i].sum(), x, create_graph=True)[0] for i in range(n)], 1)
        (jac.square().mean() + fx.square().mean()).backward()
        for net in nets:
            for name, p in net.named_parameters():  # no dead parameters
                assert p.grad is not None and torch.isfinite(p.grad).all(), name
                assert p.grad.abs().max() > 0, name


# --------------------------------------------------------------------------------------------
# Plumbing: serialisation, determinism, dtype, errors
# --------------------------------------------------------------------------------------------
def _all_nets(x_star, anchored, seed=0):
    n = x_star.numel()
    torch.manual_seed(seed)
    kw = {}
    if anchored:
        kw = {"P": random_spd(1, n), "J0": random_skew(1, n), "R0": random_spd(2, n)}
    return [
        EnergyNet(x_star, 16, 2, P=kw.get("P")),
        InterconnectionNet(x_star, 16, 2, J0=kw.get("J0")),
        DampingNet(x_star, 16, 2, R0=kw.get("R0"), rho=0.3),
    ]


@pytest.mark.parametrize("anchored", [False, True])
def test_state_dict_round_trip_with_weights_only_load(anchored):
    x_star = torch.tensor([0.5, 0.0, -1.0, 0.25], dtype=f64)
    x = points_away(x_star, 3)
    trained = [randomise_(m, 7) for m in _all_nets(x_star, anchored, seed=0)]
    fresh = _all_nets(torch.zeros(4, dtype=f64), anchored, seed=1)  # other x*, other weights
    for a, b in zip(trained, fresh):
        buf = io.BytesIO()
        torch.save(a.state_dict(), buf)
        buf.seek(0)
        b.load_state_dict(torch.load(buf, weights_only=True))
        assert torch.equal(a(x), b(x))


def test_initialisation_is_deterministic_given_the_seed():
    x_star = torch.zeros(4, dtype=f64)
    x = points_away(x_star, 0)
    for a, b in zip(_all_nets(x_star, True, seed=3), _all_nets(x_star, True, seed=3)):
        assert torch.equal(a(x), b(x))
    for a, b in zip(_all_nets(x_star, False, seed=3), _all_nets(x_star, False, seed=4)):
        assert not torch.equal(a(x), b(x))


@pytest.mark.parametrize("anchored", [False, True])
def test_float32_works(anchored):
    x_star = torch.tensor([0.5, 0.0, -1.0, 0.25], dtype=torch.float32)
    torch.manual_seed(0)
    an = lqr_anchor(np.eye(4, k=1), np.eye(4)[:, -1:], scale="unit")
    kw = (an.P, an.J, an.R) if anchored else (None, None, None)
    H = EnergyNet(x_star, 16, 2, P=kw[0])
    J = InterconnectionNet(x_star, 16, 2, J0=kw[1])
    R = DampingNet(x_star, 16, 2, R0=kw[2])
    x = points_away(x_star, 0)
    Hs, gs = H.value_and_grad(x_star.unsqueeze(0))
    assert Hs.dtype == torch.float32 and Hs.abs().max() < 1e-6 and gs.abs().max() < 1e-5
    assert (H(x) > 0).all()
    Jx, Rx = J(x), R(x)
    assert Jx.dtype == Rx.dtype == torch.float32
    assert torch.equal(Jx, -Jx.transpose(-1, -2))
    assert (R.min_eig(x) > 0).all()
    if anchored:
        jac = torch.autograd.functional.jacobian(closed_loop(H, J, R), x_star)
        A_cl = torch.tensor(np.array(an.A_cl), dtype=torch.float32)
        torch.testing.assert_close(jac, A_cl, rtol=0, atol=1e-4 * A_cl.abs().max().item())


def test_constructor_errors_are_helpful():
    x_star = torch.zeros(4, dtype=f64)
    with pytest.raises(ValueError, match="positive definite"):
        EnergyNet(x_star, 8, 1, P=-torch.eye(4, dtype=f64))
    with pytest.raises(ValueError, match="eps > 0"):
        EnergyNet(x_star, 8, 1, eps=0.0)
    with pytest.raises(ValueError, match="skew"):
        InterconnectionNet(x_star, 8, 1, J0=torch.eye(4, dtype=f64))
    with pytest.raises(ValueError, match="positive definite"):
        DampingNet(x_star, 8, 1, R0=torch.zeros(4, 4, dtype=f64))
    with pytest.raises(ValueError, match="actuated"):
        DampingNet(x_star, 8, 1, pattern="actuated")
    with pytest.raises(ValueError, match="rho"):
        DampingNet(x_star, 8, 1, rho=-1.0)
    with pytest.raises(ValueError, match="shape"):
        EnergyNet(x_star, 8, 1, P=torch.eye(3, dtype=f64))
    with pytest.raises(ValueError, match="last dimension"):
        EnergyNet(x_star, 8, 1)(torch.zeros(2, 3, dtype=f64))


def test_torch_func_transforms_work_too():
    """jacrev / jacfwd / hessian / vmap give the same derivatives as plain autograd."""
    from torch.func import grad, hessian as func_hessian, jacfwd, jacrev, vmap

    n = 4
    an = lqr_anchor(np.eye(n, k=1), np.eye(n)[:, -1:])
    x_star = torch.tensor([0.1, 0.0, -0.3, 0.2], dtype=f64)
    torch.manual_seed(0)
    H = EnergyNet(x_star, 8, 2, P=an.P)
    J = InterconnectionNet(x_star, 8, 2, J0=an.J)
    R = DampingNet(x_star, 8, 2, R0=an.R)
    H1 = lambda x: H(x.unsqueeze(0))[0]  # noqa: E731

    def f(x):  # (J_d - R_d)∇H_d with torch.func's grad (H.grad uses torch.autograd)
        X = x.unsqueeze(0)
        return (J(X) - R(X))[0] @ grad(H1)(x)

    A_cl = torch.tensor(np.array(an.A_cl))
    for jac in (jacrev, jacfwd):
        torch.testing.assert_close(jac(f)(x_star), A_cl, rtol=0, atol=1e-12)
    torch.testing.assert_close(func_hessian(H1)(x_star), torch.tensor(np.array(an.P)), rtol=0, atol=1e-12)
    x = points_away(x_star, 0, 8)
    torch.testing.assert_close(vmap(grad(H1))(x), H.grad(x), rtol=0, atol=1e-13)


def test_moving_or_casting_the_networks_drops_their_run_time_caches():
    """`desired_fast` caches the networks' values at x*; a move to another device or dtype (a run
    trained on a GPU is simulated on the CPU) must not keep the old ones, and a copy sent to a worker
    process must not carry them (on a GPU machine it failed: "Cannot re-initialize CUDA in forked
    subprocess")."""
    import copy
    import pickle

    import idapbc_pin as ip
    from idapbc_pin.config import TrainConfig
    from idapbc_pin.control.nets import build_nets

    system = ip.load_system("pendubot")
    torch.manual_seed(0)
    nets = build_nets(system, TrainConfig.fast(width=16, depth=2, dtype="float32"))
    fresh = copy.deepcopy(nets).double()
    x = torch.as_tensor(np.random.default_rng(0).uniform(*system.domain, size=(8, system.n)))
    nets.desired_fast(x.float())  # fills the caches in float32
    assert "_cache" in nets.__dict__ and nets.H.icnn.__dict__["_pos_cache"]
    shipped = pickle.loads(pickle.dumps(nets))
    assert "_cache" not in shipped.__dict__ and "_pos_cache" not in shipped.H.icnn.__dict__
    nets.double()
    assert torch.equal(nets.desired_fast(x), fresh.desired_fast(x))

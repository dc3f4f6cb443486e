"""Interval forms of a URDF plant and first-order jets: the chain's enclosures equal Pinocchio at
points and hold every sampled value of f and ∂f/∂x over random boxes; a jet holds its function's
gradient and, nested, its Hessian; a lost term or a bound not rounded outward is caught."""

from __future__ import annotations

import dataclasses
from fractions import Fraction

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.certificate import interval as interval_module
from idapbc_pin.certificate.chain_enclosure import ChainEnclosure
from idapbc_pin.certificate.enclosures import lqr_field, lqr_rate, quadratic_rate
from idapbc_pin.certificate.interval import Interval
from idapbc_pin.certificate.jet import Jet
from idapbc_pin.certificate.verified import verify_level
from idapbc_pin.control.baseline import LQRController

ROBOTS = ["pendubot", "cartpole", "furuta", "arm_passive_middle"]


def _enclosure(system) -> ChainEnclosure:
    return ChainEnclosure(system.plant.chain(), system.plant.damping)


def _boxes(system, rng, n, rel):
    lo, hi = system.domain
    x = rng.uniform(lo, hi, (n, system.n))
    w = rel * (hi - lo) * rng.random((n, system.n))
    return x, Interval(x - w, x + w), w


@pytest.mark.parametrize("name", ROBOTS)
def test_the_chain_enclosure_equals_pinocchio_at_points(name):
    system = ip.load_system(name)
    x = np.random.default_rng(0).uniform(*system.domain, (40, system.n))
    q, _ = system.split(x)
    enc = _enclosure(system)
    M, U = enc.mass_and_potential(Interval.point(q))
    f = enc(Interval.point(x))
    scale = 1.0 + np.abs(system.f(x))
    assert np.abs(M.mid - system.mass_matrix(q)).max() < 1e-12
    assert np.abs(U.mid - system.potential(q)).max() < 1e-12
    assert np.all(np.abs(f.mid - system.f(x)) < 1e-11 * scale)
    assert np.all(f.hi - f.lo < 1e-9 * scale)  # a point box gives a point, up to rounding


@pytest.mark.parametrize("name", ROBOTS[:3])
def test_random_boxes_hold_every_sampled_value_of_f_and_its_jacobian(name):
    system = ip.load_system(name)
    rng = np.random.default_rng(1)
    x, X, w = _boxes(system, rng, 60, 0.02)
    F = _enclosure(system)(Jet.variables(X))
    direct = _enclosure(system)(X)
    for _ in range(10):
        xs = x + w * rng.uniform(-1, 1, x.shape)
        xs[:5] = X.lo[:5]  # corners too
        f, J = system.f_and_df_dx(xs)
        assert np.all((direct.lo <= f) & (f <= direct.hi))
        assert np.all((F.val.lo <= f) & (f <= F.val.hi))
        # Pinocchio's ∂f/∂x carries central differences of its exact first derivatives (~1e-8)
        slack = 1e-6 * (1 + np.abs(J))
        assert np.all((F.grad.lo - slack <= J) & (J <= F.grad.hi + slack))
    assert np.isfinite(F.grad.lo).all() and np.median(F.val.hi - F.val.lo) < 1.0


def test_a_lost_term_in_the_chain_is_caught():
    """Without the joint damping, or without the armature, the enclosure misses sampled values."""
    system = ip.load_system("pendubot")
    rng = np.random.default_rng(2)
    x, X, w = _boxes(system, rng, 50, 0.01)
    chain = system.plant.chain()
    xs = x + w * rng.uniform(-1, 1, x.shape)
    f = system.f(xs)
    lost = ChainEnclosure(chain, np.zeros_like(system.plant.damping))(X)
    assert not np.all((lost.lo <= f) & (f <= lost.hi))
    rotor = ChainEnclosure(dataclasses.replace(chain, armature=chain.armature + 0.05), system.plant.damping)(X)
    assert not np.all((rotor.lo <= f) & (f <= rotor.hi))


def test_sums_and_products_round_outward_and_a_mutant_without_rounding_fails(monkeypatch):
    """Exact rational arithmetic (fractions) lies inside every rounded result; with the outward step
    removed, some results miss it."""
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=400), rng.normal(size=400) * 1e-3

    def misses():
        s, p = Interval.point(a) + Interval.point(b), Interval.point(a) * Interval.point(b)
        bad = 0
        for i in range(len(a)):
            es, ep = Fraction(a[i]) + Fraction(b[i]), Fraction(a[i]) * Fraction(b[i])
            bad += not (Fraction(s.lo[i]) <= es <= Fraction(s.hi[i])) or not (Fraction(p.lo[i]) <= ep <= Fraction(p.hi[i]))
        return bad

    assert misses() == 0
    monkeypatch.setattr(interval_module, "_down", lambda v: v)
    monkeypatch.setattr(interval_module, "_up", lambda v: v)
    assert misses() > 0


def test_a_jet_holds_its_functions_gradient_and_nested_its_hessian():
    rng = np.random.default_rng(4)
    N, n = 40, 3
    c, w = rng.normal(size=(N, n)), rng.uniform(0.01, 0.2, (N, n))
    X = Interval(c - w, c + w)
    W = rng.normal(size=(n, 4))

    def f(x):  # the same formula on intervals, jets and arrays
        lin = x @ W
        t = lin.tanh().sum(-1) if not isinstance(x, np.ndarray) else np.tanh(lin).sum(-1)
        if isinstance(x, np.ndarray):
            return t * np.cos(x[:, 0]) + np.sin(x[:, 1] * x[:, 2]) + 1 / (np.logaddexp(0, x[:, 2]) + 1)
        return t * x[:, 0].cos() + (x[:, 1] * x[:, 2]).sin() + (x[:, 2].softplus() + 1.0).reciprocal()

    J = f(Jet.variables(X))
    H = f(Jet.variables(Jet.variables(X)))
    h = 1e-4
    E = np.eye(n) * h
    for _ in range(20):
        xs = c + w * rng.uniform(-1, 1, (N, n))
        assert np.all((J.val.lo <= f(xs)) & (f(xs) <= J.val.hi))
        g = np.stack([(f(xs + E[i]) - f(xs - E[i])) / (2 * h) for i in range(n)], -1)
        assert np.all((J.grad.lo - 1e-6 <= g) & (g <= J.grad.hi + 1e-6))
        hess = np.stack([np.stack([(f(xs + E[i] + E[j]) - f(xs + E[i] - E[j]) - f(xs - E[i] + E[j]) + f(xs - E[i] - E[j])) / (4 * h * h)
                                   for j in range(n)], -1) for i in range(n)], -2)
        assert np.all((H.grad.grad.lo - 1e-4 <= hess) & (hess <= H.grad.grad.hi + 1e-4))
    # a kink (clip) gives the hull of its slopes, and refuses a second derivative
    K = Jet.variables(Interval(np.array([[-1.0], [0.5], [2.0]]), np.array([[-0.5], [1.5], [3.0]]))).clip(0.0, 1.0)
    assert np.allclose(K.grad.lo[:, 0, 0], [0.0, 0.0, 0.0], rtol=0, atol=1e-12)
    assert np.allclose(K.grad.hi[:, 0, 0], [0.0, 1.0, 0.0], rtol=0, atol=1e-12)
    with pytest.raises(NotImplementedError):
        Jet.variables(Jet.variables(X)).clip(0.0, 1.0)


def test_saturated_lqr_on_a_urdf_pendubot_is_verified_near_x_star_and_the_open_loop_is_refused():
    system = ip.load_system("pendubot")
    lqr = LQRController(system)
    x_star, S = np.asarray(system.x_star, float), lqr.S
    lo, hi = system.domain
    rate = lambda X: lqr_rate(system, lqr, S, system.effort, X)  # noqa: E731
    why, boxes = verify_level(rate, 2e-5, 1e-6, (lo, hi), (x_star, S), budget=20000)
    assert why is None and boxes > 0
    # u = u* (K = 0): the upright is unstable, so V = δᵀSδ rises near x*
    lqr.K = np.zeros_like(lqr.K)
    A, B = system.linearization()
    open_rate = lambda X: quadratic_rate(S, x_star, lambda Y: lqr_field(system, lqr, system.effort, Y), A, X)  # noqa: E731
    why, _ = verify_level(open_rate, 2e-5, 1e-6, (lo, hi), (x_star, S), budget=20000)
    assert why == "a state of the set outside the core where V̇ ≥ 0"


def test_a_core_proved_from_the_linearisation_holds_along_the_true_loop_and_the_open_loop_has_none():
    from idapbc_pin.certificate.core import proved_core
    from idapbc_pin.certificate.region import TrueLoop

    system = ip.load_system("pendubot")
    lqr = LQRController(system)
    x_star, S = np.asarray(system.x_star, float), lqr.S
    field = lambda X: lqr_field(system, lqr, system.effort, X)  # noqa: E731
    loop = TrueLoop(system, lqr, system.effort)
    A = loop.jacobian_at(x_star)
    c, rho = proved_core(S, A, x_star, field, 1.0)
    assert c > 0 and rho < np.sqrt(c / np.linalg.eigvalsh(S).max())
    # sampled states of the shell {ρ < ‖δ‖, V < c}: V̇ < 0 along the true loop (Pinocchio's f)
    rng = np.random.default_rng(5)
    d = rng.normal(size=(4000, system.n))
    d *= (np.sqrt(c / np.einsum("ni,ij,nj->n", d, S, d)) * rng.uniform(0.05, 1.0, len(d)))[:, None]
    rate = 2 * np.einsum("ni,ij,nj->n", d, S, loop(x_star + d))
    assert np.all(rate < 0)
    # the open loop (K = 0, A its own linearisation): its upright is unstable, no core
    lqr.K = np.zeros_like(lqr.K)
    open_loop = TrueLoop(system, lqr, system.effort)
    assert proved_core(S, open_loop.jacobian_at(x_star), x_star, field, 1.0, halvings=12) == (0.0, float("inf"))


def test_the_outer_laws_leave_the_learned_law_its_box_and_a_scaled_one_is_refused_inside_another():
    from idapbc_pin.certificate.enclosures import enclosable, networks_box
    from idapbc_pin.recovery.box_law import BoxFallback

    system = ip.load_system("pendubot")
    lqr = LQRController(system)
    half = 0.5 * (system.domain[1] - system.domain[0])
    plain = BoxFallback(lqr.K, lqr.u_star, system.x_star, half, system.angle_mask)
    scaled = dataclasses.replace(plain, inside_gain=3.0)
    assert np.array_equal(networks_box(plain), half) and enclosable(system, scaled) is None  # `_outer` scales it

    class KeptBox:  # a kept-box law (box and law) around the run's own outer law
        def __init__(self, inner):
            self.box, self.law, self.inner = 0.5 * half, None, inner

    assert np.array_equal(networks_box(KeptBox(plain)), 0.5 * half)
    assert "scaled inside gain" in enclosable(system, KeptBox(scaled))

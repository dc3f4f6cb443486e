"""Interval arithmetic and the verified certified set: every enclosure holds the values it encloses,
a loop with a known rising region is verified below it and refused above it, and `certify` proves
the mass-spring-damper's sets where the loop has an interval form."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import idapbc_pin as ip
from idapbc_pin.certificate.certify import certify
from idapbc_pin.certificate.enclosures import FlowEnclosure, enclosable, flow_rate, lqr_rate, plant_enclosure
from idapbc_pin.certificate.interval import Interval
from idapbc_pin.certificate.region import TrueLoop
from idapbc_pin.certificate.verified import verify_level
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.control.controller import Controller
from idapbc_pin.control.nets import build_nets
from idapbc_pin.recovery.box_law import BoxFallback


def _boxes(rng, n_boxes, lo, hi, width):
    """Random boxes [x, x + w] with x in [lo, hi] and w up to `width` times the range."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    x = lo + (hi - lo) * rng.random((n_boxes, lo.size))
    w = width * (hi - lo) * rng.random((n_boxes, lo.size)) ** 2
    return Interval(x, x + w)


def _inside(box: Interval, k: int, rng) -> np.ndarray:
    """(N, k, n) uniform points of each box, its corners among them."""
    t = rng.random((box.shape[0], k, box.shape[1]))
    t[:, 0], t[:, 1] = 0.0, 1.0
    return box.lo[:, None] + (box.hi - box.lo)[:, None] * t


def _holds(enclosure: Interval, values: np.ndarray) -> bool:
    """values (N, k, ...) lie in the enclosure (N, ...) for every k."""
    return bool(np.all(enclosure.lo[:, None] <= values) and np.all(values <= enclosure.hi[:, None]))


# ====================================================================== interval arithmetic
UNARY = {
    "exp": (np.exp, (-30, 30)),
    "tanh": (np.tanh, (-8, 8)),
    "softplus": (lambda a: np.logaddexp(0, a), (-40, 40)),
    "expit": (lambda a: 1 / (1 + np.exp(-a)), (-40, 40)),
    "square": (np.square, (-3, 3)),
    "abs": (np.abs, (-3, 3)),
    "cos": (np.cos, (-10, 10)),
    "sin": (np.sin, (-10, 10)),
    "reciprocal": (lambda a: 1 / a, (0.01, 5)),
    "ratio_one_plus": (lambda s: s / (1 + s), (-0.5, 5)),
    "psi": (lambda s: s - np.log1p(s), (-0.5, 5)),
}


@pytest.mark.parametrize("name", sorted(UNARY))
def test_each_function_of_an_interval_holds_its_values_on_the_interval(name):
    fn, (a, b) = UNARY[name]
    rng = np.random.default_rng(0)
    box = _boxes(rng, 4000, [a], [b], 0.5)
    if name in ("reciprocal", "ratio_one_plus", "psi"):
        box = box.meet(a, b)
    pts = _inside(box, 64, rng)
    assert _holds(getattr(box, name)(), fn(pts))
    point = getattr(Interval.point(box.lo), name)()  # a point interval stays a few ulps wide
    assert np.all(point.hi - point.lo <= 1e-12 * (1 + np.abs(point.lo)))


def test_arithmetic_sums_and_products_with_a_matrix_hold_their_values():
    rng = np.random.default_rng(1)
    A, B = _boxes(rng, 3000, [-2] * 5, [2] * 5, 0.3), _boxes(rng, 3000, [-2] * 5, [2] * 5, 0.3)
    W = rng.standard_normal((5, 7))
    t = rng.random((3000, 32, 1))
    pa, pb = A.lo[:, None] + (A.hi - A.lo)[:, None] * t, B.lo[:, None] + (B.hi - B.lo)[:, None] * rng.random((3000, 32, 1))
    assert _holds(A + B, pa + pb) and _holds(A - B, pa - pb) and _holds(A * B, pa * pb)
    assert _holds((A * B).sum(-1), (pa * pb).sum(-1))
    assert _holds(A @ W, pa @ W) and _holds(A.clip(-1, 0.5), np.clip(pa, -1, 0.5))
    assert _holds(A * 3.0 - 1.0, pa * 3.0 - 1.0)
    assert np.all(((A @ W).hi - (A @ W).lo) <= (A.hi - A.lo) @ np.abs(W) * (1 + 1e-12) + 1e-12)  # the hull, no wider
    loose = Interval(np.array([-2.0]), np.array([1.0]))  # an enclosure of s that reaches −1: unbounded, never narrow
    assert loose.ratio_one_plus().lo[0] == -np.inf and loose.psi().hi[0] == np.inf and loose.psi().lo[0] == 0.0
    with pytest.raises(ValueError, match="reaches 0"):
        Interval(np.array([-1.0]), np.array([1.0])).reciprocal()


# ====================================================================== enclosures of the loop
@pytest.mark.parametrize("name", ["paper_mass_spring_damper", "paper_cartpole", "paper_double_pendulum"])
def test_the_closed_form_plants_enclosures_hold_f_on_boxes(name):
    system = ip.load_system(name)
    rng = np.random.default_rng(2)
    box = _boxes(rng, 2000, *system.domain, 0.05)
    pts = _inside(box, 32, rng)
    f = system.f(pts.reshape(-1, system.n)).reshape(pts.shape)
    assert _holds(plant_enclosure(system, box), f)
    assert enclosable(system) is None
    assert enclosable(ip.load_system("pendubot")) is None  # a URDF chain: `chain_enclosure`
    assert "no interval form of the outer law" in enclosable(system, fallback=object())


def _random_controller(name, fallback=None):
    system = ip.load_system(name)
    torch.manual_seed(0)
    nets = build_nets(system, ip.TrainConfig(seed=0, dtype="float64", width=16, depth=2))
    with torch.no_grad():
        for p in nets.parameters():  # away from the initial (partly zero) output layers
            p.add_(0.3 * torch.randn_like(p))
    return Controller(system, nets, fallback)


@pytest.mark.parametrize("case", ["msd", "msd saturated", "cartpole with its outer law"])
def test_the_learned_loops_enclosure_holds_H_d_its_gradient_and_its_rate(case):
    name = "paper_cartpole" if "cartpole" in case else "paper_mass_spring_damper"
    system = ip.load_system(name)
    fallback = None
    if "outer" in case:
        lqr = LQRController(system)
        half = 0.5 * (system.domain[1] - system.domain[0])
        fallback = BoxFallback(30 * lqr.K, lqr.u_star, system.x_star, half, system.angle_mask, gain=30.0)  # its law dominates across the faces
    ctrl = _random_controller(name, fallback)
    bound = np.array([0.4]) if "saturated" in case else None
    lo, hi = system.domain
    rng = np.random.default_rng(3)
    box = _boxes(rng, 600, 1.5 * lo, 1.5 * hi, 0.04)  # a third of them beyond the training box, some across its faces
    pts = _inside(box, 24, rng).reshape(-1, system.n)
    H, grad, Vd, _ = flow_rate(system, FlowEnclosure(ctrl.flow()), ctrl._g_pinv, bound, fallback, box)
    rate = np.einsum("ni,ni->n", ctrl.grad_H_d(pts), TrueLoop(system, ctrl, bound)(pts))
    shape = (box.shape[0], 24)
    assert _holds(H, ctrl.H_d(pts).reshape(shape))
    assert _holds(grad, ctrl.grad_H_d(pts).reshape(shape + (system.n,)))
    assert _holds(Vd, rate.reshape(shape))
    if bound is not None:
        assert np.any(np.abs(ctrl(pts)) > bound)  # the clip is exercised
    # where flagged, H_d's tangent plane at a state bounds it from below, here across each box
    m = box.mid
    Hm, Gm, _, tangent = flow_rate(system, FlowEnclosure(ctrl.flow()), ctrl._g_pinv, bound, fallback, Interval.point(m))
    plane = Hm.lo[:, None] + np.einsum("ni,nki->nk", Gm.mid, pts.reshape(shape + (system.n,)) - m[:, None])
    assert tangent.mean() > 0.9
    assert np.all((ctrl.H_d(pts).reshape(shape) >= plane - 1e-9 * (1 + np.abs(plane)))[tangent])


# ====================================================================== the verdict
class _Bump:
    """V = ‖x‖² along ẋ = −x + k·exp(−‖x − x₀‖²/(2σ²))·x, as interval enclosures: V̇ = 2‖x‖²(k·e − 1)
    rises exactly where k·e > 1, a disc of radius σ√(2 ln k) about x₀ whose lowest V is known."""

    def __init__(self, k=3.0, x0=(0.6, 0.0), sigma=0.04):
        self.k, self.x0, self.sigma = k, np.asarray(x0), sigma
        r = sigma * np.sqrt(2 * np.log(k))
        self.lowest_rising = (np.linalg.norm(self.x0) - r) ** 2

    def __call__(self, X: Interval):
        V = X.square().sum(-1)
        e = ((X - self.x0).square().sum(-1) * (-1 / (2 * self.sigma**2))).exp()
        return V, X * 2.0, V * 2.0 * (e * self.k - 1.0), np.ones(X.shape[0], bool)


def test_a_loop_is_verified_below_its_rising_region_and_refused_above_it():
    bump = _Bump()
    vbox = (np.full(2, -1.0), np.full(2, 1.0))
    floor = (np.zeros(2), np.eye(2))
    core = 1e-3
    why, boxes = verify_level(bump, 0.98 * bump.lowest_rising, core, vbox, floor)
    assert why is None and boxes > 0
    why, _ = verify_level(bump, 1.02 * bump.lowest_rising, core, vbox, floor)
    assert why == "a state of the set outside the core where V̇ ≥ 0"
    why, _ = verify_level(bump, 0.98 * bump.lowest_rising, core, (np.full(2, -0.3), np.full(2, 0.3)), floor)
    assert why == "the set reaches a face of the verification box"
    why, _ = verify_level(bump, 0.98 * bump.lowest_rising, core, vbox, floor, budget=100)
    assert why == "more than 100 boxes"


def test_lqr_on_the_open_loop_mass_spring_damper_is_refused():
    """u = u* alone (K = 0): the friction term −b·p²(1 + |p|) pushes p down on both sides, so V rises."""
    system = ip.load_system("paper_mass_spring_damper")
    lqr = LQRController(system)
    lqr.K = np.zeros_like(lqr.K)
    x_star = np.asarray(system.x_star)
    why, _ = verify_level(lambda X: lqr_rate(system, lqr, lqr.S, None, X), 0.5, 1e-4, ((x_star - 4), (x_star + 4)), (x_star, lqr.S))
    assert why == "a state of the set outside the core where V̇ ≥ 0"


def test_certify_verifies_the_mass_spring_dampers_sets_and_says_why_not_elsewhere(tmp_path):
    torch.set_num_threads(1)
    system = ip.load_system("paper_mass_spring_damper")
    run = ip.train(system, ip.TrainConfig(epochs=150, width=16, depth=2, samples=64), out=tmp_path, progress=False)
    cert = certify(run, n=2000, settle=0, invariant=0)
    v, b = cert.sublevel.verified, cert.baseline.sublevel.verified
    assert v.passed and b.passed, cert.table()
    assert cert.sublevel.core < v.c <= cert.sublevel.c and cert.baseline.sublevel.core < b.c <= cert.baseline.sublevel.c
    assert v.covered_fraction > 0.5 and v.boxes > 0
    saved = json.loads((run.path / "certificate.json").read_text())
    assert saved["sublevel"]["verified"]["passed"] is True and saved["baseline"]["sublevel"]["verified"]["c"] == pytest.approx(b.c)
    assert "verified by interval arithmetic" in cert.table()
    never = certify(run, n=2000, settle=0, invariant=0, write=False, verify="never")
    assert not never.sublevel.verified.passed and never.sublevel.verified.reason == "not asked for"
    with pytest.raises(ip.IdapbcError, match="verify must be"):
        certify(run, n=2000, settle=0, invariant=0, write=False, verify="sometimes")


def test_a_free_form_set_stopped_by_a_rising_state_is_verified_a_little_below_it(tmp_path):
    """The free form (H_d = D + ε‖δ‖², no quadratic floor): its sampled set ends at a state where Ḣ_d ≥ 0,
    so the level just below it cannot be decided within its share of the boxes, and a lower one is proved."""
    torch.set_num_threads(1)
    system = ip.load_system("paper_mass_spring_damper")
    config = ip.TrainConfig(epochs=300, width=16, depth=2, samples=64, form="free")
    run = ip.train(system, config, out=tmp_path, progress=False)
    cert = certify(run, n=2000, settle=0, invariant=0, write=False)
    assert run.controller.flow().P is None and cert.sublevel.c < cert.sublevel.c_boundary  # stopped by a violation
    v = cert.sublevel.verified
    assert v.passed and cert.sublevel.core < v.c < 0.999 * cert.sublevel.c, cert.table()

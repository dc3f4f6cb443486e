"""The certificate checks the paper's conditions where they hold and fails them where they do not.

Stand-in controllers with hand-built (H_d, J_d, R_d) expose the controller interface
(`system`, `__call__`, `H_d`, `grad_H_d`, `hess_H_d`, `J_d`, `R_d`):

* exact IDA-PBC solutions (μ ≡ 0) on fully actuated systems: the paper's mass-spring-damper with
  a quadratic H_d and constant J_d, R_d ≻ 0 from the LQR loop, and the paper's double pendulum with
  H_d = ½pᵀM⁻¹p + ½K_p‖q‖² + ε qᵀp and a state-dependent (J_d, R_d = r(x)I ≻ 0);
* a deliberately broken one (cartpole, R_d = 1e-3 I, J_d = 0, μ large).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field

import numpy as np
import pytest
import scipy.linalg
import torch

import idapbc_pin as ip
from idapbc_pin.certificate.certify import certify
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.certificate.result import LABEL, Certificate
from idapbc_pin.certificate.terms import closed_loop_terms


# ====================================================================== stand-in controllers
class QuadraticIdaPbc:
    """H_d = ½δᵀPδ, constant J_d and R_d; u = (gᵀg)⁻¹gᵀ(f̃_d − f) (eq. tilde_u)."""

    def __init__(self, system, P, J, R):
        self.system, self.P, self.J, self.R = system, np.asarray(P, float), np.asarray(J, float), np.asarray(R, float)

    def _d(self, x):
        return np.atleast_2d(np.asarray(x, float)) - self.system.x_star

    def H_d(self, x):
        d = self._d(x)
        return 0.5 * np.einsum("ni,ij,nj->n", d, self.P, d)

    def grad_H_d(self, x):
        return self._d(x) @ self.P

    def hess_H_d(self, x):
        return np.broadcast_to(self.P, (self._d(x).shape[0],) + self.P.shape).copy()

    def J_d(self, x):
        return np.broadcast_to(self.J, (self._d(x).shape[0],) + self.J.shape).copy()

    def R_d(self, x):
        return np.broadcast_to(self.R, (self._d(x).shape[0],) + self.R.shape).copy()

    def __call__(self, x):
        x = np.atleast_2d(np.asarray(x, float))
        f_d = self.grad_H_d(x) @ (self.J - self.R).T
        g = self.system.g(x)
        return np.einsum("nim,ni->nm", g, f_d - self.system.f(x))  # gᵀg = I here


def lqr_ida_pbc(system):
    """The exact linear IDA-PBC of the LQR loop: P = S (Riccati), (J − R) = A_cl P⁻¹ (DESIGN §2)."""
    A, B = system.linearization()
    S = scipy.linalg.solve_continuous_are(A, B, np.eye(A.shape[0]), np.eye(B.shape[1]))
    A_cl = A - B @ (B.T @ S)
    Z = A_cl @ np.linalg.inv(S)
    return QuadraticIdaPbc(system, S, 0.5 * (Z - Z.T), -0.5 * (Z + Z.T))


class ExactDoublePendulum:
    """Exact IDA-PBC of the paper's double pendulum with R_d ≻ 0 (μ ≡ 0 to rounding).

    H_d = ½pᵀM(q)⁻¹p + ½K_p‖q‖² + ε qᵀp (convex on the domain for these gains, checked by the
    certificate), f̃_d = (v, −∂H_d/∂q − K_v ∂H_d/∂p): the unactuated rows q̇ = v match exactly.
    With y = ∇H_d and r = −yᵀf̃_d/‖y‖² > 0, f̃_d = (J_d − r I) y for the skew
    J_d = (a yᵀ − y aᵀ)/‖y‖², a = f̃_d + r y. M(q) is the paper's formula, written here in torch.
    """

    def __init__(self, system, Kp=20.0, Kv=2.0, eps=0.3):
        self.system, self.Kp, self.Kv, self.eps = system, Kp, Kv, eps

    @staticmethod
    def _M(q):
        c = 0.5 * torch.cos(q[:, 0] - q[:, 1])
        two, one = torch.full_like(c, 2.0), torch.ones_like(c)
        return torch.stack([torch.stack([two, c], -1), torch.stack([c, one], -1)], -2)

    def _H(self, x):
        q, p = x[:, :2], x[:, 2:]
        v = torch.linalg.solve(self._M(q), p.unsqueeze(-1)).squeeze(-1)
        return 0.5 * (p * v).sum(1) + 0.5 * self.Kp * (q * q).sum(1) + self.eps * (q * p).sum(1)

    def _grad(self, x, create_graph=False):
        xt = torch.as_tensor(np.atleast_2d(np.asarray(x, float))).requires_grad_(True)
        return xt, torch.autograd.grad(self._H(xt).sum(), xt, create_graph=create_graph)[0]

    def H_d(self, x):
        with torch.no_grad():
            return self._H(torch.as_tensor(np.atleast_2d(np.asarray(x, float)))).numpy()

    def grad_H_d(self, x):
        return self._grad(x)[1].detach().numpy()

    def hess_H_d(self, x):
        xt, g = self._grad(x, True)
        return torch.stack([torch.autograd.grad(g[:, i].sum(), xt, retain_graph=True)[0] for i in range(4)], 1).numpy()

    def f_d(self, x):
        x = np.atleast_2d(x)
        y = self.grad_H_d(x)
        v = np.linalg.solve(self.system.mass_matrix(x[:, :2]), x[:, 2:, None])[..., 0]
        return np.concatenate([v, -y[:, :2] - self.Kv * y[:, 2:]], axis=1)

    def _JR(self, x):
        x = np.atleast_2d(x)
        y, fd = self.grad_H_d(x), self.f_d(x)
        y2 = (y * y).sum(1)
        r = -(y * fd).sum(1) / y2
        a = fd + r[:, None] * y
        J = (a[:, :, None] * y[:, None, :] - y[:, :, None] * a[:, None, :]) / y2[:, None, None]
        return J, r[:, None, None] * np.eye(4)

    def J_d(self, x):
        return self._JR(x)[0]

    def R_d(self, x):
        return self._JR(x)[1]

    def __call__(self, x):
        x = np.atleast_2d(x)
        return (self.f_d(x) - self.system.f(x))[:, 2:]


def cartpole_broken():
    """Underactuated cartpole, H_d = ½δᵀPδ (the LQR Riccati P), J_d = 0, R_d = 1e-3 I: μ is large."""
    system = ip.load_system("paper_cartpole")
    good = lqr_ida_pbc(system)
    return QuadraticIdaPbc(system, good.P, np.zeros((4, 4)), 1e-3 * np.eye(4))


def H_dot_fd(ctrl, x, h=1e-6):
    """Ḣ_d along the true closed loop f + g u, by a central difference of H_d along the flow."""
    system = ctrl.system
    xdot = system.f(x) + np.einsum("nim,nm->ni", system.g(x), ctrl(x))
    return (ctrl.H_d(x + h * xdot) - ctrl.H_d(x - h * xdot)) / (2 * h)


def face_minimum_grid(ctrl, k=25):
    """min of H_d over a k^(n-1) grid on every face of the domain box (an upper bound of the true min)."""
    lo, hi = ctrl.system.domain
    n = lo.size
    best = np.inf
    for i in range(n):
        axes = [np.linspace(lo[j], hi[j], k) for j in range(n) if j != i]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, n - 1)
        for side in (lo[i], hi[i]):
            x = np.insert(grid, i, side, axis=1)
            best = min(best, float(ctrl.H_d(x).min()))
    return best


# ====================================================================== exact solutions
def test_exact_linear_ida_pbc_on_mass_spring_damper_is_certified_on_the_whole_domain():
    system = ip.load_system("paper_mass_spring_damper")  # q̇ = p: the unactuated row is linear
    ctrl = lqr_ida_pbc(system)
    cert = certify(ctrl, n=4000, settle=1, settle_T=8.0, write=False, scale=1.0, invariant=0)
    assert cert.max_mu < 1e-12  # μ ≡ 0: an exact solution of the matching equation
    assert cert.dissipation_everywhere.fraction_satisfied == 1.0 and cert.dissipation_everywhere.worst_margin > 0
    assert cert.local_stability.max_real < 0 and cert.local_stability.source == "finite differences"
    lam = np.linalg.eigvals((ctrl.J - ctrl.R) @ ctrl.P)  # the closed loop is exactly f̃_d = (J − R)Pδ
    assert cert.local_stability.max_real == pytest.approx(np.max(lam.real), rel=1e-5)
    assert cert.sublevel.n_violations == 0 and cert.sublevel.n_counterexamples == 0
    # min of ½δᵀPδ on the face δ_i = a is a²/(2 (P⁻¹)_ii), at δ = a P⁻¹e_i/(P⁻¹)_ii (inside the face here)
    lo, hi = system.domain
    Pinv = np.linalg.inv(ctrl.P)
    candidates = []
    for i in range(2):
        for a in (lo[i] - system.x_star[i], hi[i] - system.x_star[i]):
            d = a * Pinv[:, i] / Pinv[i, i]
            assert np.all(system.x_star + d >= lo - 1e-12) and np.all(system.x_star + d <= hi + 1e-12)
            candidates.append(a * a / (2 * Pinv[i, i]))
    c_exact = min(candidates)
    assert cert.sublevel.c == pytest.approx(c_exact, rel=1e-6)
    # covered share = area of the ellipse {δᵀPδ < 2c} over the box area (the ellipse is inside the box)
    area = np.pi * 2 * c_exact / np.sqrt(np.linalg.det(ctrl.P))
    assert cert.sublevel.covered_fraction == pytest.approx(area / np.prod(hi - lo), abs=0.02)
    assert cert.certified, cert.table()


def test_exact_ida_pbc_on_the_fully_actuated_double_pendulum_is_certified():
    system = ip.load_system("paper_double_pendulum")
    ctrl = ExactDoublePendulum(system)
    # 10 s, still half the DESIGN's 20 s: after 6 s its slow mode leaves a half-box start at |p| ≈ 0.05, the
    # settle test's own edge, on either side of it depending on how the law is sampled
    cert = certify(ctrl, n=3000, n_hessian=500, settle=1, settle_T=10.0, write=False, scale=1.0, invariant=0)
    assert cert.max_mu < 1e-12
    assert cert.structural.min_eig_R > 0 and cert.structural.min_eig_hessian > 0
    assert cert.structural.max_J_skew_error == 0.0
    assert cert.dissipation_everywhere.fraction_satisfied == 1.0
    assert cert.local_stability.max_real < 0
    assert cert.max_hdot_identity_error < 1e-12  # Ḣ_d = −(∇H_dᵀR_d∇H_d − ∇H_dᵀξ) (Proposition 1)
    # no sample violates Ḣ_d < 0, so the sublevel set is bounded by the box faces only
    assert cert.sublevel.n_violations == 0 and cert.sublevel.n_counterexamples == 0
    grid_min = face_minimum_grid(ctrl, k=13)
    assert cert.sublevel.c == cert.sublevel.c_boundary
    assert grid_min * 0.97 <= cert.sublevel.c <= grid_min * (1 + 1e-9)
    x = np.random.default_rng(7).uniform(*system.domain, size=(20000, 4))
    assert cert.sublevel.covered_fraction == pytest.approx(np.mean(ctrl.H_d(x) < cert.sublevel.c), abs=0.01)
    assert cert.equilibrium.n_settled == 2 and cert.equilibrium.offset < 1e-2
    assert cert.certified, cert.table()


def test_true_loop_energy_rate_is_minus_the_dissipation_margin():
    """Ḣ_d by finite differences along f + g u equals −(∇H_dᵀR_d∇H_d − ∇H_dᵀξ), with ξ the
    perturbation of the true closed loop ẋ = f̃_d + ξ (Proposition 1)."""
    ctrl = cartpole_broken()
    x = np.random.default_rng(3).uniform(*ctrl.system.domain, size=(200, 4))
    terms = closed_loop_terms(ctrl, x)
    fd = H_dot_fd(ctrl, x)
    np.testing.assert_allclose(terms.H_dot, fd, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(terms.H_dot, -terms.margin, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(terms.f_d + terms.xi, terms.f + np.einsum("nim,nm->ni", ctrl.system.g(x), terms.u), atol=1e-12)


# ====================================================================== broken
def test_too_little_damping_fails_the_dissipation_check_where_it_should():
    ctrl = cartpole_broken()
    cert = certify(ctrl, n=3000, settle=0, write=False, invariant=0)
    d = cert.dissipation_everywhere
    assert 0 < d.fraction_satisfied < 1 and d.worst_margin < 0
    assert cert.max_mu > 1.0
    # the worst state really has Ḣ_d > 0 along the true closed loop
    assert H_dot_fd(ctrl, np.array([d.worst_state]))[0] > 0
    # and the violations are exactly the samples where the energy grows
    x = np.random.default_rng(0).uniform(*ctrl.system.domain, size=(3000, 4))
    terms = closed_loop_terms(ctrl, x)
    rate = H_dot_fd(ctrl, x)
    clear = np.abs(rate) > 1e-6
    assert np.array_equal((terms.margin > 0)[clear], (rate < 0)[clear])
    assert d.fraction_satisfied == pytest.approx(np.mean(rate < 0), abs=2e-3)
    assert cert.sublevel.n_violations > 0 and cert.sublevel.c_violation < cert.sublevel.c_boundary
    assert not cert.certified
    names = {name: ok for name, ok, _ in cert.checks()}
    assert names["J_d skew-symmetric"] and names["R_d positive definite"]
    assert not names["dissipation everywhere (ε = 0)"]
    assert "FAIL" in cert.table()


# ====================================================================== a trained run
@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    torch.set_num_threads(1)
    system = ip.load_system("paper_cartpole")
    return ip.train(system, ip.TrainConfig(epochs=20, width=16, depth=2, samples=64), out=tmp_path_factory.mktemp("runs"), progress=False)


def test_certify_a_run_writes_certificate_json(tiny_run):
    cert = certify(tiny_run.path, n=2000, n_hessian=200, settle=1, settle_T=2.0, invariant=0)
    assert isinstance(cert, Certificate) and cert.label == LABEL
    data = json.loads((tiny_run.path / "certificate.json").read_text())
    assert data["label"] == "sampled certificate, not a proof"
    assert data["epsilon"] == pytest.approx(tiny_run.summary["epsilon"])
    assert data["n_samples"] == 2000 and {c["name"] for c in data["checks"]} >= {"J_d skew-symmetric", "x* locally exponentially stable"}
    assert not list(tiny_run.path.glob("*.tmp"))
    # structure by construction (anchored networks), eigenvalues as the trainer reported them
    assert cert.structural.max_J_skew_error == 0.0 and cert.structural.min_eig_R > 0
    assert cert.structural.H_at_target == 0.0 and cert.structural.grad_norm_at_target == 0.0
    assert cert.structural.hessian_source == "autograd"
    expected = max(re for re, _ in tiny_run.summary["eigenvalues_at_target"])
    assert cert.local_stability.max_real == pytest.approx(expected, rel=1e-6)
    assert cert.max_hdot_identity_error < 1e-4  # float32 networks
    assert 0 < cert.inside_fraction < 1
    assert "sampled certificate, not a proof" in cert.table()


def test_certify_rejects_bad_input(tiny_run, tmp_path):
    with pytest.raises(ip.IdapbcError):
        certify(tmp_path)  # not a run directory
    with pytest.raises(ip.IdapbcError):
        certify(object())
    with pytest.raises(ip.IdapbcError):
        certify(tiny_run, n=4)
    with pytest.raises(ip.IdapbcError):
        certify(tiny_run, epsilon=-1.0)


# ====================================================================== torque limits and the LQR baseline
@dataclass(frozen=True)
class LinearPlant:
    """q̇ = p, ṗ = a q − c p + u (unit mass, a > 0: unstable), duck-typed; `effort` None: unlimited."""

    a: float = 1.0
    c: float = 0.5
    effort: object = None
    name: str = "linear_plant"
    nq: int = 1
    n: int = 2
    m: int = 1
    x_star: np.ndarray = field(default_factory=lambda: np.zeros(2))
    angle_mask: np.ndarray = field(default_factory=lambda: np.zeros(2, bool))
    domain: tuple = (np.array([-1.0, -1.5]), np.array([1.0, 1.5]))

    @property
    def A(self):
        return np.array([[0.0, 1.0], [self.a, -self.c]])

    def f(self, x):
        return np.asarray(x, float) @ self.A.T  # (N, n) or (n,), like System.f

    def g(self, x):
        return np.broadcast_to(np.array([[0.0], [1.0]]), (np.atleast_2d(x).shape[0], 2, 1)).copy()

    def g_perp(self, x):
        return np.broadcast_to(np.array([[1.0, 0.0]]), (np.atleast_2d(x).shape[0], 1, 2)).copy()

    def G(self, x):
        return np.broadcast_to(np.array([[0.0, 1.0], [1.0, 0.0]]), (np.atleast_2d(x).shape[0], 2, 2)).copy()

    def linearization(self):
        return self.A, np.array([[0.0], [1.0]])


def test_lqr_certificate_of_a_linear_plant_is_the_largest_ellipse_in_the_box():
    """Without limits V̇ = −δᵀ(Q + KᵀRK)δ < 0 everywhere, so LQR's certified set {δᵀSδ < c} is the
    largest ellipse inside the box: c = min over faces δ_i = a of a²/(S⁻¹)_ii."""
    system = LinearPlant()
    cert = certify(lqr_ida_pbc(system), n=4000, settle=0, write=False, scale=1.0, invariant=0)
    base = cert.baseline
    assert base is not None and base.controller == "LQR" and not base.limits_applied
    S = LQRController(system).S
    Sinv = np.linalg.inv(S)
    lo, hi = system.domain
    candidates = []
    for i in range(2):
        for a in (lo[i], hi[i]):
            d = a * Sinv[:, i] / Sinv[i, i]  # the minimiser on that face, inside it here
            assert np.all(d >= lo - 1e-12) and np.all(d <= hi + 1e-12)
            candidates.append(a * a / Sinv[i, i])
    c_exact = min(candidates)
    assert base.sublevel.n_violations == 0 and base.sublevel.c_violation == np.inf
    assert base.sublevel.c == pytest.approx(c_exact, rel=1e-6)
    area = np.pi * c_exact / np.sqrt(np.linalg.det(S))
    assert base.sublevel.covered_fraction == pytest.approx(area / np.prod(hi - lo), abs=0.01)
    assert base.sublevel.confidence.passed and base.sublevel.confidence.samples == 14915  # ⌈ln(3/1e-6)/1e-3⌉
    # the exact linear IDA-PBC of the same loop has H_d = ½δᵀSδ: the same set, the same share
    assert cert.sublevel.c == pytest.approx(c_exact / 2, rel=1e-6)
    assert cert.sublevel.covered_fraction == pytest.approx(base.sublevel.covered_fraction, abs=0.01)
    data = cert.to_dict()
    assert set(data["baseline"]["sublevel"]) >= {"c", "covered_fraction", "n_violations", "c_boundary", "confidence"}
    assert data["verification_box"] == {"lo": [-1.0, -1.5], "hi": [1.0, 1.5]}
    assert set(data["sublevel"]["confidence"]) >= {"epsilon", "beta", "samples"}
    assert data["baseline"]["sublevel"]["covered_fraction"] == pytest.approx(base.sublevel.covered_fraction)
    assert data["limits"]["applied"] is False and data["limits"]["bound"] is None
    text = cert.table()
    assert "LQR {δᵀSδ <" in text and "certified share" in text and "torque limits: none" in text


def test_limits_certify_the_saturated_loop():
    """With |u| ≤ 0.5 the unstable plant's loop is f + g·sat(u): Ḣ_d and V̇ are taken along it,
    sets shrink, and limits=False gives back the unlimited numbers exactly."""
    free_plant, limited_plant = LinearPlant(), LinearPlant(effort=np.array([0.5]))
    ctrl = lqr_ida_pbc(limited_plant)
    x = np.random.default_rng(5).uniform(*limited_plant.domain, size=(300, 2))
    terms = closed_loop_terms(ctrl, x, bound=np.array([0.5]))
    u_sat = np.clip(ctrl(x), -0.5, 0.5)
    x_dot = limited_plant.f(x) + np.einsum("nim,nm->ni", limited_plant.g(x), u_sat)
    h = 1e-6
    fd = (ctrl.H_d(x + h * x_dot) - ctrl.H_d(x - h * x_dot)) / (2 * h)
    np.testing.assert_allclose(terms.H_dot, fd, rtol=1e-6, atol=1e-8)
    np.testing.assert_array_equal(terms.saturated, np.abs(ctrl(x)[:, 0]) > 0.5)
    np.testing.assert_allclose(terms.H_dot_law, -terms.margin, rtol=1e-10, atol=1e-10)  # Proposition 1: the law itself

    limited = certify(ctrl, n=3000, settle=0, write=False, invariant=0)
    lifted = certify(ctrl, n=3000, settle=0, write=False, limits=False, invariant=0)
    unlimited = certify(lqr_ida_pbc(free_plant), n=3000, settle=0, write=False, invariant=0)
    assert limited.limits["applied"] and limited.limits["bound"] == [0.5] and limited.saturated_fraction > 0.2
    assert limited.baseline.limits_applied
    assert limited.sublevel.c_violation < np.inf and limited.baseline.sublevel.c_violation < np.inf
    assert limited.sublevel.covered_fraction < unlimited.sublevel.covered_fraction
    assert limited.baseline.sublevel.covered_fraction < unlimited.baseline.sublevel.covered_fraction
    assert lifted.limits["lifted"] and lifted.saturated_fraction == 0.0
    assert dataclasses.asdict(lifted.sublevel) == dataclasses.asdict(unlimited.sublevel)
    assert dataclasses.asdict(lifted.baseline.sublevel) == dataclasses.asdict(unlimited.baseline.sublevel)
    assert "torque limits applied: |u| ≤ 0.5" in limited.table() and "lifted" in lifted.table()


def test_certificate_json_of_a_run_has_the_baseline(tiny_run):
    certify(tiny_run.path, n=1000, n_hessian=100, settle=0, invariant=20)
    data = json.loads((tiny_run.path / "certificate.json").read_text())
    assert 0.0 <= data["baseline"]["sublevel"]["covered_fraction"] <= 1.0
    assert data["baseline"]["controller"] == "LQR" and data["limits"]["applied"] is False
    assert set(data["invariant_share"]) == {"NIDA-PBC", "LQR"}


def test_certify_in_two_processes_gives_the_certificate_of_one(tiny_run):
    """The simulations (invariant shares, settling) run beside the sampled checks: the count of
    processes changes the time, never a figure."""
    kw = dict(n=500, n_hessian=50, settle=1, settle_T=3.0, invariant=6, write=False)
    one, two = certify(tiny_run, workers=1, **kw).to_dict(), certify(tiny_run, workers=2, **kw).to_dict()
    for d in (one, two):
        d.pop("wall_time")
    assert one == two and set(one["invariant_share"]) == {"NIDA-PBC", "LQR"}

"""The paper's conditions checked numerically on dense samples: a *sampled* certificate, not a proof.

For a trained run (or any object with the controller interface, see below) `certify` checks, on
`n` uniform samples of the training box X (DESIGN §4, "Certificate"):

* **structural conditions** (i)–(iii) of Proposition 3 (label ``prop:vanishing_mu``):
  J_d + J_dᵀ = 0, R_d ≻ 0, ∇²H_d ≻ 0 (on a subsample), H_d(x*) = 0, ∇H_d(x*) = 0, H_d > 0 off x*;
* the **dissipation inequality** of Theorem 2 (eq. ``damping_assign_relax_tilde``)

      ∇H_dᵀ R_d ∇H_d  >  ∇H_dᵀ ξ,    ξ = G⁻¹ (0; g⊥(f − f̃_d))   (sign: see below),

  on the samples outside H_ε = {H_d < ε} (the dissipation set D), with ε the run's estimate, and
  on every sample (ε = 0); the fraction satisfied and the worst margin;
* the size of E = H_ε (share of the domain samples inside);
* **local exponential stability** of x*: eigenvalues of the Jacobian of the true closed loop
  f + g u at x*;
* the **equilibrium x̄ the closed loop settles at** (true plant simulated from near x* and from
  the half-size box), and ‖x̄ − x*‖ (Proposition 2: x̄ ∈ H_ε, eq. fixedpoint);
* the **largest sublevel set** {H_d < c} in which every sample has Ḣ_d < 0 along the true closed
  loop, Ḣ_d = ∇H_dᵀ(f + g u) (violations tolerated inside E), and that stays inside the box
  (c ≤ min of H_d on the box faces, sampled and refined by L-BFGS-B per face; with H_d convex the
  set then cannot leave the box). Every trajectory starting there stays there and reaches E
  (Proposition 2), if the samples are representative: a sampled certificate, never a proof.

**Sign of ξ.** Proposition 1's proof needs G ẋ = (gᵀf̃_d; g⊥f̃_d) + (0; g⊥(f − f̃_d)), so the
perturbation that actually acts on the closed loop ẋ = f̃_d + ξ is ξ = G⁻¹(0; g⊥(f − f̃_d)) =
−G⁻¹(0; μ) with μ = −g⊥(f − f̃_d) as eq. ``mismatch`` writes it (and as `Controller.mismatch`
returns it): the paper's eq. mismatch and its proof disagree by a sign. Here ξ is the perturbation
of the true closed loop, so that Ḣ_d = ∇H_dᵀ(f̃_d + ξ) = −(∇H_dᵀR_d∇H_d − ∇H_dᵀξ) when J_d is skew:
the margin of the dissipation inequality *is* −Ḣ_d. Both are computed independently (Ḣ_d from
the control law u = ctrl(x) itself) and their agreement is reported as a consistency check; the
share satisfied with the literal sign (ξ = +G⁻¹(0; μ)) is reported too, for comparison.

The controller interface used: ``ctrl.system`` (a `System`), ``ctrl(x) -> u`` (N, m),
``ctrl.H_d(x)`` (N,), ``ctrl.grad_H_d(x)`` (N, n), ``ctrl.J_d(x)``, ``ctrl.R_d(x)`` (N, n, n);
optionally ``ctrl.hess_H_d(x)`` (N, n, n) (else autograd through ``ctrl.nets.H`` when it is a
torch module, else central differences of ``grad_H_d``) and ``ctrl.eigenvalues_at_target()`` (else
central differences of the closed loop at x*).
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._io import write_json
from ..errors import IdapbcError

__all__ = [
    "Certificate",
    "ClosedLoopTerms",
    "Dissipation",
    "Equilibrium",
    "LABEL",
    "LocalStability",
    "Structural",
    "Sublevel",
    "certify",
    "closed_loop_terms",
    "resolve_controller",
]

#: How the certificate labels itself in its table and JSON.
LABEL = "sampled certificate, not a proof"


# ====================================================================== pointwise quantities
@dataclass(frozen=True, eq=False)
class ClosedLoopTerms:
    """The paper's quantities at states x (N, n), numpy float64.

    Attributes
    ----------
    x : (N, n) states (q, p).
    H : (N,) H_d;  dH : (N, n) ∇H_d;  J, R : (N, n, n) J_d, R_d.
    f : (N, n) drift of the controller's model;  f_d : (N, n) f̃_d = (J_d − R_d)∇H_d.
    mu : (N, n − m) mismatch μ = g⊥(f̃_d − f) (eq. mismatch, as `Controller.mismatch`).
    xi : (N, n) ξ = G⁻¹(0; −μ), the perturbation of the true closed loop ẋ = f̃_d + ξ (module doc).
    dissipation : (N,) ∇H_dᵀR_d∇H_d (left side of eq. damping_assign_relax_tilde).
    drive : (N,) ∇H_dᵀξ (right side).
    u : (N, m) the control law's input;  H_dot : (N,) ∇H_dᵀ(f + g u), the true-loop Ḣ_d.
    """

    x: np.ndarray
    H: np.ndarray
    dH: np.ndarray
    J: np.ndarray
    R: np.ndarray
    f: np.ndarray
    f_d: np.ndarray
    mu: np.ndarray
    xi: np.ndarray
    dissipation: np.ndarray
    drive: np.ndarray
    u: np.ndarray
    H_dot: np.ndarray

    @property
    def margin(self) -> np.ndarray:
        """(N,) ∇H_dᵀR_d∇H_d − ∇H_dᵀξ: > 0 where the dissipation inequality holds."""
        return self.dissipation - self.drive

    @property
    def margin_literal_sign(self) -> np.ndarray:
        """(N,) the margin with ξ = +G⁻¹(0; μ), eq. mismatch's sign taken literally (not the true loop)."""
        return self.dissipation + self.drive


def _f64(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float64)


def closed_loop_terms(ctrl, x, system=None) -> ClosedLoopTerms:
    """Evaluate H_d, ∇H_d, J_d, R_d, μ, ξ, both sides of the dissipation inequality and the true Ḣ_d.

    Parameters
    ----------
    ctrl : controller interface (see the module docstring).
    x : (N, n) states (q, p).
    system : the model the controller was designed on (default ``ctrl.system``); its f, g, g⊥
        and G enter μ, ξ and Ḣ_d.
    """
    system = ctrl.system if system is None else system
    x = np.atleast_2d(_f64(x))
    H = _f64(ctrl.H_d(x)).reshape(x.shape[0])
    dH = _f64(ctrl.grad_H_d(x)).reshape(x.shape)
    J = _f64(ctrl.J_d(x)).reshape(x.shape + (x.shape[1],))
    R = _f64(ctrl.R_d(x)).reshape(J.shape)
    f = _f64(system.f(x))
    f_d = np.einsum("nij,nj->ni", J - R, dH)
    mu = np.einsum("nij,nj->ni", _f64(system.g_perp(x)), f_d - f)
    rhs = np.concatenate([np.zeros((x.shape[0], system.m)), -mu], axis=1)
    xi = np.linalg.solve(_f64(system.G(x)), rhs[..., None])[..., 0]
    u = _f64(ctrl(x)).reshape(x.shape[0], system.m)
    x_dot = f + np.einsum("nim,nm->ni", _f64(system.g(x)), u)
    return ClosedLoopTerms(
        x=x, H=H, dH=dH, J=J, R=R, f=f, f_d=f_d, mu=mu, xi=xi,
        dissipation=np.einsum("ni,nij,nj->n", dH, R, dH),
        drive=np.einsum("ni,ni->n", dH, xi),
        u=u,
        H_dot=np.einsum("ni,ni->n", dH, x_dot),
    )


def _hessians(ctrl, x: np.ndarray) -> tuple[np.ndarray, str]:
    """∇²H_d at x (N, n) -> (N, n, n) and how it was obtained."""
    if hasattr(ctrl, "hess_H_d"):
        return _f64(ctrl.hess_H_d(x)), "controller"
    energy = getattr(getattr(ctrl, "nets", None), "H", None)
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a dependency
        torch = None
    if torch is not None and isinstance(energy, torch.nn.Module) and hasattr(energy, "grad"):
        like = energy.x_star
        xt = torch.as_tensor(x, dtype=like.dtype, device=like.device).requires_grad_(True)
        with torch.enable_grad():
            g = energy.grad(xt, create_graph=True)
            rows = [torch.autograd.grad(g[:, i].sum(), xt, retain_graph=i + 1 < x.shape[1])[0] for i in range(x.shape[1])]
        hess = torch.stack(rows, dim=1).detach().to("cpu", torch.float64).numpy()
        return 0.5 * (hess + np.swapaxes(hess, 1, 2)), "autograd"
    n = x.shape[1]
    h = 1e-5 * np.maximum(1.0, np.abs(x).max(axis=0))
    cols = []
    for i in range(n):
        e = np.zeros(n)
        e[i] = h[i]
        cols.append((_f64(ctrl.grad_H_d(x + e)) - _f64(ctrl.grad_H_d(x - e))) / (2 * h[i]))
    hess = np.stack(cols, axis=2)
    return 0.5 * (hess + np.swapaxes(hess, 1, 2)), "finite differences"


def _eigenvalues_at_target(ctrl, system) -> tuple[np.ndarray, str]:
    if hasattr(ctrl, "eigenvalues_at_target"):
        return np.asarray(ctrl.eigenvalues_at_target(), complex), "controller Jacobian"
    x_star = _f64(system.x_star)
    n = x_star.size

    def F(x):
        return _f64(system.f(x)) + np.einsum("nim,nm->ni", _f64(system.g(x)), _f64(ctrl(x)).reshape(x.shape[0], -1))

    h = 1e-6
    E = h * np.eye(n)
    A = ((F(x_star + E) - F(x_star - E)) / (2 * h)).T
    return np.linalg.eigvals(A), "finite differences"


# ====================================================================== the certificate
@dataclass(frozen=True)
class Structural:
    """Conditions (i)–(iii) on the samples (Hessian on a subsample of `n_hessian`)."""

    max_J_skew_error: float  #: max |J_d + J_dᵀ| over samples and entries
    max_J: float  #: max |J_d| (scale of the skew check)
    min_eig_R: float  #: min over samples of λ_min(R_d)
    max_R_asymmetry: float  #: max |R_d − R_dᵀ|
    min_eig_hessian: float  #: min over the subsample of λ_min(∇²H_d)
    n_hessian: int
    hessian_source: str  #: "autograd", "controller" or "finite differences"
    H_at_target: float  #: H_d(x*)
    grad_norm_at_target: float  #: ‖∇H_d(x*)‖
    min_H_off_target: float  #: min over samples of H_d
    min_H_over_dist2: float  #: min over samples of H_d / ‖x − x*‖² (0 would mean a flat direction)
    median_H: float
    median_grad_norm: float


@dataclass(frozen=True)
class Dissipation:
    """Eq. damping_assign_relax_tilde on the samples with H_d ≥ `level` (Theorem 2's set D)."""

    level: float  #: ε (0: every sample)
    n_checked: int
    fraction_satisfied: float  #: share with ∇H_dᵀR_d∇H_d − ∇H_dᵀξ > 0
    worst_margin: float  #: min of that margin (nan if no sample)
    worst_state: list | None  #: (n,) state of the worst margin
    fraction_literal_sign: float  #: share satisfied with ξ = +G⁻¹(0; μ) (eq. mismatch's sign, see module doc)


@dataclass(frozen=True)
class LocalStability:
    """Eigenvalues of the true closed loop's Jacobian at x*."""

    eigenvalues: list  #: [[re, im], ...]
    max_real: float
    source: str


@dataclass(frozen=True)
class Equilibrium:
    """Where the true closed loop settles (simulated), x̄ = mean over the last window."""

    n_near: int  #: trajectories started within 5 % of the half-widths around x*
    n_half_box: int  #: trajectories started in the half-size box
    n_settled: int  #: at rest (‖v‖∞ ≤ 0.05) over the last window, out of n_near + n_half_box
    n_success: int  #: DESIGN §4 success (in the 0.05 box around x* over the last 2 s)
    x_bar: list | None  #: (n,) mean settled state of the near-x* trajectories (None if none settled)
    offset: float  #: ‖x̄ − x*‖ (angles wrapped)
    max_offset: float  #: max over every settled trajectory of ‖x̄_k − x*‖
    T: float


@dataclass(frozen=True)
class Sublevel:
    """Largest sampled sublevel set {H_d < c} with Ḣ_d < 0 (true loop) outside {H_d < exclude}."""

    c: float  #: min(c_violation, c_boundary)
    exclude: float  #: violations with H_d below this are tolerated (ε; 0: none)
    c_violation: float  #: min H_d over the violating samples (inf if none)
    n_violations: int
    c_boundary: float  #: min of H_d on the faces of the box (sampled, refined per face)
    boundary_state: list  #: (n,) where that minimum sits
    covered_fraction: float  #: share of the domain samples inside {H_d < c}
    contains_E: bool  #: c > ε: the set holds E = H_ε (else the certificate is vacuous)


@dataclass(frozen=True)
class Certificate:
    """Everything `certify` found; ``to_dict()`` is what ``certificate.json`` holds.

    Attributes
    ----------
    label : always `LABEL` ("sampled certificate, not a proof").
    system : system name.  n_samples, seed : the uniform domain samples.
    box : (lo, hi) lists, the training domain X.
    epsilon : ε of H_ε (the run's estimate; 0 if none).  inside_fraction : share of samples in E.
    max_mu, max_xi : max ‖μ‖, ‖ξ‖ over the samples.
    max_hdot_identity_error : max |Ḣ_d + margin| / (1 + |Ḣ_d|) (Proposition 1 consistency).
    structural, dissipation_outside_E, dissipation_everywhere, local_stability, equilibrium,
    sublevel, sublevel_strict : see their classes (sublevel_strict tolerates no violation).
    rho : the controller's ρ, if it has one.  wall_time : seconds.
    """

    label: str
    system: str
    n_samples: int
    seed: int
    box: tuple
    epsilon: float
    inside_fraction: float
    max_mu: float
    max_xi: float
    max_hdot_identity_error: float
    structural: Structural
    dissipation_outside_E: Dissipation
    dissipation_everywhere: Dissipation
    local_stability: LocalStability
    equilibrium: Equilibrium | None
    sublevel: Sublevel
    sublevel_strict: Sublevel
    rho: float | None
    wall_time: float

    # ---------------------------------------------------------------- verdicts
    def checks(self) -> list[tuple[str, bool, str]]:
        """(name, passed, detail) for each condition, in the order of the table."""
        s = self.structural
        tol_H = 1e-6 * max(s.median_H, 1e-300)
        tol_g = 1e-6 * max(s.median_grad_norm, 1e-300)
        d_out, d_all = self.dissipation_outside_E, self.dissipation_everywhere
        les = self.local_stability
        out = [
            ("J_d skew-symmetric", s.max_J_skew_error <= 1e-9 * max(1.0, s.max_J), f"max |J_d + J_dᵀ| = {s.max_J_skew_error:.2e}"),
            ("R_d positive definite", s.min_eig_R > 0, f"min λ(R_d) = {s.min_eig_R:.3e}"),
            ("∇²H_d positive definite", s.min_eig_hessian > 0, f"min λ(∇²H_d) = {s.min_eig_hessian:.3e} on {s.n_hessian} samples ({s.hessian_source})"),
            ("H_d(x*) = 0, ∇H_d(x*) = 0", abs(s.H_at_target) <= tol_H and s.grad_norm_at_target <= tol_g,
             f"H_d(x*) = {s.H_at_target:.2e}, ‖∇H_d(x*)‖ = {s.grad_norm_at_target:.2e}"),
            ("H_d > 0 off x*", s.min_H_off_target > 0, f"min H_d = {s.min_H_off_target:.3e}, min H_d/‖δ‖² = {s.min_H_over_dist2:.3e}"),
            (f"dissipation outside E (ε = {self.epsilon:.3g})", d_out.fraction_satisfied == 1.0,
             f"{100 * d_out.fraction_satisfied:.2f} % of {d_out.n_checked}, worst margin {d_out.worst_margin:.3e} "
             f"(literal sign of eq. mismatch: {100 * d_out.fraction_literal_sign:.1f} %)"),
            ("dissipation everywhere (ε = 0)", d_all.fraction_satisfied == 1.0,
             f"{100 * d_all.fraction_satisfied:.2f} % of {d_all.n_checked}, worst margin {d_all.worst_margin:.3e} "
             f"(literal sign: {100 * d_all.fraction_literal_sign:.1f} %)"),
            ("x* locally exponentially stable", les.max_real < 0, f"max Re λ = {les.max_real:.4g} ({les.source})"),
        ]
        if self.equilibrium is not None:
            e = self.equilibrium
            n_sim = e.n_near + e.n_half_box
            out.append(("settles at x*", e.n_settled == n_sim and e.offset <= 0.05 and e.max_offset <= 0.05,
                        f"{e.n_settled}/{n_sim} settled, ‖x̄ − x*‖ = {e.offset:.2e} (near x*), max {e.max_offset:.2e}"))
        sl = self.sublevel
        out.append(("sublevel set {H_d < c} ⊃ E", sl.contains_E,
                    f"c = {sl.c:.4g} (ε = {self.epsilon:.3g}), {100 * sl.covered_fraction:.1f} % of the domain"))
        return out

    @property
    def certified(self) -> bool:
        """Every check passed (on the samples: still not a proof)."""
        return all(ok for _, ok, _ in self.checks())

    # ---------------------------------------------------------------- output
    def to_dict(self) -> dict:
        """JSON-ready (inf and nan become None)."""
        d = dataclasses.asdict(self)
        d["checks"] = [{"name": n, "passed": bool(ok), "detail": det} for n, ok, det in self.checks()]
        d["certified"] = self.certified
        return _clean(d)

    def table(self) -> str:
        """A short human-readable table."""
        sl, st = self.sublevel, self.sublevel_strict
        lines = [
            f"certificate of {self.system}: {LABEL}",
            f"{self.n_samples} uniform samples of the training box (seed {self.seed}); ε = {self.epsilon:.4g}, "
            f"E = H_ε holds {100 * self.inside_fraction:.1f} % of them; max ‖μ‖ = {self.max_mu:.3g}, max ‖ξ‖ = {self.max_xi:.3g}",
            f"{'condition':<38}{'':>6}  detail",
            "-" * 100,
        ]
        for name, ok, detail in self.checks():
            lines.append(f"{name:<38}{'ok' if ok else 'FAIL':>6}  {detail}")
        lines.append("-" * 100)
        lines.append(
            f"largest sublevel set with Ḣ_d < 0 outside E and inside the box: {{H_d < {sl.c:.4g}}}, "
            f"{100 * sl.covered_fraction:.1f} % of the domain ({sl.n_violations} violations outside E; box faces: min H_d = {sl.c_boundary:.4g})"
        )
        lines.append(
            f"  tolerating no violation at all: {{H_d < {st.c:.4g}}}, {100 * st.covered_fraction:.1f} % of the domain ({st.n_violations} samples with Ḣ_d ≥ 0)"
        )
        if self.local_stability.eigenvalues:
            eig = ", ".join(f"{re:.3g}" + (f"{im:+.3g}j" if abs(im) > 1e-12 else "") for re, im in self.local_stability.eigenvalues)
            lines.append(f"closed-loop eigenvalues at x*: {eig}")
        if self.equilibrium is not None and self.equilibrium.x_bar is not None:
            lines.append("x̄ (near x*): [" + ", ".join(f"{v:.3g}" for v in self.equilibrium.x_bar) + "]")
        lines.append(f"consistency: max |Ḣ_d + margin| / (1 + |Ḣ_d|) = {self.max_hdot_identity_error:.1e}; {self.wall_time:.1f} s")
        lines.append(f"verdict: {'all conditions hold on the samples' if self.certified else 'NOT certified'} ({LABEL})")
        return "\n".join(lines)


def _clean(obj):
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    return obj


def write_json_atomic(path: Path, obj) -> Path:
    """Write `obj` as JSON to `path` atomically (temp file in the same folder + os.replace)."""
    return write_json(path, obj, sort_keys=False)


# ====================================================================== pieces
def resolve_controller(run_or_ctrl, epsilon: float | None = None):
    """-> (ctrl, system, ε, run directory or None) from a `Run`, a run directory or a controller.

    ε: the given value, else the run's ``summary["epsilon"]``, else 0.
    """
    path = None
    obj = run_or_ctrl
    if isinstance(obj, (str, os.PathLike)):
        from ..training.run import load_run

        obj = load_run(obj)
    if hasattr(obj, "controller") and hasattr(obj, "path"):  # a Run
        path = Path(obj.path)
        if epsilon is None:
            epsilon = (getattr(obj, "summary", None) or {}).get("epsilon")
        ctrl = obj.controller
    else:
        ctrl = obj
    missing = [name for name in ("system", "H_d", "grad_H_d", "J_d", "R_d") if not hasattr(ctrl, name)]
    if missing or not callable(ctrl):
        raise IdapbcError(
            f"cannot certify {type(ctrl).__name__}: it lacks {', '.join(missing) or '__call__'}. "
            "Fix: pass a Run, a run directory or a controller with system, __call__, H_d, grad_H_d, J_d, R_d."
        )
    epsilon = 0.0 if epsilon is None else float(epsilon)
    if not (math.isfinite(epsilon) and epsilon >= 0):
        raise IdapbcError(f"epsilon must be finite and ≥ 0, got {epsilon}. Fix: pass a level of H_d.")
    return ctrl, ctrl.system, epsilon, path


def _dissipation(t: ClosedLoopTerms, level: float) -> Dissipation:
    sel = t.H >= level
    margin = t.margin[sel]
    if not margin.size:
        return Dissipation(level, 0, math.nan, math.nan, None, math.nan)
    k = int(np.argmin(margin))
    return Dissipation(
        level=float(level),
        n_checked=int(sel.sum()),
        fraction_satisfied=float(np.mean(margin > 0)),
        worst_margin=float(margin[k]),
        worst_state=t.x[sel][k].tolist(),
        fraction_literal_sign=float(np.mean(t.margin_literal_sign[sel] > 0)),
    )


def _boundary_min(ctrl, lo: np.ndarray, hi: np.ndarray, n_per_face: int, rng) -> tuple[float, np.ndarray]:
    """min of H_d on the faces of the box [lo, hi]: uniform samples per face, then L-BFGS-B per face."""
    from scipy.optimize import minimize

    n = lo.size
    faces = []
    for i in range(n):
        for side in (lo[i], hi[i]):
            pts = lo + (hi - lo) * rng.random((n_per_face, n))
            pts[:, i] = side
            faces.append((i, side, pts))
    H = _f64(ctrl.H_d(np.concatenate([p for _, _, p in faces]))).reshape(len(faces), n_per_face)
    best_val, best_x = math.inf, None
    for (i, side, pts), h in zip(faces, H):
        k = int(np.argmin(h))
        x0, v0 = pts[k].copy(), float(h[k])
        free = np.array([j != i for j in range(n)])

        def fun(z, i=i, side=side):
            x = np.empty(n)
            x[free], x[i] = z, side
            val = float(_f64(ctrl.H_d(x[None])).ravel()[0])
            grad = _f64(ctrl.grad_H_d(x[None])).ravel()[free]
            return val, grad

        try:
            res = minimize(fun, x0[free], jac=True, method="L-BFGS-B", bounds=list(zip(lo[free], hi[free])), options={"maxiter": 200})
            if np.isfinite(res.fun) and res.fun < v0:
                x0[free], v0 = res.x, float(res.fun)
        except (ValueError, FloatingPointError):  # keep the sampled minimum
            pass
        if v0 < best_val:
            best_val, best_x = v0, x0
    return best_val, best_x


def _sublevel(t: ClosedLoopTerms, exclude: float, epsilon: float, c_boundary: float, x_boundary: np.ndarray) -> Sublevel:
    viol = (t.H_dot >= 0) & (t.H >= exclude)
    c_viol = float(t.H[viol].min()) if viol.any() else math.inf
    c = min(c_viol, c_boundary)
    return Sublevel(
        c=c,
        exclude=float(exclude),
        c_violation=c_viol,
        n_violations=int(viol.sum()),
        c_boundary=float(c_boundary),
        boundary_state=x_boundary.tolist(),
        covered_fraction=float(np.mean(t.H < c)),
        contains_E=bool(c > epsilon),
    )


def _equilibrium(ctrl, system, n_each: int, T: float, dt: float, seed: int) -> Equilibrium:
    from ..sim.simulate import SUCCESS_WINDOW, settled, simulate, success, uniform_states, wrap_angles

    x_star = _f64(system.x_star)
    lo, hi = (_f64(b) for b in system.domain)
    half_width = 0.5 * (hi - lo)
    near = uniform_states(system, n_each, (x_star - 0.05 * half_width, x_star + 0.05 * half_width), seed)
    far = uniform_states(system, n_each, "half", seed + 1)
    traj = simulate(system, ctrl, np.concatenate([near, far]), T=T, dt=dt)
    window = traj.t >= traj.t[-1] - SUCCESS_WINDOW - 1e-9
    dx = wrap_angles(traj.x[:, window] - x_star, system.angle_mask).mean(axis=1)  # (N, n) x̄_k − x*
    still = settled(traj)
    offsets = np.linalg.norm(dx, axis=1)
    near_ok = still[:n_each]
    x_bar = (x_star + dx[:n_each][near_ok].mean(axis=0)).tolist() if near_ok.any() else None
    offset = float(np.linalg.norm(np.asarray(x_bar) - x_star)) if x_bar is not None else math.nan
    return Equilibrium(
        n_near=n_each,
        n_half_box=n_each,
        n_settled=int(still.sum()),
        n_success=int(success(traj, system).sum()),
        x_bar=x_bar,
        offset=offset,
        max_offset=float(offsets[still].max()) if still.any() else math.nan,
        T=float(T),
    )


# ====================================================================== certify
def certify(
    run,
    n: int = 20000,
    seed: int = 0,
    *,
    epsilon: float | None = None,
    n_hessian: int = 2000,
    n_boundary: int | None = None,
    settle: int = 4,
    settle_T: float = 20.0,
    dt: float = 0.01,
    write: bool = True,
) -> Certificate:
    """Check the paper's conditions on `n` uniform samples of the training box.

    Parameters
    ----------
    run : a `Run`, a run directory, or any controller with the interface of the module docstring
        (``ctrl.system`` is then the plant and the model).
    n : domain samples (uniform in ``system.domain``, seeded).
    seed : seed of every random draw.
    epsilon : level ε of E = H_ε; default the run's estimate (``summary.json``), else 0.
    n_hessian : subsample on which ∇²H_d is checked.
    n_boundary : samples on the box faces (default n/4, at least 64 per face), each face's best
        refined by L-BFGS-B.
    settle : trajectories from near x* and as many from the half box for the settled equilibrium
        (0: skip the simulation).
    settle_T, dt : their horizon and step, s.
    write : write ``<run>/certificate.json`` (atomic) when given a run.

    Returns
    -------
    Certificate (``.table()``, ``.to_dict()``); a sampled certificate, not a proof.
    """
    t0 = time.perf_counter()
    ctrl, system, eps, path = resolve_controller(run, epsilon)
    n = int(n)
    if n < 16:
        raise IdapbcError(f"n must be at least 16 samples, got {n}. Fix: pass a larger --n.")
    rng = np.random.default_rng(seed)
    lo, hi = (_f64(b) for b in system.domain)
    x = lo + (hi - lo) * rng.random((n, system.n))
    terms = closed_loop_terms(ctrl, x, system)

    # --- structural (i)-(iii)
    J, R = terms.J, terms.R
    x_star = _f64(system.x_star)
    H_star = float(_f64(ctrl.H_d(x_star[None])).ravel()[0])
    g_star = float(np.linalg.norm(_f64(ctrl.grad_H_d(x_star[None])).ravel()))
    sub = x[: min(int(n_hessian), n)]
    hess, hess_source = _hessians(ctrl, sub)
    dist2 = ((x - x_star) ** 2).sum(axis=1)
    structural = Structural(
        max_J_skew_error=float(np.abs(J + np.swapaxes(J, 1, 2)).max()),
        max_J=float(np.abs(J).max()),
        min_eig_R=float(np.linalg.eigvalsh(0.5 * (R + np.swapaxes(R, 1, 2)))[:, 0].min()),
        max_R_asymmetry=float(np.abs(R - np.swapaxes(R, 1, 2)).max()),
        min_eig_hessian=float(np.linalg.eigvalsh(hess)[:, 0].min()),
        n_hessian=int(sub.shape[0]),
        hessian_source=hess_source,
        H_at_target=H_star,
        grad_norm_at_target=g_star,
        min_H_off_target=float(terms.H.min()),
        min_H_over_dist2=float((terms.H / np.maximum(dist2, 1e-300)).min()),
        median_H=float(np.median(terms.H)),
        median_grad_norm=float(np.median(np.linalg.norm(terms.dH, axis=1))),
    )

    # --- local exponential stability, settled equilibrium
    eig, eig_source = _eigenvalues_at_target(ctrl, system)
    les = LocalStability([[float(z.real), float(z.imag)] for z in eig], float(np.max(eig.real)), eig_source)
    equilibrium = _equilibrium(ctrl, system, int(settle), settle_T, dt, seed) if settle > 0 else None

    # --- sublevel sets
    per_face = max(64, (n // 4 if n_boundary is None else int(n_boundary)) // (2 * system.n))
    c_bnd, x_bnd = _boundary_min(ctrl, lo, hi, per_face, rng)

    cert = Certificate(
        label=LABEL,
        system=str(getattr(system, "name", type(system).__name__)),
        n_samples=n,
        seed=int(seed),
        box=(lo.tolist(), hi.tolist()),
        epsilon=eps,
        inside_fraction=float(np.mean(terms.H < eps)),
        max_mu=float(np.linalg.norm(terms.mu, axis=1).max()) if terms.mu.shape[1] else 0.0,
        max_xi=float(np.linalg.norm(terms.xi, axis=1).max()),
        max_hdot_identity_error=float((np.abs(terms.H_dot + terms.margin) / (1.0 + np.abs(terms.H_dot))).max()),
        structural=structural,
        dissipation_outside_E=_dissipation(terms, eps),
        dissipation_everywhere=_dissipation(terms, 0.0),
        local_stability=les,
        equilibrium=equilibrium,
        sublevel=_sublevel(terms, eps, eps, c_bnd, x_bnd),
        sublevel_strict=_sublevel(terms, 0.0, eps, c_bnd, x_bnd),
        rho=float(ctrl.rho) if hasattr(ctrl, "rho") else None,
        wall_time=time.perf_counter() - t0,
    )
    if write and path is not None:
        write_json_atomic(path / "certificate.json", cert.to_dict())
    return cert

"""What `certify` found: one frozen dataclass per condition and the `Certificate` that holds them,
with its verdicts (`Certificate.checks`), its table and what ``certificate.json`` holds."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from .._io import to_json

__all__ = ["LABEL", "share_text", "BaselineCertificate", "Certificate", "Confidence", "Dissipation", "Equilibrium", "LocalStability", "Region", "Structural", "Verified"]

#: How the certificate labels itself in its table and JSON.
LABEL = "sampled certificate, not a proof"


def share_text(share, digits: int = 3) -> str:
    """A share of a box as a percentage, with `digits` significant digits below 1 %: '12.3 %',
    '0.0123 %', '0.0 %'; '—' for None or '' (a summary cell without a value)."""
    if share in ("", None):
        return "—"
    pct = 100 * float(share)
    return f"{pct:.1f} %" if pct >= 1 or pct == 0 else f"{pct:.{digits}g} %"


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
class Confidence:
    """What the fresh samples of the certified set say (`idapbc_pin.certificate.region`, step 4).

    passed : all `samples` fresh i.i.d. samples of the final set passed: the share of the set
        (outside the core) where V does not decrease is ≤ `epsilon` with confidence ≥ 1 − `beta`.
    samples : N = ⌈ln(rounds_max/β)/ε⌉ per round.  rounds : rounds drawn (a failure lowers c and
        draws again).  failures : failing samples over the earlier rounds.
    """

    epsilon: float
    beta: float
    samples: int
    rounds: int
    failures: int
    passed: bool


@dataclass(frozen=True)
class Verified:
    """The interval-arithmetic check of a certified set (`idapbc_pin.certificate.verified`).

    passed : every box was decided: V decreases on {core ≤ V < c} along the exact loop.
    c : the verified level (0 unless passed).  boxes : boxes evaluated.
    covered_fraction : share of the training box X inside {V < c} (sampled; 0 unless passed).
    reason : why a level was not verified ('' when one was).  seconds : wall time.
    """

    passed: bool
    c: float
    boxes: int
    covered_fraction: float
    reason: str
    seconds: float


@dataclass(frozen=True)
class Region:
    """The certified set {V < c} in the verification box (`idapbc_pin.certificate.region`).

    c : its level (≤ c_boundary, ≤ the V of every violation found).
    core : level of the core certified by the linearisation (not sampled; 0: none).
    linear_decay : λ_min of −(PA + AᵀP) in P's metric, 1/s (≤ 0: the linearisation certifies nothing).
    c_boundary, boundary_state : min of V on the verification box's faces, and where.
    c_violation : lowest V of a sample or counter-example with V̇ ≥ 0 outside the core (inf: none).
    n_violations : failing search samples; n_counterexamples : failing points of the ascent.
    covered_fraction : vol(set ∩ X) / vol(X), the training box X (0 unless `confidence.passed`).
    verification_share : vol(set) / vol(V_box).
    confidence : `Confidence`.
    verified : the interval-arithmetic check of the set (`Verified`), or None where not run.
    """

    c: float
    core: float
    linear_decay: float
    c_boundary: float
    boundary_state: list
    c_violation: float
    n_violations: int
    n_counterexamples: int
    covered_fraction: float
    verification_share: float
    confidence: Confidence
    verified: Verified | None = None

    @property
    def certified(self) -> bool:
        """A set beyond the core passed its fresh samples."""
        return self.confidence.passed and self.c > self.core


@dataclass(frozen=True)
class BaselineCertificate:
    """The LQR baseline's sampled certificate (the ``"baseline"`` entry of certificate.json).

    controller : "LQR".  function : what V is.
    limits_applied : the effort limits clipped the LQR input.
    max_real : max Re of the eigenvalues of the LQR loop's linearisation A − BK.
    sublevel : its certified set in the run certificate's verification box (`Region`);
        ``covered_fraction`` is the certified share of the training box.
    """

    controller: str
    function: str
    limits_applied: bool
    max_real: float
    sublevel: Region


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
    verification_box : {"lo": [...], "hi": [...]}, the box V_box ⊇ X the certified sets live in.
    sublevel : H_d's certified set in V_box (`Region`); ``covered_fraction`` is its share of X.
    invariant_share : {controller: share of X's states whose trajectory reaches x* without leaving
        V_box} (simulated; no certified set in V_box covers more of X); None when skipped.
    rho : the controller's ρ, if it has one.  wall_time : seconds.
    limits : the input bound the true loop was checked with (`InputLimits.to_json()`: applied,
        lifted, effort, bound); None for a certificate made before limits were recorded.
    saturated_fraction : share of the samples where the law's input exceeds the bound (Ḣ_d is
        taken along f + g·sat(u) there).
    baseline : the LQR baseline's certificate on the same samples (None when not computed).
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
    verification_box: dict
    sublevel: Region
    invariant_share: dict | None
    rho: float | None
    wall_time: float
    limits: dict | None = None
    saturated_fraction: float = 0.0
    baseline: BaselineCertificate | None = None

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
        sl, conf = self.sublevel, self.sublevel.confidence
        out.append(("certified set {H_d < c} beyond the core", sl.certified,
                    f"c = {sl.c:.4g} (core {sl.core:.3g}), {share_text(sl.covered_fraction)} of the training box; "
                    f"{conf.samples} fresh samples {'passed' if conf.passed else 'did not pass'} (ε = {conf.epsilon:g}, β = {conf.beta:g})"))
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
        return to_json(d)

    def _limits_line(self) -> str:
        """Whether the true loop was checked with the effort limits, and how often they bind."""
        lim = self.limits or {}
        bound = lim.get("bound")
        if bound is None:
            what = "lifted (--no-limits)" if lim.get("lifted") else "none (the system has none)"
            return f"torque limits: {what}; Ḣ_d along f + g·u"
        text = "|".join("∞" if b is None else f"{b:.3g}" for b in bound)
        return (f"torque limits applied: |u| ≤ {text}; Ḣ_d along f + g·sat(u), "
                f"the law saturates on {100 * self.saturated_fraction:.1f} % of the samples")

    def _shares_line(self) -> str:
        """Both certified shares and invariant shares side by side (NIDA-PBC's H_d, LQR's δᵀSδ)."""
        inv = self.invariant_share or {}
        line = f"certified share of the training box: NIDA-PBC {{H_d < {self.sublevel.c:.3g}}} {share_text(self.sublevel.covered_fraction)}"
        if self.baseline is not None:
            b = self.baseline.sublevel
            line += f"  |  LQR {{δᵀSδ < {b.c:.3g}}} {share_text(b.covered_fraction)}"
        if inv:
            line += "\ninvariant share (reach x* without leaving V_box; the ceiling of any certified set): " + ", ".join(
                f"{name} {share_text(v)}" for name, v in inv.items())
        return line

    def _verified_line(self) -> str:
        """What interval arithmetic proved of each certified set (`idapbc_pin.certificate.verified`)."""
        parts = []
        for name, fn, region in (("NIDA-PBC", "H_d", self.sublevel), ("LQR", "δᵀSδ", self.baseline.sublevel if self.baseline else None)):
            v = None if region is None else region.verified
            if v is None:
                continue
            parts.append(f"{name} {{{fn} < {v.c:.4g}}} {share_text(v.covered_fraction)} of the training box ({v.boxes} boxes, {v.seconds:.1f} s)"
                         if v.passed else f"{name} not verified: {v.reason}")
        return "verified by interval arithmetic (a proof outside the core): " + ("  |  ".join(parts) if parts else "not run")

    def table(self) -> str:
        """A short human-readable table."""
        sl = self.sublevel
        v = self.verification_box
        lines = [
            f"certificate of {self.system}: {LABEL}",
            f"{self.n_samples} uniform samples of the training box (seed {self.seed}); ε = {self.epsilon:.4g}, "
            f"E = H_ε holds {100 * self.inside_fraction:.1f} % of them; max ‖μ‖ = {self.max_mu:.3g}, max ‖ξ‖ = {self.max_xi:.3g}",
            self._limits_line(),
            f"{'condition':<38}{'':>6}  detail",
            "-" * 100,
        ]
        for name, ok, detail in self.checks():
            lines.append(f"{name:<38}{'ok' if ok else 'FAIL':>6}  {detail}")
        lines.append("-" * 100)
        lines.append("verification box V_box: [" + ", ".join(f"{a:.3g}…{b:.3g}" for a, b in zip(v["lo"], v["hi"])) + "]")
        lines.append(
            f"certified set: {{H_d < {sl.c:.4g}}} with Ḣ_d < 0 outside the core {{H_d < {sl.core:.3g}}}; "
            f"V_box faces: min H_d = {sl.c_boundary:.4g}; lowest H_d with Ḣ_d ≥ 0 found: {sl.c_violation:.4g} "
            f"({sl.n_violations} samples, {sl.n_counterexamples} counter-examples)"
        )
        lines.append(self._shares_line())
        lines.append(self._verified_line())
        if self.local_stability.eigenvalues:
            eig = ", ".join(f"{re:.3g}" + (f"{im:+.3g}j" if abs(im) > 1e-12 else "") for re, im in self.local_stability.eigenvalues)
            lines.append(f"closed-loop eigenvalues at x*: {eig}")
        if self.equilibrium is not None and self.equilibrium.x_bar is not None:
            lines.append("x̄ (near x*): [" + ", ".join(f"{v:.3g}" for v in self.equilibrium.x_bar) + "]")
        lines.append(f"consistency: max |Ḣ_d + margin| / (1 + |Ḣ_d|) = {self.max_hdot_identity_error:.1e}; {self.wall_time:.1f} s")
        lines.append(f"verdict: {'all conditions hold on the samples' if self.certified else 'NOT certified'} ({LABEL})")
        return "\n".join(lines)

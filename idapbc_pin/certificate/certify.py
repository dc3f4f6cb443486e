"""The paper's conditions checked numerically on dense samples: a *sampled* certificate, not a proof.

For a trained run (or any object with the controller interface, see `idapbc_pin.certificate.terms`)
`certify` checks, on `n` uniform samples of the training box X (DESIGN §4, "Certificate"):

* **structural conditions** (i)–(iii) of Proposition 3 (label ``prop:vanishing_mu``):
  J_d + J_dᵀ = 0, R_d ≻ 0, ∇²H_d ≻ 0 (on a subsample), H_d(x*) = 0, ∇H_d(x*) = 0, H_d > 0 off x*;
* the **dissipation inequality** of Theorem 2 (eq. ``damping_assign_relax_tilde``)

      ∇H_dᵀ R_d ∇H_d  >  ∇H_dᵀ ξ,    ξ = G⁻¹ (0; g⊥(f − f̃_d))   (sign: see `terms`),

  on the samples outside H_ε = {H_d < ε} (the dissipation set D), with ε the run's estimate, and
  on every sample (ε = 0); the fraction satisfied and the worst margin;
* the size of E = H_ε (share of the domain samples inside);
* **local exponential stability** of x*: eigenvalues of the Jacobian of the true closed loop
  f + g u at x*;
* the **equilibrium x̄ the closed loop settles at** (true plant simulated from near x* and from
  the half-size box), and ‖x̄ − x*‖ (Proposition 2: x̄ ∈ H_ε, eq. fixedpoint);
* the **certified set** (`idapbc_pin.certificate.region`): the largest sublevel set {H_d < c} in
  the verification box V_box ⊇ X (`idapbc_pin.certificate.vbox`) on which H_d decreases along the
  true closed loop (the controller as deployed, outer law included) outside a core certified by
  the linearisation, with the confidence of N fresh samples (ε, β); its share of X even where it
  reaches past X;
* the **invariant share**: the share of X's states whose trajectory reaches x* without leaving
  V_box, for both controllers (`idapbc_pin.evaluation.invariance`): no certified set in V_box can
  cover more of X;
* where the loop has an interval form (the closed-form plants), the certified sets **verified**
  by interval arithmetic with box splitting (`idapbc_pin.certificate.verified`);
* the **same certified-set test for the LQR baseline** on its own Lyapunov function δᵀSδ
  (`idapbc_pin.certificate.baseline`), in the same V_box.

With the actuators' effort limits applied (the default, DESIGN §4), the true loop is f + g·sat(u):
Ḣ_d (and LQR's V̇) are taken along the saturated input, and the settling simulations clip it; the
structural conditions and the dissipation inequality are properties of the unsaturated law and are
checked as such.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from pathlib import Path

import numpy as np

from .._io import write_json
from .._parallel import JobPool
from ..control.baseline import LQRController
from ..errors import IdapbcError
from ..run import resolve_run
from ..sim.limits import input_limits
from ..evaluation.invariance import box_invariant_share
from .baseline import certify_baseline
from .checks import check_dissipation, check_structural, local_stability, settled_equilibrium
from .region import TrueLoop, certified_region
from .result import LABEL, Certificate
from .terms import _f64, closed_loop_terms
from .vbox import DEFAULT_SCALE, verification_box
from .verified import check_mode, verify_sets

__all__ = ["certify", "resolve_controller"]


def resolve_controller(run_or_ctrl, epsilon: float | None = None):
    """-> (ctrl, system, ε, run directory or None) from a `Run`, a run directory or a controller.

    ε: the given value, else the run's ``summary["epsilon"]``, else 0.
    """
    path = None
    obj = resolve_run(run_or_ctrl) if isinstance(run_or_ctrl, (str, os.PathLike)) else run_or_ctrl
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


def certify(
    run,
    n: int = 20000,
    seed: int = 0,
    *,
    epsilon: float | None = None,
    n_hessian: int = 2000,
    settle: int = 4,
    settle_T: float = 20.0,
    dt: float | None = None,
    write: bool = True,
    limits: bool = True,
    baseline: bool = True,
    scale: float = DEFAULT_SCALE,
    box=None,
    share_bound: float = 1e-3,
    beta: float = 1e-6,
    invariant: int = 200,
    workers: int = 1,
    verify: str = "auto",
) -> Certificate:
    """Check the paper's conditions on `n` uniform samples of the training box.

    Parameters
    ----------
    run : a `Run`, a run directory, or any controller with the interface of
        `idapbc_pin.certificate.terms` (``ctrl.system`` is then the plant and the model).
    n : domain samples (uniform in ``system.domain``, seeded).
    seed : seed of every random draw.
    epsilon : level ε of E = H_ε; default the run's estimate (``summary.json``), else 0.
    n_hessian : subsample on which ∇²H_d is checked.
    settle : trajectories from near x* and as many from the half box for the settled equilibrium (0: none).
    settle_T, dt : their horizon (and the invariant share's) and step, s (dt None: 2 ms, or shorter for a stiff loop, `judge_step`).
    write : write ``<run>/certificate.json`` (atomic) when given a run.
    limits : check the true loop with the effort limits (f + g·sat(u); the default); False lifts them.
    baseline : also certify the LQR baseline's δᵀSδ in the same verification box (skipped for a
        system without ``linearization``).
    scale, box : the verification box V_box = x* + scale·(X − x*), angles capped at x* ± π, or an
        explicit one ⊇ X: (lo, hi), or {coordinate: (lo, hi)} over the scaled box (`verification_box`).
    share_bound, beta : the certified set's statement: the share of it where H_d does not
        decrease is ≤ share_bound (ε) with confidence ≥ 1 − β (N = ⌈ln(3/β)/ε⌉ fresh samples).
    invariant : training-box states simulated for the invariant share in V_box (0: skip).
    workers : processes for the simulations (invariant shares, settling), beside the sampled
        checks; 1: this process, in turn; 0: one per core. The count changes the time, never a result.
    verify : prove the certified sets by interval arithmetic (`idapbc_pin.certificate.verified`):
        "auto" (loops with an interval form and 2 states), "always" (any size, box budget), "never".

    Returns
    -------
    Certificate (``.table()``, ``.to_dict()``); a sampled certificate, not a proof.
    """
    t0 = time.perf_counter()
    ctrl, system, eps, path = resolve_controller(run, epsilon)
    n = int(n)
    if n < 16:
        raise IdapbcError(f"n must be at least 16 samples, got {n}. Fix: pass a larger --n.")
    check_mode(verify)
    rng = np.random.default_rng(seed)
    lo, hi = (_f64(b) for b in system.domain)
    bounds = input_limits(system, limits)
    vbox = verification_box(system, scale, box)
    with_baseline = baseline and hasattr(system, "linearization")
    with JobPool(workers) as pool:  # the simulations run beside the sampled checks
        laws = {"NIDA-PBC": ctrl, **({"LQR": LQRController(system)} if with_baseline else {})}
        shares = [pool.submit(_invariant_job, (system, {name: law}, vbox, int(invariant), seed, settle_T, limits)) for name, law in laws.items()] if invariant > 0 else []
        settling = pool.submit(_settle_job, (ctrl, system, int(settle), settle_T, dt, seed, limits)) if settle > 0 else None
        terms = closed_loop_terms(ctrl, lo + (hi - lo) * rng.random((n, system.n)), system, bounds.bound)
        structural = check_structural(ctrl, system, terms, n_hessian)
        les = local_stability(ctrl, system)
        region, base = _certified_sets(ctrl, system, vbox, (lo, hi), bounds.bound, seed, share_bound, beta, with_baseline, verify)
        invariant_share = {k: v for f in shares for k, v in f.result().items()} or None
        equilibrium = settling.result() if settling is not None else None
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
        max_hdot_identity_error=float((np.abs(terms.H_dot_law + terms.margin) / (1.0 + np.abs(terms.H_dot_law))).max()),
        structural=structural,
        dissipation_outside_E=check_dissipation(terms, eps),
        dissipation_everywhere=check_dissipation(terms, 0.0),
        local_stability=les,
        equilibrium=equilibrium,
        verification_box={"lo": vbox[0].tolist(), "hi": vbox[1].tolist()},
        sublevel=region,
        invariant_share=invariant_share,
        rho=float(ctrl.rho) if hasattr(ctrl, "rho") else None,
        wall_time=time.perf_counter() - t0,
        limits=bounds.to_json(),
        saturated_fraction=float(np.mean(terms.saturated)),
        baseline=base,
    )
    if write and path is not None:
        write_json(path / "certificate.json", cert.to_dict(), sort_keys=False)
    return cert


def _certified_sets(ctrl, system, vbox, tbox, bound, seed, share_bound, beta, with_baseline, verify):
    """(H_d's certified set, LQR's `BaselineCertificate` or None), each with its `Verified`."""
    region = certified_region(ctrl, TrueLoop(system, ctrl, bound), system.x_star, vbox, tbox,
                              np.random.default_rng([seed, 1]), epsilon=share_bound, beta=beta)
    base = certify_baseline(system, vbox, tbox, np.random.default_rng([seed, 1]), bound, share_bound, beta) if with_baseline else None
    proven = verify_sets(ctrl, system, region, base.sublevel if base else None, vbox, tbox, bound, np.random.default_rng([seed, 2]), verify)
    region = dataclasses.replace(region, verified=proven[0])
    base = dataclasses.replace(base, sublevel=dataclasses.replace(base.sublevel, verified=proven[1])) if base else None
    return region, base


def _invariant_job(job) -> dict[str, float]:
    """`box_invariant_share` of one law (a `JobPool` job: (system, {name: law}, box, n, seed, T, limits))."""
    return box_invariant_share(*job)


def _settle_job(job):
    """`settled_equilibrium` (a `JobPool` job: (ctrl, system, n_each, T, dt, seed, limits))."""
    return settled_equilibrium(*job)

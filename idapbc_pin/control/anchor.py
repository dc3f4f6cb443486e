"""The LQR anchor a `System` and a `TrainConfig` give the anchored networks, and its automatic settings.

`linear.lqr_anchor` turns a linearisation (A, B) into an exact port-Hamiltonian form (P, J, R) of an
LQR loop; this module chooses that LQR problem for a system: the state weight Q (physical or box
units, weight ``anchor_q``), the shape of P (``config.anchor_p``), and the scale of P. ``"auto"`` and
``0`` in the config are resolved here (`anchor_settings`).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla

from ..config import TrainConfig
from ..errors import IdapbcError
from ..model import System
from .linear import LinearAnchor, fastest_pole, lqr_anchor

__all__ = [
    "AUTO_ANCHOR_Q",
    "AUTO_BOX_RATIO",
    "AUTO_CART_WEIGHTS",
    "AUTO_MAX_POLE",
    "AUTO_SLOWEST_POLE",
    "AUTO_STIFF_PLANT_Q",
    "FALLBACK_FORMS",
    "MAX_P_COND",
    "MAX_R_COND",
    "anchor_forms",
    "anchor_settings",
    "cart_setting",
    "formed_anchor",
    "half_widths",
    "local_rate",
    "p_condition",
    "prismatic_positions",
    "system_anchor",
]


def half_widths(system: System) -> np.ndarray:
    """s (n,): half-widths of the training box around x* (the larger side)."""
    lo, hi = system.domain
    return np.maximum(hi - system.x_star, system.x_star - lo)


#: ``scaling="auto"`` picks box units when the training box's half-widths span more than this ratio.
AUTO_BOX_RATIO = 20.0
#: ``anchor_q=0`` (automatic) tries these weights in turn and keeps the first whose anchor has no pole
#: faster than ``AUTO_MAX_POLE`` 1/s. Under actuator limits a stiffer loop saturates sooner
#: (docs/results-history.md). The cap also keeps |λ|·dt ≪ 0.5 for the judge's 2 ms step
#: (`idapbc_pin.sim.step.DEFAULT_STEP`).
AUTO_ANCHOR_Q = (10.0, 1.0, 0.1, 0.01)
AUTO_MAX_POLE = 15.0
#: When the plant's own linearisation at x* already has a pole faster than ``AUTO_MAX_POLE`` (joint
#: damping on light links), no weight meets the cap and the rule says nothing: the LQR baseline's own
#: weight is taken.
AUTO_STIFF_PLANT_Q = 1.0
#: ``anchor_cart=0`` (automatic) multiplies the position weight of each prismatic coordinate (a cart on
#: a rail) by the first of these whose anchor has no pole slower than ``AUTO_SLOWEST_POLE`` 1/s and
#: none faster than ``AUTO_MAX_POLE`` (else by 1). Q = anchor_q·I weighs a metre of cart like a radian
#: of angle, which leaves the cart's return to x* the loop's slowest mode (docs/results-history.md).
AUTO_CART_WEIGHTS = (1.0, 3.0, 10.0, 30.0, 100.0)
AUTO_SLOWEST_POLE = 2.0
#: The forms of P (``TrainConfig.anchor_p``) tried after the configured one, in this order, where it
#: gives no positive-definite R or a P or R conditioned worse than ``MAX_P_COND`` or ``MAX_R_COND`` (light distal links: M(q)
#: and the Riccati solution spanning 1e8–1e11).
FALLBACK_FORMS = ("riccati", "box", "lyapunov")
#: Largest condition number of P, in the networks' units (`p_condition`), taken without trying the
#: next form of `FALLBACK_FORMS`: the order at which R = ½P⁻¹Q'P⁻¹ stops coming out positive definite
#: in float64 (the four-link chain's Riccati P at anchor_q = 0.1: 1e10).
MAX_P_COND = 1e9
#: Largest condition number of the anchor's R = ½P⁻¹Q'P⁻¹ in the networks' units (`p_condition`), taken
#: without trying the next form: float64 then keeps R_d's smallest eigenvalue some 100 times above the
#: rounding of its largest (the four-link chain's Riccati R: 2.4e15).
MAX_R_COND = 1e13


def anchor_settings(system: System, config: TrainConfig) -> tuple[str, float]:
    """The resolved ``(scaling, anchor_q)`` of `config` for `system` (see `TrainConfig`'s "auto" values).

    Box units pay off only where the training box's half-widths span a wide range (``AUTO_BOX_RATIO``);
    on a box of similar sides they lose success (docs/results-history.md).
    """
    scaling = config.scaling
    if scaling == "auto":
        half = half_widths(system)
        scaling = "box" if half.max() > AUTO_BOX_RATIO * half.min() else "none"
    if config.anchor_q > 0:
        return scaling, float(config.anchor_q)
    for q in AUTO_ANCHOR_Q:
        try:
            anchor = _lqr_anchor(system, config, scaling, q)
        except IdapbcError:  # no form of P gives this weight an anchor: not a candidate
            continue
        if fastest_pole(anchor.A_cl) <= AUTO_MAX_POLE:
            return scaling, q
    if fastest_pole(system.linearization()[0]) > AUTO_MAX_POLE:
        return scaling, AUTO_STIFF_PLANT_Q
    return scaling, AUTO_ANCHOR_Q[-1]


def system_anchor(system: System, config: TrainConfig, settings: tuple[str, float] | None = None) -> LinearAnchor:
    """The anchor (P, J, R) of `system`'s LQR loop at x* that `build_nets` pins the networks to.

    ``settings``: the resolved ``(scaling, anchor_q)`` if the caller has them; by default
    `anchor_settings(system, config)`.
    """
    scaling, anchor_q = anchor_settings(system, config) if settings is None else settings
    return _lqr_anchor(system, config, scaling, anchor_q)


def prismatic_positions(system: System) -> np.ndarray:
    """(n,) bool: the state's position coordinates of the URDF's prismatic joints (a cart on a rail;
    the analytic models' linear coordinates are not among them)."""
    mask = np.zeros(system.n, dtype=bool)
    mask[: system.nq] = [joint.kind == "prismatic" for joint in system.joints]
    return mask


def _state_weight(system: System, config: TrainConfig, scaling: str, anchor_q: float) -> np.ndarray:
    """Q (n, n) before a cart's weight: anchor_q·I, or anchor_q·diag(1/s²) for box units with
    ``config.anchor_weight == "box"``."""
    half = half_widths(system)
    return anchor_q * (np.diag(1.0 / half**2) if scaling == "box" and config.anchor_weight == "box" else np.eye(system.n))


def _with_cart(Q: np.ndarray, cart: np.ndarray, weight: float) -> np.ndarray:
    """The diagonal weight Q (n, n) with the entries of the `cart` coordinates multiplied by `weight`."""
    return np.diag(np.diag(Q) * np.where(cart, weight, 1.0))


def _cart_weight(system: System, config: TrainConfig, A: np.ndarray, Bx: np.ndarray, Q: np.ndarray) -> float:
    """``config.anchor_cart``, or where it is 0 the automatic weight (`AUTO_CART_WEIGHTS`,
    `AUTO_SLOWEST_POLE`) for the LQR problem (A, Bx, Q)."""
    if config.anchor_cart > 0:
        return float(config.anchor_cart)
    cart = prismatic_positions(system)
    if not cart.any():
        return 1.0
    for weight in AUTO_CART_WEIGHTS:
        poles = np.linalg.eigvals(lqr_anchor(A, Bx, Q=_with_cart(Q, cart, weight)).A_cl)
        if poles.real.max() <= -AUTO_SLOWEST_POLE and np.abs(poles).max() <= AUTO_MAX_POLE:
            return weight
    return 1.0


def cart_setting(system: System, config: TrainConfig) -> float:
    """The resolved ``anchor_cart`` of `config` for `system`, at its resolved ``(scaling, anchor_q)``
    (`anchor_settings`): what a new run's config.json records."""
    scaling, anchor_q = anchor_settings(system, config)
    A, Bx = system.linearization()
    return _cart_weight(system, config, A, Bx, _state_weight(system, config, scaling, anchor_q))


def _lqr_anchor(system: System, config: TrainConfig, scaling: str, anchor_q: float) -> LinearAnchor:
    """The anchor for explicit settings, in the first form of P (`anchor_forms`) that gives one."""
    return formed_anchor(system, config, (scaling, anchor_q))[0]


def anchor_forms(config: TrainConfig) -> tuple[str, ...]:
    """The forms of P tried in turn: ``config.anchor_p``, then the others of `FALLBACK_FORMS`."""
    return (config.anchor_p,) + tuple(form for form in FALLBACK_FORMS if form != config.anchor_p)


def formed_anchor(system: System, config: TrainConfig, settings: tuple[str, float] | None = None) -> tuple[LinearAnchor, str, str]:
    """``(anchor, form, why)``: the anchor in the first form of P (`anchor_forms`) whose R is positive
    definite and whose P and R, in the networks' units, have condition numbers ≤ `MAX_P_COND` and
    ≤ `MAX_R_COND` (else, of those with a positive-definite R, the one least past its bounds); `why`
    says why the forms before it were passed over ("" when the configured form is the one).

    Raises
    ------
    IdapbcError
        When no form gives a positive-definite R (a badly scaled problem, not a robot without anchor:
        an unstabilisable target is refused when the system is loaded).
    """
    scaling, anchor_q = anchor_settings(system, config) if settings is None else settings
    passed, best = [], None
    for form in anchor_forms(config):
        try:
            anchor = _anchor_of_form(system, config, scaling, anchor_q, form)
        except (ValueError, np.linalg.LinAlgError) as exc:
            passed.append(f"'{form}' gave no positive-definite R ({str(exc).split(';')[0]})")
            continue
        cond_P, cond_R = p_condition(system, anchor.P, scaling), p_condition(system, anchor.R, scaling, inverse=True)
        if cond_P <= MAX_P_COND and cond_R <= MAX_R_COND:
            return anchor, form, "; ".join(passed)
        passed.append(f"'{form}' gave cond(P) = {cond_P:.3g}" if cond_P > MAX_P_COND else f"'{form}' gave cond(R) = {cond_R:.3g}")
        excess = max(cond_P / MAX_P_COND, cond_R / MAX_R_COND)
        if best is None or excess < best[2]:
            best = (anchor, form, excess)
    if best is not None:
        return best[0], best[1], "; ".join(passed)
    raise IdapbcError(
        f"no form of the LQR anchor of {system.name} has a positive-definite R at anchor_q = {anchor_q:g}: {'; '.join(passed)}. "
        "Fix: set anchor_q (e.g. 1 or 10) and scaling = 'box' in the --config file."
    )


def p_condition(system: System, P: np.ndarray, scaling: str, inverse: bool = False) -> float:
    """cond(P) in the networks' units: of SPS, S = diag(`half_widths`), under box scaling; else of P.
    ``inverse``: of a matrix that scales as P⁻¹ does (the damping R): of S⁻¹PS⁻¹ under box scaling."""
    if scaling == "box":
        half = half_widths(system)
        half = 1.0 / half if inverse else half
        P = half[:, None] * P * half[None, :]
    return float(np.linalg.cond(P))


def _anchor_of_form(system: System, config: TrainConfig, scaling: str, anchor_q: float, form: str) -> LinearAnchor:
    """The anchor for explicit settings and form of P: Q = anchor_q·I and λ_max(P) = 1 (``scaling="none"``), or
    λ_max(SPS) = 1 with S = diag(`half_widths`) (``"box"``), where Q = anchor_q·I too unless
    ``config.anchor_weight == "box"`` (then Q = anchor_q·diag(1/s²)); in either case a prismatic
    coordinate's weight multiplied by ``config.anchor_cart`` (0: `AUTO_CART_WEIGHTS`' choice)."""
    A, Bx = system.linearization()
    half = half_widths(system)
    box = scaling == "box"
    Q = _state_weight(system, config, scaling, anchor_q)
    Q = _with_cart(Q, prismatic_positions(system), _cart_weight(system, config, A, Bx, Q))
    if form == "riccati":
        kw = dict(P_mode="riccati")
    elif form == "fit":
        riccati = lqr_anchor(A, Bx, Q=Q, P_mode="riccati")
        Q_fit = box_fitted_weight(riccati.A_cl, half)
        P_fit = lqr_anchor(A, Bx, Q=Q, P_mode="lyapunov", Q_lyap=Q_fit).P
        better = inscribed_share(P_fit, half) > inscribed_share(riccati.P, half)
        kw = dict(P_mode="lyapunov", Q_lyap=Q_fit) if better else dict(P_mode="riccati")
    else:
        kw = dict(P_mode="lyapunov", Q_lyap=np.diag(1.0 / half**2) if form == "box" else None)
    if not box:
        return lqr_anchor(A, Bx, Q=Q, scale="unit", **kw)
    P = lqr_anchor(A, Bx, Q=Q, scale=None, **kw).P  # λ_max(SPS) = 1: H_d ≈ ½zᵀ(SPS)z ≤ ½‖z‖² in box units
    return lqr_anchor(A, Bx, Q=Q, scale=1.0 / np.linalg.eigvalsh(half[:, None] * P * half[None, :]).max(), **kw)


def inscribed_share(P: np.ndarray, half: np.ndarray) -> float:
    """Volume share of the box |δ_i| ≤ half_i taken by the largest ellipsoid {δᵀPδ ≤ c} whose
    tangent points on the faces, δ_i = ±half_i, c = min_i half_i²/(P⁻¹)_ii, lie inside the box."""
    n = len(half)
    c = float(np.min(half**2 / np.diag(np.linalg.inv(P))))
    unit_ball = math.pi ** (n / 2) / math.gamma(n / 2 + 1)
    return unit_ball * c ** (n / 2) / math.sqrt(np.linalg.det(P)) / float(np.prod(2 * half))


def box_fitted_weight(A_cl: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Q' = diag(w) (n, n) whose Lyapunov matrix P (A_clᵀP + PA_cl = −Q') has the ellipsoid of
    largest volume share inside the training box (`inscribed_share`): Nelder–Mead over log w from
    three starts around diag(1/half²). The loop A_cl is untouched; only H_d's shape ½δᵀPδ changes."""
    def lyap(logw):
        P = sla.solve_continuous_lyapunov(A_cl.T, -np.diag(np.exp(_floored(logw))))
        return 0.5 * (P + P.T)

    def cost(logw):
        try:
            share = inscribed_share(lyap(logw), half)
        except np.linalg.LinAlgError:
            return 1e9
        return -math.log(share) if share > 0 and math.isfinite(share) else 1e9

    start = -2.0 * np.log(half)
    from scipy.optimize import minimize  # here, not at import (`idapbc_pin.model.resting`)

    fits = [minimize(cost, start + shift, method="Nelder-Mead", options={"maxiter": 4000, "xatol": 1e-4, "fatol": 1e-7}) for shift in (0.0, 1.0, -1.0)]
    best = min(fits, key=lambda r: r.fun)
    logw = best.x if best.fun < cost(start) else start
    return np.diag(np.exp(_floored(logw)))


#: The fitted weights span at most e^7 ≈ 1100×, so Q' (hence R_d(x*) = ½P⁻¹Q'P⁻¹) stays well conditioned.
_LOG_SPAN = 7.0


def _floored(logw: np.ndarray) -> np.ndarray:
    return np.maximum(logw, logw.max() - _LOG_SPAN)


def local_rate(anchor: LinearAnchor) -> float:
    """Decay rate (1/s) of ½δᵀPδ along the LQR loop: min over δ of −(d/dt δᵀPδ)/(δᵀPδ)."""
    P, A_cl = anchor.P, anchor.A_cl
    Qp = -(A_cl.T @ P + P @ A_cl)
    L = np.linalg.cholesky(P)
    Li = np.linalg.inv(L)
    return float(np.linalg.eigvalsh(Li @ Qp @ Li.T).min())

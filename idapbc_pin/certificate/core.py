"""A core proved from the linearisation: the largest ellipsoid {δᵀPδ < c} on which V = δᵀPδ
decreases along the loop, with the remainder bounded by one interval Jacobian, not sampled.

For δ in the ellipsoid E_c and X its bounding box (convex, so it holds the segment from x* to x),
the mean-value theorem gives F(x) = F(x*) + J δ with J in the interval Jacobian ∂F/∂x(X) (`jet.Jet`
over the one box X). With A the loop's linearisation and Δ = J − A in [Δ_c − Δ_r, Δ_c + Δ_r]:

    V̇ = δᵀ(PA + AᵀP + PΔ + ΔᵀP)δ + 2δᵀP F(x*) ≤ λ ‖δ‖² + 2‖P F(x*)‖ ‖δ‖,

λ = λ_max(M_c) + λ_max(M_r), M_c = PA + AᵀP + PΔ_c + Δ_cᵀP and M_r = |P|Δ_r + Δ_rᵀ|P|: every
symmetric matrix within M_r of M_c has its eigenvalues within λ_max(M_r) of M_c's (Weyl; Rohn 1994
for interval matrices). So, where λ < 0, V̇ < 0 on E_c wherever ‖δ‖ > ρ = 2‖P F(x*)‖ / −λ; F(x*) is the loop's residual at x* in exact arithmetic on the stored weights
(enclosed on the point box, ~1e-15), so the trajectories of E_c reach the ball ‖δ‖ ≤ ρ and stay in
{V < c}. The level is the largest of a halving search whose test holds. Eigenvalues and norms are
computed in float64 and moved by a relative `MARGIN` against their rounding.
"""

from __future__ import annotations

import numpy as np

from .interval import Interval
from .jet import Jet

__all__ = ["MARGIN", "proved_core"]

#: Relative margin on every float64 eigenvalue and norm of the test (their rounding is ~1e-15).
MARGIN = 1e-9


def _holds(P, A, x_star, field, c: float) -> float | None:
    """ρ (the inner radius) where the test of the module docstring holds on E_c, else None."""
    reach = np.sqrt(c * np.diag(np.linalg.inv(P))) * (1 + MARGIN)
    X = Interval((x_star - reach)[None], (x_star + reach)[None])
    F, keep = field(Jet.variables(X))
    F0, keep0 = field(Interval.point(x_star[None]))
    if not (keep[0] and keep0[0]):
        return None
    J = F.grad
    d_mid, d_rad = 0.5 * (J.lo[0] + J.hi[0]) - A, 0.5 * (J.hi[0] - J.lo[0])
    if not (np.isfinite(d_mid).all() and np.isfinite(d_rad).all()):
        return None
    PD = P @ d_mid
    centre = P @ A + A.T @ P + PD + PD.T
    radius = np.abs(P) @ d_rad
    rounding = (np.abs(P) @ np.abs(d_mid)) * 4 * np.finfo(np.float64).eps * P.shape[0]  # of the products P·Δ_c
    radius = radius + radius.T + rounding + rounding.T
    top = float(np.linalg.eigvalsh(0.5 * (centre + centre.T)).max()) + float(np.abs(centre).max()) * MARGIN
    top += float(np.linalg.eigvalsh(radius).max()) * (1 + MARGIN)
    if not top < 0:
        return None
    residual = np.maximum(np.abs(F0.lo[0]), np.abs(F0.hi[0]))
    return float(2 * np.linalg.norm(np.abs(P) @ residual) * (1 + MARGIN) / -top)


def proved_core(P: np.ndarray, A: np.ndarray, x_star: np.ndarray, field, c_start: float, halvings: int = 40) -> tuple[float, float]:
    """(c, ρ): the largest level c = c_start·2⁻ᵏ (k ≤ `halvings`) at which V = δᵀPδ provably
    decreases on {V < c} outside the ball ‖δ‖ ≤ ρ (module docstring), or (0, ∞) where none does.

    P (n, n) positive definite; A (n, n) the loop's linearisation at x*; field: boxes (or their
    jets) -> (F, keep) (`enclosures.loop_field`, `lqr_field`); c_start: the first level tried."""
    P, A, x_star = (np.asarray(a, np.float64) for a in (P, A, x_star))
    normP = float(np.linalg.eigvalsh(P).max()) * (1 + MARGIN)
    c = float(c_start)
    for _ in range(halvings + 1):
        with np.errstate(over="ignore", invalid="ignore"):  # an enclosure past float range fails the test
            rho = _holds(P, A, x_star, field, c)
        if rho is not None and rho < np.sqrt(c / normP):
            return c, rho
        c *= 0.5
    return 0.0, float("inf")

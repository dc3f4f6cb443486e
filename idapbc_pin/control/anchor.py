"""The LQR anchor a `System` and a `TrainConfig` give the anchored networks, and its automatic settings.

`linear.lqr_anchor` turns a linearisation (A, B) into an exact port-Hamiltonian form (P, J, R) of an
LQR loop; this module chooses that LQR problem for a system: the state weight Q (physical or box
units, weight ``anchor_q``), the shape of P (``config.anchor_p``), and the scale of P. ``"auto"`` and
``0`` in the config are resolved here (`anchor_settings`).
"""

from __future__ import annotations

import numpy as np

from ..config import TrainConfig
from ..model import System
from .linear import LinearAnchor, fastest_pole, lqr_anchor

__all__ = [
    "AUTO_ANCHOR_Q",
    "AUTO_BOX_RATIO",
    "AUTO_MAX_POLE",
    "anchor_settings",
    "half_widths",
    "local_rate",
    "system_anchor",
]


def half_widths(system: System) -> np.ndarray:
    """s (n,): half-widths of the training box around x* (the larger side)."""
    lo, hi = system.domain
    return np.maximum(hi - system.x_star, system.x_star - lo)


#: ``scaling="auto"`` picks box units when the training box's half-widths span more than this ratio.
AUTO_BOX_RATIO = 20.0
#: ``anchor_q=0`` (automatic) tries these weights in turn and keeps the first whose anchor has no pole
#: faster than ``AUTO_MAX_POLE`` 1/s (|λ|·dt ≤ 0.5 for `simulate`'s 10 ms RK4 step).
AUTO_ANCHOR_Q = (10.0, 1.0, 0.1, 0.01)
AUTO_MAX_POLE = 50.0


def anchor_settings(system: System, config: TrainConfig) -> tuple[str, float]:
    """The resolved ``(scaling, anchor_q)`` of `config` for `system` (see `TrainConfig`'s "auto" values).

    Measured (the earlier 64 × 2, 600-epoch fast preset, 200 domain states): box units took the zoo
    cartpole (half-widths spanning 65×) from 9 % to 86.5 % success and cost the paper cartpole (2×)
    70 % → 54.5 %; the Furuta pendulum in box units reached 0 / 44.5 / 51 % with anchor_q = 10 / 1 /
    0.1 (fastest anchor pole 253 / 80 / 25 1/s).
    """
    scaling = config.scaling
    if scaling == "auto":
        half = half_widths(system)
        scaling = "box" if half.max() > AUTO_BOX_RATIO * half.min() else "none"
    if config.anchor_q > 0:
        return scaling, float(config.anchor_q)
    for q in AUTO_ANCHOR_Q:
        if fastest_pole(_lqr_anchor(system, config, scaling, q).A_cl) <= AUTO_MAX_POLE:
            return scaling, q
    return scaling, AUTO_ANCHOR_Q[-1]


def system_anchor(system: System, config: TrainConfig, settings: tuple[str, float] | None = None) -> LinearAnchor:
    """The anchor (P, J, R) of `system`'s LQR loop at x* that `build_nets` pins the networks to.

    ``settings``: the resolved ``(scaling, anchor_q)`` if the caller has them; by default
    `anchor_settings(system, config)`.
    """
    scaling, anchor_q = anchor_settings(system, config) if settings is None else settings
    return _lqr_anchor(system, config, scaling, anchor_q)


def _lqr_anchor(system: System, config: TrainConfig, scaling: str, anchor_q: float) -> LinearAnchor:
    """The anchor for explicit settings: Q = anchor_q·I and λ_max(P) = 1 (``scaling="none"``), or
    Q = anchor_q·diag(1/s²) and λ_max(SPS) = 1 with S = diag(`half_widths`) (``"box"``)."""
    A, Bx = system.linearization()
    half = half_widths(system)
    box = scaling == "box"
    Q = anchor_q * (np.diag(1.0 / half**2) if box else np.eye(system.n))
    if config.anchor_p == "riccati":
        kw = dict(P_mode="riccati")
    else:
        kw = dict(P_mode="lyapunov", Q_lyap=np.diag(1.0 / half**2) if config.anchor_p == "box" else None)
    if not box:
        return lqr_anchor(A, Bx, Q=Q, scale="unit", **kw)
    P = lqr_anchor(A, Bx, Q=Q, scale=None, **kw).P  # λ_max(SPS) = 1: H_d ≈ ½zᵀ(SPS)z ≤ ½‖z‖² in box units
    return lqr_anchor(A, Bx, Q=Q, scale=1.0 / np.linalg.eigvalsh(half[:, None] * P * half[None, :]).max(), **kw)


def local_rate(anchor: LinearAnchor) -> float:
    """Decay rate (1/s) of ½δᵀPδ along the LQR loop: min over δ of −(d/dt δᵀPδ)/(δᵀPδ)."""
    P, A_cl = anchor.P, anchor.A_cl
    Qp = -(A_cl.T @ P + P @ A_cl)
    L = np.linalg.cholesky(P)
    Li = np.linalg.inv(L)
    return float(np.linalg.eigvalsh(Li @ Qp @ Li.T).min())

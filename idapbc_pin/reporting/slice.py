"""A 2-D slice through x* of the basin and of the certified sets, for the figure's last row.

The slice varies the first two state coordinates (q₀, q₁) over the verification box, the others
held at x*. On a grid of it, the closed loop of the run's law is simulated (effort limits applied;
rows stop once at rest) and each grid state marked as reaching x* or not; H_d and LQR's δᵀSδ are
evaluated on a finer grid, so that their certified levels {H_d < c} and {δᵀSδ < c_LQR} can be
drawn as contours over the basin, with the training box and the verification box.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..certificate.baseline import QuadraticLyapunov
from ..control.baseline import LQRController
from ..model.boxes import verification_box
from ..sim.integrate import simulate
from ..sim.metrics import success

__all__ = ["SliceData", "basin_slice"]


@dataclass(frozen=True, eq=False)
class SliceData:
    """What the slice panel draws.

    axes : (2,) the state indices varied;  names : their names.
    basin_a, basin_b : (k,) grid of the simulated states;  basin : (k, k) bool, [j, i] reaches x*.
    a, b : (K,) fine grid;  H, V_lqr : (K, K) H_d and δᵀSδ on it ([j, i]).
    c, c_lqr : certified levels (None: not certified, or no certificate given).
    train_box, verification_box : ((lo_a, lo_b), (hi_a, hi_b)) of each box in the slice.
    shares : {name: (certified share, invariant share)} of the training box, for the legend.
    """

    axes: tuple
    names: tuple
    basin_a: np.ndarray
    basin_b: np.ndarray
    basin: np.ndarray
    a: np.ndarray
    b: np.ndarray
    H: np.ndarray
    V_lqr: np.ndarray
    c: float | None
    c_lqr: float | None
    train_box: tuple
    verification_box: tuple
    shares: dict


def _level(region: dict | None) -> float | None:
    """The certified level of a ``sublevel`` entry of certificate.json, when its set passed."""
    if not region or not (region.get("confidence") or {}).get("passed"):
        return None
    return region.get("c")


def basin_slice(ctrl, certificate: dict | None = None, n: int = 13, T: float = 20.0, limits: bool = True, fine: int = 161) -> SliceData:
    """The slice through x* over (q₀, q₁) (module doc).

    ctrl : the run's controller (``ctrl.system``, ``ctrl.H_d``).  certificate : ``Certificate.to_dict()``
    (its verification box and levels), or None (the default verification box, no contours).
    n : basin grid points per axis (n² rollouts of `T` s).  fine : grid points per axis of the contours.
    """
    system = ctrl.system
    x_star = np.asarray(system.x_star, float)
    if certificate and certificate.get("verification_box"):
        vlo, vhi = (np.asarray(certificate["verification_box"][k], float) for k in ("lo", "hi"))
    else:
        vlo, vhi = verification_box(system)
    ia, ib = 0, 1
    lo, hi = (np.asarray(v, float) for v in system.domain)

    def grid(k):
        a, b = np.linspace(vlo[ia], vhi[ia], k), np.linspace(vlo[ib], vhi[ib], k)
        A, B = np.meshgrid(a, b)
        x = np.tile(x_star, (k * k, 1))
        x[:, ia], x[:, ib] = A.ravel(), B.ravel()
        return a, b, x

    ga, gb, x0 = grid(int(n))
    traj = simulate(system, ctrl, x0, T=T, limits=limits, stop_settled=True, stop_converged=True)
    basin = success(traj, system).reshape(int(n), int(n))
    fa, fb, xf = grid(int(fine))
    H = np.asarray(ctrl.H_d(xf), float).reshape(int(fine), int(fine))
    lqr = LQRController(system)
    V = QuadraticLyapunov(lqr.S, x_star, system.angle_mask).H_d(xf).reshape(int(fine), int(fine))
    cert = certificate or {}
    shares = {}
    inv = cert.get("invariant_share") or {}
    for name, entry in (("NIDA-PBC", cert.get("sublevel")), ("LQR", (cert.get("baseline") or {}).get("sublevel"))):
        if entry:
            shares[name] = (entry.get("covered_fraction"), inv.get(name))
    return SliceData(
        axes=(ia, ib), names=(system.state_names[ia], system.state_names[ib]),
        basin_a=ga, basin_b=gb, basin=basin, a=fa, b=fb, H=H, V_lqr=V,
        c=_level(cert.get("sublevel")), c_lqr=_level((cert.get("baseline") or {}).get("sublevel")),
        train_box=((lo[ia], lo[ib]), (hi[ia], hi[ib])), verification_box=((vlo[ia], vlo[ib]), (vhi[ia], vhi[ib])),
        shares=shares,
    )

"""Opt-in loss terms that aim H_d at a large certified set in the verification box (`certify`).

The certificate (`idapbc_pin.certificate.region`) certifies the largest {H_d < c} inside the
verification box V_box on which H_d decreases along the true saturated loop. Two named terms
(`TrainConfig.verification_terms`) ask for that while training:

* ``set_decrease``  mean over samples x of V_box inside {H_d < c_V} (all but a tiny core,
  H_d ≥ `CORE`·c_V, where rounding decides the sign), of
  max(0, Ḣ_d/H_d + λ) with Ḣ_d = ∇H_dᵀ(f + g·sat(u)) along the true loop with the effort limits
  and λ = `RATE`; c_V = min of H_d on samples of V_box's faces (no gradient). The samples where it
  is positive are kept (`KEEP` of the worst) and revisited the next epoch: counter-examples
  kept across epochs.
* ``set_coverage``  mean over the training samples of max(0, log(H_d/c_V)), c_V with its gradient:
  H_d high on V_box's faces relative to its values in the training box, so that {H_d < c_V}
  covers the training box (log: the e-folds by which a sample lies outside the set, whatever
  H_d's scale).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ..control.nets import IdaPbcNets

__all__ = ["CORE", "KEEP", "RATE", "box_faces", "verification_terms"]

#: λ of ``set_decrease`` (1/s): the decay rate asked of H_d/H_d in the set.
RATE = 0.01

#: The core left out of ``set_decrease``, as a share of c_V.
CORE = 1e-6

#: Counter-examples kept for the next epoch, as a share of the epoch's V_box samples.
KEEP = 0.25


def box_faces(lo: np.ndarray, hi: np.ndarray, n: int, gen: torch.Generator) -> np.ndarray:
    """(n, dim) uniform samples of the faces of [lo, hi]: a uniform point of the box with one
    uniformly chosen coordinate moved to its lower or upper bound."""
    lo_t, hi_t = torch.as_tensor(lo, dtype=torch.float64), torch.as_tensor(hi, dtype=torch.float64)
    x = lo_t + (hi_t - lo_t) * torch.rand(n, lo_t.numel(), generator=gen, dtype=torch.float64)
    axis = torch.randint(0, lo_t.numel(), (n,), generator=gen)
    upper = torch.rand(n, generator=gen, dtype=torch.float64) < 0.5
    rows = torch.arange(n)
    x[rows, axis] = torch.where(upper, hi_t[axis], lo_t[axis])
    return x.numpy()


def verification_terms(
    nets: IdaPbcNets, H_train: Tensor, x_v: Tensor, f_v: Tensor, x_face: Tensor, effort: Tensor | None
) -> tuple[dict[str, Tensor], Tensor]:
    """``set_decrease`` and ``set_coverage`` (module doc) and the counter-examples to keep.

    Parameters
    ----------
    H_train : (N,) H_d at the epoch's training samples, with its graph.
    x_v : (K, n) samples of V_box (fresh ones and the kept counter-examples); f_v : (K, n) f(x_v).
    x_face : (F, n) samples of V_box's faces.  effort : (m,) effort limits (None: unlimited).

    Returns
    -------
    ({"set_decrease", "set_coverage"} scalars with graphs, (k, n) counter-examples, no graph).
    """
    H_face = nets.H(x_face)
    c_v = H_face.min()
    x = x_v.detach().requires_grad_(True)
    H, dH, _, _, f_d = nets.desired(x, create_graph=True)
    u = nets.control(f_v, f_d)
    if effort is not None:
        u = torch.maximum(torch.minimum(u, effort), -effort)
    x_dot = f_v + u @ nets.g.T
    rate = (dH * x_dot).sum(-1) / H.clamp(min=torch.finfo(H.dtype).tiny)
    level = c_v.detach()
    mask = ((H.detach() < level) & (H.detach() >= CORE * level)).to(H.dtype)
    residual = torch.relu(rate + RATE) * mask
    decrease = residual.sum() / mask.sum().clamp(min=1)
    tiny = torch.finfo(H.dtype).tiny
    coverage = torch.relu(torch.log(H_train.clamp(min=tiny) / c_v.clamp(min=tiny))).mean()
    bad = residual.detach() > 0
    keep = max(1, int(KEEP * x_v.shape[0]))
    worst = torch.argsort(residual.detach(), descending=True)[: min(keep, int(bad.sum()))]
    return {"set_decrease": decrease, "set_coverage": coverage}, x_v.detach()[worst]

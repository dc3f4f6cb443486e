"""The least-squares fit of a recovery law to labels (`recover`, `refit`): `fit_recovery_law`.

Labels are states X (K, n) and the inputs U (K, m) the teacher or a plan applied there (within the
limits ū). The fit is in units of ū, on δ/s (δ = wrap(x − x*), s the training box's half-widths),
by `trajectory.fit.fit_mlp` (Adam on minibatches of `RecoveryConfig.batch`, float32).

* **Direct form**: ū ⊙ tanh(MLP(δ/s)) ≈ U, squared error.
* **Residual form** (`base` given): clip(b + MLP(δ/s), ±1) ≈ U/ū with b = clip(u_IDA-PBC(X)/ū, ±1)
  the IDA-PBC law's own inputs (`base_inputs`). A label at the limit (|U| = ū) only asks the sum
  to reach that side of the limit, max(0, 1 − sign(U)·(b + MLP))², so the clip's flat part does not
  stall the fit; other labels are fitted by the squared error of the clipped sum. Where the labels
  are the IDA-PBC law's inputs (often most of them) the MLP only has to learn zero.
"""

from __future__ import annotations

import numpy as np
import torch

from ..model.angles import wrap_angles
from ..trajectory.fit import fit_mlp
from .law import RecoveryLaw

__all__ = ["base_inputs", "fit_job", "fit_recovery_law"]

#: Chunk of states per call of the IDA-PBC law in `base_inputs`.
_BASE_CHUNK = 20_000


def base_inputs(networks, X: np.ndarray, effort: np.ndarray) -> np.ndarray:
    """The IDA-PBC law's inputs at the labels, clipped to ±ū: X (K, n) -> (K, m), N·m or N.
    `networks` is the run's controller without a fallback (the input a `RecoveryLaw.apply` gets)."""
    effort = np.asarray(effort, dtype=np.float64)
    u = [networks(X[k : k + _BASE_CHUNK]) for k in range(0, len(X), _BASE_CHUNK)]
    return np.clip(np.concatenate(u).reshape(len(X), -1), -effort, effort)


def fit_recovery_law(system, X: np.ndarray, U: np.ndarray, width: int, steps: int, seed: int = 0, base: np.ndarray | None = None,
                     progress: str | None = None, batch: int = 1024) -> tuple[RecoveryLaw, float]:
    """Least-squares fit of the recovery law to labels X (K, n), U (K, m) in units of ū; with `base`
    (K, m), the IDA-PBC law's clipped inputs at X (`base_inputs`), the residual form. Returns the law
    (inner box empty) and the last minibatch's loss (the mean squared error, the hinge on labels at
    the limit in the residual form). `progress`: the label of a bar over the steps (None: no bar);
    `batch`: labels per minibatch. The fit runs in float32 (the law's arrays are float64)."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in system.domain)
    effort = np.asarray(system.effort, dtype=np.float64)
    scale = (hi - lo) / 2
    x_star, mask = np.asarray(system.x_star, dtype=np.float64), np.asarray(system.angle_mask, dtype=bool)
    F = wrap_angles(X - x_star, mask) / scale
    (weights, biases), loss = fit_mlp(F, U / effort, width, steps, seed, None if base is None else np.asarray(base, dtype=np.float64) / effort,
                                      progress, batch)
    return RecoveryLaw(weights, biases, x_star, scale, effort, mask, np.zeros(system.n), residual=base is not None), loss


def fit_job(job) -> tuple[RecoveryLaw, float]:
    """Worker: `fit_recovery_law` (system, X, U, width, steps, seed, base, progress, batch) with one torch thread."""
    torch.set_num_threads(1)
    return fit_recovery_law(*job)

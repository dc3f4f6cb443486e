"""The least-squares fit of a recovery law to labels (`recover`, `refit`): `fit_recovery_law`.

Labels are states X (K, n) and the inputs U (K, m) the teacher or a plan applied there (within the
limits ū). The fit is in units of ū, on δ/s (δ = wrap(x − x*), s the training box's half-widths),
by Adam on minibatches (`RecoveryConfig.batch`) for `steps` steps, the rate divided by 10 for the
last third, in float32: the fit's cost is the MLP's products on the minibatch, and float32 halves it.

* **Direct form**: ū ⊙ tanh(MLP(δ/s)) ≈ U, squared error.
* **Residual form** (`base` given): clip(b + MLP(δ/s), ±1) ≈ U/ū with b = clip(u_IDA-PBC(X)/ū, ±1)
  the IDA-PBC law's own inputs (`base_inputs`). A label at the limit (|U| = ū) only asks the sum
  to reach that side of the limit, max(0, 1 − sign(U)·(b + MLP))², so the clip's flat part does not
  stall the fit; other labels are fitted by the squared error of the clipped sum. Where the labels
  are the IDA-PBC law's inputs (often most of them) the MLP only has to learn zero.
"""

from __future__ import annotations

import sys

import numpy as np
import torch
from tqdm.auto import tqdm

from ..model.angles import wrap_angles
from .law import RecoveryLaw

__all__ = ["base_inputs", "fit_job", "fit_mlp", "fit_recovery_law"]

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


def fit_mlp(F: np.ndarray, Y: np.ndarray, width: int, steps: int, seed: int = 0, base: np.ndarray | None = None,
            progress: str | None = None, batch: int = 1024) -> tuple[tuple[tuple, tuple], float]:
    """The least-squares fit of tanh(MLP(F)) ≈ Y (the direct form) or of clip(base + MLP(F), ±1) ≈ Y
    (the residual form, `base` (K, m)), features F (K, d), targets Y (K, m) in units of ū: two tanh
    layers of `width`, Adam on minibatches of `batch` for `steps` steps (the rate divided by 10 for
    the last third), float32, seeded by `seed`. Returns ((weights, biases) as float64 arrays per
    layer, the last minibatch's loss); `progress`: the label of a bar over the steps (None: no bar)."""
    gen = torch.Generator().manual_seed(seed)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        layers = [torch.nn.Linear(F.shape[1], width), torch.nn.Linear(width, width), torch.nn.Linear(width, Y.shape[1])]
    net = torch.nn.Sequential(layers[0], torch.nn.Tanh(), layers[1], torch.nn.Tanh(), layers[2]).float()
    F = torch.as_tensor(F, dtype=torch.float32)
    Y = torch.as_tensor(Y, dtype=torch.float32)
    B = None if base is None else torch.as_tensor(base, dtype=torch.float32)
    at_limit = Y.abs() >= 1.0 - 1e-9
    opt = torch.optim.Adam(net.parameters(), 3e-3)
    loss = torch.zeros(())
    bar = tqdm(total=steps, desc=progress, unit="step", disable=progress is None, dynamic_ncols=True, file=sys.stderr, miniters=100)
    for k in range(steps):
        bar.update(1)
        if k == 2 * steps // 3:
            opt.param_groups[0]["lr"] = 3e-4
        idx = torch.randint(0, len(F), (min(batch, len(F)),), generator=gen)
        if B is None:
            loss = (torch.tanh(net(F[idx])) - Y[idx]).pow(2).mean()
        else:
            total, y = B[idx] + net(F[idx]), Y[idx]
            loss = torch.where(at_limit[idx], torch.relu(1.0 - torch.sign(y) * total), total.clamp(-1.0, 1.0) - y).pow(2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    bar.close()
    weights = tuple(m.weight.detach().double().numpy().copy() for m in layers)
    biases = tuple(m.bias.detach().double().numpy().copy() for m in layers)
    return (weights, biases), float(loss.detach())


def fit_job(job) -> tuple[RecoveryLaw, float]:
    """Worker: `fit_recovery_law` (system, X, U, width, steps, seed, base, progress, batch) with one torch thread."""
    torch.set_num_threads(1)
    return fit_recovery_law(*job)

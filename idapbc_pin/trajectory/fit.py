"""The least-squares fit of a state feedback to labels from plans: `fit_mlp`.

Labels are features F (K, d) of states and the inputs Y (K, m) a teacher or a plan applied there, in
units of the limits ū. Adam on minibatches for `steps` steps, the rate divided by 10 for the last
third, in float32: the fit's cost is the MLP's products on the minibatch, and float32 halves it.
The laws of the stages (`recovery.fit.fit_recovery_law`, the swing-up law) are this MLP with their
own features.
"""

from __future__ import annotations

import sys

import numpy as np
import torch
from tqdm.auto import tqdm

__all__ = ["fit_mlp"]


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

"""The `rollout` term: the cost of short simulations of the true, saturated closed loop.

The paper's residuals shape H_d, J_d and R_d one sample at a time; nothing in them sees where the
real loop goes once the actuators saturate. This term does. From K start states x₀ drawn uniformly in
x* + b·(X − x*) (X the training box, b = ``rollout_box``), it integrates

    ẋ = f(x) + g·sat(u(x)),   u(x) = (gᵀg)⁻¹gᵀ(f̃_d(x) − f(x))        (f: the plant, Pinocchio)

with explicit Euler steps h over a horizon T, and averages over the last ``tail`` seconds

    c(x) = log(1 + Σ_i (x_i − x*_i)² / s_i²)        (s: the box's half-widths, angles wrapped)

so a trajectory still far from x* costs about log of its distance and never dominates the batch.
Back-propagation runs through the whole trajectory (back-propagation through time): through the
networks by autograd, and through the plant by `PlantDrift`, whose backward pass multiplies by the
plant's exact ∂f/∂x (`System.df_dx`). sat clips u to the effort limits, so its gradient is zero on a
saturated input, as the real loop is insensitive there. A trajectory that leaves 1e4 box units
is frozen (its cost stays at that cap): it cannot blow up the gradient.

The rollout epochs' weights replace the residual-trained ones only if the real loop does at least
as well from fresh states (`rollout_gate`); the trainer keeps the residual-trained weights in
``checkpoints/pre_rollout.pt`` for that comparison.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ..control.nets import IdaPbcNets
from ..model import System
from ..sim.compare import compare_laws
from ..sim.states import scaled_box, uniform_states
from ..sim.step import judge_step

__all__ = ["PlantDrift", "rollout_cost", "rollout_gate", "rollout_starts", "saturated_field"]

#: A trajectory whose Σ (δ_i / s_i)² passes this stops being integrated (it has left for good).
ESCAPED = 1e8


class PlantDrift(torch.autograd.Function):
    """f(x) of a `System` as a torch function: (N, n) -> (N, n), float64 numpy underneath.

    Forward calls ``system.f``; backward returns gradᵀ·∂f/∂x from ``system.df_dx`` (exact first
    derivatives from Pinocchio, second-order terms by central differences; DESIGN §2). The plant
    has no weights, so only the state receives a gradient.
    """

    @staticmethod
    def forward(ctx, x: Tensor, system: System) -> Tensor:
        xn = x.detach().to("cpu", torch.float64).numpy()
        ctx.system, ctx.xn = system, xn
        return torch.as_tensor(system.f(xn), dtype=x.dtype, device=x.device)

    @staticmethod
    def backward(ctx, grad: Tensor):
        jac = torch.as_tensor(ctx.system.df_dx(ctx.xn), dtype=grad.dtype, device=grad.device)  # (N, n, n)
        return (grad.unsqueeze(1) @ jac).squeeze(1), None


def rollout_starts(system: System, count: int, box: float, gen: torch.Generator) -> np.ndarray:
    """(count, n) start states, uniform in x* + b·(X − x*) (b = `box`, X the training box), from `gen`."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in system.domain)
    r = torch.rand(count, system.n, generator=gen, dtype=torch.float64).numpy()
    x_star = np.asarray(system.x_star, dtype=np.float64)
    return x_star + box * (lo + (hi - lo) * r - x_star)


def _wrapped(nets: IdaPbcNets, x: Tensor) -> Tensor:
    """x* + wrap(x − x*) on the angles the law wraps (`IdaPbcNets.wrap`), differentiable."""
    if nets.angle_mask is None:
        return x
    d = x - nets.x_star
    return nets.x_star + torch.where(nets.angle_mask, torch.atan2(torch.sin(d), torch.cos(d)), d)


def saturated_field(nets: IdaPbcNets, system: System, x: Tensor, effort: Tensor) -> Tensor:
    """ẋ = f(x) + g·sat(u(x)) of the true closed loop: (N, n) -> (N, n), differentiable in x and the weights.

    ``effort`` (m,) holds the limits (inf: none). f is 2π-periodic in the angles, so f at the state
    equals f at its wrapped copy; the networks see the wrapped one, as the controller does.
    """
    f = PlantDrift.apply(x, system)
    f_d = nets.desired(_wrapped(nets, x), create_graph=True)[4]
    u = torch.clamp(nets.control(f, f_d), min=-effort, max=effort)
    return f + u @ nets.g.T


def rollout_cost(nets: IdaPbcNets, system: System, x0: Tensor, horizon: float, step: float, tail: float, effort: Tensor) -> Tensor:
    """Mean of log(1 + ‖(x − x*)/s‖²) over the last `tail` seconds of Euler rollouts from x0 (K, n).

    Parameters
    ----------
    horizon, step, tail : T, h and the averaging window, in seconds (tail ≤ T).
    effort : (m,) effort limits (inf where a joint has none).

    Returns a scalar tensor, differentiable w.r.t. the networks' weights.
    """
    lo, hi = system.domain
    inv_s2 = torch.as_tensor(4.0 / (np.asarray(hi) - np.asarray(lo)) ** 2, dtype=x0.dtype, device=x0.device)
    steps = max(1, round(horizon / step))
    kept = max(1, min(steps, round(tail / step)))
    x, cost = x0, x0.new_zeros(())
    alive = torch.ones(len(x0), dtype=torch.bool, device=x0.device)
    for k in range(steps):
        x_next = x + step * saturated_field(nets, system, x, effort)
        dist = ((_wrapped(nets, x_next) - nets.x_star) ** 2 * inv_s2).sum(-1)
        alive = alive & torch.isfinite(dist).detach() & (dist < ESCAPED).detach()
        x = torch.where(alive[:, None], x_next, x.detach())
        if k >= steps - kept:
            dist = torch.where(alive, dist, torch.full_like(dist, ESCAPED))
            cost = cost + torch.log1p(dist).mean() / kept
    return cost


#: States of the gate that decides whether the rollout epochs' weights are kept, and its seed offset
#: (their own stream: neither the training samples nor the evaluation's seed-0 states).
GATE_STATES = 100
GATE_SEED = 7919
#: The gate's horizon, s (DESIGN §4).
GATE_HORIZON = 20.0


def rollout_gate(system: System, before, after, box: float, seed: int) -> dict:
    """Success (DESIGN §4: T = 20 s, limits applied) of the weights before and after the rollout epochs.

    `before`, `after` : controllers ((N, n) -> (N, m)); box : the rollout box's scale b; seed : the
    run's seed. Both are simulated from the same `GATE_STATES` uniform states of x* + b·(X − x*),
    drawn with seed ``GATE_SEED + seed``. The rollout weights are kept when they do at least as well:
    back-propagation through a saturated swing can also lead somewhere worse (a link that ends up
    spinning for good, say).

    Returns {"states", "before", "after" (success rates in [0, 1]), "kept" (bool)}.
    """
    x0 = uniform_states(system, GATE_STATES, scaled_box(system, box), GATE_SEED + seed)
    dt = judge_step(system, {"before": before, "after": after}, GATE_HORIZON, None)
    (ok_before, _), (ok_after, _) = compare_laws(system, [(before, x0), (after, x0)], T=GATE_HORIZON, dt=dt, stop_settled=False)
    rates = {"before": float(ok_before.mean()), "after": float(ok_after.mean())}
    return {"states": GATE_STATES, **rates, "kept": rates["after"] >= rates["before"]}

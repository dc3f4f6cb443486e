"""The paper's residuals (§IV-B) as named terms, plus a decay-rate term, and the adaptive weights.

For samples x (N, n), with d = 1 where H_d(x) ≥ ε (outside H_ε, the dissipation set D):

* ``matching``        f_m   = (1 − d)‖μ‖                        (eq. switch_var)
* ``dissipation``     f_sd1 = d·max(0, ‖ξ‖ − κ‖∇H_d‖)           (robustness residual)
* ``damping_floor``   f_sd2 = d·max(0, κ − σ_min(R_d))
* ``local_stability`` f_dm  = (1 − d)‖∂μ/∂x‖_F                  (Theorem 2, eq. mu_bound_les)
* ``decay``           d·max(0, Ḣ_d/H_d + λ), Ḣ_d = ∇H_dᵀ(f̃_d + ξ) along the true closed loop
  (DESIGN §2 lesson 1: nothing in the paper's loss rewards speed).
* ``effort``          Σ_i max(0, |u_i| − ū_i)/ū_i over the samples of the candidate certified set
  {H_d < c}, c = min of H_d on samples of the box faces (the largest sublevel set that stays in the
  box), ū the actuators' effort limits: the certificate is checked with the saturated law, so the
  set it can certify is where u stays within the limits. Zero for robots without limits.
* ``set_decrease``, ``set_coverage``  opt-in terms aimed at the certified set in the verification
  box (`idapbc_pin.training.verification`); zero unless ``TrainConfig.verification_terms``.
* ``rollout``         the cost of simulations of the true saturated loop (`rollout.rollout_cost`);
  zero here, set by the trainer in the last ``rollout_epochs`` epochs, which train on it alone.

Inside terms are averaged over the inside samples and outside terms over the outside ones
(DESIGN lesson 3), so each term is a mean residual whatever ε is. ∂μ/∂x = g⊥(∂f̃_d/∂x − ∂f/∂x) is
exact: autograd through the networks and the plant's ∂f/∂x, only on the inside samples (lesson 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from ..control.nets import IdaPbcNets

__all__ = ["TERMS", "AdaptiveWeights", "loss_terms"]

TERMS = ("matching", "dissipation", "damping_floor", "local_stability", "decay", "effort", "set_decrease", "set_coverage", "rollout")


def _masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    return (values * mask).sum() / mask.sum().clamp(min=1)


def _desired_jacobian(nets: IdaPbcNets, x: Tensor) -> Tensor:
    """∂f̃_d/∂x at the states x (K, n): (K, n, n), graph kept.

    One forward pass on n copies of the states and one backward pass: output i of copy i,
    differentiated w.r.t. copy i, is row i of every state's Jacobian (f̃_d acts row by row, so the
    copies never mix). A loop over the n outputs would traverse the graph n times.
    """
    K, n = x.shape
    copies = x.detach().repeat(n, 1).requires_grad_(True)  # (n K, n): copy i in rows i K … (i + 1) K − 1
    f_d = nets.desired(copies, create_graph=True)[4].view(n, K, n)
    own = f_d.diagonal(dim1=0, dim2=2)  # (K, n): output i of copy i
    rows = torch.autograd.grad(own.sum(), copies, create_graph=True)[0]  # (n K, n)
    return rows.view(n, K, n).transpose(0, 1)


def loss_terms(
    nets: IdaPbcNets,
    x: Tensor,
    f: Tensor,
    epsilon: Tensor,
    kappa: float,
    df_dx_inside: Tensor | None = None,
    inside: Tensor | None = None,
    x_face: Tensor | None = None,
    effort: Tensor | None = None,
) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """Residual terms (scalars, differentiable w.r.t. the weights) and diagnostics.

    Parameters
    ----------
    x : (N, n) samples; f : (N, n) plant drift f(x) (a constant w.r.t. the weights).
    epsilon : scalar tensor, level of H_ε.
    kappa : κ of f_sd1 and f_sd2.
    df_dx_inside : (K, n, n) ∂f/∂x on the inside samples x[inside] (None: skip f_dm).
    inside : (N,) bool, the samples with H_d < ε used for df_dx_inside (recomputed if None).
    x_face : (K, n) samples of the training box's faces (for the level c of the `effort` term).
    effort : (m,) effort limits (None, or all inf: no `effort` term).
    """
    x = x.detach().requires_grad_(True)
    H, dH, J, R, f_d = nets.desired(x, create_graph=True)
    if inside is None:
        inside = H.detach() < epsilon
    d = (~inside).to(x.dtype)
    mu = nets.mismatch(f, f_d)
    xi = nets.xi(mu)
    mu_norm = mu.norm(dim=-1)
    grad_norm = dH.norm(dim=-1)
    sigma_min = torch.linalg.eigvalsh(R)[:, 0]
    H_dot = (dH * (f_d + xi)).sum(-1)
    rate = H_dot / H.clamp(min=torch.finfo(x.dtype).tiny)

    terms = {
        "matching": _masked_mean(mu_norm, 1 - d),
        "dissipation": _masked_mean(torch.relu(xi.norm(dim=-1) - kappa * grad_norm), d),
        "damping_floor": _masked_mean(torch.relu(kappa - sigma_min), d),
        "decay": _masked_mean(torch.relu(rate + nets.decay_rate), d) if float(nets.decay_rate) > 0 else x.new_zeros(()),
        "local_stability": x.new_zeros(()),
        "effort": x.new_zeros(()),
        "set_decrease": x.new_zeros(()),
        "set_coverage": x.new_zeros(()),
        "rollout": x.new_zeros(()),  # set by the trainer in its `rollout_epochs` (`rollout.rollout_cost`)
    }
    c_face = None
    if x_face is not None:
        with torch.no_grad():
            c_face = nets.H(x_face).min()
    if effort is not None and c_face is not None and bool(torch.isfinite(effort).any()):
        u = nets.control(f, f_d)
        limit = torch.where(torch.isfinite(effort), effort, torch.ones_like(effort))
        excess = (torch.relu(u.abs() - effort) / limit).sum(-1)
        terms["effort"] = _masked_mean(excess, (H.detach() < c_face).to(x.dtype))
    if df_dx_inside is not None and int(inside.sum()) > 0:
        dfd_dx = _desired_jacobian(nets, x.detach()[inside])
        dmu_dx = nets.g_perp @ (dfd_dx - df_dx_inside)
        terms["local_stability"] = dmu_dx.flatten(1).norm(dim=-1).mean()
    diagnostics = {
        "H": H,
        "inside_share": (1 - d).mean().detach(),
        "dissipation_ok": _masked_mean(((dH.unsqueeze(-2) @ R @ dH.unsqueeze(-1)).squeeze() > (dH * xi).sum(-1)).to(x.dtype), d).detach(),
        "max_mu": mu_norm.max().detach(),
        "sublevel_share": (H.detach() < c_face).to(x.dtype).mean() if c_face is not None else x.new_zeros(()),
    }
    return terms, diagnostics


@dataclass
class AdaptiveWeights:
    """r_i ← γ r_i + α f_i / max_j f_j (paper §IV-B), one weight per named term, starting at 1."""

    gamma: float
    alpha: float
    weights: dict[str, float]

    @classmethod
    def start(cls, gamma: float, alpha: float, names=TERMS) -> "AdaptiveWeights":
        return cls(gamma, alpha, {name: 1.0 for name in names})

    def total(self, terms: dict[str, Tensor]) -> Tensor:
        """L = Σ r_i f_i."""
        return sum(self.weights[k] * v for k, v in terms.items())

    def update(self, values: dict[str, float]) -> None:
        top = max(values.values())
        for k, v in values.items():
            self.weights[k] = self.gamma * self.weights[k] + (self.alpha * v / top if top > 0 else 0.0)

"""The paper's pointwise quantities along a controller: H_d, ∇H_d, J_d, R_d, μ, ξ, Ḣ_d, ∇²H_d.

**Sign of ξ.** Proposition 1's proof needs G ẋ = (gᵀf̃_d; g⊥f̃_d) + (0; g⊥(f − f̃_d)), so the
perturbation that actually acts on the closed loop ẋ = f̃_d + ξ is ξ = G⁻¹(0; g⊥(f − f̃_d)) =
−G⁻¹(0; μ) with μ = −g⊥(f − f̃_d) as eq. ``mismatch`` writes it (and as `Controller.mismatch`
returns it): the paper's eq. mismatch and its proof disagree by a sign. Here ξ is the perturbation
of the true closed loop, so that Ḣ_d = ∇H_dᵀ(f̃_d + ξ) = −(∇H_dᵀR_d∇H_d − ∇H_dᵀξ) when J_d is skew:
the margin of the dissipation inequality *is* −Ḣ_d. Both are computed independently (Ḣ_d from
the control law u = ctrl(x) itself) and their agreement is reported as a consistency check; the
share satisfied with the literal sign (ξ = +G⁻¹(0; μ)) is reported too, for comparison.

The controller interface used: ``ctrl.system`` (a `System`), ``ctrl(x) -> u`` (N, m),
``ctrl.H_d(x)`` (N,), ``ctrl.grad_H_d(x)`` (N, n), ``ctrl.J_d(x)``, ``ctrl.R_d(x)`` (N, n, n);
optionally ``ctrl.hess_H_d(x)`` (N, n, n) (else autograd through ``ctrl.nets.H`` when it is a
torch module, else central differences of ``grad_H_d``) and ``ctrl.eigenvalues_at_target()`` (else
central differences of the closed loop at x*).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ClosedLoopTerms", "closed_loop_terms", "eigenvalues_at_target", "hessians"]


@dataclass(frozen=True, eq=False)
class ClosedLoopTerms:
    """The paper's quantities at states x (N, n), numpy float64.

    Attributes
    ----------
    x : (N, n) states (q, p).
    H : (N,) H_d;  dH : (N, n) ∇H_d;  J, R : (N, n, n) J_d, R_d.
    f : (N, n) drift of the controller's model;  f_d : (N, n) f̃_d = (J_d − R_d)∇H_d.
    mu : (N, n − m) mismatch μ = g⊥(f̃_d − f) (eq. mismatch, as `Controller.mismatch`).
    xi : (N, n) ξ = G⁻¹(0; −μ), the perturbation of the true closed loop ẋ = f̃_d + ξ (module doc).
    dissipation : (N,) ∇H_dᵀR_d∇H_d (left side of eq. damping_assign_relax_tilde).
    drive : (N,) ∇H_dᵀξ (right side).
    u : (N, m) the applied input sat(u_law), clipped to the input bound (u_law where there is none);
        u_law = ctrl(x), the law the controller applies (with its fallback, if it has one).
    H_dot : (N,) ∇H_dᵀ(f + g u), the true-loop Ḣ_d with the applied input.
    H_dot_law : (N,) ∇H_dᵀ(f + g u_IDA), the unsaturated IDA-PBC law's Ḣ_d (= −margin, Proposition 1);
        u_IDA = ``ctrl.with_fallback(None)(x)`` for a controller with a fallback (a box fallback's
        inside gain, or a recovery law, changes the law inside the box), else u_law.
    saturated : (N,) bool, the law's input exceeds the bound (u ≠ u_law).
    """

    x: np.ndarray
    H: np.ndarray
    dH: np.ndarray
    J: np.ndarray
    R: np.ndarray
    f: np.ndarray
    f_d: np.ndarray
    mu: np.ndarray
    xi: np.ndarray
    dissipation: np.ndarray
    drive: np.ndarray
    u: np.ndarray
    H_dot: np.ndarray
    H_dot_law: np.ndarray
    saturated: np.ndarray

    @property
    def margin(self) -> np.ndarray:
        """(N,) ∇H_dᵀR_d∇H_d − ∇H_dᵀξ: > 0 where the dissipation inequality holds."""
        return self.dissipation - self.drive

    @property
    def margin_literal_sign(self) -> np.ndarray:
        """(N,) the margin with ξ = +G⁻¹(0; μ), eq. mismatch's sign taken literally (not the true loop)."""
        return self.dissipation + self.drive


def _f64(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float64)


def closed_loop_terms(ctrl, x, system=None, bound=None) -> ClosedLoopTerms:
    """Evaluate H_d, ∇H_d, J_d, R_d, μ, ξ, both sides of the dissipation inequality and the true Ḣ_d.

    Parameters
    ----------
    ctrl : controller interface (see the module docstring).
    x : (N, n) states (q, p).
    system : the model the controller was designed on (default ``ctrl.system``); its f, g, g⊥
        and G enter μ, ξ and Ḣ_d.
    bound : None or (m,) input bound (N·m or N, +inf where none): Ḣ_d is then taken along the
        saturated loop f + g·sat(u) (`idapbc_pin.sim.limits`).
    """
    system = ctrl.system if system is None else system
    x = np.atleast_2d(_f64(x))
    H = _f64(ctrl.H_d(x)).reshape(x.shape[0])
    dH = _f64(ctrl.grad_H_d(x)).reshape(x.shape)
    J = _f64(ctrl.J_d(x)).reshape(x.shape + (x.shape[1],))
    R = _f64(ctrl.R_d(x)).reshape(J.shape)
    f = _f64(system.f(x))
    f_d = np.einsum("nij,nj->ni", J - R, dH)
    mu = np.einsum("nij,nj->ni", _f64(system.g_perp(x)), f_d - f)
    rhs = np.concatenate([np.zeros((x.shape[0], system.m)), -mu], axis=1)
    xi = np.linalg.solve(_f64(system.G(x)), rhs[..., None])[..., 0]
    u_law = _f64(ctrl(x)).reshape(x.shape[0], system.m)
    u = u_law if bound is None else np.clip(u_law, -_f64(bound), _f64(bound))
    g = _f64(system.g(x))
    # Proposition 1 holds for the IDA-PBC law itself, not for a law the run applies beside it (a
    # fallback's inside gain, a recovery law): Ḣ_d of the IDA-PBC law for the identity, Ḣ_d of the
    # applied law for the certificate.
    u_ida = _f64(ctrl.with_fallback(None)(x)).reshape(u_law.shape) if getattr(ctrl, "fallback", None) is not None else u_law
    H_dot_law = np.einsum("ni,ni->n", dH, f + np.einsum("nim,nm->ni", g, u_ida))
    H_dot_applied = H_dot_law if u_ida is u_law else np.einsum("ni,ni->n", dH, f + np.einsum("nim,nm->ni", g, u_law))
    return ClosedLoopTerms(
        x=x, H=H, dH=dH, J=J, R=R, f=f, f_d=f_d, mu=mu, xi=xi,
        dissipation=np.einsum("ni,nij,nj->n", dH, R, dH),
        drive=np.einsum("ni,ni->n", dH, xi),
        u=u,
        H_dot=H_dot_applied if bound is None else np.einsum("ni,ni->n", dH, f + np.einsum("nim,nm->ni", g, u)),
        H_dot_law=H_dot_law,
        saturated=np.any(u != u_law, axis=1),
    )


def hessians(ctrl, x: np.ndarray) -> tuple[np.ndarray, str]:
    """∇²H_d at x (N, n) -> (N, n, n) and how it was obtained: ``"controller"`` (its
    ``hess_H_d``), ``"autograd"`` (through ``ctrl.nets.H``) or ``"finite differences"``."""
    if hasattr(ctrl, "hess_H_d"):
        return _f64(ctrl.hess_H_d(x)), "controller"
    energy = getattr(getattr(ctrl, "nets", None), "H", None)
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a dependency
        torch = None
    if torch is not None and isinstance(energy, torch.nn.Module) and hasattr(energy, "grad"):
        like = energy.x_star
        xt = torch.as_tensor(x, dtype=like.dtype, device=like.device).requires_grad_(True)
        with torch.enable_grad():
            g = energy.grad(xt, create_graph=True)
            rows = [torch.autograd.grad(g[:, i].sum(), xt, retain_graph=i + 1 < x.shape[1])[0] for i in range(x.shape[1])]
        hess = torch.stack(rows, dim=1).detach().to("cpu", torch.float64).numpy()
        return 0.5 * (hess + np.swapaxes(hess, 1, 2)), "autograd"
    n = x.shape[1]
    h = 1e-5 * np.maximum(1.0, np.abs(x).max(axis=0))
    cols = []
    for i in range(n):
        e = np.zeros(n)
        e[i] = h[i]
        cols.append((_f64(ctrl.grad_H_d(x + e)) - _f64(ctrl.grad_H_d(x - e))) / (2 * h[i]))
    hess = np.stack(cols, axis=2)
    return 0.5 * (hess + np.swapaxes(hess, 1, 2)), "finite differences"


def eigenvalues_at_target(ctrl, system) -> tuple[np.ndarray, str]:
    """(n,) complex eigenvalues of the true closed loop's Jacobian at x* and their source:
    ``ctrl.eigenvalues_at_target()`` when it has one, else central differences of f + g u."""
    if hasattr(ctrl, "eigenvalues_at_target"):
        return np.asarray(ctrl.eigenvalues_at_target(), complex), "controller Jacobian"
    x_star = _f64(system.x_star)
    n = x_star.size

    def F(x):
        return _f64(system.f(x)) + np.einsum("nim,nm->ni", _f64(system.g(x)), _f64(ctrl(x)).reshape(x.shape[0], -1))

    h = 1e-6
    E = h * np.eye(n)
    A = ((F(x_star + E) - F(x_star - E)) / (2 * h)).T
    return np.linalg.eigvals(A), "finite differences"

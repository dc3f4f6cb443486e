"""Run-time evaluation of f̃_d = (J_d − R_d)∇H_d in numpy, on a snapshot of the trained weights.

The control law needs f̃_d(x) once per control period. In torch each small operation costs 5–10 µs
of dispatch, and one evaluation of the three networks is about 70 of them: 0.65 ms for width-64
networks and 1.2 ms for the paper's 3×300 (`benchmarks/bench_controller.py`, one state), above a
1 kHz loop's budget. The same arithmetic in numpy costs about 1 µs per operation. `DesiredFlow`
holds the weights as numpy arrays (in the networks' dtype) and repeats, operation for operation,
the explicit forms of `idapbc_pin.control.networks`:

* ∇H_d from the ICNN's explicit backward pass (`EnergyNet.value_and_grad_explicit`),
* J_d = J0 + S skew(NN_J(u) − NN_J(0)) S, or skew(NN_J(u)) in the free form,
* R_d = L Lᵀ + ρS with L from `DampingNet.cholesky_factor`,

so it equals the torch networks to rounding (tests hold it to the autograd path). It is built by
`snapshot(nets)` and is only valid for the weights it was taken from; `Controller` takes a new one
whenever a parameter changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.special import expit
from torch import nn

__all__ = ["DesiredFlow", "snapshot"]


def _softplus(a: np.ndarray) -> np.ndarray:
    """log(1 + eᵃ) without overflow, the formula of `networks.softplus`."""
    return np.maximum(a, 0) + np.log1p(np.exp(-np.abs(a)))


_ACTIVATIONS = {"tanh": np.tanh, "softplus": _softplus}


@dataclass(frozen=True)
class _Mlp:
    """An `nn.Sequential` of Linear and activation layers: weights W (out, in), biases b (out,) or None."""

    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray | None, ...]
    activation: str

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """(N, n_in) -> (N, n_out)."""
        act = _ACTIVATIONS[self.activation]
        last = len(self.weights) - 1
        for k, (W, b) in enumerate(zip(self.weights, self.biases)):
            u = u @ W.T if b is None else u @ W.T + b
            if k < last:
                u = act(u)
        return u


@dataclass(frozen=True)
class DesiredFlow:
    """f̃_d(x) = (J_d(x) − R_d(x))∇H_d(x) for (N, n) numpy states, from frozen weights.

    Fields mirror the torch modules' buffers and parameters (see `idapbc_pin.control.networks`); arrays
    have the networks' dtype (float32 or float64). Build it with `snapshot`.
    """

    x_star: np.ndarray  # (n,)
    x_scale: np.ndarray  # (n,) input normalisation u = (x − x*)/x_scale (shared by the three nets)
    # H_d: ICNN layers W_x^k (width, n), b^k (width,), W_z^{k+} (width, width), w_out⁺ (width,)
    icnn_x: tuple[np.ndarray, ...]
    icnn_b: tuple[np.ndarray, ...]
    icnn_z: tuple[np.ndarray, ...]
    icnn_out: np.ndarray
    icnn_at_target: tuple[np.ndarray, np.ndarray]  # Ĥ(0) (), ∇_uĤ(0) (n,)
    icnn_map: np.ndarray | None  # (n, n) W of u = W(x − x*) (`EnergyNet.input_map`), else u = (x − x*)/x_scale
    eps: np.ndarray  # ()
    P: np.ndarray | None  # (n, n), anchored form
    # J_d
    j_net: _Mlp
    j0: np.ndarray | None  # (n, n) anchor J0; with j_at_target = NN_J(0)
    j_at_target: np.ndarray | None
    j_metric: np.ndarray | None  # (n, n) s sᵀ (box units)
    # R_d
    r_net: _Mlp
    log_d0: np.ndarray | None  # (n,) anchored diagonal of chol(R0)
    l0: np.ndarray | None  # (n(n−1)/2,) anchored strict lower part of chol(R0)
    r_at_target: np.ndarray | None  # NN_R(0)
    row_scale: np.ndarray | None  # (n(n+1)/2,) (box units)
    rho: float
    S: np.ndarray  # (n, n) damping-injection pattern
    upper: tuple[np.ndarray, np.ndarray]  # index maps of `networks.skew` and `networks.lower_tri`
    lower: tuple[np.ndarray, np.ndarray]
    diagonal: np.ndarray

    @property
    def n(self) -> int:
        return self.x_star.shape[0]

    def _grad_H(self, d: np.ndarray, u_box: np.ndarray) -> np.ndarray:
        """∇H_d: (N, n) -> (N, n) from δ = x − x* and δ/x_scale (`EnergyNet.value_and_grad_explicit`)."""
        u = u_box if self.icnn_map is None else d @ self.icnn_map.T
        pre = [u @ self.icnn_x[0].T + self.icnn_b[0]]
        for k in range(1, len(self.icnn_x)):
            pre.append(_softplus(pre[-1]) @ self.icnn_z[k - 1].T + u @ self.icnn_x[k].T + self.icnn_b[k])
        h = _softplus(pre[-1]) @ self.icnn_out
        delta, g = self.icnn_out, 0.0
        for k in range(len(pre) - 1, -1, -1):
            s = delta * expit(pre[k])
            g = g + s @ self.icnn_x[k]
            if k > 0:
                delta = s @ self.icnn_z[k - 1]
        h0, g0 = self.icnn_at_target
        s = (h - h0 - u @ g0) + self.eps * (d * d).sum(-1)
        dD = (g - g0) / self.x_scale if self.icnn_map is None else (g - g0) @ self.icnn_map
        ds = dD + 2 * self.eps * d
        if self.P is None:
            return ds
        return d @ self.P + (s / (1 + s))[:, None] * ds

    def _J(self, u: np.ndarray) -> np.ndarray:
        """J_d: (N, n) -> (N, n, n) from u = (x − x*)/x_scale, skew-symmetric (`InterconnectionNet.forward`)."""
        n = self.n
        v = self.j_net(u)
        if self.j0 is not None:
            v = v - self.j_at_target
        i, j = self.upper
        K = np.zeros((len(u), n, n), dtype=v.dtype)
        K[:, i, j] = v
        K[:, j, i] = -v
        if self.j_metric is not None:
            K = K * self.j_metric
        return K if self.j0 is None else self.j0 + K

    def _L(self, u: np.ndarray) -> np.ndarray:
        """L: (N, n) -> (N, n, n) from u, lower triangular with R_d = L Lᵀ + ρS (`DampingNet.cholesky_factor`)."""
        n = self.n
        out = self.r_net(u)
        r_d, r_o = out[:, :n], out[:, n:]
        s = self.row_scale
        if self.l0 is None:
            entries = np.concatenate([_softplus(r_d), r_o], axis=-1)
            entries = entries if s is None else entries * s
            diag, low = entries[:, :n], entries[:, n:]
        else:
            diag = np.exp(self.log_d0 + r_d - self.r_at_target[:n])
            step = r_o - self.r_at_target[n:]
            low = self.l0 + (step if s is None else step * s[n:])
        i, j = self.lower
        L = np.zeros((len(u), n, n), dtype=out.dtype)
        L[:, self.diagonal, self.diagonal] = diag
        L[:, i, j] = low
        return L

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """f̃_d(x) = J_d∇H_d − L(Lᵀ∇H_d) − ρS∇H_d: (N, n) -> (N, n), float64."""
        d = np.asarray(x, dtype=self.x_star.dtype) - self.x_star
        u = d / self.x_scale  # the input of J_d's and R_d's networks, computed once
        col = self._grad_H(d, u)[:, :, None]
        L = self._L(u)
        f_d = self._J(u) @ col - L @ (L.transpose(0, 2, 1) @ col)
        if self.rho:
            f_d = f_d - self.rho * (self.S @ col)
        return f_d[:, :, 0].astype(np.float64)


def _np(t: torch.Tensor | None) -> np.ndarray | None:
    return None if t is None else t.detach().cpu().numpy().copy()


#: torch activation modules of `networks._mlp` -> `_ACTIVATIONS` keys.
_ACTIVATION_OF = {"Tanh": "tanh", "_SoftplusModule": "softplus"}


def _mlp(seq: nn.Sequential) -> _Mlp:
    linears = [m for m in seq if isinstance(m, nn.Linear)]
    acts = {type(m).__name__ for m in seq if not isinstance(m, nn.Linear)}
    if len(acts) != 1 or not acts <= _ACTIVATION_OF.keys():
        raise ValueError(f"snapshot: unsupported activation layers {sorted(acts)}; known: {sorted(_ACTIVATION_OF)}")
    activation = _ACTIVATION_OF[acts.pop()]
    return _Mlp(tuple(_np(m.weight) for m in linears), tuple(_np(m.bias) for m in linears), activation)


@torch.no_grad()
def snapshot(nets) -> DesiredFlow:
    """A `DesiredFlow` with the current weights of `nets` (`controller.IdaPbcNets`), on the CPU."""
    H, J, R = nets.H, nets.J, nets.R
    icnn = H.icnn
    if icnn.out_x is not None:
        raise ValueError("snapshot: EnergyNet's ICNN has no affine output term")
    if not (torch.equal(H.x_scale, J.x_scale) and torch.equal(H.x_scale, R.x_scale)):
        raise ValueError("snapshot: H_d, J_d and R_d must share the input scale")
    zero = torch.zeros_like(H.x_star)
    h0, g0 = icnn.value_and_grad(zero)
    return DesiredFlow(
        x_star=_np(H.x_star),
        x_scale=_np(H.x_scale),
        icnn_x=tuple(_np(m.weight) for m in icnn.x_layers),
        icnn_b=tuple(_np(m.bias) for m in icnn.x_layers),
        icnn_z=tuple(_np(icnn._positive(k)) for k in range(icnn.depth - 1)),
        icnn_out=_np(icnn._positive(None)),
        icnn_at_target=(_np(h0), _np(g0)),
        icnn_map=_np(H.input_map),
        eps=_np(H.eps),
        P=_np(H.P),
        j_net=_mlp(J.net),
        j0=_np(J.J0),
        j_at_target=None if J.J0 is None else _np(J.net(zero)),
        j_metric=_np(J.metric),
        r_net=_mlp(R.net),
        log_d0=_np(R.log_d0),
        l0=_np(R.L0),
        r_at_target=None if R.L0 is None else _np(R.net(zero)),
        row_scale=_np(R.row_scale),
        rho=float(R.rho),
        S=_np(R.S),
        upper=np.triu_indices(H.n, 1),
        lower=np.tril_indices(H.n, -1),
        diagonal=np.arange(H.n),
    )

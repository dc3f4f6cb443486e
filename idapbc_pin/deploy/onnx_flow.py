"""desired_flow.onnx: the learned f̃_d(x) = (J_d − R_d)∇H_d as an ONNX graph, with explicit derivatives.

ONNX cannot hold ``torch.autograd.grad``, so `FlowGraph` evaluates ∇H_d by the ICNN's explicit
backward pass, formula for formula as `idapbc_pin.control.desired_flow.DesiredFlow` does, on the
same frozen weights (the ones the export writes to weights.npz). Skew and lower-triangular matrices
are placed by products with the flow's constant bases (exact), so the graph has no scatter. `onnx_model`
exports it with ``torch.onnx.export(dynamo=True)`` (needs the packages onnx and onnxscript): input
``x`` (N, n), output ``f_d`` (N, n), N dynamic, in the networks' dtype (float32 or float64).
"""

from __future__ import annotations

import contextlib
import io
import logging
import warnings

import numpy as np
import torch
from torch import Tensor, nn

from ..control.desired_flow import DesiredFlow, Mlp
from ..errors import IdapbcError

__all__ = ["FlowGraph", "onnx_model"]

#: The graph's input and output names.
INPUT, OUTPUT = "x", "f_d"


def _softplus(a: Tensor) -> Tensor:
    """log(1 + eᵃ) without overflow (the networks' formula)."""
    return torch.relu(a) + torch.log1p(torch.exp(-a.abs()))


class _MlpGraph(nn.Module):
    """An `Mlp` as torch operations: (N, n_in) -> (N, n_out)."""

    def __init__(self, mlp: Mlp, as_tensor):
        super().__init__()
        self.activation = {"tanh": torch.tanh, "softplus": _softplus}[mlp.activation]
        self.layers = len(mlp.weights)
        for k, (W, b) in enumerate(zip(mlp.weights, mlp.biases)):
            self.register_buffer(f"W{k}", as_tensor(W))
            self.register_buffer(f"b{k}", as_tensor(b))

    def forward(self, u: Tensor) -> Tensor:
        last = self.layers - 1
        for k in range(self.layers):
            W, b = getattr(self, f"W{k}"), getattr(self, f"b{k}")
            u = u @ W.T if b is None else u @ W.T + b
            if k < last:
                u = self.activation(u)
        return u


#: `DesiredFlow` fields the graph holds as buffers (besides ρ and the per-layer ICNN weights).
_FIELDS = (
    "x_star", "x_scale", "icnn_out", "icnn_h0", "icnn_g0", "icnn_map", "eps", "P",
    "j0", "j_at_target", "log_d0", "l0", "r_at_target", "row_scale", "S", "skew_basis", "lower_basis", "input_bound",
)  # fmt: skip


class FlowGraph(nn.Module):
    """f̃_d(x) for (N, n) states as torch operations on the weights of a `DesiredFlow` (no autograd).

    Buffers carry the `DesiredFlow` fields of the same names; None-valued fields (terms the networks'
    form lacks) are left out of the graph.
    """

    def __init__(self, flow: DesiredFlow):
        super().__init__()
        dtype = torch.float64 if flow.dtype == np.float64 else torch.float32
        as_tensor = lambda a: None if a is None else torch.tensor(np.asarray(a), dtype=dtype)  # noqa: E731
        self.n = flow.n
        self.depth = len(flow.icnn_x)
        self.damped = bool(flow.rho)
        arrays = {name: getattr(flow, name) for name in _FIELDS}  # skew_basis holds J_d's box metric
        arrays["rho"] = np.asarray(flow.rho)  # a buffer: the exporter rounds Python float constants to float32
        arrays.update({f"icnn_{kind}{k}": a for kind in "xbz" for k, a in enumerate(getattr(flow, f"icnn_{kind}"))})
        for name, a in arrays.items():
            self.register_buffer(name, as_tensor(a))
        self.j_net, self.r_net = _MlpGraph(flow.j_net, as_tensor), _MlpGraph(flow.r_net, as_tensor)

    def _grad_H(self, d: Tensor, u_box: Tensor) -> Tensor:
        """∇H_d (N, n) by the ICNN's explicit backward pass (`DesiredFlow._grad_H`)."""
        u = u_box if self.icnn_map is None else d @ self.icnn_map.T
        pre = [u @ self.icnn_x0.T + self.icnn_b0]
        for k in range(1, self.depth):
            pre.append(_softplus(pre[-1]) @ getattr(self, f"icnn_z{k - 1}").T + u @ getattr(self, f"icnn_x{k}").T + getattr(self, f"icnn_b{k}"))
        delta, g = self.icnn_out, None
        for k in range(self.depth - 1, -1, -1):
            s = delta * torch.sigmoid(pre[k])
            g = s @ getattr(self, f"icnn_x{k}") if g is None else g + s @ getattr(self, f"icnn_x{k}")
            if k > 0:
                delta = s @ getattr(self, f"icnn_z{k - 1}")
        dD = (g - self.icnn_g0) / self.x_scale if self.icnn_map is None else (g - self.icnn_g0) @ self.icnn_map
        ds = dD + 2 * self.eps * d
        if self.P is None:
            return ds
        h = _softplus(pre[-1]) @ self.icnn_out
        s = (h - self.icnn_h0 - u @ self.icnn_g0) + self.eps * (d * d).sum(-1)
        return d @ self.P + (s / (1 + s)).unsqueeze(-1) * ds

    def _J(self, u: Tensor) -> Tensor:
        """J_d (N, n, n), skew-symmetric (`DesiredFlow._J`)."""
        v = self.j_net(u)
        if self.j0 is not None:
            v = v - self.j_at_target
        K = (v @ self.skew_basis).reshape(-1, self.n, self.n)
        return K if self.j0 is None else self.j0 + K

    def _L(self, u: Tensor) -> Tensor:
        """L (N, n, n), lower triangular, R_d = L Lᵀ + ρS (`DesiredFlow._L`)."""
        n, s = self.n, self.row_scale
        out = self.r_net(u)
        r_d, r_o = out[:, :n], out[:, n:]
        if self.l0 is None:
            entries = torch.cat([_softplus(r_d), r_o], dim=-1)
            entries = entries if s is None else entries * s
        else:
            diag = torch.exp(self.log_d0 + r_d - self.r_at_target[:n])
            step = r_o - self.r_at_target[n:]
            entries = torch.cat([diag, self.l0 + (step if s is None else step * s[n:])], dim=-1)
        return (entries @ self.lower_basis).reshape(-1, n, n)

    def forward(self, x: Tensor) -> Tensor:
        """f̃_d(x) = J_d∇H_d − L(Lᵀ∇H_d) − ρS∇H_d: (N, n) -> (N, n)."""
        d = x - self.x_star
        u = d / self.x_scale
        col = self._grad_H(d, u).unsqueeze(-1)
        if self.input_bound is not None:  # J_d's and R_d's networks see the state clamped to the box
            u = torch.minimum(torch.maximum(u, -self.input_bound), self.input_bound)
        L = self._L(u)
        f_d = self._J(u) @ col - L @ (L.transpose(1, 2) @ col)
        if self.damped:
            f_d = f_d - self.rho * (self.S @ col)
        return f_d.squeeze(-1)


@contextlib.contextmanager
def _quiet():
    """Silence the exporter's progress lines, its notes on optional packages and its internal deprecations."""
    logger = logging.getLogger("torch.onnx")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)  # torch.export's own deprecations
            yield
    finally:
        logger.setLevel(level)


def onnx_model(flow: DesiredFlow) -> bytes:
    """The serialised ONNX model of `FlowGraph(flow)`: input ``x`` (N, n), output ``f_d`` (N, n)."""
    try:
        import onnx  # noqa: F401  (the dynamo exporter needs both)
        import onnxscript  # noqa: F401
    except ImportError as exc:
        raise IdapbcError(
            f"writing desired_flow.onnx needs the package '{exc.name}'. Fix: pip install 'idapbc-pin[export]', or export with --no-onnx."
        ) from None
    graph = FlowGraph(flow).eval()
    example = torch.zeros(2, flow.n, dtype=graph.x_star.dtype)
    with _quiet(), torch.no_grad():
        program = torch.onnx.export(
            graph,
            (example,),
            dynamo=True,
            input_names=[INPUT],
            output_names=[OUTPUT],
            dynamic_shapes=({0: torch.export.Dim("N")},),
            verbose=False,
        )
    return program.model_proto.SerializeToString()

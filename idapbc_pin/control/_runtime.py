"""`snapshot`: the trained torch networks' weights as a numpy `DesiredFlow` (the run-time path of f̃_d).

The control law needs f̃_d(x) once per control period. In torch each small operation costs 5–10 µs
of dispatch, and one evaluation of the three networks is about 70 of them, around a millisecond per
state (`benchmarks/bench_controller.py`), above a 1 kHz loop's budget. The same arithmetic in numpy
(`desired_flow.DesiredFlow`) costs about 1 µs per operation. A snapshot is only valid for the weights
it was taken from; `Controller` takes a new one whenever a parameter changes, and
`idapbc_pin.deploy.export` saves one next to the exported controller.
"""

from __future__ import annotations

import torch
from torch import nn

from .desired_flow import DesiredFlow, Mlp

__all__ = ["snapshot"]


def _np(t: torch.Tensor | None):
    return None if t is None else t.detach().cpu().numpy().copy()


def _same(a: torch.Tensor | None, b: torch.Tensor | None) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and torch.equal(a, b))


#: torch activation modules of the networks' MLPs -> `Mlp.activation`.
_ACTIVATION_OF = {"Tanh": "tanh", "_SoftplusModule": "softplus"}


def _mlp(seq: nn.Sequential) -> Mlp:
    linears = [m for m in seq if isinstance(m, nn.Linear)]
    acts = {type(m).__name__ for m in seq if not isinstance(m, nn.Linear)}
    if len(acts) != 1 or not acts <= _ACTIVATION_OF.keys():
        raise ValueError(f"snapshot: unsupported activation layers {sorted(acts)}; known: {sorted(_ACTIVATION_OF)}")
    activation = _ACTIVATION_OF[acts.pop()]
    return Mlp(tuple(_np(m.weight) for m in linears), tuple(_np(m.bias) for m in linears), activation)


@torch.no_grad()
def snapshot(nets) -> DesiredFlow:
    """A `DesiredFlow` with the current weights of `nets` (`IdaPbcNets`), on the CPU, in their dtype."""
    H, J, R = nets.H, nets.J, nets.R
    icnn = H.icnn
    if icnn.out_x is not None:
        raise ValueError("snapshot: EnergyNet's ICNN has no affine output term")
    if not (torch.equal(H.x_scale, J.x_scale) and torch.equal(H.x_scale, R.x_scale)):
        raise ValueError("snapshot: H_d, J_d and R_d must share the input scale")
    if not _same(J.input_bound, R.input_bound):
        raise ValueError("snapshot: J_d and R_d must share the input bound")
    zero = torch.zeros_like(H.x_star)
    h0, g0 = icnn.value_and_grad(zero)
    return DesiredFlow(
        x_star=_np(H.x_star),
        x_scale=_np(H.x_scale),
        icnn_x=tuple(_np(m.weight) for m in icnn.x_layers),
        icnn_b=tuple(_np(m.bias) for m in icnn.x_layers),
        icnn_z=tuple(_np(icnn._positive(k)) for k in range(icnn.depth - 1)),
        icnn_out=_np(icnn._positive(None)),
        icnn_h0=_np(h0),
        icnn_g0=_np(g0),
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
        input_bound=_np(J.input_bound),
    )

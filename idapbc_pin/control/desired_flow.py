"""f̃_d = (J_d − R_d)∇H_d in numpy from frozen weights: the controller's run-time path and the exported one.

This module imports numpy (and the standard library) only. `idapbc_pin.control._runtime.snapshot` fills a `DesiredFlow` from the
torch networks; `idapbc_pin.deploy.export` copies this very file as ``desired_flow.py`` next to the exported
``controller.py`` and ``weights.npz`` (`DesiredFlow.arrays` / `load_flow`), where it runs with neither
torch nor idapbc_pin installed.

It evaluates the explicit forms of the torch networks (`idapbc_pin.control`), formula for formula:

* ∇H_d from the ICNN's explicit backward pass (`EnergyNet.value_and_grad_explicit`), no autograd;
* J_d = J0 + skew(NN_J(u) − NN_J(0)) ⊙ s sᵀ, or skew(NN_J(u)) ⊙ s sᵀ in the free form (s sᵀ = 1
  without box units), `InterconnectionNet.forward`;
* R_d = L Lᵀ + ρS with L from `DampingNet.cholesky_factor`;

so it equals them to rounding in the networks' dtype (float32 or float64); u = (x − x*)/x_scale,
clamped to [−b, b] for J_d and R_d when the networks were built with an ``input_bound`` b.
Why numpy at run time: one evaluation is about 60 small operations, 5–10 µs each in torch and 1–2 µs
in numpy; the layout (stacked input layers, transposed weights, matrices placed by products with
constant bases) keeps that count low (`benchmarks/bench_controller.py`). Large batches are evaluated
in blocks of `block_rows` states, so that each (block, width) work array stays within
`BLOCK_BYTES`: a few cache-sized arrays instead of large ones that the C allocator maps and unmaps
from the operating system at every call. The rows of a block do not depend on the others', so the
values are those of one pass (BLAS may round a row differently in another batch).
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, field

import numpy as np

__all__ = ["BLOCK_BYTES", "DesiredFlow", "FORMAT", "Mlp", "load_flow", "softplus", "softplus_and_expit"]

#: Version of the `DesiredFlow.arrays` layout (stored under the key ``format``).
FORMAT = 1

#: Bytes of one (block, width) work array of a block of states (`DesiredFlow.block_rows`): below
#: glibc's default threshold (128 KiB) above which each allocation is a fresh memory map.
BLOCK_BYTES = 128_000


def softplus(a: np.ndarray) -> np.ndarray:
    """log(1 + eᵃ) without overflow: max(a, 0) + log1p(e^−|a|), as the torch networks compute it."""
    return np.maximum(a, 0) + np.log1p(np.exp(-np.abs(a)))


def softplus_and_expit(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """softplus(a) and its derivative, the logistic sigmoid σ(a) = 1/(1 + e^−a) = exp(a − softplus(a)),
    of an array a (two new arrays; `softplus`'s steps written into one buffer, so the same rounding).

    The ICNN needs both at every layer; this form of σ costs two operations, never overflows, and
    is accurate to about ε·|a| (ε the dtype's rounding unit), with no cancellation on either side.
    """
    sp = np.abs(a)
    for step in (np.negative, np.exp, np.log1p):
        step(sp, out=sp)
    sp = np.add(np.maximum(a, 0), sp, out=sp)
    slope = np.subtract(a, sp)
    return sp, np.exp(slope, out=slope)


def _tanh(a: np.ndarray) -> np.ndarray:
    """tanh(a), in place (`Mlp` applies it to its own products only)."""
    return np.tanh(a, out=a)


def _skew_basis(n: int, metric: np.ndarray | None, dtype) -> np.ndarray:
    """E (n(n−1)/2, n²) with v @ E = vec((A − Aᵀ) ⊙ metric), A strictly upper with entries v (triu order)."""
    k, (i, j) = np.arange(n * (n - 1) // 2), np.triu_indices(n, 1)
    E = np.zeros((len(k), n, n), dtype=dtype)
    E[k, i, j], E[k, j, i] = 1, -1
    return (E if metric is None else E * metric).reshape(len(k), n * n)


def _lower_basis(n: int, dtype) -> np.ndarray:
    """E (n(n+1)/2, n²) with v @ E = vec(L), v = (diagonal, strict lower part in tril order)."""
    i, j = np.tril_indices(n, -1)
    i, j = np.concatenate([np.arange(n), i]), np.concatenate([np.arange(n), j])
    E = np.zeros((len(i), n, n), dtype=dtype)
    E[np.arange(len(i)), i, j] = 1
    return E.reshape(len(i), n * n)


_ACTIVATIONS = {"tanh": _tanh, "softplus": softplus}  # each may overwrite its argument


@dataclass(frozen=True)
class Mlp:
    """Linear layers with an activation between them: weights W (out, in), biases b (out,) or None."""

    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray | None, ...]
    activation: str  # "tanh" | "softplus"
    transposed: tuple[np.ndarray, ...] = field(init=False, repr=False)  # contiguous Wᵀ (in, out): faster products

    def __post_init__(self):
        object.__setattr__(self, "transposed", tuple(np.ascontiguousarray(W.T) for W in self.weights))

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """(N, n_in) -> (N, n_out)."""
        act = _ACTIVATIONS[self.activation]
        last = len(self.weights) - 1
        for k, (Wt, b) in enumerate(zip(self.transposed, self.biases)):
            u = u @ Wt
            if b is not None:
                u += b
            if k < last:
                u = act(u)
        return u

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """The layers as named arrays ``<prefix>.W<k>``, ``<prefix>.b<k>``, ``<prefix>.activation``."""
        out = {f"{prefix}.activation": np.array(self.activation)}
        for k, (W, b) in enumerate(zip(self.weights, self.biases)):
            out[f"{prefix}.W{k}"] = W
            if b is not None:
                out[f"{prefix}.b{k}"] = b
        return out

    @classmethod
    def from_arrays(cls, arrays, prefix: str) -> "Mlp":
        """Inverse of `arrays`."""
        count = sum(1 for key in arrays if key.startswith(f"{prefix}.W"))
        weights = tuple(arrays[f"{prefix}.W{k}"] for k in range(count))
        biases = tuple(arrays.get(f"{prefix}.b{k}") for k in range(count))
        return cls(weights, biases, str(arrays[f"{prefix}.activation"]))


#: Fields that hold one array, or None when the networks' form has no such term.
_ARRAY_FIELDS = (
    "x_star", "x_scale", "icnn_out", "icnn_h0", "icnn_g0", "icnn_map", "eps", "P",
    "j0", "j_at_target", "j_metric", "log_d0", "l0", "r_at_target", "row_scale", "rho", "S", "input_bound",
)  # fmt: skip
#: Fields that hold one array per ICNN layer.
_LAYER_FIELDS = ("icnn_x", "icnn_b", "icnn_z")


@dataclass(frozen=True)
class DesiredFlow:
    """f̃_d(x) = (J_d(x) − R_d(x))∇H_d(x) for (N, n) states, from frozen weights (the networks' dtype).

    Fields mirror the torch modules' buffers and parameters; None marks a term the networks' form
    lacks (free vs anchored, box units or not). Build it with `snapshot` (from torch networks) or
    `from_arrays` / `load_flow` (from saved weights).
    """

    x_star: np.ndarray  # (n,)
    x_scale: np.ndarray  # (n,) input normalisation u = (x − x*)/x_scale (shared by the three nets)
    # H_d: ICNN layers W_x^k (width, n), b^k (width,), W_z^{k+} (width, width), w_out⁺ (width,)
    icnn_x: tuple[np.ndarray, ...]
    icnn_b: tuple[np.ndarray, ...]
    icnn_z: tuple[np.ndarray, ...]
    icnn_out: np.ndarray
    icnn_h0: np.ndarray  # () Ĥ(0)
    icnn_g0: np.ndarray  # (n,) ∇_uĤ(0)
    icnn_map: np.ndarray | None  # (n, n) W of u = W(x − x*) (`EnergyNet.input_map`), else u = (x − x*)/x_scale
    eps: np.ndarray  # ()
    P: np.ndarray | None  # (n, n), anchored form
    # J_d
    j_net: Mlp
    j0: np.ndarray | None  # (n, n) anchor J0; with j_at_target = NN_J(0)
    j_at_target: np.ndarray | None
    j_metric: np.ndarray | None  # (n, n) s sᵀ (box units)
    # R_d
    r_net: Mlp
    log_d0: np.ndarray | None  # (n,) anchored diagonal of chol(R0)
    l0: np.ndarray | None  # (n(n−1)/2,) anchored strict lower part of chol(R0)
    r_at_target: np.ndarray | None  # NN_R(0)
    row_scale: np.ndarray | None  # (n(n+1)/2,) (box units)
    rho: float
    S: np.ndarray  # (n, n) damping-injection pattern
    input_bound: np.ndarray | None = None  # () b: J_d's and R_d's networks see u clamped to [−b, b] (None: unclamped)
    # 0/±1 bases (box metric folded in) that place entries as matrices by one exact product:
    # vec(K) = v @ skew_basis (K skew, v in triu_indices order); vec(L) = (diag, low) @ lower_basis
    skew_basis: np.ndarray = field(init=False, repr=False)  # (n(n−1)/2, n²)
    lower_basis: np.ndarray = field(init=False, repr=False)  # (n(n+1)/2, n²)
    # the ICNN's input layers side by side, [W_x^0ᵀ … W_x^{depth−1}ᵀ] (n, depth·width) and biases,
    # and its W_z^{k+}ᵀ (width, width), contiguous: one product for every layer's input term
    icnn_in: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False)
    icnn_z_t: tuple[np.ndarray, ...] = field(init=False, repr=False)
    # states per block of `__call__` and `energy`: the widest layer's (block, width) array in `BLOCK_BYTES`
    block_rows: int = field(init=False, repr=False)

    def __post_init__(self):
        derived = {
            "skew_basis": _skew_basis(self.n, self.j_metric, self.dtype),
            "lower_basis": _lower_basis(self.n, self.dtype),
            "icnn_in": (np.concatenate([W.T for W in self.icnn_x], axis=1), np.concatenate(self.icnn_b)),
            "icnn_z_t": tuple(np.ascontiguousarray(W.T) for W in self.icnn_z),
            "block_rows": max(16, BLOCK_BYTES // (self._widest() * self.dtype.itemsize)),
        }
        for name, value in derived.items():
            object.__setattr__(self, name, value)

    @property
    def n(self) -> int:
        return self.x_star.shape[0]

    @property
    def dtype(self) -> np.dtype:
        """The networks' dtype, in which f̃_d is evaluated."""
        return self.x_star.dtype

    def _widest(self) -> int:
        """The widest layer of the three networks (outputs of one linear map)."""
        return max([self.icnn_out.shape[0]] + [W.shape[0] for W in self.j_net.weights + self.r_net.weights])

    def _blocks(self, fn, x: np.ndarray) -> np.ndarray:
        """fn over equal blocks of at most `block_rows` states of x (N, n), concatenated along N."""
        x = np.asarray(x, dtype=self.dtype)
        count = -(-len(x) // self.block_rows)
        if count <= 1:
            return fn(x)
        return np.concatenate([fn(block) for block in np.array_split(x, count)])

    # ------------------------------------------------------------------ saving and loading
    def arrays(self) -> dict[str, np.ndarray]:
        """Every weight as a named array (no None, no objects): ``np.savez(path, **flow.arrays())``."""
        out = {"format": np.array(FORMAT)}
        for name in _ARRAY_FIELDS:
            value = getattr(self, name)
            if value is not None:
                out[name] = np.asarray(value, dtype=self.dtype) if name == "rho" else value
        for name in _LAYER_FIELDS:
            out.update({f"{name}.{k}": a for k, a in enumerate(getattr(self, name))})
        return {**out, **self.j_net.arrays("j_net"), **self.r_net.arrays("r_net")}

    @classmethod
    def from_arrays(cls, arrays) -> "DesiredFlow":
        """Inverse of `arrays` (a dict, or the mapping `np.load` returns for an .npz)."""
        arrays = {key: np.asarray(arrays[key]) for key in arrays}
        if int(arrays.get("format", -1)) != FORMAT:
            raise ValueError(f"weights in format {arrays.get('format')}, this desired_flow.py reads format {FORMAT}")
        values = {name: arrays.get(name) for name in _ARRAY_FIELDS}
        values["rho"] = float(values["rho"])
        for name in _LAYER_FIELDS:
            count = sum(1 for key in arrays if key.startswith(f"{name}."))
            values[name] = tuple(arrays[f"{name}.{k}"] for k in range(count))
        return cls(j_net=Mlp.from_arrays(arrays, "j_net"), r_net=Mlp.from_arrays(arrays, "r_net"), **values)

    # ------------------------------------------------------------------ evaluation
    def _icnn(self, d: np.ndarray, u_box: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
        """The ICNN's forward pass from δ = x − x* and δ/x_scale: (u, its last layer z (N, width), the
        slopes σ(a_k) of every layer for the backward pass)."""
        u = u_box if self.icnn_map is None else d @ self.icnn_map.T
        width = self.icnn_out.shape[0]
        inputs = u @ self.icnn_in[0]  # W_x^k u + b^k of every layer k, (N, depth·width)
        inputs += self.icnn_in[1]
        z, slopes = None, []  # z_k = softplus(a_k), slopes σ(a_k) for the backward pass
        for k in range(len(self.icnn_x)):
            a = inputs[:, k * width : (k + 1) * width]
            if k > 0:
                a = np.add(z @ self.icnn_z_t[k - 1], a, out=z)  # z is not needed past this product
            z, slope = softplus_and_expit(a)
            slopes.append(slope)
        return u, z, slopes

    def _s(self, d: np.ndarray, u: np.ndarray, z: np.ndarray) -> np.ndarray:
        """s = D + ε‖δ‖² (N,): the Bregman term of Ĥ at u, from the ICNN's last layer z."""
        return (z @ self.icnn_out - self.icnn_h0 - u @ self.icnn_g0) + self.eps * (d * d).sum(-1)

    def _grad_H(self, d: np.ndarray, u_box: np.ndarray) -> np.ndarray:
        """∇H_d: (N, n) -> (N, n) from δ = x − x* and δ/x_scale (`EnergyNet.value_and_grad_explicit`)."""
        u, z, slopes = self._icnn(d, u_box)
        delta, dh_da = self.icnn_out, [None] * len(slopes)  # ∂Ĥ/∂z_k, then ∂Ĥ/∂a_k (N, width)
        for k in range(len(slopes) - 1, -1, -1):
            dh_da[k] = np.multiply(slopes[k], delta, out=slopes[k])
            if k > 0:
                delta = dh_da[k] @ self.icnn_z[k - 1]
        g = np.concatenate(dh_da, axis=1) @ self.icnn_in[0].T  # ∇_uĤ = Σ_k (∂Ĥ/∂a_k) W_x^k
        dD = (g - self.icnn_g0) / self.x_scale if self.icnn_map is None else (g - self.icnn_g0) @ self.icnn_map
        ds = dD + 2 * self.eps * d
        if self.P is None:
            return ds
        s = self._s(d, u, z)
        return d @ self.P + (s / (1 + s))[:, None] * ds

    def energy(self, x: np.ndarray) -> np.ndarray:
        """H_d(x): (N, n) -> (N,), float64 (`EnergyNet.forward`, the Bregman term as
        `value_and_grad_explicit` forms it); a recovery law's level switch reads it."""
        return self._blocks(self._energy, x)

    def _energy(self, x: np.ndarray) -> np.ndarray:
        d = x - self.x_star
        u, z, _ = self._icnn(d, d / self.x_scale)
        s = self._s(d, u, z)
        H = s if self.P is None else 0.5 * ((d @ self.P) * d).sum(-1) + s - np.log1p(s)
        return H.astype(np.float64)

    def _J(self, u: np.ndarray) -> np.ndarray:
        """J_d: (N, n) -> (N, n, n) from u = (x − x*)/x_scale, skew-symmetric (`InterconnectionNet.forward`)."""
        v = self.j_net(u)
        if self.j0 is not None:
            v = v - self.j_at_target
        K = (v @ self.skew_basis).reshape(len(u), self.n, self.n)
        return K if self.j0 is None else self.j0 + K

    def _L(self, u: np.ndarray) -> np.ndarray:
        """L: (N, n) -> (N, n, n) from u, lower triangular with R_d = L Lᵀ + ρS (`DampingNet.cholesky_factor`)."""
        n = self.n
        out = self.r_net(u)
        r_d, r_o = out[:, :n], out[:, n:]
        s = self.row_scale
        if self.l0 is None:
            entries = np.concatenate([softplus(r_d), r_o], axis=-1)
            entries = entries if s is None else entries * s
        else:
            diag = np.exp(self.log_d0 + r_d - self.r_at_target[:n])
            step = r_o - self.r_at_target[n:]
            entries = np.concatenate([diag, self.l0 + (step if s is None else step * s[n:])], axis=-1)
        return (entries @ self.lower_basis).reshape(len(u), n, n)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """f̃_d(x) = J_d∇H_d − L(Lᵀ∇H_d) − ρS∇H_d: (N, n) -> (N, n), float64."""
        return self._blocks(self._flow, x)

    def _flow(self, x: np.ndarray) -> np.ndarray:
        d = x - self.x_star
        u = d / self.x_scale
        col = self._grad_H(d, u)[:, :, None]
        if self.input_bound is not None:  # J_d's and R_d's networks see the state clamped to the box
            u = np.minimum(np.maximum(u, -self.input_bound), self.input_bound)
        L = self._L(u)
        f_d = self._J(u) @ col - L @ (L.transpose(0, 2, 1) @ col)
        if self.rho:
            f_d = f_d - self.rho * (self.S @ col)
        return f_d[:, :, 0].astype(np.float64)


def load_flow(path) -> DesiredFlow:
    """The `DesiredFlow` saved in an .npz file by ``np.savez(path, **flow.arrays())``. A missing,
    truncated or garbled file, or one that is not such weights, raises one `ValueError` line naming
    the file and the fix (this runs in an exported controller, without idapbc_pin's error types)."""
    fix = "Fix: export the run again (`idapbc-pin export RUN --out DIR`)."
    try:
        with np.load(path, allow_pickle=False) as data:
            return DesiredFlow.from_arrays(data)
    except FileNotFoundError:
        raise ValueError(f"{path} is missing. {fix}") from None
    except (OSError, EOFError, KeyError, TypeError, zipfile.BadZipFile, ValueError) as exc:
        what = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ValueError(f"{path} is damaged or holds no exported weights ({what}). {fix}") from None

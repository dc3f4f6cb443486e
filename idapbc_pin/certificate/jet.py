"""First-order jets of interval enclosures: a value and its gradient, both enclosed over a box, for
the mean-value forms of `idapbc_pin.certificate.verified`.

A `Jet` holds ``val`` (an `Interval`, or a `Jet` for a second order) of shape S and ``grad`` of
shape S + (k,): for every point ξ of the box X it encloses a function's value φ(ξ) and its
derivatives ∂φ/∂x₁…∂φ/∂x_k. Each operation applies the chain rule with its derivative enclosed on
the argument's enclosure (e.g. tanh' = 1 − tanh², taken from the enclosure of tanh), so the result
holds the exact derivative wherever the argument's does (forward-mode automatic differentiation in
interval arithmetic; Moore, Kearfott & Cloud 2009, ch. 9). With a jet of the box X itself as the
input (`Jet.variables`), a function written in these operations gives its interval Jacobian over X,
and so the mean-value form φ(X) ⊆ φ(m) + ∇φ(X)·(X − m).

A piecewise function (clip, |·|) takes the hull of its one-sided slopes where the box meets a kink:
the mean-value form stays valid for such Lipschitz functions (Clarke's generalised gradient).
A jet of jets gives second derivatives; every operation here is written in the operations of its
parts, so it nests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .interval import Interval

__all__ = ["Jet", "concat", "const_like", "stack", "where"]


def _expand(t):
    """t[..., None] for an `Interval` or a `Jet`."""
    return t[(Ellipsis, None)]


def const_like(c, like):
    """The constant array c (its own shape) in the type of `like` (an `Interval` or a `Jet`)."""
    c = np.asarray(c, np.float64)
    if isinstance(like, Jet):
        return Jet(const_like(c, like.val), _zeros(like.grad, c.shape + (like.k,)))
    return Interval.point(c)


def _zeros(like, shape):
    """Zeros of `shape` in the type of `like` (an `Interval` or a `Jet`)."""
    if isinstance(like, Jet):
        return Jet(_zeros(like.val, shape), _zeros(like.grad, shape + (like.k,)))
    return Interval.point(np.zeros(shape))


def _lift(a, like: "Jet") -> "Jet":
    """a (a `Jet`, an `Interval` or an array) as a jet of `like`'s kind (a constant: zero gradient)."""
    if isinstance(a, Jet):
        return a
    if isinstance(a, Interval):
        val = a if not isinstance(like.val, Jet) else _lift(a, like.val)
    else:
        val = const_like(a, like.val)
    return Jet(val, _zeros(like.grad, val.shape + (like.k,)))


def _norm_key(key, ndim: int) -> tuple:
    """An index into an array of `ndim` axes, with its Ellipsis spelled out."""
    key = key if isinstance(key, tuple) else (key,)
    if Ellipsis not in key:
        used = sum(k is not None for k in key)
        return key + (slice(None),) * (ndim - used)
    i = key.index(Ellipsis)
    used = sum(k is not None and k is not Ellipsis for k in key)
    return key[:i] + (slice(None),) * (ndim - used) + key[i + 1 :]


def _axis(axis: int, ndim: int) -> int:
    """`axis` of the value as a non-negative axis (the same axis of the gradient)."""
    return axis if axis >= 0 else ndim + axis


@dataclass(frozen=True)
class Jet:
    """An enclosure ``val`` (shape S) of a function over a box and ``grad`` (S + (k,)) of its gradient."""

    val: object
    grad: object
    _is_jet = True

    @classmethod
    def variables(cls, X):
        """The jet of the identity over boxes X (N, n): grad = I (N, n, n)."""
        N, n = X.shape
        return cls(X, const_like(np.broadcast_to(np.eye(n), (N, n, n)), X))

    @property
    def shape(self) -> tuple[int, ...]:
        return self.val.shape

    @property
    def k(self) -> int:
        return self.grad.shape[-1]

    @property
    def lo(self):
        return self.val.lo

    @property
    def hi(self):
        return self.val.hi

    @property
    def mid(self):
        return self.val.mid

    def __getitem__(self, key) -> "Jet":
        key = _norm_key(key, len(self.shape))
        return Jet(self.val[key], self.grad[key + (slice(None),)])

    def reshape(self, *shape) -> "Jet":
        return Jet(self.val.reshape(*shape), self.grad.reshape(*shape, self.k))

    def swap(self, a: int, b: int) -> "Jet":
        nd = len(self.shape)
        return Jet(self.val.swap(a, b), self.grad.swap(_axis(a, nd), _axis(b, nd)))

    # ----------------------------------------------------------------- arithmetic
    def __add__(self, other) -> "Jet":
        o = _lift(other, self)
        return Jet(self.val + o.val, self.grad + o.grad)

    __radd__ = __add__

    def __neg__(self) -> "Jet":
        return Jet(-self.val, -self.grad)

    def __sub__(self, other) -> "Jet":
        return self + (-_lift(other, self))

    def __rsub__(self, other) -> "Jet":
        return _lift(other, self) + (-self)

    def __mul__(self, other) -> "Jet":
        if not isinstance(other, (Jet, Interval)):
            c = np.asarray(other, np.float64)
            return Jet(self.val * c, self.grad * c[..., None] if c.ndim else self.grad * c)
        o = _lift(other, self)
        return Jet(self.val * o.val, self.grad * _expand(o.val) + o.grad * _expand(self.val))

    __rmul__ = __mul__

    def _chain(self, val, slope) -> "Jet":
        """A function with value enclosure `val` and derivative enclosure `slope` at self."""
        return Jet(val, self.grad * _expand(slope))

    def square(self) -> "Jet":
        return self._chain(self.val.square(), self.val * 2.0)

    def sum(self, axis: int = -1) -> "Jet":
        a = _axis(axis, len(self.shape))
        return Jet(self.val.sum(a), self.grad.sum(a))

    def __matmul__(self, W) -> "Jet":
        """self (..., p) @ W (p, q) for a point matrix W."""
        return Jet(self.val @ W, (self.grad.swap(-1, -2) @ W).swap(-1, -2))

    def meet(self, lo=-np.inf, hi=np.inf) -> "Jet":
        """The value met with [lo, hi] (a value known to lie there); the gradient as it is."""
        return Jet(self.val.meet(lo, hi), self.grad)

    def clip(self, lo, hi) -> "Jet":
        """min(max(x, lo), hi): slope 1 inside, 0 beyond a bound, [0, 1] where the box meets one."""
        v = _flat(self.val)
        inside = (v.lo >= lo) & (v.hi <= hi)
        beyond = (v.hi <= lo) | (v.lo >= hi)
        return self._chain(v.clip(lo, hi), Interval(np.where(inside, 1.0, 0.0), np.where(beyond, 0.0, 1.0)))

    def abs(self) -> "Jet":
        """|x|: slope ±1, [−1, 1] where the box holds 0."""
        v = _flat(self.val)
        return self._chain(v.abs(), Interval(np.where(v.lo >= 0, 1.0, -1.0), np.where(v.hi <= 0, -1.0, 1.0)))

    def exp(self) -> "Jet":
        e = self.val.exp()
        return self._chain(e, e)

    def tanh(self) -> "Jet":
        t = self.val.tanh()
        return self._chain(t, 1.0 - t.square())

    def softplus(self) -> "Jet":
        return self._chain(self.val.softplus(), self.val.expit())

    def expit(self) -> "Jet":
        s = self.val.expit()
        return self._chain(s, s * (1.0 - s))

    def reciprocal(self) -> "Jet":
        r = self.val.reciprocal()
        return self._chain(r, -r.square())

    def cos(self) -> "Jet":
        return self._chain(self.val.cos(), -self.val.sin())

    def sin(self) -> "Jet":
        return self._chain(self.val.sin(), self.val.cos())

    def widen(self, r) -> "Jet":
        return Jet(self.val.widen(r), self.grad)

    def psi(self) -> "Jet":
        """ψ(s) = s − log(1 + s); ψ' = s/(1 + s)."""
        return self._chain(self.val.psi(), self.val.ratio_one_plus())

    def ratio_one_plus(self) -> "Jet":
        """s/(1 + s); its slope 1/(1 + s)², unbounded where the value's enclosure reaches −1."""
        v = _flat(self.val)
        ok = v.lo > -1
        inv = (Interval(np.where(ok, v.lo, 0.0), np.where(ok, v.hi, 0.0)) + 1.0).meet(1e-300)
        slope = inv.reciprocal().square()
        return self._chain(v.ratio_one_plus(), Interval(np.where(ok, slope.lo, 0.0), np.where(ok, slope.hi, np.inf)))

    @classmethod
    def concat(cls, parts, axis: int = -1) -> "Jet":
        like = next(p for p in parts if isinstance(p, Jet))
        parts = [_lift(p, like) for p in parts]
        a = _axis(axis, len(like.shape))
        return cls(type(like.val).concat([p.val for p in parts], a), type(like.grad).concat([p.grad for p in parts], a))

    @classmethod
    def stack(cls, parts, axis: int = -1) -> "Jet":
        like = next(p for p in parts if isinstance(p, Jet))
        parts = [_lift(p, like) for p in parts]
        a = _axis(axis, len(like.shape) + 1)
        return cls(type(like.val).stack([p.val for p in parts], a), type(like.grad).stack([p.grad for p in parts], a))


def _flat(t) -> Interval:
    """The value of a first-order jet: a kink (clip, |·|, ψ's slope) has no second derivative here."""
    if isinstance(t, Jet):
        raise NotImplementedError("a kink inside a jet of jets has no second derivative")
    return t


def concat(parts, axis: int = -1):
    """`Interval.concat` or `Jet.concat`, whichever the parts need."""
    return (Jet if any(isinstance(p, Jet) for p in parts) else Interval).concat(parts, axis)


def stack(parts, axis: int = -1):
    """`Interval.stack` or `Jet.stack`, whichever the parts need."""
    return (Jet if any(isinstance(p, Jet) for p in parts) else Interval).stack(parts, axis)


def where(mask: np.ndarray, a, b):
    """Rows of a where mask (N,) holds, else b's: for values of one type (`Interval` or `Jet`)."""
    if isinstance(a, Jet) or isinstance(b, Jet):
        like = a if isinstance(a, Jet) else b
        a, b = _lift(a, like), _lift(b, like)
        return Jet(where(mask, a.val, b.val), where(mask, a.grad, b.grad))
    m = mask.reshape(mask.shape + (1,) * (a.lo.ndim - mask.ndim))
    return Interval(np.where(m, a.lo, b.lo), np.where(m, a.hi, b.hi))

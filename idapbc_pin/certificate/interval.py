"""Interval arithmetic in numpy, batched over boxes, with outward rounding: the enclosures of
`idapbc_pin.certificate.verified`.

An `Interval` holds float64 arrays ``lo ≤ hi`` of one shape; every operation returns an interval
that contains every value the exact operation takes on its arguments' intervals (Moore, Kearfott
& Cloud, *Introduction to Interval Analysis*, 2009). Rounding is made safe as follows:

* +, −, ×, ÷ are correctly rounded in IEEE 754, so one step outward (`numpy.nextafter`) per result
  covers them;
* a sum or a product with a point matrix of k terms (pairwise, or BLAS in any order, FMA or not) is
  within γ_k·Σ|terms| of the exact one, γ_k = k·2⁻⁵³/(1 − k·2⁻⁵³) (Higham, *Accuracy and
  Stability of Numerical Algorithms*, §3.1); that bound is added outward;
* exp, log1p and tanh come from numpy's math library, accurate to a few units in the last place:
  their results are widened by `LIBM_REL` relative plus the smallest normal number.

Products with a point matrix use the midpoint-radius form (Rump 1999), exact for the interval hull
up to the rounding bound above. An operation with a `jet.Jet` operand is left to the jet.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Interval"]

#: Relative widening of a math-library result (exp, log1p, tanh): 2⁻⁴⁴ ≈ 5.7e-14, 512 units in the
#: last place, far above the few units those functions are documented to miss by.
LIBM_REL = 2.0**-44
_TINY = np.finfo(np.float64).tiny
_U = 2.0**-53


def _down(a):
    return np.nextafter(a, -np.inf)


def _up(a):
    return np.nextafter(a, np.inf)


def _gamma(k: int) -> float:
    """γ_k of a k-term sum, rounded up generously (k·2⁻⁵³ ≪ 1 here)."""
    return 1.01 * (k + 2) * _U


def _libm(lo, hi) -> "Interval":
    """[lo, hi] widened for a math-library function's error."""
    return Interval(lo - LIBM_REL * np.abs(lo) - _TINY, hi + LIBM_REL * np.abs(hi) + _TINY)


@dataclass(frozen=True)
class Interval:
    """The box [lo, hi] of arrays of one shape (float64), lo ≤ hi elementwise."""

    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def point(cls, a) -> "Interval":
        """The degenerate interval [a, a]."""
        a = np.asarray(a, np.float64)
        return cls(a, a)

    @property
    def shape(self) -> tuple[int, ...]:
        return self.lo.shape

    @property
    def mid(self) -> np.ndarray:
        return 0.5 * (self.lo + self.hi)

    @classmethod
    def concat(cls, parts, axis: int = -1) -> "Interval":
        """Intervals joined along an existing axis."""
        return cls(np.concatenate([p.lo for p in parts], axis), np.concatenate([p.hi for p in parts], axis))

    @classmethod
    def stack(cls, parts, axis: int = -1) -> "Interval":
        """Intervals of one shape stacked along a new axis."""
        return cls(np.stack([p.lo for p in parts], axis), np.stack([p.hi for p in parts], axis))

    def __getitem__(self, key) -> "Interval":
        return Interval(self.lo[key], self.hi[key])

    def reshape(self, *shape) -> "Interval":
        return Interval(self.lo.reshape(*shape), self.hi.reshape(*shape))

    def swap(self, a: int, b: int) -> "Interval":
        """Axes a and b exchanged (a transpose of a batch of matrices)."""
        return Interval(np.swapaxes(self.lo, a, b), np.swapaxes(self.hi, a, b))

    # ----------------------------------------------------------------- arithmetic
    def __add__(self, other) -> "Interval":
        if getattr(other, "_is_jet", False):
            return NotImplemented
        o = _as_interval(other)
        return Interval(_down(self.lo + o.lo), _up(self.hi + o.hi))

    __radd__ = __add__

    def __neg__(self) -> "Interval":
        return Interval(-self.hi, -self.lo)

    def __sub__(self, other) -> "Interval":
        if getattr(other, "_is_jet", False):
            return NotImplemented
        return self + (-_as_interval(other))

    def __rsub__(self, other) -> "Interval":
        if getattr(other, "_is_jet", False):
            return NotImplemented
        return _as_interval(other) + (-self)

    def __mul__(self, other) -> "Interval":
        if getattr(other, "_is_jet", False):
            return NotImplemented
        o = _as_interval(other)
        p = np.stack(np.broadcast_arrays(self.lo * o.lo, self.lo * o.hi, self.hi * o.lo, self.hi * o.hi))
        return Interval(_down(p.min(axis=0)), _up(p.max(axis=0)))

    __rmul__ = __mul__

    def square(self) -> "Interval":
        """x², tight (0 where the interval holds 0)."""
        a, b = self.lo * self.lo, self.hi * self.hi
        lo = np.where((self.lo <= 0) & (self.hi >= 0), 0.0, np.minimum(a, b))
        return Interval(np.maximum(_down(lo), 0.0), _up(np.maximum(a, b)))

    def abs(self) -> "Interval":
        lo = np.where(self.lo >= 0, self.lo, np.where(self.hi <= 0, -self.hi, 0.0))
        return Interval(lo, np.maximum(-self.lo, self.hi))

    def sum(self, axis: int = -1) -> "Interval":
        """Σ over `axis`, with the summation's rounding bound added outward."""
        k = self.lo.shape[axis]
        lo, hi = self.lo.sum(axis), self.hi.sum(axis)
        err = _gamma(k) * np.maximum(np.abs(self.lo), np.abs(self.hi)).sum(axis) + k * _TINY
        return Interval(_down(lo - err), _up(hi + err))

    def __matmul__(self, W) -> "Interval":
        """self (..., k) @ W (k, m) for a point matrix W (midpoint-radius form)."""
        W = np.asarray(W, np.float64)
        c = self.mid
        r = _up(np.maximum(self.hi - c, c - self.lo))
        aW = np.abs(W)
        mid, rad = c @ W, r @ aW
        k = W.shape[0]
        rad = _up(rad * (1 + 2 * _gamma(k)) + _gamma(k) * (np.abs(c) @ aW) + k * _TINY)
        return Interval(_down(mid - rad), _up(mid + rad))

    def clip(self, lo, hi) -> "Interval":
        """min(max(x, lo), hi): monotone, exact."""
        return Interval(np.clip(self.lo, lo, hi), np.clip(self.hi, lo, hi))

    def meet(self, lo=-np.inf, hi=np.inf) -> "Interval":
        """The intersection with [lo, hi], for a value known to lie there."""
        return Interval(np.maximum(self.lo, lo), np.minimum(self.hi, hi))

    # ----------------------------------------------------------------- monotone functions
    def exp(self) -> "Interval":
        r = _libm(np.exp(self.lo), np.exp(self.hi))
        return r.meet(0.0)

    def tanh(self) -> "Interval":
        return _libm(np.tanh(self.lo), np.tanh(self.hi)).meet(-1.0, 1.0)

    def softplus(self) -> "Interval":
        """log(1 + eˣ) = max(x, 0) + log1p(e^−|x|), increasing."""
        f = lambda a: np.maximum(a, 0) + np.log1p(np.exp(-np.abs(a)))  # noqa: E731
        return _libm(f(self.lo), f(self.hi)).meet(0.0)

    def expit(self) -> "Interval":
        """σ(x) = 1/(1 + e^−x), increasing."""
        f = lambda a: 1.0 / (1.0 + np.exp(-a))  # noqa: E731
        return _libm(f(self.lo), f(self.hi)).meet(0.0, 1.0)

    def reciprocal(self) -> "Interval":
        """1/x for an interval of positive numbers."""
        if not np.all(self.lo > 0):
            raise ValueError("reciprocal of an interval that reaches 0 or below")
        return Interval(_down(1.0 / self.hi), _up(1.0 / self.lo))

    def cos(self) -> "Interval":
        """cos x: its values at the ends, and ±1 where a multiple of π lies inside (tested on a
        widened interval, as π is not a float)."""
        a, b = self.lo, self.hi
        wide = b - a >= 2 * np.pi
        ca, cb = np.cos(a), np.cos(b)
        slack = 1e-12 * (1 + np.abs(a) + np.abs(b))
        has_max = np.floor((b + slack) / (2 * np.pi)) >= np.ceil((a - slack) / (2 * np.pi))
        has_min = np.floor((b + slack - np.pi) / (2 * np.pi)) >= np.ceil((a - slack - np.pi) / (2 * np.pi))
        lo = np.where(wide | has_min, -1.0, np.minimum(ca, cb) - LIBM_REL - _TINY)
        hi = np.where(wide | has_max, 1.0, np.maximum(ca, cb) + LIBM_REL + _TINY)
        return Interval(np.maximum(lo, -1.0), np.minimum(hi, 1.0))

    def sin(self) -> "Interval":
        """sin x = cos(x − π/2) (the shift rounded outward)."""
        return (self - np.pi / 2).widen(4e-16 * (1 + np.maximum(np.abs(self.lo), np.abs(self.hi)))).cos()

    def widen(self, r) -> "Interval":
        """[lo − r, hi + r], r ≥ 0."""
        return Interval(_down(self.lo - r), _up(self.hi + r))

    def ratio_one_plus(self) -> "Interval":
        """s/(1 + s) for s > −1, increasing (ψ'(s) of the anchored H_d); an interval that reaches −1
        (a loose enclosure of s) gives (−∞, f(hi)]."""
        f = lambda s: s / (1.0 + s)  # noqa: E731
        with np.errstate(divide="ignore", invalid="ignore"):
            r = _libm(f(self.lo), f(self.hi))
        return Interval(np.where(self.lo > -1, r.lo, -np.inf), np.where(self.hi > -1, r.hi, -np.inf))

    def psi(self) -> "Interval":
        """ψ(s) = s − log(1 + s) for s > −1: ≥ 0, decreasing below 0 and increasing above; +∞ at an
        end at or below −1 (a loose enclosure of s)."""
        f = lambda s: s - np.log1p(np.maximum(s, -1.0))  # noqa: E731  (+∞ at s ≤ −1: ψ grows without bound there)
        with np.errstate(divide="ignore"):
            a, b = f(self.lo), f(self.hi)
        lo = np.where((self.lo <= 0) & (self.hi >= 0), 0.0, np.minimum(a, b))
        # the difference cancels: its error is log1p's, relative to s, not to the result
        err = LIBM_REL * np.maximum(np.abs(self.lo), np.abs(self.hi)) + _TINY
        return Interval(np.maximum(lo - err, 0.0), np.maximum(a, b) + err)


def _as_interval(a) -> Interval:
    return a if isinstance(a, Interval) else Interval.point(a)

"""The kept box a swing-up law shares with the run's law (`SwingUpLaw`, `TrackingLaw`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .._memo import last_call
from ..model.angles import wrap_angles

__all__ = ["KeptBoxLaw"]


class KeptBoxLaw:
    """Mixin of a swing-up law: the run's law (`inner` after the networks) inside the kept box
    |δ_i| ≤ box_i, δ = wrap(x − x*), and the law's own `law(x)` elsewhere.

    The dataclass that mixes it in holds x_star (n,), angle_mask (n,) bool, box (n,) half-widths
    (∞: a component not read) and inner (the run's own outer law, or None), and defines `law`.
    """

    def delta(self, x) -> np.ndarray:
        """δ = wrap(x − x*): (..., n) -> (..., n)."""
        return wrap_angles(np.asarray(x, dtype=np.float64) - self.x_star, self.angle_mask)

    @last_call
    def outside(self, x) -> np.ndarray:
        """(..., n) -> (...) bool: True outside the kept box (the swing-up law acts)."""
        return (np.abs(self.delta(x)) > self.box).any(axis=-1)

    def reads_networks(self, x) -> np.ndarray:
        """(N, n) -> (N,) bool: the rows whose networks' input `apply` reads (`OuterLaw`): inside the
        kept box, where the inner law (if any) reads them."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        keep = ~self.outside(x)
        reads = getattr(self.inner, "reads_networks", None)
        if reads is not None and keep.any():
            keep[keep] = reads(x[keep])
        return keep

    def apply(self, x, u, energy=None) -> np.ndarray:
        """The run's law (u after `inner`, given `energy` if it needs H_d) in the kept box, the swing-up
        law elsewhere: (N, n), (N, m) -> (N, m) (a new array)."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        u = np.array(u, dtype=np.float64, copy=True).reshape(len(x), -1)
        out = self.outside(x)
        if self.inner is not None and not out.all():  # the inner law only where it is applied
            keep = ~out
            u[keep] = self.inner.apply(x[keep], u[keep], energy=energy)
        if out.any():
            u[out] = self.law(x[out])
        return u

    def with_box(self, box):
        """The same law with another kept box (n,) (∞: a component not read)."""
        return replace(self, box=np.asarray(box, dtype=np.float64))

    def with_inner(self, inner):
        """The same law around another outer law of the run (None: the networks alone)."""
        return replace(self, inner=inner)

    @property
    def gain_at_target(self) -> float:
        """The inner law's factor on the networks' part of the linearisation at x* (1 without one)."""
        return float(getattr(self.inner, "gain_at_target", 1.0))

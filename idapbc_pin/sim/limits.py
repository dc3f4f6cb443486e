"""The input bound a rollout applies: the actuators' effort limits and an optional saturation.

DESIGN §4: the URDF's ``<limit effort>`` of the actuated joints (``system.effort``, (m,), +inf
where a joint has none) applies to every controller in every evaluation unless lifted with
``limits=False``; an explicit ``saturation`` (scalar or (m,)) is combined with it elementwise by
taking the smaller bound. Systems without an ``effort`` attribute (duck-typed test systems, the
paper's analytic systems load with +inf) are unlimited.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["InputLimits", "input_limits"]


def _fmt(bound: np.ndarray) -> str:
    """'20' when every input has that bound, else '5|10' (inf written as ∞)."""
    vals = [f"{b:.3g}" if np.isfinite(b) else "∞" for b in bound]
    return vals[0] if len(set(vals)) == 1 else "|".join(vals)


@dataclass(frozen=True, eq=False)
class InputLimits:
    """The bound |u_i| ≤ bound_i (N·m or N) a rollout clips the controller's input to.

    Attributes
    ----------
    bound : (m,) per-input bound (+inf where none), or None when nothing is clipped.
    effort : (m,) the system's own effort limits (+inf where none).
    applied : the effort limits are part of `bound` (``limits=True`` and at least one is finite).
    lifted : the system has finite effort limits but ``limits=False`` lifted them.
    saturation : the explicit saturation given (scalar or (m,)), or None.
    """

    bound: np.ndarray | None
    effort: np.ndarray
    applied: bool
    lifted: bool
    saturation: object = None

    def describe(self) -> str:
        """One phrase for a table header: which bound applies and where it comes from."""
        if self.bound is None:
            return "torque limits lifted (--no-limits): inputs unbounded" if self.lifted else "no torque limits (the system has none)"
        what = "effort limits" if self.applied else "saturation"
        if self.applied and self.saturation is not None:
            what = "effort limits and saturation"
        return f"|u| ≤ {self.bound_text()} ({what})" + (" [effort limits lifted]" if self.lifted else "")

    def bound_text(self) -> str:
        """The bound, ``'20'`` (every input) or ``'5|10'``; ``''`` when unbounded."""
        return "" if self.bound is None else _fmt(self.bound)

    def peak_text(self, peak: float) -> str:
        """A peak |u| next to the bound, e.g. ``'12.3 / 20'`` (just the peak when unbounded)."""
        text = f"{peak:.3g}"
        return text if self.bound is None else f"{text} / {self.bound_text()}"

    def to_json(self) -> dict:
        """{"applied", "lifted", "effort", "bound"} (inf → None), for the JSON files."""
        def as_list(a):
            return None if a is None else [float(v) if np.isfinite(v) else None for v in a]

        return {"applied": self.applied, "lifted": self.lifted, "effort": as_list(self.effort), "bound": as_list(self.bound)}


def input_limits(system, limits: bool = True, saturation=None) -> InputLimits:
    """The bound a rollout of `system` applies.

    Parameters
    ----------
    system : anything with ``m``; its ``effort`` ((m,), +inf where none) when it has one.
    limits : apply the effort limits (True, the default everywhere) or lift them.
    saturation : None, or max |u| per input (scalar or (m,), > 0); combined with the effort
        limits by taking the smaller bound.

    Raises ValueError for a saturation that is not positive.
    """
    m = int(system.m)
    effort = getattr(system, "effort", None)
    effort = np.full(m, np.inf) if effort is None else np.broadcast_to(np.asarray(effort, float), (m,)).copy()
    bound = np.full(m, np.inf)
    applied = bool(limits) and bool(np.isfinite(effort).any())
    if applied:
        bound = np.minimum(bound, effort)
    if saturation is not None:
        sat = np.broadcast_to(np.asarray(saturation, float), (m,))
        if np.any(~(sat > 0)):
            raise ValueError(f"saturation must be positive (max |u| per input), got {saturation!r}")
        bound = np.minimum(bound, sat)
    finite = bool(np.isfinite(bound).any())
    return InputLimits(
        bound=bound if finite else None,
        effort=effort,
        applied=applied,
        lifted=not limits and bool(np.isfinite(effort).any()),
        saturation=saturation,
    )

"""Which drawing a system gets: Pinocchio's model for URDF robots, closed forms for analytic systems."""

from __future__ import annotations

from ..errors import IdapbcError
from .drawing_analytic import AnalyticDrawing
from .drawing_base import Drawing
from .drawing_pinocchio import PinocchioDrawing

__all__ = ["STYLES", "drawing_for"]

#: Drawing styles: URDF visuals with sticks as fallback, visuals only, sticks and balls.
STYLES = ("auto", "visual", "stick")


def drawing_for(system, trace_link: str | None = None, style: str = "auto") -> Drawing:
    """The `Drawing` of `system`: `PinocchioDrawing` when its plant has a Pinocchio model and a URDF
    path, else `AnalyticDrawing` (which traces its tip and accepts no `trace_link`)."""
    if style not in STYLES:
        raise IdapbcError(f"style must be 'auto', 'visual' or 'stick', got '{style}'.")
    plant = getattr(system, "plant", None)
    if hasattr(plant, "model") and hasattr(plant, "path"):
        return PinocchioDrawing(plant, trace_link, style)
    if trace_link is not None:
        raise IdapbcError(f"trace_link applies to URDF robots; '{system.name}' is drawn from its coordinates. Fix: drop trace_link.")
    return AnalyticDrawing(system)

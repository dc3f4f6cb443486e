"""The kept boxes of a swing-up law: where the run's law keeps control and the swing-up law does not
act (`recovery.swing_stage`'s gate judges each, the anywhere step reads the one it chose)."""

from __future__ import annotations

import numpy as np

from .config import SwingUpConfig

__all__ = ["ANY_SPEED", "any_speed_boxes", "box_half_widths", "chosen_box", "kept_boxes", "posture_box"]

#: Name of the kept box that reads the training box's angles and no momentum (`any_speed_boxes`).
ANY_SPEED = "posture, any speed"


def box_half_widths(system) -> np.ndarray:
    """(n,) the training box's half-widths about its centre."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in system.domain)
    return (hi - lo) / 2


def posture_box(system, config: SwingUpConfig) -> np.ndarray:
    """(n,) the kept box of a swing-up law: the training box's angles, its momenta × `kept_momenta`
    (∞ where 0), every other coordinate not read (∞)."""
    s, mask = box_half_widths(system), np.asarray(system.angle_mask, dtype=bool)
    momenta = np.arange(s.size) >= system.nq
    k = float(config.kept_momenta)
    return np.where(mask, s, np.where(momenta & (k > 0), k * s, np.inf))


def kept_boxes(system, config: SwingUpConfig) -> dict:
    """The candidate kept boxes of the gate, {name: (n,) half-widths}: "posture" (`posture_box`),
    and "r = …" (r·s on every component) for r in `config.inner_scales`."""
    s = box_half_widths(system)
    return {"posture": posture_box(system, config)} | {f"r = {r:g}": float(r) * s for r in config.inner_scales}


def any_speed_boxes(system, config: SwingUpConfig) -> dict:
    """The second gate's kept box, {ANY_SPEED: (n,)}: the training box's angles with no momentum read
    (`posture_box` with `kept_momenta` 0); empty where the posture box reads no momentum anyway."""
    return {ANY_SPEED: posture_box(system, config.replace(kept_momenta=0.0))} if config.kept_momenta > 0 else {}


def chosen_box(run, system, config: SwingUpConfig) -> np.ndarray:
    """(n,) the kept box of the swing-up law the stage's gate chose (summary.json → "swing_up" →
    "gate" → "box"; "posture" where the run has no gate)."""
    name = ((run.summary.get("swing_up") or {}).get("gate") or {}).get("box", "posture")
    boxes = kept_boxes(system, config) | any_speed_boxes(system, config)
    return boxes.get(name, boxes["posture"])

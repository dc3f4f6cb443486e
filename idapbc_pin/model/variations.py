"""Plant parameters a robustness study varies, read from the URDF, and plants that differ row by row.

A real robot's inertial parameters are known to 10–25 %, its joints have friction the model leaves
out, and its motors add rotor inertia. The RealAIGym robustness test (leaderboard v2) varies one
parameter at a time; for any chain of 1-DoF joints the parameters come from the model itself:

* per link moved by a revolute joint (a: its axis, c⊥: the centre of mass's lever off the axis,
  I_a = aᵀI_c a + m|c⊥|²: the inertia about the axis):
  ``m·r`` (c⊥ × s at fixed m and I_a), ``I`` (I_a × s at fixed m and c), and ``m`` (m × s at fixed
  c and I_a; left out for a link hung from the fixed base, whose mass enters only through m·r and
  I_a);
* per link moved by a prismatic joint: ``m`` (mass and rotational inertia × s);
* per joint: ``b`` (viscous damping D + Δb, N·m·s/rad or N·s/m) and ``cf`` (Coulomb friction
  cf·arctan(100 v), N·m or N, the smooth form of the leaderboard);
* ``rotor``: a rotor of inertia I_r behind a gear of ratio `GEAR` on every joint (armature g²·I_r).

The changes of m, c⊥ and I_a move only the inertia about the joint's own axis (a rank-one term
along a), so I_c may leave the physically consistent cone; Pinocchio's algorithms are linear in
it and need only M(q) ≻ 0. `RowPlants` evaluates a batch whose rows each carry their own model,
damping and friction (the true plants of a robustness batch).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..errors import IdapbcError

__all__ = ["COULOMB_SLOPE", "FAMILY_KINDS", "GEAR", "Family", "RowPlants", "plant_families", "varied_model"]

#: Gear ratio of the rotor family (the RealAIGym robots' motors).
GEAR = 6.0
#: Slope of the smooth Coulomb friction cf·arctan(COULOMB_SLOPE·v) (1/(rad/s) or 1/(m/s)).
COULOMB_SLOPE = 100.0
#: What a `Family` varies: inertial ("m·r", "I", "m", "rotor") or joint friction ("b", "cf").
FAMILY_KINDS = ("m·r", "I", "m", "rotor", "b", "cf")


@dataclass(frozen=True)
class Family:
    """One varied parameter and its levels.

    name : label, e.g. "m·r elbow". kind : one of `FAMILY_KINDS`. joint : index of the coordinate
    (the joint, or the link it moves; -1 for "rotor", every joint). levels : (L,) the values: a
    scale (m·r, I, m), an increment (b, N·m·s/rad), a coefficient (cf, N·m) or a rotor inertia
    (rotor, kg·m²). nominal : the level that leaves the plant unchanged.
    """

    name: str
    kind: str
    joint: int
    levels: tuple
    nominal: float

    @property
    def inertial(self) -> bool:
        """True when the family changes the model's inertias (a model of its own per row)."""
        return self.kind in ("m·r", "I", "m", "rotor")


def _pin_model(plant) -> "pin.Model":
    model = getattr(plant, "model", None)
    if not isinstance(model, pin.Model):
        raise IdapbcError("plant variations need a URDF robot (a Pinocchio plant). Fix: use a robot loaded from a URDF or the zoo.")
    return model


def _joint_ids(plant) -> list[int]:
    """Pinocchio joint id of each minimal coordinate (the plant's joints, in the model's order)."""
    return list(range(1, _pin_model(plant).njoints))


def plant_families(plant, levels: int = 21, scale=(0.75, 1.25), damping=(-0.1, 0.1), coulomb=(-0.2, 0.2), rotor=(0.0, 1e-4)) -> list[Family]:
    """The varied parameters of `plant` (module docstring), each with `levels` evenly spaced values:
    scales in `scale`, damping increments in `damping`, Coulomb coefficients in `coulomb`, rotor
    inertias in `rotor` (kg·m², behind `GEAR`). Links in coordinate order; the rotor family last.
    A plant without a URDF (a closed form) has the joint families only."""
    lin = lambda lo, hi: tuple(float(x) for x in np.linspace(lo, hi, int(levels)))  # noqa: E731
    out: list[Family] = []
    urdf = isinstance(getattr(plant, "model", None), pin.Model)
    if urdf:
        model = plant.model
        ids = _joint_ids(plant)
    for i, info in enumerate(plant.joints if urdf else ()):
        jid = ids[i]
        if info.kind == "prismatic":
            out.append(Family(f"m {info.name}", "m", i, lin(*scale), 1.0))
        else:
            out.append(Family(f"m·r {info.name}", "m·r", i, lin(*scale), 1.0))
            out.append(Family(f"I {info.name}", "I", i, lin(*scale), 1.0))
            if model.parents[jid] != 0:
                out.append(Family(f"m {info.name}", "m", i, lin(*scale), 1.0))
    for i, info in enumerate(plant.joints):
        out.append(Family(f"b {info.name}", "b", i, lin(*damping), 0.0))
        out.append(Family(f"cf {info.name}", "cf", i, lin(*coulomb), 0.0))
    if urdf:
        out.append(Family("rotor", "rotor", -1, lin(*rotor), 0.0))
    return out


def varied_model(plant, kind: str, joint: int, value: float) -> "pin.Model":
    """A copy of `plant`'s Pinocchio model with one inertial parameter changed (module docstring):
    `kind` "m·r", "I" or "m" of the link moved by coordinate `joint` scaled by `value`, or "rotor"
    (armature `GEAR`²·value on every joint)."""
    model = _pin_model(plant).copy()
    if kind == "rotor":
        model.armature = np.asarray(model.armature, float) + GEAR**2 * float(value)
        return model
    if kind not in ("m·r", "I", "m"):
        raise IdapbcError(f"unknown inertial variation {kind!r}. Fix: one of m·r, I, m, rotor.")
    jid = _joint_ids(plant)[joint]
    inertia = model.inertias[jid]
    m, c, I_c = float(inertia.mass), np.array(inertia.lever, float), np.array(inertia.inertia, float)
    s = float(value)
    if plant.joints[joint].kind == "prismatic":
        if kind != "m":
            raise IdapbcError(f"a prismatic joint's link has no {kind} to vary. Fix: vary its mass (m).")
        model.inertias[jid] = pin.Inertia(m * s, c, I_c * s)
        return model
    a = np.asarray(plant.joints[joint].axis, float)
    a = a / np.linalg.norm(a)
    c_perp = c - (c @ a) * a
    r2 = float(c_perp @ c_perp)
    I_axis = float(a @ I_c @ a) + m * r2
    if kind == "m·r":  # the lever × s, the inertia about the axis kept
        c = (c @ a) * a + s * c_perp
        delta = m * r2 * (1.0 - s * s)
    elif kind == "I":  # the inertia about the axis × s
        delta = (s - 1.0) * I_axis
    else:  # the mass × s, the lever and the inertia about the axis kept
        delta = (1.0 - s) * m * r2
        m = m * s
    varied = pin.Inertia(m, c, np.eye(3))
    varied.inertia = I_c + delta * np.outer(a, a)  # set after construction: the constructor refuses a tensor outside the cone
    model.inertias[jid] = varied
    return model


class RowPlants:
    """A batch of true plants, one per row: accelerations with each row's own model and friction.

    Rows whose model is None use `plant` (batched, pooled ABA); the others loop over their own
    Pinocchio model (one ABA call per row). Every row adds its own viscous damping D_row and smooth
    Coulomb friction cf_row·arctan(`COULOMB_SLOPE`·v) to the torques.

    Parameters
    ----------
    plant : the nominal `PinocchioPlant`.
    models : length-N list of `pin.Model` or None.
    damping : (N, nv) viscous damping of each row (N·m·s/rad or N·s/m), the nominal's included.
    coulomb : (N, nv) Coulomb coefficients (N·m or N).
    """

    def __init__(self, plant, models: list, damping: np.ndarray, coulomb: np.ndarray):
        if any(mdl is not None for mdl in models):
            _pin_model(plant)
        self.plant = plant
        self.N = len(models)
        self.damping = np.asarray(damping, float).reshape(self.N, plant.nv)
        self.coulomb = np.asarray(coulomb, float).reshape(self.N, plant.nv)
        self._own = np.array([k for k, mdl in enumerate(models) if mdl is not None], dtype=int)
        self._shared = np.array([k for k, mdl in enumerate(models) if mdl is None], dtype=int)
        self._models = [(models[k], models[k].createData()) for k in self._own]
        self._args = (plant, list(models), self.damping, self.coulomb)

    def __reduce__(self):  # Models pickle; their Data are rebuilt (worker processes)
        return (RowPlants, self._args)

    def friction(self, v: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Joint friction torques −D v − cf·arctan(100 v) of `rows` (k,) at speeds v (k, nv)."""
        return -self.damping[rows] * v - self.coulomb[rows] * np.arctan(COULOMB_SLOPE * v)

    def accel(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """v̇ of every row: (N, nv) ×3 -> (N, nv), tau the applied joint torques (friction added here)."""
        rows = np.arange(self.N)
        tau = tau + self.friction(v, rows)
        a = np.empty_like(q)
        base = self.plant
        if self._shared.size:
            s = self._shared
            a[s] = base.forward_dynamics(q[s], v[s], tau[s] + base.damping * v[s])  # the nominal damping is in self.damping
        if self._own.size:
            qc = base.config(q[self._own])
            for j, k in enumerate(self._own):
                model, data = self._models[j]
                a[k] = pin.aba(model, data, qc[j], v[k], tau[k])
        return a

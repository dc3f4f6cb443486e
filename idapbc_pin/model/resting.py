"""Where a robot rests and where its tip is: the start and the yardstick of a swing-up (DESIGN §4).

* `resting_configuration`: the lowest-potential equilibrium q_rest (nq,), the posture a swing-up
  starts from (a pendulum hanging straight down).
* `tip_height`: the height (world z, m) of the chain's tip, batched over configurations; the
  RealAIGym leaderboard's tip test reads it (`idapbc_pin.evaluation.swingup`).

Both read the system's plant; the forward kinematics run on the Pinocchio model inside this package,
so no Pinocchio object leaves `idapbc_pin.model`.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin

from ..errors import IdapbcError
from ._pinocchio import PinocchioPlant
from .angles import wrap_angles

__all__ = ["TIP_FRAME_PATTERN", "resting_configuration", "tip_height", "tip_point"]

#: Grid points over all angle coordinates together (the grid per angle shrinks as angles add up).
_GRID_POINTS = 20_000
#: Potentials within this share of their range over the grid tie (broken toward x*).
_TIE_RTOL = 1e-9
#: A frame (a link fixed to the last moving link) whose name matches this is the chain's tip.
TIP_FRAME_PATTERN = re.compile(r"(tip|end[_-]?effector|(^|_)ee($|_)|eef|tool)", re.IGNORECASE)


# ================================================================ resting configuration
def _angle_grid(k_angles: int) -> np.ndarray:
    """(k^a, a) offsets from x* over the angle coordinates: k (even) values per angle in (−π, π],
    0 and π among them."""
    k = int(_GRID_POINTS ** (1.0 / k_angles))
    k = max(8, min(72, k - k % 2))
    axis = -math.pi + 2.0 * math.pi * np.arange(1, k + 1) / k
    return np.stack(np.meshgrid(*([axis] * k_angles), indexing="ij"), axis=-1).reshape(-1, k_angles)


def _potential_gradient(system, q: np.ndarray) -> np.ndarray:
    """∇U(q) (nq,) as −ṗ of the open loop at rest (p = 0: no Coriolis or damping term)."""
    x = np.concatenate([q, np.zeros(system.nq)])
    return -np.asarray(system.f(x), float)[system.nq :]


def _nearest_representative(q: np.ndarray, q_star: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """q with its angles moved by whole turns to within ±π of x*'s; an angle exactly opposite x*'s
    (within 1e-9 rad) takes the representative nearer 0, +π from x*'s on a tie."""
    out = q.copy()
    for i in np.flatnonzero(angles):
        d = float(wrap_angles(np.array([q[i] - q_star[i]]), np.array([True]))[0])
        if abs(abs(d) - math.pi) <= 1e-9:
            up, down = q_star[i] + math.pi, q_star[i] - math.pi
            out[i] = up if abs(up) <= abs(down) + 1e-12 else down
        else:
            out[i] = q_star[i] + d
    return out


def resting_configuration(system) -> np.ndarray:
    """The robot's resting equilibrium q_rest (nq,), float64: where its potential is lowest.

    Angle coordinates (revolute, continuous) minimise ``system.potential`` jointly: a grid over the
    circle for each (offsets from x* in (−π, π], at least 8 and at most 72 values per angle), the
    lowest grid point (ties, e.g. a wheel or a Furuta arm the potential ignores, broken toward x*)
    refined by BFGS on the exact gradient ∇U. Linear coordinates keep x*'s value: a cart rests
    anywhere on its rail, so it rests at its target. Each angle is then written within ±π of x*'s
    (the physical posture the tip test and the start states care about); an angle exactly opposite
    x*'s takes the representative nearer 0 (the URDF's own zero), +π on a tie. Works for URDF and
    built-in analytic systems alike (both have a potential).
    """
    nq = system.nq
    q_star = np.asarray(system.x_star, float)[:nq]
    angles = np.asarray(system.angle_mask, bool)[:nq]
    if not angles.any():
        return q_star.copy()
    idx = np.flatnonzero(angles)
    grid = _angle_grid(idx.size)
    Q = np.broadcast_to(q_star, (grid.shape[0], nq)).copy()
    Q[:, idx] += grid
    U = np.asarray(system.potential(Q), float)
    if not np.all(np.isfinite(U)):
        raise IdapbcError(f"the potential of '{system.name}' is not finite on the circle of its angles. Fix: check the model's masses and lengths.")
    tol = _TIE_RTOL * max(float(U.max() - U.min()), 1e-300)
    ties = np.flatnonzero(U <= U.min() + tol)
    best = ties[np.argmin(np.linalg.norm(grid[ties], axis=1))]
    q0 = Q[best].copy()

    def fun(z):
        q = q0.copy()
        q[idx] = z
        return float(system.potential(q)), _potential_gradient(system, q)[idx]

    from scipy.optimize import minimize  # here, not at import: scipy.optimize takes ~0.35 s to load

    res = minimize(fun, q0[idx], jac=True, method="BFGS", options={"gtol": 1e-12})
    q = q0.copy()
    if np.all(np.isfinite(res.x)) and fun(res.x)[0] <= U[best]:
        q[idx] = res.x
    return _nearest_representative(q, q_star, angles)


# ================================================================ tip height
def _visual_ends(urdf, link: str) -> list[np.ndarray]:
    """End points (3,) in the link's frame (m) of the cylinder and box visuals of `link` in the
    URDF file `urdf`: a cylinder's two face centres, a box's six face centres."""
    try:
        root = ET.parse(urdf).getroot()
    except (OSError, ET.ParseError):
        return []
    ends = []
    for el in root.iter("link"):
        if el.get("name") != link:
            continue
        for visual in el.findall("visual"):
            origin = visual.find("origin")
            xyz = np.array([float(a) for a in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()])
            rpy = [float(a) for a in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()]
            R = np.asarray(pin.rpy.rpyToMatrix(*rpy))
            geometry = visual.find("geometry")
            shape = geometry[0] if geometry is not None and len(geometry) else None
            if shape is None:
                continue
            if shape.tag == "cylinder":
                half = np.array([0.0, 0.0, 0.5 * float(shape.get("length", "0"))])
                ends += [xyz + R @ half, xyz - R @ half]
            elif shape.tag == "box":
                size = np.array([float(a) for a in shape.get("size", "0 0 0").split()])
                for axis in range(3):
                    half = np.zeros(3)
                    half[axis] = 0.5 * size[axis]
                    ends += [xyz + R @ half, xyz - R @ half]
    return ends


def _urdf_child_link(urdf, joint: str) -> str | None:
    try:
        root = ET.parse(urdf).getroot()
    except (OSError, ET.ParseError):
        return None
    for el in root.iter("joint"):
        if el.get("name") == joint and el.find("child") is not None:
            return el.find("child").get("link")
    return None


def _pinocchio_plant(system) -> PinocchioPlant:
    """The system's Pinocchio plant, or the one a twin engine was built from (``plant.base``: the
    MuJoCo judge of the same URDF has the same kinematics)."""
    plant = system.plant
    plant = getattr(plant, "base", plant) if not isinstance(plant, PinocchioPlant) else plant
    if not isinstance(plant, PinocchioPlant):
        raise IdapbcError(
            f"the tip test needs a URDF model, and '{system.name}' is a built-in closed form without links. "
            "Fix: load the robot from its URDF (a zoo name or a .urdf path)."
        )
    return plant


def tip_point(system) -> tuple[str, np.ndarray]:
    """(joint name, point (3,) in that joint's frame, m): the chain's tip, the end of the last link.

    The last joint of the model (the leaf of a chain) carries it. The rule, first that applies:

    1. a frame named like a tip or end effector (`TIP_FRAME_PATTERN`: tip, end_effector, ee, eef,
       tool), a link fixed to the last moving link: its origin;
    2. the link's centre of mass c is off the joint axis: the end of the link along c, i.e. the
       farthest face centre along c of the link's cylinder and box visuals when it lies beyond c
       (a rod of length l drawn from the joint), else 2c (the far end of a uniform rod, the end the
       viewer draws, `idapbc_pin.viewer.drawing_pinocchio`);
    3. c on the joint (a wheel at the tip of a pendulum): the joint's origin.

    Raises IdapbcError for a built-in analytic system (no links: the tip test needs a URDF model).
    """
    plant = _pinocchio_plant(system)
    model = plant.model
    j = model.njoints - 1
    for frame in model.frames:
        if frame.parentJoint == j and frame.type == pin.FrameType.BODY and TIP_FRAME_PATTERN.search(frame.name):
            return str(model.names[j]), np.asarray(frame.placement.translation, float).copy()
    c = np.asarray(model.inertias[j].lever, float).copy()
    norm = float(np.linalg.norm(c))
    if norm <= 1e-12:
        return str(model.names[j]), np.zeros(3)
    direction = c / norm
    link = _urdf_child_link(plant.path, model.names[j])
    ends = _visual_ends(plant.path, link) if link else []
    if ends:
        far = max(ends, key=lambda e: float(e @ direction))
        if float(far @ direction) > norm * (1.0 + 1e-9):
            return str(model.names[j]), direction * float(far @ direction)
    return str(model.names[j]), 2.0 * c


def tip_height(system, q) -> np.ndarray:
    """Height (world z, m) of the chain's tip (`tip_point`) at configurations q: (N, nq) -> (N,)
    (a single (nq,) gives a float). Pinocchio's forward kinematics of the system's URDF model.

    Raises IdapbcError for a built-in analytic system: the tip test needs a URDF model.
    """
    plant = _pinocchio_plant(system)
    q = np.asarray(q, float)
    single = q.ndim == 1
    qb = q[None] if single else q
    if qb.ndim != 2 or qb.shape[1] != system.nq:
        raise ValueError(f"q must have shape (N, {system.nq}) or ({system.nq},), got {np.shape(q)}")
    name, point = tip_point(system)
    model = plant.model
    data = model.createData()
    j = model.getJointId(name)
    out = np.empty(qb.shape[0])
    for k, qc in enumerate(plant.config(qb)):
        pin.forwardKinematics(model, data, qc)
        out[k] = data.oMi[j].act(point)[2]
    return out[0] if single else out

"""URDF robots drawn from Pinocchio's model: their visual geometry, or sticks and balls when they have none.

The only viewer module that imports Pinocchio. Visual geometry (primitives, and meshes found through
the URDF's folder and example-robot-data's ``share`` directory as package dirs) is loaded with
Pinocchio's meshcat loader and placed by ``pin.updateGeometryPlacements``. With no visuals, a
ball sits at each joint, a rod runs from each joint to its children, and from a leaf joint to the far
end of its link (2 × its centre of mass).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

from ..errors import IdapbcError
from ..model import erd_robots_dir
from ._transforms import PALETTE, material
from .drawing_base import Drawing

__all__ = ["PinocchioDrawing"]


def _rod_placement(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """4x4 placement of a meshcat cylinder (axis = local y) spanning points a -> b (3,), m."""
    d = b - a
    length = float(np.linalg.norm(d))
    T = np.eye(4)
    T[:3, 3] = 0.5 * (a + b)
    if length > 0:
        T[:3, :3] = pin.Quaternion.FromTwoVectors(np.array([0.0, 1.0, 0.0]), d / length).toRotationMatrix()
    return T


def _package_dirs(urdf: Path) -> list[str]:
    dirs = [str(urdf.parent), str(urdf.parent.parent)]
    try:
        dirs.append(str(erd_robots_dir().parent.parent))
    except IdapbcError:
        pass
    return dirs


def _visual_model(model, urdf: Path):
    """Pinocchio's visual GeometryModel of `urdf`, meshes resolved through the package dirs."""
    try:
        return pin.buildGeomFromUrdf(model, str(urdf), pin.GeometryType.VISUAL, package_dirs=_package_dirs(urdf))
    except (ValueError, RuntimeError) as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise IdapbcError(
            f"cannot load the visual geometry of '{urdf}': {msg}. Fix: put the meshes next to the URDF, or give "
            "package:// paths that resolve from the URDF's folder or example-robot-data's share directory."
        ) from None


def _trace_frame(model, trace_link: str | None) -> tuple[int, np.ndarray]:
    """-> (joint id, point (3,) in that joint's frame, m) of the traced point.

    A joint name, or the link it moves, traces that link's far end, joint origin + 2 c (c: centre of
    mass of the joint's body, the far end of a uniform rod); any other link (one fixed to a moving
    link) traces its own origin. Default: the last joint of the model.
    """

    def far_end(j: int) -> np.ndarray:
        return 2.0 * np.asarray(model.inertias[j].lever, float)

    if trace_link is None:
        j = model.njoints - 1
        return j, far_end(j)
    names = list(model.names)
    if trace_link in names[1:]:
        j = names.index(trace_link)
        return j, far_end(j)
    if model.existFrame(trace_link):
        fid = model.getFrameId(trace_link)
        frame = model.frames[fid]
        if frame.type == pin.FrameType.BODY:
            if frame.placement.isIdentity() and frame.parentJoint > 0:
                return frame.parentJoint, far_end(frame.parentJoint)
            return frame.parentJoint, np.asarray(frame.placement.translation, float)
    links = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
    raise IdapbcError(f"unknown trace link '{trace_link}'. Valid joints: {', '.join(names[1:])}; links: {', '.join(links)}.")


def _sticks(model) -> list[tuple]:
    """Stick-and-ball nodes of the kinematic tree: (path, parent joint, local placement (4, 4), kind,
    size (m), colour)."""
    m = model
    children = {j: [c for c in range(1, m.njoints) if m.parents[c] == j] for j in range(m.njoints)}
    nodes = [("sticks/base", 0, np.eye(4), "box", (0.08, 0.08, 0.08), 0x555555)]
    for j in range(1, m.njoints):
        color = PALETTE[(j - 1) % len(PALETTE)]
        nodes.append((f"sticks/joint_{m.names[j]}", j, np.eye(4), "ball", 0.035, 0x222222))
        p = m.jointPlacements[j].translation
        if np.linalg.norm(p) > 1e-9:
            # rod from the parent joint to this joint, carried by the parent joint's frame
            nodes.append((f"sticks/rod_{m.names[m.parents[j]]}_{m.names[j]}", int(m.parents[j]), _rod_placement(np.zeros(3), np.asarray(p)), "rod", np.linalg.norm(p), color))
        if not children[j]:
            tip = 2.0 * np.asarray(m.inertias[j].lever, float)
            if np.linalg.norm(tip) > 1e-9:
                nodes.append((f"sticks/rod_{m.names[j]}_end", j, _rod_placement(np.zeros(3), tip), "rod", np.linalg.norm(tip), color))
                end = np.eye(4)
                end[:3, 3] = tip
                nodes.append((f"sticks/end_{m.names[j]}", j, end, "ball", 0.05, color))
    return nodes


class PinocchioDrawing(Drawing):
    """A URDF robot: its visual geometry, or a stick-and-ball rendering when it has none.

    Parameters
    ----------
    plant : the system's Pinocchio plant: ``model`` (pin.Model), ``path`` (its URDF) and
        ``config`` (minimal coordinates (K, nq) -> Pinocchio configurations (K, model.nq)).
    trace_link : joint or link whose far end is traced (see `_trace_frame`); None: the last joint.
    style : ``"auto"`` (visuals, sticks if none), ``"visual"`` (visuals or an error) or ``"stick"``.
    """

    def __init__(self, plant, trace_link: str | None = None, style: str = "auto"):
        self.model = plant.model
        self.data = self.model.createData()
        self.config = plant.config
        self.trace_joint, self.trace_point = _trace_frame(self.model, trace_link)
        self.visual_model = _visual_model(self.model, Path(plant.path)) if style in ("auto", "visual") else None
        if self.visual_model is not None and self.visual_model.ngeoms == 0:
            if style == "visual":
                raise IdapbcError(f"'{plant.path}' has no <visual> geometry. Fix: use style='auto' or 'stick'.")
            self.visual_model = None
        if self.visual_model is not None:
            self.style = "visual"
            self.visual_data = self.visual_model.createData()
            objs = self.visual_model.geometryObjects
            self.paths = [f"visuals/{g.name}" for g in objs]
            self.scales = np.array([np.asarray(g.meshScale, float) for g in objs])
            self.moving = np.array([g.parentJoint > 0 for g in objs])
        else:
            self.style = "stick"
            self._sticks = _sticks(self.model)
            self.paths = [n[0] for n in self._sticks]
            self.scales = np.ones((len(self._sticks), 3))
            self.moving = np.array([n[1] > 0 for n in self._sticks])

    def load(self, vis) -> None:
        import meshcat.geometry as mg

        if self.style == "visual":
            from pinocchio.visualize import MeshcatVisualizer

            viz = MeshcatVisualizer(self.model, None, self.visual_model)
            viz.viewer = vis
            viz.viewerVisualGroupName = "visuals"
            for g in self.visual_model.geometryObjects:
                viz.loadViewerGeometryObject(g, pin.GeometryType.VISUAL)
            return
        for path, _, _, kind, size, color in self._sticks:
            if kind == "ball":
                vis[path].set_object(mg.Sphere(size), material(color))
            elif kind == "box":
                vis[path].set_object(mg.Box(size), material(color))
            else:
                vis[path].set_object(mg.Cylinder(size, 0.02), material(color))

    def placements(self, q: np.ndarray) -> np.ndarray:
        qs = self.config(np.atleast_2d(np.asarray(q, float)))
        out = np.empty((qs.shape[0], len(self.paths), 4, 4))
        for k, qc in enumerate(qs):
            pin.forwardKinematics(self.model, self.data, qc)
            if self.style == "visual":
                pin.updateGeometryPlacements(self.model, self.data, self.visual_model, self.visual_data)
                for i, M in enumerate(self.visual_data.oMg):
                    out[k, i] = M.homogeneous
            else:
                for i, (_, j, local, _, _, _) in enumerate(self._sticks):
                    out[k, i] = self.data.oMi[j].homogeneous @ local
        return out

    def trace(self, q: np.ndarray) -> np.ndarray:
        qs = self.config(np.atleast_2d(np.asarray(q, float)))
        out = np.empty((qs.shape[0], 3))
        for k, qc in enumerate(qs):
            pin.forwardKinematics(self.model, self.data, qc)
            out[k] = self.data.oMi[self.trace_joint].act(self.trace_point)
        return out

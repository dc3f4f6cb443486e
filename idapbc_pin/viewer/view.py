"""See it move: meshcat animations of closed-loop trajectories, live in a browser or as one HTML file.

    viewer = ip.view(run)                         # 3 rollouts from the half domain, live server
    viewer.write_html("replay.html")              # one self-contained file, replays offline
    viewer.close()                                # stops the server process

What is drawn
-------------
* URDF robots: their ``<visual>`` geometry (primitives, and meshes found through the URDF's folder and
  example-robot-data's ``share`` directory as package dirs), loaded with Pinocchio's meshcat
  loader and placed by ``pin.updateGeometryPlacements``.
* URDF robots with no visual geometry: a stick-and-ball rendering of the kinematic tree (a ball
  per joint, a rod from each joint to its children, and from a leaf joint to the far end of its link,
  2 × its centre of mass).
* The paper's analytic systems: a cart-pole (cart at q1, pole of length 1 at angle q2 about y,
  upright at 0), a double pendulum (two links of length 1, absolute angles from upright) and a
  block at position q for the mass-spring-damper.

Animation
---------
Keyframes sit at trajectory samples (at least `fps` per second where the sampling allows, always
the first and last sample) and hold each node's world placement as position + quaternion. The
meshcat clips use
``fps = 1``, so a keyframe's "frame" number *is* its time in seconds. Several rollouts play one
after another (``layout="sequence"``, a 0.5 s pause between them) or at the same time, side by side
(``layout="side_by_side"``). An optional trace draws the path of the end link's far end. The camera
frames the whole motion, across the plane of motion of planar robots.

Server and HTML
---------------
The scene is recorded in memory by meshcat's own server logic, so `Viewer.write_html` needs no
server process and writes the page meshcat's ``static_html()`` gives (viewer JavaScript inlined
from the installed package: no CDN, replays offline) plus a short script: ``replay.html#t=2.5``
opens it held at 2.5 s. `Viewer.serve` starts meshcat's
server in a child process bound to 127.0.0.1 (``port``: the HTTP port of the page
``http://127.0.0.1:<port>/static/``; None picks the first free port from 7000; a port in use is an
error; meshcat picks its internal ZeroMQ port itself, from 6000). The child exits when `close` is
called, when the viewer is garbage collected, and when this process exits in any way (it watches
its standard input), so no server outlives its viewer.
"""

from __future__ import annotations

import argparse
import math
import select
import subprocess
import sys
import tempfile
import time
import warnings
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import IdapbcError
from ..sim.states import initial_states

__all__ = [
    "DEFAULT_FPS",
    "Camera",
    "MeshcatServer",
    "Segment",
    "Viewer",
    "add_view_command",
    "view",
    "write_html",
]

#: Keyframes per second of trajectory time (three.js interpolates between them).
DEFAULT_FPS = 30.0
#: Pause between rollouts in the "sequence" layout, s.
SEQUENCE_GAP = 0.5
#: meshcat's default perspective camera: vertical field of view, degrees.
CAMERA_FOV_DEG = 75.0

_PALETTE = (0x3366CC, 0xF28C1A, 0x2CA02C, 0xD62728, 0x9467BD, 0x8C564B, 0xE377C2, 0x17BECF)


# ====================================================================== meshcat scene in memory
def _import_meshcat():
    """Import meshcat (its server module imports a pyzmq module that warns it is deprecated)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import meshcat
        import meshcat.servers.zmqserver  # noqa: F401

    return meshcat


class _ReplySocket:
    """Stands in for the server's ZeroMQ socket: keeps the last reply."""

    reply: bytes = b""

    def send(self, data: bytes) -> None:
        self.reply = data


class _BridgeState:
    """The state `meshcat.servers.zmqserver.ZMQWebSocketBridge.handle_zmq` works on, in memory."""

    def __init__(self):
        from meshcat.servers.tree import SceneTree

        self.tree = SceneTree()
        self.zmq_socket = _ReplySocket()
        self.websocket_pool: set = set()
        self.web_url = ""

    def forward_to_websockets(self, frames) -> None:  # no browsers in memory
        pass


class _SceneRecorder:
    """A meshcat "window" that records the scene in this process.

    Every command goes through meshcat's own server code (``ZMQWebSocketBridge.handle_zmq``) on an
    in-memory scene tree, so `get_scene` (what ``Visualizer.static_html()`` calls) returns exactly
    the HTML meshcat's server would, with no server process. `messages` keeps the commands in
    order, ready to be replayed into a live server.
    """

    def __init__(self):
        self._state = _BridgeState()
        self.messages: list[list[bytes]] = []
        self.web_url = None

    def _handle(self, frames: list[bytes]) -> bytes:
        ZMQWebSocketBridge = _import_meshcat().servers.zmqserver.ZMQWebSocketBridge

        ZMQWebSocketBridge.handle_zmq(self._state, frames)
        return self._state.zmq_socket.reply

    def send(self, command) -> None:
        import umsgpack

        data = command.lower()
        frames = [data["type"].encode("utf-8"), data["path"].encode("utf-8"), umsgpack.packb(data)]
        reply = self._handle(frames)
        if reply != b"ok":
            raise RuntimeError(f"meshcat rejected a {data['type']} command: {reply!r}")
        self.messages.append(frames)

    def get_scene(self) -> str:
        return self._handle([b"get_scene"]).decode("utf-8")


# ====================================================================== live server
_SERVER_SCRIPT = r"""# idapbc-pin meshcat server
import os, sys, threading
import tornado.web
from meshcat.servers import zmqserver as z

class LoopbackApp(tornado.web.Application):
    def listen(self, port, address="127.0.0.1", **kwargs):
        return super().listen(port, address=address, **kwargs)

class Bridge(z.ZMQWebSocketBridge):
    def make_app(self):
        return LoopbackApp([
            (r"/static/(.*)", z.StaticFileHandlerNoCache, {"path": z.VIEWER_ROOT, "default_filename": z.VIEWER_HTML}),
            (r"/", z.WebSocketHandler, {"bridge": self}),
        ])

def watch_parent():
    sys.stdin.buffer.read()  # EOF once the parent is gone, however it ended
    os._exit(0)

port = int(sys.argv[1]) if sys.argv[1] else None
try:
    bridge = Bridge(port=port)
except OSError as exc:
    print("error=" + str(exc).replace("\n", " "), flush=True)
    sys.exit(3)
threading.Thread(target=watch_parent, daemon=True).start()
print("zmq_url=" + bridge.zmq_url, flush=True)
print("web_url=" + bridge.web_url, flush=True)
os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
try:
    bridge.run()
except KeyboardInterrupt:
    pass
"""

#: Marker in the server's command line (tests look for leftover processes with it).
SERVER_MARKER = "# idapbc-pin meshcat server"


def _stop_process(proc: subprocess.Popen, stdin, log) -> None:
    try:
        if stdin is not None and not stdin.closed:
            stdin.close()
    except OSError:
        pass
    if proc.poll() is None:
        proc.kill()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:  # pragma: no cover - kill does not fail on Linux
        pass
    for stream in (proc.stdout, log):
        try:
            stream.close()
        except Exception:
            pass


class MeshcatServer:
    """meshcat's web + ZeroMQ server in a child process, bound to 127.0.0.1.

    Parameters
    ----------
    port : HTTP port of the viewer page ``http://127.0.0.1:<port>/static/``. None: the first
        free port from 7000. A port in use raises `IdapbcError`.
    timeout : seconds to wait for the server to start.

    The child process ends on `close`, on garbage collection, at interpreter exit, and when this
    process dies (it exits on end-of-file on its standard input).
    """

    def __init__(self, port: int | None = None, timeout: float = 30.0):
        import zmq

        if port is not None and not (isinstance(port, (int, np.integer)) and 0 < int(port) < 65536):
            raise IdapbcError(f"port must be an integer in 1..65535, got {port!r}. Fix: pass e.g. --port 7000, or omit it.")
        self._log = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(
            [sys.executable, "-u", "-c", _SERVER_SCRIPT, "" if port is None else str(int(port))],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._log,
            start_new_session=True,
        )
        self._finalizer = weakref.finalize(self, _stop_process, self.proc, self.proc.stdin, self._log)
        lines: dict[str, str] = {}
        deadline = time.monotonic() + timeout
        while "web_url" not in lines:
            left = deadline - time.monotonic()
            ready = select.select([self.proc.stdout], [], [], max(0.0, left))[0] if left > 0 else []
            if not ready:
                self.close()
                raise IdapbcError(f"the meshcat server did not start within {timeout:g} s. Fix: check that meshcat is installed (pip install meshcat).")
            line = self.proc.stdout.readline().decode("utf-8", "replace").strip()
            if not line:  # EOF: the child exited
                self.proc.wait(timeout=10)
                err = self._stderr_tail()
                self.close()
                raise IdapbcError(f"the meshcat server exited at start (status {self.proc.returncode}): {err}. Fix: reinstall meshcat (pip install meshcat).")
            key, sep, value = line.partition("=")
            if sep and key == "error":
                self.close()
                if "in use" in value or "Errno 98" in value:
                    raise IdapbcError(f"port {port} is already in use ({value}). Fix: pass another --port, or omit it to pick a free one.")
                raise IdapbcError(f"the meshcat server could not listen on port {port}: {value}. Fix: pass another --port, or omit it.")
            if sep:
                lines[key] = value
        self.zmq_url = lines["zmq_url"]
        #: The viewer page, e.g. ``http://127.0.0.1:7000/static/``.
        self.url = lines["web_url"]
        self.port = int(self.url.rsplit(":", 1)[1].split("/", 1)[0])
        self.pid = self.proc.pid
        self._socket = zmq.Context.instance().socket(zmq.REQ)
        for opt, val in ((zmq.RCVTIMEO, int(timeout * 1000)), (zmq.SNDTIMEO, int(timeout * 1000)), (zmq.LINGER, 0)):
            self._socket.setsockopt(opt, val)
        self._socket.connect(self.zmq_url)

    def _stderr_tail(self) -> str:
        try:
            self._log.seek(0)
            text = self._log.read().decode("utf-8", "replace").strip()
        except (OSError, ValueError):
            return "no message"
        return text.splitlines()[-1] if text else "no message"

    @property
    def alive(self) -> bool:
        """True while the server process runs."""
        return self.proc.poll() is None

    def send(self, frames: Sequence[bytes]) -> None:
        """Send one meshcat command (type, path, msgpack data) and wait for the server's reply."""
        import zmq

        if not self.alive:
            raise IdapbcError("the meshcat server is not running. Fix: call serve() again.")
        try:
            self._socket.send_multipart(list(frames))
            reply = self._socket.recv()
        except zmq.error.Again:
            raise IdapbcError("the meshcat server did not answer. Fix: close the viewer and serve again.") from None
        if reply != b"ok":
            raise RuntimeError(f"meshcat server replied {reply!r}")

    def scene_html(self) -> str:
        """The server's own standalone HTML of its current scene (meshcat's ``static_html()``)."""
        import zmq

        try:
            self._socket.send(b"get_scene")
            return self._socket.recv().decode("utf-8")
        except zmq.error.Again:
            raise IdapbcError("the meshcat server did not answer. Fix: close the viewer and serve again.") from None

    def close(self) -> None:
        """Stop the server process (idempotent)."""
        sock = getattr(self, "_socket", None)
        if sock is not None:
            sock.close(linger=0)
            self._socket = None
        self._finalizer()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self) -> str:
        state = f"serving {self.url}" if self.alive else "closed"
        return f"MeshcatServer(pid={self.proc.pid}, {state})"


# ====================================================================== geometry helpers
def _rod_placement(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """4x4 placement of a meshcat cylinder (axis = local y) spanning points a -> b."""
    import pinocchio as pin

    d = b - a
    length = float(np.linalg.norm(d))
    T = np.eye(4)
    T[:3, 3] = 0.5 * (a + b)
    if length > 0:
        T[:3, :3] = pin.Quaternion.FromTwoVectors(np.array([0.0, 1.0, 0.0]), d / length).toRotationMatrix()
    return T


def _rot_y(theta: np.ndarray) -> np.ndarray:
    """(K,) -> (K, 4, 4) rotations about +y (z tilts towards +x for theta > 0)."""
    c, s = np.cos(theta), np.sin(theta)
    T = np.zeros(theta.shape + (4, 4))
    T[..., 0, 0], T[..., 0, 2], T[..., 1, 1], T[..., 2, 0], T[..., 2, 2], T[..., 3, 3] = c, s, 1.0, -s, c, 1.0
    return T


def _translation(p: np.ndarray) -> np.ndarray:
    """(K, 3) -> (K, 4, 4) translations."""
    p = np.atleast_2d(p)
    T = np.broadcast_to(np.eye(4), p.shape[:-1] + (4, 4)).copy()
    T[..., :3, 3] = p
    return T


def _material(color: int, opacity: float = 1.0):
    import meshcat.geometry as mg

    if opacity < 1.0:
        return mg.MeshLambertMaterial(color=color, transparent=True, opacity=opacity)
    return mg.MeshLambertMaterial(color=color)


# ====================================================================== drawings
class _Drawing:
    """How one copy of a robot is drawn: nodes, their world placements at q, and a traced point.

    Subclasses set `paths` (node paths relative to the robot's root), `scales` ((n_nodes, 3),
    applied once with the first placement; meshcat animates position and orientation only) and
    `moving` ((n_nodes,) bool), and implement `load`, `placements` and `trace`.
    """

    paths: list[str]
    scales: np.ndarray
    moving: np.ndarray

    def load(self, vis) -> None:
        """Create every node under the meshcat visualizer `vis` (the robot's root)."""
        raise NotImplementedError

    def placements(self, q: np.ndarray) -> np.ndarray:
        """World placements (K, n_nodes, 4, 4) of the nodes at minimal coordinates q (K, nq)."""
        raise NotImplementedError

    def trace(self, q: np.ndarray) -> np.ndarray:
        """World position (K, 3) of the traced point (far end of the end link) at q (K, nq)."""
        raise NotImplementedError


def _package_dirs(urdf: Path) -> list[str]:
    dirs = [str(urdf.parent), str(urdf.parent.parent)]
    try:
        from ..model.system import erd_robots_dir

        dirs.append(str(erd_robots_dir().parent.parent))
    except IdapbcError:
        pass
    return dirs


def _visual_model(model, urdf: Path):
    """Pinocchio's visual GeometryModel of `urdf`, meshes resolved through the package dirs."""
    import pinocchio as pin

    try:
        return pin.buildGeomFromUrdf(model, str(urdf), pin.GeometryType.VISUAL, package_dirs=_package_dirs(urdf))
    except (ValueError, RuntimeError) as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise IdapbcError(
            f"cannot load the visual geometry of '{urdf}': {msg}. Fix: put the meshes next to the URDF, or give "
            "package:// paths that resolve from the URDF's folder or example-robot-data's share directory."
        ) from None


def _trace_frame(model, trace_link: str | None) -> tuple[int, np.ndarray]:
    """-> (joint id, point in that joint's frame) of the traced point.

    A joint name, or the link it moves, traces that link's far end, joint origin + 2 c (c: centre of
    mass of the joint's body, the far end of a uniform rod); any other link (one fixed to a moving
    link) traces its own origin. Default: the last joint of the model.
    """
    import pinocchio as pin

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


class _PinocchioDrawing(_Drawing):
    """A URDF robot: its visual geometry, or a stick-and-ball rendering when it has none."""

    def __init__(self, plant, trace_link: str | None = None, style: str = "auto"):
        import pinocchio as pin

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
            self.moving = np.array([self._moves(g.parentJoint) for g in objs])
        else:
            self.style = "stick"
            self._build_sticks()
        self._pin = pin

    def _moves(self, joint: int) -> bool:
        return joint > 0

    # ------------------------------------------------------------------ stick and ball
    def _build_sticks(self) -> None:
        m = self.model
        children = {j: [c for c in range(1, m.njoints) if m.parents[c] == j] for j in range(m.njoints)}
        # (path, parent joint, local placement, kind, size, color)
        nodes = [("sticks/base", 0, np.eye(4), "box", (0.08, 0.08, 0.08), 0x555555)]
        for j in range(1, m.njoints):
            color = _PALETTE[(j - 1) % len(_PALETTE)]
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
        self._sticks = nodes
        self.paths = [n[0] for n in nodes]
        self.scales = np.ones((len(nodes), 3))
        self.moving = np.array([n[1] > 0 for n in nodes])

    # ------------------------------------------------------------------ interface
    def load(self, vis) -> None:
        import meshcat.geometry as mg

        if self.style == "visual":
            from pinocchio.visualize import MeshcatVisualizer

            viz = MeshcatVisualizer(self.model, None, self.visual_model)
            viz.viewer = vis
            viz.viewerVisualGroupName = "visuals"
            for g in self.visual_model.geometryObjects:
                viz.loadViewerGeometryObject(g, self._pin.GeometryType.VISUAL)
            return
        for path, _, _, kind, size, color in self._sticks:
            if kind == "ball":
                vis[path].set_object(mg.Sphere(size), _material(color))
            elif kind == "box":
                vis[path].set_object(mg.Box(size), _material(color))
            else:
                vis[path].set_object(mg.Cylinder(size, 0.02), _material(color))

    def _kinematics(self, qc: np.ndarray) -> None:
        self._pin.forwardKinematics(self.model, self.data, qc)

    def placements(self, q: np.ndarray) -> np.ndarray:
        pin = self._pin
        qs = self.config(np.atleast_2d(np.asarray(q, float)))
        out = np.empty((qs.shape[0], len(self.paths), 4, 4))
        for k, qc in enumerate(qs):
            self._kinematics(qc)
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
            self._kinematics(qc)
            out[k] = self.data.oMi[self.trace_joint].act(self.trace_point)
        return out


class _AnalyticDrawing(_Drawing):
    """The paper's analytic systems, drawn from their coordinates (no URDF)."""

    def __init__(self, system):
        from ..model.analytic import CosCoupledPlant

        plant = system.plant
        kinds = tuple(j.kind for j in system.joints)
        if isinstance(plant, CosCoupledPlant) and kinds == ("analytic-linear", "analytic-angle"):
            self.kind = "cartpole"
            self._nodes = [
                ("rail", "box", (6.0, 0.03, 0.03), 0x888888, False),
                ("cart", "box", (0.4, 0.25, 0.15), 0x3366CC, True),
                ("pole", "rod", 1.0, 0xF28C1A, True),
                ("bob", "ball", 0.07, 0xF28C1A, True),
            ]
        elif isinstance(plant, CosCoupledPlant) and kinds == ("analytic-angle", "analytic-angle"):
            self.kind = "double_pendulum"
            self._nodes = [
                ("base", "box", (0.12, 0.12, 0.12), 0x555555, False),
                ("link1", "rod", 1.0, 0x3366CC, True),
                ("elbow", "ball", 0.06, 0x222222, True),
                ("link2", "rod", 1.0, 0xF28C1A, True),
                ("tip", "ball", 0.07, 0xF28C1A, True),
            ]
        elif len(system.joints) == 1:
            self.kind = "block"
            self._nodes = [
                ("wall", "box", (0.05, 0.5, 0.5), 0x888888, False),
                ("target", "box", (0.005, 0.42, 0.42), 0x2CA02C, False),
                ("block", "box", (0.3, 0.3, 0.3), 0x3366CC, True),
            ]
            self.q_star = float(system.x_star[0])
        else:
            raise IdapbcError(f"no drawing for the analytic system '{system.name}'. Fix: give it a URDF to view it.")
        self.paths = [n[0] for n in self._nodes]
        self.scales = np.ones((len(self._nodes), 3))
        self.moving = np.array([n[4] for n in self._nodes])

    def load(self, vis) -> None:
        import meshcat.geometry as mg

        for path, kind, size, color, _ in self._nodes:
            if kind == "box":
                geom = mg.Box(size)
            elif kind == "ball":
                geom = mg.Sphere(size)
            else:
                geom = mg.Cylinder(size, 0.025)
            vis[path].set_object(geom, _material(color, 0.5 if path == "target" else 1.0))

    def _points(self, q: np.ndarray) -> dict[str, np.ndarray]:
        q = np.atleast_2d(np.asarray(q, float))
        zeros = np.zeros(q.shape[0])
        if self.kind == "cartpole":
            cart = np.stack([q[:, 0], zeros, zeros], axis=1)
            tip = cart + np.stack([np.sin(q[:, 1]), zeros, np.cos(q[:, 1])], axis=1)
            return {"cart": cart, "tip": tip}
        if self.kind == "double_pendulum":
            elbow = np.stack([np.sin(q[:, 0]), zeros, np.cos(q[:, 0])], axis=1)
            tip = elbow + np.stack([np.sin(q[:, 1]), zeros, np.cos(q[:, 1])], axis=1)
            return {"elbow": elbow, "tip": tip}
        return {"block": np.stack([q[:, 0], zeros, zeros + 0.15], axis=1)}

    def placements(self, q: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, float))
        K = q.shape[0]
        pts = self._points(q)
        # three.js cylinders run along local y; R_x(+90°) turns y into z (the rod, upright at angle 0)
        y_to_z = np.array([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])
        half_up = _translation(np.array([[0.0, 0.0, 0.5]]))[0]
        T: dict[str, np.ndarray] = {}
        if self.kind == "cartpole":
            T["rail"] = np.broadcast_to(np.eye(4), (K, 4, 4))
            T["cart"] = _translation(pts["cart"])
            T["pole"] = _translation(pts["cart"]) @ _rot_y(q[:, 1]) @ half_up @ y_to_z
            T["bob"] = _translation(pts["tip"])
        elif self.kind == "double_pendulum":
            T["base"] = np.broadcast_to(np.eye(4), (K, 4, 4))
            T["link1"] = _rot_y(q[:, 0]) @ half_up @ y_to_z
            T["elbow"] = _translation(pts["elbow"])
            T["link2"] = _translation(pts["elbow"]) @ _rot_y(q[:, 1]) @ half_up @ y_to_z
            T["tip"] = _translation(pts["tip"])
        else:
            T["wall"] = np.broadcast_to(_translation(np.array([[-1.0, 0.0, 0.25]]))[0], (K, 4, 4))
            T["target"] = np.broadcast_to(_translation(np.array([[self.q_star, 0.0, 0.21]]))[0], (K, 4, 4))
            T["block"] = _translation(pts["block"])
        return np.stack([T[p] for p in self.paths], axis=1)

    def trace(self, q: np.ndarray) -> np.ndarray:
        pts = self._points(q)
        return pts["tip"] if "tip" in pts else pts["block"]


def _drawing(system, trace_link: str | None = None, style: str = "auto") -> _Drawing:
    if style not in ("auto", "visual", "stick"):
        raise IdapbcError(f"style must be 'auto', 'visual' or 'stick', got '{style}'.")
    plant = getattr(system, "plant", None)
    if hasattr(plant, "model") and hasattr(plant, "path"):
        return _PinocchioDrawing(plant, trace_link, style)
    if trace_link is not None:
        raise IdapbcError(f"trace_link applies to URDF robots; '{system.name}' is drawn from its coordinates. Fix: drop trace_link.")
    return _AnalyticDrawing(system)


# ====================================================================== camera
@dataclass(frozen=True)
class Camera:
    """meshcat's default perspective camera, aimed at `target` from `position` (world, z up).

    meshcat's orbit controls look at the world origin, so the viewer shifts the whole scene by
    −target; in the robot's coordinates the camera is at `position` and looks at `target`.

    Attributes
    ----------
    target : (3,) point looked at, m.
    position : (3,) camera position, m.
    fov_deg : vertical field of view, degrees (meshcat's default camera: 75).
    """

    target: np.ndarray
    position: np.ndarray
    fov_deg: float = CAMERA_FOV_DEG

    def project(self, points, width: int, height: int) -> np.ndarray:
        """Pixel coordinates (K, 2) (x right, y down) of world points (K, 3) in a width×height view.

        Points behind the camera get nan.
        """
        p = np.atleast_2d(np.asarray(points, float))
        forward = self.target - self.position
        forward = forward / np.linalg.norm(forward)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right = right / np.linalg.norm(right)
        up = np.cross(right, forward)
        rel = p - self.position
        depth = rel @ forward
        f = 0.5 * height / math.tan(math.radians(self.fov_deg) / 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = 0.5 * width + f * (rel @ right) / depth
            y = 0.5 * height - f * (rel @ up) / depth
        out = np.stack([x, y], axis=1)
        out[depth <= 0] = np.nan
        return out


def _frame_camera(points: np.ndarray, aspect: float = 4 / 3, fill: float = 0.7) -> Camera:
    """A camera that sees every point (in a view at least `aspect` wide): across the plane of motion.

    Planar motion in x-z is seen from −y (slightly from the side and above), in y-z from +x, any other
    motion from an oblique direction. The distance is the smallest at which every point projects
    inside `fill` of the view, and at least 0.5 m.
    """
    lo, hi = points.min(axis=0), points.max(axis=0)
    target = 0.5 * (lo + hi)
    spread = hi - lo
    if spread[1] <= 0.1 * max(spread.max(), 1e-9):  # motion in the x-z plane: look from -y
        direction = np.array([0.25, -1.0, 0.3])
    elif spread[0] <= 0.1 * max(spread.max(), 1e-9):  # y-z plane: look from +x
        direction = np.array([1.0, 0.25, 0.3])
    else:
        direction = np.array([1.0, -1.0, 0.7])
    direction /= np.linalg.norm(direction)
    right = np.cross(-direction, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, -direction)
    tan_v = fill * math.tan(math.radians(CAMERA_FOV_DEG) / 2)
    rel = points - target
    along = rel @ direction
    need = np.maximum(np.abs(rel @ right) / (tan_v * aspect), np.abs(rel @ up) / tan_v) + along
    distance = max(0.5, float(need.max()) * 1.05)
    return Camera(target=target, position=target + distance * direction)


# ====================================================================== trajectories
@dataclass(frozen=True)
class Segment:
    """Where one rollout sits in the animation.

    Attributes
    ----------
    index : rollout number (order given).
    root : meshcat path of the robot copy that plays it, e.g. ``/meshcat/robots/0``.
    t0 : animation time of its first sample, s.
    offset : (3,) world translation of its copy (side by side), m.
    t : (K,) its trajectory times, s (animation time = t0 + t).
    q : (K, nq) its positions.
    """

    index: int
    root: str
    t0: float
    offset: np.ndarray
    t: np.ndarray
    q: np.ndarray


def _rollouts(trajectories, nq: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Trajectory / list of them / (t, q) pair -> [(t (K,), q (K, nq))]."""
    several = isinstance(trajectories, (list, tuple)) and len(trajectories) > 0 and hasattr(trajectories[0], "q")
    items = list(trajectories) if several else [trajectories]
    out = []
    for item in items:
        t, q = (item.t, item.q) if hasattr(item, "q") else item
        t = np.asarray(t, float).ravel()
        q = np.asarray(q, float)
        q = q[None] if q.ndim == 2 else q
        if q.ndim != 3 or q.shape[1:] != (t.size, nq):
            raise IdapbcError(f"trajectory positions must have shape (N, {t.size}, {nq}) for {t.size} times, got {q.shape}. Fix: pass simulate()'s Trajectory.")
        if t.size == 0 or np.any(np.diff(t) <= 0) or not np.all(np.isfinite(t)):
            raise IdapbcError("trajectory times must be finite and strictly increasing. Fix: pass simulate()'s Trajectory.")
        out.extend((t - t[0], qi) for qi in q)
    return out


def _keyframe_indices(t: np.ndarray, fps: float) -> np.ndarray:
    """Samples at most 1/fps apart where the sampling allows, as few as that takes (first and last kept)."""
    keep = [0]
    for k in range(1, t.size - 1):
        if t[k + 1] - t[keep[-1]] > 1.0 / fps + 1e-12:
            keep.append(k)
    if t.size > 1:
        keep.append(t.size - 1)
    return np.array(keep, dtype=int)


def _quaternions(T: np.ndarray) -> np.ndarray:
    """(K, 4, 4) -> (K, 4) unit quaternions (x, y, z, w), sign-continuous along K."""
    import pinocchio as pin

    q = np.array([np.asarray(pin.Quaternion(R).coeffs()) for R in T[:, :3, :3]])
    for k in range(1, q.shape[0]):
        if q[k] @ q[k - 1] < 0:
            q[k] = -q[k]
    return q


# ====================================================================== viewer
_SEEK_SCRIPT = """<script>
// idapbc-pin: replay.html#t=2.5 holds the animation at 2.5 s
(function () {
    var m = /[#&]t=([0-9.eE+-]+)/.exec(window.location.hash);
    if (!m) return;
    var t = parseFloat(m[1]);
    function seek() {
        var a = viewer.animator;
        if (!a || a.actions.length === 0) { setTimeout(seek, 20); return; }
        a.mixer.timeScale = 0; a.seek(t);  // held at t; set timeScale back to 1 to play on
    }
    seek();
})();
</script>
"""


class Viewer:
    """An animated meshcat scene of a system along trajectories; serve it live or write it as HTML.

    Build it with `view` (or ``Viewer(system, trajectories)``). Attributes: `system`, `segments`
    (one `Segment` per rollout), `camera`, `animation` (the ``meshcat.animation.Animation``, clips
    keyed by node path), `keyframes` ({node path: (times (K,), placements (K, 4, 4))}), `vis` (the
    ``meshcat.Visualizer`` recording the scene), `traces` (one (K, 3) path of the end link's
    far end per rollout at every trajectory sample, world frame; drawn when ``trace=True``), `duration` (s), `server` (a `MeshcatServer` or None), `url`.
    """

    def __init__(
        self,
        system,
        trajectories,
        *,
        layout: str = "sequence",
        trace: bool = True,
        trace_link: str | None = None,
        fps: float = DEFAULT_FPS,
        loop: bool = True,
        style: str = "auto",
        grid: bool = True,
    ):
        meshcat = _import_meshcat()

        if layout not in ("sequence", "side_by_side"):
            raise IdapbcError(f"layout must be 'sequence' or 'side_by_side', got '{layout}'.")
        if not fps > 0:
            raise IdapbcError(f"fps must be positive, got {fps!r}.")
        self.system = system
        self.layout = layout
        self.note = ""  # which rollouts these are (set by `view`)
        self.server: MeshcatServer | None = None
        self._drawing = _drawing(system, trace_link, style)
        rollouts = _rollouts(trajectories, int(system.nq))
        self._recorder = _SceneRecorder()
        self.vis = meshcat.Visualizer(window=self._recorder)
        self._build(rollouts, trace, fps, loop)
        if not grid:
            self.vis["/Grid"].set_property("visible", False)
            self.vis["/Axes"].set_property("visible", False)

    # ------------------------------------------------------------------ scene
    def _build(self, rollouts, trace: bool, fps: float, loop: bool) -> None:
        import meshcat.geometry as mg
        from meshcat.animation import Animation, AnimationClip, AnimationTrack

        d = self._drawing
        keyed = []  # (t_keys, placements (K, nn, 4, 4), trace points (K_all, 3))
        for t, q in rollouts:
            idx = _keyframe_indices(t, fps)
            keyed.append((t[idx], d.placements(q[idx]), d.trace(q)))

        # layout: where each rollout plays, in time and space
        segments, t0 = [], 0.0
        if self.layout == "side_by_side":
            # copies side by side along x (along y for motion in the y-z plane), apart by the
            # extent of the motion along that axis plus 0.6 m
            pts = np.concatenate([P[:, d.moving, :3, 3].reshape(-1, 3) for _, P, _ in keyed] + [tr for _, _, tr in keyed])
            extent = np.ptp(pts, axis=0)
            along = 1 if extent[0] < 0.1 * max(extent.max(), 1e-9) else 0
            axis = np.eye(3)[along]
            spacing = float(extent[along]) + 0.6
        for i, ((tk, P, tr), (t, q)) in enumerate(zip(keyed, rollouts)):
            if self.layout == "sequence":
                segments.append(Segment(i, "/meshcat/robots/0", t0, np.zeros(3), t, q))
                t0 += float(t[-1]) + SEQUENCE_GAP
            else:
                offset = (i - 0.5 * (len(rollouts) - 1)) * spacing * axis
                segments.append(Segment(i, f"/meshcat/robots/{i}", 0.0, offset, t, q))
        self.segments = segments

        roots = sorted({s.root for s in segments})
        for root in roots:
            d.load(self.vis[root])

        # keyframes per node, in animation time
        self.keyframes: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for root in roots:
            segs = [(s, keyed[s.index]) for s in segments if s.root == root]
            for n, rel in enumerate(d.paths):
                times, mats = [], []
                for j, (s, (tk, P, _)) in enumerate(segs):
                    M = _translation(s.offset[None])[0] @ P[:, n]
                    times.append(s.t0 + tk)
                    mats.append(M)
                    if j + 1 < len(segs):  # hold the last pose, then jump to the next rollout
                        times.append(np.array([segs[j + 1][0].t0 - 1e-3]))
                        mats.append(M[-1:])
                times_all, mats_all = np.concatenate(times), np.concatenate(mats)
                path = f"{root}/{rel}"
                self.keyframes[path] = (times_all, mats_all)
                first = mats_all[0].copy()
                first[:3, :3] = first[:3, :3] @ np.diag(d.scales[n])
                self.vis[path].set_transform(first)

        # the animation: one clip per moving node (fps = 1: frame numbers are seconds); nodes fixed
        # to the world keep the placement set above
        animation = Animation(default_framerate=1)
        for path, (times, mats) in self.keyframes.items():
            if not d.moving[d.paths.index(path.split("/", 4)[-1])]:
                continue
            frames = [float(x) for x in times]
            pos = mats[:, :3, 3].tolist()
            quat = _quaternions(mats).tolist()
            tracks = {
                "position": AnimationTrack("position", "vector3", frames, pos),
                "quaternion": AnimationTrack("quaternion", "quaternion", list(frames), quat),
            }
            animation.clips[self.vis[path].path] = AnimationClip(tracks=tracks, fps=1)

        # traces of the end link (sequence: each shown while its rollout plays)
        self.traces = [tr + s.offset for s, (_, _, tr) in zip(segments, keyed)]
        if trace:
            for s, (_, _, tr) in zip(segments, keyed):
                color = _PALETTE[s.index % len(_PALETTE)]
                pts = (tr + s.offset).T.astype(np.float32)
                node = self.vis[f"/meshcat/traces/{s.index}"]
                node.set_object(mg.Line(mg.PointsGeometry(pts), mg.LineBasicMaterial(color=color, linewidth=2)))
                if self.layout == "sequence" and len(segments) > 1:
                    visible = AnimationClip(fps=1)
                    frames = [0.0, s.t0]
                    values = [s.index == 0, True]
                    if s.index + 1 < len(segments):
                        frames.append(segments[s.index + 1].t0 - 1e-3)
                        values.append(False)
                    visible.tracks["visible"] = AnimationTrack("visible", "boolean", frames, values)
                    animation.clips[node.path] = visible
                    node.set_property("visible", s.index == 0)
        # every clip spans the whole animation, or it would loop on its own shorter period
        self.duration = max([float(times[-1]) for times, _ in self.keyframes.values()] + [0.0])
        for clip in animation.clips.values():
            for track in clip.tracks.values():
                if track.frames and track.frames[-1] < self.duration:
                    track.frames.append(self.duration)
                    track.values.append(track.values[-1])
        self.animation = animation

        # camera: sees every node origin and the far end of the end link, all the time
        self.camera = _frame_camera(np.concatenate([m[:, :3, 3] for _, m in self.keyframes.values()] + self.traces))
        # meshcat's orbit controls always look at the world origin: shift the world (robots, traces,
        # grid, axes) by −target instead of moving the camera's target
        shift = _translation(-self.camera.target[None])[0]
        for node in ("/meshcat", "/Grid", "/Axes"):
            self.vis[node].set_transform(shift)
        rel = self.camera.position - self.camera.target
        # the camera's parent is rotated +90° about x: world (x, y, z) = local (x, −z, y)
        self.vis["/Cameras/default/rotated/<object>"].set_property("position", [float(rel[0]), float(rel[2]), float(-rel[1])])
        self.vis.set_animation(animation, play=True, repetitions=math.inf if loop else 1)

    # ------------------------------------------------------------------ outputs
    def static_html(self) -> str:
        """meshcat's standalone page of the scene (``Visualizer.static_html()``; replays offline)."""
        return self.vis.static_html()

    def replay_html(self) -> str:
        """The replay file: `static_html` plus a short script that reads a time from the URL.

        ``replay.html#t=2.5`` opens the animation held at 2.5 s (time scale 0; set it back to 1 in
        the player's controls to play on); with no ``#t=`` it plays from the start, as meshcat's
        page does.
        """
        html = self.static_html()
        end = html.rfind("</body>")
        if end < 0:  # pragma: no cover - meshcat's template always has one
            raise RuntimeError("meshcat's static HTML has no </body>")
        return html[:end] + _SEEK_SCRIPT + html[end:]

    def write_html(self, path) -> Path:
        """Write `replay_html` to `path` atomically (temp file + rename); returns the path."""
        from .._io import atomic_write_bytes

        return atomic_write_bytes(path, self.replay_html().encode("utf-8"))

    def serve(self, port: int | None = None) -> str:
        """Start meshcat's server on 127.0.0.1 (see `MeshcatServer`), send it the scene; returns the URL."""
        if self.server is not None and self.server.alive:
            return self.server.url
        server = MeshcatServer(port)
        try:
            for frames in self._recorder.messages:
                server.send(frames)
        except BaseException:
            server.close()
            raise
        self.server = server
        self._recorder.web_url = server.url
        return server.url

    @property
    def url(self) -> str | None:
        """The live viewer's URL, or None when not serving."""
        return self.server.url if self.server is not None and self.server.alive else None

    def wait(self, poll: float = 0.5) -> None:
        """Block while the server runs (the CLI; returns on Ctrl-C or when the server ends)."""
        try:
            while self.server is not None and self.server.alive:
                time.sleep(poll)
        except KeyboardInterrupt:
            pass

    def close(self) -> None:
        """Stop the live server, if any (idempotent)."""
        if self.server is not None:
            self.server.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _repr_html_(self) -> str:
        """Notebook display: the live page if serving, else the standalone replay inline."""
        if self.url:
            src = f'src="{self.url}"'
        else:
            from html import escape

            src = f'srcdoc="{escape(self.static_html(), quote=True)}"'
        return f'<div style="height: 420px; width: 100%; resize: both; overflow: hidden"><iframe {src} style="width: 100%; height: 100%; border: none"></iframe></div>'

    def __repr__(self) -> str:
        where = f"serving {self.url}" if self.url else "not serving"
        return f"Viewer({getattr(self.system, 'name', '?')}, {len(self.segments)} rollouts, {self.duration:.1f} s, {self.layout}, {where})"


# ====================================================================== entry points
def _resolve(run_or_system):
    """-> (system, controller or None, run directory or None)."""
    if isinstance(run_or_system, (str, Path)):
        p = Path(run_or_system)
        if p.is_dir() and (p / "config.json").is_file():
            from ..training.run import load_run

            run_or_system = load_run(p)
        else:
            from ..model.system import load_system

            run_or_system = load_system(str(run_or_system))
    if hasattr(run_or_system, "controller") and hasattr(run_or_system, "system"):
        return run_or_system.system, run_or_system.controller, getattr(run_or_system, "path", None)
    if hasattr(run_or_system, "nq") and hasattr(run_or_system, "plant"):
        return run_or_system, None, None
    raise IdapbcError(f"cannot view {type(run_or_system).__name__}. Fix: pass a Run, a System, a run directory or a system source.")


def _simulate(system, controller, x0, T: float, dt: float):
    from ..sim.simulate import LQRController, simulate

    if controller is None:
        controller = LQRController(system)
    if not (T > 0 and math.isfinite(T)):
        raise IdapbcError(f"T must be a positive number of seconds, got {T!r}.")
    steps = max(1, int(round(T / dt)))
    return simulate(system, controller, x0, T=steps * dt, dt=dt)


#: With ``pick="success"``, candidates drawn per requested rollout.
PICK_CANDIDATES = 20


def _pick_successes(system, controller, n: int, T: float, dt: float, seed: int):
    """Up to `n` rollouts that reach x* (DESIGN §4 criterion over the last 2 s of `T`) among
    ``PICK_CANDIDATES · n`` uniform states of the half box, in draw order, filled up with failing
    ones when fewer succeed. Returns (Trajectory of n rows, number reaching x*, candidates)."""
    from ..sim.simulate import Trajectory, success

    candidates = initial_states(system, None, PICK_CANDIDATES * n, seed)
    traj = _simulate(system, controller, candidates, T, dt)
    ok = success(traj, system)
    order = np.concatenate([np.flatnonzero(ok), np.flatnonzero(~ok)])[:n]
    x = traj.x[order]
    nq = system.nq
    picked = Trajectory(t=traj.t, x=x, q=x[..., :nq], v=traj.v[order], u=traj.u[order], diverged=traj.diverged[order])
    return picked, int(ok[order].sum()), len(candidates)


def view(
    run_or_system,
    trajectories=None,
    *,
    x0=None,
    n: int = 3,
    pick: str = "random",
    T: float = 10.0,
    dt: float = 0.01,
    seed: int = 0,
    html=None,
    open_server: bool = True,
    port: int | None = None,
    layout: str = "sequence",
    trace: bool = True,
    trace_link: str | None = None,
    fps: float = DEFAULT_FPS,
    loop: bool = True,
    style: str = "auto",
    grid: bool = True,
) -> Viewer:
    """Animate a system along closed-loop trajectories in meshcat; never blocks.

    Parameters
    ----------
    run_or_system : a trained `Run`, a `System`, a run directory or a system source (URDF path,
        zoo or built-in name, ``erd:<stem>``).
    trajectories : a `Trajectory` from `idapbc_pin.sim.simulate` (all its rollouts), a list of them,
        or a pair (t (K,), q (K, nq) or (N, K, nq)). None: simulate `n` rollouts of `T` s (step `dt`)
        from states drawn uniformly from the half-size training box (seed `seed`), or from `x0`,
        with the run's controller, or the LQR baseline when given a `System`.
    x0 : (N, n) initial states (q, p) or (N, nq) positions at rest; overrides `n` and `pick`.
    pick : ``"random"`` (the first `n` uniform half-box states) or ``"success"``: up to `n` rollouts
        that reach x* within `T` (DESIGN §4 criterion), chosen among ``PICK_CANDIDATES · n`` uniform
        half-box states and filled up with failing ones; prints how many reach x*. A picture of what
        the controller does where it works, not of how often it works (that is the ROA).
    html : write the standalone HTML replay there (atomically).
    open_server : start the live server (127.0.0.1) and print its URL; `Viewer.close` stops it.
    port : HTTP port of the live page; None picks the first free one from 7000; in use: error.
    layout : ``"sequence"`` (rollouts one after another, one robot) or ``"side_by_side"``.
    trace, trace_link : draw the path of the far end of `trace_link` (a joint or link name; default
        the last joint's link; analytic systems trace their tip).
    fps : at least this many keyframes per second of trajectory (at trajectory samples).
    loop : replay forever (else once).
    style : ``"auto"`` (URDF visuals, stick-and-ball if none), ``"visual"`` or ``"stick"``.
    grid : show meshcat's ground grid and world axes.

    Returns
    -------
    Viewer (``.url``, ``.write_html(path)``, ``.close()``; shows inline in a notebook).
    """
    system, controller, _ = _resolve(run_or_system)
    if pick not in ("random", "success"):
        raise IdapbcError(f"pick must be 'random' or 'success', got {pick!r}.")
    if trajectories is not None:
        note = "given trajectories"
    elif x0 is None and pick == "success":
        if n < 1:
            raise IdapbcError(f"n must be at least 1, got {n}.")
        trajectories, reached, drawn = _pick_successes(system, controller, n, T, dt, seed)
        note = f"{reached} of {n} rollouts reach x* (picked among {drawn} random half-box states)"
    else:
        start = initial_states(system, x0, n, seed)
        trajectories = _simulate(system, controller, start, T, dt)
        note = f"{len(start)} rollouts from " + ("random half-box states" if x0 is None else "the given states")
    viewer = Viewer(system, trajectories, layout=layout, trace=trace, trace_link=trace_link, fps=fps, loop=loop, style=style, grid=grid)
    viewer.note = note
    if html is not None:
        viewer.write_html(html)
    if open_server:
        url = viewer.serve(port)
        print(f"meshcat viewer: {url}  ({note})")
    return viewer


def write_html(path, run_or_system, trajectories=None, **kwargs) -> Path:
    """Write the standalone HTML replay of `view(run_or_system, trajectories, **kwargs)` to `path`.

    No server is started; the file is written atomically and replays offline. Returns the path.
    """
    kwargs.pop("open_server", None)
    return view(run_or_system, trajectories, open_server=False, **kwargs).write_html(path)


# ====================================================================== CLI
def add_view_command(subparsers) -> argparse.ArgumentParser:
    """Register ``idapbc-pin view RUN_OR_SOURCE ...`` on an argparse sub-parsers object."""
    from ..cli._args import key_range as _key_range, key_value as _key_value

    p = subparsers.add_parser(
        "view",
        help="meshcat animation of closed-loop rollouts: live in the browser, or a standalone HTML file",
        description=(
            "Animate closed-loop rollouts in meshcat. RUN_OR_SOURCE is a run directory (its controller) or a system "
            "source (the LQR baseline). Serves http://127.0.0.1:PORT/static/ until Ctrl-C; with --html FILE it writes "
            "the standalone replay and exits (add --serve or --port to serve as well)."
        ),
    )
    p.add_argument("source", metavar="RUN_OR_SOURCE", help="run directory, or URDF path, zoo name, built-in name (paper_*) or erd:<stem>")
    p.add_argument("--actuated", nargs="+", action="extend", metavar="JOINT", help="actuated joint(s) of a SOURCE; default: the zoo entry's")
    p.add_argument("--target", type=_key_value, action="append", metavar="JOINT=VALUE", help="target joint value of a SOURCE (rad or m), repeatable")
    p.add_argument("--domain", type=_key_range, action="append", metavar="NAME=LO:HI", help="training-box bounds of a SOURCE, repeatable")
    p.add_argument("--x0", type=float, nargs="+", action="append", metavar="V",
                   help="initial state: n values (q then momenta p) or nq positions at rest; repeat for several rollouts")
    p.add_argument("--n", type=int, default=3, metavar="K", help="rollouts from random states of the half-size training box (default 3)")
    p.add_argument("--T", type=float, default=10.0, metavar="SECONDS", help="duration of each rollout (default 10)")
    p.add_argument("--pick", choices=["random", "success"], default="random",
                   help=f"random: the first K random half-box states (default); success: up to K rollouts that reach x*, "
                        f"chosen among {PICK_CANDIDATES}·K random states")
    p.add_argument("--seed", type=int, default=0, help="seed of the random initial states (default 0)")
    p.add_argument("--html", metavar="FILE", help="write the standalone HTML replay (offline, one file)")
    p.add_argument("--port", type=int, metavar="P", help="HTTP port of the live page (default: first free from 7000)")
    p.add_argument("--serve", action="store_true", help="serve live even when --html is given")
    p.add_argument("--layout", choices=["sequence", "side_by_side"], default="sequence", help="rollouts one after another (default) or side by side")
    p.add_argument("--trace-link", metavar="NAME", help="joint or link whose far end is traced (default: the last link)")
    p.add_argument("--no-trace", action="store_true", help="do not draw the end-link trace")
    p.set_defaults(func=_cmd_view)
    return p


def _cmd_view(args: argparse.Namespace) -> int:
    import signal

    from ..cli._args import system_kwargs

    source = Path(args.source)
    if source.is_dir() and (source / "config.json").is_file():
        target = str(source)
    else:
        from ..model.system import load_system

        target = load_system(args.source, **system_kwargs(args))
    serve = args.html is None or args.serve or args.port is not None
    x0 = args.x0
    if x0 is not None and len({len(v) for v in x0}) != 1:
        raise IdapbcError("every --x0 needs the same number of values. Fix: give n (q, p) or nq (q) values each time.")
    viewer = view(
        target, x0=x0, n=args.n, pick=args.pick, T=args.T, seed=args.seed, html=args.html, open_server=False,
        layout=args.layout, trace=not args.no_trace, trace_link=args.trace_link,
    )
    if args.html:
        print(f"wrote {args.html} ({len(viewer.segments)} rollouts, {viewer.duration:.1f} s; {viewer.note})")
    if not serve:
        return 0

    def _terminate(signum, frame):  # SIGTERM: leave through the same path as Ctrl-C
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        url = viewer.serve(args.port)
        print(f"meshcat viewer: {url}  ({viewer.note}; Ctrl-C to stop)", flush=True)
        viewer.wait()
    finally:
        viewer.close()
        signal.signal(signal.SIGTERM, previous)
    print("viewer closed")
    return 0

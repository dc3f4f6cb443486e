"""See it move: meshcat animations of closed-loop trajectories, live in a browser or as one HTML file.

    viewer = ip.view(run)                         # 3 rollouts from the half domain, live server
    viewer.write_html("replay.html")              # one self-contained file, replays offline
    viewer.close()                                # stops the server process

One concept per module, as Pinocchio's ``visualize/``: a drawing back-end per kind of system over a
common base, which only turns geometry into scene nodes; the server, the recording and the
simulation live elsewhere.

* `replay`: `view` and `write_html` (simulate rollouts, pick successes, build a `Viewer`).
* `viewer`: `Viewer`, the animated scene: keyframes, clips, traces, camera; HTML and live server.
* `drawing`: which drawing a system gets; `drawing_base` the interface; `drawing_pinocchio` URDF
  robots (visual geometry, or sticks and balls); `drawing_analytic` the paper's analytic systems.
* `animation`: rollouts laid out in time or space, keyframes, meshcat clips, the ``#t=`` seek script.
* `camera`: `Camera` and framing the motion.
* `recorder`: the scene recorded in memory through meshcat's own server logic (no process).
* `server`: `MeshcatServer`, meshcat's server in a child process bound to 127.0.0.1 that exits
  with its owner (`close`, garbage collection, or this process ending in any way).
"""

from .animation import DEFAULT_FPS, Segment
from .camera import Camera
from .replay import PICK_CANDIDATES, PICKS, view, write_html
from .server import SERVER_MARKER, MeshcatServer
from .viewer import Viewer

__all__ = [
    "DEFAULT_FPS",
    "PICK_CANDIDATES",
    "PICKS",
    "SERVER_MARKER",
    "Camera",
    "MeshcatServer",
    "Segment",
    "Viewer",
    "view",
    "write_html",
]

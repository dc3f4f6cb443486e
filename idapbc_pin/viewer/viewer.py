"""`Viewer`: an animated meshcat scene of a system along trajectories, served live or written as HTML.

The scene is recorded in memory (`SceneRecorder`), so `Viewer.write_html` needs no server process;
`Viewer.serve` starts a `MeshcatServer` and replays the recorded commands into it. The camera frames
the whole motion; meshcat's orbit controls always look at the world origin, so the world (robots,
traces, grid, axes) is shifted by −target instead of moving the camera's target.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from .._io import atomic_write_bytes
from ..errors import IdapbcError
from ._meshcat import import_meshcat
from ._transforms import PALETTE, translation
from .animation import (
    DEFAULT_FPS,
    LAYOUTS,
    SEEK_SCRIPT,
    keyframe_indices,
    layout_segments,
    node_keyframes,
    pose_clip,
    rollouts,
    span_clips,
    visibility_clip,
)
from .camera import frame_camera
from .drawing import drawing_for
from .recorder import SceneRecorder
from .server import MeshcatServer

__all__ = ["Viewer"]


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
        meshcat = import_meshcat()

        if layout not in LAYOUTS:
            raise IdapbcError(f"layout must be 'sequence' or 'side_by_side', got '{layout}'.")
        if not fps > 0:
            raise IdapbcError(f"fps must be positive, got {fps!r}.")
        self.system = system
        self.layout = layout
        self.note = ""  # which rollouts these are (set by `view`)
        self.server: MeshcatServer | None = None
        self._drawing = drawing_for(system, trace_link, style)
        motions = rollouts(trajectories, int(system.nq))
        self._recorder = SceneRecorder()
        self.vis = meshcat.Visualizer(window=self._recorder)
        self._build(motions, trace, fps, loop)
        if not grid:
            self.vis["/Grid"].set_property("visible", False)
            self.vis["/Axes"].set_property("visible", False)

    # ------------------------------------------------------------------ scene
    def _build(self, motions, trace: bool, fps: float, loop: bool) -> None:
        """Robots, their keyframes and clips, the traces and the camera, for rollouts [(t, q)]."""
        from meshcat.animation import Animation

        d = self._drawing
        keyed, traces = [], []  # per rollout: (t_keys, placements (K, nn, 4, 4)); trace points (K_all, 3)
        for t, q in motions:
            idx = keyframe_indices(t, fps)
            keyed.append((t[idx], d.placements(q[idx])))
            traces.append(d.trace(q))
        moving_points = [P[:, d.moving, :3, 3].reshape(-1, 3) for _, P in keyed] if self.layout == "side_by_side" else []
        self.segments = layout_segments(motions, self.layout, moving_points + traces)
        for root in sorted({s.root for s in self.segments}):
            d.load(self.vis[root])

        self.keyframes = node_keyframes(self.segments, keyed, d.paths)
        for path, (_, mats) in self.keyframes.items():
            first = mats[0].copy()
            first[:3, :3] = first[:3, :3] @ np.diag(d.scales[d.paths.index(path.split("/", 4)[-1])])
            self.vis[path].set_transform(first)

        # one clip per moving node; nodes fixed to the world keep the placement set above
        animation = Animation(default_framerate=1)
        for path, (times, mats) in self.keyframes.items():
            if d.moving[d.paths.index(path.split("/", 4)[-1])]:
                animation.clips[self.vis[path].path] = pose_clip(times, mats)
        self.traces = [tr + s.offset for s, tr in zip(self.segments, traces)]
        if trace:
            self._draw_traces(animation)
        self.duration = max([float(times[-1]) for times, _ in self.keyframes.values()] + [0.0])
        span_clips(animation, self.duration)
        self.animation = animation
        self._aim_camera()
        self.vis.set_animation(animation, play=True, repetitions=math.inf if loop else 1)

    def _draw_traces(self, animation) -> None:
        """A line per rollout along `traces`; in a sequence each shows while its rollout plays."""
        import meshcat.geometry as mg

        for s, tr in zip(self.segments, self.traces):
            color = PALETTE[s.index % len(PALETTE)]
            node = self.vis[f"/meshcat/traces/{s.index}"]
            node.set_object(mg.Line(mg.PointsGeometry(tr.T.astype(np.float32)), mg.LineBasicMaterial(color=color, linewidth=2)))
            if self.layout == "sequence" and len(self.segments) > 1:
                animation.clips[node.path] = visibility_clip(s, self.segments)
                node.set_property("visible", s.index == 0)

    def _aim_camera(self) -> None:
        """Frame every node origin and the traced point, all the time (sets `camera`)."""
        self.camera = frame_camera(np.concatenate([m[:, :3, 3] for _, m in self.keyframes.values()] + self.traces))
        shift = translation(-self.camera.target[None])[0]
        for node in ("/meshcat", "/Grid", "/Axes"):
            self.vis[node].set_transform(shift)
        rel = self.camera.position - self.camera.target
        # the camera's parent is rotated +90° about x: world (x, y, z) = local (x, −z, y)
        self.vis["/Cameras/default/rotated/<object>"].set_property("position", [float(rel[0]), float(rel[2]), float(-rel[1])])

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
        return html[:end] + SEEK_SCRIPT + html[end:]

    def write_html(self, path) -> Path:
        """Write `replay_html` to `path` atomically (temp file + rename); returns the path."""
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
        """Block while the live server runs: what keeps the page up at the end of a script (and in
        the CLI). Returns on Ctrl-C, when the server ends, or at once when not serving; the server
        stays up until `close` or the end of this process."""
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

"""The animation: rollouts laid out in time or space, keyframes per scene node, meshcat clips.

Keyframes sit at trajectory samples (at least `fps` per second where the sampling allows, always
the first and last sample) and hold each node's world placement as position + quaternion. The
meshcat clips use ``fps = 1``, so a keyframe's "frame" number *is* its time in seconds. Several
rollouts play one after another (``layout="sequence"``, `SEQUENCE_GAP` between them, one robot) or
at the same time, side by side (``layout="side_by_side"``, one robot copy each). Every clip spans
the whole animation, or it would loop on its own shorter period.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import IdapbcError
from ._transforms import quaternions, translation

__all__ = [
    "DEFAULT_FPS",
    "LAYOUTS",
    "SEEK_SCRIPT",
    "SEQUENCE_GAP",
    "Segment",
    "keyframe_indices",
    "layout_segments",
    "node_keyframes",
    "pose_clip",
    "rollouts",
    "span_clips",
    "visibility_clip",
]

#: Keyframes per second of trajectory time (three.js interpolates between them).
DEFAULT_FPS = 30.0
#: Pause between rollouts in the "sequence" layout, s.
SEQUENCE_GAP = 0.5
#: Where rollouts play: one after another on one robot, or at once on copies side by side.
LAYOUTS = ("sequence", "side_by_side")

#: Appended to meshcat's standalone page: ``replay.html#t=2.5`` holds the animation at 2.5 s.
SEEK_SCRIPT = """<script>
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


def rollouts(trajectories, nq: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Trajectory / list of them / (t, q) pair -> [(t (K,) from 0, q (K, nq))], one per rollout."""
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


def keyframe_indices(t: np.ndarray, fps: float) -> np.ndarray:
    """Samples of t (K,) at most 1/fps apart where the sampling allows, as few as that takes (first
    and last kept)."""
    keep = [0]
    for k in range(1, t.size - 1):
        if t[k + 1] - t[keep[-1]] > 1.0 / fps + 1e-12:
            keep.append(k)
    if t.size > 1:
        keep.append(t.size - 1)
    return np.array(keep, dtype=int)


def layout_segments(rollouts: list[tuple[np.ndarray, np.ndarray]], layout: str, points: list[np.ndarray]) -> list[Segment]:
    """One `Segment` per rollout (t, q). "sequence": one robot, rollouts `SEQUENCE_GAP` apart in time;
    "side_by_side": copies along x (along y for motion in the y-z plane), apart by the extent of
    `points` ((K_i, 3) world points of the motion, m) along that axis plus 0.6 m, centred."""
    segments, t0 = [], 0.0
    if layout == "side_by_side":
        extent = np.ptp(np.concatenate(points), axis=0)
        along = 1 if extent[0] < 0.1 * max(extent.max(), 1e-9) else 0
        axis = np.eye(3)[along]
        spacing = float(extent[along]) + 0.6
    for i, (t, q) in enumerate(rollouts):
        if layout == "sequence":
            segments.append(Segment(i, "/meshcat/robots/0", t0, np.zeros(3), t, q))
            t0 += float(t[-1]) + SEQUENCE_GAP
        else:
            offset = (i - 0.5 * (len(rollouts) - 1)) * spacing * axis
            segments.append(Segment(i, f"/meshcat/robots/{i}", 0.0, offset, t, q))
    return segments


def node_keyframes(segments: list[Segment], keyed: list[tuple[np.ndarray, np.ndarray]], paths: list[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{``<root>/<node path>``: (animation times (K,), world placements (K, 4, 4))} for every robot
    copy and node. `keyed[i]`: rollout i's keyframe times (K_i,) and node placements (K_i, n_nodes, 4, 4).
    In a sequence each rollout's last pose is held until just before the next one starts."""
    keyframes: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for root in sorted({s.root for s in segments}):
        segs = [(s, keyed[s.index]) for s in segments if s.root == root]
        for n, rel in enumerate(paths):
            times, mats = [], []
            for j, (s, (tk, P)) in enumerate(segs):
                M = translation(s.offset[None])[0] @ P[:, n]
                times.append(s.t0 + tk)
                mats.append(M)
                if j + 1 < len(segs):  # hold the last pose, then jump to the next rollout
                    times.append(np.array([segs[j + 1][0].t0 - 1e-3]))
                    mats.append(M[-1:])
            keyframes[f"{root}/{rel}"] = (np.concatenate(times), np.concatenate(mats))
    return keyframes


def pose_clip(times: np.ndarray, mats: np.ndarray):
    """meshcat clip (fps = 1) of a node's position and quaternion at times (K,), s, from placements (K, 4, 4)."""
    from meshcat.animation import AnimationClip, AnimationTrack

    frames = [float(x) for x in times]
    tracks = {
        "position": AnimationTrack("position", "vector3", frames, mats[:, :3, 3].tolist()),
        "quaternion": AnimationTrack("quaternion", "quaternion", list(frames), quaternions(mats).tolist()),
    }
    return AnimationClip(tracks=tracks, fps=1)


def visibility_clip(segment: Segment, segments: list[Segment]):
    """meshcat clip (fps = 1) showing `segment`'s trace while its rollout plays in a sequence (the
    first one is also shown before the animation starts)."""
    from meshcat.animation import AnimationClip, AnimationTrack

    visible = AnimationClip(fps=1)
    frames = [0.0, segment.t0]
    values = [segment.index == 0, True]
    if segment.index + 1 < len(segments):
        frames.append(segments[segment.index + 1].t0 - 1e-3)
        values.append(False)
    visible.tracks["visible"] = AnimationTrack("visible", "boolean", frames, values)
    return visible


def span_clips(animation, duration: float) -> None:
    """Extend every track of `animation` to `duration` (s), holding its last value, so that all clips
    share one period when looping."""
    for clip in animation.clips.values():
        for track in clip.tracks.values():
            if track.frames and track.frames[-1] < duration:
                track.frames.append(duration)
                track.values.append(track.values[-1])

"""See it move: the meshcat animation replays the simulated motion, and a real browser shows it.

* The animation's keyframes are the trajectory: every keyframe placement equals Pinocchio's own
  forward kinematics (or the closed form of an analytic system) at the trajectory sample it stands
  for.
* A real headless Chromium (Debian's ``chromium``) opens the standalone HTML and the live server
  page: the robot shows where the camera model says it stands (pixels differ from meshcat's bare
  background, rendered with the robot and grid hidden), and two animation times (``#t=``) give two
  pictures that differ exactly where the robot stood.
* Meshes from example-robot-data load with no warning; a URDF without visuals gets sticks and balls.
* No test leaves a meshcat server behind, whether the viewer is closed, interrupted or killed.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

import idapbc_pin as ip
from idapbc_pin.errors import IdapbcError
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.sim.integrate import simulate
from idapbc_pin.model import erd_robots_dir
from idapbc_pin.viewer import SERVER_MARKER, MeshcatServer, Viewer, view, write_html

WIDTH, HEIGHT = 800, 600
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)
#: Virtual time for the page to load and draw, ms (the replay's ``#t=`` picks the animation time).
BUDGET_MS = 300


# ---------------------------------------------------------------------------------------- helpers
def _rest_states(system, q) -> np.ndarray:
    q = np.atleast_2d(np.asarray(q, float))
    return system.state_from(q, np.zeros_like(q))


def _closed_loop(system, q0, T=3.0):
    return simulate(system, LQRController(system), _rest_states(system, q0), T=T, dt=0.01)


def _visual_model(system):
    model = system.plant.model
    dirs = [str(system.plant.path.parent), str(erd_robots_dir().parent.parent)]
    return pin.buildGeomFromUrdf(model, str(system.plant.path), pin.GeometryType.VISUAL, package_dirs=dirs)


def _clip_keys(clip) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A meshcat clip -> (times (K,), positions (K, 3), rotations (K, 3, 3)) as it goes to the browser."""
    tracks = {t["name"]: t for t in clip.lower()["tracks"]}
    assert clip.fps == 1  # frame numbers are seconds
    pos, quat = tracks[".position"]["keys"], tracks[".quaternion"]["keys"]
    times = np.array([k["time"] for k in pos])
    assert np.array_equal(times, [k["time"] for k in quat])
    R = np.array([pin.Quaternion(k["value"][3], *k["value"][:3]).normalized().toRotationMatrix() for k in quat])
    return times, np.array([k["value"] for k in pos]), R


def _sample_of(viewer, segment_root, time_) -> tuple[object, int] | None:
    """The (segment, sample index) a keyframe time stands for, or None (a hold or padding key)."""
    for seg in viewer.segments:
        if seg.root != segment_root:
            continue
        hit = np.flatnonzero(np.abs(seg.t0 + seg.t - time_) < 1e-9)
        if hit.size:
            return seg, int(hit[0])
    return None


def _server_children() -> list[int]:
    """meshcat servers started by this process that still run (zombies count as gone)."""
    out = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            stat = (proc / "stat").read_text()
            cmdline = (proc / "cmdline").read_bytes().decode("utf-8", "replace")
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        state, ppid = fields[0], int(fields[1])
        if ppid == os.getpid() and state != "Z" and SERVER_MARKER in cmdline:
            out.append(int(proc.name))
    return out


def _running(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _chromium() -> str:
    path = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
    if path is None:
        msg = "Debian's chromium is not installed (apt-get install -y chromium); .ci/run installs it in CI"
        if os.environ.get("CI") == "true":
            pytest.fail(msg + ", but CI=true and it is missing")
        pytest.skip(msg)
    return path


def _screenshots(jobs, workdir: Path) -> list[np.ndarray]:
    """Render (url, width, height) jobs in headless Chromium -> RGB arrays (int)."""
    from PIL import Image

    chromium = _chromium()

    def shoot(i_job):
        i, (url, width, height) = i_job
        png = Path(workdir) / f"shot{i}.png"
        cmd = [chromium, *CHROMIUM_FLAGS, f"--window-size={width},{height}", f"--user-data-dir={Path(workdir) / f'profile{i}'}",
               f"--screenshot={png}", f"--virtual-time-budget={BUDGET_MS}", url]
        try:
            res = subprocess.run(cmd, stdin=subprocess.DEVNULL, capture_output=True, timeout=90)
        except subprocess.TimeoutExpired:
            pytest.fail(f"chromium took more than 90 s to render {url}")
        assert png.is_file(), f"chromium wrote no screenshot for {url}: {res.stderr.decode(errors='replace')[-2000:]}"
        return np.asarray(Image.open(png).convert("RGB")).astype(int)

    with ThreadPoolExecutor(max_workers=2) as pool:
        return list(pool.map(shoot, enumerate(jobs)))


def _robot_region(viewer: Viewer, time_=None, width=WIDTH, height=HEIGHT, pad: int = 30) -> tuple[slice, slice]:
    """Rows and columns of the screen box where the robot stands at animation time `time_`
    (None: anywhere over the whole animation): its nodes and the far end of its end link."""
    pts = []
    for times, mats in viewer.keyframes.values():
        keep = slice(None) if time_ is None else [int(np.argmin(np.abs(times - time_)))]
        pts.append(mats[keep, :3, 3])
    for seg, tip in zip(viewer.segments, viewer.traces):  # far end of the end link
        pts.append(tip if time_ is None else tip[[int(np.argmin(np.abs(seg.t0 + seg.t - time_)))]])
    pts = np.concatenate(pts)
    px = viewer.camera.project(pts, width, height)
    assert np.all(np.isfinite(px)), "part of the robot is behind the camera"
    (x0, y0), (x1, y1) = np.floor(px.min(axis=0)) - pad, np.ceil(px.max(axis=0)) + pad
    assert x1 > 0 and y1 > 0 and x0 < width and y0 < height, "the robot projects outside the view"
    return slice(max(0, int(y0)), min(height, int(y1))), slice(max(0, int(x0)), min(width, int(x1)))


def _changed(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a - b).sum(axis=-1) > 30


def _background_html(viewer: Viewer, path: Path) -> Path:
    """The same page with every robot and trace hidden (with no grid: meshcat's bare gradient)."""
    viewer.vis["/meshcat"].set_property("visible", False)
    try:
        return viewer.write_html(path)
    finally:
        viewer.vis["/meshcat"].set_property("visible", True)


def _assert_robot_shows(img, background, viewer, what: str, time_=None, min_inside: float = 0.6) -> None:
    h, w = img.shape[:2]
    rows, cols = _robot_region(viewer, time_, w, h)
    changed = _changed(img, background)
    inside, total = int(changed[rows, cols].sum()), int(changed.sum())
    assert inside >= 150, f"{what}: only {inside} pixels differ from the background where the robot stands"
    assert inside >= min_inside * total, f"{what}: {total - inside} of {total} changed pixels lie outside the robot's region"


# ---------------------------------------------------------------------------------------- keyframes
def test_keyframes_equal_the_simulated_trajectory_at_their_times():
    system = ip.load_system("cartpole")
    traj = _closed_loop(system, [[0.3, 0.4], [-0.3, -0.3]])
    viewer = view(system, traj, open_server=False)
    assert [s.t0 for s in viewer.segments] == [0.0, 3.5]  # one after another, 0.5 s apart

    model, gm = system.plant.model, _visual_model(system)
    data, gd = model.createData(), gm.createData()
    checked, seen = 0, {0: set(), 1: set()}
    for path, clip in viewer.animation.clips.items():
        name = path.entries[-1]
        if path.entries[1] != "robots":
            continue
        times, pos, R = _clip_keys(clip)
        for time_, p, rot in zip(times, pos, R):
            hit = _sample_of(viewer, "/meshcat/robots/0", time_)
            if hit is None:
                continue
            seg, k = hit
            pin.forwardKinematics(model, data, system.plant.config(traj.q[seg.index, k][None])[0])
            pin.updateGeometryPlacements(model, data, gm, gd)
            M = gd.oMg[gm.getGeometryId(name)]
            np.testing.assert_allclose(p, M.translation, atol=1e-12)
            np.testing.assert_allclose(rot, M.rotation, atol=1e-9)
            seen[seg.index].add(k)
            checked += 1
    assert checked > 2 * 2 * 80  # 2 moving bodies x 2 rollouts x ~90 keyframes
    for idx in seen.values():  # first and last samples, and at least 30 keyframes per second
        ks = sorted(idx)
        assert ks[0] == 0 and ks[-1] == traj.t.size - 1
        assert np.max(np.diff(traj.t[ks])) <= 1 / 30 + 1e-9


def test_side_by_side_keyframes_are_the_trajectory_shifted_in_space():
    system = ip.load_system("acrobot")
    traj = _closed_loop(system, [[0.2, -0.1], [-0.15, 0.2], [0.1, 0.1]], T=1.0)
    viewer = view(system, traj, open_server=False, layout="side_by_side")
    offsets = np.array([s.offset for s in viewer.segments])
    assert all(s.t0 == 0.0 for s in viewer.segments) and len({s.root for s in viewer.segments}) == 3
    assert np.all(np.diff(offsets[:, 0]) > 0.5)  # side by side along x, apart

    model, gm = system.plant.model, _visual_model(system)
    data, gd = model.createData(), gm.createData()
    checked = 0
    for path, clip in viewer.animation.clips.items():
        if path.entries[1] != "robots":
            continue
        root, name = "/" + "/".join(path.entries[:3]), path.entries[-1]
        times, pos, R = _clip_keys(clip)
        for time_, p, rot in zip(times, pos, R):
            seg, k = _sample_of(viewer, root, time_)
            pin.forwardKinematics(model, data, system.plant.config(traj.q[seg.index, k][None])[0])
            pin.updateGeometryPlacements(model, data, gm, gd)
            M = gd.oMg[gm.getGeometryId(name)]
            np.testing.assert_allclose(p, M.translation + seg.offset, atol=1e-12)
            np.testing.assert_allclose(rot, M.rotation, atol=1e-9)
            checked += 1
    assert checked == 2 * 3 * 35  # 2 moving bodies (not the base) x 3 rollouts x (every 3rd of 101 samples + the last)


@pytest.mark.parametrize("name", ["paper_cartpole", "paper_double_pendulum", "paper_mass_spring_damper"])
def test_analytic_systems_are_drawn_from_their_coordinates(name):
    system = ip.load_system(name)
    traj = _closed_loop(system, [[0.9]] if system.nq == 1 else [[0.2, 0.3]], T=1.0)
    viewer = view(system, traj, open_server=False)
    q = traj.q[0]
    keys = {path.entries[-1]: _clip_keys(clip) for path, clip in viewer.animation.clips.items()}
    times, tip, _ = keys[{"paper_cartpole": "bob", "paper_double_pendulum": "tip", "paper_mass_spring_damper": "block"}[name]]
    k = np.searchsorted(traj.t, times)
    np.testing.assert_allclose(traj.t[k], times, atol=1e-12)
    if name == "paper_cartpole":  # pole of length 1 at angle q2 about y from upright, on a cart at q1
        expected = np.stack([q[k, 0] + np.sin(q[k, 1]), 0 * k, np.cos(q[k, 1])], axis=1)
        np.testing.assert_allclose(keys["cart"][1][:, 0], q[k, 0], atol=1e-12)
    elif name == "paper_double_pendulum":  # two unit links, absolute angles from upright
        expected = np.stack([np.sin(q[k, 0]) + np.sin(q[k, 1]), 0 * k, np.cos(q[k, 0]) + np.cos(q[k, 1])], axis=1)
    else:  # a block at x = q
        expected = np.stack([q[k, 0], 0 * k, 0 * k + 0.15], axis=1)
    np.testing.assert_allclose(tip, expected, atol=1e-12)


def test_a_run_without_trajectories_is_simulated_from_the_half_domain():
    from types import SimpleNamespace

    from idapbc_pin.sim.states import uniform_states

    system = ip.load_system("pendubot")
    run = SimpleNamespace(system=system, controller=LQRController(system), path=None)  # stands in for a trained Run
    viewer = view(run, n=2, T=0.5, seed=3, open_server=False)
    assert len(viewer.segments) == 2 and viewer.duration == pytest.approx(0.5 + 0.5 + 0.5)
    x0 = uniform_states(system, 2, box="half", seed=3)
    np.testing.assert_allclose([s.q[0] for s in viewer.segments], x0[:, : system.nq])
    one = view(run, x0=[[0.1, -0.1]], T=0.5, open_server=False)  # positions at rest
    np.testing.assert_allclose(one.segments[0].q[0], [0.1, -0.1])
    with pytest.raises(IdapbcError, match="x0 needs 4 values"):
        view(run, x0=[[0.1, 0.2, 0.3]], open_server=False)


def test_pick_success_shows_rollouts_that_reach_the_target_and_says_how_many():
    from types import SimpleNamespace

    from idapbc_pin.sim.metrics import success
    from idapbc_pin.sim.states import uniform_states
    from idapbc_pin.viewer import PICK_CANDIDATES

    system = ip.load_system("pendubot")
    lqr = LQRController(system)
    run = SimpleNamespace(system=system, controller=lqr, path=None)
    viewer = view(run, n=2, T=6.0, seed=1, pick="success", open_server=False)
    candidates = uniform_states(system, 2 * PICK_CANDIDATES, box="half", seed=1)
    reached = success(simulate(system, lqr, candidates, T=6.0), system)
    first = candidates[np.flatnonzero(reached)[:2]]
    assert reached.sum() >= 2 and viewer.note.startswith("2 of 2 rollouts reach x*")
    np.testing.assert_allclose([s.q[0] for s in viewer.segments], first[:, : system.nq])
    assert all(np.abs(s.q[-1]).max() <= 0.05 for s in viewer.segments)

    class Idle:  # no torque: the pendubot falls from every state
        def __call__(self, x):
            return np.zeros((np.atleast_2d(x).shape[0], system.m))

    idle = view(SimpleNamespace(system=system, controller=Idle(), path=None), n=2, T=2.0, seed=1, pick="success", open_server=False)
    assert idle.note.startswith("0 of 2 rollouts reach x*")
    np.testing.assert_allclose([s.q[0] for s in idle.segments], candidates[:2, : system.nq])
    with pytest.raises(IdapbcError, match="pick must be"):
        view(run, n=1, pick="best", open_server=False)


def _strip_visuals(src: Path, dst: Path) -> Path:
    text = re.sub(r"<visual>.*?</visual>", "", src.read_text(), flags=re.S)
    dst.write_text(text)
    return dst


def test_a_urdf_without_visuals_gets_sticks_and_balls(tmp_path):
    urdf = _strip_visuals(Path(ip.load_system("acrobot").source), tmp_path / "bare.urdf")
    system = ip.load_system(str(urdf), actuated=["elbow"])
    traj = _closed_loop(system, [[0.2, -0.2]], T=1.0)
    viewer = view(system, traj, open_server=False)
    names = {p.split("/")[-1] for p in viewer.keyframes}
    assert {"joint_shoulder", "joint_elbow", "rod_shoulder_elbow", "rod_elbow_end", "end_elbow"} <= names
    model, data = system.plant.model, system.plant.model.createData()
    times, pos, _ = _clip_keys(viewer.animation.clips[viewer.vis["/meshcat/robots/0/sticks/joint_elbow"].path])
    _, tip, _ = _clip_keys(viewer.animation.clips[viewer.vis["/meshcat/robots/0/sticks/end_elbow"].path])
    for time_, p, e in zip(times, pos, tip):
        k = int(np.argmin(np.abs(traj.t - time_)))
        pin.forwardKinematics(model, data, system.plant.config(traj.q[0, k][None])[0])
        np.testing.assert_allclose(p, data.oMi[2].translation, atol=1e-12)
        np.testing.assert_allclose(e, data.oMi[2].act(2 * model.inertias[2].lever), atol=1e-12)  # far end of link2


def test_trajectories_given_as_time_and_positions():
    system = ip.load_system("furuta")
    t = np.linspace(0.0, 1.0, 11)
    q = np.stack([np.sin(t), 0.3 * t], axis=1)
    viewer = view(system, (t, q), open_server=False, fps=100)
    assert len(viewer.segments) == 1 and viewer.duration == pytest.approx(1.0)
    with pytest.raises(IdapbcError, match="shape"):
        view(system, (t, q[:, :1]), open_server=False)
    with pytest.raises(IdapbcError, match="unknown trace link"):
        view(system, (t, q), open_server=False, trace_link="nope")


# ---------------------------------------------------------------------------------------- meshes
def test_example_robot_data_meshes_load_without_warnings(capfd):
    system = ip.load_system("erd:double_pendulum", actuated=["joint1"])
    assert "<mesh" in Path(system.source).read_text()
    t = np.linspace(0.0, 1.0, 6)
    q = np.stack([0.5 * t, -0.5 * t], axis=1)
    capfd.readouterr()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        viewer = view(system, (t, q), open_server=False)
    out, err = capfd.readouterr()
    assert not [str(w.message) for w in caught]
    assert "warn" not in (out + err).lower() and "could not" not in (out + err).lower(), out + err

    import umsgpack

    meshes = {}
    for frames in viewer.vis.window.messages:
        cmd = umsgpack.unpackb(frames[2])
        if cmd["type"] == "set_object":
            for geom in cmd["object"]["geometries"]:
                if geom.get("type") == "_meshfile":
                    meshes[cmd["path"].rsplit("/", 1)[-1]] = (geom["format"], geom["data"].data)
    visuals = _visual_model(system).geometryObjects
    assert len(visuals) == 3 and sorted(meshes) == sorted(g.name for g in visuals)
    for g in visuals:  # the very bytes of each mesh file go to the browser
        assert meshes[g.name] == ("stl", Path(g.meshPath).read_bytes())


def test_a_missing_mesh_is_a_clear_error(tmp_path):
    urdf = tmp_path / "broken.urdf"
    text = Path(ip.load_system("acrobot").source).read_text()
    urdf.write_text(text.replace('<cylinder radius="0.025" length="1.0"/>', '<mesh filename="package://nowhere/link1.stl"/>', 1))
    system = ip.load_system(str(urdf), actuated=["elbow"])
    with pytest.raises(IdapbcError, match="cannot load the visual geometry"):
        view(system, (np.array([0.0, 1.0]), np.zeros((2, 2))), open_server=False)


# ---------------------------------------------------------------------------------------- HTML
def test_standalone_html_is_self_contained_and_written_atomically(tmp_path):
    system = ip.load_system("cartpole")
    out = write_html(tmp_path / "sub" / "replay.html", system, n=1, T=0.5)
    html = out.read_text()
    assert not re.findall(r"<script[^>]*\bsrc\s*=", html), "a script is loaded from elsewhere"
    assert not re.findall(r"<link[^>]*\bhref\s*=", html)
    hosts = set(re.findall(r"https?://([^/\s\"'<>)]+)", html))
    assert hosts <= {"www.w3.org"}, f"URLs to outside hosts: {hosts}"  # XML namespace names only
    import base64

    import umsgpack

    commands = [umsgpack.unpackb(base64.b64decode(b)) for b in re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)]
    animations = [c for c in commands if c["type"] == "set_animation"]
    assert len(animations) == 1 and animations[0]["options"]["play"]
    assert {a["path"] for a in animations[0]["animations"]} >= {"/meshcat/robots/0/visuals/cart_0", "/meshcat/robots/0/visuals/pole_0"}
    assert [p.name for p in out.parent.iterdir()] == ["replay.html"]  # no temp file left behind


# ---------------------------------------------------------------------------------------- browser
#: Two animation times of the cartpole replay, s (URL fragment ``#t=``).
EARLY_T, LATE_T = 0.3, 2.5
#: Robots rendered together on one page, each in its own 400x300 frame, next to a background frame.
GALLERY = ("acrobot", "furuta", "erd:double_pendulum", "sticks", "paper_cartpole")
CELL_W, CELL_H = 400, 300


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    """Replay files rendered by Chromium: the cartpole at two times, a background, and a gallery
    page of other robots (iframes of their replay files) with a background cell."""
    work = tmp_path_factory.mktemp("renders")
    _chromium()
    viewers: dict[str, Viewer] = {}
    cartpole = ip.load_system("cartpole")
    viewers["cartpole"] = view(cartpole, _closed_loop(cartpole, [[0.3, 0.4], [-0.3, -0.3]]), open_server=False, grid=False)
    for name, q0 in (("acrobot", [0.3, -0.4]), ("furuta", [0.6, 0.3])):
        system = ip.load_system(name)
        viewers[name] = view(system, _closed_loop(system, [q0], T=2.0), open_server=False, grid=False, trace=False)
    erd = ip.load_system("erd:double_pendulum", actuated=["joint1"])
    t = np.linspace(0.0, 3.0, 31)
    viewers["erd:double_pendulum"] = view(erd, (t, np.stack([0.8 * np.sin(t), -0.5 * t], axis=1)), open_server=False, grid=False, trace=False)
    bare = ip.load_system(str(_strip_visuals(Path(ip.load_system("acrobot").source), work / "bare.urdf")), actuated=["elbow"])
    viewers["sticks"] = view(bare, _closed_loop(bare, [[0.3, -0.4]], T=2.0), open_server=False, grid=False, trace=False)
    paper = ip.load_system("paper_cartpole")
    viewers["paper_cartpole"] = view(paper, _closed_loop(paper, [[0.5, 0.4]], T=2.0), open_server=False, grid=False, trace=False)

    files = {name: viewer.write_html(work / f"{name.replace(':', '_')}.html") for name, viewer in viewers.items()}
    background = _background_html(viewers["cartpole"], work / "background.html")
    cells = [background] + [files[name] for name in GALLERY]
    frames = "".join(
        f'<iframe src="{f.name}#t=1" style="position:absolute; left:{CELL_W * (i % 3)}px; top:{CELL_H * (i // 3)}px; '
        f'width:{CELL_W}px; height:{CELL_H}px; border:0"></iframe>'
        for i, f in enumerate(cells)
    )
    gallery = work / "gallery.html"
    gallery.write_text(f"<!DOCTYPE html><html><body style='margin:0'>{frames}</body></html>")
    cp = files["cartpole"].as_uri()
    shots = _screenshots(
        [(cp + f"#t={EARLY_T}", WIDTH, HEIGHT), (cp + f"#t={LATE_T}", WIDTH, HEIGHT), (background.as_uri(), WIDTH, HEIGHT),
         (gallery.as_uri(), 3 * CELL_W, 2 * CELL_H)],
        work,
    )
    return viewers, dict(zip(["early", "late", "background", "gallery"], shots))


@pytest.mark.slow
def test_browser_replays_the_html_at_two_times_and_the_robot_moves(renders):
    viewers, shots = renders
    viewer = viewers["cartpole"]
    times, _ = viewer.keyframes["/meshcat/robots/0/visuals/pole_0"]
    for label, t in (("early", EARLY_T), ("late", LATE_T)):  # (the 10 m rail and the trace reach beyond)
        _assert_robot_shows(shots[label], shots["background"], viewer, f"cartpole at t = {t} s", time_=t, min_inside=0.0)
    # what changed between the two times lies where the pole and cart stand at those two times
    moved = _changed(shots["early"], shots["late"])
    r1, c1 = _robot_region(viewer, EARLY_T)
    r2, c2 = _robot_region(viewer, LATE_T)
    inside = np.zeros_like(moved)
    inside[r1, c1] = inside[r2, c2] = True
    assert moved.sum() >= 300, f"the two animation times look the same ({moved.sum()} pixels differ)"
    assert moved[inside].sum() >= 0.95 * moved.sum(), "pixels changed away from the robot"


@pytest.mark.slow
@pytest.mark.parametrize("name", GALLERY)
def test_each_robot_renders_from_its_html(renders, name):
    viewers, shots = renders
    cell = GALLERY.index(name) + 1
    rows = slice(CELL_H * (cell // 3), CELL_H * (cell // 3 + 1))
    cols = slice(CELL_W * (cell % 3), CELL_W * (cell % 3 + 1))
    img, background = shots["gallery"][rows, cols], shots["gallery"][:CELL_H, :CELL_W]
    _assert_robot_shows(img, background, viewers[name], name, time_=1.0, min_inside=0.5 if name == "paper_cartpole" else 0.9)


@pytest.mark.slow
def test_live_server_page_shows_the_robot_and_closes(renders, tmp_path):
    _, shots = renders
    system = ip.load_system("cartpole")
    traj = _closed_loop(system, [[0.3, 0.4]])
    with view(system, traj, open_server=True, grid=False) as viewer:
        assert re.fullmatch(r"http://127\.0\.0\.1:\d+/static/", viewer.url)
        pid = viewer.server.pid
        assert _server_children() == [pid]
        assert viewer.server.scene_html() == viewer.static_html()  # the replay file is what the server holds
        (live,) = _screenshots([(viewer.url, WIDTH, HEIGHT)], tmp_path)
    _assert_robot_shows(live, shots["background"], viewer, "live page", min_inside=0.0)
    assert viewer.url is None and not _running(pid)
    assert _server_children() == []


def test_port_in_use_is_a_clear_error_and_leaves_no_server():
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        with pytest.raises(IdapbcError, match=f"port {port} is already in use"):
            MeshcatServer(port=port)
    assert _server_children() == []
    with MeshcatServer() as server:  # no port: meshcat picks a free one
        assert server.alive and server.url == f"http://127.0.0.1:{server.port}/static/"
        with pytest.raises(IdapbcError, match="already in use"):
            MeshcatServer(port=server.port)
    assert not server.alive and _server_children() == []


# ---------------------------------------------------------------------------------------- CLI
_CLI = (
    "import argparse, sys\n"
    "from idapbc_pin.cli.view import add_view_command\n"
    "p = argparse.ArgumentParser(prog='idapbc-pin'); add_view_command(p.add_subparsers(dest='command', required=True))\n"
    "a = p.parse_args(sys.argv[1:]); sys.exit(a.func(a))\n"
)


def test_cli_writes_the_html_and_exits_without_a_server(tmp_path):
    out = tmp_path / "replay.html"
    res = subprocess.run([sys.executable, "-c", _CLI, "view", "cartpole", "--n", "2", "--T", "0.5", "--html", str(out)],
                         capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert res.returncode == 0, res.stderr
    assert "wrote" in res.stdout and "meshcat viewer" not in res.stdout
    assert out.stat().st_size > 100_000


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL], ids=["ctrl-c", "sigterm", "sigkill"])
def test_cli_server_never_outlives_the_command(sig):
    cli = subprocess.Popen([sys.executable, "-c", _CLI, "view", "acrobot", "--n", "1", "--T", "0.5"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True)
    try:
        line = ""
        deadline = time.monotonic() + 90
        while "meshcat viewer: http://127.0.0.1:" not in line:
            assert time.monotonic() < deadline and cli.poll() is None, cli.stderr.read() if cli.poll() is not None else "timeout"
            line = cli.stdout.readline()
        servers = [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit() and _ppid(p) == cli.pid]
        assert len(servers) == 1
        cli.send_signal(sig)
        rc = cli.wait(timeout=30)
        if sig != signal.SIGKILL:
            assert rc == 0 and "viewer closed" in cli.stdout.read()
        deadline = time.monotonic() + 10
        while _running(servers[0]) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _running(servers[0]), "the meshcat server outlived the command"
    finally:
        if cli.poll() is None:
            cli.kill()
            cli.wait()


def _ppid(proc: Path) -> int:
    try:
        return int((proc / "stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return -1

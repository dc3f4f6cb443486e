"""`idapbc-pin export`: the exported controller is the trained law, and runs without idapbc_pin or torch.

Claims (issue #14, item 4):
* the standalone `controller.torque(q, v)`, run in a process that cannot import idapbc_pin or torch,
  equals B·saturate(u(x)) of the library's controller on 1000 states, to 1e-9 (float64 networks;
  float32 networks: the same numbers as the library's numpy one-state path), saturation included;
* a continuous joint ((cos θ, sin θ) in Pinocchio) maps like the library's;
* a run's linear law outside the training box (`fallback`) is exported and applied the same way,
  and so is a run's recovery law outside its inner box (`idapbc-pin recover`);
* onnxruntime's desired_flow.onnx equals f̃_d = (J_d − R_d)∇H_d (autograd path) on 1000 states;
* bad input exits 2 with one line, and nothing is half-written.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.cli.main import main
from idapbc_pin.control.controller import Controller
from idapbc_pin.control.desired_flow import load_flow
from idapbc_pin.control.speed_filter import SpeedFilter
from idapbc_pin.deploy.export import EXPORTED_FILES
from idapbc_pin.model.zoo import zoo_urdf_path

CHECKOUT = str(Path(ip.__file__).resolve().parents[1])

#: Runs in a fresh interpreter (-I: no PYTHON* variables, no user site, no script folder on sys.path)
#: with idapbc_pin and torch made unimportable: argv = export dir, states .npz, output .npz.
#: Times (s) after its command at which the standalone `swing_up_torque` is called.
MANOEUVRE_TIMES = (0.0, 0.013, 0.5, 100.0)
STANDALONE = f"""
import importlib.abc, runpy, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in ("idapbc_pin", "torch"):
            raise ModuleNotFoundError(f"{{name}} is blocked here", name=name)
sys.meta_path.insert(0, Block())
sys.path = [p for p in sys.path if p.rstrip('/') not in ({CHECKOUT!r}, '', '.')]
folder, states, result = sys.argv[1:]
sys.path.insert(0, folder)
import numpy as np
import controller
data = np.load(states)
q, v = data["q"], data["v"]
MANOEUVRE_TIMES = {MANOEUVRE_TIMES!r}
single = np.array([controller.torque(qk, vk) for qk, vk in zip(q, v)])
manoeuvre = np.stack([controller.swing_up_torque(q, v, t) for t in MANOEUVRE_TIMES])
speed_filter = controller.SpeedFilter()
filtered = np.stack([speed_filter.update(q + 0.01 * k, v + np.sin(k)) for k in range(5)])
np.savez(result, batched=controller.torque(q, v), single=single, effort=controller.EFFORT, manoeuvre=manoeuvre, filtered=filtered)
runpy.run_path(folder + "/controller.py", run_name="__main__")
assert not any(m.partition(".")[0] in ("idapbc_pin", "torch") for m in sys.modules)
"""


def _train(source, dtype: str, out: Path, **system_kwargs) -> ip.Run:
    system = ip.load_system(source, **system_kwargs)
    config = ip.TrainConfig.fast(epochs=5, width=8, depth=1, samples=64, dtype=dtype)
    return ip.train(system, config, out=out, progress=False)


def _states(system, n: int = 1000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(q, v): n states of three times the training box around x*: angles past ±π (the law wraps
    them) and momenta beyond the box (J_d and R_d keep their boundary values there)."""
    lo, hi = system.domain
    lo, hi = system.x_star + 3 * (lo - system.x_star), system.x_star + 3 * (hi - system.x_star)
    x = lo + (hi - lo) * np.random.default_rng(seed).random((n, system.n))
    return system.split(x)


def _run_standalone(folder: Path, q, v, tmp: Path) -> dict:
    np.savez(tmp / "states.npz", q=q, v=v)
    result = subprocess.run(
        [sys.executable, "-I", "-c", STANDALONE, str(folder), str(tmp / "states.npz"), str(tmp / "tau.npz")],
        capture_output=True, text=True, timeout=300, cwd=tmp,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "torque at the target" in result.stdout and "one state: median" in result.stdout
    with np.load(tmp / "tau.npz") as data:
        return dict(data)


def _close(a, b, tol: float) -> None:
    """|a − b| ≤ tol · max|b| entry-wise (relative to the scale of b)."""
    scale = max(np.abs(b).max(), 1e-12)
    assert np.abs(a - b).max() <= tol * scale, (np.abs(a - b).max() / scale, tol)


def _expected_torque(system, controller, q, v) -> np.ndarray:
    """τ = B saturate(u(x)), x = (q, M(q)v): the library's law, written out."""
    return system.saturate(controller(system.state_from(q, v))) @ system.B.T


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Tiny trained runs: pendubot (float64), cartpole (float32, the fast preset's dtype), and a
    double pendulum whose elbow is continuous (float64)."""
    tmp = tmp_path_factory.mktemp("runs")
    urdf = zoo_urdf_path("pendubot").read_text().replace('name="elbow" type="revolute"', 'name="elbow" type="continuous"')
    assert 'type="continuous"' in urdf
    (tmp / "continuous.urdf").write_text(urdf)
    return {
        "pendubot": _train("pendubot", "float64", tmp),
        "cartpole": _train("cartpole", "float32", tmp),
        "continuous": _train(tmp / "continuous.urdf", "float64", tmp, actuated=["shoulder"]),
    }


@pytest.fixture(scope="module")
def limited_pendubot(runs, tmp_path_factory):
    """The pendubot run with a shoulder limit that half of the test states exceed, exported."""
    run = runs["pendubot"]
    q, v = _states(run.system)
    u = run.controller(run.system.state_from(q, v))
    system = dataclasses.replace(run.system, effort=[np.median(np.abs(u))])
    limited = dataclasses.replace(run, system=system)
    return limited, ip.export(limited, tmp_path_factory.mktemp("export") / "pendubot")


def test_export_writes_every_file(limited_pendubot):
    run, folder = limited_pendubot
    assert sorted(p.name for p in folder.iterdir()) == sorted(EXPORTED_FILES)
    record = json.loads((folder / "controller.json").read_text())
    assert record["joints"] == list(run.system.coordinate_names) and record["actuated"] == ["shoulder"]
    assert record["effort"] == pytest.approx(list(run.system.effort)) and record["dtype"] == "float64"
    assert (folder / "robot.urdf").read_bytes() == (run.path / "robot.urdf").read_bytes()
    readme = (folder / "README.md").read_text()
    assert "1 kHz" in readme and "ROS 2" in readme and "ONNX Runtime" in readme and "shoulder" in readme


def test_standalone_torque_equals_the_saturated_law(limited_pendubot, tmp_path):
    """Float64 networks, finite effort limit: standalone τ = B saturate(u) to 1e-9, batched and per state."""
    run, folder = limited_pendubot
    system = run.system
    q, v = _states(system)
    expected = _expected_torque(system, run.controller, q, v)
    saturated = np.isclose(np.abs(expected[:, 0]), system.effort[0])
    assert 0.2 < saturated.mean() < 0.8  # the limit binds on part of the states only
    out = _run_standalone(folder, q, v, tmp_path)
    np.testing.assert_array_equal(out["effort"], system.effort)
    _close(out["batched"], expected, 1e-9)
    _close(out["single"], expected, 1e-9)
    _close(out["batched"], run.controller.torque(q, v), 1e-9)  # the library's own saturated torque
    assert np.abs(out["batched"]).max() <= system.effort[0] * (1 + 1e-12)
    for tau in out["manoeuvre"]:  # a run without a swing-up manoeuvre: its torque at any time
        np.testing.assert_array_equal(tau, out["batched"])
    speed_filter = SpeedFilter()  # the export's filter is the library's, with the same settings
    np.testing.assert_array_equal(out["filtered"], np.stack([speed_filter.update(q + 0.01 * k, v + np.sin(k)) for k in range(5)]))


@pytest.mark.parametrize("inside_gain, inside_ramp", [(1.0, [0.0, 0.0]), (3.0, [0.0, 0.0]), (3.0, [0.2, 0.5])])
def test_standalone_switches_to_the_linear_law_outside_the_box_as_the_library_does(limited_pendubot, tmp_path, inside_gain, inside_ramp):
    """A run that uses the fallback (`control.fallback`), with the learned law as trained inside the
    box or scaled by 3 about u* there (the gate's `inside_gain`), constant or ramped in from x*
    (`inside_ramp`): controller.json carries K, u*, the box, the inside gain and its ramp, and the
    standalone τ equals the library's on states mostly outside the training box, to 1e-9."""
    run = limited_pendubot[0]
    entry = {"used": True, "inside_gain": inside_gain, "inside_ramp": inside_ramp}
    run = dataclasses.replace(run, config=run.config.replace(fallback="auto"), summary={**run.summary, "fallback": entry})
    assert run.controller.fallback.inside_gain == inside_gain and list(run.controller.fallback.inside_ramp) == inside_ramp
    folder = ip.export(run, tmp_path / "export", onnx=False)
    record = json.loads((folder / "controller.json").read_text())
    np.testing.assert_array_equal(record["fallback"]["K"], run.controller.fallback.K)
    assert record["fallback"]["inside_gain"] == inside_gain and record["fallback"]["inside_ramp"] == inside_ramp
    readme = (folder / "README.md").read_text()
    assert "Outside the training box" in readme and (("Inside the training box" in readme) == (inside_gain != 1.0))
    assert ("ramped in" in readme) == (inside_ramp[1] > 0)
    q, v = _states(run.system)
    x = run.system.state_from(q, v)
    outside = run.controller.fallback.outside(x)
    assert 0.5 < outside.mean() < 1.0
    r = (np.abs(run.controller.fallback.delta(x)) / run.controller.fallback.half).max(axis=1)
    assert ((r > 0.2) & (r < 0.5)).any() if inside_ramp[1] > 0 else True  # some states on the ramp itself
    out = _run_standalone(folder, q, v, tmp_path)
    expected = run.controller.torque(q, v)
    assert not np.allclose(expected, run.controller.with_fallback(None).torque(q, v))
    _close(out["batched"], expected, 1e-9)
    _close(out["single"], expected, 1e-9)


def _standalone_equals_library_outside(run, law, folder, tmp_path) -> None:
    """The exported controller's τ equals the library's to 1e-9 on 1000 states, half of them near x*
    (inside `law`'s box), where `law` (the run's outer law) acts on 30–90 % of them and changes τ."""
    system = run.system
    q, v = _states(system)
    q_star = system.x_star[: system.nq]
    q[:500], v[:500] = q_star + 0.08 * (q[:500] - q_star), 0.08 * v[:500]  # half of them near x*, in the law's box
    outside = law.outside(system.state_from(q, v))
    assert 0.3 < outside.mean() < 0.9
    expected = run.controller.torque(q, v)
    assert not np.allclose(expected, run.controller.with_fallback(None).torque(q, v))
    out = _run_standalone(folder, q, v, tmp_path)
    _close(out["batched"], expected, 1e-9)
    _close(out["single"], expected, 1e-9)


@pytest.mark.parametrize("residual", [False, True])
def test_standalone_applies_a_recovery_law_as_the_library_does(runs, tmp_path, residual):
    """A run with a recovery law (`control.recovery`, direct or residual form): controller.json carries
    its weights and inner box, and the standalone τ equals the library's to 1e-9 on states mostly
    outside the inner box."""
    from tests.test_recovery import random_law

    from idapbc_pin.run import RECOVERY_FILE

    path = tmp_path / "run"
    shutil.copytree(runs["pendubot"].path, path)
    law = random_law(runs["pendubot"].system, inner_scale=0.3, residual=residual)
    np.savez(path / RECOVERY_FILE, **law.arrays())
    summary = json.loads((path / "summary.json").read_text()) | {"recovery": {"used": True, "inner_scale": 1.5}}
    (path / "summary.json").write_text(json.dumps(summary))
    run = ip.load_run(path)
    folder = ip.export(run, tmp_path / "export", onnx=False)
    record = json.loads((folder / "controller.json").read_text())
    assert record["fallback"]["kind"] == "recovery" and record["fallback"]["inner"] == pytest.approx(list(law.inner))
    assert "recovery law" in (folder / "README.md").read_text() and record["fallback"].get("residual", False) == residual
    assert ("correction added to the IDA-PBC law's input" in (folder / "README.md").read_text()) == residual
    _standalone_equals_library_outside(run, law, folder, tmp_path)


def test_standalone_applies_a_recovery_library_of_paths_as_the_library_does(runs, tmp_path):
    """A run whose recovery law is its labelled paths read at the nearest point (`LibraryLaw`):
    controller.json carries the paths, their gains and the inner box, and the standalone τ (a brute
    force nearest point) equals the library's (a k-d tree) to 1e-9 on states mostly outside the box."""
    from tests.test_recovery_library import _paths

    from idapbc_pin.recovery.library_law import LibraryLaw
    from idapbc_pin.run import RECOVERY_FILE
    from idapbc_pin.trajectory.library import paths_law

    system = runs["pendubot"].system
    X, U = _paths(system, P=8, L=60, seed=5)  # 472 points: the library reads them with its k-d tree
    lo, hi = system.domain
    law = LibraryLaw.from_tracks(paths_law(system, X, U, 0.3, np.full(system.n, np.inf)), (hi - lo) / 2).with_inner(0.3)
    path = tmp_path / "run"
    shutil.copytree(runs["pendubot"].path, path)
    np.savez(path / RECOVERY_FILE, **law.arrays())
    summary = json.loads((path / "summary.json").read_text()) | {"recovery": {"used": True, "inner_scale": 0.3}}
    (path / "summary.json").write_text(json.dumps(summary))
    run = ip.load_run(path)
    assert isinstance(run.fallback, LibraryLaw)
    folder = ip.export(run, tmp_path / "export", onnx=False)
    record = json.loads((folder / "controller.json").read_text())
    assert record["fallback"]["kind"] == "recovery" and len(record["fallback"]["X"]) == law.points
    assert "read at the nearest point" in (folder / "README.md").read_text()
    _standalone_equals_library_outside(run, law, folder, tmp_path)


def _swing_tracking_law(system):
    """A tracking law (a library of one labelled path) with a kept box of 0.3 of the training box."""
    from tests.test_recovery_library import _paths

    from idapbc_pin.trajectory.library import paths_law

    X, U = _paths(system, P=1, L=120, seed=6)
    lo, hi = system.domain
    return paths_law(system, X, U, 0.3, 0.3 * (hi - lo) / 2)


def _run_with_swing_law(source, law, tmp_path):
    """A copy of the run `source` under tmp_path whose kept swing-up law is `law`, loaded."""
    from idapbc_pin.run import SWINGUP_FILE

    path = tmp_path / "run"
    shutil.copytree(source.path, path)
    np.savez(path / SWINGUP_FILE, **law.arrays())
    summary = json.loads((path / "summary.json").read_text()) | {"swing_up": {"used": True}}
    (path / "summary.json").write_text(json.dumps(summary))
    return ip.load_run(path)


def test_standalone_applies_a_swing_up_tracking_law_as_the_library_does(runs, tmp_path):
    """A run whose swing-up law is a tracking law (a nominal read at the nearest point, `TrackingLaw`):
    controller.json's "swing_up" fallback carries its nominal "X", and the standalone τ equals the
    library's to 1e-9 on states mostly outside its kept box."""
    law = _swing_tracking_law(runs["pendubot"].system)
    run = _run_with_swing_law(runs["pendubot"], law, tmp_path)
    folder = ip.export(run, tmp_path / "export", onnx=False)
    record = json.loads((folder / "controller.json").read_text())
    assert record["fallback"]["kind"] == "swing_up" and len(record["fallback"]["X"]) == len(law.X)
    _standalone_equals_library_outside(run, law, folder, tmp_path)


def test_standalone_applies_a_tracking_law_only_within_its_funnel_as_the_library_does(runs, tmp_path):
    """A tracking law with a funnel ϱ: controller.json carries ϱ, and the standalone τ equals the
    library's to 1e-9 on states where the law acts, and where the state lies outside its kept box
    but beyond ϱ of its nominal (the run's law acts there)."""
    system = runs["pendubot"].system
    plain = _swing_tracking_law(system)
    q, v = _states(system)
    x = system.state_from(q, v)
    _, d = plain.nearest(x)
    dist = np.sqrt(((d * plain.weight) ** 2).sum(axis=1))
    law = plain.with_funnel(float(np.median(dist[plain.outside(x)])))
    beyond = plain.outside(x) & ~law.outside(x)
    assert 0.1 < law.outside(x).mean() and 0.1 < beyond.mean()
    run = _run_with_swing_law(runs["pendubot"], law, tmp_path)
    assert run.controller.fallback.funnel == law.funnel
    folder = ip.export(run, tmp_path / "export", onnx=False)
    record = json.loads((folder / "controller.json").read_text())
    assert record["fallback"]["funnel"] == law.funnel
    expected = run.controller.torque(q, v)
    assert not np.allclose(expected[beyond], run.controller.with_fallback(plain.with_inner(run.controller.fallback.inner)).torque(q, v)[beyond])
    out = _run_standalone(folder, q, v, tmp_path)
    _close(out["batched"], expected, 1e-9)
    _close(out["single"], expected, 1e-9)


def test_standalone_keeps_the_ida_pbc_law_on_the_level_set_of_h_d_as_the_library_does(runs, tmp_path):
    """A recovery law with a level c acts only where H_d(x) > c (outside its inner box): the
    standalone evaluates H_d from desired_flow.py and gives the library's τ to 1e-9."""
    from tests.test_recovery import random_law

    from idapbc_pin.run import RECOVERY_FILE

    path = tmp_path / "run"
    shutil.copytree(runs["pendubot"].path, path)
    system, nets_only = runs["pendubot"].system, runs["pendubot"].controller.with_fallback(None)
    q, v = _states(system)
    x = runs["pendubot"].nets.wrap(system.state_from(q, v))  # the law, and its level, see angles within π of x*
    level = float(np.median(nets_only.H_d(x)))
    law = random_law(system, inner_scale=0.0).with_level(level)
    np.savez(path / RECOVERY_FILE, **law.arrays())
    summary = json.loads((path / "summary.json").read_text()) | {"recovery": {"used": True, "inner_scale": 0.0, "level": level}}
    (path / "summary.json").write_text(json.dumps(summary))
    run = ip.load_run(path)
    assert run.controller.fallback.level == level
    folder = ip.export(run, tmp_path / "export", onnx=False)
    assert json.loads((folder / "controller.json").read_text())["fallback"]["level"] == level
    expected = run.controller.torque(q, v)
    kept = nets_only.H_d(x) <= level  # the IDA-PBC law's own torque there, the recovery law's elsewhere
    np.testing.assert_array_equal(expected[kept], nets_only.torque(q, v)[kept])
    np.testing.assert_array_equal(expected[~kept], run.controller.with_fallback(law.with_level(math.inf)).torque(q, v)[~kept])
    out = _run_standalone(folder, q, v, tmp_path)
    _close(out["batched"], expected, 1e-9)
    _close(out["single"], expected, 1e-9)


def test_standalone_applies_a_recovery_law_within_its_plan_bound_on_an_unlimited_robot(runs, tmp_path):
    """A robot without effort limits keeps a recovery law bounded by `plan_bound` (LQR's largest
    demand on the box): EFFORT stays inf, the law's own ū travels in controller.json, and the
    standalone gives the library's τ to 1e-9."""
    from tests.test_recovery import random_law

    from idapbc_pin.trajectory.plans import plan_bound
    from idapbc_pin.run import RECOVERY_FILE

    path = tmp_path / "run"
    shutil.copytree(runs["pendubot"].path, path)
    unlimited = dataclasses.replace(runs["pendubot"].system, effort=[np.inf])
    law = dataclasses.replace(random_law(unlimited, inner_scale=1.5), effort=plan_bound(unlimited))
    np.savez(path / RECOVERY_FILE, **law.arrays())
    summary = json.loads((path / "summary.json").read_text()) | {"recovery": {"used": True, "inner_scale": 1.5}}
    (path / "summary.json").write_text(json.dumps(summary))
    run = ip.load_run(path)
    run = dataclasses.replace(run, system=unlimited)
    folder = ip.export(run, tmp_path / "export", onnx=False)
    saved = json.loads((folder / "controller.json").read_text())
    assert saved["effort"] == [None] and saved["fallback"]["effort"] == pytest.approx(list(plan_bound(unlimited)))
    q, v = _states(unlimited)
    expected = run.controller.torque(q, v)
    outside = law.outside(run.nets.wrap(unlimited.state_from(q, v)))
    assert 0 < outside.sum() < len(q) and np.abs(expected[outside]).max() <= plan_bound(unlimited)[0] * (1 + 1e-12)
    out = _run_standalone(folder, q, v, tmp_path)
    assert np.isinf(out["effort"]).all()
    _close(out["batched"], expected, 1e-9)


def test_standalone_torque_float32_networks(runs, tmp_path):
    """Float32 networks (the fast preset): one state at a time, the standalone gives the library's
    one-state numbers (both run desired_flow.py) to 1e-9; batched, float32 rounding separates them."""
    run = runs["cartpole"]
    system = run.system
    folder = ip.export(run, tmp_path / "export", onnx=False)
    assert not (folder / "desired_flow.onnx").exists()
    q, v = _states(system)
    x = system.state_from(q, v)
    controller = run.controller
    one_by_one = np.array([system.saturate(controller(xk)) @ system.B.T for xk in x])
    out = _run_standalone(folder, q, v, tmp_path)
    _close(out["single"], one_by_one, 1e-9)
    _close(out["batched"], _expected_torque(system, controller, q, v), 2e-5)


def test_standalone_brakes_a_cart_near_its_rail_end_as_the_library_does(runs, tmp_path):
    """The rail guard (`control.rail_guard`) is exported: cart states near either end of the zoo
    cartpole's ±5 m rail, moving either way, get the library's torques, one state at a time, to 1e-9;
    full braking (±50 N) on the states the guard brakes, and some it does not."""
    run = runs["cartpole"]
    system = run.system
    guard = run.controller.guard
    rng = np.random.default_rng(3)
    n = 200
    q = np.column_stack([rng.choice([-1.0, 1.0], n) * rng.uniform(3.0, 4.9, n), rng.uniform(-np.pi, np.pi, n)])
    v = np.column_stack([rng.uniform(-8.0, 8.0, n), rng.uniform(-6.0, 6.0, n)])
    brake = guard.braking(system.state_from(q, v))[0][:, 0]
    assert 0 < brake.sum() < n
    folder = ip.export(run, tmp_path / "export", onnx=False)
    assert json.loads((folder / "controller.json").read_text())["rail_guard"]["upper"] == [pytest.approx(4.75)]
    one_by_one = np.array([system.saturate(run.controller(xk)) @ system.B.T for xk in system.state_from(q, v)])
    np.testing.assert_allclose(np.abs(one_by_one[brake, 0]), 50.0)
    out = _run_standalone(folder, q, v, tmp_path)
    _close(out["single"], one_by_one, 1e-9)


def test_standalone_governs_speed_and_energy_as_the_library_does(runs, tmp_path):
    """The speed and energy governor (`control.speed_governor`) is exported: from moving states of the
    pendubot (speeds up to the joints' ratings), where it acts on most, the standalone torques equal
    the library's one state at a time to 1e-9; without the governor they differ there."""
    from idapbc_pin.sim.states import moving_states

    run = runs["pendubot"]
    system = run.system
    x = moving_states(system, 200, seed=4)
    q, v = system.split(x)
    s_e, s_v, _, _ = run.controller.governor.shares(x)
    assert ((s_e > 0) | (s_v > 0)).mean() > 0.5
    folder = ip.export(run, tmp_path / "export", onnx=False)
    assert json.loads((folder / "controller.json").read_text())["governor"]["energy_rows"] == [0, 1]
    one_by_one = np.array([system.saturate(run.controller(xk)) @ system.B.T for xk in x])
    ungoverned = np.array([system.saturate(run.controller.with_governor(False)(xk)) @ system.B.T for xk in x])
    assert np.abs(one_by_one - ungoverned).max() > 1.0
    out = _run_standalone(folder, q, v, tmp_path)
    _close(out["single"], one_by_one, 1e-9)


def test_continuous_joint_maps_like_the_library(runs, tmp_path):
    """A continuous elbow is (cos θ, sin θ) in Pinocchio: the standalone maps it as the library does.
    The shoulder is left unlimited here (null in controller.json, inf in EFFORT)."""
    run = runs["continuous"]
    run = dataclasses.replace(run, system=dataclasses.replace(run.system, effort=[np.inf]))
    system = run.system
    assert [j.kind for j in system.joints] == ["revolute", "continuous"]
    folder = ip.export(run, tmp_path / "export", onnx=False)
    assert json.loads((folder / "controller.json").read_text())["effort"] == [None]
    q, v = _states(system)
    q[:, 1] = np.random.default_rng(1).uniform(-7, 7, len(q))  # several turns
    out = _run_standalone(folder, q, v, tmp_path)
    assert np.isinf(out["effort"]).all()
    _close(out["batched"], _expected_torque(system, run.controller, q, v), 1e-9)


@pytest.mark.parametrize("name", ["pendubot", "cartpole"])
def test_onnx_equals_the_desired_flow(runs, limited_pendubot, tmp_path, name):
    """onnxruntime on desired_flow.onnx = f̃_d(x) (autograd path) on 1000 states, N dynamic.

    Float64 networks: to 1e-9 of the library (measured 2e-14). Float32 networks: both sides round in
    float32, so each is judged against the same weights evaluated in float64, and the graph must be
    as accurate as the library's own float32 path (within 2e-6 of the scale, or within 1.5× the
    library's error where the anchor's f̃_d = (J_d − R_d)∇H_d cancels larger terms: the zoo cartpole
    with the physical anchor weight measured 5.7e-6 for the graph, 7.0e-6 for the library).
    """
    import copy

    from idapbc_pin.control.controller import Controller

    ort = pytest.importorskip("onnxruntime")
    run = runs[name]
    folder = limited_pendubot[1] if name == "pendubot" else ip.export(run, tmp_path / "export")
    session = ort.InferenceSession(str(folder / "desired_flow.onnx"))
    dtype = np.dtype(run.config.dtype)
    x = run.system.state_from(*_states(run.system))
    f_d = run.controller.f_d(x)
    out = session.run(["f_d"], {"x": x.astype(dtype)})[0]
    assert out.dtype == dtype
    if dtype == np.float64:
        _close(out, f_d, 1e-9)
        _close(session.run(["f_d"], {"x": x[:1].astype(dtype)})[0], f_d[:1], 1e-9)
        return
    exact = Controller(run.system, copy.deepcopy(run.controller.nets).double()).f_d(x)
    scale = np.abs(exact).max()
    library_error = np.abs(f_d - exact).max() / scale
    tol = max(2e-6, 1.5 * library_error)
    _close(out, exact, tol)
    _close(session.run(["f_d"], {"x": x[:1].astype(dtype)})[0], exact[:1], tol)
    assert library_error < 1e-4  # float32 rounding, not a different function


def test_onnx_free_form_with_extra_damping():
    """The trained runs are anchored: the free form (softplus diagonal of L) with ρ > 0 and box units,
    random weights, goes through the same graph."""
    ort = pytest.importorskip("onnxruntime")
    import torch

    from idapbc_pin.control.nets import build_nets
    from idapbc_pin.deploy.onnx_flow import onnx_model

    system = ip.load_system("cartpole")
    torch.manual_seed(3)
    config = ip.TrainConfig(width=16, depth=2, form="free", rho=0.2, kappa=0.1, scaling="box")
    controller = Controller(system, build_nets(system, config))
    with torch.no_grad():
        for p in controller.nets.parameters():
            p.add_(0.3 * torch.randn_like(p))
    session = ort.InferenceSession(onnx_model(controller.flow()))
    x = system.state_from(*_states(system))
    f_d = controller.f_d(x)
    _close(session.run(["f_d"], {"x": x})[0], f_d, 1e-9)


# ------------------------------------------------------------------------------------ bad input
def _cli_error(capsys, *args) -> str:
    assert main(["export", *map(str, args)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err and "Fix:" in err
    return err


def test_not_a_run_directory(tmp_path, capsys):
    assert "not a run directory" in _cli_error(capsys, tmp_path, "--out", tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_damaged_checkpoint(runs, tmp_path, capsys):
    run_dir = shutil.copytree(runs["cartpole"].path, tmp_path / "run")
    for name in ("best", "last"):
        path = run_dir / "checkpoints" / f"{name}.pt"
        path.write_bytes(path.read_bytes()[:100])
    assert "damaged" in _cli_error(capsys, run_dir, "--out", tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_analytic_system_is_refused(tmp_path, capsys):
    run = _train("paper_mass_spring_damper", "float64", tmp_path)
    err = _cli_error(capsys, run.path, "--out", tmp_path / "out")
    assert "export needs a URDF robot" in err
    with pytest.raises(ip.IdapbcError, match="export needs a URDF robot"):
        ip.export(run, tmp_path / "out")


def test_non_empty_folder_needs_force(runs, tmp_path, capsys):
    """--force overwrites the exported files only, and drops an earlier export's ONNX with --no-onnx."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    (out / "desired_flow.onnx").write_bytes(b"an earlier export's")
    assert "not empty" in _cli_error(capsys, runs["cartpole"].path, "--out", out)
    assert sorted(p.name for p in out.iterdir()) == ["desired_flow.onnx", "notes.txt"]
    assert "is a file" in _cli_error(capsys, runs["cartpole"].path, "--out", out / "notes.txt")
    assert main(["export", str(runs["cartpole"].path), "--out", str(out), "--force", "--no-onnx"]) == 0
    assert "wrote" in capsys.readouterr().out
    assert (out / "notes.txt").read_text() == "keep me" and (out / "controller.py").is_file()
    assert not (out / "desired_flow.onnx").exists()


@pytest.mark.parametrize("damage", ["missing", "truncated", "garbage", "other arrays"])
def test_damaged_exported_weights_are_named_in_one_line(runs, tmp_path, damage):
    """The exported controller reads weights.npz through `load_flow`: damage gets one ValueError line
    that names the file and says to export again, never numpy's or zipfile's own error."""
    out = tmp_path / "out"
    ip.export(runs["cartpole"].path, out, onnx=False)
    path = out / "weights.npz"
    load_flow(path)  # intact
    if damage == "missing":
        path.unlink()
    elif damage == "truncated":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "garbage":
        path.write_bytes(b"not an npz file" * 10)
    else:
        np.savez(path, x=np.zeros(3))
    with pytest.raises(ValueError) as info:
        load_flow(path)
    message = str(info.value)
    assert str(path) in message and "export the run again" in message and "\n" not in message

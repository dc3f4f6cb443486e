"""The swing-up law and its stage (`recovery.swing_law`, `recovery.swing_stage`): the law acts only
where the posture leaves the training box, is continuous around the whole circle, stays within the
limits; the stage writes a law the run loads, and a kill leaves the run as it was."""

import json
import math
from math import inf, nan
import shutil

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.model.angles import wrap_angles
from idapbc_pin.recovery.config import SwingUpConfig
from idapbc_pin.recovery.swing_law import SwingUpLaw, swing_features
from idapbc_pin.recovery import swing_stage as stage
from idapbc_pin.recovery.swing_stage import ANY_SPEED, any_speed_boxes, chosen_box, fit_swing_law, kept_boxes, posture_box, swing_up
from idapbc_pin.trajectory.holds import Judged
from idapbc_pin.trajectory.tracks import tracking_law, tvlqr_gains
from idapbc_pin.run import SWINGUP_FILE, SWINGUP_REFUSED_FILE
from idapbc_pin.sim.states import resting_states

from .conftest import sample_domain

#: The labelling steps here take their few starts in one chunk (`one_label_chunk`).
pytestmark = pytest.mark.usefixtures("one_label_chunk")

#: The smallest stage that exercises every step: two starts, half-second plans (two iterations each,
#: the nominals' too), one DAgger round, the library's starts planned again at 1 s where 0.5 s brings none up.
TINY = dict(starts=2, horizon=0.5, ilqr_iterations=2, track_iterations=2, dagger=1, dagger_starts=2, width=8, steps=30, gate_states=2, box_states=4,
            judge_T=3.0, workers=1, circle=0.5, manoeuvre_horizons=(0.25,), library=2, library_moving=1, library_released=1, gate_moving=2, gate_released=1, library_horizon=0.5, library_longer=(1.0,))


def random_swing_law(system, seed: int = 0, width: int = 16, inner=None, box=None) -> SwingUpLaw:
    """A swing-up law with random weights (large enough that its output saturates somewhere), kept box
    `box` (default: the training box's angles alone)."""
    rng = np.random.default_rng(seed)
    mask = np.asarray(system.angle_mask, dtype=bool)
    sizes = [2 * int(mask.sum()) + system.n - int(mask.sum()), width, width, system.m]
    weights = tuple(2.0 * rng.standard_normal((b, a)) for a, b in zip(sizes[:-1], sizes[1:]))
    biases = tuple(rng.standard_normal(b) for b in sizes[1:])
    lo, hi = system.domain
    box = np.where(mask, (hi - lo) / 2, np.inf) if box is None else box
    return SwingUpLaw(weights, biases, np.asarray(system.x_star, float), (hi - lo) / 2, np.asarray(system.effort, float), mask, box, inner)


@pytest.fixture(scope="module")
def weak_pendubot():
    return ip.load_system("pendubot", effort={"shoulder": 8.0})


def test_the_swing_up_law_acts_only_where_the_posture_leaves_the_box_and_stays_within_the_limits(weak_pendubot):
    system = weak_pendubot
    law = random_swing_law(system)
    x = np.concatenate([sample_domain(system, 1000), system.x_star + 3 * (sample_domain(system, 1000, seed=1) - system.x_star)])
    u = law.apply(x, np.full((len(x), system.m), 123.0))
    d = wrap_angles(x - system.x_star, system.angle_mask)
    posture_in = (np.abs(d[:, : system.nq]) <= law.box[: system.nq]).all(axis=1)  # speeds never decide
    assert 0 < posture_in.sum() < len(x)
    np.testing.assert_array_equal(u[posture_in], 123.0)
    assert np.abs(u[~posture_in]).max() <= system.effort.max() * (1 + 1e-12)
    assert (np.abs(u[~posture_in]) > 0.9 * system.effort).any()
    fast = np.concatenate([system.x_star[: system.nq], [50.0, -50.0]])[None]  # x* at a huge momentum: the run's law
    np.testing.assert_array_equal(law.apply(fast, [[7.0]]), [[7.0]])
    lo, hi = system.domain
    boxed = law.with_box(0.5 * (hi - lo) / 2)  # a kept box r·s in every component: the momentum decides too
    assert boxed.outside(fast).all()
    inside = (np.abs(d) <= boxed.box).all(axis=1)
    np.testing.assert_array_equal(boxed.apply(x, np.full((len(x), system.m), 123.0))[inside], 123.0)
    assert not inside[~posture_in].any() and 0 < inside.sum() < posture_in.sum()


def test_the_stage_s_teacher_pumps_outside_the_box_and_asks_the_run_s_law_only_inside(weak_pendubot):
    """`PumpThenRun`: the energy pump's input where a posture leaves the training box's angles, the
    run's law's inside; the run's law is called with the inside rows alone (none: not at all)."""
    from idapbc_pin.control.energy_pump import EnergyPumpLaw

    system = weak_pendubot
    asked = []

    def run_law(x):
        asked.append(len(x))
        return np.tanh(x[:, :1] + 2 * x[:, 1:2])

    teacher = stage.PumpThenRun(system, run_law)
    x = sample_domain(system, 40, seed=5) * 4  # states inside and outside the box's angles
    out = (np.abs(wrap_angles(x - system.x_star, system.angle_mask)) > np.where(system.angle_mask, stage.box_half_widths(system), np.inf)).any(axis=1)
    assert 0 < out.sum() < len(x)
    u = teacher(x)
    np.testing.assert_array_equal(u[out], EnergyPumpLaw(system)(x[out]))
    np.testing.assert_array_equal(u[~out], run_law(x[~out]))
    assert asked[0] == int((~out).sum())
    asked.clear()
    teacher(x[out])
    assert asked == []


def test_the_kept_box_reads_the_box_angles_and_a_multiple_of_its_momenta_and_never_the_cart():
    """`posture_box`: a state in the box's postures but faster than `kept_momenta` times the box's
    momenta is left to the swing-up law; a cart's position is never read; 0 reads no momentum."""
    system = ip.load_system("cartpole")
    lo, hi = (np.asarray(b, float) for b in system.domain)
    s, mask = (hi - lo) / 2, np.asarray(system.angle_mask, bool)
    box = posture_box(system, SwingUpConfig(kept_momenta=3.0))
    np.testing.assert_array_equal(box[: system.nq], np.where(mask[: system.nq], s[: system.nq], np.inf))
    np.testing.assert_allclose(box[system.nq:], 3.0 * s[system.nq:])
    assert np.isinf(posture_box(system, SwingUpConfig(kept_momenta=0.0))[system.nq:]).all()
    np.testing.assert_array_equal(kept_boxes(system, SwingUpConfig(kept_momenta=3.0))["posture"], box)
    law = random_swing_law(system, box=box)
    slow, fast = system.x_star.copy(), system.x_star.copy()
    slow[system.nq:] = 2.9 * s[system.nq:]
    fast[system.nq:] = 3.1 * s[system.nq:]
    far_cart = slow.copy()
    far_cart[0] = system.x_star[0] + 50.0 * s[0]
    assert not law.outside(np.stack([slow, far_cart])).any() and law.outside(fast[None]).all()
    with pytest.raises(ip.IdapbcError, match="kept_momenta"):
        SwingUpConfig(kept_momenta=-1.0)


def test_where_the_bounded_box_keeps_nothing_a_second_gate_reads_no_momentum(monkeypatch):
    """A gate that keeps no law with the bounded box runs again with the box's angles and no momentum
    read (`any_speed_boxes`); a law that second gate keeps carries that box, the entry records both
    gates, and `chosen_box` gives the library that box. Where the first gate keeps one, there is no
    second gate."""
    system = ip.load_system("reaction_wheel")
    config = SwingUpConfig()
    second = any_speed_boxes(system, config)
    np.testing.assert_array_equal(second[ANY_SPEED][: system.nq], posture_box(system, config)[: system.nq])
    assert np.isinf(second[ANY_SPEED][system.nq:]).all() and any_speed_boxes(system, SwingUpConfig(kept_momenta=0.0)) == {}
    law = random_swing_law(system)
    run = type("Run", (), {"system": system, "summary": {}})()
    calls = []

    def gate(run_, laws, config_, progress=False, fitted=None, boxes=None, shared=None):
        calls.append(boxes)
        name = "posture" if boxes is None else next(iter(boxes))
        return (0, name), {"box": name, "used": boxes is not None or first_used}

    monkeypatch.setattr(stage, "swing_gate", gate)
    for first_used in (False, True):
        calls.clear()
        entry = stage._fit_and_gate(run, system, None, (np.empty((0, system.n)), np.empty((0, system.m))), (None, None), [law], config, None, False, 0.0)
        assert len(calls) == (1 if first_used else 2) and entry["used"]
        if first_used:
            np.testing.assert_array_equal(entry["_law"].box, posture_box(system, config))
        else:
            assert entry["gate"]["box"] == ANY_SPEED and entry["gate"]["bounded"]["used"] is False
            np.testing.assert_array_equal(entry["_law"].box, second[ANY_SPEED])
            run.summary = {"swing_up": {"gate": entry["gate"]}}
            np.testing.assert_array_equal(chosen_box(run, system, config), second[ANY_SPEED])
    run.summary = {}
    np.testing.assert_array_equal(chosen_box(run, system, config), posture_box(system, config))


def test_where_no_gate_keeps_a_law_a_last_gate_judges_each_tracking_law_within_each_funnel(monkeypatch):
    """Where the gates keep nothing, a last gate judges each tracking law within each of `funnels`
    (the fits are not judged again; the run's law's verdicts are shared); a funnelled law it keeps
    is the stage's law, with its funnel in the entry and the printed verdict. Without funnels, or
    where an earlier gate keeps a law, there is no such gate."""
    from idapbc_pin.trajectory.tracking_law import TrackingLaw

    system = ip.load_system("pendubot")
    n, m = system.n, system.m
    track = TrackingLaw(np.zeros((3, n)), np.zeros((3, m)), np.zeros((3, m, n)), np.ones(n), np.asarray(system.x_star, float),
                        np.asarray(system.effort, float), np.asarray(system.angle_mask, bool), np.full(n, np.inf))
    run = type("Run", (), {"system": system, "summary": {}})()
    calls = []

    def gate(run_, laws, config_, progress=False, fitted=None, boxes=None, shared=None):
        calls.append((laws, fitted, shared))
        funnelled = all(np.isfinite(getattr(law, "funnel", np.inf)) for law in laws)
        used = funnelled and keep_funnelled
        k = 3 if funnelled else 0  # the second tracking law within the second funnel
        return (k, "posture" if boxes is None else next(iter(boxes))), {"box": "posture", "used": used, "fit": k, "fitted": fitted,
                                                                         "candidates": {"posture": [0] * len(laws)}, "states": 20, "run": 4,
                                                                         "law": 20, "box_states": 100, "run_box": 84, "law_box": 91}

    monkeypatch.setattr(stage, "swing_gate", gate)
    labels = (np.empty((0, n)), np.empty((0, m)))
    tracks = [track, track.with_box(np.full(n, 2.0))]
    for keep_funnelled, funnels in ((True, (0.5, 1.0)), (False, (0.5, 1.0)), (True, ())):
        calls.clear()
        config = SwingUpConfig(funnels=funnels)
        entry = stage._fit_and_gate(run, system, None, labels, (None, None), tracks, config, None, False, 0.0)
        assert len(calls) == (3 if funnels else 2)  # the bounded box's gate, with no momentum read, then the funnels'
        if not funnels:
            assert not entry["used"] and entry["funnel"] is None
            continue
        laws, fitted, shared = calls[-1]
        assert [law.funnel for law in laws] == [0.5, 0.5, 1.0, 1.0] and fitted == 0 and shared is calls[0][2]
        assert entry["used"] == keep_funnelled
        line = stage.format_swing_gate(entry["gate"], config)
        assert "tracking law 2 within the funnel 1" in line and "again each tracking law only within each funnel" in line
        if keep_funnelled:
            assert entry["funnel"] == 1.0 and entry["_law"].funnel == 1.0 and entry["law"] == "tracking"
            assert entry["gate"]["unfunnelled"]["used"] is False
        else:  # the refused last gate is recorded beside the first
            assert entry["funnel"] is None and entry["gate"]["funnelled"]["used"] is False and not np.isfinite(entry["_law"].funnel)
            np.testing.assert_array_equal(entry["_law"].X, tracks[1].X)


def test_the_swing_up_law_is_continuous_through_the_hanging_posture(weak_pendubot):
    """δ = +π and δ = −π are the same hanging posture: features of sines and cosines give the same input
    on either side of the wrap, where a law of δ itself would jump."""
    law = random_swing_law(weak_pendubot, seed=3)
    eps = 1e-7
    a = np.array([[math.pi - eps, 0.0, 0.3, 0.1]])
    b = np.array([[-math.pi + eps, 0.0, 0.3, 0.1]])
    np.testing.assert_allclose(law.law(a), law.law(b), atol=1e-5)
    F = swing_features(law.delta(a), law.angle_mask, law.scale)
    assert F.shape == (1, 2 * 2 + 2)


def test_the_swing_up_law_wraps_the_run_own_outer_law_and_round_trips_its_arrays(weak_pendubot):
    from tests.test_recovery import random_law

    system = weak_pendubot
    inner = random_law(system, inner_scale=0.2)
    law = random_swing_law(system, inner=inner)
    x = sample_domain(system, 500)
    u0 = np.zeros((len(x), system.m))
    np.testing.assert_array_equal(law.apply(x, u0), inner.apply(x, u0))  # inside the box's postures: the inner law alone
    back = SwingUpLaw.from_arrays(law.arrays(), inner)
    far = system.x_star + 3 * (sample_domain(system, 500, seed=2) - system.x_star)
    np.testing.assert_array_equal(back.apply(far, np.zeros((500, system.m))), law.apply(far, np.zeros((500, system.m))))
    broken = law.arrays() | {"W0": law.weights[0][:, :-1]}
    with pytest.raises(ValueError, match="do not fit"):
        SwingUpLaw.from_arrays(broken)


def test_fit_swing_law_reproduces_its_labels(weak_pendubot):
    """A least-squares fit on labels from a smooth law outside the box reproduces them to a small error."""
    system = weak_pendubot
    rng = np.random.default_rng(0)
    q = rng.uniform(-math.pi, math.pi, (3000, 2))
    x = system.state_from(q, rng.uniform(-2, 2, (3000, 2)))
    U = system.effort * np.tanh(np.sin(q[:, :1]) + 0.3 * np.cos(q[:, 1:]))
    law, mse = fit_swing_law(system, x, U, SwingUpConfig(steps=1500, width=32))
    assert mse < 0.01
    assert np.abs(law.law(x) - U).mean() < 0.15 * system.effort[0]


def test_resting_states_start_exactly_at_rest_then_spread():
    system = ip.load_system("pendubot")
    x = resting_states(system, 5, seed=1)
    q, v = system.split(x)
    np.testing.assert_allclose(wrap_angles(q[0] - np.array([math.pi, 0.0]), np.array([True, True])), 0.0, atol=1e-6)
    np.testing.assert_array_equal(v[0], 0.0)
    assert np.abs(q[1:] - q[0]).max() <= 0.1 and np.abs(v[1:]).max() <= 0.1 and np.abs(v[1:]).max() > 0
    np.testing.assert_array_equal(resting_states(system, 5, seed=1), x)


@pytest.fixture(scope="module")
def tiny_swing_run(tmp_path_factory):
    system = ip.load_system("pendubot", effort={"shoulder": 8.0})
    config = ip.TrainConfig.fast(epochs=5, width=8, depth=1, samples=64, dtype="float64")
    return ip.train(system, config, out=tmp_path_factory.mktemp("runs"), progress=False)


def test_a_stage_whose_short_plans_reach_nothing_leaves_the_run_as_it_was(tiny_swing_run, tmp_path):
    """Half-second plans cannot swing the pendubot up: the stage says so, records why, writes no law."""
    path = tmp_path / "run"
    shutil.copytree(tiny_swing_run.path, path)
    entry = swing_up(path, SwingUpConfig(**TINY), progress=False)
    assert not entry["used"] and "no plan" in entry["reason"]
    assert not (path / SWINGUP_FILE).exists() and not (path / SWINGUP_REFUSED_FILE).exists()
    run = ip.load_run(path)
    assert run.summary["swing_up"]["reason"] == entry["reason"] and not run.uses_swing_up


@pytest.fixture(scope="module")
def swung_run(tiny_swing_run, tmp_path_factory):
    """The tiny run through a tiny swing-up stage whose labels come from a smooth law outside the box
    (the plans that would give real ones take minutes): labels, fit, DAgger round, gate and files."""
    from idapbc_pin.recovery import swing_stage

    def labels(system, x0, seed, config, progress, teacher, store, step):
        rng = np.random.default_rng(seed)
        q = rng.uniform(-math.pi, math.pi, (400, system.nq))
        x = system.state_from(q, rng.uniform(-2, 2, (400, system.nq)))
        return x, system.effort * np.tanh(np.sin(q[:, :1])), 0, len(x0)

    path = tmp_path_factory.mktemp("swung") / "run"
    shutil.copytree(tiny_swing_run.path, path)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(swing_stage, "collect_labels", labels)
        mp.setattr(swing_stage, "GATE_HORIZON", 1.0)  # the box part of the gate: its counts, not their values, are checked here
        entry = swing_up(path, SwingUpConfig(**TINY, stop_when_lost=False), progress=False)  # a DAgger round whatever the first fit holds
    return ip.load_run(path), entry


def test_dagger_ends_before_labelling_where_the_first_fit_holds_none_of_its_starts(tiny_swing_run, tmp_path, monkeypatch):
    """`stop_when_lost`: a first fit that holds none of the first DAgger round's starts ends the
    rounds there; no plans run for them, and the gate judges that fit alone."""
    from idapbc_pin.recovery import swing_stage

    calls = []

    def labels(system, x0, seed, config, progress, teacher, store, step):  # labels no law can hold with: u = 0 everywhere
        calls.append(step)
        rng = np.random.default_rng(seed)
        q = rng.uniform(-math.pi, math.pi, (200, system.nq))
        return system.state_from(q, rng.uniform(-2, 2, (200, system.nq))), np.zeros((200, system.m)), 0, len(x0)

    path = tmp_path / "run"
    shutil.copytree(tiny_swing_run.path, path)
    monkeypatch.setattr(swing_stage, "collect_labels", labels)
    monkeypatch.setattr(swing_stage, "GATE_HORIZON", 1.0)
    entry = swing_up(path, SwingUpConfig(**(TINY | {"dagger": 2})), progress=False)
    assert calls == ["swing-labels"] and entry["dagger"] == [{"failed": TINY["dagger_starts"] + round(TINY["circle"] * TINY["dagger_starts"]), "stopped": True}]
    assert all(len(held) == 1 for held in entry["gate"]["candidates"].values()) and entry["fit"] == 0


def test_the_stage_writes_its_law_and_entry_and_the_run_applies_a_kept_one(swung_run, tmp_path):
    run, entry = swung_run
    name = SWINGUP_FILE if entry["used"] else SWINGUP_REFUSED_FILE
    assert (run.path / name).is_file() and not (run.path / (SWINGUP_REFUSED_FILE if entry["used"] else SWINGUP_FILE)).exists()
    summary = json.loads((run.path / "summary.json").read_text())
    gate = summary["swing_up"]["gate"]
    circle = round(TINY["circle"] * TINY["gate_states"])  # beside the near-resting states, states at rest from the circle
    assert summary["swing_up"]["law_file"] == name and gate["states"] == TINY["gate_states"] + circle and gate["near_resting"] == TINY["gate_states"]
    assert list(gate["candidates"]) == ["posture"] and all(len(h) == 1 + TINY["dagger"] for h in gate["candidates"].values())
    # the most held among the candidates that keep the box (all of them where none does)
    every = {(b, k): held for b, h in gate["candidates"].items() for k, held in enumerate(h)}
    keeping = {(b, k): held for (b, k), held in every.items() if gate["candidates_box"][b][k] >= gate["run_box"] - SwingUpConfig().box_loss}
    assert gate["law"] == gate["candidates"][gate["box"]][gate["fit"]] == max((keeping or every).values())
    assert gate["law_box"] == gate["candidates_box"][gate["box"]][gate["fit"]]
    assert not list((run.path / "recovery-chunks").glob("*")) if (run.path / "recovery-chunks").exists() else True
    # kept by hand: every command on the run applies it around the run's own outer law
    path = tmp_path / "run"
    shutil.copytree(run.path, path)
    (path / name).rename(path / SWINGUP_FILE)
    (path / "summary.json").write_text(json.dumps(summary | {"swing_up": summary["swing_up"] | {"used": True, "law_file": SWINGUP_FILE}}))
    kept = ip.load_run(path)
    assert kept.uses_swing_up and isinstance(kept.controller.fallback, SwingUpLaw)
    x = resting_states(kept.system, 3, seed=0)
    law = kept.controller.fallback
    np.testing.assert_allclose(kept.controller(x), kept.system.saturate(law.law(x)), atol=1e-12)  # hanging: the swing-up law
    box = kept.system.x_star + 0.2 * (sample_domain(kept.system, 200) - kept.system.x_star)  # within every candidate kept box
    inside = ~law.outside(box)
    assert inside.any()
    np.testing.assert_allclose(kept.controller(box[inside]), kept.box_controller(box[inside]), atol=1e-12)  # its kept box: the run's law


def test_a_damaged_swing_up_law_is_refused_at_load_in_one_line(swung_run, tmp_path):
    run, _ = swung_run
    path = tmp_path / "run"
    shutil.copytree(run.path, path)
    summary = json.loads((path / "summary.json").read_text())
    (path / "summary.json").write_text(json.dumps(summary | {"swing_up": {"used": True, "law_file": SWINGUP_FILE}}))
    (path / SWINGUP_FILE).write_bytes(b"not a zip")
    with pytest.raises(ip.IdapbcError, match="swingup.npz is damaged"):
        ip.load_run(path)


def test_the_standalone_export_applies_the_swing_up_law_as_the_library_does(swung_run, tmp_path):
    from tests.test_export import _close, _run_standalone

    from tests.test_recovery import random_law

    from idapbc_pin.run import RECOVERY_FILE

    run, _ = swung_run
    path = tmp_path / "run"
    shutil.copytree(run.path, path)
    law = random_swing_law(run.system, seed=5)
    np.savez(path / SWINGUP_FILE, **law.arrays())
    np.savez(path / RECOVERY_FILE, **random_law(run.system, inner_scale=0.3).arrays())  # the law it wraps: a recovery law
    summary = json.loads((path / "summary.json").read_text())
    (path / "summary.json").write_text(json.dumps(summary | {"swing_up": {"used": True, "law_file": SWINGUP_FILE}, "recovery": {"used": True}}))
    kept = ip.load_run(path)
    folder = ip.export(kept, tmp_path / "export", onnx=False)
    record = json.loads((folder / "controller.json").read_text())
    assert record["fallback"]["kind"] == "swing_up" and record["fallback"]["wraps"]["kind"] == "recovery"
    readme = (folder / "README.md").read_text()
    assert "swing-up law" in readme and "recovery law" in readme
    rng = np.random.default_rng(0)
    q = rng.uniform(-math.pi, math.pi, (400, 2))
    v = rng.uniform(-3, 3, (400, 2))
    q[:100] *= 0.2  # some inside the box's postures
    q[:50], v[:50] = 0.05 * q[:50], 0.05 * v[:50]  # some inside the recovery law's inner box
    expected = kept.controller.torque(q, v)
    out = _run_standalone(folder, q, v, tmp_path)
    _close(out["batched"], expected, 1e-9)
    _close(out["single"], expected, 1e-9)


def test_train_swing_up_runs_the_stage_after_training_and_records_it(tmp_path, capsys):
    """`train --swing-up` sets TrainConfig.swing_up, reads --swing-config and runs the stage after
    training (here plans too short to reach x*: the stage says so and the run keeps its law); with
    --evaluate 0 it judges nothing (`simulate --from hanging` judges a run from near hanging)."""
    from idapbc_pin.cli.main import main

    train_toml, swing_toml, out = tmp_path / "tiny.toml", tmp_path / "swing.toml", tmp_path / "runs"
    train_toml.write_text("[train]\nwidth = 8\ndepth = 1\n")
    swing_toml.write_text("[swing_up]\n" + "".join(f"{k} = {list(v) if isinstance(v, tuple) else v!r}\n" for k, v in TINY.items()).replace("'", '"'))
    argv = ["train", "pendubot", "--effort", "shoulder=8", "--fast", "--epochs", "2", "--config", str(train_toml), "--evaluate", "0",
            "--recover", "never", "--swing-up", "--swing-config", str(swing_toml), "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    (run_dir,) = out.iterdir()
    run = ip.load_run(run_dir)
    assert run.config.swing_up and "no plan" in run.summary["swing_up"]["reason"]
    text = capsys.readouterr().out
    assert "swing-up: no plan" in text and "| energy pump + LQR |" not in text and not (run_dir / "swingup.json").exists()


def test_a_bad_swing_config_is_one_line_and_exit_2(tmp_path, capsys):
    from idapbc_pin.cli.main import main

    bad = tmp_path / "swing.toml"
    bad.write_text("[swing_up]\nhorizon = -1.0\n")
    assert main(["train", "pendubot", "--swing-up", "--swing-config", str(bad), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad swing-up setting" in err[0] and "Fix:" in err[0]
    assert not any(tmp_path.glob("*/config.json"))


def test_simulate_from_hanging_prints_the_swing_up_table_and_writes_its_files(swung_run, capsys):
    from idapbc_pin.cli.main import main

    run, _ = swung_run
    assert main(["simulate", str(run.path), "--from", "hanging", "--n", "3", "--T", "2"]) == 0
    text = capsys.readouterr().out
    assert "swing-up of pendubot from 3 near-resting states" in text and "| NIDA-PBC |" in text and "| energy pump + LQR |" in text
    record = json.loads((run.path / "swingup.json").read_text())
    assert set(record["scores"]) == {"NIDA-PBC", "LQR", "energy pump + LQR"} and len(record["states"]) == 3 and record["T"] == 2.0
    assert (run.path / "swingup.png").stat().st_size > 10_000


def test_simulate_from_the_circle_judges_starts_at_rest_from_anywhere_into_their_own_file(swung_run, capsys):
    from idapbc_pin.cli.main import main

    run, _ = swung_run
    before = (run.path / "swingup.json").read_bytes() if (run.path / "swingup.json").exists() else None
    assert main(["simulate", str(run.path), "--from", "circle", "--n", "3", "--T", "2"]) == 0
    text = capsys.readouterr().out
    assert "swing-up of pendubot from 3 states at rest, every angle from the full circle" in text and "| NIDA-PBC |" in text
    record = json.loads((run.path / "swingup-circle.json").read_text())
    assert record["starts"] == "circle" and len(record["states"]) == 3
    assert np.abs(record["states"][1][2:]).max() == 0.0  # at rest: p = 0
    after = (run.path / "swingup.json").read_bytes() if (run.path / "swingup.json").exists() else None
    assert after == before  # the near-hanging evaluation's file is left as it was


def test_simulate_from_anywhere_judges_the_state_feedback_on_the_torus_and_in_the_uptime_test(swung_run, capsys, monkeypatch):
    """`simulate --from anywhere`: both tables with every reference, anywhere.json with moving starts
    and each episode's resets (the episode shortened here to 8 s with 2 resets)."""
    from idapbc_pin.cli.main import main
    from idapbc_pin.evaluation import anywhere

    monkeypatch.setattr(anywhere, "UPTIME_T", 8.0)
    monkeypatch.setattr(anywhere, "UPTIME_RESETS", 2)
    run, entry = swung_run
    library = entry["anywhere"]  # the stage's anywhere step: a library from the resting posture, 2 postures of the circle, 1 moving state and 1 release state
    assert library["starts"] == 5 and library["used"] == (run.summary["swing_up"].get("law") == "library")
    assert library["horizon"] == [0.5, 1.0] and len(library["by_horizon"]) == 2 and sum(library["by_horizon"]) == library["nominals"] <= 5
    assert not library["used"] or run.summary["swing_up"]["funnel"] is None  # a kept library acts wherever it is read
    assert main(["simulate", str(run.path), "--from", "anywhere", "--n", "3", "--T", "2", "--episodes", "2"]) == 0
    text = capsys.readouterr().out
    assert "from 3 states anywhere on the torus" in text and "uptime test: 2 episodes of 8 s, 2 resets" in text
    assert text.count("| energy pump + LQR |") == 2 and text.count("| NIDA-PBC |") == 2
    record = json.loads((run.path / "anywhere.json").read_text())
    assert record["torus"]["starts"] == "anywhere" and np.abs(record["torus"]["states"][1][2:]).max() > 0  # moving
    assert set(record["uptime"]["mean"]) == {"NIDA-PBC", "LQR", "energy pump + LQR"}
    assert np.shape(record["uptime"]["reset_times"]) == (2, 2) and all(0 <= u <= 1 for u in record["uptime"]["uptime"]["LQR"])
    assert record["uptime"]["reset"] == "drive" and "peak speed / rating" in text  # the leaderboard's reset by default
    assert set(record["uptime"]["time_over_rating"]) == {"NIDA-PBC", "LQR", "energy pump + LQR"}
    assert main(["simulate", str(run.path), "--from", "anywhere", "--no-limits"]) == 2


def test_simulate_from_moving_states_reports_the_catch_and_the_late_speed(swung_run, capsys):
    """`simulate --from moving`: states anywhere with speeds up to the ratings, the rows caught by
    5 s and the largest speed / rating after 0.5 s, into swingup-moving.json."""
    from idapbc_pin.cli.main import main

    run, _ = swung_run
    assert main(["simulate", str(run.path), "--from", "moving", "--n", "3", "--T", "2"]) == 0
    text = capsys.readouterr().out
    assert "from 3 moving states" in text and "at x* by 5 s" in text and "max speed / rating after 0.5 s" in text
    record = json.loads((run.path / "swingup-moving.json").read_text())
    assert record["starts"] == "moving" and np.abs(np.asarray(record["states"])[:, 2:]).min() > 0  # every row moving
    assert all(r is not None for r in record["scores"]["NIDA-PBC"]["late_speed_ratio"])


def test_simulate_counts_an_explicit_n_and_T_even_where_they_equal_the_box_s_defaults(swung_run, monkeypatch):
    """`simulate --from moving --n 100` judges 100 states (the box's default count, given): only an
    unset --n / --T falls back to the swing-up's 20 states over 10 s."""
    from idapbc_pin.cli.main import main
    from idapbc_pin.evaluation import swingup as swingup_module

    asked = []

    def judged(run, n, T, **kwargs):
        asked.append((n, T))
        raise ip.IdapbcError("judged")

    monkeypatch.setattr(swingup_module, "evaluate_run_swingup", judged)
    run, _ = swung_run
    for flags in (["--from", "moving", "--n", "100"], ["--from", "moving"], ["--from", "hanging", "--T", "20"]):
        assert main(["simulate", str(run.path), *flags]) == 2
    assert asked == [(100, 10.0), (20, 10.0), (20, 20.0)]


def test_the_figure_of_a_swing_up_run_ends_with_its_swing_up_from_hanging(swung_run):
    """figure.png's last row: q(t), u(t) and H(t) of the run's law, saturated LQR and the energy pump
    from the exact hanging start, the input within the effort limits drawn dashed."""
    from idapbc_pin.evaluation.swingup import evaluate_run_swingup
    from idapbc_pin.reporting.plot import plot
    from idapbc_pin.reporting.report import _figure_rows
    from idapbc_pin.reporting.swingup_figure import TITLE, draw_swingup

    run, _ = swung_run
    result = evaluate_run_swingup(run, n=1, T=1.0)
    rows = _figure_rows(run.controller, 0.0, None, 1, 1.0, None, 0, None, False, True)
    fig = plot(rows, swing=(TITLE.format(run.system.name), lambda axes: draw_swingup(axes, run, result)))
    swing_axes = fig.axes[-3:]
    assert len(fig.axes) == 5 * len(rows) + 3
    assert [ax.get_title() for ax in swing_axes] == ["swing-up a) wrap(q − q*)", "swing-up b) u(t)", "swing-up c) energy H(t)"]
    assert {line.get_label() for line in swing_axes[2].get_lines()} >= {"NIDA-PBC", "LQR", "energy pump + LQR", "H(x*)"}
    u = np.concatenate([line.get_ydata() for line in swing_axes[1].get_lines() if line.get_label() in ("NIDA-PBC", "LQR")])
    assert np.abs(u).max() <= run.system.effort[0] + 1e-9


def test_swing_up_starts_are_near_resting_then_at_rest_from_the_full_circle():
    """`swing_starts`: n near-resting states (the first exactly hanging), then round(circle·n) at rest
    from the circle, none of them a second exactly-hanging start; circle = 0 gives the first part alone."""
    from idapbc_pin.recovery.swing_stage import swing_starts
    from idapbc_pin.sim.states import resting_states

    system = ip.load_system("pendubot")
    x = swing_starts(system, 8, 0.5, seed=3)
    assert x.shape == (12, 4)
    np.testing.assert_array_equal(x[:8], resting_states(system, 8, 3))
    q, v = system.split(x[8:])
    assert (v == 0).all() and (np.abs(wrap_angles(q - system.x_star[:2], np.ones(2, bool))) > 0.2).any(axis=1).all()
    np.testing.assert_array_equal(swing_starts(system, 8, 0.0, seed=3), x[:8])


def test_the_stage_judges_tracking_laws_and_a_manoeuvre_from_its_nominals_and_a_kept_one_ships(tiny_swing_run, tmp_path, monkeypatch):
    """With a nominal plan from rest (here a short random one: real ones take a minute), the stage
    judges its tracking laws beside the fits in the gate and its manoeuvre against the run's law; a
    refused manoeuvre is written aside and never applied. Kept by hand, `simulate --from hanging`
    judges it in its own row, and the standalone export runs it as the library does."""
    from tests.test_export import MANOEUVRE_TIMES, _close, _run_standalone

    from idapbc_pin.evaluation.swingup import MANOEUVRE_ROW, evaluate_run_swingup
    from idapbc_pin.recovery import swing_stage
    from idapbc_pin.trajectory.ilqr import rollout
    from idapbc_pin.trajectory.manoeuvre import SwingManoeuvre
    from idapbc_pin.trajectory.tracks import KNOT, tvlqr_gains
    from idapbc_pin.run import MANOEUVRE_FILE, MANOEUVRE_REFUSED_FILE

    def labels(system, x0, seed, config, progress, teacher, store, step):
        rng = np.random.default_rng(seed)
        q = rng.uniform(-math.pi, math.pi, (200, system.nq))
        return system.state_from(q, rng.uniform(-2, 2, (200, system.nq))), system.effort * np.tanh(np.sin(q[:, :1])), 0, len(x0)

    def nominals(system, catch, config, count):
        rng = np.random.default_rng(0)
        U = rng.uniform(-1, 1, (25, system.m)) * system.effort / 2
        q0, v0 = system.split(resting_states(system, 1))
        Z = rollout(system, np.concatenate([q0, v0], axis=1), U[None], KNOT, 1)[0]
        return [(U, Z, tvlqr_gains(system, U, Z))]

    path = tmp_path / "run"
    shutil.copytree(tiny_swing_run.path, path)
    monkeypatch.setattr(swing_stage, "collect_labels", labels)
    monkeypatch.setattr(swing_stage, "nominals", nominals)
    monkeypatch.setattr(swing_stage, "GATE_HORIZON", 1.0)
    entry = swing_up(path, SwingUpConfig(**TINY, stop_when_lost=False), progress=False)
    fits = 1 + TINY["dagger"]
    assert entry["tracks"]["nominals"] == 1 and len(entry["tracks"]["held"]) == 3  # one nominal, three speed weights
    assert entry["gate"]["fitted"] == fits and all(len(held) == fits + 2 for held in entry["gate"]["candidates"].values())
    run = ip.load_run(path)
    judged = run.summary["swing_manoeuvre"]
    assert "anywhere" in run.summary["swing_up"]  # the anywhere step, after the manoeuvre, keeps its entry
    assert judged["states"] == TINY["gate_states"] and judged["horizons"] == [0.5, 0.25] and judged["choice"] == 0  # one nominal of each horizon
    own, run_score = judged["rest_score"]["manoeuvre"], judged["rest_score"]["run"]
    assert own is not None and run_score is not None and len(judged["picked_score"]) == 2  # a URDF robot: v2 scores from rest
    assert judged["used"] == (judged["held"] >= judged["run"] + SwingUpConfig().margin or (judged["held"] >= judged["run"] and own > run_score))
    if not judged["used"]:
        assert run.manoeuvre is None and (path / MANOEUVRE_REFUSED_FILE).is_file() and not (path / MANOEUVRE_FILE).exists()
        (path / MANOEUVRE_REFUSED_FILE).rename(path / MANOEUVRE_FILE)
        (path / "summary.json").write_text(json.dumps(run.summary | {"swing_manoeuvre": judged | {"used": True, "law_file": MANOEUVRE_FILE}}))
    kept = ip.load_run(path)
    manoeuvre = kept.manoeuvre
    assert isinstance(manoeuvre, SwingManoeuvre) and manoeuvre.duration == pytest.approx(25 * KNOT)
    result = evaluate_run_swingup(kept, n=2, T=1.0)
    assert list(result.scores)[:2] == ["NIDA-PBC", MANOEUVRE_ROW]
    from idapbc_pin.viewer.replay import _rollouts_to_show, _system_and_controller

    system, ctrl, shown = _system_and_controller(str(path))
    traj, note = _rollouts_to_show(system, ctrl, None, None, 2, "hanging", 0.2, None, 0, True, shown)  # `view RUN` replays the manoeuvre
    np.testing.assert_allclose(traj.u[:, 0], system.saturate(manoeuvre.inputs(resting_states(system, 2, 0), 0.0)), atol=1e-12)
    assert "manoeuvre" in note
    folder = ip.export(kept, tmp_path / "export", onnx=False)
    assert json.loads((folder / "controller.json").read_text())["manoeuvre"]["knot"] == KNOT
    assert "swing_up_torque" in (folder / "README.md").read_text()
    rng = np.random.default_rng(1)
    q, v = rng.uniform(-math.pi, math.pi, (50, 2)), rng.uniform(-3, 3, (50, 2))
    out = _run_standalone(folder, q, v, tmp_path)
    x = kept.system.state_from(q, v)
    for t, tau in zip(MANOEUVRE_TIMES, out["manoeuvre"]):
        u = manoeuvre.inputs(x, t) if t < manoeuvre.duration else kept.controller(x)
        _close(tau, kept.system.saturate(u) @ kept.system.B.T, 1e-9)


def test_on_a_tie_in_holds_the_gate_takes_a_fit_then_the_candidate_that_keeps_more_of_the_box(tiny_swing_run, monkeypatch):
    """The gate's choice among candidates that hold as many swing-up states, read from its judgements
    (stubbed here: the rule, not the simulations, is under test): a fit before a tracking law, then
    the one that brings more box states to x*; a candidate losing more than `box_loss` of the box is
    not eligible however much it holds."""
    from idapbc_pin.recovery import swing_stage

    system = tiny_swing_run.system
    laws = [random_swing_law(system, seed=s) for s in range(4)]  # two "fits", then two "tracking laws"

    def judged(held, boxed, times=(2.0, 2.0, 2.0, 2.0), run=(0, 5.0)):
        answers = [Judged(run[0], nan, nan, run[1]), *(Judged(h, nan, nan, t) for h, t in zip(held, times))]
        monkeypatch.setattr(swing_stage, "judge_starts", lambda system, laws, x0, config: answers)
        monkeypatch.setattr(swing_stage, "compare_laws", lambda system, jobs, **kw: [(np.arange(len(jobs[0][1])) < b, None) for b in [50, *boxed]])
        gate = swing_stage.swing_gate(tiny_swing_run, laws, SwingUpConfig(gate_states=4, box_states=100, workers=1), fitted=2)[1]
        return gate["fit"], gate["used"]

    assert judged([4, 4, 4, 4], [50, 50, 60, 60])[0] == 1  # a fit before a tracking law; the later fit
    assert judged([4, 4, 4, 4], [55, 50, 60, 60])[0] == 0  # among the fits, more box states
    assert judged([3, 3, 4, 4], [55, 50, 49, 70])[0] == 3  # more held wins; between the tracking laws, more box states
    assert judged([3, 3, 4, 2], [55, 50, 40, 70])[0] == 0  # a law that loses the box is not eligible
    # among those that hold the most, the fastest by more than time_margin (0.25 s) wins; within it, the old ties
    assert judged([4, 4, 4, 4], [50, 50, 60, 60], times=(2.0, 2.0, 1.0, 1.2))[0] == 3
    assert judged([4, 4, 4, 4], [50, 50, 60, 60], times=(1.2, 2.0, 1.0, 1.2))[0] == 0


def test_a_swing_up_law_that_holds_as_many_as_the_run_s_law_is_kept_only_where_it_is_sooner_at_x_star(tiny_swing_run, monkeypatch):
    """The verdict: `margin` more held, or as many and a median time to x* `time_margin` sooner;
    fewer held is never kept however fast, and a law that loses the box is never kept."""
    from idapbc_pin.recovery import swing_stage

    laws = [random_swing_law(tiny_swing_run.system, seed=0)]

    def used(run, law, boxed=50):
        answers = [Judged(run[0], nan, nan, run[1]), Judged(law[0], nan, nan, law[1])]
        monkeypatch.setattr(swing_stage, "judge_starts", lambda system, laws, x0, config: answers)
        monkeypatch.setattr(swing_stage, "compare_laws", lambda system, jobs, **kw: [(np.arange(len(jobs[0][1])) < b, None) for b in [50, boxed]])
        gate = swing_stage.swing_gate(tiny_swing_run, laws, SwingUpConfig(gate_states=4, box_states=100, workers=1, margin=2), fitted=1)[1]
        assert gate["run_time"] == (None if run[1] == inf else run[1]) and gate["law_time"] == (None if law[1] == inf else law[1])
        return gate["used"]

    assert used((20, 2.3), (20, 1.1))  # as many, 1.2 s sooner
    assert not used((20, 2.3), (20, 2.1))  # as many, within the margin
    assert not used((20, 2.3), (19, 0.5))  # fewer held
    assert used((17, inf), (19, inf))  # margin more held
    assert not used((20, 2.3), (20, 1.1), boxed=40)  # loses the box


def test_a_second_gate_reads_the_run_s_law_from_the_first_and_simulates_only_the_candidates(tiny_swing_run, monkeypatch):
    """`swing_gate(shared=...)`: the run's law is simulated by the first gate only (its verdicts do
    not depend on the candidates); a second gate over other kept boxes simulates the candidates alone
    and records the same figures for the run's law as a gate that simulates it again."""
    from idapbc_pin.recovery import swing_stage

    laws = [random_swing_law(tiny_swing_run.system, seed=0)]
    asked = []

    def judge(system, laws, x0, config):
        asked.append(len(laws))
        return [Judged(len(laws) + 2, nan, nan, 1.0 + k) for k in range(len(laws))]

    def compare(system, jobs, **kw):
        asked.append(len(jobs))
        return [(np.arange(len(jobs[0][1])) < 40 + 5 * k, None) for k in range(len(jobs))]

    monkeypatch.setattr(swing_stage, "judge_starts", judge)
    monkeypatch.setattr(swing_stage, "compare_laws", compare)
    config, shared = SwingUpConfig(gate_states=4, box_states=100, workers=1), {}
    first = swing_stage.swing_gate(tiny_swing_run, laws, config, fitted=1, shared=shared)[1]
    assert asked == [2, 2] and shared["run"] == (Judged(4, nan, nan, 1.0), 40)
    second = swing_stage.swing_gate(tiny_swing_run, laws, config, fitted=1, shared=shared)[1]
    assert asked == [2, 2, 1, 1]
    assert (second["run"], second["run_time"], second["run_box"]) == (first["run"], first["run_time"], first["run_box"]) == (4, 1.0, 40)
    assert second["law"] == 3 and second["law_box"] == 40  # the candidate now answers first


def test_the_anywhere_gate_keeps_a_library_by_its_own_rule_and_never_a_copy_of_the_law_it_replaces(tiny_swing_run, monkeypatch):
    """`anywhere_gate`: the run's law and the library judged on the same states; the verdict is the
    documented rule on the figures it returns. A "library" that is the run's own law again is not
    kept: its tip is up for the same share of the time, not `ANYWHERE_MARGIN` more."""
    from idapbc_pin.recovery import anywhere_stage
    from idapbc_pin.recovery.anywhere_stage import ANYWHERE_MARGIN, LIBRARY_LOSS, anywhere_gate
    from tests.test_swing_tracks import _plan

    monkeypatch.setattr(anywhere_stage, "GATE_HORIZON", 2.0)  # the box part: its counts enter the rule, not their values

    run = tiny_swing_run
    config = SwingUpConfig(gate_states=3, gate_moving=2, gate_released=1, box_states=4, judge_T=3.0, horizon=0.5, manoeuvre_horizons=(0.25,), library_longer=(), workers=1)
    U, Z, _ = _plan(run.system)
    library = tracking_law(run.system, U, Z, tvlqr_gains(run.system, U, Z), 0.1, kept_boxes(run.system, config)["posture"])
    gate = anywhere_gate(run, run.controller, library, config)
    assert gate["states"] == {"near": 3, "anywhere": 3, "box": 4} and len(gate["near"]) == len(gate["anywhere"]) == len(gate["box"]) == 2
    assert all(0.0 <= u <= 1.0 for u in gate["up"])
    rule = (gate["anywhere"][1] >= gate["anywhere"][0] - LIBRARY_LOSS and gate["up"][1] >= gate["up"][0] + ANYWHERE_MARGIN and gate["near"][1] >= gate["near"][0] - LIBRARY_LOSS
            and gate["box"][1] >= gate["box"][0] - config.box_loss)
    assert gate["used"] == rule
    same = anywhere_gate(run, run.box_controller, _NoLaw(), config)
    assert same["near"][0] == same["near"][1] and same["time"][0] == same["time"][1] and same["up"][0] == same["up"][1] and not same["used"]
    # two libraries on the same states: each judged as alone; the rule keeps the one with the larger share up
    both = anywhere_gate(run, run.box_controller, [_NoLaw(), library], config)
    assert [both[k][2] for k in ("near", "anywhere", "up", "box")] == [gate[k][1] for k in ("near", "anywhere", "up", "box")]
    passes = (both["anywhere"][2] >= both["anywhere"][0] - LIBRARY_LOSS and both["up"][2] >= both["up"][0] + ANYWHERE_MARGIN and both["near"][2] >= both["near"][0] - LIBRARY_LOSS
              and both["box"][2] >= both["box"][0] - config.box_loss)
    assert both["used"] == passes and both["library"] == (1 if passes or both["up"][2] > both["up"][1] else 0)


class _NoLaw:
    """An outer law that leaves the run's own outer law in charge (the library slot, filled with nothing new)."""

    def with_inner(self, inner):
        return inner


def test_the_anywhere_gate_counts_the_tip_up_over_the_first_seconds_as_the_uptime_test_does():
    """`_verdicts`' third figure: 1 for a state held at x*, 0 for a chain left hanging, and for a
    chain that falls from x* the share of the window before the tip drops below the uptime's line."""
    from idapbc_pin.model.resting import resting_configuration
    from idapbc_pin.recovery.anywhere_stage import UP_WINDOW, _verdicts
    from idapbc_pin.sim.leaderboard import tip_up

    system = ip.load_system("pendubot")
    zero = lambda x: np.zeros((len(np.atleast_2d(x)), system.m))  # noqa: E731
    q = np.stack([np.asarray(system.x_star)[:2], resting_configuration(system), [0.05, 0.0]])
    x0 = system.state_from(q, np.zeros_like(q))
    held, _, up = _verdicts((system, zero, x0, UP_WINDOW + 1.0))
    assert up[0] == 1.0 and up[1] == 0.0 and held[0] and not held[1]
    traj = __import__("idapbc_pin").simulate(system, zero, x0[2:], T=UP_WINDOW)
    assert 0.0 < up[2] < 1.0 and abs(up[2] - tip_up(system, traj.q[0]).mean()) <= 2.0 / len(traj.t)


def test_where_a_tracking_law_holds_every_start_the_stage_skips_labels_and_fits_unless_told_to_fit(tiny_swing_run, tmp_path, monkeypatch):
    """`always_fit`: by default, a tracking law that holds all of its near-resting starts leaves the
    gate to the tracking laws alone (no labels, no fit, no DAgger); with `always_fit` the labels are
    collected and the fits join the gate."""
    from idapbc_pin.recovery import swing_stage
    from tests.test_swing_tracks import _plan

    system = tiny_swing_run.system
    U, Z, G = _plan(system)
    law = tracking_law(system, U, Z, G, 0.1, kept_boxes(system, SwingUpConfig(**TINY))["posture"])
    labelled = []

    def labels(system, x0, seed, config, progress, teacher, store, step):
        labelled.append(step)
        rng = np.random.default_rng(seed)
        q = rng.uniform(-math.pi, math.pi, (100, system.nq))
        return system.state_from(q, np.zeros_like(q)), system.effort * np.tanh(np.sin(q[:, :1])), 0, len(x0)

    monkeypatch.setattr(swing_stage, "collect_labels", labels)
    monkeypatch.setattr(swing_stage, "nominals", lambda system, catch, config, count: [(U, Z, G)])
    monkeypatch.setattr(swing_stage, "tracking_laws", lambda system, teacher, plans, box, config, progress: ([law], {"nominals": 1, "held": [2], "states": 2}))
    monkeypatch.setattr(swing_stage, "GATE_HORIZON", 1.0)
    config = SwingUpConfig(**TINY | {"library": 0, "manoeuvre": False, "dagger": 0})
    for always, path in ((False, tmp_path / "skip"), (True, tmp_path / "fit")):
        shutil.copytree(tiny_swing_run.path, path)
        labelled.clear()
        entry = swing_up(path, config.replace(always_fit=always), progress=False)
        assert entry["fits_skipped"] is (not always) and bool(labelled) is always
        assert entry["gate"]["fitted"] == (1 if always else 0) and all(len(held) == entry["gate"]["fitted"] + 1 for held in entry["gate"]["candidates"].values())

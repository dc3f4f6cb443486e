"""The labelled paths read at the nearest point (`trajectory.library.paths_law`, `recovery.library_law`).

Claims:
* on a path's own states the library gives the path's own inputs, and next to them the path's
  input corrected by its time-varying LQR gain;
* the library law keeps the IDA-PBC law inside its inner box, acts within the limits outside it,
  and its arrays round-trip (a misshapen set is refused); a run's saved law is read back as what it is;
* the reach stage's labels are read as whole paths, every knot of each, thinned outside the smallest
  inner box for the exported controller; labels that are not whole paths make no library;
* `recover` judges the library beside the fits, and a run whose gate keeps it applies it.
(The exported controller.py applies it as the library does: tests/test_export.py.)
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.recovery import gate as recovery_gate
from idapbc_pin.recovery import stage as recovery_stage
from idapbc_pin.recovery.library_law import LibraryLaw, recovery_law_from_arrays
from idapbc_pin.recovery.stage import LABEL_PATH, RecoveryConfig, label_library, recover
from idapbc_pin.run import RECOVERY_FILE
from idapbc_pin.sim.states import uniform_states
from idapbc_pin.trajectory.ilqr import rollout
from idapbc_pin.trajectory.library import paths_law
from idapbc_pin.trajectory.tracks import KNOT

from .test_recovery import TINY, _as_compare, plan_once, random_law

#: The labelling steps here take their few starts in one chunk (`one_label_chunk`).
pytestmark = pytest.mark.usefixtures("one_label_chunk")


@pytest.fixture(scope="module")
def weak_pendubot():
    return ip.load_system("pendubot", effort={"shoulder": 8.0})


def _paths(system, P: int = 3, L: int = 40, seed: int = 0):
    """P paths of L states (x = (q, p)) every KNOT under random inputs held over each knot, from
    random box states: (X (P, L, n), U (P, L, m))."""
    rng = np.random.default_rng(seed)
    x0 = uniform_states(system, P, "half", seed)
    U = rng.uniform(-0.5, 0.5, (P, L, system.m)) * system.effort
    q, v = system.split(x0)
    Z = rollout(system, np.concatenate([q, v], axis=1), U[:, :-1], KNOT, 10)  # (P, L, n): each input held over its knot
    nq = system.nq
    X = np.stack([system.state_from(Z[i, :, :nq], Z[i, :, nq:]) for i in range(P)])
    return X, U


def test_on_a_path_s_own_states_the_library_gives_its_inputs_and_next_to_them_its_gain_s_correction(weak_pendubot):
    system = weak_pendubot
    X, U = _paths(system)
    law = paths_law(system, X, U, 0.3, np.full(system.n, np.inf))
    assert len(law.X) == X.shape[0] * (X.shape[1] - 1)  # every knot but each path's last state, which ends its plan
    pts, inputs = X[:, :-1].reshape(-1, system.n), U[:, :-1].reshape(-1, system.m)
    np.testing.assert_allclose(law.law(pts), np.clip(inputs, -system.effort, system.effort), atol=1e-12)
    k, d = law.nearest(pts + 1e-4)
    np.testing.assert_array_equal(k, np.arange(len(pts)))
    np.testing.assert_allclose(law.law(pts + 1e-4), np.clip(inputs + np.einsum("kij,kj->ki", law.K, d), -system.effort, system.effort), atol=1e-12)
    assert np.abs(law.K).max() > 0


def test_the_library_keeps_the_inner_box_acts_within_the_limits_outside_and_round_trips(weak_pendubot):
    system = weak_pendubot
    X, U = _paths(system, seed=1)
    lo, hi = system.domain
    law = LibraryLaw.from_tracks(paths_law(system, X, U, 0.3, np.full(system.n, np.inf)), (hi - lo) / 2).with_inner(0.3)
    x = uniform_states(system, 400, "domain", 2)
    u = np.full((len(x), system.m), 123.0)
    out = law.outside(x)
    assert 0 < out.mean() < 1
    applied = law.apply(x, u)
    assert np.all(applied[~out] == 123.0) and np.all(np.abs(applied[out]) <= system.effort + 1e-12)
    np.testing.assert_array_equal(applied[out], law.law(x[out]))
    again = recovery_law_from_arrays(law.arrays())
    assert isinstance(again, LibraryLaw) and not isinstance(recovery_law_from_arrays(random_law(system, 0.2).arrays()), LibraryLaw)
    np.testing.assert_array_equal(again.apply(x, u), applied)
    leveled = law.with_level(0.5)
    assert recovery_law_from_arrays(leveled.arrays()).level == 0.5
    with pytest.raises(ValueError, match="do not fit"):
        LibraryLaw.from_arrays(law.arrays() | {"K": law.K[:, :, :2]})
    with pytest.raises(ValueError, match="no 'weight'"):
        LibraryLaw.from_arrays({k: v for k, v in law.arrays().items() if k != "weight"})


def test_labels_are_read_as_whole_paths_every_knot_and_labels_that_are_not_make_no_library(weak_pendubot):
    system = weak_pendubot
    X, U = _paths(system, P=2, L=LABEL_PATH, seed=3)  # stand-ins with the labels' layout: LABEL_PATH samples per path
    law = label_library(system, X.reshape(-1, system.n), U.reshape(-1, system.m), 0.3)
    step = LABEL_PATH // (LABEL_PATH // 2)
    assert law.points == 2 * (LABEL_PATH // step - 1)
    np.testing.assert_allclose(law.X[: LABEL_PATH // step - 1], X[0, : LABEL_PATH - step : step], atol=1e-12)  # every other label: one per knot
    thin = label_library(system, X.reshape(-1, system.n), U.reshape(-1, system.m), 0.3, every=2, inner=0.25)  # for the export
    outside = (np.abs(law.delta(law.X)) > 0.25 * law.scale).any(axis=1)
    assert 0 < thin.points < law.points and thin.points == len(law.X[outside][::2])
    np.testing.assert_array_equal(thin.X, law.X[outside][::2])
    np.testing.assert_array_equal(thin.inner, 0.0)  # the gate chooses the inner box
    assert label_library(system, X.reshape(-1, system.n)[:-1], U.reshape(-1, system.m)[:-1], 0.3) is None


def test_recover_judges_the_library_beside_the_fits_and_a_run_that_keeps_it_applies_it(tmp_path, monkeypatch, capsys):
    system = ip.load_system("pendubot", effort={"shoulder": 8.0})
    run = ip.train(system, ip.TrainConfig.fast(epochs=5, width=8, depth=1, samples=64, dtype="float64"), out=tmp_path / "runs", progress=False)
    path = tmp_path / "run"
    shutil.copytree(run.path, path)
    judged = []

    def fake(job):  # the library brings every gate state to x*, a fit none beyond the run's law
        _, ctrl, x0 = job
        judged.append(type(ctrl.fallback).__name__)
        return np.full(len(x0), isinstance(ctrl.fallback, LibraryLaw))

    monkeypatch.setattr(recovery_gate, "compare_laws", _as_compare(fake))
    plan_once(monkeypatch)  # the five `recover`s below plan the same starts
    once = recovery_stage.collect_labels
    entry = recover(path, RecoveryConfig(**TINY | {"library": True}), progress=False)  # judged first, kept: no fit
    assert "LibraryLaw" in judged and "RecoveryLaw" not in judged and entry["fits_skipped"] and entry["first_fit_mse"] is None
    assert entry["used"] and entry["library"] and entry["fit_seed"] is None and entry["gate"]["library_points"] > 0
    judged.clear()
    entry = recover(path, RecoveryConfig(**TINY | {"library": True, "always_fit": True}), progress=False)
    assert "LibraryLaw" in judged and "RecoveryLaw" in judged and "fits_skipped" not in entry
    assert entry["used"] and entry["library"] and entry["fit_seed"] is None and entry["gate"]["library_points"] > 0
    line = recovery_gate.format_gate(entry["gate"], 3, 2)
    assert "the library of paths 4: the library" in line and "the 1 fits brought" in line
    loaded = ip.load_run(path)
    assert isinstance(loaded.controller.fallback, LibraryLaw) and (path / RECOVERY_FILE).is_file()
    assert json.loads((path / "summary.json").read_text())["recovery"]["library"] is True
    x = uniform_states(system, 50, "domain", 4)
    outside = loaded.controller.fallback.outside(x)
    np.testing.assert_allclose(loaded.controller(x)[outside], loaded.controller.fallback.law(x[outside]), atol=1e-12)
    library = loaded.controller.fallback
    margin = RecoveryConfig(**TINY).margin
    for best, level, verdict in ((83 - margin + 1, None, "fit"), (83 - margin, None, "lost"), (70, 83 - margin + 1, "fit")):
        refused = {"used": False, "run": 83, "states": 100, "candidates": {0.25: best, 0.5: 60}, "level_candidates": {0.1: level}}
        monkeypatch.setattr(recovery_gate, "choose_fit", lambda run, laws, config, progress, known=None, g=refused: (0, g))
        got, gate = recovery_gate.library_first(loaded, library, 4, RecoveryConfig(**TINY), progress=verdict == "lost")
        assert got == verdict and gate["library"]  # refused alone: the fits follow, unless it lags the run's law by the margin
    assert "no law is fitted to the same paths" in capsys.readouterr().out
    monkeypatch.setattr(recovery_gate, "choose_fit", lambda run, laws, config, progress, known=None: (0, {"used": True}))
    kept, gate = recovery_gate.library_first(loaded, library, 4, RecoveryConfig(**TINY))
    assert kept == "kept" and gate["library"] and gate["library_points"] == library.points
    monkeypatch.undo()
    monkeypatch.setattr(recovery_gate, "compare_laws", _as_compare(fake))
    monkeypatch.setattr(recovery_stage, "collect_labels", once)
    judged.clear()
    without = recover(path, RecoveryConfig(**TINY | {"library": False}), progress=False)  # the fits alone: none adds a state
    assert "LibraryLaw" not in judged and not without["used"] and not without["library"] and "library_points" not in without["gate"]
    assert not ip.load_run(path).uses_recovery

    def lagging(job):  # the run's law brings every gate state to x*, the library none: no fit is tried
        _, ctrl, x0 = job
        judged.append(type(ctrl.fallback).__name__)
        return np.full(len(x0), not isinstance(ctrl.fallback, LibraryLaw))

    monkeypatch.setattr(recovery_gate, "compare_laws", _as_compare(lagging))
    judged.clear()
    entry = recover(path, RecoveryConfig(**TINY | {"library": True}), progress=False)
    assert "LibraryLaw" in judged and "RecoveryLaw" not in judged and entry["library_lost"] and entry["fits_skipped"] and entry["first_fit_mse"] is None
    assert not entry["used"] and entry["library"] and not ip.load_run(path).uses_recovery
    judged.clear()
    entry = recover(path, RecoveryConfig(**TINY | {"library": True, "always_fit": True}), progress=False)  # always_fit: the fits all the same
    assert "RecoveryLaw" in judged and "library_lost" not in entry and not entry["used"]

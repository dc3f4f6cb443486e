"""A failure inside a stage after training never ends in a traceback nor touches the run's law.

One kind per test, injected into a worker's job rather than reached by a long run: a worker process
that raises (a singular solve, as iLQR's once did), a non-finite value a solver refuses, a stage that
finds no start reaching x* (it refuses, `train` goes on; a pilot of a quarter of the starts decides
that early), plans fewer than the gate's margin, and the same in the swing-up stage.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.errors import IdapbcError
from idapbc_pin.recovery import stage as stage_module
from idapbc_pin.recovery import swing_stage as swing_module
from idapbc_pin.recovery.config import PlanSettings, RecoveryConfig, SwingUpConfig
from idapbc_pin.recovery.stage import recover
from idapbc_pin.sim.states import uniform_states

SMALL = dict(starts=4, judge_T=8.0, dagger=0, plan=PlanSettings(horizon=0.5, ilqr_iterations=1))


@pytest.fixture()
def tiny_run(tmp_path):
    system = ip.load_system("pendubot", effort={"shoulder": 8.0})
    config = ip.TrainConfig.fast(epochs=3, width=8, depth=1, samples=32, dtype="float64", fallback="none")
    return ip.train(system, config, out=tmp_path, progress=False)


def _singular_chunk(job):
    """A labelling chunk whose plan solve meets a singular matrix (module level: it pickles to a worker)."""
    raise np.linalg.LinAlgError("Singular matrix")


def _unchanged(run, before: dict) -> None:
    """The run's summary and law files are as they were, and it loads with its own law."""
    assert json.loads((run.path / "summary.json").read_text()) == before
    assert not (run.path / "recovery.npz").exists() and not (run.path / "swingup.npz").exists()
    again = ip.load_run(run.path)
    assert not again.uses_recovery
    assert np.isfinite(again.controller(np.asarray(again.system.x_star)[None])).all()


@pytest.mark.parametrize("workers", [1, 2])
def test_a_worker_s_singular_matrix_is_one_line_and_the_run_stays_as_it_was(tiny_run, monkeypatch, workers):
    before = json.loads((tiny_run.path / "summary.json").read_text())
    monkeypatch.setattr(stage_module, "_label_chunk", _singular_chunk)
    with pytest.raises(IdapbcError) as excinfo:
        recover(tiny_run, RecoveryConfig(workers=workers, **SMALL), progress=False)
    message = str(excinfo.value)
    assert "\n" not in message and "LinAlgError: Singular matrix" in message
    assert "the recovery stage failed" in message and f"Fix: `idapbc-pin train --resume {tiny_run.path}`" in message
    _unchanged(tiny_run, before)


def test_a_non_finite_value_a_solver_refuses_is_one_line(tiny_run, monkeypatch):
    def nan_labels(*args, **kwargs):
        X = np.full((60, tiny_run.system.n), np.nan)
        return X, np.zeros((60, tiny_run.system.m)), 1, 0

    def refusing_fit(system, X, *args, **kwargs):
        if not np.isfinite(X).all():
            raise ValueError("Input contains NaN")
        raise AssertionError("the fit got finite labels")

    before = json.loads((tiny_run.path / "summary.json").read_text())
    monkeypatch.setattr(stage_module, "collect_labels", nan_labels)
    monkeypatch.setattr(stage_module, "fit_recovery_law", refusing_fit)
    monkeypatch.setattr(stage_module, "label_library", lambda *a, **k: None)
    with pytest.raises(IdapbcError, match=r"^the recovery stage failed \(ValueError: Input contains NaN\); the run keeps its law"):
        recover(tiny_run, RecoveryConfig(workers=1, **SMALL), progress=False)
    _unchanged(tiny_run, before)


def test_no_start_reaching_x_star_is_a_refusal_not_an_error(tiny_run, monkeypatch, capsys):
    empty = lambda *a, **k: (np.empty((0, tiny_run.system.n)), np.empty((0, tiny_run.system.m)), 0, 0)  # noqa: E731
    monkeypatch.setattr(stage_module, "collect_labels", empty)
    entry = recover(tiny_run, RecoveryConfig(workers=1, **SMALL), progress=True)
    assert entry["used"] is False and entry["refused"] is True and "no start state reached x*" in entry["reason"]
    assert "the run keeps its law as it is" in capsys.readouterr().out
    summary = json.loads((tiny_run.path / "summary.json").read_text())
    assert summary["recovery"] == entry and summary["status"] == "finished"
    assert not (tiny_run.path / "recovery.npz").exists() and not (tiny_run.path / "recovery-refused.npz").exists()
    assert not ip.load_run(tiny_run.path).uses_recovery


def _chunk_reaching(first_reaching: int, calls: list):
    """A labelling chunk (in this process) that reaches nothing before start `first_reaching`, and
    one path from each start after it; `calls` records the chunks planned."""

    def chunk(job):
        system, x0, first = job[0], job[1], job[2]
        calls.append(first)
        hits = [i for i in range(len(x0)) if first + i >= first_reaching]
        path = stage_module.LABEL_PATH
        X, U = np.zeros((path * len(hits), system.n)), np.zeros((path * len(hits), system.m))
        return X, U, 0, len(hits)

    return chunk


def test_labels_stop_after_a_pilot_whose_starts_reach_nothing(tiny_run, monkeypatch):
    system, config = tiny_run.system, RecoveryConfig(workers=1, **SMALL)
    x0 = uniform_states(system, 16, "domain", 0)  # 8 chunks of 2 starts
    for first_reaching, planned in ((4, [0, 2]), (3, [0, 2, 4, 6, 8, 10, 12, 14])):
        calls = []
        monkeypatch.setattr(stage_module, "_label_chunk", _chunk_reaching(first_reaching, calls))
        X, U, taught, recovered = stage_module.collect_labels(system, x0, 0, config, progress=False, pilot=stage_module.LABEL_PILOT)
        assert calls == planned
        assert recovered == (0 if planned == [0, 2] else 16 - first_reaching) and len(X) == recovered * stage_module.LABEL_PATH
    calls = []
    monkeypatch.setattr(stage_module, "_label_chunk", _chunk_reaching(4, calls))
    assert stage_module.collect_labels(system, x0, 0, config, progress=False)[3] == 12 and len(calls) == 8  # no pilot: every chunk
    assert stage_module.pilot_starts(16) == 4 and stage_module.pilot_starts(200) == 50 and stage_module.pilot_starts(2) == 2


def test_a_pilot_that_reaches_nothing_refuses_and_says_how_many_were_tried(tiny_run, monkeypatch):
    calls = []
    monkeypatch.setattr(stage_module, "_label_chunk", _chunk_reaching(10**6, calls))
    starts = stage_module.PILOT_MIN_STARTS
    entry = recover(tiny_run, RecoveryConfig(workers=1, **(SMALL | {"starts": starts})), progress=False)
    tried = stage_module.pilot_starts(starts)
    assert len(calls) == stage_module.LABEL_PILOT and entry["refused"] is True and entry["planned_starts"] == tried == starts // 4
    assert f"no start state reached x* (the first {tried} of {starts} were tried)" in entry["reason"]


def test_plans_fewer_than_the_gate_s_margin_refuse_and_keep_their_labels(tiny_run, monkeypatch):
    n, path = tiny_run.system.n, stage_module.LABEL_PATH
    config = RecoveryConfig(workers=1, **(SMALL | {"starts": stage_module.PILOT_MIN_STARTS}))
    few = lambda *a, **k: (np.zeros((path * 2, n)), np.zeros((path * 2, tiny_run.system.m)), 0, config.margin - 1)  # noqa: E731
    monkeypatch.setattr(stage_module, "collect_labels", few)
    monkeypatch.setattr(stage_module, "fit_recovery_law", lambda *a, **k: pytest.fail("fitted a law to fewer paths than the margin"))
    entry = recover(tiny_run, config, progress=False)
    assert entry["refused"] is True and entry["used"] is False and "states the gate asks of a recovery law (its margin): no law was fitted" in entry["reason"]
    assert (tiny_run.path / entry["labels_file"]).exists() and entry["labels"] == 2 * path
    assert not (tiny_run.path / "recovery.npz").exists() and not ip.load_run(tiny_run.path).uses_recovery

    class Fitted(Exception):
        pass

    def fitted(*args, **kwargs):
        raise Fitted

    monkeypatch.setattr(stage_module, "fit_recovery_law", fitted)
    with pytest.raises(IdapbcError, match=r"the recovery stage failed \(Fitted\)"):  # fewer starts than PILOT_MIN_STARTS say too little: it fits
        recover(tiny_run, RecoveryConfig(workers=1, **SMALL), progress=False)


def test_the_recover_command_says_the_stage_refused_and_exits_0(tiny_run, monkeypatch, cli):
    empty = lambda *a, **k: (np.empty((0, tiny_run.system.n)), np.empty((0, tiny_run.system.m)), 0, 0)  # noqa: E731
    monkeypatch.setattr(stage_module, "collect_labels", empty)
    out = cli("recover", tiny_run.path, "--workers", "1")
    assert out.returncode == 0, out.stderr
    assert "recovery stage refused: no start state reached x*" in out.stdout
    assert "Traceback" not in out.stdout + out.stderr


def test_the_recover_command_prints_a_worker_s_failure_as_one_error_line(tiny_run, monkeypatch, cli):
    monkeypatch.setattr(stage_module, "_label_chunk", _singular_chunk)
    out = cli("recover", tiny_run.path, "--workers", "1")
    assert out.returncode == 2
    errors = [line for line in out.stderr.splitlines() if line.startswith("error:")]  # the others: the progress bar
    assert len(errors) == 1 and errors[0].startswith("error: the recovery stage failed (LinAlgError: Singular matrix)") and "Fix:" in errors[0]
    assert "Traceback" not in out.stdout + out.stderr


def test_a_failure_inside_the_swing_up_stage_is_one_line(tiny_run, monkeypatch):
    def broken(*args, **kwargs):
        raise FloatingPointError("overflow in the energy of a nominal")

    before = json.loads((tiny_run.path / "summary.json").read_text())
    monkeypatch.setattr(swing_module, "_all_nominals", broken)
    monkeypatch.setattr(swing_module, "_label", broken)
    with pytest.raises(IdapbcError) as excinfo:
        swing_module.swing_up(tiny_run, SwingUpConfig(workers=1), progress=False)
    message = str(excinfo.value)
    assert "\n" not in message and message.startswith("the swing-up stage failed (FloatingPointError: overflow")
    assert "Fix:" in message
    _unchanged(tiny_run, before)

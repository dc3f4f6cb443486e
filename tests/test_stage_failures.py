"""A failure inside a stage after training never ends in a traceback nor touches the run's law.

One kind per test, injected into a worker's job rather than reached by a long run: a worker process
that raises (a singular solve, as iLQR's once did), a non-finite value a solver refuses, a stage that
finds no start reaching x* (it refuses, `train` goes on), and the same in the swing-up stage.
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

"""Expert settings reach the CLI through config files: `train --config` (TrainConfig fields),
`recover --config` and `train --recover-config` (RecoveryConfig fields, a [recovery] table); flags
given on the command line win over the file; a bad file is one error line and exit status 2."""

from __future__ import annotations

import subprocess
import sys
from types import SimpleNamespace

import pytest

import idapbc_pin as ip
from idapbc_pin.cli import recover as recover_cli
from idapbc_pin.cli.main import build_parser, main
from idapbc_pin.recovery.config import RecoveryConfig
from idapbc_pin.trajectory.plans import PlanSettings

RECOVERY_TOML = """[recovery]
starts = 12
teacher = "lqr"
margin = 5
form = "residual"
inner_scales = [0.25]
workers = 3

[recovery.plan]
population = 8
"""


def _cli(*args):
    """``idapbc-pin ARGS`` in a process of its own: its exit status and what it printed."""
    return subprocess.run([sys.executable, "-m", "idapbc_pin.cli", *map(str, args)], capture_output=True, text=True, timeout=120)


def _one_error_line(result, *fragments):
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr and result.stderr.startswith("error: ") and result.stderr.count("\n") == 1, result.stderr
    for fragment in fragments:
        assert fragment in result.stderr, result.stderr


@pytest.fixture
def asked(monkeypatch):
    """The RecoveryConfig each of `recover`, `regate` and `refit` is called with (nothing runs)."""
    calls = []

    def fake(name):
        def run(path, config, keep=False):
            calls.append((name, config, keep))
            return {"used": False, "seconds": 0.0, "regated": {"seconds": 0.0}, "refit": {"seconds": 0.0}}

        return run

    for name in ("recover", "regate", "refit"):
        monkeypatch.setattr(recover_cli, name, fake(name))
    return calls


def test_recover_reads_its_settings_from_the_recovery_table_and_workers_from_the_command_line(tmp_path, asked):
    path = tmp_path / "recovery.toml"
    path.write_text(RECOVERY_TOML)
    expected = RecoveryConfig(starts=12, teacher="lqr", margin=5, form="residual", inner_scales=(0.25,), workers=3,
                              plan=PlanSettings(population=8))  # fmt: skip
    assert main(["recover", str(tmp_path), "--config", str(path)]) == 0
    assert asked[-1] == ("recover", expected, False)
    assert main(["recover", str(tmp_path), "--config", str(path), "--workers", "1", "--regate", "--keep"]) == 0
    assert asked[-1] == ("regate", expected.replace(workers=1), True)  # --workers overrides the file's
    assert main(["recover", str(tmp_path), "--refit"]) == 0
    assert asked[-1] == ("refit", RecoveryConfig(), False)  # no file: the defaults


@pytest.mark.parametrize(
    "text, fragments",
    [
        ("[recovery]\nmargn = 5\n", ["margn", "margin"]),  # the unknown key, and the valid ones
        ('[recovery]\nmargin = "five"\n', ["'margin' must be int", "'five'"]),
        ("[recovery]\n[recovery.plan]\npopulaton = 8\n", ["populaton", "population"]),
        ('[recovery]\nteacher = "oracle"\n', ["teacher must be one of", "Fix:"]),
        ("[recovery\nmargin = 5\n", ["cannot parse", "Fix:"]),
    ],
    ids=["unknown key", "wrong type", "unknown plan key", "bad value", "bad syntax"],
)
def test_a_bad_recovery_config_is_one_line_and_exit_2(tmp_path, text, fragments, cli):
    path = tmp_path / "recovery.toml"
    path.write_text(text)
    _one_error_line(cli("recover", tmp_path / "no-run", "--config", path), *fragments)


def test_a_missing_recovery_config_is_one_line_and_exit_2(tmp_path):
    _one_error_line(_cli("recover", tmp_path, "--config", tmp_path / "nope.toml"), "not found", "Fix:")


@pytest.fixture
def trained(monkeypatch):
    """The TrainConfig `train` gets and the RecoveryConfig the recovery stage gets (nothing trains)."""
    seen = {}

    def fake_train(system, config, out=None, resume=None, workers=0):
        seen["config"], seen["workers"] = config, workers
        return SimpleNamespace(summary={"status": "finished"}, path=out, uses_recovery=False, system=SimpleNamespace(m=1), config=config)

    monkeypatch.setattr("idapbc_pin.training.train.train", fake_train)
    monkeypatch.setattr("idapbc_pin.training.summary.format_train_summary", lambda run: "trained")
    monkeypatch.setattr("idapbc_pin.recovery.trigger.auto_recover", lambda run, mode, config, lqr_success=None: seen.update(mode=mode, recovery=config))
    return seen


def test_train_takes_expert_keys_from_its_config_file_and_flags_win(tmp_path, trained):
    path = tmp_path / "train.toml"
    path.write_text('[train]\nwidth = 8\ndepth = 1\nform = "free"\nrollout_epochs = 2\nfallback = "linear"\nepochs = 50\nseed = 3\n')
    assert main(["train", "pendubot", "--fast", "--config", str(path), "--epochs", "7", "--evaluate", "0", "--recover", "never", "--out", str(tmp_path)]) == 0
    expected = ip.TrainConfig.fast(width=8, depth=1, form="free", rollout_epochs=2, fallback="linear", epochs=7, seed=3)
    assert trained["config"] == expected and "recovery" not in trained  # the file under --fast's preset, --epochs over both


def test_train_passes_the_recover_config_file_to_its_recovery_stage(tmp_path, trained, capsys):
    path = tmp_path / "recovery.toml"
    path.write_text(RECOVERY_TOML)
    argv = ["train", "pendubot", "--fast", "--evaluate", "0", "--recover", "always", "--recover-config", str(path), "--out", str(tmp_path)]
    assert main(argv) == 0
    assert trained["mode"] == "always" and trained["recovery"] == RecoveryConfig.from_file(path)
    assert main([*argv, "--workers", "2"]) == 0
    assert trained["recovery"].workers == 2 and trained["workers"] == 2
    trained.clear()
    assert main([*argv[:-6], "--out", str(tmp_path)]) == 0  # train's default: the stage where saturated LQR leaves room
    assert trained["mode"] == "auto" and trained["recovery"] == RecoveryConfig()
    trained.clear()
    capsys.readouterr()
    assert main([*argv[:-6], "--epochs", "5", "--out", str(tmp_path)]) == 0  # a smoke run: skipped, with one line
    assert "mode" not in trained
    assert "recovery stage skipped: a smoke run (5 < 200 epochs)" in capsys.readouterr().out
    assert main([*argv[:-6], "--recover", "never", "--out", str(tmp_path)]) == 0  # opted out: the command is printed instead
    assert "mode" not in trained
    assert f"idapbc-pin recover {tmp_path} --workers 0" in capsys.readouterr().out
    assert main([*argv[:-6], "--recover", "--out", str(tmp_path)]) == 0  # no file, no --workers: recover's defaults
    assert trained["mode"] == "always" and trained["recovery"] == RecoveryConfig()


def test_a_smoke_run_skips_the_roa_radii_with_one_line(tmp_path, trained, capsys, monkeypatch):
    """Fewer than SMOKE_EPOCHS epochs: the evaluation's two boxes without the radius searches; a full run has them."""
    asked = []
    lqr = SimpleNamespace(results={box: {"LQR": SimpleNamespace(success_rate=0.5)} for box in ("half", "domain")})
    monkeypatch.setattr("idapbc_pin.evaluation.evaluate.evaluate_run", lambda run, **kw: asked.append(kw["radius"]) or lqr)
    monkeypatch.setattr("idapbc_pin.evaluation.evaluate.format_evaluation", lambda evaluation: "tables")
    argv = ["train", "pendubot", "--fast", "--workers", "1", "--recover", "never", "--no-limits", "--out", str(tmp_path)]
    assert main([*argv, "--epochs", "5"]) == 0
    assert asked == [False] and "ROA radii skipped: a smoke run (5 < 200 epochs)" in capsys.readouterr().out
    assert main([*argv, "--epochs", "300"]) == 0
    assert asked == [False, True] and "ROA radii skipped" not in capsys.readouterr().out


def test_a_bad_train_config_key_is_one_line_and_exit_2(tmp_path, cli):
    path = tmp_path / "train.toml"
    path.write_text("[train]\nwidht = 8\n")
    _one_error_line(cli("train", "pendubot", "--config", path, "--out", tmp_path / "runs"), "widht")
    path.write_text('[train]\nwidth = "wide"\n')
    _one_error_line(cli("train", "pendubot", "--config", path, "--out", tmp_path / "runs"), "'width' must be int")
    bad = tmp_path / "recovery.toml"
    bad.write_text("[recovery]\nfits = 0\n")
    _one_error_line(_cli("train", "pendubot", "--fast", "--recover-config", bad, "--out", tmp_path / "runs"), "fits", "Fix:")
    assert not (tmp_path / "runs").exists()  # refused before training


def test_the_cli_stays_small_and_every_evaluation_default_is_the_library_s():
    """The flags' defaults are read from the library functions' signatures, as the pipeline's are."""
    from idapbc_pin.batch.pipeline import CERTIFY_DEFAULTS, EVALUATE_DEFAULTS, VIEW_DEFAULTS

    parser = build_parser()
    from idapbc_pin.cli.evaluate import simulate_sizes

    simulate = parser.parse_args(["simulate", "RUN"])
    assert (*simulate_sizes(simulate), simulate.seed, simulate.box, simulate.noise) == (100, 20.0, 0, "domain", 0.0)
    assert simulate_sizes(parser.parse_args(["simulate", "RUN", "--from", "moving"])) == (20, 10.0)  # the swing-up's starts
    assert simulate_sizes(parser.parse_args(["simulate", "RUN", "--from", "moving", "--n", "100"])) == (100, 10.0)
    report = parser.parse_args(["report", "RUN"])
    assert (report.n, report.T, report.seed) == (EVALUATE_DEFAULTS["n"], EVALUATE_DEFAULTS["T"], EVALUATE_DEFAULTS["seed"])
    certify = parser.parse_args(["certify", "RUN"])
    assert (certify.n, certify.settle) == (CERTIFY_DEFAULTS["n"], CERTIFY_DEFAULTS["settle"])
    view = parser.parse_args(["view", "RUN"])
    assert (view.n, view.T, view.pick) == (VIEW_DEFAULTS["n"], VIEW_DEFAULTS["T"], "auto")  # hanging for a swing-up run, else random
    robustness = parser.parse_args(["robustness", "RUN"])
    assert (robustness.box, robustness.n) == ("half", 100) and not hasattr(robustness, "noise")  # the conditions' own defaults apply


def test_the_recovery_hint_names_the_command_only_where_saturated_lqr_leaves_room():
    from idapbc_pin.recovery.trigger import ROOM_POINTS, recovery_hint

    run = SimpleNamespace(path="runs/x/1", system=SimpleNamespace(m=1))
    room = 1.0 - ROOM_POINTS / 100.0  # LQR's half-box success at which it fails from exactly ROOM_POINTS per cent
    assert "idapbc-pin recover runs/x/1 --workers 0" in recovery_hint(run, room)
    assert recovery_hint(run, room + 0.01) is None  # LQR holds the half box: nothing to suggest
    assert "idapbc-pin recover runs/x/1" in recovery_hint(run, None)  # not evaluated: the command, with its test
    assert recovery_hint(SimpleNamespace(path="r", system=SimpleNamespace(m=0)), 0.0) is None

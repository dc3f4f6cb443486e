"""A damaged run directory is refused, never half-read, and never made worse.

For every kind of damage a run directory meets in practice (a checkpoint cut off by a full disk or
a copy that stopped, overwritten with garbage, holding non-finite weights; a JSON file truncated,
hand-edited into something else; the URDF copy changed; the checkpoints folder gone) and every
command that reads a run (`train --resume`, `simulate`, `certify`, `report`, `view --html`,
`robustness`), the CLI exits with status 2 and exactly one line on stderr, ``error: … Fix: …``,
that names the damaged file, with no traceback and no warning; and the run directory is left byte
for byte as it was. The commands run in-process (`idapbc_pin.cli.main.main`), as the console
script runs them, on copies of one tiny trained run.
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import warnings
from pathlib import Path

import pytest
import torch

import idapbc_pin as ip
from idapbc_pin.cli.main import main


# ---------------------------------------------------------------------------------------- helpers
@pytest.fixture(scope="module")
def base_run(tmp_path_factory) -> Path:
    """One tiny finished run of the zoo cartpole (a URDF robot, so the run holds robot.urdf)."""
    out = tmp_path_factory.mktemp("base")
    config = ip.TrainConfig.fast(epochs=4, width=8, depth=1, samples=32)
    run = ip.train(ip.load_system("cartpole"), config, out=out, progress=False)
    assert {p.name for p in (run.path / "checkpoints").iterdir()} == {"best.pt", "last.pt"}
    return run.path


@pytest.fixture
def run_dir(base_run, tmp_path) -> Path:
    """A fresh copy of `base_run` for one test to damage."""
    return Path(shutil.copytree(base_run, tmp_path / "run"))


def cli(*argv) -> tuple[int, str, str, list[str]]:
    """(exit status, stdout, stderr, warnings raised) of ``idapbc-pin ARGV`` run in this process."""
    out, err = io.StringIO(), io.StringIO()
    with warnings.catch_warnings(record=True) as caught, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        warnings.simplefilter("always")
        try:
            status = main([str(a) for a in argv])
        except Exception as exc:  # what the console script would print as a traceback
            pytest.fail(f"idapbc-pin {' '.join(map(str, argv))} raised {type(exc).__name__}: {exc}")
    return status, out.getvalue(), err.getvalue(), [str(w.message) for w in caught]


def snapshot(directory: Path) -> dict[str, bytes | None]:
    """Every path under `directory` with its bytes (None for a folder)."""
    return {str(p.relative_to(directory)): (p.read_bytes() if p.is_file() else None) for p in sorted(directory.rglob("*"))}


# ---------------------------------------------------------------------------------------- damage
def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _garbage(path: Path) -> None:
    path.write_bytes(b"\x00\x13not a checkpoint\xff" * 64)


def _non_finite(path: Path) -> None:
    """Set one weight to NaN and save the checkpoint as torch would (a diverged training's weights)."""
    state = torch.load(path, weights_only=True)
    name = next(k for k, v in state["nets"].items() if v.is_floating_point() and v.numel())
    state["nets"][name].view(-1)[0] = float("nan")
    torch.save(state, path)


def _edit_json(path: Path, change) -> None:
    path.write_text(json.dumps(change(json.loads(path.read_text()))))


CKPT = Path("checkpoints")

#: damage name -> (how to do it to a run directory, a fragment the one error line must contain)
DAMAGE = {
    "best.pt truncated": (lambda d: _truncate(d / CKPT / "best.pt"), "best.pt is damaged"),
    "best.pt garbage": (lambda d: _garbage(d / CKPT / "best.pt"), "best.pt is damaged"),
    "best.pt empty": (lambda d: (d / CKPT / "best.pt").write_bytes(b""), "best.pt is damaged"),
    "best.pt non-finite weights": (lambda d: _non_finite(d / CKPT / "best.pt"), "best.pt is damaged (non-finite"),
    "best.pt not a checkpoint": (lambda d: torch.save([1, 2], d / CKPT / "best.pt"), "best.pt is damaged"),
    "last.pt truncated": (lambda d: _truncate(d / CKPT / "last.pt"), "last.pt is damaged"),
    "last.pt garbage": (lambda d: _garbage(d / CKPT / "last.pt"), "last.pt is damaged"),
    "last.pt non-finite weights": (lambda d: _non_finite(d / CKPT / "last.pt"), "last.pt is damaged (non-finite"),
    "both checkpoints damaged": (lambda d: (_truncate(d / CKPT / "best.pt"), _non_finite(d / CKPT / "last.pt")), "no intact checkpoint"),
    "checkpoints folder missing": (lambda d: shutil.rmtree(d / CKPT), "checkpoint"),
    "config.json truncated": (lambda d: _truncate(d / "config.json"), "config.json is damaged"),
    "config.json missing": (lambda d: (d / "config.json").unlink(), "config.json"),
    "config.json not an object": (lambda d: (d / "config.json").write_text("[1, 2]"), "config.json is damaged"),
    "config.json bad value": (lambda d: _edit_json(d / "config.json", lambda c: {**c, "lr": -1}), "config.json is damaged"),
    "config.json networks edited": (lambda d: _edit_json(d / "config.json", lambda c: {**c, "width": 16}), "does not fit the networks"),
    "system.json truncated": (lambda d: _truncate(d / "system.json"), "system.json is damaged"),
    "system.json missing": (lambda d: (d / "system.json").unlink(), "system.json"),
    "system.json entry missing": (lambda d: _edit_json(d / "system.json", lambda s: {k: v for k, v in s.items() if k != "actuated"}), "system.json is damaged"),
    "system.json unknown joint": (lambda d: _edit_json(d / "system.json", lambda s: {**s, "actuated": ["nope"]}), "system.json"),
    "robot.urdf edited": (lambda d: (d / "robot.urdf").write_text((d / "robot.urdf").read_text() + "<!-- -->"), "robot.urdf"),
    "robot.urdf missing": (lambda d: (d / "robot.urdf").unlink(), "robot.urdf"),
    "summary.json truncated": (lambda d: _truncate(d / "summary.json"), "summary.json is damaged"),
    "summary.json not an object": (lambda d: (d / "summary.json").write_text("[1]"), "summary.json is damaged"),
}

#: command name -> argv after ``idapbc-pin`` for a run directory and a scratch folder (small sizes:
#: a damaged run must be refused before any of the work starts, but a bug should not take minutes)
COMMANDS = {
    "train --resume": lambda run, tmp: ["train", "--resume", run, "--evaluate", "0", "--recover", "never"],
    "simulate": lambda run, tmp: ["simulate", run, "--n", "2", "--T", "0.1", "--no-radius"],
    "certify": lambda run, tmp: ["certify", run, "--n", "16", "--settle", "0"],
    "report": lambda run, tmp: ["report", run, "--n", "2", "--T", "0.1", "--no-radius"],
    "view --html": lambda run, tmp: ["view", run, "--html", tmp / "replay.html", "--n", "1", "--T", "0.1"],
    "robustness": lambda run, tmp: ["robustness", run, "--n", "2", "--T", "0.1"],
}

#: summary.json is written by training; a resume rewrites it (see the test below).
REWRITTEN_BY_RESUME = {"summary.json truncated", "summary.json not an object"}


def _cases():
    for damage in DAMAGE:
        for command in COMMANDS:
            if not (command == "train --resume" and damage in REWRITTEN_BY_RESUME):
                yield pytest.param(damage, command, id=f"{damage}-{command}")


# ---------------------------------------------------------------------------------------- tests
@pytest.mark.parametrize("damage, command", list(_cases()))
def test_a_damaged_run_gets_one_line_and_is_left_as_it_was(damage, command, run_dir, tmp_path):
    spoil, fragment = DAMAGE[damage]
    spoil(run_dir)
    before = snapshot(run_dir)
    status, _, err, caught = cli(*COMMANDS[command](run_dir, tmp_path))
    assert status == 2, err
    assert err.startswith("error: ") and err.count("\n") == 1, f"not exactly one error line:\n{err}"
    assert fragment in err and "Fix:" in err, err
    assert "Traceback" not in err and caught == []
    assert snapshot(run_dir) == before, "the failed command changed the run directory"
    assert not (tmp_path / "replay.html").exists()


def test_a_broken_summary_is_rewritten_by_the_resume_its_error_suggests(run_dir):
    _truncate(run_dir / "summary.json")
    status, _, err, _ = cli("simulate", run_dir, "--n", "2", "--T", "0.1", "--no-radius")
    assert status == 2 and "train --resume" in err
    status, _, err, _ = cli("train", "--resume", run_dir, "--evaluate", "0", "--recover", "never")
    assert status == 0, err
    assert json.loads((run_dir / "summary.json").read_text())["epochs_done"] == 4
    assert cli("simulate", run_dir, "--n", "2", "--T", "0.1", "--no-radius")[0] == 0


@pytest.mark.parametrize("damaged, intact", [("best", "last"), ("last", "best")])
def test_the_error_offers_the_intact_checkpoint_and_both_offers_work(damaged, intact, run_dir, tmp_path):
    """``--checkpoint <intact>`` animates the run (with one warning line about the other), and
    copying the intact checkpoint over the damaged one makes `train --resume` complete."""
    _garbage(run_dir / CKPT / f"{damaged}.pt")
    status, _, err, _ = cli("view", run_dir, "--html", tmp_path / "replay.html", "--n", "1", "--T", "0.1")
    assert status == 2
    assert f"use the intact {intact}.pt (--checkpoint {intact};" in err
    assert f"copy checkpoints/{intact}.pt over checkpoints/{damaged}.pt" in err

    status, out, err, _ = cli("view", run_dir, "--html", tmp_path / "replay.html", "--n", "1", "--T", "0.1", "--checkpoint", intact)
    assert status == 0, err
    assert err == f"warning: {run_dir / CKPT / (damaged + '.pt')} is damaged; using {intact}.pt as asked.\n"
    assert (tmp_path / "replay.html").stat().st_size > 10_000 and "wrote" in out

    shutil.copyfile(run_dir / CKPT / f"{intact}.pt", run_dir / CKPT / f"{damaged}.pt")
    status, _, err, _ = cli("train", "--resume", run_dir, "--epochs", "6", "--evaluate", "0", "--recover", "never")
    assert status == 0, err
    assert ip.load_run(run_dir, checkpoint="last").summary["epochs_done"] == 6


def test_view_checkpoint_is_refused_for_a_system_source(tmp_path):
    status, _, err, _ = cli("view", "cartpole", "--html", tmp_path / "r.html", "--checkpoint", "last")
    assert status == 2 and err.count("\n") == 1 and "--checkpoint applies to a run directory" in err


def test_a_folder_that_is_not_a_run_is_named_as_such(tmp_path):
    status, _, err, _ = cli("view", tmp_path, "--html", tmp_path / "r.html")
    assert status == 2 and "is not a run directory (no config.json)" in err


@pytest.mark.parametrize("lr", ["1", "10", "1e6"])
def test_a_diverging_learning_rate_ends_in_one_line_and_the_suggested_resume_completes(lr, tmp_path):
    """Training either finishes, or stops with one error line whose Fix is a resume command with a
    smaller learning rate; that command completes, and every reader accepts the run."""
    config, out = tmp_path / "tiny.toml", tmp_path / "runs"
    config.write_text("[train]\nwidth = 8\ndepth = 1\n")
    status, _, err, _ = cli("train", "cartpole", "--fast", "--epochs", "8", "--config", config,
                            "--lr", lr, "--out", out, "--evaluate", "0", "--recover", "never")
    (run_dir,) = out.iterdir()
    if status != 0:
        assert status == 2 and "Traceback" not in err
        last = err.strip().splitlines()[-1]  # the progress bar's lines come before it
        assert last.startswith("error: ") and "Fix: idapbc-pin train --resume" in last, err
        suggested = last.split("Fix: idapbc-pin ", 1)[1].split()
        status, _, err, _ = cli(*suggested, "--evaluate", "0", "--recover", "never")
        assert status == 0, err
    status, _, err, caught = cli("simulate", run_dir, "--n", "2", "--T", "0.5", "--no-radius")
    assert status == 0 and caught == [], err


def test_a_garbled_metrics_csv_never_ends_a_resume_in_a_traceback(run_dir):
    """metrics.csv is only appended to by training: a resume may rebuild it or refuse with one line."""
    (run_dir / "metrics.csv").write_bytes(b"\xff\xfe\x00garbled")
    before = snapshot(run_dir)
    status, _, err, _ = cli("train", "--resume", run_dir, "--epochs", "6", "--evaluate", "0", "--recover", "never")
    if status != 0:
        assert status == 2 and err.startswith("error: ") and err.count("\n") == 1 and "metrics.csv" in err, err
        assert snapshot(run_dir) == before

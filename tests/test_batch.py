"""Batch runs over pipeline files (issue 6): validation before anything runs, local workers, failing
jobs that do not stop the batch, resume after a kill, Ray giving the local executor's rows, and the
README zoo table kept in step with the committed summary.

The end-to-end runs use pipelines/smoke.toml (two robots, 15 epochs of width-16 networks, 8 ROA
states): their numbers say nothing about control quality, only that every stage ran.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from idapbc_pin.batch import (
    SUMMARY_COLUMNS,
    VOLATILE_COLUMNS,
    PipelineError,
    load_pipeline,
    read_summary,
    readme_zoo_block,
    replace_zoo_table,
    run_batch,
    zoo_table_markdown,
)
from idapbc_pin.batch.batch_dir import choose_batch_dir
from idapbc_pin.batch.job import _train_or_resume
from idapbc_pin.cli.batch import add_batch_command
from idapbc_pin.errors import IdapbcError

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "pipelines" / "smoke.toml"
SMOKE_DEFAULTS = SMOKE.read_text().split("[[job]]")[0]
#: Columns that may be empty in a complete row: the error of a job that is done, and a median
#: settling time where no state succeeded (checked against the success rate below).
MAY_BE_EMPTY = {"error"}


#: The smoke defaults with the stages after training cut to a second or so: for tests of the batch's
#: mechanics (resume, failure, reuse), not of the stages' results.
TINY_STAGES = ('evaluate = { n = 4, T = 1.0, seed = 0 }\ncertify = { n = 64, settle = 0, T = 1.0, invariant = 2 }\n'
               'figure = { n = 1, T = 0.5 }\nview = { n = 1, T = 0.5 }\n')


def _pipeline(tmp_path: Path, jobs: str, name: str = "p.toml", tiny: bool = False) -> Path:
    path = tmp_path / name
    defaults = SMOKE_DEFAULTS
    if tiny:
        keep = [line for line in defaults.splitlines(keepends=True) if not line.startswith(("evaluate", "certify", "figure", "view"))]
        defaults = "".join(keep).rstrip("\n") + "\n" + TINY_STAGES + "\n"
    path.write_text(defaults + jobs)
    return path


def _cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="idapbc-pin")
    add_batch_command(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def _stable(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k not in VOLATILE_COLUMNS} for row in rows]


def _optional_module(name: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(f"idapbc_pin.{name}") is not None


# ---------------------------------------------------------------------------------------- validation
def test_committed_pipelines_are_valid():
    from idapbc_pin.model.analytic import ANALYTIC
    from idapbc_pin.config import TrainConfig
    from idapbc_pin.model.zoo import zoo_names

    zoo = load_pipeline(ROOT / "pipelines" / "zoo.toml")
    assert sorted(job.source for job in zoo.jobs) == zoo_names()
    paper = load_pipeline(ROOT / "pipelines" / "paper.toml")
    assert sorted((job.source, job.preset) for job in paper.jobs) == sorted((nm, p) for nm in ANALYTIC for p in ("paper", "fast"))
    fast = TrainConfig.fast()
    for job in paper.jobs:  # the paper's Table I settings, or the fast preset on top of them
        assert (job.config["epochs"], job.config["samples"], job.config["width"], job.config["depth"]) == (
            (2000, 512, 300, 3) if job.preset == "paper" else (fast.epochs, fast.samples, fast.width, fast.depth)
        )
    smoke = load_pipeline(SMOKE)
    assert len(smoke.jobs) == 2
    weak = load_pipeline(ROOT / "pipelines" / "weak_actuators.toml")
    assert {job.name: job.effort for job in weak.jobs} == {"pendubot_8Nm": {"shoulder": 8.0}, "acrobot_5Nm": {"elbow": 5.0}}
    seeds = load_pipeline(ROOT / "pipelines" / "zoo_seeds.toml")
    paper_seeds = load_pipeline(ROOT / "pipelines" / "paper_seeds.toml")
    assert sorted((job.source, job.config["seed"], job.preset) for job in paper_seeds.jobs) == sorted(
        (nm, seed, "fast") for nm in ANALYTIC for seed in (0, 1, 2)
    )
    for pipeline in (weak, seeds, smoke):  # committed summaries of the IDA-PBC law alone; a smoke run never plans
        assert {job.recover for job in pipeline.jobs} == {"never"}, pipeline.path.name
    assert {job.recover for job in zoo.jobs} == {"auto"}  # the README's zoo table: train's default path


def test_smoke_flag_shrinks_every_job_and_changes_its_fingerprint(tmp_path):
    full = load_pipeline(ROOT / "pipelines" / "zoo.toml")  # recover = "auto": a recovery law where saturated LQR leaves room
    small = load_pipeline(ROOT / "pipelines" / "zoo.toml", smoke=True)
    for a, b in zip(full.jobs, small.jobs):
        assert b.config["epochs"] <= 20 and b.config["width"] <= 16 and b.evaluate["n"] <= 12
        assert a.recover == "auto" and b.recover == "never"  # a smoke run never spends minutes on plans
        assert a.fingerprint() != b.fingerprint()
    text = (ROOT / "pipelines" / "zoo.toml").read_text()
    never, unpinned = tmp_path / "never.toml", tmp_path / "unpinned.toml"  # without the line: a batch's default, "never"
    never.write_text(text.replace('recover = "auto"', 'recover = "never"'))
    unpinned.write_text(text.replace('recover = "auto"', ""))
    assert {job.recover for job in load_pipeline(unpinned).jobs} == {"never"}
    assert [j.fingerprint() for j in load_pipeline(unpinned).jobs] == [j.fingerprint() for j in load_pipeline(never).jobs]
    assert [j.fingerprint() for j in load_pipeline(never).jobs] != [j.fingerprint() for j in full.jobs]


BAD_JOBS = [
    ('name = "typo"\nsource = "acrobot"\nepochs = 5\n', "unknown key 'epochs'"),
    ('name = "joint"\nsource = "acrobot"\nactuated = ["knee"]\n', "unknown actuated joint 'knee'"),
    ('name = "where"\nsource = "no_such_robot"\n', "no_such_robot"),
    ('name = "missing"\nsource = "robots/gone.urdf"\n', "gone.urdf"),
    ('name = "kind"\nsource = "acrobot"\nactuated = "elbow"\n', "'actuated' must be an array"),
    ('name = "value"\nsource = "acrobot"\ntrain = { kappa = -1.0 }\n', "kappa"),
    ('name = "unknown"\nsource = "acrobot"\ntrain = { epoch = 3 }\n', "unknown training config key"),
    ('name = "preset"\nsource = "acrobot"\npreset = "quick"\n', "preset must be one of"),
    ('name = "box"\nsource = "acrobot"\ndomain = { elbow = [1.0] }\n', "domain.elbow must be [lo, hi]"),
    ('name = "target"\nsource = "acrobot"\ntarget = { elbow = 0.5 }\n', "not an assignable equilibrium"),
    ('name = "roa"\nsource = "acrobot"\nevaluate = { n = 0 }\n', "evaluate.n"),
    ('name = "lift"\nsource = "acrobot"\nevaluate = { limits = "no" }\n', "evaluate.limits must be true or false"),
    ('name = "draw"\nsource = "acrobot"\nevaluate = { seed = -3 }\n', "evaluate.seed must be ≥ 0, got -3"),
    ('name = "grid"\nsource = "acrobot"\nfigure = { slice = 1 }\n', "figure.slice (the basin slice's grid points per axis) must be ≥ 2, got 1"),
    ('name = "weights"\nsource = "acrobot"\ntrain = { seed = -3 }\n', "seed must be an integer ≥ 0, got -3"),
    ('name = "weak"\nsource = "pendubot"\neffort = { elbow = 8.0 }\n', "elbow"),
    ('name = "zero"\nsource = "pendubot"\neffort = { shoulder = 0.0 }\n', "must be > 0"),
    ('name = "text"\nsource = "pendubot"\neffort = { shoulder = "8" }\n', "effort.shoulder must be a number"),
    ('name = "plans"\nsource = "pendubot"\nrecover = "yes"\n', "recover must be one of"),
]


def test_a_job_may_set_the_figure_s_basin_slice_and_only_another_than_the_default_moves_its_fingerprint(tmp_path):
    jobs = "".join(f'[[job]]\nname = "{n}"\nsource = "pendubot"\n{extra}\n' for n, extra in (("a", ""), ("b", "figure = { slice = 13 }"), ("c", "figure = { slice = 5 }")))
    (tmp_path / "p.toml").write_text(jobs)  # no defaults: the smoke pipeline's set a slice of their own
    a, b, c = load_pipeline(tmp_path / "p.toml").jobs
    assert a.figure["slice"] == b.figure["slice"] == 13 and c.figure["slice"] == 5
    assert a.fingerprint() == b.fingerprint() != c.fingerprint()  # jobs written before the key keep their fingerprint


def test_a_job_may_lift_the_torque_limits_and_that_changes_its_fingerprint(tmp_path):
    path = _pipeline(tmp_path, '[[job]]\nname = "a"\nsource = "pendubot"\n\n[[job]]\nname = "b"\nsource = "pendubot"\nevaluate = { limits = false }\n')
    a, b = load_pipeline(path).jobs
    assert a.evaluate["limits"] is True and b.evaluate["limits"] is False
    assert a.fingerprint() != b.fingerprint()


def test_a_job_may_set_the_actuator_limits_and_they_reach_the_system_it_trains(tmp_path):
    from idapbc_pin.model import load_system

    path = _pipeline(tmp_path, '[[job]]\nname = "a"\nsource = "pendubot"\n\n[[job]]\nname = "b"\nsource = "pendubot"\neffort = { shoulder = 8 }\n')
    a, b = load_pipeline(path).jobs
    assert a.effort is None and b.effort == {"shoulder": 8.0}
    assert a.fingerprint() != b.fingerprint()
    urdf_limit = load_system(a.source_path, **a.system_arguments()).effort
    assert urdf_limit[0] != 8.0 and load_system(b.source_path, **b.system_arguments()).effort[0] == 8.0


@pytest.mark.parametrize("entry,message", BAD_JOBS, ids=[m.split()[0].strip("'") + str(i) for i, (_, m) in enumerate(BAD_JOBS)])
def test_a_bad_entry_is_refused_before_anything_runs_naming_the_job_and_its_line(tmp_path, entry, message):
    path = _pipeline(tmp_path, '[[job]]\nname = "good"\nsource = "furuta"\n\n# the bad one:\n[[job]]\n' + entry)
    bad_line = path.read_text().splitlines().index("# the bad one:") + 2
    out = tmp_path / "out"
    with pytest.raises(PipelineError) as err:
        run_batch(path, workers=1, out=out, progress=False)
    name = entry.split('"')[1]
    assert [(nm, line) for nm, line, _ in err.value.problems] == [(name, bad_line)]
    assert f"job '{name}' (line {bad_line})" in str(err.value) and message in str(err.value)
    assert not out.exists()  # nothing ran, nothing was written


def test_every_bad_entry_is_reported_at_once_and_duplicates_are_caught(tmp_path):
    path = _pipeline(tmp_path, '[[job]]\nname = "a"\nsource = "acrobot"\n\n[[job]]\nname = "a"\nsource = "furuta"\n\n[[job]]\nname = "b"\nsource = "x"\n')
    with pytest.raises(PipelineError) as err:
        load_pipeline(path)
    lines = [ln for ln, text in enumerate(path.read_text().splitlines(), 1) if text == "[[job]]"]
    assert [(nm, ln) for nm, ln, _ in err.value.problems] == [("a", lines[1]), ("b", lines[2])]
    assert "duplicate name" in err.value.problems[0][2]


def test_toml_syntax_errors_and_unknown_job_names_are_user_errors(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text('[[job]]\nname = "a"\nsource = acrobot\n')
    with pytest.raises(IdapbcError, match="line 3"):
        load_pipeline(path)
    with pytest.raises(IdapbcError, match="Valid job names: furuta, reaction_wheel"):
        run_batch(SMOKE, only=["nope"], out=tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_a_missing_urdf_names_the_pipeline_folder_that_relative_paths_start_from(tmp_path, monkeypatch):
    folder = tmp_path / "pipelines"
    folder.mkdir()
    path = _pipeline(folder, '[[job]]\nname = "gone"\nsource = "robots/gone.urdf"\n')
    monkeypatch.chdir(tmp_path)  # the working directory is not the pipeline's folder
    with pytest.raises(PipelineError) as err:
        load_pipeline(path)
    [(name, _, message)] = err.value.problems
    assert name == "gone"
    assert f"URDF file '{folder.resolve() / 'robots' / 'gone.urdf'}' not found" in message
    assert f"relative paths in a pipeline start from its folder, {folder.resolve()}, then from the working directory, {tmp_path.resolve()}" in message
    absolute = _pipeline(folder, f'[[job]]\nname = "abs"\nsource = "{tmp_path / "gone.urdf"}"\n', name="abs.toml")
    with pytest.raises(PipelineError) as err:
        load_pipeline(absolute)
    assert err.value.problems[0][2].endswith("not found. Fix: check the path")  # no hint about relative paths


def test_missing_ray_is_a_clear_error_before_anything_runs(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if not installed
    with pytest.raises(IdapbcError, match=r"Ray is not installed\. Fix: pip install 'idapbc-pin\[ray\]'"):
        run_batch(SMOKE, ray="auto", out=tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_two_batches_started_in_the_same_second_get_two_directories(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    pipeline = load_pipeline(SMOKE, smoke=True)
    first, second = choose_batch_dir(pipeline), choose_batch_dir(pipeline)
    assert first != second and first.is_dir() and second.is_dir()
    assert first.parent == second.parent == Path("runs")


def test_cli_arguments():
    parser = argparse.ArgumentParser(prog="idapbc-pin")
    add_batch_command(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["batch", "p.toml", "--workers", "3", "--ray", "auto", "--only", "a", "b", "--smoke", "--out", "d"])
    assert (args.pipeline, args.workers, args.ray, args.only, args.smoke, args.out) == ("p.toml", 3, "auto", ["a", "b"], True, "d")


# ---------------------------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def smoke_batch(tmp_path_factory):
    """The smoke pipeline on 2 local worker processes."""
    return run_batch(SMOKE, workers=2, out=tmp_path_factory.mktemp("smoke") / "batch", progress=False)


def test_smoke_pipeline_on_two_workers_gives_a_complete_summary(smoke_batch):
    result = smoke_batch
    assert result.ok and result.ran == ["furuta", "reaction_wheel"] and result.skipped == []
    rows = read_summary(result.summary_csv)
    assert rows == result.rows and [r["name"] for r in rows] == ["furuta", "reaction_wheel"]
    assert list(rows[0]) == list(SUMMARY_COLUMNS)
    for row in rows:
        assert row["status"] == "done"
        for ctrl in ("nida", "lqr"):
            for box in ("domain", "half"):
                assert 0.0 <= float(row[f"{ctrl}_success_{box}"]) <= 1.0
                # a median settling time exists exactly when some state succeeded
                assert (row[f"{ctrl}_settle_{box}"] != "") == (float(row[f"{ctrl}_success_{box}"]) > 0)
        settle = {c for c in row if c.endswith(tuple(f"settle_{b}" for b in ("domain", "half")))}
        empty = {c for c, v in row.items() if v == ""} - MAY_BE_EMPTY - settle
        if not _optional_module("certificate"):
            empty -= {"dissipation_fraction", "sublevel_coverage", "certified"}
        assert not empty, f"{row['name']}: empty columns {sorted(empty)}"
        assert row["les"] in ("yes", "no") and int(row["roa_n"]) == 8
    md = result.summary_md.read_text()
    assert "NIDA-PBC / LQR" in md and "furuta" in md and "reaction_wheel" in md
    for name, record in result.records.items():
        run_dir = result.path / name / record["run_dir"]
        assert record["status"] == "done" and record["error"] is None
        assert {"load", "train", "recover", "evaluate", "certify", "figure", "html", "total"} <= set(record["timings"])
        assert record["recovery"] is False  # --smoke: recover = "never"
        assert (run_dir / "evaluation.json").is_file() and (run_dir / "replay.html").is_file()
        assert (run_dir / "certificate.json").is_file() == _optional_module("certificate")
        assert (run_dir / "figure.png").is_file() == _optional_module("reporting")
        assert json.loads((result.path / name / "job.json").read_text())["row"]["status"] == "done"


#: Summaries zoo batches wrote (the README's tables are generated from them): the table tests read
#: them rather than wait for a batch of their own. The zoo through train's default path, and the law
#: alone (recover = "never", the seed table's seed 0).
ZOO_SUMMARY = ROOT / "pipelines" / "results" / "zoo-summary.csv"
ZOO_LAW_ALONE = ROOT / "pipelines" / "results" / "zoo-law-alone-summary.csv"


def test_zoo_table_renders_from_a_summary():
    table = zoo_table_markdown(ZOO_SUMMARY)
    assert table.startswith("| robot | actuated | success, domain: NIDA-PBC / LQR")
    assert "`furuta`" in table and "`reaction_wheel`" in table
    assert zoo_table_markdown(ZOO_SUMMARY) == table  # deterministic
    readme = "intro\n<!-- zoo-table:start -->\nold\n<!-- zoo-table:end -->\nrest\n"
    assert readme_zoo_block(replace_zoo_table(readme, table)) == table.strip()


def test_the_zoo_table_names_a_recovery_law_where_a_run_keeps_one(tmp_path):
    rows = read_summary(ZOO_LAW_ALONE)
    assert {r["recovery"] for r in rows} == {"no"}  # recover = "never"
    before = {r["name"]: r["fallback"] for r in rows}
    rows[0]["recovery"] = "yes"  # as a job whose recover stage kept a law would write it
    path = tmp_path / "summary.csv"
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=SUMMARY_COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    lines = {line.split(" | ")[0]: line for line in zoo_table_markdown(path).splitlines() if line.startswith("| `")}
    outside = {"yes": "linear law", "no": "networks"}
    assert "| recovery law |" in lines[f"| `{rows[0]['name']}`"]
    assert f"| {outside[before[rows[1]['name']]]}" in lines[f"| `{rows[1]['name']}`"]  # the cell may go on (an inside gain)


def test_a_job_failing_at_run_time_is_recorded_and_the_others_finish(tmp_path):
    # "broken" passes validation (a device is a property of the machine the job lands on) and fails
    # as soon as it trains, in its worker process
    path = _pipeline(tmp_path, '[[job]]\nname = "broken"\nsource = "reaction_wheel"\ntrain = { device = "cuda:99" }\n\n'
                               '[[job]]\nname = "reaction_wheel"\nsource = "reaction_wheel"\n', tiny=True)  # fmt: skip
    out = tmp_path / "out"
    assert _cli(["batch", str(path), "--workers", "2", "--out", str(out), "--no-progress"]) == 1
    rows = {r["name"]: r for r in read_summary(out / "summary.csv")}
    assert rows["reaction_wheel"]["status"] == "done" and rows["reaction_wheel"]["lqr_success_domain"] != ""
    assert rows["broken"]["status"] == "failed" and rows["broken"]["error"].startswith("train: ")
    assert "cuda" in rows["broken"]["error"]
    record = json.loads((out / "broken" / "job.json").read_text())
    assert record["stage"] == "train" and "Traceback" in record["traceback"]
    assert "broken" in (out / "summary.md").read_text().split("## Errors")[1]


@pytest.mark.slow
def test_a_killed_batch_resumes_with_only_the_remaining_jobs(tmp_path):
    pipeline = _pipeline(tmp_path, '[[job]]\nname = "furuta"\nsource = "furuta"\n\n[[job]]\nname = "reaction_wheel"\nsource = "reaction_wheel"\n', tiny=True)
    out = tmp_path / "batch"
    code = "import sys; from idapbc_pin.batch import run_batch; run_batch(sys.argv[1], workers=1, out=sys.argv[2], progress=False)"
    proc = subprocess.Popen([sys.executable, "-c", code, str(pipeline), str(out)], cwd=tmp_path, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    first = out / "furuta" / "job.json"
    try:
        deadline = time.monotonic() + 300
        while not first.is_file() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert first.is_file(), "the first job never finished"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the whole batch, mid-way through its second job
        proc.wait()
    assert not (out / "reaction_wheel" / "job.json").is_file()
    assert (out / ".lock").is_file()  # left behind by the killed process
    stamp = first.stat().st_mtime_ns

    result = run_batch(pipeline, workers=1, out=out, progress=False)
    assert result.skipped == ["furuta"] and result.ran == ["reaction_wheel"] and result.ok
    assert first.stat().st_mtime_ns == stamp  # not re-run
    assert "skipped furuta: done in a previous run" in (out / "batch.log").read_text()
    assert [r["status"] for r in read_summary(out / "summary.csv")] == ["done", "done"]
    # a third run has nothing left to do
    again = run_batch(pipeline, workers=1, out=out, progress=False)
    assert again.ran == [] and again.skipped == ["furuta", "reaction_wheel"]


def test_a_finished_job_run_again_reuses_its_run_on_a_robot_with_effort_limits(tmp_path):
    """The run's config.json holds its automatic values resolved (the fallback gain 3 of a robot with
    effort limits among them); a job run again must resolve them the same way, or it would delete the
    finished run and train from scratch."""
    pipeline = _pipeline(tmp_path, '[[job]]\nname = "wheel"\nsource = "reaction_wheel"\n', tiny=True)
    out = tmp_path / "batch"
    run_batch(pipeline, workers=1, out=out, progress=False)
    first = json.loads((out / "wheel" / "job.json").read_text())
    assert first["resumed"] is None and json.loads((out / "wheel" / first["run_dir"] / "config.json").read_text())["fallback_gain"] == 3.0
    (out / "wheel" / "job.json").unlink()  # as if the job had to be evaluated again
    again = run_batch(pipeline, workers=1, out=out, progress=False)
    assert again.ran == ["wheel"]
    record = json.loads((out / "wheel" / "job.json").read_text())
    assert record["resumed"] == "reused" and record["run_dir"] == first["run_dir"]
    assert [p.parent.name for p in (out / "wheel").glob("*/config.json")] == [first["run_dir"]]


def _alive(pid: int) -> bool:
    """Whether process `pid` exists and is not a zombie waiting to be reaped."""
    try:
        return "\nState:\tZ" not in Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="reads /proc")
def test_a_batch_driver_killed_on_its_own_takes_its_workers_with_it(tmp_path):
    """SIGKILL to the driver alone (no handler of its can run): its worker processes notice, interrupt
    their jobs as Ctrl-C would, record them as interrupted (a rerun resumes them) and exit, instead of
    training on into folders the next run of the batch uses."""
    long = 'train = { epochs = 100000, width = 16, depth = 1, samples = 64, dtype = "float64", checkpoint_every = 5, seed = 0, fallback = "none" }'
    pipeline = _pipeline(tmp_path, "".join(f'[[job]]\nname = "{n}"\nsource = "reaction_wheel"\n{long}\n' for n in ("a", "b")), tiny=True)
    out = tmp_path / "batch"
    code = "import sys; from idapbc_pin.batch import run_batch; run_batch(sys.argv[1], workers=2, out=sys.argv[2], progress=False)"
    driver = subprocess.Popen([sys.executable, "-c", code, str(pipeline), str(out)], cwd=tmp_path, start_new_session=True,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        deadline, pids = time.monotonic() + 120, {}
        while len(pids) < 2 and driver.poll() is None and time.monotonic() < deadline:
            for name in ("a", "b"):
                log = out / name / "job.log"
                if log.is_file() and "(pid " in log.read_text():
                    pids[name] = int(log.read_text().split("(pid ")[1].split(")")[0])
            time.sleep(0.2)
        assert len(pids) == 2 and driver.poll() is None, "the two jobs never started"
        while not all(list((out / n).glob("*/checkpoints/last.pt")) for n in pids) and time.monotonic() < deadline:
            time.sleep(0.2)  # both are training
        driver.kill()
        driver.wait()
        deadline = time.monotonic() + 60
        while any(_alive(pid) for pid in pids.values()) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not any(_alive(pid) for pid in pids.values()), "a worker outlived its driver"
        for name in pids:
            assert json.loads((out / name / "job.json").read_text())["status"] == "interrupted"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(driver.pid, signal.SIGKILL)


def test_a_job_killed_during_training_resumes_from_its_last_checkpoint(tmp_path):
    from idapbc_pin.model import load_system
    from idapbc_pin.training.train import train

    job = load_pipeline(SMOKE).jobs[1]
    config = job.train_config().replace(epochs=10, checkpoint_every=5)
    system = load_system(job.source_path)
    reference = train(system, config, out=tmp_path / "reference", progress=False)
    # what a kill at epoch 7 leaves: the 10-epoch config, a last checkpoint at epoch 5, no summary
    killed = train(system, config.replace(epochs=5), out=tmp_path / "job", progress=False)
    (killed.path / "config.json").write_text(json.dumps(config.to_dict()))
    (killed.path / "summary.json").unlink()
    run, how = _train_or_resume(system, config, tmp_path / "job")
    assert how == "resumed from epoch 5" and run.path == killed.path
    assert run.summary["final_terms"] == reference.summary["final_terms"]
    run, how = _train_or_resume(system, config, tmp_path / "job")  # finished: reused, not retrained
    assert how == "reused" and run.summary["final_terms"] == reference.summary["final_terms"]
    run, how = _train_or_resume(system, config.replace(seed=1), tmp_path / "job")  # other settings: fresh
    assert how is None and run.config.seed == 1
    assert [p.parent for p in (tmp_path / "job").glob("*/config.json")] == [run.path]  # the stale run is gone


def test_a_worker_that_cannot_see_the_batch_directory_ships_its_files_back(tmp_path):
    # a Ray node without the shared filesystem: the batch token is not there, so the job runs in a
    # temporary folder and returns it as an archive, which the driver unpacks into the job dir
    from idapbc_pin.batch import run_job
    from idapbc_pin.batch._shipping import unpack_dir as _unpack

    path = _pipeline(tmp_path, '[[job]]\nname = "far"\nsource = "furuta"\ntrain = { device = "cuda:99" }\n')
    job = load_pipeline(path).jobs[0]
    (tmp_path / "batch").mkdir()
    (tmp_path / "batch" / "batch.json").write_text(json.dumps({"token": "the driver's"}))
    record = run_job(job, tmp_path / "batch" / "far", batch_token="another batch's")
    assert not (tmp_path / "batch" / "far").exists() and record["status"] == "failed"
    _unpack(record.pop("_archive"), tmp_path / "batch" / "far")
    assert json.loads((tmp_path / "batch" / "far" / "job.json").read_text()) == json.loads(json.dumps(record))
    assert "cuda" in (tmp_path / "batch" / "far" / "job.log").read_text()


def test_a_batch_running_one_job_at_a_time_gives_its_recover_stage_every_core(tmp_path, monkeypatch):
    # the recovery law does not depend on its worker count (recovery.LABEL_CHUNKS), so a job that has
    # the machine to itself need not plan on one core; jobs run side by side keep one each
    from idapbc_pin.batch import job as job_module

    workers = []

    def recover_stage(run, mode, config):  # note the workers, and end the job there (the stages after it cost time)
        workers.append(config.workers)
        raise RuntimeError("recover stage reached")

    monkeypatch.setattr(job_module, "auto_recover", recover_stage)
    path = _pipeline(tmp_path, '[[job]]\nname = "wheel"\nsource = "reaction_wheel"\n')
    run_batch(path, workers=1, out=tmp_path / "b", progress=False)
    assert workers == [0]  # 0: one process per core
    record = job_module.run_job(load_pipeline(path).jobs[0], tmp_path / "alone")
    assert record["error"] == "recover: RuntimeError: recover stage reached" and workers == [0, 1]  # the default, as a pool worker runs it


@pytest.mark.slow
def test_ray_local_instance_gives_the_local_executors_rows(tmp_path):
    pytest.importorskip("ray", reason="Ray is an optional extra (pip install 'idapbc-pin[ray]'): not installed here")
    pipeline = _pipeline(tmp_path, '[[job]]\nname = "furuta"\nsource = "furuta"\n', tiny=True)  # the stages' results are not the claim
    result = run_batch(pipeline, ray="auto", workers=2, out=tmp_path / "ray", progress=False)
    assert result.ok and result.ran == ["furuta"]
    local = run_batch(pipeline, workers=1, out=tmp_path / "local", progress=False)
    furuta = [[row for row in read_summary(path) if row["name"] == "furuta"] for path in (result.summary_csv, local.summary_csv)]
    assert _stable(furuta[0]) == _stable(furuta[1]) and furuta[0][0]["status"] == "done"


# ---------------------------------------------------------------------------------------- README
def test_readme_zoo_table_matches_the_committed_zoo_summary():
    readme = (ROOT / "README.md").read_text()
    block = readme_zoo_block(readme)
    if block is None:
        pytest.skip("README.md has no <!-- zoo-table:start --> … <!-- zoo-table:end --> markers yet")
    summary = ROOT / "pipelines" / "results" / "zoo-summary.csv"
    if not summary.is_file():
        pytest.skip("pipelines/results/zoo-summary.csv is not committed yet (copy a zoo batch's summary.csv there)")
    assert block == zoo_table_markdown(summary).strip(), (
        "README's zoo table is out of step with pipelines/results/zoo-summary.csv. Fix: "
        "python -c \"from pathlib import Path; from idapbc_pin.batch import replace_zoo_table, zoo_table_markdown; "
        "p = Path('README.md'); p.write_text(replace_zoo_table(p.read_text(), zoo_table_markdown('pipelines/results/zoo-summary.csv')))\""
    )

"""One job of a batch: load → train (or resume) → recover → evaluate → certify → figure → HTML replay.

`run_job` is the function every executor runs (in this process, in a spawned worker process, as a
Ray task), so the same seeds give the same results everywhere. It never raises for a failing job:
the exception is recorded in ``job.json`` with the stage it happened in, and the batch goes on.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
import time
import traceback
from pathlib import Path

import torch

from .._io import write_json
from ..certificate.certify import certify
from ..errors import IdapbcError
from ..evaluation.evaluate import evaluate_run
from ..model import load_system
from ..recovery.stage import RecoveryConfig
from ..recovery.trigger import auto_recover
from ..reporting.report import figure
from ..run import load_run, read_checkpoint, read_config
from ..training.train import resolved_config, train
from ..viewer import view
from ._files import read_json_or_none, timestamp
from ._shipping import pack_dir, sees_batch_dir
from .pipeline import FIGURE_DEFAULTS, Job
from .record import new_record, summary_row

__all__ = ["run_job"]


class _JobInterrupted(KeyboardInterrupt):
    """Training was interrupted (Ctrl-C): the job is recorded as interrupted and the batch stops."""


def _same_config(run_dir: Path, config) -> bool:
    """Whether the run in `run_dir` was started with `config` (a damaged config.json: no)."""
    try:
        return read_config(run_dir) == config
    except IdapbcError:
        return False


def _train_or_resume(system, config, workdir: Path):
    """A finished run with this config is reused; one with a last checkpoint is resumed; else fresh.

    Runs other than the newest in `workdir` are deleted, and so is the newest when its config
    differs. Returns (run, how) with how None (fresh), "reused" or "resumed from epoch K".
    """
    runs = sorted(p.parent for p in workdir.glob("*/config.json"))
    for stale in runs[:-1]:
        shutil.rmtree(stale, ignore_errors=True)
    if runs:
        latest = runs[-1]
        same = _same_config(latest, config)
        summary = read_json_or_none(latest / "summary.json") or {}
        last = latest / "checkpoints" / "last.pt"
        if same and summary.get("status") == "finished" and summary.get("epochs_done") == config.epochs and last.is_file():
            return load_run(latest, checkpoint="last"), "reused"
        if same and last.is_file():
            epoch = int(read_checkpoint(latest, "last")["epoch"])
            return train(system, config, resume=latest, progress=False), f"resumed from epoch {epoch}"
        shutil.rmtree(latest, ignore_errors=True)
    return train(system, config, out=workdir, progress=False), None


def run_job(job: Job, job_dir: str | Path, batch_token: str | None = None, recover_workers: int = 1) -> dict:
    """Run one job into `job_dir` and return its record (also written to ``job_dir/job.json``).

    Stages: load → train (or resume) → recover (`recovery.trigger.auto_recover`) → evaluate
    (ROA of NIDA-PBC and LQR on the domain and half boxes) → certify → figure → html. Any exception stops the job and is recorded with its stage;
    it is never raised (Ctrl-C is: the job is recorded as interrupted first). Sets one torch thread
    (restored afterwards) so that N workers use N cores.

    `batch_token` is for executors whose workers may not see the batch directory (Ray clusters):
    when ``job_dir/../batch.json`` does not hold that token, the job runs in a temporary folder and
    the record carries it as ``_archive`` (tar.gz bytes) for the driver to unpack.

    `recover_workers` : processes of the recover stage (`RecoveryConfig.workers`; 0: one per core),
    1 where other jobs share the cores. The count changes the stage's time, never its law.
    """
    job_dir = Path(job_dir)
    shipped = not sees_batch_dir(job_dir, batch_token)
    workdir = Path(tempfile.mkdtemp(prefix="idapbc-batch-")) / job.name if shipped else job_dir
    workdir.mkdir(parents=True, exist_ok=True)
    record = new_record(job)
    threads = torch.get_num_threads()
    t_start, cpu_start = time.perf_counter(), time.process_time()
    run = evaluation = cert = None
    interrupted = False
    try:
        with open(workdir / "job.log", "a") as log, contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
            print(f"=== {job.name}: attempt started {record['started_at']} on {record['host']} (pid {record['pid']})", flush=True)
            try:
                run, evaluation, cert = _stages(job, workdir, record, recover_workers)
                record["status"] = "done"
            except KeyboardInterrupt:
                record["status"], interrupted = "interrupted", True
                record["error"] = f"{record['stage']}: interrupted"
            except Exception as exc:  # noqa: BLE001 (a failing job must not stop the batch)
                record["error"] = f"{record['stage']}: {type(exc).__name__}: {exc}"
                record["traceback"] = traceback.format_exc()
                print(record["traceback"], flush=True)
    finally:
        torch.set_num_threads(threads)
    record["timings"]["total"] = round(time.perf_counter() - t_start, 3)
    record["timings"]["cpu"] = round(time.process_time() - cpu_start, 3)  # CPU seconds of the job's process
    record["finished_at"] = timestamp()
    record["row"] = summary_row(job, record, run, evaluation, cert)
    write_json(workdir / "job.json", record)
    if shipped:
        record["_archive"] = pack_dir(workdir)
        shutil.rmtree(workdir.parent, ignore_errors=True)
    if interrupted:
        raise _JobInterrupted(job.name)
    return record


def _stages(job: Job, workdir: Path, record: dict, recover_workers: int = 1):
    """The job's stages, each timed into ``record["timings"]`` (s); returns (run, evaluation, certificate)."""
    timings = record["timings"]

    @contextlib.contextmanager
    def stage(name):
        record["stage"] = name
        t0 = time.perf_counter()
        yield
        timings[name] = round(time.perf_counter() - t0, 3)

    with stage("load"):
        system = load_system(job.source_path, **job.system_arguments())
        config = resolved_config(system, job.train_config())  # as train resolves it, so a rerun finds its run
        torch.set_num_threads(config.threads)
    with stage("train"):
        run, how = _train_or_resume(system, config, workdir)
        record["run_dir"], record["resumed"] = run.path.name, how
        if run.summary.get("status") == "interrupted":
            raise KeyboardInterrupt
        if run.summary.get("status") != "finished":
            raise IdapbcError(f"training ended with status {run.summary.get('status')!r}")
    with stage("recover"):  # where saturated LQR leaves room (as `train`); a reused run keeps the law it has
        if "recovery" not in run.summary:
            auto_recover(run, job.recover, RecoveryConfig(workers=recover_workers))
        record["recovery"] = bool(run.uses_recovery)
    ev = job.evaluate
    with stage("evaluate"):
        evaluation = evaluate_run(run, n=ev["n"], T=ev["T"], seed=ev["seed"], limits=ev["limits"]).record()
        record["files"]["evaluation"] = "evaluation.json"
    with stage("certify"):
        c = job.certify
        cert = certify(run, n=c["n"], seed=ev["seed"], settle=c["settle"], settle_T=c["T"], limits=ev["limits"],
                       invariant=c["invariant"], scale=c["scale"]).to_dict()
        if not (run.path / "certificate.json").is_file():
            write_json(run.path / "certificate.json", cert)
        record["files"]["certificate"] = "certificate.json"
    with stage("figure"):
        png = Path(figure(run, n=job.figure["n"], T=job.figure["T"], seed=ev["seed"], limits=ev["limits"], certificate=cert,
                          slice_n=job.figure.get("slice", FIGURE_DEFAULTS["slice"])))
        record["files"]["figure"] = str(png.relative_to(run.path)) if png.is_relative_to(run.path) else str(png)
    with stage("html"):
        viewer = view(run, n=job.view["n"], T=job.view["T"], seed=ev["seed"], pick="success", open_server=False, limits=ev["limits"])
        viewer.write_html(run.path / "replay.html")
        record["files"]["html"] = "replay.html"
        record["replay"] = viewer.note
    record["stage"] = None
    return run, evaluation, cert

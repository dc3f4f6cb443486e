"""Batch runs over a pipeline file: train, evaluate (ROA vs LQR), certify, draw and replay every job.

``idapbc-pin batch pipelines/zoo.toml [--workers N] [--ray auto|ADDRESS] [--only NAME ...] [--smoke] [--out DIR]``

Batch directory (``runs/batch-<stamp>/``, or ``--out DIR``)::

    batch.json       pipeline path and hash, smoke flag, one entry per invocation
    pipeline.toml    copy of the pipeline file          batch.log   the status lines, timestamped
    summary.csv      one row per job (`SUMMARY_COLUMNS`) summary.md  the same as Markdown tables
    <job>/job.json   status (done / failed / interrupted), error, timings, the summary row
    <job>/job.log    what the job printed
    <job>/<stamp>/   the run directory: config, checkpoints, metrics, summary.json, evaluation.json,
                     certificate.json, the figure, replay.html

Each job runs `run_job`: `load_system` → `train` → `evaluate_run` → `certify` → `report.figure` →
`view(pick="success")` → ``replay.html``. Any exception fails that job only (recorded with its stage, message and traceback);
the batch goes on. ``job.json`` is written atomically when a job ends, so a batch killed at any
moment resumes: re-running the same command (or ``--out``/``--resume`` the same directory) skips
the jobs whose ``job.json`` says done with the same settings, and re-runs the others. A job killed
during training resumes from its run's last checkpoint (`train(resume=...)`, which gives the result
of an uninterrupted run); one killed after training reuses the finished run.

Executors: in-process for one worker; a spawn `ProcessPoolExecutor` for N; Ray (optional extra) for
``--ray auto`` (a local Ray instance) or ``--ray ADDRESS`` (a cluster). Every worker runs one torch
thread (and one OpenMP/MKL thread), so N workers use N cores; the same job function runs everywhere,
so the same seeds give the same results.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import datetime as _dt
import importlib
import io
import json
import math
import os
import shutil
import socket
import sys
import tarfile
import tempfile
import time
import traceback
import uuid
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path

from .._io import atomic_write_bytes, write_json
from .pipeline import Job, Pipeline, PipelineError, load_pipeline
from ..errors import IdapbcError

__all__ = [
    "BatchResult",
    "Job",
    "Pipeline",
    "PipelineError",
    "SUMMARY_COLUMNS",
    "add_batch_command",
    "load_pipeline",
    "read_summary",
    "replace_zoo_table",
    "run_batch",
    "run_job",
    "write_summary",
    "zoo_table_markdown",
]

#: Environment of worker processes: one OpenMP / MKL / BLAS thread each (set before torch loads).
THREAD_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
#: README markers around the generated zoo table.
ZOO_TABLE_START, ZOO_TABLE_END = "<!-- zoo-table:start -->", "<!-- zoo-table:end -->"
_LOSS_TERMS = ("matching", "dissipation", "damping_floor", "local_stability", "decay")  # = loss.TERMS (no torch import here)

#: Columns of summary.csv. Success rates are fractions in [0, 1] of the ROA states (DESIGN §4);
#: settling times are medians over the successful states (s), empty when none succeeded;
#: dissipation_fraction, les, sublevel_coverage, certified come from `certify` (les falls back to
#: the trainer's eigenvalue check); loss_* are the final epoch's loss terms.
SUMMARY_COLUMNS = (
    "name", "system", "source", "actuated", "preset", "status",
    "nida_success_domain", "lqr_success_domain", "nida_success_half", "lqr_success_half",
    "nida_settle_domain", "lqr_settle_domain", "nida_settle_half", "lqr_settle_half",
    "roa_n", "roa_T",
    "dissipation_fraction", "les", "sublevel_coverage", "certified",
    "epochs", "train_seconds", *(f"loss_{t}" for t in _LOSS_TERMS),
    "job_seconds", "run_dir", "error",
)  # fmt: skip
#: Columns that depend on the machine (time, paths), not on the seeds.
VOLATILE_COLUMNS = ("train_seconds", "job_seconds", "run_dir")


# ====================================================================== small helpers
def _now() -> str:
    return _dt.datetime.now().isoformat(timespec="seconds")


_atomic_write_bytes = atomic_write_bytes


def _write_json(path: Path, obj) -> None:
    write_json(path, obj)


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _finite(v):
    if v is None:
        return None
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover (not Linux)
        return os.cpu_count() or 1


@contextlib.contextmanager
def _environ(values: dict):
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _optional(module: str, attr: str):
    """`idapbc_pin.<module>.<attr>`, or None while that module does not exist yet."""
    name = f"{__package__}.{module}"
    try:
        mod = importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name == name:
            return None
        raise
    return getattr(mod, attr, None)


# ====================================================================== one job
class _JobInterrupted(KeyboardInterrupt):
    """Training was interrupted (Ctrl-C): the job is recorded as interrupted and the batch stops."""


def _train_or_resume(system, config, workdir: Path):
    """A finished run with this config is reused; one with a last checkpoint is resumed; else fresh.

    Returns (run, how) with how None (fresh), "reused" or "resumed from epoch K".
    """
    from ..training.run import load_run
    from ..training.train import train

    runs = sorted(p.parent for p in workdir.glob("*/config.json"))
    for stale in runs[:-1]:
        shutil.rmtree(stale, ignore_errors=True)
    if runs:
        latest = runs[-1]
        same = _read_json(latest / "config.json") == config.to_dict()
        summary = _read_json(latest / "summary.json") or {}
        last = latest / "checkpoints" / "last.pt"
        if same and summary.get("status") == "finished" and summary.get("epochs_done") == config.epochs and last.is_file():
            return load_run(latest, checkpoint="last"), "reused"
        if same and last.is_file():
            import torch

            epoch = int(torch.load(last, map_location="cpu", weights_only=True)["epoch"])
            return train(system, config, resume=latest, progress=False), f"resumed from epoch {epoch}"
        shutil.rmtree(latest, ignore_errors=True)
    return train(system, config, out=workdir, progress=False), None


def _certificate_figures(cert: dict | None) -> dict:
    if not cert:
        return {}
    get = lambda *keys: _dig(cert, keys)  # noqa: E731
    max_real = get("local_stability", "max_real")
    return {
        "dissipation_fraction": get("dissipation_outside_E", "fraction_satisfied"),
        "les": None if max_real is None else bool(max_real < 0),
        "sublevel_coverage": get("sublevel", "covered_fraction"),
        "certified": cert.get("certified"),
    }


def _dig(d, keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _row(job: Job, record: dict, run=None, evaluation: dict | None = None, cert: dict | None = None) -> dict:
    """The job's summary row (raw values: floats, bools, None; formatted by `write_summary`)."""
    row = dict.fromkeys(SUMMARY_COLUMNS)
    row.update(name=job.name, system=job.system_name, source=job.source, actuated=" ".join(job.actuated_resolved), preset=job.preset, status=record["status"])
    if evaluation:
        for box in ("domain", "half"):
            for ctrl, key in (("NIDA-PBC", "nida"), ("LQR", "lqr")):
                score = evaluation.get(box, {}).get(ctrl, {})
                row[f"{key}_success_{box}"] = _finite(score.get("success_rate"))
                row[f"{key}_settle_{box}"] = _finite(score.get("median_settling_time"))
        row["roa_n"] = evaluation.get("domain", {}).get("n")
        row["roa_T"] = evaluation.get("domain", {}).get("T")
    if run is not None:
        s = run.summary
        row["epochs"] = s.get("epochs_done")
        row["train_seconds"] = _finite(s.get("train_seconds"))
        row["les"] = s.get("locally_exponentially_stable")
        for t in _LOSS_TERMS:
            row[f"loss_{t}"] = _finite(s.get("final_terms", {}).get(t))
        row["run_dir"] = f"{job.name}/{run.path.name}"
    for k, v in _certificate_figures(cert).items():
        if v is not None:
            row[k] = v
    row["job_seconds"] = record["timings"].get("total")
    row["error"] = record.get("error")
    return row


def _pack(directory: Path) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        tar.add(directory, arcname=".")
    return buf.getvalue()


def _unpack(data: bytes, directory: Path) -> None:
    directory.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        if hasattr(tarfile, "data_filter"):
            tar.extractall(directory, filter="data")
        else:  # pragma: no cover (Python < 3.10.12 / 3.11.4)
            tar.extractall(directory)


def _shares_batch_dir(job_dir: Path, token: str | None) -> bool:
    if token is None:
        return True
    meta = _read_json(job_dir.parent / "batch.json") or {}
    return meta.get("token") == token


def run_job(job: Job, job_dir: str | Path, batch_token: str | None = None) -> dict:
    """Run one job into `job_dir` and return its record (also written to ``job_dir/job.json``).

    Stages: load → train (or resume) → evaluate (ROA of NIDA-PBC and LQR on the domain and half
    boxes) → certify → figure → html. Any exception stops the job and is recorded with its stage;
    it is never raised (Ctrl-C is: the job is recorded as interrupted first). Sets one torch thread
    (restored afterwards) so that N workers use N cores.

    `batch_token` is for executors whose workers may not see the batch directory (Ray clusters):
    when ``job_dir/../batch.json`` does not hold that token, the job runs in a temporary folder and
    the record carries it as ``_archive`` (tar.gz bytes) for the driver to unpack.
    """
    import torch

    job_dir = Path(job_dir)
    shipped = not _shares_batch_dir(job_dir, batch_token)
    workdir = Path(tempfile.mkdtemp(prefix="idapbc-batch-")) / job.name if shipped else job_dir
    workdir.mkdir(parents=True, exist_ok=True)
    record = {
        "name": job.name,
        "status": "failed",
        "stage": None,
        "error": None,
        "traceback": None,
        "fingerprint": job.fingerprint(),
        "line": job.line,
        "timings": {},
        "run_dir": None,
        "resumed": None,
        "files": {},
        "started_at": _now(),
        "finished_at": None,
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "job": {"source": job.source, "actuated": job.actuated, "target": job.target, "domain": job.domain, "preset": job.preset,
                "train": job.train, "config": job.config, "evaluate": job.evaluate, "certify": job.certify, "figure": job.figure, "view": job.view, "smoke": job.smoke},
    }
    threads = torch.get_num_threads()
    t_start, cpu_start = time.perf_counter(), time.process_time()
    run = evaluation = cert = None
    interrupted = False
    try:
        with open(workdir / "job.log", "a") as log, contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
            print(f"=== {job.name}: attempt started {record['started_at']} on {record['host']} (pid {record['pid']})", flush=True)
            try:
                run, evaluation, cert = _stages(job, workdir, record)
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
    record["finished_at"] = _now()
    record["row"] = _row(job, record, run, evaluation, cert)
    _write_json(workdir / "job.json", record)
    if shipped:
        record["_archive"] = _pack(workdir)
        shutil.rmtree(workdir.parent, ignore_errors=True)
    if interrupted:
        raise _JobInterrupted(job.name)
    return record


def _stages(job: Job, workdir: Path, record: dict):
    import torch

    from ..evaluation.evaluate import evaluate_run
    from ..model.system import load_system
    from ..viewer.view import view

    timings = record["timings"]

    @contextlib.contextmanager
    def stage(name):
        record["stage"] = name
        t0 = time.perf_counter()
        yield
        timings[name] = round(time.perf_counter() - t0, 3)

    with stage("load"):
        system = load_system(job.source_path, actuated=job.actuated, target=job.target, domain=job.domain)
        config = job.train_config()
        torch.set_num_threads(config.threads)
    with stage("train"):
        run, how = _train_or_resume(system, config, workdir)
        record["run_dir"], record["resumed"] = run.path.name, how
        if run.summary.get("status") == "interrupted":
            raise KeyboardInterrupt
        if run.summary.get("status") != "finished":
            raise IdapbcError(f"training ended with status {run.summary.get('status')!r}")
    with stage("evaluate"):
        ev = job.evaluate
        evaluation = evaluate_run(run, n=ev["n"], T=ev["T"], seed=ev["seed"]).record()
        record["files"]["evaluation"] = "evaluation.json"
    cert = None
    with stage("certify"):
        certify = _optional("certify", "certify")
        if certify is not None:
            c = job.certify
            cert = certify(run, n=c["n"], seed=ev["seed"], settle=c["settle"], settle_T=c["T"]).to_dict()
            if not (run.path / "certificate.json").is_file():
                _write_json(run.path / "certificate.json", cert)
            record["files"]["certificate"] = "certificate.json"
    with stage("figure"):
        figure = _optional("report", "figure")
        if figure is not None:
            png = Path(figure(run, n=job.figure["n"], T=job.figure["T"], seed=ev["seed"]))
            record["files"]["figure"] = str(png.relative_to(run.path)) if png.is_relative_to(run.path) else str(png)
    with stage("html"):
        viewer = view(run, n=job.view["n"], T=job.view["T"], seed=ev["seed"], pick="success", open_server=False)
        viewer.write_html(run.path / "replay.html")
        record["files"]["html"] = "replay.html"
        record["replay"] = viewer.note
    record["stage"] = None
    return run, evaluation, cert


def _crash_record(job: Job, message: str) -> dict:
    """Record of a job whose worker died (killed, out of memory, segfault): written by the driver."""
    record = {"name": job.name, "status": "failed", "stage": "worker", "error": message, "traceback": None, "fingerprint": job.fingerprint(),
              "line": job.line, "timings": {}, "run_dir": None, "resumed": None, "files": {}, "started_at": None, "finished_at": _now()}
    record["row"] = _row(job, record)
    return record


# ====================================================================== executors
class _Tracker:
    """The one progress display: a tqdm bar over jobs, status lines above it, batch.log."""

    def __init__(self, batch_dir: Path, total: int, done: int, progress: bool, on_record):
        from tqdm.auto import tqdm

        self.log_path = batch_dir / "batch.log"
        self.bar = tqdm(total=total, initial=done, desc="batch", unit="job", disable=not progress, dynamic_ncols=True, file=sys.stderr)
        self.total, self.count, self.running = total, done, []
        self.on_record = on_record
        self._tqdm = tqdm

    def line(self, text: str) -> None:
        self._tqdm.write(text, file=sys.stdout)
        with open(self.log_path, "a") as fh:
            fh.write(f"{_now()} {text}\n")

    def started(self, job: Job) -> None:
        self.running.append(job.name)
        self.line(f"started {job.name}")
        self.bar.set_postfix_str("running: " + ", ".join(self.running), refresh=True)

    def finished(self, job: Job, record: dict) -> None:
        if job.name in self.running:
            self.running.remove(job.name)
        self.count += 1
        self.on_record(job, record)
        self.line(f"[{self.count}/{self.total}] {_status_line(record)}")
        self.bar.update(1)
        self.bar.set_postfix_str(("running: " + ", ".join(self.running)) if self.running else "", refresh=True)

    def close(self) -> None:
        self.bar.close()


def _pct(v) -> str:
    return "—" if v is None else f"{100 * v:.0f} %"


def _status_line(record: dict) -> str:
    row, t = record.get("row", {}), record.get("timings", {}).get("total")
    took = f" in {t:.0f} s" if t is not None else ""
    if record["status"] != "done":
        return f"{record['name']}: {record['status'].upper()}{took}: {record.get('error')}"
    resumed = f", training {record['resumed']}" if record.get("resumed") else ""
    les = {True: "yes", False: "NO", None: "?"}[row.get("les")]
    return (
        f"{record['name']}: done{took} (train {record['timings'].get('train', 0):.0f} s{resumed}); success NIDA-PBC / LQR: "
        f"domain {_pct(row.get('nida_success_domain'))} / {_pct(row.get('lqr_success_domain'))}, "
        f"half {_pct(row.get('nida_success_half'))} / {_pct(row.get('lqr_success_half'))}; LES {les}"
    )


def _run_in_process(jobs: list[Job], batch_dir: Path, tracker: _Tracker) -> None:
    for job in jobs:
        tracker.started(job)
        tracker.finished(job, run_job(job, batch_dir / job.name))


def _run_pool(jobs: list[Job], batch_dir: Path, tracker: _Tracker, workers: int) -> None:
    """Spawned worker processes, at most `workers` jobs in flight; a dead worker fails its jobs only."""
    import multiprocessing

    queue = list(jobs)
    ctx = multiprocessing.get_context("spawn")
    with _environ(THREAD_ENV):  # inherited by the spawned workers before they import torch
        while queue:
            pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx)
            inflight = {}
            broken = False
            try:
                while (queue and not broken) or inflight:
                    while queue and not broken and len(inflight) < workers:
                        job = queue.pop(0)
                        inflight[pool.submit(run_job, job, str(batch_dir / job.name))] = job
                        tracker.started(job)
                    done, _ = wait(inflight, return_when=FIRST_COMPLETED)
                    for fut in done:
                        job = inflight.pop(fut)
                        try:
                            record = fut.result()
                        except KeyboardInterrupt:
                            raise
                        except Exception as exc:  # BrokenProcessPool: the worker died
                            broken = True
                            record = _crash_record(job, f"worker process died ({type(exc).__name__}: {exc}); the job's files may be incomplete")
                            (batch_dir / job.name).mkdir(parents=True, exist_ok=True)
                            _write_json(batch_dir / job.name / "job.json", record)
                        tracker.finished(job, record)
            finally:
                pool.shutdown(wait=True, cancel_futures=True)


def _import_ray():
    try:
        import ray
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.split(".")[0] == "ray":
            raise IdapbcError("Ray is not installed. Fix: pip install 'idapbc-pin[ray]'") from None
        raise
    return ray


def _run_ray(jobs: list[Job], batch_dir: Path, tracker: _Tracker, address: str, workers: int | None, token: str) -> None:
    """Ray tasks (num_cpus=1 each) running the same `run_job`; results that a remote node wrote
    into its own temporary folder come back as an archive and are unpacked here."""
    ray = _import_ray()
    started_here = not ray.is_initialized()
    if started_here:
        try:
            if address == "auto" and not os.environ.get("RAY_ADDRESS"):
                ray.init(address="local", num_cpus=workers or _cpu_count(), include_dashboard=False, log_to_driver=False)
            else:  # a cluster: the given address, or $RAY_ADDRESS (set by `ray job submit`) for "auto"
                ray.init(address=None if address == "auto" else address, log_to_driver=False)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise IdapbcError(
                f"cannot start or join Ray at '{address}': {first}. Fix: check the address with `ray status` on the head node "
                "(HOST:6379 from a node, ray://HOST:10001 from outside); a cluster with token authentication (the default of recent "
                "`ray start`) also needs RAY_AUTH_MODE=token and its token on this machine."
            ) from None
    try:
        limit = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        remote = ray.remote(num_cpus=1, max_retries=0)(run_job)
        queue, inflight = list(jobs), {}
        try:
            while queue or inflight:
                while queue and len(inflight) < limit:
                    job = queue.pop(0)
                    inflight[remote.remote(job, str(batch_dir / job.name), token)] = job
                    tracker.started(job)
                ready, _ = ray.wait(list(inflight), num_returns=1)
                for ref in ready:
                    job = inflight.pop(ref)
                    try:
                        record = ray.get(ref)
                    except Exception as exc:  # the worker died, or the task raised past run_job
                        record = _crash_record(job, f"Ray task failed ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})")
                        (batch_dir / job.name).mkdir(parents=True, exist_ok=True)
                        _write_json(batch_dir / job.name / "job.json", record)
                    archive = record.pop("_archive", None)
                    if archive is not None:
                        shutil.rmtree(batch_dir / job.name, ignore_errors=True)
                        _unpack(archive, batch_dir / job.name)
                    tracker.finished(job, record)
        except KeyboardInterrupt:
            for ref in inflight:
                ray.cancel(ref, force=True)
            raise
    finally:
        if started_here:
            ray.shutdown()


# ====================================================================== the batch
@dataclass
class BatchResult:
    """What `run_batch` did.

    Attributes
    ----------
    path : the batch directory.  pipeline : the pipeline file.
    records : {job name: job.json content} for the jobs selected this time (ran or skipped).
    ran, skipped, failed : job names, in pipeline order (failed ⊂ ran).
    summary_csv, summary_md : the summary files (every job of the pipeline; not-yet-run ones "pending").
    rows : the summary rows as written to summary.csv (strings).
    wall_seconds : wall time of this invocation.
    """

    path: Path
    pipeline: Path
    records: dict
    ran: list
    skipped: list
    failed: list
    summary_csv: Path
    summary_md: Path
    rows: list = field(default_factory=list)
    wall_seconds: float = 0.0

    @property
    def ok(self) -> bool:
        """No selected job failed."""
        return not self.failed


def _batch_dir(pipeline: Pipeline, out, resume) -> Path:
    if resume is not None:
        path = Path(resume)
        if not (path / "batch.json").is_file():
            raise IdapbcError(f"'{path}' is not a batch directory (no batch.json). Fix: pass a directory made by `idapbc-pin batch`.")
        return path
    if out is not None:
        path = Path(out)
        if path.exists() and any(path.iterdir()) and not (path / "batch.json").is_file():
            raise IdapbcError(f"'{path}' exists and is not a batch directory (no batch.json). Fix: pass a new directory, or a batch directory to resume.")
        return path
    parent = Path("runs")
    latest = None
    for meta_path in sorted(parent.glob("batch-*/batch.json")):
        meta = _read_json(meta_path) or {}
        if meta.get("pipeline") == str(pipeline.path) and bool(meta.get("smoke")) == pipeline.smoke and not meta.get("complete"):
            latest = meta_path.parent
    if latest is not None:
        return latest
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    path, k = parent / f"batch-{stamp}", 1
    while path.exists():
        path, k = parent / f"batch-{stamp}-{k}", k + 1
    return path


@contextlib.contextmanager
def _lock(batch_dir: Path):
    lock = batch_dir / ".lock"
    me = f"{socket.gethostname()} {os.getpid()}"
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            break
        except FileExistsError:
            host, _, pid = lock.read_text().partition(" ")
            alive = host == socket.gethostname() and pid.isdigit() and _pid_alive(int(pid))
            if alive:
                raise IdapbcError(f"another batch is running in '{batch_dir}' (pid {pid}). Fix: wait for it, or pass another --out DIR.") from None
            lock.unlink(missing_ok=True)  # stale: its process is gone
    else:  # pragma: no cover
        raise IdapbcError(f"cannot lock '{batch_dir}'. Fix: remove {lock}.")
    with os.fdopen(fd, "w") as fh:
        fh.write(me)
    try:
        yield
    finally:
        lock.unlink(missing_ok=True)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def run_batch(
    pipeline_path,
    workers: int | None = None,
    ray: str | None = None,
    only=None,
    smoke: bool = False,
    out=None,
    progress: bool = True,
    *,
    resume=None,
) -> BatchResult:
    """Run every job of a pipeline file (validated in full first) and write the summary.

    Parameters
    ----------
    pipeline_path : the TOML pipeline (see `idapbc_pin.batch.pipeline` for the format).
    workers : jobs at a time (default: the number of cores, at most the number of jobs); 1 runs
        them one by one in this process. With ``ray="auto"`` it is the local instance's num_cpus.
    ray : None (local processes), ``"auto"`` (a new local Ray instance; the cluster in
        ``$RAY_ADDRESS`` when that is set, as under ``ray job submit``) or a cluster address
        (``HOST:6379`` from a cluster node, ``ray://HOST:10001`` from outside through Ray Client).
    only : job names to run (the others are left as they are).
    smoke : shrink every job (few epochs, tiny networks, small ROA and certificate) for a quick check.
    out : the batch directory (new, or one to resume). Default: the latest unfinished
        ``runs/batch-*`` of this pipeline (so re-running the same command resumes it), else a new
        ``runs/batch-<stamp>``.
    progress : show the progress bar (status lines are printed either way).
    resume : an existing batch directory to resume (like `out`, but it must exist).

    Returns
    -------
    BatchResult. Jobs whose ``job.json`` says done with the same settings are skipped.
    """
    t0 = time.perf_counter()
    pipeline = load_pipeline(pipeline_path, smoke=smoke)  # raises before anything runs
    selected = pipeline.select(only)
    if workers is not None and workers < 1:
        raise IdapbcError(f"--workers must be ≥ 1, got {workers}.")
    if ray is not None:
        _import_ray()
    batch_dir = _batch_dir(pipeline, out, resume)
    batch_dir.mkdir(parents=True, exist_ok=True)
    with _lock(batch_dir):
        meta = _read_json(batch_dir / "batch.json") or {"created": _now(), "token": uuid.uuid4().hex, "invocations": []}
        if meta.get("pipeline") not in (None, str(pipeline.path)):
            raise IdapbcError(f"'{batch_dir}' holds a batch of '{meta['pipeline']}', not '{pipeline.path}'. Fix: pass another --out DIR.")
        meta.update(pipeline=str(pipeline.path), pipeline_sha256=pipeline.sha256, smoke=pipeline.smoke, jobs=pipeline.names, complete=False)
        _write_json(batch_dir / "batch.json", meta)
        shutil.copyfile(pipeline.path, batch_dir / "pipeline.toml")

        records, pending, skipped = {}, [], []
        for job in selected:
            record = _read_json(batch_dir / job.name / "job.json")
            if record and record.get("status") == "done" and record.get("fingerprint") == job.fingerprint():
                records[job.name] = record
                skipped.append(job)
            else:
                pending.append(job)

        def on_record(job, record):
            records[job.name] = record
            write_summary(batch_dir, pipeline)

        tracker = _Tracker(batch_dir, len(selected), len(skipped), progress, on_record)
        n_workers = workers or max(1, min(_cpu_count(), len(pending)))
        executor = f"ray {ray}" if ray else ("in-process" if n_workers == 1 else f"{n_workers} worker processes")
        tracker.line(f"batch {batch_dir} ({pipeline.path.name}{', smoke' if smoke else ''}): {len(pending)} job(s) to run, {len(skipped)} done already; {executor}")
        for job in skipped:
            tracker.line(f"skipped {job.name}: done in a previous run ({records[job.name].get('run_dir')})")
        try:
            if not pending:
                pass
            elif ray:
                _run_ray(pending, batch_dir, tracker, ray, workers, meta["token"])
            elif n_workers == 1:
                _run_in_process(pending, batch_dir, tracker)
            else:
                _run_pool(pending, batch_dir, tracker, n_workers)
        except KeyboardInterrupt:
            tracker.line(f"interrupted: re-run the same command (or --resume {batch_dir}) to finish the remaining jobs")
            raise
        finally:
            tracker.close()
            rows = write_summary(batch_dir, pipeline)
            wall = time.perf_counter() - t0
            ran = [j.name for j in pending if j.name in records]
            failed = [nm for nm in ran if records[nm].get("status") != "done"]
            meta = _read_json(batch_dir / "batch.json") or meta
            meta["complete"] = all(r["status"] == "done" for r in rows)
            meta["invocations"] = [*meta.get("invocations", []), {
                "started": _dt.datetime.fromtimestamp(time.time() - wall).isoformat(timespec="seconds"), "wall_seconds": round(wall, 3),
                "executor": executor, "only": list(only) if only else None, "ran": ran, "skipped": [j.name for j in skipped], "failed": failed,
            }]  # fmt: skip
            _write_json(batch_dir / "batch.json", meta)
        tracker.line(f"finished in {wall:.0f} s: {len(ran) - len(failed)} done, {len(failed)} failed, {len(skipped)} skipped; summary: {batch_dir / 'summary.md'}")
    return BatchResult(
        path=batch_dir,
        pipeline=pipeline.path,
        records=records,
        ran=ran,
        skipped=[j.name for j in skipped],
        failed=failed,
        summary_csv=batch_dir / "summary.csv",
        summary_md=batch_dir / "summary.md",
        rows=rows,
        wall_seconds=wall,
    )


# ====================================================================== summary
def _fmt(value) -> str:
    """CSV formatting: empty for missing, yes/no for booleans, 6 significant digits for floats."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    return str(value)


def write_summary(batch_dir, pipeline: Pipeline) -> list[dict]:
    """Write summary.csv and summary.md from the jobs' job.json files; returns the CSV rows."""
    batch_dir = Path(batch_dir)
    rows = []
    for job in pipeline.jobs:
        record = _read_json(batch_dir / job.name / "job.json")
        if record is None:
            row = _row(job, {"status": "pending", "timings": {}})
        else:
            row = {**dict.fromkeys(SUMMARY_COLUMNS), **record.get("row", {})}
            if record.get("fingerprint") != job.fingerprint():
                row["status"] = f"{row['status']} (outdated settings)"
        rows.append({c: _fmt(row.get(c)) for c in SUMMARY_COLUMNS})
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=SUMMARY_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    _atomic_write_bytes(batch_dir / "summary.csv", buf.getvalue().encode())
    _atomic_write_bytes(batch_dir / "summary.md", _summary_markdown(rows, pipeline).encode())
    return rows


def read_summary(summary_csv) -> list[dict]:
    """The rows of a summary.csv (strings, as written)."""
    with open(summary_csv, newline="") as fh:
        return list(csv.DictReader(fh))


def _p(v: str) -> str:
    return "—" if v in ("", None) else f"{100 * float(v):.1f} %"


def _s(v: str, unit: str = " s") -> str:
    return "—" if v in ("", None) else f"{float(v):.3g}{unit}"


def _dur(v: str) -> str:
    """A duration in s, min or h."""
    if v in ("", None):
        return "—"
    v = float(v)
    return f"{v:.3g} s" if v < 100 else f"{v:.0f} s" if v < 600 else f"{v / 60:.0f} min" if v < 3600 else f"{v / 3600:.1f} h"


def _g(v: str) -> str:
    return "—" if v in ("", None) else f"{float(v):.2e}"


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _table(head: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    lines += ["| " + " | ".join(_cell(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _summary_markdown(rows: list[dict], pipeline: Pipeline) -> str:
    n = next((r["roa_n"] for r in rows if r["roa_n"]), "?")
    T = next((r["roa_T"] for r in rows if r["roa_T"]), "?")
    head = [
        f"# Batch summary: `{pipeline.path.name}`{' (smoke)' if pipeline.smoke else ''}",
        "",
        (pipeline.description + "\n") if pipeline.description else "",
        f"Success: share of {n} uniform initial states (per box, same states for both controllers) that reach "
        f"‖q − q*‖∞ ≤ 0.05, ‖v‖∞ ≤ 0.05 over the last 2 s of T = {T} s on the true plant (DESIGN §4). "
        "Settling: median over the successful states. Certificate: dissipation inequality outside H_ε (share of samples), "
        "local exponential stability of x*, share of the domain inside the largest sampled sublevel set: a sampled "
        "certificate, not a proof.",
        "",
        "## Closed loop",
        "",
        _table(
            ["job", "system", "actuated", "preset", "status", "success domain NIDA-PBC / LQR", "success half NIDA-PBC / LQR",
             "settling domain NIDA-PBC / LQR", "dissipation", "LES", "sublevel", "certified"],
            [[r["name"], r["system"], r["actuated"], r["preset"], r["status"],
              f"{_p(r['nida_success_domain'])} / {_p(r['lqr_success_domain'])}", f"{_p(r['nida_success_half'])} / {_p(r['lqr_success_half'])}",
              f"{_s(r['nida_settle_domain'])} / {_s(r['lqr_settle_domain'])}", _p(r["dissipation_fraction"]), r["les"] or "—",
              _p(r["sublevel_coverage"]), r["certified"] or "—"] for r in rows],
        ),
        "",
        "## Training",
        "",
        _table(
            ["job", "epochs", "train time", *_LOSS_TERMS, "job time", "run"],
            [[r["name"], r["epochs"] or "—", _dur(r["train_seconds"]), *(_g(r[f"loss_{t}"]) for t in _LOSS_TERMS), _dur(r["job_seconds"]),
              f"`{r['run_dir']}`" if r["run_dir"] else "—"] for r in rows],
        ),
    ]  # fmt: skip
    errors = [r for r in rows if r["error"]]
    if errors:
        head += ["", "## Errors", ""] + [f"- **{r['name']}** ({r['status']}): {_cell(r['error'])}" for r in errors]
    return "\n".join(head) + "\n"


def zoo_table_markdown(summary_csv) -> str:
    """The README's zoo table, rendered from a summary.csv (deterministic: no times of day, no paths).

    One row per job: actuated joints, success rate of NIDA-PBC next to LQR on the training box and
    on its half-size box, median settling times on the training box, local exponential stability,
    the certificate's dissipation share and sublevel coverage, and the training time.
    """
    rows = read_summary(summary_csv)
    n = next((r["roa_n"] for r in rows if r.get("roa_n")), "?")
    T = next((r["roa_T"] for r in rows if r.get("roa_T")), "?")
    body = []
    for r in rows:
        if r["status"] != "done":
            reason = f": {r['error'][:80]}" if r.get("error") else ""
            body.append([f"`{r['name']}`", r["actuated"], f"{r['status']}{reason}", "", "", "", "", "", ""])
            continue
        body.append([
            f"`{r['name']}`", r["actuated"],
            f"{_p(r['nida_success_domain'])} / {_p(r['lqr_success_domain'])}", f"{_p(r['nida_success_half'])} / {_p(r['lqr_success_half'])}",
            f"{_s(r['nida_settle_domain'])} / {_s(r['lqr_settle_domain'])}", r["les"] or "—",
            _p(r["dissipation_fraction"]), _p(r["sublevel_coverage"]), _dur(r["train_seconds"]),
        ])  # fmt: skip
    head = ["robot", "actuated", "success, domain: NIDA-PBC / LQR", "success, half box: NIDA-PBC / LQR",
            "median settling: NIDA-PBC / LQR", "x* LES", "dissipation ok", "sublevel set covers", "training"]  # fmt: skip
    note = (
        f"Generated from `{Path(summary_csv).name}` by `idapbc_pin.batch.batch.zoo_table_markdown`: {n} uniform states per box, "
        f"T = {T} s, success = within 0.05 of x* over the last 2 s (DESIGN §4); certificate figures are sampled, not proofs."
    )
    return _table(head, body) + "\n\n" + note + "\n"


def replace_zoo_table(readme_text: str, table: str) -> str:
    """`readme_text` with the block between the zoo-table markers replaced by `table`."""
    start, end = readme_text.find(ZOO_TABLE_START), readme_text.find(ZOO_TABLE_END)
    if start < 0 or end < start:
        raise IdapbcError(f"README has no {ZOO_TABLE_START} … {ZOO_TABLE_END} block. Fix: add both markers where the table goes.")
    return readme_text[: start + len(ZOO_TABLE_START)] + "\n" + table.strip() + "\n" + readme_text[end:]


def readme_zoo_block(readme_text: str) -> str | None:
    """The text between the zoo-table markers (stripped), or None if the markers are missing."""
    start, end = readme_text.find(ZOO_TABLE_START), readme_text.find(ZOO_TABLE_END)
    if start < 0 or end < start:
        return None
    return readme_text[start + len(ZOO_TABLE_START) : end].strip()


# ====================================================================== CLI
def _cmd_batch(args: argparse.Namespace) -> int:
    result = run_batch(args.pipeline, workers=args.workers, ray=args.ray, only=args.only, smoke=args.smoke, out=args.out,
                       progress=not args.no_progress, resume=args.resume)  # fmt: skip
    print(f"summary: {result.summary_csv} and {result.summary_md}")
    if result.failed:
        print(f"failed: {', '.join(result.failed)} (see their job.json); re-run the same command to retry them", file=sys.stderr)
        return 1
    return 0


def add_batch_command(subparsers) -> argparse.ArgumentParser:
    """Register ``idapbc-pin batch PIPELINE ...`` on an argparse sub-parsers object."""
    p = subparsers.add_parser(
        "batch",
        help="train, evaluate (ROA vs LQR), certify and replay every job of a pipeline file; one summary",
        description=(
            "Run every job of a TOML pipeline (e.g. pipelines/zoo.toml): train, ROA vs LQR on the training box and its half, "
            "certify, figure, HTML replay, each into <batch>/<job>/. The whole file is validated first. A failing job is "
            "recorded and the batch goes on; re-running the same command skips the jobs already done. Writes "
            "summary.csv and summary.md into the batch directory."
        ),
    )
    p.add_argument("pipeline", metavar="PIPELINE", help="pipeline TOML file (pipelines/zoo.toml, pipelines/paper.toml, ...)")
    p.add_argument("--workers", type=int, metavar="N", help="jobs at a time (default: one per core); 1 runs them in this process")
    p.add_argument("--ray", metavar="auto|ADDRESS", help="run the jobs as Ray tasks: 'auto' starts a local Ray instance ($RAY_ADDRESS's cluster when set), "
                   "ADDRESS joins a cluster (HOST:6379 on a node, ray://HOST:10001 from outside); pip install 'idapbc-pin[ray]'")
    p.add_argument("--only", nargs="+", action="extend", metavar="NAME", help="run only these jobs")
    p.add_argument("--smoke", action="store_true", help="shrink every job (few epochs, tiny networks, small ROA) for a quick end-to-end check")
    p.add_argument("--out", metavar="DIR", help="batch directory (default: resume the latest unfinished runs/batch-* of this pipeline, else a new runs/batch-<stamp>)")
    p.add_argument("--resume", metavar="BATCH_DIR", help="finish an existing batch directory (skips the jobs already done)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (status lines only)")
    p.set_defaults(func=_cmd_batch)
    return p

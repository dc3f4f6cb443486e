"""`run_batch`: every job of a pipeline file, run or resumed in a batch directory, and one summary."""

from __future__ import annotations

import datetime as _dt
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import IdapbcError
from ._files import read_json_or_none
from .batch_dir import choose_batch_dir, lock, open_batch, record_invocation
from .executors import describe_executor, import_ray, run_jobs
from .pipeline import Job, load_pipeline
from .progress import Tracker
from .summary import write_summary

__all__ = ["BatchResult", "run_batch"]


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


def _done_already(jobs: list[Job], batch_dir: Path) -> tuple[dict, list[Job], list[Job]]:
    """({name: record} of the jobs whose job.json says done with the same settings, those jobs, the others)."""
    records, skipped, pending = {}, [], []
    for job in jobs:
        record = read_json_or_none(batch_dir / job.name / "job.json")
        if record and record.get("status") == "done" and record.get("fingerprint") == job.fingerprint():
            records[job.name] = record
            skipped.append(job)
        else:
            pending.append(job)
    return records, skipped, pending


def run_batch(pipeline_path, workers: int | None = None, ray: str | None = None, only=None, smoke: bool = False, out=None,
              progress: bool = True, *, resume=None) -> BatchResult:  # fmt: skip
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
        import_ray()
    batch_dir = choose_batch_dir(pipeline, out, resume)
    batch_dir.mkdir(parents=True, exist_ok=True)
    with lock(batch_dir):
        meta = open_batch(batch_dir, pipeline)
        records, skipped, pending = _done_already(selected, batch_dir)

        def on_record(job, record):
            records[job.name] = record
            write_summary(batch_dir, pipeline)

        tracker = Tracker(batch_dir, len(selected), len(skipped), progress, on_record)
        executor = describe_executor(workers, ray, len(pending))
        tracker.line(f"batch {batch_dir} ({pipeline.path.name}{', smoke' if smoke else ''}): {len(pending)} job(s) to run, {len(skipped)} done already; {executor}")
        for job in skipped:
            tracker.line(f"skipped {job.name}: done in a previous run ({records[job.name].get('run_dir')})")
        try:
            run_jobs(pending, batch_dir, tracker, workers, ray, meta["token"])
        except KeyboardInterrupt:
            tracker.line(f"interrupted: re-run the same command (or --resume {batch_dir}) to finish the remaining jobs")
            raise
        finally:
            tracker.close()
            rows = write_summary(batch_dir, pipeline)
            wall = time.perf_counter() - t0
            ran = [j.name for j in pending if j.name in records]
            failed = [nm for nm in ran if records[nm].get("status") != "done"]
            record_invocation(batch_dir, meta, all(r["status"] == "done" for r in rows), {
                "started": _dt.datetime.fromtimestamp(time.time() - wall).isoformat(timespec="seconds"), "wall_seconds": round(wall, 3),
                "executor": executor, "only": list(only) if only else None, "ran": ran, "skipped": [j.name for j in skipped], "failed": failed,
            })  # fmt: skip
        tracker.line(f"finished in {wall:.0f} s: {len(ran) - len(failed)} done, {len(failed)} failed, {len(skipped)} skipped; summary: {batch_dir / 'summary.md'}")
    return BatchResult(path=batch_dir, pipeline=pipeline.path, records=records, ran=ran, skipped=[j.name for j in skipped], failed=failed,
                       summary_csv=batch_dir / "summary.csv", summary_md=batch_dir / "summary.md", rows=rows, wall_seconds=wall)  # fmt: skip

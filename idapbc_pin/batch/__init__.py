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

Each job runs `run_job`: `load_system` → `train` → `evaluate_run` → `certify` → `figure` →
`view(pick="success")` → ``replay.html``. Any exception fails that job only (recorded with its
stage, message and traceback); the batch goes on. ``job.json`` is written atomically when a job
ends, so a batch killed at any moment resumes: re-running the same command (or ``--out``/``--resume``
the same directory) skips the jobs whose ``job.json`` says done with the same settings, and re-runs
the others. A job killed during training resumes from its run's last checkpoint
(`train(resume=...)`, which gives the result of an uninterrupted run); one killed after training
reuses the finished run.

Executors: in-process for one worker; a spawn `ProcessPoolExecutor` for N; Ray (optional extra) for
``--ray auto`` (a local Ray instance) or ``--ray ADDRESS`` (a cluster). Every worker runs one torch
thread (and one OpenMP/MKL thread), so N workers use N cores; the same job function runs everywhere,
so the same seeds give the same results.

Modules, in the order a batch uses them: `pipeline` (TOML file → validated `Job`s), `batch_dir`
(which directory, its lock, batch.json), `job` (`run_job` and its stages), `record` (job.json and
its summary row), `executors` (in-process, process pool, Ray), `progress` (bar and status lines),
`summary` (summary.csv / .md, the README's zoo table), `seeds` (the zoo table's medians over training
seeds), `runner` (`run_batch`).
"""

from .job import run_job
from .pipeline import Job, Pipeline, PipelineError, load_pipeline
from .record import SUMMARY_COLUMNS, VOLATILE_COLUMNS
from .runner import BatchResult, run_batch
from .seeds import SEED_TABLE_END, SEED_TABLE_START, seed_median_markdown, seed_medians
from .summary import read_summary, readme_block, readme_zoo_block, replace_block, replace_zoo_table, write_summary, zoo_table_markdown

__all__ = [
    "BatchResult",
    "Job",
    "Pipeline",
    "PipelineError",
    "SEED_TABLE_END",
    "SEED_TABLE_START",
    "SUMMARY_COLUMNS",
    "VOLATILE_COLUMNS",
    "load_pipeline",
    "read_summary",
    "readme_block",
    "readme_zoo_block",
    "replace_block",
    "replace_zoo_table",
    "run_batch",
    "run_job",
    "seed_median_markdown",
    "seed_medians",
    "write_summary",
    "zoo_table_markdown",
]

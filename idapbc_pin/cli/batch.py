"""``idapbc-pin batch PIPELINE``: every job of a pipeline file, one summary (`idapbc_pin.batch.run_batch`)."""

from __future__ import annotations

import argparse
import sys

from ._args import add_command, add_ray_argument

__all__ = ["add_batch_command"]


def _cmd_batch(args: argparse.Namespace) -> int:
    """Run every job of a TOML pipeline (e.g. pipelines/zoo.toml): train, ROA vs LQR on the
    training box and its half, certify, figure, HTML replay, each into <batch>/<job>/. The whole
    file is validated first. A failing job is recorded and the batch goes on; re-running the
    same command skips the jobs already done. Writes summary.csv and summary.md into the batch
    directory."""
    from ..batch.runner import run_batch

    result = run_batch(args.pipeline, workers=args.workers, ray=args.ray, only=args.only, smoke=args.smoke, out=args.out,
                       progress=not args.no_progress, resume=args.resume)  # fmt: skip
    print(f"summary: {result.summary_csv} and {result.summary_md}")
    if result.failed:
        print(f"failed: {', '.join(result.failed)} (see their job.json); re-run the same command to retry them", file=sys.stderr)
        return 1
    return 0


def add_batch_command(subparsers) -> argparse.ArgumentParser:
    """Register ``idapbc-pin batch PIPELINE ...`` on an argparse sub-parsers object."""
    p = add_command(subparsers, "batch", _cmd_batch, help="train, evaluate (ROA vs LQR), certify and replay every job of a pipeline file; one summary")
    p.add_argument("pipeline", metavar="PIPELINE", help="pipeline TOML file (pipelines/zoo.toml, pipelines/paper.toml, ...)")
    p.add_argument("--workers", type=int, metavar="N", help="jobs at a time (default: one per core); 1 runs them in this process")
    add_ray_argument(p, "the jobs")
    p.add_argument("--only", nargs="+", action="extend", metavar="NAME", help="run only these jobs")
    p.add_argument("--smoke", action="store_true", help="shrink every job (few epochs, tiny networks, small ROA) for a quick end-to-end check")
    p.add_argument("--out", metavar="DIR", help="batch directory (default: resume the latest unfinished runs/batch-* of this pipeline, else a new runs/batch-<stamp>)")
    p.add_argument("--resume", metavar="BATCH_DIR", help="finish an existing batch directory (skips the jobs already done)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (status lines only)")
    return p

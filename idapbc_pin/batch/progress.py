"""What a batch shows while it runs: one tqdm bar over the jobs, status lines above it, batch.log.

Every status line is printed (stdout) and appended, timestamped, to ``<batch>/batch.log``; the
bar (stderr) only counts jobs and names the running ones.
"""

from __future__ import annotations

import sys
from pathlib import Path

from tqdm.auto import tqdm

from ._files import timestamp
from .pipeline import Job

__all__ = ["Tracker", "status_line"]


class Tracker:
    """The one progress display of a batch.

    batch_dir : where batch.log is appended.  total : jobs selected this time.  done : of those,
    the ones skipped as done already.  progress : show the bar.  on_record : called with
    (job, record) when a job ends, before its status line is printed.
    """

    def __init__(self, batch_dir: Path, total: int, done: int, progress: bool, on_record):
        self.log_path = batch_dir / "batch.log"
        self.bar = tqdm(total=total, initial=done, desc="batch", unit="job", disable=not progress, dynamic_ncols=True, file=sys.stderr)
        self.total, self.count, self.running = total, done, []
        self.on_record = on_record

    def line(self, text: str) -> None:
        """Print a status line above the bar and append it to batch.log."""
        tqdm.write(text, file=sys.stdout)
        with open(self.log_path, "a") as fh:
            fh.write(f"{timestamp()} {text}\n")

    def started(self, job: Job) -> None:
        self.running.append(job.name)
        self.line(f"started {job.name}")
        self.bar.set_postfix_str("running: " + ", ".join(self.running), refresh=True)

    def finished(self, job: Job, record: dict) -> None:
        if job.name in self.running:
            self.running.remove(job.name)
        self.count += 1
        self.on_record(job, record)
        self.line(f"[{self.count}/{self.total}] {status_line(record)}")
        self.bar.update(1)
        self.bar.set_postfix_str(("running: " + ", ".join(self.running)) if self.running else "", refresh=True)

    def close(self) -> None:
        self.bar.close()


def _pct(v) -> str:
    return "—" if v is None else f"{100 * v:.0f} %"


def status_line(record: dict) -> str:
    """One line for a job that ended: its status, time and, when done, the success rates and LES."""
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

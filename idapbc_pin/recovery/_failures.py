"""A stage's failure as the user sees it: one line ``… Fix: …`` and the run as it was, or a stage that
refused and says why.

A stage (recovery, swing-up) runs after training on a run that already holds a working law. A
failure inside it (a worker's exception, a singular solve, a NaN that a solver refuses) must not end
in a traceback nor touch the run's law: `stage_errors` turns any such exception into one
`IdapbcError` line that names the stage, the error and how to run the stage again; the chunks of
plans the stage finished stay on disk, so that run reads them back. A stage that finds nothing to
fit records its refusal instead (`record_refusal`): ``{"used": False, "reason": …}`` in
summary.json, the run's law unchanged.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

from .._io import write_json
from ..errors import IdapbcError

__all__ = ["record_refusal", "stage_errors"]


@contextlib.contextmanager
def stage_errors(stage: str, run_dir: Path, fix: str):
    """Within the block, an exception other than `IdapbcError` and Ctrl-C becomes one `IdapbcError`
    line: the `stage` ("the recovery stage") failed, with the exception's type and first line, the
    run at `run_dir` keeps its law, and `fix` (how to run the stage again or skip it)."""
    try:
        yield
    except (IdapbcError, KeyboardInterrupt):
        raise
    except Exception as exc:  # noqa: BLE001 (any failure inside the stage, a worker's included)
        text = (str(exc).strip().splitlines() or [""])[0]
        what = f"{type(exc).__name__}: {text}" if text else type(exc).__name__
        raise IdapbcError(f"{stage} failed ({what}); the run keeps its law as it is ({run_dir}). Fix: {fix}") from None


def record_refusal(run, key: str, reason: str, start: float, **extra) -> dict:
    """Write summary.json → `key` = ``{"used": False, "refused": True, "reason": reason, "seconds", **extra}``
    (atomically) for a stage that found nothing to fit; the run's law and files stay as they were (a
    law of the stage the run already uses keeps its entry: nothing is written then). Returns the
    entry. `start`: the stage's `time.perf_counter()` at its start."""
    entry = {"used": False, "refused": True, "reason": reason, "seconds": round(time.perf_counter() - start, 1), **extra}
    if (run.summary.get(key) or {}).get("used"):
        return entry
    summary = dict(run.summary) | {key: entry}
    write_json(Path(run.path) / "summary.json", summary)
    run.summary = summary
    return entry

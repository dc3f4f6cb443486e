"""The checkpoints of a run directory (``checkpoints/best.pt``, ``last.pt``): written atomically,
read with ``torch.load(weights_only=True)``, checked for damage and for fit with the networks.

A missing, truncated, garbled or non-finite checkpoint gives one `DamagedFileError` line that names
the file and the fix (the other checkpoint, when it is intact).
"""

from __future__ import annotations

import io
import warnings
import zipfile
from pathlib import Path

import torch

from .._io import DamagedFileError, atomic_write_bytes
from ..config import TrainConfig
from ..control.nets import IdaPbcNets, build_nets
from ..model import System

__all__ = ["CHECKPOINTS", "DEFAULT_CHECKPOINT", "check_checkpoints", "checkpoint_problem", "load_weights", "read_checkpoint", "save_checkpoint"]

#: The checkpoints a run keeps: the lowest summed loss so far, and the most recent epoch.
CHECKPOINTS = ("best", "last")
#: What `load_run` (and every command on a RUN) uses unless told: the final weights, which `train`
#: returns and its evaluation measures. The loss is a mean of residuals over one batch, not the region
#: of attraction, so the lowest-loss epoch is not the better controller (docs/results-history.md).
DEFAULT_CHECKPOINT = "last"


def save_checkpoint(path: Path, state: dict) -> None:
    """`torch.save(state)` written atomically (a crash leaves the previous checkpoint)."""
    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write_bytes(path, buf.getvalue())


def checkpoint_problem(path: Path, map_location="cpu") -> tuple[dict | None, str | None]:
    """(state, None) for a readable checkpoint with finite weights, else (None, the reason)."""
    if not path.is_file():
        return None, "missing"
    if path.stat().st_size == 0:
        return None, "empty file"
    if not zipfile.is_zipfile(path):  # torch.save writes a zip archive; a cut-off one has no directory
        return None, "truncated or overwritten: not a complete torch checkpoint"
    try:
        with warnings.catch_warnings():  # torch warns about odd pickles before it refuses them
            warnings.simplefilter("ignore")
            state = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # torch raises RuntimeError, UnpicklingError, EOFError, … for damaged files
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        return None, f"unreadable torch checkpoint: {reason[:100]}"
    if not isinstance(state, dict) or not isinstance(state.get("nets"), dict) or "epoch" not in state:
        return None, "not a checkpoint written by idapbc-pin train"
    bad = [k for k, v in state["nets"].items() if torch.is_tensor(v) and v.is_floating_point() and not bool(torch.isfinite(v).all())]
    if bad:
        return None, f"non-finite weights in '{bad[0]}': training diverged before this checkpoint"
    return state, None


def read_checkpoint(run_dir, name: str, map_location="cpu") -> dict:
    """The state saved in ``run_dir/checkpoints/<name>.pt`` (``weights_only=True``), weights finite.

    A missing, truncated, garbled or non-finite checkpoint raises `DamagedFileError` with one line
    that names the file and, when the other checkpoint is intact, how to use that one instead.
    """
    run_dir = Path(run_dir)
    path = run_dir / "checkpoints" / f"{name}.pt"
    state, problem = checkpoint_problem(path, map_location)
    if problem is None:
        return state
    intact = [o for o in CHECKPOINTS if o != name and checkpoint_problem(run_dir / "checkpoints" / f"{o}.pt")[1] is None]
    if intact:
        other = intact[0]
        fix = f"use the intact {other}.pt (--checkpoint {other}; for --resume, copy checkpoints/{other}.pt over checkpoints/{name}.pt)"
    elif problem.startswith("non-finite"):
        fix = "train again with a lower --lr"
    else:
        fix = "no intact checkpoint is left in this run; train again"
    what = f"'{path}' is missing" if problem == "missing" else f"{path} is damaged ({problem})"
    raise DamagedFileError(f"{what}. Fix: {fix}.")


def check_checkpoints(run_dir, system: System | None = None, config: TrainConfig | None = None) -> list[str]:
    """The names of the checkpoints present in ``run_dir/checkpoints`` (in `CHECKPOINTS` order),
    after checking that each reads back with finite weights and, given the run's `system` and
    `config`, fits the networks they describe. The first damaged one raises a one-line
    `DamagedFileError` (see `read_checkpoint`, `load_weights`), so damage never passes unnoticed."""
    run_dir = Path(run_dir)
    present = [c for c in CHECKPOINTS if (run_dir / "checkpoints" / f"{c}.pt").is_file()]
    for name in present:
        path = run_dir / "checkpoints" / f"{name}.pt"
        state, problem = checkpoint_problem(path)
        if problem is not None:
            read_checkpoint(run_dir, name)  # raises the one-line error, with the other checkpoint's offer
        if system is not None and config is not None:
            with torch.random.fork_rng(devices=[]):  # building the networks draws weights: leave the seed alone
                load_weights(build_nets(system, config), state, path)
    return present


def load_weights(nets: IdaPbcNets, state: dict, path) -> None:
    """Load a checkpoint's ``state["nets"]`` (read from `path`) into `nets`. Weights that do not fit
    the networks (config.json edited after training, or a checkpoint of another run) raise a
    one-line `DamagedFileError` instead of torch's list of mismatches."""
    try:
        nets.load_state_dict(state["nets"])
    except RuntimeError as exc:
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
        detail = lines[1] if len(lines) > 1 else (lines[0] if lines else type(exc).__name__)
        raise DamagedFileError(
            f"{path} does not fit the networks that config.json describes ({detail[:140]}). "
            "Fix: restore the config.json this checkpoint was trained with, or train again."
        ) from None

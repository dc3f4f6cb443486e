"""A run directory and its files: `Run`, `load_run`, `resolve_run` and the one checkpoint reader.

Layout of a run directory (`<out>/<stamp>/`, `out` defaults to ``runs/<system>``)::

    config.json      resolved TrainConfig          system.json   source, actuated, target, domain, URDF hash
    robot.urdf       copy of the URDF (if any)     metrics.csv   one row per epoch, every term by name
    checkpoints/last.pt, best.pt                   summary.json  final terms, ε, eigenvalues at x*, status
    recovery.npz     the recovery law, when `idapbc-pin recover` kept one (`control.recovery`)

Every file is read here (JSON through `_io.read_json`, checkpoints through `read_checkpoint`), so a
damaged file always gives the same one-line error that names it and the fix.
"""

from __future__ import annotations

import hashlib
import io
import os
import shutil
import sys
import warnings
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from .._io import DamagedFileError, atomic_write_bytes, read_json, read_npz
from ..config import TrainConfig
from ..control.controller import Controller
from ..control.fallback import BoxFallback, box_fallback
from ..control.nets import IdaPbcNets, build_nets
from ..control.recovery import RecoveryLaw
from ..errors import IdapbcError
from ..model import System, load_system

__all__ = [
    "CHECKPOINTS",
    "RECOVERY_FILE",
    "RECOVERY_LABELS_FILE",
    "RECOVERY_REFUSED_FILE",
    "Run",
    "check_checkpoints",
    "load_run",
    "load_run_system",
    "load_weights",
    "read_checkpoint",
    "read_config",
    "read_recovery",
    "require_device",
    "resolve_run",
    "save_checkpoint",
    "system_record",
]

#: The checkpoints a run keeps: the lowest summed loss so far, and the most recent epoch.
CHECKPOINTS = ("best", "last")
#: What `load_run` (and every command on a RUN) uses unless told: the final weights, which are the
#: ones `train` returns and `train --evaluate` and batch jobs measure. The lowest-loss epoch was mostly
#: the worse controller: acrobot (fast preset, limits, 100 half-box states, three runs) 73 / 67 / 59 %
#: with best.pt against 78 / 74 / 74 % with last.pt, cart_double_pendulum 17 / 11 % against 14 / 13 %,
#: paper cartpole (seeds 0-2, domain) 75.5 / 77.5 / 76 % against 81.5 / 87.5 / 75 %: the loss is a
#: mean of residuals over one batch, not the region of attraction.
DEFAULT_CHECKPOINT = "last"
#: The recovery law of a run, beside its IDA-PBC law (`training.recovery.recover`).
RECOVERY_FILE = "recovery.npz"
#: The law the last `recover` fitted when its gate refused it: kept aside, never applied, so that
#: `recover --regate` can judge it again (another margin or allowance) or keep it, in minutes.
RECOVERY_REFUSED_FILE = "recovery-refused.npz"
#: The labels (x, u) the last `recover` fitted its law to (LQR, plans and DAgger rounds), so that
#: `recover --refit` fits a law again (another seed, width or length) in a minute, without the plans.
RECOVERY_LABELS_FILE = "recovery-labels.npz"

#: Values of options that runs written before the option existed trained with (their config.json
#: lacks the key): the box-unit anchor weight diag(1/s²), physical units, H_d's ICNN fed the box-normalised state, no `effort` term, angles
#: not wrapped, J_d and R_d extrapolated beyond the box, the learned law outside the box too.
LEGACY_DEFAULTS = {"fallback": "none", "anchor_weight": "box", "scaling": "none", "energy_input": "box", "effort_term": False, "wrap_angles": False, "bounded_structure": False, "fallback_gain": 1.0}


@dataclass
class Run:
    """A trained (or training) run: its directory, system, config, networks and summary."""

    path: Path
    system: System
    config: TrainConfig
    nets: IdaPbcNets
    summary: dict = field(default_factory=dict)
    checkpoint: str = DEFAULT_CHECKPOINT
    _fallback: BoxFallback | RecoveryLaw | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def controller(self) -> Controller:
        """The control law u = (gᵀg)⁻¹gᵀ(f̃_d − f) with the trained networks, and the run's law
        where they do not act (`fallback`)."""
        return Controller(self.system, self.nets, self.fallback)

    @property
    def own_controller(self) -> Controller:
        """The run's law without a recovery law: the networks, and where the run uses it the linear
        law outside the training box with the gate's inside gain (what `recover` improves on, and
        what its gate and its `teacher` = "run" simulate)."""
        return Controller(self.system, self.nets, self._linear_fallback())

    def _linear_fallback(self) -> BoxFallback | None:
        """The linear law outside the box with the gate's inside gain, where the run uses it; else None."""
        return box_fallback(self.system, self.config, self.inside_gain, self.inside_ramp) if self.uses_fallback else None

    @property
    def uses_fallback(self) -> bool:
        """True when the run switches to the anchor's linear law outside the training box:
        ``config.fallback == "linear"``, or ``"auto"`` and the gate after training chose it
        (summary.json → fallback → used; False while training has not written it)."""
        if self.config.fallback == "auto":
            return bool((self.summary.get("fallback") or {}).get("used", False))
        return self.config.fallback == "linear"

    @property
    def inside_gain(self) -> float:
        """The factor on the learned law's deviation from u* inside the training box: the gate's
        choice (summary.json → fallback → inside_gain) where the run uses the fallback, else 1."""
        if not self.uses_fallback:
            return 1.0
        k = (self.summary.get("fallback") or {}).get("inside_gain", 1.0)
        if isinstance(k, bool) or not isinstance(k, (int, float)) or not (k >= 0.5 and np.isfinite(k)):
            raise DamagedFileError(f"'{self.path / 'summary.json'}' has fallback → inside_gain = {k!r}, not a number ≥ 0.5. "
                                   "Fix: set it to 1 (the learned law as trained inside the box).")
        return float(k)

    @property
    def inside_ramp(self) -> tuple[float, float]:
        """Where the inside gain ramps in (`BoxFallback.inside_ramp`): summary.json → fallback →
        inside_ramp; (0, 0), a constant gain, for runs gated before the ramp existed."""
        r = (self.summary.get("fallback") or {}).get("inside_ramp", [0.0, 0.0]) if self.uses_fallback else [0.0, 0.0]
        ok = isinstance(r, list) and len(r) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in r)
        if not (ok and np.isfinite(r[1]) and 0.0 <= r[0] <= r[1]):
            raise DamagedFileError(f"'{self.path / 'summary.json'}' has fallback → inside_ramp = {r!r}, not two numbers 0 ≤ r0 ≤ r1. "
                                   "Fix: set it to [0, 0] (a constant inside gain) or re-run the gate (`idapbc-pin train`).")
        return float(r[0]), float(r[1])

    @property
    def uses_recovery(self) -> bool:
        """True when `idapbc-pin recover` kept a recovery law (summary.json → recovery → used)."""
        return bool((self.summary.get("recovery") or {}).get("used", False))

    @property
    def fallback(self) -> BoxFallback | RecoveryLaw | None:
        """The law that replaces the networks' where they do not act, or None: the recovery law
        outside its inner box when the run has one (`control.recovery`), else the linear law
        outside the training box when the run uses it (`control.fallback`)."""
        if self._fallback is None:
            self._fallback = read_recovery(self.path) if self.uses_recovery else self._linear_fallback()
        return self._fallback


def read_recovery(run_dir, name: str = RECOVERY_FILE) -> RecoveryLaw:
    """The run's recovery law (``recovery.npz``, or `RECOVERY_REFUSED_FILE` for the refused one;
    read without pickles); a missing or damaged file raises a one-line `DamagedFileError`."""
    path = Path(run_dir) / name
    fix = "run `idapbc-pin recover RUN` again (or delete summary.json's \"recovery\" entry to drop the law)"
    if not path.is_file():
        says = "uses a recovery law" if name == RECOVERY_FILE else "the last recover refused its law"
        raise DamagedFileError(f"'{path}' is missing, but summary.json says the run {says}. Fix: {fix}.")
    return read_npz(path, RecoveryLaw.from_arrays, fix=fix)


# ------------------------------------------------------------------------------------ checkpoints
def save_checkpoint(path: Path, state: dict) -> None:
    """`torch.save(state)` written atomically (a crash leaves the previous checkpoint)."""
    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write_bytes(path, buf.getvalue())


def _checkpoint_problem(path: Path, map_location="cpu") -> tuple[dict | None, str | None]:
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
    state, problem = _checkpoint_problem(path, map_location)
    if problem is None:
        return state
    intact = [o for o in CHECKPOINTS if o != name and _checkpoint_problem(run_dir / "checkpoints" / f"{o}.pt")[1] is None]
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
        state, problem = _checkpoint_problem(path)
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


# ------------------------------------------------------------------------------------ system record
def system_record(system: System, run_dir: Path) -> dict:
    """system.json: what `load_system` needs to rebuild the system, and a copy + hash of the URDF."""
    record = {
        "name": system.name,
        "source": system.source,
        "actuated": list(system.actuated),
        "target": {nm: float(v) for nm, v in zip(system.coordinate_names, system.x_star[: system.nq])},
        "domain": {"lo": system.domain[0].tolist(), "hi": system.domain[1].tolist()},
        "state_names": list(system.state_names),
        "effort": {nm: (float(e) if e < float("inf") else None) for nm, e in zip(system.actuated, system.effort)},  # None: unlimited
        "urdf": None,
    }
    src = Path(system.source)
    if src.suffix == ".urdf" and src.is_file():
        shutil.copyfile(src, run_dir / "robot.urdf")
        record["urdf"] = {"file": "robot.urdf", "sha256": hashlib.sha256(src.read_bytes()).hexdigest()}
    return record


def _system_from_record(record: dict, run_dir: Path) -> System:
    where = run_dir / "system.json"
    try:
        source, actuated, target = record["source"], record["actuated"], record["target"]
        domain = (record["domain"]["lo"], record["domain"]["hi"])
        urdf = record.get("urdf")
        copy = run_dir / urdf["file"] if urdf else None
        effort = record.get("effort")  # absent in runs written before limits were data: the URDF's
        effort = None if effort is None else {nm: (float("inf") if e is None else float(e)) for nm, e in effort.items()}
    except KeyError as exc:
        raise DamagedFileError(f"{where} is damaged (no {exc} entry). Fix: restore it, or train again.") from None
    except (TypeError, ValueError, AttributeError):
        raise DamagedFileError(f"{where} is damaged (not the layout `idapbc-pin train` writes). Fix: restore it, or train again.") from None
    if copy is not None:
        if not copy.is_file():
            raise IdapbcError(f"'{copy}', the run's copy of its URDF, is missing. Fix: restore it from the run's backup, or train again.")
        if hashlib.sha256(copy.read_bytes()).hexdigest() != urdf.get("sha256"):
            raise IdapbcError(f"'{copy}' does not match the hash recorded at training time. Fix: restore the run's robot.urdf.")
        source = str(copy)
    try:
        system = load_system(source, actuated=actuated, target=target, domain=domain, effort=effort)
    except IdapbcError as exc:
        reason = str(exc) if " Fix:" in str(exc) else f"{str(exc).rstrip('.')}. Fix: restore {where.name}, or train again."
        raise IdapbcError(f"the system recorded in {where} does not load: {reason}") from None
    except (TypeError, ValueError, AttributeError, KeyError):
        raise DamagedFileError(f"{where} is damaged (not the layout `idapbc-pin train` writes). Fix: restore it, or train again.") from None
    return replace(system, name=record.get("name", system.name), source=record["source"])


def _require_run_dir(path: Path) -> None:
    if not path.is_dir() or not (path / "config.json").exists():
        raise IdapbcError(f"'{path}' is not a run directory (no config.json). Fix: pass a directory made by `idapbc-pin train`.")


def read_config(path) -> TrainConfig:
    """The resolved `TrainConfig` in a run directory's config.json (older runs get `LEGACY_DEFAULTS`)."""
    path = Path(path)
    _require_run_dir(path)
    raw = read_json(path / "config.json", fix="restore config.json, or train again")
    if not isinstance(raw, dict):
        raise DamagedFileError(f"{path / 'config.json'} is damaged (not a JSON object). Fix: restore config.json, or train again.")
    try:
        return TrainConfig.from_dict({**LEGACY_DEFAULTS, **raw})
    except IdapbcError as exc:
        reason = str(exc).split(" Fix:")[0].rstrip(".")  # the file, not a CLI flag, is what to fix
        raise DamagedFileError(f"{path / 'config.json'} is damaged ({reason}). Fix: restore config.json, or train again.") from None
    except (TypeError, ValueError):
        raise DamagedFileError(f"{path / 'config.json'} is damaged (a value of the wrong type). Fix: restore config.json, or train again.") from None


def load_run_system(path) -> System:
    """The `System` a run was trained on (from its system.json and URDF copy)."""
    path = Path(path)
    _require_run_dir(path)
    return _system_from_record(read_json(path / "system.json", fix="restore system.json, or train again"), path)


def require_device(device: str) -> torch.device:
    """`device` as a torch device that exists here, else a one-line `IdapbcError` with the fix."""
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise IdapbcError(f"unknown device '{device}' ({str(exc).splitlines()[0][:80]}). Fix: use cpu, cuda or cuda:N.") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise IdapbcError(f"device '{device}' requested but torch sees no CUDA device. Fix: use --device cpu.")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise IdapbcError(f"device '{device}' requested but torch sees {torch.cuda.device_count()} CUDA device(s). Fix: use cuda:0 … cuda:{torch.cuda.device_count() - 1}.")
    elif dev.type != "cpu":
        raise IdapbcError(f"device '{device}' is not supported. Fix: use cpu, cuda or cuda:N.")
    return dev


def load_run(path, checkpoint: str | None = None, *, device: str = "cpu") -> Run:
    """Load a run directory (checkpoints are read with ``torch.load(weights_only=True)``).

    checkpoint : 'best' or 'last'. None (default) takes `DEFAULT_CHECKPOINT`, 'last' (the final
        weights, or the best finite ones after a divergence; 'best' while no last exists) and
        refuses a run whose other checkpoint is damaged, so damage never passes unnoticed; naming one
        explicitly uses it and only warns (stderr) about the other.
    device : where the networks are loaded, whatever device trained them ('cpu' by default: a run
        trained on a GPU is evaluated and exported on a machine without one). ``config.device``
        keeps recording where the run was trained.
    """
    path = Path(path)
    config = read_config(path)
    load_on = require_device(device)
    system = load_run_system(path)
    if checkpoint is not None and checkpoint not in CHECKPOINTS:
        raise IdapbcError(f"unknown checkpoint '{checkpoint}'. Fix: use one of {', '.join(CHECKPOINTS)}.")
    if checkpoint is None:  # refuse a damaged checkpoint, even the one not used
        present = check_checkpoints(path)
    else:
        present = [c for c in CHECKPOINTS if (path / "checkpoints" / f"{c}.pt").is_file()]
    if not present:
        raise IdapbcError(
            f"run '{path}' has no checkpoint (checkpoints/best.pt or last.pt). "
            "Fix: wait until its training saves one, or train again."
        )
    name = checkpoint or (DEFAULT_CHECKPOINT if DEFAULT_CHECKPOINT in present else present[0])
    state = read_checkpoint(path, name, map_location=load_on)
    for other in present:
        if other != name and _checkpoint_problem(path / "checkpoints" / f"{other}.pt")[1] is not None:
            print(f"warning: {path / 'checkpoints' / (other + '.pt')} is damaged; using {name}.pt as asked.", file=sys.stderr)
    torch.manual_seed(config.seed)
    nets = build_nets(system, config.replace(device=str(load_on)))
    load_weights(nets, state, path / "checkpoints" / f"{name}.pt")
    run = Run(path, system, config, nets, _read_summary(path), checkpoint=name)
    if run.uses_recovery:
        run.fallback  # noqa: B018 -- reads recovery.npz now: a damaged one is refused at load, like a checkpoint
    run.inside_gain, run.inside_ramp  # noqa: B018 -- a damaged summary.json entry is refused at load too
    return run


def _read_summary(path: Path) -> dict:
    """summary.json as a dict ({} while training has not written it)."""
    if not (path / "summary.json").exists():
        return {}
    fix = "delete summary.json (it is rewritten by the next train --resume)"
    summary = read_json(path / "summary.json", fix=fix)
    if not isinstance(summary, dict):
        raise DamagedFileError(f"{path / 'summary.json'} is damaged (not a JSON object). Fix: {fix}.")
    return summary


def resolve_run(run_or_path, checkpoint: str | None = None) -> Run:
    """A `Run` as it is, or `load_run` of a run directory (str or path): the one place that accepts both."""
    if isinstance(run_or_path, Run):
        return run_or_path
    if isinstance(run_or_path, (str, os.PathLike)):
        return load_run(run_or_path, checkpoint=checkpoint)
    raise IdapbcError(f"expected a Run or a run directory, got {type(run_or_path).__name__}. Fix: pass ip.load_run(...) or its path.")

"""What a run directory records of its training: system.json (with a copy and hash of the URDF) and
config.json (the resolved `TrainConfig`), written by `train` and read back by `load_run`."""

from __future__ import annotations

import hashlib
import shutil
from dataclasses import replace
from pathlib import Path

from .._io import DamagedFileError, read_json
from ..config import TrainConfig
from ..errors import IdapbcError
from ..model import System, load_system

__all__ = ["LEGACY_DEFAULTS", "load_run_system", "read_config", "require_run_dir", "system_record"]


#: Values of options that runs written before the option existed trained with (their config.json
#: lacks the key): the box-unit anchor weight diag(1/s²), a cart's position weighted as the other coordinates, physical units, H_d's ICNN fed the box-normalised state, no `effort` term, angles
#: not wrapped, J_d and R_d extrapolated beyond the box, the learned law outside the box too.
LEGACY_DEFAULTS = {"fallback": "none", "anchor_weight": "box", "anchor_cart": 1.0, "scaling": "none", "energy_input": "box", "effort_term": False, "wrap_angles": False, "bounded_structure": False, "fallback_gain": 1.0}


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


def require_run_dir(path: Path) -> None:
    if not path.is_dir() or not (path / "config.json").exists():
        raise IdapbcError(f"'{path}' is not a run directory (no config.json). Fix: pass a directory made by `idapbc-pin train`.")


def read_config(path) -> TrainConfig:
    """The resolved `TrainConfig` in a run directory's config.json (older runs get `LEGACY_DEFAULTS`)."""
    path = Path(path)
    require_run_dir(path)
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
    require_run_dir(path)
    return _system_from_record(read_json(path / "system.json", fix="restore system.json, or train again"), path)

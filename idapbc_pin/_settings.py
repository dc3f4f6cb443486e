"""Reading a settings file: a TOML file's ``[table]`` (or its top level) or a JSON object."""

from __future__ import annotations

import dataclasses
import json
import tomllib
from pathlib import Path

from .errors import IdapbcError

__all__ = ["Settings", "read_table", "typed_values"]


def read_table(path: str | Path, table: str, what: str, fix: str) -> dict:
    """The mapping of `what` settings in `path`: TOML (its ``[table]`` or top level) or JSON.

    A missing file, bad syntax or a non-table value raises a one-line `IdapbcError`; `fix` says where
    the valid keys are listed.
    """
    path = Path(path)
    if not path.is_file():
        raise IdapbcError(f"{what} file '{path}' not found. Fix: check the path.")
    try:
        data = tomllib.loads(path.read_text()) if path.suffix == ".toml" else json.loads(path.read_text())
    except (tomllib.TOMLDecodeError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise IdapbcError(f"cannot parse {what} file '{path}': {exc}. Fix: repair its syntax.") from None
    data = data.get(table, data) if isinstance(data, dict) else data
    if not isinstance(data, dict):
        raise IdapbcError(f"{what} file '{path}' must hold a table of {table} settings. Fix: {fix}.")
    return data


def typed_values(cls, data: dict, what: str) -> dict:
    """`data`'s values checked against the types of `cls`'s field defaults (int, float, bool, str,
    tuples of numbers, nested dataclasses given as tables; a None default takes a str); -> keyword
    arguments for `cls`. An unknown key or a value of the wrong type raises a one-line `IdapbcError`
    naming it."""
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise IdapbcError(f"unknown {what} key(s) {', '.join(unknown)}. Fix: use one of {', '.join(sorted(names))}.")
    default = cls()
    out = {}
    for key, value in data.items():
        ref = getattr(default, key)
        if dataclasses.is_dataclass(ref):
            if not isinstance(value, dict):
                raise IdapbcError(f"{what} key '{key}' must be a table, got {value!r}. Fix: write it as [{key}] under its table.")
            out[key] = type(ref)(**typed_values(type(ref), value, f"{what} {key}"))
            continue
        if isinstance(ref, tuple):
            ok = isinstance(value, (list, tuple)) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            value = tuple(float(v) for v in value) if ok else value
        elif isinstance(ref, float) and isinstance(value, int) and not isinstance(value, bool):
            value, ok = float(value), True
        elif ref is None:  # an optional text setting (None: unset), such as RecoveryConfig.ray
            ok = isinstance(value, str)
        else:
            ok = isinstance(value, type(ref)) and (isinstance(ref, bool) or not isinstance(value, bool))
        if not ok:
            kind = "str" if ref is None else type(ref).__name__
            raise IdapbcError(f"{what} key '{key}' must be {kind}, got {value!r}. Fix: change that value.")
        out[key] = value
    return out


class Settings:
    """What the frozen settings dataclasses (`TrainConfig`, `RecoveryConfig`) share: validated copies,
    dicts, and reading from a mapping or a file. A subclass names `_what` (for messages), `_table`
    (its TOML table) and `_fix` (where its keys are listed)."""

    _what = "settings"
    _table = "settings"
    _fix = "see the settings' fields"

    def replace(self, **changes):
        """A copy with `changes` applied (validated)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict):
        """Build from a mapping; an unknown key or a value of the wrong type is an error naming it."""
        return cls(**typed_values(cls, data, cls._what))

    @classmethod
    def from_file(cls, path: str | Path):
        """Read a TOML file (its ``[_table]`` table, or its top level) or a JSON object."""
        return cls.from_dict(read_table(path, cls._table, cls._what, cls._fix))

"""Pipeline files: a TOML list of training jobs, validated in full before anything runs.

Format (``pipelines/*.toml``)::

    description = "optional text"

    [defaults]                 # merged into every job (tables key by key, the job wins)
    preset = "fast"            # "paper" (TrainConfig()) or "fast" (TrainConfig.fast())
    train = { seed = 0 }       # TrainConfig overrides on top of the preset
    evaluate = { n = 200, T = 20.0, seed = 0 }   # ROA: states per box, horizon (s), seed
    certify = { n = 20000, settle = 4, T = 20.0 }  # certify(): domain samples, settling runs, horizon (s); also invariant, scale
    figure = { n = 4, T = 20.0, slice = 13 }  # report.figure(): trajectories from the half box, seconds each; basin-slice grid points per axis
    view = { n = 3, T = 10.0 } # HTML replay: rollouts from the half box, seconds each

    [[job]]
    name = "acrobot"           # unique; the job's directory name
    source = "acrobot"         # zoo name, built-in name (paper_*), erd:<stem> or a URDF path
                               # (relative to the pipeline file's folder)
    actuated = ["elbow"]       # optional: default from the zoo entry
    target = { elbow = 0.0 }   # optional: joint = value (rad or m)
    domain = { shoulder = [-1.0, 1.0], p_shoulder = [-2.0, 2.0] }   # optional: NAME = [lo, hi]
    effort = { elbow = 8.0 }   # optional: actuator limits (N·m or N) over the URDF's <limit effort>
                               # (inf lifts one); the limits apply to training and evaluation
    recover = "auto"           # optional: a recovery law after training where saturated LQR leaves room
                               # ("auto"), "always" or "never" (the default, as `train`)

Every job is checked before the first one starts: unknown keys, wrong types, the system itself
(`load_system`: unknown source, unknown joint, a target that is not an equilibrium, an empty domain)
and the training config (`TrainConfig` raises on bad values). Problems name the job and the line of
its ``[[job]]`` header (tomllib reports no line numbers, so the headers are found in the text).
"""

from __future__ import annotations

import hashlib
import inspect
import json
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from ..certificate.certify import certify
from ..config import TrainConfig
from ..errors import IdapbcError
from ..evaluation.evaluate import evaluate_run
from ..model import load_system
from ..recovery.trigger import RECOVER_MODES
from ..reporting.report import figure
from ..viewer import view

__all__ = ["Job", "Pipeline", "PipelineError", "load_pipeline", "SMOKE_TRAIN", "SMOKE_EVALUATE", "SMOKE_CERTIFY", "SMOKE_FIGURE", "SMOKE_VIEW"]

PRESETS = ("paper", "fast")
TOP_KEYS = ("description", "defaults", "job")
JOB_KEYS = ("name", "source", "actuated", "target", "domain", "effort", "preset", "train", "recover", "evaluate", "certify", "figure", "view", "description")


def _defaults_of(function, **names) -> dict:
    """{key: default of `function`'s parameter names[key]}: a stage's defaults are its function's own."""
    parameters = inspect.signature(function).parameters
    return {key: parameters[name].default for key, name in names.items()}


EVALUATE_DEFAULTS = _defaults_of(evaluate_run, n="n", T="T", seed="seed", limits="limits")
CERTIFY_DEFAULTS = _defaults_of(certify, n="n", settle="settle", T="settle_T", invariant="invariant", scale="scale")
FIGURE_DEFAULTS = _defaults_of(figure, n="n", T="T", slice="slice_n")
VIEW_DEFAULTS = _defaults_of(view, n="n", T="T")
_SUBTABLE_TYPES = {"evaluate": {"n": int, "T": float, "seed": int, "limits": bool}, "certify": {"n": int, "settle": int, "T": float, "invariant": int, "scale": float}, "figure": {"n": int, "T": float, "slice": int}, "view": {"n": int, "T": float}}

#: What ``--smoke`` does to every job: a few epochs of tiny networks (and no `fallback` gate, which
#: simulates 100 states for 20 s: "auto" becomes "none"), a small ROA and certificate,
#: one short replay (values are upper bounds: a job already smaller keeps its own).
SMOKE_TRAIN = {"epochs": 20, "width": 16, "depth": 1, "samples": 64, "checkpoint_every": 10}
SMOKE_EVALUATE = {"n": 12, "T": 5.0}
SMOKE_CERTIFY = {"n": 256, "settle": 0, "T": 5.0, "invariant": 16}
SMOKE_FIGURE = {"n": 1, "T": 3.0, "slice": 5}
SMOKE_VIEW = {"n": 1, "T": 3.0}

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
_JOB_HEADER_RE = re.compile(r"^\s*\[\[\s*job\s*\]\]\s*(#.*)?$")
_DEFAULTS_HEADER_RE = re.compile(r"^\s*\[\s*defaults\s*\]\s*(#.*)?$")


class PipelineError(IdapbcError):
    """A pipeline file that cannot run; `problems` lists ``(job name, line, message)``."""

    def __init__(self, message: str, problems: list[tuple[str, int | None, str]]):
        super().__init__(message)
        self.problems = problems


@dataclass(frozen=True)
class Job:
    """One validated job of a pipeline (plain data: it crosses process and Ray boundaries).

    Attributes
    ----------
    name : unique name, also the job's directory name.
    source : the source as written in the pipeline; `source_path` is what `load_system` gets
        (URDF paths made absolute, relative to the pipeline file's folder).
    actuated, target, domain, effort : `load_system` arguments (None: the source's defaults).
    preset : ``"paper"`` or ``"fast"``; `train` the overrides as written; `config` the resolved
        `TrainConfig` as a dict (smoke shrinking included).
    evaluate : {"n", "T", "seed"} of the ROA; certify : {"n", "settle", "T"} of `certify`;
    figure : {"n", "T", "slice"} of `report.figure` ("slice": its `slice_n`); view : {"n", "T"} of the HTML replay.
    smoke : shrunk by ``--smoke``.
    recover : ``"auto"``, ``"always"`` or ``"never"``: a recovery law after training, as ``train --recover``.
    line : line of the job's ``[[job]]`` header in the pipeline file (None if not found).
    system_name, actuated_resolved : from loading the system during validation.
    """

    name: str
    source: str
    source_path: str
    actuated: tuple[str, ...] | None
    target: dict | None
    domain: dict | None
    preset: str
    train: dict
    config: dict
    evaluate: dict
    certify: dict
    figure: dict
    view: dict
    smoke: bool = False
    line: int | None = None
    system_name: str = ""
    actuated_resolved: tuple[str, ...] = ()
    description: str = ""
    effort: dict | None = None
    recover: str = "never"

    def system_arguments(self) -> dict:
        """The keyword arguments of `load_system` for this job (after `source_path`)."""
        return {"actuated": self.actuated, "target": self.target, "domain": self.domain, "effort": self.effort}

    def train_config(self) -> TrainConfig:
        return TrainConfig.from_dict(self.config)

    def fingerprint(self) -> str:
        """Hash of everything that decides the job's results (not its line, not the absolute path)."""
        data = {
            "source": self.source,
            "actuated": self.actuated,
            "target": self.target,
            "domain": self.domain,
            **({"effort": self.effort} if self.effort is not None else {}),  # jobs without one keep their old fingerprint
            **({"recover": self.recover} if self.recover != "auto" else {}),  # "auto" was the default: its jobs keep their fingerprint
            "config": self.config,
            "evaluate": self.evaluate,
            "certify": self.certify,
            "figure": {k: v for k, v in self.figure.items() if k != "slice" or v != FIGURE_DEFAULTS["slice"]},  # the default slice: the old fingerprint
            "view": self.view,
            "smoke": self.smoke,
        }
        return hashlib.sha256(json.dumps(data, sort_keys=True, default=list).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Pipeline:
    """A validated pipeline file."""

    path: Path
    sha256: str
    description: str
    jobs: tuple[Job, ...]
    smoke: bool = False
    defaults: dict = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return [job.name for job in self.jobs]

    def select(self, only=None) -> list[Job]:
        """The jobs named in `only` (all when None), in pipeline order; unknown names are an error."""
        if not only:
            return list(self.jobs)
        unknown = [nm for nm in only if nm not in self.names]
        if unknown:
            raise IdapbcError(f"no job called {', '.join(repr(u) for u in unknown)} in '{self.path}'. Valid job names: {', '.join(self.names)}.")
        return [job for job in self.jobs if job.name in set(only)]


# ---------------------------------------------------------------------------------------- checks
def _type_name(kind) -> str:
    return {str: "a string", int: "an integer", float: "a number", bool: "true or false", list: "an array", dict: "a table"}[kind]


def _check_type(value, kind, what: str) -> object:
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if not isinstance(value, kind) or (kind in (int, float) and isinstance(value, bool)):
        raise IdapbcError(f"{what} must be {_type_name(kind)}, got {value!r}")
    return value


def _merge(defaults: dict, entry: dict) -> dict:
    out = dict(defaults)
    for key, value in entry.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = {**out[key], **value}
        else:
            out[key] = value
    return out


def _check_keys(table: dict, allowed, what: str) -> None:
    unknown = [k for k in table if k not in allowed]
    if unknown:
        raise IdapbcError(f"unknown key{'s' if len(unknown) > 1 else ''} {', '.join(repr(k) for k in unknown)} in {what}. Valid keys: {', '.join(allowed)}")


def _resolve_source(source: str, base: Path) -> str:
    """The `load_system` source of a job: names as written, URDF paths made absolute.

    A relative path starts from `base`, the pipeline file's folder (then from the working
    directory, where the file exists only there); a file found in neither is an error that names
    both.
    """
    looks_like_path = source.endswith(".urdf") or "/" in source or source.startswith(("~", "."))
    if not looks_like_path or source.startswith("erd:"):
        return source
    path = Path(source).expanduser()
    relative = not path.is_absolute()
    if relative:
        candidate = base / path
        path = candidate if candidate.exists() or not path.exists() else path
    if not path.is_file():
        where = f" (relative paths in a pipeline start from its folder, {base.resolve()}, then from the working directory, {Path.cwd()})"
        raise IdapbcError(f"URDF file '{path.resolve()}' not found. Fix: check the path{where if relative else ''}.")
    return str(path.resolve())


def _system_arguments(raw: dict) -> dict:
    """The job's `load_system` keyword arguments ``actuated``, ``target``, ``domain`` and ``effort``,
    checked and cleaned (None where absent)."""
    actuated = raw.get("actuated")
    if actuated is not None:
        _check_type(actuated, list, "'actuated'")
        if not actuated or not all(isinstance(a, str) for a in actuated):
            raise IdapbcError(f"'actuated' must be a non-empty array of joint names, e.g. actuated = [\"elbow\"], got {actuated!r}")
        actuated = tuple(actuated)
    target = raw.get("target")
    if target is not None:
        _check_type(target, dict, "'target'")
        target = {k: _check_type(v, float, f"target.{k}") for k, v in target.items()}
    domain = raw.get("domain")
    if domain is not None:
        _check_type(domain, dict, "'domain'")
        clean = {}
        for k, v in domain.items():
            if not (isinstance(v, list) and len(v) == 2):
                raise IdapbcError(f"domain.{k} must be [lo, hi], got {v!r}")
            clean[k] = [_check_type(b, float, f"domain.{k}") for b in v]
        domain = clean
    effort = raw.get("effort")
    if effort is not None:
        _check_type(effort, dict, "'effort'")
        effort = {k: _check_type(v, float, f"effort.{k}") for k, v in effort.items()}
    return {"actuated": actuated, "target": target, "domain": domain, "effort": effort}


def _stage_tables(raw: dict) -> dict:
    """The job's ``evaluate``, ``certify``, ``figure`` and ``view`` tables over their defaults, checked."""
    tables = {}
    for key, defaults in (("evaluate", EVALUATE_DEFAULTS), ("certify", CERTIFY_DEFAULTS), ("figure", FIGURE_DEFAULTS), ("view", VIEW_DEFAULTS)):
        table = _check_type(raw.get(key, {}), dict, f"'{key}'")
        _check_keys(table, tuple(_SUBTABLE_TYPES[key]), f"'{key}'")
        table = {**defaults, **{k: _check_type(v, _SUBTABLE_TYPES[key][k], f"{key}.{k}") for k, v in table.items()}}
        least = 16 if key == "certify" else 1
        if table["n"] < least or table["T"] <= 0 or table.get("settle", 0) < 0:
            raise IdapbcError(f"{key}.n must be ≥ {least} and {key}.T > 0, got n = {table['n']}, T = {table['T']}")
        if table.get("slice", 2) < 2:
            raise IdapbcError(f"{key}.slice (the basin slice's grid points per axis) must be ≥ 2, got {table['slice']}")
        if table.get("seed", 0) < 0:  # numpy's generators refuse it, after the training
            raise IdapbcError(f"{key}.seed must be ≥ 0, got {table['seed']}")
        tables[key] = table
    return tables


def _build_job(raw: dict, base: Path, line: int | None, smoke: bool) -> Job:
    """One `Job` from a ``[[job]]`` table merged over ``[defaults]``; the first problem raises `IdapbcError`."""
    _check_keys(raw, JOB_KEYS, "the job")
    if "name" not in raw:
        raise IdapbcError("missing key 'name'")
    name = _check_type(raw["name"], str, "'name'")
    if not _NAME_RE.match(name):
        raise IdapbcError(f"name {name!r} is not a valid directory name (letters, digits, '_', '-', '.')")
    if "source" not in raw:
        raise IdapbcError("missing key 'source' (zoo name, built-in name, erd:<stem> or URDF path)")
    source = _check_type(raw["source"], str, "'source'")
    system_args = _system_arguments(raw)
    preset = _check_type(raw.get("preset", "paper"), str, "'preset'")
    if preset not in PRESETS:
        raise IdapbcError(f"preset must be one of {', '.join(repr(p) for p in PRESETS)}, got {preset!r}")
    train = dict(_check_type(raw.get("train", {}), dict, "'train'"))
    tables = _stage_tables(raw)
    description = _check_type(raw.get("description", ""), str, "'description'")
    recover = _check_type(raw.get("recover", "never"), str, "'recover'")
    if recover not in RECOVER_MODES:
        raise IdapbcError(f"recover must be one of {', '.join(repr(m) for m in RECOVER_MODES)}, got {recover!r}")

    # the training config: preset, then overrides, then smoke shrinking (TrainConfig validates)
    base_config = TrainConfig.fast().to_dict() if preset == "fast" else TrainConfig().to_dict()
    config = TrainConfig.from_dict({**base_config, **train})
    if smoke:
        config = config.replace(**{k: min(getattr(config, k), v) for k, v in SMOKE_TRAIN.items()}, fallback="none" if config.fallback == "auto" else config.fallback)
        recover = "never"
        for key, small in (("evaluate", SMOKE_EVALUATE), ("certify", SMOKE_CERTIFY), ("figure", SMOKE_FIGURE), ("view", SMOKE_VIEW)):
            tables[key] = {**tables[key], **{k: min(tables[key][k], v) for k, v in small.items()}}

    # the system itself: unknown source, joints, target, domain
    source_path = _resolve_source(source, base)
    try:
        system = load_system(source_path, **system_args)
    except IdapbcError:
        raise
    except Exception as exc:  # e.g. a URDF Pinocchio cannot parse
        raise IdapbcError(f"cannot load source {source!r}: {type(exc).__name__}: {exc}") from None
    return Job(
        name=name,
        source=source,
        source_path=source_path,
        **system_args,
        preset=preset,
        train=train,
        config=config.to_dict(),
        evaluate=tables["evaluate"],
        certify=tables["certify"],
        figure=tables["figure"],
        view=tables["view"],
        smoke=smoke,
        line=line,
        system_name=system.name,
        actuated_resolved=tuple(system.actuated),
        description=description,
        recover=recover,
    )


def _header_lines(text: str, pattern: re.Pattern) -> list[int]:
    return [i for i, line in enumerate(text.splitlines(), 1) if pattern.match(line)]


def load_pipeline(path: str | Path, smoke: bool = False) -> Pipeline:
    """Read and validate a pipeline file; every job is checked before this returns.

    Parameters
    ----------
    path : the TOML file.
    smoke : shrink every job (`SMOKE_TRAIN`, `SMOKE_EVALUATE`, `SMOKE_CERTIFY`, `SMOKE_FIGURE`, `SMOKE_VIEW`) for a quick end-to-end check.

    Raises
    ------
    PipelineError
        (an `IdapbcError`) listing every bad job with the line of its ``[[job]]`` header.
    """
    path = Path(path)
    if not path.is_file():
        raise IdapbcError(f"pipeline file '{path}' not found. Fix: check the path (e.g. pipelines/zoo.toml).")
    text = path.read_text()
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise IdapbcError(f"cannot parse pipeline '{path}': {exc}. Fix: repair the TOML syntax there.") from None

    problems: list[tuple[str, int | None, str]] = []
    unknown = [k for k in data if k not in TOP_KEYS]
    if unknown:
        problems.append(("(top level)", None, f"unknown key(s) {', '.join(repr(k) for k in unknown)}; valid: {', '.join(TOP_KEYS)}"))
    defaults = data.get("defaults", {})
    defaults_line = (_header_lines(text, _DEFAULTS_HEADER_RE) or [None])[0]
    if not isinstance(defaults, dict):
        problems.append(("[defaults]", defaults_line, "must be a table"))
        defaults = {}
    elif "name" in defaults:
        problems.append(("[defaults]", defaults_line, "'name' cannot have a default (every job needs its own)"))
    else:
        bad = [k for k in defaults if k not in JOB_KEYS]
        if bad:
            problems.append(("[defaults]", defaults_line, f"unknown key(s) {', '.join(repr(k) for k in bad)}; valid: {', '.join(JOB_KEYS[1:])}"))
    entries = data.get("job", [])
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        problems.append(("(top level)", None, "'job' must be an array of tables: write each job under a [[job]] header"))
        entries = []
    if not entries and not problems:
        problems.append(("(top level)", None, "no jobs: add at least one [[job]] table"))
    lines = _header_lines(text, _JOB_HEADER_RE)
    if len(lines) != len(entries):
        lines = [None] * len(entries)

    jobs: list[Job] = []
    seen: dict[str, int | None] = {}
    for k, (entry, line) in enumerate(zip(entries, lines)):
        label = entry.get("name") if isinstance(entry.get("name"), str) else f"#{k + 1}"
        try:
            job = _build_job(_merge(defaults, entry), path.parent, line, smoke)
        except IdapbcError as exc:
            problems.append((label, line, str(exc).rstrip(".")))
            continue
        if job.name in seen:
            problems.append((label, line, f"duplicate name (first used by the job at line {seen[job.name]})"))
            continue
        seen[job.name] = line
        jobs.append(job)

    if problems:
        where = lambda ln: f" (line {ln})" if ln else ""  # noqa: E731
        items = [f"job '{nm}'{where(ln)}: {msg}" if not nm.startswith(("(", "[")) else f"{nm}{where(ln)}: {msg}" for nm, ln, msg in problems]
        head = f"pipeline '{path}' has {len(problems)} problem{'s' if len(problems) > 1 else ''}; nothing was run"
        raise PipelineError(head + ":\n  " + "\n  ".join(items) + "\nFix: correct those entries and run again.", problems)
    return Pipeline(
        path=path.resolve(),
        sha256=hashlib.sha256(text.encode()).hexdigest(),
        description=str(data.get("description", "")),
        jobs=tuple(jobs),
        smoke=smoke,
        defaults=defaults,
    )

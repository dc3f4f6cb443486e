"""`load_system`: a URDF path, a zoo name, a built-in analytic name or ``erd:<stem>`` → `System`.

Every bad input raises one `IdapbcError` line that names the problem and the fix.
"""

from __future__ import annotations

import math
import sysconfig
import warnings
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..errors import IdapbcError, NotAnEquilibriumError
from ._pinocchio import load_urdf_plant
from .analytic import ANALYTIC
from .system import EQUILIBRIUM_TOL, System
from .zoo import ZOO, zoo_urdf_path

__all__ = ["DEFAULT_ANGLE_HALF_WIDTH", "DEFAULT_LINEAR_HALF_WIDTH", "DEFAULT_SPEED", "RIGID_SHARE", "erd_robots_dir", "load_system", "resolve_source"]

#: Default training box around x*: ±π/2 rad on angles, ±1 m on prismatic joints (clipped to the
#: joint limits), and momenta ±max(M_ii, RIGID_SHARE·Σ_j|M_ij|)(q*)·1 (rad/s or m/s): every joint moving
#: at up to 1 unit/s, and at least the momentum each joint carries when the whole chain turns rigidly
#: at RIGID_SHARE unit/s (a light distal link's own M_ii alone would hold the chain above it still).
DEFAULT_ANGLE_HALF_WIDTH = math.pi / 2
DEFAULT_LINEAR_HALF_WIDTH = 1.0
DEFAULT_SPEED = 1.0
RIGID_SHARE = 0.1
#: M(q) counts as singular when λ_min ≤ this × max(1, λ_max).
_SINGULAR_RTOL = 1e-10


def erd_robots_dir() -> Path:
    """example-robot-data's `robots/` folder (its wheel ships URDFs and meshes, no Python loader)."""
    for base in {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}:
        candidate = Path(base) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"
        if candidate.is_dir():
            return candidate
    raise IdapbcError("example-robot-data is not installed. Fix: pip install example-robot-data")


def _erd_urdf(stem: str) -> Path:
    matches = sorted(erd_robots_dir().glob(f"*/urdf/{stem}.urdf"))
    if not matches:
        close = sorted(p.stem for p in erd_robots_dir().glob("*/urdf/*.urdf") if stem.split("_")[0] in p.stem)
        hint = f" Close names: {', '.join(close[:12])}." if close else ""
        raise IdapbcError(f"no example-robot-data URDF named '{stem}'.{hint} Fix: use erd:<file stem>, e.g. erd:double_pendulum_continuous.")
    return matches[0]


def resolve_source(source) -> tuple[str, object, Path | None, dict]:
    """-> (name, plant-or-None, urdf path or None, registry defaults)."""
    if isinstance(source, str) and source in ZOO:
        entry = ZOO[source]
        defaults = {"actuated": entry.actuated, "target": dict(entry.target), "domain": {n: (lo, hi) for n, lo, hi in entry.domain}}
        return source, None, zoo_urdf_path(source), defaults
    if isinstance(source, str) and source in ANALYTIC:
        spec = ANALYTIC[source]
        defaults = {"actuated": spec.actuated, "target": dict(spec.target), "domain": {n: (lo, hi) for n, lo, hi in spec.domain}}
        return source, spec.build(), None, defaults
    if isinstance(source, str) and source.startswith("erd:"):
        path = _erd_urdf(source[4:])
        return path.stem, None, path, {}
    path = Path(source)
    if not path.is_file() and (path.suffix in (".urdf", ".xml") or len(path.parts) > 1):
        raise IdapbcError(f"URDF file '{source}' not found. Fix: check the path (relative paths start from {Path.cwd()}).")
    if not path.is_file():
        raise IdapbcError(
            f"'{source}' is neither a URDF file nor a known name. Fix: pass a path to a .urdf file, a zoo name "
            f"({', '.join(ZOO)}), a built-in name ({', '.join(ANALYTIC)}) or erd:<example-robot-data URDF stem>."
        )
    return path.stem, None, path, {}


def _check_mass_matrix(plant, joints, q: np.ndarray, where: str) -> None:
    M = plant.mass_matrix(q)
    eig = np.linalg.eigvalsh(M)
    bad = eig[:, 0] <= _SINGULAR_RTOL * np.maximum(1.0, eig[:, -1])
    if not bad.any():
        return
    k = int(np.argmax(bad))
    diag = np.diagonal(M[k])
    massless = [j.name for j, d in zip(joints, diag) if d <= _SINGULAR_RTOL * max(1.0, eig[k, -1])]
    which = f"joint(s) {', '.join(massless)} move(s) no mass or inertia" if massless else "the links are massless in some direction"
    raise IdapbcError(
        f"M(q) is singular {where} (smallest eigenvalue {eig[k, 0]:.3g}): {which}. "
        "Fix: give every moving link an <inertial> with positive mass and a non-degenerate inertia."
    )


def _named_values(values, names: Sequence[str], what: str) -> dict[str, object]:
    out = dict(values)
    unknown = [k for k in out if k not in names]
    if unknown:
        raise IdapbcError(f"unknown {what} '{unknown[0]}'. Valid names: {', '.join(names)}")
    return out


def load_system(
    source,
    actuated: Sequence[str] | None = None,
    target: Mapping[str, float] | Sequence[float] | None = None,
    domain: Mapping[str, tuple[float, float]] | tuple[Sequence[float], Sequence[float]] | None = None,
    effort: Mapping[str, float] | None = None,
) -> System:
    """Build a `System` from a URDF path, a zoo name, a built-in analytic name or ``erd:<stem>``.

    Parameters
    ----------
    source : path to a .urdf; a zoo name (`idapbc_pin.model.zoo.zoo_names()`); a built-in analytic
        name (``paper_double_pendulum``, ``paper_cartpole``, ``paper_mass_spring_damper``); or
        ``erd:<stem>`` for example-robot-data's ``robots/*/urdf/<stem>.urdf``.
    actuated : names of the actuated joints (order = order of u). Default: the registry entry's.
    target : {joint: value} overriding the zero configuration (rad or m), or a full (nq,) q*.
        The target state is (q*, 0) and must be an assignable equilibrium: g⊥ f(x*) = 0.
    domain : {coordinate: (lo, hi)} overrides of the default box (coordinate = joint name or
        ``p_<joint>``), or a full (lo, hi) pair of (n,) arrays.
    effort : {actuated joint: limit} overriding the URDF's ``<limit effort>`` (N·m or N; inf lifts
        it). An actuated URDF joint with no effort limit (absent or 0) is unlimited, with a warning.

    Raises
    ------
    IdapbcError
        For any bad input, with a one-line message that names the problem and the fix.
    """
    name, plant, path, defaults = resolve_source(source)
    if plant is None:
        plant = load_urdf_plant(path)
    joints = plant.joints
    actuated, B, B_perp = _actuation(joints, defaults.get("actuated", ()) if actuated is None else actuated)
    q_star = _target(joints, defaults.get("target", {}) if target is None else target)
    _check_mass_matrix(plant, joints, q_star[None], "at the target")
    x_star = np.concatenate([q_star, np.zeros(len(joints))])
    lo, hi = _domain(joints, x_star, plant.mass_matrix(q_star[None])[0], defaults.get("domain", {}) if domain is None else domain)
    rng = np.random.default_rng(0)
    nq = len(joints)
    _check_mass_matrix(plant, joints, lo[:nq] + (hi[:nq] - lo[:nq]) * rng.random((16, nq)), "inside the domain")
    system = System(
        name=name,
        source=str(path) if path is not None else name,
        joints=joints,
        actuated=actuated,
        B=B,
        B_perp=B_perp,
        x_star=x_star,
        domain=(lo, hi),
        plant=plant,
        effort=_effort(joints, actuated, effort, from_urdf=path is not None),
    )
    _check_equilibrium(system)
    return system


def _actuation(joints, actuated) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """(actuated names, B (nq, m), B⊥ (nq − m, nq)) with every name checked."""
    names = tuple(j.name for j in joints)
    actuated = tuple(actuated)
    if not actuated:
        raise IdapbcError(f"no actuated joint given. Fix: pass --actuated JOINT (one or more of: {', '.join(names)}).")
    for a in actuated:
        if a not in names:
            raise IdapbcError(f"unknown actuated joint '{a}'. Valid joints: {', '.join(names)}.")
    if len(set(actuated)) != len(actuated):
        raise IdapbcError(f"actuated joints listed twice: {', '.join(actuated)}. Fix: name each joint once.")
    B = np.zeros((len(names), len(actuated)))
    for col, a in enumerate(actuated):
        B[names.index(a), col] = 1.0
    B_perp = np.eye(len(names))[[i for i, nm in enumerate(names) if nm not in actuated]]
    return actuated, B, B_perp


def _target(joints, target) -> np.ndarray:
    """q* (nq,) from {joint: value} (others 0) or a full sequence, inside the joint limits."""
    names = tuple(j.name for j in joints)
    if isinstance(target, Mapping):
        values = _named_values(target, names, "target joint")
        q_star = np.array([float(values.get(nm, 0.0)) for nm in names])
    else:
        q_star = np.asarray(target, float).ravel()
        if q_star.shape != (len(names),):
            raise IdapbcError(f"target has {q_star.size} values but the system has {len(names)} joints ({', '.join(names)}).")
    if not np.all(np.isfinite(q_star)):
        raise IdapbcError("target contains NaN or inf. Fix: give finite joint values.")
    for j, val in zip(joints, q_star):
        if not (j.lower - 1e-12 <= val <= j.upper + 1e-12):
            raise IdapbcError(f"target {j.name}={val:g} is outside the joint limits [{j.lower:g}, {j.upper:g}]. Fix: choose a value inside them.")
    return q_star


def _domain(joints, x_star: np.ndarray, M_star: np.ndarray, domain) -> tuple[np.ndarray, np.ndarray]:
    """The training box (lo, hi), each (n,): defaults around x*, then the overrides, checked."""
    names = tuple(j.name for j in joints)
    nq = len(names)
    lo, hi = _default_domain(joints, x_star[:nq], M_star)
    state_names = names + tuple(f"p_{nm}" for nm in names)
    if isinstance(domain, Mapping):
        for key, bounds in _named_values(domain, state_names, "domain coordinate").items():
            i = state_names.index(key)
            lo[i], hi[i] = (float(b) for b in bounds)
    else:
        lo, hi = (np.asarray(b, float).ravel().copy() for b in domain)
        if lo.shape != (2 * nq,) or hi.shape != (2 * nq,):
            raise IdapbcError(f"domain bounds must each have {2 * nq} values ({', '.join(state_names)}).")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))) or np.any(hi <= lo):
        i = int(np.argmax(~(hi > lo) | ~np.isfinite(lo) | ~np.isfinite(hi)))
        raise IdapbcError(f"empty or infinite domain on {state_names[i]}: [{lo[i]:g}, {hi[i]:g}]. Fix: give finite bounds with lo < hi.")
    if np.any(x_star < lo) or np.any(x_star > hi):
        i = int(np.argmax((x_star < lo) | (x_star > hi)))
        raise IdapbcError(f"the target {state_names[i]}={x_star[i]:g} lies outside the domain [{lo[i]:g}, {hi[i]:g}]. Fix: widen the domain.")
    return lo, hi


def _effort(joints, actuated, overrides, from_urdf: bool) -> np.ndarray:
    """(m,) effort limits of the actuated joints: the overrides, else the URDF's, else +inf."""
    by_name = {j.name: j.effort for j in joints}
    given = _named_values(overrides or {}, actuated, "actuated joint in effort")
    out = []
    for a in actuated:
        value = float(given[a]) if a in given else by_name[a]
        if not (value > 0):
            raise IdapbcError(f"effort limit of '{a}' must be > 0 (inf for none), got {value:g}. Fix: e.g. --effort {a}=10.")
        if a not in given and from_urdf and math.isinf(value):
            warnings.warn(f"actuated joint '{a}' has no <limit effort> in the URDF: its torque is unlimited (pass --effort {a}=VALUE to set one)", stacklevel=3)
        out.append(value)
    return np.array(out)


def _check_equilibrium(system: System) -> None:
    residual = system.equilibrium_residual()
    if np.any(np.abs(residual) > EQUILIBRIUM_TOL):
        bad = {nm: float(r) for nm, r in zip(_perp_row_names(system), residual) if abs(r) > EQUILIBRIUM_TOL}
        rows = ", ".join(f"{nm}={r:+.4g}" for nm, r in bad.items())
        raise NotAnEquilibriumError(
            f"the target is not an assignable equilibrium: g⊥f(x*) ≠ 0, residual torque/force (N·m or N) on "
            f"unactuated joints: {rows}. Fix: choose a target where the unactuated joints are at rest under gravity "
            "(e.g. upright or hanging), or actuate those joints.",
            bad,
        )


def _perp_row_names(system: System) -> list[str]:
    return [f"q̇_{nm}" for nm in system.coordinate_names] + list(system.unactuated)


def _default_domain(joints, q_star: np.ndarray, M_star: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    half_q = np.array([DEFAULT_ANGLE_HALF_WIDTH if j.is_angle else DEFAULT_LINEAR_HALF_WIDTH for j in joints])
    lo_q = np.maximum(q_star - half_q, [j.lower for j in joints])
    hi_q = np.minimum(q_star + half_q, [j.upper for j in joints])
    half_p = np.maximum(np.abs(np.diagonal(M_star)), RIGID_SHARE * np.abs(M_star).sum(axis=1)) * DEFAULT_SPEED
    return np.concatenate([lo_q, -half_p]), np.concatenate([hi_q, half_p])

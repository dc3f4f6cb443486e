"""`inspect`: what a URDF (or built-in system) is, and whether Neural IDA-PBC can be set up on it.

Reports joints (type, axis, limits, damping, moved mass), dimensions, actuated / unactuated joints,
the underactuation degree, whether x* is an assignable equilibrium (g⊥f(x*) = 0), cond(M(q*)),
the open-loop eigenvalues at x* and the controllability of the linearisation (A, g(x*)). Without
actuated joints, every single joint is tried as the actuated one ("actuated candidates").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import IdapbcError, NotAnEquilibriumError
from .controllability import controllability_rank
from .loading import load_system
from .system import System

__all__ = ["Candidate", "ModelReport", "format_report", "inspect_system"]


@dataclass(frozen=True)
class Candidate:
    """One choice of actuated joints and what it gives at the target."""

    actuated: tuple[str, ...]
    assignable: bool
    controllable_rank: int | None  # rank of the controllability matrix, None when not assignable
    note: str = ""


@dataclass(frozen=True)
class ModelReport:
    """Everything `idapbc-pin inspect` prints; `system` is None when no actuation was chosen."""

    source: str
    name: str
    pinocchio_nq: int | None
    joints: tuple
    system: System | None
    cond_M: float
    open_loop_eigenvalues: np.ndarray | None
    controllable_rank: int | None
    candidates: tuple[Candidate, ...]


def _controllable_rank(system: System) -> int:
    A, Bx = system.linearization()
    return controllability_rank(A, Bx)


def inspect_system(source, actuated=None, target=None, domain=None, effort=None) -> ModelReport:
    """Build the report for `source` (anything `load_system` accepts).

    With `actuated` None and no registry default, each joint alone is tried as the actuated one.
    """
    try:
        system = load_system(source, actuated=actuated, target=target, domain=domain, effort=effort)
    except IdapbcError as exc:
        if actuated is not None or "no actuated joint" not in str(exc):
            raise
        system = None
    candidates: list[Candidate] = []
    if system is None:
        probe = None
        for j in _joint_names(source):
            try:
                s = load_system(source, actuated=[j], target=target, domain=domain)
            except NotAnEquilibriumError as exc:
                residuals = ", ".join(f"{nm}={r:+.4g}" for nm, r in exc.residuals.items())
                candidates.append(Candidate((j,), False, None, f"residual torque/force {residuals}"))
                continue
            probe = probe or s
            candidates.append(Candidate((j,), True, _controllable_rank(s)))
        if probe is None:  # no single joint gives an assignable target; fully actuated always does
            probe = load_system(source, actuated=_joint_names(source), target=target, domain=domain)
        names = probe.coordinate_names
        if len(names) > 1:
            candidates.append(Candidate(names, True, _controllable_rank(load_system(source, actuated=names, target=target, domain=domain)), "fully actuated"))
        ref = probe
    else:
        ref = system
    q_star = ref.x_star[: ref.nq]
    M_star = ref.mass_matrix(q_star)
    A = ref.df_dx(ref.x_star)
    return ModelReport(
        source=ref.source,
        name=ref.name,
        pinocchio_nq=int(ref.plant.nq_config),
        joints=ref.joints,
        system=system,
        cond_M=float(np.linalg.cond(M_star)),
        open_loop_eigenvalues=np.linalg.eigvals(A) if system is not None else None,
        controllable_rank=_controllable_rank(system) if system is not None else None,
        candidates=tuple(candidates),
    )


def _joint_names(source) -> list[str]:
    # load_system needs an actuated joint; a fully actuated probe only reads the joint list.
    from ._pinocchio import load_urdf_plant
    from .loading import resolve_source

    _, plant, path, _ = resolve_source(source)
    plant = plant if plant is not None else load_urdf_plant(path)
    return [j.name for j in plant.joints]


def _fmt_limit(lo: float, hi: float) -> str:
    return "none" if not np.isfinite(lo) else f"[{lo:.3g}, {hi:.3g}]"


def format_report(r: ModelReport) -> str:
    """Human-readable text of a `ModelReport` (what the CLI prints)."""
    lines = [f"{r.name}  ({r.source})"]
    nv = len(r.joints)
    dims = f"nq = {nv} minimal coordinates (one per joint), nv = {nv}, state n = {2 * nv}"
    if r.pinocchio_nq is not None and r.pinocchio_nq != nv:
        dims += f"; Pinocchio nq = {r.pinocchio_nq} (continuous joints as cos/sin)"
    lines.append(dims)
    lines.append("")
    w = 2 + max(len(j.name) for j in r.joints)
    lines.append(f"  {'joint':<{w}}{'type':<16}{'axis':<18}{'limits':<20}{'damping':>9}{'mass kg':>10}{'effort':>9}")
    for j in r.joints:
        axis = "(" + ", ".join(f"{a:g}" for a in j.axis) + ")"
        effort = "none" if not np.isfinite(j.effort) else f"{j.effort:.4g}"
        lines.append(f"  {j.name:<{w}}{j.kind:<16}{axis:<18}{_fmt_limit(j.lower, j.upper):<20}{j.damping:>9.3g}{j.mass:>10.4g}{effort:>9}")
    lines.append("")
    lines.append(f"cond(M(q*)) = {r.cond_M:.4g}")
    s = r.system
    if s is not None:
        lines.append(f"actuated: {', '.join(s.actuated)}   unactuated: {', '.join(s.unactuated) or '-'}   underactuation degree: {s.nv - s.m}")
        limits = ", ".join(f"{nm} {'unlimited' if not np.isfinite(e) else f'|u| ≤ {e:.4g}'}" for nm, e in zip(s.actuated, s.effort))
        lines.append(f"effort limits (applied in every evaluation; --no-limits lifts them): {limits}")
        q_star = ", ".join(f"{nm}={v:g}" for nm, v in zip(s.coordinate_names, s.x_star[: s.nq]))
        lines.append(f"target x*: {q_star}, at rest  ->  assignable equilibrium: yes (|g⊥f(x*)| = {np.abs(s.equilibrium_residual()).max():.2g})")
        eig = r.open_loop_eigenvalues
        unstable = int(np.sum(eig.real > 1e-9))
        lines.append("open-loop eigenvalues at x*: " + ", ".join(_fmt_complex(e) for e in sorted(eig, key=lambda z: z.real)) + f"  ({unstable} unstable)")
        ok = r.controllable_rank == s.n
        lines.append(f"linearisation at x*: controllability rank {r.controllable_rank}/{s.n} -> {'controllable' if ok else 'NOT controllable'}")
        lo, hi = s.domain
        lines.append("training domain X: " + ", ".join(f"{nm} [{a:.3g}, {b:.3g}]" for nm, a, b in zip(s.state_names, lo, hi)))
    if r.candidates:
        lines.append("")
        lines.append("actuated candidates (no --actuated given):")
        for c in r.candidates:
            label = ", ".join(c.actuated) + (f" ({c.note})" if c.note and c.assignable else "")
            if c.assignable:
                n = 2 * nv
                verdict = "controllable" if c.controllable_rank == n else f"not controllable (rank {c.controllable_rank}/{n})"
                lines.append(f"  --actuated {label:<30} target assignable, linearisation {verdict}")
            else:
                lines.append(f"  --actuated {label:<30} target NOT assignable: {c.note}")
    return "\n".join(lines)


def _fmt_complex(z: complex) -> str:
    re = 0.0 if abs(z.real) < 1e-12 else z.real
    return f"{re:.3g}" if abs(z.imag) < 1e-12 else f"{re:.3g}{z.imag:+.3g}j"

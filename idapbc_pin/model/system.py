"""A system is data: dimensions, actuation, target, training domain and a plant back-end.

`load_system` turns a URDF path, a zoo name, a built-in analytic name or an example-robot-data
robot into a `System`. Every quantity is batched over a leading dimension N (a single state may
drop it) and computed in float64. Notation (paper eq. OLPH, DESIGN §2): x = (q, p) ∈ ℝⁿ, n = 2 nv,
ẋ = f(x) + g(x)u, g = [0; B], g⊥ = [[I, 0], [0, B⊥]], G = [gᵀ; g⊥].
"""

from __future__ import annotations

import math
import sysconfig
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ._pinocchio import JointInfo, load_urdf_plant
from .analytic import ANALYTIC
from ..errors import IdapbcError, NotAnEquilibriumError
from .zoo import ZOO, zoo_urdf_path

__all__ = [
    "DEFAULT_ANGLE_HALF_WIDTH",
    "DEFAULT_LINEAR_HALF_WIDTH",
    "DEFAULT_SPEED",
    "EQUILIBRIUM_TOL",
    "System",
    "erd_robots_dir",
    "load_system",
]

#: Default training box around x*: ±π/2 rad on angles, ±1 m on prismatic joints (clipped to the
#: joint limits), and momenta ±M_ii(q*)·1 (rad/s or m/s), i.e. every joint moving at up to 1 unit/s.
DEFAULT_ANGLE_HALF_WIDTH = math.pi / 2
DEFAULT_LINEAR_HALF_WIDTH = 1.0
DEFAULT_SPEED = 1.0
#: A target is an assignable equilibrium when every component of g⊥ f(x*) is below this (N·m or N).
EQUILIBRIUM_TOL = 1e-8
#: M(q) counts as singular when λ_min ≤ this × max(1, λ_max).
_SINGULAR_RTOL = 1e-10


def _batch(a, width: int, what: str) -> tuple[np.ndarray, bool]:
    a = np.asarray(a, dtype=float)
    single = a.ndim == 1
    a = a[None] if single else a
    if a.ndim != 2 or a.shape[1] != width:
        raise ValueError(f"{what} must have shape (N, {width}) or ({width},), got {np.shape(a)}")
    return a, single


def _unbatch(a: np.ndarray, single: bool) -> np.ndarray:
    return a[0] if single else a


@dataclass(frozen=True, eq=False)
class System:
    """An input-affine system with x = (q, p), ready for Neural IDA-PBC.

    Attributes
    ----------
    name : short name (zoo name, built-in name or URDF stem).
    source : where it came from (path or name).
    joints : one `JointInfo` per minimal coordinate, in model order.
    actuated : names of the actuated coordinates, in the order of the input u.
    B : (nv, m) input matrix, columns of the identity picking the actuated joints.
    B_perp : (nv − m, nv) left annihilator of B (rows of the identity, unactuated joints).
    x_star : (n,) target state (q*, 0).
    domain : (lo, hi), each (n,): the training box X.
    plant : back-end (Pinocchio or closed form); not part of the public API.
    effort : (m,) actuator limits |u_i| ≤ effort_i of the actuated joints (N·m or N), in the order
        of u; +inf where a joint has none (URDF ``<limit effort>`` of 0 or absent, built-in systems).
    """

    name: str
    source: str
    joints: tuple[JointInfo, ...]
    actuated: tuple[str, ...]
    B: np.ndarray
    B_perp: np.ndarray
    x_star: np.ndarray
    domain: tuple[np.ndarray, np.ndarray]
    plant: object = field(repr=False)
    effort: np.ndarray | None = None

    def __post_init__(self):
        effort = np.full(self.B.shape[1], np.inf) if self.effort is None else np.asarray(self.effort, dtype=np.float64).reshape(-1)
        if effort.shape != (self.B.shape[1],) or np.any(~(effort > 0)):
            raise IdapbcError(f"effort limits need {self.B.shape[1]} positive values (inf for none), got {self.effort!r}.")
        effort.flags.writeable = False
        object.__setattr__(self, "effort", effort)

    @property
    def limited(self) -> bool:
        """True when at least one actuated joint has a finite effort limit."""
        return bool(np.isfinite(self.effort).any())

    def saturate(self, u) -> np.ndarray:
        """u clipped to ±effort per input: (N, m) -> (N, m) (unchanged where unlimited)."""
        return np.clip(np.asarray(u, dtype=np.float64), -self.effort, self.effort)

    # ------------------------------------------------------------------ dimensions and names
    @property
    def nq(self) -> int:
        """Number of minimal coordinates (one per 1-DoF joint)."""
        return len(self.joints)

    @property
    def nv(self) -> int:
        """Velocity dimension (= nq in minimal coordinates)."""
        return len(self.joints)

    @property
    def n(self) -> int:
        """State dimension 2 nq."""
        return 2 * len(self.joints)

    @property
    def m(self) -> int:
        """Number of inputs."""
        return self.B.shape[1]

    @property
    def coordinate_names(self) -> tuple[str, ...]:
        """Joint names, one per q coordinate."""
        return tuple(j.name for j in self.joints)

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the n state coordinates: joint names, then ``p_<joint>``."""
        return self.coordinate_names + tuple(f"p_{j.name}" for j in self.joints)

    @property
    def unactuated(self) -> tuple[str, ...]:
        """Names of the unactuated joints."""
        return tuple(name for name in self.coordinate_names if name not in self.actuated)

    @property
    def angle_mask(self) -> np.ndarray:
        """(n,) bool: True for angle coordinates (wrapped to (−π, π] when judging success)."""
        return np.array([j.is_angle for j in self.joints] + [False] * self.nq)

    @property
    def actuated_mask(self) -> np.ndarray:
        """(n,) bool: True on the momenta of actuated joints (rows the input reaches)."""
        return np.concatenate([np.zeros(self.nq, bool), self.B.sum(axis=1) > 0])

    # ------------------------------------------------------------------ state maps
    def split(self, x) -> tuple[np.ndarray, np.ndarray]:
        """x = (q, p) -> (q, v) with v = M(q)⁻¹p. Shapes (N, n) -> (N, nq), (N, nq)."""
        xb, single = _batch(x, self.n, "x")
        q, p = xb[:, : self.nq], xb[:, self.nq :]
        v = self.plant.velocity(q, p)
        return _unbatch(q.copy(), single), _unbatch(v, single)

    def state_from(self, q, v) -> np.ndarray:
        """(q, v) -> x = (q, M(q) v). Shapes (N, nq), (N, nq) -> (N, n)."""
        qb, single = _batch(q, self.nq, "q")
        vb, _ = _batch(v, self.nq, "v")
        p = np.einsum("nij,nj->ni", self.plant.mass_matrix(qb), vb)
        return _unbatch(np.concatenate([qb, p], axis=1), single)

    # ------------------------------------------------------------------ energies
    def mass_matrix(self, q) -> np.ndarray:
        """M(q): (N, nq) -> (N, nq, nq), symmetric positive definite (kg, kg·m²)."""
        qb, single = _batch(q, self.nq, "q")
        return _unbatch(self.plant.mass_matrix(qb), single)

    def potential(self, q) -> np.ndarray:
        """U(q): (N, nq) -> (N,), joules (gravity 9.81 m/s² along −z for URDFs)."""
        qb, single = _batch(q, self.nq, "q")
        return _unbatch(self.plant.potential(qb), single)

    def hamiltonian(self, x) -> np.ndarray:
        """H(x) = ½ pᵀM(q)⁻¹p + U(q): (N, n) -> (N,), joules."""
        xb, single = _batch(x, self.n, "x")
        return _unbatch(self.plant.hamiltonian(xb[:, : self.nq], xb[:, self.nq :]), single)

    # ------------------------------------------------------------------ open loop (eq. OLPH)
    def f(self, x) -> np.ndarray:
        """Drift f(x) = (∂H/∂p, −∂H/∂q − D v): (N, n) -> (N, n)."""
        xb, single = _batch(x, self.n, "x")
        return _unbatch(self.plant.f(xb[:, : self.nq], xb[:, self.nq :]), single)

    def f_and_df_dx(self, x) -> tuple[np.ndarray, np.ndarray]:
        """f(x) (N, n) and its Jacobian ∂f/∂x (N, n, n) in one pass (cheaper than both apart)."""
        xb, single = _batch(x, self.n, "x")
        f, J = self.plant.f_and_jacobian(xb[:, : self.nq], xb[:, self.nq :])
        return _unbatch(f, single), _unbatch(J, single)

    def df_dx(self, x) -> np.ndarray:
        """∂f/∂x: (N, n) -> (N, n, n)."""
        return self.f_and_df_dx(x)[1]

    def g(self, x) -> np.ndarray:
        """Input matrix g(x) = [0; B]: (N, n) -> (N, n, m) (constant for these systems)."""
        xb, single = _batch(x, self.n, "x")
        g = np.concatenate([np.zeros((self.nq, self.m)), self.B])
        return _unbatch(np.broadcast_to(g, (xb.shape[0],) + g.shape).copy(), single)

    def g_perp(self, x) -> np.ndarray:
        """Left annihilator g⊥ = [[I, 0], [0, B⊥]]: (N, n) -> (N, n − m, n), g⊥ g = 0."""
        xb, single = _batch(x, self.n, "x")
        nq = self.nq
        gp = np.zeros((self.n - self.m, self.n))
        gp[:nq, :nq] = np.eye(nq)
        gp[nq:, nq:] = self.B_perp
        return _unbatch(np.broadcast_to(gp, (xb.shape[0],) + gp.shape).copy(), single)

    def G(self, x) -> np.ndarray:
        """G(x) = [gᵀ; g⊥], square and invertible: (N, n) -> (N, n, n)."""
        return np.concatenate([np.swapaxes(self.g(x), -1, -2), self.g_perp(x)], axis=-2)

    def forward_dynamics(self, q, v, tau) -> np.ndarray:
        """Accelerations of the true plant (Pinocchio `aba` with joint damping, or the closed form).

        Shapes (N, nq) ×3 -> (N, nq); tau in N·m / N on every joint (use B u for inputs u).
        """
        qb, single = _batch(q, self.nq, "q")
        vb, _ = _batch(v, self.nq, "v")
        tb, _ = _batch(tau, self.nq, "tau")
        return _unbatch(self.plant.forward_dynamics(qb, vb, tb), single)

    def linearization(self) -> tuple[np.ndarray, np.ndarray]:
        """(A, B_x) = (∂f/∂x(x*), g(x*)), shapes (n, n), (n, m): the linear model at the target."""
        return self.df_dx(self.x_star), self.g(self.x_star)

    def equilibrium_residual(self, x=None) -> np.ndarray:
        """g⊥ f(x) at x (default x*), shape (n − m,): zero iff x is an assignable equilibrium."""
        x = self.x_star if x is None else np.asarray(x, float)
        return self.g_perp(x) @ self.f(x)


# ====================================================================== loading
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


def _resolve(source) -> tuple[str, object, Path | None, dict]:
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

    Raises
    ------
    IdapbcError
        For any bad input, with a one-line message that names the problem and the fix.
    """
    name, plant, path, defaults = _resolve(source)
    if plant is None:
        plant = load_urdf_plant(path)
    joints = plant.joints
    names = tuple(j.name for j in joints)
    nq = len(joints)

    # --- actuation
    actuated = tuple(defaults.get("actuated", ()) if actuated is None else actuated)
    if not actuated:
        raise IdapbcError(f"no actuated joint given. Fix: pass --actuated JOINT (one or more of: {', '.join(names)}).")
    for a in actuated:
        if a not in names:
            raise IdapbcError(f"unknown actuated joint '{a}'. Valid joints: {', '.join(names)}.")
    if len(set(actuated)) != len(actuated):
        raise IdapbcError(f"actuated joints listed twice: {', '.join(actuated)}. Fix: name each joint once.")
    B = np.zeros((nq, len(actuated)))
    for col, a in enumerate(actuated):
        B[names.index(a), col] = 1.0
    unact = [i for i, nm in enumerate(names) if nm not in actuated]
    B_perp = np.eye(nq)[unact]

    # --- target
    if target is None:
        target = defaults.get("target", {})
    if isinstance(target, Mapping):
        values = _named_values(target, names, "target joint")
        q_star = np.array([float(values.get(nm, 0.0)) for nm in names])
    else:
        q_star = np.asarray(target, float).ravel()
        if q_star.shape != (nq,):
            raise IdapbcError(f"target has {q_star.size} values but the system has {nq} joints ({', '.join(names)}).")
    if not np.all(np.isfinite(q_star)):
        raise IdapbcError("target contains NaN or inf. Fix: give finite joint values.")
    for j, val in zip(joints, q_star):
        if not (j.lower - 1e-12 <= val <= j.upper + 1e-12):
            raise IdapbcError(f"target {j.name}={val:g} is outside the joint limits [{j.lower:g}, {j.upper:g}]. Fix: choose a value inside them.")

    _check_mass_matrix(plant, joints, q_star[None], "at the target")
    x_star = np.concatenate([q_star, np.zeros(nq)])

    # --- domain
    lo, hi = _default_domain(joints, q_star, plant.mass_matrix(q_star[None])[0])
    state_names = names + tuple(f"p_{nm}" for nm in names)
    if domain is None:
        domain = defaults.get("domain", {})
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

    rng = np.random.default_rng(0)
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
    )
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
    return system


def _perp_row_names(system: System) -> list[str]:
    return [f"q̇_{nm}" for nm in system.coordinate_names] + list(system.unactuated)


def _default_domain(joints, q_star: np.ndarray, M_star: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    half_q = np.array([DEFAULT_ANGLE_HALF_WIDTH if j.is_angle else DEFAULT_LINEAR_HALF_WIDTH for j in joints])
    lo_q = np.maximum(q_star - half_q, [j.lower for j in joints])
    hi_q = np.minimum(q_star + half_q, [j.upper for j in joints])
    half_p = np.abs(np.diagonal(M_star)) * DEFAULT_SPEED
    return np.concatenate([lo_q, -half_p]), np.concatenate([hi_q, half_p])

"""Pinocchio back-end: a URDF becomes a plant whose M, U, f and ∂f/∂x come from Pinocchio.

Only this module touches `pinocchio.Model` / `pinocchio.Data`. Minimal coordinates hold one number
per 1-DoF joint (revolute, prismatic, continuous); continuous joints, which Pinocchio stores as
(cos θ, sin θ), are mapped with the same convention as ``pin.integrate(model, pin.neutral(model), θ)``.
"""

from __future__ import annotations

import math
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

from ._mechanics import mechanical_f, mechanical_jacobian
from .chain import Chain
from .joint import JointInfo
from ..errors import IdapbcError

__all__ = ["PinocchioPlant", "load_urdf_plant"]

#: Step of the central difference that gives Φ = vᵀ(∂²M/∂q²)v from Pinocchio's exact first-order
#: Coriolis matrix; truncation ~h², round-off ~1e-16/h: both ≈1e-11 relative.
_FD_STEP = 6e-6

_JOINT_KINDS = {
    "JointModelRX": ("revolute", (1.0, 0.0, 0.0)),
    "JointModelRY": ("revolute", (0.0, 1.0, 0.0)),
    "JointModelRZ": ("revolute", (0.0, 0.0, 1.0)),
    "JointModelRevoluteUnaligned": ("revolute", None),
    "JointModelRUBX": ("continuous", (1.0, 0.0, 0.0)),
    "JointModelRUBY": ("continuous", (0.0, 1.0, 0.0)),
    "JointModelRUBZ": ("continuous", (0.0, 0.0, 1.0)),
    "JointModelRevoluteUnboundedUnaligned": ("continuous", None),
    "JointModelPX": ("prismatic", (1.0, 0.0, 0.0)),
    "JointModelPY": ("prismatic", (0.0, 1.0, 0.0)),
    "JointModelPZ": ("prismatic", (0.0, 0.0, 1.0)),
    "JointModelPrismaticUnaligned": ("prismatic", None),
}

_MULTI_DOF_FIX = {
    "JointModelFreeFlyer": "a floating joint (6 DoF)",
    "JointModelPlanar": "a planar joint (3 DoF)",
    "JointModelSpherical": "a spherical joint (3 DoF)",
    "JointModelSphericalZYX": "a spherical joint (3 DoF)",
    "JointModelTranslation": "a translation joint (3 DoF)",
}


def _check_xml(path: Path) -> None:
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise IdapbcError(
            f"malformed URDF XML in '{path}': {exc}. Fix: repair the XML (an editor or `xmllint --noout` points at the line)."
        ) from None
    if root.tag != "robot":
        raise IdapbcError(f"'{path}' is XML but not a URDF (root element <{root.tag}>, expected <robot>). Fix: pass a .urdf file.")
    for link in root.iter("link"):
        _check_inertial(link, path)
    for joint in root.iter("joint"):
        jtype = joint.get("type", "")
        if jtype in ("floating", "planar"):
            raise IdapbcError(
                f"joint '{joint.get('name')}' in '{path}' is {jtype} (a free base): idapbc-pin models fixed-base "
                "chains of 1-DoF joints. Fix: fix the base to the world, or replace it by prismatic/revolute joints."
            )
        mimic = joint.find("mimic")
        if mimic is not None:  # Pinocchio would build it as an independent joint, without a word
            raise IdapbcError(
                f"joint '{joint.get('name')}' in '{path}' mimics joint '{mimic.get('joint', '?')}' (<mimic>): mimic joints are not "
                "supported, and the joint would be modelled as an independent one. Fix: remove the <mimic> tag and model the "
                "coupling as one joint, or actuate/free the joint explicitly."
            )


#: Relative slack of the inertia checks (rounding in hand-written URDFs).
_INERTIA_RTOL = 1e-9


def _check_inertial(link: ET.Element, path: Path) -> None:
    """A link's <inertial>: an error for a negative mass or an inertia that is not positive
    semi-definite; a warning for moments that break the triangle inequality or zero mass with inertia."""
    inertial = link.find("inertial")
    if inertial is None:
        return
    name = link.get("name", "?")
    fix = f"Fix: correct the <inertial> of link '{name}' in '{path}'."
    mass_el, inertia_el = inertial.find("mass"), inertial.find("inertia")
    try:
        mass = float(mass_el.get("value", "0")) if mass_el is not None else 0.0
        keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
        ixx, ixy, ixz, iyy, iyz, izz = (float(inertia_el.get(k, "0")) if inertia_el is not None else 0.0 for k in keys)
    except ValueError as exc:
        raise IdapbcError(f"link '{name}' has a non-numeric inertial value ({exc}). {fix}") from None
    if not math.isfinite(mass) or mass < 0:
        raise IdapbcError(f"link '{name}' has mass {mass:g} kg: a mass must be finite and ≥ 0. {fix}")
    I = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    if not np.all(np.isfinite(I)):
        raise IdapbcError(f"link '{name}' has a non-finite inertia. {fix}")
    moments = np.linalg.eigvalsh(I)
    scale = max(float(np.abs(moments).max()), 1e-300)
    if moments[0] < -_INERTIA_RTOL * scale:
        raise IdapbcError(f"link '{name}' has an inertia that is not positive semi-definite (principal moments {', '.join(f'{m:.3g}' for m in moments)} kg·m²). {fix}")
    a, b, c = moments
    # Many published URDFs (10 of example-robot-data's 45) break the next two slightly: warn, and let
    # the mass-matrix check of `load_system` refuse what actually makes M(q) singular.
    if c > a + b + _INERTIA_RTOL * scale:
        warnings.warn(
            f"link '{name}' in '{path}' has principal moments {a:.3g}, {b:.3g}, {c:.3g} kg·m² that break the triangle "
            f"inequality ({c:.3g} > {a:.3g} + {b:.3g}): no rigid body has them; check its <inertial>",
            stacklevel=4,
        )
    if mass == 0 and moments[-1] > 0:
        warnings.warn(f"link '{name}' in '{path}' has zero mass but a non-zero inertia; check its <inertial>", stacklevel=4)


def _build_model(path: Path) -> pin.Model:
    _check_xml(path)
    try:
        return pin.buildModelFromUrdf(str(path))
    except (RuntimeError, ValueError) as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise IdapbcError(f"Pinocchio could not build a model from '{path}': {msg}. Fix: check the URDF's links and joints.") from None


def _limit(value: float) -> float:
    """A URDF effort or speed limit: 0 (Pinocchio's value when `<limit>` lacks it) means none."""
    return value if math.isfinite(value) and value > 0 else math.inf


def _joint_infos(model: pin.Model) -> tuple[JointInfo, ...]:
    infos = []
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        name, short = model.names[jid], joint.shortname()
        if short not in _JOINT_KINDS:
            what = _MULTI_DOF_FIX.get(short, f"a {short} joint with nq={joint.nq}, nv={joint.nv}")
            raise IdapbcError(
                f"joint '{name}' is {what}: idapbc-pin handles chains of 1-DoF joints (revolute, continuous, "
                "prismatic). Fix: fix the base to the world, or split the joint into 1-DoF joints."
            )
        kind, axis = _JOINT_KINDS[short]
        if axis is None:
            axis = tuple(float(a) for a in np.asarray(joint.extract().axis).ravel())
        lower, upper = float(model.lowerPositionLimit[joint.idx_q]), float(model.upperPositionLimit[joint.idx_q])
        if kind == "continuous" or not lower < upper:  # a <limit> with lower == upper means "no limit"
            lower, upper = -math.inf, math.inf
        infos.append(
            JointInfo(
                name=name,
                kind=kind,
                axis=axis,
                lower=lower,
                upper=upper,
                damping=float(model.damping[joint.idx_v]),
                mass=float(model.inertias[jid].mass),
                effort=_limit(float(model.effortLimit[joint.idx_v])),
                speed=_limit(float(model.velocityLimit[joint.idx_v])),
            )
        )
    if not infos:
        raise IdapbcError("the URDF has no movable joint. Fix: add revolute, continuous or prismatic joints.")
    return tuple(infos)


class PinocchioPlant:
    """Mechanical plant evaluated by Pinocchio, batched over states (pooled Pinocchio calls where
    Pinocchio has them, a loop over states elsewhere).

    Holds the `pin.Model` and one `pin.Data` (scratch space; not thread-safe: use one plant per
    thread or process). Use through `idapbc_pin.System`, not directly.
    """

    def __init__(self, model: pin.Model, path: Path):
        self.model = model
        self.data = model.createData()
        self.path = path
        self.joints = _joint_infos(model)
        self.nv = model.nv
        self.damping = np.array([j.damping for j in self.joints])
        # Map minimal coordinates -> Pinocchio configuration, vectorised.
        direct_q, direct_v, circ_q, circ_v = [], [], [], []
        for jid in range(1, model.njoints):
            joint = model.joints[jid]
            if joint.nq == 1:
                direct_q.append(joint.idx_q)
                direct_v.append(joint.idx_v)
            else:
                circ_q.append(joint.idx_q)
                circ_v.append(joint.idx_v)
        self._direct = (np.array(direct_q, dtype=int), np.array(direct_v, dtype=int))
        self._circ = (np.array(circ_q, dtype=int), np.array(circ_v, dtype=int))
        self._permuted = direct_q != direct_v
        # (nv,) bool: the joint of each coordinate hangs from the fixed base (`f_rows`).
        self._at_base = np.zeros(self.nv, bool)
        for jid in range(1, model.njoints):
            self._at_base[model.joints[jid].idx_v] = model.parents[jid] == 0
        # Batched v = M⁻¹p (ABA of a gravity-free copy at zero velocity) and ∇U (RNEA at rest):
        # Pinocchio's pooled algorithms, one thread, no Python loop (see `f`).
        self._free = model.copy()
        self._free.gravity = pin.Motion.Zero()
        self._pools: dict[int, tuple] = {}
        self._pool, self._free_pool = self._pools_for(1)

    def chain(self) -> Chain:
        """The kinematic tree as plain arrays, in the order of the minimal coordinates (`model.chain`)."""
        m = self.model
        order = sorted(range(1, m.njoints), key=lambda j: m.joints[j].idx_v)
        index = {jid: k for k, jid in enumerate(order)}
        placements = [m.jointPlacements[j] for j in order]
        inertias = [m.inertias[j] for j in order]
        infos = [self.joints[j - 1] for j in order]
        return Chain(parent=tuple(index.get(int(m.parents[j]), -1) for j in order),
                     prismatic=tuple(info.kind == "prismatic" for info in infos),
                     rotation=np.array([np.array(pl.rotation) for pl in placements]),
                     translation=np.array([np.array(pl.translation) for pl in placements]),
                     axis=np.array([info.axis for info in infos], float),
                     mass=np.array([float(i.mass) for i in inertias]), lever=np.array([np.array(i.lever) for i in inertias]),
                     inertia=np.array([np.array(i.inertia) for i in inertias]),
                     armature=np.array([float(m.armature[m.joints[j].idx_v]) for j in order]), gravity=np.array(m.gravity.linear, float))

    @property
    def nq_config(self) -> int:
        """Size of Pinocchio's configuration vector (continuous joints count 2: cos, sin)."""
        return int(self.model.nq)

    def _pools_for(self, threads: int) -> tuple:
        """(pool of the model, pool of its gravity-free copy) for `threads` threads, built once."""
        if threads not in self._pools:
            self._pools[threads] = (pin.ModelPool(self.model, threads), pin.ModelPool(self._free, threads))
        return self._pools[threads]

    def __reduce__(self):  # Model pickles; Data is rebuilt (worker processes).
        return (PinocchioPlant, (self.model, self.path))

    # ----------------------------------------------------------------- configuration mapping
    def config(self, q: np.ndarray) -> np.ndarray:
        """Minimal coordinates (N, nv) -> Pinocchio configurations (N, model.nq)."""
        if not len(self._circ[0]):
            return q[:, self._direct[1]] if self._permuted else np.array(q, dtype=float)
        out = np.empty((q.shape[0], self.model.nq))
        iq, iv = self._direct
        out[:, iq] = q[:, iv]
        iq, iv = self._circ
        out[:, iq] = np.cos(q[:, iv])
        out[:, iq + 1] = np.sin(q[:, iv])
        return out

    # ----------------------------------------------------------------- energies
    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q): (N, nv) -> (N, nv, nv), kg·m² / kg."""
        m, d = self.model, self.data
        return np.stack([np.array(pin.crba(m, d, qc)) for qc in self.config(q)])

    def potential(self, q: np.ndarray) -> np.ndarray:
        """U(q): (N, nv) -> (N,), joules."""
        m, d = self.model, self.data
        return np.array([pin.computePotentialEnergy(m, d, qc) for qc in self.config(q)])

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """∇U(q) (generalised gravity): (N, nv) -> (N, nv)."""
        m, d = self.model, self.data
        return np.stack([np.array(pin.computeGeneralizedGravity(m, d, qc)) for qc in self.config(q)])

    def hamiltonian(self, q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """H = ½ pᵀM⁻¹p + U: (N, nv), (N, nv) -> (N,), joules (M⁻¹p batched: `_inverse_mass_times`)."""
        p = np.asarray(p, float)
        if p.shape[0] == 0:
            return np.zeros(0)
        qc = self.config(q)
        m, d = self.model, self.data
        potential = np.array([pin.computePotentialEnergy(m, d, qk) for qk in qc])
        return 0.5 * np.einsum("ni,ni->n", p, self._inverse_mass_times(qc, p)) + potential

    # ----------------------------------------------------------------- dynamics
    def _velocity_and_gravity(self, qc: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """v = M⁻¹p and ∇U for configurations qc (N, model.nq), p (N, nv): (N, nv) each.

        M⁻¹p is the ABA of the gravity-free model at zero velocity with torque p, ∇U the RNEA at
        rest; both through `abaInParallel`/`rneaInParallel` (one thread), equal to
        `computeMinverse(q) @ p` and `computeGeneralizedGravity(q)` to rounding (tests/test_dynamics).
        """
        N, nv = p.shape
        zeros = np.zeros((nv, N), order="F")
        grad_U = pin.rneaInParallel(1, self._pool, np.asfortranarray(qc.T), zeros, zeros)
        return self._inverse_mass_times(qc, p), np.array(grad_U).reshape(nv, N).T

    def _inverse_mass_times(self, qc: np.ndarray, p: np.ndarray) -> np.ndarray:
        """M(q)⁻¹p for configurations qc (N, model.nq), p (N, nv): the ABA of the gravity-free model
        at zero velocity with torque p (`abaInParallel`, one thread) -> (N, nv)."""
        N, nv = p.shape
        zeros = np.zeros((nv, N), order="F")
        v = pin.abaInParallel(1, self._free_pool, np.asfortranarray(qc.T), zeros, np.asfortranarray(p.T))
        return np.array(v).reshape(nv, N).T

    def velocity(self, q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """v = M(q)⁻¹ p: (N, nv) each -> (N, nv)."""
        return self._inverse_mass_times(self.config(q), np.asarray(p, float))

    def f(self, q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Open-loop f(x) = (v, Cᵀv − ∇U − D v): (N, nv) each -> (N, 2 nv).

        v and ∇U batched by Pinocchio; the Coriolis matrix C(q, v) per state (no pooled version).
        """
        m, d = self.model, self.data
        qc = self.config(q)
        v, grad_U = self._velocity_and_gravity(qc, np.asarray(p, float))
        coriolis = pin.computeCoriolisMatrix
        nv = v.shape[1]
        C = np.array([coriolis(m, d, qk, vk) for qk, vk in zip(qc, v)]).reshape(len(v), nv, nv)
        p_dot = np.einsum("nji,nj->ni", C, v) - grad_U - self.damping * v
        return np.concatenate([v, p_dot], axis=1)

    def f_rows(self, q: np.ndarray, p: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Rows `rows` (k,) of f(x), indices into (q̇, ṗ): (N, nv) ×2 -> (N, k); `f`'s own values
        where a row needs the Coriolis term, else equal to them to rounding.

        The Coriolis term (Cᵀv)_j = ∂T/∂q_j (kinetic energy T at fixed v) is zero for a joint that
        hangs from the fixed base: moving it carries every body after it rigidly, which leaves T
        unchanged. So when every momentum row asked for belongs to such a joint (the input rows of
        a pendubot or a cart-pole), ṗ_j = −∇U_j − D_j v_j needs no per-state Coriolis matrix.
        """
        rows = np.asarray(rows, dtype=int)
        joints = rows[rows >= self.nv] - self.nv
        if not self._at_base[joints].all():
            return self.f(q, p)[:, rows]
        v, grad_U = self._velocity_and_gravity(self.config(q), np.asarray(p, float))
        return np.concatenate([v, -grad_U - self.damping * v], axis=1)[:, rows]

    def f_and_jacobian(self, q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """f(x) (N, 2nv) and ∂f/∂x (N, 2nv, 2nv) in one pass.

        ∂M/∂q_j · v comes exact from RNEA derivatives (DESIGN §2); Φ = vᵀ(∂²M/∂q_i∂q_j)v from a
        central difference of Pinocchio's exact 2Cᵀ(q, v)v = [vᵀ M_i v]_i at fixed v.
        """
        m, d = self.model, self.data
        N, nv = q.shape
        zeros = np.zeros(nv)
        M_inv = np.empty((N, nv, nv))
        v = np.empty((N, nv))
        W = np.empty((N, nv, nv))
        Phi = np.empty((N, nv, nv))
        grad_U = np.empty((N, nv))
        hess_U = np.empty((N, nv, nv))
        h = _FD_STEP
        shifts = h * np.eye(nv)
        q_plus = self.config((q[:, None, :] + shifts).reshape(-1, nv)).reshape(N, nv, -1)
        q_minus = self.config((q[:, None, :] - shifts).reshape(-1, nv)).reshape(N, nv, -1)
        coriolis, gravity = pin.computeCoriolisMatrix, pin.computeGeneralizedGravity
        for k, qc in enumerate(self.config(q)):
            Mi = pin.computeMinverse(m, d, qc)
            vk = Mi @ p[k]
            grad_U[k] = gravity(m, d, qc)
            dg = pin.computeGeneralizedGravityDerivatives(m, d, qc)
            hess_U[k] = dg
            W[k] = pin.computeRNEADerivatives(m, d, qc, zeros, vk)[0] - dg
            M_inv[k] = Mi
            v[k] = vk
            qp, qm = q_plus[k], q_minus[k]
            for j in range(nv):
                Phi[k, :, j] = vk @ (coriolis(m, d, qp[j], vk) - coriolis(m, d, qm[j], vk))
        Phi /= h  # 2Cᵀv differenced over 2h
        Phi = 0.5 * (Phi + np.swapaxes(Phi, 1, 2))
        f = mechanical_f(v, W, grad_U, self.damping)
        return f, mechanical_jacobian(M_inv, v, W, Phi, hess_U, self.damping)

    def forward_dynamics(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, threads: int = 1) -> np.ndarray:
        """Accelerations from Pinocchio's ABA with joint damping (`abaInParallel`, which ignores
        `model.damping`, so −D v is added to τ): (N, nv) ×3 -> (N, nv)."""
        q, v, tau = np.asarray(q, float), np.asarray(v, float), np.asarray(tau, float)
        if q.shape[0] == 0:
            return np.zeros_like(q)
        pool, _ = self._pools_for(int(threads))
        qc = np.asfortranarray(self.config(q).T)
        a = pin.abaInParallel(int(threads), pool, qc, np.asfortranarray(v.T), np.asfortranarray((tau - self.damping * v).T))
        return a.reshape(q.shape[1], q.shape[0]).T  # a fresh (nv, N) array

    def momenta(self, q: np.ndarray, v: np.ndarray, threads: int = 1) -> np.ndarray:
        """p = M(q) v as the RNEA of the gravity-free model at zero velocity: (N, nv) ×2 -> (N, nv)."""
        q, v = np.asarray(q, float), np.asarray(v, float)
        if q.shape[0] == 0:
            return np.zeros_like(q)
        _, free_pool = self._pools_for(int(threads))
        qc = np.asfortranarray(self.config(q).T)
        zeros = np.zeros((v.shape[1], v.shape[0]), order="F")
        p = pin.rneaInParallel(int(threads), free_pool, qc, zeros, np.asfortranarray(v.T))
        return p.reshape(q.shape[1], q.shape[0]).T  # a fresh (nv, N) array

    def scaled(self, mass: float = 1.0, length: float = 1.0, damping: float = 1.0) -> "PinocchioPlant":
        """Every link's mass and rotational inertia × mass, joint placements and levers × length
        (inertia × length²: geometric similarity), joint damping × damping."""
        model = self.model.copy()
        for jid in range(1, model.njoints):
            I = model.inertias[jid]
            model.inertias[jid] = pin.Inertia(float(I.mass) * mass, np.array(I.lever) * length, np.array(I.inertia) * (mass * length**2))
            placement = model.jointPlacements[jid]
            model.jointPlacements[jid] = pin.SE3(np.array(placement.rotation), np.array(placement.translation) * length)
        if damping != 1.0:
            if not np.any(np.asarray(model.damping) != 0):
                raise IdapbcError("the plant has no joint damping to scale. Fix: drop damping=... or add <dynamics damping> to the URDF.")
            model.damping = np.asarray(model.damping) * damping
        return PinocchioPlant(model, self.path)


def load_urdf_plant(path: str | Path) -> PinocchioPlant:
    """Build a `PinocchioPlant` from a URDF file, with a clear error for every bad input."""
    path = Path(path)
    if not path.is_file():
        raise IdapbcError(f"URDF file '{path}' not found. Fix: pass the path of an existing .urdf file, a zoo name or a built-in name (`idapbc-pin inspect --list`).")
    return PinocchioPlant(_build_model(path), path)

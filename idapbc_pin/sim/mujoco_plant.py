"""An independent judge: the true plant of a URDF robot evaluated by MuJoCo instead of Pinocchio.

    truth = mujoco_judge(system)                 # same actuation, target, domain, effort limits
    roa(truth, {"LQR": LQRController(system)})   # the controller keeps its own (Pinocchio) model

`MujocoPlant` implements the `Plant` protocol. What the judge uses (accelerations, M(q), U(q),
p = M v, v = M⁻¹p, H) comes from MuJoCo loading the system's URDF file with the reference settings
of `idapbc_pin.sim._mujoco`; the port-Hamiltonian drift f(x) and ∂f/∂x, which MuJoCo does not give
in (q, p) form and which only controllers and training use, stay the Pinocchio plant's.
MuJoCo is an optional dependency (``pip install mujoco``, or the ``dev`` extra).
"""

from __future__ import annotations

import numpy as np

from ..errors import IdapbcError
from ._mujoco import full_mass_matrix, import_mujoco, joint_addresses, mujoco_model

__all__ = ["MujocoPlant", "mujoco_judge"]

#: Largest relative difference between MuJoCo's and the Pinocchio plant's M(q), U(q) differences or
#: damping accepted when the judge is built (the two agree to ~1e-12 on the zoo; a scaled or edited
#: plant is off by percent).
AGREEMENT_RTOL = 1e-6


class MujocoPlant:
    """A URDF plant evaluated by MuJoCo, one state at a time, batched over a leading dimension N.

    Every method loops over the N states in Python with one ``MjData`` (about 10 µs per state for
    the zoo's 2–3 joints): not thread-safe, use one plant per thread or process (it pickles by
    rebuilding from the Pinocchio plant). Coordinates are the Pinocchio plant's minimal coordinates;
    joints are matched by name and a URDF ``continuous`` joint is a MuJoCo hinge with one qpos.

    Parameters
    ----------
    base : the system's Pinocchio plant (`PinocchioPlant`): its ``path`` is the URDF MuJoCo loads,
        its ``joints`` the coordinate order; f and ∂f/∂x are delegated to it.
    """

    def __init__(self, base):
        path = getattr(base, "path", None)
        if path is None:
            raise IdapbcError("the MuJoCo judge needs a URDF robot; this plant has no URDF file. Fix: use the Pinocchio judge.")
        self._mj = import_mujoco()
        self.base = base
        self.path = path
        self.joints = tuple(base.joints)
        self.nv = int(base.nv)
        self.mj_model = mujoco_model(path)
        self.mj_data = self._mj.MjData(self.mj_model)
        self._qpos, self._dof = joint_addresses(self.mj_model, [j.name for j in self.joints], f"'{path}'")
        self.damping = np.array(self.mj_model.dof_damping[self._dof], dtype=float)
        _check_agreement(self, base)

    def __reduce__(self):  # MjData is scratch space: rebuilt in the worker from the Pinocchio plant
        return (MujocoPlant, (self.base,))

    @property
    def qpos_addresses(self) -> np.ndarray:
        """(nv,) int: MuJoCo's qpos address of each of the plant's coordinates."""
        return self._qpos

    @property
    def dof_addresses(self) -> np.ndarray:
        """(nv,) int: MuJoCo's dof address of each of the plant's coordinates."""
        return self._dof

    @property
    def nq_config(self) -> int:
        """Size of MuJoCo's qpos (continuous joints count 1)."""
        return int(self.mj_model.nq)

    # ----------------------------------------------------------------- one state
    def _at(self, q_k: np.ndarray) -> None:
        """Position stage (kinematics, M(q) and its factorisation) at one configuration (nv,)."""
        self.mj_data.qpos[self._qpos] = q_k
        self._mj.mj_fwdPosition(self.mj_model, self.mj_data)

    def _times_mass(self, q: np.ndarray, vec: np.ndarray, solve: bool) -> np.ndarray:
        """M(q) vec (or M(q)⁻¹ vec if `solve`): (N, nv) ×2 -> (N, nv), via ``mj_mulM`` / ``mj_solveM``."""
        full_in, full_out = np.zeros((1, self.mj_model.nv)), np.zeros((1, self.mj_model.nv))
        out = np.empty_like(vec)
        for k in range(q.shape[0]):
            self._at(q[k])
            full_in[0, self._dof] = vec[k]
            if solve:
                self._mj.mj_solveM(self.mj_model, self.mj_data, full_out, full_in)
            else:
                self._mj.mj_mulM(self.mj_model, self.mj_data, full_out[0], full_in[0])
            out[k] = full_out[0, self._dof]
        return out

    # ----------------------------------------------------------------- the Plant protocol
    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q): (N, nv) -> (N, nv, nv), kg·m² / kg."""
        q = np.asarray(q, float)
        out = np.empty((q.shape[0], self.nv, self.nv))
        idx = np.ix_(self._dof, self._dof)
        for k in range(q.shape[0]):
            self._at(q[k])
            out[k] = full_mass_matrix(self.mj_model, self.mj_data)[idx]
        return out

    def potential(self, q: np.ndarray) -> np.ndarray:
        """U(q): (N, nv) -> (N,), joules (MuJoCo's ``mj_energyPos``)."""
        q = np.asarray(q, float)
        out = np.empty(q.shape[0])
        for k in range(q.shape[0]):
            self._at(q[k])
            self._mj.mj_energyPos(self.mj_model, self.mj_data)
            out[k] = self.mj_data.energy[0]
        return out

    def momenta(self, q: np.ndarray, v: np.ndarray, threads: int = 1) -> np.ndarray:
        """p = M(q) v: (N, nv) ×2 -> (N, nv); `threads` is accepted and ignored."""
        return self._times_mass(np.asarray(q, float), np.asarray(v, float), solve=False)

    def velocity(self, q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """v = M(q)⁻¹ p: (N, nv) ×2 -> (N, nv)."""
        return self._times_mass(np.asarray(q, float), np.asarray(p, float), solve=True)

    def hamiltonian(self, q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """H = ½ pᵀM⁻¹p + U: (N, nv) ×2 -> (N,), joules."""
        p = np.asarray(p, float)
        return 0.5 * np.einsum("ni,ni->n", p, self.velocity(q, p)) + self.potential(q)

    def forward_dynamics(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, threads: int = 1) -> np.ndarray:
        """Accelerations ``qacc`` of ``mj_forward`` with joint damping: (N, nv) ×3 -> (N, nv).

        tau on every joint (N·m or N) as ``qfrc_applied``; constraints are off, so this is
        M⁻¹(τ − D v − C v − ∇U). `threads` is accepted and ignored (a loop over states).
        """
        q, v, tau = (np.asarray(a, float) for a in (q, v, tau))
        m, d = self.mj_model, self.mj_data
        out = np.empty_like(q)
        for k in range(q.shape[0]):
            d.qpos[self._qpos] = q[k]
            d.qvel[self._dof] = v[k]
            d.qfrc_applied[self._dof] = tau[k]
            self._mj.mj_forward(m, d)
            out[k] = d.qacc[self._dof]
        return out

    def f(self, q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Open-loop f(x) (N, 2 nv): the Pinocchio plant's (not used by the judge)."""
        return self.base.f(q, p)

    def f_rows(self, q: np.ndarray, p: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Rows `rows` of f(x) (N, k): the Pinocchio plant's (not used by the judge)."""
        return self.base.f_rows(q, p, rows)

    def f_and_jacobian(self, q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """f(x) (N, 2 nv) and ∂f/∂x (N, 2 nv, 2 nv): the Pinocchio plant's (not used by the judge)."""
        return self.base.f_and_jacobian(q, p)

    def scaled(self, mass: float = 1.0, length: float = 1.0, damping: float = 1.0):
        """Not supported: MuJoCo judges the URDF file as written."""
        raise IdapbcError(
            "scaling masses, lengths or damping is not supported by the MuJoCo judge (it loads the URDF as written). "
            "Fix: drop the mismatch, or use the Pinocchio judge."
        )


def _check_agreement(plant: MujocoPlant, base) -> None:
    """Refuse a Pinocchio plant that is not its URDF file (a scaled copy): damping, M(q) and
    U(q) − U(q₀) compared on a few seeded configurations."""
    q = np.random.default_rng(0).uniform(-1.0, 1.0, (4, plant.nv))
    pairs = (
        ("joint damping", plant.damping, np.asarray(base.damping, float)),
        ("M(q)", plant.mass_matrix(q), base.mass_matrix(q)),
        ("U(q) − U(q₀)", np.diff(plant.potential(q)), np.diff(base.potential(q))),
    )
    for what, mine, theirs in pairs:
        scale = max(float(np.abs(theirs).max()), 1e-12)
        if float(np.abs(mine - theirs).max()) > AGREEMENT_RTOL * scale:
            raise IdapbcError(
                f"MuJoCo's {what} from '{plant.path}' differs from the system's plant (a scaled or edited plant?). "
                "Fix: build the MuJoCo judge from the system as loaded, before any mismatch."
            )


def mujoco_judge(system):
    """`system` with a `MujocoPlant` as the true plant (``system.with_plant``).

    Parameters
    ----------
    system : a `System` loaded from a URDF (zoo name, path, ``erd:`` robot or a run's system).

    Returns
    -------
    `System`: the same actuation, target, domain and effort limits; pass it as the judge to
    `simulate`, `roa` or `roa_radius` with controllers built on `system`.

    Raises
    ------
    IdapbcError
        For a built-in analytic system (no URDF), a missing `mujoco` package, or a URDF whose
        MuJoCo model differs from the plant (module `idapbc_pin.sim._mujoco`).
    """
    base = system.plant
    if isinstance(base, MujocoPlant):
        return system
    if getattr(base, "path", None) is None:
        raise IdapbcError(
            f"the MuJoCo judge needs a URDF robot; '{system.name}' is a built-in analytic system. "
            "Fix: use the Pinocchio judge (its closed form is exact), or load the robot from a URDF."
        )
    return system.with_plant(MujocoPlant(base))

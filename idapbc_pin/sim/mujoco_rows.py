"""The robustness suite's true plants evaluated by MuJoCo: one MuJoCo model per varied row.

`MujocoRowPlants` is `idapbc_pin.model.variations.RowPlants` with MuJoCo as the engine: the same
``accel(q, v, tau)`` over a batch whose rows each carry their own plant. A row's varied parameters
are the suite's (`plant_families`, `varied_model`); what MuJoCo takes from them is data, not
algorithm:

* a row with a varied Pinocchio model gets a copy of the reference ``MjModel``
  (`idapbc_pin.sim._mujoco`) with every moving link's mass, centre of mass and rotational inertia
  about it, and every joint's armature, set from that model. Both engines express a link's inertia
  in the frame of the joint that moves it (a URDF joint's origin), so the copy is a plain transfer:
  ``body_ipos`` = the lever, ``body_inertia`` and ``body_iquat`` = the eigen-decomposition of I_c
  (a principal value may be negative where the suite's rank-one change leaves the physically
  consistent cone; MuJoCo's algorithms, like Pinocchio's, need only M(q) ≻ 0);
* viscous damping and smooth Coulomb friction, −D v − cf·arctan(`COULOMB_SLOPE`·v), are added to
  the applied torques (``qfrc_applied``) with MuJoCo's own ``dof_damping`` set to zero, so each RK4
  stage sees the friction of its own speeds, as in `RowPlants`.

The accelerations are ``qacc`` of ``mj_forward`` (constraints and contacts off), one call per row
and stage from Python (about 2 µs each).
"""

from __future__ import annotations

import copy

import numpy as np

from ..model.variations import COULOMB_SLOPE
from ._mujoco import import_mujoco

__all__ = ["MujocoRowPlants", "mujoco_copy_of"]


def mujoco_copy_of(plant, model) -> "object":
    """A copy of `plant`'s ``MjModel`` (`MujocoPlant`) with the inertias and armature of the
    Pinocchio model `model` (a `varied_model` of its base plant) and no joint damping."""
    mj = import_mujoco()
    out = copy.copy(plant.mj_model)
    for i, dof in enumerate(plant.dof_addresses):
        jid = i + 1  # Pinocchio joint of coordinate i (the plant's joints, in the model's order)
        body = int(out.dof_bodyid[dof])
        inertia = model.inertias[jid]
        evals, vecs = np.linalg.eigh(np.array(inertia.inertia, float))
        if np.linalg.det(vecs) < 0:
            vecs[:, 0] = -vecs[:, 0]
        quat = np.zeros(4)
        mj.mju_mat2Quat(quat, vecs.reshape(-1))
        out.body_mass[body] = float(inertia.mass)
        out.body_ipos[body] = np.array(inertia.lever, float)
        out.body_inertia[body] = evals
        out.body_iquat[body] = quat
        out.dof_armature[dof] = float(np.asarray(model.armature, float)[i])
    out.dof_damping[plant.dof_addresses] = 0.0
    mj.mj_setConst(out, mj.MjData(out))  # subtree masses and other constants of the new inertias
    return out


class MujocoRowPlants:
    """A batch of true plants evaluated by MuJoCo, one per row (module docstring).

    Parameters
    ----------
    plant : the nominal `MujocoPlant` (its ``base`` is the Pinocchio plant the rows vary).
    models : length-N list of varied `pin.Model` or None (the nominal).
    damping : (N, nv) viscous damping of each row (N·m·s/rad or N·s/m), the nominal's included.
    coulomb : (N, nv) Coulomb coefficients (N·m or N).
    """

    def __init__(self, plant, models: list, damping: np.ndarray, coulomb: np.ndarray):
        self._mj = import_mujoco()
        self.plant = plant
        self.N = len(models)
        nv = int(plant.nv)
        self.damping = np.asarray(damping, float).reshape(self.N, nv)
        self.coulomb = np.asarray(coulomb, float).reshape(self.N, nv)
        nominal = copy.copy(plant.mj_model)
        nominal.dof_damping[plant.dof_addresses] = 0.0
        self._pairs = []  # (MjModel, MjData) of each row; the nominal rows share one
        shared = (nominal, self._mj.MjData(nominal))
        for mdl in models:
            if mdl is None:
                self._pairs.append(shared)
            else:
                own = mujoco_copy_of(plant, mdl)
                self._pairs.append((own, self._mj.MjData(own)))
        self._qpos, self._dof = plant.qpos_addresses, plant.dof_addresses
        self._args = (plant, list(models), self.damping, self.coulomb)

    def __reduce__(self):  # MjModel/MjData are rebuilt in a worker process
        return (MujocoRowPlants, self._args)

    def friction(self, v: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Joint friction torques −D v − cf·arctan(100 v) of `rows` (k,) at speeds v (k, nv)."""
        return -self.damping[rows] * v - self.coulomb[rows] * np.arctan(COULOMB_SLOPE * v)

    def accel(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """v̇ of every row: (N, nv) ×3 -> (N, nv), tau the applied joint torques (friction added here)."""
        tau = tau + self.friction(v, np.arange(self.N))
        forward, qpos, dof = self._mj.mj_forward, self._qpos, self._dof
        out = np.empty_like(q)
        for k, (m, d) in enumerate(self._pairs):
            d.qpos[qpos] = q[k]
            d.qvel[dof] = v[k]
            d.qfrc_applied[dof] = tau[k]
            forward(m, d)
            out[k] = d.qacc[dof]
        return out

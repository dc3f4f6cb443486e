"""MuJoCo from a URDF, set up as an independent reference for the rigid-body dynamics.

Only this module, `mujoco_plant` and `mujoco_rows` touch ``mujoco.MjModel`` / ``mujoco.MjData``; `mujoco` is an
optional dependency (the ``dev`` extra), imported on first use. The settings below are the ones
``tests/test_mujoco_reference.py`` checks against Pinocchio on every zoo robot:

- compiler: ``discardvisual``, ``fusestatic`` (the fixed base joins the world body; no effect on the
  dynamics), ``balanceinertia="false"``, ``boundmass="0"``, ``boundinertia="0"`` (masses and
  inertias exactly as written), ``angle="radian"``; spelled out so that a change of MuJoCo's
  defaults cannot slip in;
- ``<visual>`` and ``<collision>`` elements are dropped before loading: contacts are off, so geometry
  only matters as a source of inertia, which MuJoCo takes from ``<inertial>`` when a link has one
  and which Pinocchio never takes from geometry (and mesh files need not be found);
- gravity (0, 0, −9.81) m/s², contacts and every constraint (joint limits) disabled, so that
  ``qacc`` of ``mj_forward`` is the unconstrained M⁻¹(τ − D v − C v − ∇U);
- ``<dynamics damping>`` arrives as ``dof_damping``; armature and friction loss must be zero
  (`joint_addresses` refuses them: the Pinocchio plant has neither).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..errors import IdapbcError

__all__ = ["full_mass_matrix", "import_mujoco", "joint_addresses", "mujoco_model"]

#: Compiler attributes of the reference set-up (see the module docstring).
COMPILER = {
    "discardvisual": "true",
    "fusestatic": "true",
    "balanceinertia": "false",
    "boundmass": "0",
    "boundinertia": "0",
    "angle": "radian",
}

#: Gravity of every URDF plant, m/s² (the same as Pinocchio's default).
GRAVITY = (0.0, 0.0, -9.81)


def import_mujoco():
    """The `mujoco` module, or a one-line `IdapbcError` with the install hint."""
    try:
        import mujoco
    except ImportError:
        raise IdapbcError(
            "the MuJoCo judge needs the `mujoco` package, which is not installed. "
            "Fix: pip install mujoco (or pip install 'idapbc-pin[dev]')."
        ) from None
    return mujoco


def _urdf_for_mujoco(path: Path) -> str:
    """The URDF's XML without geometry and with the reference compiler settings."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise IdapbcError(f"MuJoCo judge: cannot read the URDF '{path}' ({exc}). Fix: restore the file.") from None
    for link in root.iter("link"):
        for child in [c for c in link if c.tag in ("visual", "collision")]:
            link.remove(child)
    extension = root.find("mujoco")
    if extension is None:
        extension = ET.SubElement(root, "mujoco")
    compiler = extension.find("compiler")
    if compiler is None:
        compiler = ET.SubElement(extension, "compiler")
    for key, value in COMPILER.items():
        compiler.set(key, value)
    return ET.tostring(root, encoding="unicode")


def mujoco_model(path):
    """``mujoco.MjModel`` of the URDF at `path` with the reference settings (module docstring).

    Potential energy is enabled (``mj_forward`` and ``mj_energyPos`` fill ``data.energy[0]``, J).
    """
    mujoco = import_mujoco()
    path = Path(path)
    try:
        model = mujoco.MjModel.from_xml_string(_urdf_for_mujoco(path))
    except ValueError as exc:
        msg = " ".join(str(exc).split())
        raise IdapbcError(f"MuJoCo could not load '{path}': {msg}. Fix: check the URDF, or use the Pinocchio judge.") from None
    model.opt.gravity[:] = GRAVITY
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    return model


def full_mass_matrix(model, data) -> np.ndarray:
    """Dense M(q) (model.nv, model.nv) from ``data.qM`` (after ``mj_fwdPosition`` or ``mj_forward``)."""
    mujoco = import_mujoco()
    M = np.zeros((model.nv, model.nv))
    try:
        mujoco.mj_fullM(model, data, M)  # MuJoCo >= 3.3: (m, d, dst)
    except TypeError:
        mujoco.mj_fullM(model, M, data.qM)  # older: (m, dst, qM)
    return M


def joint_addresses(model, names, where: str = "the URDF") -> tuple[np.ndarray, np.ndarray]:
    """(qpos addresses, dof addresses), each (nv,) int, of the joints `names` in that order.

    Raises a one-line `IdapbcError` unless every name is a hinge or slide joint of `model` with
    one qpos, the model has exactly these degrees of freedom, and armature and friction loss are 0.
    """
    mujoco = import_mujoco()
    names = tuple(names)
    if model.nv != len(names) or model.nq != len(names):
        raise IdapbcError(
            f"MuJoCo finds nq={model.nq}, nv={model.nv} in {where}, the system has {len(names)} joints. "
            "Fix: use the Pinocchio judge for this robot."
        )
    kinds = {int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)}
    qpos, dof = [], []
    for name in names:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            raise IdapbcError(f"MuJoCo has no joint '{name}' in {where}. Fix: use the Pinocchio judge for this robot.")
        if int(model.jnt_type[jid]) not in kinds:
            kind = mujoco.mjtJoint(int(model.jnt_type[jid])).name
            raise IdapbcError(f"joint '{name}' is {kind} in MuJoCo, not a hinge or slide. Fix: use the Pinocchio judge for this robot.")
        qpos.append(int(model.jnt_qposadr[jid]))
        dof.append(int(model.jnt_dofadr[jid]))
    dof = np.array(dof, dtype=int)
    for what, values, fix in (
        ("armature", model.dof_armature, "remove the armature from the URDF's <mujoco> block"),
        ("friction loss", model.dof_frictionloss, "set <dynamics friction=\"0\"> (the plant has no Coulomb friction)"),
    ):
        if np.any(values[dof] != 0):
            k = int(np.flatnonzero(values[dof] != 0)[0])
            raise IdapbcError(f"joint '{names[k]}' has {what} {values[dof][k]:g} in MuJoCo. Fix: {fix}, or use the Pinocchio judge.")
    return np.array(qpos, dtype=int), dof

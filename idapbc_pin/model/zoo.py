"""The URDF zoo: physically consistent underactuated robots shipped in the repository's `urdf/`.

Every robot is drawn upright at q = 0 (pendulum links along +z, gravity along −z), so the default
target x* = 0 is the upright, open-loop unstable equilibrium. An entry is data: a URDF file, the
actuated joints, optional target and domain overrides, and tags. The same URDF may back several
entries (acrobot, pendubot and double_pendulum differ only in `actuated`).

Units: SI throughout. Joint coordinates are radians (revolute, continuous) or metres (prismatic);
momenta are N·m·s or N·s.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from ..errors import IdapbcError

__all__ = ["ZOO", "ZOO_ENV_VAR", "ZooEntry", "zoo_dir", "zoo_entry", "zoo_names", "zoo_urdf_path"]

#: Environment variable that, when set, names the folder holding the zoo's URDF files.
ZOO_ENV_VAR = "IDAPBC_PIN_ZOO"


@dataclass(frozen=True, kw_only=True)
class ZooEntry:
    """One robot of the zoo.

    Attributes
    ----------
    name : registry key, e.g. ``"acrobot"``.
    urdf : file name inside the zoo folder (`zoo_dir()`), e.g. ``"double_pendulum.urdf"``.
    actuated : names of the actuated joints (URDF joint names), in the order of the inputs u.
    target : ``(joint, value)`` overrides of the zero target q* (rad or m); joints not named keep 0.
        The target momenta are always 0.
    domain : ``(coordinate, lo, hi)`` overrides of the default training box; a coordinate is a
        joint name (q, rad or m) or ``"p_<joint>"`` (momentum, N·m·s or N·s).
    tags : free-form labels, e.g. ``"underactuated"``, ``"underactuation-2"``.
    description : one sentence for listings.
    """

    name: str
    urdf: str
    actuated: tuple[str, ...]
    target: tuple[tuple[str, float], ...] = ()
    domain: tuple[tuple[str, float, float], ...] = ()
    tags: tuple[str, ...] = ()
    description: str = ""


_ENTRIES = (
    ZooEntry(
        name="acrobot",
        urdf="double_pendulum.urdf",
        actuated=("elbow",),
        tags=("underactuated", "underactuation-1", "planar"),
        description="Two-link arm actuated at the elbow only (Spong's acrobot), swung up and balanced upright.",
    ),
    ZooEntry(
        name="arm_passive_middle",
        urdf="arm_passive_middle.urdf",
        actuated=("j1", "j3"),
        tags=("underactuated", "underactuation-1", "planar", "two-inputs"),
        description="Three-link arm with motors at the base and the wrist and a passive middle joint, balanced upright.",
    ),
    ZooEntry(
        name="cart_double_pendulum",
        urdf="cart_double_pendulum.urdf",
        actuated=("slider",),
        tags=("underactuated", "underactuation-2", "planar", "prismatic"),
        description="Double inverted pendulum on a cart pushed by a horizontal force.",
    ),
    ZooEntry(
        name="cart_double_pendulum_short_rail",
        urdf="cart_double_pendulum_short_rail.urdf",
        actuated=("slider",),
        tags=("underactuated", "underactuation-2", "planar", "prismatic"),
        description="Double inverted pendulum on a cart with a laboratory rig's short rail (±0.7 m).",
    ),
    ZooEntry(
        name="cartpole",
        urdf="cartpole.urdf",
        actuated=("slider",),
        tags=("underactuated", "underactuation-1", "planar", "prismatic"),
        description="Inverted pendulum on a cart pushed by a horizontal force.",
    ),
    ZooEntry(
        name="double_pendulum",
        urdf="double_pendulum.urdf",
        actuated=("shoulder", "elbow"),
        tags=("fully-actuated", "planar"),
        description="Two-link arm with both joints actuated, balanced upright.",
    ),
    ZooEntry(
        name="furuta",
        urdf="furuta.urdf",
        actuated=("arm",),
        tags=("underactuated", "underactuation-1", "perpendicular-axes"),
        description="Rotary (Furuta) pendulum: a horizontal arm turned about the vertical balances a pendulum.",
    ),
    ZooEntry(
        name="pendubot",
        urdf="double_pendulum.urdf",
        actuated=("shoulder",),
        tags=("underactuated", "underactuation-1", "planar"),
        description="Two-link arm actuated at the shoulder only (pendubot), balanced upright.",
    ),
    ZooEntry(
        name="triple_pendulum",
        urdf="triple_pendulum.urdf",
        actuated=("shoulder",),
        tags=("underactuated", "underactuation-2", "planar"),
        description="Three-link arm actuated at the shoulder only (a three-link pendubot), balanced upright.",
    ),
    ZooEntry(
        name="quad_pendulum",
        urdf="quad_pendulum.urdf",
        actuated=("j1",),
        tags=("underactuated", "underactuation-3", "planar", "light-distal-links"),
        description="Four-link chain actuated at its base joint only, with light distal links, balanced upright.",
    ),
    ZooEntry(
        name="reaction_wheel",
        urdf="reaction_wheel.urdf",
        actuated=("wheel",),
        tags=("underactuated", "underactuation-1", "planar", "continuous-joint"),
        description="Inverted pendulum balanced by the torque on a wheel at its tip.",
    ),
)

#: Registry of the zoo, sorted by name.
ZOO: dict[str, ZooEntry] = {entry.name: entry for entry in sorted(_ENTRIES, key=lambda e: e.name)}


def zoo_names() -> list[str]:
    """Names of the zoo's robots, sorted."""
    return list(ZOO)


def zoo_entry(name: str) -> ZooEntry:
    """The zoo entry called `name`.

    Raises
    ------
    IdapbcError
        (a `ValueError`) if `name` is not in the zoo; the message lists the valid names.
    """
    try:
        return ZOO[name]
    except KeyError:
        raise IdapbcError(f"unknown zoo robot '{name}'. Valid names: {', '.join(ZOO)}.") from None


def zoo_dir() -> Path:
    """Folder holding the zoo's URDF files.

    ``$IDAPBC_PIN_ZOO`` when set, else the repository's ``urdf/`` folder next to the package
    (an editable or source install).
    """
    env = os.environ.get(ZOO_ENV_VAR)
    if env:
        return Path(env).expanduser().resolve()
    return Path(__file__).resolve().parents[2] / "urdf"


def zoo_urdf_path(name: str) -> Path:
    """Path of the URDF file behind the zoo entry `name`.

    Raises
    ------
    IdapbcError
        (a `ValueError`) if `name` is not in the zoo, or if its file is missing (e.g. a
        non-editable install: set ``$IDAPBC_PIN_ZOO``).
    """
    path = zoo_dir() / zoo_entry(name).urdf
    if not path.is_file():
        raise IdapbcError(
            f"zoo URDF '{path}' not found. Fix: install idapbc-pin in editable mode (pip install -e .) "
            f"or set {ZOO_ENV_VAR} to the folder holding the zoo's .urdf files."
        )
    return path

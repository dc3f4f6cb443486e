"""The model: a URDF (Pinocchio) or a closed form becomes a `System` with a `Plant` behind it."""

from .joint import JointInfo
from .loading import erd_robots_dir, load_system, resolve_source
from .plant import Plant
from .resting import resting_configuration, tip_height
from .system import EQUILIBRIUM_TOL, System

__all__ = ["EQUILIBRIUM_TOL", "JointInfo", "Plant", "System", "erd_robots_dir", "load_system", "resolve_source", "resting_configuration",
           "tip_height"]

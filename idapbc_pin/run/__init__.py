"""The run directory: its format, `load_run` / `resolve_run`, checkpoints and records.

A run directory is written by `idapbc_pin.training.train` and read only through this subpackage.
"""

from .checkpoints import CHECKPOINTS, DEFAULT_CHECKPOINT, check_checkpoints, load_weights, read_checkpoint, save_checkpoint
from .directory import (MANOEUVRE_FILE, MANOEUVRE_REFUSED_FILE, RECOVERY_FILE, RECOVERY_LABELS_FILE, RECOVERY_REFUSED_FILE, SWINGUP_FILE, SWINGUP_REFUSED_FILE, Run, load_run, read_recovery,
                        read_swing_up, resolve_run)
from .record import load_run_system, read_config, system_record

__all__ = [
    "CHECKPOINTS",
    "DEFAULT_CHECKPOINT",
    "MANOEUVRE_FILE",
    "MANOEUVRE_REFUSED_FILE",
    "RECOVERY_FILE",
    "RECOVERY_LABELS_FILE",
    "RECOVERY_REFUSED_FILE",
    "Run",
    "SWINGUP_FILE",
    "SWINGUP_REFUSED_FILE",
    "check_checkpoints",
    "load_run",
    "load_run_system",
    "load_weights",
    "read_checkpoint",
    "read_config",
    "read_recovery",
    "read_swing_up",
    "resolve_run",
    "save_checkpoint",
    "system_record",
]

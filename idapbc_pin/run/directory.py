"""A run directory: `Run`, `load_run` and `resolve_run`, the one place a run is opened.

Layout of a run directory (`<out>/<stamp>/`, `out` defaults to ``runs/<system>``)::

    config.json      resolved TrainConfig          system.json   source, actuated, target, domain, URDF hash
    robot.urdf       copy of the URDF (if any)     metrics.csv   one row per epoch, every term by name
    checkpoints/last.pt, best.pt                   summary.json  final terms, ε, eigenvalues at x*, status
    recovery.npz     the recovery law, when `idapbc-pin recover` kept one (`idapbc_pin.recovery`)
    swingup.npz      the swing-up law, when `train --swing-up` kept one; swingup.json its evaluation from hanging

Every file is read through this subpackage (JSON through `_io.read_json`, checkpoints through
`checkpoints.read_checkpoint`, each once per load), so a damaged file always gives the same one-line
error that names it and the fix.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from .._device import require_device
from .._io import DamagedFileError, read_json, read_npz
from ..config import TrainConfig
from ..control.controller import Controller, OuterLaw
from ..control.speed_governor import ENERGY_MARGIN
from ..control.nets import IdaPbcNets, build_nets
from ..errors import IdapbcError
from ..model import System
from .checkpoints import CHECKPOINTS, DEFAULT_CHECKPOINT, checkpoint_problem, load_weights, read_checkpoint
from .record import load_run_system, read_config

__all__ = ["MANOEUVRE_FILE", "MANOEUVRE_REFUSED_FILE", "RECOVERY_FILE", "RECOVERY_LABELS_FILE", "RECOVERY_REFUSED_FILE", "Run", "SWINGUP_FILE", "SWINGUP_REFUSED_FILE", "load_run", "read_recovery",
           "read_swing_up", "resolve_run"]

#: The recovery law of a run, beside its IDA-PBC law (`idapbc_pin.recovery.recover`).
RECOVERY_FILE = "recovery.npz"
#: The law the last `recover` fitted when its gate refused it: kept aside, never applied, so that
#: `recover --regate` can judge it again (another margin or allowance) or keep it, in minutes.
RECOVERY_REFUSED_FILE = "recovery-refused.npz"
#: The labels (x, u) the last `recover` fitted its law to (LQR, plans and DAgger rounds), so that
#: `recover --refit` fits a law again (another seed, width or length) in a minute, without the plans.
RECOVERY_LABELS_FILE = "recovery-labels.npz"
#: The swing-up law of a run, around its own law (`idapbc_pin.recovery.swing_up`), and the one the
#: swing-up stage's gate refused (kept aside, never applied).
SWINGUP_FILE, SWINGUP_REFUSED_FILE = "swingup.npz", "swingup-refused.npz"
#: The swing-up manoeuvre from rest the stage kept (`idapbc_pin.trajectory.manoeuvre`), and a refused one.
MANOEUVRE_FILE, MANOEUVRE_REFUSED_FILE = "swingup-manoeuvre.npz", "swingup-manoeuvre-refused.npz"


@dataclass
class Run:
    """A trained (or training) run: its directory, system, config, networks and summary."""

    path: Path
    system: System
    config: TrainConfig
    nets: IdaPbcNets
    summary: dict = field(default_factory=dict)
    checkpoint: str = DEFAULT_CHECKPOINT
    _fallback: OuterLaw | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def controller(self) -> Controller:
        """The control law u = (gᵀg)⁻¹gᵀ(f̃_d − f) with the trained networks, and the run's law
        where they do not act (`fallback`)."""
        return Controller(self.system, self.nets, self.fallback, governor_margin=self.governor_margin)

    @property
    def box_controller(self) -> Controller:
        """The run's law without a swing-up law: the networks, and its recovery or linear law outside
        their box (what the swing-up stage improves on and hands over to)."""
        return Controller(self.system, self.nets, self._box_fallback(), governor_margin=self.governor_margin)

    @property
    def own_controller(self) -> Controller:
        """The run's law without a recovery law: the networks, and where the run uses it the linear
        law outside the training box with the gate's inside gain (what `recover` improves on, and
        what its gate and its `teacher` = "run" simulate)."""
        return Controller(self.system, self.nets, self._linear_fallback())

    @property
    def governor_margin(self) -> float:
        """Where the governor's energy clause starts (ΔE above E*): the kept recovery law's own
        (summary.json → "recovery" → "governor_margin", `recovery.catch_margin`), else `ENERGY_MARGIN`."""
        entry = self.summary.get("recovery") or {}
        margin = entry.get("governor_margin") if self.uses_recovery else None
        return ENERGY_MARGIN if margin is None else float(margin)

    def _linear_fallback(self) -> OuterLaw | None:
        """The linear law outside the box with the gate's inside gain, where the run uses it; else None."""
        from ..recovery.box_law import box_fallback  # the recovery package's stage opens runs through this module

        return box_fallback(self.system, self.config, self.inside_gain, self.inside_ramp) if self.uses_fallback else None

    @property
    def uses_fallback(self) -> bool:
        """True when the run switches to the anchor's linear law outside the training box:
        ``config.fallback == "linear"``, or ``"auto"`` and the gate after training chose it
        (summary.json → fallback → used; False while training has not written it)."""
        if self.config.fallback == "auto":
            return bool((self.summary.get("fallback") or {}).get("used", False))
        return self.config.fallback == "linear"

    @property
    def inside_gain(self) -> float:
        """The factor on the learned law's deviation from u* inside the training box: the gate's
        choice (summary.json → fallback → inside_gain) where the run uses the fallback, else 1."""
        if not self.uses_fallback:
            return 1.0
        k = (self.summary.get("fallback") or {}).get("inside_gain", 1.0)
        if isinstance(k, bool) or not isinstance(k, (int, float)) or not (k >= 0.5 and np.isfinite(k)):
            raise DamagedFileError(f"'{self.path / 'summary.json'}' has fallback → inside_gain = {k!r}, not a number ≥ 0.5. "
                                   "Fix: set it to 1 (the learned law as trained inside the box).")
        return float(k)

    @property
    def inside_ramp(self) -> tuple[float, float]:
        """Where the inside gain ramps in (`BoxFallback.inside_ramp`): summary.json → fallback →
        inside_ramp; (0, 0), a constant gain, for runs gated before the ramp existed."""
        r = (self.summary.get("fallback") or {}).get("inside_ramp", [0.0, 0.0]) if self.uses_fallback else [0.0, 0.0]
        ok = isinstance(r, list) and len(r) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in r)
        if not (ok and np.isfinite(r[1]) and 0.0 <= r[0] <= r[1]):
            raise DamagedFileError(f"'{self.path / 'summary.json'}' has fallback → inside_ramp = {r!r}, not two numbers 0 ≤ r0 ≤ r1. "
                                   "Fix: set it to [0, 0] (a constant inside gain) or re-run the gate (`idapbc-pin train`).")
        return float(r[0]), float(r[1])

    @property
    def uses_recovery(self) -> bool:
        """True when `idapbc-pin recover` kept a recovery law (summary.json → recovery → used)."""
        return bool((self.summary.get("recovery") or {}).get("used", False))

    @property
    def uses_swing_up(self) -> bool:
        """True when the swing-up stage kept a swing-up law (summary.json → swing_up → used)."""
        return bool((self.summary.get("swing_up") or {}).get("used", False))

    @property
    def manoeuvre(self):
        """The swing-up manoeuvre from rest the swing-up stage kept (`trajectory.manoeuvre.SwingManoeuvre`;
        summary.json → swing_manoeuvre → used), or None; ``run.manoeuvre.law(run.controller)`` runs it."""
        if not (self.summary.get("swing_manoeuvre") or {}).get("used", False):
            return None
        path = self.path / MANOEUVRE_FILE
        fix = "run `idapbc-pin train --resume RUN --swing-up` again (or delete summary.json's \"swing_manoeuvre\" entry to drop it)"
        if not path.is_file():
            raise DamagedFileError(f"'{path}' is missing, but summary.json says the run uses a swing-up manoeuvre. Fix: {fix}.")
        from ..trajectory.manoeuvre import SwingManoeuvre  # the stages open runs through this module

        return read_npz(path, SwingManoeuvre.from_arrays, fix=fix)

    def _box_fallback(self) -> OuterLaw | None:
        """The recovery law outside its inner box when the run has one, else the linear law outside
        the training box when the run uses it, else None."""
        return read_recovery(self.path) if self.uses_recovery else self._linear_fallback()

    @property
    def fallback(self) -> OuterLaw | None:
        """The law that replaces the networks' where they do not act, or None: the recovery law
        outside its inner box when the run has one (`recovery.law`), else the linear law
        outside the training box when the run uses it (`recovery.box_law`); with a swing-up law
        (`recovery.swing_law`), that law wrapped in it, acting where the posture leaves the box."""
        if self._fallback is None:
            box = self._box_fallback()
            self._fallback = read_swing_up(self.path, inner=box) if self.uses_swing_up else box
        return self._fallback


def read_recovery(run_dir, name: str = RECOVERY_FILE) -> OuterLaw:
    """The run's recovery law (``recovery.npz``, or `RECOVERY_REFUSED_FILE` for the refused one;
    read without pickles); a missing or damaged file raises a one-line `DamagedFileError`."""
    path = Path(run_dir) / name
    fix = "run `idapbc-pin recover RUN` again (or delete summary.json's \"recovery\" entry to drop the law)"
    if not path.is_file():
        says = "uses a recovery law" if name == RECOVERY_FILE else "the last recover refused its law"
        raise DamagedFileError(f"'{path}' is missing, but summary.json says the run {says}. Fix: {fix}.")
    from ..recovery.library_law import recovery_law_from_arrays  # the recovery package's stage opens runs through this module

    return read_npz(path, recovery_law_from_arrays, fix=fix)


def read_swing_up(run_dir, name: str = SWINGUP_FILE, inner: OuterLaw | None = None) -> OuterLaw:
    """The run's swing-up law (``swingup.npz``, or `SWINGUP_REFUSED_FILE`) around `inner`, the run's
    own outer law (read without pickles); a missing or damaged file raises a one-line `DamagedFileError`."""
    path = Path(run_dir) / name
    fix = "run `idapbc-pin train --resume RUN --swing-up` again (or delete summary.json's \"swing_up\" entry to drop the law)"
    if not path.is_file():
        raise DamagedFileError(f"'{path}' is missing, but summary.json says the run uses a swing-up law. Fix: {fix}.")
    from ..recovery.swing_law import swing_law_from_arrays  # the recovery package's stage opens runs through this module

    return read_npz(path, lambda arrays: swing_law_from_arrays(arrays, inner), fix=fix)


def load_run(path, checkpoint: str | None = None, *, device: str = "cpu") -> Run:
    """Load a run directory (checkpoints are read with ``torch.load(weights_only=True)``).

    checkpoint : 'best' or 'last'. None (default) takes `DEFAULT_CHECKPOINT`, 'last' (the final
        weights, or the best finite ones after a divergence; 'best' while no last exists) and
        refuses a run whose other checkpoint is damaged, so damage never passes unnoticed; naming one
        explicitly uses it and only warns (stderr) about the other.
    device : where the networks are loaded, whatever device trained them ('cpu' by default: a run
        trained on a GPU is evaluated and exported on a machine without one). ``config.device``
        keeps recording where the run was trained.
    """
    path = Path(path)
    config = read_config(path)
    load_on = require_device(device)
    system = load_run_system(path)
    if checkpoint is not None and checkpoint not in CHECKPOINTS:
        raise IdapbcError(f"unknown checkpoint '{checkpoint}'. Fix: use one of {', '.join(CHECKPOINTS)}.")
    present = [c for c in CHECKPOINTS if (path / "checkpoints" / f"{c}.pt").is_file()]
    read = {c: checkpoint_problem(path / "checkpoints" / f"{c}.pt", load_on) for c in present}  # each file read once
    if not present:
        raise IdapbcError(
            f"run '{path}' has no checkpoint (checkpoints/best.pt or last.pt). "
            "Fix: wait until its training saves one, or train again."
        )
    name = checkpoint or (DEFAULT_CHECKPOINT if DEFAULT_CHECKPOINT in present else present[0])
    for c in present:  # by default a damaged checkpoint is refused, even the one not used
        if read[c][1] is not None and (checkpoint is None or c == name):
            read_checkpoint(path, c)  # raises the one-line error, with the other checkpoint's offer
        if read[c][1] is not None:
            print(f"warning: {path / 'checkpoints' / (c + '.pt')} is damaged; using {name}.pt as asked.", file=sys.stderr)
    state = read[name][0]
    torch.manual_seed(config.seed)
    nets = build_nets(system, config.replace(device=str(load_on)))
    load_weights(nets, state, path / "checkpoints" / f"{name}.pt")
    run = Run(path, system, config, nets, _read_summary(path), checkpoint=name)
    if run.uses_recovery or run.uses_swing_up:
        run.fallback  # noqa: B018 -- reads recovery.npz now: a damaged one is refused at load, like a checkpoint
    run.inside_gain, run.inside_ramp  # noqa: B018 -- a damaged summary.json entry is refused at load too
    return run


def _read_summary(path: Path) -> dict:
    """summary.json as a dict ({} while training has not written it)."""
    if not (path / "summary.json").exists():
        return {}
    fix = "delete summary.json (it is rewritten by the next train --resume)"
    summary = read_json(path / "summary.json", fix=fix)
    if not isinstance(summary, dict):
        raise DamagedFileError(f"{path / 'summary.json'} is damaged (not a JSON object). Fix: {fix}.")
    return summary


def resolve_run(run_or_path, checkpoint: str | None = None) -> Run:
    """A `Run` as it is, or `load_run` of a run directory (str or path): the one place that accepts both."""
    if isinstance(run_or_path, Run):
        return run_or_path
    if isinstance(run_or_path, (str, os.PathLike)):
        return load_run(run_or_path, checkpoint=checkpoint)
    raise IdapbcError(f"expected a Run or a run directory, got {type(run_or_path).__name__}. Fix: pass ip.load_run(...) or its path.")

"""Judge or fit a run's recovery law again, without searching plans: `regate` and `refit`.

Both reuse the recovery stage's gate and fit (`stage.recover`, steps 2 and 4) on what the run's
last `recover` saved: its law (``recovery.npz`` or ``recovery-refused.npz``) or its labels
(``recovery-labels.npz``).
"""

from __future__ import annotations

import time

import torch

from ..errors import IdapbcError
from ..run import RECOVERY_FILE, RECOVERY_REFUSED_FILE, read_recovery, resolve_run
from ..trajectory.plans import planning_system
from .config import RecoveryConfig
from .gate import choose_inner, read_labels
from .library_law import LibraryLaw
from .stage import _fit, _gate_fits, _save_and_tell, _verdict

__all__ = ["refit", "regate"]


def regate(run_or_path, config: RecoveryConfig = RecoveryConfig(), progress: bool = True, *, keep: bool = False) -> dict:
    """Judge the law the run's last `recover` fitted again, with `config`'s gate (`inner_scales`,
    `gate_states`, `near_states`, `margin`, `half_loss`), without searching plans or fitting: the
    gate's simulations only (a minute or two for a 2-DoF robot, against 20-60 for `recover`).
    `keep` keeps it at the gate's best inner box whatever the verdict (the entry says "forced").
    Returns the new summary entry; the labels, fit and DAgger figures of the last `recover` stay."""
    run = resolve_run(run_or_path)
    last = run.summary.get("recovery")
    if not isinstance(last, dict) or "gate" not in last:
        raise IdapbcError(f"run '{run.path}' has no recovery law to judge again. Fix: run `idapbc-pin recover {run.path}` first.")
    name = last.get("law_file", RECOVERY_FILE if last.get("used") else None)
    if name is None:
        raise IdapbcError(
            f"run '{run.path}': its last recover refused its law before idapbc-pin kept refused laws ({RECOVERY_REFUSED_FILE}). "
            f"Fix: run `idapbc-pin recover {run.path}` again."
        )
    law = read_recovery(run.path, name)
    start = time.perf_counter()
    gate = choose_inner(run, law, config, progress)
    regated = {"from": {"used": last.get("used"), "inner_scale": last.get("inner_scale")}, "seconds": round(time.perf_counter() - start, 1)}
    entry = last | _verdict(gate, config, keep) | {"fit_seed": last.get("fit_seed", 0), "library": isinstance(law, LibraryLaw), "regated": regated}  # the saved law's seed and kind
    return _save_and_tell(run, law, entry, config, progress, start)


def refit(run_or_path, config: RecoveryConfig = RecoveryConfig(), progress: bool = True, *, keep: bool = False) -> dict:
    """Fit a recovery law again to the labels the run's last `recover` saved (``recovery-labels.npz``),
    with `config`'s `width`, `steps` and `fit_seed`, and gate it as `recover` does (`keep` as there):
    the fit's minute and the gate's, without plans or DAgger rounds. `recover` writes the labels after
    every labelling step, so this also finishes a `recover` that was interrupted. The new law replaces
    the saved one, kept or refused. Returns the new summary entry (its "refit" part: the fit's
    settings, error and time)."""
    run = resolve_run(run_or_path)
    last = run.summary.get("recovery") if isinstance(run.summary.get("recovery"), dict) else {}  # none after an interrupted recover
    system = planning_system(run.system)  # an input without a limit plans within LQR's largest demand
    X, U = read_labels(run.path, system.n, system.m)
    torch.set_num_threads(1)
    start = time.perf_counter()
    networks = run.own_controller.with_fallback(None)  # the input a recovery law's apply gets
    law, mse = _fit(system, X, U, config, networks)
    if progress:
        print(f"fitted again on the {len(X)} saved labels (fit seed {config.fit_seed}, width {config.width}, {config.steps} steps): "
              f"mean squared error {mse:.4f} (u/ū)  [{time.perf_counter() - start:.0f} s]", flush=True)
    law, gate = _gate_fits(run, system, law, X, U, config, progress, start, networks)
    refitted = {"fit_seed": None if gate.get("library") else config.fit_seed + gate.get("fit", 0), "fits": config.fits, "width": config.width, "steps": config.steps, "labels": int(len(X)), "mse": mse,
                "seconds": round(time.perf_counter() - start, 1)}
    earlier = {k: v for k, v in last.items() if k not in ("regated", "refit")}
    return _save_and_tell(run, law, earlier | _verdict(gate, config, keep) | {"refit": refitted}, config, progress, start)

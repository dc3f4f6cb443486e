"""The trainer: fresh uniform samples each epoch, named loss terms with adaptive weights, Adam,
atomic checkpoints (last and best), resume, NaN guard, Ctrl-C. Its state and checkpoints are
`training._trainer`; the run directory it writes is described in `idapbc_pin.run`.
"""

from __future__ import annotations

import copy
import csv
import datetime as _dt
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from .._device import require_device
from .._io import write_json
from ..config import TrainConfig
from ..control.anchor import anchor_settings, cart_setting, formed_anchor
from ..control.controller import Controller
from ..control.linear import fastest_pole
from ..control.nets import build_nets
from ..errors import IdapbcError
from ..model import System
from ..model.boxes import verification_box
from ..recovery import box_gate as _gate
from ..recovery.box_law import box_fallback, fallback_gain
from ..run import Run, check_checkpoints, load_weights, read_checkpoint, read_config
from ._trainer import Trainer, checkpoint, metrics_row, open_metrics, restore, save_snapshot, snapshot, start
from .loss import TERMS, loss_terms
from .rollout import rollout_cost, rollout_gate, rollout_starts
from .verification import box_faces, verification_terms

__all__ = ["TrainingDiverged", "train"]


#: The learning rate a resume after a divergence is offered at most (the presets' own, `TrainConfig.lr`).
SAFE_LR = 5e-4

#: Gradient-norm clip of the `rollout` epochs: back-propagation through a saturated swing gives norms
#: over several orders of magnitude, so each step is at most Adam's own size.
ROLLOUT_CLIP = 1.0


class TrainingDiverged(IdapbcError):
    """A training step failed (a non-finite term, gradient or weight, or a linear-algebra error on
    such values); `train` then saves the last finite state as last.pt and says how to resume."""

    def __init__(self, message: str, last_good: dict | None = None):
        super().__init__(message)
        self.last_good = last_good


def train(
    system: System,
    config: TrainConfig | None = None,
    out: str | Path | None = None,
    *,
    resume: str | Path | None = None,
    progress: bool = True,
    workers: int = 1,
) -> Run:
    """Train Neural IDA-PBC networks for `system` and return the `Run`.

    Parameters
    ----------
    system : from `load_system`.
    config : `TrainConfig` (paper defaults if None). With `resume`, only `epochs` (to extend a run),
        `lr` (to continue more gently after a divergence) and `device` (to continue a GPU run on the
        CPU, or the reverse) are taken from it; everything else comes from the run directory.
    out : parent of the new run directory (default ``runs/<system name>``).
    resume : an existing run directory to continue from its last checkpoint; the result equals an
        uninterrupted run with the same config (same seed, same machine).
    progress : show a tqdm progress bar with the named loss terms and ETA.
    workers : processes for the simulations of the gate after training (``fallback="auto"``): 1 runs
        them here, 0 one per core (`idapbc_pin._parallel.resolve_workers`); the count changes the
        time, never the result.
    """
    if not (isinstance(workers, int) and workers >= 0):
        raise IdapbcError(f"workers must be an integer ≥ 0, got {workers!r}. Fix: 0 (one process per core) or a count such as 2.")
    anchor_form = _anchor_form(system, config, resume)
    config, run_dir, state = _resolve(system, config, out, resume)
    if progress:
        print(f"run directory: {run_dir}", flush=True)
        if anchor_form and resume is None:
            print(f"anchor: P of form '{anchor_form['form']}' ({anchor_form['passed_over']})", flush=True)
    trainer = start(system, config, run_dir, state)
    open_metrics(run_dir / "metrics.csv", state is None, trainer.epoch)
    status = "finished"
    try:
        _run_epochs(trainer, progress)
    except KeyboardInterrupt:
        status = "interrupted"
        checkpoint(trainer, "last", trainer.epoch)
    except TrainingDiverged as exc:
        restore(trainer, exc.last_good)
        checkpoint(trainer, "last", trainer.epoch)
        raise TrainingDiverged(
            f"{exc} The weights with the lowest loss before that (after epoch {trainer.epoch}) are kept as "
            f"{run_dir / 'checkpoints' / 'last.pt'}. Fix: idapbc-pin train --resume {run_dir} --lr {min(config.lr / 10, SAFE_LR):g}"
        ) from None
    gate = _gate_rollout(trainer, progress) if status == "finished" and config.rollout_epochs > 0 else None
    # From here the law is only simulated: on the CPU, where the plant is, which spares the
    # per-step round trips to a GPU.
    run = Run(run_dir, system, config, trainer.nets.to("cpu"))
    if status == "finished" and config.fallback == "auto":
        # first, so that the summary's eigenvalues at x* are those of the law the run applies (a
        # scaled learned law closes A − kBK there, not the networks' loop alone)
        run.summary = {"fallback": _gate_fallback(system, config, run.nets, progress, run_dir, workers)}
    summary = _summarise(run, status, trainer.epoch, trainer.eps_ema, trainer.elapsed)
    if gate is not None:
        summary["rollout_gate"] = gate
    if anchor_form:
        summary["anchor_form"] = anchor_form
    run.summary = {**summary, **run.summary}
    write_json(run_dir / "summary.json", run.summary)
    return run


def _gate_fallback(system: System, config: TrainConfig, nets, progress: bool, run_dir: Path, workers: int) -> dict:
    """``fallback="auto"``: simulate the learned law with and without the anchor's linear law outside
    the training box, and scaled inside it (`fallback_gate`), and record which one the run uses. Ctrl-C skips the check:
    the run then keeps the learned law everywhere, records ``"interrupted": true``, and
    ``train --resume`` runs the check again."""
    t0 = time.perf_counter()
    if progress:
        print(f"checking the law outside the training box: {_gate.GATE_STATES} fresh states, {_gate.GATE_HORIZON:g} s each, "
              "with and without the anchor's linear law there (Ctrl-C skips the check) ...", flush=True)
    try:
        gate = _gate.fallback_gate(system, Controller(system, nets), box_fallback(system, config), config.seed, workers, progress=progress)
    except KeyboardInterrupt:
        if progress:
            print(f"check interrupted: the run keeps the learned law everywhere; `idapbc-pin train --resume {run_dir}` "
                  "runs the check again", flush=True)
        return {"interrupted": True, "used": False, "seconds": round(time.perf_counter() - t0, 3)}
    gate["seconds"] = round(time.perf_counter() - t0, 3)
    if progress:
        verdict = "used" if gate["used"] else "not used"
        scaled = ("" if gate["scaled"] is None else
                  f"; {100 * gate['scaled']:.0f} % with it there and the learned law scaled by "
                  f"{fallback_gain(system, config):g} inside away from x* ({'used' if gate['inside_gain'] != 1.0 else 'not used'})")
        print(f"outside the training box: success from {gate['states']} fresh states {100 * gate['networks']:.0f} % with the "
              f"learned law, {100 * gate['with_fallback']:.0f} % with the anchor's linear law there (linear law {verdict}; "
              f"{gate['only_fallback']} states reach x* only with it, {gate['only_networks']} only without){scaled}", flush=True)
    return gate


def _gate_rollout(trainer: Trainer, progress: bool) -> dict:
    """Keep the rollout epochs' weights only if the real loop does at least as well with them
    (`rollout.rollout_gate`); otherwise put checkpoints/pre_rollout.pt back as the final weights."""
    config, system = trainer.config, trainer.system
    pre = read_checkpoint(trainer.run_dir, "pre_rollout", map_location="cpu")
    before = build_nets(system, config.replace(device="cpu"))  # judged on the CPU, like every simulation
    load_weights(before, pre, trainer.run_dir / "checkpoints" / "pre_rollout.pt")
    after = copy.deepcopy(trainer.nets).to("cpu")
    gate = rollout_gate(system, Controller(system, before), Controller(system, after), config.rollout_box, config.seed)
    gate["skipped_epochs"] = trainer.rollout_skipped
    if not gate["kept"]:
        trainer.nets.load_state_dict(before.state_dict())
        checkpoint(trainer, "last", trainer.epoch)
    if progress:
        verdict = "kept" if gate["kept"] else "not kept: the weights before them are the final ones"
        print(f"rollout epochs: success from {gate['states']} fresh states {100 * gate['before']:.0f} % before, "
              f"{100 * gate['after']:.0f} % after ({verdict})", flush=True)
        if trainer.rollout_skipped:
            print(f"rollout epochs: {trainer.rollout_skipped} of {config.rollout_epochs} took no step, their gradient overflowed "
                  f"through unstable trajectories (a shorter rollout_horizon avoids it)", flush=True)
    return gate


# --------------------------------------------------------------------------------------- setup
def _resolve(system: System, config: TrainConfig | None, out, resume) -> tuple[TrainConfig, Path, dict | None]:
    """(config, run directory, last checkpoint's state): the run to resume, or a new one (state None).

    A new run's "auto" values are resolved here, so config.json holds what ran.
    """
    if resume is not None:
        run_dir = Path(resume)
        saved = read_config(run_dir)
        config = saved if config is None else saved.replace(epochs=config.epochs, lr=config.lr, device=config.device)
        require_device(config.device)  # before the checkpoint: torch calls a GPU run's checkpoint unreadable on a CPU-only machine
        check_checkpoints(run_dir, system, config)  # a damaged best.pt must not pass unnoticed either
        return config, run_dir, read_checkpoint(run_dir, "last", map_location=config.device)
    config = resolved_config(system, config or TrainConfig())
    return config, _new_run_dir(Path(out) if out is not None else Path("runs") / system.name), None


def _anchor_form(system: System, config: TrainConfig | None, resume) -> dict | None:
    """``{"form", "passed_over"}`` where the anchored form's configured P (``anchor_p``) was passed over
    for another (`control.anchor.formed_anchor`), else None; a resumed run keeps its summary's record."""
    if resume is not None:
        path = Path(resume) / "summary.json"
        if not path.is_file():
            return None
        from .._io import read_json

        try:
            return read_json(path, fix="delete summary.json").get("anchor_form")
        except IdapbcError:
            return None
    config = config or TrainConfig()
    if config.form != "anchored":
        return None
    _, form, why = formed_anchor(system, config)
    return {"form": form, "passed_over": why} if why else None


def resolved_config(system: System, config: TrainConfig) -> TrainConfig:
    """`config` with its automatic values resolved for `system` (the units and the anchor weight,
    `control.anchor.anchor_settings`, a cart's weight, `control.anchor.cart_setting`, and the fallback gain, `recovery.box_law.fallback_gain`): what a
    new run's config.json records, so a batch that runs a job again finds the run it trained."""
    scaling, anchor_q = anchor_settings(system, config)
    anchor_p = formed_anchor(system, config, (scaling, anchor_q))[1] if config.form == "anchored" else config.anchor_p
    return config.replace(scaling=scaling, anchor_q=anchor_q, anchor_p=anchor_p, anchor_cart=cart_setting(system, config),
                          fallback_gain=fallback_gain(system, config))


def _new_run_dir(out: Path) -> Path:
    """A new, empty ``out/<stamp>[-k]/checkpoints``: the first free name, taken atomically, so two
    trainings started in the same second into one folder get one directory each."""
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out.mkdir(parents=True, exist_ok=True)
    k = 0
    while True:
        run_dir = out / (stamp if k == 0 else f"{stamp}-{k}")
        try:
            run_dir.mkdir()  # fails if the name is taken, even by a process that took it a moment ago
        except FileExistsError:
            k += 1
            continue
        (run_dir / "checkpoints").mkdir()
        return run_dir


# ---------------------------------------------------------------------------------------- loop
def _run_epochs(trainer: Trainer, progress: bool) -> None:
    """From `trainer.epoch` to `config.epochs`: one step, one metrics row and the due checkpoints each."""
    config, system = trainer.config, trainer.system
    start = trainer.epoch
    bar = tqdm(
        range(start, config.epochs), initial=start, total=config.epochs, disable=not progress, desc=f"train {system.name}", unit="epoch",
        dynamic_ncols=True, mininterval=0.1 if sys.stderr.isatty() else 15.0,  # a log file gets a line every 15 s, not every epoch
    )
    t_last = time.perf_counter()
    try:
        with open(trainer.run_dir / "metrics.csv", "a", newline="") as mfile:
            writer = csv.writer(mfile)
            for epoch in bar:
                trainer.epoch = epoch
                before = snapshot(trainer)  # the weights this epoch's loss is computed at
                try:
                    total, values, diag, eps_value = _step(trainer, epoch)
                except TrainingDiverged as exc:
                    raise TrainingDiverged(str(exc), trainer.best_state or before) from None
                except (RuntimeError, ValueError, FloatingPointError) as exc:  # e.g. torch.linalg errors on NaN/inf
                    reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                    raise TrainingDiverged(f"the training step of epoch {epoch} failed ({reason[:160]}).", trainer.best_state or before) from None
                now = time.perf_counter()
                trainer.elapsed += now - t_last
                t_last = now
                raw = sum(v for k, v in values.items() if k != "rollout")  # best.pt: the lowest residuals
                writer.writerow(metrics_row(epoch + 1, total, values, trainer.weights, eps_value, diag, trainer.elapsed))
                if raw < trainer.best:  # best.pt holds the weights that scored it (before this step)
                    trainer.best = before["best"] = raw
                    trainer.best_state = before
                    save_snapshot(trainer, "best", before)
                if (epoch + 1) % config.checkpoint_every == 0 or epoch + 1 == config.epochs:
                    mfile.flush()
                    checkpoint(trainer, "last", epoch + 1)
                if progress:
                    bar.set_postfix({k: f"{v:.2e}" for k, v in values.items()} | {"dissipation_ok": f"{float(diag['dissipation_ok']):.2f}"}, refresh=False)
            trainer.epoch = config.epochs
    finally:
        bar.close()


def _sample(system: System, n: int, gen: torch.Generator) -> np.ndarray:
    lo, hi = (torch.as_tensor(b, dtype=torch.float64) for b in system.domain)
    return (lo + (hi - lo) * torch.rand(n, system.n, generator=gen, dtype=torch.float64)).numpy()


def _step(trainer: Trainer, epoch: int) -> tuple[torch.Tensor, dict[str, float], dict[str, torch.Tensor], float]:
    """One epoch: fresh samples, ε, the loss terms, one Adam step, the adaptive weights' update.

    Returns the weighted loss (scalar tensor), the terms' values by name, the diagnostics of
    `loss_terms` and ε. Raises `TrainingDiverged` on a non-finite term or gradient.
    """
    config, system, nets = trainer.config, trainer.system, trainer.nets
    x = _sample(system, config.samples, trainer.gen)
    xt = trainer.tensor(x)
    with torch.no_grad():
        H = nets.H(xt)
    eps = trainer.tensor(config.epsilon) if config.epsilon > 0 else torch.quantile(H.double(), config.inside_fraction).to(xt.dtype)
    inside = H < eps
    f = trainer.tensor(system.f(x))
    df_in = None
    if config.local_stability and bool(inside.any()):
        df_in = trainer.tensor(system.df_dx(x[inside.cpu().numpy()]))
    x_face, effort = None, None
    if config.effort_term and system.limited:
        # a stream of its own, a function of (seed, epoch): the domain samples stay those of a run without limits
        face_gen = torch.Generator().manual_seed(1_000_003 * config.seed + epoch + 1)
        x_face = trainer.tensor(box_faces(*system.domain, config.face_samples, face_gen))
        effort = trainer.tensor(np.array(system.effort))
    terms, diag = loss_terms(nets, xt, f, eps, config.kappa, df_in, inside, x_face=x_face, effort=effort)
    if config.verification_terms:
        verification, trainer.counterexamples = _verification(trainer, epoch, xt)
        terms.update(verification)
    rolling = epoch >= config.epochs - config.rollout_epochs
    if rolling:  # the last epochs train on simulations of the saturated loop alone
        if epoch == config.epochs - config.rollout_epochs:
            checkpoint(trainer, "pre_rollout", epoch)  # what `rollout_gate` compares the result with
            trainer.optimizer.state.clear()  # Adam's moments of the residuals would scale the new term's steps
        x0 = rollout_starts(system, config.rollout_samples, config.rollout_box, trainer.gen)
        limits = trainer.tensor(np.array(system.effort))
        terms["rollout"] = rollout_cost(nets, system, trainer.tensor(x0), config.rollout_horizon, config.rollout_step, config.rollout_tail, limits)
    values = {k: float(v.detach()) for k, v in terms.items()}
    bad = [k for k, v in values.items() if not math.isfinite(v)]
    if bad:
        raise TrainingDiverged(f"loss term '{bad[0]}' became {values[bad[0]]} at epoch {epoch}.")
    total = terms["rollout"] if rolling else trainer.weights.total(terms)
    trainer.optimizer.zero_grad(set_to_none=True)
    total.backward()
    bad_grad = None if _all_finite(p.grad for p in nets.parameters()) else next(
        (name for name, p in nets.named_parameters() if p.grad is not None and not bool(torch.isfinite(p.grad).all())), None)
    if bad_grad is not None and not rolling:
        raise TrainingDiverged(f"gradient of '{bad_grad}' became non-finite at epoch {epoch}.")
    if bad_grad is not None:  # back-propagation through an unstable trajectory overflowed: skip the step, not the run
        trainer.optimizer.zero_grad(set_to_none=True)
        trainer.rollout_skipped += 1
    if rolling:
        torch.nn.utils.clip_grad_norm_(nets.parameters(), ROLLOUT_CLIP)
    trainer.optimizer.step()
    if not _all_finite(nets.parameters()):
        for name, p in nets.named_parameters():
            if not bool(torch.isfinite(p).all()):
                raise TrainingDiverged(f"weights of '{name}' became non-finite at epoch {epoch}.")
    if not rolling:
        trainer.weights.update(values)
    eps_value = float(eps)
    trainer.eps_ema = eps_value if trainer.eps_ema is None else 0.95 * trainer.eps_ema + 0.05 * eps_value
    return total, values, diag, eps_value


def _verification(trainer: Trainer, epoch: int, xt: torch.Tensor) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    """The opt-in terms of `verification.verification_terms` for this epoch: `samples` fresh states
    of the verification box (a stream of their own, a function of (seed, epoch)) plus the
    counter-examples kept from the last epoch, and `face_samples` states of its faces."""
    config, system, nets = trainer.config, trainer.system, trainer.nets
    gen = torch.Generator().manual_seed(2_000_003 * config.seed + epoch + 1)
    lo, hi = verification_box(system, config.verification_scale)
    x_v = lo + (hi - lo) * torch.rand(config.samples, system.n, generator=gen, dtype=torch.float64).numpy()
    if trainer.counterexamples is not None and trainer.counterexamples.shape[0]:
        x_v = np.concatenate([x_v, trainer.counterexamples.to("cpu", torch.float64).numpy()])
    x_face = box_faces(lo, hi, config.face_samples, gen)
    effort = trainer.tensor(np.array(system.effort)) if system.limited else None
    return verification_terms(nets, nets.H(xt), trainer.tensor(x_v), trainer.tensor(system.f(x_v)), trainer.tensor(x_face), effort)


def _all_finite(tensors) -> bool:
    """Whether every entry of the tensors (None ones skipped) is finite, in one reduction per call:
    a non-finite entry makes its tensor's sum of squares non-finite (a finite tensor whose sum of
    squares overflows reads as non-finite too; the caller then looks tensor by tensor)."""
    tensors = [t for t in tensors if t is not None]
    return not tensors or bool(torch.isfinite(torch.stack(torch._foreach_norm(tensors))).all())


def _summarise(run: Run, status: str, epoch: int, eps_ema, elapsed: float) -> dict:
    ctrl = run.controller
    eig = ctrl.eigenvalues_at_target()
    les = bool(np.all(eig.real < 0))
    last = {}
    rows = (run.path / "metrics.csv").read_text().splitlines()
    if len(rows) > 1:
        head, tail = rows[0].split(","), rows[-1].split(",")
        last = {k: float(v) for k, v in zip(head, tail) if k in TERMS}
    return {
        "status": status,
        "epochs_done": epoch,
        "train_seconds": round(elapsed, 3),
        "epsilon": eps_ema,
        "final_terms": last,
        "eigenvalues_at_target": [[float(z.real), float(z.imag)] for z in eig],
        "open_loop_fastest_pole": fastest_pole(run.system.linearization()[0]),
        "locally_exponentially_stable": les,
        "rho": ctrl.rho,
    }

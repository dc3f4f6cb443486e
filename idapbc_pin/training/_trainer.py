"""The trainer's state and how it is saved: what the epochs read and advance (`Trainer`), the
in-memory snapshot a divergence rolls back to, the checkpoints (last, best, pre_rollout) and the rows
of metrics.csv. The loop that advances it is `training.train`; the run directory is `idapbc_pin.run`.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path

import torch

from .._device import require_device
from .._io import DamagedFileError, write_json
from ..config import TrainConfig
from ..control.nets import IdaPbcNets, build_nets
from ..model import System
from ..run import load_weights, save_checkpoint, system_record
from .loss import TERMS, AdaptiveWeights

__all__ = ["METRICS_COLUMNS", "Trainer", "checkpoint", "metrics_row", "open_metrics", "restore", "save_snapshot", "snapshot", "start"]


@dataclass
class Trainer:
    """What the epochs read and advance; a checkpoint saves all of it but system, config and run_dir.

    ``epoch``: the epochs done, or during an epoch its 0-based index (what Ctrl-C saves).
    ``best``: the lowest summed loss terms so far; ``eps_ema``: moving average of ε;
    ``elapsed``: training seconds, summed over resumed sessions; ``rollout_skipped``: rollout epochs
    whose gradient was not finite, skipped instead of stopping the run (`train._step`).
    """

    system: System
    config: TrainConfig
    run_dir: Path
    nets: IdaPbcNets
    optimizer: torch.optim.Optimizer
    weights: AdaptiveWeights
    gen: torch.Generator
    epoch: int = 0
    best: float = math.inf
    eps_ema: float | None = None
    elapsed: float = 0.0
    best_state: dict | None = None  #: `snapshot` of the weights with the lowest loss so far
    rollout_skipped: int = 0  #: rollout epochs whose gradient overflowed, so took no step
    counterexamples: torch.Tensor | None = None  #: (k, n) states kept by the opt-in `verification_terms` for the next epoch

    def tensor(self, a) -> torch.Tensor:
        """`a` in the networks' dtype and device."""
        return torch.as_tensor(a, dtype=getattr(torch, self.config.dtype), device=torch.device(self.config.device))


def start(system: System, config: TrainConfig, run_dir: Path, state: dict | None) -> Trainer:
    """Seeded networks, Adam and sample generator; restored from `state`, else config.json and
    system.json written."""
    require_device(config.device)
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    nets = build_nets(system, config)
    optimizer = torch.optim.Adam(nets.parameters(), lr=config.lr, foreach=True)  # one multi-tensor update for the many small weight tensors
    weights = AdaptiveWeights.start(config.gamma, config.alpha)
    gen = torch.Generator().manual_seed(config.seed)
    trainer = Trainer(system, config, run_dir, nets, optimizer, weights, gen)
    if state is not None:
        load_weights(nets, state, run_dir / "checkpoints" / "last.pt")
        optimizer.load_state_dict(state["optimizer"])
        for group in optimizer.param_groups:  # a resume may lower the learning rate
            group["lr"] = config.lr
        weights.weights = {**weights.weights, **state["weights"]}  # a term added since the checkpoint starts at 1 (zero unless trained)
        gen.set_state(state["generator"])
        trainer.epoch, trainer.best, trainer.eps_ema, trainer.elapsed = int(state["epoch"]), float(state["best"]), state["epsilon"], float(state["elapsed"])
        trainer.rollout_skipped = int(state.get("rollout_skipped", 0))  # absent from checkpoints of older runs
        trainer.counterexamples = state.get("counterexamples")
    else:
        write_json(run_dir / "config.json", config.to_dict())
        write_json(run_dir / "system.json", system_record(system, run_dir))
    return trainer


def _live(trainer: Trainer) -> dict:
    """Everything an epoch changes, as the trainer holds it now (not copied): the fields of a `snapshot`."""
    return {
        "nets": trainer.nets.state_dict(),
        "optimizer": trainer.optimizer.state_dict(),
        "weights": dict(trainer.weights.weights),
        "generator": trainer.gen.get_state(),
        "epoch": trainer.epoch,
        "best": trainer.best,
        "eps_ema": trainer.eps_ema,
        "counterexamples": trainer.counterexamples,
    }


def _cloned(tree):
    """A copy of a state dict's nesting of dicts, lists and tuples: tensors cloned, everything else
    (numbers, strings, None, as in Adam's state and param groups) shared, since it is immutable.
    Taken every epoch, where `copy.deepcopy` of Adam's state would cost a noticeable share of a fast-preset epoch."""
    if isinstance(tree, torch.Tensor):
        return tree.detach().clone()
    if isinstance(tree, dict):
        return {k: _cloned(v) for k, v in tree.items()}
    if isinstance(tree, (list, tuple)):
        return type(tree)(_cloned(v) for v in tree)
    return tree


def snapshot(trainer: Trainer) -> dict:
    """A copy of everything an epoch changes (weights, Adam, adaptive weights, generator, counters)."""
    live = _live(trainer)
    return {**live, "nets": _cloned(live["nets"]), "optimizer": _cloned(live["optimizer"])}


def restore(trainer: Trainer, snap: dict | None) -> None:
    """Put a `snapshot` back (no-op for None)."""
    if snap is None:
        return
    snap = copy.deepcopy(snap)
    trainer.nets.load_state_dict(snap["nets"])
    trainer.optimizer.load_state_dict(snap["optimizer"])
    trainer.weights.weights = dict(snap["weights"])
    trainer.gen.set_state(snap["generator"])
    trainer.epoch, trainer.best, trainer.eps_ema = snap["epoch"], snap["best"], snap["eps_ema"]
    trainer.counterexamples = snap.get("counterexamples")


def checkpoint(trainer: Trainer, name: str, epoch: int) -> None:
    """Save checkpoints/<name>.pt: everything `start` restores, at `epoch` epochs done."""
    save_snapshot(trainer, name, {**_live(trainer), "epoch": epoch})


def save_snapshot(trainer: Trainer, name: str, snap: dict) -> None:
    """Save checkpoints/<name>.pt from a `snapshot` (or the live state of `_live`): what `start` restores."""
    save_checkpoint(
        trainer.run_dir / "checkpoints" / f"{name}.pt",
        {"epoch": snap["epoch"], "nets": snap["nets"], "optimizer": snap["optimizer"], "weights": snap["weights"], "generator": snap["generator"],
         "best": snap["best"], "epsilon": snap["eps_ema"], "elapsed": trainer.elapsed, "rollout_skipped": trainer.rollout_skipped,
         **({"counterexamples": snap["counterexamples"]} if snap.get("counterexamples") is not None else {})},
    )


#: metrics.csv columns: the epoch (1-based), the weighted loss, each term and its adaptive weight r_,
#: the level ε of H_ε, the loss diagnostics, and the training seconds so far.
METRICS_COLUMNS = ["epoch", "loss", *TERMS, *(f"r_{t}" for t in TERMS), "epsilon", "inside_share", "dissipation_ok", "max_mu", "sublevel_share", "seconds"]


def open_metrics(path: Path, fresh: bool, epochs_done: int) -> None:
    """Write metrics.csv's header for a fresh run; when resuming, drop the rows past the checkpoint
    (they will be recomputed identically)."""
    if fresh or not path.exists():
        path.write_text(",".join(METRICS_COLUMNS) + "\n")
        return
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise DamagedFileError(
            f"{path} is damaged ({type(exc).__name__}). Fix: delete it (the resume writes a new one; the rows of the "
            "epochs already done are lost), then resume again."
        ) from None
    if not lines or lines[0].split(",")[:2] != METRICS_COLUMNS[:2]:
        raise DamagedFileError(f"{path} is damaged (no metrics header). Fix: delete it (the resume writes a new one), then resume again.")
    path.write_text("\n".join(lines[: epochs_done + 1]) + "\n")


def metrics_row(done: int, total: torch.Tensor, values: dict[str, float], weights: AdaptiveWeights, eps: float, diag: dict, elapsed: float) -> list:
    """One metrics.csv row (`METRICS_COLUMNS`) after `done` epochs."""
    return [
        done, f"{float(total.detach()):.6g}", *(f"{values[t]:.6g}" for t in TERMS), *(f"{weights.weights[t]:.6g}" for t in TERMS),
        f"{eps:.6g}", f"{float(diag['inside_share']):.4g}", f"{float(diag['dissipation_ok']):.4g}", f"{float(diag['max_mu']):.4g}",
        f"{float(diag['sublevel_share']):.4g}", f"{elapsed:.3f}",
    ]

"""The trainer: fresh uniform samples each epoch, named loss terms with adaptive weights, Adam,
atomic checkpoints (last and best), resume, NaN guard, Ctrl-C. The run directory it writes is
described in `training.run`.
"""

from __future__ import annotations

import csv
import datetime as _dt
import math
import time
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from .._io import write_json
from ..config import TrainConfig
from ..control.controller import anchor_settings, build_nets
from ..errors import IdapbcError
from .loss import TERMS, AdaptiveWeights, loss_terms
from ..control.linear import fastest_pole
from ..model.system import System
from .run import Run, read_checkpoint, read_config, save_checkpoint, system_record

__all__ = ["TrainingDiverged", "train"]


class TrainingDiverged(IdapbcError):
    """A loss term or gradient became NaN or inf; the last good checkpoint is kept."""


def _new_run_dir(out: Path) -> Path:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    run_dir = out / stamp
    k = 1
    while run_dir.exists():
        run_dir = out / f"{stamp}-{k}"
        k += 1
    (run_dir / "checkpoints").mkdir(parents=True)
    return run_dir


# ---------------------------------------------------------------------------------------- loop
def _sample(system: System, n: int, gen: torch.Generator) -> np.ndarray:
    lo, hi = (torch.as_tensor(b, dtype=torch.float64) for b in system.domain)
    return (lo + (hi - lo) * torch.rand(n, system.n, generator=gen, dtype=torch.float64)).numpy()


def train(
    system: System,
    config: TrainConfig | None = None,
    out: str | Path | None = None,
    *,
    resume: str | Path | None = None,
    progress: bool = True,
) -> Run:
    """Train Neural IDA-PBC networks for `system` and return the `Run`.

    Parameters
    ----------
    system : from `load_system`.
    config : `TrainConfig` (paper defaults if None). With `resume`, only `epochs` is taken from it
        (to extend a run); everything else comes from the run directory.
    out : parent of the new run directory (default ``runs/<system name>``).
    resume : an existing run directory to continue from its last checkpoint; the result equals an
        uninterrupted run with the same config (same seed, same machine).
    progress : show a tqdm progress bar with the named loss terms and ETA.
    """
    if resume is not None:
        run_dir = Path(resume)
        saved = read_config(run_dir)
        config = saved if config is None else saved.replace(epochs=config.epochs)
        state = read_checkpoint(run_dir, "last", map_location=config.device)
    else:
        config = config or TrainConfig()
        scaling, anchor_q = anchor_settings(system, config)  # "auto" values resolved: config.json holds what ran
        config = config.replace(scaling=scaling, anchor_q=anchor_q)
        run_dir = _new_run_dir(Path(out) if out is not None else Path("runs") / system.name)
        state = None
    if config.device.startswith("cuda") and not torch.cuda.is_available():
        raise IdapbcError(f"device '{config.device}' requested but torch sees no CUDA device. Fix: use --device cpu.")
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    nets = build_nets(system, config)
    optimizer = torch.optim.Adam(nets.parameters(), lr=config.lr)
    weights = AdaptiveWeights.start(config.gamma, config.alpha)
    gen = torch.Generator().manual_seed(config.seed)
    start_epoch, best, eps_ema, elapsed = 0, math.inf, None, 0.0
    if state is not None:
        nets.load_state_dict(state["nets"])
        optimizer.load_state_dict(state["optimizer"])
        weights.weights = dict(state["weights"])
        gen.set_state(state["generator"])
        start_epoch, best, eps_ema, elapsed = int(state["epoch"]), float(state["best"]), state["epsilon"], float(state["elapsed"])
    else:
        write_json(run_dir / "config.json", config.to_dict())
        write_json(run_dir / "system.json", system_record(system, run_dir))
    dtype, device = getattr(torch, config.dtype), torch.device(config.device)
    as_t = lambda a: torch.as_tensor(a, dtype=dtype, device=device)  # noqa: E731

    metrics_path = run_dir / "metrics.csv"
    columns = ["epoch", "loss", *TERMS, *(f"r_{t}" for t in TERMS), "epsilon", "inside_share", "dissipation_ok", "max_mu", "seconds"]
    if state is None or not metrics_path.exists():
        metrics_path.write_text(",".join(columns) + "\n")
    else:  # drop rows past the checkpoint (they will be recomputed identically)
        lines = metrics_path.read_text().splitlines()
        metrics_path.write_text("\n".join(lines[: start_epoch + 1]) + "\n")

    def checkpoint(name: str, epoch: int) -> None:
        save_checkpoint(
            run_dir / "checkpoints" / f"{name}.pt",
            {
                "epoch": epoch,
                "nets": nets.state_dict(),
                "optimizer": optimizer.state_dict(),
                "weights": dict(weights.weights),
                "generator": gen.get_state(),
                "best": best,
                "epsilon": eps_ema,
                "elapsed": elapsed,
            },
        )

    status = "finished"
    bar = tqdm(range(start_epoch, config.epochs), initial=start_epoch, total=config.epochs, disable=not progress, desc=f"train {system.name}", unit="epoch", dynamic_ncols=True)
    epoch = start_epoch
    t_last = time.perf_counter()
    try:
        with open(metrics_path, "a", newline="") as mfile:
            writer = csv.writer(mfile)
            for epoch in bar:
                x = _sample(system, config.samples, gen)
                xt = as_t(x)
                with torch.no_grad():
                    H = nets.H(xt)
                eps = as_t(config.epsilon) if config.epsilon > 0 else torch.quantile(H.double(), config.inside_fraction).to(dtype)
                inside = H < eps
                f = as_t(system.f(x))
                df_in = None
                if config.local_stability and bool(inside.any()):
                    df_in = as_t(system.df_dx(x[inside.cpu().numpy()]))
                terms, diag = loss_terms(nets, xt, f, eps, config.kappa, df_in, inside)
                values = {k: float(v.detach()) for k, v in terms.items()}
                bad = [k for k, v in values.items() if not math.isfinite(v)]
                if bad:
                    raise TrainingDiverged(
                        f"loss term '{bad[0]}' became {values[bad[0]]} at epoch {epoch}; the last good checkpoint is kept in "
                        f"{run_dir / 'checkpoints'}. Fix: lower --lr, check the domain, or resume from the checkpoint."
                    )
                total = weights.total(terms)
                optimizer.zero_grad(set_to_none=True)
                total.backward()
                for name, p in nets.named_parameters():
                    if p.grad is not None and not bool(torch.isfinite(p.grad).all()):
                        raise TrainingDiverged(f"gradient of '{name}' became non-finite at epoch {epoch}. Fix: lower --lr, or resume from the last checkpoint.")
                optimizer.step()
                weights.update(values)
                eps_value = float(eps)
                eps_ema = eps_value if eps_ema is None else 0.95 * eps_ema + 0.05 * eps_value
                now = time.perf_counter()
                elapsed += now - t_last
                t_last = now
                raw = sum(values.values())
                writer.writerow(
                    [epoch + 1, f"{float(total.detach()):.6g}", *(f"{values[t]:.6g}" for t in TERMS), *(f"{weights.weights[t]:.6g}" for t in TERMS),
                     f"{eps_value:.6g}", f"{float(diag['inside_share']):.4g}", f"{float(diag['dissipation_ok']):.4g}", f"{float(diag['max_mu']):.4g}", f"{elapsed:.3f}"]
                )
                if raw < best:
                    best = raw
                    checkpoint("best", epoch + 1)
                if (epoch + 1) % config.checkpoint_every == 0 or epoch + 1 == config.epochs:
                    mfile.flush()
                    checkpoint("last", epoch + 1)
                if progress:
                    bar.set_postfix({k[:6]: f"{v:.2e}" for k, v in values.items()} | {"diss_ok": f"{float(diag['dissipation_ok']):.2f}"}, refresh=False)
            epoch = config.epochs
    except KeyboardInterrupt:
        status = "interrupted"
        checkpoint("last", epoch)
    finally:
        bar.close()

    run = Run(run_dir, system, config, nets)
    run.summary = _summarise(run, status, epoch, eps_ema, elapsed)
    write_json(run_dir / "summary.json", run.summary)
    return run


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

"""Goal: the `reference_run/` fixture, a short pendubot run that pins training's results bit for bit.

``python tests/data/make_reference_run.py [OUT]`` (OUT defaults to this folder) trains `CONFIG` on the
zoo pendubot on the CPU, keeps the run directory as ``OUT/reference_run/`` and writes
``OUT/reference_run_torques.npz``: 16 seeded states ``x`` (16, n) and the torques ``u`` (16, m) in N·m
of the run's controller, under the default-checkpoint load. `tests/test_reference_run.py` trains the
same config again and asks for the same weights, the same metrics row by row (wall time aside) and the
same torques: a refactor that changes a result fails it.

float32 training rounds differently on another CPU (its BLAS kernels), by about 5e-5 of the weights
after these 12 epochs. ``python tests/data/make_reference_run.py --machine`` trains the same config on
this machine and keeps only what depends on it, checkpoints/ and metrics.csv, under
``reference_training/<machine>/`` (`machine`); the test accepts the weights of any committed reference.
"""

from __future__ import annotations

import platform
import re
import shutil
import sys
from pathlib import Path

import numpy as np

import idapbc_pin as ip

#: The fixture's training: the fast preset's networks, few epochs, no gate (seconds on 2 cores).
CONFIG = ip.TrainConfig.fast(epochs=12, samples=128, checkpoint_every=6, fallback="none", seed=5)


def states(system) -> np.ndarray:
    """16 seeded states of the half box around x*, (16, n)."""
    x = np.random.default_rng(0).uniform(*system.domain, size=(16, system.n))
    return 0.5 * x + 0.5 * system.x_star


def machine() -> str:
    """A label for this machine's CPU and torch's kernels: vendor, model and torch's CPU capability."""
    import torch

    cpu = platform.processor() or platform.machine()
    try:
        info = Path("/proc/cpuinfo").read_text()
        cpu = re.search(r"^model name\s*:\s*(.+)$", info, re.M).group(1)
    except (OSError, AttributeError):
        pass
    return re.sub(r"[^a-z0-9]+", "-", f"{cpu} {torch.backends.cpu.get_cpu_capability()}".lower()).strip("-")


def main(out: Path) -> None:
    system = ip.load_system("pendubot")
    out.mkdir(parents=True, exist_ok=True)
    run = ip.train(system, CONFIG, out=out / "tmp", progress=False)
    target = out / "reference_run"
    shutil.rmtree(target, ignore_errors=True)
    shutil.move(str(run.path), target)
    shutil.rmtree(out / "tmp")
    x = states(system)
    np.savez(out / "reference_run_torques.npz", x=x, u=ip.load_run(target).controller(x))


def main_machine(here: Path) -> Path:
    """Train the fixture's config on this machine and keep its checkpoints and metrics under
    ``here/reference_training/<machine>/``; returns that folder."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        main(Path(tmp))
        target = here / "reference_training" / machine()
        shutil.rmtree(target, ignore_errors=True)
        (target / "checkpoints").mkdir(parents=True)
        for name in ("checkpoints/best.pt", "checkpoints/last.pt", "metrics.csv"):
            shutil.copy(Path(tmp) / "reference_run" / name, target / name)
    return target


if __name__ == "__main__":
    if sys.argv[1:] == ["--machine"]:
        print(main_machine(Path(__file__).parent))
    else:
        main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).parent)

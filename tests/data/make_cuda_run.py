"""Goal: the `cuda_run/` fixture, a small pendubot run trained with ``device="cuda"``.

Run it where torch sees a GPU: ``python tests/data/make_cuda_run.py [OUT]`` (OUT defaults to this
folder). It trains 4 epochs of a width-16 fast preset on the GPU, keeps the run directory as
``OUT/cuda_run/`` and writes ``OUT/cuda_run_torques.npz``: 16 seeded states ``x`` (16, n) and the
torques ``u`` (16, m) in N·m that the run's controller computed on the GPU. `tests/test_devices.py`
loads the run on the CPU and compares.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import torch

import idapbc_pin as ip
from idapbc_pin.config import TrainConfig
from idapbc_pin.run import load_run
from idapbc_pin.training.train import train

#: The fixture's training: small enough to commit (about 40 kB of checkpoints).
CONFIG = TrainConfig.fast(epochs=4, width=16, depth=2, samples=64, checkpoint_every=2, fallback="none", device="cuda")


def main(out: Path) -> None:
    if not torch.cuda.is_available():
        sys.exit("make_cuda_run.py needs a CUDA device (torch.cuda.is_available() is False)")
    system = ip.load_system("pendubot")
    out.mkdir(parents=True, exist_ok=True)
    run = train(system, CONFIG, out=out / "tmp", progress=False)
    assert run.config.device == "cuda"
    x = np.random.default_rng(0).uniform(*system.domain, size=(16, system.n)) * 0.5 + 0.5 * system.x_star
    target = out / "cuda_run"
    shutil.rmtree(target, ignore_errors=True)
    shutil.move(str(run.path), target)
    shutil.rmtree(out / "tmp")
    u = load_run(target, device="cuda").controller(x)  # the torques the networks give on the GPU
    np.savez(out / "cuda_run_torques.npz", x=x, u=u, device=torch.cuda.get_device_name(0))
    print(f"wrote {target} and {out / 'cuda_run_torques.npz'} on {torch.cuda.get_device_name(0)}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).parent)

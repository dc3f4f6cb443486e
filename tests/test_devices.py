"""A run does not depend on the device that trained it: a run trained on a GPU is evaluated, resumed
and exported on a machine without one, with the torques it had there; and where torch sees a GPU,
a seed draws the same networks there as on the CPU and training there follows training on the CPU.

`data/cuda_run/` is a real GPU run (made by `data/make_cuda_run.py` on an NVIDIA H100/H200); the tests
marked `CUDA` run only where torch sees a GPU (not in CI).
"""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

import idapbc_pin as ip
from idapbc_pin.config import TrainConfig
from idapbc_pin.control.nets import build_nets
from idapbc_pin.run import load_run
from idapbc_pin.training.train import train

from .test_reliability import cli, snapshot

DATA = Path(__file__).parent / "data"
CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
NO_CUDA = pytest.mark.skipif(torch.cuda.is_available(), reason="checks the machine without a GPU")


@pytest.fixture
def gpu_run(tmp_path) -> Path:
    """A copy of the GPU-trained fixture run, for one test to use."""
    return Path(shutil.copytree(DATA / "cuda_run", tmp_path / "cuda_run"))


# ------------------------------------------------------------------------- a GPU run on the CPU
def test_a_run_trained_on_a_gpu_gives_the_cpu_the_torques_it_gave_there(gpu_run):
    run = load_run(gpu_run)
    assert run.config.device == "cuda" and not next(run.nets.parameters()).is_cuda
    ref = np.load(DATA / "cuda_run_torques.npz")
    u = run.controller(ref["x"])
    # float32 networks: the GPU's and the CPU's kernels round differently, a few units of float32's
    # 1.2e-7 per operation (measured: 2.8e-6 relative, 6.1e-5 N·m on torques of up to 101 N·m).
    np.testing.assert_allclose(u, ref["u"], rtol=1e-5, atol=1e-5 * np.abs(ref["u"]).max())


def test_a_gpu_run_is_simulated_and_exported_on_the_cpu(gpu_run, tmp_path):
    status, out, err, _ = cli("simulate", gpu_run, "--n", 2, "--no-radius", "--box", "half")
    assert status == 0, err
    assert "NIDA-PBC" in out
    status, out, err, _ = cli("export", gpu_run, "--out", tmp_path / "deploy", "--no-onnx")
    assert status == 0, err
    assert (tmp_path / "deploy" / "controller.py").is_file()


@NO_CUDA
def test_resuming_a_gpu_run_without_a_gpu_names_the_device_and_leaves_the_run_alone(gpu_run):
    before = snapshot(gpu_run)
    status, _, err, _ = cli("train", "--resume", gpu_run, "--epochs", 6)
    assert status == 2
    assert "device 'cuda'" in err and "no CUDA device" in err and "--device cpu" in err
    assert len(err.strip().splitlines()) == 1
    assert snapshot(gpu_run) == before


def test_a_gpu_run_resumes_on_the_cpu_when_asked(gpu_run):
    status, _, err, _ = cli("train", "--resume", gpu_run, "--epochs", 6, "--device", "cpu", "--recover", "never", "--evaluate", 0)
    assert status == 0, err
    rows = list(csv.DictReader(open(gpu_run / "metrics.csv")))
    assert [int(r["epoch"]) for r in rows] == list(range(1, 7))
    assert all(np.isfinite(float(r["loss"])) for r in rows)


def test_an_unknown_device_is_refused_in_one_line(tmp_path):
    status, _, err, _ = cli("train", "pendubot", "--fast", "--epochs", 1, "--device", "tpu", "--out", tmp_path, "--recover", "never")
    assert status == 2
    assert "tpu" in err and "Fix:" in err and len(err.strip().splitlines()) == 1


# ---------------------------------------------------------------------------- where a GPU exists
SMALL = TrainConfig.fast(epochs=5, width=16, depth=2, samples=64, checkpoint_every=5, fallback="none", dtype="float64")


@CUDA
def test_a_seed_draws_the_same_networks_on_the_gpu_as_on_the_cpu():
    system = ip.load_system("pendubot")
    nets = {}
    for device in ("cpu", "cuda"):
        torch.manual_seed(3)
        nets[device] = build_nets(system, SMALL.replace(device=device)).state_dict()
    assert all(v.is_cuda for v in nets["cuda"].values())
    for k, v in nets["cpu"].items():
        assert torch.equal(v, nets["cuda"][k].cpu()), k


@CUDA
@pytest.mark.parametrize("rollout_epochs", [0, 2])
def test_training_on_the_gpu_follows_training_on_the_cpu(tmp_path, rollout_epochs):
    system = ip.load_system("pendubot")
    runs = {d: train(system, SMALL.replace(device=d, rollout_epochs=rollout_epochs), out=tmp_path / d, progress=False) for d in ("cpu", "cuda")}
    # trained on the GPU, handed back on the CPU: the gates, --evaluate and recover simulate there
    assert runs["cuda"].config.device == "cuda" and not next(runs["cuda"].nets.parameters()).is_cuda
    losses = {d: [float(r["loss"]) for r in csv.DictReader(open(run.path / "metrics.csv"))] for d, run in runs.items()}
    np.testing.assert_allclose(losses["cuda"], losses["cpu"], rtol=1e-9)
    x = np.random.default_rng(1).uniform(*system.domain, size=(64, system.n))
    np.testing.assert_allclose(runs["cuda"].controller(x), runs["cpu"].controller(x), rtol=1e-8, atol=1e-9)


@CUDA
def test_a_gpu_run_passes_the_fallback_gate_in_worker_processes(tmp_path):
    # the gate simulates the law in worker processes on the CPU: the networks' run-time caches from
    # training on the GPU must not travel there (it failed: "Cannot re-initialize CUDA in forked subprocess")
    system = ip.load_system("pendubot")
    run = train(system, SMALL.replace(device="cuda", fallback="auto"), out=tmp_path, progress=False, workers=2)
    assert run.summary["fallback"]["states"] > 0 and not next(run.nets.parameters()).is_cuda


@CUDA
def test_same_seed_on_the_gpu_gives_the_same_weights(tmp_path):
    system = ip.load_system("pendubot")
    a, b = (train(system, SMALL.replace(device="cuda"), out=tmp_path / k, progress=False) for k in "ab")
    for k, v in a.nets.state_dict().items():
        assert torch.equal(v, b.nets.state_dict()[k]), k


@CUDA
def test_the_fixture_maker_writes_a_run_that_loads_on_the_cpu(tmp_path):
    import runpy

    runpy.run_path(str(DATA / "make_cuda_run.py"), run_name="not_main")["main"](tmp_path)
    ref = np.load(tmp_path / "cuda_run_torques.npz")
    u = load_run(tmp_path / "cuda_run").controller(ref["x"])
    np.testing.assert_allclose(u, ref["u"], rtol=1e-5, atol=1e-5 * np.abs(ref["u"]).max())

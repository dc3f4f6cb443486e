"""Shared fixtures: seeded generators, uniform samples of a system's domain."""

from __future__ import annotations

import os
import signal

# Two workers on two cores: one thread each, in every BLAS / OpenMP pool of this process and of the
# Pythons it starts (the CLI and README tests), as `idapbc_pin._parallel` gives its own workers.
for _name, _value in {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}.items():
    os.environ.setdefault(_name, _value)

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

torch.set_num_threads(1)
threadpool_limits(1)  # numpy may have loaded its BLAS before this file (a plugin's import)

# The Ctrl-C tests send SIGINT to a child Python, as a terminal would. A shell that starts the
# suite in the background without job control (`cmd &` in a script, nohup) makes it ignore SIGINT,
# and an ignored signal stays ignored in every child: the child's Python then never raises
# KeyboardInterrupt and those tests wait out their timeouts (measured: a clean-clone CI run under
# `nohup bash -c …`). Restore the terminal's disposition; children start from SIG_DFL again.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def sample_domain(system, n: int, seed: int = 0) -> np.ndarray:
    """n uniform states of the system's training box, (n, system.n)."""
    lo, hi = system.domain
    return lo + (hi - lo) * np.random.default_rng(seed).random((n, system.n))


def cart_out_and_back(reaches, T: float):
    """A hand-made cart-pole `Trajectory` sampled every 2 ms over T s: the pole upright and still,
    the cart out to each of `reaches` (m) and back within the first second, then at rest at 0."""
    from idapbc_pin.sim.trajectory import Trajectory

    t = np.arange(0, int(round(T / 0.002)) + 1) * 0.002
    reach = np.asarray(reaches, dtype=np.float64)[:, None] * np.sin(np.pi * np.minimum(t, 1.0))[None]
    q = np.stack([reach, np.zeros_like(reach)], axis=2)
    v = np.zeros_like(q)
    N = len(reach)
    return Trajectory(t=t, x=np.concatenate([q, v], axis=2), q=q, v=v, u=np.zeros((N, t.size, 1)), diverged=np.zeros(N, bool))


@pytest.fixture
def cli(capsys):
    """``idapbc-pin ARGS`` through `main` in this process (the console script's own entry point): a
    `subprocess.CompletedProcess` with its exit status and what it printed, as a fresh Python's run
    would give (tests that need a fresh Python, where nothing else may reach stderr, start one)."""
    import subprocess

    from idapbc_pin.cli.main import main

    def run(*args):
        code = main([str(a) for a in args])
        captured = capsys.readouterr()
        return subprocess.CompletedProcess(args, code, captured.out, captured.err)

    return run


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="module")
def systems():
    """``systems(name)``: a zoo or built-in system, loaded once per test module."""
    import idapbc_pin as ip

    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = ip.load_system(name)
        return cache[name]

    return get


#: The fallback gate's states and horizon (s) in the suite (`_short_fallback_gate`; the README test's
#: fresh Python takes them too).
SHORT_GATE_STATES, SHORT_GATE_HORIZON = 4, 0.5


@pytest.fixture(scope="session", autouse=True)
def _short_fallback_gate():
    """The suite trains tiny networks by the dozen; after each, ``fallback="auto"`` runs a gate that
    simulates 100 states for 20 s (`training.fallback_gate`). Here it simulates 4 states for 0.5 s;
    tests/test_fallback.py puts the real values back where the gate's decision is the claim.
    Session scope: module-scoped fixtures that train are set up before function-scoped ones."""
    from idapbc_pin.recovery import box_gate as fallback_gate

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(fallback_gate, "GATE_STATES", SHORT_GATE_STATES)
        patch.setattr(fallback_gate, "GATE_HORIZON", SHORT_GATE_HORIZON)
        yield


@pytest.fixture
def one_label_chunk(monkeypatch):
    """A labelling step's starts in one chunk (`stage.LABEL_CHUNKS` = 1) instead of eight: a test's
    few starts then share one batched simulation instead of one each (the per-step cost dominates
    there). The labels are the same up to the rounding of a batched matrix product. Modules use it
    where the chunks are not the claim: the resume tests (tests/test_plans.py) keep the eight, and
    the worker-count tests of tests/test_recovery.py put them back."""
    from idapbc_pin.recovery import stage

    monkeypatch.setattr(stage, "LABEL_CHUNKS", 1)


def pytest_collection_modifyitems(config, items):
    """Run the end-to-end tests (marked slow, a minute or two each) first: with two workers a long
    test that starts last leaves the other worker idle until it ends."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)

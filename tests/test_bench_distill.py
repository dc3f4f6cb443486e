"""`benchmarks/bench_distill.py` measures what its README table claims: the imitation term is zero
exactly for a law that reproduces its labels (beyond the limit, on the label's side, counts as
reproducing it). Its labels, fit and DAgger rounds are the library's (`training.recovery`, tested in
tests/test_recovery.py)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

import idapbc_pin as ip
from idapbc_pin.control.nets import build_nets

_DIR = Path(__file__).resolve().parents[1] / "benchmarks"
_spec = importlib.util.spec_from_file_location("bench_distill", _DIR / "bench_distill.py")
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def _weak_pendubot():
    return ip.load_system("pendubot", effort={"shoulder": 8.0})


def test_imitation_is_zero_for_the_networks_own_law_and_counts_only_the_wrong_side_of_a_limit():
    system = _weak_pendubot()
    nets = build_nets(system, ip.TrainConfig(seed=0))
    x = torch.as_tensor(np.random.default_rng(1).uniform(*system.domain, (64, system.n)), dtype=torch.float64)
    f = torch.as_tensor(system.f(x.numpy()))
    u = nets.control(f, nets.desired(x.clone().requires_grad_(True))[4]).detach()
    effort = torch.tensor([1e4], dtype=torch.float64)  # no label at the limit: plain least squares
    assert float(bench.imitation(nets, x, f, u, effort).detach()) < 1e-10
    effort = torch.tensor([8.0], dtype=torch.float64)
    at_limit = 8.0 * torch.sign(u)  # labels on the limit, on the side the law already exceeds or not
    right_side = u.abs() >= 8.0
    loss_right = bench.imitation(nets, x[right_side[:, 0]], f[right_side[:, 0]], at_limit[right_side[:, 0]], effort)
    assert right_side.any() and float(loss_right.detach()) == 0.0
    loss_wrong = bench.imitation(nets, x, f, -at_limit, effort)
    assert float(loss_wrong.detach()) > 0.5


def test_a_robot_without_effort_limits_is_refused_in_one_line():
    out = subprocess.run([sys.executable, str(_DIR / "bench_distill.py"), "paper_cartpole"], capture_output=True, text=True, cwd=_DIR)
    assert out.returncode == 2
    assert "without an effort limit" in out.stderr and "Fix: pass --effort" in out.stderr
    assert "Traceback" not in out.stderr

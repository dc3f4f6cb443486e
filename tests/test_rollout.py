"""The `rollout` term simulates the true saturated closed loop and back-propagates through it
exactly: the plant's backward pass is its Jacobian, the simulated field is the judge's
f + g·sat(u), and the trajectory's gradient matches finite differences of the cost."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch

import idapbc_pin as ip
from idapbc_pin.config import TrainConfig
from idapbc_pin.control.controller import Controller
from idapbc_pin.control.nets import build_nets
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.training.rollout import PlantDrift, rollout_cost, rollout_gate, saturated_field
from idapbc_pin.run import read_checkpoint
from idapbc_pin.training.train import train

from .conftest import sample_domain

TINY = dict(width=16, depth=2, samples=64, checkpoint_every=5)


@pytest.mark.parametrize("name", ["cartpole", "pendubot", "paper_cartpole"])
def test_the_plants_backward_pass_is_its_jacobian(name):
    """gradcheck: PlantDrift's vector-Jacobian product against central differences of f itself."""
    system = ip.load_system(name)
    x = torch.as_tensor(sample_domain(system, 3, seed=1), dtype=torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda z: PlantDrift.apply(z, system), (x,), eps=1e-6, atol=1e-5, rtol=1e-4)


def test_the_simulated_field_is_the_true_loop_with_saturated_torque():
    system = ip.load_system("pendubot", effort={"shoulder": 8.0})
    torch.manual_seed(0)
    nets = build_nets(system, TrainConfig(**TINY))
    x = sample_domain(system, 200, seed=2)
    u = Controller(system, nets)(x)
    assert np.any(np.abs(u) > 8.0), "the test needs states where the law saturates"
    expected = system.f(x) + system.saturate(u) @ system.g(system.x_star).T
    field = saturated_field(nets, system, torch.as_tensor(x), torch.as_tensor(np.array(system.effort))).detach().numpy()
    np.testing.assert_allclose(field, expected, rtol=0, atol=1e-9 * (1 + np.abs(expected).max()))


def test_back_propagation_through_the_rollout_matches_finite_differences_of_its_cost():
    """d cost / dθ along a random direction of the weights, by autograd through time vs central differences."""
    system = ip.load_system("acrobot")
    torch.manual_seed(3)
    nets = build_nets(system, TrainConfig(**TINY))
    x0 = torch.as_tensor(system.x_star + 0.3 * (sample_domain(system, 8, seed=4) - system.x_star))
    effort = torch.full((system.m,), torch.inf, dtype=torch.float64)
    cost = lambda: rollout_cost(nets, system, x0, horizon=0.1, step=0.02, tail=0.06, effort=effort)  # noqa: E731
    params = [p for p in nets.parameters() if p.requires_grad]
    grads = torch.autograd.grad(cost(), params)
    gen = torch.Generator().manual_seed(5)
    direction = [torch.randn(p.shape, generator=gen, dtype=p.dtype) for p in params]
    analytic = sum(float((g * d).sum()) for g, d in zip(grads, direction))
    h = 1e-5
    with torch.no_grad():
        values = []
        for sign in (1, -1):
            for p, d in zip(params, direction):
                p.add_(sign * h * d)
            values.append(float(cost()))
            for p, d in zip(params, direction):
                p.sub_(sign * h * d)
    numeric = (values[0] - values[1]) / (2 * h)
    assert abs(analytic) > 1e-6
    assert analytic == pytest.approx(numeric, rel=1e-4)


def test_rollout_epochs_train_on_the_rollout_term_alone_and_are_reproducible(tmp_path, monkeypatch):
    from idapbc_pin.training import rollout

    monkeypatch.setattr(rollout, "GATE_STATES", 20)  # the gate's rule, not its size, is the claim here (100 by default)
    monkeypatch.setattr(rollout, "GATE_HORIZON", 3.0)  # nor its horizon (20 s by default)
    system = ip.load_system("acrobot")
    config = TrainConfig(epochs=5, rollout_epochs=2, rollout_samples=4, rollout_horizon=0.1, rollout_step=0.02, rollout_tail=0.04, **TINY)
    a = train(system, config, out=tmp_path / "a", progress=False)
    b = train(system, config, out=tmp_path / "b", progress=False)
    for k, v in a.nets.state_dict().items():
        assert torch.equal(v, b.nets.state_dict()[k]), k
    rows = list(csv.DictReader(open(a.path / "metrics.csv")))
    assert [float(r["rollout"]) for r in rows[:3]] == [0.0, 0.0, 0.0]
    assert all(float(r["rollout"]) > 0 for r in rows[3:])
    assert [float(r["loss"]) for r in rows[3:]] == [float(r["rollout"]) for r in rows[3:]]  # the rollout term alone
    assert rows[2]["r_matching"] == rows[3]["r_matching"] == rows[4]["r_matching"]  # adaptive weights frozen
    assert a.summary["final_terms"]["rollout"] > 0
    gate = a.summary["rollout_gate"]
    assert gate["states"] == 20 and 0 <= gate["before"] <= 1 and 0 <= gate["after"] <= 1
    assert gate["kept"] == (gate["after"] >= gate["before"])
    pre = read_checkpoint(a.path, "pre_rollout")["nets"]
    last = read_checkpoint(a.path, "last")["nets"]
    same = all(torch.equal(pre[k], last[k]) for k in pre)
    assert same != gate["kept"]  # not kept: the weights before the rollout epochs are the final ones


def test_the_gate_keeps_rollout_weights_only_when_the_real_loop_does_as_well():
    system = ip.load_system("cartpole")
    lqr = LQRController(system)
    idle = lambda x: np.zeros((len(x), system.m))  # noqa: E731  (never stabilises the upright cartpole)
    worse = rollout_gate(system, before=lqr, after=idle, box=0.2, seed=0)
    assert worse["before"] > 0.9 and worse["after"] == 0 and not worse["kept"]
    assert rollout_gate(system, before=idle, after=lqr, box=0.2, seed=0)["kept"]


def test_the_cli_passes_rollout_epochs_to_the_config_and_refuses_more_than_the_epochs(tmp_path, capsys):
    from idapbc_pin.cli.main import main

    config, out = tmp_path / "rollout.toml", tmp_path / "runs"
    config.write_text("[train]\nwidth = 8\ndepth = 1\nrollout_epochs = 4\n")  # an expert key: set in the config file
    args = ["train", "acrobot", "--epochs", "3", "--config", str(config), "--out", str(out), "--evaluate", "0"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "rollout_epochs must be in [0, epochs = 3]" in err
    assert not out.exists() or not any(out.iterdir())  # refused before any run directory is made


def test_a_rollout_epoch_whose_gradient_overflows_takes_no_step_and_the_run_goes_on(tmp_path, monkeypatch):
    """Back-propagation through an unstable trajectory can overflow; such an epoch is skipped and
    counted, the run finishes, and with every rollout epoch skipped the weights are those before them."""
    import idapbc_pin.training.train as train_module

    real = train_module.rollout_cost

    def overflowing(nets, *args):
        p = next(nets.parameters())
        return real(nets, *args) + torch.sqrt((p - p.detach()).sum())  # adds 0, with an infinite gradient

    monkeypatch.setattr(train_module, "rollout_cost", overflowing)
    system = ip.load_system("paper_mass_spring_damper")
    config = TrainConfig(epochs=4, rollout_epochs=2, rollout_samples=4, rollout_horizon=0.1, rollout_step=0.02, rollout_tail=0.04, **TINY)
    run = train(system, config, out=tmp_path, progress=False)
    assert run.summary["status"] == "finished" and run.summary["rollout_gate"]["skipped_epochs"] == 2
    pre = read_checkpoint(run.path, "pre_rollout")["nets"]
    last = read_checkpoint(run.path, "last")
    assert all(torch.equal(pre[k], last["nets"][k]) for k in pre)
    assert last["rollout_skipped"] == 2

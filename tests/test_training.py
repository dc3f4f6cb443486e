"""Training is reproducible, resumable, guarded against NaN, validated, and improves the loss on the
paper's benchmarks; the anchored networks make x* locally exponentially stable by construction."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

import idapbc_pin as ip
from idapbc_pin.config import TrainConfig
from idapbc_pin.control.controller import Controller
from idapbc_pin.control.nets import build_nets
from idapbc_pin.sim.step import step_for_pole
from idapbc_pin.training.loss import TERMS
from idapbc_pin.run import load_run
from idapbc_pin.training.train import TrainingDiverged, train

TINY = dict(width=16, depth=2, samples=64, checkpoint_every=5)


def _weights(run):
    return {k: v.clone() for k, v in run.nets.state_dict().items()}


def test_same_seed_same_weights(tmp_path):
    system = ip.load_system("paper_cartpole")
    a = train(system, TrainConfig(epochs=6, **TINY), out=tmp_path / "a", progress=False)
    b = train(system, TrainConfig(epochs=6, **TINY), out=tmp_path / "b", progress=False)
    for k, v in _weights(a).items():
        assert torch.equal(v, _weights(b)[k]), k


def test_resume_equals_uninterrupted(tmp_path):
    system = ip.load_system("paper_cartpole")
    full = train(system, TrainConfig(epochs=10, **TINY), out=tmp_path / "full", progress=False)
    half = train(system, TrainConfig(epochs=5, **TINY), out=tmp_path / "half", progress=False)
    resumed = train(system, TrainConfig(epochs=10, **TINY), resume=half.path, progress=False)
    assert resumed.path == half.path
    for k, v in _weights(full).items():
        assert torch.equal(v, _weights(resumed)[k]), k
    rows = list(csv.DictReader(open(resumed.path / "metrics.csv")))
    assert [int(r["epoch"]) for r in rows] == list(range(1, 11))
    assert rows[-1]["matching"] == list(csv.DictReader(open(full.path / "metrics.csv")))[-1]["matching"]


class _NaNAfter:
    """A plant whose f turns NaN after `k` calls (an injected fault)."""

    def __init__(self, plant, k):
        self._plant, self._k = plant, k

    def __getattr__(self, name):
        return getattr(self._plant, name)

    def f(self, q, p):
        self._k -= 1
        out = self._plant.f(q, p)
        return out * np.nan if self._k < 0 else out


def test_nan_guard_names_the_term_and_epoch_and_keeps_the_checkpoint(tmp_path):
    from dataclasses import replace

    system = ip.load_system("paper_cartpole")
    broken = replace(system, plant=_NaNAfter(system.plant, 7))
    with pytest.raises(TrainingDiverged) as info:
        train(broken, TrainConfig(epochs=20, **TINY), out=tmp_path, progress=False)
    message = str(info.value)
    assert "epoch 7" in message and "'matching'" in message or "'dissipation'" in message
    run_dir = next(tmp_path.iterdir())
    state = torch.load(run_dir / "checkpoints" / "last.pt", weights_only=True)
    # last.pt holds the weights with the lowest summed loss before the failure: the weights the
    # best metrics row was computed at (that row's epoch − 1 epochs done)
    rows = [r.split(",") for r in (run_dir / "metrics.csv").read_text().splitlines()]
    head, body = rows[0], rows[1:]
    terms = [head.index(t) for t in TERMS]
    best_row = min(body, key=lambda r: sum(float(r[i]) for i in terms))
    assert state["epoch"] == int(best_row[0]) - 1 < 7
    assert all(torch.isfinite(v).all() for v in state["nets"].values() if v.is_floating_point())


def test_after_a_divergence_the_suggested_resume_with_a_lower_lr_completes(tmp_path):
    system = ip.load_system("paper_cartpole")
    with pytest.raises(TrainingDiverged) as info:
        train(system, TrainConfig(epochs=12, lr=1e6, **TINY), out=tmp_path, progress=False)
    message = str(info.value)
    assert "--resume" in message and "--lr 0.0005" in message
    run_dir = next(tmp_path.iterdir())
    run = train(system, TrainConfig(epochs=12, lr=5e-4), resume=run_dir, progress=False)
    assert run.summary["status"] == "finished" and run.summary["epochs_done"] == 12
    assert all(torch.isfinite(p).all() for p in run.nets.parameters())


@pytest.mark.parametrize(
    "bad, fragment",
    [({"rho": -1.0}, "rho"), ({"rho": 0.1, "kappa": 0.2}, "κ = 0.2) must be < rho"), ({"epochs": 0}, "epochs"), ({"form": "magic"}, "form"),
     ({"scaling": "unit"}, "scaling must be"), ({"epochs": 10, "rollout_epochs": 11}, "rollout_epochs must be in [0, epochs = 10]"),
     ({"rollout_tail": 4.0}, "rollout_tail must be in (0, rollout_horizon]"), ({"rollout_step": 0.0}, "rollout_step")],
)
def test_bad_config_is_refused(bad, fragment):
    with pytest.raises(ip.IdapbcError) as info:
        TrainConfig(**bad)
    assert fragment in str(info.value)


def test_empty_domain_is_refused():
    with pytest.raises(ip.IdapbcError, match="empty or infinite domain"):
        ip.load_system("paper_cartpole", domain={"q1": (1.0, 1.0)})


def test_config_file_round_trip(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[train]\nepochs = 7\nrho = 0.5\nkappa = 0.1\n")
    assert TrainConfig.from_file(path) == TrainConfig(epochs=7, rho=0.5, kappa=0.1)
    path.write_text("[train]\nepoch = 7\n")
    with pytest.raises(ip.IdapbcError, match="unknown training config key"):
        TrainConfig.from_file(path)


@pytest.mark.parametrize("name", ["paper_double_pendulum", "paper_cartpole", "paper_mass_spring_damper"])
def test_short_training_of_each_paper_benchmark_decreases_the_loss(name, tmp_path):
    system = ip.load_system(name)
    run = train(system, TrainConfig(epochs=60, width=32, depth=2, samples=128, dtype="float32"), out=tmp_path, progress=False)
    rows = list(csv.DictReader(open(run.path / "metrics.csv")))
    raw = [sum(float(r[t]) for t in ("matching", "dissipation", "damping_floor", "local_stability", "decay")) for r in rows]
    assert all(np.isfinite(raw))
    assert np.mean(raw[-10:]) < np.mean(raw[:10])
    assert run.summary["locally_exponentially_stable"]
    loaded = load_run(run.path, checkpoint="last")
    x = system.x_star + 0.1
    np.testing.assert_allclose(loaded.controller(x), run.controller(x), rtol=1e-6)
    default = load_run(run.path)  # every command on a RUN uses the weights train returned and evaluated
    assert default.checkpoint == run.checkpoint == "last"
    np.testing.assert_allclose(default.controller(x), run.controller(x), rtol=1e-6)
    assert json.loads((run.path / "summary.json").read_text())["status"] == "finished"


@pytest.mark.parametrize("energy_input", ["anchor", "box"])
@pytest.mark.parametrize("name", ["paper_cartpole", "acrobot", "furuta"])
def test_anchor_makes_the_closed_loop_linearisation_the_lqr_loop(name, energy_input):
    """For random weights, ∂(f + g u)/∂x at x* equals A − BK of the LQR anchor (Theorem 2, μ̄* = 0)."""
    from idapbc_pin.control.anchor import system_anchor as _anchor
    from idapbc_pin.control.controller import Controller

    system = ip.load_system(name)
    config = TrainConfig(width=16, depth=2, energy_input=energy_input)
    anchor = _anchor(system, config)
    for seed in range(3):
        torch.manual_seed(seed)
        ctrl = Controller(system, build_nets(system, config))
        np.testing.assert_allclose(ctrl.closed_loop_jacobian(), anchor.A_cl, rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(ctrl.mismatch(system.x_star), 0.0, atol=1e-12)
        np.testing.assert_allclose(ctrl(system.x_star), 0.0, atol=1e-12)


def test_controller_structure_and_extra_damping():
    system = ip.load_system("acrobot")
    torch.manual_seed(0)
    ctrl = Controller_(system)
    x = system.x_star + np.random.default_rng(0).normal(scale=0.3, size=(20, system.n))
    J = ctrl.J_d(x)
    np.testing.assert_allclose(J, -np.swapaxes(J, 1, 2), atol=1e-15)
    assert np.linalg.eigvalsh(ctrl.R_d(x)).min() > 0
    damped = ctrl.with_damping(2.0)
    np.testing.assert_allclose(damped.R_d(x) - ctrl.R_d(x), np.broadcast_to(2.0 * np.eye(system.n), J.shape), atol=1e-12)
    assert ctrl.rho == 0.0 and damped.rho == 2.0
    tau = ctrl.torque(*system.split(x))
    assert tau.shape == (20, system.nv) and np.all(tau[:, system.coordinate_names.index("shoulder")] == 0)


def test_the_control_law_sees_an_angle_one_turn_away_as_the_same_angle():
    """Angles enter the law wrapped to within π of x* (as in the LQR baseline): a pendulum that has
    swung once round gets the torque of the state next to the target, in both run-time paths.
    Runs trained before the option existed (wrap_angles False) keep their unwrapped law."""
    system = ip.load_system("acrobot")
    torch.manual_seed(4)
    ctrl = Controller(system, build_nets(system, TrainConfig(width=16, depth=2)))
    x = system.x_star + np.random.default_rng(4).normal(scale=0.3, size=(40, system.n))
    turned = x + 2 * np.pi * np.array([1.0, -2.0, 0.0, 0.0])
    np.testing.assert_allclose(ctrl(turned), ctrl(x), rtol=1e-9, atol=1e-9)  # 40 states: torch path
    np.testing.assert_allclose(ctrl(turned[5]), ctrl(x[5]), rtol=1e-9, atol=1e-9)  # one state: numpy path
    torch.manual_seed(4)
    legacy = Controller(system, build_nets(system, TrainConfig(width=16, depth=2, wrap_angles=False)))
    np.testing.assert_allclose(legacy(x), ctrl(x), rtol=1e-12, atol=1e-12)
    assert np.abs(legacy(turned) - legacy(x)).max() > 1.0


def Controller_(system):
    from idapbc_pin.control.controller import Controller

    return Controller(system, build_nets(system, TrainConfig(width=16, depth=2)))


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("scaling", ["none", "box"])
@pytest.mark.parametrize("form, energy_input", [("anchored", "anchor"), ("anchored", "box"), ("free", "box")])
def test_run_time_path_equals_the_training_path(form, energy_input, scaling, dtype):
    """Both run-time paths of f̃_d (numpy on the CPU, torch for batches from a GPU; explicit ∇H_d, no
    autograd) give the autograd path's f̃_d, and u from one state equals u from a batch."""
    system = ip.load_system("cartpole")
    torch.manual_seed(1)
    config = TrainConfig(width=16, depth=3, form=form, rho=0.2, kappa=0.1, scaling=scaling, anchor_q=10.0, dtype=dtype, energy_input=energy_input)
    ctrl = Controller(system, build_nets(system, config), governor=False)  # the networks' law alone (the governor: test_speed_governor.py)
    with torch.no_grad():  # move every weight off its initial value (the anchored last layers start small)
        for p in ctrl.nets.parameters():
            p.add_(0.3 * torch.randn_like(p))
    x = system.x_star + np.random.default_rng(1).normal(scale=0.5, size=(30, system.n))
    fd_autograd = ctrl.f_d(x)
    tol = 1e-12 if dtype == "float64" else 2e-5
    np.testing.assert_allclose(ctrl.flow()(x), fd_autograd, rtol=tol, atol=tol * np.abs(fd_autograd).max())
    fd_torch = ctrl.nets.desired_fast(torch.as_tensor(x, dtype=getattr(torch, dtype))).double().numpy()
    np.testing.assert_allclose(fd_torch, fd_autograd, rtol=tol, atol=tol * np.abs(fd_autograd).max())
    u_ref = (fd_autograd - system.f(x)) @ system.g(system.x_star)
    np.testing.assert_allclose(ctrl(x), u_ref, rtol=tol, atol=tol * np.abs(u_ref).max())  # 30 states
    np.testing.assert_allclose(ctrl(x[3]), u_ref[3], rtol=tol, atol=tol * np.abs(u_ref).max())  # one state
    np.testing.assert_allclose(ctrl.with_damping(1.5).flow()(x), ctrl.with_damping(1.5).f_d(x), rtol=tol, atol=tol * np.abs(fd_autograd).max())
    H = ctrl.H_d(x)  # the numpy H_d (a recovery law's level switch) is the networks' H_d
    np.testing.assert_allclose(ctrl.flow().energy(x), H, rtol=tol, atol=tol * np.abs(H).max())


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_a_large_batch_is_evaluated_in_blocks_with_the_values_of_one_pass(dtype):
    """Past `block_rows` states, f̃_d and H_d are evaluated block by block: the same values as the
    autograd path (the networks' rounding), and each block's rows as that block alone gives them."""
    system = ip.load_system("cartpole")
    torch.manual_seed(2)
    ctrl = Controller(system, build_nets(system, TrainConfig(width=64, depth=3, dtype=dtype)))
    flow = ctrl.flow()
    n = 2 * flow.block_rows + 7
    assert flow.block_rows * 64 * flow.dtype.itemsize <= 128_000 < n * 64 * flow.dtype.itemsize
    x = system.x_star + np.random.default_rng(3).normal(scale=0.5, size=(n, system.n))
    tol = 1e-12 if dtype == "float64" else 2e-5
    fd = flow(x)
    np.testing.assert_allclose(fd, ctrl.f_d(x), rtol=tol, atol=tol * np.abs(fd).max())
    H = flow.energy(x)
    np.testing.assert_allclose(H, ctrl.H_d(x), rtol=tol, atol=tol * np.abs(H).max())
    blocks = np.array_split(np.arange(n), 3)
    np.testing.assert_array_equal(fd, np.concatenate([flow(x[rows]) for rows in blocks]))


def test_run_time_path_follows_the_weights():
    """After an optimiser step the controller's run-time path uses the new weights, not a stale copy."""
    system = ip.load_system("cartpole")
    torch.manual_seed(2)
    ctrl = Controller(system, build_nets(system, TrainConfig(width=16, depth=2)), governor=False)  # the networks' law alone
    x = system.x_star + np.random.default_rng(2).normal(scale=0.5, size=(5, system.n))
    before = ctrl(x)
    loss = ctrl.nets.desired(torch.as_tensor(x), create_graph=True)[4].square().sum()
    optimizer = torch.optim.Adam(ctrl.nets.parameters(), lr=1e-2)
    loss.backward()
    optimizer.step()
    after = ctrl(x)
    assert np.abs(after - before).max() > 1e-6
    np.testing.assert_allclose(after, (ctrl.f_d(x) - system.f(x)) @ system.g(system.x_star), rtol=1e-12, atol=1e-12)


def test_true_closed_loop_is_desired_dynamics_plus_xi():
    """Proposition 1: under u, ẋ = f + g u equals f̃_d + ξ exactly (our sign of ξ = −G⁻¹(0; μ))."""
    system = ip.load_system("cartpole")
    torch.manual_seed(3)
    nets = build_nets(system, TrainConfig(width=16, depth=2))
    x = system.x_star + np.random.default_rng(3).normal(scale=0.4, size=(25, system.n))
    xt = torch.as_tensor(x)
    f = torch.as_tensor(system.f(x))
    f_d = nets.desired(xt)[4]
    u = nets.control(f, f_d)
    closed_loop = f + u @ nets.g.T
    torch.testing.assert_close(closed_loop, f_d + nets.xi(nets.mismatch(f, f_d)), rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("name", sorted(__import__("idapbc_pin.model.zoo", fromlist=["ZOO"]).ZOO))
def test_fast_preset_networks_build_on_every_zoo_robot(name):
    """float32 networks anchored on each robot's LQR loop (the anchor is factored in float64)."""
    from idapbc_pin.control.anchor import system_anchor as _anchor
    from idapbc_pin.control.controller import Controller

    system = ip.load_system(name)
    torch.manual_seed(0)
    config = TrainConfig.fast()
    ctrl = Controller(system, build_nets(system, config))
    A_cl = _anchor(system, config).A_cl
    assert np.abs(ctrl.closed_loop_jacobian() - A_cl).max() <= 1e-2 * max(1.0, np.abs(A_cl).max())
    assert np.all(ctrl.eigenvalues_at_target().real < 0)


@pytest.mark.slow
def test_fully_actuated_system_with_an_exact_solution_is_matched(tmp_path):
    """The mass-spring-damper is fully actuated (g⊥ = [1 0]: matching only asks q̇-row = p), so an
    exact solution exists. Training drives max ‖μ‖ below 1e-3 on fresh test samples of H_ε (where
    the paper's loss asks for matching) and the closed loop converges to x*."""
    from idapbc_pin.sim.integrate import simulate
    from idapbc_pin.sim.metrics import success
    from idapbc_pin.sim.states import uniform_states

    system = ip.load_system("paper_mass_spring_damper")
    run = train(system, TrainConfig.fast(epochs=400, depth=2), out=tmp_path, progress=False)
    ctrl = run.controller
    x = uniform_states(system, 4000, "domain", seed=11)
    inside = ctrl.H_d(x) < run.summary["epsilon"]
    assert inside.sum() > 100
    assert np.linalg.norm(ctrl.mismatch(x[inside]), axis=1).max() < 1e-3
    traj = simulate(system, ctrl, uniform_states(system, 8, "domain", seed=12), T=20.0)
    assert success(traj, system).all()


def _train_summary_text(eigs, open_loop=None, config=None) -> str:
    """`format_train_summary` of a finished run with closed-loop eigenvalues `eigs` at x* ([re, im] pairs)."""
    from types import SimpleNamespace

    from idapbc_pin.training.summary import format_train_summary

    s = {"status": "finished", "epochs_done": 1, "train_seconds": 1.0, "final_terms": {"matching": 0.1},
         "eigenvalues_at_target": eigs, "locally_exponentially_stable": True}
    if open_loop is not None:
        s["open_loop_fastest_pole"] = open_loop
    return format_train_summary(SimpleNamespace(path="RUN", summary=s, config=config))


def test_train_summary_names_the_anchor_weight_actually_used():
    """Box units (scaling) and the LQR weight's units (anchor_weight) are separate settings: box units
    with the default physical weight use Q = anchor_q·I, as `control.anchor` builds it."""
    eigs = [[-2.0, 0.0]]
    physical = _train_summary_text(eigs, config=TrainConfig(scaling="box", anchor_q=1.0))
    assert "anchor: LQR with anchor_q = 1 (networks in box units, Q = anchor_q·I in physical units)" in physical
    boxed = _train_summary_text(eigs, config=TrainConfig(scaling="box", anchor_weight="box", anchor_q=1.0))
    assert "(networks in box units, Q = anchor_q·diag(1/s²))" in boxed
    assert "anchor_q = 10 (Q = anchor_q·I in physical units)" in _train_summary_text(eigs, config=TrainConfig(scaling="none", anchor_q=10.0))


def test_train_summary_warns_when_the_loop_is_too_stiff_for_the_default_rk4_step():
    stiff = _train_summary_text([[-252.5, 0.0], [-8.6, 2.5], [-8.6, -2.5], [-0.46, 0.0]])  # the Furuta anchor with anchor_q = 10, box units
    assert "NOTE: the fastest closed-loop pole at x* has |λ| = 252 1/s" in stiff
    assert "will judge it with a 1.98 ms step" in stiff  # 20 s / ceil(20 s · 252.5 / 0.5): |λ|·dt ≤ 0.5
    assert "NOTE" not in _train_summary_text([[-40.4, 39.7], [-40.4, -39.7], [-4.8, 0.0]])
    assert "NOTE" not in _train_summary_text([[-240.0, 0.0], [-4.8, 0.0]])  # 0.48 at 2 ms: the judge keeps its step
    assert "gentler anchor" in stiff and "plant has it too" not in stiff  # no open-loop pole recorded: blame the anchor


def test_the_stiffness_note_blames_the_plant_when_its_own_pole_is_that_fast():
    """erd:double_pendulum (light links, URDF joint damping) has a −136 1/s plant pole, which no anchor
    weight removes; the judge's 2 ms step takes it, but a plant three times as stiff would not, and
    then the NOTE says so instead of suggesting a gentler anchor."""
    system = ip.load_system("erd:double_pendulum", actuated=["joint1"])
    plant = float(np.abs(np.linalg.eigvals(system.linearization()[0])).max())
    assert plant > 100.0  # the plant's damping pole

    own = _train_summary_text([[-3 * plant, 0.0], [-1.0, 0.0]], open_loop=3 * plant)  # a stiffer copy of that plant
    assert "plant has it too" in own and "gentler anchor" not in own
    assert f"will judge it with a {1e3 * step_for_pole(3 * plant, 20.0):.3g} ms step" in own and step_for_pole(3 * plant, 20.0) * 3 * plant <= 0.5
    anchor = _train_summary_text([[-300.0, 0.0], [-1.0, 0.0]], open_loop=10.0)  # a stiff anchor on a slow plant
    assert "gentler anchor" in anchor and "plant has it too" not in anchor


@pytest.mark.parametrize(
    "name, scaling, anchor_q",
    [("paper_cartpole", "none", 10.0), ("paper_double_pendulum", "none", 10.0), ("pendubot", "none", 10.0),
     ("cartpole", "box", 10.0), ("furuta", "box", 1.0), ("reaction_wheel", "box", 0.01)],
)
def test_automatic_units_and_anchor_weight(name, scaling, anchor_q):
    """Box units where the box's half-widths span > 20× (light links), and the largest anchor weight whose
    LQR loop has no pole faster than 15 1/s; explicit values are kept as given."""
    from idapbc_pin.control.anchor import AUTO_MAX_POLE, anchor_settings
    from idapbc_pin.control.anchor import half_widths as _half_widths
    from idapbc_pin.control.anchor import system_anchor as _anchor

    system = ip.load_system(name)
    half = _half_widths(system)
    assert (half.max() > 20 * half.min()) == (scaling == "box")
    assert anchor_settings(system, TrainConfig.fast()) == (scaling, anchor_q)
    auto = TrainConfig.fast().replace(scaling=scaling, anchor_q=anchor_q)
    assert np.abs(np.linalg.eigvals(_anchor(system, auto).A_cl)).max() <= AUTO_MAX_POLE
    if anchor_q < 10.0:  # the weight above it was too stiff
        stiffer = auto.replace(anchor_q=anchor_q * 10)
        assert np.abs(np.linalg.eigvals(_anchor(system, stiffer).A_cl)).max() > AUTO_MAX_POLE
    assert anchor_settings(system, TrainConfig.fast(scaling="none", anchor_q=3.0)) == ("none", 3.0)


@pytest.mark.parametrize("name", ["cartpole", "cart_double_pendulum"])
def test_a_carts_position_weight_makes_its_return_no_slower_than_the_floor(name):
    """Q = anchor_q·I weighs a metre of cart like a radian, and the cart's return is then the loop's
    slowest mode (slower than 1 1/s on both cart robots); the automatic weight on the cart's position
    (the first of 1, 3, 10, … that meets the floor under the cap) brings every pole to ≤ −2 1/s, and a
    run records it. Robots without a prismatic joint, and the analytic models, keep Q = anchor_q·I."""
    from idapbc_pin.control.anchor import AUTO_MAX_POLE, AUTO_SLOWEST_POLE, cart_setting, system_anchor
    from idapbc_pin.training.train import resolved_config

    system = ip.load_system(name)
    config = resolved_config(system, TrainConfig.fast())
    assert config.anchor_cart == cart_setting(system, TrainConfig.fast()) == 10.0
    poles = np.linalg.eigvals(system_anchor(system, config).A_cl)
    assert poles.real.max() <= -AUTO_SLOWEST_POLE and np.abs(poles).max() <= AUTO_MAX_POLE
    assert np.linalg.eigvals(system_anchor(system, config.replace(anchor_cart=1.0)).A_cl).real.max() > -1.0
    assert np.linalg.eigvals(system_anchor(system, config.replace(anchor_cart=3.0)).A_cl).real.max() > -AUTO_SLOWEST_POLE  # 3 falls short
    for other in ("acrobot", "furuta", "paper_cartpole"):
        robot = ip.load_system(other)
        resolved = resolved_config(robot, TrainConfig.fast())
        assert resolved.anchor_cart == 1.0
        np.testing.assert_array_equal(system_anchor(robot, resolved).A_cl, system_anchor(robot, resolved.replace(anchor_cart=7.0)).A_cl)


def test_a_plant_stiffer_than_the_cap_gets_the_lqr_baselines_weight():
    """Light, damped links (example-robot-data's double_pendulum_simple): the plant's own −153 1/s pole
    leaves no weight under the 15 1/s cap, and the automatic weight is then the LQR baseline's,
    anchor_q = 1 (Q = I, R = I), not the gentlest one tried."""
    from idapbc_pin.control.anchor import AUTO_MAX_POLE, AUTO_STIFF_PLANT_Q, anchor_settings

    for joint in ("joint1", "joint2"):
        system = ip.load_system("erd:double_pendulum_simple", actuated=[joint])
        assert np.abs(np.linalg.eigvals(system.linearization()[0])).max() > AUTO_MAX_POLE
        assert anchor_settings(system, TrainConfig.fast()) == ("box", AUTO_STIFF_PLANT_Q) == ("box", 1.0)
    pendubot = ip.load_system("pendubot")  # a plant under the cap keeps the rule's own choice
    assert anchor_settings(pendubot, TrainConfig.fast()) == ("none", 10.0)


def test_the_run_directory_holds_the_resolved_units_and_old_runs_load_in_physical_units(tmp_path):
    import json

    system = ip.load_system("furuta")
    run = train(system, TrainConfig.fast(epochs=2, width=8, depth=1, samples=16), out=tmp_path / "new", progress=False)
    saved = json.loads((run.path / "config.json").read_text())
    assert (saved["scaling"], saved["anchor_q"], saved["anchor_weight"]) == ("box", 1.0, "physical") and run.config.scaling == "box"
    assert ip.load_run(run.path).controller(system.x_star[None]).shape == (1, 1)
    legacy = train(system, TrainConfig.fast(epochs=2, width=8, depth=1, samples=16, scaling="none", anchor_q=10.0, energy_input="box"), out=tmp_path / "old", progress=False)
    raw = json.loads((legacy.path / "config.json").read_text())
    del raw["scaling"], raw["energy_input"], raw["anchor_cart"]  # written before the options existed
    (legacy.path / "config.json").write_text(json.dumps(raw))
    loaded = ip.load_run(legacy.path, checkpoint="last")  # the final weights (best.pt holds the best-scoring ones)
    assert (loaded.config.scaling, loaded.config.energy_input, loaded.config.anchor_cart) == ("none", "box", 1.0)
    np.testing.assert_allclose(loaded.controller(system.x_star[None] + 0.1), legacy.controller(system.x_star[None] + 0.1))


def test_the_anchor_weight_is_the_lqr_baselines_in_physical_units_and_old_box_runs_keep_theirs(tmp_path):
    """Under box scaling the anchor's linearisation is the LQR loop with Q = anchor_q·I in physical units
    (with anchor_q = 1 exactly the baseline's gain K); a run written before `anchor_weight` existed
    was anchored with Q = anchor_q·diag(1/s²) and loads that way."""
    import json

    from idapbc_pin.control.anchor import half_widths, system_anchor
    from idapbc_pin.control.baseline import LQRController

    system = ip.load_system("furuta")
    A, B = system.linearization()
    K = LQRController(system).K
    config = TrainConfig.fast(scaling="box", anchor_q=1.0)
    np.testing.assert_allclose(system_anchor(system, config).A_cl, A - B @ K, atol=1e-8)
    old = config.replace(anchor_weight="box")
    assert np.abs(np.linalg.eigvals(system_anchor(system, old).A_cl) - np.linalg.eigvals(A - B @ K)[:, None]).min(0).max() > 0.1
    assert half_widths(system).max() > 20 * half_widths(system).min()

    legacy = train(system, TrainConfig.fast(epochs=2, width=8, depth=1, samples=16, anchor_weight="box"), out=tmp_path / "old", progress=False)
    raw = json.loads((legacy.path / "config.json").read_text())
    del raw["anchor_weight"]  # written before the option existed
    (legacy.path / "config.json").write_text(json.dumps(raw))
    loaded = ip.load_run(legacy.path, checkpoint="last")
    assert loaded.config.anchor_weight == "box"
    x = system.x_star[None] + 0.05
    np.testing.assert_allclose(loaded.controller(x), legacy.controller(x))


def test_two_trainings_started_in_the_same_second_get_a_run_directory_each(tmp_path, monkeypatch):
    import datetime as real_dt
    from pathlib import Path

    import idapbc_pin.training.train as train_module

    class Frozen(real_dt.datetime):  # both trainings read the same clock second
        @classmethod
        def now(cls, tz=None):
            return real_dt.datetime(2026, 1, 2, 3, 4, 5)

    monkeypatch.setattr(train_module._dt, "datetime", Frozen)
    first = train_module._new_run_dir(tmp_path / "runs")
    # The race: another process takes the name after a look-before-create check found it free.
    monkeypatch.setattr(Path, "exists", lambda self, **kw: False)
    second = train_module._new_run_dir(tmp_path / "runs")
    third = train_module._new_run_dir(tmp_path / "runs")
    assert [p.name for p in (first, second, third)] == ["20260102-030405", "20260102-030405-1", "20260102-030405-2"]
    assert all((p / "checkpoints").is_dir() and not any((p / "checkpoints").iterdir()) for p in (first, second, third))


@pytest.mark.parametrize("form", ["anchored", "free"])
def test_the_one_pass_jacobian_of_the_desired_flow_is_autograds_per_state(form):
    """∂f̃_d/∂x from one forward and one backward pass over copies of the states (the local-stability
    term's) equals torch's Jacobian of f̃_d state by state, and its gradient w.r.t. the weights too."""
    from idapbc_pin.training.loss import _desired_jacobian

    system = ip.load_system("cartpole")
    torch.manual_seed(3)
    nets = build_nets(system, TrainConfig(width=16, depth=3, form=form, dtype="float64"))
    with torch.no_grad():
        for p in nets.parameters():
            p.add_(0.3 * torch.randn_like(p))
    x = torch.as_tensor(system.x_star + np.random.default_rng(3).normal(scale=0.5, size=(7, system.n)))
    fast = _desired_jacobian(nets, x)
    flow = lambda s: nets.desired(s.unsqueeze(0), create_graph=True)[4][0]  # noqa: E731
    slow = torch.stack([torch.autograd.functional.jacobian(flow, s, create_graph=True) for s in x])
    torch.testing.assert_close(fast, slow, rtol=1e-12, atol=1e-12)
    w = next(nets.parameters())
    g_fast, = torch.autograd.grad(fast.square().sum(), w)
    g_slow, = torch.autograd.grad(slow.square().sum(), w)
    torch.testing.assert_close(g_fast, g_slow, rtol=1e-10, atol=1e-12)

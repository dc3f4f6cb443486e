"""The law outside the training box (`control.fallback`) and the gate that decides whether a run uses it.

Claims:
* inside the training box the law is the networks' own; outside it, u* − k·Kδ with K the gain of the LQR
  loop the anchored networks are pinned to (eig(A − BK) = the learned loop's eigenvalues at x*) and k
  the run's `fallback_gain` (automatic: 3 for a robot with effort limits, 1 without; old runs 1);
  a state one turn away in an angle is the same state;
* the gate uses the fallback exactly when it brings strictly more simulated states to x*;
* a run records the decision (summary.json → fallback) and `load_run` applies it; "linear" and
  "none" force it; runs written before the option load without it.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.recovery.box_law import BoxFallback, box_fallback
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.recovery import box_gate as gate_module
from idapbc_pin.sim.step import DEFAULT_STEP, POLE_STEP, step_for_pole
from idapbc_pin.recovery.box_gate import GATE_STEP, fallback_gate, gate_step
from idapbc_pin.training.summary import format_train_summary


def _tiny(**changes) -> ip.TrainConfig:
    return ip.TrainConfig.fast(epochs=5, width=8, depth=1, samples=64, dtype="float64", **changes)


@pytest.fixture(scope="module")
def pendubot_run(tmp_path_factory):
    system = ip.load_system("pendubot")
    return ip.train(system, _tiny(fallback="linear"), out=tmp_path_factory.mktemp("fb"), progress=False)


def _wide_states(system, n=400, seed=0):
    """n states of three times the training box around x*: most of them outside it."""
    lo, hi = system.domain
    lo, hi = system.x_star + 3 * (lo - system.x_star), system.x_star + 3 * (hi - system.x_star)
    return lo + (hi - lo) * np.random.default_rng(seed).random((n, system.n))


def test_inside_the_box_the_law_is_the_networks_outside_it_the_anchors_linear_law(pendubot_run):
    run = pendubot_run
    ctrl = run.controller.with_governor(False)  # the laws alone; the governor comes after them, last
    assert isinstance(ctrl.fallback, BoxFallback)
    x = _wide_states(run.system)
    np.testing.assert_allclose(run.controller(x), run.controller.governor.apply(x, ctrl(x)), rtol=1e-12, atol=1e-12)  # x wrapped in one
    lo, hi = run.system.domain
    inside = np.all((x >= lo) & (x <= hi), axis=1)
    assert 0 < inside.sum() < len(x) - 100
    u, u_nets = ctrl(x), ctrl.with_fallback(None)(x)
    np.testing.assert_array_equal(u[inside], u_nets[inside])
    fb = ctrl.fallback
    delta = x[~inside] - run.system.x_star
    delta[:, :2] = (delta[:, :2] + np.pi) % (2 * np.pi) - np.pi  # both joints are angles
    np.testing.assert_allclose(u[~inside], fb.u_star - delta @ fb.K.T, rtol=1e-12, atol=1e-12)
    assert not np.allclose(u[~inside], u_nets[~inside])  # the switch changes something


def test_a_limited_robot_gets_three_times_the_anchor_gain_outside_the_box_an_unlimited_one_the_gain_itself(pendubot_run):
    run = pendubot_run
    assert run.config.fallback_gain == 3.0  # resolved when training starts, stored in config.json
    assert json.loads((run.path / "config.json").read_text())["fallback_gain"] == 3.0
    fb = run.controller.fallback
    np.testing.assert_allclose(fb.K, 3.0 * fb.anchor_K, rtol=1e-15)
    free = dataclasses.replace(run.system, effort=np.full(run.system.m, np.inf))
    assert not free.limited
    np.testing.assert_allclose(box_fallback(free, _tiny()).K, fb.anchor_K, rtol=1e-12)
    np.testing.assert_allclose(box_fallback(free, _tiny(fallback_gain=2.0)).K, 2.0 * fb.anchor_K, rtol=1e-12)


def test_a_state_one_turn_away_is_inside_the_box(pendubot_run):
    run = pendubot_run
    x = run.system.x_star + 0.2 * (run.system.domain[1] - run.system.x_star)
    turned = x.copy()
    turned[0] += 2 * np.pi
    assert not run.controller.fallback.outside(turned[None])[0]
    np.testing.assert_allclose(run.controller(turned), run.controller(x), rtol=1e-9, atol=1e-9)


def test_the_fallback_gain_closes_the_same_loop_as_the_networks_at_the_target(pendubot_run):
    run = pendubot_run
    fb = box_fallback(run.system, run.config)
    A, Bx = run.system.linearization()
    linear = np.sort_complex(np.linalg.eigvals(A - Bx @ fb.anchor_K))
    learned = np.sort_complex(run.controller.eigenvalues_at_target())
    np.testing.assert_allclose(linear, learned, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(fb.u_star, LQRController(run.system).u_star, atol=1e-12)


class _Law:
    """A stand-in for a learned law: LQR inside the training box, `outside_law` beyond it; with a
    fallback, the fallback's linear law beyond it instead (what `Controller.with_fallback` does)."""

    def __init__(self, system, outside_law, fallback=None):
        self.system, self.outside_law, self.fallback = system, outside_law, fallback
        self.lqr = LQRController(system)
        self.box = box_fallback(system, _tiny())

    def with_fallback(self, fallback):
        return _Law(self.system, self.outside_law, fallback)

    def __call__(self, x):
        u = self.lqr(x)
        out = self.box.outside(x)
        u[out] = self.outside_law(x[out])
        return u if self.fallback is None else self.fallback.apply(x, u)


@pytest.fixture
def real_gate(monkeypatch):
    """The gate's real horizon (20 s), on 40 states."""
    monkeypatch.setattr(gate_module, "GATE_STATES", 40)
    monkeypatch.setattr(gate_module, "GATE_HORIZON", 20.0)


def test_the_gate_takes_the_fallback_when_the_learned_law_fails_outside_the_box(real_gate):
    system = ip.load_system("pendubot")
    zero = lambda x: np.zeros((len(x), system.m))  # noqa: E731  (no torque once outside the box)
    fb = box_fallback(system, _tiny())
    gate = fallback_gate(system, _Law(system, zero), fb, seed=0)
    assert gate["states"] == 40 and gate["left_box"] > 0
    assert gate["with_fallback"] > gate["networks"] and gate["used"]
    _assert_discordant_pairs_explain_the_rates(gate)


def test_the_gate_keeps_the_learned_law_when_the_fallback_does_worse(real_gate):
    system = ip.load_system("pendubot")
    fb = box_fallback(system, _tiny())
    idle = dataclasses.replace(fb, K=np.zeros_like(fb.K))  # the "fallback" gives no feedback at all
    lqr = LQRController(system)
    gate = fallback_gate(system, _Law(system, lqr), idle, seed=0)
    assert gate["left_box"] > 0
    assert gate["with_fallback"] < gate["networks"] and not gate["used"]
    _assert_discordant_pairs_explain_the_rates(gate)


def test_the_gate_decides_the_same_in_two_worker_processes(monkeypatch):
    """The learned law and the scaled law simulated side by side in processes: the same gate, figure
    for figure, as in this process (20 states, 5 s: the claim is the equality, not the gate's size)."""
    monkeypatch.setattr(gate_module, "GATE_STATES", 20)
    monkeypatch.setattr(gate_module, "GATE_HORIZON", 5.0)
    system = ip.load_system("pendubot")
    fb = box_fallback(system, _tiny())
    assert fb.gain > 1.0  # a limited robot: three laws
    law = _Law(system, LQRController(system))
    one, two = fallback_gate(system, law, fb, seed=0), fallback_gate(system, law, fb, seed=0, workers=2)
    assert one == two
    assert one["left_box"] > 0 and one["scaled"] is not None


def _assert_discordant_pairs_explain_the_rates(gate: dict) -> None:
    """The states only one law brings to x* account for the whole difference of the two rates, and
    the law the gate picks is the one with the most successes (a tie to the simpler law)."""
    n = gate["states"]
    only_nn, only_fb = gate["only_networks"], gate["only_fallback"]
    assert 0 <= only_nn <= gate["left_box"] and 0 <= only_fb <= gate["left_box"]
    assert round(n * gate["with_fallback"]) - round(n * gate["networks"]) == only_fb - only_nn
    counts = [round(n * gate[k]) for k in ("networks", "with_fallback", "scaled") if gate[k] is not None]
    best = counts.index(max(counts))
    assert gate["used"] == (best > 0) and (gate["inside_gain"] != 1.0) == (best == 2)


def _weak(system, c):
    """u* + c (u_LQR − u*): LQR's law with its gain scaled by c."""
    lqr = LQRController(system)
    return lambda x: lqr.u_star + c * (lqr(x) - lqr.u_star)


def test_the_gate_scales_the_learned_law_inside_the_box_when_it_is_too_weak_to_hold_the_target(real_gate, monkeypatch):
    """A "learned" law with a quarter of LQR's gain leaves x* unstable (A − ¼BK has an eigenvalue at
    +2.4 1/s on the pendubot); scaled by k = 3 about u* it is ¾ of LQR's gain, inside LQR's gain
    margin. With the linear law outside the box (gain 3, no effort limits, so that the inside law
    decides) the scaled law brings the most states to x*, and the gate picks it. The gain is constant
    here (ramp (0, 0)): a ramped one is 1 at x*, where this law is unstable by design."""
    monkeypatch.setattr(gate_module, "INSIDE_RAMP", (0.0, 0.0))
    system = dataclasses.replace(ip.load_system("pendubot"), effort=np.full(1, np.inf))
    A, B = system.linearization()
    K = LQRController(system).K
    assert np.linalg.eigvals(A - 0.25 * B @ K).real.max() > 1.0 > 0 > np.linalg.eigvals(A - 0.75 * B @ K).real.max()
    fb = box_fallback(system, _tiny(fallback_gain=3.0))
    law = _Law(system, _weak(system, 0.25))
    law.lqr = _weak(system, 0.25)  # weak inside the box as well
    gate = fallback_gate(system, law, fb, seed=0)
    assert gate["scaled"] > gate["with_fallback"] > gate["networks"]
    assert gate["used"] and gate["inside_gain"] == fb.gain == 3.0 and gate["inside_ramp"] == [0.0, 0.0]
    _assert_discordant_pairs_explain_the_rates(gate)


def test_without_effort_limits_the_gate_does_not_try_a_scaled_law():
    free = dataclasses.replace(ip.load_system("pendubot"), effort=np.full(1, np.inf))
    fb = box_fallback(free, _tiny())
    assert fb.gain == 1.0
    gate = fallback_gate(free, _Law(free, LQRController(free)), fb, seed=0)  # the suite's short gate
    assert gate["scaled"] is None and gate["inside_gain"] == 1.0


def test_an_inside_gain_scales_the_learned_law_about_u_star_inside_the_box_only(pendubot_run):
    run = pendubot_run
    plain = run.controller
    scaled = plain.with_fallback(plain.fallback.with_inside_gain(3.0))
    x = _wide_states(run.system)
    inside = ~plain.fallback.outside(x)
    assert 0 < inside.sum() < len(x)
    u_nets, u_plain, u_scaled = plain.with_fallback(None)(x), plain(x), scaled(x)
    u_star = plain.fallback.u_star
    np.testing.assert_allclose(u_scaled[inside], u_star + 3.0 * (u_nets[inside] - u_star), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(u_scaled[~inside], u_plain[~inside])  # outside: the same linear law
    with pytest.raises(ValueError, match="gain margin"):
        plain.fallback.with_inside_gain(0.4)


def test_with_an_inside_gain_k_the_loop_at_the_target_is_the_anchors_with_k_times_its_gain(pendubot_run):
    """The anchored networks close the anchor's LQR loop A − BK at x*; scaled by k they close
    A − kBK, which LQR's gain margin keeps stable for every k ≥ ½."""
    run = pendubot_run
    fb = run.controller.fallback
    A, Bx = run.system.linearization()
    for k in (0.5, 3.0, 10.0):
        eig = np.sort_complex(run.controller.with_fallback(fb.with_inside_gain(k)).eigenvalues_at_target())
        np.testing.assert_allclose(eig, np.sort_complex(np.linalg.eigvals(A - k * Bx @ fb.anchor_K)), rtol=1e-6, atol=1e-8)
        assert eig.real.max() < 0


def test_a_ramped_inside_gain_is_1_near_the_target_k_far_from_it_and_linear_in_between(pendubot_run):
    """k(x) = 1 + (k_in − 1)·clip((r − r₀)/(r₁ − r₀), 0, 1), r = max_i |δ_i| / s_i: the learned law as
    trained within r₀ of x*, scaled by k_in beyond r₁, interpolated in between; outside the box the
    linear law as before."""
    run = pendubot_run
    plain = run.controller
    fb = plain.fallback.with_inside_gain(3.0, (0.2, 0.5))
    ramped = plain.with_fallback(fb)
    rng = np.random.default_rng(3)  # states at every scale up to 1.5 times the box around x*
    x = fb.x_star + rng.uniform(0.0, 1.5, (600, 1)) * rng.uniform(-1.0, 1.0, (600, run.system.n)) * fb.half
    r = (np.abs(fb.delta(x)) / fb.half).max(axis=1)
    near, far, mid = r <= 0.2, (r >= 0.5) & (r <= 1.0), (r > 0.2) & (r < 0.5)
    assert near.sum() > 0 and far.sum() > 0 and mid.sum() > 0
    u_nets, u_ramped, u_star = plain.with_fallback(None)(x), ramped(x), fb.u_star
    np.testing.assert_allclose(u_ramped[near], u_nets[near], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(u_ramped[far], u_star + 3.0 * (u_nets[far] - u_star), rtol=1e-12, atol=1e-12)
    k_mid = 1.0 + 2.0 * (r[mid] - 0.2) / 0.3
    np.testing.assert_allclose(u_ramped[mid], u_star + k_mid[:, None] * (u_nets[mid] - u_star), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(u_ramped[r > 1.0], plain(x)[r > 1.0])  # outside: the same linear law
    with pytest.raises(ValueError, match="inside_ramp"):
        plain.fallback.with_inside_gain(3.0, (0.5, 0.2))


def test_with_a_ramped_inside_gain_the_loop_at_the_target_is_the_anchors_own(pendubot_run):
    """The ramp leaves k = 1 around x*, so the linearisation there is A − BK (the anchor's LQR loop),
    not the slower A − 3BK of a constant gain."""
    run = pendubot_run
    fb = run.controller.fallback
    A, Bx = run.system.linearization()
    for ramp in ((0.2, 0.5), (0.0, 0.5)):
        eig = np.sort_complex(run.controller.with_fallback(fb.with_inside_gain(3.0, ramp)).eigenvalues_at_target())
        np.testing.assert_allclose(eig, np.sort_complex(np.linalg.eigvals(A - Bx @ fb.anchor_K)), rtol=1e-6, atol=1e-8)


def test_the_gate_simulates_a_stiff_loop_with_a_step_rk4_can_take():
    """The gate judges as every evaluation does (the judge's 2 ms step and control period); a plant
    with a 153 1/s damping pole (example-robot-data's double_pendulum_simple) still gets
    |λ|·dt ≤ 0.5, not garbage from RK4 blow-ups, and a step that divides the horizon."""
    pendubot = ip.load_system("pendubot")
    assert gate_step(pendubot, box_fallback(pendubot, _tiny())) == GATE_STEP == DEFAULT_STEP
    stiff = ip.load_system("erd:double_pendulum_simple", actuated=["joint2"])
    fb = box_fallback(stiff, _tiny())
    A, B = stiff.linearization()
    fastest = np.abs(np.linalg.eigvals(A - B @ fb.K)).max()
    step = gate_step(stiff, fb)
    assert fastest > 100.0 and step * fastest <= gate_module.GATE_POLE_STEP
    assert gate_step(stiff, fb) == step_for_pole(fastest, gate_module.GATE_HORIZON, DEFAULT_STEP, POLE_STEP)
    steps = gate_module.GATE_HORIZON / step  # whole steps: `simulate` refuses any other grid
    assert abs(steps - round(steps)) < 1e-9
    traj = ip.simulate(stiff, LQRController(stiff), stiff.x_star[None], T=gate_module.GATE_HORIZON, dt=step)
    assert traj.x.shape[1] == round(steps) + 1


def test_a_run_records_the_gate_and_load_run_applies_its_decision(tmp_path):
    system = ip.load_system("pendubot")
    run = ip.train(system, _tiny(), out=tmp_path, progress=False)
    record = json.loads((run.path / "summary.json").read_text())["fallback"]
    assert set(record) >= {"states", "networks", "with_fallback", "left_box", "only_networks", "only_fallback", "used"}
    loaded = ip.load_run(run.path)
    assert (loaded.controller.fallback is not None) == record["used"] == loaded.uses_fallback
    for forced, expected in (("linear", True), ("none", False)):
        other = dataclasses.replace(loaded, config=loaded.config.replace(fallback=forced))
        assert (other.controller.fallback is not None) is expected


def test_ctrl_c_during_the_gate_keeps_a_finished_run_and_resume_runs_the_gate_again(tmp_path, monkeypatch, capsys):
    """The gate runs after the last epoch and takes 30 s or more: interrupting it must not lose the
    trained run. The run is written as finished with the learned law everywhere, says so, and
    `train --resume` runs the check it skipped."""
    system = ip.load_system("pendubot")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(gate_module, "fallback_gate", interrupted)
        run = ip.train(system, _tiny(), out=tmp_path, progress=True)
    printed = capsys.readouterr().out
    assert "Ctrl-C skips the check" in printed and f"idapbc-pin train --resume {run.path}" in printed
    summary = json.loads((run.path / "summary.json").read_text())
    assert summary["status"] == "finished" and summary["fallback"]["interrupted"] is True
    loaded = ip.load_run(run.path)
    assert not loaded.uses_fallback and loaded.controller.fallback is None
    assert "unchecked (the check was interrupted" in format_train_summary(loaded)

    resumed = ip.train(system, resume=run.path, progress=False)
    record = json.loads((resumed.path / "summary.json").read_text())["fallback"]
    assert "interrupted" not in record and set(record) >= {"networks", "with_fallback", "used"}


def test_runs_written_before_the_option_load_without_a_fallback(pendubot_run, tmp_path):
    import shutil

    old = tmp_path / "old"
    shutil.copytree(pendubot_run.path, old)
    config = json.loads((old / "config.json").read_text())
    del config["fallback"]
    (old / "config.json").write_text(json.dumps(config))
    assert ip.load_run(old).controller.fallback is None
    del config["fallback_gain"]  # a run from before the gain factor: the anchor's own gain outside the box
    config["fallback"] = "linear"
    (old / "config.json").write_text(json.dumps(config))
    fb = ip.load_run(old).controller.fallback
    assert fb.gain == 1.0
    np.testing.assert_allclose(fb.K, pendubot_run.controller.fallback.anchor_K, rtol=1e-15)


def test_a_bad_fallback_value_is_refused_with_the_fix():
    with pytest.raises(ip.IdapbcError, match="fallback must be 'auto', 'linear' or 'none'.*Fix"):
        ip.TrainConfig(fallback="lqr")


def test_the_cli_trains_with_the_fallback_named_and_prints_the_law_outside_the_box(tmp_path, capsys):
    from idapbc_pin.cli.main import main

    config = tmp_path / "linear.toml"
    config.write_text('[train]\nwidth = 8\ndepth = 1\nfallback = "linear"\n')  # expert keys live in the config file
    main(["train", "pendubot", "--fast", "--epochs", "3", "--config", str(config),
          "--evaluate", "0", "--recover", "never", "--out", str(tmp_path)])  # fmt: skip
    printed = capsys.readouterr().out
    assert "outside the training box: the anchor's linear law u* − 3·Kδ" in printed
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert json.loads((run_dir / "config.json").read_text())["fallback"] == "linear"
    assert ip.load_run(run_dir).controller.fallback is not None


def test_train_prints_how_many_states_only_one_law_brings_home(tmp_path, capsys):
    """The gate's verdict comes with its evidence: the states where the two laws disagree."""
    from idapbc_pin.cli.main import main

    config = tmp_path / "tiny.toml"
    config.write_text("[train]\nwidth = 8\ndepth = 1\n")
    main(["train", "pendubot", "--fast", "--epochs", "3", "--config", str(config), "--evaluate", "0",
          "--recover", "never", "--out", str(tmp_path)])  # fmt: skip
    printed = capsys.readouterr().out
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    gate = json.loads((run_dir / "summary.json").read_text())["fallback"]
    assert f"{gate['only_fallback']} states reach x* only with it, {gate['only_networks']} only without" in printed


def _gated_copy(run, tmp_path, fallback: dict):
    """A copy of `run` with ``fallback = "auto"`` in config.json and `fallback` as its gate's entry in
    summary.json (what the gate after training writes)."""
    import shutil

    path = tmp_path / "run"
    shutil.copytree(run.path, path, dirs_exist_ok=True)
    summary = json.loads((path / "summary.json").read_text())
    (path / "summary.json").write_text(json.dumps({**summary, "fallback": fallback}))
    config = json.loads((path / "config.json").read_text())
    (path / "config.json").write_text(json.dumps({**config, "fallback": "auto"}))
    return path


@pytest.mark.parametrize("entry", [{"inside_gain": bad} for bad in (0.1, "three", None, float("nan"))]
                         + [{"inside_gain": 3.0, "inside_ramp": bad} for bad in ([0.5, 0.2], [-0.1, 0.5], "0.2-0.5", [0.2], [0.2, float("inf")], [True, 0.5])])
def test_a_damaged_inside_gain_or_ramp_in_summary_json_is_refused_at_load_in_one_line(pendubot_run, tmp_path, entry):
    from idapbc_pin._io import DamagedFileError

    path = _gated_copy(pendubot_run, tmp_path, {"used": True, **entry})
    with pytest.raises(DamagedFileError, match=list(entry)[-1]) as err:
        ip.load_run(path)
    assert "\n" not in str(err.value) and "Fix:" in str(err.value)


def test_a_run_gated_before_the_ramp_loads_with_a_constant_inside_gain_and_a_new_one_with_its_ramp(pendubot_run, tmp_path):
    for entry, ramp in (({"used": True, "inside_gain": 3.0}, (0.0, 0.0)),
                        ({"used": True, "inside_gain": 3.0, "inside_ramp": [0.2, 0.5]}, (0.2, 0.5))):
        fb = ip.load_run(_gated_copy(pendubot_run, tmp_path, entry)).controller.fallback
        assert fb.inside_gain == 3.0 and fb.inside_ramp == ramp


def test_with_an_inside_gain_the_certificate_takes_h_d_along_the_scaled_law_and_proposition_1_along_the_ida_pbc_law(pendubot_run):
    from idapbc_pin.certificate.terms import closed_loop_terms

    run = pendubot_run
    ctrl = run.controller.with_fallback(run.controller.fallback.with_inside_gain(3.0))
    system = run.system
    lo, hi = system.domain
    x = lo + (hi - lo) * np.random.default_rng(4).random((200, system.n))  # inside the box: the scaled law acts
    terms = closed_loop_terms(ctrl, x)
    x_dot = system.f(x) + np.einsum("nim,nm->ni", system.g(x), ctrl(x))
    h = 1e-6
    fd = (ctrl.H_d(x + h * x_dot) - ctrl.H_d(x - h * x_dot)) / (2 * h)
    np.testing.assert_allclose(terms.H_dot, fd, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(terms.H_dot_law, -terms.margin, rtol=1e-9, atol=1e-9)
    assert not np.allclose(terms.H_dot, terms.H_dot_law)  # the two laws differ

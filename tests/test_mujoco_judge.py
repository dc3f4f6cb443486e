"""A controller judged in another engine: MuJoCo, loading the same URDF, gives the same verdicts.

The controllers keep their Pinocchio model; only the true plant that `simulate` integrates changes
(`idapbc_pin.mujoco_judge`). `tests/test_mujoco_reference.py` compares the two engines' M, U and
accelerations; here the judge itself is checked, through the Plant protocol and in closed loop.
"""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
import torch

import idapbc_pin as ip
from idapbc_pin.cli.main import main
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.model.zoo import zoo_names
from idapbc_pin.evaluation.roa import roa

pytest.importorskip("mujoco", reason="the MuJoCo judge needs `pip install mujoco` (the [dev] extra)")


@pytest.mark.parametrize("name", zoo_names())
def test_mujoco_accelerations_equal_pinocchio_on_random_states_with_torques(name):
    system = ip.load_system(name)
    judge = ip.mujoco_judge(system)
    rng = np.random.default_rng(3)
    q = rng.uniform(-np.pi, np.pi, (40, system.nq))
    v = rng.uniform(-3.0, 3.0, (40, system.nq))
    tau = rng.uniform(-2.0, 2.0, (40, system.nq))
    a_pin = system.forward_dynamics(q, v, tau)
    a_mj = judge.forward_dynamics(q, v, tau, threads=2)  # threads accepted, ignored
    np.testing.assert_allclose(a_mj, a_pin, rtol=1e-9, atol=1e-9 * np.abs(a_pin).max())
    x = system.state_from(q, v)
    np.testing.assert_allclose(judge.state_from(q, v), x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(judge.split(x)[1], v, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(judge.hamiltonian(x), system.hamiltonian(x), rtol=1e-9, atol=1e-12)
    assert judge.plant.nq_config == system.nq  # a continuous joint is one MuJoCo hinge angle


def test_lqr_judged_by_mujoco_and_by_pinocchio_succeeds_from_the_same_states():
    system = ip.load_system("pendubot")
    ctrl = {"LQR": LQRController(system)}
    by_pin = roa(system, ctrl, n=40, box="half", T=5.0, seed=0)
    by_mj = roa(ip.mujoco_judge(system), ctrl, n=40, box="half", T=5.0, seed=0)
    np.testing.assert_array_equal(by_mj.x0, by_pin.x0)
    same = by_mj["LQR"].success == by_pin["LQR"].success
    assert 0 < by_pin["LQR"].success_rate < 1  # both verdicts occur: the comparison means something
    assert same.mean() >= 0.95


@pytest.mark.parametrize("name", ["acrobot", "cartpole"])
def test_the_judge_steps_like_mujoco_running_a_500_hz_controller(name):
    """MuJoCo stepping the URDF itself (mj_step, its RK4 integrator at 2 ms), with the saturated LQR
    torque computed once per step and applied as a generalised force, follows the same trajectory
    as the judge's default (the law sampled and held every 2 ms): the judge is a robot's control loop."""
    mujoco = pytest.importorskip("mujoco")
    from idapbc_pin.sim._mujoco import joint_addresses, mujoco_model
    from idapbc_pin.sim.states import uniform_states

    system = ip.load_system(name)
    lqr = LQRController(system)
    x0 = uniform_states(system, 4, "half", 11)
    traj = ip.simulate(system, lqr, x0, T=1.0)
    assert np.isclose(traj.t[1], 0.002)
    model = mujoco_model(system.plant.path)
    model.opt.timestep, model.opt.integrator = 0.002, mujoco.mjtIntegrator.mjINT_RK4
    qadr, dadr = joint_addresses(model, [j.name for j in system.plant.joints])
    q0, v0 = system.split(x0)
    for k in range(len(x0)):
        data = mujoco.MjData(model)
        data.qpos[qadr], data.qvel[dadr] = q0[k], v0[k]
        for i in range(len(traj.t) - 1):
            x = system.state_from(data.qpos[qadr][None], data.qvel[dadr][None])
            u = np.clip(lqr(x), -system.effort, system.effort)
            np.testing.assert_allclose(u[0], traj.u[k, i], atol=1e-6 * (1.0 + np.abs(u).max()))
            data.qfrc_applied[dadr] = (u @ system.B.T)[0]
            mujoco.mj_step(model, data)
        np.testing.assert_allclose(data.qpos[qadr], traj.q[k, -1], atol=1e-6)
        np.testing.assert_allclose(data.qvel[dadr], traj.v[k, -1], atol=1e-5)
    assert np.abs(traj.q[:, -1] - traj.q[:, 0]).max() > 0.1  # the robot moved: the comparison means something


def test_analytic_systems_and_scaled_plants_get_one_line_errors():
    with pytest.raises(ip.IdapbcError, match="needs a URDF robot.*Fix:") as err:
        ip.mujoco_judge(ip.load_system("paper_cartpole"))
    assert "\n" not in str(err.value)
    judge = ip.mujoco_judge(ip.load_system("pendubot"))
    with pytest.raises(ip.IdapbcError, match="not supported by the MuJoCo judge"):
        ip.perturbed_system(judge, mass=1.2)
    with pytest.raises(ip.IdapbcError, match="differs from the system's plant"):
        ip.mujoco_judge(ip.perturbed_system(ip.load_system("pendubot"), mass=1.2))


def test_without_mujoco_the_error_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # `import mujoco` now raises ImportError
    with pytest.raises(ip.IdapbcError, match=r"pip install mujoco"):
        ip.mujoco_judge(ip.load_system("pendubot"))


@pytest.fixture(scope="module")
def pendubot_run(tmp_path_factory):
    torch.set_num_threads(1)
    config = ip.TrainConfig(epochs=5, width=16, depth=2, samples=64)
    return ip.train(ip.load_system("pendubot"), config, out=tmp_path_factory.mktemp("runs"), progress=False)


def test_cli_simulate_with_the_mujoco_judge_gives_pinocchio_verdicts(pendubot_run, capsys):
    run = str(pendubot_run.path)
    common = ["simulate", run, "--n", "4", "--box", "half", "--T", "1", "--no-radius"]
    assert main(common) == 0
    by_pin = json.loads((pendubot_run.path / "simulation.json").read_text())
    assert main(common + ["--judge", "mujoco"]) == 0
    assert "judge: mujoco" in capsys.readouterr().out
    by_mj = json.loads((pendubot_run.path / "simulation.json").read_text())
    assert (by_pin["judge"], by_mj["judge"]) == ("pinocchio", "mujoco")
    for name in ("NIDA-PBC", "LQR"):
        assert by_mj[name]["success"] == by_pin[name]["success"]
        settle = [np.array(r[name]["settling_time"], dtype=float) for r in (by_mj, by_pin)]  # null: never settled
        np.testing.assert_allclose(*settle, rtol=1e-6)
        assert by_mj[name]["median_peak_input"] == pytest.approx(by_pin[name]["median_peak_input"], rel=1e-6)


def test_cli_swing_up_from_hanging_with_the_mujoco_judge_is_judged_there_and_gives_pinocchio_verdicts(pendubot_run, capsys):
    run = str(pendubot_run.path)
    common = ["simulate", run, "--from", "hanging", "--n", "3", "--T", "2"]
    assert main(common) == 0
    by_pin = json.loads((pendubot_run.path / "swingup.json").read_text())
    assert main(common + ["--judge", "mujoco"]) == 0
    assert "judged by mujoco" in capsys.readouterr().out
    by_mj = json.loads((pendubot_run.path / "swingup.json").read_text())
    assert (by_pin["judge"], by_mj["judge"]) == ("pinocchio", "mujoco")
    for name in ("NIDA-PBC", "LQR", "energy pump + LQR"):
        assert by_mj["scores"][name]["holds"] == by_pin["scores"][name]["holds"]
        assert by_mj["scores"][name]["energy"] == pytest.approx(by_pin["scores"][name]["energy"], rel=1e-5)
    assert by_mj["scores"]["NIDA-PBC"]["energy"] != by_pin["scores"]["NIDA-PBC"]["energy"]  # the same motion from another engine's rounding


def test_cli_mujoco_judge_refuses_a_mismatch_and_unknown_judges(pendubot_run, capsys):
    run = str(pendubot_run.path)
    assert main(["simulate", run, "--n", "2", "--T", "0.1", "--no-radius", "--judge", "mujoco", "--mismatch", "mass=1.2"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "not supported by the MuJoCo judge" in err and err.count("\n") == 1
    with pytest.raises(SystemExit) as exit_:
        main(["simulate", run, "--judge", "bullet"])
    assert exit_.value.code == 2


def _varied_rows(system):
    """Each family of the suite at its two extreme levels, and one nominal row: (models, damping, coulomb)."""
    from idapbc_pin.model.variations import plant_families, varied_model

    plant = system.plant
    models, damping, coulomb = [None], [np.array(plant.damping, float)], [np.zeros(plant.nv)]
    for fam in plant_families(plant):
        for value in (fam.levels[0], fam.levels[-1]):
            d, c, model = np.array(plant.damping, float), np.zeros(plant.nv), None
            if fam.inertial:
                model = varied_model(plant, fam.kind, fam.joint, value)
            elif fam.kind == "b":
                d[fam.joint] += value
            else:
                c[fam.joint] = value
            models.append(model), damping.append(d), coulomb.append(c)
    return models, np.array(damping), np.array(coulomb)


@pytest.mark.parametrize("name", ["realaigym_pendubot", "cart_double_pendulum", "furuta", "triple_pendulum"])
def test_the_suites_varied_plants_have_the_same_accelerations_in_mujoco(name):
    """Every family at its extremes (inertias off the physically consistent cone included, rotors,
    damping, Coulomb friction): MuJoCo's accelerations equal Pinocchio's, row by row."""
    from idapbc_pin.model.variations import RowPlants
    from idapbc_pin.sim.mujoco_plant import MujocoPlant
    from idapbc_pin.sim.mujoco_rows import MujocoRowPlants

    system = ip.load_system("urdf/realaigym_double_pendulum.urdf", actuated=["shoulder"]) if name == "realaigym_pendubot" else ip.load_system(name)
    models, damping, coulomb = _varied_rows(system)
    by_pin = RowPlants(system.plant, models, damping, coulomb)
    by_mj = MujocoRowPlants(MujocoPlant(system.plant), models, damping, coulomb)
    rng = np.random.default_rng(5)
    N, nv = len(models), system.nq
    q, v, tau = rng.uniform(-3, 3, (N, nv)), rng.uniform(-4, 4, (N, nv)), rng.uniform(-3, 3, (N, nv))
    a_pin = by_pin.accel(q, v, tau)
    np.testing.assert_allclose(by_mj.accel(q, v, tau), a_pin, rtol=1e-9, atol=1e-9 * np.abs(a_pin).max())
    assert not np.allclose(a_pin, a_pin[:1])  # the rows differ: each engine gave every row its own plant
    if name == "realaigym_pendubot":  # m·r × 1.25 on a near point mass: a negative principal inertia, still judged alike
        assert min(float(np.min(p[0].body_inertia)) for p in by_mj._pairs) < 0


def test_the_suite_judged_by_mujoco_gives_pinocchios_verdicts():
    from idapbc_pin.evaluation.robust_suite import SuiteConfig, judge_suite

    system = ip.load_system("pendubot")
    config = SuiteConfig(T=2.0, levels=3, repetitions=2, pushes=3)
    laws = {"LQR": LQRController(system)}
    by_pin = judge_suite(system, laws, config, start="box", seed=1)
    by_mj = judge_suite(system, laws, config, start="box", seed=1, judge="mujoco")
    ok_pin, ok_mj = by_pin.success["LQR"], by_mj.success["LQR"]
    assert 0 < ok_pin.mean() < 1  # both verdicts occur: the comparison means something
    assert by_mj.judge == "mujoco" and (ok_mj == ok_pin).mean() >= 0.95
    with pytest.raises(ip.IdapbcError, match="judge must be one of"):
        judge_suite(system, laws, config, judge="bullet")


def test_cli_robustness_with_the_mujoco_judge(pendubot_run, capsys):
    run = str(pendubot_run.path)
    common = ["robustness", run, "--levels", "2", "--repetitions", "1", "--pushes", "1", "--T", "0.2", "--workers", "1"]
    assert main(common + ["--judge", "mujoco"]) == 0
    assert "judged by mujoco" in capsys.readouterr().out
    assert json.loads((pendubot_run.path / "robustness-suite.json").read_text())["judge"] == "mujoco"
    assert main(["robustness", run, "--roa", "--judge", "mujoco"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Pinocchio only" in err and err.count("\n") == 1

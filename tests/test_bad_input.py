"""Bad input gets one line naming the problem and the fix: from the API as `IdapbcError`, from the
CLI as exit status 2 with no traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.errors import NotAnEquilibriumError

LINK = """  <link name="{name}">
    <inertial><origin xyz="0 0 {com}"/><mass value="{mass}"/>
      <inertia ixx="{I}" ixy="0" ixz="0" iyy="{I}" iyz="0" izz="{I}"/></inertial>
  </link>"""
JOINT = """  <joint name="{name}" type="{type}"><parent link="{parent}"/><child link="{child}"/>
    <origin xyz="0 0 {z}"/><axis xyz="0 1 0"/><limit lower="-4" upper="4" effort="10" velocity="10"/></joint>"""


def _pendulum(joint_type="revolute", mass2=0.5, inertia2=0.01, com2=0.25, mimic=False):
    j2 = JOINT.format(name="j2", type="revolute", parent="l1", child="l2", z=0.5)
    if mimic:  # j2 = 1·j1 + 0: Pinocchio would build an independent joint
        j2 = j2.replace("</joint>", '<mimic joint="j1" multiplier="1" offset="0"/></joint>')
    return "\n".join(
        [
            '<?xml version="1.0"?>',
            '<robot name="test_pendulum">',
            '  <link name="base"/>',
            LINK.format(name="l1", com=0.25, mass=1.0, I=0.02),
            LINK.format(name="l2", com=com2, mass=mass2, I=inertia2),
            JOINT.format(name="j1", type=joint_type, parent="base", child="l1", z=0.0),
            j2,
            "</robot>",
        ]
    )


@pytest.fixture
def write(tmp_path):
    def _write(text, name="robot.urdf"):
        path = tmp_path / name
        path.write_text(text)
        return str(path)

    return _write


def _cli(*args):
    """``idapbc-pin ARGS`` in a fresh Python; the cases of one kind go through the in-process `cli`
    fixture (tests/conftest.py), one of each kind through here."""
    return subprocess.run([sys.executable, "-m", "idapbc_pin.cli", *args], capture_output=True, text=True, timeout=120)


def test_good_pendulum_loads(write):
    system = ip.load_system(write(_pendulum()), actuated=["j1"])
    assert system.coordinate_names == ("j1", "j2") and system.m == 1


CASES = {
    "missing file": (lambda w: "no/such/robot.urdf", {"actuated": ["j1"]}, ["not found", "Fix"]),
    "malformed xml": (lambda w: w(_pendulum().replace("</robot>", "")), {"actuated": ["j1"]}, ["malformed URDF XML", "line"]),
    "floating base": (lambda w: w(_pendulum(joint_type="floating")), {"actuated": ["j1"]}, ["floating", "1-DoF"]),
    "planar joint": (lambda w: w(_pendulum(joint_type="planar")), {"actuated": ["j1"]}, ["planar", "Fix"]),
    "mimic joint": (lambda w: w(_pendulum(mimic=True)), {"actuated": ["j1"]}, ["joint 'j2'", "mimics joint 'j1'", "remove the <mimic> tag"]),
    "massless link": (lambda w: w(_pendulum(mass2=0.0, inertia2=0.0)), {"actuated": ["j1"]}, ["singular", "j2", "inertial"]),
    "negative mass": (lambda w: w(_pendulum(mass2=-1.0)), {"actuated": ["j1"]}, ["link 'l2' has mass -1 kg", "<inertial> of link 'l2'"]),
    "non-finite mass": (lambda w: w(_pendulum(mass2=float("nan"))), {"actuated": ["j1"]}, ["link 'l2' has mass nan kg"]),
    "negative inertia": (lambda w: w(_pendulum(inertia2=-0.01)), {"actuated": ["j1"]}, ["link 'l2' has an inertia that is not positive semi-definite"]),
    "unknown actuated joint": (lambda w: w(_pendulum()), {"actuated": ["elbow"]}, ["unknown actuated joint 'elbow'", "j1, j2"]),
    "no actuated joint": (lambda w: w(_pendulum()), {"actuated": []}, ["no actuated joint", "j1, j2"]),
    "not an equilibrium": (lambda w: w(_pendulum()), {"actuated": ["j1"], "target": {"j2": 0.4}}, ["not an assignable equilibrium", "j2="]),
    "unknown target joint": (lambda w: w(_pendulum()), {"actuated": ["j1"], "target": {"knee": 0.1}}, ["unknown target joint 'knee'"]),
    "empty domain": (lambda w: w(_pendulum()), {"actuated": ["j1"], "domain": {"j1": (0.5, -0.5)}}, ["empty or infinite domain on j1"]),
    "unknown name": (lambda w: "no_such_robot", {}, ["neither a URDF file nor a known name", "cartpole"]),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_raises_a_one_line_error(case, write):
    source, kwargs, fragments = CASES[case]
    with pytest.raises(ip.IdapbcError) as info:
        ip.load_system(source(write), **kwargs)
    message = str(info.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message
    assert "Fix" in message or "Valid" in message or "valid" in message


def test_moments_that_no_rigid_body_has_are_a_warning_that_names_the_link(write):
    """izz > ixx + iyy breaks the triangle inequality: the model still loads (M(q) may be regular)."""
    text = _pendulum().replace('iyy="0.01" iyz="0" izz="0.01"', 'iyy="0.01" iyz="0" izz="0.05"')
    with pytest.warns(UserWarning, match="link 'l2' .* break the triangle inequality"):
        ip.load_system(write(text), actuated=["j1"])


def test_non_equilibrium_target_reports_the_residual_torque(write):
    """Gravity torque on the unactuated elbow at j2 = 0.4 rad: m g l_c sin(0.4)."""
    with pytest.raises(NotAnEquilibriumError) as info:
        ip.load_system(write(_pendulum()), actuated=["j1"], target={"j2": 0.4})
    expected = 0.5 * 9.81 * 0.25 * np.sin(0.4)  # ṗ₂ = −∂U/∂q₂, U₂ = m₂ g l_c cos(q₁ + q₂) drawn upright
    assert info.value.residuals["j2"] == pytest.approx(expected, rel=1e-9)


def test_hanging_target_is_an_equilibrium(write):
    """Both links hanging (j1 = π) is an equilibrium for either actuation; a tilted first link is not."""
    for actuated in (["j1"], ["j2"]):
        system = ip.load_system(write(_pendulum()), actuated=actuated, target={"j1": np.pi})
        assert system.x_star[0] == pytest.approx(np.pi)
        assert system.domain[0][0] == pytest.approx(np.pi / 2) and system.domain[1][0] == pytest.approx(4.0)  # clipped to the limit
    with pytest.raises(NotAnEquilibriumError):
        ip.load_system(write(_pendulum()), actuated=["j2"], target={"j1": 1.0})


@pytest.mark.parametrize("case", ["missing file", "malformed xml", "floating base", "mimic joint", "massless link", "negative mass",
                                  "unknown actuated joint", "not an equilibrium"])
def test_cli_exits_2_with_one_line_and_no_traceback(case, write, cli):
    source, kwargs, fragments = CASES[case]
    args = ["inspect", source(write)]
    for joint in kwargs.get("actuated", []):
        args += ["--actuated", joint]
    for joint, value in kwargs.get("target", {}).items():
        args += ["--target", f"{joint}={value}"]
    result = (_cli if case == "malformed xml" else cli)(*args)  # one case in a fresh Python
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert result.stderr.startswith("error: ") and result.stderr.count("\n") == 1
    assert fragments[0] in result.stderr


def test_cli_rejects_malformed_target_syntax():
    result = _cli("inspect", "cartpole", "--target", "hinge")
    assert result.returncode == 2 and "JOINT=VALUE" in result.stderr and "Traceback" not in result.stderr


def test_cli_inspect_reports_dimensions_equilibrium_and_controllability(cli):
    result = cli("inspect", "acrobot")
    assert result.returncode == 0, result.stderr
    out = result.stdout
    for fragment in ["shoulder", "elbow", "underactuation degree: 1", "assignable equilibrium: yes", "controllability rank 4/4", "cond(M(q*))"]:
        assert fragment in out


def test_cli_inspect_lists_actuated_candidates_for_a_bare_urdf(write, cli):
    result = cli("inspect", write(_pendulum()))
    assert result.returncode == 0, result.stderr
    assert "--actuated j1" in result.stdout and "--actuated j2" in result.stdout


def test_a_negative_worker_count_is_refused_before_training(cli):
    result = cli("train", "pendubot", "--fast", "--workers", "-1")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.startswith("error: --workers must be ≥ 0") and result.stderr.count("\n") == 1
    with pytest.raises(ip.IdapbcError, match="workers must be an integer ≥ 0"):
        ip.train(ip.load_system("pendubot"), ip.TrainConfig.fast(), workers=-2)


def test_a_mimic_joint_is_refused_not_modelled_as_a_free_joint(write):
    """The shipped double pendulum with its elbow mimicking the shoulder: refused, naming both joints."""
    text = (Path(__file__).parent.parent / "urdf" / "double_pendulum.urdf").read_text()
    elbow_end = text.index("</joint>", text.index('<joint name="elbow"'))
    path = write(text[:elbow_end] + '<mimic joint="shoulder" multiplier="1" offset="0"/>\n  ' + text[elbow_end:], "mimic.urdf")
    with pytest.raises(ip.IdapbcError, match="joint 'elbow' in .* mimics joint 'shoulder'") as info:
        ip.load_system(path, actuated=["shoulder"])
    assert "\n" not in str(info.value) and "Fix: remove the <mimic> tag" in str(info.value)


def test_train_refuses_a_mimic_joint_in_one_line_before_training(write, tmp_path):
    result = _cli("train", write(_pendulum(mimic=True)), "--actuated", "j1", "--fast", "--out", str(tmp_path / "runs"))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.startswith("error: joint 'j2' in ") and result.stderr.count("\n") == 1
    assert "mimics joint 'j1'" in result.stderr and "Fix: remove the <mimic> tag" in result.stderr
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("seed", [-3, 1.5, True])
def test_train_config_refuses_a_seed_that_is_not_an_integer_at_least_0(seed):
    with pytest.raises(ip.IdapbcError, match="bad training config: seed must be an integer ≥ 0") as info:
        ip.TrainConfig(seed=seed)
    assert "\n" not in str(info.value) and "Fix" in str(info.value)
    assert ip.TrainConfig(seed=0).seed == 0 and ip.TrainConfig.fast(seed=np.int64(7)).seed == 7


@pytest.mark.parametrize("command", ["train pendubot --fast", "simulate RUN", "certify RUN", "report RUN", "robustness RUN", "view cartpole --html OUT"])
def test_a_negative_seed_is_refused_in_one_line_before_anything_runs(command, tmp_path, cli):
    """numpy's generators refuse a negative seed with a traceback: every --seed is checked first (RUN
    need not exist, nothing is written). `train` in a fresh Python, the other commands here."""
    args = command.replace("RUN", str(tmp_path / "no_run")).replace("OUT", str(tmp_path / "replay.html")).split()
    result = (_cli if args[0] == "train" else cli)(*args, "--seed", "-3", *(["--out", str(tmp_path / "runs")] if args[0] == "train" else []))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.startswith("error: ") and result.stderr.count("\n") == 1
    assert "seed must be" in result.stderr and "≥ 0" in result.stderr and "-3" in result.stderr and "Fix" in result.stderr
    assert list(tmp_path.iterdir()) == []

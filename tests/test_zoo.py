"""The zoo: every entry loads, is drawn upright at q = 0, and has a positive-definite M(q).

One parameterised test per entry (robot_descriptions / example-robot-data style). Raw Pinocchio
checks the files themselves; `idapbc_pin.load_system` checks the front door.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import idapbc_pin as ip
from idapbc_pin.model.zoo import ZOO, ZooEntry, zoo_dir, zoo_entry, zoo_names, zoo_urdf_path

# name -> (coordinates in model order, Pinocchio nq, coordinates that are pendulum angles).
# Pendulum angles are those along which U(q) has a strict maximum at q = 0 (upright); along the
# others (cart, Furuta arm, wheel) U is flat. Continuous joints count 2 in Pinocchio's nq.
EXPECTED = {
    "acrobot": (("shoulder", "elbow"), 2, {"shoulder", "elbow"}),
    "arm_passive_middle": (("j1", "j2", "j3"), 3, {"j1", "j2", "j3"}),
    "cart_double_pendulum": (("slider", "hinge1", "hinge2"), 3, {"hinge1", "hinge2"}),
    "cart_double_pendulum_short_rail": (("slider", "hinge1", "hinge2"), 3, {"hinge1", "hinge2"}),
    "cartpole": (("slider", "hinge"), 2, {"hinge"}),
    "double_pendulum": (("shoulder", "elbow"), 2, {"shoulder", "elbow"}),
    "furuta": (("arm", "pendulum"), 2, {"pendulum"}),
    "pendubot": (("shoulder", "elbow"), 2, {"shoulder", "elbow"}),
    "quad_pendulum": (("j1", "j2", "j3", "j4"), 4, {"j1", "j2", "j3", "j4"}),
    "reaction_wheel": (("pivot", "wheel"), 3, {"pivot"}),
    "triple_pendulum": (("shoulder", "elbow", "wrist"), 3, {"shoulder", "elbow", "wrist"}),
}

N_RANDOM = 50


def test_registry_is_sorted_and_complete():
    assert zoo_names() == sorted(EXPECTED)
    assert list(ZOO) == sorted(ZOO)
    for name, entry in ZOO.items():
        assert isinstance(entry, ZooEntry)
        assert entry.name == name
        assert entry.description


def test_unknown_name_lists_valid_names():
    with pytest.raises(ValueError) as excinfo:
        zoo_entry("nope")
    message = str(excinfo.value)
    assert "nope" in message
    for name in zoo_names():
        assert name in message


def test_zoo_dir_honours_environment_variable(monkeypatch, tmp_path):
    monkeypatch.delenv("IDAPBC_PIN_ZOO", raising=False)
    assert zoo_dir().is_dir()
    assert (zoo_dir() / "cartpole.urdf").is_file()
    monkeypatch.setenv("IDAPBC_PIN_ZOO", str(tmp_path))
    assert zoo_dir() == tmp_path.resolve()
    with pytest.raises(ValueError, match="IDAPBC_PIN_ZOO"):
        zoo_urdf_path("cartpole")  # the file is not in tmp_path


def test_same_urdf_three_ways():
    """Acrobot, pendubot and double_pendulum are one URDF with different actuated joints."""
    entries = [zoo_entry(n) for n in ("acrobot", "pendubot", "double_pendulum")]
    assert {e.urdf for e in entries} == {"double_pendulum.urdf"}
    assert [set(e.actuated) for e in entries] == [{"elbow"}, {"shoulder"}, {"shoulder", "elbow"}]


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_urdf_file(name):
    """The file exists, Pinocchio parses model and visuals, and q = 0 is an equilibrium."""
    names, pin_nq, _ = EXPECTED[name]
    entry = zoo_entry(name)
    path = zoo_urdf_path(name)
    assert path.is_file()
    model = pin.buildModelFromUrdf(str(path))
    assert (model.nq, model.nv) == (pin_nq, len(names))
    assert tuple(model.names[1:]) == names
    geom = pin.buildGeomFromUrdf(model, str(path), pin.GeometryType.VISUAL)
    assert geom.ngeoms >= model.nv
    # Every moving body has positive mass and a positive-definite rotational inertia.
    for inertia in model.inertias[1:]:
        assert inertia.mass > 0
        assert np.linalg.eigvalsh(inertia.inertia).min() > 0
    assert np.all(model.damping > 0)
    data = model.createData()
    assert np.array_equal(pin.computeGeneralizedGravity(model, data, pin.neutral(model)), np.zeros(model.nv))
    # The entry's joint names exist.
    assert set(entry.actuated) <= set(names)
    assert {j for j, _ in entry.target} <= set(names)
    assert {c.removeprefix("p_") for c, _, _ in entry.domain} <= set(names)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_system_upright_and_mass_matrix(name):
    names, _, pendulum = EXPECTED[name]
    entry = zoo_entry(name)
    system = ip.load_system(name)
    nq = len(names)
    assert system.nq == nq
    assert system.n == 2 * nq
    assert system.m == len(entry.actuated)
    assert tuple(system.coordinate_names) == names
    x_star = np.asarray(system.x_star)
    assert x_star.shape == (2 * nq,)
    assert np.array_equal(x_star, np.zeros(2 * nq))

    # Upright is an equilibrium: no acceleration at rest with zero input (so the gravity torque vanishes).
    q0 = np.zeros((1, nq))
    acc = system.forward_dynamics(q0, np.zeros((1, nq)), np.zeros((1, nq)))
    np.testing.assert_allclose(acc, 0.0, atol=1e-12)

    # Upright is a maximum of U along every pendulum angle and flat along the other coordinates.
    delta = 1e-2
    shifted = np.concatenate([delta * np.eye(nq), -delta * np.eye(nq)])
    dU = system.potential(shifted) - system.potential(q0)[0]
    for i, joint in enumerate(names):
        if joint in pendulum:
            assert dU[i] < -1e-6 and dU[nq + i] < -1e-6, joint
        else:
            assert abs(dU[i]) < 1e-12 and abs(dU[nq + i]) < 1e-12, joint

    # M(q) symmetric positive definite on random configurations.
    rng = np.random.default_rng(20240601)
    q = rng.uniform(-np.pi, np.pi, size=(N_RANDOM, nq))
    M = system.mass_matrix(q)
    assert M.shape == (N_RANDOM, nq, nq)
    assert M.dtype == np.float64
    np.testing.assert_allclose(M, np.swapaxes(M, 1, 2), rtol=0, atol=1e-14)
    assert np.linalg.eigvalsh(M).min() > 0


def test_unknown_system_name_is_a_value_error():
    with pytest.raises(ValueError):
        ip.load_system("nope")


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_default_momentum_box_lets_every_link_move(name):
    """The momentum half-width of each joint is M_ii(q*)·1 (its own inertia at 1 rad/s), raised where a
    light distal link would otherwise hold the whole chain still: a rigid turn of the chain at
    RIGID_SHARE rad/s stays inside. Only the four-link chain's tip is raised; every other robot's box
    is M_ii(q*) exactly."""
    from idapbc_pin.model.loading import RIGID_SHARE

    system = ip.load_system(name)
    nq = system.nq
    M = system.mass_matrix(np.asarray(system.x_star)[None, :nq])[0]
    lo, hi = (np.asarray(b)[nq:] for b in system.domain)
    rigid = RIGID_SHARE * np.abs(M).sum(axis=1)
    assert np.all(hi >= rigid) and np.all(-lo >= rigid)
    raised = np.diagonal(M) < rigid
    assert list(np.flatnonzero(raised)) == ([3] if name == "quad_pendulum" else [])
    np.testing.assert_array_equal(hi[~raised], np.diagonal(M)[~raised])

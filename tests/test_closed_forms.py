"""M(q), U(q) and the forward dynamics of the cart-pole and the two-link arm match textbook closed forms.

The physical constants are read from the zoo URDFs themselves (xml.etree), so the closed forms
cannot drift from the files. Both robots move in the x–z plane about +y: a positive angle tilts
a link from +z towards +x, so a link of COM distance l_c at absolute angle φ has its COM at
(l_c sin φ, l_c cos φ) and U = m g l_c cos φ (upright at φ = 0, gravity 9.81 m/s² along −z).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.model.zoo import zoo_urdf_path

G = 9.81
N_RANDOM = 100
TOL = dict(rtol=1e-12, atol=1e-12)


def _floats(text: str) -> np.ndarray:
    return np.array([float(t) for t in text.split()])


class Urdf:
    """Just enough of a URDF for planar closed forms (links' inertials, joints' origins and axes)."""

    def __init__(self, path: Path):
        self.root = ET.parse(path).getroot()

    def _link(self, name: str) -> ET.Element:
        (link,) = [e for e in self.root.iter("link") if e.get("name") == name]
        return link

    def _joint(self, name: str) -> ET.Element:
        (joint,) = [e for e in self.root.iter("joint") if e.get("name") == name]
        return joint

    def mass(self, link: str) -> float:
        return float(self._link(link).find("inertial/mass").get("value"))

    def com(self, link: str) -> np.ndarray:
        """COM in the link frame (m); the inertial frame must not be rotated."""
        origin = self._link(link).find("inertial/origin")
        assert np.all(_floats(origin.get("rpy", "0 0 0")) == 0)
        return _floats(origin.get("xyz"))

    def iyy(self, link: str) -> float:
        """Moment of inertia about the COM, axis y (kg m²); the y axis must be principal."""
        inertia = self._link(link).find("inertial/inertia")
        assert float(inertia.get("ixy")) == 0 and float(inertia.get("iyz")) == 0
        return float(inertia.get("iyy"))

    def origin(self, joint: str) -> np.ndarray:
        origin = self._joint(joint).find("origin")
        assert np.all(_floats(origin.get("rpy", "0 0 0")) == 0)
        return _floats(origin.get("xyz"))

    def axis(self, joint: str) -> np.ndarray:
        return _floats(self._joint(joint).find("axis").get("xyz"))

    def damping(self, joint: str) -> float:
        return float(self._joint(joint).find("dynamics").get("damping"))


# ----------------------------------------------------------------------------------- cart-pole
@pytest.fixture(scope="module")
def cartpole():
    path = zoo_urdf_path("cartpole")
    urdf = Urdf(path)
    # Layout the closed form assumes: cart slides along x, pole hinged about y on the cart's z axis,
    # both COMs on the z axis of their frames.
    assert np.array_equal(urdf.axis("slider"), [1, 0, 0])
    assert np.array_equal(urdf.axis("hinge"), [0, 1, 0])
    assert np.array_equal(urdf.origin("hinge")[:2], [0, 0])
    assert np.array_equal(urdf.com("pole")[:2], [0, 0])
    assert np.array_equal(urdf.com("cart")[:2], [0, 0])
    params = dict(
        mc=urdf.mass("cart"),
        zc=urdf.com("cart")[2] + urdf.origin("slider")[2],  # cart COM height (m)
        mp=urdf.mass("pole"),
        h=urdf.origin("hinge")[2] + urdf.origin("slider")[2],  # pivot height (m)
        lc=urdf.com("pole")[2],  # pivot -> pole COM (m)
        I=urdf.iyy("pole"),  # pole inertia about its COM (kg m²)
        d=np.array([urdf.damping("slider"), urdf.damping("hinge")]),
    )
    return ip.load_system(str(path), actuated=["slider"]), params


def cartpole_M(q, mc, mp, lc, I, **_):
    c = np.cos(q[:, 1])
    M = np.empty((len(q), 2, 2))
    M[:, 0, 0] = mc + mp
    M[:, 0, 1] = M[:, 1, 0] = mp * lc * c
    M[:, 1, 1] = I + mp * lc**2
    return M


def cartpole_U(q, mc, zc, mp, h, lc, **_):
    return G * (mc * zc + mp * (h + lc * np.cos(q[:, 1])))


def cartpole_acc(q, v, tau, d, mp, lc, **params):
    """M a = τ − D v − C v − ∂U/∂q with C v = (−m_p l_c sin θ θ̇², 0), ∂U/∂θ = −m_p g l_c sin θ."""
    s = np.sin(q[:, 1])
    rhs = tau - d * v
    rhs[:, 0] += mp * lc * s * v[:, 1] ** 2
    rhs[:, 1] += mp * G * lc * s
    return np.linalg.solve(cartpole_M(q, mp=mp, lc=lc, **params), rhs[..., None])[..., 0]


def test_cartpole_coordinates(cartpole):
    system, _ = cartpole
    assert tuple(system.coordinate_names) == ("slider", "hinge")


def test_cartpole_mass_matrix_and_potential(cartpole):
    system, p = cartpole
    rng = np.random.default_rng(1)
    q = np.column_stack([rng.uniform(-2, 2, N_RANDOM), rng.uniform(-np.pi, np.pi, N_RANDOM)])
    np.testing.assert_allclose(system.mass_matrix(q), cartpole_M(q, **p), **TOL)
    np.testing.assert_allclose(system.potential(q), cartpole_U(q, **p), **TOL)


def test_cartpole_forward_dynamics(cartpole):
    system, p = cartpole
    rng = np.random.default_rng(2)
    q = np.column_stack([rng.uniform(-2, 2, N_RANDOM), rng.uniform(-np.pi, np.pi, N_RANDOM)])
    v = rng.uniform(-3, 3, (N_RANDOM, 2))
    tau = rng.uniform(-5, 5, (N_RANDOM, 2))
    expected = cartpole_acc(q, v, tau, **p)
    np.testing.assert_allclose(system.forward_dynamics(q, v, tau), expected, rtol=1e-10, atol=1e-10)


# ------------------------------------------------------------------------------- two-link arm
@pytest.fixture(scope="module")
def arm():
    path = zoo_urdf_path("double_pendulum")
    urdf = Urdf(path)
    for joint in ("shoulder", "elbow"):
        assert np.array_equal(urdf.axis(joint), [0, 1, 0])
    assert np.array_equal(urdf.origin("elbow")[:2], [0, 0])
    for link in ("link1", "link2"):
        assert np.array_equal(urdf.com(link)[:2], [0, 0])
    params = dict(
        m1=urdf.mass("link1"),
        m2=urdf.mass("link2"),
        l1=urdf.origin("elbow")[2],  # shoulder -> elbow (m)
        lc1=urdf.com("link1")[2],
        lc2=urdf.com("link2")[2],
        I1=urdf.iyy("link1"),
        I2=urdf.iyy("link2"),
        z0=urdf.origin("shoulder")[2],  # shoulder height (m)
        d=np.array([urdf.damping("shoulder"), urdf.damping("elbow")]),
    )
    return ip.load_system(str(path), actuated=["elbow"]), params


def arm_M(q, m2, l1, lc1, lc2, I1, I2, m1, **_):
    c2 = np.cos(q[:, 1])
    M = np.empty((len(q), 2, 2))
    M[:, 0, 0] = I1 + I2 + m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * c2)
    M[:, 0, 1] = M[:, 1, 0] = I2 + m2 * (lc2**2 + l1 * lc2 * c2)
    M[:, 1, 1] = I2 + m2 * lc2**2
    return M


def arm_U(q, m1, m2, l1, lc1, lc2, z0, **_):
    q1, q12 = q[:, 0], q[:, 0] + q[:, 1]
    return G * (m1 * (z0 + lc1 * np.cos(q1)) + m2 * (z0 + l1 * np.cos(q1) + lc2 * np.cos(q12)))


def arm_acc(q, v, tau, d, m1, m2, l1, lc1, lc2, **params):
    """M a = τ − D v − c − ∂U/∂q (Spong's two-link arm, relative elbow angle, upright at 0)."""
    h = m2 * l1 * lc2 * np.sin(q[:, 1])
    s1, s12 = np.sin(q[:, 0]), np.sin(q[:, 0] + q[:, 1])
    coriolis = np.column_stack([-h * (2 * v[:, 0] * v[:, 1] + v[:, 1] ** 2), h * v[:, 0] ** 2])
    grad_U = -G * np.column_stack([(m1 * lc1 + m2 * l1) * s1 + m2 * lc2 * s12, m2 * lc2 * s12])
    rhs = tau - d * v - coriolis - grad_U
    M = arm_M(q, m1=m1, m2=m2, l1=l1, lc1=lc1, lc2=lc2, **params)
    return np.linalg.solve(M, rhs[..., None])[..., 0]


def test_arm_coordinates(arm):
    system, _ = arm
    assert tuple(system.coordinate_names) == ("shoulder", "elbow")


def test_arm_mass_matrix_and_potential(arm):
    system, p = arm
    rng = np.random.default_rng(3)
    q = rng.uniform(-np.pi, np.pi, (N_RANDOM, 2))
    np.testing.assert_allclose(system.mass_matrix(q), arm_M(q, **p), **TOL)
    np.testing.assert_allclose(system.potential(q), arm_U(q, **p), **TOL)


def test_arm_forward_dynamics(arm):
    system, p = arm
    rng = np.random.default_rng(4)
    q = rng.uniform(-np.pi, np.pi, (N_RANDOM, 2))
    v = rng.uniform(-3, 3, (N_RANDOM, 2))
    tau = rng.uniform(-5, 5, (N_RANDOM, 2))
    expected = arm_acc(q, v, tau, **p)
    np.testing.assert_allclose(system.forward_dynamics(q, v, tau), expected, rtol=1e-10, atol=1e-10)


def test_state_round_trip(arm):
    """x = (q, p = M v) and back."""
    system, p = arm
    rng = np.random.default_rng(5)
    q = rng.uniform(-np.pi, np.pi, (N_RANDOM, 2))
    v = rng.uniform(-3, 3, (N_RANDOM, 2))
    x = system.state_from(q, v)
    assert x.shape == (N_RANDOM, 4)
    np.testing.assert_allclose(x[:, :2], q, rtol=0, atol=0)
    np.testing.assert_allclose(x[:, 2:], np.einsum("nij,nj->ni", arm_M(q, **p), v), **TOL)
    q_back, v_back = system.split(x)
    np.testing.assert_allclose(q_back, q, rtol=0, atol=0)
    np.testing.assert_allclose(v_back, v, rtol=1e-12, atol=1e-12)

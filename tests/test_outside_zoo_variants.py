"""The robots outside the zoo that `benchmarks/bench_outside_zoo.py` judges are the zoo URDFs with
exactly the changes they claim: scaling every link's mass and inertia by k scales M(q) and U(q) by k;
a continuous joint keeps the dynamics of its revolute original; a missing link is refused."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

import idapbc_pin as ip

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_outside_zoo.py"
_spec = importlib.util.spec_from_file_location("bench_outside_zoo", _PATH)
bench = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = bench  # dataclasses look their module up there
_spec.loader.exec_module(bench)


def _states(system, k=16, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-np.pi, np.pi, (k, system.nq))


def test_scaling_every_link_by_k_scales_the_mass_matrix_and_the_potential_by_k(tmp_path):
    variant = bench.Variant("both_links_x1.5", "double_pendulum.urdf", ("shoulder",), {"link1": 1.5, "link2": 1.5})
    scaled = ip.load_system(bench.write_variant(variant, tmp_path), actuated=["shoulder"])
    nominal = ip.load_system(bench.URDF_DIR / "double_pendulum.urdf", actuated=["shoulder"])
    q = _states(nominal)
    np.testing.assert_allclose(scaled.mass_matrix(q), 1.5 * nominal.mass_matrix(q), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(scaled.potential(q) - scaled.potential(0 * q), 1.5 * (nominal.potential(q) - nominal.potential(0 * q)), rtol=1e-12, atol=1e-12)


def test_scaling_the_elbow_link_scales_exactly_the_entry_only_it_moves(tmp_path):
    variant = next(v for v in bench.VARIANTS if v.name == "acrobot_light_elbow")  # link2 × 0.7
    scaled = ip.load_system(bench.write_variant(variant, tmp_path), actuated=["elbow"])
    nominal = ip.load_system(bench.URDF_DIR / "double_pendulum.urdf", actuated=["elbow"])
    q = _states(nominal)
    M, M0 = scaled.mass_matrix(q), nominal.mass_matrix(q)
    np.testing.assert_allclose(M[:, 1, 1], 0.7 * M0[:, 1, 1], rtol=1e-12)  # link 2's inertia about the elbow
    np.testing.assert_allclose(M[:, 0, 1], 0.7 * M0[:, 0, 1], rtol=1e-12)  # the coupling is link 2's alone too
    assert np.all(M[:, 0, 0] > 0.7 * M0[:, 0, 0]) and np.all(M[:, 0, 0] < M0[:, 0, 0])  # link 1 is unchanged


def test_continuous_joints_keep_the_dynamics_and_the_damping_is_set(tmp_path):
    variant = next(v for v in bench.VARIANTS if v.name == "acrobot_continuous_damped")
    changed = ip.load_system(bench.write_variant(variant, tmp_path), actuated=["elbow"])
    nominal = ip.load_system(bench.URDF_DIR / "double_pendulum.urdf", actuated=["elbow"])
    assert changed.n == nominal.n == 4  # one angle per continuous joint, as for the revolute ones
    q = _states(nominal)
    np.testing.assert_allclose(changed.mass_matrix(q), nominal.mass_matrix(q), rtol=1e-12, atol=1e-14)
    x = nominal.state_from(q, np.zeros_like(q) + 1.0)
    d_f = changed.f(x) - nominal.f(x)  # only the elbow's damping differs: −(0.1 − 0.02)·v_elbow on its momentum
    np.testing.assert_allclose(d_f[:, :3], 0.0, atol=1e-10)
    np.testing.assert_allclose(d_f[:, 3], -(0.1 - 0.02) * 1.0, rtol=1e-9)


def test_a_variant_naming_a_missing_link_is_refused(tmp_path):
    with pytest.raises(ValueError, match="no link or joint 'forearm'"):
        bench.write_variant(bench.Variant("bad", "double_pendulum.urdf", ("elbow",), {"forearm": 2.0}), tmp_path)


def test_an_effort_variant_writes_its_limit_and_keeps_the_dynamics(tmp_path):
    variant = next(v for v in bench.VARIANTS if v.name == "pendubot_8nm")
    weak = ip.load_system(bench.write_variant(variant, tmp_path), actuated=["shoulder"])
    nominal = ip.load_system(bench.URDF_DIR / "double_pendulum.urdf", actuated=["shoulder"])
    assert weak.effort.tolist() == [8.0] and nominal.effort.tolist() == [20.0]
    q = _states(nominal)
    np.testing.assert_array_equal(weak.mass_matrix(q), nominal.mass_matrix(q))

"""The certified set in a verification box: its box, its samples, its core, its counter-example
search and the zero-failure bound, each held against a case with a known answer."""

from __future__ import annotations

import math

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.certificate.region import TrueLoop, certified_region, counterexamples, covered_share, linear_core
from idapbc_pin.certificate.vbox import sample_set, set_frame, verification_box, zero_failure_samples


class Quadratic:
    """V = δᵀSδ (the ``H_d`` / ``grad_H_d`` / ``hess_H_d`` interface)."""

    def __init__(self, S):
        self.S = np.asarray(S, float)

    def H_d(self, x):
        x = np.atleast_2d(x)
        return np.einsum("ni,ij,nj->n", x, self.S, x)

    def grad_H_d(self, x):
        return 2 * np.atleast_2d(x) @ self.S

    def hess_H_d(self, x):
        return np.broadcast_to(2 * self.S, (np.atleast_2d(x).shape[0], 2, 2)).copy()


class Field:
    """ẋ = −x + k·exp(−‖x − x₀‖²/(2σ²))·x: contracting except in a small ball about x₀ where, for
    k > 1, it pushes outwards (V = ‖x‖² grows where k·exp(…) > 1). Duck-types the `TrueLoop` call."""

    def __init__(self, k=3.0, x0=(0.6, 0.0), sigma=0.04):
        self.k, self.x0, self.sigma = k, np.asarray(x0), sigma

    def bump(self, x):
        return self.k * np.exp(-((np.atleast_2d(x) - self.x0) ** 2).sum(axis=1) / (2 * self.sigma**2))

    def __call__(self, x):
        x = np.atleast_2d(x)
        return -x + self.bump(x)[:, None] * x

    def jacobian_at(self, x_star, h=1e-6):
        return -np.eye(2)


def test_the_zero_failure_bound_is_the_smallest_n_with_exp_minus_eps_n_below_beta():
    n = zero_failure_samples(1e-3, 1e-6)
    assert n == 13816 and math.exp(-1e-3 * n) <= 1e-6 < math.exp(-1e-3 * (n - 1))
    assert (1 - 1e-3) ** n <= 1e-6  # the failure probability it bounds
    with pytest.raises(ip.IdapbcError, match="epsilon and beta"):
        zero_failure_samples(0.0, 1e-6)


def test_the_default_verification_box_is_four_training_boxes_with_angles_within_a_turn():
    system = ip.load_system("cartpole")  # slider (m) and pole (rad), then momenta
    lo, hi = (np.asarray(b) for b in system.domain)
    vlo, vhi = verification_box(system)
    angle = np.asarray(system.angle_mask)
    np.testing.assert_allclose(vlo[~angle], 4 * lo[~angle])  # x* = 0
    np.testing.assert_allclose(vhi[~angle], 4 * hi[~angle])
    np.testing.assert_allclose(vlo[angle], -np.pi) and np.testing.assert_allclose(vhi[angle], np.pi)
    assert np.all(vlo <= lo) and np.all(vhi >= hi)
    # a coordinate override by name, and refusals
    wide = verification_box(system, box={"slider": (-9.0, 9.0)})
    assert wide[0][0] == -9.0 and wide[1][0] == 9.0 and np.array_equal(wide[0][1:], vlo[1:])
    with pytest.raises(ip.IdapbcError, match="does not contain the training box"):
        verification_box(system, box={"slider": (-0.1, 0.1)})
    with pytest.raises(ip.IdapbcError, match="unknown coordinate 'elbow'"):
        verification_box(system, box={"elbow": (-1.0, 1.0)})
    with pytest.raises(ip.IdapbcError, match="scale must be ≥ 1"):
        verification_box(system, 0.5)


def test_samples_of_an_elongated_ellipse_are_uniform_on_it_and_its_area_is_right():
    S = np.array([[50.0, 20.0], [20.0, 9.0]])  # condition number ≈ 700: thin and tilted
    fn, c = Quadratic(S), 1.0
    rng = np.random.default_rng(0)
    frame = set_frame(fn, c, np.zeros(2), np.array([-10.0, -10.0]), np.array([10.0, 10.0]), rng)
    x, draws = sample_set(fn, c, frame, 20000, rng)
    assert x.shape[0] >= 20000 and np.all(fn.H_d(x) < c)
    area = math.pi * c / math.sqrt(np.linalg.det(S))
    assert frame.volume * x.shape[0] / draws == pytest.approx(area, rel=0.02)
    # whitened, the ellipse is a disc in a square padded by 20 %: π/4 / 1.4² ≈ 40 % of the draws hit
    assert x.shape[0] / draws == pytest.approx(math.pi / 4 / 1.4**2, abs=0.02)
    # uniform: the share inside the concentric ellipse of half the level is ½ (area ∝ level in 2-D)
    assert np.mean(fn.H_d(x) < c / 2) == pytest.approx(0.5, abs=0.015)


def test_the_covered_share_is_exact_for_a_set_that_holds_the_box_and_right_for_a_small_one():
    fn, rng = Quadratic(np.eye(2)), np.random.default_rng(1)
    vlo, vhi = np.full(2, -10.0), np.full(2, 10.0)
    for c, tbox, share in ((3.0, (np.full(2, -1.0), np.full(2, 1.0)), 1.0),  # the disc r² < 3 holds the box
                           (1e-3, (np.full(2, -1.0), np.full(2, 1.0)), math.pi * 1e-3 / 4)):  # a disc of 0.08 % of it
        frame = set_frame(fn, c, np.zeros(2), vlo, vhi, rng)
        x, draws = sample_set(fn, c, frame, 15000, rng)
        got = covered_share(fn, c, frame, x, draws, tbox, rng)
        assert got == share if share == 1.0 else got == pytest.approx(share, rel=0.03)


def test_the_linearisation_core_of_a_linear_loop_is_the_largest_allowed_and_empty_when_unstable():
    fn = Quadratic(np.eye(2))
    stable = TrueLoop(_Linear(-np.eye(2)), lambda x: np.zeros((np.atleast_2d(x).shape[0], 1)))
    core, rate = linear_core(fn, stable, np.zeros(2), np.array([1.0, 1.0]), np.random.default_rng(0))
    assert rate == pytest.approx(2.0) and core == pytest.approx(0.9 * (0.05**2), rel=1e-9)  # within 5 % of the half-widths
    unstable = TrueLoop(_Linear(np.array([[0.0, 1.0], [1.0, 0.0]])), lambda x: np.zeros((np.atleast_2d(x).shape[0], 1)))
    core, rate = linear_core(fn, unstable, np.zeros(2), np.array([1.0, 1.0]), np.random.default_rng(0))
    assert core == 0.0 and rate <= 0


class _Linear:
    """ẋ = A x with a zero input column (a duck-typed system for `TrueLoop`)."""

    def __init__(self, A):
        self.A = np.asarray(A, float)

    def f(self, x):
        return np.atleast_2d(x) @ self.A.T

    def g(self, x):
        return np.zeros((np.atleast_2d(x).shape[0], 2, 1))


def test_the_counter_example_search_finds_a_small_bad_ball_that_the_samples_miss():
    fn, field_ = Quadratic(np.eye(2)), Field()
    lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    rng = np.random.default_rng(1)
    # start from points about 3σ off the ball, where V̇ < 0 still
    starts = field_.x0 + np.array([[0.0, 0.12], [0.12, 0.05], [-0.1, -0.08]])
    assert np.all(np.einsum("ni,ni->n", fn.grad_H_d(starts), field_(starts)) < 0)
    found, V = counterexamples(fn, field_, starts, 1.0, 0.0, np.zeros(2), lo, hi)
    assert V.size and np.all(field_.bump(found) >= 1.0 - 1e-9)  # every point returned does violate
    # the whole procedure: 200 search samples miss the ball (area ≈ 0.3 % of the disc), the search does not
    region = certified_region(fn, field_, np.zeros(2), (lo, hi), (lo, hi), rng, n_search=200, epsilon=1e-2, beta=1e-3)
    assert region.n_counterexamples > 0
    worst = (np.linalg.norm(field_.x0) - field_.sigma * math.sqrt(2 * math.log(field_.k))) ** 2  # V at the ball's inner edge
    assert region.c <= worst * 1.05 and region.confidence.passed

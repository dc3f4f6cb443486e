"""The governor's energy margin of a kept recovery law (`recovery.governor_margin.catch_margin`): it
stays `ENERGY_MARGIN` where the governor costs the law nothing in its own box, and where it costs
states it rises to the catches' peak energy, at which the governed law catches them again; a
controller carries its margin through every variant and into controller.json's "governor"."""

from __future__ import annotations

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.control.speed_governor import ENERGY_MARGIN, SpeedGovernor
from idapbc_pin.recovery.governor_margin import LOSS, catch_margin
from idapbc_pin.sim.integrate import simulate
from idapbc_pin.sim.metrics import success
from idapbc_pin.sim.states import uniform_states


class _Governed:
    """Saturated LQR behind a governor with a given margin (the `Controller` interface catch_margin reads)."""

    def __init__(self, system, margin: float | None):
        self.system, self.margin = system, margin
        self.lqr = LQRController(system)
        self.governor = None if margin is None else SpeedGovernor.of(system, margin)

    def with_governor(self, on: bool):
        return _Governed(self.system, self.margin if on else None)

    def __call__(self, x):
        u = self.system.saturate(self.lqr(x))
        return u if self.governor is None else self.governor.apply(x, u)


@pytest.fixture(scope="module")
def pendubot():
    return ip.load_system("pendubot")


@pytest.fixture(scope="module")
def arm():
    return ip.load_system("double_pendulum")  # both joints driven: saturated LQR catches its box


def test_the_margin_stays_where_the_governor_costs_nothing(arm):
    """Saturated LQR's catches from the two-motor arm's box lose nothing to the default governor."""
    assert catch_margin(arm, _Governed(arm, ENERGY_MARGIN), n=40, T=4.0) == ENERGY_MARGIN


def test_a_governor_that_costs_catches_gets_the_catches_peak_and_then_costs_none(arm):
    """A margin far below E* (−0.9 ΔE) brakes catches the law makes alone; the margin found is their
    peak excess, and behind a governor with it the law catches those states again."""
    strict = _Governed(arm, -0.9)
    x0 = uniform_states(arm, 40, "domain", 0)
    alone = success(simulate(arm, strict.with_governor(False), x0, T=4.0), arm)
    assert success(simulate(arm, strict, x0, T=4.0), arm).sum() < alone.sum() - LOSS  # the premise
    margin = catch_margin(arm, strict, n=40, T=4.0)
    assert margin > -0.9
    governed = success(simulate(arm, _Governed(arm, margin), x0, T=4.0), arm)
    assert governed.sum() >= alone.sum() - LOSS


def test_a_controller_carries_its_margin_through_its_variants_and_into_the_export(pendubot):
    from idapbc_pin.config import TrainConfig
    from idapbc_pin.control.controller import Controller
    from idapbc_pin.control.nets import build_nets

    ctrl = Controller(pendubot, build_nets(pendubot, TrainConfig.fast()), governor_margin=2.5)
    variants = (ctrl.with_damping(0.1), ctrl.with_fallback(None), ctrl.with_guard(False), ctrl.with_governor(False).with_governor(True), ctrl.in_float64())
    assert all(v.governor.energy_margin == 2.5 for v in variants)
    assert ctrl.governor.to_json()["energy_margin"] == 2.5
    x = pendubot.state_from(np.array([[0.0, 0.0]]), np.array([[9.0, -9.0]]))
    e = (ctrl.governor.energy(x)[0][0] - ctrl.governor.e_star) / ctrl.governor.delta_e
    assert ENERGY_MARGIN + 0.5 < e < 2.5  # the default's energy clause brakes there at full effort, this one not at all
    assert SpeedGovernor.of(pendubot).shares(x)[0][0] == 1.0 and ctrl.governor.shares(x)[0][0] == 0.0

"""`benchmarks/bench_speed_floor.py` integrates its open-loop histories like the project's judge
(`sim.integrate.simulate`, RK4 with the input held), so its lowest peaks are speeds of the same plant:
two RK4 discretisations of one flow (the benchmark's in momenta), equal to the integrator's error,
while the torque moves the speeds by a hundred times more."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

import idapbc_pin as ip
from idapbc_pin.control.speed_governor import SpeedGovernor
from idapbc_pin.evaluation.swingup import swingup_states
from idapbc_pin.sim.integrate import simulate

_DIR = Path(__file__).resolve().parents[1] / "benchmarks"
_spec = importlib.util.spec_from_file_location("bench_speed_floor", _DIR / "bench_speed_floor.py")
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def test_open_loop_speed_ratios_match_the_simulator_under_a_constant_torque():
    system = ip.load_system("pendubot")
    x0 = swingup_states(system, n=2, seed=0, starts="moving")[0]
    level = 0.6  # of the limit, held over the whole horizon
    R = bench.ratios(system, x0, np.full((1, 4), level), horizon=0.2, dt=0.002)
    bound = np.asarray(system.effort, np.float64)
    traj = simulate(system, lambda x: np.broadcast_to(level * bound, (len(x), system.m)), x0[None], T=0.2, dt=0.002)
    v = system.split(traj.x[0, 1:])[1]
    rating = SpeedGovernor.of(system).rating
    np.testing.assert_allclose(R[0], np.abs(v) / rating, rtol=0, atol=2e-4)
    free = bench.ratios(system, x0, np.zeros((1, 4)), horizon=0.2, dt=0.002)
    assert np.abs(free - R).max() > 100 * 2e-4

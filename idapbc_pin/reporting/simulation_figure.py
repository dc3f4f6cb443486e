"""simulation.png: the figure's panels for the first rollouts of a `simulate_run` result."""

from __future__ import annotations

from pathlib import Path

from ..sim.trajectory import Trajectory
from .figure_data import figure_data
from .plot import plot, save_png

__all__ = ["simulation_figure"]


def simulation_figure(run, result, n_figure: int = 4) -> Path | None:
    """Draw Neural IDA-PBC's first `n_figure` rollouts of `result` (`SimulationResult`) as one row of
    the paper's figure into ``run.path / "simulation.png"``; -> its path, or None when there is none."""
    tr = result.trajectory
    k = min(int(n_figure), 0 if tr is None else tr.x.shape[0])
    if k <= 0:
        return None
    sub = Trajectory(t=tr.t, x=tr.x[:k], q=tr.q[:k], v=tr.v[:k], u=tr.u[:k], diverged=tr.diverged[:k])
    row = figure_data(result.controller, traj=sub, epsilon=run.summary.get("epsilon"), label=result.label)
    return save_png(plot([row]), run.path / "simulation.png")

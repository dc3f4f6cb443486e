"""swingup.png: a swing-up from the exact hanging start, the run's law beside the references.

Three panels over time, one colour per controller of a `SwingupResult` (its first start, exactly at
rest in the resting posture): a) the wrapped distance of each angle from x* (rad; prismatic
coordinates in m), b) the input u(t) with the effort limits dashed, c) the energy H(t) with the
target's H(x*) dashed. No pyplot: nothing is shown.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..control.baseline import LQRController
from ..control.energy_pump import EnergyPumpLaw
from ..model.angles import wrap_angles
from ..sim.integrate import simulate
from .plot import save_png

__all__ = ["TITLE", "draw_swingup", "swingup_figure"]

_STYLES = ("-", "--", ":", "-.")


def draw_swingup(axes, run, result) -> None:
    """Draw the three panels (a) wrap(q − q*), b) u(t), c) H(t)) into `axes` (3 matplotlib axes):
    the rollouts of the run's law (and of its manoeuvre from rest, where it keeps one), saturated LQR
    and the energy-pumping law from the first start of `result` (a `SwingupResult`), over its
    horizon and step, with the effort limits."""
    system = run.system
    laws = {"LQR": LQRController(system), "energy pump + LQR": EnergyPumpLaw(system), "NIDA-PBC": run.controller}  # the run's law drawn on top
    if getattr(run, "manoeuvre", None) is not None:  # and its manoeuvre from rest, on top of it
        laws["NIDA-PBC manoeuvre"] = run.manoeuvre.law(run.controller, dt=result.dt)
    x0 = result.states[:1]
    nq, mask = system.nq, np.asarray(system.angle_mask, bool)[: system.nq]
    for c, (name, law) in enumerate(laws.items()):
        tr = simulate(system, law, x0, T=result.T, dt=result.dt, record_every=5)
        colour, lw = {"NIDA-PBC": ("tab:blue", 1.8), "NIDA-PBC manoeuvre": ("tab:purple", 1.8)}.get(name, (("tab:orange", "tab:green")[c % 2], 0.8))
        dq = wrap_angles(tr.q[0] - np.asarray(system.x_star)[:nq], mask)
        for i in range(nq):
            axes[0].plot(tr.t, dq[:, i], _STYLES[i % 4], color=colour, lw=lw, label=f"{name}: {system.coordinate_names[i]}")
        for j in range(system.m):
            axes[1].plot(tr.t, tr.u[0, :, j], _STYLES[j % 4], color=colour, lw=lw, label=name if j == 0 else None)
        axes[2].plot(tr.t, system.hamiltonian(tr.x[0]), color=colour, lw=lw, label=name)
    effort = np.asarray(system.effort, float)
    for e in effort[np.isfinite(effort)]:
        for sign in (-1, 1):
            axes[1].axhline(sign * e, color="grey", ls="--", lw=0.8)
    axes[2].axhline(float(system.hamiltonian(system.x_star[None])[0]), color="grey", ls="--", lw=0.8, label="H(x*)")
    for ax, title, unit in zip(axes, ("a) wrap(q − q*)", "b) u(t)", "c) energy H(t)"), ("rad or m", "N·m or N", "J")):
        ax.set_title(f"swing-up {title}")
        ax.set_xlabel("t (s)")
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=6, ncol=2)
    axes[2].legend(fontsize=7)


#: The title of the swing-up panels (swingup.png's, and figure.png's swing-up row).
TITLE = "{}: swing-up from the exact hanging start, effort limits on every controller"


def swingup_figure(run, result, path: Path | None = None) -> Path | None:
    """Draw `draw_swingup`'s panels for `result` (a `SwingupResult` of `evaluate_run_swingup`) into
    ``run.path / "swingup.png"`` (or `path`); -> its path, or None without matplotlib."""
    try:
        from matplotlib.figure import Figure
    except ImportError:  # the figure is optional
        return None
    fig = Figure(figsize=(13, 3.6), layout="constrained")
    draw_swingup(fig.subplots(1, 3), run, result)
    fig.suptitle(TITLE.format(run.system.name), fontsize=10)
    return save_png(fig, path or run.path / "swingup.png")

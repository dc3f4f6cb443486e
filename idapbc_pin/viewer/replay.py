"""`view` and `write_html`: closed-loop rollouts of a run's controller (or the LQR baseline), animated.

Rollouts are simulated with `idapbc_pin.sim` from states drawn uniformly from the half-size
training box (`idapbc_pin.sim.states.initial_states`), or from given states; ``pick="success"``
keeps those that reach x*. A `Viewer` draws them; `view` can also write the HTML replay and serve it.

The live page lives in a child process that ends with this one. In a script, `view` says so and
how to keep it (`Viewer.wait`, which blocks until Ctrl-C) or to write the HTML file instead.
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..control.baseline import LQRController
from ..errors import IdapbcError
from ..model import load_system
from ..recovery.swing_law import KeptBoxLaw
from ..run import resolve_run
from ..sim.integrate import simulate
from ..sim.metrics import success
from ..sim.states import initial_states, resting_states
from ..sim.step import DEFAULT_STEP, judge_step
from .animation import DEFAULT_FPS
from .viewer import Viewer

__all__ = ["PICKS", "PICK_CANDIDATES", "view", "write_html"]

#: Which rollouts `view` shows (its ``pick``).
PICKS = ("auto", "random", "success", "hanging")

#: With ``pick="success"``, candidates drawn per requested rollout.
PICK_CANDIDATES = 20

#: What `view` prints when it serves from a script: the page ends with the process.
_SCRIPT_NOTE = (
    "note: the live viewer is served only while this script runs; keep the Viewer that view() returns and call "
    "its .wait() to serve until Ctrl-C, or its .write_html('replay.html') for a file that replays offline"
)


def _interactive() -> bool:
    """True in an interactive interpreter (``python -i``, the REPL), IPython or a notebook kernel."""
    if hasattr(sys, "ps1") or sys.flags.interactive:
        return True
    ipython = sys.modules.get("IPython")
    return ipython is not None and getattr(ipython, "get_ipython", lambda: None)() is not None


def _system_and_controller(run_or_system, checkpoint: str | None = None):
    """-> (system, controller or None, swing-up manoeuvre or None): a run directory or a Run (anything
    with ``system`` and ``controller``) gives its controller and the manoeuvre it keeps; a System, or
    a system source, gives None (LQR baseline). `checkpoint` picks the checkpoint of a run directory
    (see `load_run`)."""
    if isinstance(run_or_system, (str, Path)):
        p = Path(run_or_system)
        if p.is_dir() and (p / "config.json").is_file():
            run_or_system = resolve_run(p, checkpoint=checkpoint)
        elif checkpoint is not None:
            raise IdapbcError(f"checkpoint= applies to a run directory, and '{run_or_system}' is not one. Fix: drop it, or pass a run directory.")
        else:
            try:
                return load_system(str(run_or_system)), None, None
            except IdapbcError:
                if p.is_dir():  # meant as a run: say what it lacks
                    resolve_run(p)
                raise
    if hasattr(run_or_system, "controller") and hasattr(run_or_system, "system"):
        return run_or_system.system, run_or_system.controller, getattr(run_or_system, "manoeuvre", None)
    if hasattr(run_or_system, "nq") and hasattr(run_or_system, "plant"):
        return run_or_system, None, None
    raise IdapbcError(f"cannot view {type(run_or_system).__name__}. Fix: pass a Run, a System, a run directory or a system source.")


def _simulate(system, controller, x0: np.ndarray, T: float, dt: float | None, limits: bool = True):
    """Rollouts from x0 (N, n) for `T` s rounded to whole steps `dt` (LQR when `controller` is None;
    dt None: `judge_step`)."""
    if controller is None:
        controller = LQRController(system)
    if not (T > 0 and math.isfinite(T)):
        raise IdapbcError(f"T must be a positive number of seconds, got {T!r}.")
    dt = judge_step(system, {"law": controller}, T, dt)
    steps = max(1, int(round(T / dt)))
    return simulate(system, controller, x0, T=steps * dt, dt=dt, limits=limits)


def _pick_successes(system, controller, n: int, T: float, dt: float, seed: int, limits: bool = True):
    """Up to `n` rollouts that reach x* (the success criterion over the last 2 s of `T`) among
    ``PICK_CANDIDATES · n`` uniform states of the half box, in draw order, filled up with failing
    ones when fewer succeed. Returns (Trajectory of n rows, number reaching x*, candidates)."""
    candidates = initial_states(system, None, PICK_CANDIDATES * n, seed)
    traj = _simulate(system, controller, candidates, T, dt, limits)
    ok = success(traj, system)
    order = np.concatenate([np.flatnonzero(ok), np.flatnonzero(~ok)])[:n]
    x = traj.x[order]
    picked = replace(traj, x=x, q=x[..., : system.nq], v=traj.v[order], u=traj.u[order], diverged=traj.diverged[order])
    return picked, int(ok[order].sum()), len(candidates)


def _rollouts_to_show(system, controller, trajectories, x0, n: int, pick: str, T: float, dt: float, seed: int, limits: bool = True, manoeuvre=None):
    """-> (trajectories, a note saying which rollouts they are); `manoeuvre`: the run's swing-up manoeuvre from rest, if
    it keeps one (the swing-ups from hanging then run it)."""
    if pick not in PICKS:
        raise IdapbcError(f"pick must be one of {', '.join(PICKS)}, got {pick!r}.")
    if trajectories is not None:
        return trajectories, "given trajectories"
    if x0 is None and pick == "hanging":
        start = resting_states(system, n, seed)
        if manoeuvre is not None:  # the run's manoeuvre from rest, then its law, at the judge's step: the manoeuvre counts its ticks
            note = f"{len(start)} swing-ups by the run's manoeuvre from near the resting posture (the first exactly at rest)"
            return _simulate(system, manoeuvre.law(controller, dt=DEFAULT_STEP), start, T, DEFAULT_STEP, limits), note
        return _simulate(system, controller, start, T, dt, limits), f"{len(start)} swing-ups from near the resting posture (the first exactly at rest)"
    if x0 is None and pick == "success":
        if n < 1:
            raise IdapbcError(f"n must be at least 1, got {n}.")
        picked, reached, drawn = _pick_successes(system, controller, n, T, dt, seed, limits)
        return picked, f"{reached} of {n} rollouts reach x* (picked among {drawn} random half-box states)"
    start = initial_states(system, x0, n, seed)
    note = f"{len(start)} rollouts from " + ("random half-box states" if x0 is None else "the given states")
    return _simulate(system, controller, start, T, dt, limits), note


def view(
    run_or_system,
    trajectories=None,
    *,
    x0=None,
    n: int = 3,
    pick: str = "auto",
    T: float = 10.0,
    dt: float | None = None,
    seed: int = 0,
    html=None,
    open_server: bool = True,
    port: int | None = None,
    layout: str = "sequence",
    trace: bool = True,
    trace_link: str | None = None,
    fps: float = DEFAULT_FPS,
    loop: bool = True,
    style: str = "auto",
    grid: bool = True,
    checkpoint: str | None = None,
    limits: bool = True,
) -> Viewer:
    """Animate a system along closed-loop trajectories in meshcat; never blocks.

    The live page is served by a child process that ends with this Python process. In a notebook
    or an interactive session it stays up while the session runs; in a script, `view` prints one
    line saying so: call ``viewer.wait()`` to serve until Ctrl-C, or ``viewer.write_html(path)``
    (or ``html=path``) for a file that replays offline, with no server.

    Parameters
    ----------
    run_or_system : a trained `Run`, a `System`, a run directory or a system source (URDF path,
        zoo or built-in name, ``erd:<stem>``).
    trajectories : a `Trajectory` from `idapbc_pin.sim.simulate` (all its rollouts), a list of them,
        or a pair (t (K,), q (K, nq) or (N, K, nq)). None: simulate `n` rollouts of `T` s (step
        `dt`; None: 2 ms, or shorter for a stiff loop) from states drawn uniformly from the
        half-size training box (seed `seed`), or from `x0`,
        with the run's controller, or the LQR baseline when given a `System`.
    x0 : (N, n) initial states (q, p) or (N, nq) positions at rest; overrides `n` and `pick`.
    pick : ``"auto"`` (the default: ``"hanging"`` for a run with a swing-up law, else ``"random"``),
        ``"hanging"`` (`n` swing-ups from near the resting posture, the first exactly at rest;
        `sim.states.resting_states`), ``"random"`` (the first `n` uniform half-box states) or ``"success"``: up to `n` rollouts
        that reach x* within `T` (the success criterion of docs/method.md), chosen among
        ``PICK_CANDIDATES · n`` uniform half-box states and filled up with failing ones; prints how
        many reach x*. A picture of what the controller does where it works, not of how often it
        works (that is the ROA).
    html : write the standalone HTML replay there (atomically).
    open_server : start the live server (127.0.0.1) and print its URL; `Viewer.close` stops it.
    port : HTTP port of the live page; None picks the first free one from 7000; in use: error.
    layout : ``"sequence"`` (rollouts one after another, one robot) or ``"side_by_side"``.
    trace, trace_link : draw the path of the far end of `trace_link` (a joint or link name; default
        the last joint's link; analytic systems trace their tip).
    fps : at least this many keyframes per second of trajectory (at trajectory samples).
    loop : replay forever (else once).
    style : ``"auto"`` (URDF visuals, stick-and-ball if none), ``"visual"`` or ``"stick"``.
    grid : show meshcat's ground grid and world axes.
    checkpoint : ``"best"`` or ``"last"``, the checkpoint of a run directory to animate (None: last,
        the final weights, refusing a run with a damaged checkpoint; see `load_run`).
    limits : simulate with the actuators' effort limits (``system.effort``), as every evaluation does;
        False lifts them.

    Returns
    -------
    Viewer (``.url``, ``.write_html(path)``, ``.close()``; shows inline in a notebook).
    """
    system, controller, manoeuvre = _system_and_controller(run_or_system, checkpoint)
    if pick == "auto":  # a run with a swing-up law or manoeuvre is shown swinging up
        pick = "hanging" if isinstance(getattr(controller, "fallback", None), KeptBoxLaw) or manoeuvre is not None else "random"
    trajectories, note = _rollouts_to_show(system, controller, trajectories, x0, n, pick, T, dt, seed, limits, manoeuvre)
    viewer = Viewer(system, trajectories, layout=layout, trace=trace, trace_link=trace_link, fps=fps, loop=loop, style=style, grid=grid)
    viewer.note = note
    if html is not None:
        viewer.write_html(html)
    if open_server:
        url = viewer.serve(port)
        print(f"meshcat viewer: {url}  ({note})", flush=True)
        if not _interactive():
            print(_SCRIPT_NOTE, flush=True)
    return viewer


def write_html(path, run_or_system, trajectories=None, **kwargs) -> Path:
    """Write the standalone HTML replay of `view(run_or_system, trajectories, **kwargs)` to `path`.

    No server is started; the file is written atomically and replays offline. Returns the path.
    """
    kwargs.pop("open_server", None)
    return view(run_or_system, trajectories, open_server=False, **kwargs).write_html(path)

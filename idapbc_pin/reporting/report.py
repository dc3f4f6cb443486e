"""The paper's figure for a run, the closed-loop report, and the evaluation sub-commands.

`figure` draws, for a few initial states (uniform in the half-size training box, seeded), the
panels of the paper's Fig. 1 (§V "Results"):

    a) q(t)   b) p(t)   c) ∇H_dᵀR_d∇H_d − ∇H_dᵀξ (eq. damping_assign_relax_tilde), log scale,
    clamped at 1e-6, violations (≤ 0) marked, bars where the state has left the training box X
    d) u(t)   e) H_d(t) with E = H_ε shaded and the
    entry time t_E of each trajectory dotted (also in c)

in one row for the trained controller and one for the "extra damping" variant (ρ raised after
training, paper Fig. ii). The true plant integrates; the quantities in c) and e) are those of the
controller's model. `figure_data` returns the arrays a row is drawn from and `plot` draws rows, so
that tests can hold the panels against the simulated trajectories.

`report` runs the ROA evaluation against LQR (`evaluate_run`), `certify`, `figure` and writes a
meshcat replay (``replay.html``) of the figure's trajectories. `add_eval_commands` registers
``idapbc-pin simulate | certify | report | robustness``.
"""

from __future__ import annotations

import argparse
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from .._io import atomic_write_bytes
from ..certificate.certify import closed_loop_terms, resolve_controller, write_json_atomic
from ..errors import IdapbcError
from ..sim.states import initial_states

__all__ = [
    "DEFAULT_EXTRA_RHO",
    "MARGIN_FLOOR",
    "FigureData",
    "SimulationResult",
    "add_eval_commands",
    "extra_damping_rho",
    "figure",
    "figure_data",
    "plot",
    "report",
    "simulate_run",
]

#: Panel c) is clamped at this value (paper §V: "clamped once reaching a threshold of 1e-6").
MARGIN_FLOOR = 1e-6
#: Smallest ρ of the "extra damping" row when none is given (see `extra_damping_rho`).
DEFAULT_EXTRA_RHO = 1.0


# ====================================================================== data of one row
@dataclass(frozen=True, eq=False)
class FigureData:
    """What one row of the figure shows.

    Attributes
    ----------
    label : row label (system, ρ, conditions).
    traj : the simulated `Trajectory` (t (K,), q, v (N, K, nq), x (N, K, n), u (N, K, m)).
    H : (N, K) H_d along the trajectories.
    margin : (N, K) ∇H_dᵀR_d∇H_d − ∇H_dᵀξ along them (> 0: the dissipation inequality holds).
    epsilon : ε of E = H_ε.
    t_E : (N,) first time with H_d < ε (nan if never).
    rho : the controller's ρ (nan if it has none).
    in_domain : (N, K) bool, the state lies in the training box X (where the certificate samples).
    valid : (N, K) bool, False after a trajectory diverged (`simulate` freezes diverged rows at
        their last finite state; the figure leaves those samples out).
    coordinate_names, input_names : names of q and u components.
    q_units, p_units, u_units : per component ("rad", "m"; "N·m·s", "N·s"; "N·m", "N").
    """

    label: str
    traj: object
    H: np.ndarray
    margin: np.ndarray
    epsilon: float
    t_E: np.ndarray
    rho: float
    in_domain: np.ndarray
    valid: np.ndarray
    coordinate_names: tuple
    input_names: tuple
    q_units: tuple
    p_units: tuple
    u_units: tuple

    @property
    def p(self) -> np.ndarray:
        """(N, K, nq) momenta, the second half of x."""
        nq = len(self.coordinate_names)
        return self.traj.x[..., nq:]


def _steps(T: float, dt: float) -> float:
    if not (dt > 0 and math.isfinite(dt)):
        raise IdapbcError(f"dt must be a positive number of seconds, got {dt!r}.")
    if not (T > 0 and math.isfinite(T)):
        raise IdapbcError(f"T must be a positive number of seconds, got {T!r}. Fix: e.g. --T 20.")
    return max(1, int(round(T / dt))) * dt


def _units(system):
    joints = system.joints
    q = tuple("rad" if j.is_angle else "m" for j in joints)
    p = tuple("N·m·s" if j.is_angle else "N·s" for j in joints)
    by_name = {j.name: j for j in joints}
    u = tuple("N·m" if by_name[a].is_angle else "N" for a in system.actuated)
    return q, p, u


def _valid(traj) -> np.ndarray:
    """(N, K): True up to the last finite state of a diverged row (the frozen repeats after it: False)."""
    valid = np.ones(traj.x.shape[:2], bool)
    for k in np.flatnonzero(traj.diverged):
        same = np.all(traj.x[k] == traj.x[k, -1], axis=-1)
        frozen_from = len(same) - int(np.argmin(same[::-1])) if not same.all() else 0
        valid[k, frozen_from + 1 :] = False
    return valid


def _entry_times(t: np.ndarray, H: np.ndarray, epsilon: float) -> np.ndarray:
    inside = H < epsilon
    first = np.argmax(inside, axis=1)
    out = t[first].astype(float)
    out[~inside.any(axis=1)] = np.nan
    return out


def figure_data(
    run,
    x0=None,
    n: int = 4,
    T: float = 20.0,
    dt: float = 0.01,
    seed: int = 0,
    *,
    rho: float | None = None,
    epsilon: float | None = None,
    plant=None,
    saturation=None,
    noise: float = 0.0,
    traj=None,
    label: str | None = None,
) -> FigureData:
    """Simulate and evaluate one row of the figure.

    Parameters
    ----------
    run : a `Run`, a run directory or a controller (see `idapbc_pin.certificate.certify`).
    x0 : (N, n) initial states or (N, nq) positions at rest; default `n` uniform states of the
        half-size box (seed `seed`).
    T, dt : horizon and RK4 step, s.
    rho : replace the controller's ρ ("extra damping", `Controller.with_damping`).
    epsilon : ε of E (default the run's estimate).
    plant : the judge `System` (default the controller's model), e.g. `perturbed_system(...)`.
    saturation, noise : as in `simulate` and `MeasuredController`.
    traj : an already simulated `Trajectory` of this controller (then nothing is simulated).
    """
    from ..evaluation.robustness import MeasuredController
    from ..sim.simulate import simulate

    ctrl, system, eps, _ = resolve_controller(run, epsilon)
    if rho is not None:
        if not hasattr(ctrl, "with_damping"):
            raise IdapbcError(f"{type(ctrl).__name__} has no with_damping(ρ). Fix: drop rho.")
        if not (math.isfinite(rho) and rho >= 0):
            raise IdapbcError(f"ρ must be finite and ≥ 0, got {rho}. Fix: e.g. --rho 1.")
        ctrl = ctrl.with_damping(float(rho))
    if traj is None:
        x0 = initial_states(system, x0, n, seed)
        judge = system if plant is None else plant
        law = ctrl if (plant is None and not noise) else MeasuredController(ctrl, plant=judge, model=system, noise=noise, seed=seed)
        if saturation is not None and not np.all(np.asarray(saturation, float) > 0):
            raise IdapbcError(f"saturation must be > 0 (max |u| per input), got {saturation!r}.")
        traj = simulate(judge, law, x0, T=_steps(T, dt), dt=dt, saturation=saturation)
    N, K, nx = traj.x.shape
    terms = closed_loop_terms(ctrl, traj.x.reshape(N * K, nx), system)
    H, margin = terms.H.reshape(N, K), terms.margin.reshape(N, K)
    q_u, p_u, u_u = _units(system)
    r = float(ctrl.rho) if hasattr(ctrl, "rho") else math.nan
    if label is None:
        label = f"{getattr(system, 'name', 'system')}, ρ = {r:g}" if math.isfinite(r) else str(getattr(system, "name", "system"))
    return FigureData(
        label=label, traj=traj, H=H, margin=margin, epsilon=eps, t_E=_entry_times(traj.t, H, eps), rho=r, valid=_valid(traj),
        in_domain=np.all((traj.x >= system.domain[0]) & (traj.x <= system.domain[1]), axis=-1),
        coordinate_names=tuple(system.coordinate_names), input_names=tuple(system.actuated),
        q_units=q_u, p_units=p_u, u_units=u_u,
    )


# ====================================================================== drawing
_PANELS = ("q", "p", "margin", "u", "H")


def _style_legend(ax, styles: Sequence[str], labels: Sequence[str]) -> None:
    """Legend of the line styles (one per coordinate or input; colours are the rollouts)."""
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color="0.3", ls=styles[i % len(styles)]) for i in range(len(labels))]
    ax.legend(handles, labels, fontsize=8, loc="upper right")


def _unit_label(symbol: str, units: Sequence[str]) -> str:
    uniq = list(dict.fromkeys(units))
    return f"{symbol} [{' | '.join(uniq)}]"


def plot(rows: Sequence[FigureData]):
    """Draw rows of the figure (5 panels each); returns the matplotlib `Figure` (Agg, not shown).

    Every data line carries a gid ``"<panel>:<trajectory>:<component>"`` with panel in
    ``q, p, margin, u, H``; panel c) shows max(margin, 1e-6).
    """
    import matplotlib
    from matplotlib.figure import Figure  # no pyplot: no global backend, nothing shown
    from matplotlib.lines import Line2D

    rows = list(rows)
    if not rows:
        raise IdapbcError("nothing to plot. Fix: pass at least one FigureData row.")
    fig = Figure(figsize=(22, 4.5 * len(rows) + 0.6), layout="constrained")
    subfigs = np.atleast_1d(fig.subfigures(len(rows), 1))
    axes = np.stack([sf.subplots(1, 5) for sf in subfigs])
    for sf, d in zip(subfigs, rows):
        sf.suptitle(d.label, x=0.005, ha="left", fontsize=11, fontweight="bold")
    colors = matplotlib.colormaps["tab10"].colors
    styles = ("-", "--", ":", "-.")
    for r, d in enumerate(rows):
        t = d.traj.t
        N = d.traj.x.shape[0]
        ax_q, ax_p, ax_c, ax_u, ax_h = axes[r]
        for k in range(N):
            color = colors[k % len(colors)]
            ok = d.valid[k]

            def cut(y, ok=ok):
                return np.where(ok, y, np.nan)

            for i, name in enumerate(d.coordinate_names):
                ls = styles[i % len(styles)]
                ax_q.plot(t, cut(d.traj.q[k, :, i]), color=color, ls=ls, lw=1.3, gid=f"q:{k}:{i}")
                ax_p.plot(t, cut(d.p[k, :, i]), color=color, ls=ls, lw=1.3, gid=f"p:{k}:{i}")
            for j in range(d.traj.u.shape[2]):
                ax_u.plot(t, cut(d.traj.u[k, :, j]), color=color, ls=styles[j % len(styles)], lw=1.3, gid=f"u:{k}:{j}")
            ax_c.plot(t, cut(np.maximum(d.margin[k], MARGIN_FLOOR)), color=color, lw=1.3, gid=f"margin:{k}:0")
            bad = (d.margin[k] <= 0) & ok
            if bad.any():
                idx = np.flatnonzero(bad)[:: max(1, int(bad.sum()) // 60)]
                ax_c.plot(t[idx], np.full(idx.size, MARGIN_FLOOR), ls="none", marker="x", ms=5, color="crimson", gid=f"violation:{k}:0")
            ax_h.plot(t, cut(d.H[k]), color=color, lw=1.3, gid=f"H:{k}:0")
            outside = ~d.in_domain[k] & ok
            if outside.any():  # a bar at the top of c): the state is outside the training box X
                ax_c.plot(t, np.where(outside, 0.97 - 0.025 * k, np.nan), color=color, lw=3, alpha=0.6, solid_capstyle="butt",
                          transform=ax_c.get_xaxis_transform(), gid=f"outside:{k}:0")
            if not ok.all():  # diverged: mark where the record stops
                last = int(np.flatnonzero(ok)[-1])
                for ax, y in ((ax_q, d.traj.q[k, last]), (ax_p, d.p[k, last]), (ax_u, d.traj.u[k, last])):
                    ax.plot(np.full(y.shape, t[last]), y, ls="none", marker="X", ms=8, color=color, markeredgecolor="k")
            if math.isfinite(d.t_E[k]):
                for ax in (ax_c, ax_h):
                    ax.axvline(d.t_E[k], color=color, ls=":", lw=1.2)
        # a) q
        ax_q.set_title("a) positions q(t)", fontsize=10, loc="left")
        ax_q.set_ylabel(_unit_label("q", d.q_units))
        _style_legend(ax_q, styles, [f"{nm} [{u}]" for nm, u in zip(d.coordinate_names, d.q_units)])
        # b) p
        ax_p.set_title("b) momenta p(t)", fontsize=10, loc="left")
        ax_p.set_ylabel(_unit_label("p", d.p_units))
        _style_legend(ax_p, styles, [f"p_{nm} [{u}]" for nm, u in zip(d.coordinate_names, d.p_units)])
        # c) dissipation margin
        ax_c.set_yscale("log")
        ax_c.set_title("c) ∇H_dᵀR_d∇H_d − ∇H_dᵀξ (> 0: dissipation holds)", fontsize=10, loc="left")
        ax_c.set_ylabel(f"margin [H_d units / s], clamped at {MARGIN_FLOOR:g}")
        handles = [Line2D([], [], color="0.3", ls=":", label="t_E (enters E)")]
        if np.any(d.margin <= 0):
            handles.append(Line2D([], [], color="crimson", ls="none", marker="x", label="margin ≤ 0 (violated)"))
        if not d.in_domain.all():
            handles.append(Line2D([], [], color="0.3", lw=3, label="bars: state outside the training box X"))
        ax_c.legend(handles=handles, fontsize=8, loc="upper right", bbox_to_anchor=(1.0, 0.88))
        # d) u
        ax_u.set_title("d) input u(t)", fontsize=10, loc="left")
        ax_u.set_ylabel(_unit_label("u", d.u_units))
        _style_legend(ax_u, styles, [f"u_{nm} [{u}]" for nm, u in zip(d.input_names, d.u_units)])
        # e) H_d with E shaded
        ax_h.set_yscale("log")
        positive = d.H[(d.H > 0) & d.valid]
        top = float(positive.max()) * 3 if positive.size else 1.0
        bottom = max(float(positive.min()) if positive.size else 1e-12, top * 1e-10)
        if d.epsilon > 0:
            bottom = min(bottom, d.epsilon / 10)
            ax_h.axhspan(bottom / 10, d.epsilon, color="0.85", zorder=0, label=f"E = H_ε (ε = {d.epsilon:.3g})")
            ax_h.axhline(d.epsilon, color="0.5", lw=0.8)
        ax_h.set_ylim(bottom, top)
        ax_h.set_title("e) desired energy H_d(t)", fontsize=10, loc="left")
        ax_h.set_ylabel("H_d (desired energy, free scale)")
        ax_h.legend(handles=[*ax_h.get_legend_handles_labels()[0], Line2D([], [], color="0.3", ls=":", label="t_E")], fontsize=8, loc="upper right")
        for ax in axes[r]:
            ax.set_xlabel("t [s]")
            ax.grid(True, alpha=0.3)
            ax.set_xlim(t[0], t[-1])
    n_traj = rows[0].traj.x.shape[0]
    traj_handles = [Line2D([], [], color=colors[k % len(colors)], lw=2) for k in range(n_traj)]
    labels = []
    for k in range(n_traj):
        x0 = ", ".join(f"{v:.2f}" for v in rows[0].traj.x[k, 0])
        gone = any(k < d.valid.shape[0] and not d.valid[k].all() for d in rows)
        labels.append(f"x0 #{k + 1} = ({x0})" + (" diverged" if gone else ""))
    handles = traj_handles + [Line2D([], [], ls="none", marker="X", ms=8, color="0.5", markeredgecolor="k")] if any(not d.valid.all() for d in rows) else traj_handles
    if len(handles) > n_traj:
        labels.append("diverged (record stops)")
    fig.legend(handles, labels, loc="outside lower center", ncols=len(handles), fontsize=9)
    return fig


def _save_png(fig, path: Path, dpi: int = 100) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return atomic_write_bytes(path, buf.getvalue())


def extra_damping_rho(ctrl, n: int = 2000, seed: int = 0) -> float:
    """Default ρ of the "extra damping" row: the damping the energy gradient already sees.

    ρ = max(`DEFAULT_EXTRA_RHO`, median over half-box samples of ∇H_dᵀR_d∇H_d / ‖∇H_d‖²), to two
    significant digits, plus the controller's current ρ. R_d has no fixed scale (an anchored
    run's R_d = −sym(A_cl P⁻¹) can reach 10⁴ when P is scaled to λ_max = 1), so a fixed ρ = 1 may
    change nothing; this roughly doubles the damping along ∇H_d whatever the scale.
    """
    from ..sim.simulate import uniform_states

    x = uniform_states(ctrl.system, n, "half", seed)
    dH = np.asarray(ctrl.grad_H_d(x), float)
    R = np.asarray(ctrl.R_d(x), float)
    norm2 = (dH * dH).sum(axis=1)
    ok = norm2 > 0
    rayleigh = np.einsum("ni,nij,nj->n", dH[ok], R[ok], dH[ok]) / norm2[ok]
    typical = float(np.median(rayleigh)) if rayleigh.size else 0.0
    base = max(DEFAULT_EXTRA_RHO, float(f"{typical:.2g}"))
    return base + float(getattr(ctrl, "rho", 0.0))


def _extra_rho(ctrl, rho_extra) -> float:
    return float(rho_extra) if rho_extra is not None else extra_damping_rho(ctrl)


def _as_run(run):
    if isinstance(run, (str, os.PathLike)):
        from ..training.run import load_run

        return load_run(run)
    return run


def _figure_rows(run, x0, n, T, dt, seed, rho_extra, extra: bool) -> list[FigureData]:
    run = _as_run(run)
    ctrl, system, eps, _ = resolve_controller(run)
    x0 = initial_states(system, x0, n, seed)
    rows = [figure_data(run, x0, T=T, dt=dt, seed=seed)]
    if extra and hasattr(ctrl, "with_damping"):
        rho = _extra_rho(ctrl, rho_extra)
        rows.append(figure_data(run, x0, T=T, dt=dt, seed=seed, rho=rho, label=f"{system.name}, extra damping ρ = {rho:g}"))
    return rows


def figure(
    run,
    x0=None,
    n: int = 4,
    T: float = 20.0,
    rho_extra: float | None = None,
    path=None,
    *,
    dt: float = 0.01,
    seed: int = 0,
    extra: bool = True,
) -> Path:
    """The paper's figure for a run: a PNG with rows (trained ρ, extra damping) × panels a)–e).

    Parameters
    ----------
    run : a `Run`, a run directory, or a controller (then `path` is required).
    x0 : (N, n) initial states, or (N, nq) positions at rest; default `n` uniform states of the
        half-size box (seed `seed`).
    T, dt : horizon and RK4 step, s.
    rho_extra : ρ of the extra-damping row (default `extra_damping_rho`: at least
        `DEFAULT_EXTRA_RHO`, scaled to R_d); ``extra=False`` leaves the row out.
    path : where to write (default ``<run>/figure.png``); written atomically.

    Returns
    -------
    The PNG's path.
    """
    run = _as_run(run)
    _, _, _, run_dir = resolve_controller(run)
    if path is None:
        if run_dir is None:
            raise IdapbcError("figure of a bare controller needs path=... . Fix: pass path or a Run.")
        path = run_dir / "figure.png"
    rows = _figure_rows(run, x0, n, T, dt, seed, rho_extra, extra)
    return _save_png(plot(rows), Path(path))


# ====================================================================== simulate (CLI)
@dataclass(frozen=True, eq=False)
class SimulationResult:
    """`simulate_run`'s outcome: the scores side by side and where things were written."""

    roa: object  #: `RoaResult` (NIDA-PBC, LQR)
    settings: dict
    json_path: Path | None
    figure_path: Path | None

    def table(self) -> str:
        s = self.settings
        conds = [f"{k}={v:g}" for k, v in (s.get("mismatch") or {}).items()]
        if s.get("saturation") is not None:
            conds.append(f"|u| ≤ {s['saturation']:g}")
        if s.get("noise"):
            conds.append(f"noise σ = {s['noise']:g}")
        lines = [self.roa.table()]
        if conds:
            lines.append("conditions: " + ", ".join(conds))
        for p in (self.json_path, self.figure_path):
            if p is not None:
                lines.append(f"wrote {p}")
        return "\n".join(lines)


def _scores(system, controllers, x0, T, dt, saturation, box_name, box, seed):
    import time

    from ..sim.simulate import ControllerScore, RoaResult, equilibrium_offset, peak_input, settled, settling_time, simulate, success

    scores, trajs = {}, {}
    for name, ctrl in controllers.items():
        t0 = time.perf_counter()
        traj = simulate(system, ctrl, x0, T=T, dt=dt, saturation=saturation)
        scores[name] = ControllerScore(
            name=name, success=success(traj, system), settling_time=settling_time(traj, system),
            offset=equilibrium_offset(traj, system), settled=settled(traj), peak_input=peak_input(traj),
            diverged=traj.diverged.copy(), wall_time=time.perf_counter() - t0,
        )
        trajs[name] = traj
    res = RoaResult(system=system.name, box=box, box_name=box_name, x0=x0, T=float(T), dt=float(dt), seed=int(seed), scores=scores)
    return res, trajs


def simulate_run(
    run,
    n: int = 100,
    T: float = 20.0,
    dt: float = 0.01,
    x0=None,
    *,
    rho: float | None = None,
    mismatch=None,
    saturation: float | None = None,
    noise: float = 0.0,
    seed: int = 0,
    box: str = "domain",
    write: bool = True,
    n_figure: int = 4,
) -> SimulationResult:
    """Closed loop of a run's controller next to LQR from the same states, under optional conditions.

    Writes ``simulation.json`` (settings and scores) and ``simulation.png`` (the figure's panels for
    the first `n_figure` states, Neural IDA-PBC) into the run directory.

    Parameters
    ----------
    run : a `Run` or a run directory.
    n : uniform states of `box` ("domain" or "half"), seed `seed`; or `x0` (N, n) / (N, nq).
    T, dt : horizon and RK4 step, s.
    rho : extra damping ρ for Neural IDA-PBC.
    mismatch : {kind: scale} or "mass=1.2,..." for the judge plant (`perturbed_system`).
    saturation : max |u| per input.   noise : σ of the (q, v) measurement noise.
    """
    from ..evaluation.robustness import MeasuredController, parse_mismatch, perturbed_system
    from ..sim.simulate import LQRController, evaluation_box, uniform_states
    from ..training.run import load_run

    if not hasattr(run, "controller"):
        run = load_run(run)
    nominal = run.system
    T = _steps(T, dt)
    if box not in ("domain", "half"):
        raise IdapbcError(f"box must be 'domain' or 'half', got {box!r}.")
    if x0 is None:
        if int(n) < 1:
            raise IdapbcError(f"n must be at least 1, got {n}. Fix: --n 100.")
        x0 = uniform_states(nominal, int(n), box, seed)
        box_name, bounds = box, evaluation_box(nominal, box)
    else:
        x0 = initial_states(nominal, x0, 0, seed)
        box_name, bounds = "custom", (x0.min(axis=0), x0.max(axis=0))
    if saturation is not None and not (math.isfinite(saturation) and saturation > 0):
        raise IdapbcError(f"saturation must be a positive max |u|, got {saturation}. Fix: e.g. --saturation 20.")
    if not (math.isfinite(noise) and noise >= 0):
        raise IdapbcError(f"noise must be ≥ 0, got {noise}. Fix: e.g. --noise 0.01.")
    if rho is not None and not (math.isfinite(rho) and rho >= 0):
        raise IdapbcError(f"ρ must be finite and ≥ 0, got {rho}. Fix: e.g. --rho 1.")
    scales = parse_mismatch(mismatch)
    plant = perturbed_system(nominal, **scales) if scales else nominal
    nida = run.controller if rho is None else run.controller.with_damping(rho)
    wrap = bool(scales) or noise > 0
    controllers = {
        "NIDA-PBC": MeasuredController(nida, plant=plant, model=nominal, noise=noise, seed=seed) if wrap else nida,
        "LQR": MeasuredController(LQRController(nominal), plant=plant, model=nominal, noise=noise, seed=seed) if wrap else LQRController(nominal),
    }
    res, trajs = _scores(plant, controllers, x0, T, dt, saturation, box_name, bounds, seed)
    settings = {"n": int(x0.shape[0]), "T": T, "dt": dt, "seed": seed, "box": box_name, "rho": float(nida.rho),
                "mismatch": scales, "saturation": saturation, "noise": noise}
    json_path = fig_path = None
    if write:
        from ..sim.simulate import Trajectory

        record = dict(settings)
        for name, s in res.scores.items():
            record[name] = {
                "success_rate": s.success_rate, "median_settling_time": s.median_settling_time, "median_offset": s.median_offset,
                "median_peak_input": s.median_peak_input, "diverged": s.n_diverged, "wall_time": s.wall_time,
                "success": s.success.tolist(), "settling_time": s.settling_time.tolist(),
            }
        record["x0"] = x0.tolist()
        from ..certificate.certify import _clean

        json_path = write_json_atomic(run.path / "simulation.json", _clean(record))
        k = min(int(n_figure), x0.shape[0])
        if k > 0:
            tr = trajs["NIDA-PBC"]
            sub = Trajectory(t=tr.t, x=tr.x[:k], q=tr.q[:k], v=tr.v[:k], u=tr.u[:k], diverged=tr.diverged[:k])
            conds = ", ".join([f"{a}×{b:g}" for a, b in scales.items()] + ([f"|u|≤{saturation:g}"] if saturation else []) + ([f"σ={noise:g}"] if noise else []))
            label = f"{nominal.name}, ρ = {nida.rho:g}" + (f", {conds}" if conds else "")
            row = figure_data(nida, traj=sub, epsilon=run.summary.get("epsilon"), label=label)
            fig_path = _save_png(plot([row]), run.path / "simulation.png")
    return SimulationResult(res, settings, json_path, fig_path)


# ====================================================================== report
def report(
    run,
    n_roa: int = 200,
    T: float = 20.0,
    *,
    rho_extra: float | None = None,
    n_figure: int = 4,
    n_certify: int = 20000,
    seed: int = 0,
    html: bool = True,
) -> str:
    """Everything about a run, in its directory; returns a short text summary.

    Runs `evaluate_run` (ROA of Neural IDA-PBC vs LQR on the domain and the half box,
    ``evaluation.json``), `certify` (``certificate.json``), the figure (``figure.png``) and a
    meshcat replay of up to 3 rollouts that reach x* (``replay.html``, `view` with
    ``pick="success"``); the summary is also
    written to ``report.txt``.
    """
    from ..certificate.certify import certify
    from ..evaluation.evaluate import evaluate_run, format_evaluation
    from ..training.run import load_run

    if not hasattr(run, "controller"):
        run = load_run(run)
    evaluation = evaluate_run(run, n=n_roa, T=T, seed=seed)
    cert = certify(run, n=n_certify, seed=seed, settle_T=T)
    rows = _figure_rows(run, None, n_figure, T, 0.01, seed, rho_extra, True)
    fig_path = _save_png(plot(rows), run.path / "figure.png")
    parts = [format_evaluation(evaluation), cert.table(), f"figure: {fig_path}"]
    if html:
        from ..viewer.view import view

        viewer = view(run, n=3, T=10.0, seed=seed, pick="success", open_server=False)
        parts.append(f"replay: {viewer.write_html(run.path / 'replay.html')} ({viewer.note})")
    text = "\n\n".join(parts)
    from .._io import atomic_write_bytes as _atomic_write_bytes

    _atomic_write_bytes(run.path / "report.txt", (text + "\n").encode())
    return text


# ====================================================================== CLI glue
def _cmd_simulate(args: argparse.Namespace) -> int:
    x0 = args.x0
    if x0 is not None and len({len(v) for v in x0}) != 1:
        raise IdapbcError("every --x0 needs the same number of values. Fix: give n (q, p) or nq (q) values each time.")
    result = simulate_run(
        args.run, n=args.n, T=args.T, dt=args.dt, x0=x0, rho=args.rho, mismatch=args.mismatch,
        saturation=args.saturation, noise=args.noise, seed=args.seed, box=args.box,
    )
    print(result.table())
    return 0


def _cmd_certify(args: argparse.Namespace) -> int:
    from ..certificate.certify import certify

    cert = certify(args.run, n=args.n, seed=args.seed, epsilon=args.epsilon, settle=args.settle)
    print(cert.table())
    print(f"wrote {Path(args.run) / 'certificate.json'}")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    print(report(args.run, n_roa=args.n, T=args.T, rho_extra=args.rho, n_figure=args.n_figure, html=not args.no_html, seed=args.seed))
    return 0


def _cmd_robustness(args: argparse.Namespace) -> int:
    from ..evaluation.robustness import default_conditions, robustness_table

    sat = "auto" if args.saturation is None else args.saturation
    conds = default_conditions(mass=args.mass, saturation=sat, noise=args.noise)
    print(robustness_table(args.run, n=args.n, T=args.T, seed=args.seed, box=args.box, conditions=conds, rho=args.rho).table())
    print(f"wrote {Path(args.run) / 'robustness.json'}")
    return 0


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be ≥ 1, got {value}")
    return value


def add_eval_commands(subparsers) -> None:
    """Register ``simulate``, ``certify``, ``report`` and ``robustness`` on argparse sub-parsers."""
    p = subparsers.add_parser("simulate", help="closed loop from random states, Neural IDA-PBC next to LQR; metrics + figure into RUN")
    p.add_argument("run", metavar="RUN", help="run directory (made by `idapbc-pin train`)")
    p.add_argument("--n", type=_positive_int, default=100, help="initial states uniform in the box (default 100)")
    p.add_argument("--T", type=float, default=20.0, metavar="SECONDS", help="horizon (default 20)")
    p.add_argument("--dt", type=float, default=0.01, metavar="SECONDS", help="RK4 step (default 0.01)")
    p.add_argument("--x0", type=float, nargs="+", action="append", metavar="V",
                   help="initial state: n values (q then p) or nq positions at rest; repeat for several (overrides --n)")
    p.add_argument("--box", choices=["domain", "half"], default="domain", help="box of the random states (default: the training domain)")
    p.add_argument("--rho", type=float, metavar="R", help="extra damping ρ (R_d = L Lᵀ + ρS) for Neural IDA-PBC")
    p.add_argument("--mismatch", action="append", metavar="KIND=SCALE",
                   help="scale the judge plant: mass=1.2, length=0.9, damping=2 (repeatable or comma-separated)")
    p.add_argument("--saturation", type=float, metavar="U", help="actuator limit |u| ≤ U (N·m or N)")
    p.add_argument("--noise", type=float, default=0.0, metavar="SIGMA", help="Gaussian measurement noise σ on (q, v) (rad, m, rad/s, m/s)")
    p.add_argument("--seed", type=int, default=0, help="seed of the states and the noise (default 0)")
    p.set_defaults(func=_cmd_simulate)

    p = subparsers.add_parser("certify", help="the paper's conditions checked on dense samples (a sampled certificate); certificate.json")
    p.add_argument("run", metavar="RUN", help="run directory")
    p.add_argument("--n", type=_positive_int, default=20000, help="uniform samples of the domain (default 20000)")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--epsilon", type=float, help="level ε of E = H_ε (default: the run's estimate)")
    p.add_argument("--settle", type=int, default=4, help="simulated states near x* (and as many in the half box) for the settled equilibrium (0: skip)")
    p.set_defaults(func=_cmd_certify)

    p = subparsers.add_parser("report", help="ROA vs LQR, certificate, the paper's figure and a meshcat replay, into RUN")
    p.add_argument("run", metavar="RUN", help="run directory")
    p.add_argument("--n", type=_positive_int, default=200, help="ROA states per box (default 200)")
    p.add_argument("--T", type=float, default=20.0, metavar="SECONDS", help="horizon (default 20)")
    p.add_argument("--rho", type=float, metavar="R", help="ρ of the extra-damping row (default: the median damping along ∇H_d, at least 1)")
    p.add_argument("--n-figure", type=_positive_int, default=4, help="trajectories in the figure (default 4)")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--no-html", action="store_true", help="skip the meshcat replay")
    p.set_defaults(func=_cmd_report)

    p = subparsers.add_parser("robustness", help="success rates under mass mismatch, saturation and noise, Neural IDA-PBC vs LQR")
    p.add_argument("run", metavar="RUN", help="run directory")
    p.add_argument("--n", type=_positive_int, default=100, help="states (default 100)")
    p.add_argument("--T", type=float, default=20.0, metavar="SECONDS", help="horizon (default 20)")
    p.add_argument("--box", choices=["domain", "half"], default="half", help="box of the states (default half)")
    p.add_argument("--mass", type=float, nargs="+", default=[0.8, 1.2], metavar="S", help="link-mass scales (default 0.8 1.2)")
    p.add_argument("--saturation", type=float, metavar="U", help="actuator limit (default 2 × LQR's median nominal peak |u|)")
    p.add_argument("--noise", type=float, default=0.01, metavar="SIGMA", help="measurement noise σ (default 0.01)")
    p.add_argument("--rho", type=float, metavar="R", help="extra damping ρ for Neural IDA-PBC")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.set_defaults(func=_cmd_robustness)

"""The paper's figure for a run, and the report that gathers everything about a run.

`figure` draws, for a few initial states (uniform in the half-size training box, seeded), the
panels of the paper's Fig. 1 (§V "Results", see `idapbc_pin.reporting.plot`) in one row for the
trained controller and one for the "extra damping" variant (ρ raised after training, paper
Fig. ii; `extra_damping_rho` picks ρ).

`report` runs the ROA evaluation against LQR (`evaluate_run`, with both ROA radii), `certify`,
`figure` and writes a meshcat replay (``replay.html``) of the figure's trajectories. The actuators'
effort limits apply throughout unless ``limits=False``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._io import atomic_write_bytes
from ..certificate.certify import certify, resolve_controller
from ..errors import IdapbcError
from ..evaluation.evaluate import evaluate_run, format_evaluation
from ..run import resolve_run
from ..sim.states import initial_states, uniform_states
from ..viewer import view
from .figure_data import FigureData, figure_data
from .plot import plot, save_png
from .slice import basin_slice

__all__ = ["DEFAULT_EXTRA_RHO", "extra_damping_rho", "figure", "report"]

#: Smallest ρ of the "extra damping" row when none is given (see `extra_damping_rho`).
DEFAULT_EXTRA_RHO = 1.0


def extra_damping_rho(ctrl, n: int = 2000, seed: int = 0) -> float:
    """Default ρ of the "extra damping" row: the damping the energy gradient already sees.

    ρ = max(`DEFAULT_EXTRA_RHO`, median over half-box samples of ∇H_dᵀR_d∇H_d / ‖∇H_d‖²), to two
    significant digits, plus the controller's current ρ. R_d has no fixed scale (an anchored
    run's R_d = −sym(A_cl P⁻¹) can reach 10⁴ when P is scaled to λ_max = 1), so a fixed ρ = 1 may
    change nothing; this roughly doubles the damping along ∇H_d whatever the scale.
    """
    x = uniform_states(ctrl.system, n, "half", seed)
    dH = np.asarray(ctrl.grad_H_d(x), float)
    R = np.asarray(ctrl.R_d(x), float)
    norm2 = (dH * dH).sum(axis=1)
    ok = norm2 > 0
    rayleigh = np.einsum("ni,nij,nj->n", dH[ok], R[ok], dH[ok]) / norm2[ok]
    typical = float(np.median(rayleigh)) if rayleigh.size else 0.0
    base = max(DEFAULT_EXTRA_RHO, float(f"{typical:.2g}"))
    return base + float(getattr(ctrl, "rho", 0.0))


def _figure_rows(ctrl, epsilon: float, x0, n, T, dt, seed, rho_extra, extra: bool, limits: bool = True) -> list[FigureData]:
    """The trained row and, when `extra` and the controller has ``with_damping``, the extra-damping row."""
    system = ctrl.system
    x0 = initial_states(system, x0, n, seed)
    rows = [figure_data(ctrl, x0, T=T, dt=dt, seed=seed, epsilon=epsilon, limits=limits)]
    if extra and hasattr(ctrl, "with_damping"):
        rho = float(rho_extra) if rho_extra is not None else extra_damping_rho(ctrl)
        label = f"{system.name}, extra damping ρ = {rho:g}"
        rows.append(figure_data(ctrl, x0, T=T, dt=dt, seed=seed, rho=rho, epsilon=epsilon, label=label, limits=limits))
    return rows


def figure(
    run,
    x0=None,
    n: int = 4,
    T: float = 20.0,
    rho_extra: float | None = None,
    path=None,
    *,
    dt: float | None = None,
    seed: int = 0,
    extra: bool = True,
    limits: bool = True,
    certificate: dict | None = None,
    slice_n: int = 13,
) -> Path:
    """The paper's figure for a run: a PNG with rows (trained ρ, extra damping) × panels a)–e), and
    given a certificate, a row with the slice through x* of the basin and the certified sets.

    Parameters
    ----------
    run : a `Run`, a run directory, or a controller (then `path` is required).
    x0 : (N, n) initial states, or (N, nq) positions at rest; default `n` uniform states of the
        half-size box (seed `seed`).
    T, dt : horizon and RK4 step, s.
    rho_extra : ρ of the extra-damping row (default `extra_damping_rho`: at least
        `DEFAULT_EXTRA_RHO`, scaled to R_d); ``extra=False`` leaves the row out.
    path : where to write (default ``<run>/figure.png``); written atomically.
    limits : clip the input to the effort limits (the default); False lifts them.
    certificate : ``Certificate.to_dict()`` (``certificate.json``): draws panel f), the slice over
        (q₀, q₁) of the basin (`slice_n`² rollouts of T s) and of the certified sets (`basin_slice`).

    Returns
    -------
    The PNG's path.
    """
    ctrl, _, eps, run_dir = resolve_controller(run)
    if path is None:
        if run_dir is None:
            raise IdapbcError("figure of a bare controller needs path=... . Fix: pass path or a Run.")
        path = run_dir / "figure.png"
    rows = _figure_rows(ctrl, eps, x0, n, T, dt, seed, rho_extra, extra, limits)
    slice_data = basin_slice(ctrl, certificate, slice_n, T, limits) if certificate is not None and ctrl.system.nq >= 2 else None
    return save_png(plot(rows, slice_data), Path(path))


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
    limits: bool = True,
    radius: bool = True,
    workers: int = 1,
) -> str:
    """Everything about a run, in its directory; returns a short text summary.

    Runs `evaluate_run` (ROA of Neural IDA-PBC vs LQR on the domain and the half box,
    ``evaluation.json``), `certify` (``certificate.json``), the figure (``figure.png``) and a
    meshcat replay of up to 3 rollouts that reach x* (``replay.html``, `view` with
    ``pick="success"``; for a run with a swing-up law, 3 swing-ups from near hanging, ``pick="hanging"``,
    its swing-up evaluation, ``swingup.json``, and a last row of figure.png with the swing-up from
    hanging: q(t), u(t) and H(t)); the summary is also
    written to ``report.txt``. The ROA radii (`n_roa` states per scale) are part of the evaluation
    unless ``radius=False``; ``limits=False`` lifts the effort limits in the evaluation, the
    certificate and the figure (the replay keeps `view`'s default). `workers`: processes simulating
    the two controllers of the evaluation side by side (1: in this process).
    """
    run = resolve_run(run)
    evaluation = evaluate_run(run, n=n_roa, T=T, seed=seed, limits=limits, radius=radius, workers=workers)
    cert = certify(run, n=n_certify, seed=seed, settle_T=T, limits=limits, workers=workers)
    ctrl, _, eps, _ = resolve_controller(run)
    rows = _figure_rows(ctrl, eps, None, n_figure, T, None, seed, rho_extra, True, limits)
    slice_data = basin_slice(ctrl, cert.to_dict(), T=T, limits=limits) if ctrl.system.nq >= 2 else None
    swing, panels = None, None
    if run.uses_swing_up and limits:  # a swing-up run: from near hanging too, a row of figure.png
        from ..evaluation.swingup import evaluate_run_swingup
        from .swingup_figure import TITLE, draw_swingup

        swing = evaluate_run_swingup(run, seed=seed, workers=workers)
        panels = (TITLE.format(run.system.name), lambda axes: draw_swingup(axes, run, swing))
    fig_path = save_png(plot(rows, slice_data, swing=panels), run.path / "figure.png")
    parts = [format_evaluation(evaluation), cert.table(), f"figure: {fig_path}"]
    if swing is not None:
        parts.append(f"swing-up from 20 near-resting states (figure.png's last row):\n{swing.table()}")
    if html:
        viewer = view(run, n=3, T=10.0, seed=seed, pick="hanging" if run.uses_swing_up else "success", open_server=False, limits=limits)
        parts.append(f"replay: {viewer.write_html(run.path / 'replay.html')} ({viewer.note})")
    text = "\n\n".join(parts)
    atomic_write_bytes(run.path / "report.txt", (text + "\n").encode())
    return text

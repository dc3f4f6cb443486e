"""Drawing the paper's figure (§V "Results", Fig. 1) from `FigureData` rows, five panels a row:

    a) q(t)   b) p(t)   c) ∇H_dᵀR_d∇H_d − ∇H_dᵀξ (eq. damping_assign_relax_tilde), log scale,
    clamped at 1e-6, violations (≤ 0) marked, bars where the state has left the training box X
    d) u(t)   e) H_d(t) with E = H_ε shaded and the entry time t_E of each trajectory dotted (also in c)

and, given a `SliceData`, a last row: f) the slice through x* over (q₀, q₁) of the basin (grid
states that reach x*) with the certified sets {H_d < c} and {δᵀSδ < c_LQR}, the training box and
the verification box.

Colours are the rollouts, line styles the components. No pyplot: nothing is shown.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from .._io import atomic_write_bytes
from ..certificate.result import share_text
from ..errors import IdapbcError
from .figure_data import FigureData
from .slice import SliceData

__all__ = ["MARGIN_FLOOR", "plot", "save_png"]

#: Panel c) is clamped at this value (paper §V: "clamped once reaching a threshold of 1e-6").
MARGIN_FLOOR = 1e-6

_STYLES = ("-", "--", ":", "-.")


def _style_legend(ax, styles: Sequence[str], labels: Sequence[str]) -> None:
    """Legend of the line styles (one per coordinate or input; colours are the rollouts)."""
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color="0.3", ls=styles[i % len(styles)]) for i in range(len(labels))]
    ax.legend(handles, labels, fontsize=8, loc="upper right")


def _unit_label(symbol: str, units: Sequence[str]) -> str:
    uniq = list(dict.fromkeys(units))
    return f"{symbol} [{' | '.join(uniq)}]"


def _draw_rollout(axes, d: FigureData, k: int, color) -> None:
    """Rollout k of row `d` on the five axes: its lines (gids ``panel:k:component``), violations,
    out-of-box bars, where a diverged record stops, and t_E."""
    ax_q, ax_p, ax_c, ax_u, ax_h = axes
    t, styles = d.traj.t, _STYLES
    ok = d.valid[k]

    def cut(y):
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


def _energy_panel(ax_h, d: FigureData) -> None:
    """e) H_d on a log scale with E = H_ε shaded."""
    from matplotlib.lines import Line2D

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


def _label_row(axes, d: FigureData) -> None:
    """Titles, units, legends and grids of one row's five panels."""
    from matplotlib.lines import Line2D

    ax_q, ax_p, ax_c, ax_u, ax_h = axes
    styles = _STYLES
    ax_q.set_title("a) positions q(t)", fontsize=10, loc="left")
    ax_q.set_ylabel(_unit_label("q", d.q_units))
    _style_legend(ax_q, styles, [f"{nm} [{u}]" for nm, u in zip(d.coordinate_names, d.q_units)])
    ax_p.set_title("b) momenta p(t)", fontsize=10, loc="left")
    ax_p.set_ylabel(_unit_label("p", d.p_units))
    _style_legend(ax_p, styles, [f"p_{nm} [{u}]" for nm, u in zip(d.coordinate_names, d.p_units)])
    ax_c.set_yscale("log")
    ax_c.set_title("c) ∇H_dᵀR_d∇H_d − ∇H_dᵀξ (> 0: dissipation holds)", fontsize=10, loc="left")
    ax_c.set_ylabel(f"margin [H_d units / s], clamped at {MARGIN_FLOOR:g}")
    handles = [Line2D([], [], color="0.3", ls=":", label="t_E (enters E)")]
    if np.any(d.margin <= 0):
        handles.append(Line2D([], [], color="crimson", ls="none", marker="x", label="margin ≤ 0 (violated)"))
    if not d.in_domain.all():
        handles.append(Line2D([], [], color="0.3", lw=3, label="bars: state outside the training box X"))
    ax_c.legend(handles=handles, fontsize=8, loc="upper right", bbox_to_anchor=(1.0, 0.88))
    ax_u.set_title("d) input u(t)", fontsize=10, loc="left")
    ax_u.set_ylabel(_unit_label("u", d.u_units))
    _style_legend(ax_u, styles, [f"u_{nm} [{u}]" for nm, u in zip(d.input_names, d.u_units)])
    _energy_panel(ax_h, d)
    t = d.traj.t
    for ax in axes:
        ax.set_xlabel("t [s]")
        ax.grid(True, alpha=0.3)
        ax.set_xlim(t[0], t[-1])


def _rollout_legend(fig, rows: Sequence[FigureData], colors) -> None:
    """The figure's legend: one entry per rollout (its x0, "diverged" if it did in any row)."""
    from matplotlib.lines import Line2D

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


def _slice_panel(ax, s: SliceData) -> None:
    """f) the basin slice (gid ``basin``) with the certified sets' contours (gids ``certified:NIDA-PBC``,
    ``certified:LQR``) and both boxes."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Rectangle

    ax.pcolormesh(s.basin_a, s.basin_b, s.basin.astype(float), cmap="Greens", vmin=-0.3, vmax=1.6, shading="nearest", gid="basin")
    handles = [Patch(color="#74c476", label="reaches x* (NIDA-PBC, limits applied)")]
    for level, field, style, name in ((s.c, s.H, "-", "NIDA-PBC"), (s.c_lqr, s.V_lqr, "--", "LQR")):
        if level is not None and np.nanmin(field) < level:
            ax.contour(s.a, s.b, field, levels=[level], colors="k", linestyles=style, linewidths=1.6).set_gid(f"certified:{name}")
            cert, inv = s.shares.get(name, (None, None))
            handles.append(Line2D([], [], color="k", ls=style, label=f"certified {name}: {share_text(cert, 2)} of the box (invariant {share_text(inv, 2)})"))
    for (lo, hi), color, label in ((s.train_box, "tab:blue", "training box"), (s.verification_box, "tab:red", "verification box")):
        ax.add_patch(Rectangle(lo, hi[0] - lo[0], hi[1] - lo[1], fill=False, ec=color, lw=1.4))
        handles.append(Line2D([], [], color=color, label=label))
    ax.set_title("f) slice through x*: basin and certified sets", fontsize=10, loc="left")
    ax.set_xlabel(s.names[0])
    ax.set_ylabel(s.names[1])
    ax.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0))


def plot(rows: Sequence[FigureData], slice_data: SliceData | None = None, swing=None):
    """Draw rows of the figure (5 panels each), given `slice_data` the slice row, and given `swing`
    a last row of 3 panels (``swing = (title, draw)``: ``draw(axes)`` fills them, e.g. the swing-up
    panels of `reporting.swingup_figure.draw_swingup`); returns the matplotlib `Figure` (Agg, not shown).

    Every data line carries a gid ``"<panel>:<trajectory>:<component>"`` with panel in
    ``q, p, margin, u, H``; panel c) shows max(margin, 1e-6).
    """
    import matplotlib
    from matplotlib.figure import Figure  # no pyplot: no global backend, nothing shown

    rows = list(rows)
    if not rows:
        raise IdapbcError("nothing to plot. Fix: pass at least one FigureData row.")
    extra = (slice_data is not None) + (swing is not None)
    fig = Figure(figsize=(22, 4.5 * (len(rows) + extra) + 0.6), layout="constrained")
    subfigs = np.atleast_1d(fig.subfigures(len(rows) + extra, 1))
    swing_fig = None
    if swing is not None:
        swing_fig, subfigs = subfigs[-1], subfigs[:-1]
    if slice_data is not None:
        ax_slice = subfigs[-1].subplots(1, 3, width_ratios=[1.2, 1.3, 2.5])
        ax_slice[1].axis("off")
        ax_slice[2].axis("off")
        _slice_panel(ax_slice[0], slice_data)
        subfigs = subfigs[:-1]
    axes = np.stack([sf.subplots(1, 5) for sf in subfigs])
    for sf, d in zip(subfigs, rows):
        sf.suptitle(d.label, x=0.005, ha="left", fontsize=11, fontweight="bold")
    colors = matplotlib.colormaps["tab10"].colors
    for r, d in enumerate(rows):
        for k in range(d.traj.x.shape[0]):
            _draw_rollout(axes[r], d, k, colors[k % len(colors)])
        _label_row(axes[r], d)
    _rollout_legend(fig, rows, colors)
    if swing_fig is not None:
        title, draw = swing
        swing_fig.suptitle(title, x=0.005, ha="left", fontsize=11, fontweight="bold")
        draw(swing_fig.subplots(1, 3))
    return fig


def save_png(fig, path: Path, dpi: int = 100) -> Path:
    """Write a matplotlib figure as a PNG, atomically; returns the path."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return atomic_write_bytes(path, buf.getvalue())

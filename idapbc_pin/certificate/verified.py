"""A verified certified set: interval bounds with box splitting prove that V decreases on {V < c}
outside the core, where the loop has an interval form (`idapbc_pin.certificate.enclosures`).

For a level c (below the sampled set's, `idapbc_pin.certificate.region`) and the core level c₀:

1. **Faces.** V ≥ c on every face of the verification box V_box (where the cover below reaches it):
   the connected part of {V < c} that holds x* then lies inside V_box.
2. **Inside.** Every box of a cover of the set (V_box, cut to the bounding box of {δᵀQδ < c} where
   V ≥ δᵀQδ) is, by its enclosures, either outside the set (V ≥ c on it), inside the core (V < c₀
   on it), or a box on which V̇ < 0. A box that is none of these is halved along its widest side
   (in V_box's units) and tried again.

V is bounded on a box B by the mean-value form V(m) + ∇V(B)·(B − m) (m its centre), intersected with
its direct enclosure, and from below by its tangent plane at m where that plane bounds V (V convex,
`enclosures.FlowEnclosure.value_and_grad`); V̇ by its direct enclosure, met, for a URDF loop, with
its mean-value form V̇(m) + ∇V̇(X)·(X − m) from jets (`jet.Jet`; a quadratic V's rate does its own
split, `enclosures.quadratic_rate`). When every box is decided,
the set is **verified**:
along the exact loop (the deployed law in exact arithmetic on its weights, the closed-form plant,
the effort limits), V decreases on {c₀ ≤ V < c}, so a trajectory starting in the set stays in it and
enters the core. The core's own decrease rests on the linearisation (`region.linear_core`), as in
the sampled certificate. Rounding is bounded as `idapbc_pin.certificate.interval` states.

Boxes whose centre is a point of the set outside the core with V̇ ≥ 0 end the attempt (the level
is too high); so does the box budget.
"""

from __future__ import annotations

import time

import numpy as np

from ..control.baseline import LQRController
from ..errors import IdapbcError
from .baseline import QuadraticLyapunov
from .enclosures import FlowEnclosure, enclosable, flow_rate, lqr_rate
from .interval import Interval
from .jet import Jet
from .region import covered_share
from .result import Verified
from .vbox import sample_set, set_frame

__all__ = ["MODES", "check_mode", "not_verified", "verify_level", "verified_set", "verify_sets"]

#: Levels tried, as fractions of the sampled set's level, until one is verified; each may use an
#: equal share of what is left of the box budget.
LEVELS = (0.999, 0.99, 0.9, 0.5)
#: The box budget of each law's sets beyond 2 states (`verify_sets`): a few minutes on 2 cores.
WIDE_BUDGET = 40_000
_OVER = "over the box budget"


def _bounds(rate, X: Interval, floor, first_order: bool = False):
    """(V's lower and upper bounds, V̇'s upper bound, V̇'s lower bound at the centre, V at the centre)
    per box; ``floor`` = (x*, Q) with V ≥ δᵀQδ adds that quadratic's lower bound. ``first_order``:
    V̇ is also bounded by its mean-value form V̇(m) + ∇V̇(X)·(X − m), from the jets of the loop
    (`jet.Jet`), and the tighter of both bounds is kept."""
    with np.errstate(over="ignore", invalid="ignore"):  # an enclosure past float range is unbounded, or NaN: undecided
        return _bounds_of(rate, X, floor, first_order)


def _bounds_of(rate, X: Interval, floor, first_order: bool):
    m = X.mid
    N = X.shape[0]
    both = Interval.concat([X, Interval.point(m)], axis=0)
    if first_order:
        V, grad, Vd_jet, tangent = rate(Jet.variables(both))
        V, grad, Vd = V.val, grad.val, Vd_jet.val
    else:
        V, grad, Vd, tangent = rate(both)
    Vb, Gb, Vdb, Vm, Gm = V[:N], grad[:N], Vd[:N], V[N:], grad[N:]
    mv = (Gb * (X - m)).sum(-1) + Vm  # mean-value form
    lo, hi = np.maximum(Vb.lo, mv.lo), np.minimum(Vb.hi, mv.hi)
    plane = (Gm * (X - m)).sum(-1) + Vm  # V ≥ its tangent plane at m, where that holds (`rate`'s flag)
    lo = np.where(tangent[N:], np.maximum(lo, plane.lo), lo)
    if floor is not None:
        x_star, Q = floor
        dm, d = Interval.point(m) - x_star, X - x_star
        quad = ((d @ (2 * Q)) * (X - m)).sum(-1) + (dm @ Q * dm).sum(-1)  # its mean-value form
        lo = np.maximum(lo, np.maximum(quad.lo, (d @ Q * d).sum(-1).lo))
    vd_hi = Vdb.hi
    if first_order:
        slope = Vd_jet.grad[:N]
        vd_mv = (slope * (X - m)).sum(-1) + Vd[N:]
        vd_hi = np.minimum(vd_hi, vd_mv.hi)
    # NaN (an enclosure past float range) proves nothing
    nan = np.isnan
    return (np.where(nan(lo), -np.inf, lo), np.where(nan(hi), np.inf, hi), np.where(nan(vd_hi), np.inf, vd_hi),
            np.where(nan(Vd[N:].lo), -np.inf, Vd[N:].lo), np.where(nan(Vm.hi), np.inf, Vm.hi))


def _split(X: Interval, scale: np.ndarray, axes: np.ndarray | None = None) -> Interval:
    """Each box halved along its widest side in `scale` units (among `axes` if given)."""
    w = (X.hi - X.lo) / scale
    if axes is not None:
        w = np.where(axes[None], w, -1.0)
    k = np.argmax(w, axis=1)
    rows = np.arange(X.shape[0])
    mid = X.mid[rows, k]
    lo2, hi1 = X.lo.copy(), X.hi.copy()
    hi1[rows, k], lo2[rows, k] = mid, mid
    return Interval.concat([Interval(X.lo, hi1), Interval(lo2, X.hi)], axis=0)


def _grid(lo: np.ndarray, hi: np.ndarray, k: int, fixed: int | None = None, at: float | None = None) -> Interval:
    """k per side boxes tiling [lo, hi] (a face when `fixed` names a coordinate held at `at`)."""
    n = lo.size
    edges = [np.linspace(lo[i], hi[i], k + 1) if i != fixed else np.array([at, at]) for i in range(n)]
    idx = np.stack(np.meshgrid(*[np.arange(len(e) - 1) for e in edges], indexing="ij"), -1).reshape(-1, n)
    blo = np.stack([edges[i][idx[:, i]] for i in range(n)], 1)
    bhi = np.stack([edges[i][idx[:, i] + 1] for i in range(n)], 1)
    if fixed is not None:
        bhi[:, fixed] = at
    return Interval(blo, bhi)


def _run(rate, X: Interval, decide, floor, scale, budget: int, batch: int, axes=None) -> tuple[str | None, int]:
    """Split the boxes until `decide` settles each one. -> (None, boxes evaluated) or (why not, boxes)."""
    queue, count = [X], 0
    while queue:
        B = queue.pop()
        if B.shape[0] > batch:
            queue += [B[i : i + batch] for i in range(0, B.shape[0], batch)]
            continue
        count += B.shape[0]
        if count > budget:
            return _OVER, count
        undecided, fail = decide(*_bounds(rate, B, floor, getattr(rate, "first_order", False)))
        if fail:
            return fail, count
        if undecided.any():
            queue.append(_split(B[undecided], scale, axes))
    return None, count


def _cover(vbox, c: float, floor) -> tuple[np.ndarray, np.ndarray]:
    """A box that holds {V < c} ∩ V_box: V_box cut to the bounding box of {δᵀQδ < c} when V ≥ δᵀQδ."""
    lo, hi = (np.asarray(b, np.float64) for b in vbox)
    if floor is None:
        return lo, hi
    x_star, Q = floor
    half = np.sqrt(c * np.diag(np.linalg.inv(Q))) * (1 + 1e-6)  # max of δ_i on the ellipsoid, widened
    return np.maximum(lo, x_star - half), np.minimum(hi, x_star + half)


def verify_level(rate, c: float, core: float, vbox, floor=None, *, budget: int = 500_000, batch: int = 16384, grid: int = 8):
    """Steps 1–2 of the module doc at level c.

    rate : boxes (N, n) -> (V, ∇V, V̇) enclosures and, for point boxes, whether V's tangent plane
        there bounds V from below ((N,) bool) (`enclosures.flow_rate` or `lqr_rate`, bound to their loop).
    floor : (x*, Q) with V(x) ≥ (x − x*)ᵀQ(x − x*) everywhere, or None; it confines the cover.
    -> (None, or why the level is not verified; boxes evaluated).
    """
    vlo, vhi = (np.asarray(b, np.float64) for b in vbox)
    lo, hi = _cover(vbox, c, floor)
    scale, n = vhi - vlo, lo.size
    total = 0

    def face(V_lo, V_hi, Vd_hi, Vd_mid_lo, V_mid):
        reaches = V_mid < c
        return ~(V_lo >= c), ("the set reaches a face of the verification box" if reaches.any() else None)

    for i in range(n):
        for at in (vlo[i], vhi[i]):
            if not lo[i] <= at <= hi[i]:
                continue  # the cover stops short of this face
            why, k = _run(rate, _grid(lo, hi, grid, i, at), face, floor, scale, budget - total, batch, np.arange(n) != i)
            total += k
            if why:
                return (f"more than {budget} boxes" if why == _OVER else why), total

    def inside(V_lo, V_hi, Vd_hi, Vd_mid_lo, V_mid):
        undecided = ~((V_lo >= c) | (V_hi < core) | (Vd_hi < 0))
        bad = undecided & (V_mid < c) & (V_mid >= core) & (Vd_mid_lo >= 0)
        return undecided, ("a state of the set outside the core where V̇ ≥ 0" if bad.any() else None)

    why, k = _run(rate, _grid(lo, hi, grid), inside, floor, np.maximum(hi - lo, 1e-12 * scale), budget - total, batch)  # split in the cover's units
    return (f"more than {budget} boxes" if why == _OVER else why), total + k


def verified_set(rate, c: float, core: float, vbox, share, floor=None, *, budget: int = 500_000, levels=LEVELS) -> Verified:
    """The highest of ``levels``·c verified (`verify_level`), within `budget` boxes in all (each level
    an equal share of what is left).

    share : callable level -> share of the training box X inside {V < level} (sampled).
    """
    t0 = time.perf_counter()
    used, reasons = 0, []
    for k_level, frac in enumerate(levels):
        level = frac * c
        if not level > core:
            break
        why, k = verify_level(rate, level, core, vbox, floor, budget=(budget - used) // (len(levels) - k_level))
        used += k
        if why is None:
            return Verified(passed=True, c=level, boxes=used, covered_fraction=share(level), reason="", seconds=time.perf_counter() - t0)
        reasons.append(f"{frac:g}·c: {why}")
    return not_verified("; ".join(reasons) or "no set beyond the core", used, time.perf_counter() - t0)


def not_verified(reason: str, boxes: int = 0, seconds: float = 0.0) -> Verified:
    """A `Verified` that did not pass, with why."""
    return Verified(passed=False, c=0.0, boxes=boxes, covered_fraction=0.0, reason=reason, seconds=seconds)


MODES = ("auto", "always", "never")


def check_mode(mode: str) -> None:
    """Refuse a `verify` mode other than `MODES`, in one line that names the fix."""
    if mode not in MODES:
        raise IdapbcError(f"verify must be 'auto', 'always' or 'never', got {mode!r}. Fix: pass one of those.")


def _share(fn, x_star, vbox, tbox, rng, n: int = 20000):
    """level -> sampled share of X inside {V < level} (`region.covered_share`)."""

    def share(level: float) -> float:
        frame = set_frame(fn, level, x_star, *vbox, rng)
        x, draws = sample_set(fn, level, frame, n, rng)
        return covered_share(fn, level, frame, x, draws, tbox, rng)

    return share


def _why_not(system, ctrl, vbox, mode: str) -> str | None:
    """Why the loop is not verified here (None: it is tried)."""
    if mode == "never":
        return "not asked for"
    why = enclosable(system, getattr(ctrl, "fallback", None)) if ctrl is not None else enclosable(system)
    if why is None and getattr(ctrl, "guard", None) is not None:
        why = "no interval form of the rail guard"
    if why is None and ctrl is not None and not hasattr(ctrl, "flow"):
        why = f"no interval form of {type(ctrl).__name__} (a run's Controller has one)"
    if why is None:
        angles, x_star = np.asarray(system.angle_mask, bool), np.asarray(system.x_star, np.float64)
        if np.any((vbox[0][angles] < x_star[angles] - np.pi) | (vbox[1][angles] > x_star[angles] + np.pi)):
            why = "the verification box holds angles more than a turn apart (the law wraps them)"
    if why is None and mode == "auto" and system.n > 2:
        why = f"not tried for {system.n} states by default: the boxes needed grow fast beyond 2 (verify='always' tries, within the box budget)"
    return why


def verify_sets(ctrl, system, region, base_region, vbox, tbox, bound, rng, mode: str = "auto", budget: int = 500_000):
    """`Verified` for the run's certified set of H_d and for LQR's (None without a baseline).

    mode : "auto" (where the loop has an interval form and n ≤ 2), "always" (any n, within `budget`
    boxes each, at most `WIDE_BUDGET` beyond 2 states), "never".
    """
    x_star = np.asarray(system.x_star, np.float64)
    budget = budget if system.n <= 2 else min(budget, WIDE_BUDGET)
    out = []
    for name, reg in (("NIDA-PBC", region), ("LQR", base_region)):
        if reg is None:
            out.append(None)
            continue
        why = _why_not(system, ctrl if name == "NIDA-PBC" else None, vbox, mode)
        if why is None and not reg.certified:
            why = "no sampled set beyond the core to verify"
        if why is not None:
            out.append(not_verified(why))
            continue
        if name == "NIDA-PBC":
            flow = ctrl.flow()
            enc, g_pinv, fallback = FlowEnclosure(flow), ctrl._g_pinv, getattr(ctrl, "fallback", None)
            governor = getattr(ctrl, "governor", None)
            rate = lambda X: flow_rate(system, enc, g_pinv, bound, fallback, X, governor)  # noqa: E731
            floor = None if flow.P is None else (x_star, 0.5 * np.asarray(flow.P, np.float64))
            fn = ctrl
        else:
            lqr = LQRController(system)
            rate = lambda X: lqr_rate(system, lqr, lqr.S, bound, X)  # noqa: E731
            floor, fn = (x_star, np.asarray(lqr.S, np.float64)), QuadraticLyapunov(lqr.S, x_star, system.angle_mask)
        rate.first_order = name == "NIDA-PBC" and hasattr(system.plant, "chain")  # a URDF plant: mean-value forms of Ḣ_d (jets)
        out.append(verified_set(rate, reg.c, reg.core, vbox, _share(fn, x_star, vbox, tbox, rng), floor, budget=budget))
    return tuple(out)

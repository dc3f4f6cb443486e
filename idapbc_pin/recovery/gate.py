"""The gate of `recover`: keep a recovery law only where simulation shows it helps, and the files
that hold the law it judged.

The run's law as it is, and the law with the recovery law outside an inner box of each scale in
`RecoveryConfig.inner_scales`, run from the gate's states (half from the half box, half from the
training box, then `near_states` from the near box of scale `NEAR_SCALE`). `gate_choice` applies the
rule on the success counts; where the run's law brings every half-box gate state to x*, a law the
rule keeps is checked again on half-box states of their own (`_Confirmation`). When it keeps no inner box, the same rule judges the law acting only
where H_d(x) > c as well, for the levels c of `energy_levels` (`RecoveryLaw.level`), each level
from the near box first, and from the others only where it can still be eligible. A kept law is
written as ``recovery.npz`` and applied by every command on the run; a refused one as
``recovery-refused.npz``, never applied, so that `regate` (``idapbc-pin recover RUN --regate``)
judges it again with another rule, or keeps it, without fitting it again. The labels the law was
fitted to are kept as ``recovery-labels.npz`` (`save_labels`, `read_labels`), so that `refit`
(``idapbc-pin recover RUN --refit``) fits another law to them without the plans.
"""

from __future__ import annotations

import io
import math
import sys
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from .._io import DamagedFileError, atomic_write_bytes, read_npz, write_json
from ..run import RECOVERY_FILE, RECOVERY_LABELS_FILE, RECOVERY_REFUSED_FILE
from ..sim.compare import compare_laws
from ..sim.states import box_gate_states, scaled_box, uniform_states
from .config import RecoveryConfig
from .law import RecoveryLaw
from ..trajectory.plans import PLAN_STEP

__all__ = ["GATE_HORIZON", "LEVEL_STATES", "NEAR_SCALE", "RECOVERY_GATE_SEED", "choose_fit", "choose_inner", "energy_levels", "format_gate", "gate_choice", "library_first", "lost", "read_labels", "save_labels", "save_recovery", "write_law"]

#: Seed offset of the gate's states (neither the plans', the DAgger rounds', nor an evaluation's).
RECOVERY_GATE_SEED = 7_368_787
#: Scale of the gate's near box around x* (x* + NEAR_SCALE·(box − x*)), where the run's law must keep its successes.
NEAR_SCALE = 0.25
#: Half-box states whose H_d quantiles give the level candidates (`energy_levels`).
LEVEL_STATES = 2000
#: Horizon of the gate's simulations, s (DESIGN §4).
GATE_HORIZON = 20.0


def gate_choice(run: tuple[int, int, int], candidates: dict, margin: int, half_loss: int = 0, half_states: int | None = None) -> tuple[float | None, bool]:
    """The gate's rule on success counts (half box, training box, near box): `run` for the run's
    law, `candidates` {r: (half, domain, near)} for the law with the recovery law outside the inner
    box r. A candidate is eligible when it brings no fewer of the half-box states, and no fewer of
    the near-box states, to x* than the run's law, less `half_loss` each (the recovery law must not
    shrink the basin the IDA-PBC law already has); where the run's law brings all `half_states`
    half-box states to x*, a candidate must too (a basin the IDA-PBC law holds entirely: on the
    paper cartpole 2 forgiven of 50 became 9 lost of 200 in the evaluation). The eligible one with
    the most half-box and training-box successes wins (ties: the larger r, more IDA-PBC), and is
    kept when it adds at least `margin` of those. A candidate screened out near x*
    (`_screened_counts`: half and training box None) is never eligible. Returns (r or None, kept)."""
    half_floor = run[0] if half_states is not None and run[0] >= half_states else run[0] - half_loss
    eligible = [r for r, (h, _, near) in candidates.items() if near >= run[2] - half_loss and h is not None and h >= half_floor]
    if not eligible:
        return None, False
    best = _best(candidates, eligible)
    return best, _total(candidates[best]) >= _total(run) + margin


def _total(counts: tuple) -> int | None:
    """Half-box plus training-box successes: what the margin counts (the near box only guards);
    None for a candidate screened out near x* (`_screened_counts`)."""
    return None if counts[0] is None else counts[0] + counts[1]


def _best(candidates: dict, scales) -> float:
    """The r of `scales` with the most `_total` successes (ties: the larger r, more IDA-PBC); where
    none ran from the box states (every one screened out near x*), the most near-box successes."""
    ran = [r for r in scales if candidates[r][0] is not None]
    if ran:
        return max(ran, key=lambda r: (_total(candidates[r]), r))
    return max(scales, key=lambda r: (candidates[r][2], r))


def choose_inner(run, law: RecoveryLaw, config: RecoveryConfig, progress: bool = False) -> dict:
    """Simulate the run's law and the law with `law` outside each inner box of `config.inner_scales`
    from the gate's states (`gate_states`, half from the half box and half from the training box,
    then `near_states` from the box of scale NEAR_SCALE) and apply `gate_choice`; returns
    {"states", "run": successes, "candidates": {r: successes} (both on the first two parts),
    "run_half"/"candidates_half" and "run_near"/"candidates_near": the same on each guarded part,
    "inner_scale": the chosen r (the most successes when none is eligible), "with_recovery": its
    successes, "used"}."""
    return choose_fit(run, [law], config, progress)[1]


def choose_fit(run, laws: list, config: RecoveryConfig, progress: bool = False, known: dict | None = None) -> tuple[int, dict]:
    """`choose_inner` for each of several fitted `laws` on the same gate states (the run's law
    simulated once, every law in `config.workers` processes or Ray tasks, `config.ray`; each level
    of H_d from the near-box states first, and from the others only where it can still be eligible,
    `_screened_counts`; `progress` prints each): returns (k, gate of laws[k]), k the law the gate keeps with the most successes
    (ties: the first), or when it keeps none the one with the most successes at its best candidate
    (the law ``recovery-refused.npz`` then holds, so that `regate` judges the most promising fit). With more than one law the gate also holds
    "fits": each law's successes at its own chosen r, "fit": k, and "fit_gates": every law's own gate
    (its candidates, and its check where one ran; summary.json keeps them). When no inner box is kept, the
    same rule judges each law with the IDA-PBC law keeping the sublevel sets {H_d ≤ c} instead, c
    from `config.levels` (`energy_levels`); a law kept that way has "level": c in its gate. Where
    the run's law brings every half-box gate state to x*, each law the rule keeps (at its box, then
    at its level) must pass `_Confirmation` too. `known`, a dict shared by the gates of one stage,
    keeps the run's law's counts (its verdicts do not depend on the laws judged beside it), so that a
    second gate on the same states does not simulate it again."""
    system, seed = run.system, RECOVERY_GATE_SEED + run.config.seed
    half, n = config.gate_states // 2, config.gate_states
    x0 = np.concatenate([box_gate_states(system, n, seed), uniform_states(system, config.near_states, scaled_box(system, NEAR_SCALE), seed + 2)])
    ctrl = run.own_controller  # without any recovery law the run already has
    scales = [float(r) for r in config.inner_scales]
    known = {} if known is None else known
    fresh = "run" not in known  # the run's law not yet simulated on these states
    rest = _counts(system, [ctrl] * fresh + [ctrl.with_fallback(law.with_inner(r)) for law in laws for r in scales], x0, half, n, config, progress)
    if fresh:
        known["run"], *rest = rest
    base = known["run"]
    gates = [_gate(base, dict(zip(scales, rest[i * len(scales) : (i + 1) * len(scales)])), n, config) for i in range(len(laws))]
    confirm = _Confirmation(system, ctrl, seed + 4, config, progress, known) if base[0] >= half and config.confirm_states else None
    if confirm:
        confirm(gates, lambda i: ctrl.with_fallback(laws[i].with_inner(gates[i]["inner_scale"])))
    if config.levels and not any(g["used"] for g in gates):
        levels = energy_levels(run, config.levels)
        counts = _screened_counts(system, [ctrl.with_fallback(law.with_inner(0.0).with_level(c)) for law in laws for c in levels], x0, half, n, base,
                                  config, progress)
        for i in range(len(laws)):
            by_level = _gate(base, dict(zip(levels, counts[i * len(levels) : (i + 1) * len(levels)])), n, config)
            gates[i] |= {"level_candidates": by_level["candidates"], "level_candidates_near": by_level["candidates_near"]}
            if by_level["used"]:
                gates[i] |= {k: by_level[k] for k in ("inner_scale", "with_recovery", "used")} | {"level": by_level["inner_scale"], "inner_scale": 0.0}
        if confirm:
            confirm(gates, lambda i: ctrl.with_fallback(laws[i].with_inner(0.0).with_level(gates[i]["level"])))
    kept = [k for k, g in enumerate(gates) if g["used"]]
    k = max(kept or range(len(gates)), key=lambda i: (_ranked(gates[i]), -i))  # none kept: the best refused (for --regate)
    if len(laws) > 1:
        gates[k] |= {"fits": [g["with_recovery"] for g in gates], "fit": k, "fit_gates": [dict(g) for g in gates]}
    return k, gates[k]


def library_first(run, library, paths: int, config, progress: bool = False, known: dict | None = None) -> tuple[str, dict]:
    """The reach stage's library of `paths` labelled paths judged alone (`choose_fit`, `known` passed
    on): ("kept", its gate) where the gate keeps it; ("lost", its gate) where at its best inner box
    or level it brings `config.margin` or more fewer gate states to x* than the run's law (`lost`:
    no laws are fitted to the same paths); else ("fit", its gate): the fits follow, and the library
    is judged again beside them. The gate has "library" and "library_points" set."""
    if progress:
        print(f"library: the {paths} labelled paths read at the nearest point ({library.points} points), judged first", flush=True)
    _, gate = choose_fit(run, [library], config, progress, known)
    gate = gate | {"library": True, "library_points": library.points}
    if gate["used"]:
        return "kept", gate
    verdict = "lost" if lost(gate, config.margin) else "fit"
    if progress and verdict == "lost":
        print(f"library alone: at best {_most(gate)} of {gate['states']} gate states to x*, the run's law {gate['run']}: "
              f"{config.margin} or more fewer, so no law is fitted to the same paths (always_fit fits them)", flush=True)
    elif progress:
        print(f"library alone: {format_gate(gate, config.margin, config.half_loss)}; fitting laws to judge beside it", flush=True)
    return verdict, gate


def _most(gate: dict) -> int | None:
    """The most gate states any candidate of a gate (inner box, or level run from the gate's states) brings to x*."""
    counts = [c for c in (*gate.get("candidates", {}).values(), *gate.get("level_candidates", {}).values()) if c is not None]
    return max(counts) if counts else None


def lost(gate: dict, margin: int) -> bool:
    """Whether a gate's candidates all fall `margin` or more short of the run's law: the most gate
    states any inner box or level brings to x* (those run from the gate's states) plus `margin` is
    at most the run's law's count. The gate keeps a law that leads by `margin`; a library this far
    behind is a sign the paths themselves mislead away from them, and the fits only imitate them."""
    best = _most(gate)
    return best is not None and best + int(margin) <= int(gate["run"])


class _Confirmation:
    """The gate's second look, where the run's law brings every half-box gate state to x* (a basin the
    IDA-PBC law holds entirely): the run's law and each law the rule keeps run from
    `RecoveryConfig.confirm_states` half-box states of their own (seed `seed`), and a kept law that
    brings more than `half_loss` fewer of them to x* than the run's law is refused. The rule picks
    among many candidates on 50 half-box states, so a law that loses a few per cent of the half box
    can pass it by chance; states the choice never saw judge it without that bias. Each confirmed gate gets "confirm": a
    list of {"states", "run", "law", and "inner_scale" r or "level" c}, successes of each candidate
    of that fit the check ran (an inner box, then a level where it refused every box)."""

    def __init__(self, system, ctrl, seed: int, config, progress: bool, known: dict):
        self.system, self.ctrl, self.config, self.progress, self.known = system, ctrl, config, progress, known
        self.x0 = uniform_states(system, config.confirm_states, "half", seed)

    def __call__(self, gates: list, law_of) -> None:
        """Confirm each gate of `gates` whose "used" is set, `law_of(i)` the controller gate i keeps."""
        idx = [i for i, g in enumerate(gates) if g["used"]]
        if not idx:
            return
        ctrls = ([] if "confirm" in self.known else [self.ctrl]) + [law_of(i) for i in idx]
        n = len(self.x0)
        counts = [c[0] for c in _counts(self.system, ctrls, self.x0, n, n, self.config, self.progress)]
        if "confirm" not in self.known:  # the run's law's successes, simulated once
            self.known["confirm"], *counts = counts
        run = self.known["confirm"]
        for i, got in zip(idx, counts):
            at = {"level": gates[i]["level"]} if gates[i].get("level") is not None else {"inner_scale": gates[i]["inner_scale"]}
            gates[i]["confirm"] = [*gates[i].get("confirm", []), {"states": n, "run": run, "law": got} | at]
            gates[i]["used"] = got >= run - self.config.half_loss


def _judged(system, runs: list, config, bar):
    """Success (N,) bool of each (law, x0) of `runs` over `GATE_HORIZON`, in order, the bar moved on as each comes in."""
    for ok, _ in compare_laws(system, runs, T=GATE_HORIZON, dt=PLAN_STEP, workers=config.workers, ray=config.ray):
        bar.update(1)
        yield ok


def _bar(total: int, states: int, progress: bool):
    """The gate's progress bar, one step per law simulated."""
    return tqdm(total=total, desc=f"recovery: gate ({states} states)", unit="law", disable=not progress, dynamic_ncols=True, file=sys.stderr)


def _counts(system, ctrls: list, x0: np.ndarray, half: int, n: int, config, progress: bool) -> list[tuple[int, int, int]]:
    """(half box, training box, near box) successes of each law of `ctrls` from the gate's states x0."""
    with _bar(len(ctrls), len(x0), progress) as bar:
        return [(int(ok[:half].sum()), int(ok[half:n].sum()), int(ok[n:].sum())) for ok in _judged(system, [(c, x0) for c in ctrls], config, bar)]


def _screened_counts(system, ctrls: list, x0: np.ndarray, half: int, n: int, base: tuple[int, int, int], config, progress: bool) -> list[tuple]:
    """`_counts` of `ctrls` beside the run's law's counts `base`, each law from the near-box states
    first, and from the others only where it brings at least the run's near-box successes less
    `half_loss` to x*: a law that loses more there is never eligible (`gate_choice`), whatever the
    rest, and gets (None, None, near). A failing rollout runs its whole horizon, so this spares the
    box states' rollouts of laws the rule refuses anyway, at the price of a second batch for those it
    does not: the gate screens the levels of H_d, which run only where every inner box was refused."""
    if not config.near_states:
        return _counts(system, ctrls, x0, half, n, config, progress)
    with _bar(len(ctrls), len(x0), progress) as bar:
        near = [int(ok.sum()) for ok in _judged(system, [(c, x0[n:]) for c in ctrls], config, bar)]
        go_on = [i for i, k in enumerate(near) if k >= base[2] - config.half_loss]
        bar.total += len(go_on)
        box = {i: (int(ok[:half].sum()), int(ok[half:].sum())) for i, ok in zip(go_on, _judged(system, [(ctrls[i], x0[:n]) for i in go_on], config, bar))}
    return [(*box.get(i, (None, None)), near[i]) for i in range(len(ctrls))]


def _ranked(gate: dict) -> tuple[int, int]:
    """A gate's rank among fits: its successes at its chosen candidate, after those of every gate
    that ran a candidate from the box states, its near-box successes where all were screened out
    near x* (`_screened_counts`)."""
    if gate["with_recovery"] is None:
        return 0, gate["candidates_near"][gate["inner_scale"]]
    return 1, gate["with_recovery"]


def _gate(base: tuple[int, int, int], candidates: dict, n: int, config) -> dict:
    """The gate entry of one law: `gate_choice` on the run's counts `base` and {r or c: counts}."""
    best, used = gate_choice(base, candidates, config.margin, config.half_loss, n // 2)
    best = _best(candidates, candidates) if best is None else best
    return {"states": n, "run": _total(base), "candidates": {r: _total(c) for r, c in candidates.items()},
            "run_half": base[0], "candidates_half": {r: c[0] for r, c in candidates.items()},
            "near_states": int(config.near_states), "run_near": base[2], "candidates_near": {r: c[2] for r, c in candidates.items()},
            "inner_scale": best, "with_recovery": _total(candidates[best]), "used": used}  # fmt: skip


def energy_levels(run, quantiles) -> list[float]:
    """The level candidates c: the `quantiles` of the run's H_d over `LEVEL_STATES` uniform half-box
    states of a seed of their own (H_d's scale is free, so c is set by where the box's states lie)."""
    x = uniform_states(run.system, LEVEL_STATES, "half", RECOVERY_GATE_SEED + run.config.seed + 3)
    ctrl = run.own_controller
    H = ctrl.flow().energy(ctrl.nets.wrap(x))
    return [float(np.quantile(H, q)) for q in quantiles]


def save_recovery(run, law: RecoveryLaw, entry: dict) -> None:
    """Write the judged `law` (at ``entry["inner_scale"]``) and summary.json → "recovery" = `entry`:
    ``recovery.npz`` when ``entry["used"]``, else ``recovery-refused.npz`` (`write_law`)."""
    law = law.with_inner(entry["inner_scale"]).with_level(math.inf if entry.get("level") is None else entry["level"])
    write_law(run, law.arrays(), "recovery", entry, (RECOVERY_FILE, RECOVERY_REFUSED_FILE))


def write_law(run, arrays: dict, key: str, entry: dict, files: tuple[str, str]) -> None:
    """Write a fitted outer law's `arrays` and summary.json → `key` = `entry` | {"law_file": …}: to
    files[0] when ``entry["used"]``, else to files[1] (a refused law, never applied); then remove the
    other file. Each write is atomic, and the order never leaves summary.json naming a law that is
    not on disk (a crash in between leaves at most a stale file that nothing reads)."""
    keep, drop = files if entry["used"] else files[::-1]
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(run.path / keep, buf.getvalue())
    summary = dict(run.summary) | {key: entry | {"law_file": keep}}
    write_json(run.path / "summary.json", summary)
    (run.path / drop).unlink(missing_ok=True)
    run.summary = summary
    run._fallback = None


def save_labels(run_dir, X: np.ndarray, U: np.ndarray) -> Path:
    """Write the labels X (K, n), U (K, m) (N·m or N, within the limits) as ``recovery-labels.npz``, atomically."""
    buf = io.BytesIO()
    np.savez_compressed(buf, X=np.asarray(X, dtype=np.float64), U=np.asarray(U, dtype=np.float64))
    return atomic_write_bytes(Path(run_dir) / RECOVERY_LABELS_FILE, buf.getvalue())


def read_labels(run_dir, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """The labels X (K, n), U (K, m) the run's last `recover` saved; a missing or damaged file (or one
    that does not fit the run's n states and m inputs) raises a one-line `DamagedFileError`."""
    path = Path(run_dir) / RECOVERY_LABELS_FILE
    fix = f"run `idapbc-pin recover {run_dir}` again (it searches the plans and saves the labels)"
    if not path.is_file():
        raise DamagedFileError(f"'{path}' is missing: the run has no saved labels (a run recovered before labels were saved has none). Fix: {fix}.")
    X, U = read_npz(path, lambda arrays: (np.asarray(arrays["X"], dtype=np.float64), np.asarray(arrays["U"], dtype=np.float64)), fix=fix)
    if X.ndim != 2 or U.ndim != 2 or X.shape[1] != n or U.shape[1] != m or len(X) != len(U) or not len(X):
        raise DamagedFileError(f"{path} does not fit the run (X {X.shape}, U {U.shape}; expected (K, {n}) and (K, {m})). Fix: {fix}.")
    if not (np.isfinite(X).all() and np.isfinite(U).all()):
        raise DamagedFileError(f"{path} holds non-finite labels. Fix: {fix}.")
    return X, U


def format_gate(gate: dict, margin: int, half_loss: int) -> str:
    """The gate's figures and verdict in one line (``gate["used"]`` the verdict of the rule)."""
    cands = ", ".join(f"r = {r:g}: {_shown(s)}" for r, s in gate["candidates"].items())
    halves, nears = (", ".join(map(_shown, gate[k].values())) for k in ("candidates_half", "candidates_near"))
    kept_as = f"the IDA-PBC law keeping H_d ≤ {gate['level']:.3g}" if gate.get("level") is not None else f"inner box r = {gate['inner_scale']:g}"
    checked = _format_confirm(gate.get("confirm", []))
    verdict = (f"kept, {kept_as}" if gate["used"]
               else f"not kept (needs {margin} more than the run's law, and at most {half_loss} fewer in the half and near boxes each, "
                    f"none in the half box where the run's law brings all of it, and then at most {half_loss} fewer on other half-box states)")
    levels = ""
    if "level_candidates" in gate:  # no inner box was kept: the levels of H_d were tried
        levels = "; or only where also H_d > " + ", ".join(
            f"c = {c:.3g}: {_shown(t)} ({gate['level_candidates_near'][c]} near x*)" for c, t in gate["level_candidates"].items())
    if "fits" in gate and gate.get("library_points"):  # the last law judged is the library of paths
        *fitted, library = gate["fits"]
        chosen = "the library" if gate.get("library") else f"fit {gate['fit'] + 1}"
        fits = f"; the {len(fitted)} fits brought {', '.join(map(_shown, fitted))}, the library of paths {_shown(library)}: {chosen}"
    else:
        fits = f"; the {len(gate['fits'])} fits brought {', '.join(map(_shown, gate['fits']))}: fit {gate['fit'] + 1}" if "fits" in gate else ""
    screened = any(v is None for v in [*gate["candidates"].values(), *gate.get("level_candidates", {}).values()])
    fits += "; –: too few near x* to be eligible, not run from the box states" if screened else ""
    return (f"gate: {gate['states']} states, the run's law brings {gate['run']} to x* ({gate['run_half']} of the {gate['states'] // 2} "
            f"half-box ones; {gate['run_near']} of {gate['near_states']} near x*), with the recovery law {cands} (half box {halves}; "
            f"near x* {nears}){levels}{fits}{checked}: {verdict}")


def _shown(count) -> str:
    """A success count of the gate's line: "–" for a candidate screened out near x* (`_screened_counts`)."""
    return "–" if count is None else str(count)


def _format_confirm(confirm: list) -> str:
    """The half-box check's part of the gate line ("" where it did not run)."""
    if not confirm:
        return ""
    laws = ", ".join(f"{c['law']} (H_d > {c['level']:.3g})" if "level" in c else f"{c['law']} (r = {c['inner_scale']:g})" for c in confirm)
    return f"; on {confirm[0]['states']} other half-box states the run's law brings {confirm[0]['run']}, with the recovery law {laws}"

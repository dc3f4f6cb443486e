"""What `train` prints when it ends: status, loss terms, the anchor, the law outside the box,
eigenvalues at x*, stiffness."""

from __future__ import annotations

__all__ = ["PLANT_POLE_SHARE", "STIFF_DT", "STIFF_WARN", "format_train_summary"]

#: The judge's default RK4 step and control period (s) (`idapbc_pin.sim.step.DEFAULT_STEP`), and the
#: |λ|·dt above which `train` notes that the learned loop is too stiff for it, so the evaluations
#: shorten the step: the judge's own `POLE_STEP` (RK4 is stable on the negative real axis up to 2.78,
#: and a law sampled every dt needs a step short against the loop).
STIFF_DT, STIFF_WARN = 0.002, 0.5
#: The NOTE blames the plant rather than the anchor when the open loop at x* has a pole at least this
#: share of the fastest closed-loop one (joint damping on light links can make the plant itself that fast).
PLANT_POLE_SHARE = 0.9


def format_train_summary(run) -> str:
    """Several lines describing a finished (or interrupted) `Run` from its summary."""
    s = run.summary
    eig = ", ".join(f"{re:.3g}" + (f"{im:+.3g}j" if abs(im) > 1e-12 else "") for re, im in s["eigenvalues_at_target"])
    lines = [
        f"run: {run.path}",
        f"status: {s['status']} after {s['epochs_done']} epochs, {s['train_seconds']:.1f} s",
        "final loss terms: " + ", ".join(f"{k} {v:.3g}" for k, v in s["final_terms"].items()),
        f"closed-loop eigenvalues at x*: {eig}",
    ]
    config = getattr(run, "config", None)
    if config is not None and getattr(config, "form", "anchored") == "anchored":
        box = config.scaling == "box"
        weight = "Q = anchor_q·diag(1/s²)" if box and config.anchor_weight == "box" else "Q = anchor_q·I in physical units"
        units = f"networks in box units, {weight}" if box else weight
        from ..control.anchor import prismatic_positions

        cart, system = getattr(config, "anchor_cart", 1.0), getattr(run, "system", None)
        if cart not in (0.0, 1.0) and system is not None and prismatic_positions(system).any():
            units += f"; a prismatic joint's position weighted × {cart:g}"
        lines.insert(3, f"anchor: LQR with anchor_q = {config.anchor_q:g} ({units})")
        form = s.get("anchor_form")
        if form:
            lines.insert(4, f"anchor: P of form '{form['form']}', chosen over the configured one ({form['passed_over']})")
    if getattr(run, "uses_fallback", False):
        gate = s.get("fallback") or {}
        why = (f" (gate: {100 * gate['with_fallback']:.0f} % of {gate['states']} fresh states reach x* with it, "
               f"{100 * gate['networks']:.0f} % without)" if "with_fallback" in gate else "")
        from ..recovery.box_law import fallback_gain

        k = fallback_gain(run.system, run.config)
        law = "u* − Kδ" if k == 1 else f"u* − {k:g}·Kδ"
        lines.append(f"outside the training box: the anchor's linear law {law}{why}")
        k_in = getattr(run, "inside_gain", 1.0)
        if k_in != 1.0:
            sc = f" (gate: {100 * gate['scaled']:.0f} %)" if gate.get("scaled") is not None else ""
            r0, r1 = getattr(run, "inside_ramp", (0.0, 0.0))
            ramp = f", k ramped from 1 within {r0:g} of the box around x* to {k_in:g} beyond {r1:g}" if r1 > 0 else ""
            lines.append(f"inside the training box: the learned law scaled about u*, u* + k·(u − u*), k = {k_in:g}{ramp}{sc}")
    elif (s.get("fallback") or {}).get("interrupted"):
        lines.append(f"outside the training box: the learned law, unchecked (the check was interrupted; "
                     f"`idapbc-pin train --resume {run.path}` runs it)")
    if getattr(run, "uses_recovery", False):
        gate = s["recovery"].get("gate") or {}
        why = f" (gate: {gate['with_recovery']} of {gate['states']} fresh states reach x* with it, {gate['run']} without)" if "with_recovery" in gate else ""
        level = s["recovery"].get("level")
        where = (f"where H_d > {level:.3g} (the IDA-PBC law keeps that sublevel set of its energy)" if level is not None
                 else f"outside an inner box of {s['recovery']['inner_scale']:g} × the training box around x*")
        lines.append(f"{where}: the recovery law (`idapbc-pin recover`){why}")
    if s["locally_exponentially_stable"]:
        lines.append("x* is locally exponentially stable (all eigenvalues have negative real part)")
    else:
        lines.append("WARNING: x* is NOT locally exponentially stable under the learned controller (an eigenvalue has Re >= 0)")
    fastest = max((abs(complex(re, im)) for re, im in s["eigenvalues_at_target"]), default=0.0)
    if fastest * STIFF_DT > STIFF_WARN:
        from ..sim.step import step_for_pole  # training sits upstream of the judge; imported only here

        plant = s.get("open_loop_fastest_pole", 0.0)
        step = step_for_pole(fastest, 20.0)
        why = (
            f"the plant has it too (open loop at x*: |λ| = {plant:.3g} 1/s, e.g. joint damping on light links), so no anchor "
            "weight removes it"
            if plant >= PLANT_POLE_SHARE * fastest
            else "a gentler anchor (smaller anchor_q) would allow a longer step"
        )
        lines.append(
            f"NOTE: the fastest closed-loop pole at x* has |λ| = {fastest:.3g} 1/s: |λ|·dt = {fastest * STIFF_DT:.2g} at a "
            f"{STIFF_DT * 1e3:g} ms RK4 step and control period, past the judge's {STIFF_WARN:g} (and the loop is faster still "
            f"away from x*). Every evaluation (train --evaluate, simulate, certify, report, view, batch) will judge it with a "
            f"{step * 1e3:.3g} ms step for a 20 s horizon (simulate --dt overrides); {why}"
        )
    return "\n".join(lines)

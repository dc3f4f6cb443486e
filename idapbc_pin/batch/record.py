"""A job's record (``<job>/job.json``) and the summary row it carries.

The record says how the job ended (``status`` done / failed / interrupted, the ``stage`` it was in,
the error and its traceback), the job's settings and their `Job.fingerprint`, the timings per
stage (s), the run directory it trained into and the files it wrote. ``record["row"]`` is the job's
line of summary.csv as raw values (floats, bools, None); `summary.write_summary` formats them.
"""

from __future__ import annotations

import os
import socket

from .._io import finite_or_none
from ..training.loss import TERMS
from ._files import timestamp
from .pipeline import Job

__all__ = ["SUMMARY_COLUMNS", "VOLATILE_COLUMNS", "crash_record", "new_record", "summary_row"]

#: Columns of summary.csv. Success rates are fractions in [0, 1] of the ROA states (DESIGN §4);
#: settling times are medians over the successful states (s), empty when none succeeded;
#: dissipation_fraction, les, sublevel_coverage, certified come from `certify` (les falls back to
#: the trainer's eigenvalue check), lqr_sublevel_coverage from its LQR baseline (δᵀSδ), invariant_share and
#: lqr_invariant_share (training-box states that reach x* without leaving the verification box); limit is the
#: actuators' effort limits applied in the evaluation ("none" when unlimited or lifted); *_radius the
#: ROA radii; *_lead_low / *_lead_high the 95 % interval of NIDA-PBC's success rate minus LQR's on the
#: box's states and *_lead_p McNemar's exact p-value (`evaluation.paired`); *_peak_half the median peak |u| on the half box; fallback whether NIDA-PBC switches to
#: the anchor's linear law outside the training box (`recovery.box_law`); inside_gain the factor on the
#: learned law's deviation from u* inside the box (1: as trained; the fallback gate's choice); recovery whether a recovery law
#: (`recovery.law`, fitted where saturated LQR leaves room) replaces the networks outside its inner box;
#: loss_* the final epoch's loss terms.
SUMMARY_COLUMNS = (
    "name", "system", "source", "actuated", "preset", "status",
    "nida_success_domain", "lqr_success_domain", "nida_success_half", "lqr_success_half",
    "nida_settle_domain", "lqr_settle_domain", "nida_settle_half", "lqr_settle_half",
    "domain_lead_low", "domain_lead_high", "domain_lead_p", "half_lead_low", "half_lead_high", "half_lead_p",
    "roa_n", "roa_T", "roa_judge", "limit", "nida_radius", "lqr_radius", "nida_peak_half", "lqr_peak_half",
    "dissipation_fraction", "les", "sublevel_coverage", "lqr_sublevel_coverage", "invariant_share", "lqr_invariant_share", "certified",
    "fallback", "inside_gain", "recovery", "epochs", "train_seconds", *(f"loss_{t}" for t in TERMS),
    "job_seconds", "run_dir", "error",
)  # fmt: skip
#: Columns that depend on the machine (time, paths), not on the seeds.
VOLATILE_COLUMNS = ("train_seconds", "job_seconds", "run_dir")


def judge_text(box_record: dict) -> str | None:
    """How the judge ran the law, from one box of ``evaluation.json``: "held 2 ms" (sampled every
    dt and held, the default since the judge holds the law) or "every stage 10 ms" (evaluated at
    every RK4 stage of dt, what evaluations written before that record: they have no "hold")."""
    dt = box_record.get("dt")
    if dt is None:
        return None
    return f"{'held' if box_record.get('hold', False) else 'every stage'} {1e3 * float(dt):.3g} ms"


def new_record(job: Job) -> dict:
    """The record of a job that starts now in this process (status "failed" until it is done)."""
    return {
        "name": job.name,
        "status": "failed",
        "stage": None,
        "error": None,
        "traceback": None,
        "fingerprint": job.fingerprint(),
        "line": job.line,
        "timings": {},
        "run_dir": None,
        "resumed": None,
        "recovery": None,
        "files": {},
        "started_at": timestamp(),
        "finished_at": None,
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "job": {"source": job.source, "actuated": job.actuated, "target": job.target, "domain": job.domain, "effort": job.effort, "preset": job.preset,
                "recover": job.recover, "train": job.train, "config": job.config, "evaluate": job.evaluate, "certify": job.certify, "figure": job.figure, "view": job.view, "smoke": job.smoke},
    }  # fmt: skip


def crash_record(job: Job, message: str) -> dict:
    """Record of a job whose worker died (killed, out of memory, segfault): written by the driver."""
    record = {"name": job.name, "status": "failed", "stage": "worker", "error": message, "traceback": None, "fingerprint": job.fingerprint(),
              "line": job.line, "timings": {}, "run_dir": None, "resumed": None, "files": {}, "started_at": None, "finished_at": timestamp()}  # fmt: skip
    record["row"] = summary_row(job, record)
    return record


def _dig(d, keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _certificate_figures(cert: dict | None) -> dict:
    """The summary's certificate columns from a ``certificate.json`` dict ({} when there is none)."""
    if not cert:
        return {}
    max_real = _dig(cert, ("local_stability", "max_real"))
    return {
        "dissipation_fraction": _dig(cert, ("dissipation_outside_E", "fraction_satisfied")),
        "les": None if max_real is None else bool(max_real < 0),
        "sublevel_coverage": _dig(cert, ("sublevel", "covered_fraction")),
        "lqr_sublevel_coverage": _dig(cert, ("baseline", "sublevel", "covered_fraction")),
        "invariant_share": _dig(cert, ("invariant_share", "NIDA-PBC")),
        "lqr_invariant_share": _dig(cert, ("invariant_share", "LQR")),
        "certified": cert.get("certified"),
    }


def _limit_text(job: Job, evaluation: dict) -> str:
    """'joint=value …' of the effort limits the evaluation applied, or 'none'."""
    limits = evaluation.get("limits")
    bound = limits.get("bound") if isinstance(limits, dict) else None
    if not bound or all(b is None for b in bound):
        return "none"
    return " ".join(f"{a}={b:g}" for a, b in zip(job.actuated_resolved, bound) if b is not None)


def summary_row(job: Job, record: dict, run=None, evaluation: dict | None = None, cert: dict | None = None) -> dict:
    """The job's summary row (raw values: floats, bools, None; formatted by `write_summary`).

    record : the job's record (its status, timings and error are used).
    run : the trained `Run` (epochs, training time, final loss terms, LES), if training finished.
    evaluation : ``evaluation.json``'s dict; cert : ``certificate.json``'s dict.
    """
    row = dict.fromkeys(SUMMARY_COLUMNS)
    row.update(name=job.name, system=job.system_name, source=job.source, actuated=" ".join(job.actuated_resolved), preset=job.preset, status=record["status"])
    if evaluation:
        for box in ("domain", "half"):
            for ctrl, key in (("NIDA-PBC", "nida"), ("LQR", "lqr")):
                score = evaluation.get(box, {}).get(ctrl, {})
                row[f"{key}_success_{box}"] = finite_or_none(score.get("success_rate"))
                row[f"{key}_settle_{box}"] = finite_or_none(score.get("median_settling_time"))
            paired = evaluation.get(box, {}).get("paired") or {}
            low, high = paired.get("interval") or (None, None)
            row[f"{box}_lead_low"], row[f"{box}_lead_high"] = finite_or_none(low), finite_or_none(high)
            row[f"{box}_lead_p"] = finite_or_none(paired.get("p_value"))
        row["roa_n"] = evaluation.get("domain", {}).get("n")
        row["roa_T"] = evaluation.get("domain", {}).get("T")
        row["roa_judge"] = judge_text(evaluation.get("domain", {}))
        row["limit"] = _limit_text(job, evaluation)
        radius = evaluation.get("radius") or {}
        row["nida_radius"], row["lqr_radius"] = finite_or_none(radius.get("NIDA-PBC")), finite_or_none(radius.get("LQR"))
        row["nida_peak_half"] = finite_or_none(_dig(evaluation, ("half", "NIDA-PBC", "median_peak_input")))
        row["lqr_peak_half"] = finite_or_none(_dig(evaluation, ("half", "LQR", "median_peak_input")))
    if run is not None:
        s = run.summary
        row["epochs"] = s.get("epochs_done")
        row["train_seconds"] = finite_or_none(s.get("train_seconds"))
        row["les"] = s.get("locally_exponentially_stable")
        row["fallback"] = bool(run.uses_fallback)
        row["inside_gain"] = run.inside_gain
        row["recovery"] = bool(run.uses_recovery)
        for t in TERMS:
            row[f"loss_{t}"] = finite_or_none(s.get("final_terms", {}).get(t))
        row["run_dir"] = f"{job.name}/{run.path.name}"
    for k, v in _certificate_figures(cert).items():
        if v is not None:
            row[k] = v
    row["job_seconds"] = record["timings"].get("total")
    row["error"] = record.get("error")
    return row

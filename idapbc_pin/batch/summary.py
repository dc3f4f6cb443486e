"""The batch's summary (summary.csv, summary.md) and the README's zoo table rendered from it.

summary.csv has one row per job of the pipeline (`SUMMARY_COLUMNS`), from the jobs' ``job.json``
files: jobs not run yet are "pending", jobs whose settings changed since they ran are marked
"(outdated settings)". summary.md shows the same rows as two Markdown tables (closed loop,
training) and lists the errors. `zoo_table_markdown` is the README's table, with no times of day
and no paths, so that it changes only when the results do.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

from .._io import atomic_write_bytes
from ..certificate.result import share_text
from ..errors import IdapbcError
from ..training.loss import TERMS
from ._files import read_json_or_none
from .pipeline import Pipeline
from .record import SUMMARY_COLUMNS, summary_row

__all__ = [
    "ZOO_TABLE_END",
    "ZOO_TABLE_START",
    "read_summary",
    "readme_block",
    "readme_zoo_block",
    "replace_block",
    "replace_zoo_table",
    "write_summary",
    "zoo_table_markdown",
]

#: README markers around the generated zoo table.
ZOO_TABLE_START, ZOO_TABLE_END = "<!-- zoo-table:start -->", "<!-- zoo-table:end -->"


def _fmt(value) -> str:
    """CSV formatting: empty for missing, yes/no for booleans, 6 significant digits for floats."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    return str(value)


def write_summary(batch_dir, pipeline: Pipeline) -> list[dict]:
    """Write summary.csv and summary.md from the jobs' job.json files; returns the CSV rows."""
    batch_dir = Path(batch_dir)
    rows = []
    for job in pipeline.jobs:
        record = read_json_or_none(batch_dir / job.name / "job.json")
        if record is None:
            row = summary_row(job, {"status": "pending", "timings": {}})
        else:
            row = {**dict.fromkeys(SUMMARY_COLUMNS), **record.get("row", {})}
            if record.get("fingerprint") != job.fingerprint():
                row["status"] = f"{row['status']} (outdated settings)"
        rows.append({c: _fmt(row.get(c)) for c in SUMMARY_COLUMNS})
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=SUMMARY_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_bytes(batch_dir / "summary.csv", buf.getvalue().encode())
    atomic_write_bytes(batch_dir / "summary.md", _summary_markdown(rows, pipeline).encode())
    return rows


def read_summary(summary_csv) -> list[dict]:
    """The rows of a summary.csv (strings, as written)."""
    with open(summary_csv, newline="") as fh:
        return list(csv.DictReader(fh))


# ---------------------------------------------------------------------------------------- cells
def _p(v: str) -> str:
    """A fraction as a percentage."""
    return "—" if v in ("", None) else f"{100 * float(v):.1f} %"


def _s(v: str, unit: str = " s") -> str:
    return "—" if v in ("", None) else f"{float(v):.3g}{unit}"


def _r(v: str) -> str:
    """A ROA radius (scale of the training box)."""
    return "—" if v in ("", None) else f"{float(v):.2f}"


def _lead(r: dict, box: str) -> str:
    """NIDA-PBC's lead over LQR on a box, in points, with its 95 % interval: "+18.0 (+11.1 to +24.6)"."""
    nida, lqr, low, high = (r.get(k) for k in (f"nida_success_{box}", f"lqr_success_{box}", f"{box}_lead_low", f"{box}_lead_high"))
    if any(v in ("", None) for v in (nida, lqr, low, high)):
        return "—"
    return f"{100 * (float(nida) - float(lqr)):+.1f} ({100 * float(low):+.1f} to {100 * float(high):+.1f})"


def _dur(v: str) -> str:
    """A duration in s, min or h."""
    if v in ("", None):
        return "—"
    v = float(v)
    return f"{v:.3g} s" if v < 100 else f"{v:.0f} s" if v < 600 else f"{v / 60:.0f} min" if v < 3600 else f"{v / 3600:.1f} h"


def _g(v: str) -> str:
    return "—" if v in ("", None) else f"{float(v):.2e}"


def _outside(r: dict) -> str:
    """What NIDA-PBC runs away from where its networks act: "recovery law" (outside its inner box),
    "linear law" (outside the training box; with "inside, the learned law × k" where the gate also
    scaled the learned law about u* inside it) or "networks"; "—" for rows written before either."""
    if r.get("recovery") == "yes":
        return "recovery law"
    k = float(r.get("inside_gain") or 1.0)
    if r.get("fallback") == "yes" and k != 1.0:
        return f"linear law; inside, the learned law × {k:g}"
    return {"yes": "linear law", "no": "networks"}.get(r.get("fallback") or "", "—")


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _table(head: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    lines += ["| " + " | ".join(_cell(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------- tables
def _summary_markdown(rows: list[dict], pipeline: Pipeline) -> str:
    n = next((r["roa_n"] for r in rows if r["roa_n"]), "?")
    T = next((r["roa_T"] for r in rows if r["roa_T"]), "?")
    head = [
        f"# Batch summary: `{pipeline.path.name}`{' (smoke)' if pipeline.smoke else ''}",
        "",
        (pipeline.description + "\n") if pipeline.description else "",
        f"Success: share of {n} uniform initial states (per box, same states for both controllers) that reach "
        f"‖q − q*‖∞ ≤ 0.05, ‖v‖∞ ≤ 0.05 over the last 2 s of T = {T} s on the true plant (docs/method.md). "
        "Settling: median over the successful states. Certificate: dissipation inequality outside H_ε (share of samples), "
        "local exponential stability of x*, share of the domain inside the largest sampled sublevel set: a sampled "
        "certificate, not a proof.",
        "",
        "## Closed loop",
        "",
        _table(
            ["job", "system", "actuated", "preset", "status", "success domain NIDA-PBC / LQR", "success half NIDA-PBC / LQR",
             "half: NIDA-PBC − LQR, points (95 % CI)", "settling domain NIDA-PBC / LQR", "dissipation", "LES", "sublevel", "certified"],
            [[r["name"], r["system"], r["actuated"], r["preset"], r["status"],
              f"{_p(r['nida_success_domain'])} / {_p(r['lqr_success_domain'])}", f"{_p(r['nida_success_half'])} / {_p(r['lqr_success_half'])}",
              _lead(r, "half"), f"{_s(r['nida_settle_domain'])} / {_s(r['lqr_settle_domain'])}", _p(r["dissipation_fraction"]), r["les"] or "—",
              _p(r["sublevel_coverage"]), r["certified"] or "—"] for r in rows],
        ),
        "",
        "## Training",
        "",
        _table(
            ["job", "epochs", "train time", *TERMS, "job time", "run"],
            [[r["name"], r["epochs"] or "—", _dur(r["train_seconds"]), *(_g(r[f"loss_{t}"]) for t in TERMS), _dur(r["job_seconds"]),
              f"`{r['run_dir']}`" if r["run_dir"] else "—"] for r in rows],
        ),
    ]  # fmt: skip
    errors = [r for r in rows if r["error"]]
    if errors:
        head += ["", "## Errors", ""] + [f"- **{r['name']}** ({r['status']}): {_cell(r['error'])}" for r in errors]
    return "\n".join(head) + "\n"


def zoo_table_markdown(summary_csv) -> str:
    """The README's zoo table, rendered from a summary.csv (deterministic: no times of day, no paths).

    One row per job: actuated joints, success rate of NIDA-PBC next to LQR on the training box and
    on its half-size box, NIDA-PBC's lead on the half box with its 95 % interval, median settling times on the training box, local exponential stability,
    the certificate's dissipation share and sublevel coverage, and the training time.
    """
    rows = read_summary(summary_csv)
    n = next((r["roa_n"] for r in rows if r.get("roa_n")), "?")
    T = next((r["roa_T"] for r in rows if r.get("roa_T")), "?")
    judge = next((r["roa_judge"] for r in rows if r.get("roa_judge")), "every stage")
    body = []
    for r in rows:
        if r["status"] != "done":
            reason = f": {r['error'][:80]}" if r.get("error") else ""
            body.append([f"`{r['name']}`", r["actuated"], f"{r['status']}{reason}"] + [""] * 9)
            continue
        body.append([
            f"`{r['name']}`", r["actuated"],
            f"{_p(r['nida_success_domain'])} / {_p(r['lqr_success_domain'])}", f"{_p(r['nida_success_half'])} / {_p(r['lqr_success_half'])}",
            _lead(r, "half"), f"{_r(r.get('nida_radius'))} / {_r(r.get('lqr_radius'))}",
            f"{_s(r['nida_settle_domain'])} / {_s(r['lqr_settle_domain'])}",
            f"{_s(r.get('nida_peak_half'), '')} / {_s(r.get('lqr_peak_half'), '')} (limit {r.get('limit') or '—'})", r["les"] or "—",
            _evidence(r),
            _outside(r), _dur(r["train_seconds"]),
        ])  # fmt: skip
    head = ["robot", "actuated", "success, domain: NIDA-PBC / LQR", "success, half box: NIDA-PBC / LQR",
            "half box: NIDA-PBC − LQR, points (95 % CI)", "ROA radius: NIDA-PBC / LQR", "median settling: NIDA-PBC / LQR", "median peak abs(u), half box: NIDA-PBC / LQR",
            "x* LES", "certified share (invariant share): NIDA-PBC / LQR", "NIDA-PBC outside the box", "training"]  # fmt: skip
    note = (
        f"Generated from `{Path(summary_csv).name}` by `idapbc_pin.batch.zoo_table_markdown`: {n} uniform states per box, "
        f"T = {T} s, the law {_judge_phrase(judge)}, success = within 0.05 of x* over the last 2 s, with the effort limits "
        "applied to both controllers; "
        "NIDA-PBC − LQR = the lead on the same states with its 95 % interval (Tango's score interval, from the states where the "
        "two laws disagree; `idapbc_pin.evaluation.paired`): an interval that contains 0 is no evidence of a lead; "
        "ROA radius = largest scale s of the training box around x* at which ≥ 90 % of the states succeed; certified "
        "share = share of the training box inside the largest sublevel set of H_d (NIDA-PBC) or of δᵀSδ (LQR) in the verification "
        "box (4× the training box, angles within ±π) on which the value decreases along the true loop with the limits, outside a "
        "core certified by the linearisation: the share of the set where it does not decrease is ≤ 0.1 % with confidence "
        "1 − 10⁻⁶ (14 915 fresh samples; docs/method.md §7), sampled, not a proof; invariant share = training-box states "
        "whose trajectory reaches x* without leaving the verification box, the ceiling of any such certificate. NIDA-PBC outside "
        "the box = the law NIDA-PBC applies outside the training box, chosen after training (the anchor's linear law, or "
        "the networks'; docs/method.md §6; \"inside, the learned law × k\": the gate also scaled the learned law by k about u* "
        "inside the box, the factor ramped in from 1 within 20 % of the box around x* to k beyond 50 % for runs gated since "
        "the ramp), or \"recovery law\" where a recovery law fitted to torque plans within the limits "
        "replaces the networks outside an inner box (README, \"A recovery law for weak actuators\")."
    )
    return _table(head, body) + "\n\n" + note + "\n"


def _evidence(r: dict) -> str:
    """'certified / certified (invariant / invariant)' of a summary row; "—" for a summary made before
    the verification box (its sublevel shares measured another, in-box test)."""
    if r.get("invariant_share") in ("", None):
        return "—"
    return (f"{share_text(r['sublevel_coverage'], 2)} / {share_text(r.get('lqr_sublevel_coverage'), 2)} "
            f"({_p(r['invariant_share'])} / {_p(r.get('lqr_invariant_share'))})")


def _judge_phrase(judge: str) -> str:
    """A summary's `roa_judge` in words: "held 2 ms" -> "sampled and held every 2 ms (RK4 on the plant)";
    "every stage 10 ms" (or nothing, in summaries older than the column) -> "evaluated at every RK4 stage …"."""
    if judge.startswith("held "):
        return f"sampled and held every {judge[len('held '):]} (RK4 on the plant)"
    step = judge[len("every stage"):].strip()
    return "evaluated at every RK4 stage" + (f" of {step}" if step else "")


def replace_block(text: str, table: str, start_marker: str, end_marker: str) -> str:
    """`text` with the block between two markers replaced by `table`."""
    start, end = text.find(start_marker), text.find(end_marker)
    if start < 0 or end < start:
        raise IdapbcError(f"README has no {start_marker} … {end_marker} block. Fix: add both markers where the table goes.")
    return text[: start + len(start_marker)] + "\n" + table.strip() + "\n" + text[end:]


def readme_block(text: str, start_marker: str, end_marker: str) -> str | None:
    """The text between two markers (stripped), or None if the markers are missing."""
    start, end = text.find(start_marker), text.find(end_marker)
    if start < 0 or end < start:
        return None
    return text[start + len(start_marker) : end].strip()


def replace_zoo_table(readme_text: str, table: str) -> str:
    """`readme_text` with the block between the zoo-table markers replaced by `table`."""
    return replace_block(readme_text, table, ZOO_TABLE_START, ZOO_TABLE_END)


def readme_zoo_block(readme_text: str) -> str | None:
    """The text between the zoo-table markers (stripped), or None if the markers are missing."""
    return readme_block(readme_text, ZOO_TABLE_START, ZOO_TABLE_END)

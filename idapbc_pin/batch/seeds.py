"""Medians over training seeds: the zoo table read across several batches of the same robots.

One training seed is one draw of the networks' initial weights and of the training samples; a
difference of a few points between NIDA-PBC and LQR on one seed can be that draw alone. The zoo is
therefore also trained with seeds 1 and 2 (``pipelines/zoo_seeds.toml``; seed 0 is
``pipelines/zoo.toml``), all judged on the same evaluation states, and `seed_median_markdown` puts
the per-seed success rates and their medians side by side. LQR does not depend on the training seed:
its figures are the same in every batch (same states, same limits), and the table shows them once.

Rows are grouped by the summary's ``system`` column (a job name such as ``acrobot-seed1`` is only a
label) and keep the order of the files and of their rows: seed 0's file first, then
``zoo_seeds.toml``'s (its seed-1 jobs before its seed-2 jobs).
"""

from __future__ import annotations

import math
from pathlib import Path

from ..errors import IdapbcError
from .summary import _p, _r, _s, _table, read_summary

__all__ = ["SEED_TABLE_END", "SEED_TABLE_START", "seed_median_markdown", "seed_medians"]

#: README markers around the generated table of medians over training seeds.
SEED_TABLE_START, SEED_TABLE_END = "<!-- seed-table:start -->", "<!-- seed-table:end -->"

#: Columns whose median over seeds the table shows (NIDA-PBC and LQR alike).
MEDIAN_COLUMNS = (
    "nida_success_domain", "lqr_success_domain", "nida_success_half", "lqr_success_half",
    "nida_radius", "lqr_radius", "nida_settle_domain", "lqr_settle_domain",
)  # fmt: skip


def _median(values: list[float]) -> float:
    v = sorted(x for x in values if math.isfinite(x))
    if not v:
        return math.nan
    mid = len(v) // 2
    return v[mid] if len(v) % 2 else 0.5 * (v[mid - 1] + v[mid])


def _float(text: str) -> float:
    return float(text) if text not in ("", None) else math.nan


def seed_medians(summary_csvs) -> dict[str, dict]:
    """Per robot (the ``system`` column), over every finished row of the given summary.csv files:

    ``{"rows": [row, ...], "median": {column: value}}`` for the `MEDIAN_COLUMNS` (nan where a column
    is empty in every row), ``"recovery"``: how many rows used a recovery law, ``"fallback"``: how
    many of the others used the linear law outside the box.
    Robots keep the order in which they first appear. A missing file is an error naming it, and so
    is a robot judged differently in two rows (other states per box, horizon or effort limits): their
    success rates would not be comparable.
    """
    robots: dict[str, dict] = {}
    for path in summary_csvs:
        if not Path(path).is_file():
            raise IdapbcError(f"summary file '{path}' not found. Fix: pass the summary.csv of a finished batch.")
        for row in read_summary(path):
            if row.get("status") != "done":
                continue
            robots.setdefault(row["system"], {"rows": []})["rows"].append(row)
    for name, entry in robots.items():
        rows = entry["rows"]
        judged = {(r.get("roa_n"), r.get("roa_T"), r.get("limit"), r.get("roa_judge") or "every stage") for r in rows}
        if len(judged) > 1:
            raise IdapbcError(
                f"the rows of '{name}' were judged differently (states per box, T, limits, judge: {sorted(judged)}). "
                "Fix: pass batches that use the same `evaluate` settings and limits."
            )
        entry["median"] = {c: _median([_float(r.get(c, "")) for r in rows]) for c in MEDIAN_COLUMNS}
        entry["recovery"] = sum(r.get("recovery") == "yes" for r in rows)  # it replaces the linear law outside its box
        entry["fallback"] = sum(r.get("fallback") == "yes" and r.get("recovery") != "yes" for r in rows)
    return robots


def _per_seed(rows: list[dict], column: str) -> str:
    return " / ".join("—" if r.get(column) in ("", None) else f"{100 * float(r[column]):.1f}" for r in rows)


def _median_cell(value: float, fmt) -> str:
    """A median through a summary cell formatter (`_p`, `_r`, `_s`), "—" when there is none."""
    return fmt(str(value)) if math.isfinite(value) else "—"


def seed_median_markdown(summary_csvs) -> str:
    """The README's table of medians over training seeds, from several summary.csv files (seed 0 first).

    Per robot: NIDA-PBC's success on the training box and on its half, per seed and as a median,
    next to LQR's (the same for every seed); the median ROA radius and settling time of both; and on how many seeds NIDA-PBC applies the linear law outside the box.
    """
    robots = seed_medians(summary_csvs)
    if not robots:
        raise IdapbcError("no finished job in the summary files given. Fix: pass the summary.csv of a finished batch.")
    body = []
    for name, entry in robots.items():
        med, rows = entry["median"], entry["rows"]

        def cell(column: str, fmt=_p) -> str:
            return _median_cell(med[column], fmt)

        body.append([
            f"`{name}`", str(len(rows)),
            f"{_per_seed(rows, 'nida_success_domain')} → **{cell('nida_success_domain')}** / {cell('lqr_success_domain')}",
            f"{_per_seed(rows, 'nida_success_half')} → **{cell('nida_success_half')}** / {cell('lqr_success_half')}",
            f"{cell('nida_radius', _r)} / {cell('lqr_radius', _r)}",
            f"{cell('nida_settle_domain', _s)} / {cell('lqr_settle_domain', _s)}",
            f"{entry['fallback']} of {len(rows)}" + (f"; a recovery law: {entry['recovery']} of {len(rows)}" if entry["recovery"] else ""),
        ])  # fmt: skip
    head = ["robot", "seeds", "success, domain: NIDA-PBC per seed → median / LQR", "success, half box: NIDA-PBC per seed → median / LQR",
            "ROA radius: NIDA-PBC / LQR", "median settling: NIDA-PBC / LQR",
            "seeds with the linear law (or a recovery law) outside the box"]  # fmt: skip
    files = ", ".join(f"`{Path(p).name}`" for p in summary_csvs)
    note = (
        f"Generated from {files} by `idapbc_pin.batch.seed_median_markdown`: the zoo trained with seeds 0, 1 and 2, every "
        "run judged on the same states (those of the zoo table above); per-seed success rates in %, then the median; LQR "
        "does not depend on the training seed. Radius and settling are medians over the seeds."
    )
    return _table(head, body) + "\n\n" + note + "\n"

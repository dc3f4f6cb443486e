"""The zoo table's medians over training seeds: grouping, medians, comparability, and the README block."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from idapbc_pin.batch import SEED_TABLE_END, SEED_TABLE_START, SUMMARY_COLUMNS, readme_block, seed_median_markdown, seed_medians
from idapbc_pin.batch.record import judge_text
from idapbc_pin.errors import IdapbcError

ROOT = Path(__file__).resolve().parents[1]


def _write(path: Path, rows: list[dict]) -> Path:
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=SUMMARY_COLUMNS, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({c: row.get(c, "") for c in SUMMARY_COLUMNS})
    return path


def _row(name, system, nida, lqr, **extra):
    base = {"name": name, "system": system, "status": "done", "roa_n": "200", "roa_T": "20", "limit": "elbow=20",
            "nida_success_domain": str(nida), "lqr_success_domain": str(lqr), "nida_success_half": str(nida),
            "lqr_success_half": str(lqr), "fallback": "no"}  # fmt: skip
    return {**base, **extra}


def test_medians_group_rows_by_system_across_files(tmp_path):
    seed0 = _write(tmp_path / "zoo.csv", [_row("acrobot", "acrobot", 0.61, 0.545, fallback="yes"), _row("pendubot", "pendubot", 0.455, 0.285)])
    seeds = _write(tmp_path / "seeds.csv", [
        _row("acrobot-seed1", "acrobot", 0.50, 0.545), _row("pendubot-seed1", "pendubot", 0.40, 0.285, recovery="yes", fallback="yes"),
        _row("acrobot-seed2", "acrobot", 0.70, 0.545, fallback="yes"), _row("pendubot-seed2", "pendubot", 0.30, 0.285, status="failed"),
    ])  # fmt: skip
    robots = seed_medians([seed0, seeds])
    assert list(robots) == ["acrobot", "pendubot"]
    assert [r["name"] for r in robots["acrobot"]["rows"]] == ["acrobot", "acrobot-seed1", "acrobot-seed2"]
    assert robots["acrobot"]["median"]["nida_success_domain"] == pytest.approx(0.61)
    assert robots["acrobot"]["fallback"] == 2 and robots["acrobot"]["recovery"] == 0 and robots["pendubot"]["recovery"] == 1
    # the failed seed-2 job is left out: the median of two rows is their mean
    assert robots["pendubot"]["median"]["nida_success_half"] == pytest.approx(0.4275)
    assert math.isnan(robots["pendubot"]["median"]["nida_radius"])
    table = seed_median_markdown([seed0, seeds])
    assert "61.0 / 50.0 / 70.0 → **61.0 %** / 54.5 %" in table
    assert "| `pendubot` | 2 |" in table and "2 of 3" in table and "| 0 of 2; a recovery law: 1 of 2 |" in table


def test_rows_judged_on_other_states_are_refused(tmp_path):
    seed0 = _write(tmp_path / "zoo.csv", [_row("acrobot", "acrobot", 0.61, 0.545)])
    smoke = _write(tmp_path / "smoke.csv", [_row("acrobot-seed1", "acrobot", 0.2, 0.3, roa_n="12")])
    with pytest.raises(IdapbcError, match="judged differently"):
        seed_medians([seed0, smoke])
    with pytest.raises(IdapbcError, match="not found"):
        seed_medians([tmp_path / "missing.csv"])


def test_rows_of_another_judge_are_refused(tmp_path):
    """A summary written before the judge held the law has no roa_judge: its rows count as judged at
    every RK4 stage and do not mix with rows of the held law."""
    old = _write(tmp_path / "old.csv", [_row("acrobot", "acrobot", 0.61, 0.545)])
    new = _write(tmp_path / "new.csv", [_row("acrobot-seed1", "acrobot", 0.6, 0.5, roa_judge="held 2 ms")])
    with pytest.raises(IdapbcError, match="held 2 ms"):
        seed_medians([old, new])
    same = _write(tmp_path / "same.csv", [_row("acrobot-seed2", "acrobot", 0.7, 0.5, roa_judge="held 2 ms")])
    assert len(seed_medians([new, same])["acrobot"]["rows"]) == 2


def test_the_summary_names_how_the_judge_ran_the_law():
    assert judge_text({"dt": 0.002, "hold": True}) == "held 2 ms"
    assert judge_text({"dt": 0.01}) == "every stage 10 ms"  # evaluation.json from before the held law
    assert judge_text({}) is None


def test_readme_seed_table_matches_the_committed_summaries():
    readme = (ROOT / "README.md").read_text()
    block = readme_block(readme, SEED_TABLE_START, SEED_TABLE_END)
    files = [ROOT / "pipelines" / "results" / name for name in ("zoo-law-alone-summary.csv", "zoo-seeds-summary.csv")]
    if block is None or not all(f.is_file() for f in files):
        pytest.skip("README.md has no seed-table block or pipelines/results/zoo-seeds-summary.csv is not committed yet")
    assert block == seed_median_markdown(files).strip(), (
        "README's seed table is out of step with pipelines/results/. Fix: python -c \"from pathlib import Path; "
        "from idapbc_pin.batch import replace_block, seed_median_markdown, SEED_TABLE_START, SEED_TABLE_END; "
        "p = Path('README.md'); r = 'pipelines/results/'; p.write_text(replace_block(p.read_text(), "
        "seed_median_markdown([r + 'zoo-law-alone-summary.csv', r + 'zoo-seeds-summary.csv']), SEED_TABLE_START, SEED_TABLE_END))\""
    )

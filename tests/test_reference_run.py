"""Training's results stay bit for bit what the committed `data/reference_run/` recorded.

The fixture was trained by `data/make_reference_run.py`; retraining its config on this machine must
give the same weights, the same metrics (every column but the wall time) and the same torques. Any
refactor that changes a result, however slightly, fails here.
"""

from __future__ import annotations

import csv
import runpy
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

import idapbc_pin as ip

DATA = Path(__file__).parent / "data"
MAKE = runpy.run_path(str(DATA / "make_reference_run.py"), run_name="not_main")


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return [{k: v for k, v in row.items() if k != "seconds"} for row in csv.DictReader(fh)]


@pytest.fixture(scope="module")
def fresh(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("reference")
    MAKE["main"](out)
    return out


@pytest.mark.parametrize("name", ["best", "last"])
def test_weights_are_bit_identical_to_the_committed_run(fresh, name):
    ref = torch.load(DATA / "reference_run" / "checkpoints" / f"{name}.pt", weights_only=True)
    new = torch.load(fresh / "reference_run" / "checkpoints" / f"{name}.pt", weights_only=True)
    assert ref["epoch"] == new["epoch"]
    assert sorted(ref["nets"]) == sorted(new["nets"])
    for key, value in ref["nets"].items():
        assert torch.equal(value, new["nets"][key]), key


def test_metrics_are_identical_to_the_committed_run(fresh):
    assert _rows(fresh / "reference_run" / "metrics.csv") == _rows(DATA / "reference_run" / "metrics.csv")


def test_the_committed_run_loads_and_gives_the_recorded_torques(tmp_path):
    run_dir = Path(shutil.copytree(DATA / "reference_run", tmp_path / "run"))
    ref = np.load(DATA / "reference_run_torques.npz")
    run = ip.load_run(run_dir)
    np.testing.assert_array_equal(run.controller(ref["x"]), ref["u"])
    np.testing.assert_array_equal(ref["x"], MAKE["states"](run.system))

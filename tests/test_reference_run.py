"""Training's results stay bit for bit what the committed `data/reference_run/` recorded.

The fixture was trained by `data/make_reference_run.py`; retraining its config on this machine must
give the same weights, the same metrics (every column but the wall time) and the same torques. Any
refactor that changes a result, however slightly, fails here.

float32 training rounds differently on another CPU's kernels (about 5e-5 of the weights after the
fixture's 12 epochs), so each machine kind the project has run on has its own committed weights and
metrics (``data/reference_training/<machine>/``, made by ``make_reference_run.py --machine``, beside
the run's own); a retraining must equal one of them bit for bit. On a machine with none, the test
compares with the nearest at 1e-3 of the weights (20 times the spread between two machines) and says
how to add this one.
"""

from __future__ import annotations

import csv
import runpy
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

import idapbc_pin as ip

DATA = Path(__file__).parent / "data"
MAKE = runpy.run_path(str(DATA / "make_reference_run.py"), run_name="not_main")
#: On a machine with no committed reference: the largest difference allowed, relative to each tensor's largest entry
#: (weights) or to each value (metrics).
OTHER_MACHINE_RTOL = 1e-3


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return [{k: v for k, v in row.items() if k != "seconds"} for row in csv.DictReader(fh)]


def _references() -> list[Path]:
    """Folders with checkpoints/{best,last}.pt and metrics.csv: the committed run's, then one per machine kind."""
    run = DATA / "reference_run"
    return [run, *sorted(p for p in (DATA / "reference_training").glob("*") if p.is_dir())]


def _checkpoint(folder: Path, name: str) -> dict:
    return torch.load(folder / "checkpoints" / f"{name}.pt", weights_only=True)


def _relative_gap(ref: dict, new: dict) -> float:
    """The largest |ref − new| over the networks' float tensors, relative to each tensor's largest |entry|."""
    gaps = [((a.double() - new["nets"][k].double()).abs().max() / a.double().abs().max().clamp_min(1e-30)).item()
            for k, a in ref["nets"].items() if a.is_floating_point()]
    return max(gaps, default=0.0)


@pytest.fixture(scope="module")
def fresh(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("reference")
    MAKE["main"](out)
    return out


@pytest.fixture(scope="module")
def reference(fresh) -> Path | None:
    """The committed reference whose last weights the retraining reproduces bit for bit (None: none does)."""
    new = _checkpoint(fresh / "reference_run", "last")
    for folder in _references():
        ref = _checkpoint(folder, "last")
        if sorted(ref["nets"]) == sorted(new["nets"]) and all(torch.equal(v, new["nets"][k]) for k, v in ref["nets"].items()):
            return folder
    return None


def _nearest(fresh: Path, name: str) -> tuple[Path, float]:
    new = _checkpoint(fresh / "reference_run", name)
    return min(((folder, _relative_gap(_checkpoint(folder, name), new)) for folder in _references()), key=lambda fg: fg[1])


@pytest.mark.parametrize("name", ["best", "last"])
def test_weights_are_bit_identical_to_the_committed_run(fresh, reference, name):
    new = _checkpoint(fresh / "reference_run", name)
    if reference is None:  # a machine kind with no committed reference: near the nearest one
        folder, gap = _nearest(fresh, name)
        warnings.warn(f"no committed reference for this machine ({MAKE['machine']()}); weights within {gap:.2g} of "
                      f"{folder.name}. Add one: python tests/data/make_reference_run.py --machine", stacklevel=1)
        assert gap <= OTHER_MACHINE_RTOL, (folder.name, gap)
        assert _checkpoint(folder, name)["epoch"] == new["epoch"]
        return
    ref = _checkpoint(reference, name)
    assert ref["epoch"] == new["epoch"]
    assert sorted(ref["nets"]) == sorted(new["nets"])
    for key, value in ref["nets"].items():
        assert torch.equal(value, new["nets"][key]), key


def test_metrics_are_identical_to_the_committed_run(fresh, reference):
    rows = _rows(fresh / "reference_run" / "metrics.csv")
    if reference is not None:
        assert rows == _rows(reference / "metrics.csv")
        return
    folder, _ = _nearest(fresh, "last")
    ref = _rows(folder / "metrics.csv")
    assert [r.keys() for r in rows] == [r.keys() for r in ref] and len(rows) == len(ref)
    for a, b in zip(rows, ref):
        for key in a:
            x, y = float(a[key] or "nan"), float(b[key] or "nan")
            assert (np.isnan(x) and np.isnan(y)) or abs(x - y) <= OTHER_MACHINE_RTOL * max(abs(x), abs(y), 1e-12), (a["epoch"], key, x, y)


def test_the_committed_run_loads_and_gives_the_recorded_torques(tmp_path):
    run_dir = Path(shutil.copytree(DATA / "reference_run", tmp_path / "run"))
    ref = np.load(DATA / "reference_run_torques.npz")
    run = ip.load_run(run_dir)
    np.testing.assert_array_equal(run.controller(ref["x"]), ref["u"])
    np.testing.assert_array_equal(ref["x"], MAKE["states"](run.system))

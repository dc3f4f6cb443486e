"""Goal: measure how much of the training box any certificate of a trained loop could cover.

A certified sublevel set lies inside its verification box and V decreases on it, so every trajectory
that starts in it never leaves that box and reaches x*. The share of training-box states whose
trajectory does both (`ip.invariant_share`, simulated with the run's judge and effort limits) is
therefore a ceiling on the certified share of H_d, of LQR's δᵀSδ, or of any other function, for that
law and that box. This script prints it for the training box and boxes 2× and 4× as wide (`certify`'s
default verification box is the 4× one, angles within ±π), for NIDA-PBC and LQR, next to the
certified shares in the run's certificate.json (when `certify` or `report` wrote one).
Run: python benchmarks/bench_invariant_share.py RUN [RUN ...] [--n 500] [--seed 5]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

import idapbc_pin as ip
from idapbc_pin.control.baseline import LQRController


def _certified(run_dir: Path) -> str:
    path = run_dir / "certificate.json"
    if not path.is_file():
        return "no certificate.json"
    data = json.loads(path.read_text())
    own, base = data["sublevel"]["covered_fraction"], data["baseline"]["sublevel"]["covered_fraction"]
    return f"certified share (certificate.json): NIDA-PBC {100 * own:.2f} %, LQR {100 * base:.2f} %"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run directories")
    parser.add_argument("--n", type=int, default=500, help="uniform states of the training box (default 500)")
    parser.add_argument("--seed", type=int, default=5, help="seed of those states (default 5)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    for run_dir in args.runs:
        try:
            run = ip.load_run(run_dir)
        except ip.IdapbcError as exc:
            parser.error(str(exc))
        start = time.perf_counter()
        share = ip.invariant_share(run.system, {"NIDA-PBC": run.controller, "LQR": LQRController(run.system)}, n=args.n, seed=args.seed)
        print(share.table())
        print(f"{_certified(run_dir)}; {time.perf_counter() - start:.0f} s\n", flush=True)


if __name__ == "__main__":
    main()

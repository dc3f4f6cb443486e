"""Goal: measure the verified (proved) regions of attraction of four-state URDF loops.

For each run and each law (the run's deployed law; saturated LQR, Q = I, R = I), with the run's
effort limits, in the verification box 2× the training box: a quadratic V from the loop's own
linearisation (`loop_quadratic`, the same recipe for both laws), and for LQR also its δᵀSδ. For
each V: the core proved from the linearisation (`proved_core`), the sampled certified level c
(`certified_region`), then the interval verifier, on {c_core ≤ V < level} so that the set is
proved whole, at
0.999, 0.5, 0.1, 0.01 and 0.001 of c (`verify_level`, a box budget each) until one is proved. Prints the
training-box share of the sampled set and of the verified one (the ellipsoid's volume), the boxes
and the seconds. The invariant share (`bench_invariant_share.py`) is the ceiling of any of them.
Run: python benchmarks/bench_verified.py RUN [RUN ...] [--budget 20000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

import idapbc_pin as ip
from idapbc_pin.certificate.baseline import QuadraticLyapunov, ellipsoid_share, loop_quadratic
from idapbc_pin.certificate.core import proved_core
from idapbc_pin.certificate.enclosures import FlowEnclosure, loop_field, lqr_field, quadratic_rate
from idapbc_pin.certificate.region import TrueLoop, certified_region
from idapbc_pin.certificate.vbox import verification_box
from idapbc_pin.certificate.verified import verify_level
from idapbc_pin.control.baseline import LQRController

FRACTIONS = (0.999, 0.5, 0.1, 0.01, 0.001)


def _one(system, law, field, P, A, vbox, budget: int) -> str:
    x_star = np.asarray(system.x_star, np.float64)
    lo, hi = (np.asarray(b, np.float64) for b in system.domain)
    half = 0.5 * (hi - lo)
    t0 = time.perf_counter()
    c_core, _ = proved_core(P, A, x_star, field, 1.0)
    core = f"proved core {ellipsoid_share(P, c_core, half):.3g}"
    region = certified_region(QuadraticLyapunov(P, x_star, system.angle_mask), TrueLoop(system, law, system.effort), x_star, vbox,
                              (lo, hi), np.random.default_rng(1))
    sampled = ellipsoid_share(P, region.c, half)
    rate = lambda X: quadratic_rate(P, x_star, field, A, X)  # noqa: E731
    if c_core <= 0:
        return f"{core} · sampled {sampled:.3g} · verified 0 (no core proved: no proof; {time.perf_counter() - t0:.0f} s)"
    tried = []
    for frac in FRACTIONS:
        if not frac * region.c > max(region.core, c_core):
            break
        # down to the proved core: the whole set is then a proof
        why, boxes = verify_level(rate, frac * region.c, c_core, vbox, (x_star, P), budget=budget)
        tried.append(f"{frac:g}·c: {why or 'proved'} ({boxes} boxes)")
        if why is None:
            return (f"{core} · sampled {sampled:.3g} · verified {ellipsoid_share(P, frac * region.c, half):.3g} of the training box "
                    f"({'; '.join(tried)}; {time.perf_counter() - t0:.0f} s)")
    return f"{core} · sampled {sampled:.3g} · verified 0 ({'; '.join(tried)}; {time.perf_counter() - t0:.0f} s)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+")
    parser.add_argument("--budget", type=int, default=20000, help="boxes per level tried")
    args = parser.parse_args()
    torch.set_num_threads(1)
    for path in args.runs:
        run = ip.load_run(path)
        system, ctrl = run.system, run.controller
        vbox = verification_box(system, 2.0, None)
        half = 0.5 * (system.domain[1] - system.domain[0])
        lqr = LQRController(system)
        enc = FlowEnclosure(ctrl.flow())
        fields = {"NIDA-PBC": (ctrl, lambda X: loop_field(system, enc, ctrl._g_pinv, system.effort, ctrl.fallback, X, ctrl.governor)[:2]),
                  "LQR": (lqr, lambda X: lqr_field(system, lqr, system.effort, X))}
        print(f"{system.name} ({path})")
        for name, (law, field) in fields.items():
            A = TrueLoop(system, law, system.effort).jacobian_at(system.x_star)
            print(f"  {name}, V from its linearisation: {_one(system, law, field, loop_quadratic(A, half), A, vbox, args.budget)}", flush=True)
        A = TrueLoop(system, lqr, system.effort).jacobian_at(system.x_star)
        print(f"  LQR, V = δᵀSδ: {_one(system, lqr, fields['LQR'][1], lqr.S, A, vbox, args.budget)}", flush=True)


if __name__ == "__main__":
    main()

# Goal: two local workers finish a 4-job smoke batch at least 1.6× faster than one (issue 6).
"""Wall time of a 4-job smoke batch with 1 worker (in-process) and with 2 worker processes.

Each batch runs in a fresh Python process, timed from the outside, so both pay the start-up a
user's ``idapbc-pin batch`` pays (imports, torch, Pinocchio, matplotlib: 3–6 s per process here).
The batch is ``pipelines/zoo.toml --smoke`` restricted to cartpole and pendubot, two seeds each
(`--smoke`: 20 epochs of width-16 networks, 12 ROA states per box over 5 s, a 256-sample
certificate, a one-trajectory figure and replay), so that the two workers get equal work.

    python benchmarks/bench_batch.py [--repeats 2]

The machine's load average is printed next to the times, with the jobs' own wall and CPU seconds:
on a shared machine other work takes the cores too, and then the jobs' wall time grows while their
CPU time does not; the speed-up measured there says more about the neighbours than about the batch.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
JOBS = [("cartpole", 0), ("pendubot", 0), ("cartpole", 1), ("pendubot", 1)]
TARGET = 1.6


def pipeline_text() -> str:
    defaults = (ROOT / "pipelines" / "zoo.toml").read_text().split("[[job]]")[0]
    jobs = "".join(f'\n[[job]]\nname = "{name}-seed{seed}"\nsource = "{name}"\ntrain = {{ seed = {seed} }}\n' for name, seed in JOBS)
    return defaults + jobs


def run_once(pipeline: Path, workers: int, out: Path) -> tuple[float, float, float]:
    """(batch wall time, sum of the jobs' wall times, sum of the jobs' CPU times), seconds."""
    code = "import sys; from idapbc_pin.batch import run_batch; r = run_batch(sys.argv[1], workers=int(sys.argv[2]), out=sys.argv[3], smoke=True, progress=False); sys.exit(0 if r.ok else 1)"
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code, str(pipeline), str(workers), str(out)], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"batch with {workers} worker(s) failed:\n{proc.stdout}\n{proc.stderr}")
    records = [json.loads(p.read_text()) for p in out.glob("*/job.json")]
    return wall, sum(r["timings"]["total"] for r in records), sum(r["timings"]["cpu"] for r in records)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=1, help="alternate 1 and 2 workers this many times (median reported)")
    args = parser.parse_args()
    cores = len(os.sched_getaffinity(0))
    times: dict[int, list[float]] = {1: [], 2: []}
    with tempfile.TemporaryDirectory(prefix="bench-batch-") as tmp:
        pipeline = Path(tmp) / "bench.toml"
        pipeline.write_text(pipeline_text())
        print(f"4-job smoke batch ({', '.join(f'{n} seed {s}' for n, s in JOBS)}); {cores} cores; fresh process per batch")
        for rep in range(args.repeats):
            for workers in (1, 2):
                load = os.getloadavg()[0]
                wall, job_wall, job_cpu = run_once(pipeline, workers, Path(tmp) / f"out-{workers}-{rep}")
                times[workers].append(wall)
                print(f"  run {rep + 1}: {workers} worker{'s' if workers > 1 else ' '}: {wall:6.1f} s   (jobs: {job_wall:5.1f} s wall, "
                      f"{job_cpu:5.1f} s CPU in all; load average at start {load:.1f})", flush=True)
    one, two = statistics.median(times[1]), statistics.median(times[2])
    print(f"1 worker : {one:6.1f} s")
    print(f"2 workers: {two:6.1f} s")
    print(f"speed-up : {one / two:.2f}× (target ≥ {TARGET}×: {'met' if one / two >= TARGET else 'NOT met'})")


if __name__ == "__main__":
    main()

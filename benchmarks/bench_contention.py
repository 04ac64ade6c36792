"""Two processes on one CPU: does each take about twice its time alone, or do they stall each other?

    python benchmarks/bench_contention.py [--repeats 2] [--policies before after one-thread] [--jobs fit sample]

Each job runs as a fresh ``python -m sin3dm_lite.cli`` process: ``fit`` is the built-in canyon at
``--preset tiny``, ``sample`` draws 2 samples of the shipped canyon at cheap export settings. For each
thread policy it times one job alone, then two at once (fit beside fit, and sample beside fit), and
prints wall times and the ratio *together / alone* (the goal: ≤ 2.2 on a 2-core CPU; 2.0 is a fair
share). The policies:

* ``before``: PyTorch's defaults, one thread per core whose idle threads spin (``GOMP_SPINCOUNT=300000``);
* ``passive``: one thread per core whose idle threads sleep (``OMP_WAIT_POLICY=PASSIVE``);
* ``after``: what ``import sin3dm_lite`` sets (sin3dm_lite/threads.py: one thread, idle threads sleep).

Run it on a quiet machine: anything else running changes every figure.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

CHEAP = [
    "--steps",
    "5",
    "--mesh-resolution",
    "32",
    "--faces",
    "2000",
    "--texture-size",
    "64",
    "--no-pictures",
    "--workers",
    "0",
]
CORES = str(os.cpu_count() or 1)
POLICIES = {
    "before": {"GOMP_SPINCOUNT": "300000", "OMP_NUM_THREADS": CORES},
    "passive": {"OMP_NUM_THREADS": CORES},
    "after": {},
}


def job_cmd(job: str, out: Path) -> list[str]:
    cli = [sys.executable, "-m", "sin3dm_lite.cli"]
    if job == "fit":
        return cli + ["fit", "canyon", "--preset", "tiny", "--out", str(out)]
    if job == "sample":
        return cli + ["sample", "canyon", "-n", "2", "--out", str(out), *CHEAP]
    raise ValueError(job)


def run_jobs(jobs: list[str], env_extra: dict) -> list[float]:
    """Start ``jobs`` at the same moment; their wall times in seconds."""
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("OMP_NUM_THREADS", "OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "SIN3DM_THREADS")
    }
    env.update(env_extra)
    tmp = Path(tempfile.mkdtemp(prefix="bench-contention-"))

    def one(i_job):
        i, job = i_job
        t = time.perf_counter()
        r = subprocess.run(job_cmd(job, tmp / f"{job}{i}"), env=env, capture_output=True, text=True)
        if r.returncode:
            raise RuntimeError(f"{job} failed ({r.returncode}): {r.stderr[-500:]}")
        return time.perf_counter() - t

    try:
        with ThreadPoolExecutor(len(jobs)) as ex:
            return list(ex.map(one, enumerate(jobs)))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--policies", nargs="+", default=list(POLICIES), choices=list(POLICIES))
    ap.add_argument("--jobs", nargs="+", default=["fit", "sample"], choices=["fit", "sample"])
    args = ap.parse_args()
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores; median of {args.repeats} runs")
    print(f"{'policy':<11} {'job':<16} {'alone s':>8} {'together s':>11} {'ratio':>6}")
    for pol in args.policies:
        env = POLICIES[pol]
        alone = {j: statistics.median(run_jobs([j], env)[0] for _ in range(args.repeats)) for j in ["fit", *args.jobs]}
        pairs = [("fit", "fit")] + ([("sample", "fit")] if "sample" in args.jobs else [])
        for a, b in pairs:
            times = [run_jobs([a, b], env) for _ in range(args.repeats)]
            ta = statistics.median(t[0] for t in times)
            tb = statistics.median(t[1] for t in times)
            print(f"{pol:<11} {a + ' beside ' + b:<16} {alone[a]:8.1f} {ta:11.1f} {ta / alone[a]:6.2f}", flush=True)
            if a != b:
                print(f"{pol:<11} {b + ' beside ' + a:<16} {alone[b]:8.1f} {tb:11.1f} {tb / alone[b]:6.2f}", flush=True)


if __name__ == "__main__":
    main()

"""Throughput of mass generation (meshes per minute) at 1 and 2 processes, with and without the export worker.

    python benchmarks/bench_mass.py [--run canyon] [-n 8] [--procs 1 2] [--workers 0 1] [--quality quick|preset]

Each row runs ``sin3dm-lite sample RUN -n N --out TMP`` (under ``torchrun
--nproc_per_node=P`` for P > 1) as a fresh command and times it from start to
end, process start-up, model loading and the final index page included; the
"steady" column excludes start-up (the first sample's landing to the last's,
from samples.jsonl, scaled to N-1 intervals). ``--quality quick`` decodes at
64 voxels, 5,000 faces, 256² textures, 20 DDIM steps, no pictures; ``preset``
uses the run's own settings. With CUDA the rows are repeated with ``--device cuda``.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

QUICK = ["--mesh-resolution", "64", "--faces", "5000", "--texture-size", "256", "--steps", "20", "--no-pictures"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def one(run: str, n: int, procs: int, workers: int, extra: list[str], device: str | None) -> dict:
    out = Path(tempfile.mkdtemp(prefix="bench-mass-")) / "s"
    launcher = (
        ["-m", "torch.distributed.run", f"--nproc_per_node={procs}", f"--master_port={free_port()}"]
        if procs > 1
        else []
    )
    cmd = [
        sys.executable,
        *launcher,
        "-m",
        "sin3dm_lite.cli",
        "sample",
        run,
        "-n",
        str(n),
        "--out",
        str(out),
        "--workers",
        str(workers),
        *extra,
    ] + (["--device", device] if device else [])
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    t0 = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit(f"failed: {' '.join(cmd)}\n{p.stderr[-2000:]}")
    records = [json.loads(line) for line in (out / "samples.jsonl").read_text().splitlines()]
    times = sorted(datetime.fromisoformat(r["time"]).timestamp() for r in records)
    steady = 60 * (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 and times[-1] > times[0] else float("nan")
    return {
        "procs": procs,
        "workers": workers,
        "device": device or "cpu",
        "n": n,
        "wall_s": wall,
        "per_min": 60 * n / wall,
        "steady_per_min": steady,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--run", default="canyon", help="run folder or shipped model")
    ap.add_argument("-n", type=int, default=8)
    ap.add_argument("--procs", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--workers", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--quality", choices=["quick", "preset"], default="quick")
    a = ap.parse_args()
    import torch

    extra = QUICK if a.quality == "quick" else []
    devices = [None] + (["cuda"] if torch.cuda.is_available() else [])
    print(
        f"{os.cpu_count()} CPU cores, load average {os.getloadavg()[0]:.1f}; run {a.run}, n={a.n}, "
        f"quality {a.quality}; OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '1')}"
    )
    print(f"{'device':7s} {'procs':>5s} {'workers':>7s} {'wall s':>8s} {'meshes/min':>10s} {'steady/min':>10s}")
    for device in devices:
        for procs in a.procs:
            for workers in a.workers:
                r = one(a.run, a.n, procs, workers, extra, device)
                print(
                    f"{r['device']:7s} {procs:5d} {workers:7d} {r['wall_s']:8.1f} {r['per_min']:10.1f} "
                    f"{r['steady_per_min']:10.1f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()

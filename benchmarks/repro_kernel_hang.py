"""Reproduce the notebook stall of issue 9 (a kernel idling while the notebook runner waits).

    python benchmarks/repro_kernel_hang.py [--runs 3] [--cells 150] [--timeout 60] [--busy 2] [--sliced]
    PYTHONPATH=/path/to/unpacked/ipykernel-7.3.0 python benchmarks/repro_kernel_hang.py --busy 2   # an older kernel

It writes a notebook whose cells do what our widget panels do (an
``ipywidgets.Output`` with ``clear_output(wait=True)`` and a figure inside, a
slider whose value changes), runs it ``--runs`` times with nbclient (what nbmake
uses) and prints per run: the time, and the longest wait between one cell going
idle and the next one starting in the kernel (the kernel's own timestamps).
``--busy N`` keeps N busy-loop processes running meanwhile (CI's two cores
while a notebook trains); ``--sliced`` applies notebooks/conftest.py's fix.

Measured on the 2-core machine, 150 cells, timeout 60 s (see notebooks/conftest.py):
* quiet: every run ~3 s, ipykernel 7.3.0 and 7.4.0 alike;
* --busy 2, ipykernel 7.4.0: runs of 364 s (six 60.0 s stalls: each request left the client
  only when its poll timed out, then the cell ran in milliseconds) and 67 s (one stall), and a
  run where nbclient gave up on the kernel;
* --busy 2 --sliced: 5 of 5 runs in 3.8-7.5 s, the longest stall 1.0 s;
* --busy 2 (an earlier loop, 15 s timeout) with ipykernel 7.3.0: 4 of 11 runs hung past the timeout.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

import nbformat
from nbclient import NotebookClient

SETUP = (
    "import ipywidgets as w\nfrom IPython.display import display, clear_output\n"
    "import matplotlib\nmatplotlib.use('agg')\nimport matplotlib.pyplot as plt"
)
CELL = (
    "o = w.Output()\nwith o:\n    clear_output(wait=True)\n    f = plt.figure(figsize=(1, 1)); display(f); plt.close(f)\n"
    "s = w.IntSlider(value={i})\ndisplay(w.VBox([s, o]))\ns.value = {j}"
)


def widget_notebook(cells: int) -> nbformat.NotebookNode:
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell(SETUP)] + [
        nbformat.v4.new_code_cell(CELL.format(i=i, j=i + 1)) for i in range(cells)
    ]
    return nb


def kernel_version() -> str:
    """The ipykernel the kernel will import (PYTHONPATH is passed on to it)."""
    return subprocess.run(
        [sys.executable, "-c", "import ipykernel; print(ipykernel.__version__)"], capture_output=True, text=True
    ).stdout.strip()


def longest_stall(nb) -> float:
    """Seconds between one cell's idle and the next cell's busy, at most (the kernel's timestamps)."""

    def ts(text):
        return datetime.fromisoformat(text.replace("Z", "+00:00")).timestamp()

    times = [
        (ts(c.metadata["execution"]["iopub.status.busy"]), ts(c.metadata["execution"]["iopub.status.idle"]))
        for c in nb.cells
        if "iopub.status.busy" in c.metadata.get("execution", {})
    ]
    return max((b - prev_idle for (_, prev_idle), (b, _) in zip(times, times[1:])), default=0.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--cells", type=int, default=150)
    ap.add_argument("--timeout", type=int, default=60, help="seconds per cell (nbclient's timeout)")
    ap.add_argument("--busy", type=int, default=0, help="busy-loop processes to run meanwhile")
    ap.add_argument("--sliced", action="store_true", help="poll in 1 s slices (notebooks/conftest.py)")
    a = ap.parse_args()
    if a.sliced:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "notebooks"))
        from conftest import slice_kernel_polls

        slice_kernel_polls()
    print(
        f"ipykernel {kernel_version()}: {a.runs} runs of {a.cells} widget cells, {a.timeout} s per cell, "
        f"{a.busy} busy processes, {'sliced' if a.sliced else 'plain'} polls"
    )
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(a.busy)]
    try:
        with tempfile.TemporaryDirectory() as d:
            for r in range(a.runs):
                nb = widget_notebook(a.cells)
                t = time.perf_counter()
                try:
                    NotebookClient(
                        nb,
                        timeout=a.timeout,
                        kernel_name="python3",
                        record_timing=True,
                        resources={"metadata": {"path": d}},
                    ).execute()
                    print(
                        f"run {r + 1}: ok in {time.perf_counter() - t:.1f} s, longest stall between cells "
                        f"{longest_stall(nb):.1f} s",
                        flush=True,
                    )
                except Exception as e:  # a timeout, or nbclient giving up on the kernel
                    print(
                        f"run {r + 1}: FAILED after {time.perf_counter() - t:.1f} s: {type(e).__name__}: "
                        f"{str(e).strip().splitlines()[0][:80] if str(e).strip() else ''}",
                        flush=True,
                    )
    finally:
        for h in hogs:
            h.kill()


if __name__ == "__main__":
    main()

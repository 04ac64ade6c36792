"""Where the calibration judges: on the fit's own grid (what ``fit`` does) or at the paper's 128 voxels.

For each run and each grid it calibrates the run's diversity afresh (nothing
is saved) and prints the near copy's scores, the choice, the smoothed
LP-IoU / LP-F and the samples' G-Div there, and the time. On the fit's grid the
reference is the training grid (as ``fit`` does); on any other grid it is the
input mesh voxelised there (``sin3dm-lite calibrate RUN --resolution 128``).
Run it on a quiet machine; docs/calibration.md keeps the figures.

    python benchmarks/bench_calibrate_grid.py runs/ruin runs/canyon --resolutions 64 128
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from sin3dm_lite import Sin3DM
from sin3dm_lite.data.grid import load_grid


def calibrate_at(model: Sin3DM, run, resolution: int):
    """The calibration of ``model`` judged at ``resolution`` voxels, and its time in seconds."""
    grid = model.grid_resolution
    reference = load_grid(run / "grid.npz").sdf < 0 if resolution == grid else None
    t0 = time.perf_counter()
    cal = model.calibrate(reference, resolution=None if resolution == grid else resolution, progress=False)
    return cal, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+", help="fitted run folders (with grid.npz and their input mesh)")
    ap.add_argument("--resolutions", type=int, nargs="+", default=[64, 128], help="grids to judge on")
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    print("| run | grid | near copy LP-IoU / LP-F | choice | smoothed LP-IoU / LP-F there | G-Div there | time |")
    print("|---|---|---|---|---|---|---|")
    for name in a.runs:
        run = Path(name)
        for resolution in a.resolutions:
            model = Sin3DM.load(run)  # afresh: a calibration changes the model's config
            cal, took = calibrate_at(model, run, resolution)
            near = cal.near_copy or {}
            at = cal.at_choice or {}
            print(
                f"| {run.name} | {cal.resolution} | {near.get('lp_iou', float('nan')):.3f} / "
                f"{near.get('lp_fscore', float('nan')):.3f} | {cal.diversity:.2f} | {at.get('lp_iou', float('nan')):.3f}"
                f" / {at.get('lp_fscore', float('nan')):.3f} | {at.get('g_div', float('nan')):.3f} | {took:.0f} s |",
                flush=True,
            )


if __name__ == "__main__":
    main()

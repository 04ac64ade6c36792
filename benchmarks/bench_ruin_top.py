"""Does the ruin keep its staircase? The top of its wall around the tower, measured at 128 voxels.

The paper's patch scores hardly see the ruined tower's broken top (a small
share of its surface patches), which is what the eye sees first: flat treads
joined by sharp vertical risers. For every voxel column of the wall (above
the slab) this takes the wall's top height, bins the columns by their angle
around the tower's axis (1° bins) and reports:

* **treads**: the share of 8° arcs whose top varies by at most one voxel
  (flat; a slanted or ragged rim has few);
* **risers**: steps of at least 3 voxels between neighbouring 1° bins (sharp
  vertical edges; the input's broken top has one at each step);
* **top range**: the highest minus the lowest top (how broken the rim is);
* **openings**: the windows, as cells of angle (1°) × height (1 voxel) in the windows' band (38-66 % of the
  height) where a radial line through the wall meets no solid voxel, counted where the wall stands above the
  band (a dent where a window was does not count).

For the input mesh, the run's reconstruction (its own latent decoded) and its
samples at a few diversities (8 each, seed 0, decoded at 128 voxels).

    python benchmarks/bench_ruin_top.py --run runs/ruin --mesh ruin.stl --diversity 0.05 0.2 0.31
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

RESOLUTION = 128


def top_profile(grid: np.ndarray, up: int = 1, bins: int = 360) -> np.ndarray:
    """The wall's top height per 1° of angle around the tower's axis (NaN where no wall stands)."""
    g = np.moveaxis(np.asarray(grid, bool), up, -1)  # (a, b, height)
    height = g.shape[-1]
    filled = g.any(-1)
    top = np.where(filled, height - 1 - np.argmax(g[..., ::-1], axis=-1), -1)
    wall = top > 0.25 * top.max()  # the tower's columns, not the slab's
    a, b = np.nonzero(wall)
    angle = np.degrees(np.arctan2(b - b.mean(), a - a.mean())) % 360
    which = (angle * bins / 360).astype(int) % bins
    profile = np.full(bins, np.nan)
    np.fmax.at(profile, which, top[a, b].astype(float))
    return profile


def staircase(profile: np.ndarray, arc: int = 8, riser: float = 3.0) -> dict:
    """Treads (share of ``arc``° arcs flat to a voxel), risers (jumps ≥ ``riser`` voxels) and the top's range."""
    p = np.asarray(profile, float)
    n = len(p)
    windows = np.stack([np.roll(p, -k) for k in range(arc)])  # each column: one arc
    whole = windows[:, ~np.isnan(windows).any(0)]  # the arcs where the wall stands all along
    flat = whole.max(0) - whole.min(0) <= 1.0
    jumps = np.abs(np.roll(p, -1) - p)
    return {
        "treads": float(flat.mean()) if flat.size else 0.0,
        "risers": int(np.sum(jumps[~np.isnan(jumps)] >= riser)),
        "range": float(np.nanmax(p) - np.nanmin(p)),
        "bins": n,
    }


def openings(grid: np.ndarray, up: int = 1, band: tuple[float, float] = (0.38, 0.66)) -> int:
    """Through-openings in the windows' band: (1° × 1 voxel) cells where a radial line through the wall is empty."""
    g = np.moveaxis(np.asarray(grid, bool), up, -1)  # (a, b, height)
    ys = np.flatnonzero(g.any((0, 1)))
    y0, height = ys[0], ys[-1] - ys[0]
    a, b = np.nonzero(g[..., y0 + height // 3])  # the wall's ring a third of the way up
    ca, cb = a.mean(), b.mean()
    r = np.hypot(a - ca, b - cb)
    radii = np.linspace(np.percentile(r, 2) - 2, np.percentile(r, 98) + 2, 24)  # through the wall, a voxel beyond
    theta = np.radians(np.arange(360))[:, None]
    ia = np.clip(np.round(ca + radii * np.cos(theta)).astype(int), 0, g.shape[0] - 1)  # (360, 24)
    ib = np.clip(np.round(cb + radii * np.sin(theta)).astype(int), 0, g.shape[1] - 1)
    lo, hi = y0 + int(band[0] * height), y0 + int(band[1] * height)
    top = np.where(g.any(-1), g.shape[-1] - 1 - np.argmax(g[..., ::-1], axis=-1), -1)
    stands = top[ia, ib].max(1) > hi  # the wall goes on above the band at this angle
    return int(sum((~g[ia, ib, y].any(1) & stands).sum() for y in range(lo, hi)))


def row(label: str, grids) -> str:
    s = [staircase(top_profile(g)) for g in grids]
    treads = np.array([x["treads"] for x in s])
    risers = np.array([x["risers"] for x in s])
    ranges = np.array([x["range"] for x in s])
    holes = np.array([openings(g) for g in grids])
    return (
        f"| {label} | {treads.mean():.2f} ({treads.min():.2f}-{treads.max():.2f}) | "
        f"{risers.mean():.1f} ({risers.min()}-{risers.max()}) | {ranges.mean():.0f} | "
        f"{holes.mean():.0f} ({holes.min()}-{holes.max()}) |"
    )


def main() -> None:
    from sin3dm_lite import Sin3DM
    from sin3dm_lite.data.source import resolve_mesh

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--run", required=True, help="a fitted run folder of a ruin-like shape (y up)")
    ap.add_argument("--mesh", required=True, help="its input mesh file")
    ap.add_argument("--diversity", type=float, nargs="+", default=[0.05, 0.2, 0.31])
    ap.add_argument("-n", type=int, default=8)
    a = ap.parse_args()
    torch.set_num_threads(1)
    model = Sin3DM.load(a.run)
    print(f"at {RESOLUTION} voxels; mean (min-max) over the shapes")
    print(
        "| shapes | treads (share of 8° arcs flat to a voxel) | risers (≥ 3 voxels) | top range (voxels) | "
        "openings (1° × 1-voxel cells) |"
    )
    print("|---|---|---|---|---|")
    print(row("input mesh", [model.input_occupancy(resolve_mesh(a.mesh), RESOLUTION)]))
    recon = model.occupancy(model.input_sample(), RESOLUTION, mesh_resolution=RESOLUTION)
    print(row("reconstruction", recon), flush=True)
    for d in a.diversity:
        samples = model.sample(a.n, diversity=d, seed=0, progress=False)
        print(
            row(f"{a.n} samples at {d:g}", model.occupancy(samples, RESOLUTION, mesh_resolution=RESOLUTION)), flush=True
        )


if __name__ == "__main__":
    main()

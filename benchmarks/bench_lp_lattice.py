"""What the paper's LP-IoU / LP-F measure on a shape: how much of them is the input's lattice phase.

The paper's local-patch metrics (SSG's evaluation code) take 11³ patches on a
stride-5 lattice in both shapes. This prints, at 128 voxels:

* **moved copies**: the input itself, moved by a fraction or a few whole
  voxels along each axis before it is voxelised (a perfect copy, off the
  input's lattice), scored by the paper's LP and by the labelled variant that
  is not in the paper (``metrics.lp_scores_any_offset``: the input's patches at
  every voxel);
* **the family**: the same procedural shape with other seeds (other broken
  tops for the ruin; other terraces for the canyon, ...): what real variants
  score, G-Div beside both LPs;
* with ``--run RUN --mesh MESH``: a fitted run's samples at a few
  diversities, G-Div and both LPs against the input mesh at 128 voxels (each
  sample's mesh decoded at 128, as ``calibrate --resolution 128`` does).

Run it on a quiet machine; docs/judging-samples.md "What LP-IoU measures" keeps the figures.

    python benchmarks/bench_lp_lattice.py --shapes ruin canyon wall colonnade tiles
    python benchmarks/bench_lp_lattice.py --shapes --run runs/ruin --mesh ruin.stl --diversity 0.05 0.25 0.31 0.36
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from sin3dm_lite import metrics
from sin3dm_lite.examples import build_example
from sin3dm_lite.examples.ruin import build_ruin

RESOLUTION = 128


def shape_builder(name: str):
    """``seed -> mesh`` for the ruin, the square keep (the ruin on a square plan) or a built-in example."""
    if name == "ruin":
        return build_ruin
    if name == "keep":
        return lambda seed: build_ruin(seed, square=True)
    return lambda seed: build_example(name, seed)


def occupancy_maker(mesh, resolution: int = RESOLUTION, supersample: int = 1):
    """``(mesh, shift) -> grid``: meshes voxelised in one box around ``mesh`` (6 % margin), moved by ``shift`` voxels.

    ``supersample`` 2 voxelises the paper's way (a voxel is solid when any of its 2³ sub-voxels is inside).
    """
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    pad = 0.06 * (hi - lo).max()
    box = np.concatenate([lo - pad, hi + pad])
    voxel = (box[3:] - box[:3]).max() / resolution

    def occupancy(m, shift=(0.0, 0.0, 0.0)) -> np.ndarray:
        moved = box - np.tile(np.asarray(shift, float) * voxel, 2)  # the box back = the mesh forward
        return metrics.input_occupancy((m.vertices, m.faces), moved, resolution, supersample)

    return occupancy


def both_lps(reference: np.ndarray, grids: list) -> str:
    paper, any_offset = metrics.lp_scores(reference, grids), metrics.lp_scores_any_offset(reference, grids)
    return (
        f"{paper['lp_iou']:.3f} / {paper['lp_fscore']:.3f} | "
        f"{any_offset['lp_iou_any_offset']:.3f} / {any_offset['lp_fscore_any_offset']:.3f}"
    )


def shape_rows(name: str, moves, family: int, supersample: int = 1) -> None:
    build = shape_builder(name)
    occupancy = occupancy_maker(build(0), supersample=supersample)
    reference = occupancy(build(0))
    for d in moves:
        for axis in range(3):
            shift = [0.0, 0.0, 0.0]
            shift[axis] = d
            grid = occupancy(build(0), shift)
            print(f"| {name} | moved {d:g} voxel along {'xyz'[axis]} | - | {both_lps(reference, [grid])} |", flush=True)
    if family > 1:
        grids = [occupancy(build(seed)) for seed in range(1, family + 1)]
        print(f"| {name} | family (seeds 1-{family}) | {metrics.g_div(grids):.3f} | {both_lps(reference, grids)} |")


def run_rows(run: str, mesh: str, diversities, n: int, supersample: int = 1) -> None:
    from sin3dm_lite import Sin3DM
    from sin3dm_lite.data.source import resolve_mesh

    model = Sin3DM.load(run)
    reference = model.input_occupancy(resolve_mesh(mesh), RESOLUTION, supersample=supersample)
    for d in diversities:
        t0 = time.perf_counter()
        samples = model.sample(n, diversity=d, seed=0, progress=False)
        grids = model.occupancy(samples, RESOLUTION, mesh_resolution=RESOLUTION, supersample=supersample)
        took = time.perf_counter() - t0
        print(
            f"| {run} | {n} samples at {d:g} ({took:.0f} s) | {metrics.g_div(grids):.3f} | {both_lps(reference, grids)} |",
            flush=True,
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--shapes", nargs="*", default=[], help="ruin and/or built-in examples (moved copies, family)")
    ap.add_argument("--moves", type=float, nargs="+", default=[0.25, 1, 2, 4, 5], help="voxels at 128")
    ap.add_argument("--family", type=int, default=8, help="other seeds of each shape (0: none)")
    ap.add_argument("--run", help="a fitted run folder: its samples at --diversity")
    ap.add_argument("--mesh", help="the run's input mesh file or built-in example name")
    ap.add_argument("--diversity", type=float, nargs="+", default=[0.05, 0.25, 0.31, 0.36, 0.42])
    ap.add_argument("-n", type=int, default=8)
    ap.add_argument(
        "--voxels",
        choices=["centres", "paper"],
        default="centres",
        help="a voxel's centre decides (the default), or the paper's way: any of its 2x2x2 sub-voxels inside",
    )
    a = ap.parse_args()
    if a.run and not a.mesh:
        ap.error("--run needs --mesh (the input mesh its samples are scored against)")
    torch.set_num_threads(1)
    supersample = metrics.PAPER_SUPERSAMPLE if a.voxels == "paper" else 1
    print(
        f"at {RESOLUTION} voxels ({a.voxels}); the paper's LP, then the variant not in the paper (input patches at every voxel)"
    )
    print("| shape | what | G-Div | LP-IoU / LP-F (paper) | LP-IoU / LP-F (any offset, not the paper's) |")
    print("|---|---|---|---|---|")
    for name in a.shapes:
        shape_rows(name, a.moves, a.family, supersample)
    if a.run:
        run_rows(a.run, a.mesh, a.diversity, a.n, supersample)


if __name__ == "__main__":
    main()

"""Where a tower's samples lose the input's patches: LP-IoU's misses by height, and which latent plane varies.

For a fitted run and its input mesh, at 128 voxels the paper's way (a voxel is
solid when any of its 2³ sub-voxels is inside), this prints for each
diversity: G-Div, LP-IoU / LP-F (paper) and their share of the near copy's,
and the share of surface patches missed in five slabs from the bottom up
(``metrics.lp_misses_by_band``). ``--family ruin`` (or ``keep``) adds the
shape's own variants (the generator's seeds 1-8: other broken tops over the
same walls) as the row to compare with.

``--keep PLANE ...`` samples with whole planes of the input's latent kept
(``control.keep_planes``, the masked sampler of outpainting): ``xz`` is the
ground plan, whose features every point of a vertical column shares. It shows
which plane carries the variation: on a tower, the ground plan.

``--set diffusion.n_resblocks=3 ...`` first retrains the run's denoiser with
other settings on its latent (``bench_levers.retrain``; the run is not changed).

Run it on a quiet machine; docs/thin-parts.md "Where the samples lose patches" keeps the figures.

    python benchmarks/bench_patch_bands.py --run RUN --mesh ruin.obj --family ruin --diversity 0.05 0.5 0.52
    python benchmarks/bench_patch_bands.py --run RUN --mesh ruin.obj --keep xz --diversity 0.05 0.5 0.6
    python benchmarks/bench_patch_bands.py --run RUN --mesh keep.obj --set diffusion.n_resblocks=3 \
        diffusion.base_channels=16 diffusion.steps=1500 diffusion.batch_size=4 --diversity 0.05 0.7 1
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from bench_levers import retrain

from sin3dm_lite import Sin3DM, control, metrics
from sin3dm_lite.data.config import parse_settings
from sin3dm_lite.data.ruin import build_ruin
from sin3dm_lite.data.source import resolve_mesh
from sin3dm_lite.model.triplane import PLANES

RESOLUTION, SEEDS, N = 128, (0, 100), 8


def row(label: str, reference: np.ndarray, grids: list, g_div: float, near=None) -> tuple[float, float]:
    lp = metrics.lp_scores(reference, grids)
    bands = metrics.lp_misses_by_band(reference, grids)
    share = f" ({lp['lp_iou'] / near[0]:.0%} / {lp['lp_fscore'] / near[1]:.0%})" if near else ""
    missed = " ".join(f"{m:.0%}" for m in bands["missed"])
    print(f"| {label} | {g_div:.3f} | {lp['lp_iou']:.3f} / {lp['lp_fscore']:.3f}{share} | {missed} |", flush=True)
    return lp["lp_iou"], lp["lp_fscore"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--run", required=True, help="a fitted run folder")
    ap.add_argument("--mesh", required=True, help="the run's input mesh file or built-in example name")
    ap.add_argument("--family", choices=["ruin", "keep"], help="score the generator's seeds 1-8 too")
    ap.add_argument("--keep", nargs="*", default=[], choices=PLANES, help="whole planes of the input's latent kept")
    ap.add_argument("--diversity", type=float, nargs="+", default=[0.05, 0.5])
    ap.add_argument(
        "--set", nargs="*", default=[], help="denoiser settings to retrain with first, e.g. diffusion.n_resblocks=3"
    )
    a = ap.parse_args()
    if any(not k.startswith("diffusion.") for k in a.set):  # retrain() keeps the run's latent and decoder
        ap.error("--set takes denoiser settings only (diffusion.*): the run's autoencoder and latent are kept")
    torch.set_num_threads(1)
    model = Sin3DM.open(a.run)
    if a.set:
        fig = retrain(model, Path(a.run), model.config.updated(**parse_settings(a.set)))
        print(f"denoiser retrained with {' '.join(a.set)} in {fig['diffusion_s']:.0f} s", flush=True)
    ss = metrics.PAPER_SUPERSAMPLE
    reference = model.input_occupancy(resolve_mesh(a.mesh), RESOLUTION, supersample=ss)
    plan = control.keep_planes(model.latent, model.aabb, a.keep) if a.keep else None
    print(f"at {RESOLUTION} voxels, the paper's; {len(SEEDS) * N} samples (seeds {SEEDS}); kept: {a.keep or 'nothing'}")
    print("| what | G-Div | LP-IoU / LP-F (of the near copy) | missed, bottom to top slab |")
    print("|---|---|---|---|")
    if a.family:
        family = [
            model.input_occupancy(build_ruin(seed, square=a.family == "keep"), RESOLUTION, supersample=ss)
            for seed in range(1, 9)
        ]
        row("family (seeds 1-8)", reference, family, metrics.g_div(family))
    near = None
    for d in a.diversity:
        grids, g_divs = [], []
        for seed in SEEDS:
            samples = model.sample(N, seed=seed, diversity=d, progress=False, plan=plan)
            occ = model.occupancy(samples, [RESOLUTION], supersample=ss)[RESOLUTION]
            grids += occ
            g_divs.append(metrics.g_div(occ))
        scores = row(f"diversity {d:g}", reference, grids, float(np.mean(g_divs)), near)
        near = near or (scores if d <= 0.05 else None)


if __name__ == "__main__":
    main()

"""Can a fitted model's latent become another of the ruin's family, its decoder fixed? Which planes must change?

The generator's other seeds (`data.ruin.build_ruin`) give the same walls under another broken top. This fits
some planes of a run's latent (the others and the decoder fixed, Adam on the L1 error of the truncated SDF
at a 96-voxel grid, from the input's own latent) to one such family member, then prints at 128 voxels (the
paper's voxels) the IoU to the member and to the input, and LP-IoU against the member with its misses by
height slab (`metrics.lp_misses_by_band`): whether the new top could be written, and whether the walls under
it stayed where they were.

Run it on a quiet machine; docs/thin-parts.md "Where the samples lose patches" keeps the figures.

    python benchmarks/bench_family_fit.py --run RUN --planes xz --steps 600
    python benchmarks/bench_family_fit.py --run RUN --planes xy yz --steps 1200
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from scipy.ndimage import binary_dilation, binary_erosion, distance_transform_edt

from sin3dm_lite import Sin3DM, metrics
from sin3dm_lite.data.ruin import build_ruin
from sin3dm_lite.model.triplane import PLANES, Triplane
from sin3dm_lite.sampling import Samples

FIT_VOXELS, EVAL_VOXELS = 96, 128


def target_tsdf(occupancy: np.ndarray, threshold: float) -> np.ndarray:
    """The truncated signed distance (normalised units, negative inside) of an occupancy grid over a [-1, 1] box."""
    voxel = 2.0 / max(occupancy.shape)
    outside = distance_transform_edt(~occupancy) - 0.5 * ~occupancy
    inside = distance_transform_edt(occupancy) - 0.5 * occupancy
    return np.clip((outside - inside) * voxel, -threshold, threshold)


def fit_planes(model: Sin3DM, target: np.ndarray, planes, steps: int, lr: float, seed: int = 0) -> Triplane:
    """``planes`` of the model's latent fitted to ``target``'s SDF, everything else fixed."""
    rng = np.random.default_rng(seed)
    shape = target.shape
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), -1).reshape(-1, 3)
    points = torch.from_numpy(((idx + 0.5) / np.array(shape) * 2 - 1).astype(np.float32))
    threshold = float(model.decoder.threshold)
    sdf = torch.from_numpy(target_tsdf(target, threshold).reshape(-1).astype(np.float32))
    band = (binary_dilation(target, iterations=2) & ~binary_erosion(target, iterations=2)).reshape(-1)
    near, far = np.flatnonzero(band), np.flatnonzero(~band)
    free = {n: torch.nn.Parameter(p.clone()) for n, p in zip(PLANES, model.latent.planes) if n in planes}
    opt = torch.optim.Adam(free.values(), lr=lr)
    for p in model.decoder.parameters():
        p.requires_grad_(False)
    voxel = 2.0 / max(shape)
    for step in range(steps):
        latent = Triplane(*[free.get(n, p) for n, p in zip(PLANES, model.latent.planes)])
        pick = np.concatenate([rng.choice(near, 12_000), rng.choice(far, 4_000)])
        got = model.decoder.query_sdf(model.decoder.prepare(latent, texture=False), points[pick][None])[0]
        loss = (got.clamp(-threshold, threshold) - sdf[pick]).abs().mean() / voxel
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % 200 == 0 or step == steps - 1:
            print(f"  step {step}: mean SDF error {loss.item():.3f} voxel at {FIT_VOXELS}", flush=True)
    return Triplane(*[free.get(n, p).detach() for n, p in zip(PLANES, model.latent.planes)])


def describe(label: str, grid: np.ndarray, member: np.ndarray, reference: np.ndarray) -> None:
    bands = metrics.lp_misses_by_band(member, grid)
    print(
        f"| {label} | {metrics.iou(grid, member):.3f} | {metrics.iou(grid, reference):.3f} | {bands['lp_iou']:.3f} | "
        + " ".join(f"{m:.0%}" for m in bands["missed"])
        + " |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--run", required=True, help="a run fitted to the ruin (or, with --square, the keep)")
    ap.add_argument("--square", action="store_true", help="the square keep's family instead of the round ruin's")
    ap.add_argument("--member", type=int, default=1, help="the family member: the generator's seed")
    ap.add_argument("--planes", nargs="+", default=["xz"], choices=PLANES, help="the planes fitted")
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--lr", type=float, default=1e-3)
    a = ap.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    model = Sin3DM.open(a.run)
    member_mesh = build_ruin(a.member, square=a.square)
    print(f"fitting {'+'.join(a.planes)} to family member {a.member} ({a.steps} steps)")
    latent = fit_planes(model, model.input_occupancy(member_mesh, FIT_VOXELS), a.planes, a.steps, a.lr)
    ss = metrics.PAPER_SUPERSAMPLE
    reference = model.input_occupancy(build_ruin(0, square=a.square), EVAL_VOXELS, supersample=ss)
    member = model.input_occupancy(member_mesh, EVAL_VOXELS, supersample=ss)
    start, fitted = (
        model.occupancy(Samples(t, model.aabb), [EVAL_VOXELS], supersample=ss)[EVAL_VOXELS][0]
        for t in (model.latent, latent)
    )
    print("| latent | IoU to the member | IoU to the input | LP-IoU against the member | missed, bottom to top |")
    print("|---|---|---|---|---|")
    describe("the input's (the start)", start, member, reference)
    describe(f"{'+'.join(a.planes)} fitted", fitted, member, reference)
    describe("the member itself", member, member, reference)


if __name__ == "__main__":
    main()

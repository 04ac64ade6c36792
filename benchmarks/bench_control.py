"""Time each controlled-generation operation on a model (issue: controlled generation).

    python benchmarks/bench_control.py [--run canyon] [--repeats 3]

For retargeting, outpainting, local editing and patch duplication: the
seconds to sample one latent, and to sample plus turn it into a textured mesh
(decode, marching cubes, simplify, UV atlas, bake) with the run's sampling
settings; the median over ``--repeats`` runs (after one warm-up run), and how
much of the latent each request keeps. ``--run`` is a run folder or a shipped
model's name.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

from sin3dm_lite.app.pretrained import shipped_model
from sin3dm_lite.pipeline import Sin3DM

REQUESTS = {
    "resize 1.5×x": dict(resize=(1.5, 1.0, 1.0)),
    "outpaint 1.5×x, x-": dict(outpaint=(1.5, 1.0, 1.0), anchor="x-"),
    "regenerate x 0.35-0.65": dict(regenerate=((0.35, 0.0, 0.0), (0.65, 1.0, 1.0))),
    "duplicate x 0-0.3 → 0.6": dict(duplicate=(((0.0, 0.0, 0.0), (0.3, 1.0, 1.0)), (0.6, 0.0, 0.0))),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--run", default="canyon")
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    run = Path(a.run) if Path(a.run).is_dir() else shipped_model(a.run)
    model = Sin3DM.load(run)
    s = model.config.sampling
    print(
        f"{run.name}: preset '{model.config.name}', latent {model.latent.resolution}, DDIM {s.steps} steps, mesh "
        f"{s.mesh_resolution} voxels / {s.faces:,} faces / texture {s.texture_size}², {torch.get_num_threads()} threads"
    )
    print(f"{'operation':26s} {'latent':>14s} {'kept':>6s} {'sample s':>9s} {'+ mesh s':>9s}")
    for name, kw in REQUESTS.items():
        times, totals = [], []
        for r in range(a.repeats + 1):
            t = time.perf_counter()
            samples = model.sample(1, seed=r, progress=False, **kw)
            t_sample = time.perf_counter() - t
            model.to_mesh(samples, 0)
            if r:  # the first run warms up
                times.append(t_sample)
                totals.append(time.perf_counter() - t)
        plan = samples.plan
        kept = plan.kept().mean() if plan.mask is not None else 0.0
        print(
            f"{name:26s} {str(plan.resolution):>14s} {kept:6.0%} {statistics.median(times):9.2f} "
            f"{statistics.median(totals):9.1f}"
        )


if __name__ == "__main__":
    main()

"""Fit the `small` preset on each example and measure what users care about.

    python benchmarks/bench_samples.py [--examples canyon wall colonnade] [--runs runs/bench] [-n 8]

Per example: fit time (or the time recorded in an existing run folder's report),
reconstruction IoU, sampling time per sample (DDIM), decode + texture + export
time per textured mesh, and over n samples:
  * G-Div        mean pairwise (1 − IoU) of the samples' occupancy at 128 (0 = all identical);
  * IoU-to-input mean IoU of each sample with the input (≈1 = copies of the input);
  * LP-IoU/LP-F  share of the samples' 11³ surface patches that have a match (IoU / F-score > 0.95)
                 among the input's patches (local plausibility; 1 = every patch looks like the input).
Samples must be variations: G-Div clearly above 0 and IoU-to-input clearly below 1, with
LP-IoU / LP-F high.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from sin3dm_lite import metrics
from sin3dm_lite.export import export_mesh
from sin3dm_lite.pipeline import Sin3DM


def evaluate(model: Sin3DM, n: int, seed: int = 0, resolution: int = 128, export_dir: Path | None = None) -> dict:
    t = time.perf_counter()
    samples = model.sample(n, seed=seed, progress=False)
    t_sample = (time.perf_counter() - t) / n
    ref_mesh = model.to_mesh(model.input_sample(), 0, original_coords=False, vertex_colors=True)
    ref = metrics.voxelize(ref_mesh, model.aabb, resolution)
    vox, t_mesh = [], []
    for i in range(n):
        t = time.perf_counter()
        mesh = model.to_mesh(samples, i, original_coords=False)
        if export_dir is not None:
            export_mesh(mesh, export_dir / f"{i:03d}")
        t_mesh.append(time.perf_counter() - t)
        vox.append(metrics.voxelize(mesh, samples.aabb, resolution))
    lp = metrics.lp_scores(ref, vox)
    var = metrics.variation_scores(ref, vox)
    return {
        "sample_s": t_sample,
        "mesh_export_s": float(np.mean(t_mesh)),
        "g_div": var["g_div"],
        "iou_to_input": var["iou_to_input"],
        "lp_iou": lp["lp_iou"],
        "lp_f": lp["lp_fscore"],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--examples", nargs="+", default=["canyon", "wall", "colonnade"])
    ap.add_argument("--runs", default="runs/bench", help="run folders (reused when they exist)")
    ap.add_argument("--preset", default="small")
    ap.add_argument("-n", type=int, default=8)
    ap.add_argument("--export", action="store_true", help="also write the meshes next to the run folders")
    a = ap.parse_args()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    rows = []
    for name in a.examples:
        run = Path(a.runs) / f"{name}_{a.preset}"
        if (run / "model.pt").exists():
            model = Sin3DM.load(run)
        else:
            model = Sin3DM.fit(name, preset=a.preset, out=run, progress=False)
        rep = model.report
        fit_s = sum(rep["timings_s"].values())
        out = run / "samples" if a.export else None
        r = evaluate(model, a.n, export_dir=out)
        r.update(example=name, fit_s=fit_s, recon_iou=rep["reconstruction"]["occupancy_iou"])
        rows.append(r)
        print(
            f"{name:10s} fit {fit_s:6.0f} s | recon IoU {r['recon_iou']:.3f} | sample {r['sample_s']:.2f} s"
            f" + mesh/texture/export {r['mesh_export_s']:.1f} s per mesh | G-Div {r['g_div']:.3f}"
            f" | IoU to input {r['iou_to_input']:.3f} | LP-IoU {r['lp_iou']:.3f} | LP-F {r['lp_f']:.3f}",
            flush=True,
        )
    Path(a.runs).mkdir(parents=True, exist_ok=True)
    (Path(a.runs) / "bench_samples.json").write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()

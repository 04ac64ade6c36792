"""Fit a preset on each input and measure what users care about (issue: real variations on a laptop).

    python benchmarks/bench_samples.py [--inputs canyon wall colonnade my.obj] [--runs runs/bench] [-n 8]
    python benchmarks/bench_samples.py --inputs canyon --diversity 0.2 0.4 0.6 0.8 1.0   # the knob's curve
    python benchmarks/bench_samples.py --seeds 0 100 200   # 3 × 8 samples: the figures' spread over sample seeds

Per input: fit time per stage (or the one recorded in an existing run folder),
reconstruction IoU, time per mesh (sampling + decode + texture + export), and
over n DDIM samples, each labelled by what it is compared with:

* G-Div       mean pairwise (1 − IoU) among the samples (0 = all identical);
* IoU→input   mean IoU of each sample with the input (≈ 1 = copies);
* LP-IoU/LP-F share of the samples' 11³ surface patches whose best match among the
              **input mesh's** patches has IoU / F-score > 0.95 (the paper's metrics;
              the input voxelised at the same resolution by its winding number; --voxels paper:
              as the paper's evaluation code does, solid where any of a voxel's 2³ sub-voxels is inside);
* ceiling     the same LP metrics for the training grid itself (its marching-cubes
              mesh) against the input: what a perfect model of the grid could score.
              Where the input's detail is finer than the grid, the goal is 90 % of it;
* reconstruction vs input: the same LP metrics for the autoencoder's reconstruction of the
              input (the ceiling the diffusion stage can reach with this autoencoder);
* moved ¼ voxel  the LP metrics of the input against itself moved a quarter voxel along each
              axis: a perfect copy off the voxel lattice. Far below 1 where the input's flat
              faces lie near a layer of voxel centres (the axis-aligned examples at 64 voxels):
              there the LP metrics also punish sub-voxel shifts, not only lost detail;
* vs recon    LP metrics of the samples against the autoencoder's reconstruction instead of the input
              (softer: the model's own view of the shape; not the paper's metric);
* family      built-in examples only: the same figures for 8 other variants of the example (its
              generator with seeds 1-8: other merlon widths, river bends, column rings) against the
              input: how much shapes of the same kind differ, and how many of their patches match
              the input's. A reference for reading G-Div, not a goal.

Resolutions: the fit's grid resolution and 128 (the paper's evaluation grid).
Goals (issue 8): G-Div ≥ 0.20 with LP-F ≥ min(0.70, 0.9·ceiling) and
LP-IoU ≥ min(0.55, 0.9·ceiling) at the fit's resolution, recon IoU ≥ 0.95,
fit ≤ 300 s, ≤ 15 s per mesh.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from sin3dm_lite import metrics
from sin3dm_lite.data.box import grid_shape
from sin3dm_lite.data.config import parse_settings
from sin3dm_lite.data.grid import load_grid
from sin3dm_lite.data.source import resolve_mesh
from sin3dm_lite.formats.export import export_mesh
from sin3dm_lite.generate.extract import marching_cubes
from sin3dm_lite.pipeline import Sin3DM
from sin3dm_lite.presets import get_preset

#: points sampled per voxel when a mesh becomes voxels: 2, the paper's evaluation code (solid where any of 2³
#: sub-voxels is inside), or 1, the voxel centres (older tables in docs/); --voxels sets it
SUPERSAMPLE = {"supersample": metrics.PAPER_SUPERSAMPLE}

GOALS = {"g_div": 0.20, "lp_f": 0.70, "lp_iou": 0.55, "recon_iou": 0.95, "fit_s": 300.0, "mesh_s": 15.0}


def fit_or_load(source: str, preset: str, run: Path, settings=()) -> Sin3DM:
    """The run in ``run``, fitted first where it is not there; ``preset`` "default": the one ``fit`` takes without
    ``--preset`` (this machine's and this shape's), said as the fit says it."""
    if (run / "model.pt").exists():
        return Sin3DM.load(run)
    if preset == "default":
        from sin3dm_lite.auto.fit_default import default_preset
        from sin3dm_lite.data.source import resolve_mesh

        chosen = default_preset(mesh=resolve_mesh(source))
        print("\n".join(chosen.lines()), flush=True)
        preset = chosen.name
    cfg = get_preset(preset).updated(**parse_settings(settings)) if settings else preset
    return Sin3DM.fit(source, preset=cfg, out=run, progress=False)


def sample_grids(
    model: Sin3DM,
    n: int,
    resolutions,
    seed: int = 0,
    diversity: float | None = None,
    export: int = 0,
    export_dir: Path | None = None,
) -> dict:
    """Occupancy grids of n samples at each resolution, and the time per textured, exported mesh."""
    t = time.perf_counter()
    samples = model.sample(n, seed=seed, diversity=diversity, progress=False)
    sample_s = (time.perf_counter() - t) / n
    mesh_s = []
    for i in range(min(export, n)):  # the whole user path: decode, texture, export
        t = time.perf_counter()
        mesh = model.to_mesh(samples, i)
        export_mesh(mesh, (export_dir or Path("/tmp/bench_samples_export")) / f"{i:03d}")
        mesh_s.append(time.perf_counter() - t)
    occ = model.occupancy(samples, list(resolutions), **SUPERSAMPLE)  # the same meshes, without the texture
    return {"occ": occ, "sample_s": sample_s, "mesh_s": sample_s + float(np.mean(mesh_s)) if mesh_s else None}


def references(model: Sin3DM, source: str, run: Path, resolutions) -> dict:
    """Per resolution: the input's occupancy, the reconstruction's, and the training grid's (the ceiling)."""
    mesh = resolve_mesh(source)
    grid = load_grid(run / "grid.npz")
    data_mesh = marching_cubes(grid.sdf, grid.aabb)
    recs = model.occupancy(model.input_sample(), list(resolutions), **SUPERSAMPLE)
    out = {}
    for r in resolutions:
        inp = model.input_occupancy(mesh, r, **SUPERSAMPLE)
        data = metrics.voxelize(data_mesh, model.aabb, r, **SUPERSAMPLE)
        rec = recs[r][0]
        ceiling, ae = metrics.lp_scores(inp, [data]), metrics.lp_scores(inp, [rec])
        moved = metrics.lp_scores(inp, [_moved_input(model, mesh, r, axis) for axis in range(3)])
        out[r] = {
            "input": inp,
            "recon": rec,
            "moved_lp_iou": moved["lp_iou"],
            "moved_lp_f": moved["lp_fscore"],
            "ceiling_lp_iou": ceiling["lp_iou"],
            "ceiling_lp_f": ceiling["lp_fscore"],
            "ceiling_iou": metrics.iou(data, inp),
            "ae_lp_iou": ae["lp_iou"],
            "ae_lp_f": ae["lp_fscore"],
            "ae_iou": metrics.iou(rec, inp),
        }
    return out


def family(model: Sin3DM, source: str, refs: dict, n: int = 8) -> dict | None:
    """Per resolution of ``refs`` (:func:`references`): G-Div, IoU→input and LP against the input of the example's
    own variants (seeds 1..n)."""
    from sin3dm_lite.examples import build_example, list_examples

    if source not in list_examples():
        return None
    meshes = [build_example(source, seed) for seed in range(1, n + 1)]
    out = {}
    for r, ref in refs.items():
        occ = [model.input_occupancy(m, r, **SUPERSAMPLE) for m in meshes]
        var, lp = metrics.variation_scores(ref["input"], occ), metrics.lp_scores(ref["input"], occ)
        out[r] = {
            "g_div": var["g_div"],
            "iou_to_input": var["iou_to_input"],
            "lp_iou": lp["lp_iou"],
            "lp_f": lp["lp_fscore"],
        }
    return out


def _moved_input(model: Sin3DM, mesh, resolution: int, axis: int, voxels: float = 0.25) -> np.ndarray:
    """The input voxelised after moving it ``voxels`` of a voxel along ``axis``: a perfect copy, placed off the lattice.

    Moving the box the other way is the same thing, so the input's own voxelisation does the work."""
    box = np.array(model.aabb, np.float64)
    box[[axis, axis + 3]] -= voxels * (box[3] - box[0]) / grid_shape(box, resolution)[0]
    return model.input_occupancy(mesh, resolution, aabb=box, **SUPERSAMPLE)


def scores(refs: dict, occ: dict) -> dict:
    out = {}
    for r, ref in refs.items():
        lp_in = metrics.lp_scores(ref["input"], occ[r])
        lp_rec = metrics.lp_scores(ref["recon"], occ[r])
        var = metrics.variation_scores(ref["input"], occ[r])
        out[r] = {
            "g_div": var["g_div"],
            "iou_to_input": var["iou_to_input"],
            "lp_iou": lp_in["lp_iou"],
            "lp_f": lp_in["lp_fscore"],
            "ceiling_lp_iou": ref["ceiling_lp_iou"],
            "ceiling_lp_f": ref["ceiling_lp_f"],
            "goal_lp_iou": min(GOALS["lp_iou"], 0.9 * ref["ceiling_lp_iou"]),
            "goal_lp_f": min(GOALS["lp_f"], 0.9 * ref["ceiling_lp_f"]),
            "recon_lp_iou": lp_rec["lp_iou"],
            "recon_lp_f": lp_rec["lp_fscore"],
            "ae_lp_iou": ref["ae_lp_iou"],
            "ae_lp_f": ref["ae_lp_f"],
            "ae_iou": ref["ae_iou"],
            "moved_lp_iou": ref["moved_lp_iou"],
            "moved_lp_f": ref["moved_lp_f"],
        }
    return out


def save_projections(reference: np.ndarray, occ: list, path: Path, title: str = "") -> Path:
    """A PNG of the input and the samples seen from above (height along y) and from the front (depth along z)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grids = [reference, *occ]
    fig, axes = plt.subplots(2, len(grids), figsize=(1.6 * len(grids), 3.6), squeeze=False)
    for j, g in enumerate(grids):
        axes[0, j].imshow(g.sum(1).T, origin="lower", cmap="terrain")  # x right, z up: the top view
        axes[1, j].imshow(g.sum(2).T, origin="lower", cmap="bone")  # x right, y up: the front view
        axes[0, j].set_title("input" if j == 0 else f"{j - 1}", fontsize=8)
        for ax in axes[:, j]:
            ax.set_axis_off()
    fig.suptitle(title, fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _mark(ok: bool) -> str:
    return "✓" if ok else "✗"


def print_scores(label: str, s: dict) -> None:
    for r, v in s.items():
        print(
            f"  {label} @{r:<3d} G-Div {v['g_div']:.3f} {_mark(v['g_div'] >= GOALS['g_div'])} | IoU→input "
            f"{v['iou_to_input']:.3f} | vs input: LP-IoU {v['lp_iou']:.3f} {_mark(v['lp_iou'] >= v['goal_lp_iou'])}"
            f" LP-F {v['lp_f']:.3f} {_mark(v['lp_f'] >= v['goal_lp_f'])} | ceiling LP-IoU {v['ceiling_lp_iou']:.3f}"
            f" LP-F {v['ceiling_lp_f']:.3f} (goals {v['goal_lp_iou']:.2f} / {v['goal_lp_f']:.2f}) | reconstruction"
            f" vs input: IoU {v['ae_iou']:.3f} LP-IoU {v['ae_lp_iou']:.3f} LP-F {v['ae_lp_f']:.3f} | samples vs recon"
            f" (softer): LP-IoU {v['recon_lp_iou']:.3f} LP-F {v['recon_lp_f']:.3f} | the input moved ¼ voxel (a copy"
            f" off the lattice): LP-IoU {v['moved_lp_iou']:.3f} LP-F {v['moved_lp_f']:.3f}",
            flush=True,
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--inputs", "--examples", nargs="+", default=["canyon", "wall", "colonnade"], help="example names or mesh files"
    )
    ap.add_argument("--runs", default="runs/bench", help="run folders (reused when they exist)")
    ap.add_argument(
        "--preset",
        default="default",
        help="'default' (the one fit takes without --preset: this machine's and this shape's) or a preset's name "
        "(docs/ tables that name no preset and are older than measured.md's first used small)",
    )
    ap.add_argument("-n", type=int, default=8)
    ap.add_argument("--export", type=int, default=2, help="samples timed through texture + export")
    ap.add_argument(
        "--diversity",
        type=float,
        nargs="+",
        default=None,
        help="knob values: print G-Div / LP at each (default: the run's setting)",
    )
    ap.add_argument("--resolutions", type=int, nargs="+", default=None, help="default: the fit's and 128")
    ap.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=[0],
        help="sample seeds: n samples from each (8 samples' figures move by a few hundredths with the seed; "
        "several seeds print their mean and range)",
    )
    ap.add_argument(
        "--set",
        nargs="+",
        action="extend",
        default=[],
        metavar="SETTING",
        help="dotted settings changed from the preset, e.g. grid.resolution=96 (run folders get a suffix)",
    )
    ap.add_argument(
        "--voxels",
        choices=("centres", "paper"),
        default="paper",
        help="meshes to voxels: the paper's evaluation code's way (default, as `sin3dm-lite evaluate`: solid where "
        "any of 2x2x2 sub-voxels is inside) or the voxel centres (docs/ tables that name no way and are older than "
        "measured.md's first; a flat face on a layer of centres is kept or lost by rounding)",
    )
    a = ap.parse_args()
    SUPERSAMPLE["supersample"] = {"centres": 1, "paper": metrics.PAPER_SUPERSAMPLE}[a.voxels]
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, preset {a.preset}, n={a.n}, voxels: {a.voxels}"
    )
    rows = []
    for source in a.inputs:
        name = Path(source).stem
        tag = "".join(f"_{x}" for x in a.set).replace("=", "-")
        run = Path(a.runs) / f"{name}_{a.preset}{tag}"
        model = fit_or_load(source, a.preset, run, a.set)
        rep = model.report
        res = a.resolutions or sorted({model.config.grid.resolution, 128})
        refs = references(model, source, run, res)
        t = rep["timings_s"]
        fit_s = sum(t.values())
        recon = rep["reconstruction"]["occupancy_iou"]
        cal = rep.get("calibration")
        chose = f" → diversity {cal['diversity']:g}" if cal else ""
        print(
            f"{name}: fit {fit_s:.0f} s {_mark(fit_s <= GOALS['fit_s'])} ({_stages(t)}){chose} | recon IoU {recon:.3f} "
            f"{_mark(recon >= GOALS['recon_iou'])} | input vs its own grid @{res[0]}: IoU {refs[res[0]]['ceiling_iou']:.3f}"
        )
        fam = family(model, source, refs)
        for r, v in (fam or {}).items():
            print(
                f"  family @{r:<3d} (8 other variants of the example; a reference, not a goal) G-Div {v['g_div']:.3f}"
                f" | IoU→input {v['iou_to_input']:.3f} | vs input: LP-IoU {v['lp_iou']:.3f} LP-F {v['lp_f']:.3f}"
            )
        for d in a.diversity or [None]:
            label = f"default ({model.config.sampling.diversity:g})" if d is None else f"div {d:.2f}"
            for k, seed in enumerate(a.seeds):
                first = k == 0 and (d is None or d == a.diversity[0])
                s = sample_grids(
                    model,
                    a.n,
                    res,
                    seed=seed,
                    diversity=d,
                    export=a.export if first else 0,
                    export_dir=run / "samples",
                )
                sc = scores(refs, s["occ"])
                if s["mesh_s"] is not None:
                    print(
                        f"  {label}: {s['sample_s']:.2f} s sampling + decode/texture/export = {s['mesh_s']:.1f} s per "
                        f"mesh {_mark(s['mesh_s'] <= GOALS['mesh_s'])}"
                    )
                print_scores(label if len(a.seeds) == 1 else f"{label}, seed {seed}", sc)
                rows.append(
                    {
                        "input": name,
                        "preset": a.preset,
                        "diversity": d,
                        "seed": seed,
                        "fit_s": fit_s,
                        "default": f"default ({model.config.sampling.diversity:g})",
                        "timings_s": t,
                        "recon_iou": recon,
                        "sample_s": s["sample_s"],
                        "mesh_s": s["mesh_s"],
                        "family": {str(r): v for r, v in fam.items()} if fam else None,
                        "scores": {str(r): v for r, v in sc.items()},
                    }
                )
            if len(a.seeds) > 1:
                print_spread(label, rows[-len(a.seeds) :])
    Path(a.runs).mkdir(parents=True, exist_ok=True)
    (Path(a.runs) / "bench_samples.json").write_text(json.dumps(rows, indent=2))
    r0 = lambda row: row["scores"][min(row["scores"], key=int)]  # noqa: E731  scores at the fit's resolution
    print(
        "\n| input | diversity | seed | fit s (grid+AE+diff[+calibration]) | recon IoU | G-Div | IoU→input | LP-IoU | LP-F | ceiling "
        "LP-IoU/LP-F | family G-Div, LP-IoU/LP-F | s per mesh |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        v, t = r0(row), row["timings_s"]
        mesh_s = f"{row['mesh_s']:.1f}" if row["mesh_s"] else "-"
        stages = "+".join(f"{t[k]:.0f}" for k in STAGES if k in t)
        print(
            f"| {row['input']} | {row['diversity'] or row.get('default', 'default')} | {row['seed']} | "
            f"{row['fit_s']:.0f} ({stages}) | {row['recon_iou']:.3f} | {v['g_div']:.3f} | {v['iou_to_input']:.3f} | "
            f"{v['lp_iou']:.3f} | {v['lp_f']:.3f} | {v['ceiling_lp_iou']:.2f}/{v['ceiling_lp_f']:.2f} | {_family_cell(row)} | {mesh_s} |"
        )


STAGES = ("grid_s", "autoencoder_s", "diffusion_s", "calibrate_s")


def _stages(t: dict) -> str:
    """A fit's stage times: grid + autoencoder + diffusion, and the diversity calibration where the fit had one."""
    names = {
        "grid_s": "grid",
        "autoencoder_s": "autoencoder",
        "diffusion_s": "diffusion",
        "calibrate_s": "calibration",
    }
    return " + ".join(f"{names[k]} {t[k]:.0f}" for k in STAGES if k in t)


def print_spread(label: str, rows: list) -> None:
    """Mean and range over sample seeds of G-Div, LP-IoU and LP-F at each resolution."""
    for r in rows[0]["scores"]:
        parts = []
        for key, name in (("g_div", "G-Div"), ("lp_iou", "LP-IoU"), ("lp_f", "LP-F")):
            v = np.array([row["scores"][r][key] for row in rows])
            parts.append(f"{name} {v.mean():.3f} ({v.min():.3f}-{v.max():.3f})")
        print(f"  {label} @{int(r):<3d} mean over {len(rows)} sample seeds (range): " + " | ".join(parts))


def _family_cell(row: dict) -> str:
    if not row["family"]:
        return "-"
    f = row["family"][min(row["family"], key=int)]
    return f"{f['g_div']:.3f}, {f['lp_iou']:.2f}/{f['lp_f']:.2f}"


if __name__ == "__main__":
    main()

"""The paper's Table 1 and Table 2 at small scale, on the built-in examples (issue 12).

    python benchmarks/bench_tables.py [--inputs canyon wall colonnade] [--runs runs/tables] [-n 8] [--textured 4]
    python benchmarks/bench_tables.py --variants "small preset" "eps-prediction"      # some rows only

Table 1 (per input, the ``small`` preset): over n DDIM samples, G-Div, LP-IoU and
LP-F against the **input mesh** voxelised at the fit's resolution (the paper's
geometry metrics, benchmarks/bench_samples.py), and on renders of ``--textured``
textured samples the texture metrics of ``Sin3DM.evaluate`` (the weight-free
patch-SWD quality and render diversity always; SIFID / LPIPS with ``--weights``).

Table 2 (the paper's ablations, each retrained on the same grid; all but "w/o
encoder" also on the same latent, so only the denoiser differs):

* ``small preset``  2 ResBlocks, TriplaneConv **without** the cross-plane rollout
  (three plain 2D convolutions: this is the paper's "w/o TriplaneConv" row, which
  the small preset uses on purpose, README "Presets");
* ``with rollout``  TriplaneConv with its rollout (the paper's full block);
* ``eps-prediction`` the denoiser predicts the noise instead of x0;
* ``4 / 6 ResBlocks`` a wider receptive field;
* ``w/o encoder``   the planes optimised directly (an auto-decoder), then the denoiser.

A fit that switched to the thin-part settings (the colonnade: ``small+thin``, 96
voxels, 4 ResBlocks with the rollout, diversity 1.0) already has what two of these
rows add, so there they take the other side: ``w/o rollout`` and ``2 ResBlocks``.

Rows are written to RUNS/tables.json as they finish; a rerun skips rows that are
there, so a long run can be stopped and continued. Each row is measured at the
preset's diversity (0.7) and at 1.0 (pure noise, as in the paper).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from bench_samples import fit_or_load, references, sample_grids, scores

from sin3dm_lite import AutoencoderTrainer, reconstructed_grid, reconstruction_metrics
from sin3dm_lite.data.grid import load_grid
from sin3dm_lite.formats.export import export_mesh
from sin3dm_lite.formats.load import load_mesh
from sin3dm_lite.generate.extract import NoSurfaceError
from sin3dm_lite.model.diffusion import DiffusionTrainer
from sin3dm_lite.pipeline import Sin3DM

VARIANTS = {
    "small preset": {},
    "with rollout": {"diffusion.rollout": True},
    "eps-prediction": {"diffusion.prediction": "eps"},
    "4 ResBlocks": {"diffusion.n_resblocks": 4},
    "6 ResBlocks": {"diffusion.n_resblocks": 6},
    "w/o encoder": {"autoencoder.use_encoder": False},
}


def retrain(model: Sin3DM, run: Path, cfg, seed: int = 0, autoencoder: bool = False) -> dict:
    """Retrain ``model``'s denoiser with ``cfg`` in place (first its autoencoder on RUN's grid if ``autoencoder``).

    Returns the stage times (s), the final diffusion loss and, after an autoencoder, its reconstruction figures.
    """
    fig = {}
    if autoencoder:  # a new latent: retrain the autoencoder on RUN's grid
        grid = load_grid(run / "grid.npz")
        t = time.perf_counter()
        ae = AutoencoderTrainer(grid, cfg.autoencoder, seed=seed)
        ae.run(progress=False)
        fig["autoencoder_s"] = time.perf_counter() - t
        h0 = ae.latent()
        rec = reconstruction_metrics(reconstructed_grid(ae.model.decoder, h0, grid), grid)
        fig.update(recon_iou=rec["occupancy_iou"], color_psnr=rec["color_psnr"])
        model.decoder, model.latent = ae.model.decoder.eval(), h0
    t = time.perf_counter()
    trainer = DiffusionTrainer(model.latent, cfg.diffusion, seed=seed)
    trainer.run(progress=False)
    fig.update(diffusion_s=time.perf_counter() - t, final_loss=trainer.history["loss"][-1])
    model.config, model.denoiser = cfg, trainer.model_for_sampling
    return fig


def variant_changes(variant: str, cfg) -> tuple[str, dict]:
    """The row's label and the settings it changes in the fitted ``cfg`` (see the module's docstring)."""
    if variant == "small preset":
        return f"{cfg.name} preset", {}
    if variant == "with rollout" and cfg.diffusion.rollout:
        return "w/o rollout", {"diffusion.rollout": False}
    if variant == "4 ResBlocks" and cfg.diffusion.n_resblocks == 4:
        return "2 ResBlocks", {"diffusion.n_resblocks": 2}
    return variant, VARIANTS[variant]


PAPER = {  # the paper's figures (256 grid, 50 samples; Tables 1 and 2 average 10 shapes): G-Div, LP-IoU, LP-F, T-Div
    "canyon (paper, Table 1)": {"g_div": 0.166, "t_div": 0.218},
    "wall (paper, Table 1; another wall)": {"g_div": 0.078, "t_div": 0.048},
    "average of 10 (paper, Tables 1, 2)": {"g_div": 0.224, "lp_iou": 0.572, "lp_f": 0.699, "t_div": 0.133},
    "w/o TriplaneConv (paper, Table 2)": {"g_div": 0.310, "t_div": 0.171},
    "w/o encoder (paper, Table 2)": {"g_div": 0.355, "t_div": 0.179},
    "eps-prediction (paper, Table 2)": {"g_div": 0.402, "t_div": 0.187},
}


def textured(model: Sin3DM, samples, k: int, folder: Path) -> list[Path]:
    """Decode, texture and export the first k samples as GLB (reused when written; samples without a surface left out)."""
    paths = []
    for i in range(min(k, len(samples))):
        path = folder / f"{i:03d}" / "mesh.glb"
        if not path.exists():
            try:
                export_mesh(model.to_mesh(samples, i), path.parent, formats=("glb",))
            except NoSurfaceError:
                continue
        paths.append(path)
    return paths


def texture_scores(model: Sin3DM, paths: list[Path], weights: str | None) -> dict:
    """Sin3DM.evaluate's texture metrics of the saved meshes (the weight-free ones; SIFID / LPIPS with weights)."""
    report = model.evaluate([load_mesh(p) for p in paths], weights=weights, progress=False)
    names = ("patch_swd", "render_div", "sifid", "lpips")
    return {k: report["metrics"][k] for k in names if report["metrics"].get(k) is not None}


def measure(model: Sin3DM, source: str, run: Path, out: Path, a) -> dict:
    res = model.config.grid.resolution
    refs = references(model, source, run, [res])
    row = {}
    for d in (None, 1.0):
        if d is not None and model.config.sampling.diversity == d:  # the preset samples from pure noise already
            row[f"div {d}"] = row["default"]
            continue
        s = sample_grids(model, a.n, [res], diversity=d)
        sc = scores(refs, s["occ"])[res]
        key = "default" if d is None else f"div {d}"
        row[key] = {k: sc[k] for k in ("g_div", "iou_to_input", "lp_iou", "lp_f")}
    if a.textured:
        samples = model.sample(a.textured, seed=0, progress=False)
        t = time.perf_counter()
        paths = textured(model, samples, a.textured, out)
        row["texture"] = texture_scores(model, paths, a.weights) if paths else {}
        row["no_surface"] = a.textured - len(paths)
        row["texture_s"] = time.perf_counter() - t
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--inputs", nargs="+", default=["canyon", "wall", "colonnade"])
    ap.add_argument("--runs", default="runs/tables", help="run folders <input>_small (reused) and tables.json")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--preset", default="small", help="tiny: a quick check that the script runs")
    ap.add_argument("-n", type=int, default=8, help="samples for the geometry metrics")
    ap.add_argument("--textured", type=int, default=4, help="samples textured and rendered for the texture metrics")
    ap.add_argument("--weights", default=None, help="folder with the SIFID / LPIPS weight files (Sin3DM.evaluate)")
    a = ap.parse_args()
    runs = Path(a.runs)
    runs.mkdir(parents=True, exist_ok=True)
    table = runs / "tables.json"
    rows = json.loads(table.read_text()) if table.exists() else {}
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, n={a.n}, textured={a.textured}", flush=True)
    for source in a.inputs:
        name = Path(source).stem
        run = runs / f"{name}_{a.preset}"
        fit_or_load(source, a.preset, run)
        for variant in a.variants:
            key = f"{name} | {variant}"
            meshes = runs / "meshes" / name / variant.replace(" ", "_").replace("/", "")
            if key in rows:  # measured; add the texture metrics if they were not available then
                if not rows[key].get("texture"):
                    paths = sorted(meshes.glob("*/mesh.glb"))[: a.textured]
                    rows[key]["texture"] = texture_scores(Sin3DM.load(run), paths, a.weights) if paths else {}
                    table.write_text(json.dumps(rows, indent=2))
                continue
            model = Sin3DM.load(run)
            label, changes = variant_changes(variant, model.config)
            fig = {}
            if changes:
                fig = retrain(
                    model,
                    run,
                    model.config.updated(**changes),
                    autoencoder=any(k.startswith("autoencoder.") for k in changes),
                )
            row = {"input": name, "variant": label, "train": fig, **measure(model, source, run, meshes, a)}
            rows[key] = row
            table.write_text(json.dumps(rows, indent=2))
            d = row["default"]
            print(
                f"{name} | {label}: G-Div {d['g_div']:.3f} LP-IoU {d['lp_iou']:.3f} LP-F {d['lp_f']:.3f} | div 1.0: "
                f"{row['div 1.0']['g_div']:.3f} / {row['div 1.0']['lp_iou']:.3f} / {row['div 1.0']['lp_f']:.3f} | "
                f"texture {row.get('texture')} | {fig}",
                flush=True,
            )
    print_tables(rows)


def print_tables(rows: dict) -> None:
    tex = sorted({k for r in rows.values() for k in r.get("texture", {})})
    head = ["G-Div", "LP-IoU", "LP-F", *tex]
    print("\n| input | variant | " + " | ".join(head) + " | G-Div / LP-IoU / LP-F at diversity 1.0 |")
    print("|---|---|" + "---|" * (len(head) + 1))
    for r in rows.values():
        d, d1 = r["default"], r["div 1.0"]
        cells = [f"{d['g_div']:.3f}", f"{d['lp_iou']:.3f}", f"{d['lp_f']:.3f}"]
        cells += [f"{r.get('texture', {}).get(k, float('nan')):.3f}" for k in tex]
        print(
            f"| {r['input']} | {r['variant']} | "
            + " | ".join(cells)
            + f" | {d1['g_div']:.3f} / {d1['lp_iou']:.3f} / {d1['lp_f']:.3f} |"
        )
    print("\nThe paper's figures (T-Div is LPIPS; a weight-free render diversity is not comparable with it):")
    for label, p in PAPER.items():
        print(f"  {label}: " + ", ".join(f"{k} {v:.3f}" for k, v in p.items()))


if __name__ == "__main__":
    main()

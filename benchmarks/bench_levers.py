"""Retrain the diffusion stage of an existing run with other settings and score the samples.

    python benchmarks/bench_levers.py runs/bench/canyon_small canyon diffusion.steps=1000 diffusion.crop=16
    python benchmarks/bench_levers.py RUN SOURCE [setting=value ...] [-n 8] [--diversity 1.0]
    python benchmarks/bench_levers.py RUN wall autoencoder.steps=2000 --autoencoder-only --render pics/

The grid and the autoencoder (the latent) are reused from RUN, so one lever of
the denoiser (receptive field, rollout, crops, steps, EMA, ...) is measured at
a time; an ``autoencoder.*`` setting retrains the autoencoder on RUN's grid
first (and prints its reconstruction figures),  against the input mesh SOURCE (example name or file), with the metrics
of bench_samples.py at the fit's grid resolution. Prints one row.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
from bench_samples import print_spread, references, sample_grids, save_projections, scores

from sin3dm_lite import AutoencoderTrainer, reconstructed_grid, reconstruction_metrics
from sin3dm_lite.data.config import parse_settings
from sin3dm_lite.data.grid import load_grid
from sin3dm_lite.model.diffusion import DiffusionTrainer
from sin3dm_lite.pipeline import Sin3DM


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run")
    ap.add_argument("source")
    ap.add_argument("settings", nargs="*", help="dotted config settings, e.g. diffusion.crop=16")
    ap.add_argument("-n", type=int, default=8)
    ap.add_argument("--diversity", type=float, nargs="+", default=[1.0])
    ap.add_argument("--seed", type=int, default=0, help="training seed")
    ap.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=[0],
        help="sample seeds (8 samples' figures move by a few hundredths with them; several print the mean)",
    )
    ap.add_argument(
        "--resolutions",
        type=int,
        nargs="+",
        default=None,
        help="voxels to score at (default: the fit's grid; the paper scores at 128)",
    )
    ap.add_argument("--png", default=None, help="folder for a picture of the samples (top and front view)")
    ap.add_argument("--autoencoder-only", action="store_true", help="stop after the autoencoder's figures")
    ap.add_argument(
        "--render",
        default=None,
        help="folder for a hero view (PNG) of the new autoencoder's textured "
        "reconstruction: colour detail (a wall's mortar joints) that PSNR alone does not show",
    )
    a = ap.parse_args()
    tag = "_".join(a.settings).replace("=", "-").replace(".", "") or "as-fitted"  # picture file names
    model = Sin3DM.load(a.run)
    changes = parse_settings(a.settings)
    cfg = model.config.updated(**changes)
    fig = retrain(model, Path(a.run), cfg, seed=a.seed, autoencoder=any(k.startswith("autoencoder.") for k in changes))
    if "autoencoder_s" in fig:
        ref = references(model, a.source, Path(a.run), [cfg.grid.resolution])[cfg.grid.resolution]
        print(
            f"{Path(a.run).name} {' '.join(a.settings)}: autoencoder {fig['autoencoder_s']:.0f} s "
            f"({fig['autoencoder_s'] / cfg.autoencoder.steps:.3f} s/step) | recon IoU {fig['recon_iou']:.3f} | colour PSNR "
            f"{fig['color_psnr']:.1f} | reconstruction vs input: LP-IoU {ref['ae_lp_iou']:.3f} LP-F {ref['ae_lp_f']:.3f}",
            flush=True,
        )
        if a.render:
            from PIL import Image

            from sin3dm_lite.evaluate.render import render_hero

            path = Path(a.render) / f"{Path(a.run).name}_{tag}_reconstruction.png"
            path.parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(render_hero(model.to_mesh(model.input_sample(), 0), size=384)).save(path)
            print(f"reconstruction rendered: {path}", flush=True)
        if a.autoencoder_only:
            return
    train_s = fig["diffusion_s"]
    res = a.resolutions or [cfg.grid.resolution]
    refs = references(model, a.source, Path(a.run), res)
    for d in a.diversity:
        rows = []
        for seed in a.seeds:
            occ = sample_grids(model, a.n, res, seed=seed, diversity=d)["occ"]
            by_res = scores(refs, occ)
            for r, sc in by_res.items():
                if r != res[0]:
                    print(
                        f"  at {r} voxels: G-Div {sc['g_div']:.3f} | IoU→input {sc['iou_to_input']:.3f} | "
                        f"LP-IoU {sc['lp_iou']:.3f} | LP-F {sc['lp_f']:.3f}",
                        flush=True,
                    )
            sc = by_res[res[0]]
            rows.append(sc)
            if a.png:
                save_projections(
                    refs[res[0]]["input"],
                    occ[res[0]],
                    Path(a.png) / f"{Path(a.run).name}_{tag}_div{d}{f'_seed{seed}' if seed else ''}.png",
                    f"{' '.join(a.settings)} div {d} seed {seed}: G-Div {sc['g_div']:.3f} "
                    f"LP-IoU {sc['lp_iou']:.3f} LP-F {sc['lp_f']:.3f}",
                )
            print(
                f"{Path(a.run).name} {' '.join(a.settings) or '(as fitted)'} div {d}"
                f"{f' seed {seed}' if len(a.seeds) > 1 else ''} at {res[0]} voxels: diffusion {train_s:.0f} s "
                f"({train_s / max(cfg.diffusion.steps, 1):.3f} s/step, {torch.get_num_threads()} threads) | "
                f"G-Div {sc['g_div']:.3f} | IoU→input {sc['iou_to_input']:.3f} | LP-IoU {sc['lp_iou']:.3f} | "
                f"LP-F {sc['lp_f']:.3f} | ceiling {sc['ceiling_lp_iou']:.3f}/{sc['ceiling_lp_f']:.3f} | final loss "
                f"{fig['final_loss']:.4f}",
                flush=True,
            )
        if len(rows) > 1:
            print_spread(
                f"{Path(a.run).name} {' '.join(a.settings) or '(as fitted)'} div {d}",
                [{"scores": {res[0]: sc}} for sc in rows],
            )


if __name__ == "__main__":
    main()

"""The `paper` preset on one GPU (issue 8's GPU check): s/step per stage, peak memory, fit time, G-Div / LP at 256.

    python benchmarks/bench_gpu.py [--input canyon] [--preset paper] [--budget-s 300] [-n 8] [--out DIR]

A lent GPU session has minutes, not the paper's hours (2-3 h on an A6000), so the
script does two things and labels each figure with which one it comes from:

1. **Timing at the preset's real size.** One autoencoder trainer and one denoiser
   trainer are built exactly as a fit builds them (256-voxel grid, 65,536 points,
   batch 32 on the 128-texel latent) and timed over ``--timed`` steps after a
   warm-up (``bench_training.timed``; each step ends in a device sync). Peak GPU memory is read per
   stage. The denoiser is timed as the preset trains it (``paper``: bf16
   autocast and torch.compile on CUDA, the compile in its first step) and, for
   comparison, eager in fp32 (TF32 convolutions, PyTorch's default) and in bf16.
   The whole fit's time is the grid's measured time plus each stage's s/step
   times the preset's steps, plus the compile: an **extrapolation**.
2. **A truncated fit.** Each stage trains for as many steps as its share of
   ``--budget-s`` allows (at most the preset's), the denoiser's EMA decay lowered
   to 0.999 when it is cut short (0.9999 averages over ~10k steps, longer than a
   truncated run). Then ``-n`` DDIM samples are drawn and scored against the
   **input mesh** voxelised at 256 and 128 (G-Div among samples, IoU to the input,
   LP-IoU / LP-F: the paper's metrics, as in ``bench_samples.py``), and one sample
   is decoded, textured and exported (timed).

Writes ``gpu.json`` (updated after every stage, so a run cut off still leaves its
timings), ``projections.png`` and the exported sample into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_training import sync, timed  # noqa: E402  (a step ends in a device sync: the .tolist() of its losses)

from sin3dm_lite import metrics  # noqa: E402
from sin3dm_lite.app.device import get_device  # noqa: E402
from sin3dm_lite.app.fitting import grid_for  # noqa: E402
from sin3dm_lite.data.config import parse_settings  # noqa: E402
from sin3dm_lite.data.source import resolve_mesh  # noqa: E402
from sin3dm_lite.formats.export import export_mesh  # noqa: E402
from sin3dm_lite.model.autoencoder import AutoencoderTrainer  # noqa: E402
from sin3dm_lite.model.diffusion import DiffusionTrainer  # noqa: E402
from sin3dm_lite.pipeline import Sin3DM  # noqa: E402
from sin3dm_lite.presets import get_preset  # noqa: E402

SHORT_RUN_EMA = 0.999


def reset_peak(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats(dev)


def peak_gib(dev: torch.device) -> float | None:
    return torch.cuda.max_memory_allocated(dev) / 2**30 if dev.type == "cuda" else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--input", default="canyon", help="example name or mesh file")
    ap.add_argument("--preset", default="paper")
    ap.add_argument(
        "--set",
        nargs="+",
        action="extend",
        default=[],
        metavar="SETTING",
        help="dotted settings, e.g. autoencoder.steps=100",
    )
    ap.add_argument("--device", default=None, help="default: cuda when present")
    ap.add_argument("--budget-s", type=float, default=300.0, help="training seconds of the truncated fit, both stages")
    ap.add_argument("--ae-share", type=float, default=0.5, help="the autoencoder's share of the budget")
    ap.add_argument("--timed", type=int, default=20, help="timed steps per stage")
    ap.add_argument("-n", type=int, default=8, help="samples scored")
    ap.add_argument("--resolutions", type=int, nargs="+", default=[256, 128])
    ap.add_argument("--out", default="runs/bench_gpu")
    ap.add_argument("--timing-only", action="store_true", help="time the steps (and variants), skip the truncated fit")
    args = ap.parse_args()

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = get_preset(args.preset)
    if args.set:
        cfg = cfg.updated(**parse_settings(args.set))
    dev = get_device(args.device)
    res: dict = {
        "input": args.input,
        "preset": cfg.name,
        "device": str(dev),
        "device_name": torch.cuda.get_device_name(dev) if dev.type == "cuda" else "cpu",
        "torch": torch.__version__,
        "settings": args.set,
    }

    start = time.perf_counter()

    def save(stage: str) -> None:
        (out / "gpu.json").write_text(json.dumps(res, indent=2))
        print(f"[{time.perf_counter() - start:6.1f} s] {stage} done", flush=True)

    # ---- 1. timing at the preset's real size
    mesh = resolve_mesh(args.input)
    t = time.perf_counter()
    grid = grid_for(mesh, cfg, False)
    res["grid_s"], res["grid_shape"] = time.perf_counter() - t, list(grid.shape)
    save("grid")

    reset_peak(dev)
    ae = AutoencoderTrainer(grid, cfg.autoencoder, dev, cfg.seed)
    res["ae_s_per_step"] = timed(ae.step, args.timed, warmup=3)
    res["ae_peak_gib"] = peak_gib(dev)
    h = ae.latent()  # untrained, but the latent's size: the step time does not depend on its content
    res["latent_shape"] = list(h.resolution)
    del ae
    save("autoencoder timing")

    variants = {
        "package": cfg.diffusion,  # this preset's denoiser step (paper: bf16 autocast + torch.compile on CUDA)
        "fp32, not compiled": replace(cfg.diffusion, precision="fp32", compile=False),
        "bf16, not compiled": replace(cfg.diffusion, precision="bf16", compile=False),
    }
    for name, dcfg in variants.items():
        reset_peak(dev)
        dm = DiffusionTrainer(h, dcfg, dev, cfg.seed)
        t = time.perf_counter()
        dm.step()  # a compiled step compiles here
        res.setdefault("dm_variants", {})[name] = {
            "first_step_s": time.perf_counter() - t,
            "s_per_step": timed(dm.step, args.timed, warmup=3),
            "peak_gib": peak_gib(dev),
        }
        del dm
        save(f"denoiser timing ({name})")
    del h
    res["dm_s_per_step"] = res["dm_variants"]["package"]["s_per_step"]
    ae_steps, dm_steps = cfg.autoencoder.steps, cfg.diffusion.steps
    res["full_fit_s_extrapolated"] = (
        res["grid_s"]
        + res["ae_s_per_step"] * ae_steps
        + res["dm_variants"]["package"]["first_step_s"]
        + res["dm_s_per_step"] * dm_steps
    )
    save("timing")
    if args.timing_only:
        return
    # ---- 2. truncated fit
    n_ae = max(1, min(ae_steps, int(args.budget_s * args.ae_share / res["ae_s_per_step"])))
    n_dm = max(1, min(dm_steps, int(args.budget_s * (1 - args.ae_share) / res["dm_s_per_step"])))
    run_cfg = cfg.updated(**{"autoencoder.steps": n_ae, "diffusion.steps": n_dm})
    if n_dm < dm_steps and cfg.diffusion.ema_decay > SHORT_RUN_EMA:
        run_cfg = run_cfg.updated(**{"diffusion.ema_decay": SHORT_RUN_EMA})
    res["truncated_fit"] = {
        "autoencoder_steps": n_ae,
        "diffusion_steps": n_dm,
        "ema_decay": run_cfg.diffusion.ema_decay,
    }
    save("plan")
    reset_peak(dev)
    t = time.perf_counter()
    model = Sin3DM.fit(mesh, preset=run_cfg, device=dev, progress=False)
    res["truncated_fit"].update(
        total_s=time.perf_counter() - t,
        timings_s=model.report["timings_s"],
        reconstruction=model.report["reconstruction"],
        peak_gib=peak_gib(dev),
    )
    save("fit")

    # ---- samples, scored against the input mesh
    reset_peak(dev)
    t = time.perf_counter()
    samples = model.sample(args.n, seed=0, progress=False)
    sync(dev)
    res["sample_s_per_latent"] = (time.perf_counter() - t) / args.n
    t = time.perf_counter()
    export_mesh(model.to_mesh(samples, 0), out / "sample_000")
    res["decode_texture_export_s"] = time.perf_counter() - t
    save("sampling")
    occ = model.occupancy(samples, args.resolutions)
    rec = model.occupancy(model.input_sample(), args.resolutions)
    res["sampling_peak_gib"] = peak_gib(dev)
    scores = {}
    for r in args.resolutions:
        inp = model.input_occupancy(mesh, r)
        var, lp, lp_rec = (
            metrics.variation_scores(inp, occ[r]),
            metrics.lp_scores(inp, occ[r]),
            metrics.lp_scores(inp, rec[r]),
        )
        scores[r] = {
            "g_div": var["g_div"],
            "iou_to_input": var["iou_to_input"],
            "lp_iou": lp["lp_iou"],
            "lp_f": lp["lp_fscore"],
            "recon_iou_to_input": metrics.iou(rec[r][0], inp),
            "recon_lp_iou": lp_rec["lp_iou"],
            "recon_lp_f": lp_rec["lp_fscore"],
        }
        res["scores"] = scores
        save(f"scores at {r}")
        if r == args.resolutions[0]:
            from bench_samples import save_projections

            save_projections(
                inp, occ[r], out / "projections.png", f"{args.input}, {cfg.name} (truncated fit), {r} voxels"
            )

    print(json.dumps(res, indent=1))
    print(f"\n{args.input}, preset {cfg.name}, {res['device_name']}, torch {res['torch']}")
    print(f"grid {res['grid_shape']} in {res['grid_s']:.1f} s; latent {res['latent_shape']}")
    print(f"autoencoder {res['ae_s_per_step'] * 1e3:.1f} ms/step (peak {res['ae_peak_gib']} GiB)")
    for name, v in res["dm_variants"].items():
        print(
            f"denoiser, {name}: {v['s_per_step'] * 1e3:.1f} ms/step (first step {v['first_step_s']:.1f} s, "
            f"peak {v['peak_gib']} GiB)"
        )
    print(f"full fit ({ae_steps} + {dm_steps} steps), extrapolated: {res['full_fit_s_extrapolated'] / 60:.1f} min")
    tf = res["truncated_fit"]
    print(
        f"truncated fit: {tf['autoencoder_steps']} + {tf['diffusion_steps']} steps in {tf['total_s']:.0f} s, "
        f"recon {tf['reconstruction']}"
    )
    for r, s in scores.items():
        print(
            f"  {r} voxels vs input: G-Div {s['g_div']:.3f}  IoU→input {s['iou_to_input']:.3f}  "
            f"LP-IoU {s['lp_iou']:.3f}  LP-F {s['lp_f']:.3f}  (reconstruction: LP-IoU {s['recon_lp_iou']:.3f} "
            f"LP-F {s['recon_lp_f']:.3f})"
        )


if __name__ == "__main__":
    main()

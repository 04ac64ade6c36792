"""``Sin3DM.fit``'s stages: mesh → TSDF grid → autoencoder (the input's triplane latent) → denoiser on that one
latent → calibration of the diversity knob (not in the paper).

With a run folder every stage saves its result and the trainers checkpoint and stop cleanly on Ctrl-C, so a
resumed fit continues where the last one stopped.
"""

from __future__ import annotations

import json
import signal
import threading
import time
from pathlib import Path

import numpy as np

from ..auto.calibration import calibrates, judged_at
from ..auto.fit_default import default_preset
from ..auto.fit_policy import (
    NARROWER_CALIBRATION,
    as_fitted,
    choose_pbr,
    choose_turn,
    g_div_at_one,
    narrower_field,
    narrower_kept,
    up_hint,
)
from ..auto.review import review_fit
from ..data.config import Config, check_setting
from ..data.grid import ShapeGrid, load_grid, mesh_to_grid, save_grid
from ..data.mesh import TexturedMesh
from ..data.source import input_name, input_stem, resolve_mesh
from ..errors import Sin3DMInputError, Terminated
from ..evaluate.metrics import reconstruction_metrics
from ..files import atomic_write, holds_lock, release_lock
from ..model.autoencoder import AutoencoderTrainer
from ..model.decode import reconstructed_grid
from ..model.diffusion import DiffusionTrainer
from ..presets import get_preset
from .checkpoints import resume_trainer, save_trainer
from .device import cpu_bf16_share, get_device, resolved_precision
from .run_folder import check_run_folder, prepare_run, record_config, remove_failed_run
from .runs import input_digest
from .threads import threads_hint


def fit(
    build,
    source,
    preset=None,
    out=None,
    resume: bool = False,
    seed: int | None = None,
    device=None,
    progress: bool = True,
    pbr: bool | None = None,
    allow_outside_paths: bool = False,
    calibrate: bool | None = None,
    budget=None,
    up: str | None = None,
    turn: float | None = None,
):
    """``Sin3DM.fit`` (``build``: the model class); arguments are checked before anything is written, and a fresh
    fit that fails removes what it wrote (an interrupted one keeps its checkpoints for ``resume=True``). ``budget``:
    an :class:`~sin3dm_lite.auto.fit_default.Budget` the denoiser's steps keep to once the autoencoder has trained;
    ``up``, ``turn``: the mesh's up axis and its turn about it (``grid.up``, ``grid.turn``), for a new fit only."""
    if seed is not None and (
        isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**32
    ):
        raise Sin3DMInputError(f"seed must be a whole number from 0 to {2**32 - 1}, got {seed!r}")
    if isinstance(preset, Config):
        preset.check()  # a setting out of range (changed in place) fails here
    elif preset is not None:
        get_preset(preset)  # a bad name fails here
    for name, value in (("up", up), ("turn", turn)):
        if value is not None:
            if resume:
                raise Sin3DMInputError(
                    f"{name} is for a new fit: a resumed fit keeps its run's; leave out --{name} (Python: {name}=)"
                )
            check_setting(f"grid.{name}", value, name)
    get_device(device)
    run = Path(out) if out is not None else None
    if run is not None:
        check_run_folder(run, source, resume)
    existed = run is not None and run.exists()
    try:
        fit_run = FitRun(build, run, resume, device, progress)
        fit_run.budget = None if resume else budget  # a resumed fit keeps its run's steps
        return fit_run.stages(source, preset, seed, pbr, allow_outside_paths, calibrate, (up, turn))
    except KeyboardInterrupt:
        raise  # the checkpoints stay: continue with resume=True
    except BaseException:
        if run is not None and not resume and holds_lock(run):
            remove_failed_run(run, existed)
        raise
    finally:
        if run is not None:
            release_lock(run)


def grid_for(mesh: TexturedMesh, cfg: Config, progress: bool) -> ShapeGrid:
    """Stage 1: ``mesh`` (turned upright by ``cfg.grid.up``, then by ``grid.turn`` about y) as the TSDF + colour grid
    of ``cfg.grid``."""
    g = cfg.grid
    return mesh_to_grid(
        as_fitted(mesh, g.up, g.turn),
        g.resolution,
        threshold_voxels=g.threshold_voxels,
        n_surface_points=g.n_surface_points,
        near_surface_sigma=g.near_surface_sigma,
        seed=cfg.seed,
        progress=progress,
        margin_voxels=g.margin_voxels,
        pbr=cfg.autoencoder.pbr,
    )


class FitRun:
    """One fit after its checks: the model class, the run folder (or None), the device and the stages' timings."""

    def __init__(self, build, run: Path | None, resume: bool, device, progress: bool):
        self.build, self.run, self.resume, self.progress = build, run, resume, progress
        self.dev = get_device(device)
        self.say = print if progress else (lambda *a, **k: None)
        self.timings: dict[str, float] = {}
        self.mesh: TexturedMesh | None = None
        self.budget = None  # an auto.fit_default.Budget: the denoiser's steps kept to it

    def stages(self, source, preset, seed, pbr, allow_outside_paths, calibrate, frame=(None, None)):
        """All stages, saved into the run folder at the end; the fitted model (``frame``: ``(up, turn)``)."""
        cfg, mesh = self.settings(source, preset, seed, pbr, allow_outside_paths, frame)
        self.mesh = mesh  # None where a resumed run has its grid: the calibration then reads it again
        grid = self.grid(cfg, mesh)
        ae, h0, metrics = self.autoencoder(cfg, grid)
        from_file = isinstance(source, (str, Path)) and Path(source).is_file()
        base = {
            "preset": cfg.name,
            "input": grid.name,
            "input_path": str(Path(source).resolve()) if from_file else None,  # to compare the run with it later
            "grid_shape": list(grid.shape),
        }
        if calibrate is None:
            calibrate = calibrates(cfg, mesh)
            if calibrates(cfg) and not calibrate:
                self.say(
                    f"[fit] '{grid.name}' is flat: every sample is the same slab, so the diversity is not calibrated "
                    f"on its patches; samples default to the preset's {cfg.sampling.diversity:g}, their colours varying"
                )
        calibrate = bool(calibrate)
        model, history = self.denoise(cfg, grid, h0, ae, metrics, base, calibrate)
        if calibrate:  # copies even from pure noise: a second denoiser with a narrower field
            model, history = self.narrower(cfg, model, history, (grid, h0, ae, metrics, base))
        review_fit(model, calibrate, self.say, self.run)
        if self.run is not None:
            model.save(self.run)
            atomic_write(self.run / "losses.json", json.dumps({"autoencoder": ae.history, "diffusion": history}))
            atomic_write(self.run / "report.json", json.dumps(model.report, indent=2))
            self.say(f"[fit] run folder: {self.run}")
        return model

    def settings(self, source, preset, seed, pbr, allow_outside_paths, frame) -> tuple[Config, TexturedMesh | None]:
        """The run's config (its folder made or checked) and the input mesh (None when a resumed run has its grid)."""
        run, resume = self.run, self.resume
        have_grid = run is not None and resume and (run / "grid.npz").exists()
        # bad input fails before any folder is written
        mesh = None if have_grid else resolve_mesh(source, allow_outside_paths=allow_outside_paths)
        resuming = resume and run is not None and (run / "config.json").exists()
        if preset is None and not resuming:  # the preset for this machine and shape, said first with why and how long
            chosen = default_preset(self.dev, mesh, self.progress, *frame)
            for line in chosen.lines():
                self.say(line)
            preset = chosen.name
        if mesh is not None and not resuming:
            pbr = choose_pbr(mesh, pbr, preset, self.say)
            base = preset if isinstance(preset, Config) else get_preset(preset)
            up = base.grid.up if frame[0] is None else frame[0]
            if frame[0] is None and up == "y" and (hint := up_hint(source)):
                self.say(hint)
            turn = choose_turn(mesh.turned_upright(up), frame[1], base, self.say)
            changes = {"autoencoder.pbr": pbr, "grid.up": up, "grid.turn": turn}
            if any(base.settings()[k] != v for k, v in changes.items()):
                preset = base.updated(**changes)
        asked = None
        if run is not None:  # what the run is fitted to, recorded in a new run folder and compared on resume
            asked = {"input": input_name(source), "name": input_stem(source), "digest": input_digest(source, mesh)}
        return prepare_run(run, preset, resume, seed, asked, pbr), mesh

    def grid(self, cfg: Config, mesh: TexturedMesh | None) -> ShapeGrid:
        """Stage 1: the grid (loaded where a resumed run has it)."""
        t0 = time.perf_counter()
        if mesh is None:
            grid = load_grid(self.run / "grid.npz")
            self.say(f"[fit] grid loaded from {self.run / 'grid.npz'}")
        else:
            if cfg.grid.up != "y":
                self.say(f"[fit] '{mesh.name}' turned {cfg.grid.up.upper()}-up to Y-up: its samples are written Y-up")
            grid = grid_for(mesh, cfg, self.progress)
            if self.run is not None:
                save_grid(grid, self.run / "grid.npz")
        self.timings["grid_s"] = time.perf_counter() - t0
        return grid

    def autoencoder(self, cfg: Config, grid: ShapeGrid):
        """Stage 2: the trained autoencoder, the input's latent and its reconstruction metrics."""
        t0 = time.perf_counter()
        ae = AutoencoderTrainer(grid, cfg.autoencoder, self.dev, cfg.seed)
        if self.dev.type == "cpu" and (hint := threads_hint()):
            self.say("[fit] " + hint)
        if ae.single_color is not None:
            rgb = ", ".join(f"{c:.2f}" for c in ae.single_color)
            self.say(
                f"[fit] '{grid.name}' has one colour ({rgb}; a mesh without colour gets this grey): the autoencoder "
                "learns its geometry only, about half the work a step, and every sample keeps that colour"
            )
        train(ae, self.run / "autoencoder.pt" if self.run else None, cfg.checkpoint_every, self.progress, self.say)
        self.timings["autoencoder_training_s"] = time.perf_counter() - t0
        h0 = ae.latent()
        metrics = reconstruction_metrics(reconstructed_grid(ae.model.decoder, h0, grid), grid)
        self.timings["autoencoder_s"] = time.perf_counter() - t0
        self.say("[fit] reconstruction: " + ", ".join(f"{k} {v:.4f}" for k, v in metrics.items()))
        return ae, h0, metrics

    def denoise(self, cfg, grid, h0, ae, metrics, report_base, calibrate: bool, ckpt: str = "diffusion.pt"):
        """Stages 3 and 4: train the denoiser on ``h0``, then (``calibrate``) choose the knob; the model and losses."""
        t0 = time.perf_counter()
        if self.budget is not None:  # a fresh fit (a resumed one has none): its autoencoder trained every step here
            cfg = self.kept_to_budget(cfg, ae.step_count)
        dm = DiffusionTrainer(h0, cfg.diffusion, self.dev, cfg.seed)
        cfg = cfg.updated(**{"diffusion.latent_scale": dm.cfg.latent_scale})  # the number, where it asked for unit
        if dm.train_forward is not dm.model:
            how_long = "about a minute" if self.dev.type == "cuda" else "a few minutes on a CPU"
            self.say(
                f"[fit] diffusion: the first step compiles the denoiser for this machine (torch.compile, {how_long})"
            )
        train(dm, self.run / ckpt if self.run else None, cfg.checkpoint_every, self.progress, self.say)
        self.timings["diffusion_s"] = time.perf_counter() - t0

        report = {
            **report_base,
            "latent_shape": list(h0.resolution),
            "autoencoder_steps": ae.step_count,
            "diffusion_steps": dm.step_count,
            "reconstruction": metrics,
            **({"single_color": ae.single_color.tolist()} if ae.single_color is not None else {}),
            "final_loss": {"autoencoder": ae.history["loss"][-1], "diffusion": dm.history["loss"][-1]},
            "timings_s": self.timings,
            "device": str(self.dev),
            "precision": training_precision(cfg, self.dev),
        }
        model = self.build(
            cfg, ae.model.decoder, h0, dm.model_for_sampling, grid.aabb, grid.normalization, report, self.dev
        )
        # stage 4: the diversity knob for this shape: the most varied samples that keep its patches
        if calibrate:
            self.say(
                "[fit] calibrating the diversity knob for this shape: a few samples at a few settings, scored "
                "against the input (LP-IoU / LP-F); the most varied setting that keeps the goals becomes the "
                "run's default"
            )
            t0 = time.perf_counter()
            at = judged_at(cfg)
            if at is None:
                model.calibrate(reference=grid.sdf < 0, progress=self.progress)
            else:  # against the input mesh as the paper measures (the mesh read again on a resume)
                model.calibrate(input_mesh=self.mesh, resolution=at, progress=self.progress)
            self.timings["calibrate_s"] = time.perf_counter() - t0
        return model, dm.history

    def narrower(self, cfg: Config, first, history, stage_inputs):
        """Where even ``first``'s samples from pure noise are copies
        (:func:`~sin3dm_lite.auto.fit_policy.narrower_field`): a second denoiser with one ResBlock fewer, calibrated
        the same way, kept where it kept the goals with samples more varied than ``first``'s
        (:func:`~sin3dm_lite.auto.fit_policy.narrower_kept`); else ``first``.
        The model kept and its losses; its report says what was tried."""
        second_cfg = narrower_field(
            first.config.updated(**{"sampling.diversity": cfg.sampling.diversity}), first.report.get("calibration")
        )
        extra = self.timings["diffusion_s"] * (1 - 1 / cfg.diffusion.n_resblocks)  # a ResBlock fewer to train
        extra += NARROWER_CALIBRATION * self.timings.get("calibrate_s", 0)
        if second_cfg is None or (self.budget is not None and not self.budget.allows(extra)):
            return first, history
        n, g_div = second_cfg.diffusion.n_resblocks, g_div_at_one(first.report["calibration"])
        self.say(
            f"[fit] even from pure noise the samples are near copies (G-Div {g_div:.3f} at diversity 1): the "
            f"denoiser's field holds this shape's layout. Training a second one with {n} ResBlocks (a "
            f"{1 + 4 * n}-texel field), about {extra / 60:.0f} min more; it is kept if it varies more and keeps the patches"
        )
        first_timings, self.budget = dict(self.timings), None
        second, second_history = self.denoise(second_cfg, *stage_inputs, True, ckpt="diffusion_narrower.pt")
        kept = narrower_kept(second.report["calibration"], first.report["calibration"])
        extra_s = {f"narrower_{k}": self.timings[k] for k in ("diffusion_s", "calibrate_s")}
        self.timings.clear()  # both reports hold this dict
        self.timings.update({**first_timings, **extra_s})
        model, history = (second, second_history) if kept else (first, history)
        if kept and self.run is not None:  # the run's denoiser from now on: a resume trains and checks this one
            record_config(self.run, second_cfg)
            (self.run / "diffusion_narrower.pt").replace(self.run / "diffusion.pt")
        model.report["narrower_field"] = {
            "n_resblocks": n,
            "kept": kept,
            "first": {"n_resblocks": n + 1, "g_div_at_one": g_div, "diversity": first.config.sampling.diversity},
        }
        self.say(
            f"[fit] the narrower field {'is kept' if kept else 'kept no more varied setting: the first denoiser stays'} "
            f"(diversity {model.config.sampling.diversity:g})"
        )
        return model, history

    def kept_to_budget(self, cfg: Config, ae_steps: int) -> Config:
        """``cfg`` with the denoiser's steps the budget leaves after the autoencoder's time; a run folder records
        them, so that a resume trains to the same end."""
        seconds = self.timings["autoencoder_training_s"]
        steps, line = self.budget.denoiser_steps(ae_steps, seconds, cfg.diffusion.steps)
        if line is None:
            return cfg
        self.say(line)
        cfg = cfg.updated(**{"diffusion.steps": steps})
        if self.run is not None:
            record_config(self.run, cfg)
        return cfg


def train(trainer, ckpt: Path | None, every: int, progress: bool, say) -> None:
    """Run a trainer to its end, checkpointing every ``every`` steps; a fresh trainer resumes from ``ckpt``.

    Ctrl-C (or SIGTERM) stops only *between* steps, after a checkpoint of the last one, so a resume loses nothing.
    """
    label = trainer.kind
    saved = {"step": None}  # the step the checkpoint file holds
    if ckpt is not None and ckpt.exists() and trainer.step_count == 0:
        resume_trainer(trainer, ckpt)
        saved["step"] = trainer.step_count
        say(f"[fit] {label}: resumed at step {trainer.step_count}")
    stop = {"signal": None}  # Ctrl-C or SIGTERM: stop after this step, with its checkpoint

    def save(tr) -> None:
        if ckpt is not None and saved["step"] != tr.step_count:
            save_trainer(tr, ckpt)
            saved["step"] = tr.step_count

    def checkpoint(tr) -> None:
        asked = stop["signal"] is not None
        if tr.step_count % every == 0 or asked:
            save(tr)
        if asked:
            say(f"\n[fit] {label}: interrupted at step {tr.step_count}; checkpoint saved, continue with --resume")
            raise Terminated if stop["signal"] == signal.SIGTERM else KeyboardInterrupt

    def on_signal(signum, frame) -> None:
        stop["signal"] = signum

    main = threading.current_thread() is threading.main_thread()
    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)} if main else {}
    try:
        trainer.run(progress=progress, callback=checkpoint)
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
    save(trainer)  # the last step, unless the callback just wrote it


def training_precision(cfg: Config, device) -> dict:
    """What the fit's networks trained in (``"bf16"`` / ``"fp32"``) and, where ``"auto"`` chose on a CPU, bf16's
    measured share of fp32's time."""
    settings = {net: getattr(cfg, net).precision for net in ("autoencoder", "diffusion")}
    out = {net: resolved_precision(device, p) for net, p in settings.items()}
    auto_on_cpu = device.type == "cpu" and "auto" in settings.values()
    share = cpu_bf16_share() if auto_on_cpu else None  # timed once a process: by now, by the training
    return {**out, **({"cpu_bf16_share": round(share, 3)} if share is not None else {})}

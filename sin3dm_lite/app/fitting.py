"""``Sin3DM.fit``'s stages, in order: mesh → grid → autoencoder → denoiser → the diversity knob.

    1. grid         the input's TSDF + colour grid (switching to finer settings for thin parts: fit_policy)
    2. autoencoder  the triplane latent of the input and the decoder, with reconstruction metrics
    3. diffusion    the denoiser trained on that one latent (a wider field on trial for a shape of thin walls:
                    it goes back to the narrower one if its first samples are copies)
    4. calibrate    the most varied diversity setting that keeps the input's patches (where the config asks;
                    a shape that keeps them even from pure noise trains its denoiser again with the rollout)

With a run folder (:mod:`sin3dm_lite.app.run_folder`) every stage saves its result, the trainers checkpoint every
``config.checkpoint_every`` steps and stop cleanly on Ctrl-C (:func:`train`), and a resumed fit continues where
the last one stopped. What the fit decides and says about its input lives in :mod:`sin3dm_lite.auto.fit_policy`.
"""

from __future__ import annotations

import json
import signal
import threading
import time
import warnings
from pathlib import Path

import numpy as np

from ..auto.fit_default import default_preset
from ..auto.fit_policy import (
    are_copies,
    choose_pbr,
    from_noise_distance,
    no_rollout_switch,
    quick_hint,
    rollout_message,
    thin_parts_hint,
    thin_parts_message,
    thin_parts_switch,
    wide_field_check_step,
    wide_field_message,
    wide_field_undo,
)
from ..auto.review import review_fit
from ..data.config import Config
from ..data.grid import ShapeGrid, load_grid, mesh_to_grid, save_grid
from ..data.mesh import TexturedMesh
from ..data.source import input_name, input_stem, resolve_mesh
from ..errors import Sin3DMInputError, Terminated
from ..evaluate.metrics import reconstruction_metrics
from ..files import atomic_write, holds_lock, release_lock
from ..model.autoencoder import AutoencoderTrainer
from ..model.decode import reconstructed_grid
from ..presets import get_preset
from .checkpoints import resume_trainer, save_trainer
from .device import cpu_bf16_share, get_device, resolved_precision
from .run_folder import check_run_folder, prepare_run, read_report, remove_failed_run
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
):
    """``Sin3DM.fit`` (its docstring says what each argument does); ``build`` makes the model from its parts
    (``build(config, decoder, latent, denoiser, aabb, normalization, report, device)``: the model class).

    Every argument is checked before anything is written; a fresh fit that fails with an error removes what it
    wrote, an interrupted one (Ctrl-C) keeps its checkpoints for ``resume=True``.
    """
    if seed is not None and (
        isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**32
    ):
        raise Sin3DMInputError(f"seed must be a whole number from 0 to {2**32 - 1}, got {seed!r}")
    if isinstance(preset, Config):
        preset.check()  # a setting out of range (changed in place) fails here
    elif preset is not None:
        get_preset(preset)  # a bad name fails here
    get_device(device)
    run = Path(out) if out is not None else None
    if run is not None:
        check_run_folder(run, source, resume)
    existed = run is not None and run.exists()
    try:
        return FitRun(build, run, resume, device, progress).stages(source, preset, seed, pbr, allow_outside_paths)
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
    """Stage 1: ``mesh`` as the TSDF + colour grid of ``cfg.grid``."""
    g = cfg.grid
    return mesh_to_grid(
        mesh,
        g.resolution,
        g.threshold_voxels,
        g.n_surface_points,
        g.near_surface_sigma,
        cfg.seed,
        progress,
        margin_voxels=g.margin_voxels,
        pbr=cfg.autoencoder.pbr,
    )


class FitRun:
    """One fit after its checks: the model class, the run folder (or None), the device, what it says and the
    stages' timings (one dictionary, which the report keeps)."""

    def __init__(self, build, run: Path | None, resume: bool, device, progress: bool):
        self.build, self.run, self.resume, self.progress = build, run, resume, progress
        self.dev = get_device(device)
        self.say = print if progress else (lambda *a, **k: None)
        self.timings: dict[str, float] = {}

    def recorded(self, switch: str):
        """What a resumed run's report recorded of a switch it made before it stopped (None: fresh, or no switch)."""
        record = read_report(self.run).get(switch) if self.resume and self.run is not None else None
        if record is not None and not switch_record_ok(switch, record):
            raise Sin3DMInputError(
                f"cannot resume: '{self.run / 'report.json'}' is damaged (its {switch} is not the record of a "
                "switch this fit made); put back the original, or fit again into a new --out"
            )
        return record

    def stages(self, source, preset, seed, pbr, allow_outside_paths):
        """All stages, saved into the run folder at the end; the fitted model."""
        cfg, mesh = self.settings(source, preset, seed, pbr, allow_outside_paths)
        grid, thin, cfg, thin_parts = self.grid(cfg, mesh)
        ae, h0, metrics = self.autoencoder(cfg, grid)
        base = {
            "preset": cfg.name,
            "input": grid.name,
            # the mesh file, so the run can be compared with its input later (Sin3DM.input_mesh)
            "input_path": str(Path(source).resolve())
            if isinstance(source, (str, Path)) and Path(source).is_file()
            else None,
            "grid_shape": list(grid.shape),
            "thin_share": thin,  # ShapeGrid.thin_share of the training grid: share of the solid in parts under ~5 voxels thick
            "thin_parts_switch": thin_parts,  # {from, resolution, thin_share} when small switched to finer settings
        }
        # rollout_switch: {plain_calibration, plain_s} when a plain denoiser was trained again with the rollout
        rollout = self.recorded("rollout_switch")
        model, history = self.denoise(cfg, grid, h0, ae, metrics, {**base, "rollout_switch": rollout})
        model, history = review_fit(self, model, history, (grid, h0, ae, metrics, base), rollout, thin_parts)
        if self.run is not None:
            model.save(self.run)
            atomic_write(self.run / "losses.json", json.dumps({"autoencoder": ae.history, "diffusion": history}))
            atomic_write(self.run / "report.json", json.dumps(model.report, indent=2))
            self.say(f"[fit] run folder: {self.run}")
        return model

    def settings(self, source, preset, seed, pbr, allow_outside_paths) -> tuple[Config, TexturedMesh | None]:
        """The run's config (its run folder made, or checked for a resume) and the input mesh (None when a resumed
        run has its grid already)."""
        run, resume = self.run, self.resume
        have_grid = run is not None and resume and (run / "grid.npz").exists()
        mesh = (
            None if have_grid else resolve_mesh(source, allow_outside_paths=allow_outside_paths)
        )  # bad input fails before any folder is written
        resuming = resume and run is not None and (run / "config.json").exists()
        if preset is None and not resuming:  # the preset this machine runs well, said first with why and how long
            chosen = default_preset(self.dev, timed=self.progress)
            for line in chosen.lines():
                self.say(line)
            preset = chosen.name
        if mesh is not None and not resuming:
            pbr = choose_pbr(mesh, pbr, preset, self.say)
            base = preset if isinstance(preset, Config) else get_preset(preset)
            if base.autoencoder.pbr != pbr:
                preset = base.updated(**{"autoencoder.pbr": pbr})
        asked = None
        if run is not None:  # what the run is fitted to, recorded in a new run folder and compared on resume
            from .runs import input_digest

            asked = {"input": input_name(source), "name": input_stem(source), "digest": input_digest(source, mesh)}
        return prepare_run(run, preset, resume, seed, asked, pbr), mesh

    def grid(self, cfg: Config, mesh: TexturedMesh | None) -> tuple[ShapeGrid, float, Config, dict | None]:
        """Stage 1: the grid (loaded where a resumed run has it), its thin share, the config (switched to the thin-part
        settings where :func:`thin_parts_switch` says so) and the record of that switch."""
        run, say = self.run, self.say
        # set when this fit switches to the preset's thin-part settings (resumed: when the run switched before it stopped)
        thin_parts = self.recorded("thin_parts_switch")
        t0 = time.perf_counter()
        if mesh is None:
            grid = load_grid(run / "grid.npz")
            say(f"[fit] grid loaded from {run / 'grid.npz'}")
            thin = grid.thin_share()
        else:
            grid = grid_for(mesh, cfg, self.progress)
            thin = grid.thin_share()
            switched = thin_parts_switch(cfg, grid, thin)
            if switched is not None:  # too coarse for this shape's thin parts: the finer settings, recorded first
                say("[fit] " + thin_parts_message(cfg, switched, grid, thin))
                thin_parts = {"from": cfg.name, "resolution": max(grid.shape), "thin_share": thin}
                if switched.name.endswith("+walls") and (undo := wide_field_undo(cfg)):  # the wider field on
                    thin_parts["wide_field"] = {"undo": undo}  # trial: what undoes it (FitStages.denoise)
                cfg, grid_cfg = switched, cfg.grid
                if run is not None:  # a resumed run still knows it switched (its report is completed at the end)
                    atomic_write(run / "config.json", cfg.to_json())
                    atomic_write(run / "report.json", json.dumps({"thin_parts_switch": thin_parts}, indent=2))
                if switched.grid != grid_cfg:  # the coarse grid served only to measure (~1 s at 64 voxels)
                    grid = grid_for(mesh, cfg, self.progress)
                    thin = grid.thin_share()
            elif (hint := thin_parts_hint(cfg, grid, thin)) is not None:
                say("[fit] " + hint)
            if run is not None:
                save_grid(grid, run / "grid.npz")
        self.timings["grid_s"] = time.perf_counter() - t0
        return grid, thin, cfg, thin_parts

    def autoencoder(self, cfg: Config, grid: ShapeGrid):
        """Stage 2: the trained autoencoder, the input's latent and its reconstruction metrics."""
        t0 = time.perf_counter()
        ae = AutoencoderTrainer(grid, cfg.autoencoder, self.dev, cfg.seed)
        # a shape of one colour (the trainer found it) trains half an autoencoder: the time hint knows
        for hint in (
            quick_hint(cfg, self.dev, ae.single_color is not None),
            threads_hint() if self.dev.type == "cpu" else None,
        ):
            if hint:
                self.say("[fit] " + hint)
        if ae.single_color is not None:
            rgb = ", ".join(f"{c:.2f}" for c in ae.single_color)
            self.say(
                f"[fit] '{grid.name}' has one colour ({rgb}; a mesh without colour gets this grey): the autoencoder "
                "learns its geometry only, about half the work a step, and every sample keeps that colour"
            )
        train(ae, self.run / "autoencoder.pt" if self.run else None, cfg.checkpoint_every, self.progress, self.say)
        h0 = ae.latent()
        metrics = reconstruction_metrics(reconstructed_grid(ae.model.decoder, h0, grid), grid)
        self.timings["autoencoder_s"] = time.perf_counter() - t0
        self.say("[fit] reconstruction: " + ", ".join(f"{k} {v:.4f}" for k, v in metrics.items()))
        return ae, h0, metrics

    def denoise(self, cfg, grid, h0, ae, metrics, report_base):
        """Stages 3 and 4: train the denoiser on the latent ``h0``, then calibrate the knob (where
        ``cfg.sampling.calibrate``); the model, with its report, and the denoiser's loss history."""
        from ..model.diffusion import DiffusionTrainer

        t0 = time.perf_counter()
        ckpt = self.run / "diffusion.pt" if self.run else None
        dm = DiffusionTrainer(h0, cfg.diffusion, self.dev, cfg.seed)
        if dm.train_forward is not dm.model:
            self.say(
                "[fit] diffusion: the first step compiles the denoiser for this GPU (torch.compile, about a minute)"
            )
        wide = (report_base.get("thin_parts_switch") or {}).get("wide_field")
        if wide is not None and "check" not in wide:  # the wider field of Config.thin_walls, on trial
            train(dm, ckpt, cfg.checkpoint_every, self.progress, self.say, until_step=wide_field_check_step(cfg))
            cfg, dm = self.wide_field_check(cfg, grid, h0, ae, dm, report_base["thin_parts_switch"])
        train(dm, ckpt, cfg.checkpoint_every, self.progress, self.say)
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
        if cfg.sampling.calibrate:
            self.say(
                "[fit] calibrating the diversity knob for this shape: a few samples at a few settings, scored "
                "against the input (LP-IoU / LP-F); the most varied setting that keeps the goals becomes the "
                "run's default"
            )
            t0 = time.perf_counter()
            model.calibrate(reference=grid.sdf < 0, progress=self.progress)
            self.timings["calibrate_s"] = time.perf_counter() - t0
        return model, dm.history

    def wide_field_check(self, cfg, grid, h0, ae, dm, thin_parts):
        """The wider field's trial (:attr:`Config.thin_walls`): a few samples from pure noise of the denoiser as
        trained so far; if they are copies (:func:`are_copies` of :func:`from_noise_distance`: latents, nothing
        decoded), the narrower denoiser's config and a fresh trainer for it, else ``cfg`` and ``dm`` as they are.
        The outcome is recorded in ``thin_parts``."""
        from ..model.diffusion import DiffusionTrainer

        t0 = time.perf_counter()
        probe = self.build(
            cfg, ae.model.decoder, h0, dm.model_for_sampling, grid.aabb, grid.normalization, {}, self.dev
        )
        distance = from_noise_distance(probe, seed=cfg.seed)
        wide = thin_parts["wide_field"]
        wide["check"] = {"step": dm.step_count, "distance": distance, "copies": are_copies(distance)}
        if wide["check"]["copies"]:
            self.say("[fit] " + wide_field_message(cfg, distance, wide["undo"]))
            cfg = cfg.updated(**wide["undo"], name=cfg.name.replace("+walls", "+thin"))
            dm = DiffusionTrainer(h0, cfg.diffusion, self.dev, cfg.seed)
            if self.run is not None:  # the wider checkpoint goes first: the narrower config never meets it
                (self.run / "diffusion.pt").unlink(missing_ok=True)
                atomic_write(self.run / "config.json", cfg.to_json())
        else:
            self.say(
                f"[fit] after {dm.step_count} steps the wider denoiser's samples from pure noise vary (their latents "
                f"differ from the input's by {distance:.0%} of its variance): it keeps its field"
            )
        if self.run is not None:  # a resumed fit does not check again
            atomic_write(self.run / "report.json", json.dumps({"thin_parts_switch": thin_parts}, indent=2))
        self.timings["wide_field_check_s"] = time.perf_counter() - t0
        return cfg, dm

    def switch_to_rollout(self, cfg, grid, h0, ae, metrics, base, calibration):
        """Stages 3 and 4 again with the cross-plane rollout (:attr:`Config.rollout_switch`); the new config, model,
        loss history and the record of the switch."""
        run = self.run
        self.say("[fit] " + rollout_message(cfg))
        rollout = {
            "plain_calibration": {k: calibration[k] for k in ("diversity", "kept_goals")},
            "plain_s": self.timings.pop("diffusion_s") + self.timings.pop("calibrate_s", 0.0),
        }
        thin_parts = base["thin_parts_switch"]
        cfg = cfg.for_rollout()
        if run is not None:  # the plain checkpoint goes first: a config with the rollout never meets it
            (run / "diffusion.pt").unlink(missing_ok=True)
            atomic_write(run / "config.json", cfg.to_json())
            atomic_write(
                run / "report.json", json.dumps({"thin_parts_switch": thin_parts, "rollout_switch": rollout}, indent=2)
            )
        model, history = self.denoise(cfg, grid, h0, ae, metrics, {**base, "rollout_switch": rollout})
        if not (model.report.get("calibration") or {}).get("kept_goals"):
            # stacklevel: this method, stages, fitting.fit, Sin3DM.fit, and the code that called it
            warnings.warn(
                "with the cross-plane rollout no diversity setting kept the input's patches, which "
                "the plain denoiser did from pure noise; fit again without the switch: " + no_rollout_switch(cfg),
                stacklevel=5,
            )
        return cfg, model, history, rollout


def train(trainer, ckpt: Path | None, every: int, progress: bool, say, until_step: int | None = None) -> None:
    """Run a trainer (:class:`~sin3dm_lite.training.Trainer`) to its end (or ``until_step``), checkpointing every
    ``every`` steps; a fresh trainer resumes from ``ckpt`` where it exists.

    Ctrl-C (SIGINT) is honoured only *between* steps, after a checkpoint of the
    last finished step has been written, so a resumed run loses no work and
    never starts from a half-applied optimiser step.
    """
    label = trainer.kind
    saved = {"step": None}  # the step the checkpoint file holds
    if ckpt is not None and ckpt.exists() and trainer.step_count == 0:
        resume_trainer(trainer, ckpt)
        saved["step"] = trainer.step_count
        say(f"[fit] {label}: resumed at step {trainer.step_count}")
    stop = {"asked": False}

    def save(tr) -> None:
        if ckpt is not None and saved["step"] != tr.step_count:
            save_trainer(tr, ckpt)
            saved["step"] = tr.step_count

    def checkpoint(tr) -> None:
        if tr.step_count % every == 0 or stop["asked"]:
            save(tr)
        if stop["asked"]:
            say(f"\n[fit] {label}: interrupted at step {tr.step_count}; checkpoint saved, continue with --resume")
            raise Terminated if stop.get("signal") == signal.SIGTERM else KeyboardInterrupt

    def on_sigint(signum, frame) -> None:  # Ctrl-C or SIGTERM: stop after this step, with its checkpoint
        stop["asked"] = True
        stop["signal"] = signum

    main = threading.current_thread() is threading.main_thread()
    old = {s: signal.signal(s, on_sigint) for s in (signal.SIGINT, signal.SIGTERM)} if main else {}
    try:
        trainer.run(until_step, progress=progress, callback=checkpoint)
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
    save(trainer)  # the last step, unless the callback just wrote it


def switch_record_ok(switch: str, record) -> bool:
    """Whether ``record`` is what :meth:`FitRun.grid` (``thin_parts_switch``) or :meth:`FitRun.switch_to_rollout`
    (``rollout_switch``) writes into report.json: a resumed fit reads its fields."""
    if not isinstance(record, dict):
        return False
    if switch == "rollout_switch":
        plain = record.get("plain_calibration")
        return isinstance(plain, dict) and isinstance(record.get("plain_s"), (int, float))
    wide = record.get("wide_field")
    return isinstance(record.get("from"), str) and (
        wide is None or (isinstance(wide, dict) and isinstance(wide.get("undo"), dict))
    )


def training_precision(cfg: Config, device) -> dict:
    """What the fit's networks trained in (``"bf16"`` / ``"fp32"``: their ``precision`` setting resolved on
    ``device``) and, on a CPU with native bf16, bf16's measured share of fp32's time, which ``"auto"`` followed."""
    settings = {net: getattr(cfg, net).precision for net in ("autoencoder", "diffusion")}
    out = {net: resolved_precision(device, p) for net, p in settings.items()}
    auto_on_cpu = device.type == "cpu" and "auto" in settings.values()
    share = cpu_bf16_share() if auto_on_cpu else None  # timed once a process: by now, by the training
    return {**out, **({"cpu_bf16_share": round(share, 3)} if share is not None else {})}

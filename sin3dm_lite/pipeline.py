"""``Sin3DM``: the whole method behind one object.

    model = Sin3DM.fit("canyon", preset="small", out="runs/canyon")   # mesh → grid → triplane → diffusion
    samples = model.sample(4, seed=0)                                  # new triplanes from noise
    meshes = model.to_mesh(samples)                                    # decoded, textured meshes

A fit writes a *run folder*; every stage saves its result there, and training
checkpoints are written atomically every ``config.checkpoint_every`` steps, so
``fit(..., resume=True)`` continues an interrupted run and ends exactly where
an uninterrupted one would::

    RUN/config.json        the full configuration
    RUN/grid.npz           the input's TSDF + colour grid (stage 1)
    RUN/autoencoder.pt     autoencoder trainer state (stage 2, checkpoint)
    RUN/diffusion.pt       diffusion trainer state (stage 3, checkpoint)
    RUN/model.pt           what sampling needs: decoder, latent, denoiser (written last)
    RUN/losses.json        loss histories of both stages: {"autoencoder": {"loss", "sdf", "color"},
                           "diffusion": {"loss"}}, each a list with one value per step
    RUN/report.json        reconstruction metrics, timings, step counts (while a switched fit runs:
                           only the records of its thin-part and rollout switches, kept for --resume)
    RUN/input.json         what the fit was asked for: the input's name and digest (runs.input_digest) and the
                           settings before any switch; --resume refuses another input or other settings
"""
from __future__ import annotations

import json
import math
import signal
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from .data.config import Config, DiffusionConfig
from .data.grid import THIN_SHARE_HINT, ShapeGrid, load_grid, mesh_to_grid, save_grid
from .data.mesh import Normalization, TexturedMesh
from .data.presets import PRESETS, get_preset
from .device import bf16_is_fast, get_device
from .errors import Sin3DMInputError
from .evaluate.metrics import reconstruction_metrics
from .files import acquire_lock, atomic_path, atomic_write, create_locked_folder, holds_lock, release_lock, save_torch
from .model.autoencoder import AutoencoderTrainer, TriplaneDecoder
from .model.decode import reconstructed_grid
from .model.diffusion import check_flips
from .model.training import checkpoint_problem
from .model.triplane import Triplane

if TYPE_CHECKING:
    from .evaluate.calibrate import Calibration

MODEL_FILE = "model.pt"
MAX_SAMPLES = 10_000  # per call, whatever the memory
# what one mesh export holds at its peak (to_mesh: SDF grid, marching cubes, atlas, baked maps), measured on the shipped
# canyon model: 467 MiB at 256 voxels (256 x 128 x 160), 1,008 MiB at 2,048 texels; rounded up
EXPORT_BYTES_PER_VOXEL = 96
EXPORT_BYTES_PER_TEXEL = 256
MODEL_FORMAT = "sin3dm-lite/1"
MIN_IOU = 0.9  # fit warns below this reconstruction occupancy IoU ...
MIN_PSNR = 18.0  # ... or this colour PSNR (dB): an RMS colour error above 12.6 % (the colonnade example gets 20)
INPUT_FILE = "input.json"
RUN_FILES = ("config.json", INPUT_FILE, "grid.npz", "autoencoder.pt", "diffusion.pt", MODEL_FILE, "losses.json", "report.json")


def thin_parts_switch(cfg: Config, grid: ShapeGrid, thin: float | None = None) -> Config | None:
    """The settings :meth:`Sin3DM.fit` switches to when ``grid`` is mostly thin parts, else None.

    A preset with :attr:`Config.thin_parts` (``small``: the ``detail``
    settings, 96 voxels and a 17-texel denoiser field) swaps them in when
    more than :data:`THIN_SHARE_HINT` of the solid lies in parts under ~5
    voxels thick (:meth:`ShapeGrid.thin_share`): its 64-voxel grid and 9-texel
    field swell or break such parts (columns, small boxes, slats) in every
    sample, the finer grid keeps them in about the same fit time
    (docs/thin-parts.md). ``thin`` is the share, if already measured.
    """
    if not cfg.thin_parts:
        return None
    thin = grid.thin_share() if thin is None else thin
    return cfg.for_thin_parts() if thin > THIN_SHARE_HINT else None


def _grid_for(mesh: TexturedMesh, cfg: Config, progress: bool) -> ShapeGrid:
    g = cfg.grid
    return mesh_to_grid(mesh, g.resolution, g.threshold_voxels, g.n_surface_points, g.near_surface_sigma, cfg.seed,
                        progress, margin_voxels=g.margin_voxels, pbr=cfg.autoencoder.pbr)


def _thin_parts_message(cfg: Config, new: Config, grid: ShapeGrid, thin: float) -> str:
    return (f"{thin:.0%} of '{grid.name}' lies in parts under ~5 voxels thick at {max(grid.shape)} voxels, which "
            f"the {cfg.name} preset's samples would swell or break: fitting at {new.grid.resolution} voxels with a "
            f"{new.diffusion.n_resblocks}-ResBlock denoiser{' whose planes see each other' if new.diffusion.rollout else ''} "
            f"instead (its thin-part settings; small's are the 'detail' "
            f"preset's, about the same fit time; the run's config is named '{new.name}'). To keep {cfg.grid.resolution} voxels: CLI "
            "--no-thin-switch, Python preset=get_preset(...).updated(thin_parts={}).")


def fp32_autoencoder_minutes(cfg: Config) -> float:
    """About how long ``cfg``'s autoencoder trains in fp32 on 2 CPU cores (AVX2), in minutes.

    Fitted to two measured steps on a 2-core AMD EPYC without AVX512-BF16:
    ``small``'s (256-wide MLPs, 8,192 points, 64 voxels) 0.61 s, ``quick``'s
    (128 wide, 4,096 points) 0.18 s: a part that grows with the planes' area
    (their encoder and decoder) plus one that grows with points × width².
    ``detail``'s step (96 voxels) is 1.4x ``small``'s in fp32 here; the
    formula gives 1.25x.
    """
    a = cfg.autoencoder
    step_s = 0.119 * (cfg.grid.resolution / 64) ** 2 + 0.491 * (a.points_per_step / 8192) * (a.mlp_hidden / 256) ** 2
    return a.steps * step_s / 60


#: :func:`quick_hint` speaks up when an fp32 autoencoder would take longer than this (minutes, 2 cores)
QUICK_HINT_MINUTES = 8.0


def quick_hint(cfg: Config, device) -> str | None:
    """What :meth:`Sin3DM.fit` says when its autoencoder would be slow on a CPU without native bf16, else None.

    ``small``'s paper-width autoencoder (its MLPs are most of a fit) runs in
    bf16 where the CPU has AVX512-BF16 or AMX; elsewhere it runs in fp32, about
    20 minutes on 2 AVX2 cores (:func:`fp32_autoencoder_minutes`). The ``quick``
    preset's light autoencoder fits in about 5 minutes there, with blurrier
    texture (docs/presets.md). Any config whose autoencoder would take over
    :data:`QUICK_HINT_MINUTES` gets the hint, not only ``small``.
    """
    dev = torch.device(device)
    if dev.type != "cpu" or bf16_is_fast(dev):
        return None
    minutes = fp32_autoencoder_minutes(cfg)
    if minutes <= QUICK_HINT_MINUTES:
        return None
    return (f"this CPU has no native bf16, so the {cfg.name} config's autoencoder ({cfg.autoencoder.steps:,} steps of "
            f"{cfg.autoencoder.points_per_step:,} points, {cfg.autoencoder.mlp_hidden}-wide MLPs) is slow here: about "
            f"{minutes:.0f} minutes on 2 cores in fp32 (longer in emulated bf16). The 'quick' preset (a lighter "
            "autoencoder) fits in about 5 minutes, with the same shapes but blurrier texture: preset='quick' "
            "(CLI: --preset quick).")


def atomic_torch_save(obj, path: Path) -> None:
    """Write ``obj`` with ``torch.save`` so that ``path`` is either the old or the new file, never half of one."""
    with atomic_path(path) as tmp:
        save_torch(obj, tmp)  # a full disk: OSError(ENOSPC), not torch's "unexpected pos" RuntimeError


def _not_ours(path: Path, what: str, why: str) -> Sin3DMInputError:
    return Sin3DMInputError(
        f"'{path}' was not made by this version of sin3dm-lite ({why}); "
        + ("fit the model again with `sin3dm-lite fit MESH --out DIR`" if what == "model"
           else "delete it to restart that stage, or fit again into a new run folder")
    )


def load_checkpoint(path: Path, what: str = "checkpoint") -> dict:
    """``torch.load`` with ``weights_only=True``: checkpoints hold tensors and plain containers only.

    A file that is truncated, not a checkpoint, holds code (a pickle of
    arbitrary objects) or is not a dictionary gives a :class:`Sin3DMInputError`
    naming the file; it is never unpickled with code.
    """
    import pickle
    import zipfile

    try:
        b = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:  # weights_only refused an object: the file holds more than tensors
        raise _not_ours(path, what, "it holds Python objects other than tensors, which are not loaded") from None
    except (RuntimeError, EOFError, ValueError, zipfile.BadZipFile, OSError, UnicodeDecodeError, AttributeError) as e:
        raise _not_ours(path, what, "it is truncated or not a PyTorch checkpoint" + (
            f": {e.strerror}" if isinstance(e, OSError) and e.strerror else "")) from None
    if not isinstance(b, dict):
        raise _not_ours(path, what, f"it holds a {type(b).__name__}, not a dictionary")
    return b


def load_trainer_checkpoint(path: Path, kind: str) -> dict:
    """:func:`load_checkpoint` of a trainer checkpoint (``autoencoder.pt`` / ``diffusion.pt``) of this layout.

    One of an older version, or of the other trainer, gives the one-line "not made by this version" error.
    """
    b = load_checkpoint(path, kind)
    why = checkpoint_problem(b, kind)
    if why is not None:
        raise _not_ours(path, kind, why)
    return b


def resolve_mesh(source, allow_outside_paths: bool = False) -> TexturedMesh:
    """A ``TexturedMesh`` from the name of a built-in example, or whatever ``mesh_io.load_any`` takes.

    ``allow_outside_paths``: let a mesh file name files outside its folder (:func:`mesh_io.load_mesh`).
    """
    from .data import examples
    from .data.load import load_any

    if isinstance(source, str) and source in examples.list_examples():
        return examples.build_example(source)
    if isinstance(source, str) and not Path(source).exists() and Path(source).suffix == "":
        raise Sin3DMInputError(
            f"'{source}' is neither a mesh file nor a built-in example; examples: {', '.join(examples.list_examples())}"
        )
    return load_any(source, allow_outside_paths=allow_outside_paths)


@dataclass
class Samples:
    """Generated triplanes and the box each one lives in.

    ``aabb`` is the box in normalised coordinates; a retargeted sample has a
    box scaled by the same factors as its latent so that voxels keep their size.
    ``intermediates`` holds the denoising steps when they were asked for.
    """

    triplane: Triplane
    aabb: np.ndarray
    intermediates: list | None = None
    plan: Any = None  # the control.Plan that was sampled (size, box, known latent and mask)

    def __len__(self) -> int:
        return self.triplane.batch


class Sin3DM:
    """A fitted Sin3DM model: decoder + latent of the input shape + denoiser."""

    def __init__(
        self,
        config: Config,
        decoder: TriplaneDecoder,
        latent: Triplane,
        denoiser: torch.nn.Module,
        aabb: np.ndarray,
        normalization: Normalization,
        report: dict | None = None,
        device=None,
    ):
        from .model.diffusion import NoiseSchedule

        self.config = config
        self.device = get_device(device)
        self.decoder = decoder.to(self.device).eval()
        self.latent = latent.to(self.device)
        self.denoiser = denoiser.to(self.device).eval()
        self.aabb = np.asarray(aabb, np.float32)
        self.normalization = normalization
        self.report = report or {}
        self.schedule = NoiseSchedule.from_config(config.diffusion)
        self._reconstruction_occupancy: dict[int, np.ndarray] = {}  # see plot_beside_input

    # ------------------------------------------------------------------ fit
    @classmethod
    def fit(
        cls,
        source,
        preset: str | Config | None = None,
        out: str | Path | None = None,
        resume: bool = False,
        seed: int | None = None,
        device=None,
        progress: bool = True,
        pbr: bool | None = None,
        allow_outside_paths: bool = False,
    ) -> Sin3DM:
        """Fit the whole model to one textured mesh (a path, a ``TexturedMesh`` or an example name).

        ``allow_outside_paths``: let the mesh file name textures and libraries outside its folder
        (:func:`~sin3dm_lite.mesh_io.load_mesh`; CLI: ``--allow-outside-paths``).

        ``pbr`` (the PBR variant: metallic, roughness and normals learned and
        generated beside the colour) is on by default exactly when the mesh
        has a metallic-roughness or normal map (a one-line message says so);
        ``pbr=True`` on a mesh without maps learns its constant factors and
        its geometric normals, ``pbr=False`` learns colour only. A resumed run
        keeps the choice in its ``config.json``.

        A preset with thin-part settings (``small``) fits a shape that is
        mostly thin parts with those instead (:func:`thin_parts_switch`: the
        ``detail`` settings, 96 voxels), says so and saves them as the run's
        config; ``preset=get_preset("small").updated(thin_parts={})`` keeps
        64 voxels whatever the shape. With :attr:`Config.rollout_switch`
        (``small``), a plain denoiser whose calibration keeps the input's
        patches even from pure noise is trained again with the cross-plane
        rollout and calibrated again (:func:`keeps_goals_from_noise`; the report
        keeps the first calibration as ``rollout_switch``);
        ``.updated(rollout_switch={})`` keeps the plain one.

        ``preset`` is a preset's name or a :class:`Config` (default: ``small``).

        With ``out`` a run folder is written (see the module docstring); with
        ``resume=True`` an existing run folder is continued from its last
        checkpoint, with its own settings (``preset=None``): another input
        (``runs.input_digest``: the mesh's contents, textures included, or the
        example's name) or other settings (``preset``, ``seed``, ``pbr``) are
        refused, naming what differs. The run folder is locked (``.sin3dm-lock``) while the fit
        writes it. Every argument is checked before anything is written; a new
        run folder appears with its ``config.json`` in one rename, and a fresh
        fit that fails with an error removes what it wrote (an interrupted one,
        Ctrl-C, keeps its checkpoints for ``resume=True``). A reconstruction
        below :data:`MIN_IOU` / :data:`MIN_PSNR` gives a warning.
        """
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**32):
            raise Sin3DMInputError(f"seed must be a whole number from 0 to {2**32 - 1}, got {seed!r}")
        if isinstance(preset, Config):
            preset.check()  # a setting out of range (changed in place) fails here
        elif preset is not None:
            get_preset(preset)  # a bad name fails here
        get_device(device)
        run = Path(out) if out is not None else None
        if run is not None:
            from .files import check_not_overlapping, check_writable

            if isinstance(source, (str, Path)) and Path(source).exists():
                check_not_overlapping(run, {"input mesh": Path(source)})
            if run.exists() and not run.is_dir():
                raise Sin3DMInputError(f"run folder '{run}' is a file; choose a folder for out (CLI: --out)")
            check_writable(run)
            if resume:  # a damaged checkpoint fails now, before any stage writes
                for kind in ("autoencoder", "diffusion"):
                    if (run / f"{kind}.pt").exists():
                        load_trainer_checkpoint(run / f"{kind}.pt", kind)
                if (run / "grid.npz").exists():
                    load_grid(run / "grid.npz")
        existed = run is not None and run.exists()
        try:
            model = cls._fit(source, preset, run, resume, seed, device, progress, pbr, allow_outside_paths)
        except KeyboardInterrupt:
            raise  # the checkpoints stay: continue with resume=True
        except BaseException:
            if run is not None and not resume and holds_lock(run):
                _remove_failed_run(run, existed)
            raise
        finally:
            if run is not None:
                release_lock(run)
        _warn_if_poor(model.report.get("reconstruction", {}), model.config)
        return model

    @classmethod
    def _fit(cls, source, preset, out, resume, seed, device, progress, pbr=None, allow_outside_paths=False) -> Sin3DM:
        """:meth:`fit`'s stages, after its checks."""
        say = print if progress else (lambda *a, **k: None)
        dev = get_device(device)
        run = Path(out) if out is not None else None
        have_grid = run is not None and resume and (run / "grid.npz").exists()
        # set when this fit switches to the preset's thin-part settings (resumed: when the run switched before it stopped)
        thin_parts = _read_report(run).get("thin_parts_switch") if resume and run is not None else None
        mesh = None if have_grid else resolve_mesh(source, allow_outside_paths=allow_outside_paths)  # bad input fails before any folder is written
        resuming = resume and run is not None and (run / "config.json").exists()
        if preset is None and not resuming:
            preset = "small"
        if mesh is not None and not resuming:
            pbr = _choose_pbr(mesh, pbr, preset, say)
            base = preset if isinstance(preset, Config) else get_preset(preset)
            if base.autoencoder.pbr != pbr:
                preset = base.updated(**{"autoencoder.pbr": pbr})
        asked = None
        if run is not None:  # what the run is fitted to, recorded in a new run folder and compared on resume
            from .runs import input_digest

            asked = {"input": _input_name(source), "name": _stem(source), "digest": input_digest(source, mesh)}
        cfg = _prepare_run(run, preset, resume, seed, asked, pbr)
        timings: dict[str, float] = {}

        # stage 1: mesh → grid
        t0 = time.perf_counter()
        if have_grid:
            grid = load_grid(run / "grid.npz")
            say(f"[fit] grid loaded from {run / 'grid.npz'}")
            thin = grid.thin_share()
        else:
            grid = _grid_for(mesh, cfg, progress)
            thin = grid.thin_share()
            switched = thin_parts_switch(cfg, grid, thin)
            if switched is not None:  # too coarse for this shape's thin parts: the finer settings, recorded first
                say("[fit] " + _thin_parts_message(cfg, switched, grid, thin))
                thin_parts = {"from": cfg.name, "resolution": max(grid.shape), "thin_share": thin}
                cfg = switched
                if run is not None:  # a resumed run still knows it switched (its report is completed at the end)
                    atomic_write(run / "config.json", cfg.to_json())
                    atomic_write(run / "report.json", json.dumps({"thin_parts_switch": thin_parts}, indent=2))
                grid = _grid_for(mesh, cfg, progress)  # the coarse grid served only to measure (~1 s at 64 voxels)
                thin = grid.thin_share()
            if run is not None:
                save_grid(grid, run / "grid.npz")
        timings["grid_s"] = time.perf_counter() - t0
        hint = quick_hint(cfg, dev)
        if hint:
            say("[fit] " + hint)

        # stage 2: autoencoder
        t0 = time.perf_counter()
        ae = AutoencoderTrainer(grid, cfg.autoencoder, dev, cfg.seed)
        _train(ae, run / "autoencoder.pt" if run else None, cfg.checkpoint_every, progress, say)
        h0 = ae.latent()
        metrics = reconstruction_metrics(reconstructed_grid(ae.model.decoder, h0, grid), grid)
        timings["autoencoder_s"] = time.perf_counter() - t0
        say("[fit] reconstruction: " + ", ".join(f"{k} {v:.4f}" for k, v in metrics.items()))

        # stage 3: diffusion on the latent, stage 4: the diversity knob for this shape (calibrate.py)
        rollout = _read_report(run).get("rollout_switch") if resume and run is not None else None
        base = {
            "preset": cfg.name,
            "input": grid.name,
            # the mesh file, so the run can be compared with its input later (Sin3DM.input_mesh)
            "input_path": str(Path(source).resolve()) if isinstance(source, (str, Path)) and Path(source).is_file() else None,
            "grid_shape": list(grid.shape),
            "thin_share": thin,  # ShapeGrid.thin_share of the training grid: share of the solid in parts under ~5 voxels thick
            "thin_parts_switch": thin_parts,  # {from, resolution, thin_share} when small switched to finer settings
        }
        # rollout_switch: {plain_calibration, plain_s} when a plain denoiser was trained again with the rollout
        model, history = cls._denoise(cfg, grid, h0, ae, metrics, dev, run, progress, say, timings,
                                      {**base, "rollout_switch": rollout})
        calibration = model.report.get("calibration")
        if rollout is None and cfg.rollout_switch and keeps_goals_from_noise(cfg, calibration):
            # the shape's layout varies little whatever the knob: the rollout costs it no variation (rollout_hint)
            say("[fit] " + _rollout_message(cfg))
            rollout = {"plain_calibration": {k: calibration[k] for k in ("diversity", "kept_goals")},
                       "plain_s": timings.pop("diffusion_s") + timings.pop("calibrate_s", 0.0)}
            cfg = cfg.for_rollout()
            if run is not None:  # the plain checkpoint goes first: a config with the rollout never meets it
                (run / "diffusion.pt").unlink(missing_ok=True)
                atomic_write(run / "config.json", cfg.to_json())
                atomic_write(run / "report.json", json.dumps({"thin_parts_switch": thin_parts,
                                                              "rollout_switch": rollout}, indent=2))
            model, history = cls._denoise(cfg, grid, h0, ae, metrics, dev, run, progress, say, timings,
                                          {**base, "rollout_switch": rollout})
            if not (model.report.get("calibration") or {}).get("kept_goals"):
                import warnings

                warnings.warn("with the cross-plane rollout no diversity setting kept the input's patches, which "
                              "the plain denoiser did from pure noise; fit again without the switch: "
                              + _no_rollout_switch(cfg), stacklevel=3)
        if rollout is not None:
            timings["rollout_switch_s"] = rollout["plain_s"]
        report = model.report
        hint = None if cfg.rollout_switch else rollout_hint(cfg, calibration)
        if hint is not None:
            report["rollout_hint"] = hint
            say(hint)
        if run is not None:
            model.save(run)
            atomic_write(run / "losses.json", json.dumps({"autoencoder": ae.history, "diffusion": history}))
            atomic_write(run / "report.json", json.dumps(report, indent=2))
            say(f"[fit] run folder: {run}")
        return model

    @classmethod
    def _denoise(cls, cfg, grid, h0, ae, metrics, dev, run, progress, say, timings, report_base):
        """:meth:`fit`'s stages 3 and 4: train the denoiser on the latent ``h0``, then calibrate the knob
        (where ``cfg.sampling.calibrate``); the model, with its report, and the denoiser's loss history."""
        from .model.diffusion import DiffusionTrainer

        t0 = time.perf_counter()
        dm = DiffusionTrainer(h0, cfg.diffusion, dev, cfg.seed)
        if dm.train_forward is not dm.model:
            say("[fit] diffusion: the first step compiles the denoiser for this GPU (torch.compile, about a minute)")
        _train(dm, run / "diffusion.pt" if run else None, cfg.checkpoint_every, progress, say)
        timings["diffusion_s"] = time.perf_counter() - t0

        report = {
            **report_base,
            "latent_shape": list(h0.resolution),
            "autoencoder_steps": ae.step_count,
            "diffusion_steps": dm.step_count,
            "reconstruction": metrics,
            "final_loss": {"autoencoder": ae.history["loss"][-1], "diffusion": dm.history["loss"][-1]},
            "timings_s": timings,
            "device": str(dev),
        }
        model = cls(cfg, ae.model.decoder, h0, dm.model_for_sampling, grid.aabb, grid.normalization, report, dev)
        # stage 4: the diversity knob for this shape: the most varied samples that keep its patches
        if cfg.sampling.calibrate:
            say("[fit] calibrating the diversity knob for this shape: a few samples at a few settings, scored against "
                "the input (LP-IoU / LP-F); the most varied setting that keeps the goals becomes the run's default")
            t0 = time.perf_counter()
            model.calibrate(reference=grid.sdf < 0, progress=progress)
            timings["calibrate_s"] = time.perf_counter() - t0
        return model, dm.history

    # --------------------------------------------------------------- sample
    @torch.no_grad()
    def sample(
        self,
        n: int = 1,
        resize: tuple[float, float, float] | float = (1.0, 1.0, 1.0),
        steps: int | None = None,
        method: str | None = None,
        seed: int | list[int] = 0,
        return_intermediates=None,
        known: Triplane | None = None,
        mask: Triplane | None = None,
        progress: bool = True,
        diversity: float | None = None,
        outpaint: tuple[float, float, float] | float | None = None,
        anchor: str = "center",
        regenerate=None,
        duplicate=None,
        plan=None,
    ) -> Samples:
        """Draw ``n`` new triplanes from noise, optionally controlled (the paper's Sec. 4.4, see :mod:`.control`).

        * ``resize`` scales the latent per axis (retargeting: the denoiser is
          fully convolutional, so noise of another size gives a shape of another size);
        * ``outpaint=(sx, sy, sz)`` (each ≥ 1) grows the box and keeps the input
          in it (``anchor``: ``"center"`` or the face it sticks to, e.g. ``"x-"``);
        * ``regenerate=((x0, y0, z0), (x1, y1, z1))`` resamples that box and keeps the rest;
        * ``duplicate=(((x0, y0, z0), (x1, y1, z1)), (tx, ty, tz))`` copies the
          box so its low corner lands at ``(tx, ty, tz)`` and generates around both copies.

        Boxes are fractions [0, 1] of the model's box along x, y, z. One of
        these at a time; ``plan`` takes a :class:`control.Plan` made by hand.
        ``known``/``mask`` fix part of the latent directly (same size as the samples).

        ``diversity`` (default: the config's for plain and resized samples, 1 for
        outpainting, editing and duplication) trades variation for
        fidelity, the limitation the paper names: 1 samples from pure noise;
        below 1 sampling starts from the input's latent with that share of
        noise (a resized sample starts from the input's latent stretched to
        its size, an outpainted or edited one from the known latent), so the
        layout stays and only what the noise erased is regenerated; 0 gives
        the input (or the known latent) back. The result's ``plan`` says what was sampled.

        Sample ``i`` comes from the seed ``seed + i`` alone (or ``seed[i]`` for a
        list): ``sample(4, seed=0)``'s third is ``sample(1, seed=2)``, whatever
        the batch or the device, so any sample of a large run can be drawn again on its own.
        """
        from .model.diffusion import sample as diffusion_sample
        from .model.diffusion import start_step

        if n < 1:
            raise Sin3DMInputError(f"number of samples must be at least 1, got {n}")
        plan = self.plan(resize, outpaint, anchor, regenerate, duplicate, plan)
        if plan.known is not None and known is not None:
            raise Sin3DMInputError(f"{plan.kind} chooses what to keep itself; do not pass known/mask with it")
        known, mask = (plan.known, plan.mask) if plan.known is not None else (known, mask)
        factors = np.array(plan.resolution) / np.array(self.latent.resolution)
        limit = self.max_samples(factors)
        if n > limit:
            raise Sin3DMInputError(f"{n} samples do not fit in memory at once here (at most {limit} with "
                                   "this model and size); draw them in several calls with other seeds")
        s = self.config.sampling
        if diversity is None:  # the run's setting; controlled generation regenerates from pure noise as in the paper
            diversity = s.diversity if plan.known is None else 1.0
        t0 = start_step(self.schedule, diversity)  # checks the value
        out = diffusion_sample(
            self.denoiser,
            self.schedule,
            plan.resolution,
            n=n,
            latent_channels=self.latent.channels,
            method=method or s.method,
            steps=steps or s.steps,
            seed=seed,
            known=known,
            mask=mask,
            return_intermediates=return_intermediates,
            progress=progress,
            device=self.device,
            prediction=self.config.diffusion.prediction,
            start=plan.start if t0 < self.schedule.timesteps - 1 else None,
            diversity=diversity,
        )
        tp, inter = out if return_intermediates is not None else (out, None)
        return Samples(tp, plan.aabb, inter, plan)

    def plan(self, resize=(1.0, 1.0, 1.0), outpaint=None, anchor: str = "center", regenerate=None, duplicate=None,
             plan=None):
        """The :class:`control.Plan` that :meth:`sample` carries out for these arguments (checked: one clear error)."""
        from .generate import control

        resized = np.any(np.broadcast_to(np.asarray(resize, dtype=np.float64), (3,)) != 1.0)
        asked = [k for k, v in (("resize", resized or None), ("outpaint", outpaint), ("regenerate", regenerate),
                                ("duplicate", duplicate), ("plan", plan)) if v is not None]
        if len(asked) > 1:
            raise Sin3DMInputError(f"one control at a time: got {' and '.join(asked)}")
        if plan is not None:
            return plan
        # the margin of empty voxels around the shape (half as many texels) and the shape's cut face: not kept where
        # the shape grows out of (outpaint) or is copied away from (duplicate) a face of the model's box
        trim = int(np.ceil(self.config.grid.margin_voxels / 2)) + 1
        if outpaint is not None:
            return control.outpaint(self.latent, self.aabb, outpaint, anchor, trim=trim)
        if regenerate is not None:
            return control.regenerate(self.latent, self.aabb, regenerate)
        if duplicate is not None:
            try:
                box, to = duplicate
            except (TypeError, ValueError):
                raise Sin3DMInputError("duplicate takes (box, to): ((x0, y0, z0), (x1, y1, z1)) and (tx, ty, tz)") from None
            return control.duplicate(self.latent, self.aabb, box, to, trim=trim)
        return control.retarget(self.latent, self.aabb, resize)

    def max_samples(self, resize=(1.0, 1.0, 1.0)) -> int:
        """How many samples one :meth:`sample` call can hold: the denoiser keeps about 16 feature maps of its
        widest layer per sample, and half the free memory of the device may go to them (at most 10,000)."""
        from .device import memory_available

        factors = np.broadcast_to(np.asarray(resize, dtype=np.float64), (3,))
        x, y, z = np.maximum(4, np.round(np.array(self.latent.resolution) * factors))
        width = max(int(self.config.diffusion.base_channels), int(self.latent.channels)) * 2
        per_sample = 16 * (x * y + x * z + y * z) * width * 4
        return int(max(1, min(MAX_SAMPLES, 0.5 * memory_available(self.device) // per_sample)))

    def check_mesh_sizes(self, resolution: int, texture_size: int, aabb=None, parallel: int = 1,
                         names: tuple[str, str] = ("mesh resolution", "texture size")) -> None:
        """Refuse a mesh resolution or texture size out of range (:data:`config.LIMITS`) or beyond memory.

        One export holds about :data:`EXPORT_BYTES_PER_VOXEL` per voxel of the decode grid over ``aabb``
        (default: the model's box) and :data:`EXPORT_BYTES_PER_TEXEL` per texel; ``parallel`` exports at once
        (``--workers``) may use half the free RAM between them, as :meth:`max_samples` does. ``names``: what the
        message calls the two (CLI flags). The message gives the largest value that fits.
        """
        from .data.box import grid_shape
        from .data.config import LIMITS, check_setting
        from .device import memory_available

        keys = ("sampling.mesh_resolution", "sampling.texture_size")
        for key, value, name in zip(keys, (resolution, texture_size), names):  # a whole number, not too small
            check_setting(key, min(value, LIMITS[key][1]) if isinstance(value, int) else value, option=name)
        box = np.asarray(self.aabb if aabb is None else aabb, np.float64)
        ext = box[3:] - box[:3]
        share = float(np.prod(ext / ext.max()))  # voxels ≈ share · resolution³
        budget = 0.5 * memory_available("cpu") / max(1, parallel)  # the export's arrays live in RAM, whatever the device
        cap_res, cap_tex = LIMITS[keys[0]][1], LIMITS[keys[1]][1]

        def most_res(texels: float) -> int:  # the largest resolution that fits beside ``texels``
            return min(cap_res, int((max(budget - texels * EXPORT_BYTES_PER_TEXEL, 0) / EXPORT_BYTES_PER_VOXEL / share)
                                    ** (1 / 3)))

        def most_tex(voxels: float) -> int:  # the largest texture that fits beside ``voxels``
            return min(cap_tex, int((max(budget - voxels * EXPORT_BYTES_PER_VOXEL, 0) / EXPORT_BYTES_PER_TEXEL) ** 0.5))

        at_once = f", {parallel} exports at once (--workers)" if parallel > 1 else ""
        if resolution > most_res(0):  # too large even without a texture
            fits = texture_size <= most_tex(0)
            most = most_res(float(texture_size) ** 2) if fits else most_res(0)
            beside = f" and {names[1]} {texture_size}" if fits else ""
            raise Sin3DMInputError(
                f"{names[0]} {resolution} is too large: at most {most} here ({cap_res:,} anywhere; what fits in memory "
                f"with this box{beside}{at_once}); ask for a smaller one")
        most = most_tex(float(np.prod(grid_shape(box, resolution))))
        if texture_size > most:
            raise Sin3DMInputError(
                f"{names[1]} {texture_size} is too large: at most {most} here ({cap_tex:,} anywhere; what fits in "
                f"memory with {names[0]} {resolution}{at_once}); ask for a smaller one")

    def with_denoiser(self, denoiser: torch.nn.Module, diffusion: DiffusionConfig) -> Sin3DM:
        """The same input (decoder, latent, box) with another denoiser, e.g. one retrained for an ablation.

        ``diffusion`` is the config that denoiser was trained with (its
        ``prediction`` and schedule decide how it is sampled). Decoder and
        latent are shared with this model, not copied.
        """
        return Sin3DM(replace(self.config, diffusion=diffusion), self.decoder, self.latent, denoiser, self.aabb,
                      self.normalization, dict(self.report), self.device)

    def calibrate(self, reference: np.ndarray | None = None, input_mesh=None, progress: bool = True,
                  **options) -> Calibration:
        """Set ``config.sampling.diversity`` to the most varied setting whose samples keep the input's patches.

        :func:`sin3dm_lite.calibrate.calibrate_diversity` draws a few samples
        at a handful of settings and scores them with the paper's LP-IoU / LP-F
        against ``reference``, the input's occupancy on this model's box
        (default: ``input_mesh``, a mesh, path or example name, or else
        :meth:`input_mesh`, voxelised at the fit's grid resolution).
        The choice and what was tried land in ``report["calibration"]``;
        ``options`` go to ``calibrate_diversity`` (``goals``, ``n``, ``seed``,
        ``lowest``, ``step``, ``margin``, ``refine``, ``caution``, ``safety``, ``relative``). :meth:`save` (or
        ``sin3dm-lite calibrate``) keeps it.
        """
        from .evaluate.calibrate import calibrate_diversity, model_sampler

        if reference is None:
            mesh = self.input_mesh() if input_mesh is None else resolve_mesh(input_mesh)
            resolution = max(self.report.get("grid_shape") or [self.config.grid.resolution])
            reference = self.input_occupancy(mesh, resolution)
        cal = calibrate_diversity(model_sampler(self, reference), reference, progress=progress, **options)
        self.config = self.config.updated(**{"sampling.diversity": cal.diversity})
        self.report["calibration"] = cal.to_dict()
        if progress:
            print(f"[calibrate] {'chose' if cal.kept_goals else 'no setting kept the goals; the lowest tried,'} "
                  f"diversity {cal.diversity:g}", flush=True)
            print("\n".join(f"[calibrate] {line}" for line in cal.story().splitlines()), flush=True)
        return cal

    def input_sample(self) -> Samples:
        """The input's own latent as a one-item :class:`Samples` (decode it to see the reconstruction)."""
        return Samples(self.latent.clone(), self.aabb.copy())

    # -------------------------------------------------------------- to mesh
    def to_mesh(
        self,
        samples: Samples,
        index: int | None = None,
        resolution: int | None = None,
        faces: int | None = None,
        texture_size: int | None = None,
        vertex_colors: bool = False,
        original_coords: bool = True,
    ) -> list[TexturedMesh] | TexturedMesh:
        """Decode samples into textured meshes (all of them, or the one at ``index``)."""
        from .generate.extract import extract_mesh

        s = self.config.sampling
        self.check_mesh_sizes(resolution or s.mesh_resolution, texture_size or s.texture_size, samples.aabb)
        items = range(len(samples)) if index is None else [index]
        meshes = []
        for i in items:
            m = extract_mesh(
                self.decoder,
                samples.triplane[i],
                samples.aabb,
                normalization=self.normalization,
                resolution=resolution or s.mesh_resolution,
                faces=faces or s.faces,
                texture_size=texture_size or s.texture_size,
                vertex_colors=vertex_colors,
                original_coords=original_coords,
            )
            m.name = f"sample_{i:03d}"
            meshes.append(m)
        return meshes if index is None else meshes[0]

    def same_voxels(self, samples: Samples, resolution: int) -> int:
        """Voxels along the longest side of ``samples``' box that give the voxel size the input's box has at ``resolution``.

        A retargeted or outpainted sample is larger than the input; voxelised
        with this, it can be compared with the input voxel for voxel (and its
        pictures keep their relative sizes).
        """
        ext = np.asarray(samples.aabb[3:] - samples.aabb[:3], np.float64)
        own = np.asarray(self.aabb[3:] - self.aabb[:3], np.float64)
        return int(round(resolution * ext.max() / own.max()))

    def plot_beside_input(self, samples: Samples, resolution: int = 64, labels=None):
        """Front and top views (:func:`viz.plot_projections`) of the samples beside the input's reconstruction.

        All at the voxel size the input's box has at ``resolution`` (larger
        samples look larger). The reconstruction's grid is computed once per
        resolution and kept. Each shape is decoded at twice the picture's
        voxels (not the export's mesh resolution): a picture needs no more.
        """
        from .show.viz import plot_projections

        if resolution not in self._reconstruction_occupancy:
            self._reconstruction_occupancy[resolution] = self.occupancy(
                self.input_sample(), resolution, mesh_resolution=2 * resolution)[0]
        res = self.same_voxels(samples, resolution)
        grids = self.occupancy(samples, res, mesh_resolution=2 * res)
        labels = list(labels) if labels is not None else [f"{i:03d}" for i in range(len(grids))]
        return plot_projections([self._reconstruction_occupancy[resolution], *grids], ["input", *labels])

    def occupancy(self, samples: Samples, resolution=128, mesh_resolution: int | None = None):
        """Each sample's mesh as an occupancy grid over its box, ``resolution`` voxels along the longest side.

        What the paper's geometry metrics take (:mod:`sin3dm_lite.metrics`): the
        sample is decoded to a mesh as for export (no texture) and voxelised.
        With a list of resolutions, returns ``{resolution: [grids]}`` and decodes each sample once.
        A sample with no surface (a diverged one: all empty, or the box all inside) counts as an
        empty or a full grid, so it lowers the scores instead of stopping the evaluation.
        """
        from .data.box import grid_shape
        from .evaluate.metrics import voxelize
        from .generate.extract import NoSurfaceError

        several = not isinstance(resolution, (int, np.integer))
        res = list(resolution) if several else [resolution]
        grids: dict[int, list[np.ndarray]] = {r: [] for r in res}
        for i in range(len(samples)):
            try:
                mesh = self.to_mesh(samples, i, resolution=mesh_resolution, original_coords=False, vertex_colors=True)
            except NoSurfaceError as e:
                if e.fill is None:
                    raise
                for r in res:
                    grids[r].append(np.full(grid_shape(samples.aabb, r), bool(e.fill)))
                continue
            for r in res:
                grids[r].append(voxelize(mesh, samples.aabb, r))
        return grids if several else grids[res[0]]

    def input_occupancy(self, mesh: TexturedMesh, resolution: int = 128, aabb=None) -> np.ndarray:
        """The input mesh (in its file's coordinates) as an occupancy grid over this model's box (or ``aabb``,
        normalised coordinates): the metrics' reference."""
        from .evaluate.metrics import input_occupancy

        m = replace(mesh, vertices=self.normalization.to_normalized(np.asarray(mesh.vertices)))
        return input_occupancy(m, self.aabb if aabb is None else aabb, resolution)

    def input_mesh(self, allow_outside_paths: bool = False) -> TexturedMesh:
        """The mesh this model was fitted to: the mesh file the run's report names, if it is still there, or the
        built-in example of that name (``allow_outside_paths``: see :func:`mesh_io.load_mesh`)."""
        from .data import examples

        path, name = self.report.get("input_path"), self.report.get("input")
        if path and Path(path).is_file():
            return resolve_mesh(path, allow_outside_paths=allow_outside_paths)
        if path or name not in examples.list_examples():  # a file (even one named like an example) is not the example
            where = f"'{path}' is gone" if path else f"it was fitted to '{name}', not a built-in example"
            raise Sin3DMInputError(f"cannot find this model's input mesh ({where}); pass the input mesh "
                                   "(CLI: --input MESH) to compare samples with it")
        return examples.build_example(name)

    def evaluate(self, samples, input_mesh=None, resolution: int = 64, views: int = 8, size: int = 256,
                 weights=None, progress: bool = True) -> dict:
        """The paper's metrics of generated shapes against the input mesh (docs/paper-notes.md "Evaluation").

        ``samples``: a :class:`Samples` (decoded here) or meshes in the input
        file's coordinates (what ``sample`` exports). ``input_mesh``: a mesh,
        path or example name (default: :meth:`input_mesh`). ``weights``: a
        folder with the pre-trained weights of SIFID and LPIPS
        (:func:`metrics.load_feature_weights`), or a loaded ``FeatureNets``.

        Geometry (:func:`metrics.geometry_scores`): G-Div, LP-IoU, LP-F and the
        IoU to the input on occupancy grids of ``resolution`` voxels along the
        longest side of the model's box (a box covering larger, retargeted
        samples keeps that voxel size). Texture (:func:`metrics.texture_scores`)
        on ``views`` renders of ``size`` pixels at elevation 45°, input and
        samples framed by the same box: ``patch_swd`` and ``render_div`` always,
        ``sifid`` and ``lpips`` with ``weights``. Without an off-screen renderer
        the texture metrics are None and ``skipped["texture"]`` says why.
        G-Qual (SSFID) is never computed (``skipped["ssfid"]``).

        Returns ``{"samples", "resolution", "views", "size", "metrics": {name: value or None},
        "skipped": {name: reason}, "timings_s": {...}}``.

        Time (2-core CPU, ``OMP_NUM_THREADS=1``, other jobs running; defaults): the
        shipped ``canyon_small`` with 4 samples of 20k faces took 1.1 s for the
        geometry, 7.4-8.1 s to render 5 meshes × 8 views and 2.5 s for the
        weight-free texture metrics (+2.9 s for SIFID and LPIPS): about 2.5 s
        per sample plus the input's renders.
        """
        from .evaluate.metrics import (
            SSFID_UNAVAILABLE,
            FeatureNets,
            geometry_scores,
            load_feature_weights,
            texture_scores,
            voxelize,
        )
        from .evaluate.render import render_views, renderer_problem

        say = print if progress else (lambda *a, **k: None)
        nets = weights if isinstance(weights, FeatureNets) or weights is None else load_feature_weights(weights)
        ref = self.input_mesh() if input_mesh is None else resolve_mesh(input_mesh)
        t0 = time.perf_counter()
        meshes = self.to_mesh(samples) if isinstance(samples, Samples) else list(samples)
        if not meshes:
            raise Sin3DMInputError("evaluate needs at least one sample mesh")
        to_norm = self.normalization.to_normalized
        normed = [replace(m, vertices=to_norm(np.asarray(m.vertices, np.float64))) for m in meshes]
        # one box for all: the model's, grown to hold larger (retargeted) samples at the same voxel size
        lo = np.minimum(self.aabb[:3], np.min([m.vertices.min(0) for m in normed], axis=0))
        hi = np.maximum(self.aabb[3:], np.max([m.vertices.max(0) for m in normed], axis=0))
        box = np.concatenate([lo, hi])
        res = int(round(resolution * (hi - lo).max() / (self.aabb[3:] - self.aabb[:3]).max()))
        reference = self.input_occupancy(ref, res, box)
        grids = [voxelize(m, box, res) for m in normed]
        metrics: dict[str, Any] = geometry_scores(reference, grids)
        timings = {"geometry_s": time.perf_counter() - t0}
        say(f"[evaluate] geometry of {len(meshes)} samples at {res} voxels: {timings['geometry_s']:.1f} s")
        skipped = {"ssfid": SSFID_UNAVAILABLE}
        metrics["ssfid"] = None
        problem = renderer_problem()
        if problem is not None:
            skipped["texture"] = f"texture metrics skipped: {problem}"
            metrics.update(dict.fromkeys(["patch_swd", "render_div", "sifid", "lpips"]))
        else:
            t0 = time.perf_counter()
            frame = self.normalization.to_original(np.stack([lo, hi]))
            ref_views = render_views(ref, views, size, box=frame)
            sample_views = [render_views(m, views, size, box=frame) for m in meshes]
            timings["render_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            metrics.update({"sifid": None, "lpips": None, **texture_scores(ref_views, sample_views, nets)})
            timings["texture_s"] = time.perf_counter() - t0
            say(f"[evaluate] {views} views of {len(meshes) + 1} meshes at {size}²: rendered in {timings['render_s']:.1f} s, "
                f"texture metrics {timings['texture_s']:.1f} s")
            if nets is None:
                skipped["sifid"] = skipped["lpips"] = "no pre-trained weights given (CLI: --weights DIR)"
        if len(meshes) < 2:
            skipped["diversity"] = "G-Div and the texture diversities need at least two samples"
        return {"samples": len(meshes), "resolution": res, "views": views, "size": size, "metrics": metrics,
                "skipped": skipped, "timings_s": timings}

    # ------------------------------------------------------------ save/load
    def save(self, run_dir: str | Path) -> Path:
        """Write ``model.pt`` (everything sampling needs) and ``config.json`` into ``run_dir``."""
        run = Path(run_dir)
        run.mkdir(parents=True, exist_ok=True)
        bundle = {
            "format": "sin3dm-lite/1",
            "config": self.config.to_json(),
            "decoder": {k: v.cpu() for k, v in self.decoder.state_dict().items()},
            "latent": self.latent.state_dict(),
            "denoiser": {k: v.cpu() for k, v in self.denoiser.state_dict().items()},
            "aabb": torch.from_numpy(self.aabb.copy()),
            "center": torch.from_numpy(np.asarray(self.normalization.center, np.float64)),
            "scale": float(self.normalization.scale),
            "color_channels": int(self.decoder.color_channels),
            "report": json.dumps(self.report),
        }
        atomic_torch_save(bundle, run / MODEL_FILE)
        atomic_write(run / "config.json", self.config.to_json())
        return run / MODEL_FILE

    @classmethod
    def open(cls, run, preset=None, cache="runs/cache", device=None, progress: bool = True) -> Sin3DM:
        """The model ``run`` names: a shipped model, a run folder, or a mesh / example fitted once into ``cache``
        and reused after (the rules: :mod:`sin3dm_lite.runs`).

        ``preset`` (default: :func:`config.notebook_preset`, ``tiny`` under ``SIN3DM_FAST=1``, else ``small``) is
        used only when ``run`` has to be fitted. The model's ``run_dir`` attribute is the folder it was loaded from.
        """
        from .runs import fit_preset, resolve_run

        kind, folder = resolve_run(run, preset, cache)
        say = print if progress else (lambda *a, **k: None)
        if kind == "fit" and not (folder / MODEL_FILE).is_file():
            resume = (folder / "config.json").is_file()
            say(f"[run] '{run}': {'resuming the interrupted' if resume else 'fitting once (cached)'} fit in {folder}")
            model = cls.fit(run, preset=fit_preset(preset), out=folder, resume=resume, device=device, progress=progress)
        else:
            if kind == "fit":
                say(f"[run] '{run}': the cached fit {folder} (delete it to fit again)")
            model = cls.load(folder, device=device)
        model.run_dir = folder
        return model

    @classmethod
    def load(cls, run_dir: str | Path, device=None) -> Sin3DM:
        """Load a fitted model from a run folder (or a ``model.pt`` file)."""
        from .model.unet import TriplaneUNet

        path = Path(run_dir)
        path = path / MODEL_FILE if path.is_dir() else path
        if not path.is_file():
            raise Sin3DMInputError(
                f"no fitted model at '{run_dir}' (expected {MODEL_FILE}); fit one with `sin3dm-lite fit MESH --out DIR`"
            )
        b = load_checkpoint(path, "model")
        fmt = b.get("format")
        if fmt != MODEL_FORMAT:
            raise _not_ours(path, "model", f"its format is {fmt!r}, not '{MODEL_FORMAT}'" if fmt else "it has no format tag")
        try:
            cfg = Config.from_dict(json.loads(b["config"]))
            latent = Triplane.from_state_dict(b["latent"])
            decoder = TriplaneDecoder(cfg.autoencoder, float(b["decoder"]["threshold"]), int(b["color_channels"]))
            decoder.load_state_dict(b["decoder"])
            denoiser = TriplaneUNet(latent.channels, cfg.diffusion)
            denoiser.load_state_dict(b["denoiser"])
            norm = Normalization(center=b["center"].numpy(), scale=float(b["scale"]))
            aabb, report = b["aabb"].numpy(), json.loads(b["report"])
        except KeyError as e:
            raise _not_ours(path, "model", f"the entry {e} is missing") from None
        except Exception as e:  # noqa: BLE001 - wrong shapes, types or JSON: one clear message
            raise _not_ours(path, "model", f"its contents do not match ({type(e).__name__})") from None
        return cls(cfg, decoder, latent, denoiser, aabb, norm, report, device)


# --------------------------------------------------------------------------- helpers
def _choose_pbr(mesh: TexturedMesh, pbr: bool | None, preset, say) -> bool:
    """Whether to fit the PBR variant: asked for, or (``pbr=None``) whenever the mesh has PBR maps."""
    already = isinstance(preset, Config) and preset.autoencoder.pbr
    if pbr is None:
        pbr = bool(already or mesh.has_pbr)
        if pbr and mesh.has_pbr:
            say(f"[fit] '{mesh.name}' has PBR maps: learning base colour, metallic, roughness and normals (pbr=False: colour only)")
    elif pbr and not mesh.has_pbr:
        say(f"[fit] '{mesh.name}' has no PBR maps: learning its constant metallic / roughness and its geometric normals")
    return bool(pbr)


def _check_flips(cfg: Config) -> None:
    """``diffusion.flips`` needs a decoder that commutes with flips (autoencoder.mirror), and no PBR normals."""
    if not cfg.diffusion.flips:
        return
    check_flips(cfg.diffusion.flips)
    if not cfg.autoencoder.mirror:
        raise Sin3DMInputError(
            f"diffusion.flips='{cfg.diffusion.flips}' needs autoencoder.mirror=true: only a decoder with mirror-symmetric "
            "kernels decodes a flipped latent to the mirrored shape (CLI: --set autoencoder.mirror=true)")
    if cfg.autoencoder.pbr:
        raise Sin3DMInputError(
            "diffusion.flips does not work with the PBR variant: a mirrored shape's normals change direction, which a "
            "flipped latent does not say; fit with pbr=False (CLI: --no-pbr) or without flips")


def _prepare_run(run: Path | None, preset, resume: bool, seed: int | None, asked: dict | None = None,
                 pbr: bool | None = None) -> Config:
    """Resolve the config and check the run folder (new, or resumable with the same input and settings)."""
    cfg = None
    if preset is not None:
        cfg = preset if isinstance(preset, Config) else get_preset(preset)
        _check_flips(cfg)
        if seed is not None:
            cfg = cfg.updated(seed=seed)
    if run is None:
        if resume:
            raise Sin3DMInputError("resume needs a run folder; pass out=RUN_DIR (CLI: --out RUN_DIR)")
        return cfg
    cfg_file = run / "config.json"
    if resume:
        if not cfg_file.exists():
            raise Sin3DMInputError(f"cannot resume: '{run}' is not a fit's run folder (it has no config.json, which a "
                                   "fit writes first); start a new fit into a new or empty folder (CLI: --out)")
        asked_cfg = cfg
        try:
            cfg = Config.from_dict(json.loads(cfg_file.read_text()))
        except Sin3DMInputError as e:  # a setting out of range
            raise Sin3DMInputError(f"cannot resume: '{cfg_file}': {e}") from None
        except Exception:  # noqa: BLE001 - a damaged or foreign config: one clear message
            raise _not_ours(cfg_file, "config", "it is not a readable configuration") from None
        if asked is not None:  # another mesh or other settings would train on top of this run's checkpoints
            if asked_cfg is None and (seed is not None or pbr is not None):  # the run's own, with these changed
                asked_cfg = _recorded_config(run, cfg).updated(**({} if seed is None else {"seed": seed}))
            _check_same_request(run, asked, asked_cfg, pbr, cfg)
        acquire_lock(run)
        return cfg
    if run.exists() and any(run.iterdir()):
        if (run / "config.json").is_file():
            raise Sin3DMInputError(f"run folder '{run}' is not empty: it holds a fit; continue it with --resume, or "
                                   "choose a new or empty --out")
        raise Sin3DMInputError(f"--out '{run}' is not empty and holds no fit of sin3dm-lite; choose a new or empty "
                               "folder for --out (nothing in it is touched)")
    # the new run folder appears with its config and lock in one rename: a kill leaves a resumable
    # folder or only a temporary one (removed by the next run), never a folder that blocks the next try
    files = {"config.json": cfg.to_json()}
    if asked is not None:
        files[INPUT_FILE] = json.dumps({**asked, "config": cfg.to_dict()}, indent=2)
    create_locked_folder(run, files, option="--out")
    return cfg


def _stem(source) -> str:
    """The input's name as a grid and a report keep it: the example's name, the file's stem, the mesh's name."""
    from .data import examples

    if isinstance(source, TexturedMesh):
        return source.name
    if isinstance(source, str) and source in examples.list_examples() and not Path(source).is_file():
        return source
    return Path(source).stem


def _input_name(source) -> str:
    """How a message names the input: the example's name, the mesh file's path, or the mesh's name."""
    if isinstance(source, TexturedMesh):
        return f"the mesh '{source.name}'"
    from .data import examples

    if isinstance(source, str) and source in examples.list_examples() and not Path(source).is_file():
        return f"the example '{source}'"
    return f"'{source}'"


def _read_input(run: Path) -> dict | None:
    """The run folder's input.json (what it was fitted to), or None when it has none (an older version's run)."""
    try:
        rec = json.loads((run / INPUT_FILE).read_text())
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and isinstance(rec.get("digest"), str) else None


def _recorded_config(run: Path, cfg: Config) -> Config:
    """The settings a run was asked for (its input.json), else its config.json's ``cfg``."""
    rec = _read_input(run)
    try:
        return Config.from_dict(rec["config"]) if rec and isinstance(rec.get("config"), dict) else cfg
    except (Sin3DMInputError, TypeError):
        return cfg


def _check_same_request(run: Path, asked: dict, asked_cfg: Config | None, pbr: bool | None, cfg: Config) -> None:
    """Refuse to resume ``run`` with another input than it was fitted to, or other settings (one line: what differs)."""
    rec = _read_input(run)
    if rec is not None:
        other_input = rec["digest"] != asked["digest"]
        was = rec.get("input", "another mesh")
    else:  # a run of an older version: its report names the input, if it got that far
        name = _read_report(run).get("input")
        other_input = isinstance(name, str) and name != asked["name"]
        was = f"'{name}'"
    if other_input:
        raise Sin3DMInputError(
            f"cannot resume: '{run}' was fitted to {was}, not {asked['input']}; resume it with that input, or fit "
            f"{asked['input']} into a new --out")
    if asked_cfg is None:
        return
    want, have = asked_cfg.to_dict(), _recorded_config(run, cfg).to_dict()
    if pbr is not None:
        want["autoencoder"]["pbr"] = bool(pbr)
    elif not want["autoencoder"]["pbr"]:  # chosen from the mesh, which is the same
        want["autoencoder"]["pbr"] = have["autoencoder"]["pbr"]
    want, have = Config.from_dict(want).settings(), Config.from_dict(have).settings()
    if rec is None:  # an older run records only its config.json, which its switches and calibration changed
        have.update(name=have["name"].split("+")[0])
        differ = [k for k in ("name",) if want[k] != have[k]]
    else:
        differ = [k for k in want if want[k] != have.get(k)]
    if differ:
        shown = [f"{'preset' if k == 'name' else k} {have.get(k)!r} there, {want[k]!r} now" for k in differ[:3]]
        more = f" and {len(differ) - 3} more" if len(differ) > 3 else ""
        raise Sin3DMInputError(
            f"cannot resume: '{run}' was fitted with other settings ({'; '.join(shown)}{more}); resume it with its "
            "own (leave out --preset, --set, --seed and --pbr; Python: preset=None), or fit into a new --out")


def _read_report(run: Path) -> dict:
    """The run folder's report.json, or {} when it is missing or unreadable (it is only a record)."""
    try:
        report = json.loads((run / "report.json").read_text())
    except (OSError, ValueError):
        return {}
    return report if isinstance(report, dict) else {}


def _remove_failed_run(run: Path, existed: bool) -> None:
    """Remove what a failed fresh fit wrote into ``run`` (and the folder, if the fit made it and it is empty)."""
    import re

    for name in RUN_FILES:
        (run / name).unlink(missing_ok=True)
    for p in run.iterdir():  # temporaries of atomic writes
        if re.match(r"^\..*\.sin3dm-\d+-[^.]*\.tmp", p.name):
            p.unlink(missing_ok=True)
    release_lock(run)
    if not existed:
        try:
            run.rmdir()
        except OSError:
            pass  # someone put a file there meanwhile: leave it


def _preset_expr(cfg: Config) -> str:
    """How a user names the run's preset in Python: ``preset=get_preset('small')`` (or ``your Config``)."""
    base = cfg.name.split("+")[0]
    return f"preset=get_preset('{base}')" if base in PRESETS else "your Config"


def _refit_advice(cfg: Config, setting: str, value, also: str = "") -> str:
    """"fit again with SETTING=VALUE (CLI: --set ...; Python: ...)" for the run's ``cfg``."""
    python = f"{_preset_expr(cfg)}.updated(**{{'{setting}': {value!r}}})"
    cli = str(value).lower() if isinstance(value, bool) else value
    return f"fit again with {setting}={cli}{also} (CLI: --set {setting}={cli}; Python: {python})"


def _no_rollout_switch(cfg: Config) -> str:
    return f"--no-rollout-switch (Python: {_preset_expr(cfg)}.updated(rollout_switch={{}}))"


def keeps_goals_from_noise(cfg: Config, calibration: dict | None) -> bool:
    """Whether a fit's denoiser has no cross-plane rollout and its calibration kept the input's patches even from
    pure noise (diversity 1): the case for the rollout (:attr:`Config.rollout_switch`, :func:`rollout_hint`).

    Such a shape's layout varies little whatever the knob (a wall's brick body, dunes), so the rollout
    costs it no variation and makes the three planes agree on the detail: on the wall a colour per brick
    and its vertical joints, which the plain denoiser smears; on the dunes smoother crests and better
    patches (docs/levers.md, "The rollout switch"). The canyon, whose calibration stops below 1, copies
    its input with the rollout, so only a calibration that reaches 1 calls for it.
    """
    return bool(not cfg.diffusion.rollout and calibration and calibration.get("kept_goals")
                and calibration.get("diversity") == 1)


def _rollout_message(cfg: Config) -> str:
    return ("this shape keeps the input's patches even from pure noise (calibrated to diversity 1): its layout "
            "varies little whatever the knob, so the denoiser is trained again with the cross-plane rollout, which "
            "makes the planes agree on fine detail at no cost in variation (on the wall: whole bricks instead of "
            f"smeared joints): {cfg.for_rollout().diffusion.steps:,} steps, each about 1.8x a plain one; to keep "
            "the plain denoiser: " + _no_rollout_switch(cfg))


def rollout_hint(cfg: Config, calibration: dict | None) -> str | None:
    """The hint a fit without :attr:`Config.rollout_switch` gives when :func:`keeps_goals_from_noise` holds
    (``None`` otherwise): fit again with the rollout."""
    if not keeps_goals_from_noise(cfg, calibration):
        return None
    return ("[fit] this shape keeps the input's patches even from pure noise (calibrated to diversity 1), so its "
            "layout varies little and the cross-plane rollout would cost it no variation, while making the planes "
            "agree on fine detail (on the wall: whole bricks instead of smeared joints); to try it, "
            + _refit_advice(cfg, "diffusion.rollout", True))


def _warn_if_poor(rec: dict, cfg: Config) -> None:
    """Warn when the autoencoder's reconstruction is too poor for useful samples, with the likely cause and the
    setting of the run's ``cfg`` to fit again with.

    Colour: more autoencoder steps, about 1.3 dB per doubling (docs/levers.md; a finer grid is not the fix
    there). Occupancy: more steps or a finer grid.
    """
    import warnings

    def fix(setting: str, value: int, also: str = "") -> str:
        return _refit_advice(cfg, setting, value, also)

    iou, psnr, steps = rec.get("occupancy_iou"), rec.get("color_psnr"), cfg.autoencoder.steps
    if iou is not None and iou < MIN_IOU:
        finer = f" or grid.resolution={8 * round(1.5 * cfg.grid.resolution / 8)}"
        warnings.warn(f"low reconstruction quality: occupancy IoU {iou:.3f} < {MIN_IOU} (likely cause: too few "
                      f"autoencoder steps or a grid too coarse for thin parts); "
                      f"{fix('autoencoder.steps', 2 * steps, finer)}", stacklevel=3)
    if psnr is not None and psnr < MIN_PSNR:
        doublings = min(3, math.ceil((MIN_PSNR - psnr) / 1.3))  # about 1.3 dB per doubling of the steps
        warnings.warn(f"low reconstruction quality: colour PSNR {psnr:.2f} dB < {MIN_PSNR:.0f} dB (likely cause: too "
                      "few autoencoder steps for this texture's detail: each doubling gave about 1.3 dB on a "
                      f"two-texture mesh, and doubles the autoencoder's time); "
                      f"{fix('autoencoder.steps', steps * 2 ** doublings)}", stacklevel=3)


def _train(trainer, ckpt: Path | None, every: int, progress: bool, say) -> None:
    """Run a trainer (:class:`~sin3dm_lite.training.Trainer`) to its end, checkpointing every ``every`` steps.

    Ctrl-C (SIGINT) is honoured only *between* steps, after a checkpoint of the
    last finished step has been written, so a resumed run loses no work and
    never starts from a half-applied optimiser step.
    """
    label = trainer.kind
    saved = {"step": None}  # the step the checkpoint file holds
    if ckpt is not None and ckpt.exists():
        state = load_trainer_checkpoint(ckpt, label)
        try:
            trainer.load_state_dict(state)
        except KeyError as e:
            raise _not_ours(ckpt, label, f"the entry {e} is missing") from None
        except (RuntimeError, ValueError, TypeError, AttributeError, IndexError) as e:
            raise _not_ours(ckpt, label, f"its contents do not match ({type(e).__name__})") from None
        saved["step"] = trainer.step_count
        say(f"[fit] {label}: resumed at step {trainer.step_count}")
    stop = {"asked": False}

    def save(tr) -> None:
        if ckpt is not None and saved["step"] != tr.step_count:
            atomic_torch_save(tr.state_dict(), ckpt)
            saved["step"] = tr.step_count

    def checkpoint(tr) -> None:
        if tr.step_count % every == 0 or stop["asked"]:
            save(tr)
        if stop["asked"]:
            say(f"\n[fit] {label}: interrupted at step {tr.step_count}; checkpoint saved, continue with --resume")
            raise KeyboardInterrupt

    def on_sigint(signum, frame) -> None:
        stop["asked"] = True

    main = threading.current_thread() is threading.main_thread()
    old = signal.signal(signal.SIGINT, on_sigint) if main else None
    try:
        trainer.run(progress=progress, callback=checkpoint)
    finally:
        if main:
            signal.signal(signal.SIGINT, old)
    save(trainer)  # the last step, unless the callback just wrote it


def open_run(run, preset=None, cache="runs/cache", device=None, progress: bool = True) -> Sin3DM:
    """:meth:`Sin3DM.open` as a function: the model a shipped name, a run folder, a mesh or an example names."""
    return Sin3DM.open(run, preset, cache, device, progress)

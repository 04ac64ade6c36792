"""``Sin3DM``: the whole method behind one object.

    model = Sin3DM.fit("canyon", preset="small", out="runs/canyon")   # mesh → grid → triplane → diffusion
    samples = model.sample(4, seed=0)                                  # new triplanes from noise
    meshes = model.to_mesh(samples)                                    # decoded, textured meshes

Each method is a call into the stage that does the work, so a reader follows one of them to one module:

    fit                       fitting (the stages; run_folder: the run folder; fit_policy: what the fit decides)
    sample, plan, to_mesh     sampling (settings left at None: request.SampleRequest.resolve)
    save, load                checkpoints (model.pt)
    open                      runs (what RUN names), then fit or load
    calibrate                 evaluate.calibrate (the diversity knob)
    occupancy, evaluate, ...  evaluate.evaluation (samples against the input)
    plot_beside_input         show.sample_figures

A fit writes a *run folder* (its files: :mod:`sin3dm_lite.app.run_folder`); ``fit(..., resume=True)`` continues an
interrupted run and ends exactly where an uninterrupted one would.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from .app import sampling, values
from .app.checkpoints import MODEL_FILE, read_model, write_model
from .app.device import get_device
from .app.sampling import Samples
from .auto.fit_policy import warn_if_poor
from .data.config import Config, DiffusionConfig
from .data.mesh import Normalization, TexturedMesh
from .data.source import recorded_input, resolve_mesh
from .errors import Sin3DMInputError
from .evaluate import evaluation
from .files.inputs import check_regular
from .model.autoencoder import TriplaneDecoder
from .model.triplane import Triplane

if TYPE_CHECKING:
    from .evaluate.calibration_record import Calibration


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
        from .model.schedule import NoiseSchedule

        self.config = config
        self.device = get_device(device)
        self.decoder = decoder.to(self.device).eval()
        self.latent = latent.to(self.device)
        self.denoiser = denoiser.to(self.device).eval()
        self.aabb = np.asarray(aabb, np.float32)
        self.normalization = normalization
        self.report = report or {}
        self.schedule = NoiseSchedule.from_config(config.diffusion)

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
        keeps the choice in its ``config.json``. A mesh of one colour (without
        colour: the default grey) trains the autoencoder's geometry alone, its
        colour decoded as it is (``report["single_color"]``): about half the
        autoencoder's time.

        A preset with thin-part settings (``small``) fits a shape that is
        mostly thin parts with those instead (:func:`fit_policy.thin_parts_switch`: the
        ``detail`` settings, 96 voxels), says so and saves them as the run's
        config; ``preset=get_preset("small").updated(thin_parts={})`` keeps
        64 voxels whatever the shape. With :attr:`Config.rollout_switch`
        (``small``), a plain denoiser whose calibration keeps the input's
        patches even from pure noise is trained again with the cross-plane
        rollout and calibrated again (:func:`fit_policy.keeps_goals_from_noise`; the report
        keeps the first calibration as ``rollout_switch``);
        ``.updated(rollout_switch={})`` keeps the plain one. With
        :attr:`Config.thin_walls` (``quick``), a shape that is almost all thin
        walls gets a wider denoiser field too, which goes back to the narrower
        one if its samples from pure noise copy the shape after a few steps
        (:func:`fit_policy.are_copies`; the report's ``thin_parts_switch``
        records the check); ``.updated(thin_walls={})`` keeps the narrower one.

        ``preset`` is a preset's name or a :class:`Config` (default: this machine's, :mod:`sin3dm_lite.auto.fit_default`).

        With ``out`` a run folder is written (:mod:`sin3dm_lite.app.run_folder`); with
        ``resume=True`` an existing run folder is continued from its last
        checkpoint, with its own settings (``preset=None``): another input
        (``runs.input_digest``: the mesh's contents, textures included, or the
        example's name) or other settings (``preset``, ``seed``, ``pbr``) are
        refused, naming what differs. The run folder is locked (``.sin3dm-lock``) while the fit
        writes it. Every argument is checked before anything is written; a new
        run folder appears with its ``config.json`` in one rename, and a fresh
        fit that fails with an error removes what it wrote (an interrupted one,
        Ctrl-C, keeps its checkpoints for ``resume=True``). A reconstruction
        below :data:`fit_policy.MIN_IOU` / :data:`~fit_policy.MIN_PSNR` gives a warning.
        """
        from .app.fitting import fit

        model = fit(cls, source, preset, out, resume, seed, device, progress, pbr, allow_outside_paths)
        warn_if_poor(model.report.get("reconstruction", {}), model.config)
        return model

    def calibrate(
        self,
        reference: np.ndarray | None = None,
        input_mesh=None,
        progress: bool = True,
        resolution: int | None = None,
        supersample: int | None = None,
        **options,
    ) -> Calibration:
        """Set ``config.sampling.diversity`` to the most varied setting whose samples keep the input's patches.

        :func:`sin3dm_lite.calibrate.calibrate_diversity` draws a few samples
        at a handful of settings and scores them with the paper's LP-IoU / LP-F
        against ``reference``, the input's occupancy on this model's box
        (default: ``input_mesh``, a mesh, path or example name, or else
        :meth:`input_mesh`, voxelised at ``resolution`` voxels along the longest
        side: by default the fit's grid (:attr:`grid_resolution`), which is fast;
        128 judges as the paper measures, in about four times the time: the canyon and the colonnade
        then get 1, a thin-walled ruin a more varied default that flattens its top in some samples,
        docs/calibration.md).
        ``supersample``: the voxels judged, 1 the voxel centres (the default on the fit's grid, whose
        training grid is the centres' signs), 2 the paper's (the default at another ``resolution``:
        :meth:`evaluate`'s voxels, so the judge sees what it reports).
        The choice and what was tried land in ``report["calibration"]``;
        ``options`` go to ``calibrate_diversity`` (``goals``, ``n``, ``seed``,
        ``lowest``, ``step``, ``margin``, ``refine``, ``caution``, ``safety``, ``relative``, ``far``). :meth:`save` (or
        ``sin3dm-lite calibrate``) keeps it.
        """
        from .evaluate.calibrate import calibrate_diversity, model_sampler

        if reference is None:
            mesh = self.input_mesh() if input_mesh is None else resolve_mesh(input_mesh)
            on_grid = resolution in (None, self.grid_resolution)
            resolution = resolution or self.grid_resolution
            if not 16 <= resolution <= 512:
                raise Sin3DMInputError(f"the calibration's resolution must be from 16 to 512 voxels, got {resolution}")
            if supersample is None:
                supersample = 1 if on_grid else evaluation.PAPER_SUPERSAMPLE
            evaluation.check_fine_grid(resolution, supersample)
            reference = self.input_occupancy(mesh, resolution, supersample=supersample)
        elif resolution is not None and resolution != max(np.shape(reference)):
            raise Sin3DMInputError(
                f"resolution {resolution} does not match the reference grid {np.shape(reference)}; give one of them"
            )
        supersample = 1 if supersample is None else supersample
        sampler = model_sampler(self, reference, supersample=supersample)
        cal = calibrate_diversity(sampler, reference, progress=progress, **options)
        cal.supersample = supersample
        self.config = self.config.updated(**{"sampling.diversity": cal.diversity})
        self.report["calibration"] = cal.to_dict()
        if progress:
            print(
                f"[calibrate] {'chose' if cal.kept_goals else 'no setting kept the goals; chose'} "
                f"diversity {cal.diversity:g}",
                flush=True,
            )
            print("\n".join(f"[calibrate] {line}" for line in cal.story().splitlines()), flush=True)
        return cal

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
        snap: float | None = None,
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

        ``snap`` (0-1; default the config's ``sampling.snap``: 0, the paper's sampler, in every preset, 1 where
        ``quick``'s thin-part switch took over) pulls the last steps' predicted clean latent towards the input's
        7×7 latent patches
        (:func:`~sin3dm_lite.auto.snap.snap_to_patches`): thin walls and broken tops keep their shape at a
        higher diversity (docs/thin-parts.md). The calibration samples with the config's ``sampling.snap``, so
        fit with it set (CLI ``--set sampling.snap=1``) to have the diversity chosen for the snapped sampler.

        Sample ``i`` comes from the seed ``seed + i`` alone (or ``seed[i]`` for a
        list): ``sample(4, seed=0)``'s third is ``sample(1, seed=2)``, whatever
        the batch or the device, so any sample of a large run can be drawn again on its own.
        """
        values.whole(n, "n")  # every argument: sampling.check_sample_args, the checks the CLI's flags call too
        plan = self.plan(resize, outpaint, anchor, regenerate, duplicate, plan)
        return sampling.draw(
            self, n, plan, steps, method, seed, return_intermediates, known, mask, progress, diversity, snap
        )

    def plan(
        self, resize=(1.0, 1.0, 1.0), outpaint=None, anchor: str = "center", regenerate=None, duplicate=None, plan=None
    ):
        """The :class:`control.Plan` that :meth:`sample` carries out for these arguments (checked: one clear error)."""
        return sampling.plan_for(self, resize, outpaint, anchor, regenerate, duplicate, plan)

    def max_samples(self, resize=(1.0, 1.0, 1.0)) -> int:
        """How many samples one :meth:`sample` call can hold: the denoiser keeps about 16 feature maps of its
        widest layer per sample, and half the free memory of the device may go to them (at most 10,000)."""
        return sampling.max_samples(self, resize)

    def check_mesh_sizes(
        self,
        resolution: int,
        texture_size: int,
        aabb=None,
        parallel: int = 1,
        names: tuple[str, str] = ("mesh resolution", "texture size"),
    ) -> None:
        """Refuse a mesh resolution or texture size out of range (:data:`config.LIMITS`) or beyond memory.

        One export holds about :data:`sampling.EXPORT_BYTES_PER_VOXEL` per voxel of the decode grid over ``aabb``
        (default: the model's box) and :data:`~sampling.EXPORT_BYTES_PER_TEXEL` per texel; ``parallel`` exports at once
        (``--workers``) may use half the free RAM between them, as :meth:`max_samples` does. ``names``: what the
        message calls the two (CLI flags). The message gives the largest value that fits.
        """
        box = self.aabb if aabb is None else aabb
        sampling.check_mesh_sizes(resolution, texture_size, box, parallel, names)

    def with_denoiser(self, denoiser: torch.nn.Module, diffusion: DiffusionConfig) -> Sin3DM:
        """The same input (decoder, latent, box) with another denoiser, e.g. one retrained for an ablation.

        ``diffusion`` is the config that denoiser was trained with (its
        ``prediction`` and schedule decide how it is sampled). Decoder and
        latent are shared with this model, not copied.
        """
        shared = (self.decoder, self.latent, denoiser, self.aabb, self.normalization, dict(self.report), self.device)
        return Sin3DM(replace(self.config, diffusion=diffusion), *shared)

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
        return sampling.decode(self, samples, index, resolution, faces, texture_size, vertex_colors, original_coords)

    # ------------------------------------------------------- against the input
    def same_voxels(self, samples: Samples, resolution: int) -> int:
        """Voxels along the longest side of ``samples``' box that give the voxel size the input's box has at ``resolution``.

        A retargeted or outpainted sample is larger than the input; voxelised
        with this, it can be compared with the input voxel for voxel (and its
        pictures keep their relative sizes).
        """
        return evaluation.same_voxels(samples.aabb, self.aabb, resolution)

    def plot_beside_input(self, samples: Samples, resolution: int = 64, labels=None):
        """Front and top views (:func:`viz.plot_projections`) of the samples beside the input's reconstruction.

        All at the voxel size the input's box has at ``resolution`` (larger
        samples look larger). The reconstruction's grid is computed once per
        resolution and kept. Each shape is decoded at twice the picture's
        voxels (not the export's mesh resolution): a picture needs no more.
        """
        from .show.sample_figures import plot_beside_input

        return plot_beside_input(self, samples, resolution, labels)

    def occupancy(self, samples: Samples, resolution=128, mesh_resolution: int | None = None, supersample: int = 1):
        """Each sample's mesh as an occupancy grid over its box, ``resolution`` voxels along the longest side.

        What the paper's geometry metrics take (:mod:`sin3dm_lite.metrics`): the
        sample is decoded to a mesh as for export (no texture) and voxelised.
        With a list of resolutions, returns ``{resolution: [grids]}`` and decodes each sample once.
        A sample with no surface (a diverged one: all empty, or the box all inside) counts as an
        empty or a full grid, so it lowers the scores instead of stopping the evaluation.
        ``supersample=2`` voxelises as the paper does (a voxel is solid when any of its 2³ sub-voxels is inside,
        :func:`metrics.voxelize`); the default 1 samples the voxel centres.
        """

        def to_mesh(i: int) -> TexturedMesh:
            return self.to_mesh(samples, i, resolution=mesh_resolution, original_coords=False, vertex_colors=True)

        return evaluation.occupancy(to_mesh, len(samples), samples.aabb, resolution, supersample)

    def input_occupancy(self, mesh: TexturedMesh, resolution: int = 128, aabb=None, supersample: int = 1) -> np.ndarray:
        """The input mesh (in its file's coordinates) as an occupancy grid over this model's box (or ``aabb``,
        normalised coordinates): the metrics' reference (``supersample``: as for :meth:`occupancy`)."""
        box = self.aabb if aabb is None else aabb
        return evaluation.input_occupancy(mesh, self.normalization, box, resolution, supersample)

    @property
    def grid_resolution(self) -> int:
        """Voxels along the longest side of the grid this model was fitted on (where its calibration judges)."""
        return max(self.report.get("grid_shape") or [self.config.grid.resolution])

    def input_mesh(self, allow_outside_paths: bool = False) -> TexturedMesh:
        """The mesh this model was fitted to: the mesh file the run's report names, if it is still there, or the
        built-in example of that name (``allow_outside_paths``: see :func:`mesh_io.load_mesh`)."""
        return recorded_input(self.report.get("input_path"), self.report.get("input"), allow_outside_paths)

    def evaluate(
        self,
        samples,
        input_mesh=None,
        resolution: int | Sequence[int] = 64,
        views: int = 8,
        size: int = 256,
        weights=None,
        progress: bool = True,
        supersample: int = evaluation.PAPER_SUPERSAMPLE,
    ) -> dict:
        """The paper's metrics of generated shapes against the input mesh (docs/paper-notes.md "Evaluation").

        ``samples``: a :class:`Samples` (decoded here) or meshes in the input
        file's coordinates (what ``sample`` exports). ``input_mesh``: a mesh,
        path or example name (default: :meth:`input_mesh`). ``weights``: a
        folder with the pre-trained weights of SIFID and LPIPS
        (:func:`metrics.load_feature_weights`), or a loaded ``FeatureNets``.

        Geometry (:func:`metrics.geometry_scores`): G-Div, LP-IoU, LP-F, the labelled variant that is not the
        paper's (``lp_iou_any_offset``, ``lp_fscore_any_offset``: the input's patches at every voxel, so a
        piece moved by a voxel still counts) and the IoU to the input on occupancy grids of ``resolution`` voxels along the
        longest side of the model's box (a box covering larger, retargeted
        samples keeps that voxel size), input and samples voxelised as the paper's evaluation code does
        (``supersample=2``: a voxel is solid when any of its 2³ sub-voxels is inside; 1 samples the voxel
        centres alone, stricter on walls a voxel or two thick); with several resolutions, e.g. ``(128, 64)``
        (the paper's grid and the training grid), the first gets every metric and the
        others the geometry's, in ``geometry_at["64"]``. Texture (:func:`metrics.texture_scores`)
        on ``views`` renders of ``size`` pixels at elevation 45°, input and
        samples framed by the same box: ``patch_swd`` and ``render_div`` always,
        ``sifid`` and ``lpips`` with ``weights``. Without an off-screen renderer
        the texture metrics are None and ``skipped["texture"]`` says why.
        G-Qual (SSFID) is never computed (``skipped["ssfid"]``).

        Returns ``{"samples", "resolution", "views", "size", "metrics": {name: value or None},
        "skipped": {name: reason}, "timings_s": {...}}``, with several resolutions also
        ``"geometry_at": {"64": {"voxels", "metrics"}}`` (the time it takes: :func:`evaluation.evaluate`).
        """
        nets = evaluation.feature_nets(weights)
        ref = self.input_mesh() if input_mesh is None else resolve_mesh(input_mesh)
        to_meshes = self.to_mesh if isinstance(samples, Samples) else list
        return evaluation.evaluate(
            samples, to_meshes, ref, self.normalization, self.aabb, resolution, views, size, nets, progress, supersample
        )

    # ------------------------------------------------------------ save/load
    def save(self, run_dir: str | Path) -> Path:
        """Write ``model.pt`` (everything sampling needs) and ``config.json`` into ``run_dir``."""
        return write_model(self, Path(run_dir))

    @classmethod
    def open(cls, run, preset=None, cache="runs/cache", device=None, progress: bool = True) -> Sin3DM:
        """The model ``run`` names: a shipped model, a run folder, or a mesh / example fitted once into ``cache``
        and reused after (the rules: :mod:`sin3dm_lite.app.runs`).

        ``preset`` (default: :func:`presets.notebook_preset`, ``tiny`` under ``SIN3DM_FAST=1``, else ``small``) is
        used only when ``run`` has to be fitted. The model's ``run_dir`` attribute is the folder it was loaded from.
        """
        from .app.runs import fit_preset, resolve_run

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
        path = Path(run_dir)
        path = check_regular(path / MODEL_FILE if path.is_dir() else path, "a model")  # a FIFO would block
        if not path.is_file():
            raise Sin3DMInputError(
                f"no fitted model at '{run_dir}' (expected {MODEL_FILE}); fit one with `sin3dm-lite fit MESH --out DIR`"
            )
        return cls(*read_model(path), device)


def open_run(run, preset=None, cache="runs/cache", device=None, progress: bool = True) -> Sin3DM:
    """:meth:`Sin3DM.open` as a function: the model a shipped name, a run folder, a mesh or an example names."""
    return Sin3DM.open(run, preset, cache, device, progress)

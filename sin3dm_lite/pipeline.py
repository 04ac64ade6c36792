"""``Sin3DM``: the whole method behind one object.

    model = Sin3DM.fit("canyon", preset="small", out="runs/canyon")   # mesh → grid → triplane → diffusion
    samples = model.sample(4, seed=0)                                  # new triplanes from noise
    meshes = model.to_mesh(samples)                                    # decoded, textured meshes

Each method is a call into the module that does the work: ``fit`` app.fitting, ``sample``, ``plan`` and
``to_mesh`` app.sampling, ``save`` and ``load`` app.checkpoints, ``open`` app.runs, ``calibrate`` auto.calibration,
``occupancy``, ``evaluate`` and the like evaluate.evaluation, ``plot_beside_input`` show.sample_figures.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from .app import sampling
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
        calibrate: bool | None = None,
        budget=None,
        up: str | None = None,
        turn: float | None = None,
    ) -> Sin3DM:
        """Fit Sin3DM to one textured mesh (a path, a ``TexturedMesh`` or an example name): mesh → TSDF + colour
        grid → triplane autoencoder (the input's latent) → diffusion model on that latent (the paper's Sec. 4).

        ``preset``: a name or a :class:`Config` (default: :mod:`sin3dm_lite.auto.fit_default`'s for this machine and
        shape). ``pbr``: learn metallic, roughness and normals too (default: when the mesh has such maps).
        ``allow_outside_paths``: let the mesh name textures outside its folder. With ``out`` a run folder is written
        and checkpointed; ``resume=True`` continues it and ends where an uninterrupted fit would. ``calibrate``:
        choose the run's diversity at the end (not in the paper; default: for the CPU presets), and where even pure
        noise gives copies try a denoiser with one ResBlock fewer (``app.fitting.FitRun.narrower``). ``budget``: an
        :class:`~sin3dm_lite.auto.fit_default.Budget` (the CLI's ``--minutes``) the denoiser's steps keep to.
        ``up``, ``turn``: the mesh's up axis (``"z"`` for a Z-up model) and degrees about it (default:
        :func:`~sin3dm_lite.auto.fit_policy.choose_turn`'s), turned before the grid (``grid.up``, ``grid.turn``)."""
        from .app.fitting import fit

        args = (source, preset, out, resume, seed, device, progress, pbr, allow_outside_paths, calibrate, budget)
        model = fit(cls, *args, up=up, turn=turn)
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
        """Set ``config.sampling.diversity`` to the most varied setting whose samples keep the input's patches (not in
        the paper; :func:`sin3dm_lite.auto.calibration.calibrate_model`). :meth:`save` keeps the choice."""
        from .auto.calibration import calibrate_model

        return calibrate_model(self, reference, input_mesh, progress, resolution, supersample, **options)

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
        """Draw ``n`` new triplanes from noise, optionally controlled (the paper's Sec. 4.4, :mod:`.control`).

        ``resize`` (retargeting: noise of another size), ``outpaint=(sx, sy, sz)`` with ``anchor`` (grow the box,
        keep the input), ``regenerate=(lo, hi)`` (resample a box, keep the rest), ``duplicate=((lo, hi), to)``
        (copy a box, generate around both): boxes are fractions of the model's box, one control at a time;
        ``plan`` a :class:`control.Plan` made by hand; ``known``/``mask`` fix part of the latent directly.
        ``diversity`` (default: the config's; 1 for outpainting, editing and duplication) trades variation for
        fidelity, the limitation the paper names: 1 samples from pure noise, below 1 from the input's latent
        with that share of noise, 0 gives it back.
        Sample ``i`` comes from the seed ``seed + i`` alone (or ``seed[i]``), whatever the batch or the device.
        """
        plan = self.plan(resize, outpaint, anchor, regenerate, duplicate, plan)
        return sampling.draw(self, n, plan, steps, method, seed, return_intermediates, known, mask, progress, diversity)

    def plan(
        self, resize=(1.0, 1.0, 1.0), outpaint=None, anchor: str = "center", regenerate=None, duplicate=None, plan=None
    ):
        """The :class:`control.Plan` that :meth:`sample` carries out for these arguments (checked: one clear error)."""
        return sampling.plan_for(self, resize, outpaint, anchor, regenerate, duplicate, plan)

    def max_samples(self, resize=(1.0, 1.0, 1.0)) -> int:
        """How many samples one :meth:`sample` call can hold in half the device's free memory (at most 10,000)."""
        return sampling.max_samples(self, resize)

    def with_denoiser(self, denoiser: torch.nn.Module, diffusion: DiffusionConfig) -> Sin3DM:
        """The same input (decoder, latent, box, shared) with another denoiser, e.g. one retrained for an ablation,
        and ``diffusion``, the config it was trained with (its ``prediction`` and schedule decide its sampling)."""
        shared = (self.decoder, self.latent, denoiser, self.aabb, self.normalization, dict(self.report), self.device)
        return Sin3DM(replace(self.config, diffusion=diffusion), *shared)

    def input_sample(self) -> Samples:
        """The input's own latent as a one-item :class:`Samples` (decode it to see the reconstruction)."""
        return Samples(self.latent.clone(), self.aabb.copy())

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
        """Decode samples into textured meshes (all of them, or the one at ``index``), ``original_coords`` in the input
        file's coordinates (turned upright where the fit turned its input: ``grid.up``), else normalised."""
        return sampling.decode(self, samples, index, resolution, faces, texture_size, vertex_colors, original_coords)

    def same_voxels(self, samples: Samples, resolution: int) -> int:
        """Voxels along the longest side of ``samples``' box with the voxel size the input's box has at
        ``resolution``: a retargeted or outpainted sample compared with the input voxel for voxel."""
        return evaluation.same_voxels(samples.aabb, self.aabb, resolution)

    def plot_beside_input(self, samples: Samples, resolution: int = 64, labels=None):
        """Front and top views (:func:`viz.plot_projections`) of the samples beside the input's reconstruction,
        all at the voxel size the input's box has at ``resolution`` (larger samples look larger)."""
        from .show.sample_figures import plot_beside_input

        return plot_beside_input(self, samples, resolution, labels)

    def occupancy(self, samples: Samples, resolution=128, mesh_resolution: int | None = None, supersample: int = 1):
        """Each sample's mesh as an occupancy grid over its box, ``resolution`` voxels along the longest side (a
        list: ``{resolution: [grids]}``), what the paper's geometry metrics take; ``supersample=2`` voxelises as the
        paper does (:func:`evaluation.occupancy`)."""

        def to_mesh(i: int) -> TexturedMesh:
            return self.to_mesh(samples, i, resolution=mesh_resolution, original_coords=False, vertex_colors=True)

        return evaluation.occupancy(to_mesh, len(samples), samples.aabb, resolution, supersample)

    def input_occupancy(self, mesh: TexturedMesh, resolution: int = 128, aabb=None, supersample: int = 1) -> np.ndarray:
        """The input mesh (in its file's coordinates, turned upright here as the fit turned it: ``grid.up``) as an
        occupancy grid over this model's box (or ``aabb``, normalised coordinates): the metrics' reference
        (``supersample``: as for :meth:`occupancy`)."""
        box = self.aabb if aabb is None else aabb
        upright = mesh.turned_upright(self.config.grid.up)
        return evaluation.input_occupancy(upright, self.normalization, box, resolution, supersample)

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
        """The paper's metrics of generated shapes (a :class:`Samples`, or meshes as this model writes them: in the
        input file's coordinates, turned upright by ``grid.up``) against the input mesh (default: :meth:`input_mesh`;
        in its file's coordinates, turned here): G-Div, LP-IoU, LP-F and the IoU on ``resolution``
        voxels (several give ``geometry_at``), and on ``views`` renders of ``size`` pixels patch SWD, render
        diversity, SIFID and LPIPS (those two with ``weights``); :func:`evaluation.evaluate` says what each returns."""
        nets = evaluation.feature_nets(weights)
        ref = (self.input_mesh() if input_mesh is None else resolve_mesh(input_mesh)).turned_upright(
            self.config.grid.up
        )
        to_meshes = self.to_mesh if isinstance(samples, Samples) else list
        return evaluation.evaluate(
            samples, to_meshes, ref, self.normalization, self.aabb, resolution, views, size, nets, progress, supersample
        )

    def save(self, run_dir: str | Path) -> Path:
        """Write ``model.pt`` (everything sampling needs) and ``config.json`` into ``run_dir``."""
        return write_model(self, Path(run_dir))

    @classmethod
    def open(cls, run, preset=None, cache="runs/cache", device=None, progress: bool = True) -> Sin3DM:
        """The model ``run`` names: a shipped model, a run folder, or a mesh / example fitted once into ``cache``
        with ``preset`` and reused after; its ``run_dir`` is the folder it came from."""
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

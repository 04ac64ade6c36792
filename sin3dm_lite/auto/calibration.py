"""Calibrating a fitted model's diversity knob: :func:`~sin3dm_lite.evaluate.calibrate.calibrate_diversity`'s
choice on the input's occupancy, kept in the model's config and report. Not in the paper, which samples from pure
noise (the knob's value 1).
"""

from __future__ import annotations

import numpy as np

from ..data.grid import is_flat
from ..data.source import resolve_mesh
from ..errors import Sin3DMInputError
from ..evaluate import calibrate as walk  # looked up at each call: a test or notebook may swap its parts
from ..evaluate import evaluation
from ..evaluate.calibration_record import Calibration

#: the presets whose fits choose their diversity by default: the CPU ones, whose short training leaves a knob curve
#: that differs from shape to shape (``paper`` samples from pure noise, as the paper does)
CALIBRATED = ("small", "quick", "detail", "fine")
#: where a fit's calibration judges the finer presets' samples: the paper's evaluation grid and voxels
PAPER_RESOLUTION = 128
#: the goals' caps at :data:`PAPER_RESOLUTION`: none, each goal is its share of the shape's own near copy; on a
#: training grid, whose near copy keeps almost every patch, the absolute goals (``evaluate.calibrate.GOALS``) cap them
UNCAPPED = {"lp_iou": 1.0, "lp_fscore": 1.0}
#: the walk a fit's calibration takes, on any grid: rungs 0.2 apart and two draws near the answer (the walk's own
#: defaults are 0.1 and four); replayed on stored samples of real fits and the built-ins
#: (benchmarks/bench_calibration.py, docs/calibration.md) it draws far fewer samples for choices as close
COARSE_WALK = {"step": 0.2, "refine": 2}


def default_goals(resolution: int | None) -> dict:
    """The goals a calibration judged at ``resolution`` voxels takes when none are asked for."""
    return dict(UNCAPPED if resolution == PAPER_RESOLUTION else walk.GOALS)


def calibrates(cfg, mesh=None) -> bool:
    """Whether a fit of ``cfg`` (of ``mesh``, where known) calibrates its diversity when not told
    (``Sin3DM.fit(calibrate=None)``). Not a flat mesh's (:func:`~sin3dm_lite.data.grid.is_flat`): every sample is
    the same slab, so the patch scores it calibrates on cannot tell one setting from another."""
    flat = mesh is not None and is_flat(mesh.normalized(), cfg.grid.resolution)
    return cfg.name.split("+")[0] in CALIBRATED and not flat


def judged_at(cfg) -> int | None:
    """The resolution a fit of ``cfg`` calibrates at: :data:`PAPER_RESOLUTION` for a training grid finer than 64
    voxels (``detail``, ``fine``: thin walls, which a 96-voxel training grid judges far more harshly), else None:
    the training grid itself, which is fast."""
    return PAPER_RESOLUTION if cfg.grid.resolution > 64 else None


def calibrate_model(
    model,
    reference: np.ndarray | None = None,
    input_mesh=None,
    progress: bool = True,
    resolution: int | None = None,
    supersample: int | None = None,
    **options,
) -> Calibration:
    """Set ``model.config.sampling.diversity`` to the most varied setting whose samples keep the input's patches.

    :func:`~sin3dm_lite.evaluate.calibrate.calibrate_diversity` draws a few samples at a handful of settings and
    scores them with the paper's LP-IoU / LP-F against ``reference``, the input's occupancy on the model's box
    (default: ``input_mesh``, a mesh, path or example name, or else the model's input, voxelised at ``resolution``
    voxels along the longest side, by default the fit's grid). ``supersample``: the voxels judged, 1 the voxel
    centres (the default on the fit's grid), 2 the paper's (the default at another ``resolution``). The choice and
    what was tried land in ``report["calibration"]``; ``options`` go to ``calibrate_diversity`` (``goals`` by
    default :func:`default_goals` for the grid judged on; the walk of :data:`COARSE_WALK`).
    """
    if reference is None:
        mesh = model.input_mesh() if input_mesh is None else resolve_mesh(input_mesh)
        on_grid = resolution in (None, model.grid_resolution)
        resolution = resolution or model.grid_resolution
        if not 16 <= resolution <= 512:
            raise Sin3DMInputError(f"the calibration's resolution must be from 16 to 512 voxels, got {resolution}")
        if supersample is None:
            supersample = 1 if on_grid else evaluation.PAPER_SUPERSAMPLE
        evaluation.check_fine_grid(resolution, supersample)
        reference = model.input_occupancy(mesh, resolution, supersample=supersample)
    elif resolution is not None and resolution != max(np.shape(reference)):
        raise Sin3DMInputError(
            f"resolution {resolution} does not match the reference grid {np.shape(reference)}; give one of them"
        )
    supersample = 1 if supersample is None else supersample
    options.setdefault("goals", default_goals(max(np.shape(reference))))
    options = {**COARSE_WALK, **options}
    sampler = walk.model_sampler(model, reference, supersample=supersample)
    cal = walk.calibrate_diversity(sampler, reference, progress=progress, **options)
    cal.supersample = supersample
    model.config = model.config.updated(**{"sampling.diversity": cal.diversity})
    model.report["calibration"] = cal.to_dict()
    if progress:
        print(
            f"[calibrate] {'chose' if cal.kept_goals else cal.missed + '; chose'} diversity {cal.diversity:g}",
            flush=True,
        )
        print("\n".join(f"[calibrate] {line}" for line in cal.story().splitlines()), flush=True)
    return cal


__all__ = [
    "CALIBRATED",
    "COARSE_WALK",
    "PAPER_RESOLUTION",
    "UNCAPPED",
    "calibrate_model",
    "calibrates",
    "default_goals",
    "judged_at",
]

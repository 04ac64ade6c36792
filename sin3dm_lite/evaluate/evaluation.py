"""Generated shapes against their input: occupancy grids at the input's voxel size, and the paper's metrics.

The work behind ``Sin3DM.occupancy``, ``input_occupancy``, ``same_voxels`` and ``evaluate``; each function takes
what it needs of a fitted model (its box, its normalisation, a function that decodes a sample into a mesh).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from ..app import values
from ..data.box import grid_shape
from ..errors import Sin3DMInputError
from .features import SSFID_UNAVAILABLE, FeatureNets, load_feature_weights
from .geometry import PAPER_SUPERSAMPLE, check_supersample, geometry_scores, voxelize
from .geometry import input_occupancy as occupancy_of_input
from .metrics import texture_scores


def same_voxels(box, own_box, resolution: int) -> int:
    """Voxels along the longest side of ``box`` that give the voxel size ``own_box`` has at ``resolution``."""
    ext = np.asarray(box[3:] - box[:3], np.float64)
    own = np.asarray(own_box[3:] - own_box[:3], np.float64)
    return int(round(resolution * ext.max() / own.max()))


def occupancy(to_mesh, count: int, box, resolution=128, supersample: int = 1):
    """Each of ``count`` samples over ``box`` as an occupancy grid, ``resolution`` voxels along the longest side;
    ``to_mesh(i)`` decodes sample ``i`` (normalised coordinates). With a list of resolutions, returns
    ``{resolution: [grids]}`` and decodes each sample once. A sample with no surface (``NoSurfaceError`` with a
    ``fill``) counts as an empty or a full grid. ``supersample``: as for :func:`geometry.voxelize`."""
    from ..generate.extract import NoSurfaceError

    several = not isinstance(resolution, (int, np.integer))
    res = check_resolutions(resolution)
    check_fine_grid(res, supersample)
    grids: dict[int, list[np.ndarray]] = {r: [] for r in res}
    for i in range(count):
        try:
            mesh = to_mesh(i)
        except NoSurfaceError as e:
            if e.fill is None:
                raise
            for r in res:
                grids[r].append(np.full(grid_shape(box, r), bool(e.fill)))
            continue
        for r in res:
            grids[r].append(voxelize(mesh, box, r, supersample))
    return grids if several else grids[res[0]]


def input_occupancy(mesh, normalization, box, resolution: int = 128, supersample: int = 1) -> np.ndarray:
    """The input ``mesh`` (in its file's coordinates, normalised with ``normalization``) as an occupancy grid over
    ``box``: the metrics' reference (``supersample``: as for :func:`occupancy`)."""
    m = replace(mesh, vertices=normalization.to_normalized(np.asarray(mesh.vertices)))
    return occupancy_of_input(m, box, resolution, supersample)


#: how ``evaluate`` and ``calibrate`` name their voxels in what they print
VOXELS_SAID = {1: "the voxel centres", PAPER_SUPERSAMPLE: "the paper's voxels: any of 2³ points inside"}


def voxels_said(supersample: int) -> str:
    """What a grid of ``supersample``³ points a voxel is called in what ``evaluate`` and ``calibrate`` print."""
    return VOXELS_SAID.get(supersample, f"{supersample}³ points a voxel")


#: the finest grid the geometry metrics sample a mesh on, voxels a side (resolution × supersample)
MAX_FINE_VOXELS = 512
#: the most views of a mesh one render or evaluation takes (one a degree)
MAX_VIEWS = 360


def check_views(views, size, names: tuple[str, str] = ("views", "size")) -> None:
    """Check views around a mesh (1 to :data:`MAX_VIEWS`) and their size in pixels (16 to 4096); ``names``: what
    the message calls them."""
    values.whole(views, names[0], 1, MAX_VIEWS)
    values.whole(size, names[1], 16, 4096)


def check_resolutions(resolution, name: str = "resolution") -> list[int]:
    """One grid's voxels or several, each 16 to 512, as a list."""
    many = resolution if isinstance(resolution, (list, tuple, np.ndarray)) else [resolution]
    if len(many) == 0:
        raise Sin3DMInputError(f"{name} must be one grid's voxels or several, got none")
    return [values.whole(r, name, 16, 512) for r in many]


def check_fine_grid(resolution, supersample: int) -> None:
    """Refuse grids whose sub-voxels (``resolution × supersample`` a side) would not fit in memory."""
    supersample = check_supersample(supersample)
    for r in np.atleast_1d(resolution):
        if int(r) * supersample > MAX_FINE_VOXELS:
            raise Sin3DMInputError(
                f"{int(r)} voxels with {supersample}³ points a voxel samples {int(r) * supersample} a side, more than "
                f"{MAX_FINE_VOXELS}; use a resolution of at most {MAX_FINE_VOXELS // supersample} (the paper's is "
                "128), or the voxel centres alone (CLI --voxels centres, Python supersample=1)"
            )


def feature_nets(weights) -> FeatureNets | None:
    """SIFID's and LPIPS's networks: ``weights`` loaded (a folder, :func:`load_feature_weights`), or as given."""
    return weights if isinstance(weights, FeatureNets) or weights is None else load_feature_weights(weights)


def evaluate(
    samples,
    to_meshes,
    reference,
    normalization,
    aabb,
    resolution: int | Sequence[int] = 64,
    views: int = 8,
    size: int = 256,
    nets: FeatureNets | None = None,
    progress: bool = True,
    supersample: int = PAPER_SUPERSAMPLE,
) -> dict:
    """``Sin3DM.evaluate``: the paper's metrics of the sample meshes ``to_meshes(samples)`` (in the input file's
    coordinates) against the input mesh ``reference``.

    Geometry (:func:`geometry.geometry_scores`) on a grid over ``aabb``, the model's box grown to hold larger
    (retargeted) samples at the same voxel size, input and samples voxelised alike (``supersample``³ points a
    voxel). Texture (:func:`metrics.texture_scores`) on ``views`` renders of ``size`` pixels framed by the same
    box; without an off-screen renderer its metrics are None and ``skipped["texture"]`` says why. Returns
    ``{"samples", "resolution", "supersample", "views", "size", "metrics", "skipped", "timings_s"}``; with several
    resolutions the first gets every metric, each other one the geometry's (``geometry_at[str(resolution)]``).
    """
    say = print if progress else (lambda *a, **k: None)
    check_views(views, size)
    check_resolutions(resolution)
    check_fine_grid(resolution, supersample)  # before any decoding
    t0 = time.perf_counter()
    meshes = to_meshes(samples)
    if not meshes:
        raise Sin3DMInputError("evaluate needs at least one sample mesh")
    to_norm = normalization.to_normalized
    normed = [replace(m, vertices=to_norm(np.asarray(m.vertices, np.float64))) for m in meshes]
    lo = np.minimum(aabb[:3], np.min([m.vertices.min(0) for m in normed], axis=0))
    hi = np.maximum(aabb[3:], np.max([m.vertices.max(0) for m in normed], axis=0))
    box = np.concatenate([lo, hi])
    first, *others = dict.fromkeys(int(r) for r in np.atleast_1d(resolution))  # each grid once, in order
    scale = (hi - lo).max() / (aabb[3:] - aabb[:3]).max()

    def geometry(resolution: int) -> tuple[int, dict]:  # at the model's voxel size for ``resolution``
        res = int(round(resolution * scale))
        check_fine_grid(res, supersample)  # larger (retargeted) samples grow the grid
        ref_grid = input_occupancy(reference, normalization, box, res, supersample)
        return res, geometry_scores(ref_grid, [voxelize(m, box, res, supersample) for m in normed])

    res, metrics = geometry(first)
    geometry_at = {}
    for r in others:
        voxels, scores = geometry(r)
        geometry_at[str(r)] = {"voxels": voxels, "metrics": scores}
    timings = {"geometry_s": time.perf_counter() - t0}
    grids = ", ".join(map(str, [res, *(g["voxels"] for g in geometry_at.values())]))
    how = voxels_said(supersample)
    say(f"[evaluate] geometry of {len(meshes)} samples at {grids} voxels, {how}: {timings['geometry_s']:.1f} s")
    metrics["ssfid"] = None
    frame = normalization.box_to_original(np.stack([lo, hi]))
    texture = _texture_metrics(meshes, reference, frame, views, size, nets, metrics, timings, say)
    skipped = {"ssfid": SSFID_UNAVAILABLE, **texture}
    if len(meshes) < 2:
        skipped["diversity"] = "G-Div and the texture diversities need at least two samples"
    return {
        "samples": len(meshes),
        "resolution": res,
        "supersample": supersample,
        "views": views,
        "size": size,
        "metrics": metrics,
        **({"geometry_at": geometry_at} if geometry_at else {}),
        "skipped": skipped,
        "timings_s": timings,
    }


def _texture_metrics(meshes, reference, frame, views, size, nets, metrics, timings, say) -> dict:
    """Render ``reference`` and ``meshes`` framed by ``frame`` and add the texture metrics to ``metrics`` (None
    without a renderer); returns what was skipped and why."""
    from . import render

    problem = render.renderer_problem()
    if problem is not None:
        metrics.update(dict.fromkeys(["patch_swd", "render_div", "sifid", "lpips"]))
        return {"texture": f"texture metrics skipped: {problem}"}
    t0 = time.perf_counter()
    ref_views = render.render_views(reference, views, size, box=frame)
    sample_views = [render.render_views(m, views, size, box=frame) for m in meshes]
    timings["render_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    metrics.update({"sifid": None, "lpips": None, **texture_scores(ref_views, sample_views, nets)})
    timings["texture_s"] = time.perf_counter() - t0
    say(
        f"[evaluate] {views} views of {len(meshes) + 1} meshes at {size}²: rendered in {timings['render_s']:.1f} s, "
        f"texture metrics {timings['texture_s']:.1f} s"
    )
    return (
        {}
        if nets is not None
        else dict.fromkeys(["sifid", "lpips"], "no pre-trained weights given (CLI: --weights DIR)")
    )

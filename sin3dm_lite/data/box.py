"""Box and grid geometry, shared by every stage: sizes, cell centres and coordinates.

Three frames appear in the package: *original* coordinates (the input mesh as
loaded); *normalised* coordinates (``mesh.Normalization``: centred, the longest
side spanning about [-1, 1]); *box* coordinates, an axis-aligned box
``aabb = (xmin, ymin, zmin, xmax, ymax, zmax)`` in normalised coordinates mapped
to [-1, 1]^3 (what triplane lookups take).

A grid over a box is **cell-centred**: voxel ``k`` of an axis with ``n``
voxels sits at box coordinate ``-1 + (2k + 1) / n``. The voxel counts come
from a resolution by one rule (:func:`grid_shape`).
"""

from __future__ import annotations

import numpy as np

from ..errors import Sin3DMInputError

#: a sheet becomes a slab of this half thickness, in normalised units (the longest side spans 2): a voxel of a
#: 64-voxel grid either side, 1/32 of the shape's longest side in all
SHEET_HALF = 1 / 32


def as_aabb(aabb) -> np.ndarray:
    """``(6,)`` float64 box from an array-like or from anything with an ``.aabb`` (a ``ShapeGrid``)."""
    box = np.asarray(getattr(aabb, "aabb", aabb), dtype=np.float64).reshape(-1)
    if box.shape != (6,) or not np.all(box[3:] > box[:3]):
        raise Sin3DMInputError(f"aabb must be (xmin, ymin, zmin, xmax, ymax, zmax) with max > min, got {box}")
    return box


def _round_up(n: float, multiple: int) -> int:
    return int(np.ceil(n / multiple) * multiple)


def grid_shape(extent, resolution: int, multiple: int = 1, margin_voxels: float = 0.0) -> tuple[int, int, int]:
    """Voxels per axis for a box of side lengths ``extent`` (or an ``aabb`` of 6 numbers).

    The longest axis gets ``resolution`` voxels, every other axis its share
    ``int(resolution · extent / longest extent)``, rounded down as the original
    code does (a share within 1e-3 of a whole number counts as that number).
    Then, for the training grid:

    * ``margin_voxels`` > 0: the shorter axes are measured against the box's
      2 units instead (the shape was shrunk to leave the margin, see
      :func:`margin_scale`) and get ``2 · margin_voxels`` more voxels,
      rounded **up**: a margin is a minimum;
    * ``multiple``: every count rounded up to a multiple of it (8 for the
      training grid, so the latent halves it and the U-Net's levels divide),
      the longest axis included.

    Every axis has at least ``max(2, multiple)`` voxels.
    """
    e = np.asarray(extent, dtype=np.float64).reshape(-1)
    if e.shape == (6,):
        e = as_aabb(e)
        e = e[3:] - e[:3]
    if e.shape != (3,) or not np.all(e >= 0) or not e.max() > 0:
        raise Sin3DMInputError(f"a box needs three side lengths >= 0, the longest > 0, got {e}")
    n_long = _round_up(resolution, multiple)
    long = int(np.argmax(e))
    dims = []
    for a, side in enumerate(e):
        if a == long:
            dims.append(n_long)
            continue
        if margin_voxels > 0:
            n = int(np.ceil(n_long * side / 2 + 2 * margin_voxels))
        else:
            n = int(np.floor(resolution * side / e.max() + 1e-3))  # a float32 box (±n/n_max) is off by ~1e-5 voxel
        dims.append(max(2, multiple, _round_up(n, multiple)))
    return tuple(dims)  # type: ignore[return-value]


def margin_scale(extent, n_long: int, margin_voxels: float) -> float:
    """Factor (≤ 1) that shrinks a normalised shape so its longest side leaves ``margin_voxels`` to both box faces.

    ``extent`` is in normalised units (the longest axis spans [-1, 1] over ``n_long`` voxels).
    """
    vs = 2.0 / n_long
    half = float(np.max(extent)) / 2
    return min(1.0, (1.0 - margin_voxels * vs) / half)


def centred_box(shape) -> np.ndarray:
    """The box of a grid whose voxels are cubes and whose longest side spans [-1, 1]: ``±shape / max(shape)``."""
    half = np.asarray(shape, np.float64) / max(shape)
    return np.concatenate([-half, half]).astype(np.float32)


def cell_centres(shape) -> list[np.ndarray]:
    """Cell-centred **box** coordinates per axis (float32): voxel ``k`` of ``n`` sits at ``-1 + (2k + 1) / n``."""
    return [(-1 + (2 * np.arange(n) + 1) / n).astype(np.float32) for n in shape]


def axis_centres(aabb, shape, axis: int) -> np.ndarray:
    """Cell-centred **normalised** coordinates along one axis (float64): ``lo + (k + 0.5) / n · (hi - lo)``."""
    box = as_aabb(aabb)
    n = shape[axis]
    return box[axis] + (np.arange(n) + 0.5) / n * (box[axis + 3] - box[axis])


def to_box(points, aabb, dtype=np.float64) -> np.ndarray:
    """Normalised coordinates → box coordinates in [-1, 1], computed in ``dtype``."""
    box = np.asarray(getattr(aabb, "aabb", aabb)).reshape(-1)
    as_aabb(box)  # checks it
    lo, hi = box[:3].astype(dtype), box[3:].astype(dtype)
    return (2 * (np.asarray(points).astype(dtype) - lo) / (hi - lo) - 1).astype(dtype)


def to_index(points, aabb, shape) -> np.ndarray:
    """Normalised coordinates → continuous voxel index (voxel centre ``k`` at ``k``)."""
    box = as_aabb(aabb)
    return (np.asarray(points, np.float64) - box[:3]) / (box[3:] - box[:3]) * np.asarray(shape) - 0.5


def flat_axes(extent, resolution: int) -> np.ndarray:
    """``(3,)`` bool: the axes along which a normalised shape of sides ``extent`` is thinner than a voxel of
    ``resolution``."""
    return np.asarray(extent) < 2.0 / resolution


def training_dims(extent, resolution: int, margin_voxels: float) -> tuple[float, np.ndarray]:
    """``(shrink, voxels per axis)`` of the training grid of a normalised shape of sides ``extent``: the factor that
    leaves ``margin_voxels`` of empty space around it, and the counts (multiples of 8) of its grid; a flat shape's
    box is as thick as its slab (:data:`SHEET_HALF` to each side). The fit's estimate times a grid of these too."""
    extent = np.asarray(extent, np.float64)
    if flat_axes(extent, resolution).any():
        extent = np.maximum(extent, 2 * SHEET_HALF)
    dims = np.array(grid_shape(extent, resolution, multiple=8))
    if margin_voxels <= 0:
        return 1.0, dims
    shrink = margin_scale(extent, int(dims.max()), margin_voxels)
    return shrink, np.array(grid_shape(extent * shrink, resolution, multiple=8, margin_voxels=margin_voxels))


__all__ = [
    "SHEET_HALF",
    "as_aabb",
    "axis_centres",
    "cell_centres",
    "centred_box",
    "flat_axes",
    "grid_shape",
    "margin_scale",
    "to_box",
    "to_index",
    "training_dims",
]

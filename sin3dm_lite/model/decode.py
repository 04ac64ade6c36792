"""Decoding a triplane: the decoder's per-plane features once, point queries, SDF grids.

The autoencoder's decoder (``autoencoder.TriplaneDecoder``) answers "what is
the signed distance and colour at this point?". Everything that asks it many
such questions lives here: :func:`prepare` runs the per-plane 2D conv blocks
once per triplane (the original implementation ran them once per chunk of
points), :func:`query_points` decodes points in bounded-memory chunks,
:func:`decode_grid` a cell-centred SDF (and colour) grid over a box.

The decoder protocol::

    features = decoder.prepare(triplane)          # per-plane 2D conv blocks, once per triplane
    sdf, color = decoder.query(features, points)  # points [B, N, 3] in box coordinates [-1, 1]^3
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from ..data.box import as_aabb, cell_centres, grid_shape
from ..data.grid import ShapeGrid
from ..errors import Sin3DMInputError
from .triplane import Triplane

if TYPE_CHECKING:
    from .autoencoder import TriplaneDecoder


def _module_device(module) -> torch.device:
    try:
        return next(module.parameters()).device
    except (StopIteration, AttributeError):
        return torch.device("cpu")


@dataclass
class PreparedTriplane:
    """What ``decoder.prepare`` returned for one triplane, and the device to query on (pass it instead of a
    :class:`Triplane` to the functions below: the per-plane conv blocks then ran once, here)."""

    features: Any
    device: torch.device


def prepare(decoder, triplane: Triplane | PreparedTriplane) -> PreparedTriplane:
    """Run the decoder's per-plane conv blocks once for a batch-1 triplane."""
    if isinstance(triplane, PreparedTriplane):
        return triplane
    if not isinstance(triplane, Triplane):
        raise TypeError(f"expected a Triplane or PreparedTriplane, got {type(triplane).__name__}")
    if triplane.batch != 1:
        raise Sin3DMInputError(
            f"mesh extraction decodes one shape at a time, but the triplane has batch {triplane.batch}; "
            "pass triplane[i] for the i-th sample"
        )
    device = _module_device(decoder)
    with torch.no_grad():
        features = decoder.prepare(triplane.to(device))
    return PreparedTriplane(features, device)


#: query batches are padded to a multiple of this many points (see :func:`query_points`)
ROW_TILE = 64

#: points per decoder batch by device type: on a CPU a batch's activations should fit the cache; a GPU wants big ones
CHUNK = {"cpu": 2**13, "cuda": 2**16}


def default_chunk(device: torch.device | str) -> int:
    """The points per decoder batch on ``device`` (:data:`CHUNK`; unknown device types get the GPU's)."""
    return CHUNK.get(torch.device(device).type, CHUNK["cuda"])


def query_points(
    decoder,
    prepared: PreparedTriplane,
    points_box: np.ndarray,
    chunk: int | None = None,
    sdf: bool = True,
    color: bool = True,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Decode ``(N, 3)`` box-coordinate points in chunks of ``chunk`` (default: :func:`default_chunk`) →
    ``sdf (N,)`` and ``color (N, K)``.

    ``sdf=False`` or ``color=False`` gives ``None`` for that output; a decoder
    that has ``query_sdf`` / ``query_color`` then skips the head not needed.

    Every batch is padded to a multiple of :data:`ROW_TILE` points (copies of
    its last point, dropped again): CPU matrix kernels round the leftover rows
    of a tiled batch differently, and with the padding a point's value does not
    depend on how many points it was decoded with, so the coarse-to-fine
    :func:`decode_grid` gives bit for bit the values of the full decode.
    """
    points_box = np.asarray(points_box, np.float32).reshape(-1, 3)
    chunk = chunk or default_chunk(prepared.device)
    only_sdf = getattr(decoder, "query_sdf", None) if not color else None
    only_color = getattr(decoder, "query_color", None) if not sdf else None
    parts: tuple[list, list] = ([], [])
    with torch.no_grad():
        for s in range(0, len(points_box), chunk):
            part = points_box[s : s + chunk]
            m = len(part)
            if m % ROW_TILE:  # repeat the last point: every real row goes through the full-tile kernel path
                part = np.concatenate([part, np.repeat(part[-1:], ROW_TILE - m % ROW_TILE, axis=0)])
            p = torch.from_numpy(part).to(prepared.device)[None]
            if only_sdf is not None:
                d, c = only_sdf(prepared.features, p), None
            elif only_color is not None:
                d, c = None, only_color(prepared.features, p)
            else:
                d, c = decoder.query(prepared.features, p)
            if sdf:
                parts[0].append(d[0, :m].float().cpu().numpy())
            if color:
                parts[1].append(c[0, :m].float().cpu().numpy())
    if len(points_box) == 0:
        return (np.zeros(0, np.float32) if sdf else None), (np.zeros((0, 3), np.float32) if color else None)
    return (np.concatenate(parts[0]) if sdf else None), (np.concatenate(parts[1]) if color else None)


# ----------------------------------------------------------------------------- the SDF grid
def decode_grid(
    decoder,
    triplane: Triplane | PreparedTriplane,
    aabb,
    resolution: int,
    chunk: int | None = None,
    with_color: bool = False,
    coarse: int | None = 4,
    exact_band: float = 2.0,
    lipschitz: float = 2.0,
    stats: dict | None = None,
):
    """Decode the SDF (and colour) on a cell-centred grid over ``aabb``.

    The grid has ``resolution`` voxels along the box's longest side (see
    :func:`grid_shape`), cell-centred. Points are decoded in chunks of
    ``chunk`` (default: :func:`default_chunk`) so memory stays bounded.

    **Coarse to fine** (default ``coarse=4``): most of the grid is far from the
    surface, where marching cubes only needs the sign. The decoder is queried
    on every ``coarse``-th voxel first, then on finer lattices, and a voxel is
    decoded only where the values around it, assuming the SDF is
    ``lipschitz``-Lipschitz, cannot prove it far from the surface; the others
    get an interpolation (:func:`_decode_coarse_to_fine`). Every voxel within
    ``exact_band`` voxels of the zero level then has bit for bit the value of
    the full decode, and marching cubes gives the same mesh. It can miss only a
    speck or hole smaller than the coarse spacing in a decoder steeper than
    ``lipschitz``; raise ``lipschitz`` or lower ``coarse`` for such a decoder.
    ``exact_band=0`` decodes fewer points and still gives the same mesh, but
    voxels a voxel or two from the surface may be interpolated. Colours
    (``with_color``) are decoded at the same voxels and interpolated at the
    others. ``coarse=None`` or ``1`` decodes every voxel.

    Args:
        coarse: step of the first lattice in voxels (4: 1/64 of the voxels).
        exact_band: half-width, in voxels (of the longest axis), of the band around the
            zero level that is always decoded.
        lipschitz: assumed bound on the SDF's slope (normalised units per normalised unit).
        stats: a dict to fill with ``voxels`` (grid size), ``decoded`` (points
            queried, lattice points outside the grid included) and per-step
            counts ``levels`` (``[(step, decoded), ...]``) and ``closure``.

    Returns:
        ``sdf (X, Y, Z)`` float32, or ``(sdf, color (X, Y, Z, K))`` when ``with_color``.
    """
    prepared = prepare(decoder, triplane)
    chunk = chunk or default_chunk(prepared.device)
    box = as_aabb(aabb)
    shape = grid_shape(box, resolution)
    if coarse is None or int(coarse) <= 1:
        sdf, color = _decode_full(decoder, prepared, shape, chunk, with_color)
        total = int(np.prod(shape))
        if stats is not None:
            stats.update(voxels=total, decoded=total, levels=[(1, total)], closure=0)
    else:
        if exact_band < 0 or lipschitz <= 0:
            raise Sin3DMInputError(f"need exact_band >= 0 and lipschitz > 0, got {exact_band} and {lipschitz}")
        sdf, color = _decode_coarse_to_fine(
            decoder, prepared, box, shape, chunk, with_color, int(coarse), float(exact_band), float(lipschitz), stats
        )
    return (sdf, color) if with_color else sdf


def _decode_full(decoder, prepared: PreparedTriplane, shape, chunk: int, with_color: bool):
    """Every voxel of the grid, chunk by chunk → ``sdf``, ``color`` (``None`` without ``with_color``)."""
    axes = cell_centres(shape)
    total = int(np.prod(shape))
    sdf = np.empty(total, np.float32)
    color = None
    for s in range(0, total, chunk):  # build each chunk's points on the fly: no full point grid in memory
        idx = np.unravel_index(np.arange(s, min(s + chunk, total)), shape)
        pts = np.stack([axes[a][idx[a]] for a in range(3)], axis=-1)
        d, c = query_points(decoder, prepared, pts, chunk=chunk, color=with_color)
        sdf[s : s + len(d)] = d
        if with_color:
            if color is None:
                color = np.empty((total, c.shape[-1]), np.float32)
            color[s : s + len(d)] = c
    return sdf.reshape(shape), (color.reshape(*shape, -1) if with_color else None)


def _lattice_steps(coarse: int) -> list[int]:
    """Lattice steps from ``coarse`` down to 1, each dividing the one before: 4 → [4, 2, 1], 6 → [6, 3, 1]."""
    steps = [coarse]
    while steps[-1] > 1:
        h = steps[-1]
        steps.append(h // next(q for q in range(2, h + 1) if h % q == 0))  # divide by the smallest prime factor
    return steps


def mc_support(sdf: np.ndarray, level: float = 0.0) -> np.ndarray:
    """Voxels whose value marching cubes can look at: corners of cubes not strictly on one side of ``level``.

    The grid is padded by one layer that is outside (above ``level``), as
    :func:`marching_cubes` does with ``close_boundary``, so an inside voxel on
    the boundary counts. A cube with a value exactly at ``level`` counts too.
    """
    pos = np.pad(sdf > level, 1, constant_values=True)
    neg = np.pad(sdf < level, 1, constant_values=False)
    n = sdf.shape
    corners = [tuple(slice(d, d + n[a] + 1) for a, d in enumerate(o)) for o in itertools.product((0, 1), repeat=3)]
    all_pos, all_neg = pos[corners[0]].copy(), neg[corners[0]].copy()
    for sl in corners[1:]:
        all_pos &= pos[sl]
        all_neg &= neg[sl]
    mixed = ~(all_pos | all_neg)  # one per cube of the padded grid
    mark = np.zeros(pos.shape, bool)
    for sl in corners:
        mark[sl] |= mixed
    return mark[1:-1, 1:-1, 1:-1]


def _decode_coarse_to_fine(
    decoder,
    prepared: PreparedTriplane,
    box: np.ndarray,
    shape,
    chunk: int,
    with_color: bool,
    coarse: int,
    exact_band: float,
    lipschitz: float,
    stats: dict | None,
):
    """:func:`decode_grid`, coarse to fine, on a grid padded to a whole number of coarse cells.

    The lattices go from ``coarse`` down to 1 (4 → 2 → 1). A voxel of a finer
    lattice lies in a cell of the previous one; if the cell's eight corners
    have one sign, the SDF, assumed ``lipschitz``-Lipschitz (1 for an exact
    SDF; a learned decoder only roughly, hence the default 2), is bounded from
    below by ``max over corners (|sdf(corner)| - lipschitz * distance)``. Where
    that bound is at least ``exact_band`` voxels the voxel gets the trilinear
    interpolation of the corners (right sign, magnitude not exact) instead of
    a decoder query; otherwise, and in every cell whose corners change sign,
    it is decoded. The bounds carry from level to level (a bounded voxel is a
    corner of the next level's cells with its bound).

    Last, a closure: every voxel that is a corner of a marching-cubes cube
    not strictly on one side of 0 (the grid padded by an outside layer, as
    :func:`marching_cubes` does) is decoded if it was not, until there is none
    left. This is a flood fill: should an interpolated voxel have the wrong
    sign (the decoder steeper than ``lipschitz``), it borders a decoded voxel
    of its true sign, gets decoded, and so on through the whole wrong region.
    """
    steps = _lattice_steps(coarse)
    first = steps[0]
    grid = _PaddedGrid(decoder, prepared, shape, first, chunk, with_color)
    spacing = (box[3:] - box[:3]) / np.array(shape, np.float64)  # normalised units per voxel
    band = np.float32(exact_band * spacing.max())
    lattice = np.meshgrid(*(np.arange(0, m, first) for m in grid.padded), indexing="ij")
    counts = [(first, grid.decode(tuple(g.ravel() for g in lattice)))]
    for big, h in zip(steps[:-1], steps[1:]):
        counts.append((h, grid.decode(_refine(grid, big, h, shape, spacing, band, lipschitz))))

    crop = tuple(slice(0, k) for k in shape)
    sdf, decoded = grid.val[crop], grid.done[crop]  # views: decode() writes through
    closure = 0
    while True:
        missing = mc_support(sdf) & ~decoded
        if not missing.any():
            break
        closure += grid.decode(np.nonzero(missing))
    if stats is not None:
        stats.update(
            voxels=int(np.prod(shape)), decoded=sum(c for _, c in counts) + closure, levels=counts, closure=closure
        )
    return np.ascontiguousarray(sdf), (np.ascontiguousarray(grid.col[crop]) if with_color else None)


class _PaddedGrid:
    """The grid being filled, padded to a whole number of coarse cells: values, lower bounds on ``|sdf|``
    (``|sdf|`` where decoded), which voxels are decoded, and colours (``with_color``; made at the first decode)."""

    def __init__(self, decoder, prepared: PreparedTriplane, shape, first: int, chunk: int, with_color: bool):
        self.decoder, self.prepared, self.chunk, self.with_color = decoder, prepared, chunk, with_color
        self.padded = tuple(-(-(k - 1) // first) * first + 1 for k in shape)
        # the same float64 → float32 formula as box.cell_centres, continued past the grid for the padding
        self.axes = [(-1 + (2 * np.arange(m) + 1) / k).astype(np.float32) for m, k in zip(self.padded, shape)]
        self.val = np.zeros(self.padded, np.float32)
        self.bound = np.zeros(self.padded, np.float32)  # lower bound on |sdf|; |sdf| where decoded
        self.done = np.zeros(self.padded, bool)
        self.col: np.ndarray | None = None

    def decode(self, idx) -> int:
        """Query the decoder at the voxels ``idx`` (a tuple of index arrays) and record them; returns how many."""
        if len(idx[0]) == 0:
            return 0
        pts = np.stack([self.axes[a][idx[a]] for a in range(3)], axis=-1)
        d, c = query_points(self.decoder, self.prepared, pts, chunk=self.chunk, color=self.with_color)
        self.val[idx] = d
        self.bound[idx] = np.abs(d)
        self.done[idx] = True
        if self.with_color:
            if self.col is None:
                self.col = np.zeros((*self.padded, c.shape[-1]), np.float32)
            self.col[idx] = c
        return len(d)


def _refine(grid: _PaddedGrid, big: int, h: int, shape, spacing, band, lipschitz: float) -> tuple:
    """One level finer, from lattice step ``big`` to ``h``: the points whose cell's corners prove them at least
    ``band`` from the surface get the corners' interpolation and bound; returns the indices of the others (to decode)."""
    with_color = grid.with_color
    r = big // h
    cells = [(m - 1) // big for m in grid.padded]
    known = (slice(None, None, big),) * 3
    c_val, c_bound = grid.val[known], grid.bound[known]
    c_pos, c_neg = c_val > 0, c_val < 0
    c_col = grid.col[known] if with_color else None
    fine = (slice(None, None, h),) * 3
    f_val, f_bound = grid.val[fine], grid.bound[fine]
    f_col = grid.col[fine] if with_color else None
    limit = [k - 1 + h for k in shape]  # lattice points from here on are corners of no cell that holds a voxel
    todo: list[list[np.ndarray]] = [[], [], []]
    for off in itertools.product(range(r), repeat=3):
        if off == (0, 0, 0):
            continue
        choices = _cell_corners(off, r, h, cells, spacing)
        same_pos, same_neg, lower, interp, icol = _from_corners(
            choices, c_pos, c_neg, c_val, c_bound, c_col, lipschitz, with_color
        )
        far = (same_pos | same_neg) & (lower >= band)
        target = tuple(slice(o, None, r) for o in off)
        f_val[target][far] = interp[far]
        f_bound[target][far] = lower[far]
        if with_color:
            f_col[target][far] = icol[far]
        miss = np.nonzero(~far)
        idx = [h * (o + r * m) for o, m in zip(off, miss)]
        keep = (idx[0] < limit[0]) & (idx[1] < limit[1]) & (idx[2] < limit[2])
        for a in range(3):
            todo[a].append(idx[a][keep])
    return tuple(np.concatenate(t) for t in todo)


def _cell_corners(off, r: int, h: int, cells, spacing) -> list[list[tuple]]:
    """Per axis: the corners (slice of the known lattice, weight, distance) of the cells holding the points at ``off``."""
    choices = []
    for a, o in enumerate(off):
        if o == 0:
            choices.append([(slice(None), 1.0, 0.0)])
        else:
            t = o / r
            choices.append(
                [(slice(0, cells[a]), 1 - t, o * h * spacing[a]), (slice(1, cells[a] + 1), t, (r - o) * h * spacing[a])]
            )
    return choices


def _from_corners(choices, c_pos, c_neg, c_val, c_bound, c_col, lipschitz: float, with_color: bool):
    """What the corners of each cell say about the points inside it: all positive, all negative, a lower bound on
    ``|sdf|`` (the Lipschitz bound from the nearest corner) and the trilinear interpolation of SDF (and colour)."""
    same_pos = same_neg = lower = interp = icol = None
    for combo in itertools.product(*choices):
        sl = tuple(c[0] for c in combo)
        w = np.float32(np.prod([c[1] for c in combo]))
        dist = float(np.sqrt(sum(c[2] ** 2 for c in combo)))
        lb = c_bound[sl] - np.float32(lipschitz * dist)
        if lower is None:
            same_pos, same_neg, lower, interp = c_pos[sl].copy(), c_neg[sl].copy(), lb, w * c_val[sl]
            icol = w * c_col[sl] if with_color else None
        else:
            same_pos &= c_pos[sl]
            same_neg &= c_neg[sl]
            lower = np.maximum(lower, lb)  # NaN stays NaN and gets decoded
            interp += w * c_val[sl]
            if with_color:
                icol += w * c_col[sl]
    return same_pos, same_neg, lower, interp, icol


# ----------------------------------------------------------------------------- the input's reconstruction
def reconstructed_grid(
    decoder: TriplaneDecoder, h: Triplane, grid: ShapeGrid, name: str = "reconstruction"
) -> ShapeGrid:
    """The grid the latent ``h`` describes: decoded SDF and colour at every voxel of ``grid``.

    Same box, threshold and normalisation as ``grid`` (so the two can be compared slice by slice), no training
    points; every voxel decoded.
    """
    sdf, color = decode_grid(decoder, h[:1], grid.aabb, max(grid.shape), with_color=True, coarse=None)
    assert sdf.shape == grid.shape, (sdf.shape, grid.shape)  # a ShapeGrid box is ±n_axis / n_max
    return dataclasses.replace(
        grid,
        sdf=sdf,
        color=color,
        name=name,
        points=np.zeros((0, 3), np.float32),
        point_sdf=np.zeros(0, np.float32),
        point_color=np.zeros((0, color.shape[-1]), np.float32),
    )


__all__ = ["PreparedTriplane", "ROW_TILE", "decode_grid", "mc_support", "prepare", "query_points", "reconstructed_grid"]

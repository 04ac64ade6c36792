"""Geometry metrics of the paper's evaluation (no network) on *occupancy grids*: boolean ``(X, Y, Z)`` arrays on
the cell-centred grid :mod:`sin3dm_lite.generate.extract` decodes on (``resolution`` voxels along the box's longest
side; the paper uses 128).

:func:`voxelize` and :func:`input_occupancy` make the grids; :func:`iou` and :func:`g_div` (mean pairwise
``1 − IoU``) compare whole shapes of one grid; :func:`geometry_scores` adds the local-patch scores of
:mod:`~sin3dm_lite.evaluate.patches` (LP-IoU / LP-F).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ..data.box import as_aabb, axis_centres, grid_shape, to_index
from ..errors import Sin3DMInputError
from ..formats.repair import first_listing
from ..generate.bake import rasterize_triangles
from .patches import ANY_OFFSET_MAX_VOXELS, lp_scores, lp_scores_any_offset

#: tiny shift (in voxels) of the mesh against the ray grid: marching-cubes vertices of the same grid lie exactly
#: on the rays, and a ray through an edge would be counted twice
_RAY_JITTER = np.array([3.1e-6, 2.3e-6])


def _verts_faces(mesh) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(mesh, (tuple, list)):
        verts, faces = mesh
    else:  # TexturedMesh, trimesh.Trimesh
        verts, faces = mesh.vertices, mesh.faces
    return np.asarray(verts, np.float64), np.asarray(faces, np.int64)


def psnr(mse: float) -> float:
    """Peak signal-to-noise ratio (dB) of colours in [0, 1] from their mean squared error (120 dB for none)."""
    return float(10 * math.log10(1.0 / max(mse, 1e-12)))


def reconstruction_metrics(reconstruction, grid) -> dict[str, float]:
    """How well a reconstruction (``decode.reconstructed_grid``, both ``ShapeGrid``) reproduces the input grid.

    * ``sign_accuracy``: share of voxels where the decoded SDF has the input's sign;
    * ``occupancy_iou``: IoU of the inside voxels (SDF < 0);
    * ``occupancy_iou_quarter_voxel``: the same IoU leaving out voxels whose centre lies within a quarter voxel of
      the input surface (their sign flips with any sub-voxel shift of the surface);
    * ``color_l1`` / ``color_psnr``: colour error on voxels within the truncation band;
    * ``color_psnr_surface``: the same PSNR on voxels whose centre lies within half a voxel of the input surface,
      the colour a baked texture shows. Off the surface each band voxel takes the nearest surface point's colour; on
      a curved surface that spreads a sharp pattern's edges, and the band's figure counts them many times over.

    PBR grids (``grid.has_pbr``) add, on the same voxels: ``metallic_l1``, ``roughness_l1``, ``normal_angle_deg``
    (mean angle between the decoded and the input normal) and ``metallic_iou`` (IoU of the ``metallic > 0.5`` voxels).
    """
    sdf, col = reconstruction.sdf, reconstruction.color[..., :3]
    gt_in, pr_in = grid.sdf < 0, sdf < 0
    clear = np.abs(grid.sdf) >= 0.25 * grid.voxel_size
    band = np.abs(grid.sdf) < grid.threshold
    err = col[band] - grid.color[band][:, :3]
    mse = float((err**2).mean()) if band.any() else float("nan")
    surface = np.abs(grid.sdf[band]) < 0.5 * grid.voxel_size
    mse_surface = float((err[surface] ** 2).mean()) if surface.any() else mse
    out = {
        "sign_accuracy": float((gt_in == pr_in).mean()),
        "occupancy_iou": iou(gt_in, pr_in),
        "occupancy_iou_quarter_voxel": iou(gt_in[clear], pr_in[clear]),
        "color_l1": float(np.abs(err).mean()) if band.any() else float("nan"),
        "color_psnr": psnr(mse),
        "color_psnr_surface": psnr(mse_surface),
    }
    if getattr(grid, "has_pbr", False) and reconstruction.color.shape[-1] == grid.color.shape[-1] and band.any():
        rec, ref = reconstruction.color[band], grid.color[band]
        n_rec, n_ref = rec[:, 5:8] * 2 - 1, ref[:, 5:8] * 2 - 1
        n_rec = n_rec / np.maximum(np.linalg.norm(n_rec, axis=1, keepdims=True), 1e-8)
        n_ref = n_ref / np.maximum(np.linalg.norm(n_ref, axis=1, keepdims=True), 1e-8)
        cos = np.clip(np.einsum("ij,ij->i", n_rec, n_ref), -1, 1)
        out.update(
            metallic_l1=float(np.abs(rec[:, 3] - ref[:, 3]).mean()),
            roughness_l1=float(np.abs(rec[:, 4] - ref[:, 4]).mean()),
            normal_angle_deg=float(np.degrees(np.arccos(cos)).mean()),
            metallic_iou=iou(ref[:, 3] > 0.5, rec[:, 3] > 0.5),
        )
    return out


#: the paper's voxelisation (the SSG / Sin3DM evaluation code): a voxel is solid when *any* of its 2 × 2 × 2
#: sub-voxels is inside; ``supersample=1`` samples the voxel centres alone, stricter on thin walls
PAPER_SUPERSAMPLE = 2


def any_inside(fine: np.ndarray, factor: int) -> np.ndarray:
    """Pool an occupancy grid ``factor``× coarser: a coarse voxel is solid when any of its ``factor³`` fine ones is."""
    fine = np.asarray(fine, bool)
    if factor == 1:
        return fine
    x, y, z = (n // factor for n in fine.shape)
    if min(x, y, z) < 1 or fine.shape != (x * factor, y * factor, z * factor):
        raise Sin3DMInputError(f"a grid of shape {fine.shape} does not pool {factor}x (each side a multiple of it)")
    for axis in range(3):  # one axis at a time, strided slices: much faster than any() over a 6-d reshape
        head = (slice(None),) * axis
        fine = functools.reduce(np.logical_or, (fine[(*head, slice(i, None, factor))] for i in range(factor)))
    return fine


def interpolated_inside(sdf: np.ndarray, supersample: int = PAPER_SUPERSAMPLE) -> np.ndarray:
    """The paper's voxels of the mesh marching cubes makes of ``sdf`` (values at the voxel centres), without making
    it: a voxel is solid when any of its ``supersample³`` sub-voxel centres is inside, the SDF interpolated
    trilinearly between the centres (as marching cubes does) and towards an outside layer beyond the outermost
    ones (as mesh extraction closes the box's faces)."""
    factor = check_supersample(supersample)
    grids = [np.pad(np.asarray(sdf, np.float32), 1, mode="edge")]
    border = np.ones(grids[0].shape, bool)
    border[1:-1, 1:-1, 1:-1] = False
    grids[0][border] = np.abs(grids[0][border]) + 1e-6
    for axis in range(3):
        head = (slice(None),) * axis
        n = grids[0].shape[axis]
        grids = [
            (1 - abs(o)) * g[(*head, slice(1, n - 1))] + abs(o) * g[(*head, slice(1 + s, n - 1 + s))]
            for g in grids
            for o in (np.arange(factor) + 0.5) / factor - 0.5
            for s in [1 if o > 0 else -1]
        ]
    return functools.reduce(np.logical_or, (g < 0 for g in grids))


def check_supersample(supersample) -> int:
    """``supersample`` as an int; an error when it is not a whole number ≥ 1."""
    if not isinstance(supersample, (int, np.integer)) or isinstance(supersample, bool) or supersample < 1:
        raise Sin3DMInputError(
            f"supersample must be a whole number ≥ 1 (1: voxel centres; 2: the paper's), got {supersample!r}"
        )
    return int(supersample)


def voxelize(mesh, aabb, resolution: int = 128, supersample: int = 1) -> np.ndarray:
    """Occupancy of the voxel centres of a grid over ``aabb`` → bool ``(X, Y, Z)``, for a closed mesh.

    Ray casting along +z through every column of voxel centres: each triangle the ray crosses adds +1 (leaving the
    shape) or −1 (entering); a voxel is inside when the crossings above it do not cancel (a winding number along the
    ray). ``mesh``: a ``TexturedMesh``, ``trimesh.Trimesh`` or ``(verts, faces)`` in ``aabb``'s coordinates;
    ``supersample``: ``supersample³`` sub-voxel centres per voxel, solid when any is inside (:data:`PAPER_SUPERSAMPLE`
    is the paper's way).
    """
    factor = check_supersample(supersample)
    shape = tuple(factor * n for n in grid_shape(as_aabb(aabb), resolution))
    return any_inside(_voxel_centres_inside(mesh, aabb, shape), factor)


def _voxel_centres_inside(mesh, aabb, shape, outward: bool = False) -> np.ndarray:
    """:func:`voxelize` on a grid of ``shape`` voxels over ``aabb`` (``outward``: the faces are known to wind
    outwards, so inside is a winding number above ½, as for the generalised winding number)."""
    verts, faces = _verts_faces(mesh)
    box = as_aabb(aabb)
    nx, ny, nz = shape
    # continuous voxel index: voxel centre k sits at k
    idx = to_index(verts, box, shape)
    idx[:, :2] += _RAY_JITTER
    tri = idx[faces]
    f, x, y, bary = rasterize_triangles(tri[:, :, :2], nx, ny, eps=0.0)
    ab, ac = tri[:, 1, :2] - tri[:, 0, :2], tri[:, 2, :2] - tri[:, 0, :2]
    sign = np.sign(ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])[f]  # z of the normal: +1 exit, −1 entry
    z_hit = np.einsum("nk,nk->n", bary, tri[f, :, 2])
    m = np.clip(np.ceil(z_hit), 0, nz).astype(np.int64)  # the hit lies above voxels k < m
    acc = np.bincount((x * ny + y) * (nz + 1) + m, weights=sign, minlength=nx * ny * (nz + 1))
    acc = acc.reshape(nx, ny, nz + 1)
    winding = np.cumsum(acc[..., ::-1], axis=-1)[..., ::-1][..., 1:]  # winding[k] = sum of acc[m] for m > k
    return winding > 0.5 if outward else np.abs(winding) > 0.5  # a whole number of crossings, up to rounding


def input_occupancy(mesh, aabb, resolution: int = 128, supersample: int = 1) -> np.ndarray:
    """The *input* mesh as an occupancy grid: inside (winding number > ½) at every voxel centre; the reference the
    LP metrics compare against.

    Unlike :func:`voxelize` it needs no closed mesh: an open one's generalised winding number decides. A closed
    mesh's winding number is whole, so :func:`voxelize`'s ray cast counts it exactly and much faster. Open sheets
    and parts thinner than a voxel are the training grid's slabs here too
    (:meth:`~sin3dm_lite.data.distance.Distance.find_slabs`), on a closed mesh as well; a point inside a slab is
    inside whatever its winding number, so only the others ask it. Otherwise, with
    ``supersample`` > 1 only the voxels near the surface (or across a hole) get a winding number per sub-voxel; the
    others take their centre's. The mesh must be in the same (normalised) coordinates as ``aabb``; ``supersample``:
    as for :func:`voxelize`.
    """
    from types import SimpleNamespace

    from ..data.distance import Distance

    factor = check_supersample(supersample)
    box = as_aabb(aabb)
    coarse = tuple(grid_shape(box, resolution))
    shape = tuple(factor * n for n in coarse)
    verts, faces = _verts_faces(mesh)
    faces = faces[first_listing(verts, faces)]  # a two-sided mesh's pairs would cancel in the winding number
    dist = Distance(SimpleNamespace(vertices=verts, faces=faces))  # closed parts turned outwards
    slabs = any(dist.find_slabs())  # open sheets and thin parts as slabs, the same as the training grid has them
    if dist.closed and not slabs:
        return any_inside(_voxel_centres_inside((dist.v, dist.f), box, shape, outward=True), factor)
    centres = _centres(box, coarse)
    side = np.zeros(coarse, bool)  # the voxel centres' answer
    near = _dilate(_surface_cells(dist.v, dist.f, box, coarse))
    if slabs:  # every voxel within a slab's reach of its face
        slab = _surface_cells(dist.v, dist.f[dist.reach > 0], box, coarse)
        for _ in range(1 + int(np.ceil(dist.reach_max / ((box[3:] - box[:3]) / coarse).min()))):
            slab = _dilate(slab)
        cells = np.flatnonzero(slab)
        side.reshape(-1)[cells] = dist.in_slab(centres[cells])
        near |= slab
    rest = ~side.reshape(-1)  # where no slab decides, the winding number does
    side.reshape(-1)[rest] = dist.winding(centres[rest]) > 0.5
    if factor == 1:
        return side
    # a voxel's sub-voxels can differ from its centre only where the surface passes near it, or where the
    # winding number crosses ½ between centres (across a hole): there each sub-voxel gets its own winding number
    todo = np.argwhere(near | _sign_changes(side))
    offsets = np.stack(np.meshgrid(*(np.arange(factor),) * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    sub = (todo[:, None, :] * factor + offsets[None]).reshape(-1, 3)
    axes = [axis_centres(box, shape, a) for a in range(3)]
    fine = np.repeat(np.repeat(np.repeat(side, factor, 0), factor, 1), factor, 2)
    points = np.stack([axes[a][sub[:, a]] for a in range(3)], axis=-1)
    inside = np.zeros(len(points), bool)
    if slabs:  # only a slab's own voxels can hold it (the centres' rule above)
        at = np.repeat(slab[tuple(todo.T)], len(offsets))
        inside[at] = dist.in_slab(points[at])
    inside[~inside] = dist.winding(points[~inside]) > 0.5
    fine[tuple(sub.T)] = inside
    return any_inside(fine, factor)


def _centres(box, shape) -> np.ndarray:
    """The voxel centres of a grid of ``shape`` over ``box``, ``(N, 3)`` in x-major order."""
    axes = [axis_centres(box, shape, a) for a in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _surface_cells(verts, faces, box, shape) -> np.ndarray:
    """Voxels that each triangle's bounding box touches (so every voxel the surface passes through)."""
    cell = to_index(verts, box, shape) + 0.5  # voxel k spans [k, k + 1)
    top = np.array(shape) - 1
    tri = cell[faces]
    lo = np.clip(np.floor(tri.min(1)).astype(np.int64), 0, top)
    hi = np.clip(np.floor(tri.max(1)).astype(np.int64), 0, top)
    cells = np.zeros(shape, bool)
    small = (hi - lo <= 1).all(axis=1)  # most triangles: at most 2 voxels along each axis
    for o in np.stack(np.meshgrid(*(np.arange(2),) * 3, indexing="ij"), axis=-1).reshape(-1, 3):
        cells[tuple(np.minimum(lo[small] + o, hi[small]).T)] = True
    for a, b in zip(lo[~small], hi[~small]):
        cells[a[0] : b[0] + 1, a[1] : b[1] + 1, a[2] : b[2] + 1] = True
    return cells


def _dilate(grid: np.ndarray) -> np.ndarray:
    """``grid`` grown by one voxel along each axis and diagonal (a 3 × 3 × 3 neighbourhood)."""
    for axis in range(3):
        grown = grid.copy()
        lo, hi = [slice(None)] * 3, [slice(None)] * 3
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        grown[tuple(lo)] |= grid[tuple(hi)]
        grown[tuple(hi)] |= grid[tuple(lo)]
        grid = grown
    return grid


def _sign_changes(side: np.ndarray) -> np.ndarray:
    """Voxels whose answer differs from a face neighbour's."""
    out = np.zeros(side.shape, bool)
    for axis in range(3):
        change = np.diff(side, axis=axis)
        lo, hi = [slice(None)] * 3, [slice(None)] * 3
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        out[tuple(lo)] |= change
        out[tuple(hi)] |= change
    return out


def check_same_grid(grids: list[np.ndarray]) -> None:
    """Refuse occupancy grids of different shapes: they cannot be compared voxel by voxel."""
    shapes = {tuple(np.shape(g)) for g in grids}
    if len(shapes) > 1:
        raise Sin3DMInputError(
            f"occupancy grids of different shapes {sorted(shapes)} cannot be compared voxel by voxel; "
            "voxelise every shape in the same box and resolution (retargeted samples need their own set)"
        )


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two occupancy grids of the same shape (1.0 when both are empty)."""
    check_same_grid([a, b])
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    union = np.logical_or(a, b).sum()
    return 1.0 if union == 0 else float(np.logical_and(a, b).sum() / union)


def pairwise_iou(grids) -> np.ndarray:
    """``(n, n)`` IoU matrix of occupancy grids that share one shape."""
    grids = [np.asarray(g, bool) for g in grids]
    check_same_grid(grids)
    grids = [g.reshape(-1) for g in grids]
    n = len(grids)
    out = np.ones((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            union = np.count_nonzero(grids[i] | grids[j])
            out[i, j] = out[j, i] = 1.0 if union == 0 else np.count_nonzero(grids[i] & grids[j]) / union
    return out


def g_div(grids) -> float:
    """G-Div: mean of ``1 − IoU`` over all pairs of generated shapes (0 = all identical, 1 = all disjoint); the
    grids must share one shape (same box and resolution)."""
    grids = list(grids)
    if len(grids) < 2:
        raise Sin3DMInputError(f"g_div needs at least two shapes, got {len(grids)}")
    m = pairwise_iou(grids)
    i, j = np.triu_indices(len(grids), k=1)
    return float(np.mean(1.0 - m[i, j]))


def g_div_by_layer(grids, axis: int = 1) -> np.ndarray:
    """G-Div split over the layers of the grid along ``axis`` (1, y: heights): where the samples differ.

    ``1 − IoU(a, b) = |a xor b| / |a ∪ b|`` is a sum over layers: entry ``k`` is the mean over pairs of the
    disagreeing voxels in layer ``k`` divided by the pair's union, so the entries sum to :func:`g_div`.
    """
    grids = [np.asarray(g, bool) for g in grids]
    if len(grids) < 2:
        raise Sin3DMInputError(f"g_div_by_layer needs at least two shapes, got {len(grids)}")
    check_same_grid(grids)
    if axis not in (0, 1, 2):
        raise Sin3DMInputError(f"axis must be 0, 1 or 2 (x, y, z), got {axis!r}")
    other = tuple(a for a in range(3) if a != axis)
    out = np.zeros(grids[0].shape[axis])
    i, j = np.triu_indices(len(grids), k=1)
    for a, b in zip(i, j):
        union = np.count_nonzero(grids[a] | grids[b])
        if union:
            out += (grids[a] ^ grids[b]).sum(other) / union
    return out / len(i)


def variation_scores(reference: np.ndarray, samples) -> dict:
    """How far samples stray from the input and from each other (occupancy grids in one box): ``iou_to_input``
    (mean IoU with ``reference``; near 1: copies), ``per_sample_iou`` and ``g_div`` (None for a single sample)."""
    samples = list(samples)
    per = [iou(s, reference) for s in samples]
    return {
        "iou_to_input": float(np.mean(per)),
        "per_sample_iou": per,
        "g_div": g_div(samples) if len(samples) > 1 else None,
    }


def reconstruction_iou(mesh_a, mesh_b, aabb, resolution: int = 128) -> float:
    """IoU of two meshes voxelised in the same box (e.g. the input and its autoencoder reconstruction)."""
    return iou(voxelize(mesh_a, aabb, resolution), voxelize(mesh_b, aabb, resolution))


def geometry_scores(reference: np.ndarray, samples, any_offset: bool = True) -> dict:
    """The paper's weight-free geometry metrics of generated shapes against the input (occupancy grids, one box).

    * ``g_div`` — G-Div (higher = more diverse; None for one sample);
    * ``lp_iou``, ``lp_fscore`` — LP-IoU / LP-F (:func:`~sin3dm_lite.evaluate.patches.lp_scores`);
    * ``iou_to_input`` — mean IoU of each sample with the input (near 1 = copies of the input);
    * with ``any_offset``, ``lp_iou_any_offset``, ``lp_fscore_any_offset`` — **not in the paper**: the input's
      patches at every voxel (:func:`~sin3dm_lite.evaluate.patches.lp_scores_any_offset`; None above
      :data:`~sin3dm_lite.evaluate.patches.ANY_OFFSET_MAX_VOXELS` a side).
    """
    samples = list(samples)
    lp, var = lp_scores(reference, samples), variation_scores(reference, samples)
    out = {
        "g_div": var["g_div"],
        "lp_iou": lp["lp_iou"],
        "lp_fscore": lp["lp_fscore"],
        "iou_to_input": var["iou_to_input"],
    }
    if any_offset and max(np.shape(reference)) <= ANY_OFFSET_MAX_VOXELS:
        out.update({k: v for k, v in lp_scores_any_offset(reference, samples).items() if not k.startswith("per_")})
    else:
        out.update(lp_iou_any_offset=None, lp_fscore_any_offset=None)
    return out

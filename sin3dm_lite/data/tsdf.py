"""The truncated SDF and colour of a mesh, on a grid (:func:`tsdf_grid`) and at points (:func:`point_tsdf`):
the computation behind ``grid.mesh_to_grid``."""

from __future__ import annotations

import numpy as np

from .distance import Distance
from .mesh import TexturedMesh

#: The channels of ``ShapeGrid.color`` in a PBR grid: base colour, metallic, roughness, world-space normal · ½ + ½.
PBR_CHANNELS = ("red", "green", "blue", "metallic", "roughness", "normal_x", "normal_y", "normal_z")


def surface_channels(
    mesh: TexturedMesh, face_index: np.ndarray, barycentric: np.ndarray, pbr: bool = False
) -> np.ndarray:
    """What a voxel stores about its closest surface point: RGB ``(n, 3)``, or with ``pbr`` the 8 :data:`PBR_CHANNELS`."""
    rgb = mesh.colors_at(face_index, barycentric)
    if not pbr:
        return rgb
    m = mesh.pbr_at(face_index, barycentric)  # metallic, roughness, unit normal in [-1, 1]
    return np.concatenate([rgb, m[:, :2], m[:, 2:] * 0.5 + 0.5], axis=1).astype(np.float32)


def _block_view(a: np.ndarray, s: int) -> np.ndarray:
    """View an ``(H, W, D, ...)`` array as ``(H/s, s, W/s, s, D/s, s, ...)`` blocks (writes go through)."""
    h, w, d = a.shape[:3]
    return a.reshape(h // s, s, w // s, s, d // s, s, *a.shape[3:])


def tsdf_grid(
    dist: Distance,
    mesh: TexturedMesh,
    dims,
    aabb: np.ndarray,
    vs: float,
    threshold: float,
    say,
    sure_margin: float = 0.4,
    pbr: bool = False,
):
    """Truncated SDF and colour on the cell-centred grid, by coarse-to-fine block refinement.

    Blocks of 8³ voxels are visited first. For a block of ``s³`` voxels whose
    centre lies at exact distance ``d`` from the surface, every voxel centre is
    within ``h = (s-1)·√3/2`` voxels of the block centre, so if
    ``d ≥ threshold + h`` no voxel of the block is in the band: all get
    ``±threshold``. Other blocks split into 8 children, down to single voxels,
    which get their exact distance, and their colour when inside the band.

    The sign is the fast winding number ``w`` (inside where ``w > ½``). The
    ball of radius ``d`` around a block centre holds no surface, so ``w`` has
    no jump in it and, where it is clearly 0 or 1 at the centre
    (``|w - ½| > sure_margin``), the whole ball (and so the block when ``d > h``)
    shares the centre's sign: children inherit it instead of paying for their
    own winding number. Near a hole ``w`` drifts smoothly through ½ (that is
    how it closes holes); there blocks keep splitting, for the sign only,
    until every voxel has its own winding number.

    Returns the SDF, the colour and ``sure``: where a voxel's sign came from a
    winding number clearly 0 or 1 (used to sign the training points).
    """
    dims = np.asarray(dims)
    lo = aabb[:3].astype(np.float64)
    sdf = np.empty(tuple(dims), np.float32)
    color = np.zeros((*dims, len(PBR_CHANNELS) if pbr else 3), np.float32)
    sure_grid = np.empty(tuple(dims), bool)
    s = 8
    blocks = np.argwhere(np.ones(tuple(dims // s), bool))  # block coordinates at level s
    w = np.zeros(len(blocks))  # winding number (own, or inherited where `known`)
    known = np.zeros(len(blocks), bool)
    far = np.zeros(len(blocks), bool)  # already known to be out of the band
    children = np.stack(np.meshgrid(*(np.arange(2),) * 3, indexing="ij"), -1).reshape(-1, 3)
    n_dist = n_wind = 0
    while True:
        centre = lo + (blocks * s + s / 2) * vs
        d = np.full(len(blocks), np.inf)
        d[~far], fi, bc = dist.closest(centre[~far])
        w[~known] = dist.winding(centre[~known])
        n_dist, n_wind = n_dist + int((~far).sum()), n_wind + int((~known).sum())
        sign = np.where(w > 0.5, -1.0, 1.0)
        sure = np.abs(w - 0.5) > sure_margin
        if s == 1:
            i, j, k = blocks.T
            face = np.zeros(len(blocks), np.int64)
            face[~far] = fi
            sdf[i, j, k], thick = dist.thicken(sign * np.minimum(d, threshold), centre, d, face, threshold)
            sure_grid[i, j, k] = sure & ~thick  # a slab's sign is not the winding number's
            band = (d < threshold) | (np.isfinite(d) & (np.abs(sdf[i, j, k]) < threshold))  # and a slab's own band
            color[i[band], j[band], k[band]] = surface_channels(mesh, fi[band[~far]], bc[band[~far]], pbr)
            break
        h = (s - 1) * np.sqrt(3) / 2 * vs
        far = d >= threshold + dist.reach_max + h  # a slab's band reaches its reach beyond the face
        done = far & sure
        i, j, k = blocks[done].T
        _block_view(sdf, s)[i, :, j, :, k, :] = (sign[done] * threshold)[:, None, None, None]
        _block_view(sure_grid, s)[i, :, j, :, k, :] = True
        split = ~done
        blocks = (blocks[split][:, None, :] * 2 + children[None]).reshape(-1, 3)
        known = np.repeat((d > h)[split] & sure[split], 8)
        w, far = np.repeat(w[split], 8), np.repeat(far[split], 8)
        s //= 2
    say(f"[grid] exact distances at {n_dist:,} points, winding numbers at {n_wind:,} (grid of {dims.prod():,} voxels)")
    return sdf, color, sure_grid


def signs_from_grid(p, d, grid_sdf, sure, lo, vs, closed: bool):
    """Inside/outside of points from the voxels around them, where a surface-free ball allows it.

    A point ``p`` at distance ``d`` from the surface and a voxel centre ``v``
    at distance ``|sdf(v)|`` (at least that, beyond the band) each sit in a
    ball with no surface inside. On a ``closed`` mesh the winding number only
    changes across the surface, so if the two balls overlap,
    ``|p - v| < d + |sdf(v)|``, the path from ``p`` to ``v`` through them
    keeps the sign. Near a hole the winding number also drifts through ½ in
    empty space, so there one ball must hold the other,
    ``|p - v| < max(d, |sdf(v)|)``, and the voxel's sign must be a sure one
    (see :func:`tsdf_grid`). Returns ``(resolved, inside)``; the unresolved
    points need their own winding number.
    """
    dims = np.array(grid_sdf.shape)
    f = (p - lo) / vs - 0.5
    base = np.floor(f).astype(np.int64)
    nearest = (f - base > 0.5).astype(np.int64)  # try the nearest of the 8 voxels first
    resolved = np.zeros(len(p), bool)
    inside = np.zeros(len(p), bool)
    todo = np.arange(len(p))
    for off in np.stack(np.meshgrid(*(np.arange(2),) * 3, indexing="ij"), -1).reshape(-1, 3):
        idx = np.clip(base[todo] + (nearest[todo] ^ off), 0, dims - 1)
        i, j, k = idx.T
        sv = grid_sdf[i, j, k].astype(np.float64)
        r = np.linalg.norm(p[todo] - (lo + (idx + 0.5) * vs), axis=1)
        reach = d[todo] + np.abs(sv) if closed else np.maximum(d[todo], np.abs(sv))
        ok = sure[i, j, k] & (sv != 0) & (r < 0.999 * reach)
        inside[todo[ok]] = sv[ok] < 0
        resolved[todo[ok]] = True
        todo = todo[~ok]
    return resolved, inside


def point_tsdf(dist: Distance, mesh: TexturedMesh, p: np.ndarray, threshold: float, grid: tuple, pbr: bool = False):
    """Exact truncated SDF and colour (0 outside the band) at arbitrary points.

    ``grid = (sdf, sure, lo, voxel_size)`` from :func:`tsdf_grid`: most signs come from the voxels around each
    point (:func:`signs_from_grid`), only the rest from their own winding number.
    """
    p = np.ascontiguousarray(p, dtype=np.float64)
    d, fi, bc = dist.closest(p)
    resolved, inside = signs_from_grid(p, d, *grid, closed=dist.closed)
    resolved |= dist.slab_decides(p, d, fi)  # deep in a slab, the sign does not change the value
    inside[~resolved] = dist.winding(p[~resolved]) > 0.5
    sdf, _ = dist.thicken(np.where(inside, -1.0, 1.0) * np.minimum(d, threshold), p, d, fi, threshold)
    sdf = sdf.astype(np.float32)
    col = np.zeros((len(p), len(PBR_CHANNELS) if pbr else 3), np.float32)
    band = d < threshold
    col[band] = surface_channels(mesh, fi[band], bc[band], pbr)
    return sdf, col


__all__ = ["PBR_CHANNELS", "point_tsdf", "signs_from_grid", "surface_channels", "tsdf_grid"]

"""Mesh → truncated SDF + colour grid, the representation the autoencoder learns from.

Sin3DM first turns the textured mesh into a regular voxel grid: the signed
distance to the surface, clipped to a thin band of ±3 voxels (a *truncated*
SDF: only the surface's neighbourhood carries information), and the surface
colour at every voxel inside that band. The autoencoder later compresses this
grid into a triplane.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import point_cloud_utils as pcu
from scipy import ndimage

from .errors import Sin3DMInputError
from .files import atomic_path
from .mesh_io import Normalization, TexturedMesh


@dataclass
class ShapeGrid:
    """The paper's input representation of one shape.

    Attributes:
        sdf: ``(H, W, D)`` float32 truncated signed distance (negative inside),
            clipped to ``±threshold``; axis 0 is x, 1 is y, 2 is z.
        color: ``(H, W, D, K)`` float32 in [0, 1] (K = 3 for RGB); 0 outside the band.
        aabb: ``(6,)`` the symmetric box ``(xmin, ymin, zmin, xmax, ymax, zmax)`` in
            normalised coordinates, ``±n_axis / n_max``.
        threshold: truncation distance in normalised units (3 voxels by default).
        normalization: maps the input file's coordinates to the normalised frame.
        points / point_sdf / point_color: near-surface training samples
            (normalised coordinates) with their exact truncated SDF and colour.
        name: label of the source mesh.
    """

    sdf: np.ndarray
    color: np.ndarray
    aabb: np.ndarray
    threshold: float
    normalization: Normalization
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    point_sdf: np.ndarray = field(default_factory=lambda: np.zeros((0,), np.float32))
    point_color: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    name: str = "shape"

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.sdf.shape)  # type: ignore[return-value]

    @property
    def voxel_size(self) -> float:
        """Edge length of one (cubic) voxel in normalised units."""
        return float((self.aabb[3] - self.aabb[0]) / self.sdf.shape[0])

    def axis_coords(self, axis: int) -> np.ndarray:
        """Cell-centred voxel coordinates along one axis: ``min + (k + 0.5) / n * size``."""
        n = self.sdf.shape[axis]
        lo, hi = self.aabb[axis], self.aabb[axis + 3]
        return (lo + (np.arange(n) + 0.5) / n * (hi - lo)).astype(np.float32)

    def voxel_centers(self) -> np.ndarray:
        """``(H, W, D, 3)`` coordinates of every voxel centre."""
        return np.stack(np.meshgrid(*(self.axis_coords(a) for a in range(3)), indexing="ij"), axis=-1)

    def to_box(self, points: np.ndarray) -> np.ndarray:
        """Normalised coordinates → box coordinates in [-1, 1] (what triplane lookups take)."""
        lo, hi = self.aabb[:3], self.aabb[3:]
        return (2 * (np.asarray(points) - lo) / (hi - lo) - 1).astype(np.float32)

    def from_box(self, points: np.ndarray) -> np.ndarray:
        lo, hi = self.aabb[:3], self.aabb[3:]
        return ((np.asarray(points) + 1) / 2 * (hi - lo) + lo).astype(np.float32)


# --------------------------------------------------------------------------- building
def grid_dims(extent: np.ndarray, resolution: int) -> tuple[int, int, int]:
    """Voxel counts per axis as in the original code: ``int(res · extent / max_extent)`` rounded up to a multiple of 8."""
    extent = np.asarray(extent, dtype=np.float64)
    dims = []
    for e in extent:
        n = int(resolution * e / extent.max())
        dims.append(max(8, int(np.ceil(n / 8) * 8)))
    dims[int(np.argmax(extent))] = int(np.ceil(resolution / 8) * 8)
    return tuple(dims)  # type: ignore[return-value]


def _check_resolution(resolution: int) -> None:
    if not isinstance(resolution, (int, np.integer)) or resolution < 16 or resolution > 512:
        raise Sin3DMInputError(
            f"grid resolution {resolution!r} is out of range; use a whole number from 16 to 512 "
            "(32-64 for a CPU, 256 as in the paper)"
        )


class _Distance:
    """Truncated signed distance to a mesh, computed only where it matters.

    Exact point-to-triangle distances are the expensive part, and far from the
    surface the TSDF is just ``±threshold``. The sign comes from
    point-cloud-utils' fast winding number, which is cheap and robust — also
    for open or multi-part meshes, where "make it watertight" tricks fail.
    """

    def __init__(self, mesh: TexturedMesh):
        self.v = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
        self.f = np.ascontiguousarray(mesh.faces, dtype=np.int64)

    def inside(self, p: np.ndarray) -> np.ndarray:
        w = pcu.triangle_soup_fast_winding_number(self.v, self.f, np.ascontiguousarray(p, dtype=np.float64))
        return w > 0.5

    def cover(self, gap: float) -> np.ndarray:
        """Points on the surface such that every surface point lies within ``gap`` of one of them.

        Each triangle gets a barycentric lattice fine enough for its longest edge.
        """
        tri = self.v[self.f]  # (F, 3, 3)
        edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(1)
        k = np.maximum(1, np.ceil(edge / gap)).astype(np.int64)
        out = [self.v]
        for kk in np.unique(k[k > 1]):
            i, j = np.meshgrid(np.arange(kk + 1), np.arange(kk + 1), indexing="ij")
            keep = i + j <= kk
            bc = np.stack([i[keep], j[keep], kk - i[keep] - j[keep]], 1) / kk  # (L, 3)
            out.append(np.einsum("lk,fkd->fld", bc, tri[k == kk]).reshape(-1, 3))
        return np.concatenate(out)

    def tsdf(self, p: np.ndarray, threshold: float, chunk: int = 1 << 18):
        """Truncated SDF (negative inside), closest face (-1 outside the band) and barycentrics.

        Exact distances from point-cloud-utils' closest-point query (its
        ``signed_distance_to_mesh`` is not used: its distances are approximate,
        and far off on open meshes); the sign from the fast winding number.
        """
        p = np.ascontiguousarray(p, dtype=np.float64)
        inside = self.inside(p)
        sdf = np.empty(len(p), np.float32)
        fid = np.full(len(p), -1, np.int64)
        bcs = np.zeros((len(p), 3), np.float64)
        for a in range(0, len(p), chunk):
            d, fi, bc = pcu.closest_points_on_mesh(p[a : a + chunk], self.v, self.f)
            band = d < threshold
            sdf[a : a + chunk] = np.where(inside[a : a + chunk], -1, 1) * np.minimum(d, threshold)
            fid[a : a + chunk] = np.where(band, fi, -1)
            bcs[a : a + chunk] = np.where(band[:, None], bc, 0.0)
        return sdf, fid, bcs


def mesh_to_grid(
    mesh: TexturedMesh,
    resolution: int = 128,
    threshold_voxels: float = 3.0,
    n_surface_points: int = 500_000,
    near_surface_sigma: float = 0.005,
    seed: int = 0,
    progress: bool = True,
) -> ShapeGrid:
    """Turn a textured mesh into the paper's truncated SDF + colour grid.

    1. Normalise (centre, longest side × 1.03 → [-1, 1]) and size the grid:
       ``resolution`` voxels along the longest side, the other axes rounded up
       to multiples of 8, a symmetric box ``±n_axis / n_max``.
    2. Signed distance at every cell-centred voxel, truncated at
       ``threshold_voxels`` voxels. Blocks of 4³ voxels whose centre is far from
       the surface are filled with ``±threshold`` from one winding-number sign;
       exact distances are computed only in blocks that touch the band.
    3. RGB at every voxel within the band from the closest point on the
       original surface (texture lookup with bilinear filtering).
    4. Training points: surface samples plus Gaussian noise (σ =
       ``near_surface_sigma``), with their exact truncated SDF and colour.
    """
    _check_resolution(resolution)
    say = print if progress else (lambda *a, **k: None)
    t0 = time.perf_counter()
    m = mesh.normalized()
    extent = m.bounds[1] - m.bounds[0]
    dims = np.array(grid_dims(extent, resolution))
    half = dims / dims.max()
    aabb = np.concatenate([-half, half]).astype(np.float32)
    vs = 2.0 / dims.max()
    threshold = float(threshold_voxels * vs)
    say(f"[grid] '{mesh.name}': {len(m.faces):,} faces → grid {dims[0]}×{dims[1]}×{dims[2]}, band ±{threshold:.4f}")

    dist = _Distance(m)
    out = ShapeGrid(np.zeros(tuple(dims), np.float32), np.empty(0), aabb, threshold, m.normalization, name=mesh.name)
    axes = [out.axis_coords(a).astype(np.float64) for a in range(3)]

    # coarse pass: blocks of 4×4×4 voxels (dims are multiples of 8, so blocks tile the grid).
    # A block needs exact distances only if it may hold a voxel within the band; mark the
    # blocks that contain surface points (spaced at most `gap` apart) and grow the mark by
    # enough blocks to cover threshold + gap.
    b, gap = 4, 0.5 * vs
    cdims = dims // b
    cover = dist.cover(gap)
    cidx = np.clip(np.floor((cover - aabb[:3]) / (b * vs)).astype(np.int64), 0, cdims - 1)
    near_block = np.zeros(tuple(cdims), bool)
    near_block[cidx[:, 0], cidx[:, 1], cidx[:, 2]] = True
    grow = int(np.ceil((threshold + gap) / (b * vs)))
    near_block = ndimage.binary_dilation(near_block, np.ones((3, 3, 3), bool), iterations=grow)
    centers = [ax.reshape(-1, b).mean(1) for ax in axes]
    cpts = np.stack(np.meshgrid(*centers, indexing="ij"), -1).reshape(-1, 3)
    cin = dist.inside(cpts).reshape(tuple(cdims))

    sdf = np.where(cin, -threshold, threshold).astype(np.float32)
    sdf = np.repeat(np.repeat(np.repeat(sdf, b, 0), b, 1), b, 2)
    color = np.zeros((*dims, 3), np.float32)

    # fine pass: every voxel in a block that may touch the band
    bi = np.argwhere(near_block)  # (K, 3) block indices
    offs = np.stack(np.meshgrid(*(np.arange(b),) * 3, indexing="ij"), -1).reshape(-1, 3)
    idx = (bi[:, None, :] * b + offs[None]).reshape(-1, 3)  # fine voxel indices
    pts = np.stack([axes[a][idx[:, a]] for a in range(3)], -1)
    s, fi, bc = dist.tsdf(pts, threshold)
    sdf[idx[:, 0], idx[:, 1], idx[:, 2]] = s
    band = fi >= 0
    color[idx[band, 0], idx[band, 1], idx[band, 2]] = m.colors_at(fi[band], bc[band])
    say(f"[grid] distances near the surface: {len(pts):,} of {dims.prod():,} voxels ({time.perf_counter() - t0:.1f} s)")

    # training points near the surface
    rng = np.random.default_rng(seed)
    if n_surface_points > 0:
        sp, _, _ = m.surface_points(n_surface_points, rng)
        sp = sp + rng.normal(scale=near_surface_sigma, size=sp.shape)
        sp = np.clip(sp, aabb[:3], aabb[3:])
        ps, pf, pb = dist.tsdf(sp, threshold)
        pc = np.zeros((len(sp), 3), np.float32)
        ok = pf >= 0
        pc[ok] = m.colors_at(pf[ok], pb[ok])
        out.points, out.point_sdf, out.point_color = sp.astype(np.float32), ps, pc
    out.sdf, out.color = sdf, color
    say(f"[grid] done in {time.perf_counter() - t0:.1f} s: {int((np.abs(sdf) < threshold).sum()):,} voxels in the band")
    return out


# --------------------------------------------------------------------------- files
def save_grid(grid: ShapeGrid, path: str | Path) -> Path:
    """Write a grid to ``.npz`` (``sdf``, ``color``, ``aabb``, ``threshold``, ``center``, ``scale``, points), atomically."""
    path = Path(path)
    if path.suffix != ".npz":
        raise Sin3DMInputError(f"grid files are .npz; got '{path.name}' — use a name like grid.npz")
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        np.savez_compressed(
            tmp,
            sdf=grid.sdf.astype(np.float32),
            color=grid.color.astype(np.float32),
            aabb=np.asarray(grid.aabb, np.float32),
            threshold=np.float32(grid.threshold),
            center=np.asarray(grid.normalization.center, np.float64),
            scale=np.float64(grid.normalization.scale),
            points=grid.points,
            point_sdf=grid.point_sdf,
            point_color=grid.point_color,
            name=np.array(grid.name),
        )
    return path


def load_grid(path: str | Path) -> ShapeGrid:
    """Read a grid written by :func:`save_grid`."""
    path = Path(path)
    if not path.is_file():
        raise Sin3DMInputError(f"grid file '{path}' not found; create one with `sin3dm-lite grid MESH --out {path.name}`")
    with np.load(path) as z:
        return ShapeGrid(
            sdf=z["sdf"],
            color=z["color"],
            aabb=z["aabb"],
            threshold=float(z["threshold"]),
            normalization=Normalization(center=z["center"], scale=float(z["scale"])),
            points=z["points"],
            point_sdf=z["point_sdf"],
            point_color=z["point_color"],
            name=str(z["name"]),
        )

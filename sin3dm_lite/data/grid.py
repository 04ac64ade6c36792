"""Mesh → truncated SDF + colour grid, the representation the autoencoder learns from.

Sin3DM first turns the textured mesh into a regular voxel grid: the signed
distance to the surface, clipped to a thin band of ±3 voxels (a *truncated*
SDF: only the surface's neighbourhood carries information), and the surface
colour at every voxel inside that band. The autoencoder later compresses this
grid into a triplane.

The PBR variant (paper, appendix "Supporting PBR Material") keeps more than
colour per voxel: base colour (3), metallic, roughness and the surface normal
(3), eight channels in :data:`PBR_CHANNELS` order, all in [0, 1] (the
world-space normal stored as ``n · 0.5 + 0.5``, as a normal map stores its
vectors). With the SDF that is the paper's 9-channel grid.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..errors import Sin3DMInputError
from ..files import atomic_path
from ..formats.repair import listed_once
from .box import SHEET_HALF, axis_centres, centred_box, flat_axes, to_box, training_dims
from .config import LIMITS
from .distance import THIN_DEPTHS, Distance, Slabs
from .mesh import MAX_COORDINATE, Normalization, TexturedMesh, is_rotation, unique_rows
from .tsdf import PBR_CHANNELS, point_tsdf, tsdf_grid

#: colours closer than half a step of 8-bit colour count as one (:meth:`ShapeGrid.single_color`)
ONE_COLOUR_TOLERANCE = 0.5 / 255


@dataclass
class ShapeGrid:
    """The paper's input representation of one shape.

    Attributes:
        sdf: ``(H, W, D)`` float32 truncated signed distance (negative inside),
            clipped to ``±threshold``; axis 0 is x, 1 is y, 2 is z.
        color: ``(H, W, D, K)`` float32 in [0, 1]; 0 outside the band. K = 3 for RGB;
            K = 8 for PBR (:data:`PBR_CHANNELS`: RGB, metallic, roughness,
            world-space normal · ½ + ½).
        aabb: ``(6,)`` the symmetric box ``(xmin, ymin, zmin, xmax, ymax, zmax)`` in
            normalised coordinates, ``±n_axis / n_max``.
        threshold: truncation distance in normalised units (3 voxels by default).
        normalization: maps the input file's coordinates (turned upright: ``grid.up``) to the normalised frame.
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
    def has_pbr(self) -> bool:
        """True for a PBR grid (8 channels: :data:`PBR_CHANNELS`)."""
        return self.color.shape[-1] == len(PBR_CHANNELS)

    @property
    def rgb(self) -> np.ndarray:
        """``(H, W, D, 3)`` base colour (the first three channels)."""
        return self.color[..., :3]

    def channel(self, name: str) -> np.ndarray:
        """One PBR quantity: ``"metallic"`` / ``"roughness"`` ``(H, W, D)``, ``"normal"`` ``(H, W, D, 3)`` in [-1, 1]."""
        if not self.has_pbr:
            raise Sin3DMInputError(
                f"grid '{self.name}' has no PBR channels (it was built from a mesh without PBR maps)"
            )
        if name == "normal":
            band = np.abs(self.sdf) < self.threshold
            return np.where(band[..., None], self.color[..., 5:8] * 2 - 1, 0.0).astype(np.float32)
        return self.color[..., PBR_CHANNELS.index(name)]

    def single_color(self, tolerance: float = ONE_COLOUR_TOLERANCE) -> np.ndarray | None:
        """The shape's colour ``(K,)`` if its whole surface has one (a mesh without colour: the default grey, or one
        plain material), else None. Checked on the voxels of the truncation band and the near-surface points."""
        band = np.abs(self.sdf) < self.threshold
        if not band.any():
            return None
        colors = np.concatenate([self.color[band], self.point_color.reshape(-1, self.color.shape[-1])])
        if np.ptp(colors, axis=0).max() > tolerance:
            return None
        return colors.mean(0, dtype=np.float64).astype(np.float32)

    @property
    def voxel_size(self) -> float:
        """Edge length of one (cubic) voxel in normalised units."""
        return float((self.aabb[3] - self.aabb[0]) / self.sdf.shape[0])

    def axis_coords(self, axis: int) -> np.ndarray:
        """Cell-centred voxel coordinates along one axis: ``min + (k + 0.5) / n * size``."""
        return axis_centres(self.aabb, self.shape, axis).astype(np.float32)

    def voxel_centers(self) -> np.ndarray:
        """``(H, W, D, 3)`` coordinates of every voxel centre."""
        return np.stack(np.meshgrid(*(self.axis_coords(a) for a in range(3)), indexing="ij"), axis=-1)

    def to_box(self, points: np.ndarray) -> np.ndarray:
        """Normalised coordinates → box coordinates in [-1, 1] (what triplane lookups take)."""
        return to_box(points, self.aabb, dtype=np.float32)

    def thin_share(self, radius: float = 2) -> float:
        """Share of the solid (voxels with SDF < 0) in parts thinner than the ball of ``radius`` voxels.

        A morphological opening with a ball (the voxel offsets within ``radius`` of its centre) keeps every part the
        ball fits into and removes the rest: columns, slats, small boxes, thin walls. The latent has half the grid's
        resolution, so a part 5 voxels thick is drawn from about two texels.
        """
        from scipy import ndimage

        solid = self.sdf < 0
        if not solid.any():
            return 0.0
        o = np.indices((2 * int(radius) + 1,) * 3) - int(radius)
        ball = (o**2).sum(0) <= radius**2
        kept = ndimage.binary_opening(solid, ball)
        return float((solid & ~kept).sum() / solid.sum())


# --------------------------------------------------------------------------- building
def check_resolution(resolution: int) -> None:
    """The grid resolution against its range, which :data:`config.LIMITS` owns."""
    low, high = LIMITS["grid.resolution"]
    if not isinstance(resolution, (int, np.integer)) or not low <= resolution <= high:
        raise Sin3DMInputError(
            f"grid resolution {resolution!r} is out of range; use a whole number from {low} to {high} "
            "(32-64 for a CPU, 256 as in the paper)"
        )


def _check_coordinates(mesh: TexturedMesh) -> None:
    """Refuse coordinates so large that the bounding box (or the normalisation) overflows."""
    v = np.asarray(mesh.vertices)
    with np.errstate(over="ignore", invalid="ignore"):
        big = float(np.abs(v).max(initial=0.0)) if v.size else 0.0
        lo, hi = v.astype(np.float64).min(0), v.astype(np.float64).max(0)
        extent = hi - lo
    if not np.isfinite(big) or not np.all(np.isfinite(extent)) or big > MAX_COORDINATE:
        raise Sin3DMInputError(
            f"'{mesh.name}' has a vertex coordinate of {big:.3g}, too large for its bounding box (the limit is "
            f"{MAX_COORDINATE:.0e}); remove the stray vertex or scale the mesh down in a mesh editor"
        )


#: longest sides (in the file's units) outside this range get a warning with the normalisation's scale factor
USUAL_SIZE = (1e-3, 1e5)


def normalisation_notes(mesh: TexturedMesh, normalised: TexturedMesh, closed: bool) -> list[str]:
    """One line each for what a user would not expect from the normalisation: a mesh of an unusual size
    (:data:`USUAL_SIZE`: wrong units?) scaled by a large factor, and an open mesh or triangle soup whose
    inside is only approximate (the generalised winding number)."""
    notes = []
    longest = float(np.ptp(np.asarray(mesh.vertices, np.float64), axis=0).max())
    if not USUAL_SIZE[0] <= longest <= USUAL_SIZE[1]:
        factor = normalised.normalization.scale / mesh.normalization.scale
        notes.append(
            f"'{mesh.name}' is {longest:.3g} units long: the normalisation scales it by {factor:.3g} into the "
            "box [-1, 1] (samples are mapped back to the input's size); if the units are wrong, rescale it "
            "in a mesh editor"
        )
    if not closed:
        _, weld = unique_rows(np.asarray(normalised.vertices))
        edges = np.sort(weld[normalised.faces][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        _, counts = np.unique(edges[:, 0] * (int(weld.max()) + 1) + edges[:, 1], return_counts=True)
        alone = float((counts == 1).mean())
        what = (
            "a triangle soup (no two faces share an edge)"
            if alone == 1.0
            else f"not watertight ({alone:.1%} of its edges border a hole)"
            if alone > 0
            else "not a closed surface (edges shared by more than two faces, or faces that cannot all be wound alike)"
        )
        notes.append(
            f"'{mesh.name}' is {what}: inside and outside come from the generalised winding number, which "
            "is approximate near holes; look at the grid's slices (notebook 01) or close the mesh in an "
            "editor if the shape comes out wrong"
        )
    return notes


def mesh_to_grid(
    mesh: TexturedMesh,
    resolution: int = 128,
    threshold_voxels: float = 3.0,
    n_surface_points: int = 500_000,
    near_surface_sigma: float = 0.005,
    seed: int = 0,
    progress: bool = True,
    margin_voxels: float = 0.0,
    pbr: bool | None = None,
) -> ShapeGrid:
    """Turn a textured mesh into the paper's truncated SDF + colour grid.

    1. Normalise (centre, longest side × 1.03 → [-1, 1]) and size the grid:
       ``resolution`` voxels along the longest side, the other axes rounded up
       to multiples of 8, a symmetric box ``±n_axis / n_max``. With
       ``margin_voxels`` the shape keeps at least that many voxels of empty
       space to every face of the box (scaled down a little if 1.03 does not
       leave enough, see :func:`margin_scale`): surfaces in the latent's
       outermost texel, where the triplane lookup is clamped, are misplaced.
    2. Signed distance at every cell-centred voxel, truncated at
       ``threshold_voxels`` voxels: exact distances only where the band may be
       (:func:`~sin3dm_lite.data.tsdf.tsdf_grid`), the sign from the fast
       winding number, so open meshes work too; open sheets and parts thinner
       than a voxel become slabs (:meth:`~sin3dm_lite.data.distance.Distance.find_slabs`).
    3. RGB at every voxel within the band from the closest point on the
       original surface (texture lookup with bilinear filtering).
    4. Training points: surface samples plus Gaussian noise (σ =
       ``near_surface_sigma``), with their exact truncated SDF and colour.

    ``pbr`` (``None``: whenever the mesh has a metallic-roughness or normal
    map) stores the 8 :data:`PBR_CHANNELS` instead of RGB (``TexturedMesh.pbr_at``:
    glTF's metallic and roughness, the world-space normal); ``pbr=True`` on a
    mesh without maps stores its constant factors and its geometric normals.
    """
    check_resolution(resolution)
    say = print if progress else (lambda *a, **k: None)
    t0 = time.perf_counter()
    _check_coordinates(mesh)
    pbr = mesh.has_pbr if pbr is None else bool(pbr)
    m, dims, flat = _normalised(mesh, resolution, margin_voxels)
    aabb = centred_box(dims)
    vs = 2.0 / dims.max()
    threshold = float(threshold_voxels * vs)
    if pbr:
        say(f"[grid] PBR channels: {', '.join(PBR_CHANNELS)}")
    say(f"[grid] '{mesh.name}': {len(m.faces):,} faces → grid {dims[0]}×{dims[1]}×{dims[2]}, band ±{threshold:.4f}")

    dist = Distance(m)
    slabs = dist.find_slabs() if len(m.faces) else Slabs(0.0, 0.0)  # a flat mesh: one slab (its box holds it)
    for message in _surprises(mesh, m, dist, slabs) + _slab_notes(mesh.name, slabs, vs):
        warnings.warn(message, stacklevel=2)
    sdf, color, sure = tsdf_grid(dist, m, dims, aabb, vs, threshold, say, pbr=pbr)
    if not (sdf < 0).any():
        raise Sin3DMInputError(_no_inside(mesh, resolution, flat))
    out = ShapeGrid(sdf, color, aabb, threshold, m.normalization, name=mesh.name)
    say(f"[grid] grid done ({time.perf_counter() - t0:.1f} s)")
    if n_surface_points > 0:
        out.points, out.point_sdf, out.point_color = _training_points(
            dist, m, out, (sure, vs), n_surface_points, near_surface_sigma, seed, pbr
        )
    say(
        f"[grid] done in {time.perf_counter() - t0:.1f} s: {int((np.abs(out.sdf) < threshold).sum()):,} voxels in the band"
    )
    return out


#: a mesh whose surface is this share of open sheets or more is all slabs: the winding number decides nothing
ALL_SHEETS = 0.999


def is_flat(m: TexturedMesh, resolution: int) -> bool:
    """Whether the normalised mesh ``m`` is thinner than a voxel of ``resolution`` along some axis (a floor, a
    field, a decal): an open sheet whose slab (:meth:`Distance.find_slabs`) is all the grid holds."""
    return bool(len(m.vertices)) and bool(flat_axes(np.ptp(m.vertices, axis=0), resolution).any())


def _normalised(mesh: TexturedMesh, resolution: int, margin_voxels: float):
    """The mesh normalised (and shrunk to keep ``margin_voxels`` of empty space), the grid's voxel counts
    (:func:`training_dims`) and whether it is flat (decided before the shrink, as :func:`is_flat` decides); a flat
    sheet lies a quarter voxel off the box's mid-plane, where two rows of voxel centres meet: so its slab holds a row
    of them however few voxels thick it is (one at 32). Each triangle is kept once, as the loader reads a file
    (:func:`~sin3dm_lite.formats.repair.listed_once`): a two-sided mesh's two listings would cancel in the winding
    number."""
    m = listed_once(mesh.normalized())
    extent = np.ptp(m.vertices, axis=0) if len(m.vertices) else np.ones(3)
    flat = flat_axes(extent, resolution)
    shrink, dims = training_dims(extent, resolution, margin_voxels)
    if shrink < 1:
        m = replace(
            m,
            vertices=m.vertices * shrink,
            normalization=replace(m.normalization, scale=m.normalization.scale * shrink),
        )
    if flat.any():
        shift = np.where(flat, 0.5 / dims.max(), 0.0)  # a quarter voxel
        norm = m.normalization
        m = replace(
            m, vertices=m.vertices + shift, normalization=replace(norm, center=norm.center - shift / norm.scale)
        )
    return m, dims, bool(flat.any())


def _no_inside(mesh: TexturedMesh, resolution: int, flat: bool) -> str:
    """The error for a grid with no inside voxel: a flat mesh says its sides, and what to do."""
    if not flat or not len(mesh.vertices):
        return (
            f"'{mesh.name}' has no inside at {resolution} voxels: it encloses no volume; give a closed (watertight) "
            "mesh or a solid with some thickness"
        )
    side = np.ptp(np.asarray(mesh.vertices, np.float64), axis=0)
    sides = " × ".join(f"{x:.3g}" for x in side)
    return (
        f"'{mesh.name}' has no inside at {resolution} voxels: it is flat, {sides}, its thinnest side "
        f"{side.min() / max(side.max(), 1e-300):.2%} of its longest, and the slab a flat mesh becomes covers no voxel "
        "centre (a sliver, or faces narrower than a voxel); give it some width and thickness in an editor"
    )


def _surprises(mesh: TexturedMesh, normalised: TexturedMesh, dist: Distance, slabs: Slabs) -> list[str]:
    """The warnings a grid comes with: faces wound anew, inside-out parts turned round, :func:`normalisation_notes`
    (but where the whole surface is open sheets, whose slabs need no winding number)."""
    notes, turned = [], dist.turned_round
    if turned.faces:
        notes.append(
            f"{turned.faces:,} of the {len(normalised.faces):,} faces of '{mesh.name}' are wound against their "
            "neighbours (they would punch holes into its inside); the grid winds them as their neighbours"
        )
    if turned.parts:
        what = (
            f"'{mesh.name}' is inside out"
            if turned.parts == turned.of_parts == 1
            else f"{turned.parts} of the {turned.of_parts} parts of '{mesh.name}' are inside out"
        )
        notes.append(
            f"{what} (faces wound clockwise seen from outside); the grid turns them the right way round "
            "to tell inside from outside"
        )
    return notes + normalisation_notes(mesh, normalised, dist.closed or slabs.sheets >= ALL_SHEETS)


def _slab_notes(name: str, slabs: Slabs, voxel: float) -> list[str]:
    """The warnings for a mesh with open sheets or thin parts (:meth:`Distance.find_slabs`), if it has any."""
    made = f"slabs 1/{1 / SHEET_HALF:.0f} of the shape's longest side thick ({2 * SHEET_HALF / voxel:.1f} voxels here)"
    notes = []
    if slabs.sheets:
        notes.append(
            f"{max(slabs.sheets, 0.001):.1%} of the surface of '{name}' is open sheets that enclose no volume (a "
            f"ground plane, walls of a single polygon): the grid would lose them, so it makes them {made}; give the "
            "sheets a thickness in an editor to choose it yourself"
        )
    if slabs.thin:
        notes.append(
            f"{max(slabs.thin, 0.001):.1%} of the surface of '{name}' is parts thinner than "
            f"{THIN_DEPTHS[-1] / voxel:.1f} voxels (boards, sheet metal): the voxel centres would miss them, so the "
            f"grid makes them {made}; thicken them in an editor to choose it yourself"
        )
    return notes


def _training_points(
    dist: Distance, m: TexturedMesh, grid: ShapeGrid, sure_and_vs: tuple, n: int, sigma: float, seed: int, pbr: bool
):
    """``n`` points near the surface (surface samples plus Gaussian noise of ``sigma``, clipped to the box) with
    their exact truncated SDF and colour: ``(points, sdf, colour)``; ``sure_and_vs`` from :func:`tsdf_grid`."""
    rng = np.random.default_rng(seed)
    sure, vs = sure_and_vs
    aabb = grid.aabb
    sp, _, _ = m.surface_points(n, rng)
    sp = sp + rng.normal(scale=sigma, size=sp.shape)
    sp = np.clip(sp, aabb[:3], aabb[3:])
    ps, pc = point_tsdf(dist, m, sp, grid.threshold, grid=(grid.sdf, sure, aabb[:3].astype(np.float64), vs), pbr=pbr)
    return sp.astype(np.float32), ps, pc


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
            rotation=np.asarray(grid.normalization.rotation, np.float64),
            points=grid.points,
            point_sdf=grid.point_sdf,
            point_color=grid.point_color,
            name=np.array(grid.name),
        )
    return path


def load_grid(path: str | Path, fix: str | None = None) -> ShapeGrid:
    """Read a grid written by :func:`save_grid`, its declared sizes checked before any array is read and its shapes
    and values after (a bad file: one line naming it and ``fix``, what to do)."""
    from ..files.inputs import check_regular

    path = Path(path)
    check_regular(path, "a grid")
    if not path.is_file():
        raise Sin3DMInputError(
            f"grid file '{path}' not found; create one with `sin3dm-lite grid MESH --out {path.name}`"
        )
    try:
        _check_declared_sizes(path)
        with np.load(path) as z:
            grid = ShapeGrid(
                sdf=z["sdf"],
                color=z["color"],
                aabb=z["aabb"],
                threshold=float(z["threshold"]),
                normalization=Normalization(
                    z["center"], float(z["scale"]), z["rotation"] if "rotation" in z else np.eye(3)
                ),
                points=z["points"],
                point_sdf=z["point_sdf"],
                point_color=z["point_color"],
                name=str(z["name"]),
            )
        why = _grid_problem(grid)
    except _Damaged as e:
        why = str(e)
    except Exception as e:  # noqa: BLE001 - truncated, foreign, pickled objects: one clear message
        why = f"the entry {e} is missing" if isinstance(e, KeyError) else "it is truncated or not a grid file"
    if why is not None:
        raise Sin3DMInputError(
            f"'{path}' was not made by this version of sin3dm-lite ({why}); "
            + (fix or f"write it again with `sin3dm-lite grid MESH --out {path.name}`")
        )
    return grid


class _Damaged(Exception):
    """What is wrong with a grid file, said before its arrays are read."""


#: a grid file's arrays: at most this many voxels along a side (grid.resolution's limit, margins and rounding added)
MAX_GRID_SIDE = 1024


def _check_declared_sizes(path: Path) -> None:
    """The ``.npy`` headers of the grid file ``path``: no array larger than a grid of :data:`MAX_GRID_SIDE` voxels a
    side could be, and all of them together within half the memory available."""
    import zipfile

    from ..app.device import memory_available

    total = 0
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            with zf.open(info) as f:
                version = np.lib.format.read_magic(f)
                read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                shape, _, dtype = read(f)
            n = int(np.prod(shape, dtype=object))
            if n > MAX_GRID_SIDE**3 * 8:  # the largest: the colours of a PBR grid
                raise _Damaged(f"its array '{info.filename}' declares {n:,} values, more than any grid holds")
            total += n * dtype.itemsize
    if total > memory_available("cpu") // 2:
        raise _Damaged(f"its arrays declare {total / 2**30:,.1f} GiB, more than half the memory available")


def _grid_problem(g: ShapeGrid) -> str | None:
    """What is wrong with a grid read from a file (None: nothing): shapes that disagree, values that are not finite,
    a box or truncation out of range."""
    a, n = np.asarray(g.aabb, np.float64), len(g.points)
    if g.sdf.ndim != 3 or g.color.shape[:3] != g.sdf.shape or g.color.ndim != 4 or g.color.shape[3] not in (3, 8):
        return f"its sdf {g.sdf.shape} and color {g.color.shape} are not one grid of 3 or 8 colour channels"
    if max(g.sdf.shape) > MAX_GRID_SIDE or min(g.sdf.shape) < 1:
        return f"its grid {g.sdf.shape} is not from 1 to {MAX_GRID_SIDE} voxels a side"
    if g.points.shape != (n, 3) or g.point_sdf.shape != (n,) or g.point_color.shape != (n, g.color.shape[3]):
        return "its training points, their SDF and their colours do not agree in number"
    if a.shape != (6,) or not np.isfinite(a).all() or not ((a[3:] - a[:3] > 0).all() and np.abs(a).max() <= 1.0001):
        return "its box (aabb) is not six finite numbers of a box inside [-1, 1]"
    if not (np.isfinite(g.threshold) and 0 < g.threshold <= 8):
        return f"its truncation {g.threshold!r} is not a number above 0 and at most 8"
    c, scale = np.asarray(g.normalization.center, np.float64), g.normalization.scale
    if c.shape != (3,) or not np.isfinite(c).all() or not (np.isfinite(scale) and scale > 0):
        return "its normalisation (center, scale) is not finite"
    if not is_rotation(g.normalization.rotation):
        return "its normalisation's rotation is not a 3 × 3 rotation"
    arrays = (g.sdf, g.color, g.points, g.point_sdf, g.point_color)
    if not all(np.issubdtype(x.dtype, np.floating) and np.isfinite(x).all() for x in arrays):
        return "its arrays hold NaN, infinite or non-number values"
    return None

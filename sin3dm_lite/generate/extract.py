"""Triplane → textured mesh: the last stage of the method, one function per step.

The decoder turns a triplane into an implicit shape: for any 3D point it gives
a signed distance (negative inside) and a colour. To get a mesh we

1. decode the SDF on a cell-centred grid (``decode.decode_grid``), coarse to fine:
   exactly near the surface, interpolated where only the sign matters,
2. run marching cubes on it (:func:`marching_cubes`),
3. optionally drop small pieces (:func:`keep_components`),
4. reduce the triangle count (:func:`simplify`),
5. cut the surface into charts and flatten them into a texture atlas
   (:func:`uv_atlas`),
6. bake the decoder's colour into a texture (:mod:`.bake`, its functions
   importable from here too: :func:`bake_texture`, :func:`pad_gutter`,
   :func:`pbr_maps`).

:func:`extract_mesh` runs the whole path and can hand back every intermediate
for a notebook to show. Unlike the original implementation, marching-cubes
vertices are placed on the voxel centres (no half-voxel shift), all
components are kept by default and the gutter is filled several texels wide.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..data.box import as_aabb, to_box
from ..data.mesh import Material, Normalization, TexturedMesh, component_labels, face_areas
from ..errors import Sin3DMInputError
from ..model.decode import PreparedTriplane, decode_grid, prepare, query_points
from ..model.triplane import Triplane
from .bake import bake_texture, pad_gutter, pbr_maps, position_map, rasterize_triangles, uv_to_pixel


class NoSurfaceError(Sin3DMInputError):
    """The decoded SDF never crosses the iso-level, so there is no surface to mesh.

    ``fill`` says what the box holds instead: 0.0 (all outside), 1.0 (all inside) or None (NaN / inf).
    """

    fill: float | None = None


# ----------------------------------------------------------------------------- 2. marching cubes
def marching_cubes(sdf: np.ndarray, aabb, level: float = 0.0, close_boundary: bool = True):
    """Iso-surface of a cell-centred SDF grid → ``(verts (V, 3) float64, faces (F, 3) int64)``.

    Vertices are in normalised coordinates, placed so that grid index ``k``
    lands exactly on voxel centre ``lo + (k + 0.5) / n * size`` (no half-voxel
    shift). Faces wind counter-clockwise seen from outside (normals point out
    of the region where ``sdf < level``).

    ``close_boundary`` pads the grid with a layer that is outside the shape,
    so a shape that touches the box (a retargeted or outpainted sample) is
    closed by a cap on the box face instead of being left open. The padding
    value mirrors the boundary voxel so the cap lies on the box face.
    """
    sdf = np.asarray(sdf, np.float32)
    if sdf.ndim != 3:
        raise Sin3DMInputError(f"sdf must be a 3D grid, got shape {sdf.shape}")
    if not np.all(np.isfinite(sdf)):
        raise NoSurfaceError("the decoded SDF contains NaN or inf; the decoder or triplane is broken")
    if sdf.min() >= level or sdf.max() <= level:
        where = "outside (empty shape)" if sdf.min() >= level else "inside (the shape fills the whole box)"
        err = NoSurfaceError(
            f"no surface: every SDF value is {where} (min {sdf.min():.4g}, max {sdf.max():.4g}, level {level}); "
            "check the triplane (e.g. a sample that diverged) or the iso-level"
        )
        err.fill = 0.0 if sdf.min() >= level else 1.0
        raise err
    from skimage import measure

    box = as_aabb(aabb)
    n = np.array(sdf.shape, np.float64)
    spacing = (box[3:] - box[:3]) / n
    offset = 0.5
    if close_boundary:
        d = sdf - level
        padded = np.pad(d, 1, mode="edge")
        inner = np.zeros(padded.shape, bool)
        inner[1:-1, 1:-1, 1:-1] = True
        # outside with the boundary voxel's magnitude: the zero crossing falls half-way, on the box face
        padded[~inner] = np.abs(padded[~inner]) + 1e-6
        sdf, level, offset = padded, 0.0, -0.5
    verts, faces, _, _ = measure.marching_cubes(sdf, level=level, allow_degenerate=False)
    verts = box[:3] + (verts.astype(np.float64) + offset) * spacing
    return verts, faces.astype(np.int64)


# ----------------------------------------------------------------------------- 3. components
def remove_unused_vertices(verts: np.ndarray, faces: np.ndarray):
    """Drop vertices no face uses and renumber the faces."""
    used = np.zeros(len(verts), bool)
    used[faces.ravel()] = True
    new_index = np.cumsum(used) - 1
    return verts[used], new_index[faces].astype(np.int64)


def keep_components(verts: np.ndarray, faces: np.ndarray, mode: str = "all", min_faces: int = 0):
    """Keep connected pieces of the mesh.

    ``mode="all"`` (default) keeps every piece with at least ``min_faces``
    faces (``min_faces=0`` keeps everything; e.g. 50 drops specks);
    ``mode="largest"`` keeps only the piece with the most faces (what the
    original code always did, which deletes legitimately separate parts).
    """
    if mode not in ("all", "largest"):
        raise Sin3DMInputError(f"components must be 'all' or 'largest', got {mode!r}")
    if mode == "all" and min_faces <= 0:  # keeps everything: no need to label the pieces
        return remove_unused_vertices(verts, faces)
    labels = component_labels(len(verts), faces)
    sizes = np.bincount(labels)
    keep = np.zeros(len(sizes), bool)
    if mode == "largest":
        keep[np.argmax(sizes)] = True
    else:
        keep = sizes >= min_faces
    sel = keep[labels]
    if not sel.any():
        raise NoSurfaceError(
            f"no component has at least {min_faces} faces (largest has {sizes.max()}); lower min_faces"
        )
    return remove_unused_vertices(verts, faces[sel])


# ----------------------------------------------------------------------------- 4. simplification
def simplify(verts: np.ndarray, faces: np.ndarray, target_faces: int | None):
    """Quadric edge-collapse simplification to about ``target_faces`` (skipped when already under budget)."""
    if target_faces is None or len(faces) <= target_faces:
        return verts, faces
    import fast_simplification

    v, f = fast_simplification.simplify(
        np.ascontiguousarray(verts, np.float64), np.ascontiguousarray(faces, np.int32), target_count=int(target_faces)
    )
    return remove_unused_vertices(np.asarray(v, np.float64), np.asarray(f, np.int64))


# ----------------------------------------------------------------------------- 5. UV atlas
#: no UV chart may cover more than this share of the surface (xatlas ``max_chart_area``); see :func:`uv_atlas`
MAX_CHART_SHARE = 1 / 15


def uv_atlas(
    verts: np.ndarray,
    faces: np.ndarray,
    resolution: int = 1024,
    padding: int = 4,
    max_chart_share: float = MAX_CHART_SHARE,
):
    """Cut the mesh into charts and pack them into one square-ish atlas with xatlas.

    Args:
        resolution: the texture size the atlas is packed for (xatlas picks the
            texel density to fill about this many texels per side).
        padding: empty texels between charts (room for the gutter fill, so
            bilinear filtering and mipmaps do not mix neighbouring charts).
        max_chart_share: no chart grows beyond this share of the surface area
            (0: no limit). Growing big charts is most of xatlas's time on
            many-faceted surfaces; a flat region stays one chart whatever its
            size (xatlas makes planar charts first).

    Returns:
        ``vmapping (V',)``: the original vertex of each atlas vertex (seams
        split vertices); ``new_faces (F, 3)`` indexing atlas vertices (face
        ``i`` is still face ``i`` of the input); ``uvs (V', 2)`` in [0, 1]
        (OpenGL convention: v goes up). Simplify first: xatlas is slow above
        about 100k faces.
    """
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(np.ascontiguousarray(verts, np.float32), np.ascontiguousarray(faces, np.uint32))
    pack = xatlas.PackOptions()
    pack.resolution = int(resolution)
    pack.padding = int(padding)
    pack.bilinear = True
    chart = xatlas.ChartOptions()
    if max_chart_share > 0:
        chart.max_chart_area = float(face_areas(verts, faces).sum() * max_chart_share)
    atlas.generate(chart, pack)
    if atlas.atlas_count > 1:  # charts did not fit one page: repack at the density found, on one page
        pack.texels_per_unit = atlas.texels_per_unit
        pack.resolution = 0
        atlas.generate(chart, pack)
    vmapping, new_faces, uvs = atlas[0]
    return vmapping.astype(np.int64), new_faces.astype(np.int64), uvs.astype(np.float32)


# ----------------------------------------------------------------------------- the whole path
def extract_mesh(
    decoder,
    triplane: Triplane,
    aabb,
    normalization: Normalization | None = None,
    resolution: int = 128,
    faces: int | None = 30_000,
    texture_size: int = 1024,
    components: str = "all",
    min_component_faces: int = 0,
    vertex_colors: bool = False,
    original_coords: bool = True,
    chunk: int | None = None,
    coarse: int | None = 4,
    return_steps: bool = False,
):
    """Decode a batch-1 triplane into a textured mesh.

    SDF grid (``resolution`` along the longest side of ``aabb``) → marching
    cubes → components → simplification to ``faces`` → xatlas UVs → texture
    of ``texture_size``² baked from the decoder → gutter filled.

    Args:
        aabb: the box the triplane covers, in normalised coordinates (for a
            retargeted sample, the correspondingly scaled box).
        normalization: the input mesh's ``Normalization``; with
            ``original_coords`` the vertices are mapped back into the input
            file's coordinates (the result's ``normalization`` is then the
            identity, as for a freshly loaded mesh; otherwise it is this one,
            so ``mesh.normalization.to_original`` still works).
        faces: face budget after simplification (``None``: no simplification).
        components / min_component_faces: see :func:`keep_components`.
        vertex_colors: skip the atlas and store per-vertex colours (quick look).
        coarse: coarse-to-fine SDF decode (see :func:`decode_grid`; ``None``
            decodes every voxel, same mesh, slower).
        return_steps: also return a dict of intermediates: ``sdf``, ``raw``
            (verts, faces), ``simplified`` (verts, faces), ``uv`` (uvs, faces),
            ``vmapping``, ``baked`` (before :func:`pad_gutter`), ``texture``,
            ``covered`` (texture path only), ``seconds`` (time per step),
            ``decode_stats`` (see :func:`decode_grid`) and ``normalization``.
    Returns:
        ``TexturedMesh`` (or ``(TexturedMesh, steps)``).
    """
    box = as_aabb(aabb)
    steps: dict[str, Any] = {}
    lap = _Stopwatch()
    prepared = prepare(decoder, triplane)
    lap("prepare")
    v, f = _surface(
        decoder, prepared, box, resolution, chunk, coarse, (components, min_component_faces), faces, steps, lap
    )
    if vertex_colors:
        mesh = _vertex_coloured_mesh(decoder, prepared, box, v, f, chunk)
        lap("vertex_colors")
    else:
        mesh = _baked_mesh(decoder, prepared, box, v, f, texture_size, chunk, steps, lap)
    norm = _place(mesh, normalization, original_coords)
    mesh.name = "sample"
    steps.update(seconds=lap.seconds, normalization=norm)
    return (mesh, steps) if return_steps else mesh


class _Stopwatch:
    """``lap(name)``: the seconds since the last lap (or since it was made), kept under ``name`` in ``seconds``."""

    def __init__(self):
        self.seconds: dict[str, float] = {}
        self.t = time.perf_counter()

    def __call__(self, name: str) -> None:
        now = time.perf_counter()
        self.seconds[name] = now - self.t
        self.t = now


def _surface(
    decoder,
    prepared: PreparedTriplane,
    box: np.ndarray,
    resolution: int,
    chunk: int | None,
    coarse: int | None,
    components: tuple[str, int],
    faces: int | None,
    steps: dict,
    lap: _Stopwatch,
):
    """Steps 1-4: the SDF grid, marching cubes, the components kept (mode, least faces), simplified → ``(v, f)``."""
    decode_stats: dict[str, Any] = {}
    # exact_band=0: only the voxels marching cubes reads are decoded exactly (the same mesh, fewer points)
    sdf = decode_grid(
        decoder, prepared, box, resolution, chunk=chunk, coarse=coarse, exact_band=0.0, stats=decode_stats
    )
    lap("decode_grid")
    steps["decode_stats"] = decode_stats
    v, f = marching_cubes(sdf, box)
    lap("marching_cubes")
    steps.update(sdf=sdf, raw=(v, f))
    v, f = keep_components(v, f, mode=components[0], min_faces=components[1])
    lap("keep_components")
    v, f = simplify(v, f, faces)
    lap("simplify")
    steps["simplified"] = (v, f)
    return v, f


def _place(mesh: TexturedMesh, normalization: Normalization | None, original_coords: bool) -> Normalization:
    """Map the mesh back into the input file's coordinates (``original_coords``) or record the normalisation it is
    in; returns that normalisation (the identity without one)."""
    norm = normalization if normalization is not None else Normalization.identity()
    if original_coords and normalization is not None:
        mesh.vertices = norm.to_original(mesh.vertices)
        mesh.normalization = Normalization.identity()
    else:
        mesh.normalization = norm
    return norm


def _vertex_coloured_mesh(
    decoder, prepared: PreparedTriplane, box: np.ndarray, v, f, chunk: int | None
) -> TexturedMesh:
    """The quick look: the decoder's colour at each vertex, no atlas."""
    _, col = query_points(decoder, prepared, to_box(v, box), chunk=chunk, sdf=False)
    material = Material(name="vertex_colors", base_color=np.ones(4, np.float32))
    return TexturedMesh(
        v, f, np.zeros(len(f), np.int64), [material], vertex_colors=np.clip(col[:, :3], 0, 1).astype(np.float32)
    )


def _baked_mesh(
    decoder,
    prepared: PreparedTriplane,
    box: np.ndarray,
    v,
    f,
    texture_size: int,
    chunk: int | None,
    steps: dict,
    lap: _Stopwatch,
) -> TexturedMesh:
    """xatlas UVs → texture baked from the decoder → gutter filled (→ PBR maps for a PBR decoder)."""
    vmapping, faces_uv, uvs = uv_atlas(v, f, resolution=texture_size)
    lap("uv_atlas")
    image, covered = bake_texture(decoder, prepared, box, v[vmapping], faces_uv, uvs, texture_size, chunk=chunk)
    lap("bake_texture")
    texture = pad_gutter(image[..., :3], covered)
    lap("pad_gutter")
    steps.update(uv=(uvs, faces_uv), vmapping=vmapping, baked=image, texture=texture, covered=covered)
    material = Material(name="baked", base_color=np.ones(4, np.float32), image=texture)
    if image.shape[-1] == 8:  # a PBR decoder: metallic-roughness and normal maps over the same atlas
        material.metallic = material.roughness = 1.0  # glTF factors that multiply the maps
        material.metallic_roughness_image, material.normal_image = pbr_maps(
            image, covered, v[vmapping], faces_uv, uvs, texture_size
        )
        lap("pbr_maps")
        steps.update(metallic_roughness=material.metallic_roughness_image, normal=material.normal_image)
    # keep the welded vertices (watertight); the seams live in the per-corner UVs
    return TexturedMesh(v, f, np.zeros(len(f), np.int64), [material], face_uvs=uvs[faces_uv])


__all__ = [
    "NoSurfaceError",
    "bake_texture",
    "component_labels",
    "extract_mesh",
    "keep_components",
    "marching_cubes",
    "pad_gutter",
    "pbr_maps",
    "position_map",
    "rasterize_triangles",
    "remove_unused_vertices",
    "simplify",
    "uv_atlas",
    "uv_to_pixel",
]

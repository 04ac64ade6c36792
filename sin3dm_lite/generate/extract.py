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
6. bake a texture: every texel covered by a triangle in UV space gets the
   decoder's colour at its 3D point (:func:`bake_texture`), and the gutter
   around the UV islands is filled so seams do not show (:func:`pad_gutter`);
   a PBR decoder's metallic, roughness and normals go into their own maps over
   the same atlas (:func:`pbr_maps`).

:func:`extract_mesh` runs the whole path and can hand back every intermediate
for a notebook to show.

The decoder protocol (see ``autoencoder.py``)::

    prepared = decoder.prepare(triplane)          # per-plane 2D conv blocks, once per triplane
    sdf, color = decoder.query(prepared, points)  # points [B, N, 3] in box coordinates [-1, 1]^3

Two flaws of the original implementation are avoided on purpose (docs/paper-notes.md,
"Decoding to a textured mesh"): the 2D conv blocks run once per triplane, not
once per chunk of query points, and marching-cubes vertices are placed on the
voxel centres (no half-voxel shift). All components are kept by default and the
gutter is filled several texels wide.

Coordinates: *normalised* coordinates are the frame the input mesh was scaled
into (``Normalization``); *box* coordinates map the ``aabb``
``(xmin, ymin, zmin, xmax, ymax, zmax)`` to ``[-1, 1]^3``.
"""
from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..data.box import as_aabb, to_box
from ..data.mesh import Material, Normalization, TexturedMesh, component_labels, face_areas, tangent_frames
from ..errors import Sin3DMInputError
from ..model.decode import PreparedTriplane, decode_grid, prepare, query_points
from ..model.triplane import Triplane


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
MAX_CHART_SHARE = 1 / 7


def uv_atlas(verts: np.ndarray, faces: np.ndarray, resolution: int = 1024, padding: int = 4,
             max_chart_share: float = MAX_CHART_SHARE):
    """Cut the mesh into charts and pack them into one square-ish atlas with xatlas.

    Args:
        resolution: the texture size the atlas is packed for (xatlas picks the
            texel density to fill about this many texels per side).
        padding: empty texels between charts (room for the gutter fill, so
            bilinear filtering and mipmaps do not mix neighbouring charts).
        max_chart_share: no chart grows beyond this share of the surface area
            (0: no limit). xatlas grows charts without a limit by default, and
            on bricky, many-faceted surfaces that takes long: charting a
            20,000-face sample of the wall took 9-11 s without a cap, of the
            tiles 16 s; with 1/7 3.7 and 5.4 s, the atlas as full (0.84-0.86 used).
            Smooth shapes barely change (canyon 2.4 → 2.1 s, colonnade 2.8 s).
            A flat region stays one chart whatever its size (xatlas makes
            planar charts first).

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


# ----------------------------------------------------------------------------- 6. texture baking
def rasterize_triangles(tri: np.ndarray, width: int, height: int, eps: float = 1e-9,
                        max_candidates: int = 2_000_000):
    """Find the pixel centres inside 2D triangles, vectorised over triangles.

    Pixel ``(x, y)`` has its centre at the integer point ``(x, y)``. Each
    triangle's bounding box is expanded into candidate pixels (in batches of
    about ``max_candidates``), then an edge test with barycentric
    coordinates keeps the ones inside (``eps`` tolerance so that centres on a
    shared edge are not lost).

    Args:
        tri: ``(F, 3, 2)`` triangle corners in pixel units.
    Returns:
        ``face (n,)``, ``x (n,)``, ``y (n,)`` int64 and ``bary (n, 3)`` float64.
        A pixel on an edge shared by two triangles may appear twice.
    """
    tri = np.asarray(tri, np.float64)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = b - a, c - a
    den = ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0]
    lo = np.maximum(np.ceil(tri.min(1) - eps), 0).astype(np.int64)
    hi = np.minimum(np.floor(tri.max(1) + eps), [width - 1, height - 1]).astype(np.int64)
    w = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0)
    h = np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    count = np.where(np.abs(den) > 1e-12, w * h, 0)
    valid = np.nonzero(count)[0]
    out = ([], [], [], [])
    csum = np.cumsum(count[valid])
    starts = np.searchsorted(csum, np.arange(0, csum[-1] if len(csum) else 0, max_candidates), side="right")
    bounds = list(starts) + [len(valid)]
    for s, e in zip(bounds[:-1], bounds[1:]):
        if e <= s:
            continue
        fid = valid[s:e]
        n = count[fid]
        f = np.repeat(fid, n)
        local = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        x = lo[f, 0] + local % w[f]
        y = lo[f, 1] + local // w[f]
        px, py = x - a[f, 0], y - a[f, 1]
        l1 = (px * ac[f, 1] - py * ac[f, 0]) / den[f]
        l2 = (ab[f, 0] * py - ab[f, 1] * px) / den[f]
        l0 = 1 - l1 - l2
        inside = (l0 >= -eps) & (l1 >= -eps) & (l2 >= -eps)
        out[0].append(f[inside])
        out[1].append(x[inside])
        out[2].append(y[inside])
        out[3].append(np.stack([l0[inside], l1[inside], l2[inside]], axis=1))
    if not out[0]:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    return tuple(np.concatenate(o) for o in out)  # type: ignore[return-value]


def uv_to_pixel(uvs: np.ndarray, size: int) -> np.ndarray:
    """UV in [0, 1] (v up) → pixel coordinates with texel centres at integers (row 0 is v = 1)."""
    uvs = np.asarray(uvs, np.float64)
    return np.stack([uvs[:, 0] * size - 0.5, (1 - uvs[:, 1]) * size - 0.5], axis=1)


def position_map(verts: np.ndarray, faces_uv: np.ndarray, uvs: np.ndarray, size: int, return_faces: bool = False):
    """Rasterise the UV layout: the 3D point behind every covered texel.

    Returns ``positions (size, size, 3)`` float32 (0 where uncovered) and
    ``covered (size, size)`` bool; with ``return_faces`` also ``face (size, size)``
    int64, the face behind each texel (-1 where uncovered).
    """
    verts = np.asarray(verts, np.float64)
    if len(verts) != len(uvs):
        raise Sin3DMInputError(
            f"verts ({len(verts)}) must be indexed like uvs ({len(uvs)}): pass verts[vmapping] from uv_atlas"
        )
    tri = uv_to_pixel(uvs, size)[faces_uv]
    f, x, y, bary = rasterize_triangles(tri, size, size)
    positions = np.zeros((size, size, 3), np.float32)
    covered = np.zeros((size, size), bool)
    positions[y, x] = np.einsum("nk,nkd->nd", bary, verts[faces_uv[f]])
    covered[y, x] = True
    if return_faces:
        face = np.full((size, size), -1, np.int64)
        face[y, x] = f
        return positions, covered, face
    return positions, covered


def bake_texture(decoder, triplane: Triplane | PreparedTriplane, aabb, verts: np.ndarray, faces_uv: np.ndarray,
                 uvs: np.ndarray, size: int, chunk: int = 2**16):
    """Bake the decoder's colour into a texture image.

    Every texel covered by a triangle in UV space is mapped to its 3D point by
    barycentric interpolation (:func:`position_map`), and that point's colour
    is decoded (in chunks).

    Args:
        verts: ``(V', 3)`` normalised positions indexed like ``uvs``, i.e.
            ``verts[vmapping]`` with ``vmapping`` from :func:`uv_atlas`.
        faces_uv: ``(F, 3)`` faces indexing ``verts`` and ``uvs``.
        size: texture width = height in texels.
    Returns:
        ``image (size, size, K)`` float32 in [0, 1] (0 where uncovered; fill
        with :func:`pad_gutter`) and ``covered (size, size)`` bool.
    """
    prepared = prepare(decoder, triplane)
    positions, covered = position_map(verts, faces_uv, uvs, size)
    _, color = query_points(decoder, prepared, to_box(positions[covered], aabb), chunk=chunk, sdf=False)
    image = np.zeros((size, size, color.shape[-1]), np.float32)
    image[covered] = np.clip(color, 0.0, 1.0)
    return image, covered


def pbr_maps(baked: np.ndarray, covered: np.ndarray, verts: np.ndarray, faces_uv: np.ndarray, uvs: np.ndarray,
             size: int) -> tuple[np.ndarray, np.ndarray]:
    """A PBR bake's channels 3-7 → glTF's ``metallic_roughness`` and tangent-space ``normal`` images.

    ``baked`` is :func:`bake_texture`'s ``(size, size, 8)`` image in
    ``grid.PBR_CHANNELS`` order. Metallic goes to B, roughness to G (R = 1,
    glTF leaves it to occlusion). The decoded normal is in world space; a
    normal map stores it in each face's tangent frame, so texel by texel it is
    written as ``(n·T, n·B, n·N)`` with the frame of the face behind the texel
    (:func:`mesh_io.tangent_frames` of the new atlas, the convention the grid
    read the input's map with), kept in the upper half (z ≥ 0.05, a normal
    pointing into the surface would shade black), then encoded ``· ½ + ½``.
    Gutters are filled with :func:`pad_gutter`.
    """
    _, _, face = position_map(verts, faces_uv, uvs, size, return_faces=True)
    mr = np.ones((size, size, 3), np.float32)
    mr[..., 1], mr[..., 2] = baked[..., 4], baked[..., 3]
    t, b, n = tangent_frames(verts, faces_uv, uvs[faces_uv])
    inside = covered & (face >= 0)
    f = face[inside]
    w = baked[inside][:, 5:8].astype(np.float64) * 2 - 1
    tn = np.stack([np.einsum("ij,ij->i", w, t[f]), np.einsum("ij,ij->i", w, b[f]), np.einsum("ij,ij->i", w, n[f])], 1)
    tn[:, 2] = np.maximum(tn[:, 2], 0.05)
    tn /= np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-12)
    normal = np.tile(np.float32([0.5, 0.5, 1.0]), (size, size, 1))
    normal[inside] = (tn * 0.5 + 0.5).astype(np.float32)
    return pad_gutter(mr, inside), pad_gutter(normal, inside)


def pad_gutter(image: np.ndarray, covered: np.ndarray, pixels: int | None = 8) -> np.ndarray:
    """Fill uncovered texels near UV islands with the colour of the nearest covered texel.

    Texels up to ``pixels`` away from an island copy their nearest covered
    texel (one Euclidean distance transform finds it for all texels at once);
    ``pixels=None`` fills the whole image that way. Texels further away get
    the mean colour, so mipmapped lookups do not pull in black.
    """
    from scipy import ndimage

    image = np.array(image, np.float32, copy=True)
    if not covered.any():
        image[:] = 0.5
        return image
    dist, (iy, ix) = ndimage.distance_transform_edt(~covered, return_indices=True)
    near = ~covered if pixels is None else (~covered) & (dist <= pixels)
    image[near] = image[iy[near], ix[near]]
    far = ~covered & ~near
    image[far] = image[covered].mean(axis=0)
    return image


# ----------------------------------------------------------------------------- the whole path
def extract_mesh(decoder, triplane: Triplane, aabb, normalization: Normalization | None = None,
                 resolution: int = 128, faces: int | None = 30_000, texture_size: int = 1024,
                 components: str = "all", min_component_faces: int = 0, vertex_colors: bool = False,
                 original_coords: bool = True, chunk: int = 2**16, coarse: int | None = 4,
                 return_steps: bool = False):
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
            ``vmapping``, ``baked`` (the texture before :func:`pad_gutter`), ``texture``,
            ``covered`` (texture path only),
            ``seconds`` (time per step), ``decode_stats`` (points decoded, see
            :func:`decode_grid`) and ``normalization``.
    Returns:
        ``TexturedMesh`` (or ``(TexturedMesh, steps)``).
    """
    box = as_aabb(aabb)
    seconds: dict[str, float] = {}
    steps: dict[str, Any] = {}
    t = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal t
        now = time.perf_counter()
        seconds[name] = now - t
        t = now

    prepared = prepare(decoder, triplane)
    lap("prepare")
    decode_stats: dict[str, Any] = {}
    sdf = decode_grid(decoder, prepared, box, resolution, chunk=chunk, coarse=coarse, stats=decode_stats)
    lap("decode_grid")
    steps["decode_stats"] = decode_stats
    v, f = marching_cubes(sdf, box)
    lap("marching_cubes")
    steps.update(sdf=sdf, raw=(v, f))
    v, f = keep_components(v, f, mode=components, min_faces=min_component_faces)
    lap("keep_components")
    v, f = simplify(v, f, faces)
    lap("simplify")
    steps["simplified"] = (v, f)

    if vertex_colors:
        mesh = _vertex_coloured_mesh(decoder, prepared, box, v, f, chunk)
        lap("vertex_colors")
    else:
        mesh = _baked_mesh(decoder, prepared, box, v, f, texture_size, chunk, steps, lap)

    norm = normalization if normalization is not None else Normalization.identity()
    if original_coords and normalization is not None:
        mesh.vertices = norm.to_original(mesh.vertices)
        mesh.normalization = Normalization.identity()
    else:
        mesh.normalization = norm
    mesh.name = "sample"
    steps.update(seconds=seconds, normalization=norm)
    return (mesh, steps) if return_steps else mesh


def _vertex_coloured_mesh(decoder, prepared: PreparedTriplane, box: np.ndarray, v, f, chunk: int) -> TexturedMesh:
    """The quick look: the decoder's colour at each vertex, no atlas."""
    _, col = query_points(decoder, prepared, to_box(v, box), chunk=chunk, sdf=False)
    material = Material(name="vertex_colors", base_color=np.ones(4, np.float32))
    return TexturedMesh(v, f, np.zeros(len(f), np.int64), [material],
                        vertex_colors=np.clip(col[:, :3], 0, 1).astype(np.float32))


def _baked_mesh(decoder, prepared: PreparedTriplane, box: np.ndarray, v, f, texture_size: int, chunk: int,
                steps: dict, lap) -> TexturedMesh:
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
        material.metallic_roughness_image, material.normal_image = pbr_maps(image, covered, v[vmapping], faces_uv,
                                                                             uvs, texture_size)
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

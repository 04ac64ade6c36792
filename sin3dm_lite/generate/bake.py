"""Texture baking, step 6 of ``extract``: the decoder's colour (and PBR values) painted into a UV atlas.

Every texel covered by a triangle in UV space gets the decoder's colour at its
3D point (:func:`bake_texture`), and the gutter around the UV islands is
filled so seams do not show (:func:`pad_gutter`); a PBR decoder's metallic,
roughness and normals go into their own maps (:func:`pbr_maps`).
"""

from __future__ import annotations

import numpy as np

from ..data.box import to_box
from ..data.mesh import tangent_frames
from ..errors import Sin3DMInputError
from ..model.decode import PreparedTriplane, prepare, query_points
from ..model.triplane import Triplane


def rasterize_triangles(tri: np.ndarray, width: int, height: int, eps: float = 1e-9, max_candidates: int = 2_000_000):
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


def bake_texture(
    decoder,
    triplane: Triplane | PreparedTriplane,
    aabb,
    verts: np.ndarray,
    faces_uv: np.ndarray,
    uvs: np.ndarray,
    size: int,
    chunk: int | None = None,
):
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


def pbr_maps(
    baked: np.ndarray, covered: np.ndarray, verts: np.ndarray, faces_uv: np.ndarray, uvs: np.ndarray, size: int
) -> tuple[np.ndarray, np.ndarray]:
    """A PBR bake's channels 3-7 → glTF's ``metallic_roughness`` and tangent-space ``normal`` images.

    ``baked`` is :func:`bake_texture`'s ``(size, size, 8)`` image in
    ``grid.PBR_CHANNELS`` order. Metallic goes to B, roughness to G (R = 1,
    glTF leaves it to occlusion). The decoded normal is in world space; a
    normal map stores it in each face's tangent frame, so texel by texel it is
    written as ``(n·T, n·B, n·N)`` with the frame of the face behind the texel
    (``data.mesh.tangent_frames`` of the new atlas), kept in the upper half
    (z ≥ 0.05: a normal pointing into the surface would shade black), then
    encoded ``· ½ + ½``. Gutters are filled with :func:`pad_gutter`.
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


__all__ = ["bake_texture", "pad_gutter", "pbr_maps", "position_map", "rasterize_triangles", "uv_to_pixel"]

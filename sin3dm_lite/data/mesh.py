"""The textured mesh every stage shares, and what can be asked of its surface.

Sin3DM learns from *one* textured shape. Whatever the file format
(:mod:`sin3dm_lite.formats`), it becomes a :class:`TexturedMesh`: triangle
geometry plus everything needed to ask "what colour is the surface at this
point?" (per-face UVs into one or more material textures, vertex colours, or a
plain material colour), the materials kept separate so nothing is lost.

The paper normalises every input the same way: centre the bounding box, scale
so that the longest side times 1.03 spans [-1, 1]. :class:`Normalization`
keeps that transform so generated shapes can be mapped back into the input's
own coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import Sin3DMInputError

#: Colour used for a mesh that has no texture, vertex colour or material colour.
DEFAULT_COLOR = np.array([0.7, 0.7, 0.7], dtype=np.float32)

#: The paper's margin: the longest side times this factor maps to [-1, 1].
BOX_MARGIN = 1.03

# the largest vertex coordinate accepted: beyond it the bounding box or the triangle areas overflow, or
# the rest of the mesh shrinks below float32 precision once normalised
MAX_COORDINATE = 1e15

#: the rotation that turns a mesh modelled with each axis up so that it stands on +y, as OBJ and glTF have it and
#: the pictures draw it (a rotation, not a mirror: faces keep their winding); Z-up is Blender's and most CAD's
UP_TURNS = {
    "y": np.eye(3),
    "z": np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], np.float64),  # (x, y, z) → (x, z, −y)
    "x": np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], np.float64),  # (x, y, z) → (−y, x, z)
}


def default_rgba() -> np.ndarray:
    """:data:`DEFAULT_COLOR` as an RGBA factor: the colour of a surface that has none."""
    return np.array([*DEFAULT_COLOR, 1.0], np.float32)


@dataclass
class Material:
    """One surface material.

    ``base_color`` is the RGBA factor in [0, 1] (the MTL ``Kd`` or glTF
    ``baseColorFactor``); ``image`` is an optional ``(h, w, 3)`` float32 texture
    in [0, 1] that is multiplied by the factor. The PBR fields are kept for the
    PBR variant: scalar factors plus optional ``(h, w, 3)`` images
    (glTF metallic-roughness: roughness in G, metallic in B; tangent-space
    normal map in RGB).
    """

    name: str = "default"
    base_color: np.ndarray = field(default_factory=lambda: np.ones(4, np.float32))
    image: np.ndarray | None = None
    metallic: float = 0.0
    roughness: float = 1.0
    metallic_roughness_image: np.ndarray | None = None
    normal_image: np.ndarray | None = None


@dataclass
class Normalization:
    """Similarity transform ``normalized = (original · rotationᵀ − center) · scale``: a turn about the up axis
    (the identity unless a fit turned the shape's walls along x and z: :meth:`TexturedMesh.turned_about_y`), then
    the paper's centring and scaling; :meth:`to_original` undoes all three."""

    center: np.ndarray  # (3,), in the turned frame
    scale: float
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3), repr=False)  # (3, 3), a turn (determinant +1)

    def to_normalized(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, dtype=np.float64) @ self.rotation.T - self.center) * self.scale

    def to_original(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, dtype=np.float64) / self.scale + self.center) @ self.rotation

    def box_to_original(self, box: np.ndarray) -> np.ndarray:
        """The ``(2, 3)`` box (min and max corner) in original coordinates around the normalised box ``box``."""
        lo, hi = np.asarray(box, np.float64).reshape(2, 3)
        corners = self.to_original(np.stack(np.meshgrid(*zip(lo, hi), indexing="ij"), -1).reshape(-1, 3))
        return np.stack([corners.min(0), corners.max(0)])

    @classmethod
    def identity(cls) -> Normalization:
        return cls(center=np.zeros(3), scale=1.0)


@dataclass
class TexturedMesh:
    """Triangles plus a colour source, in one coordinate frame.

    Attributes:
        vertices: ``(V, 3)`` float64 positions.
        faces: ``(F, 3)`` int64 vertex indices.
        face_material: ``(F,)`` int64 index into ``materials``.
        face_uvs: ``(F, 3, 2)`` float32 UV per face corner, or ``None``; rows of
            faces whose material has no texture may hold NaN.
        vertex_colors: ``(V, 3)`` float32 in [0, 1], or ``None``. Used for faces
            whose material has no image.
        materials: at least one :class:`Material`.
        normalization: the transform that was applied to reach these vertices
            from the file's coordinates (identity for a freshly loaded mesh).
        name: a label for plots and file names.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_material: np.ndarray
    materials: list[Material]
    face_uvs: np.ndarray | None = None
    vertex_colors: np.ndarray | None = None
    normalization: Normalization = field(default_factory=Normalization.identity)
    name: str = "mesh"

    # ------------------------------------------------------------------ queries
    @property
    def bounds(self) -> np.ndarray:
        """``(2, 3)`` min and max corner."""
        return np.stack([self.vertices.min(0), self.vertices.max(0)])

    @property
    def has_texture(self) -> bool:
        return self.face_uvs is not None and any(m.image is not None for m in self.materials)

    @property
    def has_pbr(self) -> bool:
        """True when a material has a metallic-roughness or normal *map* (factors alone do not count)."""
        return self.face_uvs is not None and any(
            m.metallic_roughness_image is not None or m.normal_image is not None for m in self.materials
        )

    def _material_groups(self, face_index: np.ndarray, barycentric: np.ndarray):
        """Yields ``(material, rows, uv)`` for every material some surface point lies on: ``rows`` index the
        points, ``uv`` ``(n, 2)`` is their interpolated texture coordinate (``None``: no UVs or no map)."""
        mat_of = self.face_material[face_index]
        for mi, mat in enumerate(self.materials):
            sel = np.nonzero(mat_of == mi)[0]
            if len(sel) == 0:
                continue
            uv = None
            if self.face_uvs is not None and any(
                m is not None for m in (mat.image, mat.metallic_roughness_image, mat.normal_image)
            ):
                uv = np.einsum("nk,nkd->nd", barycentric[sel], self.face_uvs[face_index[sel]].astype(np.float64))
            yield mat, sel, uv

    def pbr_at(self, face_index: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        """Metallic, roughness and the world-space unit normal at surface points: ``(n, 5)`` float32.

        glTF's rules: the material's ``metallic`` / ``roughness`` factors times
        the map's B / G channel where there is a map. The normal is the
        face's geometric normal, bent by the tangent-space normal map where
        there is one: ``n = x·T + y·B + z·N`` with ``(x, y, z) = 2·texel − 1``
        and the face's tangent frame from :func:`tangent_frames`.
        """
        face_index = np.asarray(face_index, dtype=np.int64)
        bc = np.asarray(barycentric, dtype=np.float64)
        out = np.empty((len(face_index), 5), dtype=np.float32)
        t, b, n = tangent_frames(
            self.vertices, self.faces[face_index], None if self.face_uvs is None else self.face_uvs[face_index]
        )
        for mat, sel, uv in self._material_groups(face_index, bc):
            out[sel, 0], out[sel, 1] = mat.metallic, mat.roughness
            normal = n[sel]
            if uv is not None and mat.metallic_roughness_image is not None:
                mr = sample_texture(mat.metallic_roughness_image, uv)
                out[sel, 0] *= mr[:, 2]
                out[sel, 1] *= mr[:, 1]
            if uv is not None and mat.normal_image is not None:
                tn = sample_texture(mat.normal_image, uv)[:, :3].astype(np.float64) * 2 - 1
                normal = tn[:, :1] * t[sel] + tn[:, 1:2] * b[sel] + tn[:, 2:3] * n[sel]
                normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
            out[sel, 2:] = normal
        out[:, :2] = np.clip(out[:, :2], 0.0, 1.0)
        return out

    def colors_at(self, face_index: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        """Surface RGB in [0, 1] at points given by face index and barycentric coordinates.

        Textures are sampled with bilinear filtering and wrap-around UVs (as a
        renderer would); vertex colours are interpolated; otherwise the
        material colour is used.
        """
        face_index = np.asarray(face_index, dtype=np.int64)
        bc = np.asarray(barycentric, dtype=np.float64)
        out = np.empty((len(face_index), 3), dtype=np.float32)
        for mat, sel, uv in self._material_groups(face_index, bc):
            factor = np.asarray(mat.base_color, np.float32)[:3]
            if mat.image is not None and uv is not None:
                out[sel] = sample_texture(mat.image, uv) * factor
            elif self.vertex_colors is not None:
                corners = self.vertex_colors[self.faces[face_index[sel]]]  # (n, 3, 3)
                out[sel] = np.einsum("nk,nkc->nc", bc[sel], corners) * factor
            else:
                out[sel] = factor
        return np.clip(out, 0.0, 1.0)

    def surface_points(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Area-uniform surface samples: ``(points (n,3), face_index (n,), barycentric (n,3))``."""
        tri = self.vertices[self.faces]
        area = face_areas(self.vertices, self.faces)
        total = area.sum()
        if not np.isfinite(total) or total <= 0:
            raise Sin3DMInputError(
                f"mesh '{self.name}' has zero surface area; give a mesh with non-degenerate triangles"
            )
        fi = rng.choice(len(self.faces), size=n, p=area / total)
        r1, r2 = rng.random(n), rng.random(n)
        s = np.sqrt(r1)
        bc = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
        pts = np.einsum("nk,nkd->nd", bc, tri[fi])
        return pts, fi, bc

    # -------------------------------------------------------------- transforms
    def turned_upright(self, up: str = "y") -> TexturedMesh:
        """The mesh turned so that its ``up`` axis (``"z"`` for a Z-up model) points along +y (:data:`UP_TURNS`): the
        frame a fit with ``grid.up`` learns in and writes its samples in. ``"y"`` returns the mesh itself."""
        if up not in UP_TURNS:
            raise Sin3DMInputError(f"up must be one of {', '.join(UP_TURNS)}, not {up!r}")
        if up == "y":
            return self
        return replace(self, vertices=np.asarray(self.vertices, np.float64) @ UP_TURNS[up].T)

    def turned_about_y(self, degrees: float) -> TexturedMesh:
        """The mesh turned by ``degrees`` about the up (y) axis, the turn kept in its ``normalization`` so that
        generated shapes are turned back into the input's frame (a fit's ``grid.turn``). ``0`` returns the mesh."""
        if degrees == 0:
            return self
        c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
        r = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # x towards −z for a positive turn
        n = self.normalization
        turned = Normalization(center=n.center @ r.T, scale=n.scale, rotation=r @ n.rotation)
        return replace(self, vertices=np.asarray(self.vertices, np.float64) @ r.T, normalization=turned)

    def normalized(self) -> TexturedMesh:
        """The paper's normalisation: centre the bounding box, longest side × 1.03 → [-1, 1]."""
        lo, hi = self.bounds
        extent = hi - lo
        if not np.all(np.isfinite(extent)) or extent.max() <= 0:
            raise Sin3DMInputError(
                f"mesh '{self.name}' has a zero-size bounding box; it needs faces that span some volume"
            )
        center = (lo + hi) / 2
        scale = 2.0 / (extent.max() * BOX_MARGIN)
        n = self.normalization
        new = replace(n, center=n.center + center / n.scale, scale=n.scale * scale)
        return replace(self, vertices=(self.vertices - center) * scale, normalization=new)


def is_rotation(r) -> bool:
    """Whether ``r`` is a 3 × 3 rotation: finite, orthonormal, determinant +1 (a turn, not a mirror)."""
    r = np.asarray(r, np.float64)
    return (
        r.shape == (3, 3)
        and bool(np.isfinite(r).all() and np.allclose(r @ r.T, np.eye(3), atol=1e-6))
        and (np.linalg.det(r) > 0)
    )


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area of each triangle, ``(F,)``."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def component_labels(n_verts: int, faces: np.ndarray) -> np.ndarray:
    """Connected-component label of every face (faces sharing a vertex are connected)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows = faces.ravel()
    cols = faces[:, [1, 2, 0]].ravel()
    graph = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n_verts, n_verts))
    _, labels = connected_components(graph, directed=False)
    return labels[faces[:, 0]]


def tangent_frames(vertices: np.ndarray, faces: np.ndarray, face_uvs: np.ndarray | None):
    """Per-face tangent frame ``(T, B, N)``, each ``(F, 3)`` unit vectors, for tangent-space normal maps.

    ``N`` is the geometric face normal (counter-clockwise winding). ``T`` and
    ``B`` are the directions in which the texture coordinates ``u`` and ``v``
    grow on the face (solve ``e1 = du1·T + dv1·B``, ``e2 = du2·T + dv2·B``
    for the two edges), made orthonormal to ``N``: ``T`` by Gram-Schmidt,
    ``B = ±N × T`` with the sign of the ``v`` direction, so mirrored UV
    islands keep their handedness (MikkTSpace's bitangent sign; ``v`` up, the
    OpenGL / glTF "+Y up" normal-map convention). Faces without usable UVs
    (none, NaN or zero UV area) get any ``T`` perpendicular to ``N``. The grid
    reads normal maps and mesh extraction writes them with these frames.
    """
    tri = np.asarray(vertices, np.float64)[faces]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.cross(e1, e2)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    t = np.zeros_like(n)
    vdir = np.zeros_like(n)
    if face_uvs is not None:
        uv = np.asarray(face_uvs, np.float64)
        d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
        ok = np.isfinite(det) & (np.abs(det) > 1e-20)
        r = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
        t = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * r
        vdir = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * r
    t = t - np.einsum("fi,fi->f", t, n)[:, None] * n
    norm = np.linalg.norm(t, axis=1)
    bad = ~(norm > 1e-12)
    if bad.any():  # any perpendicular: the axis least aligned with N, projected
        axis = np.eye(3)[np.abs(n[bad]).argmin(1)]
        t[bad] = axis - np.einsum("fi,fi->f", axis, n[bad])[:, None] * n[bad]
        norm[bad] = np.linalg.norm(t[bad], axis=1)
    t /= np.maximum(norm, 1e-30)[:, None]
    b = np.cross(n, t)
    flip = np.einsum("fi,fi->f", b, vdir) < 0
    b[flip] *= -1
    return t, b, n


def sample_texture(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of ``image`` ``(h, w[, c])`` at ``uv`` ``(n, 2)``: ``(n[, c])`` float32.

    OpenGL/OBJ convention: ``u`` goes right, ``v`` goes *up* (row 0 of the
    image is ``v = 1``); UVs outside [0, 1] wrap around (repeat).
    """
    h, w = image.shape[:2]
    flat = image.astype(np.float32, copy=False).reshape(h * w, -1)  # gathers from one flat table are cheaper
    uv = np.where(np.isfinite(uv), uv, 0.0)
    x = (uv[:, 0] % 1.0) * w - 0.5
    y = (1.0 - (uv[:, 1] % 1.0)) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx = (x - x0).astype(np.float32)[:, None]
    fy = (y - y0).astype(np.float32)[:, None]
    x0, y0 = x0.astype(np.int64) % w, y0.astype(np.int64) % h
    x1, y1 = (x0 + 1) % w, (y0 + 1) % h
    top = flat[y0 * w + x0]
    top += (flat[y0 * w + x1] - top) * fx
    bot = flat[y1 * w + x0]
    bot += (flat[y1 * w + x1] - bot) * fx
    top += (bot - top) * fy
    return top.reshape(len(uv), *image.shape[2:])


def unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the distinct rows of ``a`` in first-occurrence order, and each row's distinct index."""
    a = np.ascontiguousarray(a + 0.0 if a.dtype.kind == "f" else a)  # -0.0 and 0.0 are the same row
    if a.ndim == 2 and a.dtype.itemsize * a.shape[1] == 8:  # e.g. float32 UV pairs: sort one uint64
        _, first, inverse = np.unique(a.view(np.uint64).reshape(-1), return_index=True, return_inverse=True)
    else:  # lexicographic sort, then group equal neighbours (faster than np.unique(axis=0))
        order = np.lexsort(a.T[::-1])
        srt = a[order]
        new = np.r_[True, np.any(srt[1:] != srt[:-1], axis=1)] if len(a) else np.zeros(0, bool)
        first = order[new]  # lexsort is stable: the first occurrence of each group
        inverse = np.empty(len(a), np.int64)
        inverse[order] = np.cumsum(new) - 1
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return first[order], rank[inverse.reshape(-1)]

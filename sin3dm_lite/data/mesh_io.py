"""Load a textured mesh from disk and normalise it into the paper's box.

Sin3DM learns from *one* textured shape. Whatever the file format, we turn it
into a :class:`TexturedMesh`: triangle geometry plus everything needed to ask
"what colour is the surface at this point?" (per-face UVs into one or more
material textures, vertex colours, or a plain material colour).  Keeping the
materials separate (instead of packing them into one atlas) means a
multi-material OBJ or a glTF scene loses nothing.

The paper normalises every input the same way (docs/paper-notes.md, "Input grid"):
centre the bounding box, scale so that the longest side times 1.03 spans
[-1, 1]. :class:`Normalization` keeps that transform so generated shapes can
be mapped back into the input's own coordinates.

Public API::

    load_mesh(path, *, max_texture_size=4096, allow_outside_paths=False) -> TexturedMesh   # .obj .glb .gltf .ply .stl .off
    load_any(source) -> TexturedMesh          # a path, or a TexturedMesh (returned as is)
    image_to_array(image, max_size=None)      # PIL image / array -> (h, w, 3) float32 in [0, 1]
    array_to_pil(array, max_size=None)        # the other way: (h, w, 3) in [0, 1] -> 8-bit PIL image
    sample_texture(image, uv)                 # bilinear, wrap-around texture lookup
    unique_rows(array)                        # distinct rows in first-occurrence order (welding)

The writers (``save_obj``, ``save_glb``, ``export_mesh``) live in
:mod:`sin3dm_lite.export`.

Bad input raises one :class:`~sin3dm_lite.errors.Sin3DMInputError` whose
message names the problem and the fix; a missing or unreadable texture is a
``UserWarning`` and the material falls back to its plain colour.
"""
from __future__ import annotations

import base64
import io
import json
import re
import struct
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from ..errors import Sin3DMInputError

#: Colour used for a mesh that has no texture, vertex colour or material colour.
DEFAULT_COLOR = np.array([0.7, 0.7, 0.7], dtype=np.float32)

#: The paper's margin: the longest side times this factor maps to [-1, 1].
BOX_MARGIN = 1.03


def _default_rgba() -> np.ndarray:
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
    """Similarity transform ``normalized = (original - center) * scale``."""

    center: np.ndarray  # (3,)
    scale: float

    def to_normalized(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, dtype=np.float64) - self.center) * self.scale

    def to_original(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, dtype=np.float64) / self.scale + self.center

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
        t, b, n = tangent_frames(self.vertices, self.faces[face_index],
                                 None if self.face_uvs is None else self.face_uvs[face_index])
        mat_of = self.face_material[face_index]
        for mi, mat in enumerate(self.materials):
            sel = np.nonzero(mat_of == mi)[0]
            if len(sel) == 0:
                continue
            out[sel, 0], out[sel, 1] = mat.metallic, mat.roughness
            normal = n[sel]
            if self.face_uvs is not None and (mat.metallic_roughness_image is not None or mat.normal_image is not None):
                uv = np.einsum("nk,nkd->nd", bc[sel], self.face_uvs[face_index[sel]].astype(np.float64))
                if mat.metallic_roughness_image is not None:
                    mr = sample_texture(mat.metallic_roughness_image, uv)
                    out[sel, 0] *= mr[:, 2]
                    out[sel, 1] *= mr[:, 1]
                if mat.normal_image is not None:
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
        mat_of = self.face_material[face_index]
        for mi, mat in enumerate(self.materials):
            sel = np.nonzero(mat_of == mi)[0]
            if len(sel) == 0:
                continue
            factor = np.asarray(mat.base_color, np.float32)[:3]
            if mat.image is not None and self.face_uvs is not None:
                uv = np.einsum("nk,nkd->nd", bc[sel], self.face_uvs[face_index[sel]].astype(np.float64))
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
            raise Sin3DMInputError(f"mesh '{self.name}' has zero surface area; give a mesh with non-degenerate triangles")
        fi = rng.choice(len(self.faces), size=n, p=area / total)
        r1, r2 = rng.random(n), rng.random(n)
        s = np.sqrt(r1)
        bc = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
        pts = np.einsum("nk,nkd->nd", bc, tri[fi])
        return pts, fi, bc

    # -------------------------------------------------------------- transforms
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
        new = Normalization(center=self.normalization.to_original(center), scale=self.normalization.scale * scale)
        return replace(self, vertices=(self.vertices - center) * scale, normalization=new)


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
    (none, NaN or zero UV area) get any ``T`` perpendicular to ``N``. The
    grid reads normal maps with these frames and mesh extraction writes them
    with the same function, so a map survives the round trip.
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


# =============================================================================
# Loading
# =============================================================================
#
# Colour rules (the same for every format):
#   * a face whose material has a texture takes ``texture(uv) * base_color``;
#   * otherwise, if the mesh has vertex colours: ``interpolated colour * base_color``;
#   * otherwise the material's ``base_color``;
#   * a file with no colour information at all gets one material with
#     :data:`DEFAULT_COLOR`.
# Where a format says a texture or vertex colours *replace* the material colour
# (OBJ/MTL: ``map_Kd`` replaces ``Kd``; vertex colours replace ``Kd``) the
# loader stores a white factor, so the rules above give what a viewer shows.
# glTF multiplies ``baseColorFactor`` into the texture, and so do we.

#: File extensions :func:`load_mesh` reads.
SUPPORTED_EXTENSIONS = (".obj", ".glb", ".gltf", ".ply", ".stl", ".off")
#: The same formats in words, for help texts (``sin3dm-lite ... --help``); a test loads one file of each.
READABLE = "OBJ (+MTL), GLB/glTF, PLY, STL, OFF"

#: Textures larger than this (longest side, pixels) are shrunk on load: one
#: float32 RGB 4096² image is already 200 MB, and a 256³ grid never needs more.
MAX_TEXTURE_SIZE = 4096

def load_mesh(path, *, max_texture_size: int | None = MAX_TEXTURE_SIZE, allow_outside_paths: bool = False) -> TexturedMesh:
    """Read a textured mesh file into a :class:`TexturedMesh` (the file's own coordinates).

    Formats (by extension, case-insensitive):

    * ``.obj`` (+ ``.mtl`` + images): ``map_Kd`` textures, ``Kd`` colours,
      several materials (each face keeps its material and its own per-corner
      UVs), vertex colours ``v x y z r g b``, PBR extensions ``Pm``/``Pr``/
      ``map_Pm``/``map_Pr``/``map_Bump``/``norm``. Parsed here, not by trimesh,
      so face order, vertex order and UV indices are exactly the file's
      (trimesh groups faces by material and drops a ``map_Kd`` with options:
      ``tests/test_mesh_io.py::test_obj_reader_keeps_what_trimesh_loses``).
      Every other format is read by trimesh.
    * ``.glb`` / ``.gltf``: every mesh node of the default scene with its node
      transform applied, every primitive with its material (base colour
      texture and factor; metallic-roughness texture and factors and normal
      map go to the material's PBR fields), ``COLOR_0`` vertex colours.
    * ``.ply``: vertex colours or face colours; ``.stl`` / ``.off``: geometry only.

    Vertices with identical position (and colour) are welded, unreferenced
    vertices dropped, polygons fan-triangulated. A texture that is missing or
    unreadable produces a ``UserWarning`` naming the file, and the material
    falls back to its plain colour. Textures become float32 RGB in [0, 1]
    (alpha dropped, grey expanded; sRGB values kept as stored), shrunk to
    ``max_texture_size`` pixels on the longest side (``None``: never).

    A mesh file reads only files in its own folder (and below): an MTL library,
    texture, glTF buffer or image, or PLY texture that it names outside that
    folder (``../../x.png``, ``/etc/passwd``, a symbolic link pointing out) is
    refused, unless ``allow_outside_paths=True`` (CLI: ``--allow-outside-paths``)
    says that the mesh is trusted.

    Raises:
        Sin3DMInputError: missing file, unsupported extension, unreadable file,
            no faces, NaN/inf coordinates, zero-size bounding box or zero area,
            a file named outside the mesh's folder.
    """
    path = _check_input_path(path)
    load = _load_obj if path.suffix.lower() == ".obj" else _load_with_trimesh
    return _assemble(*load(path, max_texture_size, _Scope(path, allow_outside_paths)), name=path.stem,
                     source=path.name)


# the largest vertex coordinate accepted: beyond it the bounding box or the triangle areas overflow, or
# the rest of the mesh shrinks below float32 precision once normalised
MAX_COORDINATE = 1e15


def load_any(source, **kwargs) -> TexturedMesh:
    """A :class:`TexturedMesh` from a file path or an existing ``TexturedMesh`` (returned as is)."""
    if isinstance(source, TexturedMesh):
        return source
    if isinstance(source, str) or hasattr(source, "__fspath__"):
        return load_mesh(source, **kwargs)
    raise Sin3DMInputError(
        f"cannot make a mesh from {type(source).__name__}; pass a file path "
        f"({', '.join(SUPPORTED_EXTENSIONS)}) or a TexturedMesh"
    )


# ----------------------------------------------------------------- validation
@dataclass(frozen=True)
class _Scope:
    """Where a mesh file may make the loader read: its own folder (symbolic links resolved), or anywhere if allowed."""

    mesh: Path
    anywhere: bool = False

    def allows(self, p: Path) -> bool:
        return self.anywhere or p.resolve().is_relative_to(self.mesh.parent.resolve())

    def refuse(self, ref: str, what: str, found: Path) -> Sin3DMInputError:
        link = ", through a symbolic link" if found.is_symlink() else ""
        return Sin3DMInputError(
            f"'{self.mesh.name}' names a file outside its folder: {what} '{ref}' is '{found.resolve()}'{link}; a mesh "
            f"file may only make sin3dm-lite read files in its own folder '{self.mesh.parent.resolve()}': copy the "
            "file there, or pass --allow-outside-paths (Python: allow_outside_paths=True) if you trust this mesh"
        )


def _check_input_path(path) -> Path:
    try:
        path = Path(path).expanduser()
    except TypeError:
        raise Sin3DMInputError(f"expected a file path, got {type(path).__name__}") from None
    if not path.exists():
        raise Sin3DMInputError(
            f"mesh file not found: '{path}' (working directory: {Path.cwd()}); check the path and its spelling"
        )
    if path.is_dir():
        raise Sin3DMInputError(f"'{path}' is a directory; give the path of a mesh file inside it")
    if path.suffix.lower() not in SUPPORTED_EXTENSIONS:
        raise Sin3DMInputError(
            f"'{path.name}' has an unsupported extension '{path.suffix or '(none)'}'; supported mesh "
            f"formats are {', '.join(SUPPORTED_EXTENSIONS)}; convert the file (for example File > Export "
            "in Blender) or rename it if the extension is wrong"
        )
    return path


def _unreadable(path, what: str, exc: BaseException | str) -> Sin3DMInputError:
    detail = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
    return Sin3DMInputError(
        f"could not read '{path.name}' as {what} ({detail}); the file may be corrupt, truncated or "
        "not what its extension says; re-export it from the program that made it"
    )


# ------------------------------------------------------------------ assembly
@dataclass
class _Part:
    """A piece of a mesh as read from a file, before concatenation."""

    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64, into this part's vertices
    face_material: np.ndarray  # (F,) int64, into the shared material list
    face_uvs: np.ndarray | None = None  # (F, 3, 2)
    vertex_colors: np.ndarray | None = None  # (V, 3) float32


def _assemble(parts: list[_Part], materials: list[Material], name: str, source: str) -> TexturedMesh:
    """Concatenate parts, validate, drop unreferenced vertices, weld duplicates."""
    parts = [p for p in parts if len(p.faces)]
    if not parts:
        raise Sin3DMInputError(
            f"'{source}' contains no triangle faces (an empty file, or a point cloud / lines only); "
            "Sin3DM needs a surface mesh: export the faces, or reconstruct a surface from the points first"
        )
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts])
    vertices = np.concatenate([p.vertices for p in parts]).astype(np.float64)
    faces = np.concatenate([p.faces + o for p, o in zip(parts, offsets)]).astype(np.int64)
    face_material = np.concatenate([p.face_material for p in parts]).astype(np.int64)
    face_uvs = None
    if any(p.face_uvs is not None for p in parts):
        face_uvs = np.concatenate(
            [p.face_uvs if p.face_uvs is not None else np.full((len(p.faces), 3, 2), np.nan) for p in parts]
        ).astype(np.float32)
    colors = None
    if any(p.vertex_colors is not None for p in parts):
        colors = np.concatenate(
            [p.vertex_colors if p.vertex_colors is not None else np.ones((len(p.vertices), 3)) for p in parts]
        ).astype(np.float32)

    # keep only referenced vertices: stray points must not enlarge the bounding box
    used = np.zeros(len(vertices), bool)
    used[faces] = True
    vertices, faces = vertices[used], (np.cumsum(used) - 1)[faces]
    colors = colors[used] if colors is not None else None

    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        raise Sin3DMInputError(
            f"'{source}' has {int(bad.sum())} vertices with NaN or infinite coordinates (the first is "
            f"vertex {int(np.argmax(bad))}); repair or delete them in a mesh editor and export again"
        )
    # weld vertices with exactly equal position (and colour), in first-occurrence order
    keep, inverse = unique_rows(vertices if colors is None else np.hstack([vertices, colors.astype(np.float64)]))
    vertices, faces, colors = vertices[keep], inverse[faces], (colors[keep] if colors is not None else None)

    extent = vertices.max(0) - vertices.min(0)
    if extent.max() <= 0:
        raise Sin3DMInputError(
            f"'{source}' has a zero-size bounding box (all its vertices are at the same point); "
            "Sin3DM needs faces that span some volume"
        )
    big = float(np.abs(vertices).max())
    if big > MAX_COORDINATE:  # the box, the areas and the normalisation would overflow or lose all precision
        raise Sin3DMInputError(
            f"'{source}' has a vertex coordinate of {big:.3g}, too large for its bounding box (the limit is "
            f"{MAX_COORDINATE:.0e}); remove the stray vertex or scale the mesh down in a mesh editor"
        )
    area = face_areas(vertices, faces)
    if not area.sum() > 0:
        raise Sin3DMInputError(
            f"'{source}' has zero surface area (every triangle is degenerate: collinear or repeated "
            "vertices); Sin3DM needs a surface mesh"
        )

    used_materials, face_material = np.unique(face_material, return_inverse=True)  # unused ones may hold big images
    if face_uvs is not None and not np.isfinite(face_uvs).any():
        face_uvs = None
    return TexturedMesh(vertices=vertices, faces=faces, face_material=face_material,
                        materials=[materials[i] for i in used_materials], face_uvs=face_uvs, vertex_colors=colors,
                        name=name)


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


# -------------------------------------------------------------------- images
def image_to_array(image, max_size: int | None = None) -> np.ndarray:
    """A PIL image or array as ``(h, w, 3)`` float32 RGB in [0, 1].

    Alpha is dropped, grey is repeated into RGB, 16-bit and float images are
    scaled; images larger than ``max_size`` (longest side) are shrunk with a
    box filter.
    """
    from PIL import Image

    if isinstance(image, Image.Image):
        image.load()
        if image.mode in ("I;16", "I;16B", "I;16L", "I;16N", "I", "F"):
            arr = np.asarray(image).astype(np.float32)
            if image.mode.startswith("I;16"):
                arr = arr / 65535.0
            elif image.mode == "I":  # 32-bit int: 16-bit data in practice, 8-bit if it fits
                arr = arr / (255.0 if arr.max(initial=0) <= 255 else 65535.0)
            image = Image.fromarray(np.ascontiguousarray(arr, np.float32))  # mode "F", resized below if needed
        elif image.mode != "RGB":
            image = image.convert("RGBA" if image.mode in ("P", "PA", "LA", "RGBa", "La") else "RGB")
        arr = np.asarray(_shrink(image, max_size))
    else:
        arr = np.asarray(image)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"not an image: array of shape {arr.shape}")
    # pick the RGB channels first, then make one float32 copy (a 4096² texture is 200 MB per copy)
    arr = np.repeat(arr[:, :, :1], 3, axis=2) if arr.shape[2] in (1, 2) else arr[:, :, :3]  # grey (+ alpha)
    out = np.ascontiguousarray(arr, dtype=np.float32)
    if out is arr:
        out = out.copy()  # never scale the caller's array in place
    if arr.dtype in (np.uint8, np.uint16):
        out /= 255.0 if arr.dtype == np.uint8 else 65535.0
    elif arr.dtype != bool:
        np.nan_to_num(out, copy=False)
        np.clip(out, 0.0, 1.0, out=out)
    return out


def array_to_pil(arr: np.ndarray, max_size: int | None = None):
    """``(h, w, 3)`` floats in [0, 1] → 8-bit PIL image, shrunk to ``max_size`` (longest side) if given."""
    from PIL import Image

    return _shrink(Image.fromarray(np.round(np.clip(arr, 0, 1) * 255).astype(np.uint8)), max_size)


def _shrink(img, max_size: int | None):
    """A PIL image shrunk (box filter) so that its longest side is at most ``max_size``."""
    from PIL import Image

    if not max_size or max(img.size) <= max_size:
        return img
    s = max_size / max(img.size)
    return img.resize((max(1, round(img.width * s)), max(1, round(img.height * s))), Image.BOX)


def _warn(message: str) -> None:
    """``warnings.warn`` attributed to the first caller outside this module (the user's line)."""
    import sys
    import warnings

    level, frame = 2, sys._getframe(1)  # stacklevel 2 = the caller of _warn
    while frame is not None and frame.f_code.co_filename == __file__:
        frame, level = frame.f_back, level + 1
    warnings.warn(message, UserWarning, stacklevel=level)


# ----------------------------------------------------------------------- OBJ
def _load_obj(path, max_size, scope: _Scope):
    """A Wavefront OBJ (+ MTL) → one part and its materials."""
    data = path.read_bytes()
    if b"\x00" in data[:65536]:
        raise _unreadable(path, "a Wavefront OBJ", "it contains binary data, an OBJ file is text")
    text = data.decode("utf-8", errors="replace").replace("\r\n", "\n").replace("\r", "\n")
    text = "\n" + text.replace("\\\n", " ")  # joins "\" continuation lines

    # one regular-expression scan per keyword (much faster than a Python loop over lines)
    def scan(keyword):
        found = list(re.finditer(rf"^[ \t]*{keyword}[ \t]+([^\n]*)", text, re.MULTILINE))
        return [m.group(1) for m in found], np.fromiter((m.start() for m in found), np.int64, len(found))

    v_rows, v_pos = scan("v")
    vt_rows, vt_pos = scan("vt")
    f_rows, f_pos = scan("f")
    use_names, use_pos = scan("usemtl")
    # the material slot in force at each face: that of the last usemtl before it (slot 0: none yet)
    mat_names = [None, *dict.fromkeys(name.strip() for name in use_names)]
    slot_of = {name: slot for slot, name in enumerate(mat_names)}
    use_slot = np.array([0] + [slot_of[name.strip()] for name in use_names], np.int64)
    info = np.stack([f_pos, use_slot[np.searchsorted(use_pos, f_pos)],
                     np.searchsorted(v_pos, f_pos), np.searchsorted(vt_pos, f_pos)], axis=1)
    fv, ft, fm = _obj_faces(path, f_rows, info, line_of=lambda pos: text.count("\n", 0, pos))
    used_slots, fm = np.unique(fm, return_inverse=True)  # keep only the material slots faces use
    mat_names = [mat_names[i] for i in used_slots]

    vertices, colors = _obj_vertices(path, v_rows)
    uvs = np.nan_to_num(_obj_numbers(path, vt_rows, "vt", 1, width=2)[:, :2])
    if len(fv) and fv.max() >= len(vertices):
        raise _unreadable(path, "a Wavefront OBJ", f"a face refers to vertex {fv.max() + 1} but the file "
                          f"defines only {len(vertices)} vertices")
    if len(ft) and ft.max() >= len(uvs):
        raise _unreadable(path, "a Wavefront OBJ", f"a face refers to texture coordinate {ft.max() + 1} but the "
                          f"file defines only {len(uvs)} ('vt' lines)")

    # the used materials' definitions in the MTL libraries
    texture = partial(_load_texture, max_size=max_size, cache={}, scope=scope)
    library: dict[str, tuple[Material, tuple | None]] = {}
    loaded_any = False
    for entry in (e.strip() for e in scan("mtllib")[0]):
        # "mtllib a.mtl b.mtl", unless that is one file name with spaces
        for name in (entry.split() if " " in entry and not _resolve_asset(entry, path.parent, scope, "the material "
                     "library") else [entry]):
            mtl = _resolve_asset(name, path.parent, scope, "the material library")
            if mtl is None:
                _warn(
                    f"material library '{name}' named in '{path.name}' was not found (looked in '{path.parent}'); "
                    "using plain colours: put the .mtl file next to the .obj"
                )
                continue
            try:
                library.update(_parse_mtl(mtl, set(mat_names), texture))
                loaded_any = True
            except OSError as exc:
                _warn(f"material library '{mtl.name}' could not be read ({exc}); using plain colours")

    # one Material per used name, ordered as the MTL defines them (the file's intent), undefined ones last
    lib_order = {name: i for i, name in enumerate(library)}
    order = sorted(range(len(mat_names)), key=lambda i: (lib_order.get(mat_names[i], len(lib_order)), i))
    materials, uv_transforms = [], []
    for mname in (mat_names[i] for i in order):
        mat, uv_t = library.get(mname, (None, None))
        if mat is None:
            if mname is not None and loaded_any:
                _warn(f"material '{mname}' used in '{path.name}' is not defined in its .mtl file; using a plain colour")
            mat = Material(name=mname or "default", base_color=_default_rgba())
        if colors is not None and mat.image is None:  # vertex colours replace Kd
            mat = replace(mat, base_color=np.array([1, 1, 1, mat.base_color[3]], np.float32))
        materials.append(mat)
        uv_transforms.append(uv_t)
    face_material = np.argsort(order)[fm]

    face_uvs = None
    if len(uvs) and (ft >= 0).any():
        face_uvs = np.where((ft >= 0)[..., None], uvs[np.maximum(ft, 0)], np.nan).astype(np.float32)
        for mi, t in enumerate(uv_transforms):
            if t is not None:
                sel = face_material == mi
                face_uvs[sel] = face_uvs[sel] * t[0] + t[1]
    return [_Part(vertices, fv, face_material, face_uvs, colors)], materials


def _obj_faces(path, rows: list[str], info: np.ndarray, line_of):
    """Face lines → triangles ``(F, 3)`` of vertex and uv indices (0-based; uv -1: none) and material slots.

    ``info`` holds, for each line, its position in the text, its material slot
    and how many vertices and uvs were defined before it. Indices are 1-based;
    negative ones count back from the last vertex (uv) defined so far.
    Polygons are fan-triangulated; lines with fewer than three corners are
    skipped. Files with one index layout (the usual case) are parsed in one
    vectorised step.
    """
    counts = np.array([len(row.split()) for row in rows], np.int64)  # corners per line
    line = np.repeat(np.arange(len(rows)), np.maximum(counts - 2, 0))  # the line of each triangle
    if (counts == 3).all():
        tri = " ".join(rows).split()
    else:  # fan triangulation
        tri = [t for c in map(str.split, rows) for k in range(1, len(c) - 1) for t in (c[0], c[k], c[k + 1])]
    nums = None
    if len({t.count("/") for t in tri}) == 1:  # v, v/vt, v//vn or v/vt/vn on every corner
        try:
            nums = np.array(" ".join(tri).replace("//", "/0/").replace("/", " ").split(), np.int64)
            nums = np.pad(nums.reshape(len(line), 3, -1), [(0, 0), (0, 0), (0, 1)])[..., :2]  # vt 0: absent
        except ValueError:
            nums = None
    if nums is None:  # mixed layouts, or an error to locate: corner by corner

        def corner(token):
            s = token.split("/")
            try:
                return int(s[0]), (int(s[1]) if len(s) > 1 and s[1] else 0)
            except ValueError:
                return 0, 0  # reported below, like an index 0

        nums = np.array([corner(t) for t in tri], np.int64).reshape(-1, 3, 2)
    v, t = nums[..., 0], nums[..., 1]
    vi = np.where(v < 0, v + info[line, 2:3], v - 1)
    ti = np.where(t < 0, t + info[line, 3:4], t - 1)  # vt 0 (absent) → -1
    bad = (vi < 0).any(axis=1) | ((t < 0) & (ti < 0)).any(axis=1)
    if bad.any():
        i = line[np.argmax(bad)]
        raise _unreadable(
            path, "a Wavefront OBJ", f"line {line_of(info[i, 0])}: bad face 'f {rows[i].strip()[:80]}' (an index is "
            "not a number, is 0, or points before the first vertex)"
        )
    return vi, ti, info[line, 1]


def _obj_numbers(path, rows, what, min_cols, width):
    """Lines of numbers → ``(n, width)`` float64 (``width`` at least), NaN where a line is shorter."""
    rows = [row.split() for row in rows]
    widths = set(map(len, rows)) | {width}
    try:
        short = next((i for i, row in enumerate(rows) if len(row) < min_cols), None)
        if short is not None:
            raise ValueError(f"{what} line #{short + 1} has {len(rows[short])} numbers, needs {min_cols}")
        if len(widths) > 1:
            rows = [row + ["nan"] * (max(widths) - len(row)) for row in rows]
        return np.array(rows, np.float64).reshape(len(rows), max(widths))
    except ValueError as exc:
        raise _unreadable(path, "a Wavefront OBJ", f"bad '{what}' line: {exc}") from None


def _obj_vertices(path, rows):
    """``v x y z [w]`` or ``v x y z r g b`` rows → positions and (optional) colours."""
    arr = _obj_numbers(path, rows, "v", 3, width=3)
    rgb = arr[:, 3:6] if arr.shape[1] >= 6 else np.full((len(arr), 3), np.nan)
    has = np.isfinite(rgb).all(axis=1)
    if not has.any():
        return arr[:, :3], None
    if np.nanmax(rgb) > 1.0:  # some writers use 0..255
        rgb = rgb / 255.0
    return arr[:, :3], np.where(has[:, None], np.clip(np.nan_to_num(rgb), 0, 1), 1.0).astype(np.float32)


def _parse_mtl(path, used: set, texture) -> dict[str, tuple[Material, tuple | None]]:
    """The ``newmtl`` blocks of an MTL file → ``{name: (material, uv transform or None)}``, in file order.

    Only the materials named in ``used`` are built, so textures that no face
    shows are neither decoded nor warned about; ``texture`` loads an image
    (:func:`_load_texture`). A loaded ``map_Kd`` replaces ``Kd`` and a loaded
    ``map_Pr``/``map_Pm`` replaces ``Pr``/``Pm`` (as Blender and three.js
    read them). The uv transform is ``(scale, offset)`` from the ``map_Kd
    -s/-o`` options.
    """
    raw: dict[str, dict] = {}
    cur: dict = {}  # statements before the first newmtl belong to no material
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        key, rest = (line.split(None, 1) + ["", ""])[:2]
        k, rest = key.lower(), rest.strip()
        try:
            if key == "newmtl":
                cur = raw.setdefault(rest, {})
            elif k == "kd":
                vals = [float(x) for x in rest.split()[:3]]
                cur["Kd"] = vals * 3 if len(vals) == 1 else vals
            elif k == "d":
                cur["d"] = float(rest.split()[-1])
            elif k == "tr" and "d" not in cur:
                cur["d"] = 1.0 - float(rest.split()[-1])
            elif k in ("pm", "pr"):
                cur[k] = float(rest.split()[0])
            elif k in ("map_kd", "map_pm", "map_pr", "map_bump", "bump", "norm"):
                cur[k] = _parse_tex_line(rest)
        except (ValueError, IndexError):
            continue  # a malformed optional line: ignore it like other viewers do
    out = {}
    for mname, d in raw.items():
        if mname not in used:
            continue
        kd = np.clip((d.get("Kd", list(DEFAULT_COLOR)) + [1.0, 1.0, 1.0])[:3], 0, 1)
        mat = Material(name=mname, base_color=np.array([*kd, d.get("d", 1.0)], np.float32),
                       metallic=d.get("pm", 0.0), roughness=d.get("pr", 1.0))
        uv_transform = None
        if "map_kd" in d:
            fname, opts = d["map_kd"]
            mat.image = texture(fname, "map_Kd", mname, path)
            if mat.image is not None:
                mat.base_color[:3] = 1.0  # the texture replaces Kd (Blender, three.js and co. agree)
                s = [float(x) for x in opts.get("-s", [])] + [1.0, 1.0]
                o = [float(x) for x in opts.get("-o", [])] + [0.0, 0.0]
                if s[:2] != [1.0, 1.0] or o[:2] != [0.0, 0.0]:
                    uv_transform = (np.array(s[:2], np.float32), np.array(o[:2], np.float32))
        for key, chan in (("map_pr", 1), ("map_pm", 2)):  # glTF layout: roughness in G, metallic in B
            img = texture(d[key][0], key.replace("map_p", "map_P"), mname, path) if key in d else None
            if img is None:
                continue
            if mat.metallic_roughness_image is None:
                mat.metallic_roughness_image = np.ones_like(img)
            elif img.shape != mat.metallic_roughness_image.shape:  # to the size of the first map
                img = image_to_array(array_to_pil(img).resize(mat.metallic_roughness_image.shape[1::-1]))
            mat.metallic_roughness_image[:, :, chan] = img[:, :, 0]
            setattr(mat, "roughness" if chan == 1 else "metallic", 1.0)
        key = next((k for k in ("norm", "map_bump", "bump") if k in d), None)
        img = texture(d[key][0], key, mname, path) if key else None
        if img is not None and np.ptp(img, axis=2).max() > 1e-3:  # a grey bump map is a height map: not used
            mat.normal_image = img
        out[mname] = (mat, uv_transform)
    return out


_TEX_OPTION_ARGS = {  # MTL texture options and how many arguments each takes (at most)
    "-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1, "-imfchan": 1,
    "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1, "-type": 1,
}


def _parse_tex_line(rest: str):
    """``[options] filename`` of an MTL map line → (filename, {option: [args]}).

    An option's first argument is taken as it is, further ones only while
    they are numbers; the last token always belongs to the filename.
    """
    tokens, opts = rest.split(), {}
    while len(tokens) > 1 and tokens[0].lower() in _TEX_OPTION_ARGS:
        opt = tokens.pop(0).lower()
        args = opts[opt] = []
        while len(args) < _TEX_OPTION_ARGS[opt] and len(tokens) > 1 and (not args or _is_number(tokens[0])):
            args.append(tokens.pop(0))
    return " ".join(tokens), opts


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _load_texture(ref: str, what: str, mname: str, mtl: Path, *, max_size, cache: dict, scope: _Scope):
    """The image an MTL map line names, as an array; ``None`` with a warning if it is missing or unreadable.

    Each file is decoded once (``cache``): several materials often share one atlas.
    """
    from PIL import Image

    owner = f"{what} of material '{mname}' in '{mtl.name}'"
    path = _resolve_asset(ref, mtl.parent, scope, f"the {what} texture of material '{mname}' in '{mtl.name}'")
    if path is None:
        _warn(
            f"texture file '{ref}' ({owner}) was not found (looked in '{mtl.parent}'); "
            "using the material colour instead: put the image next to the .mtl file or fix the path"
        )
        return None
    key = path.resolve()
    if key not in cache:
        try:
            with Image.open(path) as img:
                cache[key] = image_to_array(img, max_size)
        except Exception as exc:  # corrupt / unsupported image: warn and fall back
            cache[key] = None
            _warn(
                f"texture file '{path.name}' ({owner}) could not be read ({type(exc).__name__}: {exc}); "
                "using the material colour instead: re-save the image as PNG or JPEG"
            )
    return cache[key]


def _resolve_asset(ref: str, base: Path, scope: _Scope, what: str, cwd: bool = True) -> Path | None:
    """Find a file a mesh file names: as written (relative to ``base``, else to the working directory if ``cwd``),
    then by its base name (also ignoring case) in ``base``; None if there is none.

    Files outside the mesh's folder are skipped (``scope``); if only such files exist, the reference is
    refused (:class:`Sin3DMInputError` naming ``what``, the reference and the file).
    """
    name = Path(ref.strip().strip('"').replace("\\", "/"))

    def candidates():
        yield from (base / name, name, base / name.name) if cwd else (base / name, base / name.name)
        try:  # base / an absolute path = the path
            yield from (c for c in base.iterdir() if c.name.lower() == name.name.lower())
        except OSError:
            return

    outside = None
    for candidate in candidates():
        if candidate.is_file():
            if scope.allows(candidate):
                return candidate
            outside = outside or candidate
    if outside is not None:
        raise scope.refuse(ref.strip(), what, outside)
    return None


# ------------------------------------------------------- glTF / PLY / STL / OFF
def _load_with_trimesh(path, max_size, scope: _Scope):
    """Every triangle geometry of the file's scene, node transforms applied."""
    import trimesh
    from trimesh.visual import ColorVisuals, TextureVisuals

    fmt = {".glb": "a binary glTF (GLB)", ".gltf": "a glTF", ".ply": "a PLY mesh", ".stl": "an STL mesh",
           ".off": "an OFF mesh"}[path.suffix.lower()]
    if path.stat().st_size == 0:
        raise _unreadable(path, fmt, "the file is empty")
    image_problems = []
    if path.suffix.lower() in (".glb", ".gltf"):
        header, binary = _gltf_json(path, fmt)
        for kind in ("buffers", "images"):  # external files trimesh would read: in the mesh's folder only
            for item in header.get(kind, []) if isinstance(header.get(kind), list) else []:
                uri = item.get("uri") if isinstance(item, dict) else None
                if isinstance(uri, str) and not uri.startswith("data:"):
                    _resolve_asset(unquote(uri), path.parent, scope, f"the glTF {kind[:-1]}", cwd=False)
        image_problems = _gltf_image_problems(path, header, binary)
    elif path.suffix.lower() == ".ply":
        texture = _ply_texture_file(path)
        if texture is not None:
            _resolve_asset(texture, path.parent, scope, "the texture file", cwd=False)
    try:
        scene = trimesh.load(str(path), force="scene", process=False, resolver=_resolver(path, scope))
    except Exception as exc:
        raise _unreadable(path, fmt, exc) from None
    for problem in image_problems:
        _warn(problem)

    parts: list[_Part] = []
    materials: list[Material] = []
    index: dict = {}  # a trimesh material (by id) or a colour → its position in materials

    def add(mat: Material, key) -> int:
        if key not in index:
            index[key] = len(materials)
            materials.append(mat)
        return index[key]

    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        geom = scene.geometry.get(geom_name)
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue  # point clouds, lines
        vertices = trimesh.transform_points(np.asarray(geom.vertices, np.float64), transform)
        faces = np.asarray(geom.faces, np.int64)
        if np.linalg.det(np.asarray(transform)[:3, :3]) < 0:
            faces = faces[:, ::-1]  # a mirroring transform flips the winding: restore outward normals
        visual, n = geom.visual, len(faces)
        if isinstance(visual, TextureVisuals) and visual.material is not None:
            uv = getattr(visual, "uv", None)
            has_uv = uv is not None and len(uv) == len(vertices)
            mat, key = _material_from_trimesh(visual.material, max_size, path, geom_name), id(visual.material)
            if not has_uv and any(x is not None for x in (mat.image, mat.metallic_roughness_image, mat.normal_image)):
                if mat.image is not None:
                    _warn(f"'{geom_name}' in '{path.name}' has a texture but no UV coordinates; using its base colour")
                mat, key = replace(mat, image=None, metallic_roughness_image=None, normal_image=None), (key, "no-uv")
            face_uvs = np.asarray(uv, np.float64)[faces].astype(np.float32) if has_uv else None
            colors = _color_array(visual.vertex_attributes.get("color"), len(vertices))
            parts.append(_Part(vertices, faces, np.full(n, add(mat, key)), face_uvs, colors))
        elif isinstance(visual, ColorVisuals) and visual.kind == "vertex":
            mi = add(Material(name="vertex_colors", base_color=np.ones(4, np.float32)), "vertex_colors")
            colors = _color_array(visual.vertex_colors, len(vertices))
            parts.append(_Part(vertices, faces, np.full(n, mi), None, colors))
        elif isinstance(visual, ColorVisuals) and visual.kind == "face":
            fc = _color_array(visual.face_colors, n)
            uniq, inv = np.unique(np.round(fc * 255).astype(np.int64), axis=0, return_inverse=True)
            if len(uniq) <= 64:  # a few colours: one material each
                mi = [add(Material(name=f"face_color_{k}", base_color=np.array([*c / 255.0, 1.0], np.float32)),
                          ("face", tuple(c))) for k, c in enumerate(uniq)]
                parts.append(_Part(vertices, faces, np.asarray(mi)[inv.reshape(-1)]))
            else:  # many colours: give every face its own three vertices
                mi = add(Material(name="vertex_colors", base_color=np.ones(4, np.float32)), "vertex_colors")
                parts.append(_Part(vertices[faces].reshape(-1, 3), np.arange(3 * n).reshape(-1, 3),
                                   np.full(n, mi), None, np.repeat(fc, 3, axis=0)))
        else:
            parts.append(_Part(vertices, faces, np.full(n, add(Material(base_color=_default_rgba()), "default"))))
    return parts, materials


def _unit(c) -> np.ndarray:
    """trimesh colours (uint16 0..65535, other integers 0..255, floats 0..1) → float32 in [0, 1]."""
    c = np.asarray(c)
    c = c / (65535.0 if c.dtype == np.uint16 else 255.0) if c.dtype.kind in "iu" else c
    return np.clip(np.asarray(c, np.float32), 0.0, 1.0)


def _color_array(colors, n) -> np.ndarray | None:
    """RGB or RGBA colours of ``n`` vertices or faces → (n, 3) float32 in [0, 1], or None."""
    c = None if colors is None else np.asarray(colors)
    return _unit(c[:, :3]) if c is not None and c.ndim == 2 and len(c) == n and c.shape[1] >= 3 else None


def _rgba(color) -> np.ndarray:
    """A trimesh material colour (RGB or RGBA) → float32 RGBA in [0, 1]."""
    c = _unit(np.asarray(color).reshape(-1)[:4])
    return np.r_[c, np.ones(4 - len(c), np.float32)]


def _material_from_trimesh(tm, max_size, path, geom_name) -> Material:
    """trimesh PBRMaterial / SimpleMaterial → :class:`Material`."""
    from trimesh.visual.material import PBRMaterial

    name = getattr(tm, "name", None) or geom_name

    def img(pil, what):
        try:
            return None if pil is None else image_to_array(pil, max_size)
        except Exception as exc:
            _warn(f"the {what} texture of material '{name}' in '{path.name}' could not be decoded "
                  f"({type(exc).__name__}: {exc}); continuing without it")
            return None

    if isinstance(tm, PBRMaterial):
        return Material(
            name=name,
            base_color=np.ones(4, np.float32) if tm.baseColorFactor is None else _rgba(tm.baseColorFactor),
            image=img(tm.baseColorTexture, "base colour"),
            # glTF's defaults when a factor is absent are 1.0 (metallic and rough)
            metallic=1.0 if tm.metallicFactor is None else float(tm.metallicFactor),
            roughness=1.0 if tm.roughnessFactor is None else float(tm.roughnessFactor),
            metallic_roughness_image=img(getattr(tm, "metallicRoughnessTexture", None), "metallic-roughness"),
            normal_image=img(getattr(tm, "normalTexture", None), "normal"),
        )
    if _is_trimesh_placeholder(getattr(tm, "image", None)):
        # trimesh invents a 2x2 grey image for UVs without a texture (e.g. a PLY with
        # texture coordinates but no TextureFile): that is "no colour", not a texture
        return Material(name="default", base_color=_default_rgba())
    image, diffuse = img(getattr(tm, "image", None), "diffuse"), getattr(tm, "diffuse", None)
    base = np.ones(4, np.float32) if image is not None or diffuse is None else _rgba(diffuse)
    return Material(name=name, base_color=base, image=image)


def _is_trimesh_placeholder(pil) -> bool:
    """Is this trimesh's ``color_image()`` default: 2x2 RGBA, every pixel (100, 100, 100, 255)?"""
    try:
        return (pil is not None and pil.size == (2, 2) and pil.mode == "RGBA"
                and bool(np.all(np.asarray(pil) == (100, 100, 100, 255))))
    except Exception:
        return False


def _resolver(path: Path, scope: _Scope):
    """trimesh's file resolver for ``path`` (its own folder only, unless ``scope`` allows anywhere)."""
    from trimesh.resolvers import FilePathResolver

    try:
        return FilePathResolver(str(path), allow_anywhere=scope.anywhere)
    except TypeError:  # an older trimesh: no such option
        return FilePathResolver(str(path))


def _ply_texture_file(path: Path) -> str | None:
    """The ``comment TextureFile NAME`` of a PLY header (trimesh loads that image), or None."""
    with open(path, "rb") as f:
        head = f.read(65536).split(b"end_header", 1)[0].decode("latin-1")
    for line in head.splitlines():
        at = line.lower().find("texturefile")
        if at >= 0:
            return line[at + len("texturefile"):].strip() or None
    return None


def _gltf_json(path, fmt: str) -> tuple[dict, bytes]:
    """A glTF's JSON and (GLB) binary chunk; a clear error if it is not glTF at all, ``({}, b"")`` on other surprises."""
    data = path.read_bytes()
    if path.suffix.lower() == ".gltf":
        try:
            header = json.loads(data.decode("utf-8"))
        except ValueError as exc:  # UnicodeDecodeError is one
            raise _unreadable(path, fmt, f"not valid JSON: {exc}") from None
        return (header if isinstance(header, dict) else {}), b""
    if data[:4] != b"glTF":
        raise _unreadable(path, fmt, "it does not start with the GLB magic bytes 'glTF'")
    try:  # 12-byte header, then the JSON chunk and the binary chunk
        off = 20 + struct.unpack_from("<I", data, 12)[0]
        header = json.loads(data[20:off])
        binary = data[off + 8 : off + 8 + struct.unpack_from("<I", data, off)[0]] if off + 8 <= len(data) else b""
        return (header if isinstance(header, dict) else {}), binary
    except Exception:
        return {}, b""


def _gltf_image_problems(path, header: dict, binary: bytes) -> list[str]:
    """A warning for each texture a glTF's materials use that is missing or undecodable (trimesh silently drops
    them). Its external files were checked to be in its folder (:func:`_load_with_trimesh`).

    Best effort: any other surprise → no warnings.
    """
    from PIL import Image

    def blob(item):  # the bytes of an image or buffer: data URI, file beside the glTF, or buffer view
        if "uri" not in item:
            view = header["bufferViews"][item["bufferView"]]
            buf = header["buffers"][view["buffer"]]
            return (binary if "uri" not in buf else blob(buf))[view.get("byteOffset", 0):][: view["byteLength"]]
        if item["uri"].startswith("data:"):
            return base64.b64decode(item["uri"].split(",", 1)[1])
        if not (path.parent / unquote(item["uri"])).is_file():
            raise FileNotFoundError("file not found")
        return (path.parent / unquote(item["uri"])).read_bytes()

    try:
        images, textures, users = header.get("images", []), header.get("textures", []), {}
        for mat in header.get("materials", []):
            pbr = mat.get("pbrMetallicRoughness", {})
            for slot, info in (("baseColorTexture", pbr.get("baseColorTexture")),
                               ("metallicRoughnessTexture", pbr.get("metallicRoughnessTexture")),
                               ("normalTexture", mat.get("normalTexture"))):
                if info and info.get("index") is not None and info["index"] < len(textures):
                    tex = textures[info["index"]]
                    exts = [e for e in (tex.get("extensions") or {}).values() if isinstance(e, dict) and "source" in e]
                    src = exts[-1]["source"] if exts else tex.get("source")
                    if src is not None and src < len(images):
                        users.setdefault(src, []).append(f"{slot} of material '{mat.get('name', '?')}'")
        problems = []
        for src, used_by in users.items():
            im = images[src]
            label = f"'{unquote(im['uri'])}'" if "uri" in im and not im["uri"].startswith("data:") else f"#{src} (embedded)"
            try:
                with Image.open(io.BytesIO(blob(im))) as pil:
                    pil.verify()
            except Exception as exc:
                reason = "not a readable image" if "cannot identify image" in str(exc) else f"{type(exc).__name__}: {exc}"
                problems.append(f"texture image {label} in '{path.name}' ({', '.join(used_by)}) is missing or "
                                f"unreadable ({reason}); using the material colour instead")
        return problems
    except Exception:
        return []

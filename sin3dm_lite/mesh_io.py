"""Load a textured mesh from disk and normalise it into the paper's box.

Sin3DM learns from *one* textured shape. Whatever the file format, we turn it
into a :class:`TexturedMesh`: triangle geometry plus everything needed to ask
"what colour is the surface at this point?" (per-face UVs into one or more
material textures, vertex colours, or a plain material colour).  Keeping the
materials separate (instead of packing them into one atlas) means a
multi-material OBJ or a glTF scene loses nothing.

The paper normalises every input the same way (REFERENCE.md, "Input grid"):
centre the bounding box, scale so that the longest side times 1.03 spans
[-1, 1]. :class:`Normalization` keeps that transform so generated shapes can
be mapped back into the input's own coordinates.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .errors import Sin3DMInputError

#: Colour used for a mesh that has no texture, vertex colour or material colour.
DEFAULT_COLOR = np.array([0.7, 0.7, 0.7], dtype=np.float32)

#: The paper's margin: the longest side times this factor maps to [-1, 1].
BOX_MARGIN = 1.03


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
    base_color: np.ndarray = field(default_factory=lambda: np.array([*DEFAULT_COLOR, 1.0], np.float32))
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

    def as_dict(self) -> dict:
        return {"center": [float(c) for c in self.center], "scale": float(self.scale)}

    @classmethod
    def identity(cls) -> "Normalization":
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
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
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
    def normalized(self) -> "TexturedMesh":
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

    def to_trimesh(self, max_texture: int = 1024):
        """A ``trimesh.Trimesh`` for viewing (vertex colours baked from the colour source)."""
        import trimesh

        tri = self.vertices[self.faces]
        # colour each vertex by the colour at its corner in one face that uses it
        fi = np.repeat(np.arange(len(self.faces)), 3)
        bc = np.tile(np.eye(3), (len(self.faces), 1))
        col = self.colors_at(fi, bc)
        v = tri.reshape(-1, 3)
        f = np.arange(len(v)).reshape(-1, 3)
        m = trimesh.Trimesh(v, f, vertex_colors=(col * 255).astype(np.uint8), process=False)
        return m


def sample_texture(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of ``image`` ``(h, w, c)`` at ``uv`` ``(n, 2)``.

    OpenGL/OBJ convention: ``u`` goes right, ``v`` goes *up* (row 0 of the
    image is ``v = 1``); UVs outside [0, 1] wrap around (repeat).
    """
    h, w = image.shape[:2]
    uv = np.where(np.isfinite(uv), uv, 0.0)
    x = (uv[:, 0] % 1.0) * w - 0.5
    y = (1.0 - (uv[:, 1] % 1.0)) * h - 0.5
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    x0w, x1w = x0 % w, (x0 + 1) % w
    y0c, y1c = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
    img = image.astype(np.float32, copy=False)
    top = img[y0c, x0w] * (1 - fx) + img[y0c, x1w] * fx
    bot = img[y1c, x0w] * (1 - fx) + img[y1c, x1w] * fx
    return (top * (1 - fy) + bot * fy).astype(np.float32)

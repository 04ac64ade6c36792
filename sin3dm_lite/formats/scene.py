"""glTF / GLB, PLY, STL and OFF: read by trimesh, each mesh node turned into a :class:`~.common.Part` (its node
transform applied) whose trimesh visual gives the colour: a material, vertex colours, face colours or the default.
"""

from __future__ import annotations

import io
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..data.mesh import Material, default_rgba
from .common import Part, Scope, resolve_asset, unreadable, warn
from .gltf import check_compression, check_gltf_files, gltf_image_problems, gltf_json, plain_gltf
from .images import image_to_array, named_image_warnings

_FORMAT_NAMES = {
    ".glb": "a binary glTF (GLB)",
    ".gltf": "a glTF",
    ".ply": "a PLY mesh",
    ".stl": "an STL mesh",
    ".off": "an OFF mesh",
}


def load_scene(path, max_size, scope: Scope):
    """Every triangle geometry of the file's scene, node transforms applied: parts and their materials."""
    import trimesh

    fmt = _FORMAT_NAMES[path.suffix.lower()]
    if path.stat().st_size == 0:
        raise unreadable(path, fmt, "the file is empty")
    with named_image_warnings(f"a texture of '{path.name}'"):
        image_problems, plain = _check_named_files(path, fmt, scope)
        source = str(path) if plain is None else io.BytesIO(plain)  # a glTF rewritten for trimesh (plain_gltf)
        try:
            scene = trimesh.load(
                source, file_type=path.suffix[1:].lower(), force="scene", process=False, resolver=_resolver(path, scope)
            )
        except Exception as exc:
            raise unreadable(path, fmt, exc) from None
    for problem in image_problems:
        warn(problem)

    parts, materials = [], _Materials()
    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        geom = scene.geometry.get(geom_name)
        if isinstance(geom, trimesh.Trimesh) and len(geom.faces) > 0:  # not point clouds, lines
            parts.append(_geometry_part(geom, transform, geom_name, path, max_size, materials))
    return parts, materials.list


def _check_named_files(path: Path, fmt: str, scope: Scope) -> tuple[list[str], bytes | None]:
    """Refuse files outside the mesh's folder that a glTF or PLY names; the glTF's texture problems (warnings) and
    the glTF rewritten where trimesh would misread it (:func:`~.gltf.plain_gltf`; None: read the file itself)."""
    if path.suffix.lower() in (".glb", ".gltf"):
        header, binary = gltf_json(path, fmt)
        check_compression(path, header)
        check_gltf_files(path, header, scope)
        try:
            plain = plain_gltf(path, header, binary)
        except Exception:  # a malformed accessor: trimesh reads the file and says what is wrong
            plain = None
        return gltf_image_problems(path, header, binary), plain
    if path.suffix.lower() == ".ply":
        texture = _ply_texture_file(path)
        if texture is not None:
            resolve_asset(texture, path.parent, scope, "the texture file", cwd=False)
    return [], None


class _Materials:
    """The scene's materials, each added once: by trimesh material (its id) or by colour."""

    def __init__(self):
        self.list: list[Material] = []
        self.index: dict = {}  # a trimesh material (by id) or a colour → its position in the list

    def add(self, mat: Material, key) -> int:
        if key not in self.index:
            self.index[key] = len(self.list)
            self.list.append(mat)
        return self.index[key]


def _geometry_part(geom, transform, geom_name: str, path: Path, max_size, materials: _Materials) -> Part:
    """One mesh node: its vertices moved by the node's transform, its visual as materials and colours."""
    import trimesh
    from trimesh.visual import ColorVisuals, TextureVisuals

    vertices = trimesh.transform_points(np.asarray(geom.vertices, np.float64), transform)
    faces = np.asarray(geom.faces, np.int64)
    if np.linalg.det(np.asarray(transform)[:3, :3]) < 0:
        faces = faces[:, ::-1]  # a mirroring transform flips the winding: restore outward normals
    visual, n = geom.visual, len(faces)
    if isinstance(visual, TextureVisuals) and visual.material is not None:
        return _textured_part(visual, vertices, faces, geom_name, path, max_size, materials)
    if isinstance(visual, ColorVisuals) and visual.kind == "vertex":
        mi = materials.add(Material(name="vertex_colors", base_color=np.ones(4, np.float32)), "vertex_colors")
        return Part(vertices, faces, np.full(n, mi), None, _color_array(visual.vertex_colors, len(vertices)))
    if isinstance(visual, ColorVisuals) and visual.kind == "face":
        return _face_color_part(visual, vertices, faces, materials)
    return Part(vertices, faces, np.full(n, materials.add(Material(base_color=default_rgba()), "default")))


def _textured_part(visual, vertices, faces, geom_name: str, path: Path, max_size, materials: _Materials) -> Part:
    """A geometry with a material: its maps need UVs, else the material keeps only its factors."""
    uv = getattr(visual, "uv", None)
    has_uv = uv is not None and len(uv) == len(vertices)
    mat, key = _material_from_trimesh(visual.material, max_size, path, geom_name), id(visual.material)
    if not has_uv and any(x is not None for x in (mat.image, mat.metallic_roughness_image, mat.normal_image)):
        if mat.image is not None:
            warn(f"'{geom_name}' in '{path.name}' has a texture but no UV coordinates; using its base colour")
        mat, key = replace(mat, image=None, metallic_roughness_image=None, normal_image=None), (key, "no-uv")
    face_uvs = np.asarray(uv, np.float64)[faces].astype(np.float32) if has_uv else None
    colors = _color_array(visual.vertex_attributes.get("color"), len(vertices))
    return Part(vertices, faces, np.full(len(faces), materials.add(mat, key)), face_uvs, colors)


def _face_color_part(visual, vertices, faces, materials: _Materials) -> Part:
    """A geometry with a colour per face: a material per colour while there are few, else vertex colours."""
    n = len(faces)
    fc = _color_array(visual.face_colors, n)
    uniq, inv = np.unique(np.round(fc * 255).astype(np.int64), axis=0, return_inverse=True)
    if len(uniq) <= 64:  # a few colours: one material each
        mi = [
            materials.add(
                Material(name=f"face_color_{k}", base_color=np.array([*c / 255.0, 1.0], np.float32)), ("face", tuple(c))
            )
            for k, c in enumerate(uniq)
        ]
        return Part(vertices, faces, np.asarray(mi)[inv.reshape(-1)])
    # many colours: give every face its own three vertices
    mi = materials.add(Material(name="vertex_colors", base_color=np.ones(4, np.float32)), "vertex_colors")
    return Part(
        vertices[faces].reshape(-1, 3), np.arange(3 * n).reshape(-1, 3), np.full(n, mi), None, np.repeat(fc, 3, axis=0)
    )


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
            warn(
                f"the {what} texture of material '{name}' in '{path.name}' could not be decoded "
                f"({type(exc).__name__}: {exc}); continuing without it"
            )
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
    if _is_trimesh_placeholder(getattr(tm, "image", None)):  # trimesh's stand-in for UVs without a texture
        return Material(name="default", base_color=default_rgba())
    image, diffuse = img(getattr(tm, "image", None), "diffuse"), getattr(tm, "diffuse", None)
    base = np.ones(4, np.float32) if image is not None or diffuse is None else _rgba(diffuse)
    return Material(name=name, base_color=base, image=image)


def _is_trimesh_placeholder(pil) -> bool:
    """Is this trimesh's ``color_image()`` default: 2x2 RGBA, every pixel (100, 100, 100, 255)?"""
    try:
        return (
            pil is not None
            and pil.size == (2, 2)
            and pil.mode == "RGBA"
            and bool(np.all(np.asarray(pil) == (100, 100, 100, 255)))
        )
    except Exception:
        return False


def _resolver(path: Path, scope: Scope):
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
            return line[at + len("texturefile") :].strip() or None
    return None

"""Write meshes to disk: OBJ + MTL + PNG (:func:`save_obj`) and binary glTF (:func:`save_glb`).

Every writer is atomic (:func:`~sin3dm_lite.files.atomic_write`, :func:`~sin3dm_lite.files.atomic_folder`): a
failure or a kill never leaves a half-written output behind. :func:`~.load.load_mesh` reads everything written here.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..data.mesh import Material, TexturedMesh, unique_rows
from ..errors import Sin3DMInputError
from ..files import atomic_folder, atomic_write
from .images import array_to_pil

FORMATS = ("obj", "glb")


def export_mesh(mesh: TexturedMesh, out_dir, name: str = "mesh", formats=FORMATS) -> dict[str, Path]:
    """Write ``out_dir/<name>.obj`` (with its ``.mtl`` and texture ``.png``) and/or ``out_dir/<name>.glb``, all
    moved into place only once complete (:func:`~sin3dm_lite.files.atomic_folder`); returns ``{format: path}``."""
    formats = (formats,) if isinstance(formats, str) else tuple(formats)
    unknown = [f for f in formats if f not in FORMATS]
    if unknown or not formats:
        raise Sin3DMInputError(f"unknown export format(s) {unknown or formats}; choose from {', '.join(FORMATS)}")
    if not name or Path(name).name != name:
        raise Sin3DMInputError(f"name must be a plain file name without folders, got {name!r}")
    out_dir = Path(out_dir).expanduser()
    if out_dir.exists() and not out_dir.is_dir():
        raise Sin3DMInputError(f"'{out_dir}' is a file; export_mesh needs a folder to write into")
    with atomic_folder(out_dir) as tmp:
        if "obj" in formats:
            save_obj(mesh, tmp / f"{name}.obj")
        if "glb" in formats:
            save_glb(mesh, tmp / f"{name}.glb")
    return {fmt: out_dir / f"{name}.{fmt}" for fmt in formats}


def baked_image(mat: Material) -> np.ndarray:
    """The material's texture with its RGB factor multiplied in (what a viewer shows)."""
    return np.clip(mat.image * np.asarray(mat.base_color, np.float32)[:3], 0.0, 1.0)


def split_corners(faces: np.ndarray, face_uvs: np.ndarray):
    """Give every distinct (vertex, uv) pair its own vertex, as GLB and trimesh need.

    Returns ``(vertex_of (N,), uv (N, 2), new_faces (F, 3))``.
    """
    corner_v = faces.reshape(-1).astype(np.int64)
    corner_uv = np.ascontiguousarray(np.nan_to_num(face_uvs.reshape(-1, 2)).astype(np.float32) + 0.0)
    key = np.column_stack([corner_v, corner_uv.view(np.int64).reshape(-1)])  # (vertex, uv bits)
    first, inverse = unique_rows(key)
    return corner_v[first], corner_uv[first].astype(np.float64), inverse.reshape(-1, 3)


def _prepare_output(path, suffix):
    """``path`` as a Path after checking its suffix; its folder is created."""
    path = Path(path).expanduser()
    if path.suffix.lower() != suffix:
        raise Sin3DMInputError(
            f"'{path.name}' should end in '{suffix}' (got '{path.suffix or '(none)'}'); "
            f"pick a file name like '{path.stem}{suffix}'"
        )
    if path.is_dir():
        raise Sin3DMInputError(f"'{path}' is a directory; give a file name")
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def _safe_name(name: str, used: set) -> str:
    """``name`` reduced to ``[A-Za-z0-9_.-]``, made unique among ``used`` (and added to it)."""
    base = re.sub(r"[^A-Za-z0-9_.\-]+", "_", str(name or "material")).strip("_") or "material"
    out, k = base, 1
    while out in used:
        out, k = f"{base}_{k}", k + 1
    used.add(out)
    return out


def save_obj(mesh: TexturedMesh, path) -> Path:
    """Write ``path`` (.obj) with ``<stem>.mtl`` and the textures as PNGs beside it.

    Faces keep their order and per-corner UVs (``f v/vt``), so no vertex is split. A texture is written with the
    colour factor multiplied in and ``Kd 1 1 1``: viewers disagree on whether ``Kd`` tints ``map_Kd``, this way
    they all agree. PBR maps become ``map_Pr``/``map_Pm`` (grey PNGs) and ``map_Bump``.
    """
    path = _prepare_output(path, ".obj")
    used_names: set = set()
    names = [_safe_name(m.name, used_names) for m in mesh.materials]
    with atomic_folder(path.parent) as folder:  # images and the .mtl are moved first, the .obj last
        _write_mtl(mesh, folder, path.stem, names)
        _write_obj_lines(mesh, folder, path.stem, names)
    return path


def _write_mtl(mesh: TexturedMesh, folder: Path, stem: str, names: list[str]) -> None:
    """``<stem>.mtl`` and the PNGs its materials name (see :func:`save_obj`)."""
    lines = ["# written by sin3dm-lite", ""]
    single_texture = sum(m.image is not None for m in mesh.materials) == 1
    baked: dict = {}  # (image, factor) → file: materials sharing an atlas share its PNG
    for k, mat in enumerate(mesh.materials):
        prefix = stem if (single_texture and mat.image is not None) else f"{stem}_{k}"
        c = np.asarray(mat.base_color, np.float64)
        kd, maps = _material_maps(mat, mesh.face_uvs is not None, folder, prefix, baked)
        lines += [
            f"newmtl {names[k]}",
            "Ka 0.000000 0.000000 0.000000",
            "Kd {:.6f} {:.6f} {:.6f}".format(*kd),
            "Ks 0.000000 0.000000 0.000000",
            "Ns 10.000000",
            f"d {float(c[3]) if len(c) > 3 else 1.0:.6f}",
            "illum 1",
            f"Pr {float(mat.roughness):.6f}",
            f"Pm {float(mat.metallic):.6f}",
            *maps,
            "",
        ]
    (folder / f"{stem}.mtl").write_text("\n".join(lines), encoding="utf-8")


def _material_maps(mat: Material, has_uv: bool, folder: Path, prefix: str, baked: dict):
    """Write a material's textures as ``<prefix>…png``; returns its ``Kd`` and its MTL map lines."""
    kd, maps = tuple(np.clip(np.asarray(mat.base_color, np.float64)[:3], 0, 1)), []
    if not has_uv:
        return kd, maps
    if mat.image is not None:
        key = (id(mat.image), tuple(np.asarray(mat.base_color, np.float32)[:3]))
        if key not in baked:
            baked[key] = f"{prefix}.png"
            array_to_pil(baked_image(mat)).save(folder / baked[key])
        maps.append(f"map_Kd {baked[key]}")
        kd = (1.0, 1.0, 1.0)
    if mat.metallic_roughness_image is not None:
        for chan, tag, factor in ((1, "Pr", float(mat.roughness)), (2, "Pm", float(mat.metallic))):
            fname = f"{prefix}_{'roughness' if chan == 1 else 'metallic'}.png"
            array_to_pil(mat.metallic_roughness_image[:, :, chan] * factor).save(folder / fname)  # grey
            maps.append(f"map_{tag} {fname}")
    if mat.normal_image is not None:
        array_to_pil(mat.normal_image).save(folder / f"{prefix}_normal.png")
        maps.append(f"map_Bump -bm 1.000000 {prefix}_normal.png")
    return kd, maps


def _write_obj_lines(mesh: TexturedMesh, folder: Path, stem: str, names: list[str]) -> None:
    """``<stem>.obj``: every distinct corner UV once (faces without UVs hold NaN), faces in their order."""
    faces, fm = np.asarray(mesh.faces, np.int64), np.asarray(mesh.face_material, np.int64)
    has_uv = mesh.face_uvs is not None
    fuv = np.asarray(mesh.face_uvs, np.float32) if has_uv else np.full((len(faces), 3, 2), np.nan, np.float32)
    face_has_uv = np.isfinite(fuv).all(axis=(1, 2))
    first, inv = unique_rows(fuv[face_has_uv].reshape(-1, 2))
    uv_index = np.zeros((len(faces), 3), np.int64)
    uv_index[face_has_uv] = inv.reshape(-1, 3)
    colors = _baked_vertex_colors(mesh)
    with open(folder / f"{stem}.obj", "w", encoding="utf-8", newline="\n") as fh:
        fh.write(f"# written by sin3dm-lite: {len(mesh.vertices)} vertices, {len(faces)} faces\n")
        fh.write(f"mtllib {stem}.mtl\no {_safe_name(mesh.name, set())}\n")
        if colors is None:
            _write_rows(fh, "v %.9g %.9g %.9g\n", mesh.vertices)
        else:
            _write_rows(fh, "v %.9g %.9g %.9g %.6f %.6f %.6f\n", np.hstack([mesh.vertices, colors]))
        _write_rows(fh, "vt %.9g %.9g\n", fuv[face_has_uv].reshape(-1, 2)[first])
        # runs of faces with the same material and the same has-uv flag, in the original order
        change = np.flatnonzero((np.diff(fm) != 0) | (np.diff(face_has_uv.astype(np.int8)) != 0)) + 1
        last = None
        for a, b in zip(np.r_[0, change], np.r_[change, len(faces)]):
            if fm[a] != last:
                fh.write(f"usemtl {names[fm[a]]}\n")
                last = fm[a]
            if face_has_uv[a]:
                block = np.stack([faces[a:b] + 1, uv_index[a:b] + 1], axis=2).reshape(b - a, 6)
                _write_rows(fh, "f %d/%d %d/%d %d/%d\n", block)
            else:
                _write_rows(fh, "f %d %d %d\n", faces[a:b] + 1)


def _write_rows(fh, row_format: str, array: np.ndarray, chunk: int = 65536) -> None:
    """Write every row of ``array`` with ``row_format`` (much faster than ``np.savetxt``)."""
    values = array.tolist()
    for start in range(0, len(values), chunk):
        part = values[start : start + chunk]
        fh.write((row_format * len(part)) % tuple(x for row in part for x in row))


def _baked_vertex_colors(mesh: TexturedMesh) -> np.ndarray | None:
    """Vertex colours times the factor of the (untextured) material that uses each vertex (the first one wins):
    OBJ vertex colours replace ``Kd`` when read back, so the factor goes into the colours."""
    if mesh.vertex_colors is None:
        return None
    factor = np.ones((len(mesh.vertices), 3), np.float32)
    for k, mat in reversed(list(enumerate(mesh.materials))):  # reversed: lower material index wins
        if mat.image is None or mesh.face_uvs is None:
            idx = np.unique(mesh.faces[mesh.face_material == k])
            factor[idx] = np.asarray(mat.base_color, np.float32)[:3]
    return np.clip(mesh.vertex_colors * factor, 0, 1)


def save_glb(mesh: TexturedMesh, path) -> Path:
    """Write a binary glTF: the scene of :func:`to_trimesh_scene`, one primitive per material."""
    path = _prepare_output(path, ".glb")
    atomic_write(path, to_trimesh_scene(mesh).export(file_type="glb"))
    return path


def to_trimesh_scene(mesh: TexturedMesh):
    """A ``trimesh.Scene`` of the mesh, one geometry per material with a PBR metallic-roughness material.

    Textured materials split vertices where a vertex has several UVs; an untextured material with vertex colours
    becomes vertex colours (factor multiplied in); otherwise a plain ``baseColorFactor``.
    """
    import trimesh
    from trimesh.visual import ColorVisuals, TextureVisuals
    from trimesh.visual.material import PBRMaterial

    scene, used_names = trimesh.Scene(), set()
    for k, mat in enumerate(mesh.materials):
        sel = np.flatnonzero(mesh.face_material == k)
        if len(sel) == 0:
            continue
        maps = {
            "baseColorTexture": mat.image,
            "metallicRoughnessTexture": mat.metallic_roughness_image,
            "normalTexture": mat.normal_image,
        }
        maps = {key: array_to_pil(m) for key, m in maps.items() if m is not None and mesh.face_uvs is not None}
        # uint8 on purpose: trimesh reads a list of ints as 0..255
        factor = trimesh.visual.color.to_rgba(np.clip(np.asarray(mat.base_color, np.float64), 0, 1))
        pbr = PBRMaterial(
            name=mat.name,
            baseColorFactor=factor,
            metallicFactor=float(mat.metallic),
            roughnessFactor=float(mat.roughness),
            **maps,
        )
        if maps:
            vertex_of, uv, faces = split_corners(mesh.faces[sel], mesh.face_uvs[sel])
            visual = TextureVisuals(uv=uv, material=pbr)
        else:
            vertex_of, faces = np.unique(mesh.faces[sel], return_inverse=True)
            visual = TextureVisuals(material=pbr)
            if mesh.vertex_colors is not None:
                col = np.clip(mesh.vertex_colors[vertex_of] * np.asarray(mat.base_color, np.float32)[:3], 0, 1)
                rgba = np.column_stack([np.round(col * 255), np.full(len(col), factor[3])]).astype(np.uint8)
                visual = ColorVisuals(vertex_colors=rgba)
        geom = trimesh.Trimesh(mesh.vertices[vertex_of], faces.reshape(-1, 3), visual=visual, process=False)
        gname = _safe_name(f"{mesh.name}_{mat.name}", used_names)
        scene.add_geometry(geom, geom_name=gname, node_name=gname)
    if not scene.geometry:
        raise Sin3DMInputError(f"mesh '{mesh.name}' has no faces to write")
    return scene


__all__ = ["FORMATS", "baked_image", "export_mesh", "save_glb", "save_obj", "split_corners", "to_trimesh_scene"]

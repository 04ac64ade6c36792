"""Wavefront OBJ, parsed here rather than by trimesh, so face order, vertex order and UV indices stay the file's.

Each keyword (``v``, ``vt``, ``f``, ``usemtl``, ``mtllib``) is found with one regular-expression scan of the whole
text rather than a Python loop over lines; the material libraries are read by :mod:`.mtl`.
"""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np

from ..data.mesh import Material, default_rgba
from .common import Part, Scope, unreadable, warn
from .mtl import read_libraries

OBJ = "a Wavefront OBJ"


def load_obj(path, max_size, scope: Scope):
    """A Wavefront OBJ (+ MTL) → one part and its materials."""
    text = _obj_text(path)
    v_rows, v_pos = _scan(text, "v")
    vt_rows, vt_pos = _scan(text, "vt")
    fv, ft, fm, mat_names = _faces_by_material(path, text, v_pos, vt_pos)
    vertices, colors = _obj_vertices(path, v_rows)
    uvs = np.nan_to_num(_obj_numbers(path, vt_rows, "vt", 1, width=2)[:, :2])
    if len(fv) and fv.max() >= len(vertices):
        raise unreadable(
            path, OBJ, f"a face refers to vertex {fv.max() + 1} but the file defines only {len(vertices)} vertices"
        )
    if len(ft) and ft.max() >= len(uvs):
        raise unreadable(
            path,
            OBJ,
            f"a face refers to texture coordinate {ft.max() + 1} but the file defines only {len(uvs)} ('vt' lines)",
        )
    library, loaded_any = read_libraries(_scan(text, "mtllib")[0], path, set(mat_names), scope, max_size)
    materials, uv_transforms, order = _obj_materials(path, mat_names, library, loaded_any, colors)
    face_material = np.argsort(order)[fm]
    face_uvs = _obj_face_uvs(uvs, ft, face_material, uv_transforms)
    return [Part(vertices, fv, face_material, face_uvs, colors)], materials


def _obj_text(path) -> str:
    """The file as text with ``\\n`` line ends, continuation lines joined, a newline in front (for the scans)."""
    data = path.read_bytes()
    if b"\x00" in data[:65536]:
        raise unreadable(path, OBJ, "it contains binary data, an OBJ file is text")
    text = data.decode("utf-8", errors="replace").replace("\r\n", "\n").replace("\r", "\n")
    return "\n" + text.replace("\\\n", " ")  # joins "\" continuation lines


def _scan(text: str, keyword: str):
    """The rest of every line that starts with ``keyword``, and where each line starts in ``text``."""
    found = list(re.finditer(rf"^[ \t]*{keyword}[ \t]+([^\n]*)", text, re.MULTILINE))
    return [m.group(1) for m in found], np.fromiter((m.start() for m in found), np.int64, len(found))


def _faces_by_material(path, text: str, v_pos: np.ndarray, vt_pos: np.ndarray):
    """Triangles of vertex and uv indices (:func:`_obj_faces`), each face's material slot, and the names of the
    slots faces use (``None``: faces before any ``usemtl``)."""
    f_rows, f_pos = _scan(text, "f")
    use_names, use_pos = _scan(text, "usemtl")
    # the material slot in force at each face: that of the last usemtl before it (slot 0: none yet)
    mat_names = [None, *dict.fromkeys(name.strip() for name in use_names)]
    slot_of = {name: slot for slot, name in enumerate(mat_names)}
    use_slot = np.array([0] + [slot_of[name.strip()] for name in use_names], np.int64)
    info = np.stack(
        [
            f_pos,
            use_slot[np.searchsorted(use_pos, f_pos)],
            np.searchsorted(v_pos, f_pos),
            np.searchsorted(vt_pos, f_pos),
        ],
        axis=1,
    )
    fv, ft, fm = _obj_faces(path, f_rows, info, line_of=lambda pos: text.count("\n", 0, pos))
    used_slots, fm = np.unique(fm, return_inverse=True)  # keep only the material slots faces use
    return fv, ft, fm, [mat_names[i] for i in used_slots]


def _obj_materials(path, mat_names: list, library: dict, loaded_any: bool, colors):
    """One :class:`Material` per used name, ordered as the MTL defines them (the file's intent), undefined ones
    last; returns the materials, their uv transforms and ``order`` (slot of each material)."""
    lib_order = {name: i for i, name in enumerate(library)}
    order = sorted(range(len(mat_names)), key=lambda i: (lib_order.get(mat_names[i], len(lib_order)), i))
    materials, uv_transforms = [], []
    for mname in (mat_names[i] for i in order):
        mat, uv_t = library.get(mname, (None, None))
        if mat is None:
            if mname is not None and loaded_any:
                warn(f"material '{mname}' used in '{path.name}' is not defined in its .mtl file; using a plain colour")
            mat = Material(name=mname or "default", base_color=default_rgba())
        if colors is not None and mat.image is None:  # vertex colours replace Kd
            mat = replace(mat, base_color=np.array([1, 1, 1, mat.base_color[3]], np.float32))
        materials.append(mat)
        uv_transforms.append(uv_t)
    return materials, uv_transforms, order


def _obj_face_uvs(uvs: np.ndarray, ft: np.ndarray, face_material: np.ndarray, uv_transforms: list):
    """Per-corner UVs ``(F, 3, 2)`` (NaN where a face has none, each material's ``-s``/``-o`` applied), or None."""
    if not (len(uvs) and (ft >= 0).any()):
        return None
    face_uvs = np.where((ft >= 0)[..., None], uvs[np.maximum(ft, 0)], np.nan).astype(np.float32)
    for mi, t in enumerate(uv_transforms):
        if t is not None:
            sel = face_material == mi
            face_uvs[sel] = face_uvs[sel] * t[0] + t[1]
    return face_uvs


def _from_lowest(row: str) -> list[str]:
    """A face line's corners, turned round to start at its lowest vertex index: a polygon listed again the other way
    round (a two-sided export) is then cut into the same triangles, which the loader keeps once."""
    c = row.split()
    try:
        k = min(range(len(c)), key=lambda i: int(c[i].split("/")[0]))
    except ValueError:
        return c  # a bad index, reported by the caller
    return c[k:] + c[:k]


def _obj_faces(path, rows: list[str], info: np.ndarray, line_of):
    """Face lines → triangles ``(F, 3)`` of vertex and uv indices (0-based; uv -1: none) and material slots.

    ``info`` holds, for each line, its position in the text, its material slot and how many vertices and uvs were
    defined before it (negative indices count back from there). Polygons are fan-triangulated
    (:func:`_from_lowest`), lines with fewer than three corners skipped; files with one index layout (the usual
    case) are parsed in one vectorised step.
    """
    counts = np.array([len(row.split()) for row in rows], np.int64)  # corners per line
    line = np.repeat(np.arange(len(rows)), np.maximum(counts - 2, 0))  # the line of each triangle
    if (counts == 3).all():
        tri = " ".join(rows).split()
    else:  # fan triangulation from each polygon's lowest vertex index
        tri = [t for c in map(_from_lowest, rows) for k in range(1, len(c) - 1) for t in (c[0], c[k], c[k + 1])]
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
        raise unreadable(
            path,
            OBJ,
            f"line {line_of(info[i, 0])}: bad face 'f {rows[i].strip()[:80]}' (an index is "
            "not a number, is 0, or points before the first vertex)",
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
        raise unreadable(path, OBJ, f"bad '{what}' line: {exc}") from None


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

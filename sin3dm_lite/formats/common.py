"""What every mesh reader shares: the folder a mesh file may read from, errors and warnings, assembly.

A reader (:mod:`.obj`, :mod:`.scene`) returns a list of :class:`Part` and the materials they index; :func:`assemble`
joins them into one :class:`~sin3dm_lite.data.mesh.TexturedMesh` and refuses what Sin3DM cannot learn from. Bad
input raises a :class:`~sin3dm_lite.errors.Sin3DMInputError` naming the problem and the fix; a missing texture is a
``UserWarning`` (:func:`warn`) and the material keeps its plain colour.
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..data.mesh import MAX_COORDINATE, Material, TexturedMesh, face_areas, unique_rows
from ..errors import Sin3DMInputError
from ..files.inputs import check_regular, not_regular
from .repair import first_listing


@dataclass(frozen=True)
class Scope:
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


def unreadable(path, what: str, exc: BaseException | str) -> Sin3DMInputError:
    """The error for a file that cannot be read as ``what`` (``"a Wavefront OBJ"``), ``exc`` saying why."""
    detail = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
    return Sin3DMInputError(
        f"could not read '{path.name}' as {what} ({detail}); the file may be corrupt, truncated or "
        "not what its extension says; re-export it from the program that made it"
    )


def warn(message: str) -> None:
    """``warnings.warn`` attributed to the first caller outside this package (the user's line)."""
    level, frame = 2, sys._getframe(1)  # stacklevel 2 = the caller of warn
    while frame is not None and f"{frame.f_globals.get('__name__', '')}.".startswith(f"{__package__}."):
        frame, level = frame.f_back, level + 1  # a frame of this package: one more level up
    warnings.warn(message, UserWarning, stacklevel=level)


def resolve_asset(ref: str, base: Path, scope: Scope, what: str, cwd: bool = True) -> Path | None:
    """Find a file a mesh file names: as written (relative to ``base``, else to the working directory if ``cwd``),
    then by its base name (also ignoring case) in ``base``; None if there is none.

    Files outside ``scope`` are skipped, and refused if no other is found; a FIFO or a device is refused.
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
        if not_regular(candidate) not in (None, "a folder"):  # a FIFO or a device would block the reader forever
            check_regular(candidate, what)
        if candidate.is_file():
            if scope.allows(candidate):
                return candidate
            outside = outside or candidate
    if outside is not None:
        raise scope.refuse(ref.strip(), what, outside)
    return None


@dataclass
class Part:
    """A piece of a mesh as read from a file, before concatenation."""

    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64, into this part's vertices
    face_material: np.ndarray  # (F,) int64, into the shared material list
    face_uvs: np.ndarray | None = None  # (F, 3, 2)
    vertex_colors: np.ndarray | None = None  # (V, 3) float32


#: 32-bit coordinates that step by more than this share of the shape's size lose detail a fine grid would show
COARSE_STEP = 1e-3


def _warn_if_coarse(vertices: np.ndarray, source: str) -> None:
    """Warn where a file stores 32-bit coordinates so far from the origin that they step coarsely across the shape
    (a scan exported in map coordinates): the detail is lost in the file, before the loader sees it."""
    if not np.array_equal(vertices, vertices.astype(np.float32)):
        return  # more digits than 32 bits hold: the file kept its detail
    size = float(np.ptp(vertices, axis=0).max())
    far = float(np.abs(vertices).max())
    step = float(np.spacing(np.float32(far)))
    if step > COARSE_STEP * size:
        warn(
            f"'{source}' lies {far:.3g} from the origin, where its 32-bit coordinates step by {step:.3g} "
            f"({step / size:.1%} of its size): detail finer than that was lost when the file was written; export it "
            "again near the origin (Blender: Object > Set Origin > Origin to Geometry, then Location 0, 0, 0; a "
            "scanning tool's local-coordinates option)"
        )


def _read_once(vertices: np.ndarray, faces: np.ndarray, source: str) -> np.ndarray:
    """The faces to keep (:func:`~.repair.first_listing`), and a warning where some repeat another: a two-sided
    export lists each face again wound the other way, and the pairs would cancel in the winding number that tells
    the grid inside from outside."""
    once = first_listing(vertices, faces)
    if len(once) < len(faces):
        warn(
            f"{len(faces) - len(once):,} of the {len(faces):,} triangles of '{source}' repeat another (a two-sided "
            "export lists every face again, wound the other way, and the two would cancel): each is read once"
        )
    return once


def assemble(parts: list[Part], materials: list[Material], name: str, source: str) -> TexturedMesh:
    """Concatenate parts, validate, keep each triangle once (:func:`first_listing`), drop unreferenced vertices,
    weld duplicates."""
    parts = [p for p in parts if len(p.faces)]
    if not parts:
        raise Sin3DMInputError(
            f"'{source}' contains no triangle faces (an empty file, a point cloud or lines only, or a corrupt file); "
            "Sin3DM needs a surface mesh: export the faces (re-export a corrupt file), or reconstruct a surface from "
            "the points first"
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

    once = _read_once(vertices, faces, source)
    faces, face_material = faces[once], face_material[once]
    face_uvs = face_uvs[once] if face_uvs is not None else None

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

    if (vertices.max(0) - vertices.min(0)).max() <= 0:
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
    _warn_if_coarse(vertices, source)
    if not face_areas(vertices, faces).sum() > 0:
        raise Sin3DMInputError(
            f"'{source}' has zero surface area (every triangle is degenerate: collinear or repeated "
            "vertices); Sin3DM needs a surface mesh"
        )

    used_materials, face_material = np.unique(face_material, return_inverse=True)  # unused ones may hold big images
    if face_uvs is not None and not np.isfinite(face_uvs).any():
        face_uvs = None
    return TexturedMesh(
        vertices=vertices,
        faces=faces,
        face_material=face_material,
        materials=[materials[i] for i in used_materials],
        face_uvs=face_uvs,
        vertex_colors=colors,
        name=name,
    )

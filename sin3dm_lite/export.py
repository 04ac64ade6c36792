"""Write generated meshes to disk: OBJ + MTL + PNG and binary glTF (GLB).

The writers themselves live in :mod:`sin3dm_lite.mesh_io` (``save_obj``,
``save_glb``); this module puts one shape's files into a folder *atomically*:
everything is written into a temporary folder next to the target first and
moved into place only when every file is complete, so a failure (disk full,
bad texture) never leaves a half-written output folder behind.

PBR maps of a material (``metallic_roughness_image``, ``normal_image``) go
into the GLB's metallic-roughness material; the OBJ writes them as
``map_Pr`` / ``map_Pm`` / ``map_Bump`` PNGs (see ``mesh_io.save_obj``).
"""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from . import mesh_io
from .errors import Sin3DMInputError
from .mesh_io import TexturedMesh

FORMATS = ("obj", "glb")


def export_mesh(mesh: TexturedMesh, out_dir, name: str = "mesh", formats=FORMATS) -> dict[str, Path]:
    """Write ``out_dir/<name>.obj`` (with its ``.mtl`` and texture ``.png``) and/or ``out_dir/<name>.glb``.

    Files are written into a temporary folder beside ``out_dir`` and moved
    into place only after all of them are complete. A new ``out_dir``
    appears in one rename; into an existing one each file is moved with an
    atomic replace (other files there are left alone).

    Returns:
        ``{format: path}`` of the main file of each format (the OBJ's MTL and
        PNG lie beside it).
    """
    formats = (formats,) if isinstance(formats, str) else tuple(formats)
    unknown = [f for f in formats if f not in FORMATS]
    if unknown or not formats:
        raise Sin3DMInputError(f"unknown export format(s) {unknown or formats}; choose from {', '.join(FORMATS)}")
    if not name or Path(name).name != name:
        raise Sin3DMInputError(f"name must be a plain file name without folders, got {name!r}")
    out_dir = Path(out_dir).expanduser()
    if out_dir.exists() and not out_dir.is_dir():
        raise Sin3DMInputError(f"'{out_dir}' is a file; export_mesh needs a folder to write into")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".partial", dir=out_dir.parent))
    tmp.chmod(0o755)  # mkdtemp makes it private; the result is an ordinary folder
    try:
        if "obj" in formats:
            mesh_io.save_obj(mesh, tmp / f"{name}.obj")
        if "glb" in formats:
            mesh_io.save_glb(mesh, tmp / f"{name}.glb")
        if not out_dir.exists():
            os.replace(tmp, out_dir)  # the whole folder appears at once
        else:
            # the .obj last: it only appears once the files it names are there
            for item in sorted(tmp.iterdir(), key=lambda p: (p.suffix == ".obj", p.name)):
                os.replace(item, out_dir / item.name)
            tmp.rmdir()
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {fmt: out_dir / f"{name}.{fmt}" for fmt in formats}


__all__ = ["FORMATS", "export_mesh"]

"""Reading a mesh file: ``load_mesh`` and ``load_any``, and the namespace ``sin3dm_lite.mesh_io``.

Whatever its format, a mesh is read into a :class:`~sin3dm_lite.data.mesh.TexturedMesh` in the file's own
coordinates (:meth:`TexturedMesh.normalized` then puts it into the paper's box). ``from sin3dm_lite import
mesh_io`` gives this module, which also carries the mesh types and image helpers, so a notebook finds everything
about meshes in one namespace. The writers are in :mod:`sin3dm_lite.formats.export`.
"""

from __future__ import annotations

from pathlib import Path

from ..data.mesh import (  # noqa: F401
    BOX_MARGIN,
    DEFAULT_COLOR,
    Material,
    Normalization,
    TexturedMesh,
    sample_texture,
    tangent_frames,
    unique_rows,
)
from ..errors import Sin3DMInputError
from ..files.inputs import check_regular
from .common import Scope, assemble
from .images import array_to_pil, image_to_array  # noqa: F401
from .obj import load_obj
from .scene import load_scene

# Colour, in every format: a textured face is ``texture(uv) * base_color``, else ``vertex colour * base_color``
# with vertex colours, else ``base_color`` (DEFAULT_COLOR without any colour information). Where a format says a
# texture or vertex colours *replace* the colour (OBJ's ``map_Kd`` and ``v x y z r g b`` replace ``Kd``), the
# loader stores a white factor, so these rules give what a viewer shows.

#: File extensions :func:`load_mesh` reads.
SUPPORTED_EXTENSIONS = (".obj", ".glb", ".gltf", ".ply", ".stl", ".off")
#: The same formats in words, for help texts.
READABLE = "OBJ (+MTL), GLB/glTF, PLY, STL, OFF"

#: Textures larger than this (longest side, pixels) are shrunk on load: a 256³ grid never needs more.
MAX_TEXTURE_SIZE = 4096


def load_mesh(
    path, *, max_texture_size: int | None = MAX_TEXTURE_SIZE, allow_outside_paths: bool = False
) -> TexturedMesh:
    """Read a textured mesh file into a :class:`TexturedMesh` (the file's own coordinates).

    * ``.obj`` (+ ``.mtl`` + images): textures, colours, several materials, per-corner UVs, vertex colours and the
      PBR extensions, parsed here (:mod:`.obj`) so that face order, vertex order and UV indices are the file's;
    * ``.glb`` / ``.gltf``: every mesh node with its transform, every primitive with its PBR material;
    * ``.ply``: vertex or face colours; ``.stl`` / ``.off``: geometry only.

    Identical vertices are welded, unreferenced ones dropped, a triangle listed twice (a two-sided export) kept
    once, polygons fan-triangulated. A missing or unreadable texture is a ``UserWarning`` and the material keeps
    its plain colour; textures become float32 RGB in [0, 1], shrunk to ``max_texture_size`` (``None``: never). A
    file the mesh names outside its own folder is refused unless ``allow_outside_paths=True``. Any bad input
    raises a :class:`Sin3DMInputError`.
    """
    path = check_input_path(path)
    load = load_obj if path.suffix.lower() == ".obj" else load_scene
    return assemble(*load(path, max_texture_size, Scope(path, allow_outside_paths)), name=path.stem, source=path.name)


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


def check_input_path(path) -> Path:
    """``path`` as a ``Path`` to an existing file with a readable extension; a clear error otherwise."""
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
    check_regular(path, "a mesh")
    if path.suffix.lower() not in SUPPORTED_EXTENSIONS:
        raise Sin3DMInputError(
            f"'{path.name}' has an unsupported extension '{path.suffix or '(none)'}'; supported mesh "
            f"formats are {', '.join(SUPPORTED_EXTENSIONS)}; convert the file (for example File > Export "
            "in Blender) or rename it if the extension is wrong"
        )
    return path

"""Reading a mesh file: ``load_mesh`` and ``load_any``, and the namespace ``sin3dm_lite.mesh_io``.

Sin3DM learns from one textured shape; whatever its file format, it is read
into a :class:`~sin3dm_lite.data.mesh.TexturedMesh` in the file's own
coordinates (:meth:`TexturedMesh.normalized` then puts it into the paper's box).
The readers themselves are in :mod:`sin3dm_lite.formats`.

``from sin3dm_lite import mesh_io`` gives this module, which also carries
the mesh types and the image helpers, so a notebook finds everything about
meshes and their files in one namespace::

    mesh_io.load_mesh(path, *, max_texture_size=4096, allow_outside_paths=False)   # .obj .glb .gltf .ply .stl .off
    mesh_io.load_any(source)            # a path, or a TexturedMesh (returned as is)
    mesh_io.SUPPORTED_EXTENSIONS, mesh_io.READABLE, mesh_io.BOX_MARGIN
    mesh_io.TexturedMesh, Material, Normalization, tangent_frames, sample_texture, unique_rows
    mesh_io.image_to_array(image, max_size=None), array_to_pil(array, max_size=None)

The writers (``save_obj``, ``save_glb``, ``export_mesh``) live in
:mod:`sin3dm_lite.formats.export`.

Bad input raises one :class:`~sin3dm_lite.errors.Sin3DMInputError` whose
message names the problem and the fix; a missing or unreadable texture is a
``UserWarning`` and the material falls back to its plain colour.
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


def load_mesh(
    path, *, max_texture_size: int | None = MAX_TEXTURE_SIZE, allow_outside_paths: bool = False
) -> TexturedMesh:
    """Read a textured mesh file into a :class:`TexturedMesh` (the file's own coordinates).

    Formats (by extension, case-insensitive):

    * ``.obj`` (+ ``.mtl`` + images): ``map_Kd`` textures, ``Kd`` colours,
      several materials (each face keeps its material and its own per-corner
      UVs), vertex colours ``v x y z r g b``, PBR extensions ``Pm``/``Pr``/
      ``map_Pm``/``map_Pr``/``map_Bump``/``norm``. Parsed by us (:mod:`.formats.obj`), not by trimesh,
      so face order, vertex order and UV indices are exactly the file's
      (trimesh groups faces by material and drops a ``map_Kd`` with options:
      ``tests/test_formats.py::test_obj_reader_keeps_what_trimesh_loses``).
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
    check_regular(path, "a mesh")  # a FIFO or a device would block the reader forever
    if path.suffix.lower() not in SUPPORTED_EXTENSIONS:
        raise Sin3DMInputError(
            f"'{path.name}' has an unsupported extension '{path.suffix or '(none)'}'; supported mesh "
            f"formats are {', '.join(SUPPORTED_EXTENSIONS)}; convert the file (for example File > Export "
            "in Blender) or rename it if the extension is wrong"
        )
    return path

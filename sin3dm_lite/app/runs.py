"""One setting, ``RUN``, names the model a notebook works on; fitted runs are cached.

    model = Sin3DM.open("canyon")              # a shipped model: loaded
    model = Sin3DM.open("runs/my_vase")        # a run folder (holding model.pt): loaded
    model = Sin3DM.open("my_vase.glb")         # a mesh file: fitted once into the cache, then loaded
    model = Sin3DM.open("colonnade")           # an example without a shipped model: the same

What ``RUN`` may be, checked in this order:

1. the name of a shipped model (``canyon`` or ``canyon_small``, :func:`pretrained.shipped_names`), even where a
   local folder has that name (a warning says so; ``./canyon`` names the local one: :func:`shipped_or_folder`,
   the rule the CLI's commands follow too);
2. an existing run folder with ``model.pt`` (or a ``model.pt`` file);
3. a mesh file or the name of a built-in example: fitted with ``preset`` into
   ``cache/<stem>-<hash12>``, where the hash covers the input (what is read from the file, its MTL and
   textures included,
   or the example's name and generator seed) and the preset's JSON. The same
   input and settings find the same folder: a finished fit (``model.pt``) is
   loaded, an interrupted one (``config.json`` and checkpoints) is resumed, so
   a kernel restart reloads instead of training again.

Anything else is refused with one line that says what ``RUN`` may be.
"""

from __future__ import annotations

import hashlib
import shlex
import warnings
from pathlib import Path

import numpy as np

from ..data.config import Config
from ..errors import Sin3DMInputError
from ..formats.load import load_mesh
from ..presets import get_preset, notebook_preset

CACHE = Path("runs/cache")  # relative to the working directory (a notebook's: notebooks/)
EXAMPLE_SEED = 0  # the generator seed ``Sin3DM.fit`` builds an example with
MODEL_FILE = "model.pt"


def fit_preset(preset) -> Config:
    if preset is None:
        return notebook_preset()
    return preset if isinstance(preset, Config) else get_preset(preset)


def run_key(source, preset=None) -> str:
    """``<stem>-<hash12>``: the cache folder's name for fitting ``source`` (mesh path or example name) with ``preset``."""

    cfg = fit_preset(preset)
    h = hashlib.sha256()
    stem = _feed_input(h, source)
    h.update(b"\0config:" + cfg.to_json().encode())
    return f"{stem}-{h.hexdigest()[:12]}"


def _feed_input(h, source, mesh=None) -> str:
    """Feed what a fit of ``source`` reads to ``h`` (an example's name and seed, or the mesh with its MTL and
    textures); ``mesh``: ``source`` already loaded. Returns the input's stem (the example's name, the file's stem)."""
    from .. import examples
    from ..data.mesh import TexturedMesh

    if isinstance(source, str) and source in examples.list_examples() and not Path(source).is_file():
        h.update(f"example:{source}:seed={EXAMPLE_SEED}".encode())
        return source
    if isinstance(source, TexturedMesh):
        _hash_mesh(h, source)
        return source.name or "mesh"
    path = Path(source)
    if not path.is_file():
        raise Sin3DMInputError(f"'{source}' is neither a mesh file nor a built-in example")
    _hash_mesh(
        h, mesh if mesh is not None else load_mesh(path)
    )  # what was read, so an OBJ's MTL and textures count too
    return path.stem


def input_digest(source, mesh=None) -> str:
    """SHA-256 of what a fit of ``source`` (mesh path, ``TexturedMesh`` or example name) reads: the same input, the
    same digest, whatever the file is called; another mesh, texture or example, another digest. ``mesh``: ``source``
    already loaded (it is not read again)."""
    h = hashlib.sha256()
    _feed_input(h, source, mesh)
    return h.hexdigest()


def _hash_mesh(h, mesh) -> None:
    """Feed everything of ``mesh`` the fit reads (geometry, UVs, colours, materials and their images) to ``h``."""
    arrays = [mesh.vertices, mesh.faces, mesh.face_material, mesh.face_uvs, mesh.vertex_colors]
    for m in mesh.materials:
        arrays += [
            m.base_color,
            np.float64([m.metallic, m.roughness]),
            m.image,
            m.metallic_roughness_image,
            m.normal_image,
        ]
    for a in arrays:
        h.update(b"\0none" if a is None else np.ascontiguousarray(a).tobytes() + str(np.shape(a)).encode())


def cached_run(source, preset=None, cache: str | Path = CACHE) -> Path:
    """The cache folder a fit of ``source`` with ``preset`` goes to (it may not exist yet)."""
    return Path(cache) / run_key(source, preset)


def shipped_or_folder(run, stacklevel: int = 3) -> tuple[str, Path] | None:
    """The one rule for a name that both a shipped model and a local path may mean (``Sin3DM.open`` and the
    commands that take a RUN ask it): a bare name of a shipped model (``canyon``, ``canyon_small``, as a ``str``)
    is the shipped model; a path (``./canyon``, ``runs/canyon``, a ``Path``) is the local one. Where a local
    ``canyon`` exists beside the shipped name, a warning says which was taken and how to name the other.

    Returns ``("shipped", its folder)``, ``("folder", the run folder)`` for a folder holding ``model.pt`` (or that
    file), or None (neither: the caller says what else RUN may be). ``stacklevel``: the warning's, as
    ``warnings.warn`` takes it (3: the caller's caller).
    """
    from .pretrained import shipped_model

    name = str(run)
    shipped = shipped_model(name) if isinstance(run, str) else None
    path = Path(run).expanduser()
    if shipped is not None:
        if path.exists():
            what = "run folder" if (path / MODEL_FILE).is_file() else "folder" if path.is_dir() else "file"
            warnings.warn(
                f"'{name}' is the shipped model {shipped.name}, not the {what} '{name}' here; "
                f"for that {what}, write ./{name}",
                UserWarning,
                stacklevel=stacklevel,
            )
        return "shipped", shipped
    if path.is_dir() and (path / MODEL_FILE).is_file():
        return "folder", path
    if path.is_file() and path.name == MODEL_FILE:
        return "folder", path.parent
    return None


def resolve_run(run, preset, cache) -> tuple[str, Path]:
    """What ``run`` names: ``("shipped" | "folder", the folder to load)`` or ``("fit", the cache folder to fit into)``."""
    from .. import examples
    from .pretrained import shipped_examples

    if not isinstance(run, (str, Path)) or not str(run).strip():
        raise Sin3DMInputError(f"RUN must be a name or a path, got {run!r}")
    name = str(run)
    found = shipped_or_folder(run, stacklevel=5)  # the warning names the line that called Sin3DM.open
    if found is not None:
        return found
    path = Path(run).expanduser()
    if path.is_dir():
        raise Sin3DMInputError(
            f"RUN '{run}' is a folder without {MODEL_FILE}: an unfinished fit; continue it with "
            f"`sin3dm-lite fit MESH --out {shlex.quote(str(run))} --resume`, or set RUN to the mesh to fit it into the cache"
        )
    if path.is_file() or (isinstance(run, str) and name in examples.list_examples()):
        return "fit", cached_run(run, preset, cache)
    raise Sin3DMInputError(
        f"RUN '{run}' is not a shipped model ({', '.join(shipped_examples())}), "
        f"a run folder, a mesh file or a built-in example ({', '.join(examples.list_examples())})"
    )


__all__ = ["CACHE", "cached_run", "fit_preset", "input_digest", "resolve_run", "run_key", "shipped_or_folder"]

"""One setting, ``RUN``, names the model a notebook works on (``Sin3DM.open(RUN)``); fitted runs are cached.

``RUN`` is, in this order: the name of a shipped model (``canyon``; ``./canyon`` names a local folder); a run
folder with ``model.pt`` (or that file); a mesh file or a built-in example's name, fitted once into
``cache/<stem>-<hash12>`` (the hash covers what the fit reads and the preset), so that a kernel restart loads the
finished fit, or resumes an interrupted one, instead of training again.
"""

from __future__ import annotations

import hashlib
import shlex
import warnings
from pathlib import Path

import numpy as np

from .. import examples
from ..data.config import Config
from ..data.mesh import TexturedMesh
from ..errors import Sin3DMInputError
from ..formats.load import load_mesh
from ..presets import get_preset, notebook_preset
from .pretrained import MODEL_FILE

CACHE = Path("runs/cache")  # relative to the working directory (a notebook's: notebooks/)
EXAMPLE_SEED = 0  # the generator seed ``Sin3DM.fit`` builds an example with


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
    """Feed what a fit of ``source`` (``mesh``: already loaded) reads to ``h``; returns the input's stem."""
    if isinstance(source, str) and source in examples.list_examples() and not Path(source).is_file():
        h.update(f"example:{source}:seed={EXAMPLE_SEED}".encode())
        return source
    if isinstance(source, TexturedMesh):
        _hash_mesh(h, source)
        return source.name or "mesh"
    path = Path(source)
    if not path.is_file():
        raise Sin3DMInputError(f"'{source}' is neither a mesh file nor a built-in example")
    _hash_mesh(h, mesh if mesh is not None else load_mesh(path))  # what was read: an OBJ's MTL and textures too
    return path.stem


def input_digest(source, mesh=None) -> str:
    """SHA-256 of what a fit of ``source`` (``mesh``: already loaded) reads, whatever the file is called."""
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
    """``("shipped" | "folder", folder)`` or None: a bare ``str`` naming a shipped model is that model (a warning
    says so where a local one exists), a path (``./canyon``, a ``Path``) the local one."""
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

"""Procedurally generated textured example shapes, the package's built-in inputs.

Sin3DM recombines the local patches of *one* shape, so good inputs have local structure that recurs with
variation: strata and terraces along a canyon, bricks and merlons along a wall, columns along a colonnade.
Each shape (``canyon``, ``wall``, ``colonnade``, ``tiles``) is built from numpy, deterministic for a seed,
from closed solids (``geometry``) painted through one UV atlas (``texture``) with detail finer than its
triangles.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..data.mesh import TexturedMesh
from ..errors import Sin3DMInputError
from .canyon import build_canyon
from .colonnade import build_colonnade
from .geometry import y_up
from .tiles import build_tiles
from .wall import build_wall

#: name -> one-line description of each built-in example.
EXAMPLES = {
    "canyon": "a river canyon cut into a block: terraced cliffs banded with rock strata, steps varying along its length",
    "wall": "a crenellated brick wall: protruding bricks of varied colour in grey mortar, merlons of varied width",
    "colonnade": "four turned columns with painted rings on a stepped base, carrying a beam with a triglyph frieze",
    "tiles": "a PBR tiled floor: brushed and hammered steel tiles and chipped painted tiles in rough grout "
    "(metallic, roughness and normal maps)",
}

#: The input the quickstart uses.
DEFAULT_EXAMPLE = "canyon"


def list_examples() -> list[str]:
    """Names accepted by :func:`build_example`."""
    return list(EXAMPLES)


def build_example(name: str, seed: int = 0) -> TexturedMesh:
    """Build the example ``name``; ``seed`` picks the variant (same seed, same mesh)."""
    if name not in _BUILDERS:
        raise Sin3DMInputError(f"unknown example '{name}'; choose one of: {', '.join(list_examples())}")
    mesh = _BUILDERS[name](np.random.default_rng(seed))  # built z-up
    mesh.vertices = y_up(mesh.vertices)
    return mesh


def write_example(name: str, out_dir, seed: int = 0) -> Path:
    """Write ``out_dir/<name>.obj`` (+ ``.mtl`` and ``.png``) for Blender or any viewer; returns the OBJ path."""
    from ..formats.export import save_obj

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return save_obj(build_example(name, seed), out_dir / f"{name}.obj")


_BUILDERS = {"canyon": build_canyon, "wall": build_wall, "colonnade": build_colonnade, "tiles": build_tiles}

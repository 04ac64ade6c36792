"""A fit's input, however it is named: a built-in example's name, a mesh file, or a ``TexturedMesh``.

:func:`resolve_mesh` turns it into the mesh; :func:`input_stem` and :func:`input_name` say how a grid, a report
and a message name it; :func:`recorded_input` finds it again from what a fit's report recorded.
"""

from __future__ import annotations

from pathlib import Path

from .. import examples
from ..errors import Sin3DMInputError
from ..formats.load import load_any
from .mesh import TexturedMesh


def is_example(source) -> bool:
    """Whether ``source`` names a built-in example (a file of that name beside it wins)."""
    return isinstance(source, str) and source in examples.list_examples() and not Path(source).is_file()


def resolve_mesh(source, allow_outside_paths: bool = False) -> TexturedMesh:
    """A ``TexturedMesh`` from the name of a built-in example, or whatever ``load_any`` takes.

    ``allow_outside_paths``: let a mesh file name files outside its folder.
    """
    if isinstance(source, str) and source in examples.list_examples():
        return examples.build_example(source)
    if isinstance(source, str) and not Path(source).exists() and Path(source).suffix == "":
        raise Sin3DMInputError(
            f"'{source}' is neither a mesh file nor a built-in example; examples: {', '.join(examples.list_examples())}"
        )
    return load_any(source, allow_outside_paths=allow_outside_paths)


def input_stem(source) -> str:
    """The input's name as a grid and a report keep it: the example's name, the file's stem, the mesh's name."""
    if isinstance(source, TexturedMesh):
        return source.name
    if is_example(source):
        return source
    return Path(source).stem


def input_name(source) -> str:
    """How a message names the input: the example's name, the mesh file's path, or the mesh's name."""
    if isinstance(source, TexturedMesh):
        return f"the mesh '{source.name}'"
    if is_example(source):
        return f"the example '{source}'"
    return f"'{source}'"


def recorded_input(path: str | None, name: str | None, allow_outside_paths: bool = False) -> TexturedMesh:
    """The mesh a fit's report names: the mesh file ``path`` (its ``input_path``), if it is still there, or the
    built-in example ``name`` (its ``input``) when the fit was of an example."""
    if path and Path(path).is_file():
        return resolve_mesh(path, allow_outside_paths=allow_outside_paths)
    if path or name not in examples.list_examples():  # a file (even one named like an example) is not the example
        where = f"'{path}' is gone" if path else f"it was fitted to '{name}', not a built-in example"
        raise Sin3DMInputError(
            f"cannot find this model's input mesh ({where}); pass the input mesh "
            "(CLI: --input MESH) to compare samples with it"
        )
    return examples.build_example(name)

"""The package's layering: data flows Data → Model → Generate → (Eval, Show) → facade, and imports follow it.

A module may import from its own stage or an earlier one, never from a later
stage or from the facade; no module imports another module's private
(underscore) names; every name the package exports resolves.
"""
import ast
from pathlib import Path

import pytest

import sin3dm_lite

PACKAGE = Path(sin3dm_lite.__file__).parent

#: stage of every module (a module may import only from stages <= its own)
STAGES = {
    "errors": 0, "config": 0, "device": 0, "files": 0,  # utilities used everywhere
    "mesh_io": 1, "box": 1, "grid": 1,  # data
    "triplane": 2, "training": 2, "autoencoder": 2, "decode": 2, "unet": 2, "diffusion": 2,  # model
    "extract": 3, "export": 3, "control": 3,  # generate
    "metrics": 4, "viz": 4, "widgets": 4, "viewer": 4, "render": 4, "calibrate": 4,  # eval and show
    "lesson2d": 4, "exercises": 4,  # teaching: the method in 2D, the exercises' checks
    "pipeline": 5, "cli": 5, "mass": 5, "runs": 5, "examples": 5, "pretrained": 5,  # the facade and its built-in inputs
}


def _imports(path: Path):
    """(module imported, names) for every relative import in a module, function-level ones included."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            if node.module:
                yield node.module.split(".")[0], [a.name for a in node.names]
            else:  # from . import x, y
                for a in node.names:
                    yield a.name, []


def test_every_module_has_a_stage():
    modules = {p.stem for p in PACKAGE.glob("*.py")} - {"__init__"}
    assert modules == set(STAGES), "add new modules to STAGES (and to the README's layout table)"


@pytest.mark.parametrize("module", sorted(STAGES))
def test_imports_follow_the_data_flow(module):
    later = [(m, names) for m, names in _imports(PACKAGE / f"{module}.py") if STAGES[m] > STAGES[module]]
    assert not later, f"{module} (stage {STAGES[module]}) imports from a later stage: {later}"


@pytest.mark.parametrize("module", sorted(STAGES))
def test_no_private_names_across_modules(module):
    private = [(m, n) for m, names in _imports(PACKAGE / f"{module}.py") for n in names if n.startswith("_")]
    assert not private, f"{module} imports private names: {private}"


def test_the_public_api_resolves():
    for name in sin3dm_lite.__all__:
        assert getattr(sin3dm_lite, name) is not None, name
    assert sin3dm_lite.Sin3DM.__module__ == "sin3dm_lite.pipeline"
    with pytest.raises(AttributeError):
        sin3dm_lite.no_such_name

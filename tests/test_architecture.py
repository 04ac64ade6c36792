"""The package's layers, written down once: data flows Data → Model → Generate → Evaluate → Show → App.

``LAYERS`` below is the single table of which module sits on which level
(``docs/architecture.md`` and the package docstring describe it in words). A
module imports only from its own level or a lower one, and never in a circle;
every import counts: module-level and inside functions, relative
(``from ..data import grid``) and absolute (``import sin3dm_lite.model.unet``).
No module imports another module's private (underscore) names, every module is
in the table, and modules stay short enough to read (≤ 500 lines, functions
≤ 80 lines).
"""

from __future__ import annotations

import ast
import json
import re
from pathlib import Path

import pytest

import sin3dm_lite

PACKAGE = Path(sin3dm_lite.__file__).parent
NOTEBOOKS = PACKAGE.parent / "notebooks"

BASE, DATA, MODEL, GENERATE, EVALUATE, SHOW, APP = range(7)

#: level of every module ("model.unet" is sin3dm_lite/model/unet.py; a package's __init__ is its own name)
LAYERS = {
    # base: used everywhere (errors, the device and thread policy, atomic files, locks, the manifest, output folders)
    "errors": BASE,
    "app.device": BASE,
    "app.threads": BASE,
    "files": BASE,
    "files.atomic": BASE,
    "files.confined": BASE,
    "app": BASE,
    "auto": APP,
    "auto.calibration": APP,
    "auto.review": APP,
    "files.locks": BASE,
    "files.manifest": BASE,
    "files.outputs": BASE,
    "files.inputs": BASE,  # the one check of every path a user hands over (regular files only; text named)
    # data: settings, geometry of the box, meshes and their files, built-in shapes, mesh → TSDF grid (tsdf computes it)
    "data": DATA,
    "data.config": DATA,
    "presets": DATA,
    "data.box": DATA,
    "data.mesh": DATA,
    "formats.load": DATA,
    "formats.export": DATA,
    "formats": DATA,
    "formats.common": DATA,
    "formats.repair": DATA,
    "formats.images": DATA,
    "formats.obj": DATA,
    "formats.mtl": DATA,
    "formats.gltf": DATA,
    "formats.scene": DATA,
    "examples": DATA,
    "examples.geometry": DATA,
    "examples.texture": DATA,
    "examples.canyon": DATA,
    "examples.wall": DATA,
    "examples.colonnade": DATA,
    "examples.tiles": DATA,
    "examples.ruin": DATA,
    "data.distance": DATA,
    "data.tsdf": DATA,
    "data.grid": DATA,
    "data.source": DATA,
    "app.values": DATA,  # what a value a user passes may be: the checks the CLI and the Python API share
    # model: triplane, autoencoder, decoding, U-Net, the noise schedule, diffusion, the trainers
    "model": MODEL,
    "model.triplane": MODEL,
    "kernels": MODEL,
    "kernels.pointops": MODEL,
    "kernels.bf16ops": MODEL,
    "kernels.planeops": MODEL,
    "model.training": MODEL,
    "model.autoencoder": MODEL,
    "model.decode": MODEL,
    "model.unet": MODEL,
    "model.schedule": MODEL,
    "model.diffusion": MODEL,
    # generate: what to sample (control), texture baking and the SDF → textured mesh step
    "generate": GENERATE,
    "generate.control": GENERATE,
    "generate.bake": GENERATE,
    "generate.extract": GENERATE,
    # evaluate: metrics and their networks, headless rendering, the diversity calibration
    "evaluate": EVALUATE,
    "evaluate.geometry": EVALUATE,
    "evaluate.patches": EVALUATE,
    "evaluate.features": EVALUATE,
    "evaluate.ssfid": EVALUATE,
    "evaluate.texture": EVALUATE,
    "evaluate.metrics": EVALUATE,
    "evaluate.render": EVALUATE,
    "evaluate.calibration_record": EVALUATE,
    "evaluate.curves": EVALUATE,
    "evaluate.calibrate": EVALUATE,
    "evaluate.evaluation": EVALUATE,
    # show: figures by stage, k3d viewers and pages, widget panels (the panel, the sampling stage's, all of them)
    "show": SHOW,
    "show.figures": SHOW,
    "show.data_figures": SHOW,
    "show.model_figures": SHOW,
    "show.diffusion_figures": SHOW,
    "show.sample_figures": SHOW,
    "show.eval_figures": SHOW,
    "show.viz": SHOW,
    "show.camera": SHOW,
    "show.viewer": SHOW,
    "show.pages": SHOW,
    "show.explorer": SHOW,
    "show.sampling_widgets": SHOW,
    "show.widgets": SHOW,
    # teach: the 2D lesson and the exercises' checks (they use the model and the metrics)
    "teach": SHOW,
    "teach.lesson2d": SHOW,
    "teach.receptive_field": SHOW,
    "teach.checking": SHOW,
    "teach.exercises": SHOW,
    "teach.shape_exercises": SHOW,
    "teach.loop_exercises": SHOW,
    # app: the facade, run folders, mass sampling (the run, its folder, ranks and workers), the CLI (main, parser,
    # commands by group), shipped models, the public namespace
    "pipeline": APP,
    "app.runs": APP,
    "app.mass": APP,
    "app.mass_folder": APP,
    "app.mass_workers": APP,
    "app.pretrained": APP,
    "cli": APP,
    "cli.__main__": APP,
    "cli.parser_cli": APP,
    "cli.values_cli": APP,
    "cli.fit_cli": APP,
    "cli.sample_cli": APP,
    "cli.evaluate_cli": APP,
    "__init__": APP,
    # the facade's stages: fitting (fit_policy decides, run_folder and checkpoints keep the files), sampling (request:
    # a sample run's settings and their defaults)
    "app.fitting": APP,
    "auto.fit_policy": APP,
    "auto.fit_default": APP,
    "app.run_folder": APP,
    "app.checkpoints": APP,
    "app.model_file": APP,  # every field of a model.pt checked before anything is built
    "app.sampling": APP,
    "app.request": APP,
}

MAX_LINES, MAX_FUNCTION_LINES = 500, 80


def _modules() -> dict[str, Path]:
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE).with_suffix("").parts)
        if parts[-1] == "__init__" and len(parts) > 1:
            parts = parts[:-1]
        found[".".join(parts)] = path
    return found


MODULES = _modules()


def _package_of(name: str) -> list[str]:
    """The package a module's relative imports start from (a package's __init__ is inside itself)."""
    parts = [] if name == "__init__" else name.split(".")
    return parts if name != "__init__" and (MODULES[name].name == "__init__.py") else parts[:-1]


def _resolve(dotted: str) -> str | None:
    """The module in the table that ``sin3dm_lite.<dotted>`` names ("" is the package itself)."""
    if not dotted:
        return "__init__"
    return dotted if dotted in MODULES else None


def imports(name: str):
    """(imported module, [names]) for every import of the package in module ``name``, wherever it stands."""
    package = _package_of(name)
    for node in ast.walk(ast.parse(MODULES[name].read_text())):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "sin3dm_lite" or alias.name.startswith("sin3dm_lite."):
                    yield _resolve(alias.name.partition(".")[2]) or alias.name, []
            continue
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level:
            base = package[: len(package) - (node.level - 1)] + (node.module.split(".") if node.module else [])
        elif node.module and (node.module == "sin3dm_lite" or node.module.startswith("sin3dm_lite.")):
            base = node.module.split(".")[1:]
        else:
            continue
        names = [a.name for a in node.names]
        submodules = [n for n in names if ".".join(base + [n]) in MODULES]
        for n in submodules:  # from .data import examples
            yield ".".join(base + [n]), []
        others = [n for n in names if n not in submodules]
        if others or not submodules:
            yield _resolve(".".join(base)) or ".".join(base), others


def test_every_module_is_in_the_table():
    assert set(MODULES) - set(LAYERS) == set(), "add new modules to LAYERS (and to docs/architecture.md)"
    assert set(LAYERS) - set(MODULES) == set(), "LAYERS names modules that do not exist"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_go_down_the_layers(module):
    targets = list(imports(module))
    unknown = [t for t, _ in targets if t not in LAYERS]
    assert not unknown, f"{module} imports modules that do not exist: {unknown}"
    upward = sorted({t for t, _ in targets if LAYERS[t] > LAYERS[module]})
    assert not upward, f"{module} (level {LAYERS[module]}) imports from a higher level: {upward}"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_private_names_across_modules(module):
    private = [(m, n) for m, names in imports(module) for n in names if n.startswith("_") and m != module]
    assert not private, f"{module} imports private names: {private}"


def _cycles(graph: dict | None = None) -> list[set[str]]:
    """Strongly connected groups of more than one module in the import graph (Tarjan)."""
    if graph is None:
        graph = {m: {t for t, _ in imports(m) if t in LAYERS and t != m} for m in MODULES}
    index, low, stack, on_stack, groups = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.add(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(group)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return groups


def test_no_import_cycles():
    cycles = list(_cycles())
    assert not cycles, f"modules that import each other (in a circle): {cycles}"


def test_the_cycle_checker_finds_a_cycle():
    graph = {"pipeline": {"app.runs"}, "app.runs": {"pipeline", "files"}, "files": set()}  # the cycle phase 2 broke
    assert _cycles(graph) == [{"pipeline", "app.runs"}]


def _long_functions(path: Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            length = node.end_lineno - node.lineno + 1
            if length > MAX_FUNCTION_LINES:
                yield f"{node.name} ({length} lines)"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_modules_and_functions_are_short(module):
    lines = len(MODULES[module].read_text().splitlines())
    assert lines <= MAX_LINES, f"{module} has {lines} lines (at most {MAX_LINES}): split it by job"
    long = list(_long_functions(MODULES[module]))
    assert not long, f"{module}: functions over {MAX_FUNCTION_LINES} lines: {long}; split them into named parts"


def test_the_public_api_resolves():
    for name in sin3dm_lite.__all__:
        assert getattr(sin3dm_lite, name) is not None, name
    assert sin3dm_lite.Sin3DM.__module__ == "sin3dm_lite.pipeline"
    with pytest.raises(AttributeError):
        sin3dm_lite.no_such_name


def _notebook_attributes():
    """(notebook, module name, attribute) for each ``viz.plot_slice``-style use of a module the notebook imports."""
    namespaces = sorted(sin3dm_lite._MODULES)
    found = set()
    for nb in sorted(NOTEBOOKS.rglob("*.ipynb")):
        code = "\n".join("".join(c["source"]) for c in json.loads(nb.read_text())["cells"] if c["cell_type"] == "code")
        imported = set()
        for m in re.finditer(r"from sin3dm_lite import \(?([\w,\s]+)\)?", code):
            imported |= {n.strip() for n in m.group(1).replace("\n", ",").split(",")}
        pattern = r"(?<![\w.])(" + "|".join(namespaces) + r")\.(\w+)"
        for m in re.finditer(pattern, code):
            if m.group(1) in imported:
                found.add((nb.name, m.group(1), m.group(2)))
    return sorted(found)


NOTEBOOK_ATTRIBUTES = _notebook_attributes()


def test_the_notebooks_use_module_namespaces():
    assert ("01_mesh_to_grid.ipynb", "examples", "write_example") in NOTEBOOK_ATTRIBUTES
    assert len({name for _, name, _ in NOTEBOOK_ATTRIBUTES}) >= 5


@pytest.mark.parametrize("notebook,name,attribute", NOTEBOOK_ATTRIBUTES)
def test_what_the_notebooks_use_resolves(notebook, name, attribute):
    assert hasattr(getattr(sin3dm_lite, name), attribute), f"{notebook} uses sin3dm_lite.{name}.{attribute}"

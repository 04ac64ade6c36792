"""The notebooks' committed outputs: made at reading settings by `python scripts/run_notebooks.py`, never stale.

A notebook whose metadata records no digest yet is skipped (its outputs have
not been made); one whose recorded digest no longer matches its code cells
fails, naming the command that makes them again.
"""

from pathlib import Path

import nbformat
import pytest

ROOT = Path(__file__).parents[1]


def _load_script(name: str):
    """A script of scripts/ as a module (they are run from a checkout, not installed)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, Path(__file__).parents[1] / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


notebook_run = _load_script("run_notebooks")
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_outputs_match_the_code(path):
    nb = nbformat.read(path, as_version=4)
    if notebook_run.recorded(nb) is None:
        pytest.skip(f"no outputs recorded yet: run `{notebook_run.COMMAND} notebooks/{path.name}`")
    why = notebook_run.stale_reason(nb, f"notebooks/{path.name}")
    assert why is None, why


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_no_widget_state(path):
    nb = nbformat.read(path, as_version=4)
    assert "widgets" not in nb.metadata, (
        f"{path.name} holds widget state: run `{notebook_run.COMMAND} notebooks/{path.name}`"
    )
    views = [
        i
        for i, c in enumerate(nb.cells)
        if c.cell_type == "code"
        for o in c.get("outputs", [])
        if notebook_run.WIDGET_MIME in o.get("data", {})
    ]
    assert not views, f"{path.name}: widget views in cells {views}"


def test_all_notebooks_fit_the_size_limit():
    total = sum(p.stat().st_size for p in NOTEBOOKS)
    assert total <= notebook_run.MAX_TOTAL_BYTES, f"the notebooks hold {total / 1e6:.1f} MB, more than 20 MB"


def _notebook(code, outputs=()):
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_markdown_cell("# a title"), *(nbformat.v4.new_code_cell(c) for c in code)]
    nb.cells[1].outputs = list(outputs)
    return nb


def test_the_digest_follows_code_cells_only():
    nb = _notebook(["a = 1", "print(a)"])
    d = notebook_run.code_digest(nb)
    nb.cells[0].source = "# another title"
    nb.cells[1].outputs = [nbformat.v4.new_output("stream", text="1\n")]
    assert notebook_run.code_digest(nb) == d
    nb.cells[2].source = "print(a + 1)"
    assert notebook_run.code_digest(nb) != d
    moved = _notebook(["a = 1\nprint(a)", ""])  # the same lines in other cells
    assert notebook_run.code_digest(moved) != notebook_run.code_digest(_notebook(["a = 1", "print(a)"]))


def test_a_stale_digest_is_reported_with_the_command():
    nb = _notebook(["x = 1"])
    assert notebook_run.recorded(nb) is None and notebook_run.stale_reason(nb) is None  # nothing recorded: no verdict
    nb.metadata["sin3dm"] = {"code_digest": notebook_run.code_digest(nb), "fast": False}
    assert notebook_run.stale_reason(nb) is None
    nb.cells[1].source = "x = 2"
    why = notebook_run.stale_reason(nb, "notebooks/99_demo.ipynb")
    assert why and notebook_run.COMMAND in why and "99_demo" in why
    nb.metadata["sin3dm"] = {"code_digest": notebook_run.code_digest(nb), "fast": True}
    assert "SIN3DM_FAST" in notebook_run.stale_reason(nb)  # outputs of a test run are not the reading ones


def test_strip_widgets_keeps_the_static_picture():
    widget = {"model_id": "abc", "version_major": 2, "version_minor": 0}
    outs = [
        nbformat.v4.new_output("display_data", data={notebook_run.WIDGET_MIME: widget, "text/plain": "Plot(...)"}),
        nbformat.v4.new_output("display_data", data={notebook_run.WIDGET_MIME: widget, "image/png": "iVBOR"}),
        nbformat.v4.new_output("display_data", data={"image/png": "iVBOR", "text/plain": "<Figure>"}),
        nbformat.v4.new_output("stream", text="hello\n"),
    ]
    nb = _notebook(["show()"], outs)
    nb.metadata["widgets"] = {"application/vnd.jupyter.widget-state+json": {"state": {}}}
    assert notebook_run.strip_widgets(nb) == 1
    kept = nb.cells[1].outputs
    assert "widgets" not in nb.metadata and len(kept) == 3
    assert all(notebook_run.WIDGET_MIME not in o.get("data", {}) for o in kept)
    assert kept[0].data == {"image/png": "iVBOR"} and kept[1].data["image/png"] == "iVBOR"


def test_the_tool_runs_a_notebook_and_records_it(tmp_path):
    path = tmp_path / "tiny.ipynb"
    nb = _notebook(
        [
            "import os, ipywidgets\nprint('fast' if os.environ.get('SIN3DM_FAST') else 'reading')",
            "ipywidgets.IntSlider(3)",
        ]
    )
    nbformat.write(nb, path)
    meta = notebook_run.run_notebook(path, fast=True, timeout=120)
    done = nbformat.read(path, as_version=4)
    assert meta["fast"] is True and notebook_run.recorded(done)["code_digest"] == notebook_run.code_digest(done)
    assert done.cells[1].outputs[0].text == "fast\n"
    assert done.cells[2].outputs == [] and "widgets" not in done.metadata  # the slider's view and state are gone
    assert "SIN3DM_FAST" in notebook_run.stale_reason(done)

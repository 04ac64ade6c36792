"""Run the notebooks top to bottom and keep their outputs, so a reader sees the pictures on GitHub.

    python scripts/run_notebooks.py                      # every notebooks/*.ipynb at reading settings
    python scripts/run_notebooks.py notebooks/01_mesh_to_grid.ipynb
    python scripts/run_notebooks.py --check              # only say which notebooks' outputs are stale

A tool for the course's authors, run from a checkout (the notebooks are not part of the installed package).

Each notebook runs in its own kernel from the ``notebooks/`` folder with
``SIN3DM_FAST`` unset (the `small` preset a reader gets; ``--fast`` sets it, for
trying the tool, and marks the outputs as such so the test refuses them). Then:

* widget state goes: ``metadata.widgets`` and every widget view output (a k3d
  plot or a slider panel is a widget; its state is megabytes and shows nothing
  on GitHub). The static picture that the notebooks draw beside each viewer
  (``viz.plot_meshes``) stays;
* the notebook's metadata records, under ``sin3dm``, a digest of its code cells'
  source (:func:`code_digest`), the package version and the run's settings.

``tests/test_notebook_outputs.py`` recomputes the digest and fails when a code
cell changed after the outputs were made, naming this command.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import os
import sys
import time
from pathlib import Path

from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.files import atomic_path

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
WIDGET_MIME = "application/vnd.jupyter.widget-view+json"
META_KEY = "sin3dm"
COMMAND = "python scripts/run_notebooks.py"
MAX_TOTAL_BYTES = 20 * 1024 * 1024  # all notebooks together, outputs included


def read_notebook(path: Path):
    """The notebook at ``path`` (nbformat 4), or one line saying why it is none: a missing file, another kind of
    file, a ``.ipynb`` that is not JSON or not a notebook's structure (``nbformat.validate``)."""
    import nbformat

    path = Path(path)
    if not path.is_file():
        what = "is a folder" if path.is_dir() else "not found"
        raise Sin3DMInputError(f"notebook '{path}' {what}; give .ipynb files, or none for every notebooks/*.ipynb")
    if path.suffix != ".ipynb":
        raise Sin3DMInputError(f"'{path}' is not a notebook (.ipynb); give .ipynb files, or none for all of them")
    try:
        nb = nbformat.read(path, as_version=4)
        nbformat.validate(nb)
    except (
        ValueError,
        TypeError,
        KeyError,
        AttributeError,
        nbformat.ValidationError,
    ) as e:  # NotJSONError: a ValueError
        reason = "not JSON" if isinstance(e, nbformat.reader.NotJSONError) else "not a notebook's structure"
        raise Sin3DMInputError(
            f"'{path}' is not a readable Jupyter notebook ({reason}); open it in Jupyter and save it again, "
            "or restore it from git"
        ) from None
    return nb


def write_notebook(nb, path: Path) -> None:
    """Write ``nb`` over ``path`` (through a link, keeping its mode) whole or not at all: a full disk or a kill
    leaves the old notebook, never a truncated one (``nbformat.write`` empties the file first)."""
    import nbformat

    text = nbformat.writes(nb)
    real = Path(os.path.realpath(path))
    mode = real.stat().st_mode & 0o777
    with atomic_path(real, before_move=lambda tmp: os.chmod(tmp, mode)) as tmp:
        tmp.write_text(text if text.endswith("\n") else text + "\n", encoding="utf-8")


def code_digest(nb) -> str:
    """SHA-256 of the notebook's code cells' source, in order (markdown and outputs do not count)."""
    h = hashlib.sha256()
    for cell in nb.cells:
        if cell.cell_type == "code":
            src = cell.source if isinstance(cell.source, str) else "".join(cell.source)
            h.update(src.rstrip().encode("utf-8"))
            h.update(b"\n\x1e\n")  # record separator: moving a line between cells changes the digest
    return h.hexdigest()


def recorded(nb) -> dict | None:
    """What :func:`run_notebook` recorded in the notebook's metadata, or None for a notebook never run by it."""
    meta = nb.metadata.get(META_KEY)
    return dict(meta) if meta and "code_digest" in meta else None


def stale_reason(nb, name: str = "the notebook") -> str | None:
    """Why the committed outputs of ``nb`` cannot be trusted (None: they can; also None when nothing is recorded)."""
    meta = recorded(nb)
    if meta is None:
        return None
    if meta.get("fast"):
        return f"{name} holds outputs of a SIN3DM_FAST run, not of the reading settings: rerun `{COMMAND} {name}`"
    if meta["code_digest"] != code_digest(nb):
        return f"{name}: a code cell changed since its outputs were made: rerun `{COMMAND} {name}`"
    return None


def strip_widgets(nb) -> int:
    """Drop widget state and widget views from ``nb`` in place; returns how many outputs were removed.

    An output that carried a widget view keeps its other representations
    (an image beside it, say) unless only its text repr is left, which for a
    widget is noise like ``HBox(children=...)``.
    """
    nb.metadata.pop("widgets", None)
    removed = 0
    for cell in nb.cells:
        if cell.cell_type != "code":
            continue
        kept = []
        for out in cell.get("outputs", []):
            data = out.get("data")
            if data is not None and WIDGET_MIME in data:
                data.pop(WIDGET_MIME)
                if set(data) <= {"text/plain"}:
                    removed += 1
                    continue
            kept.append(out)
        cell.outputs = kept
    return removed


def clear_outputs(nb) -> None:
    """Remove every output, execution count and the recorded digest (what a notebook looks like for merging)."""
    for cell in nb.cells:
        if cell.cell_type == "code":
            cell.outputs, cell.execution_count = [], None
            cell.metadata.pop("execution", None)
    nb.metadata.pop(META_KEY, None)
    nb.metadata.pop("widgets", None)


def _slice_kernel_polls() -> None:
    """The notebook tests' guard against a lost kernel wake-up (notebooks/conftest.py, issue 9), if it is there."""
    conftest = NOTEBOOKS / "conftest.py"
    if not conftest.is_file():
        return
    spec = importlib.util.spec_from_file_location("sin3dm_nb_conftest", conftest)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)


def run_notebook(path: str | Path, fast: bool = False, timeout: int = 1800, kernel: str = "python3") -> dict:
    """Execute ``path`` top to bottom in place, strip widgets and record the digest; returns the recorded metadata."""
    from nbclient import NotebookClient

    import sin3dm_lite

    path = Path(path)
    nb = read_notebook(path)
    clear_outputs(nb)
    _slice_kernel_polls()
    saved = os.environ.get("SIN3DM_FAST")
    if fast:
        os.environ["SIN3DM_FAST"] = "1"
    else:
        os.environ.pop("SIN3DM_FAST", None)
    start = time.perf_counter()
    try:
        NotebookClient(
            nb,
            timeout=timeout,
            kernel_name=kernel,
            resources={"metadata": {"path": str(path.parent)}},
            record_timing=False,
        ).execute()  # widget state is kept while running (Output widgets need it), stripped below
    finally:
        if saved is None:
            os.environ.pop("SIN3DM_FAST", None)
        else:
            os.environ["SIN3DM_FAST"] = saved
    seconds = time.perf_counter() - start
    strip_widgets(nb)
    meta = {
        "code_digest": code_digest(nb),
        "package_version": sin3dm_lite.__version__,
        "fast": bool(fast),
        "run_seconds": round(seconds),
        "command": f"{COMMAND} {path.parent.name}/{path.name}",
    }
    nb.metadata[META_KEY] = meta
    write_notebook(nb, path)
    return meta


def run_all(paths=(), fast: bool = False, check: bool = False, clear: bool = False, timeout: int = 1800) -> int:
    """Run ``paths`` (default: every notebook) and keep their outputs; ``check`` lists stale ones, ``clear`` removes
    outputs. Returns 1 if one failed, is stale or the notebooks are too large, else 0."""
    paths = list(paths) or sorted(NOTEBOOKS.glob("*.ipynb"))
    read = {path: read_notebook(path) for path in paths}  # every file checked before any is run or changed
    bad = 0
    for path in paths:
        if check or clear:
            nb = read[path]
            if clear:
                clear_outputs(nb)
                write_notebook(nb, path)
                print(f"{path}: outputs cleared")
                continue
            why = stale_reason(nb, f"notebooks/{path.name}") or (
                None if recorded(nb) else f"{path}: no outputs recorded"
            )
            bad += why is not None
            print(why or f"{path}: up to date")
            continue
        print(f"running {path} ({'SIN3DM_FAST=1' if fast else 'reading settings'}) ...", flush=True)
        try:
            meta = run_notebook(path, fast=fast, timeout=timeout)
        except Exception as e:  # a failing cell (an assert on a figure the text states): report, keep the file, go on
            bad += 1
            print(f"  FAILED, {path} left as it was: {type(e).__name__}: {str(e)[-2000:]}", flush=True)
            continue
        print(f"  {meta['run_seconds']} s, {path.stat().st_size / 1e6:.1f} MB", flush=True)
    total = sum(p.stat().st_size for p in NOTEBOOKS.glob("*.ipynb"))
    print(f"all notebooks: {total / 1e6:.1f} MB (limit {MAX_TOTAL_BYTES / 1e6:.0f} MB)")
    return 1 if bad or total > MAX_TOTAL_BYTES else 0


def main(argv: list[str] | None = None) -> int:
    """The command line: 0 when every notebook ran (or is up to date), 1 when one failed or is stale, 2 on a bad
    file or a disk error (one line, no traceback)."""
    from sin3dm_lite.cli import disk_error

    p = argparse.ArgumentParser(prog="run_notebooks.py", description=__doc__.splitlines()[0])
    p.add_argument("notebooks", nargs="*", type=Path, help="notebooks to run (default: every notebooks/*.ipynb)")
    p.add_argument(
        "--fast", action="store_true", help="run with SIN3DM_FAST=1 (to try it; the tests refuse such outputs)"
    )
    p.add_argument(
        "--check", action="store_true", help="run nothing: list notebooks whose outputs are stale or missing"
    )
    p.add_argument("--clear", action="store_true", help="run nothing: remove every output and the recorded digest")
    p.add_argument("--timeout", type=int, default=1800, help="seconds one cell may take (default 1800)")
    a = p.parse_args(argv)
    try:
        return run_all(a.notebooks, fast=a.fast, check=a.check, clear=a.clear, timeout=a.timeout)
    except (Sin3DMInputError, OSError) as e:
        why = e if isinstance(e, Sin3DMInputError) else disk_error(e, None, False)
        print(f"run_notebooks.py: error: {why}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C: the notebook being run is left as it was (written whole or not at all)
        print("run_notebooks.py: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

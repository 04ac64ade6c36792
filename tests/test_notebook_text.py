"""The notebooks read as lessons: short enough, a reading time at the top, exercises at the end."""

import json
import re
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("[0-9]*.ipynb"))
MAX_WORDS = 2500


def _cells(path: Path) -> list[dict]:
    return json.loads(path.read_text(encoding="utf-8"))["cells"]


def _markdown(cell: dict) -> str:
    return "".join(cell["source"]) if cell["cell_type"] == "markdown" else ""


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_a_lesson_not_a_log(path):
    cells = _cells(path)
    words = sum(len(re.findall(r"\w+", _markdown(c))) for c in cells)  # \w+: LaTeX and code count too
    assert words <= MAX_WORDS, f"{path.name} has {words} words of markdown (at most {MAX_WORDS}): move details to docs/"
    assert re.search(r"\*Reading run: about \d+ minutes? on a 2-core CPU", _markdown(cells[0])), (
        f"{path.name}: the first cell should say how long a reading run takes"
    )
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", "".join(_markdown(c) for c in cells)), (
        f"{path.name} quotes a dated measurement: it belongs in docs/"
    )
    control = [c for c in cells for ch in "".join(c["source"]) if ch in "\a\b\v\f"]
    assert not control, f"{path.name}: a control character in a cell (a LaTeX backslash lost to a Python string?)"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_every_notebook_ends_with_exercises(path):
    headings = [m for c in _cells(path) for m in re.findall(r"^## (.+)$", _markdown(c), flags=re.M)]
    assert any(h.startswith("Exercises") for h in headings[-3:]), f"{path.name}: no Exercises section at its end"

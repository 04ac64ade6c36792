"""Every notebook the notebooks or the README name (``NN_name.ipynb``) exists in notebooks/."""
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
LINK = re.compile(r"\b(\d\d_[A-Za-z0-9_]+\.ipynb)\b")


def _markdown(nb: Path) -> str:
    cells = json.loads(nb.read_text(encoding="utf-8"))["cells"]
    return "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "markdown")


def _sources():
    yield "README.md", (ROOT / "README.md").read_text(encoding="utf-8")
    for nb in NOTEBOOKS:
        yield f"notebooks/{nb.name}", _markdown(nb)


def test_the_pattern_finds_links():
    assert LINK.findall("see [03](03_diffusion_on_triplanes.ipynb) and notebooks/05_sampling.ipynb.") == [
        "03_diffusion_on_triplanes.ipynb", "05_sampling.ipynb"]


@pytest.mark.parametrize("name,text", list(_sources()), ids=lambda v: v if isinstance(v, str) and len(v) < 60 else "")
def test_linked_notebooks_exist(name, text):
    existing = {nb.name for nb in NOTEBOOKS}
    missing = sorted(set(LINK.findall(text)) - existing)
    assert not missing, f"{name} refers to notebooks that do not exist: {missing}"

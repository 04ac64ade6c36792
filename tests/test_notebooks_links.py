"""Every relative Markdown link in the notebooks, the README and docs/ points at a file (and heading) that exists.

Links are ``[text](target)`` and ``![alt](target)`` outside code (fenced blocks
and inline code are skipped). Web links (``http:``, ``https:``, ``mailto:``) are
not followed. A target ``file#anchor`` must name an existing file, and, for a
Markdown file or a notebook, a heading whose GitHub anchor is ``anchor``; a bare
``#anchor`` refers to a heading of the same file.
"""

import json
import re
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).parents[1]
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^()\s>]+(?:\([^)]*\)[^()\s>]*)*)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.S | re.M)
INLINE_CODE = re.compile(r"`[^`\n]*`")
HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*#*\s*$", re.M)
WEB = ("http:", "https:", "mailto:", "ftp:")


def markdown_of(path: Path) -> str:
    """The Markdown text of a .md file or of a notebook's markdown cells."""
    if path.suffix == ".ipynb":
        cells = json.loads(path.read_text(encoding="utf-8"))["cells"]
        return "\n\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "markdown")
    return path.read_text(encoding="utf-8")


def _prose(text: str) -> str:
    return INLINE_CODE.sub("", FENCE.sub("", text))


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, markup and punctuation dropped, spaces to hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link in a heading keeps its text
    text = re.sub(r"[`*]|<[^>]+>", "", text).strip().lower()  # GitHub keeps underscores
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a .md file or a notebook, duplicates numbered as GitHub does (``name-1``)."""
    seen: dict[str, int] = {}
    out = set()
    for h in HEADING.findall(FENCE.sub("", markdown_of(path))):
        s = slug(h)
        n = seen.get(s, 0)
        out.add(s if n == 0 else f"{s}-{n}")
        seen[s] = n + 1
    return out


def links(text: str) -> list[str]:
    return LINK.findall(_prose(text))


def broken_links(path: Path) -> list[str]:
    """The relative links in ``path`` whose file or heading does not exist, each with the reason."""
    bad = []
    for target in links(markdown_of(path)):
        if target.startswith(WEB):
            continue
        file_part, _, anchor = target.partition("#")
        dest = path if not file_part else (path.parent / unquote(file_part)).resolve()
        if not dest.exists():
            bad.append(f"{target} (no file {dest})")
        elif anchor and dest.suffix in (".md", ".ipynb") and unquote(anchor).lower() not in anchors(dest):
            bad.append(f"{target} (no heading '#{anchor}' in {dest.name})")
    return bad


def _documents():
    return [ROOT / "README.md", *sorted((ROOT / "notebooks").glob("*.ipynb")), *sorted((ROOT / "docs").glob("*.md"))]


@pytest.mark.parametrize("path", _documents(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path):
    bad = broken_links(path)
    assert not bad, f"{path.relative_to(ROOT)} has dead links: {bad}"


def test_the_notebooks_link_to_each_other():
    # every notebook but the last links to at least one other notebook (its "Next" cell)
    notebooks = sorted((ROOT / "notebooks").glob("*.ipynb"))
    for nb in notebooks[:-1]:
        targets = [t for t in links(markdown_of(nb)) if t.split("#")[0].endswith(".ipynb")]
        assert targets, f"{nb.name} links to no other notebook"


def test_the_parser_finds_links_and_skips_code():
    text = (
        'see [03](03_diffusion_on_triplanes.ipynb), ![pic](docs/a%20b.png "title") and [web](https://x.org)\n'
        "`[not](a_link.md)`\n```\n[nor](this.md)\n```\n[sec](#a-heading) [f(x)](docs/f(x).md)"
    )
    assert links(text) == [
        "03_diffusion_on_triplanes.ipynb",
        "docs/a%20b.png",
        "https://x.org",
        "#a-heading",
        "docs/f(x).md",
    ]
    assert slug("1 · The input shape") == "1--the-input-shape"
    assert slug("Diversity ↔ fidelity") == "diversity--fidelity"
    assert slug("Measured (`bench.py`, 2 cores)") == "measured-benchpy-2-cores"
    assert slug("The table (`bench_tables.py`)") == "the-table-bench_tablespy"


def test_a_dead_link_is_reported(tmp_path):
    (tmp_path / "01_here.ipynb").write_text(
        json.dumps({"cells": [{"cell_type": "markdown", "metadata": {}, "source": ["## 2 · A section\n"]}]}),
        encoding="utf-8",
    )
    nb = tmp_path / "00_broken.ipynb"
    nb.write_text(
        json.dumps(
            {
                "cells": [
                    {
                        "cell_type": "markdown",
                        "metadata": {},
                        "source": [
                            "Go on to [the next one](01_here.ipynb), [its section](01_here.ipynb#2--a-section), ",
                            "[a lost one](02_missing.ipynb), [a lost heading](01_here.ipynb#3--nowhere) and [web](https://example.org).",
                        ],
                    },
                    {
                        "cell_type": "code",
                        "metadata": {},
                        "source": ["# [ignored](nowhere.ipynb)"],
                        "outputs": [],
                        "execution_count": None,
                    },
                ]
            }
        ),
        encoding="utf-8",
    )
    bad = broken_links(nb)
    assert len(bad) == 2, bad
    assert bad[0].startswith("02_missing.ipynb") and "3--nowhere" in bad[1]

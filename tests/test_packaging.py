"""pyproject.toml and environment.yml list the same dependencies; README holds the CI command."""

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CONDA_NAMES = {"torch": "pytorch"}  # PyPI name → conda-forge name


def _req(spec: str) -> tuple[str, str]:
    m = re.match(r"^\s*([A-Za-z0-9_.\-]+)\s*(>=\s*[\w.]+)?", spec)
    return m.group(1).lower().replace("_", "-"), (m.group(2) or "").replace(" ", "")


def test_environment_yml_matches_pyproject():
    tomllib = pytest.importorskip("tomllib")
    proj = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    wanted = dict(_req(s) for s in proj["dependencies"] + proj["optional-dependencies"]["dev"])
    wanted = {CONDA_NAMES.get(k, k): v for k, v in wanted.items()}
    text = (ROOT / "environment.yml").read_text().split("dependencies:", 1)[1]
    lines = [l.strip()[2:] for l in text.splitlines() if l.strip().startswith("- ")]
    have = dict(_req(l) for l in lines if not l.startswith(("-e", "pip", "python")) and not l.endswith(":"))
    assert have == wanted
    assert "conda-forge" in (ROOT / "environment.yml").read_text()
    assert any(l.startswith("-e .") for l in lines), "environment.yml must install the package through pip"


def test_readme_test_command_is_what_ci_runs():
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"<!-- test-command -->\s*```bash\n(.+?)\n```\s*<!-- /test-command -->", readme, re.S)
    assert block, "README.md needs the test command between <!-- test-command --> markers"
    ci = (ROOT / ".ci" / "run").read_text()
    assert "test-command" in ci and "bash -eo pipefail -c" in ci
    cmd = subprocess.run(
        [
            "bash",
            "-c",
            "sed -n '/<!-- test-command -->/,/<!-- \\/test-command -->/p' README.md | sed -n '/^```/,/^```/p' | sed '1d;$d'",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert cmd == block.group(1).strip()
    assert "pytest" in cmd and "torch==" in cmd

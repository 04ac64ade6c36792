"""The pretrained ``small`` models of the built-in examples, shipped inside the package (made by
``sin3dm-lite fit``; ``shipped/README.md`` has the commands), so the demo and the notebooks start at once."""

from __future__ import annotations

from pathlib import Path

from .. import examples
from ..errors import Sin3DMInputError

DATA = Path(__file__).parent.parent / "shipped"  # sin3dm_lite/shipped
MODEL_FILE = "model.pt"  # what sampling needs, in a run folder (written by app.checkpoints)


def pretrained_path(name: str = "default") -> Path:
    """Path of a shipped run folder (holding ``model.pt``)."""
    folder = DATA / (examples.DEFAULT_EXAMPLE + "_small" if name == "default" else name)
    if not (folder / MODEL_FILE).is_file():
        raise Sin3DMInputError(
            f"the shipped model '{folder.name}' is missing from this install; run `sin3dm-lite demo --train` to fit one"
        )
    return folder


def shipped_names() -> list[str]:
    """Names of the shipped run folders (``canyon_small``, ...)."""
    return sorted(p.name for p in DATA.iterdir() if (p / MODEL_FILE).is_file())


def shipped_examples() -> list[str]:
    """Built-in examples that have a shipped model (the default one first): what ``Sin3DM.open(name)`` loads."""
    names = [n for n in examples.list_examples() if shipped_model(n) is not None]
    return sorted(names, key=lambda n: n != examples.DEFAULT_EXAMPLE)


def shipped_model(name: str) -> Path | None:
    """The shipped run folder called ``name``, or that of the example ``name`` (``canyon`` → ``canyon_small``); None if none."""
    for candidate in (name, f"{name}_small"):
        if "/" not in candidate and (DATA / candidate / MODEL_FILE).is_file():
            return DATA / candidate
    return None


def is_shipped(folder: Path) -> bool:
    """Whether ``folder`` is one of the shipped run folders (part of the installed package: never written)."""
    return Path(folder).resolve().parent == DATA.resolve()

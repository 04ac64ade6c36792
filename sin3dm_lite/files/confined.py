"""Nothing written through a link: every write, replace and delete in an output folder stays inside it.

A user who moved a sample out of a folder of samples and linked it back must never see ``--overwrite`` replace or
delete what the link points to: :func:`refuse_links` refuses any link in the folder before the work, and
:func:`confined` checks each path again at the moment it is written (the folder may change while a run works).
``--out`` itself may be a link: the rule is about what lies inside it.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import Sin3DMInputError


def link_error(path: Path, option: str = "--out") -> Sin3DMInputError:
    """The one-line refusal of the symbolic link ``path`` inside an output folder."""
    try:
        target = f" (to '{os.readlink(path)}')"
    except OSError:
        target = ""
    return Sin3DMInputError(
        f"'{path}' is a symbolic link{target} inside the output folder, and sin3dm-lite writes nothing through "
        f"a link; move what it points to into its place (or the link out of the folder), or choose another {option}"
    )


def open_own(path: Path, flags: int) -> int:
    """``os.open(path, flags)`` for a file sin3dm-lite writes in place (a lock, a manifest part): never through a
    symbolic link, and refused when the file has other names (hard links), whose content would change with it."""
    fd = os.open(path, flags | getattr(os, "O_NOFOLLOW", 0), 0o644)
    if os.fstat(fd).st_nlink > 1:
        os.close(fd)
        raise Sin3DMInputError(
            f"'{path}' has other names (hard links), and sin3dm-lite writes it in place, which would change them "
            "too; remove this name (the others keep their content) and run again"
        )
    return fd


def refuse_links(out: str | Path, option: str = "--out") -> None:
    """Refuse ``out`` if any file or folder inside it (at any depth) is a symbolic link."""
    out = Path(out)
    if not out.is_dir():
        return
    for root, dirs, files in os.walk(out):  # os.walk lists a link to a folder but does not enter it
        for name in sorted(dirs + files):
            p = Path(root) / name
            if p.is_symlink():
                raise link_error(p, option)


def confined(out: str | Path, path: str | Path, option: str = "--out") -> Path:
    """``path`` itself, once checked: below ``out`` by name, no link on the way from ``out`` to it (``path``
    included), and its real path inside ``out``'s real path. Call it right before writing, replacing or
    deleting ``path``; it refuses in one line (:func:`link_error`) otherwise."""
    out, path = Path(out), Path(path)
    outside = f"'{path}' lies outside the output folder '{out}'; nothing was written there"
    parts = path.relative_to(out).parts if path.is_relative_to(out) else ("..",)
    if ".." in parts:
        raise Sin3DMInputError(outside)
    cur = out
    for part in parts:
        cur = cur / part
        if cur.is_symlink():
            raise link_error(cur, option)
    if not Path(os.path.realpath(path)).is_relative_to(os.path.realpath(out)):
        raise Sin3DMInputError(outside)
    return path

"""Files a user hands over (a mesh, its textures, a checkpoint, a run's json): checked before they are opened.

Every such path must be a regular file: a named pipe (FIFO) or a device such as ``/dev/zero`` would block or never
end, and a folder cannot be read (:func:`check_regular`). :func:`what_text_is` names the text files often saved in
a binary file's place (a Git LFS pointer, an HTML page), so that the message says what the file is.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

from ..errors import Sin3DMInputError

#: what a file that is not regular is, by its ``stat`` mode
_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)


def not_regular(path) -> str | None:
    """What ``path`` is when it exists (links followed) but is not a regular file ("a named pipe (FIFO)", ...);
    None for a regular file or a path that does not exist (the callers say "not found" in their own words)."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    if stat.S_ISREG(mode):
        return None
    return next((kind for test, kind in _KINDS if test(mode)), "not a regular file")


def check_regular(path, what: str) -> Path:
    """``path`` as a ``Path``; a :class:`Sin3DMInputError` when it exists but is not a regular file (``what``: the
    file expected there, e.g. "a mesh file")."""
    path = Path(path)
    kind = not_regular(path)
    if kind is not None:
        link = f" (a link to '{os.path.realpath(path)}')" if path.is_symlink() else ""
        raise Sin3DMInputError(
            f"'{path}' is {kind}{link}, not a regular file; sin3dm-lite reads {what} only from a regular file: "
            "give the path of one"
        )
    return path


def what_text_is(head: bytes) -> str | None:
    """What a file that begins with ``head`` is when it is text where a binary file was expected: a Git LFS
    pointer or an HTML page (with the fix); None for anything else."""
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n").lower()
    if text.startswith(b"version https://git-lfs"):
        return "a Git LFS pointer, not the file itself; run `git lfs pull` in the repository it came from"
    if text.startswith((b"<!doctype html", b"<html", b"<head")) or b"<html" in text[:512]:
        return "an HTML page, not a checkpoint; download the file itself (the site's raw or download link)"
    return None


def read_json(path, what: str):
    """The JSON value in the regular file ``path`` (``what`` names it in the messages); :class:`Sin3DMInputError`
    for a file that is not regular, ValueError (``json.JSONDecodeError``, ``UnicodeDecodeError``) for one that is
    not JSON, OSError for one that cannot be read."""
    return json.loads(check_regular(path, what).read_text(encoding="utf-8"))


def json_or_why(path, what: str) -> tuple[object, str | None]:
    """``(value, None)`` for the JSON in the regular file ``path``, ``(None, why)`` where it cannot be read as JSON
    (truncated, not text); a file that is not regular is refused (:func:`check_regular`)."""
    try:
        return read_json(path, what), None
    except Sin3DMInputError:  # not a regular file: said as it is
        raise
    except (OSError, ValueError) as e:
        return None, f"it cannot be read as JSON ({type(e).__name__}; truncated?)"


__all__ = ["check_regular", "json_or_why", "not_regular", "read_json", "what_text_is"]

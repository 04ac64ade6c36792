"""The manifest: which files of an output folder this tool wrote (``.sin3dm-manifest.json``), and with which command.

Only those files are ever replaced. A file is recorded *before* it appears, and a file of ours it replaces stays
recorded until the move is done (:func:`recorded_path`, :func:`replacing`), so no kill makes our own file look
foreign to the next run. A long writer appends to manifest parts as it goes (:func:`append_manifest_part`).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from contextlib import contextmanager
from pathlib import Path

from .atomic import atomic_path, atomic_write, write_data
from .confined import open_own
from .locks import locked

MANIFEST = ".sin3dm-manifest.json"
MANIFEST_PART = ".sin3dm-manifest-{}.jsonl"  # parts of the manifest appended by a long writer (one per process)
_PART = re.compile(r"^\.sin3dm-manifest-[\w.-]+\.jsonl$")

# A manifest entry: ``{"size": bytes, "mtime_ns": time, "sha256": content digest, "by": command}``. A file is ours
# when its size and time match, or its size and content do (a copy keeps the content, not always the time); older
# entries (``[size, mtime_ns]``) are still read, as written by any command.


def _digest(p: Path) -> str:
    h = hashlib.sha256()
    with open(p, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def file_entry(p: Path, by: str | None = None) -> dict:
    """The manifest entry of the file ``p`` as it is now, written by the command ``by``."""
    st = os.stat(p)
    entry = {"size": st.st_size, "mtime_ns": st.st_mtime_ns, "sha256": _digest(p)}
    return {**entry, "by": by} if by else entry


def read_manifest(folder: Path) -> dict[str, dict | list]:
    """What this tool wrote in ``folder`` before: ``{relative path: entry}`` (empty without a valid manifest)."""
    try:
        data = json.loads((Path(folder) / MANIFEST).read_text(encoding="utf-8"))
        files = dict(data["files"] if data.get("tool") == "sin3dm-lite" else {})
    except (OSError, ValueError, KeyError, AttributeError, TypeError):
        return {}
    for record in read_manifest_parts(folder):
        if isinstance(record.get("files"), dict):
            files.update(record["files"])
    inside = lambda f: isinstance(f, str) and f and not os.path.isabs(f) and ".." not in Path(f).parts
    return {Path(f).as_posix(): st for f, st in files.items() if inside(f) and f != MANIFEST and _entries(st)}


def manifest_parts(folder: Path) -> list[Path]:
    """The manifest parts (``.sin3dm-manifest-<name>.jsonl``) in ``folder``, by name."""
    try:
        return sorted(p for p in Path(folder).iterdir() if _PART.match(p.name) and p.is_file())
    except OSError:
        return []


def read_manifest_parts(folder: Path) -> list[dict]:
    """Every record (one JSON object per line) of ``folder``'s manifest parts; a line cut short by a kill is skipped."""
    records = []
    for part in manifest_parts(folder):
        try:
            lines = part.read_text(encoding="utf-8").splitlines()
        except OSError:
            continue
        for line in lines:
            try:
                r = json.loads(line)
            except ValueError:
                continue
            if isinstance(r, dict):
                records.append(r)
    return records


def append_manifest_part(folder: Path, name: str, record: dict) -> None:
    """Append ``record`` (with ``files: {relative path: entry}``) as one line to the part ``name``, on disk; call it
    *before* moving those files into place, so that a kill leaves no file of ours unrecorded."""
    fd = open_own(Path(folder) / MANIFEST_PART.format(name), os.O_WRONLY | os.O_APPEND | os.O_CREAT)
    with os.fdopen(fd, "a", encoding="utf-8") as f:
        f.write(json.dumps(record) + "\n")
        f.flush()
        os.fsync(f.fileno())


def file_record(folder: Path, names, by: str | None = None) -> dict[str, dict]:
    """``{relative path: entry}`` of ``names`` in ``folder`` as they are now, written by ``by`` (what a manifest holds)."""
    return {Path(n).as_posix(): file_entry(Path(folder) / n, by) for n in names}


def writer(folder: Path, rel: str, manifest: dict | None = None) -> str | None:
    """The command that wrote ``folder/rel`` if it is a file of ours nobody changed since ("" when an older
    version wrote it without saying), else None. Same size and time, or same size and content (a copy)."""
    manifest = read_manifest(folder) if manifest is None else manifest
    if rel not in manifest:
        return None
    p = Path(folder) / rel
    try:
        if not p.is_file() or p.is_symlink():
            return None
        st = os.stat(p)
    except OSError:
        return None
    same_size = [e for e in _entries(manifest[rel]) if e["size"] == st.st_size]
    match = next((e for e in same_size if e.get("mtime_ns") == st.st_mtime_ns), None)
    if match is None and any(e.get("sha256") for e in same_size):
        try:
            digest = _digest(p)
        except OSError:
            return None
        match = next((e for e in same_size if e.get("sha256") == digest), None)
    return None if match is None else str(match.get("by") or "")


def is_ours(folder: Path, rel: str, manifest: dict | None = None, by: str | None = None) -> bool:
    """Whether ``folder/rel`` is a file this tool wrote (with the command ``by``, if given) and nobody changed since."""
    w = writer(folder, rel, manifest)
    return w is not None and (by is None or w in ("", by))


def _entries(entry) -> list[dict]:
    """A manifest entry's acceptable states: one, or two while a replacement is under way."""

    def one(e):
        if isinstance(e, dict) and isinstance(e.get("size"), int) and isinstance(e.get("mtime_ns"), int):
            return e
        if isinstance(e, list) and len(e) == 2 and all(isinstance(x, int) for x in e):  # older versions
            return {"size": e[0], "mtime_ns": e[1]}
        return None

    if one(entry) is not None:
        return [one(entry)]
    if isinstance(entry, list) and entry and all(one(e) is not None for e in entry):
        return [one(e) for e in entry]
    return []


def write_manifest(folder: Path, files: dict) -> None:
    """Record ``files`` (``{relative path: entry}``) as written by this tool in ``folder``."""
    atomic_write(
        Path(folder) / MANIFEST, json.dumps({"tool": "sin3dm-lite", "files": dict(sorted(files.items()))}, indent=1)
    )


def record_written(folder: Path, names, by: str | None = None) -> None:
    """Add the files ``names`` (relative to ``folder``, as they are now, written by the command ``by``) to its manifest."""
    write_manifest(folder, {**read_manifest(folder), **file_record(folder, names, by)})


@contextmanager
def recorded_path(path: str | Path, by: str | None = None):
    """Yield a temporary path beside ``path``; when the block succeeds, record it as ours and move it onto ``path``.

    The manifest learns the new file *before* it appears and keeps the old file acceptable until the move is done,
    so a kill at any moment leaves ``path`` absent, old or new, always recorded.
    """
    path = Path(path)
    folder, rel = path.parent, path.name

    def record(tmp: Path) -> None:  # os.replace keeps size and time
        m = read_manifest(folder)
        write_manifest(folder, {**m, **replacing(folder, m, {rel: file_entry(tmp, by)})})

    folder.mkdir(parents=True, exist_ok=True)
    with locked(folder):  # no other process writes the folder (and its manifest) meanwhile
        with atomic_path(path, before_move=record) as tmp:
            yield tmp
        record_written(folder, [rel], by)  # the old file's stat is no longer acceptable


def replacing(folder: Path, manifest: dict, new: dict[str, dict]) -> dict:
    """The manifest entries of the files ``new`` (``{relative path: entry}``) about to be moved into ``folder``:
    where one replaces a file of ours, its entry keeps the old stat beside the new. Write ``{**manifest,
    **replacing(...)}`` *before* the moves, and the plain entries once they are done."""
    out = {}
    for f, st in new.items():
        old = _entries(manifest[f]) if is_ours(folder, f, manifest) else []
        out[f] = old + _entries(st) if old else st
    return out


def write_recorded(path: str | Path, data: bytes | str, by: str | None = None) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` atomically and record it in its folder's manifest (:func:`recorded_path`)."""
    with recorded_path(path, by) as tmp:
        write_data(tmp, data)
    return Path(path)

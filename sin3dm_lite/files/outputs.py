"""Output folders: checked before the long work (:func:`check_output_folder`), filled without touching anything
that is not ours (:func:`install_output`, :func:`merge_output`), files of ours removed (:func:`remove_files`).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from ..errors import Sin3DMInputError
from .atomic import is_temporary, resolved_path
from .confined import confined, refuse_links
from .locks import LOCK, locked
from .manifest import file_record, is_ours, read_manifest, replacing, write_manifest, writer


def check_not_overlapping(out: Path, protected: dict[str, Path], option: str = "--out") -> None:
    """Refuse ``out`` equal to, inside or containing any of ``protected`` (``{what: path}``)."""
    o = resolved_path(out)
    for what, p in protected.items():
        if p is None:
            continue
        q = resolved_path(p)
        if o == q or q in o.parents or o in q.parents:
            how = "is" if o == q else ("is inside" if q in o.parents else "contains")
            raise Sin3DMInputError(f"{option} '{out}' {how} the {what} '{p}'; choose an {option} outside it")


def check_writable(path: Path, option: str = "--out") -> None:
    """Fail now, not after the long work, if ``path`` (a file or folder to create) cannot be written."""
    path = Path(path)
    for p in (path, *path.parents):  # a link to nothing: a write would replace the link, or fail on it
        if p.exists():
            break
        if p.is_symlink():
            raise Sin3DMInputError(
                f"{option} '{path}': '{p}' is a symbolic link to '{os.readlink(p)}', which does not exist, and "
                f"sin3dm-lite neither writes through nor replaces a link; create what it points to, or choose "
                f"another {option}"
            )
    base = path if path.is_dir() else path.parent
    while not base.exists() and base.parent != base:  # the nearest existing ancestor must let us create the rest
        base = base.parent
    if not base.is_dir():
        raise Sin3DMInputError(
            f"cannot write {option} '{path}': '{base}' is a file, not a folder; choose another {option}"
        )
    try:
        fd, probe = tempfile.mkstemp(prefix=f".sin3dm-{os.getpid()}-probe.tmp", dir=base)
        os.close(fd)
        os.remove(probe)
    except OSError as e:
        raise Sin3DMInputError(
            f"cannot write {option} '{path}' ({e.strerror} in '{base}'); choose a writable {option}"
        ) from None


def _files_under(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in Path(folder).rglob("*") if p.is_file() or p.is_symlink())


def foreign_files(out: Path, names, by: str | None = None) -> list[str]:
    """Of ``names`` (relative paths, files or folders), those that exist in ``out`` and are not (all) ours
    (written by the command ``by``, if given)."""
    out = Path(out)
    ours = read_manifest(out)
    found = []
    for n in names:
        p = out / n
        if p.is_dir() and not p.is_symlink():
            found += [f"{n}/{f}" for f in _files_under(p) if not is_ours(out, f"{n}/{f}", ours, by)]
        elif (p.exists() or p.is_symlink()) and not is_ours(out, Path(n).as_posix(), ours, by):
            found.append(Path(n).as_posix())
    return found


def clash_error(out: Path, rel: str, by: str | None = None, option: str = "--out") -> Sin3DMInputError:
    """The one-line refusal for ``out/rel``, a file in the way that is not ours, or another command's."""
    w = writer(out, rel)
    if w:
        return Sin3DMInputError(
            f"'{Path(out) / rel}' was written by `sin3dm-lite {w}`, and `sin3dm-lite {by}` replaces only files it "
            f"wrote itself; move it away or choose another {option}"
        )
    return Sin3DMInputError(
        f"'{Path(out) / rel}' was not written by sin3dm-lite and would be replaced; move it away or choose another {option}"
    )


def present(out: Path) -> list[Path]:
    """What ``out`` holds, less temporaries and a lock (a writer killed at its start): no content of anyone's."""
    try:
        return [p for p in Path(out).iterdir() if not (is_temporary(p.name) or p.name == LOCK)]
    except OSError:
        return []


def check_output_folder(out: Path, overwrite: bool, names=(), option: str = "--out", by: str | None = None) -> None:
    """Refuse an ``out`` that is a file, or a non-empty folder without ``overwrite``; with it, refuse if any of
    ``names`` (what the command will write) is a file this tool (the command ``by``, if given) did not write there."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise Sin3DMInputError(f"{option} '{out}' is a file; give a folder to write into")
    if not out.is_dir() or not present(out):
        return
    refuse_links(out, option)
    if not overwrite:
        raise Sin3DMInputError(
            f"output folder '{out}' is not empty; pass --overwrite to replace what sin3dm-lite wrote there before "
            f"(other files are kept), or choose another {option}"
        )
    clash = foreign_files(out, names, by)
    if clash:
        raise clash_error(out, clash[0], by, option)


def merge_output(tmp: Path, out: Path, by: str | None = None) -> None:
    """Move the files of ``tmp`` into the existing folder ``out`` beside what is there, recording them in its manifest;
    unlike :func:`install_output` nothing else of ours is removed. The caller has checked for foreign files."""
    names = sorted(p.name for p in Path(tmp).iterdir())
    new = file_record(tmp, names, by)  # os.replace keeps size and time
    with locked(out):
        old = read_manifest(out)
        write_manifest(out, {**old, **replacing(out, old, new)})  # first: a kill leaves no file of ours unrecorded
        for n in names:
            os.replace(Path(tmp) / n, confined(out, Path(out) / n))
        write_manifest(out, {**old, **new})


def install_output(tmp: Path, out: Path, by: str | None = None) -> list[str]:
    """Move everything in the finished folder ``tmp`` into ``out`` and record it in ``out``'s manifest; returns the
    new files.

    A new ``out`` appears in one rename. Into an existing ``out``, the files the command ``by`` wrote there before
    are removed first; files of other commands, or not ours, are never touched, and one in the way of a new file
    stops everything before any change. The manifest is written first with old and new entries.
    """
    tmp, out = Path(tmp), Path(out)
    new = file_record(tmp, _files_under(tmp), by)
    if not out.exists():
        write_manifest(tmp, new)
        os.rename(tmp, out)
        return sorted(new)
    with locked(out):  # no other process writes it meanwhile (a `sample` run filling it)
        return _install_into(tmp, out, new, by)


def _install_into(tmp: Path, out: Path, new: dict, by: str | None) -> list[str]:
    old = read_manifest(out)
    for f in new:
        confined(out, out / f)  # no new file lands through a link (the folder may have changed since the checks)
    kept = {f: e for f, e in old.items() if is_ours(out, f, old)}
    clash = [f for f in new if ((out / f).exists() or (out / f).is_symlink()) and not is_ours(out, f, old, by)]
    if clash:
        raise clash_error(out, clash[0], by)
    # this command's earlier files (a render of more views leaves none behind); an older version's, where replaced
    mine = {f: e for f, e in kept.items() if f in new or (by is not None and writer(out, f, old) == by)}
    others = {f: e for f, e in kept.items() if f not in mine}
    write_manifest(out, {**kept, **replacing(out, kept, new)})
    remove_files(out, mine)
    for f in new:
        dst = confined(out, out / f)
        dst.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp / f, confined(out, dst))  # checked again: mkdir may have met a link made meanwhile
    write_manifest(out, {**others, **new})
    shutil.rmtree(tmp, ignore_errors=True)
    return sorted(new)


def remove_files(out: Path, rels) -> None:
    """Delete the files ``rels`` (relative to ``out``; the caller has checked that they are ours), deepest
    first, then the folders they leave empty; a folder that still holds anything stays."""
    for f in sorted(rels, key=lambda f: -len(Path(f).parts)):
        confined(out, Path(out) / f).unlink(missing_ok=True)  # never through a link, never outside ``out``
        for d in list(Path(f).parents)[:-1]:  # folders of ours left empty
            try:
                confined(out, Path(out) / d).rmdir()
            except OSError:
                break

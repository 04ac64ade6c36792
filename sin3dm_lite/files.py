"""Write files safely.

* Atomically: a reader (or a crash) sees the old file or the new one, never half of one.
* Never over another's files: an output folder records what this tool wrote
  in a manifest (``.sin3dm-manifest.json``); only those files are ever replaced.
  A file is recorded *before* it appears, and a file of ours it replaces stays
  recorded until the move is done (:func:`recorded_path`, :func:`replacing`),
  so no kill makes our own file look foreign to the next run.
* Temporary files and folders carry the writer's PID in their name, so that a
  later run removes the ones a killed process left behind
  (:func:`atomic_path` for one file, :func:`atomic_folder` for several).
* A long writer (``sample`` of many shapes) records as it goes in manifest
  parts (``.sin3dm-manifest-<name>.jsonl``, one JSON object with a ``files``
  entry per line, appended and flushed per item); they count as the manifest
  until the writer merges them into it at the end (:func:`append_manifest_part`).
* A run folder is locked (``.sin3dm-lock`` holding the PID) while one process writes it.
"""
from __future__ import annotations

import errno
import json
import os
import re
import shutil
import socket
import tempfile
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

from .errors import Sin3DMInputError

TEMP_PREFIX = ".sin3dm-tmp-"  # temporary folders: .sin3dm-tmp-<pid>-<random>
MANIFEST = ".sin3dm-manifest.json"
MANIFEST_PART = ".sin3dm-manifest-{}.jsonl"  # parts of the manifest appended by a long writer (one per process)
_PART = re.compile(r"^\.sin3dm-manifest-[\w.-]+\.jsonl$")
LOCK = ".sin3dm-lock"
_TEMP_DIR = re.compile(r"^\.sin3dm-tmp-(\d+)-")
_TEMP_FILE = re.compile(r"^\..*\.sin3dm-(\d+)-[^.]*\.tmp")  # from atomic_path


@contextmanager
def atomic_path(path: str | Path, before_move=None):
    """Yield a temporary path next to ``path``; move it onto ``path`` when the block succeeds.

    The temporary name keeps ``path``'s suffix (``np.savez`` and friends care).
    On an exception the temporary file is removed and ``path`` is untouched.
    ``before_move(tmp)``, if given, runs on the finished file just before the
    move (:func:`recorded_path` records it there).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.sin3dm-{os.getpid()}-", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o644)  # mkstemp makes the file private; the result is an ordinary file
        if before_move is not None:
            before_move(Path(tmp))
        os.replace(tmp, path)
    except OSError as e:
        raise named(e, path) from None
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def atomic_write(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        _write(tmp, data)
    return Path(path)


def _write(path: Path, data: bytes | str) -> None:
    if isinstance(data, str):
        path.write_text(data, encoding="utf-8")
    else:
        path.write_bytes(data)


#: below this much free space a failed write is taken for a full disk
NEARLY_FULL = 64 << 20
# how torch.save reports a write that did not go through (its C++ writer raises RuntimeError, not OSError)
_TORCH_WRITE_FAILED = ("inline_container", "PytorchStreamWriter", "file write failed", "unexpected pos")


def save_torch(obj, path: str | Path) -> None:
    """``torch.save(obj, path)``; a write that fails (a full disk) is an :class:`OSError` naming ``path``.

    torch's own error for a full disk is a ``RuntimeError`` such as
    ``[enforce fail at inline_container.cc:672] unexpected pos …``, which says
    nothing to a user; this raises ``OSError(ENOSPC)`` instead when the disk
    holding ``path`` is (nearly) full, else an ``OSError(EIO)`` quoting torch.
    """
    import torch

    try:
        torch.save(obj, path)
    except RuntimeError as e:
        if not any(s in str(e) for s in _TORCH_WRITE_FAILED):
            raise
        raise write_failed(Path(path), str(e).strip().splitlines()[0][:200]) from None


def shown_path(path: str | Path) -> str:
    """``'NAME' in 'FOLDER'`` for a file being written, our temporaries (``.sin3dm-tmp-*``, ``atomic_path``'s) left out.

    What a user recognises in a message: ``out/.sin3dm-tmp-12-ab/model.pt`` is ``'model.pt' in 'out'``, and
    a temporary folder itself is ``into 'out'``.
    """
    path = Path(path)
    m = re.match(r"^\.(.*)\.sin3dm-\d+-[^.]*\.tmp(.*)$", path.name)  # atomic_path's .STEM.sin3dm-PID-X.tmpSUFFIX
    name = m.group(1) + m.group(2) if m else path.name
    while _TEMP_DIR.match(path.name):
        path, name = path.parent, None
    folder = path.parent
    while _TEMP_DIR.match(folder.name):
        folder = folder.parent
    return f"'{name}' in '{folder}'" if name else f"into '{path}'"


def named(e: OSError, path: str | Path) -> OSError:
    """``e`` itself if it names a file, else the same error naming ``path`` (``fh.write`` on a full disk names none)."""
    return e if e.filename or e.errno is None else OSError(e.errno, e.strerror or str(e), str(path))


def write_failed(path: Path, detail: str) -> OSError:
    """The :class:`OSError` for a write to ``path`` that failed without one: ENOSPC if its disk is (nearly) full."""
    try:
        full = shutil.disk_usage(Path(path).parent).free < NEARLY_FULL
    except OSError:
        full = False
    if full:
        return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
    return OSError(errno.EIO, f"the write failed ({detail})", str(path))


# --------------------------------------------------------------------------- temporaries
def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this machine (a zombie counts as dead)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's process
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


def make_temp_dir(parent: Path) -> Path:
    """A new folder ``parent/.sin3dm-tmp-<pid>-<random>`` (mode 755); a later run removes it if this process dies."""
    tmp = Path(tempfile.mkdtemp(prefix=f"{TEMP_PREFIX}{os.getpid()}-", dir=parent))
    tmp.chmod(0o755)  # mkdtemp makes it private; the result becomes an ordinary folder
    return tmp


@contextmanager
def atomic_folder(folder: str | Path):
    """Yield a temporary folder to write files into; move them into ``folder`` when the block succeeds.

    The temporary folder is ``.sin3dm-tmp-<pid>-<random>``: inside ``folder``
    if it exists, else beside it (leftovers of killed writers there are removed
    first, see :func:`remove_stale_temps`). A new ``folder`` appears in one
    rename; into an existing one each file is moved with an atomic replace,
    ``.obj`` files last (an OBJ only appears once the files it names are
    there), and other files in it are left alone. On an exception ``folder`` is
    unchanged and the temporary folder is removed.
    """
    folder = Path(folder)
    base = folder if folder.is_dir() else folder.parent
    base.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(base)
    tmp = make_temp_dir(base)
    try:
        yield tmp
        if not folder.exists():
            os.rename(tmp, folder)  # the whole folder appears at once
        else:
            for item in sorted(tmp.iterdir(), key=lambda p: (p.suffix == ".obj", p.name)):
                os.replace(item, folder / item.name)
    except OSError as e:
        raise named(e, folder) from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def remove_stale_temps(folder: Path) -> list[Path]:
    """Remove temporary folders/files in ``folder`` left by sin3dm-lite processes that no longer run."""
    removed = []
    try:
        entries = list(Path(folder).iterdir())
    except OSError:
        return removed
    for e in entries:
        m = _TEMP_DIR.match(e.name) or _TEMP_FILE.match(e.name)
        if m is None or pid_alive(int(m.group(1))):
            continue
        try:
            if e.is_dir() and not e.is_symlink():
                shutil.rmtree(e)
            else:
                e.unlink()
            removed.append(e)
        except OSError:
            pass
    return removed


# --------------------------------------------------------------------------- output checks
def _resolved(p: Path) -> Path:
    return Path(os.path.abspath(Path(p).expanduser())).resolve()


def check_not_overlapping(out: Path, protected: dict[str, Path], option: str = "--out") -> None:
    """Refuse ``out`` equal to, inside or containing any of ``protected`` (``{what: path}``)."""
    o = _resolved(out)
    for what, p in protected.items():
        if p is None:
            continue
        q = _resolved(p)
        if o == q or q in o.parents or o in q.parents:
            how = "is" if o == q else ("is inside" if q in o.parents else "contains")
            raise Sin3DMInputError(f"{option} '{out}' {how} the {what} '{p}'; choose an {option} outside it")


def check_writable(path: Path, option: str = "--out") -> None:
    """Fail now, not after the long work, if ``path`` (a file or folder to create) cannot be written."""
    path = Path(path)
    base = path if path.is_dir() else path.parent
    while not base.exists():  # the nearest existing ancestor must let us create what is missing
        if base.parent == base:
            break
        base = base.parent
    if not base.is_dir():
        raise Sin3DMInputError(f"cannot write {option} '{path}': '{base}' is a file, not a folder; choose another {option}")
    try:
        fd, probe = tempfile.mkstemp(prefix=f".sin3dm-{os.getpid()}-probe.tmp", dir=base)
        os.close(fd)
        os.remove(probe)
    except OSError as e:
        raise Sin3DMInputError(f"cannot write {option} '{path}' ({e.strerror} in '{base}'); choose a writable {option}") from None


# --------------------------------------------------------------------------- manifest
def _stat(p: Path) -> list[int]:
    st = os.stat(p)
    return [st.st_size, st.st_mtime_ns]


def read_manifest(folder: Path) -> dict[str, list[int]]:
    """What this tool wrote in ``folder`` before: ``{relative path: [size, mtime_ns]}`` (empty without a valid manifest)."""
    try:
        data = json.loads((Path(folder) / MANIFEST).read_text(encoding="utf-8"))
        files = data["files"] if data.get("tool") == "sin3dm-lite" else {}
        files = dict(files)
    except (OSError, ValueError, KeyError, AttributeError, TypeError):
        return {}
    for record in read_manifest_parts(folder):
        if isinstance(record.get("files"), dict):
            files.update(record["files"])
    out = {}
    for f, st in files.items():
        if (isinstance(f, str) and f and not os.path.isabs(f) and ".." not in Path(f).parts and f != MANIFEST
                and _stats(st)):
            out[Path(f).as_posix()] = st
    return out


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
    """Append ``record`` (with ``files: {relative path: [size, mtime_ns]}``) as one line to the part ``name``, on disk.

    Call it *before* moving those files into place (a move keeps size and
    time): a kill then leaves no file of ours unrecorded.
    """
    with open(Path(folder) / MANIFEST_PART.format(name), "a", encoding="utf-8") as f:
        f.write(json.dumps(record) + "\n")
        f.flush()
        os.fsync(f.fileno())


def file_record(folder: Path, names) -> dict[str, list[int]]:
    """``{relative path: [size, mtime_ns]}`` of ``names`` in ``folder`` as they are now (what a manifest holds)."""
    return {Path(n).as_posix(): _stat(Path(folder) / n) for n in names}


def is_ours(folder: Path, rel: str, manifest: dict | None = None) -> bool:
    """Whether ``folder/rel`` is a file this tool wrote and nobody changed since (same size and time)."""
    manifest = read_manifest(folder) if manifest is None else manifest
    p = Path(folder) / rel
    try:
        return rel in manifest and p.is_file() and not p.is_symlink() and _stat(p) in _stats(manifest[rel])
    except OSError:
        return False


def _stats(entry) -> list[list[int]]:
    """A manifest entry's acceptable ``[size, mtime_ns]`` pairs: one, or two while a replacement is under way."""
    if isinstance(entry, list) and len(entry) == 2 and all(isinstance(x, int) for x in entry):
        return [list(entry)]
    if isinstance(entry, list) and entry and all(isinstance(x, list) and len(x) == 2 for x in entry):
        return [list(x) for x in entry]
    return []


def write_manifest(folder: Path, files: dict[str, list[int]]) -> None:
    """Record ``files`` (``{relative path: [size, mtime_ns]}``) as written by this tool in ``folder``."""
    atomic_write(Path(folder) / MANIFEST, json.dumps({"tool": "sin3dm-lite", "files": dict(sorted(files.items()))}, indent=1))


def record_written(folder: Path, names) -> None:
    """Add the files ``names`` (relative to ``folder``, as they are now) to its manifest."""
    m = read_manifest(folder)
    m.update({Path(n).as_posix(): _stat(Path(folder) / n) for n in names})
    write_manifest(folder, m)


@contextmanager
def recorded_path(path: str | Path):
    """Yield a temporary path beside ``path``; when the block succeeds, record it as ours and move it onto ``path``.

    Like :func:`atomic_path`, but the manifest of ``path``'s folder learns the
    new file *before* it appears, and keeps the old file of ours acceptable
    until the move is done. A kill at any moment leaves ``path`` absent, the old
    file or the new one, always recorded: a rerun with ``--overwrite`` replaces
    it instead of refusing it as someone else's. (Writing the file and then
    recording it left a window in which a kill made our own file look foreign.)
    """
    path = Path(path)
    folder, rel = path.parent, path.name

    def record(tmp: Path) -> None:  # os.replace keeps size and time
        m = read_manifest(folder)
        write_manifest(folder, {**m, **replacing(folder, m, {rel: _stat(tmp)})})

    with atomic_path(path, before_move=record) as tmp:
        yield tmp
    record_written(folder, [rel])  # the old file's stat is no longer acceptable


def replacing(folder: Path, manifest: dict, new: dict[str, list[int]]) -> dict:
    """The manifest entries of the files ``new`` (``{relative path: [size, mtime_ns]}``) about to be moved into
    ``folder``: where one replaces a file of ours (by ``manifest``), its entry keeps the old stat beside the new.

    Write ``{**manifest, **replacing(...)}`` *before* the moves, so a kill
    between the manifest and the moves leaves nothing of ours looking foreign,
    and the plain entries once the moves are done.
    """
    out = {}
    for f, st in new.items():
        old = _stats(manifest[f]) if is_ours(folder, f, manifest) else []
        out[f] = old + [list(st)] if old else list(st)
    return out


def write_recorded(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` atomically and record it in its folder's manifest (:func:`recorded_path`)."""
    with recorded_path(path) as tmp:
        _write(tmp, data)
    return Path(path)


def _files_under(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in Path(folder).rglob("*") if p.is_file() or p.is_symlink())


def foreign_files(out: Path, names) -> list[str]:
    """Of ``names`` (relative paths, files or folders), those that exist in ``out`` and are not (all) ours."""
    out = Path(out)
    ours = read_manifest(out)
    found = []
    for n in names:
        p = out / n
        if p.is_dir() and not p.is_symlink():
            found += [f"{n}/{f}" for f in _files_under(p) if not is_ours(out, f"{n}/{f}", ours)]
        elif (p.exists() or p.is_symlink()) and not is_ours(out, Path(n).as_posix(), ours):
            found.append(Path(n).as_posix())
    return found


def check_output_folder(out: Path, overwrite: bool, names=(), option: str = "--out") -> None:
    """Refuse an ``out`` that is a file, or a non-empty folder without ``overwrite``.

    With ``overwrite``, refuse if any of ``names`` (what the command will write)
    is a file this tool did not write there before.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise Sin3DMInputError(f"{option} '{out}' is a file; give a folder to write into")
    if not out.is_dir():
        return
    present = [p for p in out.iterdir()  # temporaries and a lock (a writer killed at its start) are no content
               if not (_TEMP_DIR.match(p.name) or _TEMP_FILE.match(p.name) or p.name == LOCK)]
    if not present:
        return
    if not overwrite:
        raise Sin3DMInputError(
            f"output folder '{out}' is not empty; pass --overwrite to replace what sin3dm-lite wrote there before "
            f"(other files are kept), or choose another {option}"
        )
    clash = foreign_files(out, names)
    if clash:
        raise Sin3DMInputError(
            f"'{out / clash[0]}' was not written by sin3dm-lite and would be replaced; move it away or choose another {option}"
        )


def merge_output(tmp: Path, out: Path) -> None:
    """Move the files of ``tmp`` into the existing folder ``out`` beside what is there, recording them in its manifest.

    Unlike :func:`install_output` nothing else of ours in ``out`` is removed
    (``examples --write`` adds one example to a folder); the caller has checked
    that no foreign file is in the way.
    """
    names = sorted(p.name for p in Path(tmp).iterdir())
    new = {n: _stat(Path(tmp) / n) for n in names}  # os.replace keeps size and time
    old = read_manifest(out)
    write_manifest(out, {**old, **replacing(out, old, new)})  # first: a kill leaves no file of ours unrecorded
    for n in names:
        os.replace(Path(tmp) / n, Path(out) / n)
    write_manifest(out, {**old, **new})


def install_output(tmp: Path, out: Path) -> list[str]:
    """Move everything in the finished folder ``tmp`` into ``out`` and record it in ``out``'s manifest.

    A new ``out`` appears in one rename. Into an existing ``out``, the files
    the old manifest lists (unchanged since) are removed first; other files are
    never touched, and one in the way of a new file stops everything before
    any change. The manifest is written first with old and new entries, so a
    kill halfway leaves no file of ours unrecorded. Returns the new files.
    """
    tmp, out = Path(tmp), Path(out)
    new = {f: _stat(tmp / f) for f in _files_under(tmp)}
    if not out.exists():
        write_manifest(tmp, new)
        os.rename(tmp, out)
        return sorted(new)
    old = read_manifest(out)
    mine = {f: st for f, st in old.items() if is_ours(out, f, old)}
    clash = [f for f in new if (out / f).exists() and f not in mine]
    if clash:
        raise Sin3DMInputError(f"'{out / clash[0]}' was not written by sin3dm-lite and would be replaced; move it away and run again")
    write_manifest(out, {**mine, **replacing(out, mine, new)})
    for f in sorted(mine, key=lambda f: -len(Path(f).parts)):
        (out / f).unlink(missing_ok=True)
        for d in list(Path(f).parents)[:-1]:  # folders of ours left empty
            try:
                (out / d).rmdir()
            except OSError:
                break
    for f in new:
        dst = out / f
        dst.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp / f, dst)
    write_manifest(out, new)
    for part in manifest_parts(out):  # folded into the old manifest, which is replaced now
        part.unlink(missing_ok=True)
    shutil.rmtree(tmp, ignore_errors=True)
    return sorted(new)


# --------------------------------------------------------------------------- run-folder lock
_held: set[Path] = set()


def _lock_info() -> dict:
    return {"pid": os.getpid(), "host": socket.gethostname(), "since": time.strftime("%Y-%m-%d %H:%M:%S")}


def create_locked_folder(folder: Path, files: dict[str, str], option: str = "--out") -> None:
    """Create ``folder`` holding ``files`` (``{name: text}``) and a lock of this process, in one rename.

    A kill leaves either the complete folder (with a stale lock the next
    writer takes over) or a temporary folder beside it that the next run removes.
    """
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(folder.parent)
    tmp = make_temp_dir(folder.parent)
    try:
        for name, text in files.items():
            (tmp / name).write_text(text, encoding="utf-8")
        (tmp / LOCK).write_text(json.dumps(_lock_info()))
        os.rename(tmp, folder)  # replaces an empty folder; fails if another process filled it meanwhile
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        raise Sin3DMInputError(f"cannot create '{folder}' ({e.strerror}); choose another {option}") from None
    _held.add(_resolved(folder))


def acquire_lock(folder: Path) -> None:
    """Lock ``folder`` for this process (``folder/.sin3dm-lock`` with the PID).

    A lock of a live process refuses; a lock of a dead one is taken over with a warning.
    """
    folder = Path(folder)
    lock = folder / LOCK
    me = _lock_info()
    for _ in range(3):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                info = json.loads(lock.read_text())
                pid, host = int(info["pid"]), str(info.get("host", ""))
            except (OSError, ValueError, KeyError, TypeError):
                info, pid, host = {}, -1, me["host"]  # unreadable: a writer killed while writing it
            if host == me["host"] and not pid_alive(pid) or pid == -1:
                warnings.warn(f"run folder '{folder}' was locked by process {pid}, which no longer runs; taking it over",
                              stacklevel=3)
                try:
                    lock.unlink()
                except FileNotFoundError:
                    pass
                continue
            raise Sin3DMInputError(
                f"run folder '{folder}' is being written by another sin3dm-lite process (PID {pid} on {host or 'this machine'}, "
                f"since {info.get('since', '?')}); wait for it to finish, or delete '{lock}' if that process is gone"
            ) from None
        with os.fdopen(fd, "w") as f:
            json.dump(me, f)
        _held.add(_resolved(folder))
        remove_stale_temps(folder)  # the folder is ours now: leftovers of a killed writer can go
        return
    raise Sin3DMInputError(f"could not lock run folder '{folder}'; another process keeps taking '{lock}'")


def holds_lock(folder: Path) -> bool:
    return _resolved(folder) in _held


def release_lock(folder: Path) -> None:
    """Remove ``folder``'s lock if this process holds it."""
    key = _resolved(folder)
    if key in _held:
        _held.discard(key)
        try:
            (Path(folder) / LOCK).unlink()
        except FileNotFoundError:
            pass

"""One file or folder written whole (:func:`atomic_path`, :func:`atomic_folder`), and the temporaries a killed
writer leaves behind: their names carry the writer's PID and machine, so a later run removes them.
"""

from __future__ import annotations

import errno
import hashlib
import os
import re
import shutil
import socket
import tempfile
from contextlib import contextmanager, suppress
from pathlib import Path

TEMP_PREFIX = ".sin3dm-tmp-"  # temporary folders: .sin3dm-tmp-<pid>@<machine>-<random>
#: what follows a temporary's prefix: the writer's PID and (not in older names) its machine
OWNER = r"(\d+)(?:@([0-9a-f]{8}))?-"
_TEMP_DIR = re.compile(r"^\.sin3dm-tmp-" + OWNER)
_TEMP_FILE = re.compile(r"^\..*\.sin3dm-" + OWNER + r"[^.]*\.tmp")  # from atomic_path


def machine_tag() -> str:
    """Eight hex digits naming this machine (from its host name) in a temporary's name: a PID means something
    only on the machine that gave it (a folder may be shared between machines)."""
    return hashlib.sha1(socket.gethostname().encode()).hexdigest()[:8]


def owner_name() -> str:
    """``<pid>@<machine tag>`` of this process, for a temporary's name."""
    return f"{os.getpid()}@{machine_tag()}"


def writer_gone(m: re.Match) -> bool:
    """Whether the writer named in a temporary's name (``m`` of a pattern ending in :data:`OWNER`) is gone: its
    PID no longer runs, judged on its own machine only (an older name, without a machine, as if made here)."""
    return m.group(2) in (None, machine_tag()) and not pid_alive(int(m.group(1)))


@contextmanager
def atomic_path(path: str | Path, before_move=None):
    """Yield a temporary path next to ``path`` (with its suffix: ``np.savez`` cares); move it onto ``path`` when
    the block succeeds, after ``before_move(tmp)`` if given. On an exception ``path`` is untouched."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_file(path.parent, path.name)
    try:
        yield tmp
        os.chmod(tmp, 0o644)  # mkstemp makes the file private; the result is an ordinary file
        if before_move is not None:
            before_move(tmp)
        os.replace(tmp, path)
    except OSError as e:
        raise named(e, path) from None
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


@contextmanager
def atomic_paths(folder: str | Path, names):
    """Yield ``{name: temporary path}`` beside each ``folder/name``; when the block succeeds, move them all onto
    their names, only once every one is written: a failure while writing changes none of them."""
    folder = Path(folder)
    tmps: dict[str, Path] = {}
    try:
        for n in names:
            tmps[n] = _temp_file(folder, n)
        yield dict(tmps)
        for t in tmps.values():
            os.chmod(t, 0o644)
        for n, t in tmps.items():
            os.replace(t, folder / n)
    except OSError as e:
        raise named(e, folder) from None
    finally:
        for t in tmps.values():
            if os.path.exists(t):
                os.remove(t)


def _temp_file(folder: Path, name: str) -> Path:
    """A new empty file ``folder/.<stem>.sin3dm-<owner>-<random>.tmp<suffix>`` for the file ``name``."""
    name = Path(name)
    fd, tmp = tempfile.mkstemp(prefix=f".{name.stem}.sin3dm-{owner_name()}-", suffix=f".tmp{name.suffix}", dir=folder)
    os.close(fd)
    return Path(tmp)


def atomic_write(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        write_data(tmp, data)
    return Path(path)


def write_data(path: Path, data: bytes | str) -> None:
    """Write ``data`` to ``path`` as it is (text as UTF-8), not atomically: into a temporary path."""
    if isinstance(data, str):
        path.write_text(data, encoding="utf-8")
    else:
        path.write_bytes(data)


#: below this much free space a failed write is taken for a full disk
NEARLY_FULL = 64 << 20
# how torch.save reports a write that did not go through (its C++ writer raises RuntimeError, not OSError)
_TORCH_WRITE_FAILED = ("inline_container", "PytorchStreamWriter", "file write failed", "unexpected pos")


def save_torch(obj, path: str | Path) -> None:
    """``torch.save(obj, path)``; a write that fails is an :class:`OSError` naming ``path`` (ENOSPC on a full disk)
    rather than torch's ``RuntimeError`` (``... unexpected pos ...``), which says nothing to a user."""
    import torch

    try:
        torch.save(obj, path)
    except RuntimeError as e:
        if not any(s in str(e) for s in _TORCH_WRITE_FAILED):
            raise
        raise write_failed(Path(path), str(e).strip().splitlines()[0][:200]) from None


def shown_path(path: str | Path) -> str:
    """``'NAME' in 'FOLDER'`` for a file being written, our temporaries left out: ``out/.sin3dm-tmp-12-ab/model.pt``
    is ``'model.pt' in 'out'``, and a temporary folder itself is ``into 'out'``."""
    path = Path(path)
    m = re.match(r"^\.(.*)\.sin3dm-" + OWNER + r"[^.]*\.tmp(.*)$", path.name)  # .STEM.sin3dm-OWNER-X.tmpSUFFIX
    name = m.group(1) + m.group(4) if m else path.name
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
    with suppress(OSError):
        if shutil.disk_usage(Path(path).parent).free < NEARLY_FULL:
            return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
    return OSError(errno.EIO, f"the write failed ({detail})", str(path))


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
    """A new folder ``parent/.sin3dm-tmp-<pid>@<machine>-<random>`` (mode 755); a later run on this machine
    removes it if this process dies."""
    tmp = Path(tempfile.mkdtemp(prefix=f"{TEMP_PREFIX}{owner_name()}-", dir=parent))
    tmp.chmod(0o755)  # mkdtemp makes it private; the result becomes an ordinary folder
    return tmp


@contextmanager
def atomic_folder(folder: str | Path):
    """Yield a temporary folder (inside ``folder`` if it exists, else beside it) to write files into; move them into
    ``folder`` when the block succeeds. A new ``folder`` appears in one rename; into an existing one each file is
    moved with an atomic replace, ``.obj`` files last (an OBJ appears only once the files it names are there)."""
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
    """Remove temporary folders/files in ``folder`` left by sin3dm-lite processes of this machine that no longer
    run (another machine's are left alone: its PIDs mean nothing here)."""
    removed = []
    try:
        entries = list(Path(folder).iterdir())
    except OSError:
        return removed
    for e in entries:
        m = _TEMP_DIR.match(e.name) or _TEMP_FILE.match(e.name)
        if m is None or not writer_gone(m):
            continue
        with suppress(OSError):
            if e.is_dir() and not e.is_symlink():
                shutil.rmtree(e)
            else:
                e.unlink()
            removed.append(e)
    return removed


def is_temporary(name: str) -> bool:
    """Whether ``name`` is one of our temporaries (a ``.sin3dm-tmp-*`` folder or :func:`atomic_path`'s file)."""
    return bool(_TEMP_DIR.match(name) or _TEMP_FILE.match(name))


def resolved_path(p: str | Path) -> Path:
    """``p`` absolute, with ``~`` and symbolic links resolved: one name for one folder."""
    return Path(os.path.abspath(Path(p).expanduser())).resolve()

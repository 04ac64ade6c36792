"""One writer per folder: an OS lock (flock; a byte lock on Windows) held on ``folder/.sin3dm-lock`` for the
writer's life, the file naming its PID, host and start time for the messages. The OS drops the lock however the
process ends, so a lock file nobody holds is provably stale, and one just created (its writer starting) is held.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import sys
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

from ..errors import Sin3DMInputError
from .atomic import make_temp_dir, pid_alive, remove_stale_temps, resolved_path
from .confined import link_error, open_own

LOCK = ".sin3dm-lock"

try:
    import fcntl

    def _try_lock(fd: int) -> bool:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except (BlockingIOError, PermissionError):
            return False
except ImportError:  # Windows
    import msvcrt

    def _try_lock(fd: int) -> bool:
        try:
            os.lseek(fd, 0, os.SEEK_SET)
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
            return True
        except OSError:
            return False


_held: dict[Path, int] = {}  # locked folder → the open lock file


def _lock_info() -> dict:
    return {"pid": os.getpid(), "host": socket.gethostname(), "since": time.strftime("%Y-%m-%d %H:%M:%S")}


def _write_info(fd: int) -> None:
    os.lseek(fd, 0, os.SEEK_SET)
    os.ftruncate(fd, 0)
    os.write(fd, json.dumps(_lock_info()).encode())
    os.fsync(fd)


def _read_info(fd: int) -> dict:
    """The owner a lock file names ({} while its writer has not written it yet, or unreadable)."""
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        info = json.loads(os.read(fd, 4096).decode())
        int(info["pid"])
        return info
    except (OSError, ValueError, KeyError, TypeError, UnicodeDecodeError):
        return {}


def create_locked_folder(folder: Path, files: dict[str, str], option: str = "--out") -> None:
    """Create ``folder`` holding ``files`` (``{name: text}``) and a lock of this process, in one rename (a link to
    an empty folder is made through). The current folder is refused: renamed onto, it would vanish under the shell.
    """
    folder = Path(folder)
    if folder.is_dir() and resolved_path(folder) == resolved_path(Path.cwd()):
        raise Sin3DMInputError(
            f"{option} '{folder}' is the current folder, and this makes its folder anew; give a new folder's name, "
            "or start from outside this folder"
        )
    folder = resolved_path(folder) if folder.is_symlink() else folder
    folder.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(folder.parent)
    tmp = make_temp_dir(folder.parent)
    fd = None
    try:
        for name, text in files.items():
            (tmp / name).write_text(text, encoding="utf-8")
        fd = os.open(tmp / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        if not _try_lock(fd):  # nobody else can see it yet
            raise OSError(0, "could not lock a new file")
        _write_info(fd)
        os.rename(tmp, folder)  # replaces an empty folder; fails if another process filled it meanwhile
    except OSError as e:
        if fd is not None:
            os.close(fd)
        shutil.rmtree(tmp, ignore_errors=True)
        raise Sin3DMInputError(f"cannot create '{folder}' ({e.strerror}); choose another {option}") from None
    _held[resolved_path(folder)] = fd


def acquire_lock(folder: Path, what: str = "folder", option: str | None = "--out") -> None:
    """Lock ``folder`` for this process (an OS lock on ``folder/.sin3dm-lock``, which names the PID).

    A lock another process holds refuses. A lock file nobody holds is taken over (with a warning), unless it names a
    process that still runs here, or one on another machine: nothing proves that process gone. ``what`` names the
    folder in messages, ``option`` the flag that chooses another (None: a command without one).
    """
    folder = Path(folder)
    lock = folder / LOCK
    key = resolved_path(folder)
    if key in _held:
        raise Sin3DMInputError(f"{what} '{folder}' is already being written by this process; wait for that to finish")
    me = _lock_info()
    for _ in range(3):
        if lock.is_symlink():  # the lock file is written: never through a link
            raise link_error(lock)
        try:
            fd = open_own(lock, os.O_RDWR | os.O_CREAT)
        except OSError as e:
            raise Sin3DMInputError(f"cannot lock {what} '{folder}' ({e.strerror}); check its permissions") from None
        if not _try_lock(fd):
            info = _read_info(fd)
            os.close(fd)
            who = (
                f"PID {info['pid']} on {info.get('host') or 'this machine'}, since {info.get('since', '?')}"
                if info
                else "it is just starting"
            )
            raise Sin3DMInputError(
                f"{what} '{folder}' is being written by another sin3dm-lite process ({who}); "
                f"wait for it to finish{f', or choose another {option}' if option else ''}"
            ) from None
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(lock))
        except OSError:
            same = False
        if not same:  # its owner removed the file while we opened it: take the new one
            os.close(fd)
            continue
        info = _read_info(fd)
        if info:
            pid, host = int(info["pid"]), str(info.get("host", ""))
            if host and host != me["host"] or pid_alive(pid) and pid != me["pid"]:
                os.close(fd)  # a writer of an older version (no OS lock), or on another machine: not provably gone
                raise Sin3DMInputError(
                    f"{what} '{folder}' is being written by another sin3dm-lite process (PID {pid} on "
                    f"{host or 'this machine'}, since {info.get('since', '?')}); wait for it to finish, or delete "
                    f"'{lock}' if that process is gone"
                )
            warnings.warn(
                f"{what} '{folder}' was locked by process {pid}, which no longer runs; taking it over", stacklevel=3
            )
        elif os.fstat(fd).st_size:
            warnings.warn(
                f"{what} '{folder}' had an unreadable lock that no process holds; taking it over", stacklevel=3
            )
        _write_info(fd)
        _held[key] = fd
        remove_stale_temps(folder)  # the folder is ours now: leftovers of a killed writer can go
        return
    raise Sin3DMInputError(f"could not lock {what} '{folder}'; another process keeps taking '{lock}'")


@contextmanager
def locked(folder: Path, what: str = "output folder"):
    """Hold ``folder``'s lock for the block (unless this process holds it already)."""
    if holds_lock(folder):
        yield
        return
    acquire_lock(folder, what)
    try:
        yield
    finally:
        release_lock(folder)


def holds_lock(folder: Path) -> bool:
    return resolved_path(folder) in _held


def release_lock(folder: Path) -> None:
    """Remove ``folder``'s lock if this process holds it (the file first, so no one locks a removed file).

    A lock file that cannot be removed is left for the next writer to take over: a warning, said only when no
    other error unwinds (that error is the one the user reads).
    """
    fd = _held.pop(resolved_path(folder), None)
    if fd is None:
        return
    unwinding = sys.exc_info()[1] is not None
    lock = Path(folder) / LOCK
    try:
        lock.unlink(missing_ok=True)
    except OSError:
        os.close(fd)  # Windows removes no open file: close it and try once more
        fd = None
        try:
            lock.unlink(missing_ok=True)
        except OSError as e:
            if not unwinding:
                warnings.warn(
                    f"could not remove the lock '{lock}' ({e.strerror}); the next sin3dm-lite command takes it over",
                    stacklevel=2,
                )
    if fd is not None:
        os.close(fd)

"""The ``sin3dm-lite`` command.

    sin3dm-lite examples [--write NAME --out DIR]      list / write the built-in example shapes
    sin3dm-lite grid MESH --resolution N --out FILE.npz mesh → TSDF + colour grid
    sin3dm-lite fit MESH_OR_EXAMPLE --preset small --out RUN_DIR [--resume]
    sin3dm-lite sample RUN_DIR -n 4 --out DIR [--resize SX SY SZ] [--diversity D]
    torchrun --nproc_per_node=N -m sin3dm_lite.cli sample RUN_DIR -n 1000 --out DIR   sharded (see mass.py)
    sin3dm-lite demo [--example NAME] [--out DIR] [--train]   the whole method on a built-in example
    sin3dm-lite render MESH --views 8 --size 512 --out DIR   PNG views (no display or GPU needed)
    sin3dm-lite evaluate RUN SAMPLES_DIR [--out report.json] [--weights DIR]   the paper's metrics
    sin3dm-lite calibrate RUN_DIR [--resolution 128]    choose the run's diversity for its shape (fit does it too)
    sin3dm-lite --version                               the installed version

Every user error prints one line naming the problem and the fix, and exits with code 2. No command overwrites a
file it did not write (``--overwrite`` replaces only what its manifest, ``.sin3dm-manifest.json``, lists); outputs
are checked before the long work, written into a temporary folder beside the target and moved into place.

The parser is in ``parser_cli``; the commands in ``fit_cli`` (examples, grid, fit), ``sample_cli`` (sample, demo)
and ``evaluate_cli`` (render, evaluate, calibrate); ``main`` here runs one and turns user errors into one line.
"""

from __future__ import annotations

import signal
import sys
import threading
import warnings
from contextlib import contextmanager

from ..errors import Sin3DMInputError, Terminated
from .evaluate_cli import cmd_calibrate, cmd_evaluate, cmd_render
from .fit_cli import cmd_examples, cmd_fit, cmd_grid
from .parser_cli import COMMANDS, build_parser, package_version
from .sample_cli import cmd_demo, cmd_sample, sample_request


def disk_error(e: OSError, out: str | None = None, has_out: bool = True) -> str:
    """One line for a failed write or read: what, where and the fix (``out``: the command's ``--out``, named when
    the error names no file; ``has_out``: whether the command has an ``--out`` to suggest)."""
    import errno

    from ..files import shown_path

    where = f" {shown_path(e.filename)}" if e.filename else ""
    other = " or choose another --out" if has_out else ""
    if e.errno in (errno.ENOSPC, errno.EDQUOT):
        what = "no space left on device" if e.errno == errno.ENOSPC else "disk quota exceeded"
        where = where or (f" into '{out}'" if out else " the output")
        return f"{what} while writing{where}; free space{other}"
    return f"{e.strerror or e}{where}; check that path (permissions, free space){other}"


@contextmanager
def sigterm_as_interrupt():
    """While a command runs, SIGTERM raises :class:`errors.Terminated`: the command stops as after Ctrl-C."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def terminate(signum, frame):
        raise Terminated

    old = signal.signal(signal.SIGTERM, terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv:  # no command: the help, as a successful answer
        parser.print_help()
        return 0
    a = parser.parse_args(argv)
    show = warnings.showwarning

    def one_line(message, category, filename, lineno, file=None, line=None):  # warnings as one line, no source
        if issubclass(category, SyntaxWarning):  # a library's source compiled on first import, not the user's input
            return
        print(f"sin3dm-lite {a.command}: warning: {message}", file=sys.stderr)

    warnings.showwarning = one_line
    try:
        with sigterm_as_interrupt():
            run_command(a)
    except (Sin3DMInputError, OSError) as e:  # OSError: the disk, not the code (full, made read-only meanwhile)
        why = e if isinstance(e, Sin3DMInputError) else disk_error(e, getattr(a, "out", None), hasattr(a, "out"))
        print(f"sin3dm-lite {a.command}: error: {why}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        how = "terminated" if isinstance(e, Terminated) else "interrupted"
        print(f"sin3dm-lite {a.command}: {how}{': ' + str(e) if str(e) else ''}", file=sys.stderr)
        return 143 if isinstance(e, Terminated) else 130
    finally:
        warnings.showwarning = show
    return 0


def run_command(a) -> None:
    {
        "examples": cmd_examples,
        "grid": cmd_grid,
        "fit": cmd_fit,
        "sample": cmd_sample,
        "demo": cmd_demo,
        "render": cmd_render,
        "evaluate": cmd_evaluate,
        "calibrate": cmd_calibrate,
    }[a.command](a)


__all__ = ["main", "build_parser", "COMMANDS", "package_version", "sample_request", "disk_error"]

"""One exception type for everything a user can get wrong.

The CLI catches :class:`Sin3DMInputError`, prints its message (which names the
problem *and* the fix) and exits with code 2, without a traceback.
"""


class Sin3DMInputError(ValueError):
    """Bad user input: a missing file, an unreadable mesh, an impossible setting."""


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill PID``, a job scheduler's stop) turned into an interruption: the command ends as after
    Ctrl-C (what finished is kept, one line says how to continue), not killed where it stands."""

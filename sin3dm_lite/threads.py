"""How many CPU threads, and how they wait: the one place that decides (imported before torch).

PyTorch's CPU kernels run on OpenMP threads (GNU libgomp in the PyPI wheels). By
default an idle OpenMP thread *spins* for a while before it sleeps, waiting for the
next parallel loop. Alone on a machine that is a little faster; but two processes
that each start one thread per core then spin on each other's cores, and each waits
for a thread that cannot run: a fit beside a notebook kernel, a test suite beside its
notebooks, or a sampler beside its export worker slow each other down many times over.

The policy, applied when ``sin3dm_lite`` is imported (before torch):

* idle OpenMP threads sleep at once (``OMP_WAIT_POLICY=PASSIVE``), so processes
  sharing the cores share them instead of stalling each other;
* the number of threads stays PyTorch's (one per core);
* helper processes (the sampler's export workers) use one thread each.

A user's own settings always win: with ``OMP_WAIT_POLICY`` or ``GOMP_SPINCOUNT`` in the
environment nothing is changed, and ``OMP_NUM_THREADS`` / ``torch.set_num_threads`` are
never overridden. The measurements behind the choice are in docs/performance.md
("Threads") and ``benchmarks/bench_contention.py`` prints them again.
"""
from __future__ import annotations

import os
import sys

#: environment variables that mean the user chose how OpenMP threads wait
USER_WAIT_SETTINGS = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "KMP_BLOCKTIME")


def apply_wait_policy(environ=os.environ) -> str | None:
    """Make idle OpenMP threads sleep instead of spin, unless the user chose; returns what was set (or None).

    Only takes effect in a process that has not loaded torch yet (OpenMP reads the
    variable when it starts); :func:`policy_in_effect` tells whether it did.
    """
    if any(k in environ for k in USER_WAIT_SETTINGS):
        return None
    environ["OMP_WAIT_POLICY"] = "PASSIVE"
    return "PASSIVE"


def policy_in_effect() -> bool:
    """Whether this process's OpenMP threads sleep when idle (the variable was set before torch loaded)."""
    return os.environ.get("OMP_WAIT_POLICY", "").upper() == "PASSIVE" and not _torch_loaded_before_policy


_torch_loaded_before_policy = "torch" in sys.modules

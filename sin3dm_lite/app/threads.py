"""How many CPU threads, and how they wait: the one place that decides (applied by ``import sin3dm_lite``).

This method's tensors are small, so a parallel loop is over before a second thread pays for itself, and two
processes that each spin one OpenMP thread per core stall each other. The policy: one thread per process
(``OMP_NUM_THREADS=1``) whose idle threads sleep at once (``OMP_WAIT_POLICY=PASSIVE``); ``SIN3DM_THREADS=N`` asks
for N threads, which then spin briefly before they sleep (``GOMP_SPINCOUNT``), since a thread that sleeps at once
pays a wake-up at every parallel loop. A fit reproduces bit for bit only at the same thread count. The user's own
settings (``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``, ``OMP_WAIT_POLICY``, ``GOMP_SPINCOUNT``, ``KMP_BLOCKTIME``, a
``torch.set_num_threads`` made before the import) always win.
"""

from __future__ import annotations

import os
import sys

#: environment variables that mean the user chose how OpenMP threads wait
USER_WAIT_SETTINGS = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "KMP_BLOCKTIME")
#: environment variables that mean the user chose how many threads
USER_THREAD_SETTINGS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")
#: threads per process unless ``SIN3DM_THREADS`` or the user's settings say otherwise
DEFAULT_THREADS = 1
#: how long an idle OpenMP thread spins before it sleeps when ``SIN3DM_THREADS`` asks for more than one
SPIN_COUNT = "10000"
#: what :func:`apply_policy` set in this process's environment (empty where the user's settings won)
APPLIED: dict[str, str] = {}


def env_count(environ, name: str, low: int, default: int, high: int | None = None, why_high: str = "") -> int:
    """The whole number the environment variable ``name`` sets (unset: ``default``); a value below ``low`` gives
    ``default``, one above ``high`` gives ``high``, said on stderr and set in ``environ`` for the processes started."""
    raw = environ.get(name, "").strip()
    if not raw:
        return default
    try:
        value = int(raw)
    except ValueError:
        value = None
    if value is None or value < low:
        used, why = default, f"is not a whole number of at least {low}"
    elif high is not None and value > high:
        used, why = high, f"is more than {why_high} ({high})"
    else:
        return value
    print(f"sin3dm-lite: {name}={environ.get(name)!r} {why}; using {used}", file=sys.stderr, flush=True)
    environ[name] = str(used)
    return used


def chosen_threads(environ=os.environ) -> int:
    """The thread count the policy asks for: ``SIN3DM_THREADS`` (1 to the usable cores), else 1."""
    return env_count(
        environ, "SIN3DM_THREADS", 1, DEFAULT_THREADS, usable_cores(), "the CPU cores this process may use"
    )


def apply_policy(environ=os.environ) -> dict[str, str]:
    """Set the thread count and wait policy where the user did not (and torch's count where it is already loaded
    at its default); returns the variables it set."""
    changed: dict[str, str] = {}
    if not any(k in environ for k in USER_WAIT_SETTINGS):
        if chosen_threads(environ) > 1 and not any(k in environ for k in USER_THREAD_SETTINGS):
            changed["GOMP_SPINCOUNT"] = SPIN_COUNT  # more threads asked for: spin briefly, then sleep
        else:
            changed["OMP_WAIT_POLICY"] = "PASSIVE"
    if not any(k in environ for k in USER_THREAD_SETTINGS):
        changed["OMP_NUM_THREADS"] = str(chosen_threads(environ))
    environ.update(changed)
    if environ is os.environ:
        APPLIED.update(changed)
    torch = sys.modules.get("torch")
    if "OMP_NUM_THREADS" in changed and torch is not None and torch.get_num_threads() == (os.cpu_count() or 1):
        torch.set_num_threads(int(changed["OMP_NUM_THREADS"]))  # loaded before us, still at its default
    return changed


def threads_hint(applied: dict | None = None, cores: int | None = None) -> str | None:
    """What a CPU fit says when the policy (``applied``, default this process's) gave it one thread of several
    cores, else None."""
    cores = usable_cores() if cores is None else cores
    applied = APPLIED if applied is None else applied
    if cores < 2 or applied.get("OMP_NUM_THREADS") != "1":
        return None
    return (
        f"one CPU thread (so that jobs sharing the CPU do not stall each other); with nothing else running, "
        f"SIN3DM_THREADS=2 makes a fit about 1.2-1.5x faster on this {cores}-core machine (set it before starting "
        "Python or the command), and about 2x slower beside another busy job"
    )


#: the most export workers :func:`export_workers` picks by itself (each holds a CPU copy of the model and a decode grid)
MAX_EXPORT_WORKERS = 4


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity where the OS tells it, else ``os.cpu_count()``)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # macOS, Windows
        return os.cpu_count() or 1


def export_workers(environ=os.environ) -> int:
    """How many processes export samples when ``--workers`` is not given: ``SIN3DM_WORKERS``, else one per usable
    core shared among torchrun's local ranks, from 1 to :data:`MAX_EXPORT_WORKERS`."""
    local = environ.get("LOCAL_WORLD_SIZE", "1")
    ranks = int(local) if local.isdigit() and int(local) > 0 else 1
    return env_count(environ, "SIN3DM_WORKERS", 0, max(1, min(MAX_EXPORT_WORKERS, usable_cores() // ranks)))

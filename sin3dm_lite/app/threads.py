"""How many CPU threads, and how they wait: the one place that decides (applied by ``import sin3dm_lite``).

PyTorch's CPU kernels run on OpenMP threads (GNU libgomp in the PyPI wheels), one
per core by default, and an idle OpenMP thread *spins* for a while before it sleeps,
waiting for the next parallel loop. This method's tensors are small (one latent of
a few dozen texels a side, a few thousand points per step): a parallel loop is over
before a second thread pays for itself. And two processes that each start one
spinning thread per core stall each other many times over: a fit beside a notebook
kernel, a test suite beside its notebooks, a sampler beside its export worker.

The policy, applied when ``sin3dm_lite`` is imported (before torch where it can be):

* one thread per process (``OMP_NUM_THREADS=1``): two processes then share two cores
  instead of stalling each other (on 2-core CPUs, with and without AVX-512, every
  training step of the CPU presets also measured faster on one thread than on two
  sleeping ones);
* idle OpenMP threads sleep at once (``OMP_WAIT_POLICY=PASSIVE``), so an OpenMP pool that
  something else starts does not spin on the cores;
* ``SIN3DM_THREADS=N`` asks for N threads, and for N > 1 idle threads spin a little
  before they sleep (``GOMP_SPINCOUNT=10000``) instead: a thread that sleeps at once
  pays a wake-up at every parallel loop, and two sleeping threads ran a ``quick``
  training step *slower* than one. With the short spin, a process **alone** on a
  2-core CPU trains ``quick`` about 1.2-1.4x (``small`` with bf16 1.5x) faster on two threads than on one; beside
  another busy process it runs about 2x slower, so it stays an opt-in
  (:func:`threads_hint` says so where it pays). Results differ in the last bits from
  a one-thread run (sums are split differently), so a fit reproduces bit for bit only
  at the same thread count.

A user's own settings always win: with ``OMP_NUM_THREADS`` (or ``MKL_NUM_THREADS``) in
the environment the thread count is not touched, with ``OMP_WAIT_POLICY`` /
``GOMP_SPINCOUNT`` / ``KMP_BLOCKTIME`` the wait policy is not, and a
``torch.set_num_threads`` made before importing the package is kept. The measurements
are in docs/performance.md ("Threads").
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
#: how long an idle OpenMP thread spins before it sleeps when ``SIN3DM_THREADS`` asks for more than one (libgomp's
#: ``GOMP_SPINCOUNT``): 10,000 kept the second thread's gain on a ``quick`` step, 300-3,000 lost it (docs/performance.md)
SPIN_COUNT = "10000"
#: what :func:`apply_policy` set in this process's environment (empty where the user's settings won)
APPLIED: dict[str, str] = {}


def env_count(environ, name: str, low: int, default: int, high: int | None = None, why_high: str = "") -> int:
    """The whole number the environment variable ``name`` sets (unset or empty: ``default``).

    One that is no whole number or is below ``low`` gives ``default``, one above ``high`` gives ``high``
    (``why_high``: what that limit is); either is said in one line on stderr, and ``environ`` then holds the
    value used, so that the processes started from here (export workers, notebook kernels) use it without
    saying it again.
    """
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
    """The thread count the policy asks for: ``SIN3DM_THREADS``, a whole number from 1 to the usable cores (another
    value is said on stderr, :func:`env_count`), else 1."""
    return env_count(
        environ, "SIN3DM_THREADS", 1, DEFAULT_THREADS, usable_cores(), "the CPU cores this process may use"
    )


def apply_policy(environ=os.environ) -> dict[str, str]:
    """Set the thread count and wait policy where the user did not; returns the variables it set.

    The variables take effect in a process that has not loaded torch yet, and in every
    process it starts (export workers, notebook kernels). Where torch is already loaded
    with its default thread count, that count is set too.
    """
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
    """What a CPU fit says when the policy gave it one thread (``applied``: what :func:`apply_policy` set, default
    this process's) on a machine with more cores, else None."""
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
    """How many processes decode, texture and export samples when ``--workers`` is not given.

    ``SIN3DM_WORKERS=N`` sets it (the test suite sets 1: its two processes share two cores; a value that is no
    count is said on stderr and the default used; memory caps it later, ``mass.check_sample_sizes``).
    Else one per usable core, shared among the sampling ranks on this machine (torchrun's
    ``LOCAL_WORLD_SIZE``), at least 1 and at most :data:`MAX_EXPORT_WORKERS`. Each worker
    runs one thread (the policy above), and the denoiser's share of a sample is small
    beside its decode, texture and export, so on a 2-core CPU two workers export about
    twice as many meshes a minute as one (docs/performance.md, "Many shapes").
    """
    local = environ.get("LOCAL_WORLD_SIZE", "1")
    ranks = int(local) if local.isdigit() and int(local) > 0 else 1
    return env_count(environ, "SIN3DM_WORKERS", 0, max(1, min(MAX_EXPORT_WORKERS, usable_cores() // ranks)))

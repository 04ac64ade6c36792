"""What a value a user passes may be: the one owner of every check that the CLI and the Python API share.

So ``-n 2.5`` and ``sample(2.5)`` are refused by the same line, with one :class:`~sin3dm_lite.errors.Sin3DMInputError`
that says what the value may be. ``name`` is how the message calls the value; ``None`` (the parser, which names the
flag itself) gives ``expected RANGE, got VALUE``.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from ..data.config import LIMITS, allowed, check_setting
from ..errors import Sin3DMInputError

#: seeds: the config's ``seed`` range (a fit's seed), which ``torch.Generator.manual_seed`` takes on every platform
SEED_RANGE = LIMITS["seed"]
#: one sample's own seed in a list of seeds (a run's ``seed + i``): what ``torch.Generator.manual_seed`` takes
SAMPLE_SEED_MAX = 2**63 - 1
#: a resize or outpaint factor is at most this (a latent 8 times the input's along each axis)
MAX_FACTOR = 8.0


def refuse(name: str | None, rule: str, value) -> Sin3DMInputError:
    """The one-line error for ``value``: ``NAME must be RULE, got VALUE`` (``expected RULE, got VALUE`` unnamed)."""
    shown = repr(value)
    if is_whole(value):
        shown = str(int(value))
    elif isinstance(value, (float, np.floating)):  # 2.0 stays 2.0 (a float where a whole number is asked)
        shown = f"{float(value):g}"
        shown += "" if any(c in shown for c in ".ena") else ".0"
    return Sin3DMInputError(f"{name} must be {rule}, got {shown}" if name else f"expected {rule}, got {shown}")


def is_whole(value) -> bool:
    """An integer (Python's or numpy's), not a bool: ``2`` is, ``2.0``, ``"2"`` and ``True`` are not."""
    return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))


def is_real(value) -> bool:
    """A finite real number (an integer or a float, not a bool, not NaN or infinite)."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)) and math.isfinite(float(value))


def whole(value, name: str | None = None, low: int = 1, high: int | None = None) -> int:
    """``value`` as an int if it is a whole number from ``low`` (to ``high``), else the one-line error."""
    if low == 1 and high is None:
        rule = "a positive whole number"
    elif high is None:
        rule = f"a whole number, {low} or more" if low == 0 else f"a whole number of at least {low}"
    else:
        rule = f"a whole number from {low:,} to {high:,}"
    if not is_whole(value) or value < low or (high is not None and value > high):
        raise refuse(name, rule, value)
    return int(value)


def seed(value, name: str | None = "seed") -> int:
    """A seed: a whole number in :data:`SEED_RANGE`."""
    low, high = SEED_RANGE
    if not is_whole(value) or not low <= value <= high:
        raise refuse(name, f"a whole number from {low} to {high} (seeds)", value)
    return int(value)


def seeds(value, n: int, name: str = "seed"):
    """``Sin3DM.sample``'s ``seed``: one seed (sample ``i`` takes ``seed + i``), a list of ``n`` seeds, or a
    ``torch.Generator`` (which draws the whole batch)."""
    import torch

    if isinstance(value, torch.Generator):
        return value
    if isinstance(value, (list, tuple, np.ndarray)):
        if len(value) != n:
            raise Sin3DMInputError(f"{len(value)} seeds for {n} samples; give one seed per sample, or one seed")
        # a run's ``seed + i`` may pass SEED_RANGE: each is checked as torch takes it
        return [whole(v, f"each of the seeds ({name})", 0, SAMPLE_SEED_MAX) for v in value]
    return seed(value, name)


def share(value, name: str | None = None) -> float:
    """A share from 0 to 1 (diversity)."""
    if not is_real(value) or not 0 <= value <= 1:
        raise refuse(name, "a number from 0 to 1", value)
    return float(value)


def finite(value, name: str | None = None) -> float:
    """Any finite number."""
    if not is_real(value):
        raise refuse(name, "a finite number", value)
    return float(value)


def positive(value, name: str | None = None) -> float:
    """A finite number above 0 (a time budget in minutes)."""
    if not is_real(value) or not value > 0:
        raise refuse(name, "a number above 0", value)
    return float(value)


def factors(value, what: str, low: float = 0.0, low_included: bool = False) -> tuple[float, float, float]:
    """Size factors along x, y, z (one number for all three, or three), each above ``low`` (or from ``low``,
    ``low_included``) and at most :data:`MAX_FACTOR`; ``what``: ``resize`` or ``outpaint``."""
    rule = f"from {low:g} to {MAX_FACTOR:g}" if low_included else f"in ({low:g}, {MAX_FACTOR:g}]"
    extra = " (outpainting grows the box; resize shrinks it)" if what == "outpaint" else ""
    items = [value] if is_real(value) or isinstance(value, (bool, np.bool_)) else value
    try:
        items = list(items)
    except TypeError:
        items = None
    if items is None or len(items) not in (1, 3) or not all(is_real(v) for v in items):
        raise Sin3DMInputError(f"{what} takes one number or three (x, y, z), each {rule}{extra}, got {value!r}")
    bad = [v for v in items if not ((low <= v if low_included else low < v) and v <= MAX_FACTOR)]
    if bad:
        raise Sin3DMInputError(f"{what} factors must be {rule}{extra}, got {float(bad[0]):g}")
    f = [float(v) for v in items]
    return (f[0], f[0], f[0]) if len(f) == 1 else (f[0], f[1], f[2])


def setting(key: str, value, name: str | None, high: bool = True):
    """``value`` for the sampling setting ``key`` (``sampling.steps``, ...): None (the model's own), or what
    :data:`data.config.LIMITS` allows; ``high=False`` leaves the upper bound to a later check of the memory."""
    if value is None:
        return None
    low, top = LIMITS[key]
    try:
        check_setting(key, min(value, top) if not high and is_whole(value) else value)
    except Sin3DMInputError:
        rule = allowed(key) if high else f"a whole number of at least {low}"
        raise refuse(name, rule, value) from None
    return value


def flag(value, name: str) -> bool:
    """True or False, not a truthy string or number."""
    if not isinstance(value, (bool, np.bool_)):
        raise refuse(name, "True or False", value)
    return bool(value)


def index(value, count: int, name: str = "index") -> int:
    """The index of one of ``count`` items (``0`` to ``count - 1``)."""
    if count == 0:
        raise Sin3DMInputError(f"there is nothing to pick {name} {value!r} from: no samples")
    return whole(value, f"{name} (these samples hold {count})", 0, count - 1)


__all__ = [
    "MAX_FACTOR",
    "SAMPLE_SEED_MAX",
    "SEED_RANGE",
    "factors",
    "finite",
    "flag",
    "index",
    "is_real",
    "is_whole",
    "refuse",
    "seed",
    "seeds",
    "setting",
    "share",
    "whole",
]

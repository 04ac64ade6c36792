"""What every exercise check shares: the error it raises, calling the student's function, comparing, reporting."""

from __future__ import annotations

import numpy as np
import torch


class ExerciseError(AssertionError):
    """Your function disagrees with the library; the message says where and, when it can, why."""


def call(name: str, fn, *args, hint: str = ""):
    """Run the student's function; an exception becomes an ExerciseError naming it (plus a hint)."""
    try:
        return fn(*args)
    except Exception as e:  # the student's bug, reported in the exercise's terms
        raise ExerciseError(
            f"your {name} raised {type(e).__name__}: {e}" + (f"\n  hint: {hint}" if hint else "")
        ) from e


def parts(name: str, out, n: int, what: str):
    """The student's answer as ``n`` parts (a tuple or list), or an ExerciseError: "should return ``what``"."""
    if not (isinstance(out, (tuple, list)) and len(out) == n):
        raise ExerciseError(f"your {name} should return {what}")
    return out


def as64(name: str, value, like: torch.Tensor) -> torch.Tensor:
    """The student's answer as a float64 tensor of ``like``'s shape, or an ExerciseError saying what it is.

    float32 is welcome (compare it with :func:`tolerance`); float16 and bfloat16 are too coarse to check.
    """
    if not isinstance(value, (torch.Tensor, np.ndarray)):
        raise ExerciseError(
            f"your {name} returned a {type(value).__name__}, expected a tensor of shape {tuple(like.shape)}"
        )
    value = torch.as_tensor(value)
    if tuple(value.shape) != tuple(like.shape):
        raise ExerciseError(f"your {name} returned shape {tuple(value.shape)}, expected {tuple(like.shape)}")
    if value.dtype in (torch.float16, torch.bfloat16):
        raise ExerciseError(f"your {name} returned {value.dtype}: compute in float32 or float64")
    return value.detach().cpu().double()


def tolerance(value, base: float, scale: float = 1.0) -> float:
    """How far an answer in ``value``'s dtype may be from the float64 reference and still be right.

    ``base`` for float64 (and integer) answers. A float32 answer carries float32 rounding, amplified where
    the formula divides by a small number (``1-ᾱ_t`` near t = 0), so it may differ by ``2·10⁴`` float32
    epsilons times ``scale`` (the size of the values compared, at least 1).
    """
    dtype = value.dtype if isinstance(value, (torch.Tensor, np.ndarray)) else np.dtype(np.float64)
    if dtype in (torch.float32, np.float32):
        return max(base, 2e4 * float(np.finfo(np.float32).eps) * max(1.0, float(scale)))
    return base


def as_array(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    """The student's answer as a float64 numpy array of ``shape``, or an ExerciseError saying what it is."""
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ExerciseError(
            f"your {name} returned a {type(value).__name__}, expected an array of shape {shape}"
        ) from None
    if arr.shape != tuple(shape):
        raise ExerciseError(f"your {name} returned shape {arr.shape}, expected {tuple(shape)}")
    return arr


def _np64(x) -> np.ndarray:
    return np.asarray(x.detach().cpu().double() if isinstance(x, torch.Tensor) else x, np.float64)


def matching_hint(got, candidates: dict, tol: float, want=None, rtol: float = 0.0) -> str:
    """The hint of the first wrong answer (``{hint: answer}``) that the student's output matches.

    With ``want`` (the right answer) a wrong answer matches when it agrees with the output wherever the
    output is wrong, so a mistake that shows at a few elements only is still named. ``rtol`` widens the
    match by a share of the wrong answer's size.
    """
    got = _np64(got)
    if want is not None:
        wrong = np.abs(got - _np64(want)) > tol
        if not wrong.any():
            return ""
    for text, cand in candidates.items():
        cand = _np64(cand)
        if cand.shape != got.shape:
            continue
        near = np.abs(got - cand) <= tol + rtol * np.abs(cand)
        if near[wrong].all() if want is not None else near.all():
            return f"\n  hint: {text}"
    return ""


def passed(name: str, cases: int, err: float) -> None:
    """The line a check prints when the student's function agrees with the library."""
    print(f"✓ your {name} matches the library on {cases} random cases (max error {err:.1e})")


__all__ = ["ExerciseError", "as64", "as_array", "call", "matching_hint", "parts", "passed", "tolerance"]

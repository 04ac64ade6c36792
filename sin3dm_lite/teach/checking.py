"""What every exercise check shares: the error it raises, calling the student's function, comparing, reporting.

The checks themselves are in :mod:`~sin3dm_lite.teach.exercises` (the diffusion model, the triplane, the
denoiser, evaluation) and :mod:`~sin3dm_lite.teach.shape_exercises` (the grid's box, retargeting, edit
masks, tangent frames).
"""

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


def as64(name: str, value, like: torch.Tensor) -> torch.Tensor:
    """The student's answer as a float64 tensor of ``like``'s shape, or an ExerciseError saying what it is.

    A float32 answer is welcome (compare it with :func:`tolerance`); float16 and bfloat16 are too coarse to check.
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
    the formula divides by a small number (``1-ᾱ_t`` near t = 0 is about 1e-4): it may differ by
    ``2·10⁴`` float32 epsilons (2.4e-3) times ``scale`` (the size of the values compared, at least 1).
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


def matching_hint(got, candidates: dict, tol: float, want=None, rtol: float = 0.0) -> str:
    """The hint of the first wrong answer the student's output matches (tensors or arrays of the same shape).

    With ``want`` (the right answer) a wrong answer matches when it agrees with the student's output on every
    element where that output is wrong: so a mistake that shows at a few steps or texels only is still named.
    ``rtol`` widens the match by a share of the wrong answer's size (float32 rounding of a large wrong value).
    """
    got = np.asarray(got.detach().cpu().double() if isinstance(got, torch.Tensor) else got, np.float64)
    if want is not None:
        want = np.asarray(want.detach().cpu().double() if isinstance(want, torch.Tensor) else want, np.float64)
        wrong = np.abs(got - want) > tol
        if not wrong.any():
            return ""
    for text, cand in candidates.items():
        cand = np.asarray(cand.detach().cpu().double() if isinstance(cand, torch.Tensor) else cand, np.float64)
        if cand.shape != got.shape:
            continue
        near = np.abs(got - cand) <= tol + rtol * np.abs(cand)
        if near[wrong].all() if want is not None else near.all():
            return f"\n  hint: {text}"
    return ""


def passed(name: str, cases: int, err: float) -> None:
    """The line a check prints when the student's function agrees with the library."""
    print(f"✓ your {name} matches the library on {cases} random cases (max error {err:.1e})")


__all__ = ["ExerciseError", "as64", "as_array", "call", "matching_hint", "passed", "tolerance"]

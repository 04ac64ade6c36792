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
    """The student's answer as a float64 tensor of ``like``'s shape, or an ExerciseError saying what it is."""
    if not isinstance(value, (torch.Tensor, np.ndarray)):
        raise ExerciseError(
            f"your {name} returned a {type(value).__name__}, expected a tensor of shape {tuple(like.shape)}"
        )
    value = torch.as_tensor(value)
    if tuple(value.shape) != tuple(like.shape):
        raise ExerciseError(f"your {name} returned shape {tuple(value.shape)}, expected {tuple(like.shape)}")
    return value.detach().cpu().double()


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


def matching_hint(got, candidates: dict, tol: float) -> str:
    """The hint of the first wrong answer the student's output matches (tensors or arrays of the same shape)."""
    for text, wrong in candidates.items():
        if isinstance(got, torch.Tensor):
            if wrong.shape == got.shape and float((got - wrong.double()).abs().max()) <= tol:
                return f"\n  hint: {text}"
        elif np.shape(wrong) == np.shape(got) and np.allclose(got, wrong, rtol=0, atol=tol):
            return f"\n  hint: {text}"
    return ""


def passed(name: str, cases: int, err: float) -> None:
    """The line a check prints when the student's function agrees with the library."""
    print(f"✓ your {name} matches the library on {cases} random cases (max error {err:.1e})")


__all__ = ["ExerciseError", "as64", "as_array", "call", "matching_hint", "passed"]

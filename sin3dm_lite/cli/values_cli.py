"""What each option's value may be: the argparse types of the ``sin3dm-lite`` command.

Each parses one word of the command line and refuses a bad one with a line that names the range
(``expected a share from 0 to 1, got 1.5``), which the parser prints as its one-line error.
"""

from __future__ import annotations

import argparse


def number(text: str, kind: type, what: str):
    """``text`` read as ``kind`` (int or float), or the one-line error "expected ``what``, got 'text'"."""
    try:
        return kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got '{text}'") from None


def int_at_least(low: int, what: str):
    """An argparse type: a whole number ≥ ``low``; ``what`` names the range in the error."""

    def parse(text: str) -> int:
        v = number(text, int, "a whole number")
        if v < low:
            raise argparse.ArgumentTypeError(f"expected {what}, got {v}")
        return v

    return parse


positive_int = int_at_least(1, "a positive number")
whole = int_at_least(0, "0 or more")


def factor(what: str, low: float, low_included: bool):
    """An argparse type: a size factor up to 8 above ``low``; ``what`` names the flag in the error."""

    def parse(text: str) -> float:
        v = number(text, float, "a number")
        if not ((low <= v if low_included else low < v) and v <= 8):
            raise argparse.ArgumentTypeError(f"{what}, got {v:g}")
        return v

    return parse


resize_factor = factor("resize factors must be in (0, 8]", 0.0, False)
outpaint_factor = factor(
    "outpaint factors must be from 1 to 8 (outpainting grows the box; --resize shrinks it)", 1.0, True
)


def unit_float(text: str) -> float:
    v = number(text, float, "a number from 0 to 1")
    if not (0 <= v <= 1):
        raise argparse.ArgumentTypeError(f"expected a share from 0 to 1, got {v}")
    return v


def unit_score(text: str) -> float:
    v = finite_float(text)
    if not 0 <= v <= 1:
        raise argparse.ArgumentTypeError(f"a patch score is from 0 to 1, got {v}")
    return v


def finite_float(text: str) -> float:
    v = number(text, float, "a number")
    if v != v or v in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number, got '{text}'")
    return v


def seed_int(text: str) -> int:
    v = number(text, int, "a whole number")
    if not 0 <= v < 2**32:
        raise argparse.ArgumentTypeError(f"seeds run from 0 to {2**32 - 1}, got {v}")
    return v

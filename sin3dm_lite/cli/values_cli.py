"""The argparse types of the ``sin3dm-lite`` command: each reads one word as a number and hands it to the check
the Python API calls too (:mod:`sin3dm_lite.app.values`); a bad one becomes the parser's one-line error."""

from __future__ import annotations

import argparse

from ..app import values
from ..errors import Sin3DMInputError


def checked(kind: type, what: str, check):
    """An argparse type: the word read as ``kind`` (``what`` names it when it is no number), then ``check``."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got '{text}'") from None
        try:
            return check(value)
        except Sin3DMInputError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    return parse


def int_at_least(low: int):
    """An argparse type: a whole number ≥ ``low`` (:func:`values.whole`)."""
    return checked(int, "a whole number", lambda v: values.whole(v, None, low))


positive_int = int_at_least(1)
whole = int_at_least(0)
resize_factor = checked(float, "a number", lambda v: values.factors(v, "resize")[0])
outpaint_factor = checked(float, "a number", lambda v: values.factors(v, "outpaint", 1.0, True)[0])
unit_float = checked(float, "a number from 0 to 1", values.share)
finite_float = checked(float, "a number", values.finite)
positive_float = checked(float, "a number", values.positive)
seed_int = checked(int, "a whole number", lambda v: values.seed(v, None))


def sampling_setting(key: str, high: bool = True):
    """An argparse type: a value of the sampling setting ``key`` (:func:`values.setting`; ``high=False``: the top is
    checked against the memory later)."""
    return checked(int, "a whole number", lambda v: values.setting(key, v, None, high))


def unit_score(text: str) -> float:
    v = finite_float(text)
    if not 0 <= v <= 1:
        raise argparse.ArgumentTypeError(f"a patch score is from 0 to 1, got {v}")
    return v

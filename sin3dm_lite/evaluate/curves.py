"""The calibration's curves: a score per setting drawn, smoothed to fall as the knob rises, its standard errors,
and where it crosses a goal (:func:`~sin3dm_lite.evaluate.calibrate.calibrate_diversity` reads its choice there).
"""

from __future__ import annotations

import numpy as np


def non_increasing(values: list[float], weights: list[float], pooled: bool = False):
    """The closest non-increasing sequence to ``values`` in weighted least squares (pool adjacent violators).

    Patch scores fall as the knob rises; measured on a few samples they can rise by chance from one setting to the
    next. Pooling such neighbours averages their samples instead of believing either one. With ``pooled``, also
    returns each value's pooled weight (the samples its smoothed score rests on)."""
    blocks: list[list[float]] = []  # [mean, weight, count]
    for v, w in zip(values, weights):
        blocks.append([v, w, 1])
        while len(blocks) > 1 and blocks[-2][0] < blocks[-1][0]:
            (a, wa, ka), (b, wb, kb) = blocks[-2], blocks[-1]
            blocks[-2:] = [[(a * wa + b * wb) / (wa + wb), wa + wb, ka + kb]]
    fitted = [v for v, _, k in blocks for _ in range(k)]
    return (fitted, [w for _, w, k in blocks for _ in range(k)]) if pooled else fitted


def crossing(levels: list[float], fitted: list[float], goal: float) -> float | None:
    """The highest setting where the fitted scores (levels from high to low) reach ``goal``, linearly between
    the last setting that misses it and the first that keeps it; None when none keeps it."""
    for k, (d, y) in enumerate(zip(levels, fitted)):
        if y >= goal:
            if k == 0:
                return d
            return d + (levels[k - 1] - d) * (y - goal) / (y - fitted[k - 1])
    return None


def curve(tried: list[dict], key: str) -> tuple[list[float], list[float], list[float]]:
    """The settings drawn (from high to low, each once), ``key``'s scores there made non-increasing in the knob
    (each setting weighted by its number of samples: a setting drawn twice pools its samples), and the standard
    error of each smoothed score (the samples' pooled spread over the root of the samples it rests on)."""
    by_setting: dict[float, list[float]] = {}
    for t in tried:
        w = by_setting.setdefault(t["diversity"], [0.0, 0.0])
        w[0] += t[key] * t["n"]
        w[1] += t["n"]
    levels = sorted(by_setting, reverse=True)
    means = [by_setting[d][0] / by_setting[d][1] for d in levels]
    weights = [by_setting[d][1] for d in levels]
    # drawn from high to low settings; the scores must fall as the setting rises, so fit from low to high
    fitted, pooled = (v[::-1] for v in non_increasing(means[::-1], weights[::-1], pooled=True))
    dof = sum(t["n"] - 1 for t in tried)
    spread = float(np.sqrt(sum((t["n"] - 1) * t.get(f"{key}_sd", 0.0) ** 2 for t in tried) / dof)) if dof else 0.0
    return levels, fitted, [spread / np.sqrt(w) for w in pooled]


__all__ = ["crossing", "curve", "non_increasing"]

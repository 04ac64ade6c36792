"""Choosing the diversity knob for one shape: the most varied samples that still keep the input's patches.

The paper names the trade-off between diversity and fidelity as its main
limitation, and the knob (``Sin3DM.sample(diversity=...)``: start the reverse
process at step ``d · 999`` from the input's latent, noised) turns it. Its
curve differs from shape to shape, and it is steep: on one fit of a tiled
slab the samples' LP-IoU against the input is 0.78 at 0.6, 0.62 at 0.68 and
0.48 at 1.0, while a rock field keeps 0.72 at 1.0 (README, "Diversity ↔
fidelity"). So no fixed default suits every mesh.

:func:`calibrate_diversity` measures the curve instead. It walks down the
knob from 1 (pure noise, the paper's sampling) in steps of 0.1, draws a few
samples at each setting, decodes their occupancy at the fit's grid
resolution and scores them against the input's occupancy with the paper's
LP-IoU / LP-F (:func:`metrics.lp_scores`: the share of the samples' surface
patches that have a near-exact match among the input's). It stops at the
first setting that keeps the goals with room to spare, smooths the scores
into a curve that falls with the knob, and returns where that curve crosses
the goals (read 0.02 above them, for the noise of a few samples). Each setting gets its own sample seeds, so no single lucky or
unlucky set of samples decides.

``Sin3DM.fit`` runs it at the end of a fit when the preset's
``sampling.calibrate`` is on (``small``, ``detail``, ``quick``) and saves the chosen value as the
run's ``sampling.diversity``; ``sin3dm-lite calibrate RUN`` runs it on a
fitted run. It costs a few seconds per setting drawn: a handful of samples
decoded on the training grid, no meshes.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .errors import Sin3DMInputError

#: what the samples must keep against the input: the paper's averages are LP-F 0.699 at G-Div 0.224, and the
#: project's goals (issue "real variations") LP-IoU ≥ 0.55 with LP-F ≥ 0.70. The few samples calibration draws scatter
#: by a few hundredths around the figures of many (README "Diversity ↔ fidelity"), so the choice does too
GOALS = {"lp_iou": 0.55, "lp_fscore": 0.70}


@dataclass
class Calibration:
    """What :func:`calibrate_diversity` chose, and the settings it tried on the way (in order)."""

    diversity: float
    goals: dict
    n: int
    resolution: int
    tried: list = field(default_factory=list)  # [{"diversity", "lp_iou", "lp_fscore", "g_div", "kept", "*_fitted"}]
    kept_goals: bool = False  # False when even the lowest setting drawn missed the goals (then it is the answer)

    def to_dict(self) -> dict:
        return asdict(self)

    def summary(self) -> str:
        """One line per setting drawn (raw and smoothed patch scores, G-Div), then the choice."""
        lines = [f"diversity {t['diversity']:.2f}: LP-IoU {t['lp_iou']:.3f} (smoothed {t['lp_iou_fitted']:.3f}) · "
                 f"LP-F {t['lp_fscore']:.3f} (smoothed {t['lp_fscore_fitted']:.3f}) · G-Div {t['g_div']:.3f}"
                 for t in self.tried]
        lines.append(f"chosen: {self.diversity:g}" + ("" if self.kept_goals else
                                                        " (the lowest drawn: no setting kept the goals)"))
        return "\n".join(lines)


def sample_occupancy(model, diversity: float, n: int, seed: int, resolution: int) -> list[np.ndarray]:
    """``n`` samples at ``diversity`` (seeds ``seed`` …), each decoded to occupancy (SDF < 0) on the model's
    box at ``resolution`` voxels along its longest side: the sign of the decoder, no mesh."""
    from .decode import decode_grid

    samples = model.sample(n, seed=seed, diversity=diversity, progress=False)
    out = []
    for i in range(n):
        sdf = decode_grid(model.decoder, samples.triplane[i:i + 1], samples.aabb, resolution)
        out.append(sdf < 0)
    return out


def _non_increasing(values: list[float], weights: list[float]) -> list[float]:
    """The closest non-increasing sequence to ``values`` in weighted least squares (pool adjacent violators).

    Patch scores fall as the knob rises; measured on a few samples they can
    rise by chance from one setting to the next. Pooling such neighbours
    averages their samples instead of believing either one.
    """
    blocks: list[list[float]] = []  # [mean, weight, count]
    for v, w in zip(values, weights):
        blocks.append([v, w, 1])
        while len(blocks) > 1 and blocks[-2][0] < blocks[-1][0]:
            (a, wa, ka), (b, wb, kb) = blocks[-2], blocks[-1]
            blocks[-2:] = [[(a * wa + b * wb) / (wa + wb), wa + wb, ka + kb]]
    return [v for v, _, k in blocks for _ in range(k)]


def _crossing(levels: list[float], fitted: list[float], goal: float) -> float | None:
    """The highest setting where the fitted scores (levels from high to low) reach ``goal``, linearly between
    the last setting that misses it and the first that keeps it; None when none keeps it."""
    for k, (d, y) in enumerate(zip(levels, fitted)):
        if y >= goal:
            if k == 0:
                return d
            d_miss, y_miss = levels[k - 1], fitted[k - 1]
            return d + (d_miss - d) * (y - goal) / (y - y_miss)
    return None


def calibrate_diversity(model, reference: np.ndarray, goals: dict | None = None, n: int = 8, seed: int = 10_000,
                        lowest: float = 0.5, step: float = 0.1, margin: float = 0.05, safety: float = 0.02,
                        progress: bool = True) -> Calibration:
    """The highest diversity in ``[lowest, 1]`` whose samples keep ``goals`` against ``reference``.

    Walks down a ladder of settings, 1, 1 - ``step``, ... ``lowest``, drawing
    ``n`` samples at each with **seeds of its own** (``seed + 1000·k`` at the
    k-th setting), and stops at the first setting whose samples keep every
    goal by ``margin`` (lower settings only keep more). The patch scores of
    all settings drawn are then made non-increasing in the knob (pooling
    neighbours that disagree by chance) and the answer is where that curve
    crosses each goal raised by ``safety``, linearly between the two settings
    around the crossing; the lower crossing of the two goals wins. Read at the
    goal itself the crossing of 8 noisy samples per setting lands above the
    true one about half the time, and there the samples miss the goal (the
    canyon: 0.84, where 24 other samples keep LP-F 0.692); 0.02 higher it
    lands at 0.70 (24 samples: 0.722). Independent seeds per setting
    matter: one set of samples reused at every setting can be lucky or unlucky
    at all of them at once (a tiled slab: a bisection on one seed set chose
    anything from 0.59 to 0.88 for five sets, this ladder 0.63 to 0.69; README
    "The knob chosen per shape").

    Args:
        model: a fitted :class:`~sin3dm_lite.Sin3DM`.
        reference: the input's occupancy on the model's box (the training
            grid's ``sdf < 0``; its longest side sets the resolution samples
            are decoded at).
        goals: minimum ``lp_iou`` and ``lp_fscore`` (default :data:`GOALS`).
        n: samples per setting (at least 2, for G-Div).
        seed: the first sample seed.
        lowest: the lowest setting drawn, and the answer when even it misses the goals.
        step: the ladder's spacing.
        margin: how far above every goal a setting must score to end the walk early.
        safety: how far above each goal the smoothed curve is read.
    """
    goals = dict(GOALS if goals is None else goals)
    unknown = set(goals) - set(GOALS)
    if unknown:
        raise Sin3DMInputError(f"unknown calibration goals {sorted(unknown)}; use {sorted(GOALS)}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise Sin3DMInputError(f"calibration needs at least 2 samples per setting (G-Div compares them), got {n!r}")
    if not 0.0 <= lowest < 1.0:
        raise Sin3DMInputError(f"lowest must be a diversity from 0 to below 1, got {lowest!r}")
    if not 0.0 < step <= 1.0 - lowest:
        raise Sin3DMInputError(f"step must be above 0 and at most 1 - lowest ({1.0 - lowest:g}), got {step!r}")
    if not 0.0 <= safety < 1.0 or not 0.0 <= margin < 1.0:
        raise Sin3DMInputError(f"margin and safety are shares of patches from 0 to below 1, got {margin!r} and {safety!r}")
    bad = {k: v for k, v in goals.items() if not 0.0 <= v <= 1.0}
    if bad:
        raise Sin3DMInputError(f"calibration goals are shares of patches, from 0 to 1; got {bad}")
    reference = np.asarray(reference, bool)
    resolution = max(reference.shape)
    from .box import grid_shape

    if tuple(grid_shape(model.aabb, resolution)) != reference.shape:
        raise Sin3DMInputError(f"the reference grid {reference.shape} is not on this model's box at {resolution} "
                               "voxels; pass the training grid's occupancy (grid.sdf < 0 of the run's grid.npz)")
    from .metrics import g_div, lp_scores

    result = Calibration(diversity=lowest, goals=goals, n=int(n), resolution=resolution)
    levels = [round(1.0 - k * step, 4) for k in range(int(np.floor((1.0 - lowest) / step + 1e-9)) + 1)]
    for k, d in enumerate(levels):
        occ = sample_occupancy(model, d, n, seed + 1000 * k, resolution)
        lp = lp_scores(reference, occ)
        row = {"diversity": d, "lp_iou": lp["lp_iou"], "lp_fscore": lp["lp_fscore"], "g_div": g_div(occ)}
        row["kept"] = all(row[key] >= v for key, v in goals.items())
        result.tried.append(row)
        if progress:
            print(f"[calibrate] diversity {d:.4g}: LP-IoU {row['lp_iou']:.3f} LP-F {row['lp_fscore']:.3f} "
                  f"G-Div {row['g_div']:.3f} {'keeps' if row['kept'] else 'misses'} the goals", flush=True)
        if all(row[key] >= v + margin for key, v in goals.items()):
            break
    drawn = [t["diversity"] for t in result.tried]
    crossings = []
    for key, goal in goals.items():
        # drawn from high to low settings; the scores must fall as the setting rises, so fit from low to high
        fitted = _non_increasing([t[key] for t in result.tried][::-1], [1.0] * len(drawn))[::-1]
        for t, f in zip(result.tried, fitted):
            t[f"{key}_fitted"] = f
        crossings.append(_crossing(drawn, fitted, min(goal + safety, 1.0)))
    if all(c is not None for c in crossings):
        result.diversity = round(float(min(crossings)), 2)
        result.kept_goals = True
    return result


__all__ = ["GOALS", "Calibration", "calibrate_diversity", "sample_occupancy"]

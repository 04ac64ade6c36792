"""Choosing the diversity knob for one shape: the most varied samples that still keep the input's patches.

The paper names the trade-off between diversity and fidelity as its main
limitation, and the knob (``Sin3DM.sample(diversity=...)``: start the reverse
process at step ``d · 999`` from the input's latent, noised) turns it. Its
curve differs from shape to shape, and it is steep: on a tiled slab the
samples' LP-IoU against the input falls fast as the knob opens, while a rock
field keeps its patches at 1.0 (docs/calibration.md). So no fixed default
suits every mesh.

:func:`calibrate_diversity` measures the curve instead. It takes a *sampling
function* ``sample_fn(diversity, n, seed) -> [occupancy grid, ...]`` (for a
fitted model, :func:`model_sampler` makes one: a few samples decoded to their
occupancy at the fit's grid resolution, no meshes) and scores what it returns
against the input's occupancy with the paper's LP-IoU / LP-F
(:func:`metrics.lp_scores`: the share of the samples' surface patches that have
a near-exact match among the input's).

First it scores the shape's own **near copy** (diversity 0.05, :data:`NEAR_COPY`):
what this fit keeps of the input at this grid at all, its ceiling. A wall two
voxels thick cannot be held exactly by the grid, so even a near copy of a thin
ruin keeps few patches; goals it cannot reach would send the walk to its floor,
the most varied setting. So each goal is the smaller of the absolute goal
(:data:`GOALS`) and 85 % of the near copy's score (:data:`RELATIVE`); a near
copy whose LP-F is below 0.1 (:data:`MIN_CEILING`) sets no ceiling, since a fit
that cannot even copy its input is not to be judged against nothing. Shapes
whose near copy keeps the input are judged as before, thin ones against their
own ceiling.

Then it walks down the knob from 1 (pure noise, the paper's sampling) in steps
of 0.1, down to 0.1 (:data:`LOWEST`) if the shape needs it, draws a few samples
at each setting (skipping the next one where a setting keeps less than half a
goal, :data:`FAR`: it is far above the answer), stops at the first setting
that keeps the goals with room to spare, smooths the scores into a curve that
falls with the knob, draws a few more settings where that curve crosses the goals, and returns the crossing of
the curve lowered by 1.5 standard errors (for the noise of a few samples). Each
setting gets its own sample seeds, so no single lucky or unlucky set of samples
decides. The samples' G-Div at the choice is recorded against the diversity
requirement (:data:`G_DIV_GOAL`); it does not move the choice, which fidelity
decides. The record (:class:`Calibration`, in :mod:`.calibration_record`)
tells it with :meth:`Calibration.story`: per goal, the near copy's score, the
goal and the choice.

**Why so** (``benchmarks/bench_calibration.py`` replays the calibration 400
times on 48 stored samples per setting; docs/calibration.md): independent seeds
per setting matter, since one set of samples reused at every setting is lucky
or unlucky at all of them at once (a bisection on one seed set chose anything
from 0.59 to 0.88 on a tiled slab). Read at the goals themselves, 8 samples per
setting land above the true crossing about half the time. A fixed 0.02 above
them (the first rule) was too little where the curve is steep and bends between
two settings and too much where it is flat. The refinement removes most of the
bend's error and the standard error shrinks as samples pool near the answer;
1.5 standard errors rather than one keep the choice off the goals' edge where
the curve is flat.

**Grid.** Everything is measured on the grid of the reference given, for a fit
its training grid (64 voxels along the longest side for ``small`` and
``quick``), which is fast; the paper measures at 128 voxels, where thin parts
score differently (``sin3dm-lite evaluate --resolution 128`` measures there, and
``benchmarks/bench_samples.py`` reports both grids). ``sin3dm-lite calibrate
RUN --resolution 128`` judges there, against the input mesh, with the paper's
voxels (``evaluate``'s: a voxel is solid when any of its 2³ sub-voxels is
inside), in about four times the time: a canyon's and a colonnade's default
is then 1, a thin ruin's so varied that some samples flatten its stepped
top (docs/calibration.md). The record keeps its resolution and voxels, and
the story names them.

``Sin3DM.fit`` runs it at the end of a fit when the preset's
``sampling.calibrate`` is on (``small``, ``detail``, ``quick``) and saves the chosen value as the
run's ``sampling.diversity``; ``sin3dm-lite calibrate RUN`` runs it on a
fitted run. It costs a few seconds per setting drawn: a handful of samples
decoded on the training grid, no meshes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..errors import Sin3DMInputError
from .calibration_record import MIN_CEILING, SCORE_NAMES, Calibration

#: what the samples must keep against the input at most: the paper's averages are LP-F 0.699 at G-Div 0.224, and
#: the project's goals LP-IoU ≥ 0.55 with LP-F ≥ 0.70. The few samples calibration draws scatter by a few
#: hundredths around the figures of many (docs/calibration.md), so the choice does too
GOALS = {"lp_iou": 0.55, "lp_fscore": 0.70}
#: the goals relative to the ceiling: each goal is at most this share of the shape's near-copy score
RELATIVE = 0.85
#: the setting whose samples stand for the near copy (the ceiling), and where its seeds start (after ``seed``)
NEAR_COPY, NEAR_COPY_SEEDS = 0.05, 100_000
#: the diversity requirement: the samples' G-Div at the choice (the issue's goal; recorded, not a goal of the walk)
G_DIV_GOAL = 0.15
#: the ladder's floor: the lowest setting drawn, and the answer when even it misses the goals
LOWEST = 0.1

#: extra settings drawn near the answer once the ladder has bracketed it (:func:`calibrate_diversity`)
REFINE = 4
#: a rung whose samples keep less than this share of a goal is far from the answer: the ladder skips the next rung
#: (on the thin-walled ruin 1.0-0.6 all keep LP-F 0.22-0.30 against a goal of 0.70; docs/calibration.md)
FAR = 0.5
#: how the smoothed curve is read: lowered by CAUTION standard errors, SAFETY (a share of patches) above each goal
SAFETY, CAUTION = 0.0, 1.5

#: ``sample_fn(diversity, n, seed)``: ``n`` samples' occupancy grids, seeds ``seed`` …, on the reference's grid
SampleFn = Callable[[float, int, int], Sequence[np.ndarray]]


def sample_occupancy(model, diversity: float, n: int, seed: int, resolution: int, supersample: int = 1):
    """``n`` samples at ``diversity`` (seeds ``seed`` …), each as occupancy on the model's box at ``resolution``
    voxels along its longest side.

    With the voxel centres (``supersample=1``) that is the sign of the decoder,
    no mesh. Only the sign is needed, so the coarse-to-fine decode queries the
    decoder only where its bound cannot prove the sign (``exact_band=0``; a
    mesh needs exact values two voxels around the surface): the same
    occupancy, voxel for voxel, on 12 samples of the canyon, the tiles and the
    rocks, in 0.18-0.37 s per sample instead of 0.43-0.62 at 64-96 voxels.
    With the paper's voxels (``supersample=2``) each sample is decoded to its
    mesh and voxelised as ``evaluate`` does (:meth:`Sin3DM.occupancy`): what
    the judge sees is what ``sin3dm-lite evaluate`` reports, about twice the
    time (the coloured ruin at 128: 1.5 s a sample against 0.8).
    """
    from ..model.decode import decode_grid

    samples = model.sample(n, seed=seed, diversity=diversity, progress=False)
    if supersample > 1:
        return model.occupancy(samples, resolution, supersample=supersample)
    out = []
    for i in range(n):
        sdf = decode_grid(model.decoder, samples.triplane[i : i + 1], samples.aabb, resolution, exact_band=0.0)
        out.append(sdf < 0)
    return out


def model_sampler(model, reference: np.ndarray, supersample: int = 1) -> SampleFn:
    """The sampling function :func:`calibrate_diversity` takes, for a fitted :class:`~sin3dm_lite.Sin3DM`: its
    samples as occupancy (:func:`sample_occupancy`, ``supersample`` sub-voxels a side) on ``reference``'s grid,
    which must lie on the model's box (the training grid's ``sdf < 0``, or the input voxelised on that box the
    same way)."""
    from ..data.box import grid_shape

    shape = np.shape(reference)
    resolution = max(shape)
    if tuple(grid_shape(model.aabb, resolution)) != tuple(shape):
        raise Sin3DMInputError(
            f"the reference grid {shape} is not on this model's box at {resolution} "
            "voxels; pass the training grid's occupancy (grid.sdf < 0 of the run's grid.npz)"
        )

    def sample_fn(diversity: float, n: int, seed: int) -> list[np.ndarray]:
        return sample_occupancy(model, diversity, n, seed, resolution, supersample)

    return sample_fn


def summarize(per_sample: dict, g_div: float = float("nan")) -> dict:
    """A setting's row from its samples' scores (``{"lp_iou": [...], "lp_fscore": [...]}``): each goal's mean and
    per-sample spread (``*_sd``, for the standard errors), and the samples' G-Div."""
    row = {"g_div": float(g_div)}
    for key, values in per_sample.items():
        row[key], row[f"{key}_sd"] = float(np.mean(values)), float(np.std(values, ddof=1))
    return row


def score_setting(sample_fn: SampleFn, reference: np.ndarray, diversity: float, n: int, seed: int) -> dict:
    """``n`` samples of ``sample_fn`` at ``diversity`` scored against ``reference``: the row :func:`summarize`
    makes, plus the per-sample scores (``per_sample``)."""
    from .metrics import g_div, lp_scores

    occ = [np.asarray(o, bool) for o in sample_fn(diversity, n, seed)]
    if len(occ) != n or any(o.shape != reference.shape for o in occ):
        raise Sin3DMInputError(
            f"the sampling function gave {len(occ)} grids of shapes {sorted({o.shape for o in occ})}"
            f" for {n} samples; calibration needs {n} grids of the reference's {reference.shape}"
        )
    lp = lp_scores(reference, occ)
    per_sample = {"lp_iou": lp["per_shape_iou"], "lp_fscore": lp["per_shape_fscore"]}
    return {**summarize(per_sample, g_div(occ)), "per_sample": per_sample}


def _non_increasing(values: list[float], weights: list[float], pooled: bool = False):
    """The closest non-increasing sequence to ``values`` in weighted least squares (pool adjacent violators).

    Patch scores fall as the knob rises; measured on a few samples they can
    rise by chance from one setting to the next. Pooling such neighbours
    averages their samples instead of believing either one. With ``pooled``,
    also returns each value's pooled weight (the samples its smoothed score rests on).
    """
    blocks: list[list[float]] = []  # [mean, weight, count]
    for v, w in zip(values, weights):
        blocks.append([v, w, 1])
        while len(blocks) > 1 and blocks[-2][0] < blocks[-1][0]:
            (a, wa, ka), (b, wb, kb) = blocks[-2], blocks[-1]
            blocks[-2:] = [[(a * wa + b * wb) / (wa + wb), wa + wb, ka + kb]]
    fitted = [v for v, _, k in blocks for _ in range(k)]
    return (fitted, [w for _, w, k in blocks for _ in range(k)]) if pooled else fitted


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


def _curve(tried: list[dict], key: str) -> tuple[list[float], list[float], list[float]]:
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
    fitted, pooled = (v[::-1] for v in _non_increasing(means[::-1], weights[::-1], pooled=True))
    dof = sum(t["n"] - 1 for t in tried)
    spread = float(np.sqrt(sum((t["n"] - 1) * t.get(f"{key}_sd", 0.0) ** 2 for t in tried) / dof)) if dof else 0.0
    return levels, fitted, [spread / np.sqrt(w) for w in pooled]


def _choice(tried: list[dict], goals: dict, safety: float, caution: float) -> float | None:
    """Where the smoothed curves, less ``caution`` standard errors, cross each goal + ``safety`` (the lower
    crossing wins); None if one never does. Writes each row's smoothed scores (``*_fitted``)."""
    crossings = []
    for key, goal in goals.items():
        levels, fitted, se = _curve(tried, key)
        at = dict(zip(levels, fitted))
        for t in tried:
            t[f"{key}_fitted"] = at[t["diversity"]]
        low = [f - caution * e for f, e in zip(fitted, se)]
        crossings.append(_crossing(levels, low, min(goal + safety, 1.0)))
    return None if any(c is None for c in crossings) else float(min(crossings))


def calibrate_diversity(
    sample_fn: SampleFn,
    reference: np.ndarray,
    goals: dict | None = None,
    n: int = 8,
    seed: int = 10_000,
    lowest: float = LOWEST,
    step: float = 0.1,
    margin: float = 0.05,
    safety: float = SAFETY,
    refine: int = REFINE,
    caution: float = CAUTION,
    relative: float | None = RELATIVE,
    far: float = FAR,
    progress: bool = True,
) -> Calibration:
    """The highest diversity in ``[lowest, 1]`` whose samples keep the goals against ``reference``.

    First the near copy: ``n`` samples at diversity :data:`NEAR_COPY` (seeds
    from ``seed + NEAR_COPY_SEEDS``), scored against ``reference`` on its grid:
    the ceiling of this fit at this grid. Each goal is the smaller of
    ``goals[key]`` and ``relative`` × the near copy's score; a near copy whose
    LP-F is below :data:`MIN_CEILING` sets none (``relative=None``: the goals as
    given, no near copy drawn).

    Then it walks down a ladder of settings, 1, 1 - ``step``, ... ``lowest``, drawing
    ``n`` samples at each with **seeds of its own** (``seed + 1000·k`` for the
    k-th setting drawn), and stops at the first setting whose samples keep
    every goal by ``margin`` (lower settings only keep more; a goal lowered to its
    ceiling lowers its margin in proportion). A rung keeping less than ``far`` ×
    a goal skips the next rung, drawn after all if the rung after it ends the
    walk (the two rungs around the answer are always drawn). The patch scores
    of all settings drawn are made non-increasing in the knob (pooling
    neighbours that disagree by chance, weighted by their samples). Then,
    ``refine`` times, it draws ``n`` more samples at the point of a half-step
    grid (0.05 apart) nearest the current answer, so the samples go where the
    answer is decided. The answer is where the smoothed curve, lowered by
    ``caution`` standard errors (the samples' spread over the root of the
    samples each smoothed score rests on) and read ``safety`` above each goal,
    crosses it, linearly between the two settings around the crossing; the
    lower crossing of the two goals wins. The near copy's samples set the
    goals and do not enter the curve, so a shape whose near copy keeps the
    absolute goals is calibrated as it was before the ceiling.

    Why so: the module's docstring (the replays are in docs/calibration.md).

    Args:
        sample_fn: ``sample_fn(diversity, n, seed)`` returns ``n`` samples' occupancy grids (seeds ``seed`` …)
            on ``reference``'s grid; :func:`model_sampler` makes one for a fitted model.
        reference: the input's occupancy (for a fit, the training grid's ``sdf < 0``: the calibration
            measures on its grid, the training grid, not the paper's 128 voxels).
        goals: the most ``lp_iou`` and ``lp_fscore`` asked for (default :data:`GOALS`).
        n: samples per setting (at least 2, for G-Div).
        seed: the first sample seed.
        lowest: the lowest setting drawn, and the answer when even it misses the goals.
        step: the ladder's spacing.
        margin: how far above every goal a setting must score to end the walk early.
        safety: how far above each goal (a share of patches) the smoothed curve is read.
        refine: how many more settings to draw near the answer once the ladder has bracketed it.
        caution: how many standard errors the smoothed curve is lowered before it is read.
        relative: each goal is at most this share of the near copy's score (None: absolute goals).
        far: a rung keeping less than this share of a goal skips the next rung (0: every rung is drawn).
    """
    absolute = dict(GOALS if goals is None else goals)
    _check_options(absolute, n, refine, lowest, step, caution, safety, margin, relative, far)
    reference = np.asarray(reference, bool)

    def draw(d: float, k: int) -> dict:
        return score_setting(sample_fn, reference, d, n, seed + 1000 * k)

    result = Calibration(
        diversity=lowest, goals=absolute, n=int(n), resolution=max(reference.shape), g_div_goal=G_DIV_GOAL
    )
    if relative is not None:
        _set_ceiling(result, draw(NEAR_COPY, NEAR_COPY_SEEDS // 1000), relative, progress)
    # a goal lowered to its ceiling lowers its margin alike: a near copy keeps only 1/RELATIVE of its goal
    margins = {k: margin * (v / absolute[k] if absolute[k] > 0 else 1.0) for k, v in result.goals.items()}
    _walk(result, draw, lowest, step, margins, safety, refine, caution, progress, far)
    result.at_choice = _at_choice(result)
    return result


def _set_ceiling(result: Calibration, near: dict, relative: float, progress: bool) -> None:
    """Record the near copy's row ``near`` and lower ``result.goals`` (the absolute ones) to ``relative`` × its
    scores, unless its LP-F is below :data:`MIN_CEILING`."""
    absolute = result.goals
    near.pop("per_sample", None)
    result.near_copy = {"diversity": NEAR_COPY, "n": result.n, **near}
    if near["lp_fscore"] >= MIN_CEILING:
        result.goals = {k: min(v, round(relative * near[k], 4)) for k, v in absolute.items()}
    result.absolute_goals, result.relative = absolute, float(relative)
    if progress:
        print(
            f"[calibrate] near copy (diversity {NEAR_COPY:g}): "
            + "; ".join(f"{SCORE_NAMES[k]} {near[k]:.3f}, goal {result.goals[k]:.3f}" for k in absolute)
            + f" ({relative:.0%} of it, at most {', '.join(f'{v:.2f}' for v in absolute.values())})",
            flush=True,
        )


def _check_options(goals: dict, n, refine, lowest, step, caution, safety, margin, relative, far) -> None:
    """:func:`calibrate_diversity`'s options, each refused in one line naming it."""
    unknown = set(goals) - set(GOALS)
    if unknown:
        raise Sin3DMInputError(f"unknown calibration goals {sorted(unknown)}; use {sorted(GOALS)}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise Sin3DMInputError(f"calibration needs at least 2 samples per setting (G-Div compares them), got {n!r}")
    if isinstance(refine, bool) or not isinstance(refine, (int, np.integer)) or refine < 0:
        raise Sin3DMInputError(f"refine is a number of extra settings, 0 or more, got {refine!r}")
    if not 0.0 <= lowest < 1.0:
        raise Sin3DMInputError(f"lowest must be a diversity from 0 to below 1, got {lowest!r}")
    if not 0.0 < step <= 1.0 - lowest:
        raise Sin3DMInputError(f"step must be above 0 and at most 1 - lowest ({1.0 - lowest:g}), got {step!r}")
    if not 0.0 <= caution <= 10.0:
        raise Sin3DMInputError(f"caution is a number of standard errors from 0 to 10, got {caution!r}")
    if not 0.0 <= safety < 1.0 or not 0.0 <= margin < 1.0:
        raise Sin3DMInputError(
            f"margin and safety are shares of patches from 0 to below 1, got {margin!r} and {safety!r}"
        )
    if not 0.0 <= far < 1.0:
        raise Sin3DMInputError(f"far is a share of a goal from 0 (draw every rung) to below 1, got {far!r}")
    if relative is not None and not 0.0 < relative <= 1.0:
        raise Sin3DMInputError(
            f"relative is a share of the near copy's scores, above 0 and at most 1, got {relative!r}"
        )
    bad = {k: v for k, v in goals.items() if not 0.0 <= v <= 1.0}
    if bad:
        raise Sin3DMInputError(f"calibration goals are shares of patches, from 0 to 1; got {bad}")


def _at_choice(result: Calibration) -> dict:
    """The smoothed patch scores at the chosen setting, and the samples' G-Div there (linear between the settings
    drawn around it, each setting's samples pooled)."""
    out = {}
    for key in result.goals:
        levels, fitted, _ = _curve(result.tried, key)
        out[key] = float(np.interp(result.diversity, levels[::-1], fitted[::-1]))
    by_setting: dict[float, list[float]] = {}
    for t in result.tried:
        by_setting.setdefault(t["diversity"], []).extend([t.get("g_div", np.nan)] * t["n"])
    levels = sorted(by_setting)
    out["g_div"] = float(np.interp(result.diversity, levels, [np.mean(by_setting[d]) for d in levels]))
    return out


def _walk(
    result: Calibration,
    draw,
    lowest: float,
    step: float,
    margin: float | dict,
    safety: float,
    refine: int,
    caution: float,
    progress: bool,
    far: float = FAR,
) -> None:
    """The ladder, then the refinement, with ``draw(diversity, k) -> {"lp_iou", "lp_fscore", "g_div"}`` scoring
    ``result.n`` samples with the k-th seeds. Fills ``result`` (kept apart from the sampling so that
    ``benchmarks/bench_calibration.py`` can replay it on stored scores). ``margin``: one for every goal, or one
    per goal. ``far``: a rung keeping less than this share of a goal skips the next one."""
    goals = result.goals
    margins = margin if isinstance(margin, dict) else dict.fromkeys(goals, margin)

    def add(d: float, why: str = "") -> dict:
        row = {"diversity": d, "n": result.n, **draw(d, len(result.tried))}
        row.pop("per_sample", None)  # the report keeps the summary
        row["kept"] = all(row[key] >= v for key, v in goals.items())
        result.tried.append(row)
        if progress:
            print(
                f"[calibrate] {why}diversity {d:.4g}: LP-IoU {row['lp_iou']:.3f} LP-F {row['lp_fscore']:.3f} "
                f"G-Div {row['g_div']:.3f} {'keeps' if row['kept'] else 'misses'} the goals",
                flush=True,
            )
        return row

    levels = [round(1.0 - k * step, 4) for k in range(int(np.floor((1.0 - lowest) / step + 1e-9)) + 1)]
    k, last = 0, -1
    while k < len(levels):
        row = add(levels[k])
        if all(row[key] >= v + margins[key] for key, v in goals.items()):
            if k - last == 2:  # the rung just above was skipped: the answer lies between, so draw it
                add(levels[k - 1], "the skipped rung above: ")
            break
        # far below a goal: the next rung misses it too, so skip it (never the floor)
        far_off = any(row[key] < far * v for key, v in goals.items()) and k + 2 < len(levels)
        if far_off and progress:
            print(
                f"[calibrate] {levels[k]:g} keeps less than {far:.0%} of a goal: {levels[k + 1]:g} skipped", flush=True
            )
        last, k = k, k + (2 if far_off else 1)
    below = iter(levels[k + 1 :])  # the ladder's settings below the last drawn

    def read() -> float | None:
        # the lowered curve can miss a goal where the walk stopped (few samples, wide error): walk on down
        chosen = _choice(result.tried, goals, safety, caution)
        while chosen is None and (d := next(below, None)) is not None:
            add(d)
            chosen = _choice(result.tried, goals, safety, caution)
        return chosen

    chosen = read()
    half = step / 2
    for _ in range(refine):
        if chosen is None or chosen >= 1.0:  # nothing to refine: out of reach, or pure noise keeps the goals
            break
        add(round(min(max(lowest + round((chosen - lowest) / half) * half, lowest), 1.0), 4), "near the answer: ")
        chosen = read()
    if chosen is not None:
        result.diversity = round(chosen, 2)
        result.kept_goals = True


__all__ = [
    "FAR",
    "GOALS",
    "G_DIV_GOAL",
    "LOWEST",
    "MIN_CEILING",
    "NEAR_COPY",
    "RELATIVE",
    "Calibration",
    "SampleFn",
    "calibrate_diversity",
    "model_sampler",
    "sample_occupancy",
    "score_setting",
    "summarize",
]

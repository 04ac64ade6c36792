"""Choosing the diversity knob for one shape: the most varied samples that still keep the input's patches.

The paper names the trade-off between diversity and fidelity as its main limitation; the knob
(``Sin3DM.sample(diversity=...)``: start the reverse process at step ``d · 999`` from the noised input latent)
turns it, and its curve differs from shape to shape. :func:`calibrate_diversity` measures it: it scores a
*sampling function* ``sample_fn(diversity, n, seed)`` (:func:`model_sampler` makes one for a fitted model) against
the input with LP-IoU / LP-F and G-Div. The rule (docs/calibration.md):

1. the shape's **near copy** (diversity :data:`NEAR_COPY`) sets the goals: shares of its scores (:data:`RELATIVE`),
   capped by :data:`GOALS`; LP-F decides, LP-IoU is a softer floor;
2. a ladder from 1 down in steps of 0.1, smoothed into curves that fall with the knob and refined near the answer;
   the choice is the most varied setting whose curves, lowered by a few standard errors, keep both goals;
3. where that choice's samples are copies (G-Div under :func:`copy_line`), the most varied setting that keeps LP-F;
4. where no setting keeps LP-F, or only copies do, the least varied setting whose samples are not copies, and
   the record says so (:attr:`Calibration.note`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..errors import Sin3DMInputError
from .calibration_record import (
    COPY_RATIO,
    MIN_CEILING,
    SCORE_NAMES,
    VARIED_G_DIV,
    Calibration,
    copy_line,
    g_div_at,
    least_varied,
    mean_by_setting,
)
from .curves import crossing, curve

#: the most each patch score's goal can be (the absolute caps)
GOALS = {"lp_iou": 0.55, "lp_fscore": 0.70}
#: each goal is at most this share of the near copy's score; LP-IoU's is lower because its 5-voxel lattice counts
#: a sub-voxel move as a lost patch
RELATIVE = {"lp_iou": 0.65, "lp_fscore": 0.85}
#: the setting whose samples stand for the near copy (the ceiling), and where its seeds start (after ``seed``)
NEAR_COPY, NEAR_COPY_SEEDS = 0.05, 100_000
#: the diversity requirement the record reports the choice against
G_DIV_GOAL = VARIED_G_DIV
#: the lowest setting drawn, and the answer when even it misses the goals
LOWEST = 0.1
#: extra settings drawn near the answer once the ladder has bracketed it
REFINE = 4
#: a rung whose samples keep less than this share of a goal is far from the answer: the ladder skips the next rung
FAR = 0.5
#: how the smoothed curve is read: lowered by CAUTION standard errors, SAFETY (a share of patches) above each goal
SAFETY, CAUTION = 0.0, 1.5

#: ``sample_fn(diversity, n, seed)``: ``n`` samples' occupancy grids, seeds ``seed`` …, on the reference's grid
SampleFn = Callable[[float, int, int], Sequence[np.ndarray]]


def sample_occupancy(model, diversity: float, n: int, seed: int, resolution: int, supersample: int = 1):
    """``n`` samples at ``diversity`` (seeds ``seed`` …) as occupancy on the model's box at ``resolution`` voxels
    along its longest side, decoded without a mesh: the voxel centres' signs (``supersample=1``) or the paper's
    voxels of the mesh they make (``2``: :func:`geometry.interpolated_inside`). A decoder trained in bf16 decodes
    under ``autocast("auto")`` (its plane convolutions stay fp32); the samples are drawn in fp32, as a user draws them.
    """
    from ..app.device import autocast
    from ..model.decode import decode_grid, prepare
    from .geometry import interpolated_inside

    samples = model.sample(n, seed=seed, diversity=diversity, progress=False)
    planes = [prepare(model.decoder, samples.triplane[i : i + 1]) for i in range(n)]
    bf16 = (model.report.get("precision") or {}).get("autoencoder") == "bf16"
    with autocast(model.device, "auto" if bf16 else "fp32"):
        sdfs = [decode_grid(model.decoder, p, samples.aabb, resolution, exact_band=0.0) for p in planes]
    return [sdf < 0 if supersample == 1 else interpolated_inside(sdf, supersample) for sdf in sdfs]


def model_sampler(model, reference: np.ndarray, supersample: int = 1) -> SampleFn:
    """The sampling function :func:`calibrate_diversity` takes for a fitted model: its samples as occupancy
    (:func:`sample_occupancy`) on ``reference``'s grid, which must lie on the model's box."""
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
    """A setting's row from its samples' scores (``{"lp_iou": [...], "lp_fscore": [...]}``): each score's mean and
    spread (``*_sd``), and the samples' G-Div."""
    row = {"g_div": float(g_div)}
    for key, values in per_sample.items():
        row[key], row[f"{key}_sd"] = float(np.mean(values)), float(np.std(values, ddof=1))
    return row


def score_setting(sample_fn: SampleFn, reference: np.ndarray, diversity: float, n: int, seed: int) -> dict:
    """``n`` samples of ``sample_fn`` at ``diversity`` scored against ``reference``: :func:`summarize`'s row plus
    the per-sample scores (``per_sample``)."""
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


def _choice(tried: list[dict], goals: dict, safety: float, caution: float) -> float | None:
    """Where the smoothed curves, less ``caution`` standard errors, cross each goal + ``safety`` (the lower
    crossing wins); None if one never does. Writes each row's smoothed scores (``*_fitted``)."""
    crossings = []
    for key, goal in goals.items():
        levels, fitted, se = curve(tried, key)
        at = dict(zip(levels, fitted))
        for t in tried:
            t[f"{key}_fitted"] = at[t["diversity"]]
        low = [f - caution * e for f, e in zip(fitted, se)]
        crossings.append(crossing(levels, low, min(goal + safety, 1.0)))
    return None if any(c is None for c in crossings) else float(min(crossings))


def calibrate_diversity(
    sample_fn: SampleFn,
    reference: np.ndarray,
    goals: dict | None = None,
    n: int = 8,
    seed: int = 10_000,
    progress: bool = True,
    **walk,
) -> Calibration:
    """The most varied diversity in ``[lowest, 1]`` whose samples keep the goals against ``reference`` (the rule:
    the module's docstring).

    Args:
        sample_fn: ``sample_fn(diversity, n, seed)`` returns ``n`` occupancy grids on ``reference``'s grid.
        reference: the input's occupancy (for a fit, the training grid's ``sdf < 0``).
        goals: the most ``lp_iou`` and ``lp_fscore`` asked for (default :data:`GOALS`).
        n: samples per setting (at least 2, for G-Div).
        seed: the first sample seed; the k-th setting drawn uses seeds from ``seed + 1000·k``.
        walk: how the settings are walked (:func:`calibrate_scores`).
    """
    from ..app import values

    seed = values.seed(seed)
    if seed + NEAR_COPY_SEEDS + 1000 * 100 >= 2**32:  # every setting's seeds stay seeds
        raise Sin3DMInputError(f"the calibration's seed must be below {2**32 - NEAR_COPY_SEEDS - 100_000}, got {seed}")
    reference = np.asarray(reference, bool)

    def draw(d: float, k: int) -> dict:
        return score_setting(sample_fn, reference, d, n, seed + 1000 * k)

    return calibrate_scores(draw, max(reference.shape), goals, n, progress=progress, **walk)


def calibrate_scores(
    draw: Callable[[float, int], dict],
    resolution: int,
    goals: dict | None = None,
    n: int = 8,
    progress: bool = True,
    lowest: float = LOWEST,
    step: float = 0.1,
    margin: float = 0.05,
    safety: float = SAFETY,
    refine: int = REFINE,
    caution: float = CAUTION,
    relative: float | dict | None = RELATIVE,
    far: float = FAR,
) -> Calibration:
    """:func:`calibrate_diversity`'s rule on any scorer: ``draw(diversity, k)`` gives the row of ``n`` samples drawn
    with the k-th seeds (``lp_iou``, ``lp_fscore``, their ``*_sd``, ``g_div``: :func:`summarize`), the near copy's
    with ``k`` = ``NEAR_COPY_SEEDS // 1000``. Apart from the sampling so that stored scores can replay it
    (``benchmarks/bench_calibration.py``); ``resolution`` is only recorded.

    Args:
        lowest, step: the ladder 1, 1 - ``step``, … ``lowest``.
        margin: how far above every goal a setting must score to end the ladder early.
        safety, caution: the smoothed curves are read ``safety`` above each goal, lowered by ``caution`` standard
            errors.
        refine: how many more settings to draw near the answer once the ladder has bracketed it.
        relative: each goal is at most this share of the near copy's score (one for both, or one per goal);
            None draws no near copy (absolute goals).
        far: a rung keeping less than this share of a goal skips the next rung (0: every rung is drawn).
    """
    absolute = dict(GOALS if goals is None else goals)
    shares = _shares(relative, absolute)
    _check_options(absolute, n, refine, lowest, step, caution, safety, margin, shares, far)
    result = Calibration(diversity=lowest, goals=absolute, n=int(n), resolution=int(resolution), g_div_goal=G_DIV_GOAL)
    result.copy_line = copy_line(None)
    if shares is not None:
        _set_ceiling(result, draw(NEAR_COPY, NEAR_COPY_SEEDS // 1000), shares, progress)
    # a goal lowered to its ceiling lowers its margin alike
    margins = {k: margin * (v / absolute[k] if absolute[k] > 0 else 1.0) for k, v in result.goals.items()}
    _walk(result, draw, lowest, step, margins, safety, refine, caution, progress, far)
    result.at_choice = _at_choice(result)
    return result


def _shares(relative, goals: dict) -> dict | None:
    """``relative`` as one share per goal (one number for every goal, or a dict; None: no near copy)."""
    if relative is None:
        return None
    if isinstance(relative, dict):
        return {k: relative.get(k, RELATIVE.get(k, 1.0)) for k in goals}
    return dict.fromkeys(goals, relative)


def _set_ceiling(result: Calibration, near: dict, shares: dict, progress: bool) -> None:
    """Record the near copy's row ``near``; unless its LP-F is below :data:`MIN_CEILING`, lower ``result.goals``
    (the absolute ones) to ``shares`` × its scores and set the copy line from its G-Div."""
    absolute = result.goals
    near.pop("per_sample", None)
    result.near_copy = {"diversity": NEAR_COPY, "n": result.n, **near}
    if near["lp_fscore"] >= MIN_CEILING:  # a near copy that keeps nothing is no copy: its G-Div says nothing either
        result.goals = {k: min(v, round(shares[k] * near[k], 4)) for k, v in absolute.items()}
        result.copy_line = copy_line(near.get("g_div"))
    result.absolute_goals, result.relative = absolute, shares
    if progress:
        print(
            f"[calibrate] near copy (diversity {NEAR_COPY:g}): "
            + "; ".join(
                f"{SCORE_NAMES[k]} {near[k]:.3f}, goal {result.goals[k]:.3f} ({shares[k]:.0%}"
                + (f", at most {v:.2f})" if v < 1 else ")")
                for k, v in absolute.items()
            )
            + f"; G-Div {near.get('g_div', np.nan):.3f}: samples under G-Div {result.copy_line:.3f} are copies",
            flush=True,
        )


#: the most samples per setting a calibration draws
MAX_N = 64


def _check_options(goals: dict, n, refine, lowest, step, caution, safety, margin, relative, far) -> None:
    """:func:`calibrate_diversity`'s options, each refused in one line naming it."""
    from ..app import values

    unknown = set(goals) - set(GOALS)
    if unknown:
        raise Sin3DMInputError(f"unknown calibration goals {sorted(unknown)}; use {sorted(GOALS)}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 2 <= n <= MAX_N:
        raise Sin3DMInputError(f"calibration draws 2 to {MAX_N} samples per setting (G-Div compares them), got {n!r}")
    for name, v in dict(lowest=lowest, step=step, caution=caution, safety=safety, margin=margin, far=far).items():
        values.finite(v, name)
    if isinstance(refine, bool) or not isinstance(refine, (int, np.integer)) or refine < 0:
        raise Sin3DMInputError(f"refine is a number of extra settings, 0 or more, got {refine!r}")
    if not 0.0 <= lowest < 1.0:
        raise Sin3DMInputError(f"lowest must be a diversity from 0 to below 1, got {lowest!r}")
    if not 0.0 < step <= 1.0 - lowest:
        raise Sin3DMInputError(f"step must be above 0 and at most 1 - lowest ({1.0 - lowest:g}), got {step!r}")
    if not 0.0 <= caution <= 10.0:
        raise Sin3DMInputError(f"caution is a number of standard errors from 0 to 10, got {caution!r}")
    if not 0.0 <= safety < 1.0 or not 0.0 <= margin < 1.0:
        raise Sin3DMInputError(f"margin and safety are shares of patches from 0 to below 1, got {margin!r}, {safety!r}")
    if not 0.0 <= far < 1.0:
        raise Sin3DMInputError(f"far is a share of a goal from 0 (draw every rung) to below 1, got {far!r}")
    if relative is not None and not all(0.0 < v <= 1.0 for v in relative.values()):
        raise Sin3DMInputError(
            f"relative is a share of the near copy's scores, above 0 and at most 1, got {relative!r}"
        )
    bad = {k: v for k, v in goals.items() if not 0.0 <= v <= 1.0}
    if bad:
        raise Sin3DMInputError(f"calibration goals are shares of patches, from 0 to 1; got {bad}")


def _at_choice(result: Calibration) -> dict:
    """The smoothed patch scores at the chosen setting, and the samples' G-Div there (:func:`g_div_at`)."""
    out = {}
    for key in result.goals:
        levels, fitted, _ = curve(result.tried, key)
        out[key] = float(np.interp(result.diversity, levels[::-1], fitted[::-1]))
    out["g_div"] = g_div_at(result.tried, result.diversity)
    return out


def _decide(tried: list[dict], goals: dict, safety: float, caution: float, line: float, keep_f=None) -> tuple:
    """The choice on the smoothed curves (:func:`_choice`) and why, if not the plain reading. Where the samples at
    the crossing of every goal are copies (G-Div under ``line``): the most varied setting whose LP-F estimate (no
    ``caution``) keeps ``keep_f`` and its goal, if more varied; where no setting keeps every goal: LP-F's own
    crossing (with ``caution``)."""
    chosen = _choice(tried, goals, safety, caution)
    varied = chosen is not None and not g_div_at(tried, chosen) < line  # NaN (G-Div unknown): not copies
    if varied or "lp_fscore" not in goals:
        return chosen, ""
    keep = goals["lp_fscore"] if chosen is None else max(goals["lp_fscore"], keep_f or 0.0)
    alone = _choice(tried, {"lp_fscore": keep}, safety, caution if chosen is None else 0.0)
    if alone is None or (chosen is not None and alone <= chosen):
        return chosen, ""
    if chosen is None:
        return alone, f"LP-IoU misses its floor at every setting drawn; {alone:.2f} keeps LP-F (the goal that decides)"
    return alone, (
        f"at {chosen:.2f}, where LP-IoU keeps its floor too, the samples are copies (G-Div "
        f"{g_div_at(tried, chosen):.3f} < {line:.3f}); the LP-IoU floor gives way to {alone:.2f}, the most varied "
        f"setting that keeps LP-F {keep:.2f} (its estimate)"
    )


def _fallback(result: Calibration, copies: float | None = None) -> None:
    """No setting keeps the LP-F goal, or only copies (at ``copies``) do: choose the least varied setting drawn whose
    samples are not copies, else the lowest drawn; :attr:`Calibration.note` says why."""
    least, by_setting = least_varied(result)
    goal = f"LP-F {result.goals.get('lp_fscore', np.nan):.2f}"
    result.only_copies_kept, missed = copies is not None, f"no setting drawn kept {goal}"
    if copies is not None:
        missed = f"only copies kept {goal} (at {copies:.2f} G-Div {g_div_at(result.tried, copies):.3f})"
    if least is not None:
        result.diversity = least
        result.note = (
            f"{missed}: chose {result.diversity:g}, the least varied setting whose samples are not copies (G-Div "
            f"{by_setting[result.diversity]:.3f} ≥ {result.copy_line:.3f}); below it the samples are copies "
            "(sample --diversity D picks another)"
        )
    else:
        result.diversity = min(by_setting) if by_setting else result.diversity
        result.note = (
            f"{missed}, and the samples at every setting drawn are copies (G-Div under {result.copy_line:.3f}): "
            f"chose the lowest drawn, {result.diversity:g}; this fit does not vary this shape"
        )


def _torn(result: Calibration, setting: float | None, far: float) -> bool:
    """Whether the samples at ``setting`` keep less than ``far`` of the LP-F goal (torn, not varied); None: torn."""
    goal = far * result.goals.get("lp_fscore", 0.0)
    return setting is None or mean_by_setting(result.tried, "lp_fscore")[setting] < goal


def _halfway(result: Calibration, add, step: float) -> bool:
    """Draw up to two settings halfway between the least varied setting whose samples are not copies and the copies
    below it (the knob can jump within a rung, and a skipped rung can hide the setting that varies without tearing),
    whether or not that setting is torn: whether the copies stand is judged on the setting next to them. Whether any
    was drawn."""
    drawn = False
    for _ in range(2):
        least, by_setting = least_varied(result)
        copied = [d for d in by_setting if least is not None and d < least]
        if copied and least - max(copied) > step / 4 + 1e-9:
            add(round((least + max(copied)) / 2, 2), "between copies and the least varied: ")
            drawn = True
    return drawn


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
    ``result.n`` samples with the k-th seeds; fills ``result``. Kept apart from the sampling so that stored scores
    can replay it. ``margin``: one for every goal, or one per goal."""
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

    line = result.copy_line or 0.0
    keep_f = (result.relative or {}).get("lp_fscore", 0.0) * (result.near_copy or {}).get("lp_fscore", 0.0)

    def read() -> tuple[float | None, str]:
        # the lowered curve can miss a goal where the walk stopped (few samples, wide error): walk on down
        chosen, why = _decide(result.tried, goals, safety, caution, line, keep_f)
        while chosen is None and (d := next(below, None)) is not None:
            add(d)
            chosen, why = _decide(result.tried, goals, safety, caution, line, keep_f)
        return chosen, why

    chosen, why = read()
    half = step / 2
    for _ in range(refine):
        if chosen is None or chosen >= 1.0:  # nothing to refine: out of reach, or pure noise keeps the goals
            break
        add(round(min(max(lowest + round((chosen - lowest) / half) * half, lowest), 1.0), 4), "near the answer: ")
        chosen, why = read()
    if (chosen is None or g_div_at(result.tried, chosen) < line) and _halfway(result, add, step):
        chosen, why = read()
    least = least_varied(result)[0]  # a default of copies is no sampler, nor is one far below LP-F's goal (torn)
    torn = _torn(result, least, far)
    copies = chosen is not None and g_div_at(result.tried, chosen) < line and not torn and least > chosen
    if chosen is not None and not copies:
        result.diversity, result.note = round(chosen, 2), why or None
        result.kept_goals = True
    else:
        _fallback(result, chosen)


__all__ = [
    "FAR",
    "GOALS",
    "G_DIV_GOAL",
    "LOWEST",
    "MIN_CEILING",
    "NEAR_COPY",
    "RELATIVE",
    "VARIED_G_DIV",
    "COPY_RATIO",
    "Calibration",
    "SampleFn",
    "calibrate_diversity",
    "calibrate_scores",
    "copy_line",
    "model_sampler",
    "sample_occupancy",
    "score_setting",
    "summarize",
]

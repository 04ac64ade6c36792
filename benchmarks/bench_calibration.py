"""How steady is the calibrated diversity, and what does a cheaper calibration lose? Replays it on stored samples.

Step 1 (``--draw``) samples a fitted run densely where its calibration judges (``auto.calibration``: 128 voxels,
the paper's voxels, for ``detail`` and ``fine``; the training grid's voxel centres for the others): ``--pool``
samples (32) at the near copy and at each diversity 0.10, 0.15, ... 1.00, each scored against the input with the
paper's LP-IoU / LP-F; it stores the per-sample scores and the samples' pairwise IoU (G-Div of any subset is the
mean of its pairs' ``1 - IoU``) in ``POOL.json``.

Step 2 (the default) replays the calibration's own rule (:func:`sin3dm_lite.evaluate.calibrate.calibrate_scores`:
the near copy's goals and copy line, the ladder, the smoothing, the refinement, the fallbacks) ``--replays`` times
per variant, each draw taking ``n`` samples not yet used in that replay at the pool's setting nearest the one asked
(the refinement's halfway settings, e.g. 0.53, are read at 0.55). It prints per variant the choice's mean, spread
and range, its distance to the **truth** (the same rule read on the whole pool's curves, no caution), and at the
choice on the whole pool's curves: LP-F and LP-IoU as shares of the near copy's and G-Div; how often the choice's
samples are copies or miss LP-F's goal; and the samples drawn (the calibration's cost).

    python benchmarks/bench_calibration.py --draw runs/tower_fine --pool-out /tmp/pool_tower.json
    python benchmarks/bench_calibration.py /tmp/pool_tower.json /tmp/pool_shelf.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from sin3dm_lite.auto.calibration import COARSE_WALK, default_goals, judged_at
from sin3dm_lite.evaluate.calibrate import G_DIV_GOAL, NEAR_COPY, RELATIVE, calibrate_scores, summarize
from sin3dm_lite.evaluate.calibration_record import copy_line
from sin3dm_lite.evaluate.curves import non_increasing

#: the pool's settings besides the near copy
SETTINGS = [round(0.1 + 0.05 * k, 2) for k in range(19)]

#: (name, options of calibrate_scores; 8 samples a setting unless said); the package's walk first
VARIANTS = [
    ("the package's, on every grid (ladder 0.2, 2 refine)", COARSE_WALK),
    ("the walk's own defaults (ladder 0.1, 4 refine)", dict()),
    ("3 refine", dict(refine=3)),
    ("2 refine", dict(refine=2)),
    ("0 refine", dict(refine=0)),
    ("6 a setting, 3 refine", dict(n=6, refine=3)),
    ("ladder 0.2, 4 refine", dict(step=0.2)),
    ("ladder 0.2, 3 refine", dict(step=0.2, refine=3)),
]


def draw_pool(run: str, out: str, n: int) -> None:
    """Score ``n`` samples at the near copy and at each of :data:`SETTINGS` on the grid the run's calibration
    judges, into ``out``."""
    from sin3dm_lite import Sin3DM
    from sin3dm_lite.evaluate import evaluation
    from sin3dm_lite.evaluate.calibrate import model_sampler
    from sin3dm_lite.evaluate.geometry import pairwise_iou
    from sin3dm_lite.evaluate.patches import lp_scores

    model = Sin3DM.load(run)
    resolution = judged_at(model.config) or model.grid_resolution
    supersample = 1 if resolution == model.grid_resolution else evaluation.PAPER_SUPERSAMPLE
    ref = model.input_occupancy(model.input_mesh(), resolution, supersample=supersample)
    sample_fn = model_sampler(model, ref, supersample=supersample)
    pool, t0 = {}, time.perf_counter()
    for j, d in enumerate([NEAR_COPY, *SETTINGS]):
        occ = [np.asarray(o, bool) for o in sample_fn(d, n, 50_000 + 1000 * j)]  # seeds apart from a fit's
        lp = lp_scores(ref, occ)
        pool[f"{d:g}"] = {
            "lp_iou": lp["per_shape_iou"],
            "lp_fscore": lp["per_shape_fscore"],
            "iou": np.round(pairwise_iou(occ), 6).tolist(),
        }
        print(f"{run} {d:.2f}: LP-IoU {lp['lp_iou']:.3f} LP-F {lp['lp_fscore']:.3f} ({time.perf_counter() - t0:.0f} s)")
        chosen = (model.report.get("calibration") or {}).get("diversity")  # the fit's own choice
        record = {"run": run, "resolution": resolution, "n": n, "fit_chose": chosen, "pool": pool}
        Path(out).write_text(json.dumps(record))


def _row(scores: dict, take) -> dict:
    """The calibration's row for the pool's samples ``take`` at one setting."""
    iou = np.asarray(scores["iou"])[np.ix_(take, take)]
    i, j = np.triu_indices(len(take), k=1)
    per_sample = {key: [scores[key][t] for t in take] for key in ("lp_iou", "lp_fscore")}
    return summarize(per_sample, float(np.mean(1.0 - iou[i, j])))


def _nearest(pool: dict, d: float) -> str:
    return min(pool, key=lambda key: abs(float(key) - d))


def replay(pool: dict, resolution: int, options: dict, rng: np.random.Generator):
    """One calibration on the pool: its record, the samples it drew, and how many of them it drew again (a setting
    drawn more often than the pool holds: the pool's samples again, reshuffled)."""
    n = options.get("n", 8)
    order = {d: list(rng.permutation(len(v["lp_iou"]))) for d, v in pool.items()}
    drawn, reused = [], []

    def draw(d: float, k: int) -> dict:
        key = str(NEAR_COPY) if d == NEAR_COPY else _nearest(pool, d)
        left = order[key]
        if len(left) < n:  # the refinement drew this setting often: its samples again, in a new order
            left[:] = list(rng.permutation(len(pool[key]["lp_iou"])))
            reused.append(n)
        take, left[:] = left[:n], left[n:]
        drawn.append(n)
        return _row(pool[key], take)

    cal = calibrate_scores(draw, resolution, default_goals(resolution), progress=False, **options)
    return cal, sum(drawn), sum(reused)


def truth(pool: dict, resolution: int) -> tuple[float, dict]:
    """The rule read on the whole pool (every sample at every setting, no walk, no caution): the most varied setting
    that keeps every goal, unless its samples are copies, then LP-F's alone, else the least varied that is not
    copies; and the pool's curves (settings high to low; LP scores made non-increasing in the knob)."""
    everything = {key: list(range(len(v["lp_iou"]))) for key, v in pool.items()}
    rows = {key: _row(pool[key], idx) for key, idx in everything.items()}
    levels = sorted((float(k) for k in pool if float(k) != NEAR_COPY), reverse=True)
    curves = {"level": levels, "g_div": [rows[f"{d:g}"]["g_div"] for d in levels]}
    for key in ("lp_iou", "lp_fscore"):
        means = [rows[f"{d:g}"][key] for d in levels]
        curves[key] = non_increasing(means[::-1], [1.0] * len(means))[::-1]
    near = rows[str(NEAR_COPY)]
    goals = {k: min(v, RELATIVE[k] * near[k]) for k, v in default_goals(resolution).items()}
    line = copy_line(near["g_div"])

    def most_varied(keys) -> float | None:
        kept = [d for i, d in enumerate(levels) if all(curves[k][i] >= goals[k] for k in keys)]
        return max(kept) if kept else None

    varied = [d for i, d in enumerate(levels) if curves["g_div"][i] >= line]
    answer = most_varied(goals)  # every goal; where its samples are copies, LP-F alone; else the least varied
    if answer is None or answer not in varied:
        alone = most_varied(["lp_fscore"])
        answer = alone if alone in varied else (min(varied) if varied else min(levels))
    return answer, {**curves, "near": near, "goals": goals, "line": line}


def at(curves: dict, d: float, key: str) -> float:
    return float(np.interp(d, curves["level"][::-1], curves[key][::-1]))


def report(path: str, replays: int) -> None:
    data = json.loads(Path(path).read_text())
    pool, res = data["pool"], data["resolution"]
    answer, c = truth(pool, res)
    near = c["near"]
    print(
        f"\n{data['run']} ({data['n']} samples a setting, at {res} voxels; the fit chose {data.get('fit_chose')}): "
        f"near copy LP-IoU {near['lp_iou']:.3f} LP-F {near['lp_fscore']:.3f} G-Div {near['g_div']:.3f}; "
        f"copies under G-Div {c['line']:.3f}; the truth {answer:.2f}"
    )
    print("  setting  " + " ".join(f"{d:5.2f}" for d in c["level"][::-1]))
    for key in ("lp_iou", "lp_fscore", "g_div"):
        print(f"  {key:9s}" + " ".join(f"{v:5.3f}" for v in c[key][::-1]))
    head = f"{'variant':48s} {'mean':>5s} {'sd':>5s} {'range':>10s} {'|Δ|':>5s} {'LP-F/nc':>7s} {'LP-IoU/nc':>9s}"
    print(head + f" {'G-Div':>6s} {'copies':>6s} {'F miss':>6s} {'all kept':>8s} {'samples':>7s}")
    for name, options in VARIANTS:
        rng = np.random.default_rng(0)
        runs = [replay(pool, res, options, rng) for _ in range(replays)]
        chosen = np.array([cal.diversity for cal, _, _ in runs])
        cost = np.array([s for _, s, _ in runs])
        again = sum(r for _, _, r in runs) / cost.sum()
        f = np.array([at(c, d, "lp_fscore") for d in chosen]) / near["lp_fscore"]
        iou = np.array([at(c, d, "lp_iou") for d in chosen]) / near["lp_iou"]
        g = np.array([at(c, d, "g_div") for d in chosen])
        kept = (f >= RELATIVE["lp_fscore"] - 1e-9) & (iou >= RELATIVE["lp_iou"] - 1e-9) & (g >= G_DIV_GOAL)
        print(
            f"{name:48s} {chosen.mean():5.3f} {chosen.std():5.3f} {chosen.min():4.2f}-{chosen.max():4.2f} "
            f"{np.abs(chosen - answer).mean():5.3f} {f.mean():7.0%} {iou.mean():9.0%} {g.mean():6.3f} "
            f"{np.mean(g < c['line']):6.0%} {np.mean(f < RELATIVE['lp_fscore'] - 1e-9):6.0%} {kept.mean():8.0%} {cost.mean():7.1f}"
            + (f" ({again:.0%} drawn again)" if again else "")
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pools", nargs="*", help="POOL.json files written by --draw")
    ap.add_argument("--draw", metavar="RUN", help="a fitted run folder to draw a pool from")
    ap.add_argument("--pool-out", help="where --draw writes its pool")
    ap.add_argument("--pool", type=int, default=32, help="samples per setting drawn for the pool")
    ap.add_argument("--replays", type=int, default=400)
    a = ap.parse_args()
    if a.draw:
        draw_pool(a.draw, a.pool_out or f"pool_{Path(a.draw).name}.json", a.pool)
    for path in a.pools:
        report(path, a.replays)


if __name__ == "__main__":
    main()

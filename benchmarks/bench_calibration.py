"""How steady is the calibrated diversity? Replays the calibration many times on stored per-sample scores.

Step 1 (``--draw``) samples a fitted run densely: ``--pool`` samples (48) at
each diversity ``--lowest`` (0.50), +0.05, ... 1.00, each decoded to occupancy on the
training grid and scored against it with the paper's LP-IoU / LP-F, and
stores the per-sample scores in ``POOL.json``. Its means, made
non-increasing in the knob, are the "true" curve; where it crosses the goals
is the true answer (no safety margin).

Step 2 (the default) replays :func:`sin3dm_lite.evaluate.calibrate._walk` (the
calibration's own ladder, smoothing and refinement) ``--replays`` times per
variant, each draw taking ``n`` samples not yet used in that replay from the
pool at the setting asked for. It prints per variant: the chosen diversity's
mean, spread and range, how far it lies from the true answer, how often the
true curve misses a goal at the choice and by how much at most in 95 % of the
replays, and the samples drawn.

    python benchmarks/bench_calibration.py --draw runs/canyon_small --pool-out /tmp/pool_canyon.json
    python benchmarks/bench_calibration.py /tmp/pool_canyon.json /tmp/pool_tiles.json
    python benchmarks/bench_calibration.py --draw RUIN_RUN --lowest 0.3 --pool-out /tmp/pool_ruin.json

A replay walks down to the pool's lowest setting; a pool must reach below the
answer (the ruin's is about 0.45, so its pool starts at 0.3).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from sin3dm_lite.evaluate.calibrate import FAR, GOALS, Calibration, _walk, summarize
from sin3dm_lite.evaluate.curves import crossing, non_increasing


def settings(lowest: float) -> list[float]:
    """The pool's settings: ``lowest``, +0.05, ... 1.00."""
    return [round(lowest + 0.05 * k, 2) for k in range(int(round((1.0 - lowest) / 0.05)) + 1)]


#: (name, options): the former rule first; the package default is marked
VARIANTS = [
    ("former: ladder, read 0.02 above", dict(n=8, refine=0, safety=0.02, caution=0.0)),
    ("+ 2 refine", dict(n=8, refine=2, safety=0.02, caution=0.0)),
    ("+ 4 refine", dict(n=8, refine=4, safety=0.02, caution=0.0)),
    ("ladder, read 1 SE above", dict(n=8, refine=0, safety=0.0, caution=1.0)),
    ("+ 2 refine, 1 SE", dict(n=8, refine=2, safety=0.0, caution=1.0)),
    ("+ 4 refine, 1 SE", dict(n=8, refine=4, safety=0.0, caution=1.0)),
    ("+ 2 refine, 1.5 SE", dict(n=8, refine=2, safety=0.0, caution=1.5)),
    ("+ 4 refine, 1.5 SE (the former default)", dict(n=8, refine=4, safety=0.0, caution=1.5)),
    ("+ 4 refine, 2 SE", dict(n=8, refine=4, safety=0.0, caution=2.0)),
    ("+ 2 refine, 0.01 + 1 SE", dict(n=8, refine=2, safety=0.01, caution=1.0)),
    ("+ 4 refine, 0.01 + 1 SE", dict(n=8, refine=4, safety=0.01, caution=1.0)),
    ("16 per setting, 1.5 SE", dict(n=16, refine=0, safety=0.0, caution=1.5)),
    ("default, skipping rungs below 0.4 x a goal", dict(n=8, refine=4, safety=0.0, caution=1.5, far=0.4)),
    (
        f"default, skipping below {FAR:g} x a goal (the package's)",
        dict(n=8, refine=4, safety=0.0, caution=1.5, far=FAR),
    ),
    ("default, skipping rungs below 0.6 x a goal", dict(n=8, refine=4, safety=0.0, caution=1.5, far=0.6)),
    ("default, skipping below 0.5, 3 refine", dict(n=8, refine=3, safety=0.0, caution=1.5, far=0.5)),
]


def draw_pool(run: str, out: str, n: int, lowest: float = 0.5) -> None:
    from sin3dm_lite import Sin3DM
    from sin3dm_lite.evaluate.calibrate import model_sampler, score_setting

    model = Sin3DM.load(run)
    ref = np.load(Path(run) / "grid.npz")["sdf"] < 0
    res = max(ref.shape)
    pool, t0 = {}, time.perf_counter()
    for j, d in enumerate(settings(lowest)):
        row = score_setting(
            model_sampler(model, ref), ref, d, n, 50_000 + 1000 * j
        )  # seeds apart from the calibration's (10,000+)
        pool[str(d)] = row["per_sample"]
        print(
            f"{run} diversity {d:.2f}: LP-IoU {row['lp_iou']:.3f} LP-F {row['lp_fscore']:.3f} "
            f"({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )
        Path(out).write_text(json.dumps({"run": run, "resolution": res, "n": n, "pool": pool}))


def true_curve(pool: dict, key: str) -> tuple[list[float], list[float]]:
    """The pool's means from high to low settings, made non-increasing in the knob."""
    levels = sorted((float(d) for d in pool), reverse=True)
    means = [float(np.mean(pool[str(d)][key])) for d in levels]
    return levels, non_increasing(means[::-1], [1.0] * len(means))[::-1]


def replay(pool: dict, options: dict, rng: np.random.Generator) -> tuple[float, int]:
    """One calibration on the pool's scores: (its choice, samples drawn)."""
    n = options["n"]
    order = {d: list(rng.permutation(len(v["lp_iou"]))) for d, v in pool.items()}

    def draw(d: float, k: int) -> dict:
        left = order[str(round(d, 2))]
        if len(left) < n:
            raise RuntimeError(f"the pool has too few samples left at {d}; draw a larger pool")
        take, left[:] = left[:n], left[n:]
        scores = pool[str(round(d, 2))]
        return summarize({key: [scores[key][i] for i in take] for key in GOALS})

    lowest = min(float(d) for d in pool)
    cal = Calibration(diversity=lowest, goals=dict(GOALS), n=n, resolution=0)
    _walk(
        cal,
        draw,
        lowest,
        0.1,
        0.05,
        options["safety"],
        options["refine"],
        options["caution"],
        False,
        options.get("far", 0.0),
    )
    return cal.diversity, n * len(cal.tried)


def report(path: str, replays: int) -> None:
    data = json.loads(Path(path).read_text())
    pool = data["pool"]
    curves = {key: true_curve(pool, key) for key in GOALS}
    crossings = [crossing(*curves[key], goal) for key, goal in GOALS.items()]
    truth = min(c if c is not None else min(curves["lp_iou"][0]) for c in crossings)
    line = " · ".join(f"{key} " + " ".join(f"{y:.3f}" for y in curves[key][1][::-1]) for key in GOALS)
    print(f"\n{data['run']} ({data['n']} samples per setting, {min(map(float, pool)):.2f} … 1.00): {line}")
    print(f"true answer (the pool's curve crosses the goals): {truth:.3f}")
    print(
        f"{'variant':38s} {'mean':>5s} {'sd':>5s} {'range':>11s} {'|Δ| to true':>11s} {'misses a goal':>13s} "
        f"{'95% short by':>12s} {'samples':>7s}"
    )
    for name, options in VARIANTS:
        rng = np.random.default_rng(0)
        chosen, cost = np.array([replay(pool, options, rng) for _ in range(replays)]).T
        at = {key: np.interp(chosen, curves[key][0][::-1], curves[key][1][::-1]) for key in GOALS}
        short = np.max([goal - at[key] for key, goal in GOALS.items()], axis=0)  # > 0: the true curve misses a goal
        print(
            f"{name:38s} {chosen.mean():5.3f} {chosen.std():5.3f} {chosen.min():5.2f}-{chosen.max():4.2f} "
            f"{np.abs(chosen - truth).mean():11.3f} {np.mean(short > 1e-9):13.0%} "
            f"{max(np.percentile(short, 95), 0.0):12.3f} {cost.mean():7.1f}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pools", nargs="*", help="POOL.json files written by --draw")
    ap.add_argument("--draw", metavar="RUN", help="a fitted run folder (with grid.npz) to draw a pool from")
    ap.add_argument("--pool-out", help="where --draw writes its pool")
    ap.add_argument("--pool", type=int, default=48, help="samples per setting drawn for the pool")
    ap.add_argument("--lowest", type=float, default=0.5, help="the pool's lowest setting (below the shape's answer)")
    ap.add_argument("--replays", type=int, default=400)
    a = ap.parse_args()
    if a.draw:
        draw_pool(a.draw, a.pool_out or f"pool_{Path(a.draw).name}.json", a.pool, a.lowest)
    for path in a.pools:
        report(path, a.replays)


if __name__ == "__main__":
    main()

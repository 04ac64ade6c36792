"""The benchmark scripts the docs quote still import: a name moved in the package must not break them unseen."""

import importlib.util
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.mark.parametrize("script", sorted(p.name for p in BENCHMARKS.glob("*.py")))
def test_every_benchmark_script_imports(script, monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))  # the scripts import each other as siblings
    spec = importlib.util.spec_from_file_location(f"_bench_{script[:-3]}", BENCHMARKS / script)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)
    spec.loader.exec_module(module)  # the module's top level only: its main() runs under __main__
    assert callable(getattr(module, "main", None))


def test_the_calibration_replay_finds_a_pools_answer(monkeypatch, tmp_path, capsys):
    """bench_calibration.py replays the package's own rule on stored scores: on a pool whose samples keep the input
    up to 0.5 but are copies there (pairwise IoU 0.99), and vary above it (0.8) but keep two thirds of the patches (not torn), the
    truth and the walk choose the least varied setting that is not copies, and the report says what each walk
    drew."""
    import json

    import numpy as np

    monkeypatch.syspath_prepend(str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location("_bench_replay", BENCHMARKS / "bench_calibration.py")
    bench = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, bench)
    spec.loader.exec_module(bench)
    rng, n = np.random.default_rng(0), 16
    pool = {}
    for d in [0.05, *bench.SETTINGS]:
        keep = 0.9 if d <= 0.5 else 0.6
        iou = np.full((n, n), 0.99 if d <= 0.5 else 0.8)
        np.fill_diagonal(iou, 1.0)
        scores = {k: (keep + 0.01 * rng.standard_normal(n)).tolist() for k in ("lp_iou", "lp_fscore")}
        pool[f"{d:g}"] = {**scores, "iou": iou.tolist()}
    path = tmp_path / "pool.json"
    path.write_text(json.dumps({"run": "synthetic", "resolution": 128, "n": n, "pool": pool}))
    answer, curves = bench.truth(pool, 128)
    assert answer == 0.55 and curves["line"] == 0.1
    cal, drawn, _ = bench.replay(pool, 128, dict(bench.COARSE_WALK), np.random.default_rng(1))
    assert 0.55 <= cal.diversity <= 0.6 and cal.only_copies_kept and drawn == 8 * (len(cal.tried) + 1)
    bench.report(str(path), replays=3)
    out = capsys.readouterr().out
    assert "the truth 0.55" in out and out.count("\n") >= 6 + len(bench.VARIANTS)


def test_the_flops_table_holds_each_stage_against_the_peak_it_runs_on(monkeypatch):
    """docs/performance.md's GPU table: bf16 rows against the bf16 tensor peak, the fp32 convolutions against TF32
    (cuDNN's default), the point MLPs' fp32 products against the fp32 cores; a CPU's rows against its fp32 peak."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import torch
    from bench_training import against

    monkeypatch.setattr(torch.backends.cudnn, "allow_tf32", True)
    assert against("bf16 autocast", "autoencoder step", cuda=True) == "bf16"
    assert against("fp32", "denoiser step, compiled", cuda=True) == "tf32"
    assert against("fp32", "autoencoder step", cuda=True) == "fp32"
    assert against("fp32", "decode to the grid", cuda=True) == "fp32"
    assert {against(p, "denoiser step", cuda=False) for p in ("fp32", "bf16 autocast")} == {"fp32"}
    monkeypatch.setattr(torch.backends.cudnn, "allow_tf32", False)
    assert against("fp32", "denoiser step", cuda=True) == "fp32"

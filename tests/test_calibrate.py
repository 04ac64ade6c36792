"""Choosing the diversity knob per shape: the ladder, its smoothing, its scoring path, and what a fit and the CLI keep."""
import json
import warnings

import numpy as np
import pytest

from sin3dm_lite.cli import main
from sin3dm_lite.data.box import grid_shape
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.evaluate import calibrate as C
from sin3dm_lite.evaluate.metrics import iou
from sin3dm_lite.pipeline import Sin3DM

from .conftest import micro_config

AABB = np.array([-1.0, -0.5, -0.75, 1.0, 0.5, 0.75], np.float32)


class _Box:
    aabb = AABB


def _reference() -> np.ndarray:
    """A slab with a ridge: enough surface patches for LP scores."""
    ref = np.zeros(grid_shape(AABB, 24), bool)
    ref[:, :6] = True
    ref[8:14, 6:9] = True
    return ref


class _Knob:
    """Fake samples: the input up to diversity ``edge``, empty above it; ``drawn`` records each call."""

    def __init__(self, edge: float):
        self.edge, self.drawn = edge, []

    def __call__(self, model, diversity, n, seed, resolution):
        self.drawn.append((diversity, n, seed, resolution))
        ref = _reference()
        return [ref if diversity <= self.edge else np.zeros_like(ref) for _ in range(n)]


@pytest.fixture
def knob(monkeypatch):
    k = _Knob(0.7)
    monkeypatch.setattr(C, "sample_occupancy", k)
    return k


def test_the_ladder_walks_down_to_the_first_setting_that_keeps_the_goals(knob):
    cal = C.calibrate_diversity(_Box(), _reference(), n=3, seed=5, refine=0, safety=0.02, progress=False)
    assert [t["diversity"] for t in cal.tried] == [1.0, 0.9, 0.8, 0.7]  # 0.7 keeps both goals by the margin: stop
    assert [t["kept"] for t in cal.tried] == [False, False, False, True]
    assert [seed for _, _, seed, _ in knob.drawn] == [5, 1005, 2005, 3005]  # seeds of its own at every setting
    assert {(n, res) for _, n, _, res in knob.drawn} == {(3, 24)}
    # the scores jump from 0 to 1 between 0.8 and 0.7: the crossing of LP-F 0.70 + 0.02 lies at 0.728 (of LP-IoU
    # 0.55 + 0.02 at 0.743), without the safety margin at 0.73
    assert cal.diversity == 0.73 and cal.kept_goals
    text = cal.summary().splitlines()  # what notebook 04 prints: a line per setting drawn, then the choice
    assert len(text) == 5 and text[0].startswith("diversity 1.00: LP-IoU 0.000") and text[-1] == "chosen: 0.73"
    assert C.calibrate_diversity(_Box(), _reference(), n=3, refine=0, safety=0.2, progress=False).diversity == 0.71


def test_refinement_draws_where_the_answer_lies_and_pools_repeated_settings(knob):
    """The ladder brackets the edge between 0.8 and 0.7; refinement draws at the half-step point nearest the answer
    (0.75, which misses), narrowing the answer to between 0.75 and 0.7, then at 0.7 again, whose 6 samples are
    pooled with the ladder's 3 there."""
    cal = C.calibrate_diversity(_Box(), _reference(), n=3, seed=5, refine=2, safety=0.02, progress=False)
    assert [t["diversity"] for t in cal.tried] == [1.0, 0.9, 0.8, 0.7, 0.75, 0.7]
    assert [seed for _, _, seed, _ in knob.drawn] == [5, 1005, 2005, 3005, 4005, 5005]
    assert cal.diversity == 0.71 and cal.kept_goals  # 0.7 + 0.05 · (1 - 0.72): the edge is at 0.7
    assert C._curve(cal.tried, "lp_fscore")[:2] == ([1.0, 0.9, 0.8, 0.75, 0.7], [0.0, 0.0, 0.0, 0.0, 1.0])
    assert C.calibrate_diversity(_Box(), _reference(), n=3, refine=0, safety=0.02, progress=False).diversity == 0.73
    knob.edge = 1.0  # nothing to refine when pure noise keeps the goals
    assert len(C.calibrate_diversity(_Box(), _reference(), n=3, refine=2, progress=False).tried) == 1


def test_a_setting_row_keeps_each_goals_mean_and_spread(knob):
    row = C.summarize({"lp_iou": [0.2, 0.4, 0.6], "lp_fscore": [1.0, 1.0, 1.0]}, 0.3)
    assert row["lp_iou"] == pytest.approx(0.4) and row["lp_iou_sd"] == pytest.approx(0.2)
    assert row["lp_fscore_sd"] == 0.0 and row["g_div"] == 0.3
    scored = C.score_setting(_Box(), _reference(), 0.5, 3, 0)  # the fake knob: the input itself, three times
    assert scored["per_sample"]["lp_iou"] == [1.0] * 3 and scored["lp_iou"] == 1.0 and scored["lp_iou_sd"] == 0.0


def test_the_walk_goes_on_down_when_the_lowered_curve_misses_where_it_stopped():
    """0.9's 8 samples keep the goals by the margin on average but scatter widely: one standard error below, they
    miss, so the ladder goes on to 0.8 instead of answering with the lowest setting."""
    scores = {1.0: (0.3, 0.4, 0.0), 0.9: (0.61, 0.76, 0.3), 0.8: (0.9, 0.95, 0.0)}

    def draw(d, k):
        iou_, f, sd = scores[d]
        return {"lp_iou": iou_, "lp_fscore": f, "g_div": 0.1, "lp_iou_sd": sd, "lp_fscore_sd": sd}

    cal = C.Calibration(diversity=0.5, goals=dict(C.GOALS), n=8, resolution=24)
    C._walk(cal, draw, lowest=0.5, step=0.1, margin=0.05, safety=0.0, refine=0, caution=1.0, progress=False)
    assert [t["diversity"] for t in cal.tried] == [1.0, 0.9, 0.8]
    assert cal.kept_goals and 0.8 <= cal.diversity <= 0.9


def test_a_setting_drawn_twice_counts_by_its_samples():
    tried = [{"diversity": 0.8, "n": 8, "lp_iou": 0.6}, {"diversity": 0.7, "n": 8, "lp_iou": 0.8},
             {"diversity": 0.7, "n": 24, "lp_iou": 0.4}]
    # 0.7's 32 samples score 0.5, below 0.8's 8 samples (0.6) by chance: pooled by samples, (0.6·8 + 0.5·32) / 40
    levels, fitted, _ = C._curve(tried, "lp_iou")
    assert levels == [0.8, 0.7] and fitted == pytest.approx([0.52, 0.52])


def test_the_curve_is_read_standard_errors_below_its_scores():
    """Two settings of 8 samples with a spread of 0.2 each: standard error 0.2 / √8 on each smoothed score; read
    one standard error low, the curve crosses 0.6 nearer the setting that keeps it. Pooling settings (by chance, or
    by drawing one again) rests a score on more samples and narrows its error."""
    tried = [{"diversity": 0.8, "n": 8, "lp_iou": 0.5, "lp_iou_sd": 0.2},
             {"diversity": 0.7, "n": 8, "lp_iou": 0.7, "lp_iou_sd": 0.2}]
    levels, fitted, se = C._curve(tried, "lp_iou")
    assert fitted == [0.5, 0.7] and se == pytest.approx([0.2 / 8 ** 0.5] * 2)
    assert C._choice(tried, {"lp_iou": 0.6}, safety=0.0, caution=0.0) == pytest.approx(0.75)
    assert C._choice(tried, {"lp_iou": 0.6}, safety=0.0, caution=1.0) == pytest.approx(0.7 + 0.1 * (0.7 - 0.2 / 8 ** 0.5 - 0.6) / 0.2)
    tried.append({"diversity": 0.7, "n": 24, "lp_iou": 0.7, "lp_iou_sd": 0.2})
    assert C._curve(tried, "lp_iou")[2] == pytest.approx([0.2 / 8 ** 0.5, 0.2 / 32 ** 0.5])
    tried[0]["lp_iou"] = 0.9  # rises above 0.7's by chance: one block of 40 samples
    assert C._curve(tried, "lp_iou")[2] == pytest.approx([0.2 / 40 ** 0.5] * 2)


def test_scores_that_rise_with_the_knob_by_chance_are_pooled():
    """A noisy curve is made to fall with the knob before its crossing is read."""
    fitted = C._non_increasing([0.8, 0.6, 0.65, 0.5], [1.0] * 4)
    assert fitted == pytest.approx([0.8, 0.625, 0.625, 0.5])
    levels = [1.0, 0.9, 0.8]
    assert C._crossing(levels, [0.4, 0.5, 0.6], 0.55) == pytest.approx(0.85)
    assert C._crossing(levels, [0.6, 0.7, 0.8], 0.55) == 1.0 and C._crossing(levels, [0.1, 0.2, 0.3], 0.55) is None


def test_pure_noise_that_keeps_the_goals_is_taken_at_once(knob):
    knob.edge = 1.0
    cal = C.calibrate_diversity(_Box(), _reference(), progress=False)
    assert cal.diversity == 1.0 and len(cal.tried) == 1 and cal.kept_goals


def test_goals_out_of_reach_give_the_lowest_setting_and_say_so(knob):
    knob.edge = 0.1
    cal = C.calibrate_diversity(_Box(), _reference(), lowest=0.4, step=0.2, progress=False)
    assert cal.diversity == 0.4 and not cal.kept_goals and "no setting kept the goals" in cal.summary()
    assert [t["diversity"] for t in cal.tried] == [1.0, 0.8, 0.6, 0.4]


@pytest.mark.parametrize("kw, match", [
    ({"n": 1}, "at least 2 samples"),
    ({"lowest": 1.0}, "lowest"),
    ({"goals": {"g_div": 0.2}}, "unknown calibration goals"),
    ({"goals": {"lp_iou": 55}}, "from 0 to 1"),
    ({"step": 0.0}, "step"),
    ({"step": 0.6}, "step"),
    ({"safety": 1.5}, "safety"),
    ({"refine": -1}, "refine"),
    ({"caution": -1.0}, "caution"),
])
def test_bad_options_are_named(kw, match):
    with pytest.raises(Sin3DMInputError, match=match):
        C.calibrate_diversity(_Box(), _reference(), progress=False, **kw)


def test_a_reference_on_another_box_is_refused():
    with pytest.raises(Sin3DMInputError, match="not on this model's box"):
        C.calibrate_diversity(_Box(), np.zeros((24, 24, 24), bool), progress=False)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    run = tmp_path_factory.mktemp("cal") / "wall"
    cfg = micro_config().updated(**{"sampling.calibrate": True, "sampling.diversity": 0.9})
    return Sin3DM.fit("wall", preset=cfg, out=run, progress=False), run


def test_a_fit_saves_its_calibrated_diversity(calibrated):
    model, run = calibrated
    cal = model.report["calibration"]
    assert model.config.sampling.diversity == cal["diversity"]
    assert 0.5 <= cal["diversity"] <= 1.0 and cal["tried"][0]["diversity"] == 1.0 and "lp_iou_fitted" in cal["tried"][0]
    assert json.loads((run / "config.json").read_text())["sampling"]["diversity"] == cal["diversity"]
    report = json.loads((run / "report.json").read_text())
    assert report["calibration"] == cal and report["timings_s"]["calibrate_s"] > 0
    assert Sin3DM.load(run).config.sampling.diversity == cal["diversity"]  # what `sample` uses by default


def test_the_rollout_hint_applies_only_to_a_plain_denoiser_calibrated_to_pure_noise():
    from sin3dm_lite.data.config import get_preset
    from sin3dm_lite.pipeline import rollout_hint

    small = get_preset("small")
    hint = rollout_hint(small, {"diversity": 1.0, "kept_goals": True})
    assert "--set diffusion.rollout=true" in hint and "get_preset('small').updated(**{'diffusion.rollout': True})" in hint
    assert rollout_hint(small, {"diversity": 0.73, "kept_goals": True}) is None  # the canyon: its layout varies
    assert rollout_hint(small, {"diversity": 1.0, "kept_goals": False}) is None  # 1 only as the lowest drawn
    assert rollout_hint(small.updated(**{"diffusion.rollout": True}), {"diversity": 1.0, "kept_goals": True}) is None
    assert rollout_hint(small, None) is None  # no calibration


KEEP_EVERY_SETTING = {"lp_iou": 0.0, "lp_fscore": 0.0}  # goals kept at every setting: calibrated to 1
PLAIN = {"sampling.calibrate": True, "diffusion.rollout": False}
SWITCH = {"diffusion.rollout": True, "diffusion.steps": 20}


def _fit_keeping_the_goals(folder, cfg):
    """``Sin3DM.fit`` with progress under :data:`KEEP_EVERY_SETTING`: ``(model, run folder, what it printed)``."""
    import contextlib
    import io

    run, printed = folder / "w", io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(printed), warnings.catch_warnings():
        mp.setattr(C, "GOALS", KEEP_EVERY_SETTING)
        warnings.simplefilter("ignore")  # a micro fit reconstructs poorly
        model = Sin3DM.fit("wall", preset=cfg, out=run, progress=True)
    return model, run, printed.getvalue()


@pytest.fixture(scope="module")
def plain_fit(tmp_path_factory):
    """A plain denoiser (no rollout switch) whose calibration keeps the goals from pure noise."""
    return _fit_keeping_the_goals(tmp_path_factory.mktemp("plain"), micro_config().updated(**PLAIN))


@pytest.fixture(scope="module")
def switched_fit(tmp_path_factory):
    """The same with the rollout switch: trained again with the cross-plane rollout (20 steps)."""
    return _fit_keeping_the_goals(tmp_path_factory.mktemp("switched"),
                                  micro_config().updated(**PLAIN, rollout_switch=SWITCH))


def test_a_plain_fit_that_keeps_the_goals_from_pure_noise_says_the_hint(plain_fit):
    model, run, out = plain_fit
    assert model.config.sampling.diversity == 1.0 and not model.config.diffusion.rollout
    report = json.loads((run / "report.json").read_text())
    assert report["rollout_hint"] in out and "--set diffusion.rollout=true" in report["rollout_hint"]
    assert ".updated(**{'diffusion.rollout': True})" in report["rollout_hint"]


def _has_rollout(denoiser) -> bool:
    return any(getattr(m, "rollout", False) for m in denoiser.modules())


def test_a_fit_that_keeps_the_goals_from_pure_noise_switches_to_the_rollout(switched_fit, plain_fit):
    """With rollout_switch a plain fit calibrated to 1 trains its denoiser again with the rollout, says so, records
    the first calibration and its time, and its run folder loads as what it is: a rollout denoiser (the resume:
    the next test)."""
    from sin3dm_lite.data.config import Config

    model, run, out = switched_fit
    assert "trained again with the cross-plane rollout" in out and "--no-rollout-switch" in out
    assert "rollout_hint" not in model.report
    assert model.config.diffusion.rollout and model.config.diffusion.steps == 20 and not model.config.rollout_switch
    assert _has_rollout(model.denoiser)  # the denoiser sampling uses is the rollout one
    report = json.loads((run / "report.json").read_text())
    switch = report["rollout_switch"]
    assert switch["plain_calibration"] == {"diversity": 1.0, "kept_goals": True} and switch["plain_s"] > 0
    t = report["timings_s"]
    assert t["rollout_switch_s"] == switch["plain_s"] and t["diffusion_s"] > 0 and t["calibrate_s"] > 0
    assert report["calibration"]["kept_goals"]
    saved = Config.from_dict(json.loads((run / "config.json").read_text()))
    assert saved.diffusion.rollout and not saved.rollout_switch
    loaded = Sin3DM.load(run)
    assert loaded.config.diffusion.rollout and _has_rollout(loaded.denoiser)
    losses = json.loads((run / "losses.json").read_text())
    assert len(losses["diffusion"]["loss"]) == 20  # the rollout denoiser's, not both

    # --no-rollout-switch (rollout_switch={}: the plain fit's settings) keeps the plain denoiser and only hints
    plain = plain_fit[0]
    assert not plain.config.diffusion.rollout and plain.report["rollout_switch"] is None and "rollout_hint" in plain.report


@pytest.mark.filterwarnings("ignore:low reconstruction")  # a micro fit
def test_a_fit_interrupted_in_its_rollout_denoiser_resumes_to_the_same_model(switched_fit, tmp_path, monkeypatch):
    """Ctrl-C during the second training leaves a rollout config, a rollout checkpoint and the switch's record;
    --resume ends with the uninterrupted switched fit's model, bit for bit."""
    import os
    import signal

    import torch

    from sin3dm_lite.model import diffusion

    monkeypatch.setattr(C, "GOALS", KEEP_EVERY_SETTING)
    cfg = micro_config().updated(**PLAIN, rollout_switch=SWITCH)
    _, full, _ = switched_fit  # the uninterrupted fit
    real_step = diffusion.DiffusionTrainer.step

    def step_then_ctrl_c(self):
        loss = real_step(self)
        if self.cfg.rollout and self.step_count == 7:
            os.kill(os.getpid(), signal.SIGINT)
        return loss

    monkeypatch.setattr(diffusion.DiffusionTrainer, "step", step_then_ctrl_c)
    run = tmp_path / "cut"
    with pytest.raises(KeyboardInterrupt):
        Sin3DM.fit("wall", preset=cfg, out=run, progress=False)
    assert json.loads((run / "config.json").read_text())["diffusion"]["rollout"] is True
    assert torch.load(run / "diffusion.pt", weights_only=True)["step"] == 7
    assert json.loads((run / "report.json").read_text())["rollout_switch"]["plain_calibration"]["kept_goals"]
    monkeypatch.setattr(diffusion.DiffusionTrainer, "step", real_step)
    resumed = Sin3DM.fit("wall", out=run, resume=True, progress=False)
    a = torch.load(full / "model.pt", weights_only=True)
    b = torch.load(run / "model.pt", weights_only=True)
    for part in ("decoder", "denoiser", "latent"):
        for k in a[part]:
            assert torch.equal(a[part][k], b[part][k]), (part, k)
    assert resumed.report["diffusion_steps"] == 20 and resumed.report["rollout_switch"]["plain_calibration"]["kept_goals"]


@pytest.mark.filterwarnings("ignore:low reconstruction")  # a micro fit
def test_a_switched_fit_whose_rollout_keeps_no_goal_warns_with_the_way_back(tmp_path, monkeypatch):
    """The switch's only risk, said plainly: the rollout denoiser kept no setting where the plain one did."""
    def fake(model, reference, progress=True, **options):
        kept = not model.config.diffusion.rollout  # the plain denoiser keeps the goals from pure noise, the rollout none
        return C.Calibration(diversity=1.0 if kept else 0.5, goals={}, n=1, resolution=8, kept_goals=kept)

    monkeypatch.setattr(C, "calibrate_diversity", fake)
    cfg = micro_config().updated(**{"sampling.calibrate": True, "diffusion.rollout": False, "diffusion.steps": 5,
                                    "rollout_switch": {"diffusion.rollout": True, "diffusion.steps": 5}})
    with pytest.warns(UserWarning, match="with the cross-plane rollout no diversity setting kept.*--no-rollout-switch"):
        model = Sin3DM.fit("wall", preset=cfg, out=tmp_path / "w", progress=False)
    assert model.config.diffusion.rollout and model.report["rollout_switch"]["plain_calibration"]["kept_goals"]


def test_calibration_scores_the_occupancy_the_metrics_score(calibrated):
    """The SDF's sign on the training grid (calibration) and the exported mesh voxelised (the metrics) agree, and
    the sign-only decode gives the full decode's signs voxel for voxel."""
    from sin3dm_lite.model.decode import decode_grid

    model, run = calibrated
    res = max(model.report["grid_shape"])
    fast = C.sample_occupancy(model, 1.0, 2, 3, res)
    samples = model.sample(2, seed=3, diversity=1.0, progress=False)
    slow = model.occupancy(samples, res, mesh_resolution=res)
    for i, (a, b) in enumerate(zip(fast, slow)):
        assert a.shape == b.shape and a.any()
        assert iou(a, b) > 0.9
        assert np.array_equal(a, decode_grid(model.decoder, samples.triplane[i:i + 1], samples.aabb, res) < 0)


def test_cli_calibrate_rewrites_the_run_config(calibrated, capsys, tmp_path):
    """The barely trained micro model keeps no patches, so the calibration lands on its lowest setting, 0.5."""
    _, run = calibrated
    cfg = json.loads((run / "config.json").read_text())
    cfg["sampling"]["diversity"] = 0.9  # config.json is rewritten from the model the command loads and calibrates
    (run / "config.json").write_text(json.dumps(cfg))
    code = main(["calibrate", str(run), "-n", "2", "--lp-iou", "0.3", "--lp-f", "0.4"])
    out = capsys.readouterr().out
    assert code == 0 and "→ 0.5 " in out and "saved" in out
    assert json.loads((run / "config.json").read_text())["sampling"]["diversity"] == 0.5
    assert Sin3DM.load(run).config.sampling.diversity == 0.5
    report = json.loads((run / "report.json").read_text())
    assert report["calibration"]["goals"] == {"lp_iou": 0.3, "lp_fscore": 0.4}
    assert report["calibration"]["kept_goals"] is False


def test_cli_calibrate_without_the_grid_uses_the_input_mesh(calibrated, capsys, tmp_path):
    """A run folder without grid.npz is calibrated against the mesh --input names, voxelised on the model's box."""
    import shutil

    _, run = calibrated
    bare = tmp_path / "bare"
    shutil.copytree(run, bare)
    (bare / "grid.npz").unlink()
    assert main(["calibrate", str(bare), "-n", "2", "--input", "wall"]) == 0
    cal = json.loads((bare / "report.json").read_text())["calibration"]
    assert cal["resolution"] == max(json.loads((bare / "report.json").read_text())["grid_shape"])
    assert main(["calibrate", str(bare), "-n", "2", "--input", str(tmp_path / "gone.obj")]) == 2
    assert "gone.obj" in capsys.readouterr().err


def test_cli_calibrate_errors_in_one_line(capsys, tmp_path):
    assert main(["calibrate", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err
    assert "not found" in err and len(err.strip().splitlines()) == 1
    with pytest.raises(SystemExit) as e:
        main(["calibrate", "run", "-n", "1"])
    assert e.value.code == 2 and "at least 2" in capsys.readouterr().err

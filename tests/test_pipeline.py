"""Sin3DM end to end on a very small setting: run folder, report, save/load, resume, sampling, meshes."""

import json
import os
import signal
from dataclasses import replace

import numpy as np
import pytest
import torch

from sin3dm_lite.app.device import cpu_bf16_share, resolved_precision
from sin3dm_lite.data.config import Config
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.model import autoencoder
from sin3dm_lite.pipeline import Sin3DM
from sin3dm_lite.presets import get_preset

from .conftest import micro_config, micro_model


@pytest.fixture(scope="module")
def fitted(micro_fit):
    return micro_model(micro_fit), micro_fit[1]


def test_run_folder_and_report(fitted):
    model, run = fitted
    for name in ["config.json", "grid.npz", "autoencoder.pt", "diffusion.pt", "model.pt", "losses.json", "report.json"]:
        assert (run / name).is_file(), name
    assert not list(run.glob("*.tmp"))
    report = json.loads((run / "report.json").read_text())
    assert report["autoencoder_steps"] == 30 and report["diffusion_steps"] == 30
    rec = report["reconstruction"]
    assert 0 <= rec["occupancy_iou"] <= 1 and 0 <= rec["sign_accuracy"] <= 1 and rec["color_psnr"] > 0
    losses = json.loads((run / "losses.json").read_text())
    assert len(losses["autoencoder"]["loss"]) == 30 and len(losses["diffusion"]["loss"]) == 30
    torch.load(run / "model.pt", weights_only=True)  # loads without unpickling code
    # what the networks trained in, so that the fit's times can be read: the settings resolved on this machine
    cfg = model.config
    expected = {net: resolved_precision("cpu", getattr(cfg, net).precision) for net in ("autoencoder", "diffusion")}
    assert {k: report["precision"][k] for k in expected} == expected and set(expected.values()) <= {"bf16", "fp32"}
    assert ("cpu_bf16_share" in report["precision"]) == (
        cpu_bf16_share() is not None and "auto" in (cfg.autoencoder.precision, cfg.diffusion.precision)
    )


def test_auto_precision_resolves_to_what_the_step_runs_in(monkeypatch):
    """'auto' is bf16 exactly where bf16 measures faster; 'fp32' and 'bf16' are themselves; anything else is refused."""
    from sin3dm_lite.app import device

    for fast in (True, False):
        monkeypatch.setattr(device, "bf16_is_fast", lambda dev, f=fast: f)
        assert resolved_precision("cpu", "auto") == ("bf16" if fast else "fp32")
        assert resolved_precision("cpu", "fp32") == "fp32" and resolved_precision("cpu", "bf16") == "bf16"
    with pytest.raises(Sin3DMInputError, match="unknown precision 'half'"):
        resolved_precision("cpu", "half")

    # the fit's record: each network's setting resolved, and bf16's measured share where 'auto' asked for it
    from sin3dm_lite.app import fitting

    cfg = micro_config().updated(**{"autoencoder.precision": "auto", "diffusion.precision": "fp32"})
    dev = torch.device("cpu")
    monkeypatch.setattr(device, "bf16_is_fast", lambda d: True)
    monkeypatch.setattr(fitting, "cpu_bf16_share", lambda: 0.4912)
    assert fitting.training_precision(cfg, dev) == {"autoencoder": "bf16", "diffusion": "fp32", "cpu_bf16_share": 0.491}
    monkeypatch.setattr(device, "bf16_is_fast", lambda d: False)
    monkeypatch.setattr(fitting, "cpu_bf16_share", lambda: None)  # no native bf16: nothing measured, nothing said
    assert fitting.training_precision(cfg, dev) == {"autoencoder": "fp32", "diffusion": "fp32"}
    fixed = cfg.updated(**{"autoencoder.precision": "fp32"})
    monkeypatch.setattr(fitting, "cpu_bf16_share", lambda: pytest.fail("measured for fixed precisions"))
    assert fitting.training_precision(fixed, dev) == {"autoencoder": "fp32", "diffusion": "fp32"}


def test_load_round_trip_gives_the_same_samples(fitted):
    model, run = fitted
    again = Sin3DM.load(run)
    a = model.sample(2, seed=5, progress=False)
    b = again.sample(2, seed=5, progress=False)
    for p, q in zip(a.triplane.planes, b.triplane.planes):
        torch.testing.assert_close(p, q)
    np.testing.assert_array_equal(a.aabb, b.aabb)


def test_retargeted_samples_have_a_scaled_latent_and_box(fitted):
    model, _ = fitted
    s = model.sample(1, resize=(2.0, 0.5, 1.0), progress=False)
    x, y, z = model.latent.resolution
    assert y >= 8  # so that halving it stays above the 4-texel minimum
    assert s.triplane.resolution == (2 * x, round(y * 0.5), z)
    np.testing.assert_allclose(s.aabb[[0, 3]], model.aabb[[0, 3]] * 2, rtol=1e-6)
    np.testing.assert_allclose(s.aabb[[1, 4]], model.aabb[[1, 4]] * 0.5, rtol=1e-6)
    np.testing.assert_allclose(s.aabb[[2, 5]], model.aabb[[2, 5]], rtol=1e-6)


def test_to_mesh_in_the_input_box(fitted):
    model, _ = fitted
    s = model.input_sample()
    mesh = model.to_mesh(s, 0, original_coords=False)
    assert len(mesh.faces) > 0
    lo, hi = model.aabb[:3], model.aabb[3:]
    assert np.all(mesh.vertices >= lo - 1e-4) and np.all(mesh.vertices <= hi + 1e-4)
    assert mesh.materials[0].image is not None and mesh.materials[0].image.std() > 0


def test_interrupted_fit_resumes_to_the_same_result(fitted, tmp_path, monkeypatch):
    model, run_full = fitted
    run = tmp_path / "interrupted"
    real_step = autoencoder.AutoencoderTrainer.step

    def step_then_ctrl_c(self):
        loss = real_step(self)
        if self.step_count == 17:  # Ctrl-C in the middle of the autoencoder stage
            os.kill(os.getpid(), signal.SIGINT)
        return loss

    monkeypatch.setattr(autoencoder.AutoencoderTrainer, "step", step_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        Sin3DM.fit("wall", preset=micro_config(), out=run, progress=False)
    saved = torch.load(run / "autoencoder.pt", weights_only=True)
    assert saved["step"] == 17  # the last finished step was saved: no lost work
    monkeypatch.setattr(autoencoder.AutoencoderTrainer, "step", real_step)
    resumed = Sin3DM.fit("wall", out=run, resume=True, progress=False)
    a = torch.load(run_full / "model.pt", weights_only=True)
    b = torch.load(run / "model.pt", weights_only=True)
    for part in ("decoder", "denoiser", "latent"):
        for k in a[part]:
            assert torch.equal(a[part][k], b[part][k]), (part, k)
    assert resumed.report["autoencoder_steps"] == 30


@pytest.mark.filterwarnings("ignore:low reconstruction")  # two training steps
def test_resume_refuses_another_input_or_other_settings_and_writes_nothing(fitted, tmp_path):
    """Issue 35: `fit cube.obj --preset tiny --resume --out <a canyon run>` said "fit done" and left a report naming
    the cube beside the canyon's model. The run records its input's digest (contents, not the file's name) and the
    settings asked for (input.json); resume refuses anything else, saying what differs, before it writes."""
    import re
    import shutil

    import trimesh

    from sin3dm_lite.app.run_folder import INPUT_FILE

    def snapshot(folder):
        return {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}

    _, full = fitted
    run = tmp_path / "wall"
    shutil.copytree(full, run)
    assert json.loads((run / INPUT_FILE).read_text())["config"] == micro_config().to_dict()
    before = snapshot(run)
    for kwargs, words in [
        ({"source": "canyon"}, "was fitted to the example 'wall', not the example 'canyon'"),
        ({"preset": "tiny"}, "other settings (grid.resolution 24 there, 32 now;"),
        ({"preset": "small"}, "other settings (preset 'tiny' there, 'small' now;"),
        ({"seed": 3}, "other settings (seed 0 there, 3 now)"),
        ({"pbr": True}, "autoencoder.pbr False there, True now"),
    ]:
        with pytest.raises(Sin3DMInputError, match=re.escape(words)):
            Sin3DM.fit(**{"source": "wall", **kwargs}, out=run, resume=True, progress=False)
        assert snapshot(run) == before, kwargs  # nothing written, no lock left
    # a mesh file: its contents decide, not its name
    trimesh.creation.box(extents=(1.0, 0.6, 0.4)).export(tmp_path / "box.obj")
    trimesh.creation.box(extents=(1.0, 0.5, 0.4)).export(tmp_path / "other.obj")
    shutil.copy(tmp_path / "box.obj", tmp_path / "renamed.obj")
    cfg = micro_config().updated(**{"autoencoder.steps": 2, "diffusion.steps": 2})
    Sin3DM.fit(str(tmp_path / "box.obj"), preset=cfg, out=tmp_path / "box", progress=False)
    before = snapshot(tmp_path / "box")
    with pytest.raises(
        Sin3DMInputError,
        match="was fitted to '.*box.obj', not '.*other.obj'; resume it with that "
        "input, or fit '.*other.obj' into a new --out",
    ):
        Sin3DM.fit(str(tmp_path / "other.obj"), preset=cfg, out=tmp_path / "box", resume=True, progress=False)
    assert snapshot(tmp_path / "box") == before
    resumed = Sin3DM.fit(str(tmp_path / "renamed.obj"), preset=cfg, out=tmp_path / "box", resume=True, progress=False)
    assert resumed.report["autoencoder_steps"] == 2


def test_mesh_sizes_beyond_memory_are_refused_with_the_largest_that_fits(fitted, monkeypatch):
    """Issue 35: a huge texture or mesh resolution ran for minutes into gigabytes or an ArrayMemoryError; to_mesh
    (and `sample` before it makes a folder) refuses it at once, naming the most the free memory holds."""
    from sin3dm_lite.app import device
    from sin3dm_lite.app.sampling import EXPORT_BYTES_PER_TEXEL

    model, _ = fitted
    s = model.input_sample()
    with pytest.raises(Sin3DMInputError, match="resolution 100000 is too large: at most [0-9]+ here"):
        model.to_mesh(s, 0, resolution=100000)
    monkeypatch.setattr(device, "memory_available", lambda dev: 1 << 30)  # 1 GiB free: half of it for one export
    with pytest.raises(Sin3DMInputError, match="texture_size 4096 is too large: at most ([0-9]+) here") as e:
        model.to_mesh(s, 0, resolution=32, texture_size=4096)
    told = int(str(e.value).split("at most ")[1].split()[0])
    assert 1024 < told < ((1 << 29) // EXPORT_BYTES_PER_TEXEL) ** 0.5  # the grid's share comes off the texture's
    with pytest.raises(Sin3DMInputError, match="texture_size must be a whole number of at least 16, got 8"):
        model.to_mesh(s, 0, resolution=32, texture_size=8)


def test_checkpoints_are_written_once_per_step(tmp_path, monkeypatch):
    import re
    from pathlib import Path

    from sin3dm_lite.app import checkpoints
    from sin3dm_lite.files import OWNER

    writes = []
    real = checkpoints.save_torch  # every torch file: checkpoints (atomic_torch_save) and model.pt (write_model)

    def counted(obj, path):
        name = re.match(rf"^\.(.*)\.sin3dm-{OWNER}[^.]*\.tmp(.*)$", Path(path).name)  # the temporary's name
        writes.append(name[1] + name[4])
        return real(obj, path)

    monkeypatch.setattr(checkpoints, "save_torch", counted)
    cfg = micro_config().updated(checkpoint_every=20)  # 30 steps: at step 20, then the last one
    Sin3DM.fit("wall", preset=cfg, out=tmp_path / "run", progress=False)
    assert writes == ["autoencoder.pt"] * 2 + ["diffusion.pt"] * 2 + ["model.pt"]
    writes.clear()
    cfg = micro_config()  # every 10 steps: the last checkpoint is the last step, not written again
    Sin3DM.fit("wall", preset=cfg, out=tmp_path / "run10", progress=False)
    assert writes == ["autoencoder.pt"] * 3 + ["diffusion.pt"] * 3 + ["model.pt"]
    writes.clear()
    Sin3DM.fit("wall", preset=cfg, out=tmp_path / "run10", resume=True, progress=False)  # nothing left to train
    assert writes == ["model.pt"]


def test_run_folder_errors(fitted, tmp_path):
    _, run = fitted
    with pytest.raises(Sin3DMInputError, match="--resume"):
        Sin3DM.fit("wall", preset=micro_config(), out=run, progress=False)
    with pytest.raises(Sin3DMInputError, match="config.json"):
        Sin3DM.fit("wall", out=tmp_path / "nothing", resume=True, progress=False)
    with pytest.raises(Sin3DMInputError, match="no fitted model"):
        Sin3DM.load(tmp_path / "missing")
    with pytest.raises(Sin3DMInputError, match="neither a mesh file nor a built-in example"):
        Sin3DM.fit("no_such_example", preset=micro_config(), out=tmp_path / "x", progress=False)
    assert not (tmp_path / "x").exists()  # bad input leaves no folder behind


@pytest.mark.parametrize("resize", [(0, 1, 1), (-1, 1, 1), (np.nan, 1, 1), (100, 1, 1)])
def test_bad_resize_is_a_clear_error(fitted, resize):
    model, _ = fitted
    with pytest.raises(Sin3DMInputError, match="resize"):
        model.sample(1, resize=resize, progress=False)


def test_with_denoiser_samples_with_the_new_denoiser_and_its_config(fitted):
    from dataclasses import replace

    from sin3dm_lite.model.unet import TriplaneUNet

    model, _ = fitted
    eps = replace(model.config.diffusion, prediction="eps")
    other = TriplaneUNet(model.latent.channels, eps)
    twin = model.with_denoiser(other, eps)
    assert twin.denoiser is other and twin.config.diffusion.prediction == "eps"
    assert model.config.diffusion.prediction == "x0" and model.denoiser is not other  # the original is unchanged
    assert twin.decoder is model.decoder and twin.latent.xy.data_ptr() == model.latent.xy.data_ptr()  # shared
    assert twin.config.sampling == model.config.sampling and twin.report == model.report
    a = twin.sample(1, seed=2, progress=False)
    b = model.sample(1, seed=2, progress=False)
    assert a.triplane.resolution == b.triplane.resolution
    assert not torch.equal(a.triplane.xy, b.triplane.xy)


def _mean_distance(samples, latent) -> float:
    """Mean squared difference of each sample's planes from the input latent's."""
    return float(sum(((p - q) ** 2).mean() for p, q in zip(samples.triplane.planes, latent.planes)))


def test_diversity_knob_runs_from_the_input_to_pure_noise(fitted):
    model, _ = fitted
    assert model.config.sampling.diversity == 1.0
    zero = model.sample(2, seed=3, diversity=0.0, progress=False)
    for p, q in zip(zero.triplane.planes, model.latent.repeat(2).planes):
        torch.testing.assert_close(p, q)  # nothing regenerated: the input itself
    dist = {d: _mean_distance(model.sample(4, seed=3, diversity=d, progress=False), model.latent) for d in (0.05, 1.0)}
    assert dist[0.05] < dist[1.0], dist  # lowest setting closest to the input latent, highest farthest
    # 1.0 is the paper's unconditional sampling, exactly what the default gives
    a, b = model.sample(2, seed=7, progress=False), model.sample(2, seed=7, diversity=1.0, progress=False)
    for p, q in zip(a.triplane.planes, b.triplane.planes):
        torch.testing.assert_close(p, q)


def test_diversity_with_resize_starts_from_the_stretched_input(fitted):
    model, _ = fitted
    s = model.sample(1, resize=(1.5, 1.0, 1.0), diversity=0.0, progress=False)
    x, y, z = model.latent.resolution
    assert s.triplane.resolution == (round(1.5 * x), y, z)
    torch.testing.assert_close(s.triplane.yz, model.latent.yz)  # the yz plane does not change size


@pytest.mark.parametrize("diversity", [-0.1, 1.5, float("nan"), "high"])
def test_bad_diversity_is_a_clear_error(fitted, diversity):
    model, _ = fitted
    with pytest.raises(Sin3DMInputError, match="diversity"):
        model.sample(1, diversity=diversity, progress=False)


def test_sample_refuses_more_samples_than_fit_in_memory(fitted, monkeypatch):
    model, _ = fitted
    monkeypatch.setattr("sin3dm_lite.app.device.memory_available", lambda device: 64 << 20)  # 64 MiB free
    limit = model.max_samples()
    assert 1 <= limit < 10_000
    assert model.max_samples((2.0, 2.0, 2.0)) < limit  # bigger latents, fewer at once
    with pytest.raises(Sin3DMInputError, match=f"at most {limit}"):
        model.sample(limit + 1, progress=False)


def test_occupancy_of_samples_at_one_or_several_resolutions(fitted):
    model, _ = fitted
    s = model.input_sample()
    one = model.occupancy(s, 24)
    both = model.occupancy(s, [16, 24])
    assert len(one) == 1 and one[0].dtype == bool and one[0].any()
    np.testing.assert_array_equal(both[24][0], one[0])
    assert both[16][0].shape[0] == 16 and both[24][0].shape[0] == 24  # x is the longest axis of the wall


@pytest.mark.parametrize("sdf_value, expected", [(1.0, False), (-1.0, True)])
def test_occupancy_of_a_sample_without_surface_is_empty_or_full(fitted, monkeypatch, sdf_value, expected):
    """A diverged sample (no surface) scores as an empty or full box instead of stopping an evaluation."""
    from sin3dm_lite.generate.extract import marching_cubes

    model, _ = fitted
    s = model.input_sample()

    def no_surface(*args, **kwargs):  # what extract_mesh raises for such a sample
        marching_cubes(np.full((4, 4, 4), sdf_value, np.float32), s.aabb)

    monkeypatch.setattr(model, "to_mesh", no_surface)
    (grid,) = model.occupancy(s, 16)
    assert grid.shape[0] == 16 and grid.dtype == bool and (grid == expected).all()


def test_input_mesh_is_the_example_or_the_file_the_run_was_fitted_to(fitted, tmp_path):
    from sin3dm_lite.examples import build_example, write_example

    model, run = fitted
    assert len(model.input_mesh().faces) == len(build_example("wall").faces)  # an example: built again
    mesh_file = write_example("wall", tmp_path / "mine")  # a file of the user's: read again from where it was
    fitted_file = Sin3DM.fit(
        mesh_file, preset=micro_config().updated(**{"diffusion.steps": 2}), out=tmp_path / "run", progress=False
    )
    reloaded = Sin3DM.load(tmp_path / "run")
    assert reloaded.report["input_path"] == str(mesh_file.resolve())
    assert len(reloaded.input_mesh().faces) == len(fitted_file.input_mesh().faces) > 0
    for p in mesh_file.parent.iterdir():
        p.unlink()
    with pytest.raises(Sin3DMInputError, match="is gone.*--input MESH"):
        reloaded.input_mesh()


def test_settings_from_text_keep_their_kinds():
    """`fit --set` text becomes typed settings; a wrong name or kind is one clear error, not a crash in training."""
    from sin3dm_lite.data.config import parse_settings
    from sin3dm_lite.errors import Sin3DMInputError

    changes = parse_settings(
        [
            "diffusion.rollout=True",
            "diffusion.steps=1500",
            "sampling.diversity=0.5",
            "sampling.method=ddpm",
            "autoencoder.precision = fp32",
        ]
    )
    assert changes == {
        "diffusion.rollout": True,
        "diffusion.steps": 1500,
        "sampling.diversity": 0.5,
        "sampling.method": "ddpm",
        "autoencoder.precision": "fp32",
    }
    assert parse_settings(["diffusion.rollout=false"]) == {"diffusion.rollout": False}
    cfg = get_preset("small").updated(**{**changes, "sampling.diversity": 1})  # an integer is a number too
    assert cfg.diffusion.rollout is True and cfg.diffusion.steps == 1500 and cfg.sampling.diversity == 1
    # ... and stays a number: a rate given as 0 (``--set diffusion.latent_scale=0``) takes a fraction later
    assert isinstance(cfg.sampling.diversity, float) and cfg.updated(**{"sampling.diversity": 0.62})
    for bad, words in [
        ({"diffusion.steps": "many"}, "whole number"),
        ({"diffusion.rollout": 1}, "true or false"),
        ({"sampling.diversity": "high"}, "a number"),
        ({"diffusion.stepz": 3}, "unknown"),
    ]:
        with pytest.raises(Sin3DMInputError, match=words):
            get_preset("small").updated(**bad)
    with pytest.raises(Sin3DMInputError, match="SETTING=VALUE"):
        parse_settings(["diffusion.rollout"])


def test_every_setting_is_checked_against_its_range_where_a_config_is_made(tmp_path):
    """Issue 35: `--set autoencoder.steps=-5` trained to IoU 0, `diffusion.steps=0` and `sampling.diversity=5` were
    taken, `nosuch.key` was a KeyError. Every setting has a range (config.LIMITS), checked by `updated`, by `Config(...)`
    and by `fit` (a setting changed in place), with the range or the valid names in the one-line message."""
    from sin3dm_lite.data.config import LIMITS, Config, DiffusionConfig, SamplingConfig, _settings

    tiny = get_preset("tiny")
    assert set(_settings(tiny.to_dict())) == set(LIMITS)  # every setting has a rule
    for name in ("tiny", "small", "quick", "detail", "fine", "paper"):
        get_preset(name).check()  # the presets keep their own rules
    for bad, words in [
        ({"autoencoder.steps": -5}, "'autoencoder.steps' must be a whole number from 1 to"),
        ({"diffusion.steps": 0}, "'diffusion.steps' must be a whole number from 1 to"),
        ({"sampling.diversity": 5}, "'sampling.diversity' must be a number from 0 to 1, not 5"),
        ({"sampling.diversity": float("nan")}, "from 0 to 1"),
        ({"sampling.method": "euler"}, "one of 'ddim', 'ddpm'"),
        ({"autoencoder.decoder_kernel": 4}, "one of 1, 3, 5"),
        ({"diffusion.beta_start": 0.5}, "below diffusion.beta_end"),
        ({"sampling.steps": 5000}, "diffusion.timesteps"),
        ({"nosuch.key": 1}, "SECTION one of autoencoder, diffusion, grid, sampling"),
        ({"diffusion.stpes": 3}, "did you mean 'diffusion.steps'"),
        ({"diffusion.foo": 3}, "the diffusion settings are: base_channels"),
        ({"diffusion.steps.x": 3}, "unknown config setting"),
    ]:
        with pytest.raises(Sin3DMInputError, match=words):
            tiny.updated(**bad)
    with pytest.raises(Sin3DMInputError, match="'sampling.diversity' must be"):  # the Python API's own Config
        Config(sampling=SamplingConfig(diversity=5.0))
    with pytest.raises(Sin3DMInputError, match="'diffusion.steps' must be"):
        Config(diffusion=DiffusionConfig(steps=0))
    cfg = get_preset("tiny")
    cfg.autoencoder.steps = -5  # changed in place: fit checks before it writes anything
    with pytest.raises(Sin3DMInputError, match="'autoencoder.steps' must be"):
        Sin3DM.fit("wall", preset=cfg, out=tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_an_older_config_with_retired_settings_loads_without_them(tmp_path):
    """Settings of earlier versions (snapping's ``sampling.snap``, the fit's switches ``thin_parts``,
    ``rollout_switch``, ``thin_walls``, ``sampling.calibrate``; the mirror decoder, flips and crops at their off
    values) in an older run's config.json and model.pt are dropped as it loads; asked for by name they are unknown
    settings."""
    import shutil

    from sin3dm_lite.app.pretrained import pretrained_path

    run = tmp_path / "old"
    shutil.copytree(pretrained_path("wall_small"), run)
    d = json.loads((run / "config.json").read_text())
    want = Config.from_dict(d)
    d["sampling"] |= {"snap": 1.0, "snap_place": 0.3, "calibrate": True}
    d |= {"thin_parts": {"sampling.snap": 1.0}, "thin_walls": {}, "rollout_switch": {"diffusion.rollout": True}}
    d["autoencoder"]["mirror"], d["diffusion"]["flips"], d["diffusion"]["crop"] = False, "", 0
    old = Config.from_dict(d)
    assert old == want and "snap" not in old.to_json() and "thin" not in old.to_json()
    (run / "config.json").write_text(json.dumps(d))
    bundle = torch.load(run / "model.pt", weights_only=True)
    bundle["config"] = json.dumps(d)
    torch.save(bundle, run / "model.pt")
    model = Sin3DM.load(run)
    assert model.config == old and model.sample(1, steps=2, progress=False).triplane.batch == 1
    for name in ("sampling.snap", "thin_parts", "rollout_switch", "autoencoder.mirror", "diffusion.crop"):
        with pytest.raises(Sin3DMInputError, match=f"unknown config setting '{name}'"):
            want.updated(**{name: 1.0})


@pytest.mark.parametrize(
    "part, key, value", [("autoencoder", "mirror", True), ("diffusion", "flips", "xz"), ("diffusion", "crop", 8)]
)
def test_a_run_fitted_with_a_retired_experiment_is_refused_by_name(tmp_path, part, key, value):
    """A mirror decoder's weights decode wrongly through today's plain convolutions, and a denoiser trained on flipped
    or cropped latents is not the one today's code describes: such a run is refused, naming the setting."""
    import shutil

    from sin3dm_lite.app.pretrained import pretrained_path

    run = tmp_path / "old"
    shutil.copytree(pretrained_path("wall_small"), run)
    d = json.loads((run / "config.json").read_text())
    d[part][key] = value
    (run / "config.json").write_text(json.dumps(d))
    bundle = torch.load(run / "model.pt", weights_only=True)
    bundle["config"] = json.dumps(d)
    torch.save(bundle, run / "model.pt")
    with pytest.raises(Sin3DMInputError, match=f"{part}.{key}={value!r}.*no longer has"):
        Sin3DM.load(run)


def test_the_quick_preset_is_small_with_a_lighter_autoencoder():
    """`quick` changes only the autoencoder's cost, the denoiser's steps and the texture's size: same grid, latent,
    denoiser field and sampling otherwise."""
    small, quick = get_preset("small"), get_preset("quick")
    assert (
        quick.grid == small.grid and replace(quick.sampling, texture_size=small.sampling.texture_size) == small.sampling
    )
    assert quick.sampling.texture_size == small.sampling.texture_size // 2  # a quarter of the texels to bake
    assert quick.autoencoder.mlp_hidden < small.autoencoder.mlp_hidden
    assert 0 < quick.autoencoder.color_points < quick.autoencoder.points_per_step  # colour on a share of the points
    assert (
        quick.autoencoder.points_per_step * quick.autoencoder.steps
        < small.autoencoder.points_per_step * small.autoencoder.steps
    )
    assert replace(quick.diffusion, steps=small.diffusion.steps) == small.diffusion


def test_plot_beside_input_draws_each_shape_at_the_inputs_voxel_size_decoded_for_the_picture(fitted, monkeypatch):
    model, _ = fitted
    samples = model.sample(2, resize=(1.5, 1.0, 1.0), seed=0, progress=False)
    asked = []
    to_mesh = Sin3DM.to_mesh
    monkeypatch.setattr(
        Sin3DM, "to_mesh", lambda self, s, i, **kw: asked.append(kw["resolution"]) or to_mesh(self, s, i, **kw)
    )
    fig = model.plot_beside_input(samples, 16, ["a", "b"])
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert titles == ["input", "a", "b"]
    widths = [ax.images[0].get_array().shape[1] for ax in fig.axes[:3]]  # front views: x across
    assert widths[1] == widths[2] == round(1.5 * widths[0])  # the longer samples look longer
    assert asked == [32, 48, 48]  # twice the picture's voxels, not the export's mesh resolution


def test_the_finer_presets_are_their_coarse_ones_at_96_voxels_with_the_wider_field_and_the_rollout():
    """`detail` is `small`, `fine` is `quick`, each at 96 voxels with 4 ResBlocks, the cross-plane rollout, 1,000
    autoencoder and 1,000 denoiser steps (in bf16 where it is faster), sampled from pure noise: the default's choice
    for thin parts; `fine`, for CPUs without fast bf16, on denoiser batches of 4."""
    finer = {
        "grid.resolution": 96,
        "autoencoder.steps": 1000,
        "diffusion.n_resblocks": 4,
        "diffusion.rollout": True,
        "diffusion.steps": 1000,
        "diffusion.precision": "auto",
        "sampling.diversity": 1.0,
    }
    assert get_preset("small").updated(name="detail", **finer) == get_preset("detail")
    assert get_preset("quick").updated(name="fine", **finer, **{"diffusion.batch_size": 4}) == get_preset("fine")


def test_a_fit_with_a_unit_latent_scale_records_the_number_and_resumes_to_the_same_model(tmp_path, monkeypatch):
    """``diffusion.latent_scale=0`` (``detail``'s): the fit records the number it found in the run's config, so a
    loaded run samples in the same units; a fit interrupted while training the denoiser finds the same number
    again and resumes to the same model."""
    from sin3dm_lite.model import diffusion

    cfg = micro_config().updated(**{"diffusion.latent_scale": 0})
    full = Sin3DM.fit("wall", preset=cfg, out=tmp_path / "full", progress=False)
    scale = full.config.diffusion.latent_scale
    assert scale > 1.5  # the tanh latent's values spread well under 1
    loaded = Sin3DM.load(tmp_path / "full")
    assert loaded.config.diffusion.latent_scale == scale == loaded.denoiser.cfg.latent_scale
    samples = loaded.sample(2, seed=0, progress=False)
    assert max(float(p.abs().max()) for p in samples.triplane.planes) <= 1.0  # in the encoder's units

    real_step = diffusion.DiffusionTrainer.step

    def step_then_ctrl_c(self):
        loss = real_step(self)
        if self.step_count == 17:
            os.kill(os.getpid(), signal.SIGINT)
        return loss

    monkeypatch.setattr(diffusion.DiffusionTrainer, "step", step_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        Sin3DM.fit("wall", preset=cfg, out=tmp_path / "cut", progress=False)
    monkeypatch.setattr(diffusion.DiffusionTrainer, "step", real_step)
    resumed = Sin3DM.fit("wall", out=tmp_path / "cut", resume=True, progress=False)
    assert resumed.config.diffusion.latent_scale == scale
    a = torch.load(tmp_path / "full" / "model.pt", weights_only=True)
    b = torch.load(tmp_path / "cut" / "model.pt", weights_only=True)
    assert all(torch.equal(a["denoiser"][k], b["denoiser"][k]) for k in a["denoiser"])

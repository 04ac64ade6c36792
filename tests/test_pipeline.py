"""Sin3DM end to end on a very small setting: run folder, report, save/load, resume, sampling, meshes."""

import json
import os
import signal
from dataclasses import replace

import numpy as np
import pytest
import torch

from sin3dm_lite.app.device import cpu_bf16_share, resolved_precision
from sin3dm_lite.auto.fit_policy import thin_parts_switch
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

    writes = []
    real = checkpoints.save_torch  # every torch file: checkpoints (atomic_torch_save) and model.pt (write_model)

    def counted(obj, path):
        writes.append(re.sub(r"^\.(.*)\.sin3dm-\d+-[^.]*\.tmp(.*)$", r"\1\2", Path(path).name))  # the temporary's name
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


@pytest.mark.filterwarnings("ignore:low reconstruction")  # two training steps
def test_a_fit_of_a_thin_shape_switches_to_the_thin_part_settings(tmp_path, capsys, monkeypatch):
    """A preset with thin_parts refits the grid at the finer settings when the shape is mostly thin parts, says so,
    and records the settings it used, so that the run folder loads and resumes as what it is."""
    from sin3dm_lite.app import fitting
    from sin3dm_lite.data.grid import load_grid

    cfg = micro_config().updated(
        **{
            "name": "small",
            "grid.resolution": 32,
            "autoencoder.steps": 2,
            "diffusion.steps": 2,
            "thin_parts": {"grid.resolution": 40, "diffusion.n_resblocks": 3},
        }
    )
    model = Sin3DM.fit("tiles", preset=cfg, out=tmp_path / "tiles", progress=True)
    out = capsys.readouterr().out
    assert "lies in parts under ~5 voxels thick at 32 voxels" in out and "fitting at 40 voxels" in out
    assert "--no-thin-switch" in out
    saved = Config.from_dict(json.loads((tmp_path / "tiles" / "config.json").read_text()))
    assert saved.name == "small+thin" and saved.grid.resolution == 40 and saved.diffusion.n_resblocks == 3
    assert saved.thin_parts == {} and model.config.grid.resolution == 40
    assert max(load_grid(tmp_path / "tiles" / "grid.npz").shape) == 40
    switch = json.loads((tmp_path / "tiles" / "report.json").read_text())["thin_parts_switch"]
    assert switch["from"] == "small" and switch["resolution"] == 32 and switch["thin_share"] > 0.2
    assert Sin3DM.load(tmp_path / "tiles").config.grid.resolution == 40
    # a resumed run (here with nothing left to train) keeps the record of its switch
    resumed = Sin3DM.fit("tiles", out=tmp_path / "tiles", resume=True, progress=False)
    assert resumed.report["thin_parts_switch"] == switch and resumed.config.name == "small+thin"
    assert json.loads((tmp_path / "tiles" / "report.json").read_text())["thin_parts_switch"] == switch

    # the same settings without thin_parts, or on a shape with few thin parts, keep the preset's grid; a fit
    # without the switch says what fit_policy.thin_parts_hint says (quick's hint; None at these 32 voxels)
    monkeypatch.setattr(fitting, "thin_parts_hint", lambda c, g, thin: f"HINT {c.name} {thin:.2f}")
    model = Sin3DM.fit("tiles", preset=cfg.updated(thin_parts={}), out=tmp_path / "kept", progress=True)
    out = capsys.readouterr().out
    assert "fitting at" not in out and f"[fit] HINT small {model.report['thin_share']:.2f}" in out
    assert "GRIDHINT" not in out  # no switch, no hint
    assert model.config.name == "small" and model.report["thin_parts_switch"] is None
    assert max(load_grid(tmp_path / "kept" / "grid.npz").shape) == 32
    grid = load_grid(tmp_path / "kept" / "grid.npz")
    assert thin_parts_switch(cfg, grid, thin=0.1) is None
    assert thin_parts_switch(cfg, grid, thin=0.5).grid.resolution == 40


@pytest.mark.filterwarnings("ignore:low reconstruction")  # a few training steps
@pytest.mark.parametrize("copies", [True, False])
def test_a_shape_of_thin_walls_tries_the_wider_field_and_drops_it_if_it_copies(tmp_path, capsys, monkeypatch, copies):
    """quick's thin-walls switch (Config.thin_walls): the wider denoiser trains to the check step, its samples from
    pure noise are looked at; copies send the fit back to the narrower denoiser, trained from its first step, and
    the run folder holds that one; varied samples keep the wider one. The outcome is recorded, and a resumed fit
    does not check again."""
    from sin3dm_lite.app import fitting
    from sin3dm_lite.auto import fit_policy

    monkeypatch.setattr(fit_policy, "THIN_WALLS_SHARE", 0.0)  # the tiles at 24 voxels count as thin walls here
    monkeypatch.setattr(fit_policy, "WIDE_FIELD_CHECK_STEP", 3)
    spreads = []
    monkeypatch.setattr(fitting, "are_copies", lambda d: spreads.append(d) or copies)
    cfg = micro_config().updated(
        **{
            "name": "quick",
            "autoencoder.steps": 2,
            "diffusion.steps": 6,
            "thin_parts": {"sampling.diversity": 1.0, "diffusion.batch_size": 3},
            "thin_walls": {
                "diffusion.n_resblocks": 3,
                "diffusion.base_channels": 8,
                "diffusion.batch_size": 2,
                "autoencoder.decoder_kernel": 3,
                "autoencoder.residual_planes": True,
            },
        }
    )
    run = tmp_path / "tiles"
    model = Sin3DM.fit("tiles", preset=cfg, out=run, progress=True)
    out = capsys.readouterr().out
    assert "a field of 13 latent texels instead of 9" in out and "after 3 steps" in out
    assert len(spreads) == 1 and spreads[0] > 0.0  # one look: the samples' distance from the input (untrained: far)
    check = model.report["thin_parts_switch"]["wide_field"]
    # back to the thin-part switch's narrower denoiser: the preset's blocks, the switch's batches (not the preset's)
    # ... the denoiser's settings only: the autoencoder, 3×3 plane convolutions, is trained by then and stays
    assert check["undo"] == {"diffusion.n_resblocks": 2, "diffusion.base_channels": 16, "diffusion.batch_size": 3}
    assert check["check"] == {"step": 3, "distance": spreads[0], "copies": copies}
    assert "plane convolutions are 3x3 instead of 5x5" in out
    saved = Config.from_dict(json.loads((run / "config.json").read_text()))
    assert saved.autoencoder.decoder_kernel == 3 and saved.autoencoder.residual_planes
    if copies:
        assert "are copies of the input" in out and "trained again with the narrower field" in out
        assert saved.name == "quick+thin" and (saved.diffusion.n_resblocks, saved.diffusion.base_channels) == (2, 16)
        assert saved.diffusion.batch_size == 3
    else:
        assert "it keeps its field" in out
        assert saved.name == "quick+walls" and (saved.diffusion.n_resblocks, saved.diffusion.base_channels) == (3, 8)
        assert saved.diffusion.batch_size == 2
    assert model.config == saved
    losses = json.loads((run / "losses.json").read_text())["diffusion"]["loss"]
    assert len(losses) == 6  # the kept denoiser's, all its steps
    loaded = Sin3DM.load(run)
    assert loaded.config == saved and loaded.sample(1, seed=0, progress=False).triplane.planes[0].shape[0] == 1
    monkeypatch.setattr(fitting, "are_copies", lambda d: pytest.fail("a resumed fit checked again"))
    resumed = Sin3DM.fit("tiles", out=run, resume=True, progress=False)
    assert resumed.config == saved and resumed.report["thin_parts_switch"]["wide_field"] == check


@pytest.mark.filterwarnings("ignore:low reconstruction")  # a few training steps
def test_a_denoiser_the_user_chose_keeps_the_thin_walls_free_planes_without_a_trial(tmp_path, capsys, monkeypatch):
    """A denoiser setting the user sets drops Config.thin_walls' wider field (nothing to try: the fit never looks
    at samples from pure noise) but not what keeps a thin wall's windows: the free planes are trained and saved."""
    from sin3dm_lite.app import fitting
    from sin3dm_lite.auto import fit_policy

    monkeypatch.setattr(fit_policy, "THIN_WALLS_SHARE", 0.0)  # the tiles at 24 voxels count as thin walls here
    monkeypatch.setattr(fitting, "are_copies", lambda d: pytest.fail("no wider field to try"))
    walls = {"diffusion.n_resblocks": 3, "diffusion.base_channels": 8, "autoencoder.residual_planes": True}
    cfg = micro_config().updated(
        **{"name": "quick", "autoencoder.steps": 2, "diffusion.steps": 4, "thin_parts": {"sampling.diversity": 1.0}},
        thin_walls=walls,
    )
    cfg = cfg.updated(**{"diffusion.n_resblocks": 1})  # the user's denoiser
    assert cfg.thin_walls == {"autoencoder.residual_planes": True}
    model = Sin3DM.fit("tiles", preset=cfg, out=tmp_path / "tiles", progress=True)
    out = capsys.readouterr().out
    assert "free planes" in out and "a field of" not in out
    assert "wide_field" not in model.report["thin_parts_switch"]
    saved = Sin3DM.load(tmp_path / "tiles").config
    assert saved.name == "quick+walls" and saved.autoencoder.residual_planes
    assert (saved.diffusion.n_resblocks, saved.diffusion.base_channels) == (1, cfg.diffusion.base_channels)
    assert model.report["diffusion_steps"] == 4


def test_small_switches_to_exactly_the_detail_settings():
    """The 'detail' preset is what small switches to (one source of truth), and it does not switch again."""
    small, detail = get_preset("small"), get_preset("detail")
    switched = small.for_thin_parts()
    assert switched.updated(name="detail") == detail and switched.name == "small+thin"
    assert detail.thin_parts == {} and detail.for_thin_parts() == detail
    # the light preset for CPUs without bf16 switches to a denoiser batch of 6: the same grid and networks
    quick = get_preset("quick")
    thin = quick.updated(**{"diffusion.batch_size": 6}, name="quick+thin", thin_parts={}, thin_walls={})
    assert quick.for_thin_parts() == thin
    # ... and on a shape of thin walls only, a wider denoiser field too (on trial: fitting.FitStages.denoise)
    walls = thin.updated(
        **{
            "diffusion.n_resblocks": 4,
            "diffusion.base_channels": 16,
            "diffusion.steps": 1500,
            "diffusion.batch_size": 4,
            "autoencoder.residual_planes": True,
        },
        name="quick+walls",
    )
    assert quick.for_thin_parts(walls=True) == walls
    # small's thin walls: not detail's grid (which copies them and closes their windows) but quick's switches on its
    # own grid and autoencoder, replacing the thin-part settings; a denoiser the user picks drops them (detail again)
    mine = small.for_thin_parts(walls=True)
    assert mine.name == "small+walls" and mine.grid == small.grid and mine.diffusion == walls.diffusion
    assert mine.sampling == replace(walls.sampling, texture_size=small.sampling.texture_size)
    assert mine.autoencoder == replace(small.autoencoder, residual_planes=True) and mine.sampling.diversity == 0.7
    assert mine.diffusion.rollout is False and small.for_thin_parts() == switched
    assert small.updated(**{"diffusion.steps": 3000}).for_thin_parts(walls=True).grid.resolution == 96
    # the rollout switch: small has it, what already has the rollout (detail, paper) or a light CPU (quick) does not
    assert small.rollout_switch and not detail.rollout_switch and not get_preset("quick").rollout_switch
    rolled = small.for_rollout()
    assert rolled.diffusion.rollout and rolled.diffusion.steps == 1250 and rolled.rollout_switch == {}
    assert rolled.grid == small.grid and rolled.thin_parts == small.thin_parts and detail.for_rollout() == detail
    assert small.updated(**{"diffusion.rollout": False}).rollout_switch == {}  # chosen by hand: kept
    mine = small.updated(**{"diffusion.steps": 3000}).for_rollout()  # the user's steps survive the switch
    assert mine.diffusion.rollout and mine.diffusion.steps == 3000
    # a setting the user changes is never undone by the switch; the others still switch
    mine = small.updated(**{"diffusion.n_resblocks": 6}).for_thin_parts()
    assert mine.diffusion.n_resblocks == 6 and mine.grid.resolution == 96


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
    for name in ("tiny", "small", "quick", "detail", "paper"):
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
        ({"thin_parts": {"grid.resolution": 8}}, r"thin_parts\['grid.resolution'\] must be"),
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
    """Settings of earlier versions (config.RETIRED: snapping's ``sampling.snap`` and ``sampling.snap_place``) in an
    older run's config.json and model.pt, in its sampling section or in a switch, are dropped as it loads; asked for
    by name they are unknown settings."""
    import shutil

    from sin3dm_lite.app.pretrained import pretrained_path
    from sin3dm_lite.data.config import RETIRED

    assert {"sampling.snap", "sampling.snap_place"} <= RETIRED
    run = tmp_path / "old"
    shutil.copytree(pretrained_path("wall_small"), run)
    d = json.loads((run / "config.json").read_text())
    want = Config.from_dict(d)
    d["sampling"] |= {"snap": 1.0, "snap_place": 0.3}
    d["thin_parts"] = {"sampling.snap": 1.0, "diffusion.batch_size": 6}
    d["thin_walls"] = {"sampling.snap_place": 0.3}
    old = Config.from_dict(d)
    assert old == replace(want, thin_parts={"diffusion.batch_size": 6}) and "snap" not in old.to_json()
    (run / "config.json").write_text(json.dumps(d))
    bundle = torch.load(run / "model.pt", weights_only=True)
    bundle["config"] = json.dumps(d)
    torch.save(bundle, run / "model.pt")
    model = Sin3DM.load(run)
    assert model.config == old and model.sample(1, steps=2, progress=False).triplane.batch == 1
    with pytest.raises(Sin3DMInputError, match="unknown config setting 'sampling.snap'"):
        want.updated(**{"sampling.snap": 1.0})


@pytest.mark.filterwarnings("ignore:low reconstruction")  # two training steps
def test_a_slow_fit_on_a_cpu_without_bf16_suggests_the_quick_preset(tmp_path, capsys, monkeypatch):
    """A paper-width autoencoder runs in fp32 where bf16 is not native: the fit says how long and names `quick`.

    The hint follows the autoencoder's cost, not the preset's name: small, its thin-part switch and detail get it,
    quick, tiny and a small with a short autoencoder do not, and nobody gets it where bf16 is native."""
    from sin3dm_lite.auto import fit_policy

    monkeypatch.setattr(fit_policy, "bf16_is_fast", lambda device: False)
    for name in ("small", "detail", "paper"):
        assert "--preset quick" in fit_policy.quick_hint(get_preset(name), "cpu"), name
    assert "about 20 minutes" in fit_policy.quick_hint(get_preset("small"), "cpu")  # 2,000 steps of 0.61 s
    # a shape of one colour trains half an autoencoder; quick's colour head sees 2,048 of its 4,096 points
    assert "about 10 minutes" in fit_policy.quick_hint(get_preset("small"), "cpu", one_color=True)
    quick = fit_policy.fp32_autoencoder_minutes(get_preset("quick"))
    assert quick == pytest.approx(1000 * 0.165 / 60, rel=0.02)
    assert fit_policy.fp32_autoencoder_minutes(get_preset("quick"), one_color=True) == pytest.approx(
        quick * 0.55, rel=0.02
    )
    assert "--preset quick" in fit_policy.quick_hint(get_preset("small").for_thin_parts(), "cpu")
    for cfg in (get_preset("quick"), get_preset("tiny"), get_preset("small").updated(**{"autoencoder.steps": 500})):
        assert fit_policy.quick_hint(cfg, "cpu") is None, cfg.name
    # the fit prints it (a micro fit priced like small's), and the two-thread opt-in where the policy chose one
    from sin3dm_lite.app import threads

    monkeypatch.setattr(fit_policy, "fp32_autoencoder_minutes", lambda cfg, one_color=False: 20.0)
    monkeypatch.setattr(threads, "APPLIED", {"OMP_WAIT_POLICY": "PASSIVE", "OMP_NUM_THREADS": "1"})
    monkeypatch.setattr(threads, "usable_cores", lambda: 2)
    cfg = micro_config().updated(**{"name": "small", "autoencoder.steps": 2, "diffusion.steps": 2})
    Sin3DM.fit("canyon", preset=cfg, out=tmp_path / "fp32", device="cpu", progress=True)
    out = capsys.readouterr().out
    assert "--preset quick" in out and "[fit] one CPU thread" in out and "SIN3DM_THREADS=2" in out
    monkeypatch.setattr(fit_policy, "bf16_is_fast", lambda device: True)
    assert fit_policy.quick_hint(get_preset("small"), "cpu") is None  # native bf16: small is fast enough


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


def test_flip_augmentation_fits_with_a_mirror_decoder_and_refuses_without(tmp_path):
    from sin3dm_lite.model.autoencoder import MirrorConv2d

    cfg = micro_config().updated(**{"diffusion.flips": "xz"})
    with pytest.raises(Sin3DMInputError, match="autoencoder.mirror=true"):
        Sin3DM.fit("wall", preset=cfg, out=tmp_path / "plain", progress=False)
    with pytest.raises(Sin3DMInputError, match="PBR"):
        Sin3DM.fit(
            "wall", preset=cfg.updated(**{"autoencoder.mirror": True}), out=tmp_path / "pbr", pbr=True, progress=False
        )
    assert not (tmp_path / "plain").exists() and not (tmp_path / "pbr").exists()  # refused before writing
    run = tmp_path / "mirror"
    Sin3DM.fit("wall", preset=cfg.updated(**{"autoencoder.mirror": True}), out=run, progress=False)
    model = Sin3DM.load(run)
    assert model.config.diffusion.flips == "xz" and isinstance(model.decoder.geo_blocks[1].conv1, MirrorConv2d)
    s = model.sample(2, seed=0, progress=False)
    assert s.triplane.batch == 2 and all(torch.isfinite(p).all() for p in s.triplane.planes)


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

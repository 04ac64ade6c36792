"""Triplane autoencoder: shapes, the loss, fitting, exact resume."""

import dataclasses
import io
import pickle

import numpy as np
import pytest
import torch

from sin3dm_lite.data.config import AutoencoderConfig
from sin3dm_lite.evaluate.metrics import reconstruction_metrics
from sin3dm_lite.model.autoencoder import (
    AutoencoderTrainer,
    TriplaneDecoder,
    TriplaneEncoder,
    sdf_loss,
)
from sin3dm_lite.model.decode import reconstructed_grid
from sin3dm_lite.model.triplane import Triplane

from .conftest import tiny_ae_cfg


def test_encoder_planes_have_half_resolution_and_tanh_range():
    enc = TriplaneEncoder(AutoencoderConfig())
    x = torch.randn(1, 4, 16, 8, 24)
    tp = enc(x)
    assert tp.xy.shape == (1, 12, 8, 4) and tp.xz.shape == (1, 12, 8, 12) and tp.yz.shape == (1, 12, 4, 12)
    for p in tp.planes:
        assert p.abs().max() < 1
    vol = enc.volume(x)
    assert vol.shape == (1, 12, 8, 4, 12)
    # axis pooling is a plain mean of the volume
    torch.testing.assert_close(tp.xy, TriplaneEncoder.squash(vol.mean(4)))


@pytest.mark.parametrize("shape", [(1, 4, 16, 8, 24), (2, 4, 13, 10, 7), (1, 9, 6, 6, 6)])
def test_encoder_planes_are_the_volume_averaged_along_each_axis_with_the_same_gradients(shape):
    """forward computes each plane as a 2D convolution of the grid's averages, never building the volume: the
    planes and the weights' gradients must be those of the 3D convolution averaged (odd sizes and PBR's 9
    channels too)."""
    torch.manual_seed(0)
    enc = TriplaneEncoder(AutoencoderConfig(pbr=shape[1] == 9), color_channels=shape[1] - 1)
    x = torch.randn(*shape)
    vol = enc.volume(x)
    want = [TriplaneEncoder.squash(vol.mean(axis)) for axis in (4, 3, 2)]
    got = enc(x).planes
    for a, b in zip(got, want):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)
    grads = [
        torch.autograd.grad(sum((p * w).sum() for p, w in zip(planes, (1, 2, 3))), list(enc.parameters()))
        for planes in (got, want)
    ]
    for a, b in zip(*grads):
        torch.testing.assert_close(a, b, atol=1e-4, rtol=1e-4)


def test_the_grids_averages_are_computed_once_per_grid_and_again_when_it_changes():
    """A fit feeds the encoder the same grid at every step, so the grid's averages (the encoder's input taps) are
    kept: the same tensors on a second call, the same planes; a grid changed in place, or another grid, gets new
    ones (what the planes then are checked against the 3D convolution); a pickled encoder leaves them behind."""
    torch.manual_seed(0)
    enc = TriplaneEncoder(AutoencoderConfig())
    x = torch.randn(1, 4, 10, 6, 8)
    first = enc(x).planes
    taps = enc.taps(x)
    assert all(a is b for a, b in zip(taps, enc.taps(x)))  # kept
    assert all(torch.equal(a, b) for a, b in zip(first, enc(x).planes))
    for changed in (x.mul_(2), torch.randn(1, 4, 10, 6, 8)):  # in place (version counter), and a new tensor
        want = [TriplaneEncoder.squash(enc.volume(changed).mean(axis)) for axis in (4, 3, 2)]
        assert not any(a is b for a, b in zip(taps, enc.taps(changed)))
        for a, b in zip(enc(changed).planes, want):
            torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)
    needs_grad = torch.randn(1, 4, 10, 6, 8, requires_grad=True)  # not a constant: not kept (nor its graph)
    enc.taps(needs_grad)
    assert enc._taps[0]() is not needs_grad
    assert "_taps" not in pickle.loads(pickle.dumps(enc)).__dict__


def test_decoder_blocks_start_as_their_shortcut_and_query_shapes():
    cfg = AutoencoderConfig(decoder_channels=16, mlp_hidden=32)
    dec = TriplaneDecoder(cfg, threshold=0.1)
    tp = Triplane.randn(2, 12, (6, 5, 7))
    prep = dec.prepare(tp)
    torch.testing.assert_close(prep.geo.xy, dec.geo_blocks[0].skip(tp.xy[:, :4]))  # zero-initialised second conv
    sdf, col = dec.query(prep, torch.rand(2, 50, 3) * 2 - 1)
    assert sdf.shape == (2, 50) and col.shape == (2, 50, 3)
    assert col.min() >= 0 and col.max() <= 1


def test_sdf_loss_weights_towards_and_away_from_the_surface():
    thr = 1.0
    gt = torch.tensor([0.5])
    # prediction closer to the surface: weight 1.5; further away: 0.5; across the surface: 1.5
    assert sdf_loss(torch.tensor([0.3]), gt, thr).item() == pytest.approx(1.5 * 0.2)
    assert sdf_loss(torch.tensor([0.7]), gt, thr).item() == pytest.approx(0.5 * 0.2)
    assert sdf_loss(torch.tensor([-0.5]), gt, thr).item() == pytest.approx(1.5 * 1.0)
    # beyond the truncation band any value of the right sign is correct
    assert sdf_loss(torch.tensor([3.0]), torch.tensor([1.0]), thr).item() == 0


@pytest.mark.parametrize("use_encoder", [True, False])
def test_tiny_fit_reduces_loss_and_reconstructs(box_grid, use_encoder):
    tr = AutoencoderTrainer(box_grid, tiny_ae_cfg(use_encoder=use_encoder, steps=150), seed=0)
    tr.run(progress=False)
    h = tr.history["loss"]
    assert len(h) == 150
    assert np.mean(h[-10:]) < 0.5 * np.mean(h[:10])
    rec = reconstructed_grid(tr.model.decoder, tr.latent(), box_grid)
    m = reconstruction_metrics(rec, box_grid)
    keys = {"sign_accuracy", "occupancy_iou", "occupancy_iou_quarter_voxel", "color_l1", "color_psnr"}
    assert set(m) == keys | {"color_psnr_surface"}
    assert m["occupancy_iou"] > 0.8 and m["sign_accuracy"] > 0.9
    assert m["color_l1"] < 0.25
    # the decoded box_grid: same box as the input, signs as the metrics counted them
    assert rec.shape == box_grid.shape and rec.color.shape == box_grid.color.shape and rec.name == "reconstruction"
    np.testing.assert_array_equal(rec.aabb, box_grid.aabb)
    assert rec.threshold == box_grid.threshold and len(rec.points) == 0 and len(box_grid.points) > 0
    assert np.mean((rec.sdf < 0) == (box_grid.sdf < 0)) == pytest.approx(m["sign_accuracy"])


def test_fit_autoencoder_is_the_trainer_run_to_the_end(box_grid):
    from sin3dm_lite.model.autoencoder import fit_autoencoder

    cfg = tiny_ae_cfg(steps=6)
    model, h0, history = fit_autoencoder(box_grid, cfg, seed=2, progress=False)
    tr = AutoencoderTrainer(box_grid, cfg, seed=2)
    tr.run(progress=False)
    assert history == tr.history and len(history["loss"]) == 6
    for a, b in zip(h0.planes, tr.latent().planes):
        assert torch.equal(a, b)


def test_auto_decoder_planes_train_at_their_own_learning_rates(box_grid):
    tr = AutoencoderTrainer(box_grid, tiny_ae_cfg(use_encoder=False, lr_geo=1e-3, lr_tex=5e-3), seed=0)
    geo_group, tex_group = tr.optimizer.param_groups
    raw = tr.model
    assert geo_group["lr"] == 1e-3 and tex_group["lr"] == 5e-3
    assert all(any(p is q for q in geo_group["params"]) for p in raw.raw_geo.parameters())
    assert all(any(p is q for q in tex_group["params"]) for p in raw.raw_tex.parameters())
    h = raw.encode()
    assert h.channels == 12
    torch.testing.assert_close(h.xz[:, 4:], TriplaneEncoder.squash(raw.raw_tex["xz"]))  # texture channels last


@pytest.mark.parametrize("held", [False, True])  # True: a shape of one colour, its texture half held
def test_resume_is_bit_identical(box_grid, held):
    grid, cfg = one_colour(box_grid) if held else box_grid, tiny_ae_cfg(steps=20)
    full = AutoencoderTrainer(grid, cfg, seed=3)
    full.run(progress=False)
    assert (full.single_color is not None) is held

    part = AutoencoderTrainer(grid, cfg, seed=3)
    part.run(until_step=8, progress=False)
    buf = io.BytesIO()
    torch.save(part.state_dict(), buf)
    buf.seek(0)
    resumed = AutoencoderTrainer(grid, cfg, seed=3)
    resumed.load_state_dict(torch.load(buf, weights_only=True))
    assert resumed.step_count == 8
    resumed.run(progress=False)
    assert resumed.step_count == 20
    for a, b in zip(full.model.state_dict().values(), resumed.model.state_dict().values()):
        assert torch.equal(a, b)
    assert full.history == resumed.history


def test_reconstruction_metrics_on_a_known_shift(box_grid):
    # a reconstruction whose surface sits 0.2 voxel inside the input's: only voxels within 0.2 voxel flip
    shifted = dataclasses.replace(box_grid, sdf=box_grid.sdf + 0.2 * box_grid.voxel_size)
    m = reconstruction_metrics(shifted, box_grid)
    flipped = ((box_grid.sdf < 0) & (box_grid.sdf >= -0.2 * box_grid.voxel_size)).sum()
    assert flipped > 0
    assert m["occupancy_iou"] == pytest.approx(1 - flipped / (box_grid.sdf < 0).sum())
    assert m["occupancy_iou_quarter_voxel"] == 1.0
    assert m["color_l1"] == 0 and m["color_psnr"] == pytest.approx(120)


def test_the_surface_colour_psnr_counts_only_the_colour_a_baked_texture_shows(box_grid):
    """color_psnr_surface judges the voxels within half a voxel of the input surface; colour wrong only further
    off it (where the band spreads a sharp pattern's edges) lowers color_psnr, not it; colour wrong at the
    surface lowers both."""
    off = np.abs(box_grid.sdf) >= 0.5 * box_grid.voxel_size
    band = np.abs(box_grid.sdf) < box_grid.threshold
    assert (band & ~off).any() and (band & off).any()
    away = dataclasses.replace(box_grid, color=np.where(off[..., None], 1 - box_grid.color, box_grid.color))
    m = reconstruction_metrics(away, box_grid)
    assert m["color_psnr_surface"] == pytest.approx(120) and m["color_psnr"] < 20
    at = dataclasses.replace(box_grid, color=np.where(off[..., None], box_grid.color, 1 - box_grid.color))
    m = reconstruction_metrics(at, box_grid)
    assert m["color_psnr_surface"] < 20 and m["color_psnr"] < 30


def one_colour(grid, rgb=(0.2, 0.5, 0.7)):
    """``grid`` painted one colour: every band voxel and training point ``rgb``."""
    out = dataclasses.replace(grid)
    band = np.abs(out.sdf) < out.threshold
    out.color = np.where(band[..., None], np.float32(rgb), np.float32(0)).astype(np.float32)
    out.point_color = np.broadcast_to(np.float32(rgb), out.point_color.shape).copy()
    return out


@pytest.mark.parametrize("use_encoder", [True, False])
def test_a_shape_of_one_colour_trains_its_geometry_only_and_decodes_its_colour_exactly(box_grid, use_encoder):
    """A mesh without colour (the default grey) or of one plain colour: the texture half is not trained (about
    half an autoencoder step), decodes that colour at every point, and the latent's texture channels are zero; the
    geometry trains as before. A grid of varied colour (``box_grid``) trains both halves."""
    grey = one_colour(box_grid)
    np.testing.assert_allclose(grey.single_color(), [0.2, 0.5, 0.7], atol=1e-6)
    assert box_grid.single_color() is None
    cfg = tiny_ae_cfg(use_encoder=use_encoder, steps=150)
    tr = AutoencoderTrainer(grey, cfg, seed=0)
    held = [p for p in tr.model.param_groups()[1]]
    before = [p.detach().clone() for p in held]
    tr.run(progress=False)
    assert all(torch.equal(a, b) for a, b in zip(before, held)) and not any(p.requires_grad for p in held)
    assert set(tr.history["color"]) == {0.0}
    h = tr.latent()
    assert all(torch.equal(p[:, 4:], torch.zeros_like(p[:, 4:])) for p in h.planes)
    rec = reconstructed_grid(tr.model.decoder, h, grey)
    m = reconstruction_metrics(rec, grey)
    assert m["occupancy_iou"] > 0.8 and m["color_l1"] < 1e-4
    points = torch.rand(1, 500, 3) * 2 - 1
    rgb = tr.model.decoder.query_color(tr.model.decoder.prepare(h), points)
    torch.testing.assert_close(rgb, torch.tensor([0.2, 0.5, 0.7]).expand_as(rgb), atol=1e-5, rtol=0)
    varied = AutoencoderTrainer(box_grid, cfg, seed=0)
    assert varied.single_color is None and all(p.requires_grad for p in varied.model.param_groups()[1])


def test_the_colour_loss_takes_at_most_color_points_of_the_band(box_grid, monkeypatch):
    """``color_points`` caps the points the colour head sees in a step (the SDF still sees all of them); 0 takes
    every point in the band."""
    seen = []
    real = TriplaneDecoder.query_color
    monkeypatch.setattr(
        TriplaneDecoder, "query_color", lambda self, prep, p, **k: seen.append(p.shape[1]) or real(self, prep, p, **k)
    )
    for cap in (0, 300):
        tr = AutoencoderTrainer(box_grid, tiny_ae_cfg(points_per_step=2048, color_points=cap), seed=0)
        seen.clear()
        tr.run(until_step=3, progress=False)
        assert len(seen) == 3 and (set(seen) == {300} if cap else min(seen) > 1000), (cap, seen)


def test_a_texture_of_pure_colours_is_learnt_not_stuck_on_one_colour():
    """Red 1 and blue 0 everywhere (a yellow duck, an orange beak): L1 through the sigmoid pushed the colour heads'
    outputs into the hundreds, where float32's sigmoid is flat, and the whole head stuck on (1, 1, 0)."""
    from sin3dm_lite.model.autoencoder import LOGIT_BOUND

    from .conftest import make_sphere_grid

    g = make_sphere_grid(shape=(24, 24, 24), n_points=4000)

    def paint(p):
        c = np.tile(np.array([1.0, 0.84, 0.0], np.float32), (len(p), 1))
        c[p[:, 0] > 0.2] = [1.0, 0.5, 0.0]  # an orange cap
        return c

    band, centres = np.abs(g.sdf) < g.threshold, g.voxel_centers()
    g.color = np.where(band[..., None], paint(centres.reshape(-1, 3)).reshape(*g.shape, 3), 0).astype(np.float32)
    g.point_color = paint(g.points)
    tr = AutoencoderTrainer(g, tiny_ae_cfg(steps=150), seed=0)
    tr.run(progress=False)
    rec = reconstructed_grid(tr.model.decoder, tr.latent(), g)
    cap, rest = band & (centres[..., 0] > 0.3), band & (centres[..., 0] < 0.1)
    assert rec.color[cap][:, 1].mean() == pytest.approx(0.5, abs=0.08)
    assert rec.color[rest][:, 1].mean() == pytest.approx(0.84, abs=0.08)
    with torch.no_grad():
        logits = tr.model.decoder.query_color(tr.model.decoder.prepare(tr.latent()), torch.tensor(g.points)[None], True)
    assert logits.abs().max() < LOGIT_BOUND + 2  # held where the sigmoid has a slope

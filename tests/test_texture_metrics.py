"""Texture metrics on renders: weight-free ones on pictures with known answers, weight-based ones with random weights."""

import ctypes.util
import sys
from dataclasses import replace

import numpy as np
import pytest
import torch

from sin3dm_lite import metrics as M
from sin3dm_lite.errors import Sin3DMInputError

needs_egl = pytest.mark.skipif(
    sys.platform.startswith("linux") and ctypes.util.find_library("EGL") is None,
    reason="no libEGL on this machine: apt-get install libegl1 libgl1-mesa-dri",
)


def picture(size=96, seed=0) -> np.ndarray:
    """A 'render': white background, a square of 8-pixel coloured checker tiles in the middle."""
    rng = np.random.default_rng(seed)
    palette = rng.integers(0, 230, (6, 3))
    n = size // 2 // 8
    tiles = palette[rng.integers(0, 6, (n, n))]
    img = np.full((size, size, 3), 255, np.uint8)
    img[size // 4 : size // 4 + 8 * n, size // 4 : size // 4 + 8 * n] = np.repeat(np.repeat(tiles, 8, 0), 8, 1)
    return img


def shuffled(img, tile=8, seed=1) -> np.ndarray:
    """The same picture with its 8-pixel tiles moved around (the input's pieces, another layout)."""
    fg = np.argwhere(M.foreground(img))
    (y0, x0), (y1, x1) = fg.min(0), fg.max(0) + 1
    block = img[y0:y1, x0:x1]
    n = block.shape[0] // tile
    tiles = block.reshape(n, tile, n, tile, 3).transpose(0, 2, 1, 3, 4).reshape(n * n, tile, tile, 3)
    tiles = tiles[np.random.default_rng(seed).permutation(n * n)]
    out = img.copy()
    out[y0:y1, x0:x1] = tiles.reshape(n, n, tile, tile, 3).transpose(0, 2, 1, 3, 4).reshape(block.shape)
    return out


def washed_out(img, amount=0.5) -> np.ndarray:
    """The shape's colours blended towards grey (background kept white)."""
    out = img.astype(float)
    fg = M.foreground(img)
    out[fg] = (1 - amount) * out[fg] + amount * 128
    return out.round().astype(np.uint8)


def noisy(img, sigma, seed=0) -> np.ndarray:
    out = img.astype(float) + np.random.default_rng(seed).normal(0, sigma, img.shape)
    out = np.clip(out, 0, 254).round().astype(np.uint8)
    out[~M.foreground(img)] = 255
    return out


# --------------------------------------------------------------------------- weight-free, pure arrays
def test_patch_swd_is_zero_for_identical_pictures_and_orders_known_changes():
    img = picture()
    assert M.patch_swd(img, img) == 0.0
    moved, grey = M.patch_swd(img, shuffled(img)), M.patch_swd(img, washed_out(img))
    assert 0 < moved < grey  # the input's pieces in another layout are closer than the wrong colours
    assert M.patch_swd(img, noisy(img, 5)) < M.patch_swd(img, noisy(img, 40))
    assert M.patch_swd(img, shuffled(img)) == moved  # fixed seed: the same number every time


def test_render_div_is_zero_for_identical_samples_and_rises_with_perturbation():
    views = [picture(seed=s) for s in range(3)]  # three views of one sample
    assert M.render_div([views, views, views]) == 0.0
    small = M.render_div([views, [noisy(v, 5) for v in views]])
    large = M.render_div([views, [noisy(v, 40) for v in views]])
    assert 0 < small < large < 1
    with pytest.raises(Sin3DMInputError, match="two samples"):
        M.render_div([views])
    with pytest.raises(Sin3DMInputError, match="same number of views"):
        M.render_div([views, views[:2]])


def test_t_qual_averages_over_views_and_samples():
    a, b = picture(seed=0), picture(seed=1)
    d = M.t_qual([a, b], [[a, b], [b, a]], M.colour_distance)
    assert d == pytest.approx(M.colour_distance(a, b) / 2)
    scores = M.texture_scores([a], [[a]])
    assert scores["patch_swd"] == 0.0 and scores["render_div"] is None and "sifid" not in scores


# --------------------------------------------------------------------------- weight-free, real renders
@needs_egl
def test_texture_metrics_on_renders_of_a_textured_cube():
    from sin3dm_lite.evaluate.render import render_views

    from .test_render import textured_cube

    cube = textured_cube()
    grey = replace(cube, materials=[replace(cube.materials[0], image=cube.materials[0].image * 0.4 + 0.3)])
    box = np.array([[-0.8] * 3, [0.8] * 3])
    views = render_views(cube, n_views=4, size=96, box=box)
    again = render_views(cube, n_views=4, size=96, elevation=40, box=box)  # a slightly different look at the input
    washed = render_views(grey, n_views=4, size=96, box=box)
    assert M.t_qual(views, [views]) == 0.0
    assert 0 < M.t_qual(views, [again]) < M.t_qual(views, [washed])
    assert M.render_div([views, views]) == 0.0 and M.render_div([views, washed]) > M.render_div([views, again]) > 0


# --------------------------------------------------------------------------- pre-trained features, by path
@pytest.fixture(scope="module")
def weights_dir(tmp_path_factory):
    """Randomly initialised weights saved under the standard names, with extra keys as the real files have."""
    folder = tmp_path_factory.mktemp("weights")
    torch.manual_seed(0)
    stem = M.InceptionStem()
    for m in stem.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.1, 0.1)
            m.running_var.uniform_(0.5, 2.0)
    torch.save(
        {**stem.state_dict(), "fc.weight": torch.zeros(1000, 2048)}, folder / "pt_inception-2015-12-05-6726825d.pth"
    )
    net = M.LPIPSAlex()
    torch.save(
        {
            **{f"features.{k}": v for k, v in net.features.state_dict().items()},
            "classifier.1.weight": torch.zeros(4096, 9216),
        },
        folder / "alexnet-owt-7be5be79.pth",
    )
    torch.save(
        {f"lin{k}.model.1.weight": torch.rand(1, c, 1, 1) for k, c in enumerate(M.LPIPSAlex.CHANNELS)},
        folder / "alex.pth",
    )
    return folder


def test_sifid_and_lpips_with_weights_loaded_by_path(weights_dir):
    nets = M.load_feature_weights(weights_dir)
    a, b = picture(seed=0), noisy(picture(seed=0), 30)
    assert M.sifid(a, a, nets) == pytest.approx(0.0, abs=1e-6)
    assert M.lpips(a, a, nets) == 0.0
    assert M.sifid(a, b, nets) > 1e-3 and M.lpips(a, b, nets) > 1e-4
    s = M.texture_scores([a], [[a], [b]], nets)
    assert s["sifid"] > 0 and s["lpips"] == pytest.approx(M.lpips(a, b, nets))


def test_missing_or_mismatched_weights_give_one_clear_error(weights_dir, tmp_path):
    with pytest.raises(Sin3DMInputError, match="pt_inception-2015-12-05-6726825d.pth' not found.*https://"):
        M.load_feature_weights(tmp_path)
    for name in ("pt_inception-2015-12-05-6726825d.pth", "alexnet-owt-7be5be79.pth"):
        (tmp_path / name).write_bytes((weights_dir / name).read_bytes())
    with pytest.raises(Sin3DMInputError, match="alex.pth' not found"):
        M.load_feature_weights(tmp_path)
    torch.save({"lin0.model.1.weight": torch.zeros(1, 3, 1, 1)}, tmp_path / "alex.pth")
    with pytest.raises(Sin3DMInputError, match="do not match: 'lin0.model.1.weight' has shape"):
        M.load_feature_weights(tmp_path)
    (tmp_path / "alex.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(Sin3DMInputError, match="cannot read weights"):
        M.load_feature_weights(tmp_path)
    with pytest.raises(Sin3DMInputError, match="not found"):
        M.load_feature_weights(tmp_path / "nowhere")


def test_degraded_pictures_keep_the_background_and_score_as_expected():
    img = picture(size=96)
    washed, shuffled_px = M.degraded(img, "wash", 0.6), M.degraded(img, "shuffle")
    for out in (washed, shuffled_px):
        assert out.dtype == np.uint8 and out.shape == img.shape
        np.testing.assert_array_equal(M.foreground(out), M.foreground(img))  # the silhouette stays
    fg = M.foreground(img)
    np.testing.assert_array_equal(np.sort(shuffled_px[fg], axis=0), np.sort(img[fg], axis=0))  # same colours
    assert washed[fg].std(axis=0).max() < img[fg].std(axis=0).max()  # flatter colours
    np.testing.assert_array_equal(M.degraded(img, "wash", 0.0), img)
    assert M.patch_swd(img, img) == 0.0
    assert M.patch_swd(img, washed) > 0.01 and M.patch_swd(img, shuffled_px) > 0.01
    with pytest.raises(Sin3DMInputError):
        M.degraded(img, "blur")
    with pytest.raises(Sin3DMInputError):
        M.degraded(img, "wash", 1.5)

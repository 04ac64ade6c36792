"""The 2D lesson's module: an image as a flat triplane, the forward process, the two denoisers, copy or recombine."""

import numpy as np
from matplotlib.figure import Figure

from sin3dm_lite import lesson2d as L
from sin3dm_lite.model.schedule import NoiseSchedule


def test_pebbles_is_a_deterministic_image_in_range():
    a, b = L.pebbles(24, seed=0), L.pebbles(24, seed=0)
    assert a.shape == (24, 24, 3) and a.dtype == np.float32
    assert np.array_equal(a, b) and not np.array_equal(a, L.pebbles(24, seed=1))
    assert 0 <= a.min() and a.max() <= 1


def test_an_image_is_the_xy_plane_of_a_flat_triplane():
    img = L.pebbles(16)
    tp = L.image_to_triplane(img)
    assert tp.resolution == (16, 16, 1) and tp.channels == 3
    assert float(tp.xz.abs().max()) == 0 and float(tp.yz.abs().max()) == 0
    np.testing.assert_allclose(L.triplane_to_images(tp)[0], img, atol=1e-6)


def test_forward_process_ends_in_noise_and_starts_at_the_image():
    sch, img = NoiseSchedule(), L.pebbles(16)
    steps = L.noised(img, sch, [-1, 0, 999], seed=0)
    assert steps.shape == (3, 16, 16, 3)
    np.testing.assert_allclose(steps[0], img, atol=1e-6)
    assert np.abs(steps[1] - img).max() < 0.1  # t = 0: a hundredth of noise
    assert np.corrcoef(steps[2].ravel(), img.ravel())[0, 1] < 0.2  # t = T-1: almost no image left
    s, n = L.signal_to_noise(sch, 999)
    assert s < 0.01 and n > 0.99 and abs(s * s + n * n - 1) < 1e-9


def test_the_two_fields_are_what_the_lesson_says():
    small, large = L.lesson_config("small", 10), L.lesson_config("large", 10)
    assert not small.rollout and not large.rollout
    assert L.receptive_field_width(small) == 9 and L.receptive_field_width(large) == 28


def test_nearest_patch_distance():
    img = L.pebbles(16)
    same = np.stack([img, img])
    assert np.allclose(L.nearest_patch_distance(same, img, 5), 0, atol=1e-6)
    shifted = np.roll(img, 5, axis=1)[None]  # the same pebbles elsewhere: small windows still found, the whole not
    near, whole = L.patch_distance_curve(shifted, img, [3, 16])
    assert near < 0.02 < whole
    noise = np.random.default_rng(0).random((1, 16, 16, 3)).astype(np.float32)
    assert L.nearest_patch_distance(noise, img, 3)[0] > 0.1


def test_fit_and_sample_run_the_package_trainer_and_sampler():
    img = L.pebbles(12)
    model, history = L.fit_image(img, L.lesson_config("small", 3, channels=8))
    assert len(history["loss"]) == 3 and all(np.isfinite(history["loss"]))
    out = L.sample_images(model, (12, 16), n=2, steps=3)
    assert out.shape == (2, 12, 16, 3) and 0 <= out.min() and out.max() <= 1


def test_figures():
    img, sch = L.pebbles(12), NoiseSchedule()
    assert isinstance(L.plot_noised(img, sch, 500), Figure)
    fig = L.plot_images([img[None], np.stack([img, img])], rows=["a", "b"], titles=["x"])
    assert len(fig.axes) == 4
    assert isinstance(L.plot_patch_curve([3, 5], {"small": np.array([0.1, 0.2])}, {"small": 9}), Figure)

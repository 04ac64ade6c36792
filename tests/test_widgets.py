"""The ipywidgets panels of ``sin3dm_lite.show.widgets``: the right controls, and their callbacks draw."""

import ipywidgets as widgets
import numpy as np
import pytest
import torch
from matplotlib.figure import Figure

from sin3dm_lite import widgets as sw
from sin3dm_lite.model.triplane import Triplane, plane_to_image

from .conftest import rf_square


def image_of(fig, k=0):
    return np.asarray([ax for ax in fig.axes if ax.images][k].images[0].get_array())


def test_slice_explorer_controls_and_callback(sphere_grid):
    panel = sw.slice_explorer(sphere_grid)
    assert isinstance(panel, widgets.VBox) and isinstance(panel.output, widgets.Output)
    c = panel.controls
    assert set(c) == {"axis", "index", "kind"}
    assert isinstance(c["axis"], widgets.Dropdown) and list(c["axis"].options) == ["x", "y", "z"]
    assert (c["index"].min, c["index"].max, c["index"].value) == (0, 19, 10)
    assert isinstance(panel.last_figure, Figure) and panel.last_error is None  # drawn once when built
    # moving the slider redraws through the observer with the new value
    c["index"].value = 4
    np.testing.assert_array_equal(image_of(panel.last_figure), sphere_grid.sdf[:, :, 4].T)
    # changing the axis refits the slider to that axis (y has 12 slices) before one redraw
    c["axis"].value = "y"
    assert (c["index"].max, c["index"].value) == (11, 6)
    np.testing.assert_array_equal(image_of(panel.last_figure), sphere_grid.sdf[:, 6, :].T)
    c["kind"].value = "color"
    assert image_of(panel.last_figure).shape == (20, 16, 3)
    assert panel.last_error is None


def test_errors_are_shown_not_swallowed(sphere_grid):
    panel = sw.Explorer({"n": widgets.IntSlider(value=1)}, lambda n: 1 / 0)
    assert panel.last_figure is None and "ZeroDivisionError" in panel.last_error
    with pytest.raises(ZeroDivisionError):
        panel.figure()


def test_truncation_explorer(sphere_grid):
    panel = sw.truncation_explorer(sphere_grid)
    thr = panel.controls["threshold"]
    assert thr.max == pytest.approx(3.0) and thr.value == 1.0
    assert len([ax for ax in panel.last_figure.axes if ax.images]) == 2  # chosen + the grid's own
    thr.value = 3.0
    assert len([ax for ax in panel.last_figure.axes if ax.images]) == 1 and panel.last_error is None


def test_triplane_channel_explorer():
    torch.manual_seed(0)
    tp = Triplane.randn(2, 4, (6, 5, 7))
    panel = sw.triplane_channel_explorer(tp)
    c = panel.controls
    assert set(c) == {"mode", "channel", "batch"} and c["channel"].max == 3 and c["batch"].max == 1
    renders = []
    draw = panel._render
    panel._render = lambda **v: (renders.append(v), draw(**v))[1]
    with panel.hold():  # two changes, no redraw ...
        c["mode"].value = "channel"
        c["batch"].value = 1
    assert renders == []
    c["channel"].value = 2  # ... until the next one, which draws all three
    assert renders == [{"mode": "channel", "channel": 2, "batch": 1}]
    np.testing.assert_allclose(image_of(panel.last_figure, 1), plane_to_image(tp.xz[1], 2).swapaxes(0, 1), atol=1e-6)
    assert "channel 2" in [ax for ax in panel.last_figure.axes if ax.images][1].get_title()


def test_denoising_explorer():
    torch.manual_seed(0)
    tp = Triplane.randn(1, 4, (6, 5, 7))
    steps = [{"step": i, "t": t, "x_t": tp * (i + 1), "x0": tp + i} for i, t in enumerate([900, 400, 0])]
    panel = sw.denoising_explorer(steps)
    step = panel.controls["step"]
    assert [label for label, _ in step.options] == ["t=900", "t=400", "t=0"]
    assert len([ax for ax in panel.last_figure.axes if ax.images]) == 2  # one column: x_t and x0
    step.value = 2
    panel.controls["plane"].value = "yz"
    axes = [ax for ax in panel.last_figure.axes if ax.images]
    assert axes[0].get_title() == "t = 0" and image_of(panel.last_figure).shape == (7, 5, 3)
    with pytest.raises(ValueError):
        sw.denoising_explorer([])


def test_receptive_field_explorer_caches():
    calls = []

    def fn(n):
        calls.append(n)
        return rf_square(33, 2 * n + 1, zero_corner=False), 2 * n + 1

    panel = sw.receptive_field_explorer(fn)
    dd = panel.controls["n_resblocks"]
    assert list(dd.options) == [2, 4, 6] and dd.value == 4
    dd.value = 6
    dd.value = 4
    assert calls == [4, 6]
    assert "4 ResBlocks" in panel.last_figure.axes[0].get_title()
    fig = panel.refresh()
    assert isinstance(fig, Figure) and calls == [4, 6]


# ----------------------------------------------------------------------------- live panels: they call the model
@pytest.fixture(scope="module")
def model(micro_fit):
    from .conftest import micro_model

    return micro_model(micro_fit)


def spy(monkeypatch, obj, name):
    """Record the keyword arguments of every call of ``obj.name`` (still calling it)."""
    calls, original = [], getattr(obj, name)

    def wrapper(*a, **k):
        calls.append(k)
        return original(*a, **k)

    monkeypatch.setattr(obj, name, wrapper)
    return calls


def images(fig):
    return [np.asarray(ax.images[0].get_array()) for ax in fig.axes if ax.images]


def test_sampling_panel_samples_on_every_change_and_decodes_on_the_button(model, monkeypatch):
    calls = spy(monkeypatch, model, "sample")
    panel = sw.sampling_panel(
        model, n_samples=2, preview=16, steps=3, mesh=dict(resolution=24, faces=500, texture_size=64), k3d=False
    )
    c = panel.controls
    assert set(c) == {"seed", "steps", "diversity", "sx", "sy", "sz"} and panel.last_error is None
    assert calls == [
        dict(resize=(1.0, 1.0, 1.0), steps=3, seed=0, diversity=model.config.sampling.diversity, progress=False)
    ]
    before = images(panel.last_figure)
    assert len(before) == 2 * 3  # input + 2 samples, two views each
    c["seed"].value = 5
    assert calls[-1]["seed"] == 5 and panel.last_error is None
    assert any(not np.array_equal(a, b) for a, b in zip(before, images(panel.last_figure)))  # new samples drawn
    c["diversity"].value = 1.0
    c["sx"].value = 1.5
    assert calls[-1]["resize"] == (1.5, 1.0, 1.0) and calls[-1]["diversity"] == 1.0 and len(calls) == 3
    assert panel.state["samples"].plan.resolution[0] > model.latent.resolution[0]
    shown = images(panel.last_figure)
    assert shown[1].shape[1] > shown[0].shape[1]  # the longer sample is drawn longer (x →) than the input
    fig = panel.full()
    assert len(panel.state["meshes"]) == 2 and isinstance(fig, Figure)
    assert all(len(m.faces) > 0 for m in panel.state["meshes"])


def test_denoising_slider_samples_a_trajectory_and_resamples(model, monkeypatch):
    calls = spy(monkeypatch, model, "sample")
    panel = sw.denoising_slider(model, seed=1, steps=4, record=3, plane="xz", preview=16)
    assert calls[-1]["return_intermediates"] == 3 and calls[-1]["seed"] == 1 and panel.last_error is None
    step = panel.controls["step"]
    assert len(step.options) == 3 and step.options[0][0].startswith("t=")
    first = images(panel.last_figure)
    step.value = 2
    last = images(panel.last_figure)
    assert not np.array_equal(first[0], last[0])  # x_t at the last step is not the noise of the first
    trajectory = panel.state["samples"]
    panel.children[-1].children[0].value = 7  # the seed box, then the button
    panel.resample()
    assert calls[-1]["seed"] == 7 and panel.state["samples"] is not trajectory and step.value == 0
    panel.controls["view"].value = "shape"
    assert panel.last_error is None and "predicted x0" in panel.last_figure.axes[0].get_title()


def test_texel_receptive_field_follows_the_texel(model, monkeypatch):
    from sin3dm_lite.teach import receptive_field as rfield

    calls = spy(monkeypatch, sw, "receptive_field")
    panel = sw.texel_receptive_field(model, plane="xy")
    x, y, z = model.latent.resolution
    c = panel.controls
    assert (c["i"].max, c["j"].max, c["i"].value, c["j"].value) == (x - 1, y - 1, x // 2, y // 2)
    assert calls[-1]["texel"] == (x // 2, y // 2) and panel.last_error is None
    c["i"].value = 0
    c["j"].value = 1
    assert calls[-1]["texel"] == (0, 1) and calls[-1]["plane"] == "xy"
    rf = panel.cache[("xy", 0, 1)]
    peak = np.unravel_index(np.argmax(rf.local_map), rf.local_map.shape)
    assert peak == (0, 1)  # the field sits on the chosen texel, not the centre
    assert np.allclose(panel.last_figure.axes[0].lines[0].get_xydata(), [[0, 1]])  # the cross marks it
    n = len(calls)
    c["map"].value = "whole"  # the same texel: drawn from the cache
    assert len(calls) == n and panel.last_error is None
    c["plane"].value = "yz"  # sliders refit to y × z before one measurement
    assert (c["i"].max, c["j"].max) == (y - 1, z - 1) and calls[-1]["texel"] == (y // 2, z // 2)
    assert len(calls) == n + 1 and calls[-1]["plane"] == "yz"
    with pytest.raises(ValueError, match="outside"):
        rfield.receptive_field(
            model.denoiser, resolution=(x, y, z), latent_channels=model.latent.channels, texel=(x, 0)
        )


def test_triplane_conv_explorer_takes_the_latent_apart(model, monkeypatch):
    parts_calls = spy(monkeypatch, sw, "rollout_parts")
    draws = spy(monkeypatch, sw.viz, "plot_triplane_conv")
    panel = sw.triplane_conv_explorer(model.latent)
    assert len(parts_calls) == 1 and panel.last_error is None and len(draws) == 1
    pca = images(panel.last_figure)
    panel.controls["mode"].value = "channel"
    panel.controls["channel"].value = 2
    grey = images(panel.last_figure)
    assert draws[-1] == {"channel": 2} and grey[0].shape == pca[0].shape and not np.allclose(grey[0], pca[0])
    assert np.allclose(grey[0][..., 0], grey[0][..., 1])  # one channel: grey
    panel.controls["plane"].value = "yz"
    assert panel.last_error is None and "TriplaneConv on yz" in panel.last_figure.texts[-1].get_text()
    assert len(parts_calls) == 1  # taken apart once

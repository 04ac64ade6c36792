"""The ipywidgets panels of ``sin3dm_lite.widgets``: the right controls, and their callbacks draw."""
import ipywidgets as widgets
import numpy as np
import pytest
import torch
from matplotlib.figure import Figure

from sin3dm_lite import widgets as sw
from sin3dm_lite.triplane import Triplane, plane_to_image

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

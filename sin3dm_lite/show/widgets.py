"""Small ipywidgets panels around the :mod:`sin3dm_lite.show.viz` figures (``from sin3dm_lite import widgets``).

Each panel is an :class:`Explorer` that redraws a library figure when a control moves; the data and model
stages' panels are here, the sampling stage's in :mod:`.sampling_widgets`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import ipywidgets as widgets
import torch

from ..data.grid import ShapeGrid
from ..model.triplane import PLANE_AXES, Triplane
from ..model.unet import rollout_parts
from ..teach.receptive_field import receptive_field
from . import viz
from .explorer import Explorer, float_slider
from .sampling_widgets import control_panel, denoising_explorer, denoising_slider, plane_dropdown, sampling_panel


def _index_slider(n: int, description: str = "index") -> widgets.IntSlider:
    return widgets.IntSlider(value=n // 2, min=0, max=n - 1, description=description, continuous_update=False)


def _colour_controls(tp: Triplane) -> tuple[widgets.ToggleButtons, widgets.IntSlider]:
    """PCA / single-channel toggle and the channel slider."""
    mode = widgets.ToggleButtons(options=["pca", "channel"], value="pca", description="colour")
    channel = widgets.IntSlider(value=0, min=0, max=tp.channels - 1, description="channel", continuous_update=False)
    return mode, channel


def _axis_and_index(grid: ShapeGrid, axis: str):
    """An axis dropdown, a slice slider and the ``on_change`` that fits the slider to a new axis (centred)."""
    axis_c = widgets.Dropdown(options=list(viz.AXES), value=axis, description="axis", layout={"width": "140px"})
    index_c = _index_slider(grid.shape[viz.AXES.index(axis)])

    def on_change(name, value):
        if name == "axis":
            n = grid.shape[viz.AXES.index(value)]
            index_c.max = n - 1
            index_c.value = n // 2

    return axis_c, index_c, on_change


def slice_explorer(grid: ShapeGrid, axis: str = "z", up: str | None = "y") -> Explorer:
    """Axis dropdown + slice slider + SDF/colour toggle → :func:`viz.plot_slice` (``up`` drawn vertically)."""
    axis_c, index_c, on_change = _axis_and_index(grid, axis)
    kind_c = widgets.ToggleButtons(options=["sdf", "color"], value="sdf", description="show")
    return Explorer(
        {"axis": axis_c, "index": index_c, "kind": kind_c},
        lambda axis, index, kind: viz.plot_slice(grid, axis, index, kind, up=up),
        on_change=on_change,
        title=f"{grid.name}: slices",
    )


def truncation_explorer(grid: ShapeGrid, axis: str = "z") -> Explorer:
    """Threshold slider (voxels, up to the grid's own) → :func:`viz.plot_truncation` next to the grid's own."""
    own = grid.threshold / grid.voxel_size
    thr_c = float_slider(min(1.0, own), min(0.25, own), own, 0.25, "threshold")
    axis_c, index_c, on_change = _axis_and_index(grid, axis)
    return Explorer(
        {"threshold": thr_c, "axis": axis_c, "index": index_c},
        lambda threshold, axis, index: viz.plot_truncation(
            grid, [threshold, own] if threshold < own - 1e-6 else [own], axis, index
        ),
        on_change=on_change,
        title=f"truncation (voxels; the grid's own is {own:g})",
    )


def triplane_channel_explorer(tp: Triplane) -> Explorer:
    """PCA / single-channel toggle, channel slider and batch slider → :func:`viz.plot_triplane`."""
    mode_c, channel_c = _colour_controls(tp)
    batch_c = widgets.IntSlider(
        value=0, min=0, max=max(tp.batch - 1, 0), description="sample", continuous_update=False, disabled=tp.batch == 1
    )

    def render(mode, channel, batch):
        return viz.plot_triplane(tp, "pca" if mode == "pca" else int(channel), batch=int(batch))

    return Explorer({"mode": mode_c, "channel": channel_c, "batch": batch_c}, render, title="triplane features")


def receptive_field_explorer(fn: Callable[[int], tuple], choices: Sequence[int] = (2, 4, 6)) -> Explorer:
    """Dropdown of ResBlock counts → ``fn(n) -> (rf_map, analytic_width)`` (cached) → :func:`viz.plot_receptive_field`."""
    cache: dict[int, tuple] = {}
    blocks_c = widgets.Dropdown(
        options=list(choices), value=choices[len(choices) // 2], description="ResBlocks", layout={"width": "180px"}
    )

    def render(n_resblocks):
        if n_resblocks not in cache:
            cache[n_resblocks] = fn(n_resblocks)
        rf_map, analytic = cache[n_resblocks]
        return viz.plot_receptive_field(rf_map, analytic, title=f"{n_resblocks} ResBlocks")

    return Explorer({"n_resblocks": blocks_c}, render, title="receptive field")


def texel_receptive_field(model, plane: str = "xy") -> Explorer:
    """Pick an output texel (sliders along the plane's two axes): its measured receptive field in the model's denoiser.

    ``map="local"`` is the field through the convolutions only, ``"whole"`` through the whole network
    (:func:`receptive_field.receptive_field`). Each texel is measured once and kept in ``panel.cache``.
    """
    res = model.latent.resolution
    u, v = PLANE_AXES[plane]
    plane_c = plane_dropdown(plane)
    i_c, j_c = _index_slider(res[u], viz.AXES[u]), _index_slider(res[v], viz.AXES[v])
    map_c = widgets.ToggleButtons(options=["local", "whole"], value="local", description="map")
    cache: dict = {}

    def on_change(name, value):
        if name == "plane":
            u, v = PLANE_AXES[value]
            i_c.max, i_c.value, i_c.description = res[u] - 1, res[u] // 2, viz.AXES[u]
            j_c.max, j_c.value, j_c.description = res[v] - 1, res[v] // 2, viz.AXES[v]

    def render(plane, i, j, map):
        i, j = int(i), int(j)
        if (plane, i, j) not in cache:
            cache[plane, i, j] = receptive_field(
                model.denoiser, resolution=res, latent_channels=model.latent.channels, plane=plane, texel=(i, j)
            )
        rf = cache[plane, i, j]
        u, v = PLANE_AXES[plane]
        return viz.plot_receptive_field(
            rf.local_map if map == "local" else rf.measured_map,
            rf.analytic,
            title=f"{plane} texel ({viz.AXES[u]} {i}, {viz.AXES[v]} {j}), {map} map",
            center=(i, j),
        )

    controls = {"plane": plane_c, "i": i_c, "j": j_c, "map": map_c}
    panel = Explorer(controls, render, on_change=on_change, title="receptive field of one texel")
    panel.cache = cache
    return panel


def triplane_conv_explorer(tp: Triplane, plane: str = "xy") -> Explorer:
    """A TriplaneConv taken apart on ``tp`` (:func:`unet.rollout_parts`): plane dropdown, PCA or one channel
    → :func:`viz.plot_triplane_conv`."""
    with torch.no_grad():
        parts = rollout_parts(tp.detach().cpu())
    plane_c = plane_dropdown(plane)
    mode_c, channel_c = _colour_controls(tp)

    def render(plane, mode, channel):
        return viz.plot_triplane_conv(parts, plane, channel=None if mode == "pca" else int(channel))

    return Explorer({"plane": plane_c, "mode": mode_c, "channel": channel_c}, render, title="TriplaneConv taken apart")


__all__ = [
    "Explorer",
    "control_panel",
    "denoising_explorer",
    "denoising_slider",
    "receptive_field_explorer",
    "sampling_panel",
    "slice_explorer",
    "texel_receptive_field",
    "triplane_channel_explorer",
    "triplane_conv_explorer",
    "truncation_explorer",
]

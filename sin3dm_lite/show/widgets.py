"""Small ipywidgets panels around the :mod:`sin3dm_lite.show.viz` figures (and a k3d gallery of full-quality samples).

Two kinds: explorers re-plot arrays computed earlier (slices, triplanes, a
recorded trajectory); live panels call the model on every change
(:func:`sampling_panel`, :func:`denoising_slider`, :func:`texel_receptive_field`,
:func:`control_panel`), on coarse grids while dragging and at full quality on a button.

Each panel is an :class:`Explorer` (:mod:`.explorer`): a row of controls above an ``Output``
area. Moving a control calls a *library* function (``viz.plot_slice``,
``viz.plot_triplane``, ...) with the controls' values and shows the figure it
returns. Those functions are tested on their own; the notebook calls each once
directly before wrapping it here, because widget callbacks hide their errors
(ours prints the traceback into the panel instead of swallowing it).

This module holds the panels of the data and model stages (grid slices, the
truncation, triplane features, receptive fields, a TriplaneConv taken apart)
and is the namespace of all of them (``from sin3dm_lite import widgets``); the
sampling stage's (the denoising trajectory, sampling, controlled generation)
are in :mod:`.sampling_widgets`.

For tests and scripts: ``panel.controls`` maps parameter names to widgets,
``panel.figure()`` returns the figure for the current values, ``panel.refresh()``
redraws the output (and returns the figure).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import ipywidgets as widgets
import torch

from ..data.grid import ShapeGrid
from ..model.triplane import PLANE_AXES, PLANES, Triplane
from ..model.unet import rollout_parts
from ..teach.receptive_field import receptive_field
from . import viz
from .explorer import Explorer
from .sampling_widgets import control_panel, denoising_explorer, denoising_slider, sampling_panel


def _axis_dropdown(value: str = "z") -> widgets.Dropdown:
    return widgets.Dropdown(options=list(viz.AXES), value=value, description="axis", layout={"width": "140px"})


def _index_slider(n: int) -> widgets.IntSlider:
    return widgets.IntSlider(value=n // 2, min=0, max=n - 1, description="index", continuous_update=False)


def _keep_index_in_range(grid: ShapeGrid, index_control: widgets.IntSlider):
    """When the axis changes, fit the index slider to that axis and centre it."""

    def on_change(name, value):
        if name == "axis":
            n = grid.shape[viz.AXES.index(value)]
            index_control.max = n - 1
            index_control.value = n // 2

    return on_change


def slice_explorer(grid: ShapeGrid, axis: str = "z", up: str | None = "y") -> Explorer:
    """Axis dropdown + slice slider + SDF/colour toggle → :func:`viz.plot_slice` (``up`` drawn vertically)."""
    axis_c = _axis_dropdown(axis)
    index_c = _index_slider(grid.shape[viz.AXES.index(axis)])
    kind_c = widgets.ToggleButtons(options=["sdf", "color"], value="sdf", description="show")
    return Explorer(
        {"axis": axis_c, "index": index_c, "kind": kind_c},
        lambda axis, index, kind: viz.plot_slice(grid, axis, index, kind, up=up),
        on_change=_keep_index_in_range(grid, index_c),
        title=f"{grid.name}: slices",
    )


def truncation_explorer(grid: ShapeGrid, axis: str = "z") -> Explorer:
    """Threshold slider (voxels, up to the grid's own) → :func:`viz.plot_truncation` next to the grid's own."""
    own = grid.threshold / grid.voxel_size
    thr_c = widgets.FloatSlider(
        value=min(1.0, own),
        min=min(0.25, own),
        max=own,
        step=0.25,
        description="threshold",
        continuous_update=False,
        readout_format=".2f",
    )
    axis_c = _axis_dropdown(axis)
    index_c = _index_slider(grid.shape[viz.AXES.index(axis)])
    return Explorer(
        {"threshold": thr_c, "axis": axis_c, "index": index_c},
        lambda threshold, axis, index: viz.plot_truncation(
            grid, [threshold, own] if threshold < own - 1e-6 else [own], axis, index
        ),
        on_change=_keep_index_in_range(grid, index_c),
        title=f"truncation (voxels; the grid's own is {own:g})",
    )


def triplane_channel_explorer(tp: Triplane) -> Explorer:
    """PCA / single-channel toggle, channel slider and batch slider → :func:`viz.plot_triplane`."""
    mode_c = widgets.ToggleButtons(options=["pca", "channel"], value="pca", description="colour")
    channel_c = widgets.IntSlider(value=0, min=0, max=tp.channels - 1, description="channel", continuous_update=False)
    batch_c = widgets.IntSlider(
        value=0, min=0, max=max(tp.batch - 1, 0), description="sample", continuous_update=False, disabled=tp.batch == 1
    )

    def render(mode, channel, batch):
        return viz.plot_triplane(tp, "pca" if mode == "pca" else int(channel), batch=int(batch))

    return Explorer({"mode": mode_c, "channel": channel_c, "batch": batch_c}, render, title="triplane features")


def receptive_field_explorer(fn: Callable[[int], tuple], choices: Sequence[int] = (2, 4, 6)) -> Explorer:
    """Dropdown of ResBlock counts → ``fn(n) -> (rf_map, analytic_width)`` → :func:`viz.plot_receptive_field`.

    ``fn`` (measuring a receptive field takes a backward pass) is called once per choice and cached.
    """
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

    Calls :func:`receptive_field.receptive_field` on ``model.denoiser`` at the latent's
    size with ``texel=(i, j)`` and draws :func:`viz.plot_receptive_field`
    centred on it: ``map="local"`` through the convolutions only,
    ``"whole"`` the whole network (GroupNorm and cross-plane means couple every
    texel). Each texel is measured once (two backward passes) and kept.
    """
    res = model.latent.resolution

    def size(p):
        a, b = PLANE_AXES[p]
        return res[a], res[b]

    a, b = size(plane)
    plane_c = widgets.Dropdown(options=list(PLANES), value=plane, description="plane", layout={"width": "140px"})
    i_c = widgets.IntSlider(
        value=a // 2, min=0, max=a - 1, description=viz.AXES[PLANE_AXES[plane][0]], continuous_update=False
    )
    j_c = widgets.IntSlider(
        value=b // 2, min=0, max=b - 1, description=viz.AXES[PLANE_AXES[plane][1]], continuous_update=False
    )
    map_c = widgets.ToggleButtons(options=["local", "whole"], value="local", description="map")
    cache: dict = {}

    def on_change(name, value):
        if name == "plane":
            a, b = size(value)
            u, v = PLANE_AXES[value]
            i_c.max, i_c.value, i_c.description = a - 1, a // 2, viz.AXES[u]
            j_c.max, j_c.value, j_c.description = b - 1, b // 2, viz.AXES[v]

    def render(plane, i, j, map):
        key = (plane, int(i), int(j))
        if key not in cache:
            cache[key] = receptive_field(
                model.denoiser,
                resolution=res,
                latent_channels=model.latent.channels,
                plane=plane,
                texel=(int(i), int(j)),
            )
        rf = cache[key]
        u, v = PLANE_AXES[plane]
        return viz.plot_receptive_field(
            rf.local_map if map == "local" else rf.measured_map,
            rf.analytic,
            title=f"{plane} texel ({viz.AXES[u]} {i}, {viz.AXES[v]} {j}), {map} map",
            center=(int(i), int(j)),
        )

    panel = Explorer(
        {"plane": plane_c, "i": i_c, "j": j_c, "map": map_c},
        render,
        on_change=on_change,
        title="receptive field of one texel",
    )
    panel.cache = cache
    return panel


def triplane_conv_explorer(tp: Triplane, plane: str = "xy") -> Explorer:
    """A TriplaneConv taken apart on ``tp`` (:func:`unet.rollout_parts`): plane dropdown, PCA or one channel
    → :func:`viz.plot_triplane_conv`."""
    with torch.no_grad():
        parts = rollout_parts(tp.detach().cpu())
    plane_c = widgets.Dropdown(options=list(PLANES), value=plane, description="plane", layout={"width": "140px"})
    mode_c = widgets.ToggleButtons(options=["pca", "channel"], value="pca", description="colour")
    channel_c = widgets.IntSlider(value=0, min=0, max=tp.channels - 1, description="channel", continuous_update=False)

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

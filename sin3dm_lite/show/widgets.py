"""Small ipywidgets panels around the :mod:`sin3dm_lite.show.viz` figures (and a k3d gallery of full-quality samples).

Two kinds: explorers re-plot arrays computed earlier (slices, triplanes, a
recorded trajectory); live panels call the model on every change
(:func:`sampling_panel`, :func:`denoising_slider`, :func:`texel_receptive_field`,
:func:`control_panel`), on coarse grids while dragging and at full quality on a button.

Each panel is an :class:`Explorer`: a row of controls above an ``Output``
area. Moving a control calls a *library* function (``viz.plot_slice``,
``viz.plot_triplane``, ...) with the controls' values and shows the figure it
returns. Those functions are tested on their own; the notebook calls each once
directly before wrapping it here, because widget callbacks hide their errors
(ours prints the traceback into the panel instead of swallowing it).

For tests and scripts: ``panel.controls`` maps parameter names to widgets,
``panel.figure()`` returns the figure for the current values, ``panel.refresh()``
redraws the output (and returns the figure).
"""
from __future__ import annotations

import traceback
from collections.abc import Callable, Sequence
from contextlib import contextmanager

import ipywidgets as widgets
import numpy as np
import torch
from IPython.display import clear_output, display
from matplotlib.figure import Figure

from ..data.grid import ShapeGrid
from ..model.decode import decode_grid
from ..model.triplane import PLANE_AXES, PLANES, Triplane
from ..model.unet import receptive_field, rollout_parts
from . import viz


class Explorer(widgets.VBox):
    """Controls + output; ``render(**values) -> Figure`` is called whenever a control changes.

    ``on_change(name, value)``, when given, runs first (under :meth:`hold`), e.g. to
    adjust another control's range, so the figure is redrawn once per user action.
    """

    def __init__(
        self,
        controls: dict[str, widgets.ValueWidget],
        render: Callable[..., Figure],
        on_change: Callable[[str, object], None] | None = None,
        title: str | None = None,
    ):
        self.controls = dict(controls)
        self.output = widgets.Output()
        self.last_figure: Figure | None = None
        self.last_error: str | None = None
        self._render = render
        self._on_change = on_change
        self._held = False
        header = [widgets.HTML(f"<b>{title}</b>")] if title else []
        super().__init__(children=[*header, widgets.HBox(list(self.controls.values())), self.output])
        for name, control in self.controls.items():
            control.observe(lambda change, name=name: self._changed(name, change["new"]), names="value")
        self.refresh()

    def values(self) -> dict:
        return {name: c.value for name, c in self.controls.items()}

    def figure(self) -> Figure:
        """The figure for the current control values (exceptions propagate)."""
        return self._render(**self.values())

    @contextmanager
    def hold(self):
        """Change several controls without redrawing after each one."""
        held, self._held = self._held, True
        try:
            yield
        finally:
            self._held = held

    def refresh(self) -> Figure | None:
        """Redraw the output; a failing render shows its traceback there (and in ``last_error``)."""
        with self.output:
            clear_output(wait=True)
            try:
                fig = self.figure()
            except Exception:  # show it: ipywidgets would otherwise swallow it
                self.last_error = traceback.format_exc()
                print(self.last_error)
                return None
            self.last_error = None
            self.last_figure = fig
            display(fig)
            return fig

    def _changed(self, name: str, value) -> None:
        if self._held:
            return
        if self._on_change is not None:
            with self.hold():
                self._on_change(name, value)
        self.refresh()


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
    thr_c = widgets.FloatSlider(value=min(1.0, own), min=min(0.25, own), max=own, step=0.25,
                                description="threshold", continuous_update=False, readout_format=".2f")
    axis_c = _axis_dropdown(axis)
    index_c = _index_slider(grid.shape[viz.AXES.index(axis)])
    return Explorer(
        {"threshold": thr_c, "axis": axis_c, "index": index_c},
        lambda threshold, axis, index: viz.plot_truncation(
            grid, [threshold, own] if threshold < own - 1e-6 else [own], axis, index),
        on_change=_keep_index_in_range(grid, index_c),
        title=f"truncation (voxels; the grid's own is {own:g})",
    )


def triplane_channel_explorer(tp: Triplane) -> Explorer:
    """PCA / single-channel toggle, channel slider and batch slider → :func:`viz.plot_triplane`."""
    mode_c = widgets.ToggleButtons(options=["pca", "channel"], value="pca", description="colour")
    channel_c = widgets.IntSlider(value=0, min=0, max=tp.channels - 1, description="channel", continuous_update=False)
    batch_c = widgets.IntSlider(value=0, min=0, max=max(tp.batch - 1, 0), description="sample",
                                continuous_update=False, disabled=tp.batch == 1)

    def render(mode, channel, batch):
        return viz.plot_triplane(tp, "pca" if mode == "pca" else int(channel), batch=int(batch))

    return Explorer({"mode": mode_c, "channel": channel_c, "batch": batch_c}, render, title="triplane features")


def denoising_explorer(intermediates: Sequence[dict], plane: str = "xy", channels="pca") -> Explorer:
    """Step slider (+ plane dropdown) → one column of :func:`viz.plot_denoising`: ``x_t`` and predicted ``x0``.

    PCA colours use the final result's basis at every step, so they stay comparable as the slider moves.
    """
    steps = list(intermediates)
    if not steps:
        raise ValueError("intermediates is empty: ask the sampler to record its steps")
    step_c = widgets.SelectionSlider(options=[(f"t={int(e['t'])}", k) for k, e in enumerate(steps)], value=0,
                                     description="step", continuous_update=False)
    plane_c = widgets.Dropdown(options=list(PLANES), value=plane, description="plane", layout={"width": "140px"})

    def render(step, plane):
        return viz.plot_denoising([steps[step]], plane=plane, channels=channels, reference=steps[-1]["x0"])

    return Explorer({"step": step_c, "plane": plane_c}, render, title="denoising")


def receptive_field_explorer(fn: Callable[[int], tuple], choices: Sequence[int] = (2, 4, 6)) -> Explorer:
    """Dropdown of ResBlock counts → ``fn(n) -> (rf_map, analytic_width)`` → :func:`viz.plot_receptive_field`.

    ``fn`` (measuring a receptive field takes a backward pass) is called once per choice and cached.
    """
    cache: dict[int, tuple] = {}
    blocks_c = widgets.Dropdown(options=list(choices), value=choices[len(choices) // 2], description="ResBlocks",
                                layout={"width": "180px"})

    def render(n_resblocks):
        if n_resblocks not in cache:
            cache[n_resblocks] = fn(n_resblocks)
        rf_map, analytic = cache[n_resblocks]
        return viz.plot_receptive_field(rf_map, analytic, title=f"{n_resblocks} ResBlocks")

    return Explorer({"n_resblocks": blocks_c}, render, title="receptive field")


def control_panel(model, n_samples: int = 2, resolution: int | None = None, **sample_kwargs) -> Explorer:
    """Pick a box for local editing or patch duplication; the mask over the planes redraws live, a button samples.

    Controls: the operation, the box as ranges of x, y, z (fractions of the
    model's box) and, for ``duplicate``, where the copy's low corner goes.
    The figure is :func:`viz.plot_plan` of ``model.plan(...)`` (a request
    the sampler would refuse shows its one-line reason instead). The
    **sample** button (or ``panel.run()`` from code) draws ``n_samples`` with
    the seed shown and puts the planes and :func:`viz.plot_projections` of the
    decoded shapes (``model.plot_beside_input`` at ``resolution``, default the
    grid's) below; ``panel.last_samples`` keeps them.
    """
    from ..errors import Sin3DMInputError

    def rng(lo, hi, name):
        return widgets.FloatRangeSlider(value=(lo, hi), min=0, max=1, step=0.05, description=name,
                                        continuous_update=False, readout_format=".2f")

    def at(v, name):
        return widgets.FloatSlider(value=v, min=0, max=1, step=0.05, description=name, continuous_update=False,
                                   readout_format=".2f")

    controls = {"op": widgets.Dropdown(options=["regenerate", "duplicate"], value="regenerate", description="edit",
                                       layout={"width": "190px"}),
                "x": rng(0.35, 0.65, "x"), "y": rng(0.0, 1.0, "y"), "z": rng(0.0, 1.0, "z"),
                "tx": at(0.7, "copy to x"), "ty": at(0.0, "copy to y"), "tz": at(0.0, "copy to z")}

    def plan_of(op, x, y, z, tx, ty, tz):
        box = ((x[0], y[0], z[0]), (x[1], y[1], z[1]))
        return model.plan(regenerate=box) if op == "regenerate" else model.plan(duplicate=(box, (tx, ty, tz)))

    def message(text: str) -> Figure:
        fig = Figure(figsize=(9, 0.8))
        fig.text(0.01, 0.5, text, fontsize=9, va="center", wrap=True)
        return fig

    def render(**values):
        try:
            return viz.plot_plan(plan_of(**values))
        except Sin3DMInputError as e:
            return message(f"not possible: {e}")

    panel = Explorer(controls, render, title="controlled generation: pick a box")
    seed = widgets.IntText(value=0, description="seed", layout={"width": "160px"})
    button = widgets.Button(description="sample", button_style="primary")
    result = widgets.Output()
    panel.last_samples = None
    res = resolution or int(model.config.grid.resolution)

    def run(_=None):
        plan = plan_of(**panel.values())
        samples = model.sample(n_samples, plan=plan, seed=int(seed.value), progress=False, **sample_kwargs)
        panel.last_samples = samples
        figs = [viz.plot_plan(plan, samples),
                model.plot_beside_input(samples, res, [f"seed {seed.value}, {i}" for i in range(n_samples)])]
        with result:
            clear_output(wait=True)
            for f in figs:
                display(f)
        return figs

    button.on_click(run)
    panel.run = run
    panel.children = (*panel.children, widgets.HBox([seed, button]), result)
    return panel


# ----------------------------------------------------------------------------- panels that run the model
def _seed_box(value: int = 0) -> widgets.BoundedIntText:
    return widgets.BoundedIntText(value=value, min=0, max=2**31 - 1, description="seed", layout={"width": "170px"})


def _show_in(output: widgets.Output, *items) -> None:
    with output:
        clear_output(wait=True)
        for item in items:
            display(item)


def sampling_panel(model, n_samples: int = 2, preview: int = 32, steps: int | None = None, mesh: dict | None = None,
                   k3d: bool = True) -> Explorer:
    """Seed, DDIM steps, diversity and resize (x, y, z) → ``model.sample`` → a cheap preview; a button decodes meshes.

    Every change samples ``n_samples`` new triplanes and draws
    :func:`viz.plot_projections` of their shapes beside the input's, decoded
    with :func:`decode.decode_grid` on a coarse grid (``preview`` voxels along
    the input box's longest side, the same voxel size for resized samples).
    The **full quality** button (``panel.full()`` from code) decodes textured
    meshes with ``model.to_mesh(**mesh)`` (default: the model's sampling
    settings) and shows :func:`viz.plot_meshes` (and a k3d gallery with
    ``k3d``). ``panel.state`` holds ``"samples"`` and, after the button, ``"meshes"``.
    """
    s = model.config.sampling
    steps = int(steps or min(s.steps, 10))
    state: dict = {}

    def factor(name):
        return widgets.FloatSlider(value=1.0, min=0.5, max=2.0, step=0.25, description=name, continuous_update=False,
                                   readout_format=".2f", layout={"width": "230px"})

    controls = {"seed": _seed_box(),
                "steps": widgets.IntSlider(value=steps, min=1, max=max(s.steps, steps), description="DDIM steps",
                                           continuous_update=False),
                "diversity": widgets.FloatSlider(value=float(s.diversity), min=0.0, max=1.0, step=0.1,
                                                 description="diversity", continuous_update=False, readout_format=".1f"),
                "sx": factor("resize x"), "sy": factor("resize y"), "sz": factor("resize z")}

    def occupancy(tp, aabb, res):
        return decode_grid(model.decoder, tp, aabb, res) < 0

    def render(seed, steps, diversity, sx, sy, sz):
        samples = model.sample(n_samples, resize=(sx, sy, sz), steps=int(steps), seed=int(seed), diversity=diversity,
                               progress=False)
        state["samples"] = samples
        if "input" not in state:
            state["input"] = occupancy(model.latent, model.aabb, preview)
        res = model.same_voxels(samples, preview)
        grids = [occupancy(samples.triplane[i], samples.aabb, res) for i in range(len(samples))]
        size = "" if np.allclose((sx, sy, sz), 1) else f", ×({sx:g}, {sy:g}, {sz:g})"
        return viz.plot_projections([state["input"], *grids],
                                    ["input", *(f"seed {seed} #{i}{size}" for i in range(len(grids)))])

    panel = Explorer(controls, render, title=f"sampling: preview on a {preview}-voxel grid")
    panel.state = state
    button = widgets.Button(description="full quality", button_style="primary")
    result = widgets.Output()

    def full(_=None):
        samples = state["samples"]
        meshes = model.to_mesh(samples, **(mesh or {}))
        labels = [f"sample {i}" for i in range(len(meshes))]
        state["meshes"] = meshes
        fig = viz.plot_meshes(meshes, labels)
        items = [fig]
        if k3d:
            from . import viewer

            items.insert(0, viewer.gallery(meshes, labels=labels))
        _show_in(result, *items)
        return fig

    button.on_click(full)
    panel.full = full
    panel.children = (*panel.children, button, result)
    return panel


def denoising_slider(model, seed: int = 0, steps: int | None = None, record: int = 8, plane: str = "xz",
                     preview: int = 32) -> Explorer:
    """A freshly sampled trajectory (``model.sample(return_intermediates=record)``) and a slider over its steps.

    Shows ``x_t`` and the predicted ``x0`` of the chosen step on one plane
    (:func:`viz.plot_denoising`, one PCA basis: the final result's), or, with
    ``view="shape"``, y slices of the SDF the decoder gives for that ``x0`` on a
    ``preview``-voxel grid. **resample** (``panel.resample()``) draws a new
    trajectory with the seed shown. ``panel.state["samples"]`` holds it.
    """
    steps = int(steps or min(model.config.sampling.steps, 10))
    state: dict = {}
    seed_c = _seed_box(seed)

    def draw_trajectory():
        state["samples"] = model.sample(1, steps=steps, seed=int(seed_c.value), return_intermediates=record,
                                        diversity=1.0, progress=False)
        return [(f"t={int(e['t'])}", k) for k, e in enumerate(state["samples"].intermediates)]

    step_c = widgets.SelectionSlider(options=draw_trajectory(), value=0, description="step", continuous_update=False)
    plane_c = widgets.Dropdown(options=list(PLANES), value=plane, description="plane", layout={"width": "140px"})
    view_c = widgets.ToggleButtons(options=["planes", "shape"], value="planes", description="show")

    def render(step, plane, view):
        inter = state["samples"].intermediates
        e = inter[step]
        if view == "planes":
            return viz.plot_denoising([e], plane=plane, reference=inter[-1]["x0"])
        sdf = decode_grid(model.decoder, e["x0"], state["samples"].aabb, preview)
        return viz.plot_samples_slices([sdf], axis="y", titles=[f"predicted x0 at t = {int(e['t'])}"])

    panel = Explorer({"step": step_c, "plane": plane_c, "view": view_c}, render, title="denoising, step by step")
    panel.state = state
    button = widgets.Button(description="resample", button_style="primary")

    def resample(_=None):
        with panel.hold():
            step_c.options = draw_trajectory()
            step_c.value = 0
        return panel.refresh()

    button.on_click(resample)
    panel.resample = resample
    panel.children = (*panel.children, widgets.HBox([seed_c, button]))
    return panel


def texel_receptive_field(model, plane: str = "xy") -> Explorer:
    """Pick an output texel (sliders along the plane's two axes): its measured receptive field in the model's denoiser.

    Calls :func:`unet.receptive_field` on ``model.denoiser`` at the latent's
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
    i_c = widgets.IntSlider(value=a // 2, min=0, max=a - 1, description=viz.AXES[PLANE_AXES[plane][0]],
                            continuous_update=False)
    j_c = widgets.IntSlider(value=b // 2, min=0, max=b - 1, description=viz.AXES[PLANE_AXES[plane][1]],
                            continuous_update=False)
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
            cache[key] = receptive_field(model.denoiser, resolution=res, latent_channels=model.latent.channels,
                                         plane=plane, texel=(int(i), int(j)))
        rf = cache[key]
        u, v = PLANE_AXES[plane]
        return viz.plot_receptive_field(rf.local_map if map == "local" else rf.measured_map, rf.analytic,
                                        title=f"{plane} texel ({viz.AXES[u]} {i}, {viz.AXES[v]} {j}), {map} map",
                                        center=(int(i), int(j)))

    panel = Explorer({"plane": plane_c, "i": i_c, "j": j_c, "map": map_c}, render, on_change=on_change,
                     title="receptive field of one texel")
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

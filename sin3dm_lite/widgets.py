"""Small ipywidgets panels around the :mod:`sin3dm_lite.viz` figures.

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
from contextlib import contextmanager
from typing import Callable, Sequence

import ipywidgets as widgets
from IPython.display import clear_output, display
from matplotlib.figure import Figure

from . import viz
from .grid import ShapeGrid
from .triplane import PLANES, Triplane


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
    from .errors import Sin3DMInputError

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

"""The widget panels of the sampling stage: the denoising trajectory, sampling with its knobs, controlled generation.

:func:`denoising_explorer` re-plots a trajectory recorded earlier; the others
call the model on every change (:func:`sampling_panel`,
:func:`denoising_slider`, :func:`control_panel`), on coarse grids while
dragging and at full quality on a button. Each is an
:class:`~sin3dm_lite.show.explorer.Explorer`; all are importable from
:mod:`sin3dm_lite.show.widgets` (``from sin3dm_lite import widgets``).
"""

from __future__ import annotations

from collections.abc import Sequence

import ipywidgets as widgets
import numpy as np
from IPython.display import clear_output, display
from matplotlib.figure import Figure

from ..model.decode import decode_grid
from ..model.triplane import PLANES
from . import viz
from .explorer import Explorer


def denoising_explorer(intermediates: Sequence[dict], plane: str = "xy", channels="pca") -> Explorer:
    """Step slider (+ plane dropdown) → one column of :func:`viz.plot_denoising`: ``x_t`` and predicted ``x0``.

    PCA colours use the final result's basis at every step, so they stay comparable as the slider moves.
    """
    steps = list(intermediates)
    if not steps:
        raise ValueError("intermediates is empty: ask the sampler to record its steps")
    step_c = widgets.SelectionSlider(
        options=[(f"t={int(e['t'])}", k) for k, e in enumerate(steps)],
        value=0,
        description="step",
        continuous_update=False,
    )
    plane_c = widgets.Dropdown(options=list(PLANES), value=plane, description="plane", layout={"width": "140px"})

    def render(step, plane):
        return viz.plot_denoising([steps[step]], plane=plane, channels=channels, reference=steps[-1]["x0"])

    return Explorer({"step": step_c, "plane": plane_c}, render, title="denoising")


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
        return widgets.FloatRangeSlider(
            value=(lo, hi), min=0, max=1, step=0.05, description=name, continuous_update=False, readout_format=".2f"
        )

    def at(v, name):
        return widgets.FloatSlider(
            value=v, min=0, max=1, step=0.05, description=name, continuous_update=False, readout_format=".2f"
        )

    controls = {
        "op": widgets.Dropdown(
            options=["regenerate", "duplicate"], value="regenerate", description="edit", layout={"width": "190px"}
        ),
        "x": rng(0.35, 0.65, "x"),
        "y": rng(0.0, 1.0, "y"),
        "z": rng(0.0, 1.0, "z"),
        "tx": at(0.7, "copy to x"),
        "ty": at(0.0, "copy to y"),
        "tz": at(0.0, "copy to z"),
    }

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
        figs = [
            viz.plot_plan(plan, samples),
            model.plot_beside_input(samples, res, [f"seed {seed.value}, {i}" for i in range(n_samples)]),
        ]
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


def sampling_panel(
    model, n_samples: int = 2, preview: int = 32, steps: int | None = None, mesh: dict | None = None, k3d: bool = True
) -> Explorer:
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
    controls = _sampling_controls(s, steps)

    def occupancy(tp, aabb, res):
        return decode_grid(model.decoder, tp, aabb, res) < 0

    def render(seed, steps, diversity, sx, sy, sz):
        samples = model.sample(
            n_samples, resize=(sx, sy, sz), steps=int(steps), seed=int(seed), diversity=diversity, progress=False
        )
        state["samples"] = samples
        if "input" not in state:
            state["input"] = occupancy(model.latent, model.aabb, preview)
        res = model.same_voxels(samples, preview)
        grids = [occupancy(samples.triplane[i], samples.aabb, res) for i in range(len(samples))]
        size = "" if np.allclose((sx, sy, sz), 1) else f", ×({sx:g}, {sy:g}, {sz:g})"
        return viz.plot_projections(
            [state["input"], *grids], ["input", *(f"seed {seed} #{i}{size}" for i in range(len(grids)))]
        )

    panel = Explorer(controls, render, title=f"sampling: preview on a {preview}-voxel grid")
    panel.state = state
    button = widgets.Button(description="full quality", button_style="primary")
    result = widgets.Output()

    def full(_=None):
        return _full_quality(model, state, mesh, k3d, result)

    button.on_click(full)
    panel.full = full
    panel.children = (*panel.children, button, result)
    return panel


def _sampling_controls(s, steps: int) -> dict[str, widgets.ValueWidget]:
    """:func:`sampling_panel`'s controls: seed, DDIM steps, diversity (from the sampling settings ``s``), resize."""

    def factor(name):
        return widgets.FloatSlider(
            value=1.0,
            min=0.5,
            max=2.0,
            step=0.25,
            description=name,
            continuous_update=False,
            readout_format=".2f",
            layout={"width": "230px"},
        )

    return {
        "seed": _seed_box(),
        "steps": widgets.IntSlider(
            value=steps, min=1, max=max(s.steps, steps), description="DDIM steps", continuous_update=False
        ),
        "diversity": widgets.FloatSlider(
            value=float(s.diversity),
            min=0.0,
            max=1.0,
            step=0.1,
            description="diversity",
            continuous_update=False,
            readout_format=".1f",
        ),
        "sx": factor("resize x"),
        "sy": factor("resize y"),
        "sz": factor("resize z"),
    }


def _full_quality(model, state: dict, mesh: dict | None, k3d: bool, result: widgets.Output) -> Figure:
    """:func:`sampling_panel`'s button: textured meshes of ``state["samples"]`` (kept as ``state["meshes"]``) shown
    in ``result`` as :func:`viz.plot_meshes` (and a k3d gallery with ``k3d``); returns the figure."""
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


def denoising_slider(
    model, seed: int = 0, steps: int | None = None, record: int = 8, plane: str = "xz", preview: int = 32
) -> Explorer:
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
        state["samples"] = model.sample(
            1, steps=steps, seed=int(seed_c.value), return_intermediates=record, diversity=1.0, progress=False
        )
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


__all__ = ["control_panel", "denoising_explorer", "denoising_slider", "sampling_panel"]

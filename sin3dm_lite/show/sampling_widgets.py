"""The widget panels of the sampling stage: the denoising trajectory, sampling with its knobs, controlled generation.

The live panels call the model on every change, on coarse grids, and at full quality on a button.
"""

from __future__ import annotations

from collections.abc import Sequence

import ipywidgets as widgets
import numpy as np
from matplotlib.figure import Figure

from ..model.decode import decode_grid
from ..model.triplane import PLANES
from . import viz
from .explorer import Explorer, float_slider, show_in


def plane_dropdown(value: str = "xy") -> widgets.Dropdown:
    return widgets.Dropdown(options=list(PLANES), value=value, description="plane", layout={"width": "140px"})


def _step_slider(intermediates: Sequence[dict]) -> widgets.SelectionSlider:
    return widgets.SelectionSlider(
        options=_step_options(intermediates), value=0, description="step", continuous_update=False
    )


def _step_options(intermediates: Sequence[dict]) -> list[tuple[str, int]]:
    return [(f"t={int(e['t'])}", k) for k, e in enumerate(intermediates)]


def denoising_explorer(intermediates: Sequence[dict], plane: str = "xy", channels="pca") -> Explorer:
    """Step slider (+ plane dropdown) → one column of :func:`viz.plot_denoising`: ``x_t`` and predicted ``x0``.

    PCA colours use the final result's basis at every step, so they stay comparable as the slider moves.
    """
    steps = list(intermediates)
    if not steps:
        raise ValueError("intermediates is empty: ask the sampler to record its steps")

    def render(step, plane):
        return viz.plot_denoising([steps[step]], plane=plane, channels=channels, reference=steps[-1]["x0"])

    return Explorer({"step": _step_slider(steps), "plane": plane_dropdown(plane)}, render, title="denoising")


def control_panel(model, n_samples: int = 2, resolution: int | None = None, **sample_kwargs) -> Explorer:
    """Pick a box for local editing or patch duplication; the mask over the planes redraws live, a button samples.

    The box is given as ranges of x, y, z (fractions of the model's box), for ``duplicate`` with where the
    copy's low corner goes; the figure is :func:`viz.plot_plan`. The **sample** button (``panel.run()``) draws
    ``n_samples`` and shows them beside the input at ``resolution``; ``panel.last_samples`` keeps them.
    """
    from ..errors import Sin3DMInputError

    def fraction(kind, value, name):
        return float_slider(value, 0, 1, 0.05, name, kind=kind)

    controls = {
        "op": widgets.Dropdown(
            options=["regenerate", "duplicate"], value="regenerate", description="edit", layout={"width": "190px"}
        ),
        "x": fraction(widgets.FloatRangeSlider, (0.35, 0.65), "x"),
        "y": fraction(widgets.FloatRangeSlider, (0.0, 1.0), "y"),
        "z": fraction(widgets.FloatRangeSlider, (0.0, 1.0), "z"),
        "tx": fraction(widgets.FloatSlider, 0.7, "copy to x"),
        "ty": fraction(widgets.FloatSlider, 0.0, "copy to y"),
        "tz": fraction(widgets.FloatSlider, 0.0, "copy to z"),
    }

    def plan_of(op, x, y, z, tx, ty, tz):
        box = ((x[0], y[0], z[0]), (x[1], y[1], z[1]))
        return model.plan(regenerate=box) if op == "regenerate" else model.plan(duplicate=(box, (tx, ty, tz)))

    def render(**values):
        try:
            return viz.plot_plan(plan_of(**values))
        except Sin3DMInputError as e:
            fig = Figure(figsize=(9, 0.8))
            fig.text(0.01, 0.5, f"not possible: {e}", fontsize=9, va="center", wrap=True)
            return fig

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
        show_in(result, *figs)
        return figs

    button.on_click(run)
    panel.run = run
    panel.children = (*panel.children, widgets.HBox([seed, button]), result)
    return panel


def _seed_box(value: int = 0) -> widgets.BoundedIntText:
    return widgets.BoundedIntText(value=value, min=0, max=2**31 - 1, description="seed", layout={"width": "170px"})


def sampling_panel(
    model, n_samples: int = 2, preview: int = 32, steps: int | None = None, mesh: dict | None = None, k3d: bool = True
) -> Explorer:
    """Seed, DDIM steps, diversity and resize (x, y, z) → ``model.sample`` → a cheap preview; a button decodes meshes.

    The preview decodes ``preview`` voxels along the input box's longest side. The **full quality** button
    (``panel.full()``) decodes ``model.to_mesh(**mesh)`` and shows :func:`viz.plot_meshes` (and, with ``k3d``,
    a gallery). ``panel.state`` holds ``"samples"`` and, after the button, ``"meshes"``.
    """
    s = model.config.sampling
    steps = int(steps or min(s.steps, 10))
    state: dict = {}

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

    panel = Explorer(_sampling_controls(s, steps), render, title=f"sampling: preview on a {preview}-voxel grid")
    panel.state = state
    button = widgets.Button(description="full quality", button_style="primary")
    result = widgets.Output()

    def full(_=None):
        meshes = model.to_mesh(state["samples"], **(mesh or {}))
        labels = [f"sample {i}" for i in range(len(meshes))]
        state["meshes"] = meshes
        items = [viz.plot_meshes(meshes, labels)]
        if k3d:
            from . import viewer

            items.insert(0, viewer.gallery(meshes, labels=labels))
        show_in(result, *items)
        return items[-1]

    button.on_click(full)
    panel.full = full
    panel.children = (*panel.children, button, result)
    return panel


def _sampling_controls(s, steps: int) -> dict[str, widgets.ValueWidget]:
    """:func:`sampling_panel`'s controls: seed, DDIM steps, diversity (from the sampling settings ``s``), resize."""

    def factor(name):
        return float_slider(1.0, 0.5, 2.0, 0.25, name, layout={"width": "230px"})

    return {
        "seed": _seed_box(),
        "steps": widgets.IntSlider(
            value=steps, min=1, max=max(s.steps, steps), description="DDIM steps", continuous_update=False
        ),
        "diversity": float_slider(float(s.diversity), 0.0, 1.0, 0.1, "diversity", readout_format=".1f"),
        "sx": factor("resize x"),
        "sy": factor("resize y"),
        "sz": factor("resize z"),
    }


def denoising_slider(
    model, seed: int = 0, steps: int | None = None, record: int = 8, plane: str = "xz", preview: int = 32
) -> Explorer:
    """A freshly sampled trajectory (``model.sample(return_intermediates=record)``) and a slider over its steps.

    Shows ``x_t`` and the predicted ``x0`` of the chosen step on one plane (:func:`viz.plot_denoising`), or,
    with ``view="shape"``, y slices of the SDF decoded from that ``x0`` on a ``preview``-voxel grid.
    **resample** (``panel.resample()``) draws a new trajectory with the seed shown (``panel.state["samples"]``).
    """
    steps = int(steps or min(model.config.sampling.steps, 10))
    state: dict = {}
    seed_c = _seed_box(seed)

    def draw_trajectory():
        state["samples"] = model.sample(
            1, steps=steps, seed=int(seed_c.value), return_intermediates=record, diversity=1.0, progress=False
        )
        return state["samples"].intermediates

    step_c = _step_slider(draw_trajectory())

    def render(step, plane, view):
        inter = state["samples"].intermediates
        e = inter[step]
        if view == "planes":
            return viz.plot_denoising([e], plane=plane, reference=inter[-1]["x0"])
        sdf = decode_grid(model.decoder, e["x0"], state["samples"].aabb, preview)
        return viz.plot_samples_slices([sdf], axis="y", titles=[f"predicted x0 at t = {int(e['t'])}"])

    view_c = widgets.ToggleButtons(options=["planes", "shape"], value="planes", description="show")
    controls = {"step": step_c, "plane": plane_dropdown(plane), "view": view_c}
    panel = Explorer(controls, render, title="denoising, step by step")
    panel.state = state
    button = widgets.Button(description="resample", button_style="primary")

    def resample(_=None):
        with panel.hold():
            step_c.options = _step_options(draw_trajectory())
            step_c.value = 0
        return panel.refresh()

    button.on_click(resample)
    panel.resample = resample
    panel.children = (*panel.children, widgets.HBox([seed_c, button]))
    return panel


__all__ = ["control_panel", "denoising_explorer", "denoising_slider", "sampling_panel"]

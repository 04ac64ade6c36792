"""Figures of the Generate stage: slices of samples, the diversity curve, a control plan, projections and rendered pictures of meshes."""

from __future__ import annotations

import weakref
from collections.abc import Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from ..data.mesh import Material, TexturedMesh
from ..errors import Sin3DMInputError
from ..evaluate import render
from ..model.triplane import PLANE_AXES, PLANES, pca_basis, pca_project
from .figures import (
    AXES,
    SDF_CMAP,
    as_numpy,
    axis_index,
    contour_texels,
    grid_slice,
    label_axes,
    new_figure,
    panel_height,
    plane_axes,
    show_image,
)


def plot_samples_slices(
    sdf_grids: Sequence[np.ndarray],
    axis: int | str = "z",
    index: int | None = None,
    titles: Sequence[str] | None = None,
    columns: int | None = None,
    up: str | None = "y",
) -> Figure:
    """Middle slices (or slice ``index``) of several decoded SDF grids, with the zero contour.

    All panels share one symmetric colour scale (the largest ``|sdf|``, at most 1); the ``up`` axis is drawn
    vertically where it is one of the slice's axes.
    """
    a = axis_index(axis)
    ui, vi = plane_axes(a, up)
    slices = []
    for g in sdf_grids:
        s, _ = grid_slice(as_numpy(g), a, index)
        slices.append(s.T if ui > vi else s)
    n = len(slices)
    columns = columns or min(n, 4)
    rows = -(-n // columns)
    fig = new_figure(2.8 * columns, panel_height(2.8, slices[0].shape[1] / slices[0].shape[0]) * rows)
    panels = fig.subplots(rows, columns, squeeze=False)
    vmax = min(1.0, max(float(np.abs(s).max()) for s in slices)) or 1.0
    for k, ax in enumerate(panels.flat):
        if k >= n:
            ax.set_axis_off()
            continue
        s = slices[k]
        show_image(ax, s, cmap=SDF_CMAP, vmin=-vmax, vmax=vmax)
        if s.min() < 0 < s.max():
            contour_texels(ax, s, 0.0, colors="k", linewidths=0.8)
        ax.set_title(titles[k] if titles else f"sample {k}", fontsize=9)
        label_axes(ax, ui, vi)
    return fig


def plot_diversity_curve(values: Sequence[float], rows: Sequence[dict], goals: dict | None = None) -> Figure:
    """The diversity ↔ fidelity trade-off: scores of samples drawn at each value of the knob.

    ``rows[i]`` holds the scores at ``values[i]``: ``g_div`` and any of ``iou_to_input``, ``lp_iou``,
    ``lp_fscore``; ``goals`` (same keys) draws dashed lines at target values.
    """
    labels = {
        "g_div": "G-Div (diversity)",
        "iou_to_input": "IoU to the input",
        "lp_iou": "LP-IoU (fidelity)",
        "lp_fscore": "LP-F (fidelity)",
    }
    fig = new_figure(5.5, 3.4)
    ax = fig.add_subplot(1, 1, 1)
    for key, label in labels.items():
        if all(key in r for r in rows):
            (line,) = ax.plot(values, [r[key] for r in rows], "o-", label=label)
            if goals and key in goals:
                ax.axhline(goals[key], ls="--", lw=0.8, color=line.get_color())
    ax.set_xlabel("diversity (0 = the input, 1 = from pure noise)")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def plot_plan(plan, samples=None, batch: int = 0, title: str | None = None) -> Figure:
    """A controlled-generation request (``control.Plan``) on the three planes, and what the sampler made of it.

    Top row: the latent the request starts from, in PCA colours, with the part the sampler generates tinted
    red (by ``1 - mask``). Bottom row (with ``samples``): sample ``batch`` with the tint's outline, in the top
    row's PCA basis, so kept texels look the same in both rows.
    """
    top = plan.known if plan.known is not None else plan.start
    rows = [("request", top)] + ([("sample", samples.triplane)] if samples is not None else [])
    x, y, z = plan.resolution
    widths, heights = [x, x, y], [y, z, z]
    scale = 9.0 / sum(widths)
    fig = new_figure(9.5, (max(heights) * scale + 0.6) * len(rows) + 0.3)
    panels = fig.subplots(len(rows), 3, squeeze=False, gridspec_kw={"width_ratios": widths})
    bases = [pca_basis(as_numpy(getattr(top, name)[0])) for name in PLANES]
    for r, (label, tp) in enumerate(rows):
        for c, name in enumerate(PLANES):
            ax = panels[r, c]
            plane = as_numpy(getattr(tp, name)[batch if label == "sample" else 0])
            show_image(ax, pca_project(plane, *bases[c]))
            if plan.mask is not None:
                free = 1 - as_numpy(getattr(plan.mask, name)[0, 0])
                if label == "request":
                    tint = np.zeros((*free.shape, 4))
                    tint[..., 0], tint[..., 3] = 1.0, 0.6 * free
                    show_image(ax, tint)
                elif 0 < free.max():
                    contour_texels(ax, free, 0.5, colors="r", linewidths=1.0)
            ax.set_title(f"{label}: {name}", fontsize=9)
            label_axes(ax, *PLANE_AXES[name])
    fig.suptitle(title or f"{plan.kind}: red = generated, clear = kept from the input", fontsize=10)
    return fig


def plot_projections(grids: Sequence[np.ndarray], titles: Sequence[str] | None = None, up: str = "y") -> Figure:
    """Occupancy grids seen from the front and from above: how many voxels are filled along each ray.

    With ``up="y"`` the front view looks along z (x →, y ↑) and the top view along y (x →, z ↑: seen from
    below, a mirrored top view). Grids of different sizes keep their relative sizes.
    """
    grids = [as_numpy(g) for g in grids]
    ui = axis_index(up)
    if ui == 0:
        raise ValueError("up must be y or z: the views put x to the right")
    depth = 3 - ui  # the front view looks along the axis that is neither x nor up
    n = len(grids)
    widths = [g.shape[0] for g in grids]
    fig = new_figure(min(2.6 * n, 12), 4.2)
    panels = fig.subplots(2, n, squeeze=False, gridspec_kw={"width_ratios": widths})
    for j, g in enumerate(grids):
        front = g.sum(axis=depth)  # (x, up)
        top = g.sum(axis=ui)  # (x, the other)
        show_image(panels[0, j], front, cmap="bone")
        show_image(panels[1, j], top, cmap="terrain")
        panels[0, j].set_title(titles[j] if titles else f"{j}", fontsize=9)
        for ax in panels[:, j]:
            ax.set(xticks=[], yticks=[])
    panels[0, 0].set_ylabel(f"front ({AXES[ui]} up)", fontsize=8)
    panels[1, 0].set_ylabel(f"top ({AXES[depth]} up)", fontsize=8)
    return fig


_RECONSTRUCTIONS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # model → {resolution: occupancy grid}


def plot_beside_input(model, samples, resolution: int = 64, labels: Sequence[str] | None = None) -> Figure:
    """``Sin3DM.plot_beside_input``: front and top views (:func:`plot_projections`) of ``model``'s samples beside
    the input's reconstruction (kept per model and resolution), at the voxel size of the input's box at ``resolution``.
    """
    kept = _RECONSTRUCTIONS.setdefault(model, {})
    if resolution not in kept:
        kept[resolution] = model.occupancy(model.input_sample(), resolution, mesh_resolution=2 * resolution)[0]
    res = model.same_voxels(samples, resolution)
    grids = model.occupancy(samples, res, mesh_resolution=2 * res)
    labels = list(labels) if labels is not None else [f"{i:03d}" for i in range(len(grids))]
    return plot_projections([kept[resolution], *grids], ["input", *labels])


def plot_meshes(meshes, labels: Sequence[str] | None = None, size: int = 256, columns: int = 4) -> Figure:
    """A static picture of meshes side by side: each one's three-quarter view, its label underneath.

    For a notebook read without a kernel. ``meshes``: a ``TexturedMesh``, or a list of them, ``trimesh.Trimesh``
    es or ``(vertices, faces)`` pairs (in grey), drawn at ``size``² pixels in one frame so sizes compare. Where
    off-screen OpenGL cannot start, the figure is a line of text saying so.
    """

    def textured(m) -> TexturedMesh:
        if isinstance(m, TexturedMesh):
            return m
        v, f = m if isinstance(m, tuple) else (m.vertices, m.faces)
        return TexturedMesh(
            np.asarray(v, np.float64),
            np.asarray(f, np.int64),
            np.zeros(len(f), np.int64),
            [Material(base_color=np.float32([0.55, 0.55, 0.55, 1.0]))],
        )

    if isinstance(meshes, TexturedMesh) or hasattr(meshes, "faces"):
        meshes = [meshes]
    meshes = [textured(m) for m in meshes]
    if not meshes or (labels is not None and len(labels) != len(meshes)):
        raise Sin3DMInputError(
            f"plot_meshes needs at least one mesh and one label per mesh, got {len(meshes)} "
            f"meshes and {'no' if labels is None else len(labels)} labels"
        )
    if not 16 <= int(size) <= 1024:
        raise Sin3DMInputError(f"size must be from 16 to 1024 pixels, got {size}")
    corners = np.concatenate([np.asarray(m.vertices, np.float64).reshape(-1, 3) for m in meshes])
    box = np.stack([corners.min(0), corners.max(0)]) if len(corners) else None
    try:
        sheet = render.contact_sheet(
            [render.render_hero(m, size=int(size), box=box) for m in meshes], labels, columns=columns
        )
    except Sin3DMInputError as e:  # no OpenGL context here, or a mesh with nothing to draw
        fig = new_figure(9.0, 0.5)
        fig.text(0.01, 0.5, f"no static picture: {e}", fontsize=8, va="center", wrap=True)
        return fig
    dpi = 100
    fig = plt.figure(figsize=(sheet.shape[1] / dpi, sheet.shape[0] / dpi), dpi=dpi)
    plt.close(fig)  # shown once, as the cell's value
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.imshow(sheet, interpolation="none")
    ax.set_axis_off()
    return fig

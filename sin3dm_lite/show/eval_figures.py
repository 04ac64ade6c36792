"""Figures of the Evaluate stage: pictures, the IoU matrix, layer variation, patch matches and rendered pairs."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from ..evaluate.metrics import check_same_grid, colour_distance, foreground, g_div_by_layer, pairwise_iou
from .data_figures import as_float_image
from .figures import axis_index, new_figure, show_image


def plot_picture(image: np.ndarray, title: str | None = None, width: float = 10.0) -> Figure:
    """One picture (``(H, W, 3)``, uint8 or floats in [0, 1]: a render, a ``render.contact_sheet``), no axes."""
    img = as_float_image(image)
    fig = new_figure(width, width * img.shape[0] / img.shape[1] + (0.35 if title else 0.0))
    ax = fig.subplots()
    ax.imshow(img, interpolation="antialiased")
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=10)
    return fig


def plot_iou_matrix(grids: Sequence[np.ndarray], labels: Sequence[str] | None = None) -> Figure:
    """G-Div as a picture: the ``1 − IoU`` of every pair of occupancy grids (one box), the diagonal blank."""
    d = 1.0 - pairwise_iou(grids)
    n = len(d)
    i, j = np.triu_indices(n, k=1)
    off = d[i, j]
    shown = d.copy()
    np.fill_diagonal(shown, np.nan)
    labels = list(labels) if labels is not None else [f"{k}" for k in range(n)]
    fig = new_figure(1.2 + 0.62 * n, 0.9 + 0.55 * n)
    ax = fig.subplots()
    im = ax.imshow(shown, cmap="viridis", vmin=0.0, vmax=max(float(off.max()) if len(off) else 0.0, 1e-3))
    for a in range(n):
        for b in range(n):
            if a != b:  # then off is not empty
                color = "w" if d[a, b] < 0.6 * off.max() else "k"
                ax.text(b, a, f"{d[a, b]:.2f}", ha="center", va="center", fontsize=8, color=color)
    ax.set_xticks(range(n), labels, fontsize=8, rotation=90 if n > 6 else 0)
    ax.set_yticks(range(n), labels, fontsize=8)
    fig.colorbar(im, ax=ax, shrink=0.8, label="1 − IoU")
    ax.set_title(
        f"G-Div = mean above the diagonal = {off.mean():.3f}" if len(off) else "one shape: no pairs", fontsize=9
    )
    return fig


def plot_layer_variation(reference: np.ndarray, grids: Sequence[np.ndarray], axis: int | str = "y") -> Figure:
    """Where the samples differ, layer by layer along ``axis`` (default y: heights, bottom to top).

    Left: the input's solid voxels per layer. Right: each layer's share of G-Div (:func:`metrics.g_div_by_layer`).
    """
    k = axis_index(axis)
    check_same_grid([reference, *grids])  # the input and the samples in one box
    parts = g_div_by_layer(grids, k)
    other = tuple(a for a in range(3) if a != k)
    solid = np.asarray(reference, bool).sum(other)
    layers = np.arange(len(parts))
    fig = new_figure(8.0, 1.6 + 0.08 * len(parts))
    left, right = fig.subplots(1, 2, sharey=True)
    left.barh(layers, solid, color="0.55", height=0.9)
    left.set_xlabel("solid voxels in the input", fontsize=8)
    left.set_ylabel(f"layer along {'xyz'[k]}", fontsize=8)
    right.barh(layers, parts, color="tab:orange", height=0.9)
    right.set_xlabel("share of G-Div", fontsize=8)
    right.set_title(f"G-Div {parts.sum():.3f} = sum of the bars", fontsize=9)
    for ax in (left, right):
        ax.tick_params(labelsize=7)
    return fig


def _patch_strip(cube: np.ndarray, slices: Sequence[int]) -> np.ndarray:
    """Slices ``cube[:, :, k]`` of an occupancy patch side by side (x →, y ↑), NaN gaps between them."""
    parts = []
    for k in slices:
        parts += [np.where(cube[:, :, k], 0.85, 0.15), np.full((1, cube.shape[1]), np.nan)]
    return np.concatenate(parts[:-1], axis=0)


def plot_patch_matches(matches: dict, slices: Sequence[int] | None = None) -> Figure:
    """What LP-IoU compares (``metrics.patch_matches``): generated surface patches above their best input match.

    Each patch is drawn as a few z slices side by side (dark = occupied), titled with the pair's IoU and
    F-score. The last panel is the histogram of each patch's best IoU: LP-IoU is the share right of the dashes.
    """
    gen, ref = matches["generated"], matches["matched"]
    n, p = len(gen), gen.shape[-1]
    slices = list(slices) if slices is not None else sorted({p // 5, p // 2, p - 1 - p // 5})
    fig = new_figure(2.3 * n + 3.2, 3.0)
    panels = fig.subplots(2, n + 1, squeeze=False, gridspec_kw={"width_ratios": [1.0] * n + [1.4]})
    for k in range(n):
        for row, cube, label in ((0, gen[k], "generated"), (1, ref[k], "best input patch")):
            ax = panels[row, k]
            show_image(ax, _patch_strip(cube, slices), cmap="Greys", vmin=0, vmax=1)
            ax.set(xticks=[], yticks=[])
            scores = f"IoU {matches['iou'][k]:.2f} · F {matches['fscore'][k]:.2f}"
            ax.set_title(scores if row == 0 else label, fontsize=8)
        if k == 0:
            panels[0, 0].set_ylabel("generated", fontsize=8)
            panels[1, 0].set_ylabel("input", fontsize=8)
    gs = panels[0, n].get_gridspec()
    for ax in panels[:, n]:
        ax.remove()
    ax = fig.add_subplot(gs[:, n])
    best, thr = np.asarray(matches["best_iou"]), matches["threshold"]
    ax.hist(best, bins=np.linspace(0, 1, 21), color="0.5")
    ax.axvline(thr, ls="--", color="r", lw=1)
    ax.set_xlabel("best IoU of each patch", fontsize=8)
    ax.set_title(f"{len(best)} patches: {np.mean(best > thr):.0%} above {thr}", fontsize=8)
    ax.tick_params(labelsize=7)
    fig.suptitle(f"z slices {', '.join(map(str, slices))} of {p}³ patches; dark = occupied", fontsize=9)
    return fig


def plot_render_pairs(
    views_a: Sequence[np.ndarray],
    views_b: Sequence[np.ndarray],
    labels: Sequence[str] = ("sample 0", "sample 1"),
    views: Sequence[int] | None = None,
) -> Figure:
    """What the render diversity compares: the same view of two shapes, and where their colours differ.

    Rows: shape a, shape b, ``|a − b|`` (mean over RGB) where either shows the shape; each column's title is
    the view's ``metrics.colour_distance``. ``views`` picks the views shown (assumed ``360 / len(views_a)``° apart).
    """
    if len(views_a) != len(views_b):
        raise ValueError(f"both shapes need the same views, got {len(views_a)} and {len(views_b)}")
    views = list(views) if views is not None else list(range(len(views_a)))
    fig = new_figure(2.2 * len(views) + 0.6, 7.0)
    panels = fig.subplots(3, len(views), squeeze=False)
    for c, k in enumerate(views):
        a, b = as_float_image(views_a[k]), as_float_image(views_b[k])
        diff = np.abs(a - b).mean(axis=-1)
        diff[~(foreground(views_a[k]) | foreground(views_b[k]))] = np.nan
        panels[0, c].imshow(a)
        panels[1, c].imshow(b)
        im = panels[2, c].imshow(diff, cmap="magma", vmin=0, vmax=0.5)
        panels[0, c].set_title(
            f"azimuth {360 * k / len(views_a):.0f}°: distance {colour_distance(views_a[k], views_b[k]):.3f}", fontsize=8
        )
        for ax in panels[:, c]:
            ax.set(xticks=[], yticks=[])
    for r, label in enumerate([*labels, "|difference|"]):
        panels[r, 0].set_ylabel(label, fontsize=8)
    fig.colorbar(im, ax=panels[2, :].tolist(), shrink=0.8, label="colour difference")
    return fig

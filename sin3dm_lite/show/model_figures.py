"""Figures of the Model stage: the three triplane feature maps, how a plane sees the volume, one TriplaneConv, the U-Net's receptive field."""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from ..data.grid import ShapeGrid
from ..model.triplane import PLANE_AXES, PLANES, Triplane, pca_basis, pca_project, plane_to_image
from .figures import AXES, as_numpy, axis_index, label_axes, new_figure, plane_axes, show_image


def triplane_images(tp: Triplane, channels: str | int = "pca", batch: int = 0) -> list[np.ndarray]:
    """The three planes of sample ``batch`` as ``(A, B, 3)`` images (see :func:`plane_to_image`)."""
    return [plane_to_image(p[batch], channels) for p in tp.planes]


def plot_triplane(
    tp: Triplane, channels: str | int | Sequence[int] = "pca", titles: bool = True, batch: int = 0
) -> Figure:
    """The xy, xz and yz feature planes side by side, at their true relative sizes.

    ``channels="pca"`` colours each plane by its first three principal components (one basis per plane, so
    compare structure, not hue); an ``int`` shows one channel in grey; a list of ints draws one row each.
    Each plane is drawn with its first axis → and its second ↑.
    """
    rows = list(channels) if isinstance(channels, (list, tuple)) else [channels]
    x, y, z = tp.resolution
    widths, heights = [x, x, y], [y, z, z]
    scale = 9.0 / sum(widths)
    fig = new_figure(9.5, max(1.6, (max(heights) * scale + 0.5)) * len(rows))
    panels = fig.subplots(len(rows), 3, squeeze=False, gridspec_kw={"width_ratios": widths})
    for r, ch in enumerate(rows):
        for c, (name, img) in enumerate(zip(PLANES, triplane_images(tp, ch, batch))):
            ax = panels[r, c]
            show_image(ax, img)
            label_axes(ax, *PLANE_AXES[name])
            if titles:
                label = "PCA" if ch == "pca" else f"channel {ch}"
                ax.set_title(f"{name} {tuple(img.shape[:2])} · {label}", fontsize=9)
    return fig


def _view_words(name: str, up: int) -> str:
    """How a picture of plane ``name`` (first axis →, second ↑) looks at the shape when axis ``up`` is vertical."""
    u, v = PLANE_AXES[name]
    lacking = 3 - u - v
    if lacking == up:  # a plan: a true top view when (→, ↑, up) is right-handed, else the view from below
        if (u, v, lacking) in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
            return f"seen from above ({AXES[u]} →, {AXES[v]} ↑)"
        return f"seen from below ({AXES[u]} →, {AXES[v]} ↑):\n    a top view, mirrored"
    side = f"a side view along {AXES[lacking]}"
    if v == up:
        return f"{side} ({AXES[u]} →, {AXES[v]} ↑: upright)"
    return f"{side} ({AXES[u]} →, {AXES[v]} ↑):\n    on its side, the height {AXES[up]} runs →"


def _slice_words(axis: int, up: int) -> str:
    u, v = plane_axes(axis, up)
    kind = "horizontal" if axis == up else "vertical"
    return f"slice across {AXES[axis]} ({kind}): {AXES[u]} →, {AXES[v]} ↑"


def plot_plane_axes(shape=None, up: str = "y", n_points: int = 4000, azim: float = 30.0) -> Figure:
    """The three triplane planes drawn on the shape's box, labelled, with the x, y, z axes and ``up`` vertical.

    ``shape``: a mesh or :class:`ShapeGrid` (drawn as ``n_points`` surface points), a box ``(6,)`` =
    ``(min xyz, max xyz)`` or None (a unit cube). Each plane sits on the box face at the minimum of the axis it
    lacks, which the encoder averages over; the text beside says how the 2D figures orient planes and slices.
    """
    ui = axis_index(up)
    lo, hi, points = _box_and_points(shape, n_points)
    ext = np.maximum(hi - lo, 1e-9)

    fig = new_figure(10.0, 5.2)
    gs = fig.add_gridspec(1, 2, width_ratios=[1.5, 1.0])
    ax = fig.add_subplot(gs[0, 0], projection="3d")
    if points is not None:  # the shape, shaded by height
        shade = dict(c=points[:, ui], cmap="Greys", vmin=lo[ui] - 0.6 * ext[ui], vmax=hi[ui])
        ax.scatter(*points.T, s=1.5, alpha=0.7, depthshade=False, **shade)
    corners = np.array([[(lo[k], hi[k])[(i >> k) & 1] for k in range(3)] for i in range(8)])  # bit k: axis k
    for i in range(8):
        for bit in (1, 2, 4):
            if not i & bit:
                ax.plot(*corners[[i, i | bit]].T, color="k", lw=0.6)
    _draw_planes(ax, lo, hi, ext, ui)
    _draw_axes_triad(ax, lo, hi, ext, ui)
    pad = 0.15 * ext.max()
    ax.set(xlim=(lo[0] - pad, hi[0] + pad), ylim=(lo[1] - pad, hi[1] + pad), zlim=(lo[2] - pad, hi[2] + pad))
    ax.set_box_aspect(tuple(np.roll(ext + 2 * pad, 2 - ui)))  # with vertical_axis, matplotlib reads it rolled
    ax.view_init(elev=22, azim=azim, vertical_axis=AXES[ui])  # x → (a little back), up ↑, the third axis towards us
    ax.set(xlabel="x", ylabel="y", zlabel="z")
    ax.tick_params(labelsize=7)
    _describe_views(fig, gs, ui)
    return fig


def _box_and_points(shape, n_points: int):
    """The box ``(lo, hi)`` of what :func:`plot_plane_axes` draws and up to ``n_points`` points on its surface (or None)."""
    points = None
    if shape is None:
        lo, hi = -np.ones(3), np.ones(3)
    elif isinstance(shape, ShapeGrid):
        lo, hi = np.asarray(shape.aabb[:3], float), np.asarray(shape.aabb[3:], float)
        pts = np.asarray(shape.points, float).reshape(-1, 3)
        points = (
            pts[np.random.default_rng(0).choice(len(pts), min(len(pts), n_points), replace=False)] if len(pts) else None
        )
    elif hasattr(shape, "vertices") and hasattr(shape, "faces"):
        v, f = np.asarray(shape.vertices, float), np.asarray(shape.faces)
        lo, hi = v.min(0), v.max(0)
        tri = v[f]  # (F, 3, 3); random surface points, area-weighted
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        rng = np.random.default_rng(0)
        pick = rng.choice(len(f), n_points, p=area / area.sum()) if area.sum() > 0 else rng.choice(len(f), n_points)
        r = rng.random((n_points, 2))
        r = np.where(r.sum(1, keepdims=True) > 1, 1 - r, r)
        points = tri[pick, 0] + r[:, :1] * (tri[pick, 1] - tri[pick, 0]) + r[:, 1:] * (tri[pick, 2] - tri[pick, 0])
    else:
        box = np.asarray(as_numpy(shape), float).reshape(-1)
        if box.shape != (6,):
            raise ValueError(f"give a mesh, a ShapeGrid or a box (6,) = (min xyz, max xyz), got shape {box.shape}")
        lo, hi = box[:3], box[3:]
    return lo, hi, points


def _draw_planes(ax, lo, hi, ext, ui: int) -> None:
    """Each triplane plane as a tinted quad on the box wall it is named after, labelled just outside the box."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    colors = {"xy": "tab:blue", "xz": "tab:green", "yz": "tab:orange"}
    for name in PLANES:
        u, v = PLANE_AXES[name]
        m = 3 - u - v
        color = colors[name]
        quad = np.zeros((4, 3))
        quad[:, u] = [lo[u], hi[u], hi[u], lo[u]]
        quad[:, v] = [lo[v], lo[v], hi[v], hi[v]]
        quad[:, m] = lo[m]
        ax.add_collection3d(Poly3DCollection([quad], facecolor=color, edgecolor=color, alpha=0.25, lw=1.5))
        spot = quad.mean(0)  # the label sits just outside the box, next to its wall
        if m == ui:  # the floor: in front of its front edge
            front = [k for k in range(3) if k not in (u, v, ui)] or [v]
            spot[front[0]] = hi[front[0]] + 0.25 * ext.max()
        elif ui in (u, v):  # a wall: above its top edge
            spot[ui] = hi[ui] + 0.12 * ext.max()
        style = dict(color=color, fontsize=10, ha="center", va="center", fontweight="bold", zorder=10)
        ax.text(*spot, f"{name} plane\n(mean over {AXES[m]})", **style)


def _draw_axes_triad(ax, lo, hi, ext, ui: int) -> None:
    """The x, y, z arrows, standing off the box's corner."""
    start = lo.copy()  # outside the box, off its corner at (min, min, max of the third)
    third = [a for a in range(3) if a not in (0, ui)][0]
    start[third] = hi[third] + 0.15 * ext.max()
    start[0] -= 0.15 * ext.max()
    for k in range(3):
        d = np.zeros(3)
        d[k] = 0.3 * ext.max()
        ax.quiver(*start, *d, color="crimson", lw=1.5, arrow_length_ratio=0.2)
        ax.text(
            *(start + 1.18 * d), AXES[k] + (" (up)" if k == ui else ""), color="crimson", fontsize=11, fontweight="bold"
        )


def _describe_views(fig, gs, ui: int) -> None:
    """The text panel: how the 2D figures orient each plane and each grid slice."""
    lines = ["How the 2D figures draw each plane", "(first axis →, second ↑):", ""]
    lines += [f"{name}: {_view_words(name, ui)}" for name in PLANES]
    lines += ["", f"Grid slices ({AXES[ui]} drawn vertically):", ""]
    lines += [_slice_words(a, ui) for a in range(3)]
    text = fig.add_subplot(gs[0, 1])
    text.set_axis_off()
    text.text(0.0, 0.5, "\n".join(lines), fontsize=9, va="center", ha="left", transform=text.transAxes)
    fig.suptitle(f"the three planes on the shape's box ({AXES[ui]} up)", fontsize=10)


def plot_triplane_conv(parts: dict, plane: str = "xy", batch: int = 0, channel: int | None = None) -> Figure:
    """One TriplaneConv's rollout for ``plane`` (the paper's Fig. 3b), from :func:`sin3dm_lite.model.unet.rollout_parts`.

    Columns: this plane and the two others. Top: the three planes. Middle: the others mean-pooled over the
    axis this plane lacks. Bottom: those expanded to this plane's size, and on the left the concatenation
    ``[plane, expanded, expanded]`` (3C channels) that this plane's Conv2d reads. Colours: PCA, one basis per
    column; with ``channel`` = c, that channel in grey per column and the concatenation's c, C+c, 2C+c as RGB.
    """
    if plane not in PLANES:
        raise ValueError(f"plane must be one of {PLANES}, got {plane!r}")
    part = parts[plane]
    n_channels = int(part["plane"].shape[1])
    if channel is not None and not 0 <= channel < n_channels:
        raise ValueError(f"channel must be from 0 to {n_channels - 1}, got {channel}")
    u, v = PLANE_AXES[plane]
    lacking = part["axis"]
    fig = new_figure(10.0, 8.0)
    gs = fig.add_gridspec(3, 3, height_ratios=[1.0, 0.55, 1.0])
    own = as_numpy(part["plane"][batch])
    mean, basis = pca_basis(own)
    title = f"{plane}: this plane, C = {own.shape[0]}" + ("" if channel is None else f", channel {channel}")
    _conv_panel(fig.add_subplot(gs[0, 0]), _conv_colours(own, mean, basis, own, channel), title, (u, v))
    note = fig.add_subplot(gs[1, 0])
    note.set_axis_off()
    words = f"{plane} is kept as it is;\nthe other two planes are\naveraged over {lacking},\nthe axis {plane} lacks"
    note.text(0.5, 0.5, words, ha="center", va="center", fontsize=9, transform=note.transAxes)
    _conv_concatenation(fig.add_subplot(gs[2, 0]), as_numpy(part["input"][batch]), plane, channel, n_channels)
    for c, (other, pooled, expanded) in enumerate(zip(part["sources"], part["pooled"], part["expanded"]), start=1):
        arrays = [as_numpy(x[batch]) for x in (parts[other]["plane"], pooled, expanded)]
        _conv_source_column(fig, [gs[r, c] for r in range(3)], (plane, other, lacking), *arrays, channel)
    fig.suptitle(
        f"TriplaneConv on {plane}: Conv2d(concat[{plane}, mean_{lacking}({part['sources'][0]}), "
        f"mean_{lacking}({part['sources'][1]})])",
        fontsize=10,
    )
    return fig


def _conv_colours(arr, m_, b_, ref, channel: int | None) -> np.ndarray:
    """``[C, A, B]`` → ``(A, B, 3)``: PCA with the basis ``(m_, b_)``, or ``channel`` in grey on ``ref``'s scale."""
    if channel is None:
        return pca_project(arr, m_, b_)
    lo, hi = float(ref[channel].min()), float(ref[channel].max())
    return np.repeat(np.clip((arr[channel] - lo) / (hi - lo + 1e-8), 0, 1)[..., None], 3, axis=-1)


def _conv_panel(ax, img, title, axes_uv):
    """One plane of :func:`plot_triplane_conv`, its axes named."""
    show_image(ax, img)
    ax.set_title(title, fontsize=9)
    label_axes(ax, *axes_uv)


def _conv_concatenation(ax, cat: np.ndarray, plane: str, channel: int | None, n_channels: int) -> None:
    """The ``[plane, expanded, expanded]`` input of the plane's Conv2d: PCA, or channels c, C+c, 2C+c as RGB."""
    if channel is None:
        cat_img, cat_note = pca_project(cat, *pca_basis(cat)), ""
    else:
        picked = cat[[channel, n_channels + channel, 2 * n_channels + channel]]
        lo, hi = picked.min(axis=(1, 2), keepdims=True), picked.max(axis=(1, 2), keepdims=True)
        cat_img = np.moveaxis((picked - lo) / (hi - lo + 1e-8), 0, -1)
        cat_note = f"\nchannels {channel}, {n_channels + channel}, {2 * n_channels + channel} as RGB"
    title = f"concatenated: {cat.shape[0]} = 3C channels\n→ the Conv2d of {plane}" + cat_note
    _conv_panel(ax, cat_img, title, PLANE_AXES[plane])


def _conv_source_column(fig: Figure, cells, names: tuple[str, str, str], src, vec, expanded, channel) -> None:
    """One of the other planes (``names``: this plane, the other, the axis this one lacks) in the three ``cells``:
    itself, its mean over the lacking axis (``vec``: ``[C, A, 1]`` or ``[C, 1, B']``), that expanded to this plane."""
    plane, other, lacking = names
    u, v = PLANE_AXES[plane]
    m_, b_ = pca_basis(src)
    title = f"{other}: averaged over {lacking} ↓"
    _conv_panel(fig.add_subplot(cells[0]), _conv_colours(src, m_, b_, src, channel), title, PLANE_AXES[other])
    along = u if vec.shape[2] == 1 else v
    ax = fig.add_subplot(cells[1])
    show_image(ax, _conv_colours(vec, m_, b_, src, channel), aspect="auto")
    ax.set_title(f"mean over {lacking} of {other}:\na feature per {AXES[along]}, {list(vec.shape)}", fontsize=9)
    if along == u:
        ax.set_xlabel(AXES[u], fontsize=8)
        ax.set_yticks([])
    else:
        ax.set_ylabel(AXES[v], fontsize=8)
        ax.set_xticks([])
    ax.tick_params(labelsize=7)
    across = v if along == u else u
    title = f"expanded along {AXES[across]} to {plane}'s size"
    _conv_panel(fig.add_subplot(cells[2]), _conv_colours(expanded, m_, b_, src, channel), title, (u, v))


def _rf_draw(ax, rf_map: np.ndarray, analytic_width: float | None, vmin: float, center=None):
    rf = np.asarray(rf_map, np.float64)
    a, b = rf.shape
    ca, cb = (a // 2, b // 2) if center is None else center
    cmap = plt.get_cmap("magma")
    cmap = cmap.with_extremes(bad=cmap(0.0))  # exact zeros (no influence at all) in the darkest colour
    positive = np.where(rf > 0, rf, np.nan)
    im = show_image(ax, positive, cmap=cmap, norm=LogNorm(vmin=vmin, vmax=1.0), extent=(-0.5, a - 0.5, -0.5, b - 0.5))
    ax.plot([ca], [cb], marker="+", color="cyan", ms=10, mew=1.5)
    if analytic_width:
        w = float(analytic_width)
        ax.add_patch(Rectangle((ca - w / 2, cb - w / 2), w, w, fill=False, ec="cyan", lw=1.2, ls="--"))
    return im


RF_LEVEL = 1e-2  # where figures cut the field: above the plane-wide coupling (GroupNorm, cross-plane means)


def measured_width(rf_map: np.ndarray, level: float = RF_LEVEL, center=None) -> int:
    """Side of the smallest centred square holding every texel with ``rf >= level`` (the measured field)."""
    rf = np.asarray(rf_map)
    a, b = rf.shape
    ca, cb = (a // 2, b // 2) if center is None else center
    ia, ib = np.nonzero(rf >= level)
    if len(ia) == 0:
        return 0
    return int(2 * max(np.abs(ia - ca).max(), np.abs(ib - cb).max()) + 1)


def plot_receptive_field(
    rf_map: np.ndarray,
    analytic_width: float | None = None,
    title: str | None = None,
    ax=None,
    vmin: float = 1e-5,
    center: tuple[int, int] | None = None,
    level: float = RF_LEVEL,
) -> Figure:
    """The measured receptive field of one output texel on a log colour scale (into ``ax`` when given).

    ``rf_map`` is ``|∂ output[centre] / ∂ input|`` over one plane ``[A, B]``, maximum 1; the log scale (down to
    ``vmin``) shows the weak plane-wide coupling beside the local field. The cross marks the centre texel
    (``(A//2, B//2)`` unless given), the dashed square the analytic width; the title gives the measured width.
    """
    if ax is None:
        fig = new_figure(4.4, 3.8)
        ax = fig.subplots()
    fig = ax.figure
    im = _rf_draw(ax, rf_map, analytic_width, vmin, center)
    fig.colorbar(im, ax=ax, shrink=0.85, label="|gradient| (max 1)")
    info = f"measured (≥{level:g}) {measured_width(rf_map, level, center)} texels"
    if analytic_width:
        info = f"analytic {analytic_width:g} · " + info
    ax.set_title(f"{title}\n{info}" if title else info, fontsize=9)
    return fig


def plot_receptive_fields(
    items: Sequence[tuple[str, np.ndarray, float | None]], vmin: float = 1e-5, level: float = RF_LEVEL
) -> Figure:
    """Several receptive fields side by side on one log scale: ``[(label, rf_map, analytic_width), ...]``."""
    fig = new_figure(3.6 * len(items) + 0.8, 3.8)
    panels = fig.subplots(1, len(items), squeeze=False)[0]
    im = None
    for ax, (label, rf, width) in zip(panels, items):
        im = _rf_draw(ax, rf, width, vmin)
        extra = f"analytic {width:g} · " if width else ""
        ax.set_title(f"{label}\n{extra}measured (≥{level:g}) {measured_width(rf, level)}", fontsize=9)
    fig.colorbar(im, ax=panels.tolist(), shrink=0.85, label="|gradient| (max 1)")
    return fig

"""Matplotlib figures for every stage: grid slices, triplanes, losses, denoising, receptive fields;
and static pictures of meshes (``plot_meshes``, rendered by :mod:`sin3dm_lite.render`) to put beside k3d viewers.

Every function takes plain data (numpy arrays, :class:`~sin3dm_lite.grid.ShapeGrid`,
:class:`~sin3dm_lite.triplane.Triplane`) and *returns* a ``matplotlib.figure.Figure``;
nothing here calls ``plt.show``. The figures are removed from pyplot's list of
open figures as soon as they are made, so in Jupyter each one appears exactly
once, as the value of the cell (``fig = plot_slice(...)``; ``fig``), and a
script saves it with ``fig.savefig(path)``. The widgets in
:mod:`sin3dm_lite.widgets` call these same functions.

Orientation used by every 2D picture of the volume (slices, triplane planes,
receptive fields): the *first* remaining axis runs to the right and the
second one runs up (``imshow(..., origin="lower")`` of the transposed array).
A slice across z therefore shows x → and y ↑, the same view as the xy plane of
a triplane.
"""
from __future__ import annotations

from typing import Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from ..data.grid import ShapeGrid
from ..model.triplane import PLANE_AXES, PLANES, Triplane, pca_basis, pca_project, plane_to_image

AXES = ("x", "y", "z")
SDF_CMAP = "RdBu"  # red inside (negative), blue outside
NEUTRAL = np.array([0.82, 0.82, 0.82], np.float32)  # background where the colour grid is undefined


# --------------------------------------------------------------------------- helpers
def _figure(width: float, height: float) -> Figure:
    """A new figure that pyplot does not keep open (so Jupyter shows it once, as the cell's value)."""
    fig = plt.figure(figsize=(width, height), layout="constrained")
    plt.close(fig)
    return fig


def _panel_height(width: float, aspect: float, title: float = 0.45) -> float:
    """Height (inches) of a panel ``width`` wide showing an image of ``aspect`` = height / width, plus its title."""
    return float(np.clip(width * aspect, 0.35 * width, 1.6 * width)) + title


def _axis_index(axis: int | str) -> int:
    if isinstance(axis, str):
        if axis not in AXES:
            raise ValueError(f"axis must be one of {AXES} or 0/1/2, got {axis!r}")
        return AXES.index(axis)
    if axis not in (0, 1, 2):
        raise ValueError(f"axis must be one of {AXES} or 0/1/2, got {axis!r}")
    return int(axis)


def _numpy(x) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def grid_slice(volume: np.ndarray, axis: int | str, index: int | None = None) -> tuple[np.ndarray, int]:
    """``volume[..., index, ...]`` across ``axis`` (middle slice when ``index`` is None) and the index used.

    Works on ``(H, W, D)`` and ``(H, W, D, K)`` arrays; the result keeps the two other
    axes in order (e.g. ``(H, W)`` for ``axis="z"``).
    """
    a = _axis_index(axis)
    n = volume.shape[a]
    index = n // 2 if index is None else int(index)
    if not 0 <= index < n:
        raise IndexError(f"slice index {index} is outside 0..{n - 1} along {AXES[a]}")
    return np.take(volume, index, axis=a), index


def _plane_axes(axis: int, up: int | str | None = None) -> tuple[int, int]:
    """The two axes a slice across ``axis`` shows, (→, ↑): in order, unless ``up`` is the first one."""
    u, v = [k for k in range(3) if k != axis]
    if up is not None and _axis_index(up) == u:
        u, v = v, u
    return u, v


def _extent(grid: ShapeGrid, axis: int, up: int | str | None = None) -> tuple[float, float, float, float]:
    """World extent of a slice drawn with axis ``u`` → and ``v`` ↑ (see :func:`_plane_axes`)."""
    u, v = _plane_axes(axis, up)
    return (float(grid.aabb[u]), float(grid.aabb[u + 3]), float(grid.aabb[v]), float(grid.aabb[v + 3]))


def _show(ax, image: np.ndarray, **kwargs):
    """Draw a 2D (or 2D×3 RGB) array with axis 0 to the right and axis 1 up."""
    img = np.swapaxes(image, 0, 1)
    return ax.imshow(img, origin="lower", interpolation="nearest", **kwargs)


def _slice_title(grid: ShapeGrid, axis: int, index: int, kind: str) -> str:
    coord = float(grid.axis_coords(axis)[index])
    return f"{kind} · {AXES[axis]} = {index} ({AXES[axis]} = {coord:+.3f})"


def color_slice_image(grid: ShapeGrid, axis: int | str, index: int | None = None) -> np.ndarray:
    """RGB slice of the colour grid, :data:`NEUTRAL` grey where ``|sdf| >= threshold`` (colour undefined there)."""
    sdf, index = grid_slice(grid.sdf, axis, index)
    col, _ = grid_slice(grid.color, axis, index)
    rgb = np.clip(col[..., :3], 0.0, 1.0).astype(np.float32)
    band = np.abs(sdf) < grid.threshold
    return np.where(band[..., None], rgb, NEUTRAL)


def _draw_slice(ax, grid: ShapeGrid, axis: int, index: int, kind: str, threshold_lines: bool = True,
                up: int | str | None = None):
    u, v = _plane_axes(axis, up)
    swap = u > v  # the slice array keeps the remaining axes in order; put `up` vertical
    ext = _extent(grid, axis, up)
    sdf, index = grid_slice(grid.sdf, axis, index)
    sdf = sdf.T if swap else sdf
    if kind == "sdf":
        im = _show(ax, sdf, cmap=SDF_CMAP, vmin=-grid.threshold, vmax=grid.threshold, extent=ext)
    elif kind == "color":
        rgb = color_slice_image(grid, axis, index)
        im = _show(ax, rgb.swapaxes(0, 1) if swap else rgb, extent=ext)
    else:
        raise ValueError(f"kind must be 'sdf' or 'color', got {kind!r}")
    _contours(ax, grid, (u, v), sdf, threshold_lines)
    ax.set_xlabel(AXES[u])
    ax.set_ylabel(AXES[v])
    ax.set_title(_slice_title(grid, axis, index, kind), fontsize=9)
    return im


def _contours(ax, grid: ShapeGrid, uv: tuple[int, int], sdf: np.ndarray, threshold_lines: bool) -> None:
    """Zero level (solid) and, optionally, the edges of the truncation band (dashed); ``sdf`` is ``(u, v)``."""
    u, v = uv
    if sdf.min() < 0 < sdf.max():
        ax.contour(grid.axis_coords(u), grid.axis_coords(v), sdf.T, levels=[0.0], colors="k", linewidths=1.0)
    if threshold_lines:
        t = 0.98 * grid.threshold  # the band's edge (the sdf is flat at ±threshold beyond it)
        levels = [lv for lv in (-t, t) if sdf.min() < lv < sdf.max()]
        if levels:
            ax.contour(grid.axis_coords(u), grid.axis_coords(v), sdf.T, levels=levels,
                       colors="0.3", linewidths=0.6, linestyles="--")


# --------------------------------------------------------------------------- grids
def plot_grid_slices(
    grid: ShapeGrid,
    index: int | Sequence[int] | None = None,
    axes: Sequence[str] = ("x", "y", "z"),
    show_color: bool = True,
    threshold_lines: bool = True,
    up: str | None = "y",
) -> Figure:
    """TSDF slices across each axis (top row) and the colour slice under each (bottom row).

    The SDF uses a diverging colour map centred on 0 with limits ``±threshold``
    (red inside, blue outside); the black line is the surface (zero level) and
    the dashed lines, with ``threshold_lines``, the edges of the truncation band.
    The colour grid is only defined inside the band; outside it is drawn in
    neutral grey. ``index`` is one index for every axis, one per axis, or None
    for the middle slices. Each panel shows the two other axes in order (→, ↑),
    except that the ``up`` axis (``"y"`` as in OBJ/glTF and the built-in
    examples; ``None`` to keep the order) is drawn vertically where it appears.

    Axes of the figure: one per panel (``len(axes)`` or ``2 * len(axes)``) plus
    one shared colour bar.
    """
    ax_ids = [_axis_index(a) for a in axes]
    if index is None or np.isscalar(index):
        indices = [index] * len(ax_ids)
    else:
        indices = list(index)
        if len(indices) != len(ax_ids):
            raise ValueError(f"give one index per axis ({len(ax_ids)}), got {len(indices)}")
    rows = 2 if show_color else 1
    fig = _figure(3.3 * len(ax_ids) + 0.8, 3.0 * rows)
    panels = fig.subplots(rows, len(ax_ids), squeeze=False)
    im = None
    for col, (a, i) in enumerate(zip(ax_ids, indices)):
        im = _draw_slice(panels[0, col], grid, a, i, "sdf", threshold_lines, up)
        if show_color:
            _draw_slice(panels[1, col], grid, a, i, "color", threshold_lines, up)
    fig.colorbar(im, ax=panels[0, :].tolist(), label="truncated SDF", shrink=0.9)
    fig.suptitle(f"{grid.name}: grid {grid.shape}, threshold {grid.threshold:.4f} "
                 f"({grid.threshold / grid.voxel_size:.1f} voxels)", fontsize=10)
    return fig


def plot_slice(grid: ShapeGrid, axis: int | str = "z", index: int | None = None, kind: str = "sdf",
               threshold_lines: bool = True, up: str | None = "y") -> Figure:
    """One panel: the SDF (``kind="sdf"``) or colour (``kind="color"``) slice across ``axis`` at ``index``.

    ``up`` is drawn vertically when it is one of the panel's axes (see :func:`plot_grid_slices`).

    This is what :func:`sin3dm_lite.widgets.slice_explorer` redraws when its slider moves.
    """
    a = _axis_index(axis)
    fig = _figure(4.2, 3.6)
    ax = fig.subplots()
    im = _draw_slice(ax, grid, a, index, kind, threshold_lines, up)
    if kind == "sdf":
        fig.colorbar(im, ax=ax, shrink=0.85)
    return fig


def plot_truncation(
    grid: ShapeGrid | np.ndarray,
    thresholds: Sequence[float] | None = None,
    axis: int | str = "z",
    index: int | None = None,
) -> Figure:
    """What the truncation threshold does: an SDF clipped at several thresholds (in voxels).

    Given a :class:`ShapeGrid`, its SDF is re-clipped at each threshold
    (default: 1, 2 and the grid's own). That SDF is *already* truncated at
    ``grid.threshold``, so only thresholds up to that one can be shown honestly
    (a larger one would need the untruncated distance, which the grid no longer
    has): larger values raise ``ValueError``. Given a plain ``(X, Y, Z)`` array
    instead (an untruncated SDF on the ``±n_axis / n_max`` box), any threshold works.

    Top: the SDF along one line through the middle of the slice (along the
    slice's first remaining axis) for each threshold; the flat parts are where
    the distance was clipped. Below: the slice at each threshold, on one
    colour scale (± the largest threshold).
    """
    if not isinstance(grid, ShapeGrid):
        field = np.asarray(_numpy(grid), np.float32)
        half = np.array(field.shape, np.float64) / max(field.shape)
        grid = ShapeGrid(field, np.zeros((1, 1, 1, 3), np.float32), np.concatenate([-half, half]),
                         float(np.abs(field).max()), None, name="sdf")  # type: ignore[arg-type]
    a = _axis_index(axis)
    own = grid.threshold / grid.voxel_size
    if thresholds is None:
        thresholds = [t for t in (1.0, 2.0) if t < own] + [own]
    thresholds = [float(t) for t in thresholds]
    too_big = [t for t in thresholds if t > own + 1e-6]
    if too_big:
        raise ValueError(
            f"thresholds {too_big} exceed the grid's own truncation ({own:.2f} voxels): the grid stores "
            f"the SDF clipped at ±{grid.threshold:.4f}, so larger thresholds cannot be reconstructed"
        )
    sdf, index = grid_slice(grid.sdf, a, index)
    u, v = [k for k in range(3) if k != a]
    line = sdf.shape[1] // 2  # the row through the middle of the slice, along axis u
    coords = grid.axis_coords(u)

    fig = _figure(max(3.0 * len(thresholds), 6.0), 6.0)
    gs = fig.add_gridspec(2, len(thresholds), height_ratios=[1.0, 1.3])
    prof = fig.add_subplot(gs[0, :])
    vmax = max(thresholds) * grid.voxel_size
    im = None
    for k, t in enumerate(thresholds):
        tw = t * grid.voxel_size
        clipped = np.clip(sdf, -tw, tw)
        prof.plot(coords, clipped[:, line], drawstyle="steps-mid", label=f"{t:g} voxels")
        ax = fig.add_subplot(gs[1, k])
        im = _show(ax, clipped, cmap=SDF_CMAP, vmin=-vmax, vmax=vmax, extent=_extent(grid, a))
        if clipped.min() < 0 < clipped.max():
            ax.contour(coords, grid.axis_coords(v), clipped.T, levels=[0.0], colors="k", linewidths=0.8)
        ax.axhline(float(grid.axis_coords(v)[line]), color="0.2", lw=0.6, ls=":")
        ax.set_title(f"threshold {t:g} vox ({tw:.4f})", fontsize=9)
        ax.set_xlabel(AXES[u])
        ax.set_ylabel(AXES[v])
    prof.axhline(0.0, color="k", lw=0.6)
    prof.set_xlabel(AXES[u])
    prof.set_ylabel("SDF")
    prof.set_title(f"SDF along {AXES[u]} at {AXES[v]} = {grid.axis_coords(v)[line]:+.3f} "
                   f"(slice {AXES[a]} = {index})", fontsize=9)
    prof.legend(fontsize=8, loc="upper right")
    fig.colorbar(im, ax=fig.axes[1:], shrink=0.8)
    return fig


def _box_outline(ax, grid: ShapeGrid, u: int, v: int) -> None:
    lo_u, hi_u, lo_v, hi_v = grid.aabb[u], grid.aabb[u + 3], grid.aabb[v], grid.aabb[v + 3]
    ax.add_patch(Rectangle((lo_u, lo_v), hi_u - lo_u, hi_v - lo_v, fill=False, ec="k", lw=1.0))


def plot_points(grid: ShapeGrid, n: int = 4000, seed: int = 0) -> Figure:
    """The near-surface training points projected on the xy, xz and yz planes, coloured by their SDF.

    A random subset of ``n`` points (fixed ``seed``) is drawn so the picture
    stays readable; the rectangle is the grid's bounding box.
    """
    pts = np.asarray(grid.points, np.float32).reshape(-1, 3)
    sdf = np.asarray(grid.point_sdf, np.float32).reshape(-1)
    if len(pts) > n:
        sel = np.random.default_rng(seed).choice(len(pts), size=n, replace=False)
        pts, sdf = pts[sel], sdf[sel]
    fig = _figure(11.0, 3.8)
    panels = fig.subplots(1, 3)
    sc = None
    for ax, name in zip(panels, PLANES):
        u, v = PLANE_AXES[name]
        sc = ax.scatter(pts[:, u], pts[:, v], c=sdf, s=2, cmap=SDF_CMAP, vmin=-grid.threshold, vmax=grid.threshold)
        _box_outline(ax, grid, u, v)
        pad = 0.05 * float(grid.aabb[3:].max())
        ax.set_xlim(grid.aabb[u] - pad, grid.aabb[u + 3] + pad)
        ax.set_ylim(grid.aabb[v] - pad, grid.aabb[v + 3] + pad)
        ax.set_aspect("equal")
        ax.set_xlabel(AXES[u])
        ax.set_ylabel(AXES[v])
        ax.set_title(f"{name} projection", fontsize=9)
    fig.colorbar(sc, ax=panels.tolist(), label="point SDF", shrink=0.85)
    fig.suptitle(f"{len(pts)} of {len(grid.points)} near-surface training points", fontsize=10)
    return fig


# --------------------------------------------------------------------------- triplanes
def triplane_images(tp: Triplane, channels: str | int = "pca", batch: int = 0) -> list[np.ndarray]:
    """The three planes of sample ``batch`` as ``(A, B, 3)`` images (see :func:`plane_to_image`)."""
    return [plane_to_image(p[batch], channels) for p in tp.planes]


def plot_triplane(
    tp: Triplane,
    channels: str | int | Sequence[int] = "pca",
    titles: bool = True,
    batch: int = 0,
) -> Figure:
    """The xy, xz and yz feature planes side by side, at their true relative sizes.

    ``channels="pca"`` colours each plane by its first three principal
    components (each plane has its own basis, so compare structure, not hue);
    an ``int`` shows one channel in grey; a list of ints draws one row per
    channel. The plane ``xy [X, Y]`` is drawn with x → and y ↑ (the same view
    as a z slice of the grid), ``xz`` with x → and z ↑, ``yz`` with y → and z ↑.
    """
    rows = list(channels) if isinstance(channels, (list, tuple)) else [channels]
    x, y, z = tp.resolution
    widths, heights = [x, x, y], [y, z, z]
    scale = 9.0 / sum(widths)
    fig = _figure(9.5, max(1.6, (max(heights) * scale + 0.5)) * len(rows))
    panels = fig.subplots(len(rows), 3, squeeze=False, gridspec_kw={"width_ratios": widths})
    for r, ch in enumerate(rows):
        for c, (name, img) in enumerate(zip(PLANES, triplane_images(tp, ch, batch))):
            ax = panels[r, c]
            _show(ax, img)
            u, v = PLANE_AXES[name]
            ax.set_xlabel(AXES[u], fontsize=8)
            ax.set_ylabel(AXES[v], fontsize=8)
            ax.tick_params(labelsize=7)
            if titles:
                label = "PCA" if ch == "pca" else f"channel {ch}"
                ax.set_title(f"{name} {tuple(img.shape[:2])} · {label}", fontsize=9)
    return fig


def _view_words(name: str, up: int) -> str:
    """How a picture of plane ``name`` (first axis →, second ↑) looks at the shape when axis ``up`` is vertical."""
    u, v = PLANE_AXES[name]
    lacking = 3 - u - v
    if lacking == up:
        return f"seen from above ({AXES[u]} →, {AXES[v]} ↑)"
    side = f"a side view along {AXES[lacking]}"
    if v == up:
        return f"{side} ({AXES[u]} →, {AXES[v]} ↑: upright)"
    return f"{side} ({AXES[u]} →, {AXES[v]} ↑):\n    on its side, the height {AXES[up]} runs →"


def _slice_words(axis: int, up: int) -> str:
    u, v = _plane_axes(axis, up)
    kind = "horizontal" if axis == up else "vertical"
    return f"slice across {AXES[axis]} ({kind}): {AXES[u]} →, {AXES[v]} ↑"


def plot_plane_axes(shape=None, up: str = "y", n_points: int = 4000, azim: float = 30.0) -> Figure:
    """The three triplane planes drawn on the shape's box, labelled, with the x, y, z axes and ``up`` vertical.

    ``shape`` is a mesh (``TexturedMesh``, ``trimesh.Trimesh`` or anything with
    ``vertices`` and ``faces``; drawn as ``n_points`` points on its surface), a
    :class:`ShapeGrid` (its box and ``n_points`` of its near-surface points) or a box ``(6,)`` array
    ``(min xyz, max xyz)``; None draws a unit cube. Each plane sits on the box face
    it is named after (xy on the back wall z = min, xz on the floor y = min,
    yz on the left wall x = min): the encoder averages the volume onto it along
    the third axis. The text beside the box says how the package's 2D figures
    orient each plane (first axis →, second ↑, see :func:`plot_triplane`) and each
    grid slice (:func:`plot_grid_slices`, the ``up`` axis vertical), which the
    three view names follow from.
    """
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    ui = _axis_index(up)
    points = None
    if shape is None:
        lo, hi = -np.ones(3), np.ones(3)
    elif isinstance(shape, ShapeGrid):
        lo, hi = np.asarray(shape.aabb[:3], float), np.asarray(shape.aabb[3:], float)
        pts = np.asarray(shape.points, float).reshape(-1, 3)
        points = pts[np.random.default_rng(0).choice(len(pts), min(len(pts), n_points), replace=False)] if len(pts) else None
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
        box = np.asarray(_numpy(shape), float).reshape(-1)
        if box.shape != (6,):
            raise ValueError(f"give a mesh, a ShapeGrid or a box (6,) = (min xyz, max xyz), got shape {box.shape}")
        lo, hi = box[:3], box[3:]
    ext = np.maximum(hi - lo, 1e-9)

    fig = _figure(10.0, 5.2)
    gs = fig.add_gridspec(1, 2, width_ratios=[1.5, 1.0])
    ax = fig.add_subplot(gs[0, 0], projection="3d")
    if points is not None:  # the shape, shaded by height
        ax.scatter(*points.T, s=1.5, c=points[:, ui], cmap="Greys", vmin=lo[ui] - 0.6 * ext[ui], vmax=hi[ui],
                   alpha=0.7, depthshade=False)
    corners = np.array([[lo[0] if i & 1 == 0 else hi[0], lo[1] if i & 2 == 0 else hi[1], lo[2] if i & 4 == 0 else hi[2]]
                        for i in range(8)])
    for i in range(8):
        for bit in (1, 2, 4):
            if not i & bit:
                ax.plot(*corners[[i, i | bit]].T, color="k", lw=0.6)
    colors = {"xy": "tab:blue", "xz": "tab:green", "yz": "tab:orange"}
    for name in PLANES:
        u, v = PLANE_AXES[name]
        m = 3 - u - v
        quad = np.zeros((4, 3))
        for k, (a, b) in enumerate(((0, 0), (1, 0), (1, 1), (0, 1))):
            quad[k, u] = (lo[u], hi[u])[a]
            quad[k, v] = (lo[v], hi[v])[b]
            quad[k, m] = lo[m]
        ax.add_collection3d(Poly3DCollection([quad], facecolor=colors[name], edgecolor=colors[name], alpha=0.25, lw=1.5))
        spot = quad.mean(0)  # the label sits just outside the box, next to its wall
        if m == ui:  # the floor: in front of its front edge
            front = [k for k in range(3) if k not in (u, v, ui)] or [v]
            spot[front[0]] = hi[front[0]] + 0.25 * ext.max()
        elif ui in (u, v):  # a wall: above its top edge
            spot[ui] = hi[ui] + 0.12 * ext.max()
        ax.text(*spot, f"{name} plane\n(mean over {AXES[m]})", color=colors[name], fontsize=10, ha="center",
                va="center", fontweight="bold", zorder=10)
    arrow = 0.3 * ext.max()
    for k in range(3):
        d = np.zeros(3)
        d[k] = arrow
        start = lo.copy()  # the triad stands outside the box, off its corner at (min, min, max of the third)
        third = [a for a in range(3) if a not in (0, ui)][0]
        start[third] = hi[third] + 0.15 * ext.max()
        start[0] -= 0.15 * ext.max()
        ax.quiver(*start, *d, color="crimson", lw=1.5, arrow_length_ratio=0.2)
        ax.text(*(start + 1.18 * d), AXES[k] + (" (up)" if k == ui else ""), color="crimson", fontsize=11,
                fontweight="bold")
    pad = 0.15 * ext.max()
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_zlim(lo[2] - pad, hi[2] + pad)
    ax.set_box_aspect(tuple(np.roll(ext + 2 * pad, 2 - ui)))  # with vertical_axis, matplotlib reads it rolled
    ax.view_init(elev=22, azim=azim, vertical_axis=AXES[ui])  # x → (a little back), up ↑, the third axis towards us
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    ax.tick_params(labelsize=7)

    lines = ["How the 2D figures draw each plane", "(first axis →, second ↑):", ""]
    for name in PLANES:
        lines += [f"{name}: {_view_words(name, ui)}"]
    lines += ["", f"Grid slices ({AXES[ui]} drawn vertically):", ""]
    lines += [_slice_words(a, ui) for a in range(3)]
    text = fig.add_subplot(gs[0, 1])
    text.set_axis_off()
    text.text(0.0, 0.5, "\n".join(lines), fontsize=9, va="center", ha="left", transform=text.transAxes)
    fig.suptitle(f"the three planes on the shape's box ({AXES[ui]} up)", fontsize=10)
    return fig


def plot_triplane_conv(parts: dict, plane: str = "xy", batch: int = 0, channel: int | None = None) -> Figure:
    """One TriplaneConv's rollout for ``plane`` (the paper's Fig. 3b), from :func:`sin3dm_lite.unet.rollout_parts`.

    Columns: this plane, and each of the two other planes. Top row: the three
    planes, each in its own orientation (first axis →, second ↑). Middle: the two
    others mean-pooled over the axis this plane lacks, a feature per texel of
    the axis they share with it, drawn along that axis. Bottom: those features
    expanded (repeated) to this plane's size, and on the left the concatenation
    ``[plane, expanded, expanded]`` (3C channels) that this plane's Conv2d reads.
    Colours: PCA, one basis per column (fitted on the top row's plane; the
    concatenation has its own). With ``channel`` = c: that channel in grey, on
    one scale per column (its plane's range), and the concatenation's channels
    c, C+c, 2C+c (the plane's and the two expanded ones) as red, green, blue.
    """
    if plane not in PLANES:
        raise ValueError(f"plane must be one of {PLANES}, got {plane!r}")
    part = parts[plane]
    n_channels = int(part["plane"].shape[1])
    if channel is not None and not 0 <= channel < n_channels:
        raise ValueError(f"channel must be from 0 to {n_channels - 1}, got {channel}")

    def colours(arr, m_, b_, ref):  # [C, A, B] → (A, B, 3): PCA, or the one channel in grey on ref's scale
        if channel is None:
            return pca_project(arr, m_, b_)
        lo, hi = float(ref[channel].min()), float(ref[channel].max())
        return np.repeat(np.clip((arr[channel] - lo) / (hi - lo + 1e-8), 0, 1)[..., None], 3, axis=-1)

    u, v = PLANE_AXES[plane]
    lacking = part["axis"]
    fig = _figure(10.0, 8.0)
    gs = fig.add_gridspec(3, 3, height_ratios=[1.0, 0.55, 1.0])
    own = _numpy(part["plane"][batch])
    mean, basis = pca_basis(own)

    def draw(ax, img, title, axes_uv):
        _show(ax, img)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel(AXES[axes_uv[0]], fontsize=8)
        ax.set_ylabel(AXES[axes_uv[1]], fontsize=8)
        ax.tick_params(labelsize=7)

    draw(fig.add_subplot(gs[0, 0]), colours(own, mean, basis, own),
         f"{plane}: this plane, C = {own.shape[0]}" + ("" if channel is None else f", channel {channel}"), (u, v))
    note = fig.add_subplot(gs[1, 0])
    note.set_axis_off()
    note.text(0.5, 0.5, f"{plane} is kept as it is;\nthe other two planes are\naveraged over {lacking},\n"
              f"the axis {plane} lacks", ha="center", va="center", fontsize=9, transform=note.transAxes)
    cat = _numpy(part["input"][batch])
    if channel is None:
        cat_img, cat_note = pca_project(cat, *pca_basis(cat)), ""
    else:
        picked = cat[[channel, n_channels + channel, 2 * n_channels + channel]]
        lo, hi = picked.min(axis=(1, 2), keepdims=True), picked.max(axis=(1, 2), keepdims=True)
        cat_img = np.moveaxis((picked - lo) / (hi - lo + 1e-8), 0, -1)
        cat_note = f"\nchannels {channel}, {n_channels + channel}, {2 * n_channels + channel} as RGB"
    draw(fig.add_subplot(gs[2, 0]), cat_img,
         f"concatenated: {cat.shape[0]} = 3C channels\n→ the Conv2d of {plane}" + cat_note, (u, v))
    for c, (other, pooled, expanded) in enumerate(zip(part["sources"], part["pooled"], part["expanded"]), start=1):
        src = _numpy(parts[other]["plane"][batch])
        m_, b_ = pca_basis(src)
        draw(fig.add_subplot(gs[0, c]), colours(src, m_, b_, src), f"{other}: averaged over {lacking} ↓", PLANE_AXES[other])
        vec = _numpy(pooled[batch])  # [C, A, 1] or [C, 1, B']
        along = u if vec.shape[2] == 1 else v
        ax = fig.add_subplot(gs[1, c])
        _show(ax, colours(vec, m_, b_, src), aspect="auto")
        ax.set_title(f"mean over {lacking} of {other}:\na feature per {AXES[along]}, {list(vec.shape)}", fontsize=9)
        if along == u:
            ax.set_xlabel(AXES[u], fontsize=8)
            ax.set_yticks([])
        else:
            ax.set_ylabel(AXES[v], fontsize=8)
            ax.set_xticks([])
        ax.tick_params(labelsize=7)
        across = v if along == u else u
        draw(fig.add_subplot(gs[2, c]), colours(_numpy(expanded[batch]), m_, b_, src),
             f"expanded along {AXES[across]} to {plane}'s size", (u, v))
    fig.suptitle(f"TriplaneConv on {plane}: Conv2d(concat[{plane}, mean_{lacking}({part['sources'][0]}), "
                 f"mean_{lacking}({part['sources'][1]})])", fontsize=10)
    return fig


def plot_denoising(
    intermediates: Sequence[dict],
    plane: str = "xy",
    channels: str | int = "pca",
    batch: int = 0,
    reference: Triplane | None = None,
) -> Figure:
    """The reverse process: ``x_t`` (top row) and the predicted ``x0`` (bottom row) at each recorded step.

    ``intermediates`` is the sampler's list of ``{"step", "t", "x_t", "x0"}``
    dicts (triplanes with a batch dimension; sample ``batch`` is shown). With
    ``channels="pca"`` every panel is projected on *one* PCA basis, fitted on
    ``reference``'s plane (default: the last entry's ``x0``, the final result),
    so a colour means the same feature direction in every column.
    """
    if plane not in PLANES:
        raise ValueError(f"plane must be one of {PLANES}, got {plane!r}")
    if len(intermediates) == 0:
        raise ValueError("intermediates is empty: ask the sampler to record its steps")
    k = PLANES.index(plane)

    def get(tp: Triplane) -> np.ndarray:
        return _numpy(tp.planes[k][batch])

    if channels == "pca":
        mean, basis = pca_basis(get(reference if reference is not None else intermediates[-1]["x0"]))
        to_image = lambda p: pca_project(p, mean, basis)  # noqa: E731
    else:
        to_image = lambda p: plane_to_image(p, channels)  # noqa: E731
    n = len(intermediates)
    a, b = get(intermediates[0]["x_t"]).shape[-2:]  # drawn with a → and b ↑
    fig = _figure(max(2.0 * n, 3.0), 2 * _panel_height(2.0, b / a) + 0.3)
    panels = fig.subplots(2, n, squeeze=False)
    for c, entry in enumerate(intermediates):
        for r, key in enumerate(("x_t", "x0")):
            ax = panels[r, c]
            _show(ax, to_image(get(entry[key])))
            ax.set_xticks([])
            ax.set_yticks([])
        panels[0, c].set_title(f"t = {int(entry['t'])}", fontsize=9)
    panels[0, 0].set_ylabel(f"x_t ({plane})")
    panels[1, 0].set_ylabel("predicted x0")
    return fig


# --------------------------------------------------------------------------- training curves
def moving_average(values: Sequence[float], window: int) -> np.ndarray:
    """Mean of each run of ``window`` consecutive values (length ``len(values) - window + 1``)."""
    v = np.asarray(values, np.float64)
    window = max(1, min(int(window), len(v)))
    c = np.cumsum(np.insert(v, 0, 0.0))
    return (c[window:] - c[:-window]) / window


def plot_losses(history, log: bool = True, title: str | None = None, window: int | None = None) -> Figure:
    """Training curves: each series raw (thin, faint) and its moving average (thick).

    ``history`` is a list of floats or a dict ``name -> list of floats``;
    ``window`` defaults to 1/50 of the run (at least 1). The y axis is
    logarithmic when ``log`` and every value is positive.
    """
    series = history if isinstance(history, dict) else {"loss": history}
    fig = _figure(6.0, 3.6)
    ax = fig.subplots()
    all_positive = True
    for k, (name, values) in enumerate(series.items()):
        v = np.asarray([float(x) for x in values], np.float64)
        if len(v) == 0:
            continue
        all_positive &= bool(np.all(v > 0))
        color = f"C{k}"
        steps = np.arange(len(v))
        ax.plot(steps, v, color=color, lw=0.6, alpha=0.35)
        w = window or max(1, len(v) // 50)
        ma = moving_average(v, w)
        ax.plot(steps[w - 1:] if w <= len(v) else steps[-1:], ma, color=color, lw=2.0, label=f"{name} (avg {w})")
    if log and all_positive:
        ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("loss")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title)
    return fig


def plot_schedule(alphas_cumprod, betas) -> Figure:
    """The noise schedule: ``β_t`` (left) and ``ᾱ_t``, ``√ᾱ_t`` (signal), ``√(1-ᾱ_t)`` (noise) (right)."""
    ac = _numpy(alphas_cumprod).astype(np.float64)
    b = _numpy(betas).astype(np.float64)
    t = np.arange(len(ac))
    fig = _figure(9.0, 3.4)
    left, right = fig.subplots(1, 2)
    left.plot(np.arange(len(b)), b, color="C3")
    left.set_title("β_t", fontsize=10)
    left.set_xlabel("t")
    right.plot(t, ac, label="ᾱ_t", color="C0")
    right.plot(t, np.sqrt(ac), label="√ᾱ_t (signal)", color="C2")
    right.plot(t, np.sqrt(1 - ac), label="√(1-ᾱ_t) (noise)", color="C1")
    right.set_xlabel("t")
    right.set_title("x_t = √ᾱ_t x0 + √(1-ᾱ_t) ε", fontsize=10)
    right.legend(fontsize=8)
    for ax in (left, right):
        ax.grid(alpha=0.3)
    return fig


# --------------------------------------------------------------------------- receptive field
def _rf_draw(ax, rf_map: np.ndarray, analytic_width: float | None, vmin: float, center=None):
    rf = np.asarray(rf_map, np.float64)
    a, b = rf.shape
    ca, cb = (a // 2, b // 2) if center is None else center
    cmap = plt.get_cmap("magma")
    cmap = cmap.with_extremes(bad=cmap(0.0))  # exact zeros (no influence at all) in the darkest colour
    im = _show(ax, np.where(rf > 0, rf, np.nan), cmap=cmap, norm=LogNorm(vmin=vmin, vmax=1.0),
               extent=(-0.5, a - 0.5, -0.5, b - 0.5))
    ax.plot([ca], [cb], marker="+", color="cyan", ms=10, mew=1.5)
    if analytic_width:
        w = float(analytic_width)
        ax.add_patch(Rectangle((ca - w / 2, cb - w / 2), w, w, fill=False, ec="cyan", lw=1.2, ls="--"))
    return im


RF_LEVEL = 1e-2  # where figures cut the field: above the weak global coupling of small maps


def measured_width(rf_map: np.ndarray, level: float = RF_LEVEL, center=None) -> int:
    """Side of the smallest centred square holding every texel with ``rf >= level`` (the measured field).

    The default level, 1e-2 of the peak, stays above the plane-wide coupling
    (GroupNorm, cross-plane means) that reaches ~1e-2 on a 32-texel map, so it
    also works on the whole-network map. ``unet.receptive_field`` measures its
    ``measured_width`` on the convolution-only map as the bounding box of the
    texels above 1e-3; for the centred, symmetric fields it measures,
    ``level=rf.threshold`` here gives the same width.
    """
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
    """The measured receptive field of one output texel on a log colour scale.

    ``rf_map`` is ``|∂ output[centre] / ∂ input|`` over one plane ``[A, B]``,
    normalised to a maximum of 1. The log scale (down to ``vmin``) makes the
    weak, plane-wide coupling (around 1e-3, from the cross-plane features)
    visible next to the strong local field. The cross marks the centre texel
    (``(A//2, B//2)`` unless given) and the dashed square has the analytic
    width (in texels); the title gives the measured width, the side of the
    centred square holding every texel ``≥ level``. Draws into ``ax`` when given.
    """
    if ax is None:
        fig = _figure(4.4, 3.8)
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
    """Several receptive fields side by side on one log scale: ``[(label, rf_map, analytic_width), ...]``.

    Each title gives the analytic width and the measured one (texels ``≥ level``).
    """
    fig = _figure(3.6 * len(items) + 0.8, 3.8)
    panels = fig.subplots(1, len(items), squeeze=False)[0]
    im = None
    for ax, (label, rf, width) in zip(panels, items):
        im = _rf_draw(ax, rf, width, vmin)
        extra = f"analytic {width:g} · " if width else ""
        ax.set_title(f"{label}\n{extra}measured (≥{level:g}) {measured_width(rf, level)}", fontsize=9)
    fig.colorbar(im, ax=panels.tolist(), shrink=0.85, label="|gradient| (max 1)")
    return fig


# --------------------------------------------------------------------------- samples and textures
def plot_samples_slices(
    sdf_grids: Sequence[np.ndarray],
    axis: int | str = "z",
    index: int | None = None,
    titles: Sequence[str] | None = None,
    columns: int | None = None,
    up: str | None = "y",
) -> Figure:
    """Middle slices (or slice ``index``) of several decoded SDF grids, with the zero contour.

    A quick way to compare samples without 3D. All panels share one symmetric
    colour scale (the largest ``|sdf|`` over the slices, at most 1); the ``up``
    axis is drawn vertically where it is one of the slice's axes, and the
    figure's size follows the slices' aspect.
    """
    a = _axis_index(axis)
    ui, vi = _plane_axes(a, up)
    slices = []
    for g in sdf_grids:
        g = _numpy(g)
        s, _ = grid_slice(g, a, index if index is not None else g.shape[a] // 2)
        slices.append(s.T if ui > vi else s)
    n = len(slices)
    columns = columns or min(n, 4)
    rows = -(-n // columns)
    fig = _figure(2.8 * columns, _panel_height(2.8, slices[0].shape[1] / slices[0].shape[0]) * rows)
    panels = fig.subplots(rows, columns, squeeze=False)
    vmax = min(1.0, max(float(np.abs(s).max()) for s in slices)) or 1.0
    u, v = AXES[ui], AXES[vi]
    for k, ax in enumerate(panels.flat):
        if k >= n:
            ax.set_axis_off()
            continue
        s = slices[k]
        _show(ax, s, cmap=SDF_CMAP, vmin=-vmax, vmax=vmax)
        if s.min() < 0 < s.max():
            ax.contour(np.arange(s.shape[0]), np.arange(s.shape[1]), s.T, levels=[0.0], colors="k", linewidths=0.8)
        ax.set_title(titles[k] if titles else f"sample {k}", fontsize=9)
        ax.set_xlabel(u, fontsize=8)
        ax.set_ylabel(v, fontsize=8)
        ax.tick_params(labelsize=7)
    return fig


def plot_diversity_curve(values: Sequence[float], rows: Sequence[dict], goals: dict | None = None) -> Figure:
    """The diversity ↔ fidelity trade-off: scores of samples drawn at each value of the knob.

    ``rows[i]`` holds the scores at ``values[i]``: ``g_div`` (among the samples),
    and any of ``iou_to_input``, ``lp_iou``, ``lp_fscore`` (against the input).
    ``goals`` (same keys) draws dashed lines at target values.
    """
    labels = {"g_div": "G-Div (diversity)", "iou_to_input": "IoU to the input", "lp_iou": "LP-IoU (fidelity)",
              "lp_fscore": "LP-F (fidelity)"}
    fig = _figure(5.5, 3.4)
    ax = fig.add_subplot(1, 1, 1)
    for key, label in labels.items():
        if all(key in r for r in rows):
            line, = ax.plot(values, [r[key] for r in rows], "o-", label=label)
            if goals and key in goals:
                ax.axhline(goals[key], ls="--", lw=0.8, color=line.get_color())
    ax.set_xlabel("diversity (0 = the input, 1 = from pure noise)")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def plot_plan(plan, samples=None, batch: int = 0, title: str | None = None) -> Figure:
    """A controlled-generation request (``control.Plan``) on the three planes, and what the sampler made of it.

    Top row: the latent the request starts from (the known latent, or for a
    retarget the input's latent stretched), in PCA colours, with the part the
    sampler generates tinted red (by ``1 - mask``; the ramp is the blend
    border). Bottom row (with ``samples``): the sample ``batch``, with the
    same tint's outline. Colours use the top row's PCA basis, so kept texels
    look the same in both rows.
    """
    top = plan.known if plan.known is not None else plan.start
    rows = [("request", top)] + ([("sample", samples.triplane)] if samples is not None else [])
    x, y, z = plan.resolution
    widths, heights = [x, x, y], [y, z, z]
    scale = 9.0 / sum(widths)
    fig = _figure(9.5, (max(heights) * scale + 0.6) * len(rows) + 0.3)
    panels = fig.subplots(len(rows), 3, squeeze=False, gridspec_kw={"width_ratios": widths})
    bases = []
    for c, name in enumerate(PLANES):
        p0 = _numpy(getattr(top, name)[0])
        bases.append(pca_basis(p0))
    for r, (label, tp) in enumerate(rows):
        for c, name in enumerate(PLANES):
            ax = panels[r, c]
            plane = _numpy(getattr(tp, name)[batch if label == "sample" else 0])
            _show(ax, pca_project(plane, *bases[c]))
            if plan.mask is not None:
                free = 1 - _numpy(getattr(plan.mask, name)[0, 0])
                if label == "request":
                    tint = np.zeros((*free.shape, 4))
                    tint[..., 0], tint[..., 3] = 1.0, 0.6 * free
                    _show(ax, tint)
                elif 0 < free.max():
                    ax.contour(np.arange(free.shape[0]), np.arange(free.shape[1]), free.T, levels=[0.5],
                               colors="r", linewidths=1.0)
            u, v = PLANE_AXES[name]
            ax.set_title(f"{label}: {name}", fontsize=9)
            ax.set_xlabel(AXES[u], fontsize=8)
            ax.set_ylabel(AXES[v], fontsize=8)
            ax.tick_params(labelsize=7)
    fig.suptitle(title or f"{plan.kind}: red = generated, clear = kept from the input", fontsize=10)
    return fig


def plot_projections(grids: Sequence[np.ndarray], titles: Sequence[str] | None = None, up: str = "y") -> Figure:
    """Occupancy grids seen from the front and from above: how many voxels are filled along each ray.

    A static picture of decoded shapes (e.g. from ``Sin3DM.occupancy``) that
    needs no 3D viewer. With ``up="y"`` the front view looks along z (x →,
    y ↑) and the top view along y (x →, z ↑). Grids of different sizes keep
    their relative sizes.
    """
    grids = [_numpy(g) for g in grids]
    ui = _axis_index(up)
    if ui == 0:
        raise ValueError("up must be y or z: the views put x to the right")
    depth = 3 - ui  # the front view looks along the axis that is neither x nor up
    n = len(grids)
    widths = [g.shape[0] for g in grids]
    fig = _figure(min(2.6 * n, 12), 4.2)
    panels = fig.subplots(2, n, squeeze=False, gridspec_kw={"width_ratios": widths})
    for j, g in enumerate(grids):
        front = g.sum(axis=depth)  # (x, up)
        top = g.sum(axis=ui)  # (x, the other)
        _show(panels[0, j], front, cmap="bone")
        _show(panels[1, j], top, cmap="terrain")
        panels[0, j].set_title(titles[j] if titles else f"{j}", fontsize=9)
        for ax in panels[:, j]:
            ax.set_xticks([])
            ax.set_yticks([])
    panels[0, 0].set_ylabel(f"front ({AXES[ui]} up)", fontsize=8)
    panels[1, 0].set_ylabel(f"top ({AXES[depth]} up)", fontsize=8)
    return fig


def _as_float_image(image: np.ndarray) -> np.ndarray:
    img = _numpy(image)
    if img.dtype == np.uint8:
        img = img.astype(np.float32) / 255.0
    return np.clip(img[..., :3] if img.ndim == 3 else img, 0.0, 1.0)


def plot_texture(image: np.ndarray, covered: np.ndarray | None = None) -> Figure:
    """A UV texture (``(h, w, 3)``, float in [0, 1] or uint8) and, optionally, its ``covered`` mask.

    The axes read (u, v) directly: row 0 of the image is ``v = 1`` (OBJ convention).
    """
    img = _as_float_image(image)
    fig = _figure(8.0 if covered is not None else 4.4, 4.2)
    panels = fig.subplots(1, 2 if covered is not None else 1, squeeze=False)[0]
    panels[0].imshow(img, extent=(0, 1, 0, 1), origin="upper", interpolation="nearest")
    panels[0].set_title(f"texture {img.shape[1]}×{img.shape[0]}", fontsize=9)
    if covered is not None:
        cov = np.asarray(covered).astype(bool)
        panels[1].imshow(cov, extent=(0, 1, 0, 1), origin="upper", cmap="gray", vmin=0, vmax=1,
                         interpolation="nearest")
        panels[1].set_title(f"covered texels: {cov.mean():.1%}", fontsize=9)
    for ax in panels:
        ax.set_xlabel("u")
        ax.set_ylabel("v")
    return fig


def plot_uv_layout(uvs: np.ndarray, faces: np.ndarray | None = None, image: np.ndarray | None = None,
                   linewidth: float = 0.3, color: str = "k") -> Figure:
    """UV triangles as a wireframe (one ``LineCollection``), over the texture when given.

    ``uvs`` is either per vertex ``(V, 2)`` with ``faces (F, 3)``, or per face corner
    ``(F, 3, 2)`` (``TexturedMesh.face_uvs``; ``faces`` is then ignored). Rows with
    NaN (faces without a texture) are skipped.
    """
    uv = _numpy(uvs).astype(np.float32)
    if uv.ndim == 2:
        if faces is None:
            raise ValueError("per-vertex uvs (V, 2) need faces (F, 3)")
        tri = uv[np.asarray(faces)]
    else:
        tri = uv
    tri = tri[np.isfinite(tri).all(axis=(1, 2))]
    closed = np.concatenate([tri, tri[:, :1]], axis=1)  # (F, 4, 2): each triangle as a closed polyline
    fig = _figure(5.0, 5.0)
    ax = fig.subplots()
    if image is not None:
        ax.imshow(_as_float_image(image), extent=(0, 1, 0, 1), origin="upper", interpolation="nearest")
    ax.add_collection(LineCollection(closed, linewidths=linewidth, colors=color))
    lo = np.minimum(closed.reshape(-1, 2).min(0) if len(closed) else 0.0, 0.0)
    hi = np.maximum(closed.reshape(-1, 2).max(0) if len(closed) else 1.0, 1.0)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("u")
    ax.set_ylabel("v")
    ax.set_title(f"UV layout: {len(tri)} triangles", fontsize=9)
    return fig


def plot_meshes(meshes, labels: Sequence[str] | None = None, size: int = 256, columns: int = 4) -> Figure:
    """A static picture of meshes side by side: each one's three-quarter view, its label underneath.

    The picture beside a k3d viewer for a notebook read without a kernel (GitHub,
    nbviewer, an exported page), where the viewer shows nothing. Every mesh is
    drawn by :func:`sin3dm_lite.render.render_hero` at ``size``² pixels, all framed
    by one box (the union of their bounds), so sizes compare; give them in one
    coordinate frame. ``meshes``: a ``TexturedMesh`` or a list of them,
    ``trimesh.Trimesh`` es or ``(vertices, faces)`` pairs (the last two in plain
    grey). The figure is the contact sheet's pixels one to one (saved in the
    notebook as a PNG). Where off-screen OpenGL cannot start (Linux without
    Mesa's EGL) the figure is one line of text saying so: the notebook runs on.
    """
    from ..errors import Sin3DMInputError
    from ..data.mesh_io import Material, TexturedMesh
    from ..evaluate.render import contact_sheet, render_hero

    def textured(m) -> TexturedMesh:
        if isinstance(m, TexturedMesh):
            return m
        v, f = m if isinstance(m, tuple) else (m.vertices, m.faces)
        return TexturedMesh(np.asarray(v, np.float64), np.asarray(f, np.int64), np.zeros(len(f), np.int64),
                            [Material(base_color=np.float32([0.55, 0.55, 0.55, 1.0]))])

    if isinstance(meshes, TexturedMesh) or hasattr(meshes, "faces"):
        meshes = [meshes]
    meshes = [textured(m) for m in meshes]
    if not meshes or (labels is not None and len(labels) != len(meshes)):
        raise Sin3DMInputError(f"plot_meshes needs at least one mesh and one label per mesh, got {len(meshes)} "
                               f"meshes and {'no' if labels is None else len(labels)} labels")
    if not 16 <= int(size) <= 1024:
        raise Sin3DMInputError(f"size must be from 16 to 1024 pixels, got {size}")
    corners = np.concatenate([np.asarray(m.vertices, np.float64).reshape(-1, 3) for m in meshes])
    box = np.stack([corners.min(0), corners.max(0)]) if len(corners) else None
    try:
        sheet = contact_sheet([render_hero(m, size=int(size), box=box) for m in meshes], labels, columns=columns)
    except Sin3DMInputError as e:  # no OpenGL context here, or a mesh with nothing to draw
        fig = _figure(9.0, 0.5)
        fig.text(0.01, 0.5, f"no static picture: {e}", fontsize=8, va="center", wrap=True)
        return fig
    dpi = 100
    fig = plt.figure(figsize=(sheet.shape[1] / dpi, sheet.shape[0] / dpi), dpi=dpi)
    plt.close(fig)  # shown once, as the cell's value
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.imshow(sheet, interpolation="none")
    ax.set_axis_off()
    return fig


# --------------------------------------------------------------------------- evaluation
def plot_picture(image: np.ndarray, title: str | None = None, width: float = 10.0) -> Figure:
    """One picture (``(H, W, 3)``, uint8 or floats in [0, 1]: a render, a ``render.contact_sheet``), no axes."""
    img = _as_float_image(image)
    fig = _figure(width, width * img.shape[0] / img.shape[1] + (0.35 if title else 0.0))
    ax = fig.subplots()
    ax.imshow(img, interpolation="antialiased")
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=10)
    return fig


def plot_iou_matrix(grids: Sequence[np.ndarray], labels: Sequence[str] | None = None) -> Figure:
    """G-Div as a picture: the ``1 − IoU`` of every pair of occupancy grids (one box), values written in.

    G-Div is the mean of the cells above the diagonal; the diagonal (a shape
    with itself, 0) is left blank.
    """
    from ..evaluate.metrics import pairwise_iou

    d = 1.0 - pairwise_iou(grids)
    n = len(d)
    i, j = np.triu_indices(n, k=1)
    off = d[i, j]
    shown = d.copy()
    np.fill_diagonal(shown, np.nan)
    labels = list(labels) if labels is not None else [f"{k}" for k in range(n)]
    fig = _figure(1.2 + 0.62 * n, 0.9 + 0.55 * n)
    ax = fig.subplots()
    im = ax.imshow(shown, cmap="viridis", vmin=0.0, vmax=max(float(off.max()) if len(off) else 0.0, 1e-3))
    for a in range(n):
        for b in range(n):
            if a != b:
                ax.text(b, a, f"{d[a, b]:.2f}", ha="center", va="center", fontsize=8,
                        color="w" if d[a, b] < 0.6 * (off.max() if len(off) else 1) else "k")
    ax.set_xticks(range(n), labels, fontsize=8, rotation=90 if n > 6 else 0)
    ax.set_yticks(range(n), labels, fontsize=8)
    fig.colorbar(im, ax=ax, shrink=0.8, label="1 − IoU")
    ax.set_title(f"G-Div = mean above the diagonal = {off.mean():.3f}" if len(off) else "one shape: no pairs",
                 fontsize=9)
    return fig


def plot_layer_variation(reference: np.ndarray, grids: Sequence[np.ndarray], axis: int | str = "y") -> Figure:
    """Where the samples differ, layer by layer along ``axis`` (default y: heights, bottom to top).

    Left: the input's solid voxels per layer (what there is to vary). Right:
    each layer's share of G-Div (:func:`metrics.g_div_by_layer`; the bars sum to G-Div).
    """
    from ..evaluate.metrics import check_same_grid, g_div_by_layer

    k = _axis_index(axis)
    check_same_grid([reference, *grids])  # the input and the samples in one box
    parts = g_div_by_layer(grids, k)
    other = tuple(a for a in range(3) if a != k)
    solid = np.asarray(reference, bool).sum(other)
    layers = np.arange(len(parts))
    fig = _figure(8.0, 1.6 + 0.08 * len(parts))
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

    Each patch (an 11³ block of voxels) is drawn as a few z slices side by
    side (dark = occupied); the title gives the pair's IoU and F-score. The
    last panel is the histogram of every compared patch's best IoU: the
    shape's LP-IoU is the share right of the dashed threshold.
    """
    gen, ref = matches["generated"], matches["matched"]
    n, p = len(gen), gen.shape[-1]
    slices = list(slices) if slices is not None else sorted({p // 5, p // 2, p - 1 - p // 5})
    fig = _figure(2.3 * n + 3.2, 3.0)
    panels = fig.subplots(2, n + 1, squeeze=False, gridspec_kw={"width_ratios": [1.0] * n + [1.4]})
    for k in range(n):
        for row, cube, label in ((0, gen[k], "generated"), (1, ref[k], "best input patch")):
            ax = panels[row, k]
            _show(ax, _patch_strip(cube, slices), cmap="Greys", vmin=0, vmax=1)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"IoU {matches['iou'][k]:.2f} · F {matches['fscore'][k]:.2f}" if row == 0 else label,
                         fontsize=8)
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


def plot_render_pairs(views_a: Sequence[np.ndarray], views_b: Sequence[np.ndarray],
                      labels: Sequence[str] = ("sample 0", "sample 1"), views: Sequence[int] | None = None) -> Figure:
    """What the render diversity compares: the same view of two shapes, and where their colours differ.

    Rows: shape a, shape b, ``|a − b|`` (mean over RGB, 0–1) on the pixels where
    either shows the shape; each column's title is the view's
    ``metrics.colour_distance``, the mean of that difference. ``views`` picks
    the view indices shown (default: all; views are assumed every ``360 / len(views_a)`` degrees).
    """
    from ..evaluate.metrics import colour_distance, foreground

    if len(views_a) != len(views_b):
        raise ValueError(f"both shapes need the same views, got {len(views_a)} and {len(views_b)}")
    views = list(views) if views is not None else list(range(len(views_a)))
    fig = _figure(2.2 * len(views) + 0.6, 7.0)
    panels = fig.subplots(3, len(views), squeeze=False)
    for c, k in enumerate(views):
        a, b = _as_float_image(views_a[k]), _as_float_image(views_b[k])
        diff = np.abs(a - b).mean(axis=-1)
        diff[~(foreground(views_a[k]) | foreground(views_b[k]))] = np.nan
        panels[0, c].imshow(a)
        panels[1, c].imshow(b)
        im = panels[2, c].imshow(diff, cmap="magma", vmin=0, vmax=0.5)
        panels[0, c].set_title(f"azimuth {360 * k / len(views_a):.0f}°: distance "
                               f"{colour_distance(views_a[k], views_b[k]):.3f}", fontsize=8)
        for ax in panels[:, c]:
            ax.set_xticks([])
            ax.set_yticks([])
    for r, label in enumerate([*labels, "|difference|"]):
        panels[r, 0].set_ylabel(label, fontsize=8)
    fig.colorbar(im, ax=panels[2, :].tolist(), shrink=0.8, label="colour difference")
    return fig


# --------------------------------------------------------------------------- PBR
def pbr_map_images(source) -> dict[str, np.ndarray]:
    """The four PBR maps of a mesh (its first material with maps) or a ``Material``, as float images.

    ``{"base colour": (h, w, 3), "metallic": (h, w), "roughness": (h, w), "normal": (h, w, 3)}``:
    metallic is the metallic-roughness map's B channel times the factor,
    roughness its G channel times the factor (glTF); the normal map is shown
    as stored (tangent space, flat = (0.5, 0.5, 1), the familiar lilac).
    Missing maps come out as constant images of the factor (or flat normals).
    """
    materials = getattr(source, "materials", None) or [source]
    mat = next((m for m in materials if m.metallic_roughness_image is not None or m.normal_image is not None),
               materials[0])
    base = _as_float_image(mat.image) if mat.image is not None else np.ones((8, 8, 3), np.float32)
    base = base * np.asarray(mat.base_color, np.float32)[:3]
    shape = base.shape[:2]
    if mat.metallic_roughness_image is not None:
        mr = _as_float_image(mat.metallic_roughness_image)
        metal, rough = mr[..., 2] * mat.metallic, mr[..., 1] * mat.roughness
    else:
        metal, rough = np.full(shape, mat.metallic, np.float32), np.full(shape, mat.roughness, np.float32)
    normal = (_as_float_image(mat.normal_image) if mat.normal_image is not None
              else np.broadcast_to(np.float32([0.5, 0.5, 1.0]), (*shape, 3)))
    return {"base colour": base, "metallic": metal, "roughness": rough, "normal": normal}


def plot_pbr_maps(source, title: str | None = None) -> Figure:
    """Base colour, metallic, roughness and normal maps side by side (a mesh or a ``Material``).

    k3d shades only a colour texture, so this is how a reader sees the
    material of a PBR result; the 3D viewers show its base colour.
    Axes read (u, v): row 0 of every map is ``v = 1``.
    """
    maps = pbr_map_images(source)
    fig = _figure(13.0, 3.6)
    panels = fig.subplots(1, 4)
    for ax, (name, img) in zip(panels, maps.items()):
        gray = img.ndim == 2
        ax.imshow(img, extent=(0, 1, 0, 1), origin="upper", interpolation="nearest",
                  cmap="gray" if gray else None, vmin=0 if gray else None, vmax=1 if gray else None)
        stats = f"mean {img.mean():.2f}, std {img.std():.2f}" if gray else f"{img.shape[1]}×{img.shape[0]}"
        ax.set_title(f"{name}\n{stats}", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def pbr_slice_images(grid: ShapeGrid, axis: int | str = "y", index: int | None = None) -> dict[str, np.ndarray]:
    """One slice of each PBR quantity of a grid, :data:`NEUTRAL` grey outside the band.

    ``{"base colour", "metallic", "roughness", "normal"}``; the world-space
    normal is shown as ``n · ½ + ½`` (x → red, y → green, z → blue).
    """
    if not grid.has_pbr:
        raise ValueError(f"grid '{grid.name}' has no PBR channels")
    sdf, index = grid_slice(grid.sdf, axis, index)
    col, _ = grid_slice(grid.color, axis, index)
    band = (np.abs(sdf) < grid.threshold)[..., None]
    pick = {"base colour": col[..., :3], "metallic": col[..., 3:4].repeat(3, -1),
            "roughness": col[..., 4:5].repeat(3, -1), "normal": col[..., 5:8]}
    return {k: np.where(band, np.clip(v, 0, 1), NEUTRAL).astype(np.float32) for k, v in pick.items()}


def plot_pbr_slices(grid: ShapeGrid, axis: int | str = "y", index: int | None = None, up: str | None = "y") -> Figure:
    """The channels of a PBR grid in one slice: base colour, metallic, roughness, world-space normal.

    Same orientation as :func:`plot_grid_slices` (the ``up`` axis vertical).
    """
    a = _axis_index(axis)
    imgs = pbr_slice_images(grid, a, index)
    _, index = grid_slice(grid.sdf, a, index)
    u, v = _plane_axes(a, up)
    swap = u > v
    ext = _extent(grid, a, up)
    aspect = (ext[3] - ext[2]) / (ext[1] - ext[0])
    fig = _figure(13.0, _panel_height(3.2, aspect))
    panels = fig.subplots(1, 4)
    for ax, (name, img) in zip(panels, imgs.items()):
        _show(ax, img.swapaxes(0, 1) if swap else img, extent=ext)
        ax.set_title(f"{name}", fontsize=9)
        ax.set_xlabel(AXES[u])
        ax.set_ylabel(AXES[v])
    fig.suptitle(_slice_title(grid, a, index, "PBR channels"), fontsize=10)
    return fig

"""What every figure shares: the axes of the volume, a figure that leaves pyplot alone, a slice drawn the same way everywhere.

Every 2D picture of the volume (slices, triplane planes, receptive fields) draws the *first* remaining axis
to the right and the second one up, so a slice across z shows x → and y ↑, like the xy plane of a triplane.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from ..data.grid import ShapeGrid

AXES = ("x", "y", "z")
SDF_CMAP = "RdBu"  # red inside (negative), blue outside
NEUTRAL = np.array([0.82, 0.82, 0.82], np.float32)  # background where the colour grid is undefined


def new_figure(width: float, height: float) -> Figure:
    """A new figure that pyplot does not keep open (so Jupyter shows it once, as the cell's value)."""
    fig = plt.figure(figsize=(width, height), layout="constrained")
    plt.close(fig)
    return fig


def panel_height(width: float, aspect: float, title: float = 0.45) -> float:
    """Height (inches) of a panel ``width`` wide showing an image of ``aspect`` = height / width, plus its title."""
    return float(np.clip(width * aspect, 0.35 * width, 1.6 * width)) + title


def axis_index(axis: int | str) -> int:
    if axis not in (*AXES, 0, 1, 2):
        raise ValueError(f"axis must be one of {AXES} or 0/1/2, got {axis!r}")
    return AXES.index(axis) if isinstance(axis, str) else int(axis)


def as_numpy(x) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def label_axes(ax, u: int, v: int) -> None:
    """Name a panel's axes ``u`` (→) and ``v`` (↑) in small type."""
    ax.set_xlabel(AXES[u], fontsize=8)
    ax.set_ylabel(AXES[v], fontsize=8)
    ax.tick_params(labelsize=7)


def grid_slice(volume: np.ndarray, axis: int | str, index: int | None = None) -> tuple[np.ndarray, int]:
    """``volume[..., index, ...]`` across ``axis`` (middle slice when ``index`` is None) and the index used.

    Works on ``(H, W, D)`` and ``(H, W, D, K)`` arrays; the result keeps the two other axes in order.
    """
    a = axis_index(axis)
    n = volume.shape[a]
    index = n // 2 if index is None else int(index)
    if not 0 <= index < n:
        raise IndexError(f"slice index {index} is outside 0..{n - 1} along {AXES[a]}")
    return np.take(volume, index, axis=a), index


def plane_axes(axis: int, up: int | str | None = None) -> tuple[int, int]:
    """The two axes a slice across ``axis`` shows, (→, ↑): in order, unless ``up`` is the first one."""
    u, v = [k for k in range(3) if k != axis]
    if up is not None and axis_index(up) == u:
        u, v = v, u
    return u, v


def plane_extent(grid: ShapeGrid, axis: int, up: int | str | None = None) -> tuple[float, float, float, float]:
    """World extent of a slice drawn with axis ``u`` → and ``v`` ↑ (see :func:`plane_axes`)."""
    u, v = plane_axes(axis, up)
    return (float(grid.aabb[u]), float(grid.aabb[u + 3]), float(grid.aabb[v]), float(grid.aabb[v + 3]))


def show_image(ax, image: np.ndarray, **kwargs):
    """Draw a 2D (or 2D×3 RGB) array with axis 0 to the right and axis 1 up."""
    return ax.imshow(np.swapaxes(image, 0, 1), origin="lower", interpolation="nearest", **kwargs)


def contour_texels(ax, image: np.ndarray, level: float, **style) -> None:
    """The ``level`` contour of a 2D array drawn by :func:`show_image` (texel coordinates)."""
    ax.contour(np.arange(image.shape[0]), np.arange(image.shape[1]), image.T, levels=[level], **style)


def slice_title(grid: ShapeGrid, axis: int, index: int, kind: str) -> str:
    coord = float(grid.axis_coords(axis)[index])
    return f"{kind} · {AXES[axis]} = {index} ({AXES[axis]} = {coord:+.3f})"


def color_slice_image(grid: ShapeGrid, axis: int | str, index: int | None = None) -> np.ndarray:
    """RGB slice of the colour grid, :data:`NEUTRAL` grey where ``|sdf| >= threshold`` (colour undefined there)."""
    sdf, index = grid_slice(grid.sdf, axis, index)
    col, _ = grid_slice(grid.color, axis, index)
    rgb = np.clip(col[..., :3], 0.0, 1.0).astype(np.float32)
    band = np.abs(sdf) < grid.threshold
    return np.where(band[..., None], rgb, NEUTRAL)


def draw_slice(
    ax, grid: ShapeGrid, axis: int, index: int, kind: str, threshold_lines: bool = True, up: int | str | None = None
):
    u, v = plane_axes(axis, up)
    swap = u > v  # the slice array keeps the remaining axes in order; put `up` vertical
    ext = plane_extent(grid, axis, up)
    sdf, index = grid_slice(grid.sdf, axis, index)
    sdf = sdf.T if swap else sdf
    if kind == "sdf":
        im = show_image(ax, sdf, cmap=SDF_CMAP, vmin=-grid.threshold, vmax=grid.threshold, extent=ext)
    elif kind == "color":
        rgb = color_slice_image(grid, axis, index)
        im = show_image(ax, rgb.swapaxes(0, 1) if swap else rgb, extent=ext)
    else:
        raise ValueError(f"kind must be 'sdf' or 'color', got {kind!r}")
    draw_contours(ax, grid, (u, v), sdf, threshold_lines)
    ax.set(xlabel=AXES[u], ylabel=AXES[v])
    ax.set_title(slice_title(grid, axis, index, kind), fontsize=9)
    return im


def draw_contours(ax, grid: ShapeGrid, uv: tuple[int, int], sdf: np.ndarray, threshold_lines: bool) -> None:
    """Zero level (solid) and, optionally, the edges of the truncation band (dashed); ``sdf`` is ``(u, v)``."""
    coords, lo, hi = (grid.axis_coords(uv[0]), grid.axis_coords(uv[1])), sdf.min(), sdf.max()
    if lo < 0 < hi:
        ax.contour(*coords, sdf.T, levels=[0.0], colors="k", linewidths=1.0)
    t = 0.98 * grid.threshold  # just inside the band's edge: the sdf is flat at ±threshold beyond it
    levels = [lv for lv in (-t, t) if lo < lv < hi] if threshold_lines else []
    if levels:
        ax.contour(*coords, sdf.T, levels=levels, colors="0.3", linewidths=0.6, linestyles="--")

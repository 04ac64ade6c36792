"""Figures of the Data stage: slices of the TSDF and colour grid, the truncation, sample points, the input's texture and UV layout, PBR maps and slices."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from ..data.grid import ShapeGrid
from ..model.triplane import PLANE_AXES, PLANES
from .figures import (
    AXES,
    NEUTRAL,
    SDF_CMAP,
    as_numpy,
    axis_index,
    draw_slice,
    grid_slice,
    new_figure,
    panel_height,
    plane_axes,
    plane_extent,
    show_image,
    slice_title,
)


def plot_grid_slices(
    grid: ShapeGrid,
    index: int | Sequence[int] | None = None,
    axes: Sequence[str] = ("x", "y", "z"),
    show_color: bool = True,
    threshold_lines: bool = True,
    up: str | None = "y",
) -> Figure:
    """TSDF slices across each axis (top row) and the colour slice under each (bottom row).

    The SDF is red inside, blue outside (limits ``±threshold``); the black line is the surface and the dashed
    lines, with ``threshold_lines``, the edges of the truncation band, outside which the colour is grey.
    ``index`` is one index for every axis, one per axis, or None for the middle slices. Each panel shows the
    two other axes in order (→, ↑), except that the ``up`` axis (None: keep the order) is drawn vertically.
    """
    ax_ids = [axis_index(a) for a in axes]
    if index is None or np.isscalar(index):
        indices = [index] * len(ax_ids)
    else:
        indices = list(index)
        if len(indices) != len(ax_ids):
            raise ValueError(f"give one index per axis ({len(ax_ids)}), got {len(indices)}")
    rows = 2 if show_color else 1
    fig = new_figure(3.3 * len(ax_ids) + 0.8, 3.0 * rows)
    panels = fig.subplots(rows, len(ax_ids), squeeze=False)
    im = None
    for col, (a, i) in enumerate(zip(ax_ids, indices)):
        im = draw_slice(panels[0, col], grid, a, i, "sdf", threshold_lines, up)
        if show_color:
            draw_slice(panels[1, col], grid, a, i, "color", threshold_lines, up)
    fig.colorbar(im, ax=panels[0, :].tolist(), label="truncated SDF", shrink=0.9)
    voxels = grid.threshold / grid.voxel_size
    fig.suptitle(f"{grid.name}: grid {grid.shape}, threshold {grid.threshold:.4f} ({voxels:.1f} voxels)", fontsize=10)
    return fig


def plot_slice(
    grid: ShapeGrid,
    axis: int | str = "z",
    index: int | None = None,
    kind: str = "sdf",
    threshold_lines: bool = True,
    up: str | None = "y",
) -> Figure:
    """One panel: the SDF (``kind="sdf"``) or colour (``kind="color"``) slice across ``axis`` at ``index``.

    ``up`` is drawn vertically when it is one of the panel's axes (see :func:`plot_grid_slices`).
    """
    a = axis_index(axis)
    fig = new_figure(4.2, 3.6)
    ax = fig.subplots()
    im = draw_slice(ax, grid, a, index, kind, threshold_lines, up)
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

    A :class:`ShapeGrid`'s SDF is re-clipped at each threshold (default: 1, 2 and the grid's own); it is
    already truncated at its own, so larger thresholds raise ``ValueError``. A plain ``(X, Y, Z)`` array
    (an untruncated SDF on the ``±n_axis / n_max`` box) takes any threshold. Top: the SDF along the line
    through the middle of the slice, per threshold. Below: the slice at each threshold, on one colour scale.
    """
    if not isinstance(grid, ShapeGrid):
        field = np.asarray(as_numpy(grid), np.float32)
        half = np.array(field.shape, np.float64) / max(field.shape)
        no_colour, box = np.zeros((1, 1, 1, 3), np.float32), np.concatenate([-half, half])
        grid = ShapeGrid(field, no_colour, box, float(np.abs(field).max()), None, name="sdf")  # type: ignore[arg-type]
    a = axis_index(axis)
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

    fig = new_figure(max(3.0 * len(thresholds), 6.0), 6.0)
    gs = fig.add_gridspec(2, len(thresholds), height_ratios=[1.0, 1.3])
    prof = fig.add_subplot(gs[0, :])
    vmax = max(thresholds) * grid.voxel_size
    im = None
    for k, t in enumerate(thresholds):
        tw = t * grid.voxel_size
        clipped = np.clip(sdf, -tw, tw)
        prof.plot(coords, clipped[:, line], drawstyle="steps-mid", label=f"{t:g} voxels")
        ax = fig.add_subplot(gs[1, k])
        im = show_image(ax, clipped, cmap=SDF_CMAP, vmin=-vmax, vmax=vmax, extent=plane_extent(grid, a))
        if clipped.min() < 0 < clipped.max():
            ax.contour(coords, grid.axis_coords(v), clipped.T, levels=[0.0], colors="k", linewidths=0.8)
        ax.axhline(float(grid.axis_coords(v)[line]), color="0.2", lw=0.6, ls=":")
        ax.set_title(f"threshold {t:g} vox ({tw:.4f})", fontsize=9)
        ax.set(xlabel=AXES[u], ylabel=AXES[v])
    prof.axhline(0.0, color="k", lw=0.6)
    prof.set(xlabel=AXES[u], ylabel="SDF")
    prof.set_title(
        f"SDF along {AXES[u]} at {AXES[v]} = {grid.axis_coords(v)[line]:+.3f} (slice {AXES[a]} = {index})", fontsize=9
    )
    prof.legend(fontsize=8, loc="upper right")
    fig.colorbar(im, ax=fig.axes[1:], shrink=0.8)
    return fig


def plot_points(grid: ShapeGrid, n: int = 4000, seed: int = 0) -> Figure:
    """A random ``n`` of the near-surface training points on the xy, xz and yz planes, coloured by their SDF."""
    pts = np.asarray(grid.points, np.float32).reshape(-1, 3)
    sdf = np.asarray(grid.point_sdf, np.float32).reshape(-1)
    if len(pts) > n:
        sel = np.random.default_rng(seed).choice(len(pts), size=n, replace=False)
        pts, sdf = pts[sel], sdf[sel]
    fig = new_figure(11.0, 3.8)
    panels = fig.subplots(1, 3)
    sc = None
    for ax, name in zip(panels, PLANES):
        u, v = PLANE_AXES[name]
        sc = ax.scatter(pts[:, u], pts[:, v], c=sdf, s=2, cmap=SDF_CMAP, vmin=-grid.threshold, vmax=grid.threshold)
        lo_u, hi_u, lo_v, hi_v = grid.aabb[u], grid.aabb[u + 3], grid.aabb[v], grid.aabb[v + 3]
        ax.add_patch(Rectangle((lo_u, lo_v), hi_u - lo_u, hi_v - lo_v, fill=False, ec="k", lw=1.0))
        pad = 0.05 * float(grid.aabb[3:].max())
        ax.set(xlim=(lo_u - pad, hi_u + pad), ylim=(lo_v - pad, hi_v + pad), aspect="equal")
        ax.set(xlabel=AXES[u], ylabel=AXES[v])
        ax.set_title(f"{name} projection", fontsize=9)
    fig.colorbar(sc, ax=panels.tolist(), label="point SDF", shrink=0.85)
    fig.suptitle(f"{len(pts)} of {len(grid.points)} near-surface training points", fontsize=10)
    return fig


def as_float_image(image: np.ndarray) -> np.ndarray:
    """An image as floats in [0, 1] (uint8 divided by 255), RGB only."""
    img = as_numpy(image)
    if img.dtype == np.uint8:
        img = img.astype(np.float32) / 255.0
    return np.clip(img[..., :3] if img.ndim == 3 else img, 0.0, 1.0)


def plot_texture(image: np.ndarray, covered: np.ndarray | None = None) -> Figure:
    """A UV texture (``(h, w, 3)``, float in [0, 1] or uint8) and, optionally, its ``covered`` mask, axes (u, v)."""
    img = as_float_image(image)
    fig = new_figure(8.0 if covered is not None else 4.4, 4.2)
    panels = fig.subplots(1, 2 if covered is not None else 1, squeeze=False)[0]
    panels[0].imshow(img, extent=(0, 1, 0, 1), origin="upper", interpolation="nearest")
    panels[0].set_title(f"texture {img.shape[1]}×{img.shape[0]}", fontsize=9)
    if covered is not None:
        cov = np.asarray(covered).astype(bool)
        panels[1].imshow(cov, extent=(0, 1, 0, 1), origin="upper", cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        panels[1].set_title(f"covered texels: {cov.mean():.1%}", fontsize=9)
    for ax in panels:
        ax.set(xlabel="u", ylabel="v")
    return fig


def plot_uv_layout(
    uvs: np.ndarray,
    faces: np.ndarray | None = None,
    image: np.ndarray | None = None,
    linewidth: float = 0.3,
    color: str = "k",
) -> Figure:
    """UV triangles as a wireframe (one ``LineCollection``), over the texture when given.

    ``uvs`` is per vertex ``(V, 2)`` with ``faces (F, 3)``, or per face corner ``(F, 3, 2)`` (``faces`` is then
    ignored). Faces with NaN uvs (no texture) are skipped.
    """
    uv = as_numpy(uvs).astype(np.float32)
    if uv.ndim == 2 and faces is None:
        raise ValueError("per-vertex uvs (V, 2) need faces (F, 3)")
    tri = uv[np.asarray(faces)] if uv.ndim == 2 else uv
    tri = tri[np.isfinite(tri).all(axis=(1, 2))]
    closed = np.concatenate([tri, tri[:, :1]], axis=1)  # (F, 4, 2): each triangle as a closed polyline
    fig = new_figure(5.0, 5.0)
    ax = fig.subplots()
    if image is not None:
        ax.imshow(as_float_image(image), extent=(0, 1, 0, 1), origin="upper", interpolation="nearest")
    ax.add_collection(LineCollection(closed, linewidths=linewidth, colors=color))
    lo = np.minimum(closed.reshape(-1, 2).min(0) if len(closed) else 0.0, 0.0)
    hi = np.maximum(closed.reshape(-1, 2).max(0) if len(closed) else 1.0, 1.0)
    ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), aspect="equal", xlabel="u", ylabel="v")
    ax.set_title(f"UV layout: {len(tri)} triangles", fontsize=9)
    return fig


def pbr_map_images(source) -> dict[str, np.ndarray]:
    """The four PBR maps of a mesh (its first material with maps) or a ``Material``, as float images.

    ``{"base colour", "metallic", "roughness", "normal"}``: metallic and roughness are the B and G channels
    of the metallic-roughness map times their factors (glTF), the normal map as stored (tangent space);
    missing maps come out as constant images of the factor (or flat normals).
    """
    materials = getattr(source, "materials", None) or [source]
    with_maps = [m for m in materials if m.metallic_roughness_image is not None or m.normal_image is not None]
    mat = (with_maps or materials)[0]
    base = as_float_image(mat.image) if mat.image is not None else np.ones((8, 8, 3), np.float32)
    base = base * np.asarray(mat.base_color, np.float32)[:3]
    shape = base.shape[:2]
    if mat.metallic_roughness_image is not None:
        mr = as_float_image(mat.metallic_roughness_image)
        metal, rough = mr[..., 2] * mat.metallic, mr[..., 1] * mat.roughness
    else:
        metal, rough = np.full(shape, mat.metallic, np.float32), np.full(shape, mat.roughness, np.float32)
    flat = np.broadcast_to(np.float32([0.5, 0.5, 1.0]), (*shape, 3))
    normal = as_float_image(mat.normal_image) if mat.normal_image is not None else flat
    return {"base colour": base, "metallic": metal, "roughness": rough, "normal": normal}


def plot_pbr_maps(source, title: str | None = None) -> Figure:
    """Base colour, metallic, roughness and normal maps side by side (a mesh or a ``Material``).

    k3d shades only a colour texture, so this is how a reader sees a PBR material.
    """
    fig = new_figure(13.0, 3.6)
    panels = fig.subplots(1, 4)
    for ax, (name, img) in zip(panels, pbr_map_images(source).items()):
        gray = dict(cmap="gray", vmin=0, vmax=1) if img.ndim == 2 else {}
        ax.imshow(img, extent=(0, 1, 0, 1), origin="upper", interpolation="nearest", **gray)
        stats = f"mean {img.mean():.2f}, std {img.std():.2f}" if gray else f"{img.shape[1]}×{img.shape[0]}"
        ax.set_title(f"{name}\n{stats}", fontsize=9)
        ax.set(xticks=[], yticks=[])
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def pbr_slice_images(grid: ShapeGrid, axis: int | str = "y", index: int | None = None) -> dict[str, np.ndarray]:
    """One slice of each PBR quantity of a grid, :data:`NEUTRAL` grey outside the band.

    The world-space normal is shown as ``n · ½ + ½`` (x → red, y → green, z → blue).
    """
    if not grid.has_pbr:
        raise ValueError(f"grid '{grid.name}' has no PBR channels")
    sdf, index = grid_slice(grid.sdf, axis, index)
    col, _ = grid_slice(grid.color, axis, index)
    band = (np.abs(sdf) < grid.threshold)[..., None]
    pick = {
        "base colour": col[..., :3],
        "metallic": col[..., 3:4].repeat(3, -1),
        "roughness": col[..., 4:5].repeat(3, -1),
        "normal": col[..., 5:8],
    }
    return {k: np.where(band, np.clip(v, 0, 1), NEUTRAL).astype(np.float32) for k, v in pick.items()}


def plot_pbr_slices(grid: ShapeGrid, axis: int | str = "y", index: int | None = None, up: str | None = "y") -> Figure:
    """The channels of a PBR grid in one slice (base colour, metallic, roughness, normal), ``up`` vertical."""
    a = axis_index(axis)
    imgs = pbr_slice_images(grid, a, index)
    _, index = grid_slice(grid.sdf, a, index)
    u, v = plane_axes(a, up)
    swap = u > v
    ext = plane_extent(grid, a, up)
    aspect = (ext[3] - ext[2]) / (ext[1] - ext[0])
    fig = new_figure(13.0, panel_height(3.2, aspect))
    panels = fig.subplots(1, 4)
    for ax, (name, img) in zip(panels, imgs.items()):
        show_image(ax, img.swapaxes(0, 1) if swap else img, extent=ext)
        ax.set_title(f"{name}", fontsize=9)
        ax.set(xlabel=AXES[u], ylabel=AXES[v])
    fig.suptitle(slice_title(grid, a, index, "PBR channels"), fontsize=10)
    return fig

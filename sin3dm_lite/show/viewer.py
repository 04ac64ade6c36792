"""Interactive 3D viewers with k3d: textured meshes, galleries, SDF volumes, point clouds.

Every plot function returns a ``k3d.Plot`` or adds to the one given (``plot=``). ``up`` (``"y"`` or ``"z"``)
describes *the data*, which :func:`~sin3dm_lite.show.camera.to_view` turns into k3d's z-up frame; ``offset``
arguments are in k3d's frame. This module is the notebooks' ``viewer`` namespace, so it re-exports
:mod:`.camera` and the standalone HTML pages of :mod:`.pages`.
"""

from __future__ import annotations

import html
from collections.abc import Sequence

import k3d
import numpy as np

from ..data.mesh import TexturedMesh, unique_rows
from ..formats.export import baked_image, split_corners
from ..formats.images import png_bytes
from .camera import UP_AXES, VIEW, fit_camera, screen_up_vector, to_view, view_camera  # noqa: F401 (namespace)
from .pages import NO_WEBGL, index_page, read_snapshot, save_html, snapshot_array, with_webgl_message  # noqa: F401

#: how :func:`gallery` draws a label: centred under its anchor, dark, no box
_LABEL_STYLE = dict(reference_point="ct", color=0x222222, size=0.9, label_box=False, is_html=True)


def pack_colors(rgb: np.ndarray) -> np.ndarray:
    """``(N, 3)`` colours (float in [0, 1] or uint8) → ``(N,)`` uint32 ``0xRRGGBB``."""
    c = np.asarray(rgb)
    if c.dtype != np.uint8:
        c = np.clip(np.round(np.asarray(c, np.float64) * 255.0), 0, 255).astype(np.uint8)
    c = c[..., :3].astype(np.uint32)
    return (c[..., 0] << 16) | (c[..., 1] << 8) | c[..., 2]


def new_plot(**kwargs) -> k3d.Plot:
    """A k3d plot with our defaults (no grid box, white background); keyword arguments go to ``k3d.plot``."""
    return k3d.plot(**(dict(grid_visible=False, background_color=0xFFFFFF, camera_auto_fit=True, height=480) | kwargs))


def _arrays(vertices, indices, uvs=None, image=None, colors=None) -> dict:
    return dict(vertices=vertices, indices=indices, uvs=uvs, image=image, colors=colors)


def _texture_arrays(mesh: TexturedMesh) -> dict | None:
    """:func:`mesh_arrays` of a mesh drawn with one texture (None when it can't be): vertices are split by their
    distinct (vertex, uv) pairs, since a renderer needs one uv per vertex and a seam's vertex has several."""
    if mesh.face_uvs is None or len(mesh.faces) == 0:
        return None
    used = np.unique(mesh.face_material)
    if len(used) != 1:
        return None
    mat = mesh.materials[int(used[0])]
    if mat.image is None or not np.isfinite(mesh.face_uvs).all():
        return None
    vertex_of, uvs, faces = split_corners(np.asarray(mesh.faces), np.asarray(mesh.face_uvs))
    return _arrays(np.asarray(mesh.vertices)[vertex_of], faces, uvs, baked_image(mat)[..., :3])


def _color_arrays(mesh: TexturedMesh) -> dict:
    """Per-vertex packed colours from ``colors_at`` at every face corner (vertices split where colours differ)."""
    n_faces = len(mesh.faces)
    fi = np.repeat(np.arange(n_faces), 3)
    bc = np.tile(np.eye(3), (n_faces, 1))
    packed = pack_colors(mesh.colors_at(fi, bc))
    corner_vertex = np.asarray(mesh.faces, np.int64).reshape(-1)
    first, inverse = unique_rows(np.column_stack([corner_vertex, packed.astype(np.int64)]))
    vertices = np.asarray(mesh.vertices)[corner_vertex[first]]
    return _arrays(vertices, inverse.reshape(-1, 3), colors=packed[first].astype(np.uint32))


def _trimesh_arrays(mesh, texture: bool) -> dict:
    """:func:`mesh_arrays` of a ``trimesh.Trimesh``."""
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    visual = mesh.visual
    kind = getattr(visual, "kind", None)
    if texture and kind == "texture" and getattr(visual, "uv", None) is not None:
        mat = visual.material
        img = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        if img is not None and len(visual.uv) == len(vertices):
            rgb = np.asarray(img.convert("RGB"), np.float32) / 255.0
            factor = getattr(mat, "baseColorFactor", None)  # glTF materials: RGBA, uint8 or float
            if factor is not None:
                factor = np.asarray(factor)
                scale = 255.0 if np.issubdtype(factor.dtype, np.integer) else 1.0
                rgb = np.clip(rgb * (factor[:3].astype(np.float32) / scale), 0.0, 1.0)
            return _arrays(vertices, faces, np.asarray(visual.uv, np.float64), rgb)
    if kind == "texture":
        visual = visual.to_color()  # trimesh samples the texture at the vertices
    colors = None if kind is None else pack_colors(np.asarray(visual.vertex_colors)[:, :3])
    return _arrays(vertices, faces, colors=colors)


def mesh_arrays(mesh, texture: bool = True) -> dict:
    """What :func:`mesh_plot` hands to k3d, in *data* coordinates: ``vertices``, ``indices`` and either
    ``uvs`` + ``image`` (OBJ convention, v up) or ``colors`` (packed uint32, or None for a plain colour)."""
    if not isinstance(mesh, TexturedMesh):
        return _trimesh_arrays(mesh, texture)
    return (_texture_arrays(mesh) if texture else None) or _color_arrays(mesh)


def mesh_plot(
    mesh,
    plot: k3d.Plot | None = None,
    texture: bool = True,
    name: str | None = None,
    offset: Sequence[float] = (0.0, 0.0, 0.0),
    up: str = "y",
    color: int | None = None,
    flat_shading: bool = False,
    max_texture: int | None = 2048,
    **mesh_kwargs,
) -> k3d.Plot:
    """A :class:`TexturedMesh` or ``trimesh.Trimesh`` in k3d (added to ``plot`` when given).

    A mesh whose faces all use one textured material is drawn with its texture (PNG, at most ``max_texture``
    pixels a side); anything else gets per-vertex colours sampled at the face corners, or with
    ``color=0xRRGGBB`` one plain colour. Extra keyword arguments go to ``k3d.mesh``.
    """
    plot = plot if plot is not None else new_plot()
    arrays = mesh_arrays(mesh, texture=texture and color is None)
    vertices = to_view(arrays["vertices"], up) + np.asarray(offset, np.float32)
    opts = dict(flat_shading=flat_shading, side="double", name=name or getattr(mesh, "name", None) or "mesh")
    if color is not None:
        opts.update(color=int(color))
    elif arrays["uvs"] is not None:
        uv = np.asarray(arrays["uvs"], np.float64)
        # k3d's v = 0 is the image's top row (glTF's convention), OBJ's and ours the bottom row: v -> 1 - v
        k3d_uv = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1).astype(np.float32)
        opts.update(
            color=0xFFFFFF,
            texture=png_bytes(arrays["image"], max_texture),
            texture_file_format="png",
            uvs=k3d_uv,
            # uvs outside [0, 1] wrap (as in sample_texture); an atlas inside is clamped, so no edge bleeds in
            texture_wrap="repeat" if (uv.min() < 0.0 or uv.max() > 1.0) else "clamp",
        )
    elif arrays["colors"] is not None:
        opts.update(colors=np.asarray(arrays["colors"], np.uint32), color=0xFFFFFF)
    else:
        opts.update(color=0xB3B3B3)
    opts.update(mesh_kwargs)
    plot += k3d.mesh(vertices.astype(np.float32), np.asarray(arrays["indices"], np.uint32), **opts)
    return plot


def _view_bounds(mesh, up: str) -> np.ndarray:
    """``(2, 3)`` min / max corner of a mesh in k3d's frame."""
    v = to_view(np.asarray(mesh.vertices), up)
    return np.stack([v.min(0), v.max(0)])


def gallery(
    meshes: Sequence,
    labels: Sequence[str] | None = None,
    spacing: float = 0.25,
    columns: int | None = None,
    up: str = "y",
    texture: bool = True,
    plot: k3d.Plot | None = None,
) -> k3d.Plot:
    """Several meshes side by side along x (``spacing`` apart), in rows of ``columns``, each with a label.

    Rows go downwards (k3d's -z), far enough apart that they do not hide each other from the default camera
    (:data:`VIEW`). Labels (``k3d.text``, shown by saved pages too) hang in front of each mesh's base
    (:func:`label_position`), so that from above they fall below the mesh on the screen.
    """
    plot = plot if plot is not None else new_plot()
    n = len(meshes)
    if labels is not None and len(labels) != n:
        raise ValueError(f"got {len(labels)} labels for {n} meshes")
    columns = columns or n
    bounds = [_view_bounds(m, up) for m in meshes]
    screen_up = screen_up_vector(*VIEW)  # a point's height in the default view is roughly screen_up @ point
    low = None  # the lowest screen height of the rows so far, labels included
    for row_start in range(0, n, columns):
        row = range(row_start, min(row_start + columns, n))
        row_height = max(bounds[k][1, 2] - bounds[k][0, 2] for k in row)
        offsets, x = [], 0.0
        for k in row:  # left edge at x, centred in y, top of the row at 0
            lo, hi = bounds[k]
            offsets.append(np.array([x - lo[0], -(lo[1] + hi[1]) / 2, -hi[2]]))
            x += (hi[0] - lo[0]) + spacing
        corners = np.concatenate([_corners(bounds[k] + o) for k, o in zip(row, offsets)])
        if low is not None:  # lower the row until its top is below the rows above, in the default view
            drop = (screen_up @ corners.T).max() - low + spacing * screen_up[2]
            for o in offsets:
                o[2] -= drop / screen_up[2]
            corners[:, 2] -= drop / screen_up[2]
        low = (screen_up @ corners.T).min() if low is None else min(low, (screen_up @ corners.T).min())
        for k, o in zip(row, offsets):
            lo, hi = bounds[k] + o
            name = labels[k] if labels is not None else getattr(meshes[k], "name", f"mesh {k}")
            mesh_plot(meshes[k], plot=plot, texture=texture, name=str(name), offset=o.astype(np.float32), up=up)
            if labels is not None:
                at = label_position(lo, hi)
                plot += k3d.text(html.escape(str(labels[k])), position=at, name=f"label {k}", **_LABEL_STYLE)
                low = min(low, screen_up @ at - 0.15 * row_height)  # room for the text hanging below
    return plot


def _corners(box) -> np.ndarray:
    """The 8 corners of a ``(2, 3)`` box."""
    (x0, y0, z0), (x1, y1, z1) = box
    return np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], np.float64)


def label_position(lo, hi) -> list[float]:
    """Where :func:`gallery` anchors a mesh's label (k3d frame, box ``lo``..``hi``): the middle of its base,
    moved towards the viewer (k3d's -y) by a fifth of the box's largest side."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    pad = 0.2 * float((hi - lo).max())
    return [float((lo[0] + hi[0]) / 2), float(lo[1] - pad), float(lo[2])]


def volume_plot(
    sdf,
    aabb: Sequence[float] | None = None,
    up: str = "y",
    volume: bool = True,
    isosurface: bool = True,
    level: float = 0.0,
    color: int = 0x6A9FD8,
    plot: k3d.Plot | None = None,
) -> k3d.Plot:
    """An SDF grid ``[X, Y, Z]`` (or a ``ShapeGrid``) as a k3d volume and/or its zero isosurface.

    ``aabb`` is ``(xmin, ymin, zmin, xmax, ymax, zmax)`` of the cell-centred grid (default: a ``ShapeGrid``'s
    own box, else ``±n_axis / n_max``). The volume is opaque inside, clear outside; k3d extracts the isosurface
    at ``level`` in the browser.
    """
    if hasattr(sdf, "sdf") and hasattr(sdf, "aabb"):
        aabb = sdf.aabb if aabb is None else aabb
        sdf = sdf.sdf
    field = np.asarray(sdf.detach().cpu().numpy() if hasattr(sdf, "detach") else sdf, np.float32)
    if field.ndim != 3:
        raise ValueError(f"sdf must be a 3D grid [X, Y, Z], got shape {field.shape}")
    n = np.array(field.shape, np.float64)
    aabb = np.concatenate([-n / n.max(), n / n.max()]) if aabb is None else np.asarray(aabb, np.float64)
    lo, hi = aabb[:3], aabb[3:]
    half = (hi - lo) / n / 2  # half a voxel: marching cubes puts samples on the box's corners
    if up == "y":  # (x, y, z) -> (x, -z, y): new axes are x, reversed z, y
        field = np.ascontiguousarray(field.transpose(0, 2, 1)[:, ::-1, :])
        lo, hi, half = (np.array([lo[0], -hi[2], lo[1]]), np.array([hi[0], -lo[2], hi[1]]), half[[0, 2, 1]])
    elif up != "z":
        raise ValueError(f"up must be one of {UP_AXES}, got {up!r}")
    zyx = np.ascontiguousarray(field.transpose(2, 1, 0))  # k3d indexes volumes [z, y, x]
    box = [lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]]
    plot = plot if plot is not None else new_plot()
    if volume:
        t = float(np.abs(zyx).max()) or 1.0
        plot += k3d.volume(
            zyx,
            bounds=box,
            color_range=[-t, t],
            color_map=k3d.colormaps.matplotlib_color_maps.RdBu,
            opacity_function=[0.0, 0.5, 0.45, 0.35, 0.5, 0.0, 1.0, 0.0],
            alpha_coef=8.0,
            name="sdf volume",
        )
    if isosurface:
        inner = [lo[0] + half[0], hi[0] - half[0], lo[1] + half[1], hi[1] - half[1], lo[2] + half[2], hi[2] - half[2]]
        plot += k3d.marching_cubes(
            zyx, level=float(level), bounds=inner, color=int(color), flat_shading=False, name=f"isosurface {level:g}"
        )
    return plot


def points_plot(
    points: np.ndarray,
    colors: np.ndarray | None = None,
    point_size: float = 0.01,
    up: str = "y",
    plot: k3d.Plot | None = None,
    name: str = "points",
) -> k3d.Plot:
    """A point cloud; ``colors`` is ``(N, 3)`` RGB (float in [0, 1] or uint8) or ``(N,)`` packed uint32."""
    pts = to_view(points, up)
    opts = dict(point_size=point_size, shader="3d", name=name)
    if colors is not None:
        c = np.asarray(colors)
        packed = c.astype(np.uint32) if c.ndim == 1 else pack_colors(c)
        if len(packed) != len(pts):
            raise ValueError(f"{len(packed)} colours for {len(pts)} points")
        opts["colors"] = packed
    else:
        opts["color"] = 0x3070B0
    plot = plot if plot is not None else new_plot()
    plot += k3d.points(pts, **opts)
    return plot

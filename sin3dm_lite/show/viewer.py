"""Interactive 3D viewers with k3d: textured meshes, galleries, SDF volumes, points, standalone HTML.

Every function returns a ``k3d.Plot`` (show it by making it a cell's value, or
``plot.display()``) and can add to an existing plot instead (``plot=``).
:func:`save_html` writes a plot as a single self-contained page that opens in
any browser without a server or a network connection.

Frames. k3d's up axis is z; OBJ files (and our normalised meshes) are usually
y-up. Every function here takes ``up="y"`` (default) or ``up="z"`` describing
*the data*, and turns y-up data so that its y becomes k3d's z:
``(x, y, z) → (x, -z, y)``, a rotation (no mirror), so a shape's front (+z)
faces k3d's -y, where :func:`fit_camera` puts the camera: in front, to the
right and well above (:data:`VIEW`), so that a canyon's river shows. ``offset``
arguments are in k3d's frame (after that rotation).

k3d in practice: float32 vertices, uint32 indices, packed ``0xRRGGBB`` uint32
colours; a textured mesh gets ``color=0xffffff`` (the texture is multiplied by
it), ``texture=<PNG bytes>``, ``texture_file_format="png"`` and one uv per
vertex.
"""
from __future__ import annotations

import base64
import html
import os
import re
import zlib
from collections.abc import Sequence
from pathlib import Path

import k3d
import numpy as np

from ..data.export import baked_image, split_corners
from ..data.formats.images import array_to_pil, png_bytes
from ..data.mesh import TexturedMesh, unique_rows
from ..files import atomic_write

UP_AXES = ("y", "z")

#: the default camera of a saved page: (azimuth, elevation) in degrees, in the data's y-up frame with the
#: renderer's convention (azimuth 0 = from the front, +z; 90 = from +x). From above at an angle: at 25° the
#: canyon's near bank hides its river, at 60° the river runs through the picture.
VIEW = (30.0, 60.0)


# --------------------------------------------------------------------------- small helpers

def to_trimesh(mesh: TexturedMesh, max_texture: int = 1024):
    """A ``trimesh.Trimesh`` for viewing (``trimesh``'s own viewers, scenes and exporters).

    A mesh with exactly one material that has a texture (and per-corner
    UVs) keeps it: the result has ``TextureVisuals`` with the texture (times
    the material factor, longest side at most ``max_texture``) and vertices
    split wherever a vertex has several UVs. Anything else gets vertex
    colours evaluated at every face corner (every face has its own three
    vertices, so colour edges stay sharp).
    """
    import trimesh

    if len(mesh.materials) == 1 and mesh.materials[0].image is not None and mesh.face_uvs is not None:
        mat = mesh.materials[0]
        vert_of, uv, faces = split_corners(mesh.faces, mesh.face_uvs)
        image = array_to_pil(baked_image(mat), max_size=max_texture)
        visual = trimesh.visual.TextureVisuals(
            uv=uv, material=trimesh.visual.material.SimpleMaterial(image=image, name=mat.name)
        )
        return trimesh.Trimesh(mesh.vertices[vert_of], faces, visual=visual, process=False)

    tri = mesh.vertices[mesh.faces]
    # colour each vertex by the colour at its corner in one face that uses it
    fi = np.repeat(np.arange(len(mesh.faces)), 3)
    bc = np.tile(np.eye(3), (len(mesh.faces), 1))
    col = mesh.colors_at(fi, bc)
    v = tri.reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    m = trimesh.Trimesh(v, f, vertex_colors=np.round(col * 255).astype(np.uint8), process=False)
    return m


def to_view(points: np.ndarray, up: str = "y") -> np.ndarray:
    """Data coordinates → k3d's z-up frame (``up="y"``: ``(x, y, z) → (x, -z, y)``), as float32."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if up == "y":
        p = np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1)
    elif up != "z":
        raise ValueError(f"up must be one of {UP_AXES}, got {up!r}")
    return p.astype(np.float32)


def pack_colors(rgb: np.ndarray) -> np.ndarray:
    """``(N, 3)`` colours (float in [0, 1] or uint8) → ``(N,)`` uint32 ``0xRRGGBB``."""
    c = np.asarray(rgb)
    if c.dtype != np.uint8:
        c = np.clip(np.round(np.asarray(c, np.float64) * 255.0), 0, 255).astype(np.uint8)
    c = c[..., :3].astype(np.uint32)
    return (c[..., 0] << 16) | (c[..., 1] << 8) | c[..., 2]


def new_plot(**kwargs) -> k3d.Plot:
    """A k3d plot with our defaults (no grid box, white background); keyword arguments go to ``k3d.plot``."""
    opts = dict(grid_visible=False, background_color=0xFFFFFF, camera_auto_fit=True, height=480)
    opts.update(kwargs)
    return k3d.plot(**opts)


# --------------------------------------------------------------------------- mesh → arrays
def _texture_arrays(mesh: TexturedMesh):
    """Per-vertex (position, uv) arrays for a mesh drawn with one texture, or None when it can't be.

    A :class:`TexturedMesh` stores one uv per face *corner* (``face_uvs (F, 3, 2)``):
    a vertex on a UV seam has several. We split vertices by their distinct
    (vertex, uv) pairs, which is what a renderer needs (one uv per vertex).
    """
    if mesh.face_uvs is None or len(mesh.faces) == 0:
        return None
    used = np.unique(mesh.face_material)
    if len(used) != 1:
        return None
    mat = mesh.materials[int(used[0])]
    if mat.image is None or not np.isfinite(mesh.face_uvs).all():
        return None
    vertex_of, uvs, faces = split_corners(np.asarray(mesh.faces), np.asarray(mesh.face_uvs))
    return np.asarray(mesh.vertices)[vertex_of], faces, uvs, baked_image(mat)[..., :3]


def _color_arrays(mesh: TexturedMesh):
    """Per-vertex packed colours from ``colors_at`` at every face corner (vertices split where colours differ)."""
    n_faces = len(mesh.faces)
    fi = np.repeat(np.arange(n_faces), 3)
    bc = np.tile(np.eye(3), (n_faces, 1))
    packed = pack_colors(mesh.colors_at(fi, bc))
    corner_vertex = np.asarray(mesh.faces, np.int64).reshape(-1)
    first, inverse = unique_rows(np.column_stack([corner_vertex, packed.astype(np.int64)]))
    return np.asarray(mesh.vertices)[corner_vertex[first]], inverse.reshape(-1, 3), packed[first].astype(np.uint32)


def _trimesh_arrays(mesh, texture: bool):
    """(vertices, faces, uvs or None, image or None, packed colours or None) of a ``trimesh.Trimesh``."""
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    visual = mesh.visual
    if texture and getattr(visual, "kind", None) == "texture" and getattr(visual, "uv", None) is not None:
        mat = visual.material
        img = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        if img is not None and len(visual.uv) == len(vertices):
            rgb = np.asarray(img.convert("RGB"), np.float32) / 255.0
            factor = getattr(mat, "baseColorFactor", None)  # glTF materials: RGBA, uint8 or float
            if factor is not None:
                factor = np.asarray(factor)
                scale = 255.0 if np.issubdtype(factor.dtype, np.integer) else 1.0
                rgb = np.clip(rgb * (factor[:3].astype(np.float32) / scale), 0.0, 1.0)
            return vertices, faces, np.asarray(visual.uv, np.float64), rgb, None
    colors = None
    kind = getattr(visual, "kind", None)
    if kind == "texture":
        visual = visual.to_color()  # trimesh samples the texture at the vertices
    if kind is not None:
        colors = pack_colors(np.asarray(visual.vertex_colors)[:, :3])
    return vertices, faces, None, None, colors


def mesh_arrays(mesh, texture: bool = True) -> dict:
    """What :func:`mesh_plot` hands to k3d, in *data* coordinates: ``vertices``, ``indices`` and either
    ``uvs`` + ``image`` (OBJ convention, v up) or ``colors`` (packed uint32, or None for a plain colour)."""
    if isinstance(mesh, TexturedMesh):
        tex = _texture_arrays(mesh) if texture else None
        if tex is not None:
            v, f, uv, img = tex
            return dict(vertices=v, indices=f, uvs=uv, image=img, colors=None)
        v, f, col = _color_arrays(mesh)
        return dict(vertices=v, indices=f, uvs=None, image=None, colors=col)
    v, f, uv, img, col = _trimesh_arrays(mesh, texture)
    return dict(vertices=v, indices=f, uvs=uv, image=img, colors=col)


# --------------------------------------------------------------------------- plots
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

    A mesh whose faces all use one textured material is drawn with its texture
    (PNG, at most ``max_texture`` pixels a side); anything else (several
    materials, vertex colours, a plain colour, or ``texture=False``) gets
    per-vertex colours sampled at the face corners. ``color=0xRRGGBB`` draws a
    single plain colour instead. Extra keyword arguments go to ``k3d.mesh``.
    """
    plot = plot if plot is not None else new_plot()
    arrays = mesh_arrays(mesh, texture=texture and color is None)
    vertices = to_view(arrays["vertices"], up) + np.asarray(offset, np.float32)
    opts = dict(flat_shading=flat_shading, side="double", name=name or getattr(mesh, "name", None) or "mesh")
    if color is not None:
        opts.update(color=int(color))
    elif arrays["uvs"] is not None:
        uv = np.asarray(arrays["uvs"], np.float64)
        # k3d uploads the PNG with flipY = false, so its v = 0 is the image's TOP row (glTF's
        # convention, which k3d's own glTF reader passes through unchanged), while OBJ / our
        # TexturedMesh put v = 0 at the BOTTOM row. Hence v -> 1 - v. Checked by rendering a
        # quad with a red-top / blue-bottom texture in headless Chromium: with the flip the
        # red half is on top; without it the picture is upside down.
        k3d_uv = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1).astype(np.float32)
        opts.update(
            color=0xFFFFFF,
            texture=png_bytes(arrays["image"], max_texture),
            texture_file_format="png",
            uvs=k3d_uv,
            # UVs outside [0, 1] wrap around (as in sample_texture); an atlas inside [0, 1] is
            # clamped so that filtering at its border does not bleed in the opposite edge
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

    Each mesh keeps its own scale; rows go downwards (k3d's -z), far enough apart
    that they do not hide each other from the default camera (:data:`VIEW`,
    from above). Labels are ``k3d.text`` objects, which the standalone HTML
    page shows too, placed in front of each mesh's base and hanging down from
    there (:func:`label_position`), so that from above they fall below the
    mesh on the screen instead of over it.
    """
    plot = plot if plot is not None else new_plot()
    n = len(meshes)
    if labels is not None and len(labels) != n:
        raise ValueError(f"got {len(labels)} labels for {n} meshes")
    columns = columns or n
    bounds = [_view_bounds(m, up) for m in meshes]
    screen_up = _screen_up(*VIEW)  # a point's height in the default view is roughly screen_up @ point
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
                plot += k3d.text(html.escape(str(labels[k])), position=at, reference_point="ct", color=0x222222,
                                 size=0.9, label_box=False, is_html=True, name=f"label {k}")
                low = min(low, screen_up @ at - 0.15 * row_height)  # room for the text hanging below
    return plot


def _corners(box) -> np.ndarray:
    """The 8 corners of a ``(2, 3)`` box."""
    (x0, y0, z0), (x1, y1, z1) = box
    return np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], np.float64)


def _screen_up(azimuth: float, elevation: float) -> np.ndarray:
    """The screen's up direction (k3d frame) of a camera at ``azimuth``/``elevation`` (:func:`view_camera`)."""
    az, el = np.radians(azimuth), np.radians(elevation)
    return to_view([-np.sin(el) * np.sin(az), np.cos(el), -np.sin(el) * np.cos(az)])[0].astype(np.float64)


def label_position(lo, hi) -> list[float]:
    """Where :func:`gallery` anchors a mesh's label (k3d frame, box ``lo``..``hi``): the middle of its base,
    moved towards the viewer (k3d's -y) by a fifth of the box's largest side. The text hangs down from there."""
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

    ``aabb`` is ``(xmin, ymin, zmin, xmax, ymax, zmax)`` of the cell-centred grid
    (a ``ShapeGrid``'s own box by default; otherwise the box ``±n_axis / n_max``).
    The volume is drawn inside-opaque (negative values), outside clear; the
    isosurface at ``level`` is extracted by k3d in the browser (``k3d.marching_cubes``).
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
        lo, hi, half = (np.array([lo[0], -hi[2], lo[1]]), np.array([hi[0], -lo[2], hi[1]]),
                        half[[0, 2, 1]])
    elif up != "z":
        raise ValueError(f"up must be one of {UP_AXES}, got {up!r}")
    zyx = np.ascontiguousarray(field.transpose(2, 1, 0))  # k3d indexes volumes [z, y, x]
    box = [lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]]
    plot = plot if plot is not None else new_plot()
    if volume:
        t = float(np.abs(zyx).max()) or 1.0
        plot += k3d.volume(
            zyx, bounds=box, color_range=[-t, t], color_map=k3d.colormaps.matplotlib_color_maps.RdBu,
            opacity_function=[0.0, 0.5, 0.45, 0.35, 0.5, 0.0, 1.0, 0.0], alpha_coef=8.0, name="sdf volume",
        )
    if isosurface:
        inner = [lo[0] + half[0], hi[0] - half[0], lo[1] + half[1], hi[1] - half[1], lo[2] + half[2], hi[2] - half[2]]
        plot += k3d.marching_cubes(zyx, level=float(level), bounds=inner, color=int(color), flat_shading=False,
                                   name=f"isosurface {level:g}")
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


# --------------------------------------------------------------------------- HTML
def view_camera(lo, hi, azimuth: float = VIEW[0], elevation: float = VIEW[1], fov: float = 60.0,
                factor: float = 1.1) -> list[float]:
    """k3d's camera vector ``[eye, target, up]`` (9 numbers) looking at the box ``lo``..``hi`` (k3d's frame).

    ``azimuth`` and ``elevation`` (degrees) are in the data's y-up frame, as in
    :mod:`sin3dm_lite.evaluate.render`: azimuth 0 from the front (+z of the data, k3d's
    -y), 90 from +x; elevation 90 straight from above. The eye is far enough
    away that the box's bounding sphere, times ``factor``, fits in a view of
    ``fov`` degrees.
    """
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-9)
    distance = radius * factor / np.sin(np.radians(fov) / 2)
    az, el = np.radians(azimuth), np.radians(elevation)
    direction = to_view([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])[0].astype(np.float64)
    eye = centre + distance * direction
    return [*map(float, eye), *map(float, centre), 0.0, 0.0, 1.0]


def fit_camera(plot: k3d.Plot, azimuth: float = VIEW[0], elevation: float = VIEW[1], factor: float = 1.1) -> list[float]:
    """Point the camera at everything in the plot, from above at an angle by default (:func:`view_camera`).

    Returns the camera vector it set.
    """
    b = plot.get_auto_grid()  # [xmin, xmax, ymin, ymax, zmin, zmax] of all objects
    plot.camera = view_camera(b[::2], b[1::2], azimuth, elevation, fov=plot.camera_fov, factor=factor)
    return list(plot.camera)


#: shown instead of a blank page by a browser without WebGL (:func:`save_html`)
NO_WEBGL = ("This page needs WebGL to show the 3D view, and this browser has it turned off or cannot use it. "
            "Turn on hardware acceleration (or try another browser), or open the mesh files (mesh.obj, mesh.glb) "
            "in Blender or any 3D viewer.")


def with_webgl_message(page: str) -> str:
    """A k3d page with a message that shows when the browser has no WebGL (or no JavaScript) instead of a blank page."""
    box = "position:relative;z-index:10;max-width:40em;margin:3em auto;padding:1em 1.5em;font:16px sans-serif;" \
          "background:#fff3cd;border:1px solid #d4a017;border-radius:4px"
    note = html.escape(NO_WEBGL)
    extra = (f'<div id="sin3dm-no-webgl" style="display:none;{box}">{note}</div>\n'
             f'<noscript><div style="{box}">{note} (It also needs JavaScript.)</div></noscript>\n'
             "<script>(function () {\n"
             "  var gl = null, c = document.createElement('canvas');\n"
             "  try { gl = c.getContext('webgl2') || c.getContext('webgl') || c.getContext('experimental-webgl'); }"
             " catch (e) {}\n"
             "  if (!gl) { document.getElementById('sin3dm-no-webgl').style.display = 'block'; }\n"
             "})();</script>\n")
    m = re.search(r"<body[^>]*>\s*", page)
    if m is None:
        raise ValueError("no <body> in this page")
    return page[:m.end()] + extra + page[m.end():]


def save_html(plot: k3d.Plot, path, fit: bool = True, **camera) -> Path:
    """Write ``plot`` as one self-contained HTML page (k3d's JavaScript embedded; no server, no network).

    With ``fit`` the camera is first pointed at the whole scene (:func:`fit_camera`,
    keyword arguments go there) and the page keeps that view; otherwise the
    plot's current camera is used. A browser without WebGL shows a short
    message (:data:`NO_WEBGL`) instead of a blank page. The file is written
    atomically (a reader never sees half a page). Returns the path.
    """
    path = Path(path)
    auto_fit = plot.camera_auto_fit
    if fit:
        fit_camera(plot, **camera)
        plot.camera_auto_fit = False  # keep our view instead of k3d's default one on load
    try:
        page = plot.get_snapshot()
    finally:
        plot.camera_auto_fit = auto_fit
    atomic_write(path, with_webgl_message(page))
    return path


def read_snapshot(html_or_path) -> dict:
    """Decode the scene stored in a page written by :func:`save_html` (for tests and checks).

    Returns k3d's binary snapshot as a dict: ``objects`` (one dict per drawable,
    arrays as ``{"dtype", "shape", "data"}``), ``plot`` (its parameters), ``version``.
    """
    import msgpack

    text = str(html_or_path)
    if "<html" not in text[:2000].lower():
        text = Path(html_or_path).read_text(encoding="utf-8")
    m = re.search(r"var data = '([A-Za-z0-9+/=]*)'", text)
    if m is None:
        raise ValueError("no k3d snapshot data in this page")
    return msgpack.unpackb(zlib.decompress(base64.b64decode(m.group(1))), raw=False)


def snapshot_array(obj: dict, key: str) -> np.ndarray:
    """An array attribute of one object from :func:`read_snapshot` (e.g. ``"vertices"``) as numpy."""
    a = obj[key]
    data = a["data"]
    if obj.get("compression_level", 0) and isinstance(data, bytes):
        try:
            data = zlib.decompress(data)
        except zlib.error:
            pass
    return np.frombuffer(data, dtype=a["dtype"]).reshape(a["shape"])


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "sample"


def index_page(entries: Sequence[dict], path, title: str = "sin3dm-lite samples") -> Path:
    """A plain ``index.html`` listing samples: a viewer link and download links for each.

    Each entry is a dict with ``title`` and any of ``html_path`` (an existing
    viewer page), ``snapshot`` (a ``k3d.Plot`` or page text, written next to the
    index as ``<title>.html``), ``obj_path``, ``glb_path``, ``thumbnail`` (an
    image path). Links are relative to the index, so the folder can be moved
    or zipped as a whole.
    """
    path = Path(path)
    root = path.parent
    root.mkdir(parents=True, exist_ok=True)

    def rel(p) -> str:
        return html.escape(Path(os.path.relpath(Path(p).resolve(), root.resolve())).as_posix(), quote=True)

    rows = []
    for k, e in enumerate(entries):
        name = str(e.get("title", f"sample {k}"))
        viewer = e.get("html_path")
        snap = e.get("snapshot")
        if viewer is None and snap is not None:
            viewer = root / f"{_slug(name)}.html"
            if isinstance(snap, str):
                atomic_write(viewer, snap)
            else:
                save_html(snap, viewer)
        links = []
        if viewer is not None:
            links.append(f'<a href="{rel(viewer)}">3D viewer</a>')
        for key, label in (("obj_path", "OBJ"), ("glb_path", "GLB")):
            if e.get(key):
                links.append(f'<a href="{rel(e[key])}" download>{label}</a>')
        thumb = (f'<a href="{rel(viewer)}"><img src="{rel(e["thumbnail"])}" alt="{html.escape(name)}" width="160"></a>'
                 if e.get("thumbnail") and viewer is not None
                 else f'<img src="{rel(e["thumbnail"])}" alt="{html.escape(name)}" width="160">' if e.get("thumbnail")
                 else "")
        rows.append(f"<tr><td>{thumb}</td><td>{html.escape(name)}</td><td>{' · '.join(links)}</td></tr>")
    page = "\n".join([
        "<!doctype html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;margin:2em}td{padding:.4em 1em;vertical-align:middle}"
        "table{border-collapse:collapse}tr:nth-child(even){background:#f4f4f4}</style>",
        "</head><body>",
        f"<h1>{html.escape(title)}</h1>",
        "<table>",
        "<tr><th></th><th>sample</th><th>open / download</th></tr>",
        *rows,
        "</table>",
        "</body></html>",
        "",
    ])
    atomic_write(path, page)
    return path

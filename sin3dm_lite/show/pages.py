"""Standalone HTML pages: a k3d plot saved as one self-contained page, read back, and an index of samples."""

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

from ..files import atomic_write
from .camera import fit_camera

#: shown instead of a blank page by a browser without WebGL (:func:`save_html`)
NO_WEBGL = (
    "This page needs WebGL to show the 3D view, and this browser has it turned off or cannot use it. "
    "Turn on hardware acceleration (or try another browser), or open the mesh files (mesh.obj, mesh.glb) "
    "in Blender or any 3D viewer."
)


def with_webgl_message(page: str) -> str:
    """A k3d page with a message that shows when the browser has no WebGL (or no JavaScript) instead of a blank page."""
    box = (
        "position:relative;z-index:10;max-width:40em;margin:3em auto;padding:1em 1.5em;font:16px sans-serif;"
        "background:#fff3cd;border:1px solid #d4a017;border-radius:4px"
    )
    note = html.escape(NO_WEBGL)
    extra = (
        f'<div id="sin3dm-no-webgl" style="display:none;{box}">{note}</div>\n'
        f'<noscript><div style="{box}">{note} (It also needs JavaScript.)</div></noscript>\n'
        "<script>(function () {\n"
        "  var gl = null, c = document.createElement('canvas');\n"
        "  try { gl = c.getContext('webgl2') || c.getContext('webgl') || c.getContext('experimental-webgl'); }"
        " catch (e) {}\n"
        "  if (!gl) { document.getElementById('sin3dm-no-webgl').style.display = 'block'; }\n"
        "})();</script>\n"
    )
    m = re.search(r"<body[^>]*>\s*", page)
    if m is None:
        raise ValueError("no <body> in this page")
    return page[: m.end()] + extra + page[m.end() :]


def save_html(plot: k3d.Plot, path, fit: bool = True, **camera) -> Path:
    """Write ``plot`` as one self-contained HTML page (k3d's JavaScript embedded; no server, no network).

    With ``fit`` the page keeps the view of :func:`fit_camera` (keyword arguments go there), otherwise the
    plot's current camera. A browser without WebGL shows :data:`NO_WEBGL`. Written atomically; returns the path.
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

    Returns k3d's snapshot as a dict: ``objects`` (arrays as ``{"dtype", "shape", "data"}``), ``plot``, ``version``.
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

    Each entry is a dict with ``title`` and any of ``html_path`` (an existing viewer page), ``snapshot`` (a
    ``k3d.Plot`` or page text, written next to the index as ``<title>.html``), ``obj_path``, ``glb_path``,
    ``thumbnail`` (an image path). Links are relative, so the folder can be moved as a whole.
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
        snapshot = e.get("snapshot")
        if viewer is None and snapshot is not None:
            viewer = root / f"{_slug(name)}.html"
            if isinstance(snapshot, str):
                atomic_write(viewer, snapshot)
            else:
                save_html(snapshot, viewer)
        links = []
        if viewer is not None:
            links.append(f'<a href="{rel(viewer)}">3D viewer</a>')
        for key, label in (("obj_path", "OBJ"), ("glb_path", "GLB")):
            if e.get(key):
                links.append(f'<a href="{rel(e[key])}" download>{label}</a>')
        thumb = ""
        if e.get("thumbnail"):
            thumb = f'<img src="{rel(e["thumbnail"])}" alt="{html.escape(name)}" width="160">'
            if viewer is not None:
                thumb = f'<a href="{rel(viewer)}">{thumb}</a>'
        rows.append(f"<tr><td>{thumb}</td><td>{html.escape(name)}</td><td>{' · '.join(links)}</td></tr>")
    page = "\n".join(
        [
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
        ]
    )
    atomic_write(path, page)
    return path

"""Headless pictures of textured meshes: the paper's 8 views, a hero view, a contact sheet.

Sin3DM's figures and evaluation look at a shape from 8 views (azimuth every 45°, elevation 45°), the camera framing
the input's box: :func:`render_views` makes them on a CPU with no display (pass the *input's* box as ``box`` for its
samples, so all are framed alike). Shading is a diffuse material lit from the camera on white; PBR maps
(``metallic_roughness_image``, ``normal_image``) are used where a material has them. y is up; azimuth 0 looks at
the front (the camera on +z), azimuth 90 from +x.

The renderer is pyrender: headless through Mesa's software EGL on Linux without ``$DISPLAY``
(``PYOPENGL_PLATFORM=egl``, set before OpenGL is imported), an invisible pyglet window elsewhere.
"""

from __future__ import annotations

import functools
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..data.mesh import TexturedMesh
from ..errors import Sin3DMInputError
from ..files import atomic_write
from ..formats.export import baked_image
from ..formats.images import png_bytes

#: vertical field of view of the camera, degrees
FOV = 40.0
#: the hero view: (azimuth, elevation) in degrees
HERO = (35.0, 25.0)
BACKGROUND = 255


def _pyrender():
    """Import pyrender, picking EGL on a Linux machine without a display; one-line error if it can't start."""
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY") and "OpenGL" not in sys.modules:
        os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    try:
        import pyrender
    except ImportError as e:
        raise Sin3DMInputError(
            f"rendering needs pyrender ({e}); install it with `pip install pyrender-maintained`"
        ) from None
    return pyrender


@functools.cache
def renderer_problem() -> str | None:
    """None if off-screen rendering works here, else the one-line reason (and fix); tried once per process."""
    try:
        _pyrender().OffscreenRenderer(16, 16).delete()
    except Sin3DMInputError as e:
        return str(e)
    except Exception as e:  # noqa: BLE001 - no EGL / no display
        return (
            f"cannot start an off-screen OpenGL context ({type(e).__name__}: {e}); on Linux install "
            "Mesa's EGL (`apt-get install libegl1 libgl1-mesa-dri`)"
        )
    return None


def view_angles(n_views: int = 8, elevation: float = 45.0) -> list[tuple[float, float]]:
    """``n_views`` (azimuth, elevation) pairs in degrees, azimuth every ``360 / n_views``."""
    return [(360.0 * k / n_views, float(elevation)) for k in range(n_views)]


def _check_box(mesh: TexturedMesh, box) -> np.ndarray:
    lo_hi = np.asarray(mesh.bounds if box is None else box, np.float64)
    if lo_hi.shape != (2, 3) or not np.all(np.isfinite(lo_hi)) or np.any(lo_hi[1] < lo_hi[0]):
        raise Sin3DMInputError(f"box must be the (2, 3) low and high corners of a finite box, got {lo_hi.tolist()}")
    return lo_hi


def _check_mesh(mesh) -> TexturedMesh:
    if not isinstance(mesh, TexturedMesh):
        raise Sin3DMInputError(f"expected a TexturedMesh (see sin3dm_lite.load_mesh), got {type(mesh).__name__}")
    if len(mesh.faces) == 0:
        raise Sin3DMInputError(f"mesh '{mesh.name}' has no faces; there is nothing to render")
    if not np.all(np.isfinite(mesh.vertices)):
        raise Sin3DMInputError(f"mesh '{mesh.name}' has vertices that are not finite numbers")
    return mesh


def _corner_normals(mesh: TexturedMesh) -> np.ndarray:
    """``(F, 3, 3)`` smooth normals at the face corners (area-weighted vertex normals of the welded mesh)."""
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # length = 2 × area
    vn = np.zeros_like(v)
    for k in range(3):
        np.add.at(vn, f[:, k], fn)
    vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)
    return vn[f]


def _texture(image: np.ndarray, pyrender):
    """An ``(h, w, 3)`` image in [0, 1] (or uint8) as a linearly filtered pyrender texture."""
    if image.dtype != np.uint8:
        image = (np.clip(image[..., :3], 0, 1) * 255 + 0.5).astype(np.uint8)
    return pyrender.Texture(
        source=np.ascontiguousarray(image[..., :3]),
        source_channels="RGB",
        sampler=pyrender.Sampler(magFilter=0x2601, minFilter=0x2601),
    )  # GL_LINEAR


def _primitives(mesh: TexturedMesh, pyrender) -> list:
    """One pyrender primitive per material: textured ones carry UVs and the baked texture, others corner colours.
    Vertices are unwelded (three per face), so UV seams and colour changes need no care; normals stay smooth."""
    faces = np.asarray(mesh.faces, np.int64)
    pos = np.asarray(mesh.vertices, np.float32)[faces]  # (F, 3, 3)
    nrm = _corner_normals(mesh).astype(np.float32)
    matte = dict(metallicFactor=0.0, roughnessFactor=1.0, doubleSided=True)
    prims = []
    for mi, mat in enumerate(mesh.materials):
        sel = np.nonzero(np.asarray(mesh.face_material) == mi)[0]
        if len(sel) == 0:
            continue
        n = len(sel)
        common = dict(
            positions=pos[sel].reshape(-1, 3),
            normals=nrm[sel].reshape(-1, 3),
            indices=np.arange(3 * n, dtype=np.uint32).reshape(-1, 3),
        )
        if mat.image is not None and mesh.face_uvs is not None:
            uv = np.nan_to_num(np.asarray(mesh.face_uvs)[sel]).reshape(-1, 2).astype(np.float32)
            material = pyrender.MetallicRoughnessMaterial(
                baseColorTexture=_texture(baked_image(mat), pyrender), **matte
            )
            if mat.metallic_roughness_image is not None:  # PBR: glTF's maps and factors (metal, gloss)
                material.metallicRoughnessTexture = _texture(mat.metallic_roughness_image, pyrender)
                material.metallicFactor, material.roughnessFactor = float(mat.metallic), float(mat.roughness)
            if mat.normal_image is not None:  # tangent frames from the UVs' screen derivatives (pyrender's shader)
                material.normalTexture = _texture(mat.normal_image, pyrender)
            prims.append(pyrender.Primitive(texcoord_0=uv, material=material, **common))
        else:
            colors = mesh.colors_at(np.repeat(sel, 3), np.tile(np.eye(3), (n, 1))).astype(np.float32)
            rgba = np.column_stack([colors, np.ones(3 * n, np.float32)])
            material = pyrender.MetallicRoughnessMaterial(baseColorFactor=[1.0, 1.0, 1.0, 1.0], **matte)
            prims.append(pyrender.Primitive(color_0=rgba, material=material, **common))
    return prims


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """4×4 camera-to-world pose (OpenGL: the camera looks down its -z, y up)."""
    fwd = target - eye
    fwd /= np.linalg.norm(fwd)
    up = np.array([0.0, 1.0, 0.0])
    if abs(fwd @ up) > 0.999:  # looking straight down or up
        up = np.array([0.0, 0.0, -1.0])
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, np.cross(right, fwd), -fwd, eye
    return pose


def camera_pose(box, azimuth: float, elevation: float, fov: float = FOV) -> np.ndarray:
    """Pose of a camera on a sphere around ``box`` whose view holds the whole box (its bounding sphere)."""
    lo, hi = np.asarray(box, np.float64)
    center = (lo + hi) / 2
    radius = max(np.linalg.norm(hi - lo) / 2, 1e-9)
    dist = radius / np.sin(np.radians(fov) / 2) * 1.02
    az, el = np.radians(azimuth), np.radians(elevation)
    eye = center + dist * np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])
    return _look_at(eye, center)


def _render(mesh: TexturedMesh, angles, size: int, box) -> list[np.ndarray]:
    mesh = _check_mesh(mesh)
    box = _check_box(mesh, box)
    if not (16 <= int(size) <= 4096):
        raise Sin3DMInputError(f"image size must be from 16 to 4096 pixels, got {size}")
    pyrender = _pyrender()
    scene = pyrender.Scene(bg_color=[1.0, 1.0, 1.0, 1.0], ambient_light=[0.35, 0.35, 0.35])
    scene.add(pyrender.Mesh(_primitives(mesh, pyrender)))
    lo, hi = box
    diag = max(np.linalg.norm(hi - lo), 1e-9)
    cam = scene.add(pyrender.PerspectiveCamera(yfov=np.radians(FOV), znear=diag * 0.01, zfar=diag * 10))
    # the light comes from above-left of the camera, so faces turned to the viewer are bright and edges readable
    light = scene.add(pyrender.DirectionalLight(color=np.ones(3), intensity=2.6))
    tilt = np.eye(4)
    tilt[:3, :3] = _rotation([1, 0, 0], 0.35) @ _rotation([0, 1, 0], -0.35)
    try:
        renderer = pyrender.OffscreenRenderer(int(size), int(size))
    except Exception as e:  # no EGL / no display: the one thing that goes wrong on a bare machine
        raise Sin3DMInputError(
            f"cannot start an off-screen OpenGL context ({type(e).__name__}: {e}); on Linux install Mesa's EGL "
            "(`apt-get install libegl1 libgl1-mesa-dri`) or set PYOPENGL_PLATFORM=osmesa with libosmesa6"
        ) from None
    images = []
    try:
        for az, el in angles:
            pose = camera_pose(box, az, el)
            scene.set_pose(cam, pose)
            scene.set_pose(light, pose @ tilt)
            color, depth = renderer.render(scene)
            img = np.array(color[..., :3], np.uint8)
            img[depth <= 0] = BACKGROUND  # the clear colour, whatever the GL driver did with it
            images.append(img)
    finally:
        renderer.delete()
    return images


def _rotation(axis, angle: float) -> np.ndarray:
    """3×3 rotation about ``axis`` by ``angle`` radians (Rodrigues)."""
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def render_views(
    mesh: TexturedMesh, n_views: int = 8, size: int = 512, elevation: float = 45.0, box=None
) -> list[np.ndarray]:
    """The paper's views: ``n_views`` azimuths every ``360 / n_views`` degrees at ``elevation``, ``(size, size, 3)`` uint8.

    ``box`` (``(2, 3)`` low / high corners) is what the camera frames (default: the mesh's bounds).
    """
    return _render(mesh, _angles(n_views, elevation), size, box)


def _angles(n_views: int, elevation: float) -> list[tuple[float, float]]:
    """:func:`view_angles` for a checked number of views."""
    if int(n_views) < 1:
        raise Sin3DMInputError(f"n_views must be at least 1, got {n_views}")
    return view_angles(int(n_views), elevation)


def render_hero(mesh: TexturedMesh, size: int = 512, box=None) -> np.ndarray:
    """One three-quarter view (azimuth 35°, elevation 25°) for a README or a preview."""
    return _render(mesh, [HERO], size, box)[0]


def view_names(n_views: int = 8, hero: bool = True) -> list[str]:
    """The file names :func:`save_views` writes."""
    return [f"view_{k:03d}.png" for k in range(n_views)] + (["hero.png"] if hero else [])


def save_views(
    mesh: TexturedMesh, folder, n_views: int = 8, size: int = 512, elevation: float = 45.0, box=None, hero: bool = True
) -> list[Path]:
    """Write ``view_000.png`` … (and ``hero.png``) into ``folder``; each file appears whole (atomic write)."""
    angles = _angles(n_views, elevation) + ([HERO] if hero else [])
    images = _render(mesh, angles, size, box)  # everything rendered before the first file is written
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return [atomic_write(folder / name, png_bytes(img)) for name, img in zip(view_names(int(n_views), hero), images)]


def sheet_columns(n: int) -> int:
    """How many columns a contact sheet of ``n`` panels gets: the grid with the fewest empty cells in its last row,
    as square as that allows (ties: the wider), no narrower than square and at most twice as wide (5 panels: one
    row of 5; 9: 3 × 3)."""
    if n < 1:
        raise Sin3DMInputError(f"a contact sheet needs at least one panel, got {n}")
    square = math.isqrt(n - 1) + 1  # the smallest c with c * c >= n

    def badness(c: int) -> tuple[int, int, int]:
        rows = -(-n // c)
        return rows * c - n, abs(c - rows), -c

    return min(range(square, min(n, 2 * square) + 1), key=badness)


def shared_crop(images: Sequence[np.ndarray], margin: int = 6) -> list[np.ndarray]:
    """Images of one size cropped alike to where any of them differs from its background (its corner's colour),
    plus ``margin`` pixels: renders of one box keep their common scale and place, without the white around them.
    Images of other sizes, or without content, are returned as they are."""
    imgs = [np.asarray(im) for im in images]
    if len({im.shape for im in imgs}) != 1:
        return imgs
    mask = np.zeros(imgs[0].shape[:2], bool)
    for im in imgs:
        pixels = im.reshape(*im.shape[:2], -1).astype(np.int16)
        mask |= np.abs(pixels - pixels[0, 0]).max(-1) > 8
    if not mask.any():
        return imgs
    (r0, r1), (c0, c1) = ((idx[0], idx[-1] + 1) for idx in (np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))))
    rows = slice(max(0, r0 - margin), min(mask.shape[0], r1 + margin))
    cols = slice(max(0, c0 - margin), min(mask.shape[1], c1 + margin))
    return [im[rows, cols] for im in imgs]


def contact_sheet(
    images: Sequence[np.ndarray],
    labels: Sequence[str] | None = None,
    columns: int | None = None,
    pad: int = 4,
    crop: bool = False,
) -> np.ndarray:
    """Images in a grid of ``columns`` (default :func:`sheet_columns`: as full as the count allows), each with its
    label underneath; ``(H, W, 3)`` uint8 on white. ``crop``: the white around the renders cut away alike
    (:func:`shared_crop`).

    Tiles are the size of the largest image (smaller ones are centred).
    """
    from PIL import Image, ImageDraw, ImageFont

    if len(images) == 0:
        raise Sin3DMInputError("contact_sheet needs at least one image")
    if labels is not None and len(labels) != len(images):
        raise Sin3DMInputError(f"{len(labels)} labels for {len(images)} images; give one label per image")
    imgs = [np.asarray(im) for im in images]
    imgs = [np.clip(np.round(im * 255.0), 0, 255).astype(np.uint8) if im.dtype != np.uint8 else im for im in imgs]
    imgs = [np.repeat(im[..., None], 3, 2) if im.ndim == 2 else im[..., :3] for im in imgs]
    imgs = shared_crop(imgs) if crop else imgs
    th = max(im.shape[0] for im in imgs)
    tw = max(im.shape[1] for im in imgs)
    font = ImageFont.load_default()
    label_h = 14 if labels is not None else 0
    cols = sheet_columns(len(imgs)) if columns is None else max(1, min(int(columns), len(imgs)))
    rows = -(-len(imgs) // cols)
    sheet = Image.new("RGB", (cols * (tw + pad) + pad, rows * (th + label_h + pad) + pad), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for i, im in enumerate(imgs):
        r, c = divmod(i, cols)
        x0, y0 = pad + c * (tw + pad), pad + r * (th + label_h + pad)
        sheet.paste(Image.fromarray(im), (x0 + (tw - im.shape[1]) // 2, y0 + (th - im.shape[0]) // 2))
        if labels is not None:
            text = str(labels[i])
            width = draw.textlength(text, font=font)
            draw.text((x0 + (tw - width) / 2, y0 + th + 1), text, fill=(0, 0, 0), font=font)
    return np.asarray(sheet)

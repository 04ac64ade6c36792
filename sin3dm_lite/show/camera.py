"""k3d's frame and camera: data coordinates turned into k3d's z-up frame, and where the camera looks from.

OBJ files (and our normalised meshes) are y-up; :func:`to_view` turns them by ``(x, y, z) → (x, -z, y)``, a
rotation (no mirror), so a shape's front (+z) faces k3d's -y, where :func:`fit_camera` puts the camera.
"""

from __future__ import annotations

import k3d
import numpy as np

UP_AXES = ("y", "z")

#: the default camera of a saved page: (azimuth, elevation) in degrees, in the data's y-up frame (azimuth 0 =
#: from the front, +z; 90 = from +x). From this high a canyon's near bank does not hide its river.
VIEW = (30.0, 60.0)


def to_view(points: np.ndarray, up: str = "y") -> np.ndarray:
    """Data coordinates → k3d's z-up frame (``up="y"``: ``(x, y, z) → (x, -z, y)``), as float32."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if up == "y":
        p = np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1)
    elif up != "z":
        raise ValueError(f"up must be one of {UP_AXES}, got {up!r}")
    return p.astype(np.float32)


def screen_up_vector(azimuth: float, elevation: float) -> np.ndarray:
    """The screen's up direction (k3d frame) of a camera at ``azimuth``/``elevation`` (:func:`view_camera`)."""
    az, el = np.radians(azimuth), np.radians(elevation)
    return to_view([-np.sin(el) * np.sin(az), np.cos(el), -np.sin(el) * np.cos(az)])[0].astype(np.float64)


def view_camera(
    lo, hi, azimuth: float = VIEW[0], elevation: float = VIEW[1], fov: float = 60.0, factor: float = 1.1
) -> list[float]:
    """k3d's camera vector ``[eye, target, up]`` (9 numbers) looking at the box ``lo``..``hi`` (k3d's frame).

    ``azimuth`` and ``elevation`` (degrees) are in the data's y-up frame, as in :mod:`sin3dm_lite.evaluate.render`;
    the eye is far enough away that the box's bounding sphere, times ``factor``, fits in ``fov`` degrees.
    """
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-9)
    distance = radius * factor / np.sin(np.radians(fov) / 2)
    az, el = np.radians(azimuth), np.radians(elevation)
    direction = to_view([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])[0].astype(np.float64)
    eye = centre + distance * direction
    return [*map(float, eye), *map(float, centre), 0.0, 0.0, 1.0]


def fit_camera(
    plot: k3d.Plot, azimuth: float = VIEW[0], elevation: float = VIEW[1], factor: float = 1.1
) -> list[float]:
    """Point the camera at everything in the plot (:func:`view_camera`) and return the camera vector it set."""
    b = plot.get_auto_grid()  # [xmin, xmax, ymin, ymax, zmin, zmax] of all objects
    plot.camera = view_camera(b[::2], b[1::2], azimuth, elevation, fov=plot.camera_fov, factor=factor)
    return list(plot.camera)

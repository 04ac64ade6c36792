"""A ruined round tower, the paper's own kind of input: thin walls, a stepped broken top, a door and windows.

Unlike the built-in examples, whose parts are several voxels across, its walls are ``wall_voxels`` thick at
the training grid it is sized for, a shape at the grid's limit. The solid is a signed distance (a ring, a
slab and boxes cut through the wall) closed by marching cubes; colours are per vertex (stone blocks in
courses, darker joints, an earthen slab). :func:`ruin_tower` builds it z-up from a random generator like the
examples' builders; :func:`build_ruin` y-up from a seed, like :func:`~sin3dm_lite.examples.build_example`.
"""

from __future__ import annotations

import numpy as np

from ..data.mesh import Material, TexturedMesh
from ..errors import Sin3DMInputError
from ..presets import get_preset
from .geometry import y_up

#: samples of the signed distance per voxel of the training grid
DETAIL = 2
#: how the top breaks: the number of steps around the tower
STEPS = 12
DESCRIPTION = (
    "a ruined round tower on a ground slab: walls 2-3 voxels thick at the training grid, a top broken "
    "in steps, a door and two windows"
)


def ruin_tower(
    rng: np.random.Generator,
    resolution: int = 64,
    wall_voxels: float | tuple[float, float] = 2.5,
    square: bool = False,
    flat: bool = False,
    windows: bool = True,
) -> TexturedMesh:
    """The ruin, z-up, for a training grid of ``resolution`` voxels along its longest side (its height).

    A round tower on a square ground slab; its wall ``wall_voxels`` thick, or for a pair ``(thinnest,
    thickest)`` thinner and thicker twice around; a top that falls in steps of 3-5 voxels to about half the
    height on one side; a door facing -x and two windows on the high side. ``rng`` varies the top, with it
    the windows' places, and the stones' colours. ``square``: a square keep instead (the windows on the +x
    and +y faces); ``flat``: the top level all round; ``windows=False``: the door only.
    """
    if not 16 <= resolution <= 512:
        raise Sin3DMInputError(f"resolution must be from 16 to 512 voxels, got {resolution!r}")
    ends = np.ravel(wall_voxels)
    if not (len(ends) in (1, 2) and np.all((ends >= 1.0) & (ends <= 8.0)) and ends[0] <= ends[-1]):
        raise Sin3DMInputError(
            f"wall_voxels must be from 1 to 8, or a pair (thinnest, thickest) of such, got {wall_voxels!r}"
        )
    plan = _plan(rng, resolution, wall_voxels, square, flat, windows)
    vertices, faces = _surface(plan)
    colors = _colors(rng, vertices, plan)
    return TexturedMesh(
        vertices=vertices / plan["height"],
        faces=faces,
        face_material=np.zeros(len(faces), np.int64),
        materials=[Material(name="stone")],
        vertex_colors=colors,
        name="ruin",
    )


def build_ruin(
    seed: int = 0,
    resolution: int = 64,
    wall_voxels: float | tuple[float, float] = 2.5,
    square: bool = False,
    flat: bool = False,
    windows: bool = True,
) -> TexturedMesh:
    """:func:`ruin_tower` for ``seed``, turned y-up like the built-in examples (same seed, same mesh)."""
    mesh = ruin_tower(np.random.default_rng(seed), resolution, wall_voxels, square, flat, windows)
    mesh.vertices = y_up(mesh.vertices)
    return mesh


def _plan(rng: np.random.Generator, resolution: int, wall, square: bool, flat: bool, windows: bool) -> dict:
    """The tower's measures, in voxels of the training grid (the height is the longest side)."""
    # the presets keep a margin of empty voxels to the box: the shape's longest side spans resolution - 2·margin
    height = resolution - 2 * get_preset("quick").grid.margin_voxels
    radius = (0.32 if square else 0.38) * height  # outer (a square's half side)
    low = int(rng.integers(STEPS))  # the sector where the top is lowest
    away = np.abs(np.arange(STEPS) - low)
    away = np.minimum(away, STEPS - away)  # sectors from the lowest, 0 … STEPS / 2 (the full height)
    levels = height - np.concatenate([[0.0], np.cumsum(height * rng.uniform(0.06, 0.09, STEPS // 2))])  # 3-5 voxels
    tops = levels[STEPS // 2 - away] - np.where(away == STEPS // 2, 0.0, rng.uniform(0.0, 1.0, STEPS))
    tops = np.full(STEPS, height) if flat else tops
    slab = 3.0
    door = {"angle": np.pi, "width": 0.16 * height, "bottom": slab, "top": slab + 0.3 * height}
    # the windows on the high side, two sectors either side of the highest, where the wall stands above them
    window_angles = -np.pi + (low + STEPS // 2 + np.array([-2, 2]) + 0.5) * 2 * np.pi / STEPS
    if square:  # through the middle of two faces (an opening at a corner's angle would miss the wall)
        window_angles = np.array([0.0, np.pi / 2])
    openings = [
        {"angle": a, "width": 0.07 * height, "bottom": b * height, "top": (b + 0.12) * height}
        for a, b in zip(window_angles, (0.42, 0.5) if windows else ())
    ]
    return {
        "height": height,
        "radius": radius,
        "wall": wall,
        "slab": slab,
        "half_slab": radius + 0.06 * height,
        "tops": tops,
        "door": door,
        "windows": openings,
        "square": square,
    }


def _across(plan: dict, x, y) -> np.ndarray:
    """Distance from the tower's axis: round (Euclidean) or square (the larger of |x|, |y|)."""
    return np.maximum(np.abs(x), np.abs(y)) if plan["square"] else np.hypot(x, y)


def _wall(plan: dict, angle):
    """The wall's thickness at each point's ``angle`` around the axis: one number, or between a pair's two,
    thickest at a quarter radian (and opposite), thinnest a right angle away."""
    wall = plan["wall"]
    if np.ndim(wall) == 0:
        return wall
    thin, thick = wall
    return thin + (thick - thin) * (0.5 + 0.5 * np.cos(2 * angle - 0.5))


def _opening(x, y, z, radius: float, wall, o: dict) -> np.ndarray:
    """Signed distance (negative inside) of a box through the wall at angle ``o["angle"]``."""
    c, s = np.cos(o["angle"]), np.sin(o["angle"])
    radial, tangential = x * c + y * s, -x * s + y * c
    mid = radius - wall / 2
    return np.maximum.reduce(
        [
            np.abs(tangential) - o["width"] / 2,
            np.abs(radial - mid) - wall,
            np.maximum(o["bottom"] - z, z - o["top"]),
            -radial,
        ]
    )


def _sdf(plan: dict, x, y, z) -> np.ndarray:
    """The ruin's signed distance (negative inside; exact enough near its surface for marching cubes)."""
    angle = np.arctan2(y, x)
    r, wall = _across(plan, x, y), _wall(plan, angle)
    sector = np.floor((angle + np.pi) / (2 * np.pi) * STEPS).astype(int) % STEPS
    ring = np.abs(r - (plan["radius"] - wall / 2)) - wall / 2
    tower = np.maximum.reduce([ring, z - plan["tops"][sector], -z])
    h = plan["half_slab"]
    slab = np.maximum.reduce([np.abs(x) - h, np.abs(y) - h, np.abs(z - plan["slab"] / 2) - plan["slab"] / 2])
    solid = np.minimum(tower, slab)
    for o in [plan["door"], *plan["windows"]]:
        solid = np.maximum(solid, -_opening(x, y, z, plan["radius"], wall, o))
    return solid


def _surface(plan: dict) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes on the signed distance sampled :data:`DETAIL` times per voxel, with a voxel of outside all
    round: a closed surface, faces wound outwards."""
    from skimage.measure import marching_cubes

    # the samples are shifted off the shape's planes (a third of a sample): a sample exactly on the surface would
    # give marching cubes zero-area triangles and twin vertices
    h, top, d = plan["half_slab"] + 1.0, plan["height"] + 1.0, 1.0 / DETAIL
    start = np.array([-h, -h, -1.0]) + d / 3
    xs, zs = np.arange(start[0], h, d), np.arange(start[2], top, d)
    x, y, z = np.meshgrid(xs, xs, zs, indexing="ij")
    volume = _sdf(plan, x, y, z).astype(np.float32)
    vertices, faces, _, _ = marching_cubes(volume, level=0.0, spacing=(d, d, d), gradient_direction="descent")
    vertices = vertices.astype(np.float64) + start
    return vertices, faces.astype(np.int64)


def _colors(rng: np.random.Generator, vertices: np.ndarray, plan: dict) -> np.ndarray:
    """Stone blocks of varied colour in courses (a voxel and a half high), darker joints, an earthen slab."""
    x, y, z = vertices.T
    course = 1.5
    row = np.floor(z / course).astype(int)
    arc = np.arctan2(y, x) * plan["radius"]  # along the wall, in voxels
    block = np.floor(arc / 3.0 + 0.5 * (row % 2)).astype(int)
    tint = rng.uniform(0.85, 1.15, (1024,))
    stone = np.array([0.62, 0.58, 0.52]) * tint[(row * 31 + block * 17) % 1024, None]
    joint = (z % course < 0.25) | ((arc / 3.0 + 0.5 * (row % 2)) % 1.0 < 0.08)
    stone[joint] *= 0.6
    earth = np.array([0.45, 0.38, 0.28])
    colors = np.where(((z < plan["slab"] + 1e-6) & (_across(plan, x, y) > plan["radius"] + 0.5))[:, None], earth, stone)
    return np.clip(colors, 0.0, 1.0).astype(np.float32)


__all__ = ["DESCRIPTION", "build_ruin", "ruin_tower"]

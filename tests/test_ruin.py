"""The ruin test shape: a closed surface, walls 2-3 voxels thick at the training grid, a door, windows, a stepped top."""

import numpy as np
import pytest

from sin3dm_lite.data.grid import mesh_to_grid
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.examples.ruin import build_ruin, ruin_tower
from sin3dm_lite.presets import get_preset

TINY = get_preset("tiny").grid


@pytest.fixture(scope="module")
def ruin():
    return build_ruin(0, resolution=TINY.resolution)


@pytest.fixture(scope="module")
def occupancy(ruin):
    """The ruin on the tiny preset's training grid (32 voxels, its margin), y up."""
    grid = mesh_to_grid(
        ruin, resolution=TINY.resolution, margin_voxels=TINY.margin_voxels, n_surface_points=1000, progress=False
    )
    return grid.sdf < 0


def test_the_ruin_is_a_closed_surface_wound_outwards(ruin):
    f = ruin.faces
    edges = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    directed = {tuple(e) for e in edges.tolist()}
    assert len(directed) == len(edges)  # no edge twice in one direction ...
    assert all((b, a) in directed for a, b in directed)  # ... and every edge once the other way: closed, one winding
    v = ruin.vertices
    assert np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() > 0  # outward normals
    assert ruin.vertex_colors.shape == v.shape and ruin.vertex_colors.std(0).min() > 0.01  # stones of varied colour
    assert np.ptp(v, 0).argmax() == 1  # y up, its height the longest side


def test_a_seed_is_a_ruin(ruin):
    again = build_ruin(0, resolution=TINY.resolution)
    assert np.array_equal(again.vertices, ruin.vertices) and np.array_equal(again.faces, ruin.faces)
    other = ruin_tower(np.random.default_rng(1), resolution=TINY.resolution)
    assert len(other.faces) != len(ruin.faces)  # another broken top


def _runs(line: np.ndarray) -> list[int]:
    """Lengths of the runs of occupied voxels along a line."""
    edges = np.diff(np.concatenate([[0], line.astype(int), [0]]))
    return list(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1))


def test_walls_are_two_to_three_voxels_and_the_door_is_open(occupancy):
    """Along x through the tower's axis: both walls, 2-3 voxels each, above the door; at the door's height only
    the +x wall (the door faces -x); the ground slab is the lowest occupied layer."""
    o = occupancy
    ys = np.flatnonzero(o.any((0, 2)))
    centre = o.shape[2] // 2
    height = ys[-1] - ys[0] + 1
    door = ys[0] + 3 + int(0.15 * height)  # the slab, then half the door's height
    above = ys[0] + 3 + int(0.4 * height)
    assert [2 <= r <= 3 for r in _runs(o[:, above, centre])] == [True, True]
    assert [2 <= r <= 3 for r in _runs(o[:, door, centre])] == [True]
    assert np.flatnonzero(o[:, door, centre])[0] > o.shape[0] // 2  # the wall left is the +x one
    assert o[:, ys[0], :].mean() > 0.4 and o[:, ys[0] + 4, :].mean() < 0.2  # a slab, then only the ring


def test_the_top_breaks_in_steps_and_the_windows_are_open(occupancy):
    """Around the wall the top stands at many heights, a few voxels apart; below it, on the high side, two
    windows: empty voxels in the wall band above the door."""
    o = occupancy
    top = np.where(o.any(1), o.shape[1] - 1 - np.argmax(o[:, ::-1, :], axis=1), -1)
    c = (np.array(o.shape)[[0, 2]] - 1) / 2
    radius = np.hypot(*np.meshgrid(np.arange(o.shape[0]) - c[0], np.arange(o.shape[2]) - c[1], indexing="ij"))
    wall = np.abs(radius - radius[top > top.max() // 2].max() + 1.5) < 0.7  # the middle of the wall
    heights = np.unique(top[wall])
    assert len(heights) >= 6 and heights.max() - heights.min() >= 0.3 * top.max()
    ys = np.flatnonzero(o.any((0, 2)))
    windows = [y for y in range(ys[0] + 4 + int(0.3 * len(ys)), ys[-1]) if (wall & ~o[:, y, :] & (top > y)).any()]
    assert len(windows) >= 2


def test_a_square_keep_has_straight_thin_walls_a_stepped_top_and_a_door():
    """``square=True``: the same ruin with a square plan: along x through the axis two straight walls 2-3
    voxels thick (one at the door's height), and the top around the walls at many heights."""
    keep = build_ruin(0, resolution=TINY.resolution, square=True)
    o = mesh_to_grid(
        keep, resolution=TINY.resolution, margin_voxels=TINY.margin_voxels, n_surface_points=1000, progress=False
    )
    assert o.thin_share() > 0.6  # almost all thin walls, as the round tower
    o = o.sdf < 0
    ys = np.flatnonzero(o.any((0, 2)))
    height, centre = ys[-1] - ys[0] + 1, o.shape[2] // 2
    door = ys[0] + 3 + int(0.15 * height)  # the slab, then half the door's height
    assert [2 <= r <= 3 for r in _runs(o[o.shape[0] // 2, door, :])] == [True, True]  # along z: both walls
    assert [2 <= r <= 3 for r in _runs(o[:, door, centre])] == [True]  # along x at the door: the +x wall only
    # straight walls: at one height the walls across z lie in the same rows all along x's middle
    band = o[o.shape[0] // 2 - 3 : o.shape[0] // 2 + 4, door, :]
    assert (band == band[:1]).all()
    top = np.where(o.any(1), o.shape[1] - 1 - np.argmax(o[:, ::-1, :], axis=1), -1)
    assert len(np.unique(top[top > ys[0] + 3])) >= 6


def test_an_uneven_wall_is_thickest_and_thinnest_where_it_says():
    """``wall_voxels=(3, 6)``: 6 voxels at a quarter radian (and opposite), 3 a right angle away, at the grid of 64."""
    mesh = ruin_tower(np.random.default_rng(3), 64, (3, 6))
    height = 64 - 2 * get_preset("quick").grid.margin_voxels  # one voxel of the grid is 1 / height of the mesh
    v = np.asarray(mesh.vertices) * height
    angle, r = np.arctan2(v[:, 1], v[:, 0]), np.hypot(v[:, 0], v[:, 1])
    low = (v[:, 2] > 5) & (v[:, 2] < 0.3 * height)  # above the slab, below the windows; the door faces -x
    for at, thick in [(0.25, 6), (0.25 + np.pi / 2, 3), (0.25 - np.pi / 2, 3)]:
        near = low & (np.abs(np.angle(np.exp(1j * (angle - at)))) < 0.03)
        assert np.ptp(r[near]) == pytest.approx(thick, abs=0.25)


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"resolution": 8}, "resolution"),
        ({"wall_voxels": 0.5}, "wall_voxels"),
        ({"wall_voxels": (6, 3)}, "a pair"),
        ({"wall_voxels": (3, 9)}, "a pair"),
    ],
)
def test_bad_sizes_are_named(kw, match):
    with pytest.raises(Sin3DMInputError, match=match):
        build_ruin(**kw)


def test_without_windows_the_same_ruin_has_only_its_door():
    """``windows=False``: the same top and door (the same draws of the seed), the wall closed where the windows
    were: more solid, and every voxel the windowed ruin fills filled too."""

    def solid(mesh):
        g = mesh_to_grid(
            mesh, resolution=TINY.resolution, margin_voxels=TINY.margin_voxels, n_surface_points=1000, progress=False
        )
        return g.sdf < 0

    with_windows, plain = (build_ruin(0, resolution=TINY.resolution, windows=w) for w in (True, False))
    a, b = solid(with_windows), solid(plain)
    assert (b & ~a).sum() >= 4 and not (a & ~b).any()  # the windows closed, nothing else moved
    flat = solid(build_ruin(0, resolution=TINY.resolution, windows=False, flat=True))
    assert flat.sum() > b.sum()  # its top still broken (a flat one is fuller): the same plan but the windows

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


@pytest.mark.parametrize("kw, match", [({"resolution": 8}, "resolution"), ({"wall_voxels": 0.5}, "wall_voxels")])
def test_bad_sizes_are_named(kw, match):
    with pytest.raises(Sin3DMInputError, match=match):
        build_ruin(**kw)


def test_quick_and_small_switch_on_the_ruin_and_say_what_else_there_is():
    """The ruin is mostly thin walls at 64 voxels: small switches to its finer thin-part settings; quick (whose
    finer settings take 5x its fit without bf16) switches on the same fit and names
    --thin-switch; quick without its switch gives the hint, which names both."""
    from sin3dm_lite.auto.fit_policy import thin_parts_hint, thin_parts_message, thin_parts_switch, wide_field_undo

    quick = get_preset("quick")
    grid = mesh_to_grid(
        build_ruin(0, resolution=64),
        resolution=quick.grid.resolution,
        margin_voxels=quick.grid.margin_voxels,
        n_surface_points=1000,
        progress=False,
    )
    thin = grid.thin_share()
    assert thin > 0.5
    switched = thin_parts_switch(quick, grid, thin)
    # almost all thin walls: on trial, the wider denoiser field (4 ResBlocks of 16 channels)
    assert switched.grid == quick.grid and switched.name == "quick+walls"
    d = switched.diffusion
    assert (d.n_resblocks, d.base_channels, d.steps, d.batch_size) == (4, 16, 1500, 4)
    assert switched.thin_walls == {} and switched.thin_parts == {}
    said = thin_parts_message(quick, switched, grid, thin)
    assert f"{thin:.0%}" in said and "--thin-switch" in said and "96 voxels" in said
    assert "4 ResBlocks of 16 channels for 1,500 steps on batches of 4 instead of 2 of 32" in said
    assert "a field of 17 latent texels instead of 9" in said and "after 150 steps" in said
    assert "--set thin_walls={}" in said and "updated(thin_walls={})" in said
    # the autoencoder keeps the paper's 5×5 plane convolutions (3×3 close the windows of a thin wall); a kernel the
    # user sets stays theirs, the field still tried
    # ... with free geometry planes beside the encoder's (a window in a thin wall shows in them), said so
    assert switched.autoencoder == quick.autoencoder.__class__(**{**vars(quick.autoencoder), "residual_planes": True})
    assert "plane convolutions" not in said and "free planes" in said
    assert "updated(thin_walls={}) (which drops the line above too; setting a denoiser setting" in said
    # one line per change under the first: the batches, the wider field, the free planes, then three choices
    head, *items = said.split("\n")
    assert head.endswith("(the run's config is named 'quick+walls'):") and len(items) == 6
    assert all(i.startswith("    - ") for i in items) and said.count("batches of 4") == 1
    own = quick.updated(**{"autoencoder.decoder_kernel": 3})
    mine = thin_parts_switch(own, grid, thin)
    assert mine.name == "quick+walls" and mine.autoencoder.decoder_kernel == 3 and mine.diffusion.n_resblocks == 4
    # a shape of fewer thin parts (the colonnade's 0.24) gets the thin-part switch only, and so does a fit whose
    # denoiser the user chose (a setting thin_walls names) or without the trial
    fewer = thin_parts_switch(quick, grid, 0.3)
    assert fewer.name == "quick+thin" and fewer.diffusion == quick.updated(**{"diffusion.batch_size": 6}).diffusion
    assert fewer.autoencoder == quick.autoencoder  # the paper's 5×5 plane convolutions
    assert "ResBlocks" not in thin_parts_message(quick, fewer, grid, 0.3)
    wide = quick.updated(**{"diffusion.n_resblocks": 3})
    # ... which drops the wider field alone: the free planes stay, said so
    assert wide.thin_walls == {"autoencoder.residual_planes": True}
    chose = thin_parts_switch(wide, grid, thin)
    assert chose.name == "quick+walls" and chose.diffusion == wide.updated(**{"diffusion.batch_size": 6}).diffusion
    assert chose.autoencoder.residual_planes
    said = thin_parts_message(wide, chose, grid, thin)
    assert "free planes" in said and "ResBlocks" not in said and "--set thin_walls={}" in said
    assert thin_parts_switch(quick.updated(thin_walls={}), grid, thin).name == "quick+thin"
    assert thin_parts_hint(quick, grid, thin) is None  # it switched: the message says it all
    plain = quick.updated(thin_parts={})  # --no-thin-switch
    hint = thin_parts_hint(plain, grid, thin)
    assert hint is not None and f"{thin:.0%}" in hint and "--thin-switch" in hint and "96 voxels" in hint
    assert thin_parts_switch(plain, grid, thin) is None
    small = get_preset("small")
    # small: a shape of thin walls gets quick's thin-walls switch on small's grid and autoencoder, said so; a shape of
    # fewer thin parts detail's settings
    assert thin_parts_hint(small, grid, thin) is None
    own = thin_parts_switch(small, grid, thin)
    assert own.name == "small+walls" and own.grid == small.grid and own.autoencoder.steps == small.autoencoder.steps
    assert own.diffusion.n_resblocks == 4 and not own.diffusion.rollout
    said = thin_parts_message(small, own, grid, thin)
    assert "copy a shape of thin walls and close its windows: CLI --thin-switch asks for them anyway" in said
    assert "free planes" in said and "a field of 17 latent texels instead of 9" in said
    assert thin_parts_switch(small, grid, 0.3).grid.resolution == 96
    assert wide_field_undo(small) == {  # the trial's fallback: small's own denoiser (its thin-part one is 96 voxels')
        "diffusion.n_resblocks": 2,
        "diffusion.base_channels": 32,
        "diffusion.steps": 2000,
        "diffusion.batch_size": 8,
        "diffusion.rollout": False,
    }
    assert thin_parts_hint(plain, grid, 0.1) is None and thin_parts_switch(quick, grid, 0.1) is None  # few thin parts
    assert thin_parts_hint(get_preset("tiny"), grid, thin) is None  # tests' 32 voxels
    # the finer settings the message names do what it says
    asked = quick.updated(thin_parts={**quick.thin_parts, **small.thin_parts})
    for walls in (False, True):  # the finer settings' own 4-ResBlock field, not the trial's narrower channels
        finer = asked.for_thin_parts(walls=walls)
        assert finer.grid.resolution == 96 and finer.diffusion.rollout and finer.autoencoder.mlp_hidden == 128
        assert finer.diffusion.base_channels == 32 and finer.name == "quick+thin"

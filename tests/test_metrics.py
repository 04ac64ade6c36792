"""Geometry metrics on shapes whose answers are known by construction."""

import numpy as np
import pytest
import trimesh

from sin3dm_lite import extract as ex
from sin3dm_lite import metrics as M
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.evaluate import patches

BOX = np.array([-1.0, -1, -1, 1, 1, 1])


def centres(n, box=BOX):
    axes = [box[a] + (np.arange(n) + 0.5) / n * (box[a + 3] - box[a]) for a in range(3)]
    return np.meshgrid(*axes, indexing="ij")


def lattice(n=60, first=15, count=3, period=10, radius=4.5):
    """``count³`` balls on a lattice with the given period, inside an empty margin."""
    i = np.arange(n)
    near = np.abs((i - first + period / 2) % period - period / 2)  # distance to the nearest lattice plane
    within = (i >= first - period / 2) & (i < first + (count - 0.5) * period)
    d2 = near[:, None, None] ** 2 + near[None, :, None] ** 2 + near[None, None, :] ** 2
    return (d2 < radius**2) & within[:, None, None] & within[None, :, None] & within[None, None, :]


def test_iou_of_a_hand_made_pair():
    a = np.zeros((10, 10, 10), bool)
    b = np.zeros_like(a)
    a[2:6, 2:6, 2:6] = True  # 64 voxels
    b[4:8, 2:6, 2:6] = True  # shifted by 2: 32 shared, union 96
    assert M.iou(a, b) == pytest.approx(1 / 3)
    assert M.iou(a, a) == 1.0 and M.iou(np.zeros_like(a), np.zeros_like(a)) == 1.0
    assert M.pairwise_iou([a, b])[0, 1] == pytest.approx(1 / 3)


def test_g_div_identical_disjoint_and_mismatched_grids():
    a = np.zeros((12, 12, 12), bool)
    a[:6] = True
    assert M.g_div([a, a, a]) == 0.0
    assert M.g_div([a, ~a]) == 1.0
    b = np.roll(a, 3, axis=0)  # IoU(a, b) = 3 / 9
    assert M.g_div([a, b]) == pytest.approx(1 - 1 / 3)
    with pytest.raises(Sin3DMInputError, match="retargeted"):
        M.g_div([a, np.zeros((12, 12, 13), bool)])
    with pytest.raises(Sin3DMInputError):
        M.g_div([np.zeros((12, 12, 13), bool), np.zeros((13, 12, 12), bool)])  # same size, other shape
    with pytest.raises(Sin3DMInputError):
        M.g_div([a])


def test_lp_identical_shapes_score_one():
    x, y, z = centres(48)
    shape = (np.sin(6 * x) + np.cos(5 * y) + np.sin(4 * z)) > 0.2
    scores = M.lp_scores(shape, [shape, shape])
    assert scores["lp_iou"] == 1.0 and scores["lp_fscore"] == 1.0
    assert M.lp_iou(shape, [shape]) == 1.0 and M.lp_fscore(shape, shape) == 1.0


def test_shifted_periodic_pattern_is_locally_perfect_but_diverse():
    ref = lattice()
    shifted = np.roll(ref, 10, axis=0)  # one period (two patch strides) to the right, still inside the margin
    assert M.g_div([ref, shifted]) == pytest.approx(0.5)  # 2 of 3 ball layers overlap: IoU 2 / 4
    scores = M.lp_scores(ref, [shifted])
    assert scores["lp_iou"] == 1.0 and scores["lp_fscore"] == 1.0


def thin_slab_with_steps(n=40):
    """A wall two voxels thick with a stepped top: the kind of shape the stride-5 lattice is hard on."""
    g = np.zeros((n, n, n), bool)
    g[8:30, 8:10, 8:30] = True
    for k, top in enumerate((30, 27, 24, 28)):
        g[8 + 5 * k : 13 + 5 * k, 8:10, top:32] = False
    return g


def test_any_offset_lp_forgives_a_whole_voxel_move_the_paper_lp_does_not():
    ref = thin_slab_with_steps()
    moved = np.roll(ref, 1, axis=0)  # a perfect copy, one voxel off the input's lattice
    paper, any_offset = M.lp_scores(ref, [moved]), M.lp_scores_any_offset(ref, [moved])
    assert paper["lp_iou"] < 0.5  # measured: 0.38
    assert any_offset["lp_iou_any_offset"] == 1.0 and any_offset["lp_fscore_any_offset"] == 1.0
    aligned = M.lp_scores_any_offset(ref, [np.roll(ref, 5, axis=0)])  # on the lattice: both metrics agree
    assert aligned["lp_iou_any_offset"] == 1.0 == M.lp_scores(ref, [np.roll(ref, 5, axis=0)])["lp_iou"]


def test_any_offset_lp_is_the_exact_search_over_every_input_patch():
    """The pruned search (distinct patches, count windows) gives what comparing with every patch gives."""
    rng = np.random.default_rng(3)
    x, y, z = centres(36)
    ref = (np.sin(5 * x) + np.cos(4 * y) + np.sin(3 * z)) > 0.3
    noisy = ref ^ (rng.random(ref.shape) < 0.004)  # a few flipped voxels: some patches stay above 0.95
    for threshold in (0.8, 0.95):
        got = M.lp_scores_any_offset(ref, [noisy, np.roll(ref, 2, axis=1)], threshold=threshold)
        want_iou, want_f = [], []
        every = M.extract_patches(ref, stride=1)
        for grid in (noisy, np.roll(ref, 2, axis=1)):
            best_iou, best_f = patches._best_matches(M.extract_patches(grid)[:1000], every)
            want_iou.append(np.mean(best_iou > threshold))
            want_f.append(np.mean(best_f > threshold))
        assert got["per_shape_iou"] == pytest.approx(want_iou) and got["per_shape_fscore"] == pytest.approx(want_f)
        assert 0 < got["per_shape_iou"][0] < 1  # the noisy copy: a case where the pruning has to decide
    with pytest.raises(Sin3DMInputError, match="threshold"):
        M.lp_scores_any_offset(ref, [ref], threshold=1.0)
    with pytest.raises(Sin3DMInputError, match="no surface patches"):
        M.lp_scores_any_offset(np.zeros_like(ref), [ref])


def test_unrelated_shape_scores_low():
    ref = lattice()
    x, y, z = centres(60)
    blob = x**2 + y**2 + z**2 < 0.5
    assert M.lp_iou(ref, [blob]) < 0.2


def test_patch_fscore_is_dice_of_occupied_voxels():
    """Generated patch ⊂ reference patch: precision 1, recall 10/20 → IoU 0.5, F = 2/3."""
    g = np.zeros((1, 1331), bool)
    r = np.zeros((1, 1331), bool)
    g[0, :10] = True
    r[0, :20] = True
    best_iou, best_f = patches._best_matches(g, r)
    assert best_iou[0] == pytest.approx(0.5) and best_f[0] == pytest.approx(2 / 3)


def test_extract_patches_keeps_surface_patches_only():
    empty = np.zeros((30, 30, 30), bool)
    assert len(M.extract_patches(empty)) == 0
    block = empty.copy()
    block[3:27, 3:27, 15:27] = True
    # patch centres at 0, 5, ..., 25 per axis; only the cores around z = 15 (voxels 14..16) straddle a face
    patches = M.extract_patches(block)
    assert patches.shape == (5 * 5, 11**3)
    # outside the grid counts as empty: a full grid has surface patches along its border only
    assert 0 < len(M.extract_patches(~empty)) < 6**3


def test_voxelize_marching_cubes_mesh_matches_its_sdf():
    x, y, z = centres(32)
    sdf = np.sqrt((x - 0.1) ** 2 + y**2 + z**2) - 0.6
    v, f = ex.marching_cubes(sdf, BOX)
    occ = M.voxelize((v, f), BOX, 32)
    assert occ.shape == (32, 32, 32)
    np.testing.assert_array_equal(occ, sdf < 0)
    np.testing.assert_array_equal(M.voxelize((v, f[:, ::-1]), BOX, 32), sdf < 0)  # inward-facing too


def test_voxelize_fills_nested_and_separate_shells():
    big = trimesh.creation.icosphere(subdivisions=5, radius=0.8)  # 20k faces
    occ = M.voxelize(big, BOX, 128)
    x, y, z = centres(128)
    assert M.iou(occ, x**2 + y**2 + z**2 < 0.8**2) > 0.99
    # nested shells count crossings (a winding number): the same way round, the inner one is still inside;
    # an inside-out inner shell cancels the outer one, leaving a hollow ball
    outer, inner = trimesh.creation.icosphere(4, radius=0.8), trimesh.creation.icosphere(4, radius=0.4)
    r2 = sum(c**2 for c in centres(64))
    solid = M.voxelize(trimesh.util.concatenate([outer, inner]), BOX, 64)
    assert M.iou(solid, r2 < 0.8**2) > 0.98
    inner.invert()
    hollow = M.voxelize(trimesh.util.concatenate([outer, inner]), BOX, 64)
    assert M.iou(hollow, (0.4**2 <= r2) & (r2 < 0.8**2)) > 0.97
    # two disjoint spheres in a non-cubic box
    box = np.array([-1.0, -0.5, -0.5, 1.0, 0.5, 0.5])
    a = trimesh.creation.icosphere(3, radius=0.3)
    b = a.copy()
    a.apply_translation([-0.5, 0, 0])
    b.apply_translation([0.5, 0, 0])
    two = trimesh.util.concatenate([a, b])
    occ2 = M.voxelize(two, box, 64)
    assert occ2.shape == (64, 32, 32)
    xs, ys, zs = np.meshgrid(
        *[box[i] + (np.arange(n) + 0.5) / n * (box[i + 3] - box[i]) for i, n in enumerate(occ2.shape)], indexing="ij"
    )
    truth = np.minimum((xs + 0.5) ** 2, (xs - 0.5) ** 2) + ys**2 + zs**2 < 0.3**2
    assert M.iou(occ2, truth) > 0.97


def test_the_papers_voxels_are_solid_where_any_sub_voxel_is_inside():
    """The paper's evaluation voxelises at twice the resolution and pools (any of 2³ inside): a wall thinner than
    a voxel, lying between two layers of voxel centres, is lost by the centres and kept by the paper's voxels."""
    fine = np.zeros((8, 6, 4), bool)
    fine[3, 0, 1] = True  # one fine voxel: the coarse voxel (1, 0, 0) holds it
    pooled = M.any_inside(fine, 2)
    assert pooled.shape == (4, 3, 2) and pooled.sum() == 1 and pooled[1, 0, 0]
    np.testing.assert_array_equal(M.any_inside(fine, 1), fine)
    with pytest.raises(Sin3DMInputError, match="pool 2x"):
        M.any_inside(np.zeros((5, 4, 4), bool), 2)
    # a slab 0.8 voxel thick at 16 voxels, centred on the border of voxels 7 and 8 along x (x = 0): it misses their
    # centres (half a voxel away) and holds a sub-voxel centre of each (a quarter voxel away)
    slab = trimesh.creation.box(extents=(0.8 * 2 / 16, 1.5, 1.5))
    centres_only = M.voxelize(slab, BOX, 16)
    paper = M.voxelize(slab, BOX, 16, supersample=M.PAPER_SUPERSAMPLE)
    assert centres_only.sum() == 0
    assert paper.shape == (16, 16, 16)
    assert paper.any(axis=(1, 2)).tolist() == [i in (7, 8) for i in range(16)]  # both voxels hold a sub-centre in it
    # the input's voxels (winding numbers, open meshes too) are pooled the same way
    np.testing.assert_array_equal(M.input_occupancy(slab, BOX, 16, supersample=2), paper)
    assert M.input_occupancy(slab, BOX, 16).sum() == 0
    # a ball: the paper's voxels hold the centres' and a thin shell more
    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.6)
    a, b = M.voxelize(ball, BOX, 32), M.voxelize(ball, BOX, 32, supersample=2)
    assert (a & ~b).sum() == 0 and 0 < (b & ~a).sum() < 0.25 * a.sum()
    for bad in (0, 1.5, True, "2"):
        with pytest.raises(Sin3DMInputError, match="supersample must be"):
            M.voxelize(ball, BOX, 32, supersample=bad)


def test_reconstruction_iou_of_a_mesh_with_itself():
    m = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    assert M.reconstruction_iou(m, m, BOX, 32) == 1.0
    shifted = m.copy()
    shifted.apply_translation([0.25, 0, 0])  # exactly 4 voxels of 16 along x: IoU 12 / 20
    assert M.reconstruction_iou(m, shifted, BOX, 32) == pytest.approx(0.6)


def test_variation_scores_of_copies_and_shifted_samples():
    ref = np.zeros((12, 12, 12), bool)
    ref[3:9, 3:9, 3:9] = True
    moved = np.roll(ref, 2, axis=0)  # 4 of 6 layers overlap: IoU 4 / 8
    v = M.variation_scores(ref, [ref, ref])
    assert v == {"iou_to_input": 1.0, "per_sample_iou": [1.0, 1.0], "g_div": 0.0}
    v = M.variation_scores(ref, [ref, moved])
    assert v["per_sample_iou"] == [1.0, 0.5] and v["iou_to_input"] == 0.75 and v["g_div"] == 0.5
    assert M.variation_scores(ref, [moved]) == {"iou_to_input": 0.5, "per_sample_iou": [0.5], "g_div": None}


def test_input_occupancy_of_an_open_and_a_closed_mesh():
    """The reference of the LP metrics: voxel centres inside the input, open meshes included."""
    box = trimesh.creation.box(extents=(1.0, 0.5, 0.5))  # x in [-0.5, 0.5]
    aabb = np.array([-1, -0.5, -0.5, 1, 0.5, 0.5])
    occ = M.input_occupancy(box, aabb, 16)  # 16 × 8 × 8 voxels of 0.125
    assert occ.shape == (16, 8, 8)
    assert occ[4:12, 2:6, 2:6].all() and occ.sum() == 8 * 4 * 4  # centres inside |x| < 0.5, |y|, |z| < 0.25
    # the same box without its top face is still a box: the winding number is ≈ 1 inside
    top = box.face_normals[:, 1] > 0.5
    open_box = (box.vertices, box.faces[~top])
    np.testing.assert_array_equal(M.input_occupancy(open_box, aabb, 16), occ)
    # agrees with voxelize on a closed mesh
    np.testing.assert_array_equal(M.voxelize((box.vertices, box.faces), aabb, 16), occ)


def test_patch_matches_show_the_pairs_lp_iou_scores():
    ref = lattice()
    shifted = np.roll(ref, 10, axis=0)
    m = M.patch_matches(ref, shifted, n=3)
    assert m["generated"].shape == m["matched"].shape == (3, 11, 11, 11)
    np.testing.assert_array_equal(m["generated"], m["matched"])  # a shifted copy: every patch has its twin
    assert np.all(m["iou"] == 1.0) and np.all(m["fscore"] == 1.0)
    assert np.mean(m["best_iou"] > m["threshold"]) == M.lp_iou(ref, [shifted])
    x, y, z = centres(60)
    blob = x**2 + y**2 + z**2 < 0.5
    m = M.patch_matches(ref, blob, n=4)
    assert list(m["iou"]) == sorted(m["iou"])  # spread from the worst-matched patch to the best
    assert m["iou"][0] == m["best_iou"].min() and m["iou"][-1] == m["best_iou"].max()
    g, r = m["generated"][0], m["matched"][0]
    assert m["iou"][0] == pytest.approx(M.iou(g, r))  # the pair shown is the pair scored
    assert np.mean(m["best_iou"] > 0.95) == M.lp_iou(ref, [blob])
    with pytest.raises(Sin3DMInputError, match="surface patches"):
        M.patch_matches(ref, np.zeros_like(ref))


def test_results_table_lines_up_columns_and_marks_missing_values():
    text = M.results_table({"default": {"metrics": {"g_div": 0.21, "lp_iou": 0.5}}, "diversity 1.0": {"g_div": 0.3}})
    lines = text.splitlines()
    assert len(lines) == 1 + len(M.METRICS)
    assert "default" in lines[0] and "diversity 1.0" in lines[0]
    g = next(line for line in lines if line.startswith("g_div"))
    assert "0.210" in g and "0.300" in g and "G-Div" in g
    assert next(line for line in lines if line.startswith("lp_iou")).split()[1:3] == ["0.500", "-"]
    end = lines[0].index("diversity 1.0") + len("diversity 1.0")  # each row's values end under their labels
    assert all(line[:end].endswith(("0.300", "-")) for line in lines[1:]), text
    with pytest.raises(Sin3DMInputError):
        M.results_table({})


def _battlements(n=5, seed=0):
    """A slab that every shape shares, with random columns on top (layers 8-10 of 12 along y)."""
    rng = np.random.default_rng(seed)
    body = np.zeros((16, 12, 10), bool)
    body[2:14, 1:8, 3:7] = True
    grids = []
    for _ in range(n):
        g = body.copy()
        g[2:14, 8:11, 3:7] = rng.random((12, 1, 4)) < 0.5
        grids.append(g)
    return grids


def test_g_div_by_layer_sums_to_g_div_and_shows_where_the_shapes_differ():
    grids = _battlements()
    parts = M.g_div_by_layer(grids, axis=1)
    assert parts.shape == (12,) and parts.sum() == pytest.approx(M.g_div(grids))
    assert np.all(parts[:8] == 0) and np.all(parts[8:11] > 0) and parts[11] == 0  # only the top varies
    assert np.allclose(parts[8:11], parts[8])  # a column is one random choice: the same in all its layers
    along_x = M.g_div_by_layer(grids, axis=0)
    assert along_x.shape == (16,) and along_x.sum() == pytest.approx(M.g_div(grids))
    assert np.all(along_x[:2] == 0) and np.all(along_x[14:] == 0)
    assert np.all(M.g_div_by_layer([grids[0], grids[0]]) == 0)
    with pytest.raises(Sin3DMInputError, match="at least two"):
        M.g_div_by_layer(grids[:1])
    with pytest.raises(Sin3DMInputError, match="axis must be 0, 1 or 2"):
        M.g_div_by_layer(grids, axis=3)


def test_the_inputs_voxels_of_a_closed_mesh_are_its_winding_numbers():
    """A closed input is voxelised by a ray cast (fast), an open one by winding numbers: both give the grid the
    generalised winding number gives, inside-out parts turned round first, holes and nested parts included."""
    from types import SimpleNamespace

    from sin3dm_lite.data.distance import Distance

    torus = trimesh.creation.torus(major_radius=0.5, minor_radius=0.2)
    inner = trimesh.creation.box(extents=(0.3, 0.3, 0.3))
    inner.apply_translation([0.5, 0, 0])  # inside the torus's tube: winding 2 there
    outer = trimesh.creation.box(extents=(0.4, 1.6, 0.5))
    outer.invert()  # an inside-out part: turned round before counting
    parts = [torus, inner, outer]
    verts = np.concatenate([p.vertices for p in parts])
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    faces = np.concatenate([p.faces + o for p, o in zip(parts, offsets)])

    def by_winding(v, f, res=24):  # the generalised winding number at every voxel centre
        x = centres(res)
        p = np.stack(x, -1).reshape(-1, 3)
        return (Distance(SimpleNamespace(vertices=v, faces=f)).winding(p) > 0.5).reshape(x[0].shape)

    closed = M.input_occupancy((verts, faces), BOX, 24)
    np.testing.assert_array_equal(closed, by_winding(verts, faces))
    assert closed.sum() > by_winding(torus.vertices, torus.faces).sum()  # the turned-round box counts
    cut = faces[verts[faces].mean(1)[:, 2] < 0.15]  # the top of every part cut off: open, winding numbers decide
    np.testing.assert_array_equal(M.input_occupancy((verts, cut), BOX, 24), by_winding(verts, cut))
    paper = M.input_occupancy((verts, faces), BOX, 12, supersample=2)
    np.testing.assert_array_equal(paper, M.any_inside(by_winding(verts, faces), 2))
    # open, the paper's voxels: sub-voxels get their own winding number near the surface and across the holes
    np.testing.assert_array_equal(M.input_occupancy((verts, cut), BOX, 12, 2), M.any_inside(by_winding(verts, cut), 2))
    slab = trimesh.creation.box(extents=(0.8 * 2 / 16, 1.5, 1.5))  # between two layers of voxel centres
    side = slab.face_normals[:, 1] > 0.5
    open_slab = (slab.vertices, slab.faces[~side])  # one end open: its centres are all outside, as closed
    assert M.input_occupancy(open_slab, BOX, 16).sum() == 0
    np.testing.assert_array_equal(M.input_occupancy(open_slab, BOX, 16, 2), M.voxelize(slab, BOX, 16, 2))


def hollow_tower(n=48, wall=3, top=40):
    """A square tower of ``wall``-voxel walls on a slab, open at the top, along y (up)."""
    g = np.zeros((n, n, n), bool)
    g[8:40, 4:top, 8:40] = True
    g[8 + wall : 40 - wall, 7:top, 8 + wall : 40 - wall] = False
    g[4:44, 2:5, 4:44] = True
    return g


def test_lp_misses_by_band_finds_where_a_variant_lost_its_patches():
    ref = hollow_tower()
    same = M.lp_misses_by_band(ref, [ref, ref])
    assert same["lp_iou"] == 1.0 and same["missed"] == [0.0] * 5
    assert sum(same["share"]) == pytest.approx(1.0) and all(s > 0 for s in same["share"])
    new_top = ref.copy()
    new_top[8:24, 34:40, 8:40] = False  # another broken top: half the tower lower
    top = M.lp_misses_by_band(ref, new_top)
    assert top["missed"][:3] == [0.0] * 3 and min(top["missed"][3:]) > 0.1  # measured: 0.27, 0.15
    moved = np.zeros_like(ref)
    moved[:, 5:] = ref[:, 5:]
    moved[1:, 5:] = ref[:-1, 5:]  # the walls one voxel sideways, the slab in place
    walls = M.lp_misses_by_band(ref, moved)
    assert min(walls["missed"]) > 0.4 and walls["lp_iou"] < top["lp_iou"]  # measured: 0.5-1 in every slab
    assert walls["lp_iou"] == pytest.approx(M.lp_scores(ref, [moved], max_patches=10**6)["lp_iou"])
    assert np.isnan(M.lp_misses_by_band(ref, np.zeros_like(ref))["lp_iou"])  # an empty sample is not a perfect one


@pytest.mark.parametrize("radius", [0.47, 0.23])
def test_the_papers_voxels_read_from_an_sdf_grid_are_those_of_its_marching_cubes_mesh(radius):
    """The calibration judges a sample by the paper's voxels without making its mesh: its SDF at the voxel centres
    read between them as marching cubes reads it (trilinearly), closed at the box's faces as the mesh is."""
    from sin3dm_lite.evaluate.geometry import interpolated_inside

    x, y, z = centres(24)
    for sdf in (np.sqrt((x - 0.1) ** 2 + y**2 + z**2) - radius, x + 0.135):  # a ball; a slab through the -x face
        mesh = M.voxelize(ex.marching_cubes(sdf, BOX), BOX, 24, supersample=2)
        paper = interpolated_inside(sdf, 2)
        assert paper.shape == sdf.shape and np.mean(paper != mesh) < 0.002
        assert (sdf < 0).sum() < paper.sum()  # the centres' voxels and those the surface passes through
        np.testing.assert_array_equal(interpolated_inside(sdf, 1), sdf < 0)

"""mesh → TSDF + colour grid: signs and distances against independent computations."""

import warnings

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from sin3dm_lite.data.box import grid_shape
from sin3dm_lite.data.grid import load_grid, mesh_to_grid, save_grid
from sin3dm_lite.data.mesh import Material, TexturedMesh
from sin3dm_lite.errors import Sin3DMInputError

from .conftest import textured


def grid_dims(extent, resolution, margin_voxels=0.0):
    """The training grid's rule: box.grid_shape with counts rounded up to multiples of 8."""
    return grid_shape(extent, resolution, multiple=8, margin_voxels=margin_voxels)


def box_sdf(p, half):
    q = np.abs(p) - half
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0)


def test_grid_dims_follow_the_paper():
    # docs/paper-notes.md: extents 4.56 x 6.32 x 4.54 at 256 → 184 x 256 x 184
    assert grid_dims(np.array([4.56, 6.32, 4.54]), 256) == (184, 256, 184)
    assert all(d % 8 == 0 for d in grid_dims(np.array([1.0, 0.33, 0.1]), 64))


def test_margin_keeps_every_box_face_clear_of_the_shape():
    box = trimesh.creation.box(extents=(1.0, 0.5, 0.3))
    plain = mesh_to_grid(textured(box), 64, n_surface_points=0, progress=False)
    g = mesh_to_grid(textured(box), 64, n_surface_points=0, progress=False, margin_voxels=3.25)
    vs = g.voxel_size
    half = np.array([1.0, 0.5, 0.3]) / 2 * g.normalization.scale  # the box's half size in the grid's frame
    assert np.all(g.aabb[3:] - half >= 3.25 * vs - 1e-6)  # at least the margin on every side
    assert g.aabb[3] - half[0] == pytest.approx(3.25 * vs)  # exactly it along the longest axis (shrunk to fit)
    assert g.normalization.scale < plain.normalization.scale and g.shape[1:] > plain.shape[1:]
    faces = [g.sdf[0], g.sdf[-1], g.sdf[:, 0], g.sdf[:, -1], g.sdf[:, :, 0], g.sdf[:, :, -1]]
    assert min(f.min() for f in faces) >= 2.7 * vs  # outermost voxels: 3.25 - 0.5 voxels outside, at least
    # the normalisation still maps the grid back onto the input: the box's corner lands on the original corner
    corner = g.normalization.to_original(half[None])[0]
    np.testing.assert_allclose(corner, [0.5, 0.25, 0.15], atol=1e-9)
    assert grid_dims(np.array([2.0, 0.5, 0.3]), 64, 3.25) == (64, 24, 24)  # 16 + 6.5 → 24; 9.6 + 6.5 → 24


@pytest.mark.parametrize("res", [32, 64])
def test_sphere_sdf_matches_analytic(res):
    g = mesh_to_grid(textured(trimesh.creation.icosphere(subdivisions=5)), res, n_surface_points=2000, progress=False)
    assert g.shape == (res, res, res)
    np.testing.assert_allclose(g.aabb, [-1, -1, -1, 1, 1, 1])
    assert g.threshold == pytest.approx(3 * 2 / res)
    r = np.linalg.norm(g.voxel_centers(), axis=-1) - 1 / 1.03  # normalised radius: longest side × 1.03 = 2
    exact = np.clip(r, -g.threshold, g.threshold)
    assert np.abs(exact - g.sdf).max() < 0.02 * g.threshold * res / 8  # tessellation error only
    assert np.all(((g.sdf < 0) == (r < 0)) | (np.abs(r) < 1e-3))


def test_box_sdf_non_cubic_grid_and_symmetric_box():
    g = mesh_to_grid(textured(trimesh.creation.box(extents=(1.0, 0.5, 0.3))), 64, n_surface_points=2000, progress=False)
    assert g.shape == (64, 32, 24)  # 0.5/1*64 = 32; 0.3/1*64 = 19.2 → 19 → 24
    np.testing.assert_allclose(g.aabb, [-1, -0.5, -0.375, 1, 0.5, 0.375])
    half = np.array([1.0, 0.5, 0.3]) / 2 * g.normalization.scale
    exact = np.clip(box_sdf(g.voxel_centers().reshape(-1, 3), half), -g.threshold, g.threshold)
    np.testing.assert_allclose(g.sdf.reshape(-1), exact, atol=2e-4)  # float32 inside point-cloud-utils


def test_open_mesh_signs_and_distances_match_trimesh():
    # a sphere with its top cap cut off: no "make watertight" step, the winding number gives the sign
    sphere = trimesh.creation.icosphere(subdivisions=4)
    keep = sphere.triangles_center[:, 2] < 0.6
    cup = trimesh.Trimesh(sphere.vertices, sphere.faces[keep], process=False)
    assert not cup.is_watertight
    g = mesh_to_grid(textured(cup), 32, n_surface_points=2000, progress=False)
    c = g.voxel_centers()
    s = g.sdf.reshape(-1)
    # deep inside near the bottom: inside; outside the sphere (box corner): outside
    inside_pt = np.argmin(np.linalg.norm(c.reshape(-1, 3) - np.array([0, 0, -0.5]), axis=-1))
    assert s[inside_pt] < 0
    assert g.sdf[0, 0, 0] > 0 and g.sdf[-1, -1, -1] > 0
    # distances inside the band equal those to a dense point sampling of the surface (independent of pcu)
    band = np.abs(g.sdf) < g.threshold * 0.99
    n = g.normalization
    cup_n = trimesh.Trimesh(n.to_normalized(cup.vertices), cup.faces, process=False)
    dense = cup_n.sample(400_000, seed=0)
    d, _ = cKDTree(dense).query(c[band])
    assert np.abs(np.abs(g.sdf[band]) - d).max() < 0.01  # sample spacing ≈ 0.005; a voxel is 0.0625


@pytest.mark.parametrize("res", [40, 64])
def test_block_refinement_equals_a_brute_force_grid(res):
    # the coarse-to-fine pass skips most voxels; it must give what a distance and a
    # winding number at *every* voxel give, also next to a hole, where the winding
    # number drifts through 1/2 away from any surface
    import point_cloud_utils as pcu

    sphere = trimesh.creation.icosphere(subdivisions=4)
    bumps = sphere.vertices * (1 + 0.1 * np.sin(6 * sphere.vertices[:, :1]))
    cup = trimesh.Trimesh(bumps, sphere.faces[sphere.triangles_center[:, 2] < 0.5], process=False)
    second = trimesh.creation.box(extents=(0.3, 0.3, 0.3))
    second.apply_translation([0.2, 0.1, 0.9])  # a closed part in the cup's opening
    mesh = textured(trimesh.util.concatenate([cup, second]))
    g = mesh_to_grid(mesh, res, n_surface_points=20_000, near_surface_sigma=0.5 / res, progress=False)
    m = mesh.normalized()
    v, f = m.vertices.astype(np.float64), m.faces.astype(np.int64)

    def brute(c):
        d, _, _ = pcu.closest_points_on_mesh(c, v, f)
        w = pcu.triangle_soup_fast_winding_number(v, f, c)
        return np.where(w > 0.5, -1, 1) * np.minimum(d, g.threshold), w

    grid_sdf, w = brute(g.voxel_centers().reshape(-1, 3).astype(np.float64))
    np.testing.assert_allclose(g.sdf.reshape(-1), grid_sdf, atol=1e-6)
    assert ((w > 0.2) & (w < 0.8)).sum() > 100  # the test does cover voxels near the hole
    # the training points take most signs from the voxels around them: the same signs
    point_sdf, w = brute(g.points.astype(np.float64))
    np.testing.assert_allclose(g.point_sdf, point_sdf, atol=1e-6)
    assert ((w > 0.2) & (w < 0.8)).sum() > 20


def test_inside_out_parts_are_turned_round_with_a_warning():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    right = mesh_to_grid(textured(sphere), 32, n_surface_points=0, progress=False)
    with pytest.warns(UserWarning, match="'m' is inside out"):
        inverted = mesh_to_grid(
            textured(trimesh.Trimesh(sphere.vertices, sphere.faces[:, ::-1])), 32, n_surface_points=0, progress=False
        )
    assert (right.sdf < 0).sum() > 1000
    np.testing.assert_array_equal(inverted.sdf, right.sdf)
    # several parts: only the closed, inside-out box is flipped; the others keep their inside
    box = trimesh.creation.box(extents=(0.5, 0.5, 0.5))
    box.apply_translation([1.5, 0, 0])
    cup = trimesh.Trimesh(sphere.vertices - [2.5, 0, 0], sphere.faces[sphere.triangles_center[:, 2] < 0.6])  # open
    scene = trimesh.util.concatenate([sphere, trimesh.Trimesh(box.vertices, box.faces[:, ::-1]), cup])
    with pytest.warns(UserWarning, match="1 of the 3 parts"):
        g = mesh_to_grid(textured(scene), 64, n_surface_points=0, progress=False)
    centre = g.to_box(g.normalization.to_normalized(np.array([[1.5, 0, 0], [0, 0, 0], [-2.5, 0, -0.5]])))
    idx = np.floor((centre + 1) / 2 * np.array(g.shape)).astype(int)
    assert all(g.sdf[i, j, k] < 0 for i, j, k in idx)  # inside the box, the sphere and the cup's bottom


def test_a_two_sided_mesh_built_in_python_grids_and_scores_as_its_one_side():
    """The loader keeps each triangle of a two-sided file once; a mesh built in Python never meets the loader, so
    the grid and the metrics' input occupancy keep each triangle once themselves (the pairs would cancel in the
    winding number: the box read as a thin shell, inside out)."""
    from sin3dm_lite.evaluate.geometry import input_occupancy

    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    one = textured(box)
    two = textured(trimesh.Trimesh(box.vertices, np.vstack([box.faces, box.faces[:, ::-1]]), process=False))
    assert len(two.faces) == 24
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "inside out", no "thin parts"
        grids = [mesh_to_grid(m, 16, n_surface_points=0, progress=False).sdf for m in (one, two)]
    assert (grids[0] < 0).sum() > 500
    np.testing.assert_array_equal(grids[1], grids[0])
    box6 = np.array([-1.0, -1, -1, 1, 1, 1])
    occupied = [input_occupancy(m.normalized(), box6, 32, supersample=2) for m in (one, two)]
    assert occupied[0].sum() > 5000
    np.testing.assert_array_equal(occupied[1], occupied[0])


def test_closed_means_every_edge_used_both_ways():
    from sin3dm_lite.data.distance import Distance

    sphere = trimesh.creation.icosphere(subdivisions=2)
    assert Distance(textured(sphere)).closed
    assert not Distance(textured(trimesh.Trimesh(sphere.vertices, sphere.faces[1:]))).closed  # a hole
    wrong = sphere.faces.copy()
    wrong[0] = wrong[0, ::-1]
    one_wrong = Distance(textured(trimesh.Trimesh(sphere.vertices, wrong, process=False)))
    assert one_wrong.closed and one_wrong.turned_round.faces == 1  # one face flipped: wound as its neighbours
    a, b = trimesh.creation.box(), trimesh.creation.box()
    b.apply_translation([1, 0, 0])  # two cubes sharing a face: still closed surfaces, edges used 4 times
    assert Distance(textured(trimesh.util.concatenate([a, b]))).closed
    # a UV seam (vertices duplicated at the same position) does not open the surface
    v, f = sphere.vertices, sphere.faces.copy()
    seam = np.vstack([v, v[f[0]]])
    f[0] = len(v) + np.arange(3)
    assert Distance(textured(trimesh.Trimesh(seam, f, process=False))).closed


def test_two_part_mesh_has_both_parts_inside():
    a = trimesh.creation.icosphere(subdivisions=3, radius=0.4)
    b = a.copy()
    a.apply_translation([-0.6, 0, 0])
    b.apply_translation([0.6, 0, 0])
    g = mesh_to_grid(textured(trimesh.util.concatenate([a, b])), 32, n_surface_points=2000, progress=False)
    s = g.sdf
    mid = s.shape[1] // 2, s.shape[2] // 2
    line = s[:, mid[0], mid[1]]
    # inside, outside (the gap), inside along the x axis
    inside = line < 0
    runs = np.flatnonzero(np.diff(inside.astype(int)))
    assert len(runs) == 4


def test_colour_from_known_texture():
    # a thin slab whose top face shows a texture with four coloured quadrants
    slab = trimesh.creation.box(extents=(2.0, 2.0, 0.2))
    v, f = np.asarray(slab.vertices), np.asarray(slab.faces)
    tex = np.zeros((64, 64, 3), np.float32)
    tex[:32, :32] = [1, 0, 0]  # v > 0.5, u < 0.5 (row 0 is v = 1)
    tex[:32, 32:] = [0, 1, 0]
    tex[32:, :32] = [0, 0, 1]
    tex[32:, 32:] = [1, 1, 0]
    uv = (v[:, :2] + 1) / 2  # planar projection: u = x, v = y
    mesh = TexturedMesh(
        v,
        f,
        np.zeros(len(f), np.int64),
        [Material(base_color=np.ones(4, np.float32), image=tex)],
        face_uvs=uv[f].astype(np.float32),
    )
    g = mesh_to_grid(mesh, 32, n_surface_points=2000, progress=False)
    c = g.voxel_centers()
    top = np.argmin(np.abs(c[0, 0, :, 2] - 0.1 * g.normalization.scale))  # voxel layer at the top face
    layer = g.color[:, :, top]
    n = layer.shape[0]
    q = n // 4
    np.testing.assert_allclose(layer[q, 3 * q], [1, 0, 0], atol=1e-4)  # x < 0, y > 0
    np.testing.assert_allclose(layer[3 * q, 3 * q], [0, 1, 0], atol=1e-4)
    np.testing.assert_allclose(layer[q, q], [0, 0, 1], atol=1e-4)
    np.testing.assert_allclose(layer[3 * q, q], [1, 1, 0], atol=1e-4)
    # colour is zero outside the band
    assert np.all(g.color[np.abs(g.sdf) >= g.threshold] == 0)


def test_training_points_are_near_the_surface_with_exact_values():
    g = mesh_to_grid(
        textured(trimesh.creation.icosphere(subdivisions=4)),
        32,
        n_surface_points=5000,
        near_surface_sigma=0.01,
        progress=False,
    )
    assert g.points.shape == (5000, 3) and g.point_sdf.shape == (5000,) and g.point_color.shape == (5000, 3)
    r = np.linalg.norm(g.points, axis=1) - 1 / 1.03
    assert np.abs(r).mean() < 0.02
    np.testing.assert_allclose(g.point_sdf, np.clip(r, -g.threshold, g.threshold), atol=3e-3)


def test_save_load_round_trip(tmp_path):
    g = mesh_to_grid(textured(trimesh.creation.box()), 16, n_surface_points=100, progress=False)
    path = save_grid(g, tmp_path / "g.npz")
    h = load_grid(path)
    np.testing.assert_array_equal(g.sdf, h.sdf)
    np.testing.assert_array_equal(g.color, h.color)
    np.testing.assert_array_equal(g.aabb, h.aabb)
    assert h.threshold == pytest.approx(g.threshold)
    np.testing.assert_allclose(h.normalization.center, g.normalization.center)
    assert h.normalization.scale == g.normalization.scale and h.name == g.name == "m"
    assert len(h.points) == 100
    for a, b in [(g.points, h.points), (g.point_sdf, h.point_sdf), (g.point_color, h.point_color)]:
        np.testing.assert_array_equal(a, b)
    assert list(tmp_path.iterdir()) == [path]  # no temp file left behind


@pytest.mark.parametrize("res", [8, 15, 4096, 64.5])
def test_bad_resolution_is_a_clear_error(res):
    with pytest.raises(Sin3DMInputError, match="resolution"):
        mesh_to_grid(textured(trimesh.creation.box()), res, progress=False)


def test_thin_share_tells_thin_parts_from_solid_ones():
    """A row of slats 2 voxels thick (6 at 96 voxels) is all thin; one block is not; the slats are less thin on a finer grid."""
    slats = trimesh.util.concatenate(
        [trimesh.creation.box(extents=(0.1, 0.8, 0.8)).apply_translation((x, 0, 0)) for x in np.linspace(-0.8, 0.8, 6)]
    )
    block = trimesh.creation.box(extents=(1.0, 0.8, 0.8))
    thin32 = mesh_to_grid(textured(slats), 32, n_surface_points=0, progress=False).thin_share()
    thin96 = mesh_to_grid(textured(slats), 96, n_surface_points=0, progress=False).thin_share()
    fat = mesh_to_grid(textured(block), 32, n_surface_points=0, progress=False).thin_share()
    assert thin32 > 0.9 and fat < 0.1 and thin96 < 0.2


def test_a_ball_of_radius_3_5_tells_a_round_wall_of_6_voxels_from_one_of_8():
    """The ball of radius 3 (whole offsets within 3) is thinner between the axes than along them: a round wall 6
    voxels thick at 64 keeps most of itself against it. Radius 3.5 adds the (3,1,0) and (2,2,2) offsets: the wall
    of 6 is thin, the wall of 8 still is not."""
    from sin3dm_lite.examples.ruin import build_ruin

    six, eight = (
        mesh_to_grid(build_ruin(3, wall_voxels=w), 64, margin_voxels=3.25, n_surface_points=0, progress=False)
        for w in (6, 8)
    )
    assert six.thin_share(3) < 0.5 < 0.9 < six.thin_share(3.5) and eight.thin_share(3.5) < 0.3


def _grid_warnings(mesh) -> list[str]:
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mesh_to_grid(mesh, 16, n_surface_points=0, progress=False)
    return [str(w.message) for w in caught]


@pytest.mark.parametrize("size", [1e9, 1e-12])
def test_a_mesh_of_an_unusual_size_says_how_much_the_normalisation_scaled_it(size):
    """Issue 35: a 1e9- or 1e-12-scale mesh was accepted without a word; now one line with the factor."""
    box = trimesh.creation.box(extents=(1.0, 0.5, 0.3))
    box.apply_scale(size)
    notes = _grid_warnings(textured(box))
    assert len(notes) == 1 and "\n" not in notes[0]
    assert notes[0].startswith(f"'m' is {size:.3g} units long: the normalisation scales it by {2 / 1.03 / size:.3g}")
    assert _grid_warnings(textured(trimesh.creation.box(extents=(1.0, 0.5, 0.3)))) == []  # an ordinary one: none


def test_an_open_mesh_or_a_triangle_soup_says_that_its_inside_is_approximate():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    tri = sphere.vertices[sphere.faces]
    tri = tri - 0.02 * (tri - tri.mean(1, keepdims=True))  # every triangle shrunk a little: none touches another
    soup = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(tri.size // 3).reshape(-1, 3), process=False)
    notes = _grid_warnings(textured(soup))
    assert len(notes) == 1 and notes[0].startswith(
        "'m' is a triangle soup (no two faces share an edge): inside and "
        "outside come from the generalised winding number"
    )
    cup = trimesh.Trimesh(sphere.vertices, sphere.faces[sphere.triangles_center[:, 2] < 0.9])
    notes = _grid_warnings(textured(cup))
    assert len(notes) == 1 and notes[0].startswith("'m' is not watertight (")
    assert "% of its edges border a hole): inside and outside" in notes[0]


def test_faces_wound_against_their_neighbours_are_wound_as_they_are():
    """A real mesh often has faces wound the wrong way; the winding number would read each as a hole. The grid
    winds them as their neighbours (with a warning) and comes out as the clean mesh's."""
    sphere = trimesh.creation.icosphere(subdivisions=3)
    right = mesh_to_grid(textured(sphere), 32, n_surface_points=0, progress=False)
    faces = sphere.faces.copy()
    wrong = np.random.default_rng(0).random(len(faces)) < 0.2
    faces[wrong] = faces[wrong, ::-1]
    with pytest.warns(UserWarning, match=f"{wrong.sum()} of the {len(faces):,} faces of 'm' are wound against"):
        mended = mesh_to_grid(textured(trimesh.Trimesh(sphere.vertices, faces)), 32, n_surface_points=0, progress=False)
    np.testing.assert_array_equal(mended.sdf, right.sdf)


def test_an_open_part_inside_out_is_turned_round():
    """An open mesh wound inside out (a tower with no floor from an exporter of the other winding) has no volume
    to go by, and the winding number would find no inside in it: the faces' own sides tell, and it is turned."""
    from sin3dm_lite.data.distance import Distance

    sphere = trimesh.creation.icosphere(subdivisions=3)
    cup = trimesh.Trimesh(sphere.vertices, sphere.faces[sphere.triangles_center[:, 2] < 0.6])  # open at the top
    right = mesh_to_grid(textured(cup), 32, n_surface_points=0, progress=False)
    inverted = textured(trimesh.Trimesh(cup.vertices, cup.faces[:, ::-1]))
    with pytest.warns(UserWarning, match="'m' is inside out"):
        turned = mesh_to_grid(inverted, 32, n_surface_points=0, progress=False)
    assert (right.sdf < 0).sum() > 1000
    np.testing.assert_array_equal(turned.sdf, right.sdf)
    # a flat sheet has no inside either way: it is left as it is
    sheet = trimesh.creation.box(extents=(1, 1, 1e-3))
    sheet = trimesh.Trimesh(sheet.vertices, sheet.faces[sheet.face_normals[:, 2] > 0.5])
    assert Distance(textured(sheet)).turned_round.parts == 0
    assert Distance(textured(trimesh.Trimesh(sheet.vertices, sheet.faces[:, ::-1]))).turned_round.parts == 0


def test_the_closest_points_barycentrics_are_in_the_meshs_own_corner_order():
    """The colour of a voxel is read at the closest point through the mesh's UVs: the barycentrics must name the
    corners of the mesh's faces, also where the distance turned a face round."""
    from sin3dm_lite.data.distance import Distance

    sphere = trimesh.creation.icosphere(subdivisions=2)
    mesh = textured(trimesh.Trimesh(sphere.vertices, sphere.faces[:, ::-1]))  # inside out: every face turned
    dist = Distance(mesh)
    assert dist.corners_reversed.all()
    p = np.random.default_rng(0).normal(size=(200, 3))
    d, fi, bc = dist.closest(p)
    on_surface = np.einsum("nk,nkd->nd", bc, mesh.vertices[mesh.faces[fi]])
    np.testing.assert_allclose(np.linalg.norm(p - on_surface, axis=1), d, atol=1e-9)


def _ground_and_box():
    """A closed box standing on an open ground plane of one sheet (two triangles), as real scenes often have."""
    box = trimesh.creation.box(extents=(0.6, 0.6, 0.6))
    box.apply_translation([0, 0.3, 0])
    ground = trimesh.Trimesh([(-2, 0, -2), (2, 0, -2), (2, 0, 2), (-2, 0, 2)], [(0, 2, 1), (0, 3, 2)])
    return trimesh.util.concatenate([box, ground])


def test_an_open_sheet_becomes_a_slab_two_voxels_thick_with_a_warning():
    """Without it the ground would vanish: the winding number has no inside on either side of a lone sheet."""
    with pytest.warns(UserWarning, match=r"open sheets that enclose no volume .* slabs 1/32 of the shape's longest"):
        g = mesh_to_grid(textured(_ground_and_box()), 64, n_surface_points=2000, progress=False)
    ground_y = g.normalization.to_normalized(np.zeros((1, 3)))[0, 1]  # grid coordinates are normalised ones
    inside = g.sdf < 0
    column = inside[8, :, 8]  # a column through the ground, far from the box
    ys = g.axis_coords(1)[column]
    assert 1 <= column.sum() <= 2 and np.all(np.abs(ys - ground_y) < g.voxel_size)  # the slab, nothing else
    # the slab's SDF is its distance: the voxel centres' |y - ground| minus 1/32 (one voxel at 64)
    np.testing.assert_allclose(g.sdf[8, :, 8][column], np.abs(ys - ground_y) - g.voxel_size, atol=1e-5)
    # the box keeps its solid inside, and the training points inside the slab are inside
    centre = g.normalization.to_normalized(np.array([[0.0, 0.3, 0.0]]))
    i, j, k = np.floor((centre[0] - g.aabb[:3]) / g.voxel_size).astype(int)
    assert g.sdf[i, j, k] < 0
    corner = g.normalization.to_normalized(np.array([[0.4, 0.0, 0.4]]))[0]  # beyond the box's footprint
    away = (np.abs(g.points[:, 0]) > corner[0]) | (np.abs(g.points[:, 2]) > corner[2])
    in_slab = away & (np.abs(g.points[:, 1] - ground_y) < 0.5 * g.voxel_size)
    edge = g.normalization.to_normalized(np.array([[2.0, 0.0, 2.0]]))[0]  # the slab ends where the ground does
    within = (np.abs(g.points[:, 0]) < edge[0]) & (np.abs(g.points[:, 2]) < edge[2])
    assert (in_slab & within).any() and np.all(g.point_sdf[in_slab & within] < 0)


def _height_field(n: int = 40) -> trimesh.Trimesh:
    """A lone wavy sheet over [-1, 1]², its height ±0.3: its winding number exceeds ½ under each dip."""
    x, z = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    v = np.stack([x, 0.3 * np.sin(3 * x) * np.cos(2 * z), z], -1).reshape(-1, 3)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    return trimesh.Trimesh(v, np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)]))


def test_a_curved_sheet_is_one_slab_without_a_solid_under_its_dip():
    """The sheet leaves the winding number, so no lens of solid grows under its dips."""
    with pytest.warns(UserWarning, match="open sheets"):
        g = mesh_to_grid(textured(_height_field()), 48, n_surface_points=0, progress=False)
    assert (g.sdf < 0).sum(axis=1).max() <= 3  # at most a slab's voxels in any vertical column
    assert ((g.sdf < 0).sum(axis=1) > 0).mean() > 0.9  # and the slab covers the sheet


def test_closed_meshes_have_no_sheets():
    from sin3dm_lite.data.distance import Distance

    dist = Distance(textured(trimesh.creation.icosphere(subdivisions=2)))
    assert dist.find_slabs().sheets == 0.0 and dist.sheet is None
    open_cup = trimesh.creation.icosphere(subdivisions=2)
    open_cup = trimesh.Trimesh(open_cup.vertices, open_cup.faces[open_cup.triangles_center[:, 2] < 0.6])
    assert Distance(textured(open_cup)).find_slabs().sheets == 0.0  # a hole, but it bounds a volume


def test_the_metrics_reference_keeps_an_open_sheet_as_a_slab_too():
    """The LP metrics compare samples with the input voxelised: its sheets must be there as the grid has them."""
    from sin3dm_lite.evaluate.geometry import input_occupancy

    mesh = _ground_and_box()
    mesh.vertices = (mesh.vertices - mesh.bounds.mean(0)) / (0.515 * mesh.extents.max())  # into [-1, 1]
    box = np.array([-1.0, -0.25, -1.0, 1.0, 0.25, 1.0])
    occ = input_occupancy(mesh, box, 32)
    assert occ.shape == (32, 8, 32)
    assert 1 <= occ[2, :, 2].sum() <= 2  # the ground far from the box: a slab of one or two voxels
    assert occ[16, :, 16].sum() > occ[2, :, 2].sum()  # the box stands on it
    sheet = _height_field()
    sheet.vertices /= 1.03
    field = input_occupancy(sheet, np.array([-1.0, -0.3, -1.0, 1.0, 0.3, 1.0]), 48, supersample=2)
    assert field.sum(axis=1).max() <= 3 and (field.sum(axis=1) > 0).mean() > 0.9  # one slab, no lens under a dip


def _board(size=(1.6, 0.004, 1.0), at=(0.0, 0.0, 0.0), hole: float = 0.0) -> trimesh.Trimesh:
    """A closed board far thinner than a voxel (a shelf, sheet metal); ``hole``: the side of a square hole through
    it, made as a frame of four closed boards so that the hole's rims are faces thick along the board."""
    x, t, z = size
    if not hole:
        return trimesh.creation.box(extents=size).apply_translation(at)
    side, end = (x - hole) / 2, (z - hole) / 2
    pieces = [((side, t, z), (-(hole + side) / 2, 0, 0)), ((side, t, z), ((hole + side) / 2, 0, 0))]
    pieces += [((hole, t, end), (0, 0, -(hole + end) / 2)), ((hole, t, end), (0, 0, (hole + end) / 2))]
    boxes = [trimesh.creation.box(extents=e).apply_translation(np.add(c, at)) for e, c in pieces]
    return trimesh.util.concatenate(boxes)


def test_a_board_thinner_than_a_voxel_becomes_a_slab_with_a_warning():
    """Its inside is real, but no voxel centre falls in it: without the slab the grid loses the shelf. The standing
    board stands over the centroid of one of the lying board's two bottom triangles: asked with the whole mesh, that
    triangle would read the standing board's inside behind it as its own thickness, and half the slab would go."""
    standing = _board((0.004, 0.8, 1.0), (0.8 / 3, 0.4, 0.0))
    shelf = trimesh.util.concatenate([_board(), standing])
    with pytest.warns(UserWarning, match=r"parts thinner than .* voxels \(boards, sheet metal\)"):
        g = mesh_to_grid(textured(shelf), 64, n_surface_points=2000, progress=False)
    inside = g.sdf < 0
    to_grid = g.normalization.to_normalized
    board_y = to_grid(np.zeros((1, 3)))[0, 1]
    rows = np.abs(g.axis_coords(1) - board_y) < 2 * g.voxel_size
    x, z = g.axis_coords(0), g.axis_coords(2)
    under = np.abs(x - to_grid(np.array([[0.8 / 3, 0, 0]]))[0, 0]) < 2 * g.voxel_size  # the standing board's columns
    xs = (np.abs(x) < g.normalization.scale * 0.75) & ~under  # inside the lying board's 1.6 × 1.0 footprint
    zs = np.abs(z) < g.normalization.scale * 0.45
    count = inside[:, rows, :].sum(axis=1)[np.ix_(xs, zs)]  # the lying board's slab, column by column
    assert count.min() == count.max() and 1 <= count.min() <= 3  # one slab of 1-3 voxels, the same everywhere
    assert inside[under][:, ~rows].sum() > 10 * g.shape[2] // 2  # the standing board is kept too
    on = (np.abs(g.points[:, 1] - board_y) < 0.5 * g.voxel_size) & (
        np.abs(g.points[:, 0]) < 0.75 * g.normalization.scale
    )
    on &= np.abs(g.points[:, 2]) < g.normalization.scale * 0.45
    assert on.sum() > 100 and np.all(g.point_sdf[on] < 0)  # its training points inside


def test_a_slabs_whole_band_has_the_surfaces_colour_and_its_exact_distance():
    """A slab reaches beyond its face, so its band does too: every voxel of that band takes the closest face's colour
    (a grey mesh stays one colour, as a real STL of thin ribs showed: its outer band was left black, and the fit
    trained a texture it did not have) and its distance to the slab, not the band's edge value."""
    with pytest.warns(UserWarning, match="parts thinner than"):
        block = trimesh.creation.box(extents=(0.2, 0.4, 0.2)).apply_translation((0.6, 0.2, 0.35))  # not flat
        g = mesh_to_grid(
            textured(trimesh.util.concatenate([_board(), block])), 64, n_surface_points=2000, progress=False
        )
    band = np.abs(g.sdf) < g.threshold
    assert np.all(g.color[band].max(axis=1) > 0.5)  # no voxel of the band left uncoloured
    np.testing.assert_allclose(g.single_color(), [1.0, 1.0, 1.0])
    middle, face = g.normalization.to_normalized(np.array([[0.0, 0.0, 0.0], [0.0, 0.002, 0.0]]))  # the top face
    i, _, k = np.floor((middle - g.aabb[:3]) / g.voxel_size).astype(int)
    column = g.sdf[i, :, k]  # through the middle of the board
    to_face = np.abs(g.axis_coords(1) - middle[1]) - (face[1] - middle[1])
    expected = np.minimum(to_face - g.voxel_size, g.threshold)  # its slab reaches a voxel beyond the face
    np.testing.assert_allclose(column, expected, atol=1e-5)


def test_a_slab_thicker_than_the_band_stays_truncated():
    """The grid's SDF is clipped to ±threshold everywhere; a slab is 1/32 of the longest side thick, more than the
    band at 256 voxels (8 voxels against ±3), and its middle read -1.3 thresholds there."""
    block = trimesh.creation.box(extents=(0.2, 0.4, 0.2)).apply_translation((0.6, 0.2, 0.35))
    with pytest.warns(UserWarning, match="parts thinner than"):  # a band of half a voxel: the slab (±1) is thicker
        g = mesh_to_grid(textured(trimesh.util.concatenate([_board(), block])), 64, 0.5, 2000, progress=False)
    assert g.sdf.min() == pytest.approx(-g.threshold) and g.sdf.max() == pytest.approx(g.threshold)
    assert (g.sdf < 0).sum() > 64 * 40  # the slab is still there, under the whole board


def test_a_hole_through_a_thin_board_stays_open():
    """The slab is the board pushed out along its normal: neither the hole's rim (thick along the board) nor the
    board's faces past their edge reach into the hole, which keeps its width to a voxel (2 voxels of slab each
    side at 128: either would take about two voxels from each side)."""
    post = trimesh.creation.box(extents=(0.2, 0.4, 0.2)).apply_translation((-0.7, -0.2, -0.4))  # not flat
    mesh = textured(trimesh.util.concatenate([_board(hole=0.5), post]))
    with pytest.warns(UserWarning, match="parts thinner than"):
        g = mesh_to_grid(mesh, 128, n_surface_points=0, progress=False)
    inside = (g.sdf < 0).any(axis=1)  # seen from above
    middle = ~inside[g.shape[0] // 4 : 3 * g.shape[0] // 4, g.shape[2] // 2]  # across the middle of the hole
    assert abs(middle.sum() - 0.5 * g.normalization.scale / g.voxel_size) <= 1
    assert inside[:, g.shape[2] // 2].sum() > 20  # and the board around it is there


def test_thick_parts_have_no_slabs():
    from sin3dm_lite.data.distance import Distance, Slabs

    cube = trimesh.creation.box(extents=(1.0, 0.1, 1.0))  # thin, but three voxels at 64 and more: a voxel holds it
    wedge = trimesh.Trimesh([(0, 0, 0), (1, 0, 0), (0, 0.3, 0), (0, 0, 1), (1, 0, 1), (0, 0.3, 1)]).convex_hull
    for mesh in (trimesh.creation.icosphere(subdivisions=2), cube, wedge):  # the wedge's sharp edge is not a part
        dist = Distance(textured(mesh))
        assert dist.find_slabs() == Slabs(0.0, 0.0) and dist.reach is None


def test_the_metrics_reference_keeps_a_thin_board_as_a_slab_too():
    from sin3dm_lite.evaluate.geometry import input_occupancy

    board = _board((1.9, 0.004, 1.9))
    occ = input_occupancy(board, np.array([-1.0, -0.25, -1.0, 1.0, 0.25, 1.0]), 32)
    assert occ.shape == (32, 8, 32)
    column = occ[4:28, :, 4:28].sum(axis=1)
    assert column.min() >= 1 and column.max() <= 2  # a closed mesh, yet no voxel centre falls in the board itself


@pytest.mark.parametrize("resolution, box, thick", [(64, 16, 2), (32, 8, 1)])
def test_a_flat_mesh_is_one_slab_in_a_box_that_holds_it(resolution, box, thick):
    """A mesh flatter than a voxel (a floor, a field, a decal) is an open sheet: one slab 1/32 of its longest side
    thick, its colours kept, in a box as thick as the slab and its margin (it was refused, though its colours and
    outline are a shape to learn); no word on holes, since the winding number decides nothing there. At 32 voxels
    the slab is one voxel thick: the sheet lies off the plane where two rows of voxel centres meet, or it held none."""
    flat = _height_field()
    flat.vertices[:, 1] *= 0.01  # ±0.003 over a side of 2
    red_left = np.where(flat.vertices[:, :1] < 0, [[1.0, 0.1, 0.1]], [[0.1, 0.1, 1.0]])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        g = mesh_to_grid(
            textured(flat, vertex_colors=red_left), resolution, n_surface_points=0, progress=False, margin_voxels=3.25
        )
    said = " ".join(str(w.message) for w in caught)
    assert "100.0% of the surface of 'm' is open sheets" in said and "watertight" not in said
    assert g.sdf.shape == (resolution, box, resolution)  # the slab and at least 3.25 voxels of margin, in 8s
    solid = g.sdf < 0
    inner = slice(resolution // 8, -resolution // 8)
    assert solid.sum(axis=1)[inner, inner].min() == thick and solid.sum(axis=1).max() == thick  # one slab
    inside = g.color[solid]
    assert inside[:, 0].max() > 0.9 and inside[:, 2].max() > 0.9  # red and blue halves both kept
    # the sheet a quarter voxel off the mid-plane, and the slab mapped back onto the file's sheet within a voxel
    assert abs(g.normalization.to_normalized(flat.vertices)[:, 1].mean() - 0.5 / resolution) < 1e-3
    centres = g.normalization.to_original(g.voxel_centers()[solid])
    assert np.abs(centres[:, 1]).max() <= 2 / resolution / g.normalization.scale


def test_a_mesh_without_area_has_no_inside_and_says_what_to_do():
    """Faces of no area (every vertex on a line) make no sheet and no slab: the error names the flat sides."""
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], float)
    line = TexturedMesh(v, np.array([[0, 1, 2], [1, 2, 3]]), np.zeros(2, np.int64), [Material()], name="m")
    with pytest.raises(
        Sin3DMInputError,
        match=r"it is flat, 3 × 0 × 0, its thinnest side 0\.00% .* covers no voxel centre .* thickness",
    ):
        mesh_to_grid(line, 64, n_surface_points=0, progress=False)


@pytest.mark.parametrize("down", [False, True])
def test_a_stray_triangle_on_a_face_is_read_like_the_rest(down):
    """A lone triangle lying on a box's face (an exporter's leftover, seen in robosuite's meshes) is a part of one
    face: asked alone, point-cloud-utils answers a single point with a bare number, which broke the thin-part probe."""
    from sin3dm_lite.data.distance import winding_number

    tri = np.array([[-0.2, 0.5, -0.2], [0.2, 0.5, -0.2], [0.0, 0.5, 0.2]])
    stray = trimesh.Trimesh(tri, [[0, 1, 2]] if down else [[0, 2, 1]], process=False)
    mesh = trimesh.util.concatenate([trimesh.creation.box(extents=(1, 1, 1)), stray])
    g = mesh_to_grid(textured(mesh), 32, n_surface_points=100, progress=False, margin_voxels=3.25)
    assert g.sdf[16, 16, 16] < 0 and g.sdf[1, 1, 1] > 0  # the box, solid, in its margin
    assert winding_number(tri, np.array([[0, 1, 2]]), np.array([[0.0, 0.0, 0.0]])).shape == (1,)


@pytest.mark.parametrize("up, axis", [("z", 2), ("x", 0), ("y", 1)])
def test_a_mesh_turned_upright_stands_along_y_and_keeps_its_inside(up, axis):
    """``turned_upright(up)`` (a fit's ``grid.up``) turns the ``up`` axis to +y, a rotation: the top stays the top
    and the faces keep their winding, so a closed mesh keeps its (positive) volume; a bad axis is one line."""
    extents = np.full(3, 0.4)
    extents[axis] = 1.0
    box = trimesh.creation.box(extents=extents)
    box.apply_translation(np.eye(3)[axis] * 2.0)  # lifted along its up
    turned = textured(box).turned_upright(up)
    assert np.argmax(np.ptp(turned.vertices, axis=0)) == 1  # long along y
    assert turned.vertices[:, 1].min() > 1.0  # and still above the ground, not hanging under it
    volume = trimesh.Trimesh(turned.vertices, turned.faces, process=False).volume
    assert volume == pytest.approx(box.volume) and volume > 0
    with pytest.raises(Sin3DMInputError, match="up must be one of y, z, x"):
        textured(box).turned_upright("w")


def test_a_turn_about_y_is_kept_in_the_normalization_and_undone_by_it():
    """``turned_about_y`` turns the vertices and keeps the turn in ``normalization``: the normalised mesh is
    ``to_normalized`` of the file's vertices, ``to_original`` gives them back, and ``box_to_original`` holds the
    normalised box's turned corners; a grid file keeps the turn."""
    box = textured(trimesh.creation.box(extents=(1.0, 0.5, 0.3)))
    n = box.turned_about_y(30.0).normalized()
    np.testing.assert_allclose(n.normalization.to_normalized(box.vertices), n.vertices, atol=1e-12)
    np.testing.assert_allclose(n.normalization.to_original(n.vertices), box.vertices, atol=1e-12)
    lo, hi = n.normalization.box_to_original(np.array([n.vertices.min(0), n.vertices.max(0)]))
    assert (box.vertices >= lo - 1e-9).all() and (box.vertices <= hi + 1e-9).all()
    assert hi[0] - lo[0] > 1.0  # the turned box's corners reach past the unturned one along x
    assert box.turned_about_y(0) is box
    volume = trimesh.Trimesh(n.vertices, n.faces, process=False).volume
    assert volume > 0  # a turn, not a mirror


def test_a_grid_file_keeps_the_turn(tmp_path):
    box = textured(trimesh.creation.box(extents=(1.0, 0.5, 0.3))).turned_about_y(-20.0)
    grid = mesh_to_grid(box, 16, n_surface_points=500, progress=False)
    save_grid(grid, tmp_path / "g.npz")
    back = load_grid(tmp_path / "g.npz")
    np.testing.assert_allclose(back.normalization.rotation, grid.normalization.rotation)
    assert not np.allclose(back.normalization.rotation, np.eye(3))

"""Triplane → textured mesh, checked with an analytic decoder whose exact answer is known."""

import functools

import numpy as np
import pytest
import torch
from torch import nn

from sin3dm_lite import box
from sin3dm_lite import extract as ex
from sin3dm_lite.data.mesh import Normalization
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.model import decode as dc
from sin3dm_lite.model.triplane import Triplane

from .conftest import AABB, SphereDecoder, zero_triplane


def sphere_sdf(shape, aabb=AABB, center=(0.0, 0.0, 0.0), radius=0.5):
    axes = [aabb[a] + (np.arange(n) + 0.5) / n * (aabb[a + 3] - aabb[a]) for a, n in enumerate(shape)]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    c = np.asarray(center)
    return (np.sqrt((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) - radius).astype(np.float32)


def test_grid_shape_follows_longest_side():
    assert box.grid_shape(AABB, 32) == (24, 32, 20)
    assert box.grid_shape([-1, -1, -0.01, 1, 1, 0.01], 16) == (16, 16, 2)  # at least 2 voxels per axis


@pytest.mark.parametrize("shape", [(96, 48, 56), (64, 32, 40), (128, 72, 120), (256, 136, 200)])
def test_a_training_grids_float32_box_gives_back_its_own_shape(shape):
    # decode and the metrics rebuild the grid from its stored float32 box: 56/96 in float32 · 96 = 55.99999
    assert box.grid_shape(box.centred_box(shape), shape[0]) == shape


def test_decode_grid_chunked_equals_one_shot_and_prepares_once():
    dec = SphereDecoder()
    tp = zero_triplane()
    sdf, col = dc.decode_grid(dec, tp, AABB, 32, chunk=1000, with_color=True, coarse=None)
    assert dec.prepare_calls == 1 and dec.query_calls == int(np.ceil(24 * 32 * 20 / 1000))
    sdf1, col1 = dc.decode_grid(dec, tp, AABB, 32, chunk=10**9, with_color=True, coarse=None)
    assert sdf.shape == (24, 32, 20) and col.shape == (24, 32, 20, 3)
    np.testing.assert_array_equal(sdf, sdf1)
    np.testing.assert_array_equal(col, col1)
    # the grid is cell-centred: voxel k sits at lo + (k + 0.5) / n * size
    np.testing.assert_allclose(sdf, sphere_sdf(sdf.shape), atol=1e-5)
    assert np.array_equal(dc.decode_grid(dec, tp, AABB, 32, coarse=1), sdf)  # sdf only; coarse=1 is the full decode


# ----------------------------------------------------------------------------- coarse-to-fine decode
def assert_fast_decode_exact(dec, tp, aabb, resolution, band_voxels=2.0, **kwargs):
    """The coarse-to-fine decode against the full one: exact near the surface, same signs, same mesh."""
    full = dc.decode_grid(dec, tp, aabb, resolution, coarse=None)
    stats = {}
    fast = dc.decode_grid(dec, tp, aabb, resolution, stats=stats, **kwargs)
    voxel = (aabb[3:] - aabb[:3]).max() / max(full.shape)
    near = np.abs(full) < band_voxels * voxel
    assert near.any() and (full > 0).any() and (full < 0).any()
    np.testing.assert_array_equal(fast[near], full[near])  # bit for bit
    np.testing.assert_array_equal(np.sign(fast), np.sign(full))
    v_full, f_full = ex.marching_cubes(full, aabb)
    v_fast, f_fast = ex.marching_cubes(fast, aabb)
    np.testing.assert_array_equal(f_fast, f_full)
    np.testing.assert_array_equal(v_fast, v_full)
    assert stats["voxels"] == full.size
    assert stats["decoded"] == sum(n for _, n in stats["levels"]) + stats["closure"]
    return full, fast, stats


class TruncatedSphereDecoder(SphereDecoder):
    """The sphere's SDF clamped to ±truncation, like the truncated SDF a real decoder was trained on."""

    def __init__(self, truncation, **kwargs):
        super().__init__(**kwargs)
        self.truncation = truncation

    def query(self, prepared, points):
        sdf, color = super().query(prepared, points)
        return sdf.clamp(-self.truncation, self.truncation), color


@pytest.mark.parametrize("coarse", [2, 3, 4, 8])
def test_coarse_to_fine_sphere_is_exact_near_the_surface(coarse):
    dec = SphereDecoder()
    full, fast, stats = assert_fast_decode_exact(dec, zero_triplane(), AABB, 48, coarse=coarse)
    assert stats["levels"][0][0] == coarse and stats["levels"][-1][0] == 1
    assert stats["decoded"] < 0.5 * full.size
    # far from the surface: trilinear interpolation of decoded values, so the right sign and roughly the distance
    # (off most at the sphere's centre, where |p| has its kink)
    assert np.abs(fast - full).max() < coarse * 2.0 / 48


def test_coarse_to_fine_truncated_sdf_touching_the_box_and_colours():
    voxel = 2.0 / 48
    # radius 0.7 pokes through the x and z faces of the box: the cap cubes need the boundary voxels exactly
    dec = TruncatedSphereDecoder(truncation=6 * voxel, radius=0.7)
    full, fast, stats = assert_fast_decode_exact(dec, zero_triplane(), AABB, 48)
    assert stats["decoded"] < 0.6 * full.size
    sdf, col = dc.decode_grid(dec, zero_triplane(), AABB, 48, with_color=True)
    np.testing.assert_array_equal(sdf, fast)
    _, col_full = dc.decode_grid(dec, zero_triplane(), AABB, 48, with_color=True, coarse=None)
    assert col.shape == col_full.shape == (*full.shape, 3)
    near = np.abs(full) < 2 * voxel
    np.testing.assert_array_equal(col[near], col_full[near])
    np.testing.assert_allclose(col, col_full, atol=1e-5)  # the colour is linear: interpolation is exact


@functools.cache
def random_triplane_decoder(seed=0):
    """A real ``TriplaneDecoder`` with random weights, a smooth random triplane prepared once (conv blocks run)."""
    from sin3dm_lite.data.config import AutoencoderConfig
    from sin3dm_lite.model.autoencoder import TriplaneDecoder

    torch.manual_seed(seed)
    dec = TriplaneDecoder(AutoencoderConfig(decoder_channels=16, mlp_hidden=32), threshold=0.1)
    tp = Triplane.randn(1, 12, (3, 4, 3), generator=torch.Generator().manual_seed(seed))
    return dec, dc.prepare(dec, tp)


def sdf_like_triplane_decoder(truncation=None, seed=0):
    """The real decoder of :func:`random_triplane_decoder` made SDF-like: a bumpy sphere.

    ``query_sdf`` becomes the box's sphere SDF plus the real decoder's output,
    scaled so that its largest slope between neighbouring voxels is 0.5 (the
    sum stays below the decode's assumed ``lipschitz=2``) and its amplitude a
    few voxels; optionally clamped like a truncated SDF. Every value still goes
    through the decoder's MLP, whose last bits depend on the batch unless
    ``query_points`` pads it.
    """
    from sin3dm_lite.model.autoencoder import TriplaneDecoder

    base, prepared = random_triplane_decoder(seed)
    raw = dc.decode_grid(base, prepared, AABB, 32, coarse=None)
    raw_slope = max(np.abs(np.diff(raw, axis=a)).max() for a in range(3)) / (2.0 / 32)
    gain, offset = 0.5 / raw_slope, float(raw.mean())
    sphere = SphereDecoder(radius=0.55)

    class Bumpy(nn.Module):
        def __init__(self):
            super().__init__()
            self.base = base

        def query_sdf(self, prep, points):
            sdf = sphere.query({"offset": torch.zeros(1)}, points)[0]
            sdf = sdf + gain * (TriplaneDecoder.query_sdf(self.base, prep, points) - offset)
            return sdf if truncation is None else sdf.clamp(-truncation, truncation)

        def query(self, prep, points):
            return self.query_sdf(prep, points), self.base.query_color(prep, points)

    return Bumpy(), prepared


@pytest.mark.parametrize("truncation", [None, 0.375])
def test_coarse_to_fine_real_decoder_gives_the_same_mesh(truncation):
    dec, prepared = sdf_like_triplane_decoder(truncation)  # 0.375 = 6 voxels, the small preset's band at 128
    full, fast, stats = assert_fast_decode_exact(dec, prepared, AABB, 32)
    v, f = ex.marching_cubes(full, AABB)
    assert len(f) > 1000  # a real surface, not a speck
    bump = full - sphere_sdf(full.shape, radius=0.55)
    bump = bump[np.abs(full) < 0.1]
    assert bump.max() - bump.min() > 2.0 / 32  # the decoder moves the surface by more than a voxel
    assert stats["decoded"] < 0.6 * full.size


@pytest.mark.parametrize("truncation", [None, 0.375])
def test_the_mesh_path_decodes_only_what_marching_cubes_reads(truncation):
    """``extract_mesh`` decodes with ``exact_band=0``: fewer points, the mesh of the full decode bit for bit."""
    dec, prepared = sdf_like_triplane_decoder(truncation)
    full = dc.decode_grid(dec, prepared, AABB, 32, coarse=None)
    stats, banded = {}, {}
    fast = dc.decode_grid(dec, prepared, AABB, 32, exact_band=0.0, stats=stats)
    np.testing.assert_array_equal(np.sign(fast), np.sign(full))
    for a, b in zip(ex.marching_cubes(fast, AABB), ex.marching_cubes(full, AABB)):
        np.testing.assert_array_equal(a, b)
    dc.decode_grid(dec, prepared, AABB, 32, stats=banded)
    assert stats["decoded"] < 0.85 * banded["decoded"]
    _, steps = ex.extract_mesh(dec, prepared, AABB, resolution=32, faces=None, vertex_colors=True, return_steps=True)
    assert steps["decode_stats"]["decoded"] == stats["decoded"]
    np.testing.assert_array_equal(steps["raw"][1], ex.marching_cubes(full, AABB)[1])


def test_query_points_value_does_not_depend_on_its_batch():
    """Matrix kernels round the leftover rows of a batch differently; the row padding hides that."""
    dec, prepared = random_triplane_decoder()
    pts = np.random.default_rng(0).uniform(-1, 1, (3001, 3)).astype(np.float32)
    all_at_once, _ = dc.query_points(dec, prepared, pts, color=False)
    for start, size in [(0, 1), (5, 3), (17, 1001), (1000, 2001)]:
        part, _ = dc.query_points(dec, prepared, pts[start : start + size], color=False)
        np.testing.assert_array_equal(part, all_at_once[start : start + size])
    chunked, _ = dc.query_points(dec, prepared, pts, chunk=999, color=False)
    np.testing.assert_array_equal(chunked, all_at_once)


def test_points_are_decoded_in_cache_sized_batches_on_a_cpu_and_big_ones_on_a_gpu():
    assert dc.default_chunk("cpu") == dc.CHUNK["cpu"] < dc.default_chunk("cuda") == dc.CHUNK["cuda"]
    dec, prepared = random_triplane_decoder()
    pts = np.random.default_rng(1).uniform(-1, 1, (dc.CHUNK["cpu"] * 2 + 5, 3)).astype(np.float32)
    batches = []
    query = dec.query
    dec.query = lambda features, p: batches.append(p.shape[1]) or query(features, p)
    default, col = dc.query_points(dec, prepared, pts)
    assert batches == [dc.CHUNK["cpu"], dc.CHUNK["cpu"], 64]  # the last one padded to a ROW_TILE multiple
    one_batch, col1 = dc.query_points(dec, prepared, pts, chunk=len(pts))
    np.testing.assert_array_equal(default, one_batch)
    np.testing.assert_array_equal(col, col1)


def test_mc_support_marks_cubes_that_cross_the_level_and_the_boundary():
    sdf = np.ones((6, 6, 6), np.float32)
    sdf[3, 3, 3] = -1
    mark = dc.mc_support(sdf)
    assert mark.sum() == 27 and mark[2:5, 2:5, 2:5].all()
    sdf[0, 0, 0] = -1  # inside on the corner of the grid: the padding layer outside makes a cube cross
    assert dc.mc_support(sdf)[:2, :2, :2].all() and dc.mc_support(sdf).sum() == 27 + 8
    assert not dc.mc_support(np.ones((4, 4, 4))).any()


def test_prepared_triplane_is_reused_and_batch_must_be_one():
    dec = SphereDecoder()
    prepared = dc.prepare(dec, zero_triplane())
    dc.decode_grid(dec, prepared, AABB, 16)
    dc.decode_grid(dec, prepared, AABB, 16)
    assert dec.prepare_calls == 1
    with pytest.raises(Sin3DMInputError, match="batch 2"):
        ex.extract_mesh(dec, zero_triplane(batch=2), AABB, resolution=16)


def test_marching_cubes_sphere_on_voxel_centres_and_outward():
    shape = box.grid_shape(AABB, 32)
    voxel = (AABB[3] - AABB[0]) / shape[0]
    center = np.array([0.05, -0.1, 0.02])  # off the grid's symmetry
    v, f = ex.marching_cubes(sphere_sdf(shape, center=center), AABB)
    r = np.linalg.norm(v - center, axis=1)
    assert np.abs(r - 0.5).max() < voxel / 4
    assert np.all(v.min(0) >= center - 0.5 - voxel / 4) and np.all(v.max(0) <= center + 0.5 + voxel / 4)
    tri = v[f]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(normals, axis=1)
    surface_centroid = (tri.mean(1) * area[:, None]).sum(0) / area.sum()
    assert np.abs(surface_centroid - center).max() < 1e-3 * voxel  # no half-voxel shift
    v0, _ = ex.marching_cubes(sphere_sdf(shape), AABB)
    assert np.abs(v0.mean(0)).max() < 1e-6  # centred sphere: vertex mean at the centre
    assert np.all(np.einsum("fd,fd->f", normals, tri.mean(1) - center) > 0)


def test_marching_cubes_without_surface_is_a_clear_error():
    with pytest.raises(ex.NoSurfaceError, match="empty"):
        ex.marching_cubes(np.ones((8, 8, 8)), AABB)
    with pytest.raises(ex.NoSurfaceError, match="fills the whole box"):
        ex.marching_cubes(-np.ones((8, 8, 8)), AABB)


def test_shape_touching_the_box_is_closed_on_the_box_face():
    import trimesh

    shape = (16, 16, 16)
    box = np.array([-1.0, -1, -1, 1, 1, 1])
    sdf = sphere_sdf(shape, aabb=box, radius=1.2)  # pokes through every face of the box
    v, f = ex.marching_cubes(sdf, box)
    assert trimesh.Trimesh(v, f, process=True).is_watertight
    assert np.allclose(v.min(0), -1, atol=1e-6) and np.allclose(v.max(0), 1, atol=1e-6)
    v2, f2 = ex.marching_cubes(sdf, box, close_boundary=False)
    assert not trimesh.Trimesh(v2, f2, process=True).is_watertight


def test_keep_components_all_largest_and_specks():
    shape = (32, 32, 32)
    box = np.array([-1.0, -1, -1, 1, 1, 1])
    sdf = np.minimum(sphere_sdf(shape, box, (-0.4, 0, 0), 0.45), sphere_sdf(shape, box, (0.6, 0, 0), 0.2))
    v, f = ex.marching_cubes(sdf, box)
    sizes = np.bincount(ex.component_labels(len(v), f))
    assert len(sizes) == 2
    va, fa = ex.keep_components(v, f)
    assert len(fa) == len(f)
    vl, fl = ex.keep_components(v, f, mode="largest")
    assert len(fl) == sizes.max() and vl[:, 0].max() < 0.1
    vs, fs = ex.keep_components(v, f, min_faces=sizes.min() + 1)
    assert len(fs) == sizes.max() and fs.max() == len(vs) - 1


def test_simplify_reaches_budget_and_skips_small_meshes():
    v, f = ex.marching_cubes(sphere_sdf((40, 40, 40), np.array([-1.0, -1, -1, 1, 1, 1])), [-1, -1, -1, 1, 1, 1])
    vs, fs = ex.simplify(v, f, 2000)
    assert 1800 <= len(fs) <= 2000
    assert np.abs(np.linalg.norm(vs, axis=1) - 0.5).max() < 0.02
    v2, f2 = ex.simplify(vs, fs, 10_000)
    assert v2 is vs and f2 is fs


def test_rasterize_triangles_counts_pixel_centres():
    tri = np.array([[[-0.5, -0.5], [9.5, -0.5], [-0.5, 9.5]]])  # covers centres with x + y <= 9
    f, x, y, bary = ex.rasterize_triangles(tri, 20, 20)
    assert len(f) == 55 and np.all(x + y <= 9)
    np.testing.assert_allclose(np.einsum("nk,kd->nd", bary, tri[0]), np.stack([x, y], 1), atol=1e-9)
    f, x, y, _ = ex.rasterize_triangles(tri, 5, 5)  # clipped to the image
    assert len(f) == 25 and x.max() == 4 and y.max() == 4


def test_pad_gutter_fills_near_islands_and_rest_with_mean():
    red, blue = np.array([1.0, 0, 0]), np.array([0, 0, 1.0])
    img = np.zeros((32, 32, 3), np.float32)
    covered = np.zeros((32, 32), bool)
    covered[4:8, 4:8], img[4:8, 4:8] = True, red  # 16 red texels
    covered[18:24, 18:24], img[18:24, 18:24] = True, blue  # 36 blue texels
    mean = (16 * red + 36 * blue) / 52
    out = ex.pad_gutter(img, covered, pixels=3)
    np.testing.assert_array_equal(out[covered], img[covered])
    np.testing.assert_allclose(out[5, 10], red)  # 3 texels right of the red island
    np.testing.assert_allclose(out[21, 15], blue)  # 3 texels left of the blue one
    np.testing.assert_allclose(out[5, 11], mean, rtol=1e-6)  # 4 texels away: the mean colour, never black
    np.testing.assert_allclose(out[10, 10], mean, rtol=1e-6)  # √18 ≈ 4.2 from the red island's corner
    everywhere = ex.pad_gutter(img, covered, pixels=None)
    np.testing.assert_allclose(everywhere[12, 12], red)  # √50 from red, √72 from blue
    np.testing.assert_allclose(everywhere[13, 13], blue)  # √72 from red, √50 from blue


def test_extract_mesh_textured_steps_and_colours():
    dec = SphereDecoder()
    mesh, steps = ex.extract_mesh(
        dec,
        zero_triplane(),
        AABB,
        resolution=32,
        faces=1500,
        texture_size=256,
        original_coords=False,
        return_steps=True,
    )
    assert dec.prepare_calls == 1
    assert {"sdf", "raw", "simplified", "uv", "texture", "covered", "seconds"} <= set(steps)
    assert steps["sdf"].shape == (24, 32, 20) and len(mesh.faces) <= 1500
    assert steps["decode_stats"]["decoded"] < steps["decode_stats"]["voxels"]  # coarse to fine by default
    uvs, faces_uv = steps["uv"]
    assert np.array_equal(steps["vmapping"][faces_uv], mesh.faces)  # xatlas keeps the face order
    assert uvs.min() >= 0 and uvs.max() <= 1
    assert mesh.has_texture and mesh.materials[0].image.shape == (256, 256, 3)
    assert steps["covered"].mean() > 0.3
    tex = mesh.materials[0].image
    # the texture is the baked image, its gutter filled: covered texels unchanged
    np.testing.assert_array_equal(tex[steps["covered"]], steps["baked"][steps["covered"]][:, :3])
    assert not steps["baked"][~steps["covered"]].any()
    assert tex.std(axis=(0, 1)).min() > 0.05  # not constant
    # gutter: no black texel right next to an island
    from scipy import ndimage

    ring = ndimage.binary_dilation(steps["covered"], iterations=3) & ~steps["covered"]
    assert tex[ring].sum(-1).min() > 0.1
    # the baked texture, looked up through the mesh's UVs, gives the decoder's colour
    bary = np.full((len(mesh.faces), 3), 1 / 3)
    centroids = mesh.vertices[mesh.faces].mean(1)
    expected = (box.to_box(centroids, AABB) + 1) / 2
    err = np.abs(mesh.colors_at(np.arange(len(mesh.faces)), bary) - expected)
    assert err.mean() < 0.01 and np.quantile(err, 0.99) < 0.05


def test_uv_charts_are_capped_at_a_share_of_the_surface():
    """Large curved charts are cut (they made xatlas slow on bricky samples); the atlas stays a valid one."""
    import trimesh

    from sin3dm_lite.data.mesh import component_labels

    cyl = trimesh.creation.cylinder(0.3, 3.0, sections=32)
    v, f = np.asarray(cyl.vertices), np.asarray(cyl.faces)

    def largest_chart(share):
        vmapping, faces_uv, uvs = ex.uv_atlas(v, f, resolution=256, max_chart_share=share)
        assert np.array_equal(vmapping[faces_uv], f) and uvs.min() >= 0 and uvs.max() <= 1
        label = component_labels(len(vmapping), faces_uv)  # atlas vertices are split at seams: a chart is a component
        return (np.bincount(label, cyl.area_faces) / cyl.area).max()

    assert largest_chart(0) > 0.25  # xatlas alone: the side in two charts
    assert largest_chart(ex.MAX_CHART_SHARE) <= ex.MAX_CHART_SHARE * 1.01


def test_extract_mesh_original_coordinates_and_vertex_colours():
    dec = SphereDecoder()
    norm = Normalization(center=np.array([1.0, 2.0, 3.0]), scale=0.5)
    mesh = ex.extract_mesh(dec, zero_triplane(), AABB, normalization=norm, resolution=24, vertex_colors=True)
    assert mesh.face_uvs is None and mesh.vertex_colors.shape == (len(mesh.vertices), 3)
    r = np.linalg.norm(mesh.vertices - norm.center, axis=1)
    assert np.abs(r - 1.0).max() < 0.02  # radius 0.5 / scale 0.5
    assert np.allclose(mesh.normalization.center, 0) and mesh.normalization.scale == 1.0
    expected = (box.to_box(norm.to_normalized(mesh.vertices), AABB) + 1) / 2
    np.testing.assert_allclose(mesh.vertex_colors, expected, atol=1e-5)


def test_retargeted_box_gives_a_correspondingly_scaled_shape():
    dec = SphereDecoder()
    wide = AABB * np.array([2, 1, 1, 2, 1, 1])  # the triplane was sampled twice as long along x
    mesh = ex.extract_mesh(
        dec, zero_triplane(res=(24, 16, 10)), wide, resolution=32, faces=3000, texture_size=128, original_coords=False
    )
    lo, hi = mesh.bounds
    voxel = (wide[3] - wide[0]) / 32
    np.testing.assert_allclose(hi, [1.0, 0.5, 0.5], atol=voxel / 2)
    np.testing.assert_allclose(lo, [-1.0, -0.5, -0.5], atol=voxel / 2)

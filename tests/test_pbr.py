"""The PBR variant end to end: example maps → 8-channel grid → autoencoder with two more heads → baked maps → GLB."""

import numpy as np
import pytest
import torch
import trimesh

from sin3dm_lite.data.config import replace
from sin3dm_lite.data.grid import PBR_CHANNELS, mesh_to_grid
from sin3dm_lite.data.mesh import tangent_frames
from sin3dm_lite.evaluate.metrics import iou, reconstruction_metrics
from sin3dm_lite.examples import build_example
from sin3dm_lite.formats.export import export_mesh
from sin3dm_lite.formats.load import load_mesh
from sin3dm_lite.generate.extract import extract_mesh
from sin3dm_lite.model.autoencoder import AutoencoderTrainer, fit_autoencoder
from sin3dm_lite.model.decode import reconstructed_grid
from sin3dm_lite.presets import get_preset

from .conftest import textured

TINY = get_preset("tiny")


def closest_points(points, mesh):
    """Distance, face and barycentrics of the closest surface point of ``mesh`` to each point (point-cloud-utils)."""
    import point_cloud_utils as pcu

    v, f = np.ascontiguousarray(mesh.vertices, np.float64), np.ascontiguousarray(mesh.faces, np.int64)
    return pcu.closest_points_on_mesh(np.ascontiguousarray(points, np.float64), v, f)


def tiny_grid(mesh, **kw):
    g = TINY.grid
    return mesh_to_grid(
        mesh,
        g.resolution,
        g.threshold_voxels,
        g.n_surface_points,
        g.near_surface_sigma,
        0,
        False,
        margin_voxels=g.margin_voxels,
        **kw,
    )


@pytest.fixture(scope="module")
def tiles():
    return build_example("tiles")


@pytest.fixture(scope="module")
def tiles_grid(tiles):
    return tiny_grid(tiles)


@pytest.fixture(scope="module")
def fitted(tiles_grid):
    torch.set_num_threads(1)
    model, h0, history = fit_autoencoder(tiles_grid, replace(TINY.autoencoder, pbr=True), progress=False)
    return model, h0, history


@pytest.fixture(scope="module")
def exported(fitted, tiles_grid, tmp_path_factory):
    model, h0, _ = fitted
    s = TINY.sampling
    mesh, steps = extract_mesh(
        model.decoder,
        h0,
        tiles_grid.aabb,
        tiles_grid.normalization,
        resolution=s.mesh_resolution,
        faces=s.faces,
        texture_size=s.texture_size,
        return_steps=True,
    )
    paths = export_mesh(mesh, tmp_path_factory.mktemp("pbr"), "sample")
    return mesh, steps, paths


# ----------------------------------------------------------------------------- 1. the example
def test_example_has_varying_pbr_maps(tiles):
    assert tiles.has_pbr
    mat = tiles.materials[0]
    mr, nm = mat.metallic_roughness_image, mat.normal_image
    assert mr.shape == nm.shape == mat.image.shape
    assert mr[..., 1].std() > 0.1 and mr[..., 2].std() > 0.1  # roughness (G) and metallic (B) vary
    assert nm[..., :2].std() > 0.01  # the normal map bends normals (flat = 0.5, 0.5, 1)
    np.testing.assert_allclose(np.linalg.norm(nm * 2 - 1, axis=-1), 1, atol=0.02)
    _, fi, bc = tiles.surface_points(4000, np.random.default_rng(0))
    p = tiles.pbr_at(fi, bc)
    metal = p[:, 0] > 0.5
    assert 0.1 < metal.mean() < 0.6  # steel and paint both cover a good share
    assert p[metal, 1].mean() < p[~metal, 1].mean() - 0.2  # steel is smoother than paint and grout


def test_tangent_frames_are_orthonormal_and_follow_uv():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    f = np.array([[0, 1, 2]])
    uv = np.array([[[0, 0], [1, 0], [0, 1]]], np.float32)
    t, b, n = tangent_frames(v, f, uv)
    np.testing.assert_allclose(np.concatenate([t, b, n]), np.eye(3), atol=1e-12)
    t2, b2, n2 = tangent_frames(v, f, uv * [[-1, 1]])  # mirrored u: T flips, B keeps following v
    np.testing.assert_allclose(t2[0], [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(b2[0], [0, 1, 0], atol=1e-12)
    t3, b3, _ = tangent_frames(v, f, None)  # no UVs: still a frame
    assert abs(t3[0] @ n[0]) < 1e-12 and abs(np.linalg.norm(b3[0]) - 1) < 1e-12


# ----------------------------------------------------------------------------- 2. the grid
def test_grid_pbr_channels(tiles, tiles_grid):
    g = tiles_grid
    assert g.has_pbr and g.color.shape[-1] == len(PBR_CHANNELS) == 8 and g.point_color.shape[1] == 8
    band = np.abs(g.sdf) < g.threshold
    n = g.channel("normal")[band]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1, atol=1e-4)
    # every band voxel holds the material of its closest surface point: metal where the example is metal
    m = replace(tiles, vertices=g.normalization.to_normalized(tiles.vertices))  # the grid's frame (margin included)
    centres = g.voxel_centers()[band][:: max(1, band.sum() // 1500)]
    _, tri, bc = closest_points(centres, m)
    expected = tiles.pbr_at(tri, bc)
    got = g.color[band][:: max(1, band.sum() // 1500)]
    agree = np.abs(got[:, 3] - expected[:, 0]) < 0.05  # metallic (ties between equally close faces may differ)
    assert agree.mean() > 0.97
    assert (np.abs(got[:, 4] - expected[:, 1]) < 0.05).mean() > 0.97  # roughness
    assert 0.1 < (got[:, 3] > 0.5).mean() < 0.6


def test_grid_normals_follow_geometry_without_normal_map(box_grid):
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    g = tiny_grid(textured(box), pbr=True)  # no maps: the geometric normals
    assert g.has_pbr
    band = np.abs(g.sdf) < g.threshold
    c = g.voxel_centers()[band]
    half = np.abs(c).max(0)  # the box's half extents as the band reaches them (≈ face + band)
    d = np.sort(half - np.abs(c), axis=1)
    face = (half - np.abs(c)).argmin(1)
    clear = d[:, 1] - d[:, 0] > 2 * g.voxel_size  # well away from edges
    expected = np.eye(3)[face] * np.sign(c[np.arange(len(c)), face])[:, None]
    dots = np.einsum("ij,ij->i", g.channel("normal")[band], expected)[clear]
    assert clear.sum() > 100 and dots.mean() > 0.99
    np.testing.assert_allclose(g.channel("metallic")[band], 0.0)  # Material(): metallic 0, roughness 1
    np.testing.assert_allclose(g.channel("roughness")[band], 1.0)


# ----------------------------------------------------------------------------- 3. the autoencoder
def test_autoencoder_reconstructs_materials(fitted, tiles_grid):
    model, h0, history = fitted
    assert {"material", "normal"} <= set(history)
    assert history["material"][-1] < history["material"][0]
    rec = reconstructed_grid(model.decoder, h0, tiles_grid)
    assert rec.color.shape[-1] == 8
    band = np.abs(tiles_grid.sdf) < tiles_grid.threshold
    assert abs(rec.color[band][:, 4].mean() - tiles_grid.color[band][:, 4].mean()) < 0.1  # mean roughness
    r = reconstruction_metrics(rec, tiles_grid)
    # metal covers ~19 % of the band: an all-metal guess scores IoU ≈ 0.19, a random mask of that size ≈ 0.1;
    # 150 tiny steps reach ≈ 0.6 (the small preset more), so 0.45 means "the metal is in the same places"
    assert r["metallic_iou"] > 0.45
    assert r["roughness_l1"] < 0.12 and r["metallic_l1"] < 0.15 and r["normal_angle_deg"] < 35


def test_pbr_config_must_match_grid(tiles_grid, box_grid):
    from sin3dm_lite.errors import Sin3DMInputError

    with pytest.raises(Sin3DMInputError, match="pbr"):
        AutoencoderTrainer(tiles_grid, TINY.autoencoder)
    with pytest.raises(Sin3DMInputError, match="pbr"):
        AutoencoderTrainer(box_grid, replace(TINY.autoencoder, pbr=True))


# ----------------------------------------------------------------------------- 4. export
def test_export_bakes_pbr_maps(exported, tiles):
    mesh, steps, _ = exported
    mat = mesh.materials[0]
    mr, nm, cov = mat.metallic_roughness_image, mat.normal_image, steps["covered"]
    assert mr.shape == nm.shape == mat.image.shape
    assert mr[cov][:, 2].std() > 0.1 and mr[cov][:, 1].std() > 0.05  # metallic and roughness vary
    assert nm[cov][:, :2].std() > 0.01
    _, fi, bc = tiles.surface_points(20000, np.random.default_rng(0))
    assert abs(mr[cov][:, 1].mean() - tiles.pbr_at(fi, bc)[:, 1].mean()) < 0.1  # mean roughness of the surface
    # where the sample is metal, the input is metal: compare at the input's closest points
    _, sfi, sbc = mesh.surface_points(3000, np.random.default_rng(0))
    pts = np.einsum("nk,nkd->nd", sbc, mesh.vertices[mesh.faces[sfi]])
    _, tri, tbc = closest_points(pts, tiles)
    assert iou(mesh.pbr_at(sfi, sbc)[:, 0] > 0.5, tiles.pbr_at(tri, tbc)[:, 0] > 0.5) > 0.4


def test_exported_glb_reloads_with_pbr_textures(exported):
    mesh, _, paths = exported
    scene = trimesh.load(paths["glb"])
    (geom,) = scene.geometry.values()
    pm = geom.visual.material
    assert pm.metallicRoughnessTexture is not None and pm.normalTexture is not None
    mr = np.asarray(pm.metallicRoughnessTexture.convert("RGB"), np.float32) / 255
    nm = np.asarray(pm.normalTexture.convert("RGB"), np.float32) / 255
    assert mr[..., 2].std() > 0.1 and mr[..., 1].std() > 0.05 and nm[..., :2].std() > 0.01
    back = load_mesh(paths["glb"])
    assert back.has_pbr
    mtl = paths["obj"].with_suffix(".mtl").read_text()
    assert "map_Pr" in mtl and "map_Pm" in mtl and "map_Bump" in mtl
    assert load_mesh(paths["obj"]).has_pbr


# ----------------------------------------------------------------------------- 5. inputs without PBR maps
def test_input_without_pbr_is_unchanged(box_grid):
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    m = textured(box)
    assert not m.has_pbr
    auto, off = tiny_grid(m), tiny_grid(m, pbr=False)
    assert auto.color.shape[-1] == 3 and not auto.has_pbr
    for name in ("sdf", "color", "points", "point_sdf", "point_color"):
        np.testing.assert_array_equal(getattr(auto, name), getattr(off, name))
    tr = AutoencoderTrainer(box_grid, TINY.autoencoder)
    keys = set(tr.model.state_dict())
    assert not any(k.startswith(("decoder.mr_mlp", "decoder.normal_mlp")) for k in keys)
    assert tr.model.encoder.tex.in_channels == 4 and tr.model.decoder.tex_mlp.out.out_features == 3
    assert tr.loss_names == ("loss", "sdf", "color") and set(tr.history) == {"loss", "sdf", "color"}
    assert set(reconstruction_metrics(box_grid, box_grid)) == {
        "sign_accuracy",
        "occupancy_iou",
        "occupancy_iou_quarter_voxel",
        "color_l1",
        "color_psnr",
        "color_psnr_surface",
    }


def test_plot_pbr_figures(tiles, tiles_grid):
    from sin3dm_lite import viz

    assert len(viz.plot_pbr_maps(tiles).axes) == 4
    assert len(viz.plot_pbr_slices(tiles_grid, "y").axes) == 4
    imgs = viz.pbr_map_images(tiles)
    assert set(imgs) == {"base colour", "metallic", "roughness", "normal"} and imgs["metallic"].std() > 0.1

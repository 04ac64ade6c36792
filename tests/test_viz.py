"""The matplotlib figures of ``sin3dm_lite.show.viz``: right panels, right data drawn."""

import ctypes.util
import io
import sys

import matplotlib.pyplot as plt
import numpy as np
import pytest
import torch
import trimesh
from matplotlib.collections import LineCollection
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from PIL import Image

from sin3dm_lite import metrics as M
from sin3dm_lite import viz
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.model.triplane import Triplane, pca_basis, pca_project, plane_to_image

from .conftest import rf_square


@pytest.fixture(scope="module")
def tp():
    torch.manual_seed(0)
    return Triplane.randn(2, 5, (8, 6, 10))


def image_axes(fig):
    return [ax for ax in fig.axes if ax.images]


def test_library_does_not_leave_figures_open(sphere_grid):
    before = plt.get_fignums()
    fig = viz.plot_slice(sphere_grid, "z", 3)
    assert isinstance(fig, Figure)
    assert plt.get_fignums() == before  # shown once in Jupyter, no leak in loops


def test_grid_slice_middle_and_bounds(sphere_grid):
    s, i = viz.grid_slice(sphere_grid.sdf, "y")
    assert i == sphere_grid.shape[1] // 2 and s.shape == (16, 20)
    np.testing.assert_array_equal(s, sphere_grid.sdf[:, i, :])
    with pytest.raises(IndexError):
        viz.grid_slice(sphere_grid.sdf, "z", 20)
    with pytest.raises(ValueError):
        viz.grid_slice(sphere_grid.sdf, "w")


def test_plot_grid_slices_panels_and_data(sphere_grid):
    fig = viz.plot_grid_slices(sphere_grid)
    panels = image_axes(fig)
    assert len(panels) == 6  # 3 sdf + 3 colour
    assert len(fig.axes) == 7  # + one shared colour bar
    # top row: sdf slices, drawn transposed (first remaining axis →, second ↑), except that
    # y (up, by default) stays vertical: the x slice shows z → and y ↑
    for k, axis in enumerate("xyz"):
        ax = panels[k]
        expected, idx = viz.grid_slice(sphere_grid.sdf, axis)
        np.testing.assert_array_equal(np.asarray(ax.images[0].get_array()), expected if axis == "x" else expected.T)
        assert (ax.get_xlabel(), ax.get_ylabel()) == {"x": ("z", "y"), "y": ("x", "z"), "z": ("x", "y")}[axis]
        assert ax.images[0].origin == "lower"
        lo, hi = ax.images[0].get_clim()
        assert lo == pytest.approx(-sphere_grid.threshold) and hi == pytest.approx(sphere_grid.threshold)
        coord = sphere_grid.axis_coords(k)[idx]
        assert f"{axis} = {idx}" in ax.get_title() and f"{coord:+.3f}" in ax.get_title()
        assert ax.collections, "zero contour drawn"
    # bottom row: colour inside the band, neutral grey outside
    rgb = np.asarray(panels[3 + 2].images[0].get_array()).swapaxes(0, 1)  # z slice, back to (x, y, 3)
    sdf, _ = viz.grid_slice(sphere_grid.sdf, "z")
    col, _ = viz.grid_slice(sphere_grid.color, "z")
    band = np.abs(sdf) < sphere_grid.threshold
    np.testing.assert_allclose(rgb[band], col[band])
    np.testing.assert_allclose(rgb[~band], np.broadcast_to(viz.NEUTRAL, rgb[~band].shape))


def test_plot_grid_slices_options(sphere_grid):
    fig = viz.plot_grid_slices(sphere_grid, index=[2, 4], axes=("x", "z"), show_color=False, threshold_lines=False)
    panels = image_axes(fig)
    assert len(panels) == 2
    np.testing.assert_array_equal(np.asarray(panels[1].images[0].get_array()), sphere_grid.sdf[:, :, 4].T)
    with pytest.raises(ValueError):
        viz.plot_grid_slices(sphere_grid, index=[1, 2], axes=("x", "y", "z"))


def test_plot_slice_kinds(sphere_grid):
    fig = viz.plot_slice(sphere_grid, "x", 5, kind="sdf", up=None)
    assert len(image_axes(fig)) == 1
    np.testing.assert_array_equal(np.asarray(fig.axes[0].images[0].get_array()), sphere_grid.sdf[5].T)
    # y up (the default): z → and y ↑, extent and labels follow
    ax = viz.plot_slice(sphere_grid, "x", 5, kind="color").axes[0]
    np.testing.assert_allclose(np.asarray(ax.images[0].get_array()), viz.color_slice_image(sphere_grid, "x", 5))
    assert ax.images[0].get_extent() == pytest.approx(
        [sphere_grid.aabb[2], sphere_grid.aabb[5], sphere_grid.aabb[1], sphere_grid.aabb[4]]
    )
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("z", "y")
    ax = viz.plot_slice(sphere_grid, "x", 5, kind="sdf", up="z").axes[0]  # a z-up mesh: y → and z ↑
    np.testing.assert_array_equal(np.asarray(ax.images[0].get_array()), sphere_grid.sdf[5].T)
    fig = viz.plot_slice(sphere_grid, 1, 6, kind="color")
    assert len(fig.axes) == 1
    img = np.asarray(fig.axes[0].images[0].get_array())
    assert img.shape == (20, 16, 3)
    np.testing.assert_allclose(img.swapaxes(0, 1), viz.color_slice_image(sphere_grid, "y", 6))
    # extent is in world coordinates: x then z
    assert fig.axes[0].images[0].get_extent() == pytest.approx(
        [sphere_grid.aabb[0], sphere_grid.aabb[3], sphere_grid.aabb[2], sphere_grid.aabb[5]]
    )
    with pytest.raises(ValueError):
        viz.plot_slice(sphere_grid, "z", 3, kind="normals")


def test_plot_truncation(sphere_grid):
    own = sphere_grid.threshold / sphere_grid.voxel_size
    fig = viz.plot_truncation(sphere_grid, thresholds=[1, 2, own], axis="z", index=10)
    panels = image_axes(fig)
    assert len(panels) == 3
    profile = fig.axes[0]
    assert len(profile.get_lines()) >= 3
    # the 1-voxel profile is the stored slice re-clipped at one voxel
    sdf = sphere_grid.sdf[:, :, 10]
    line = sdf.shape[1] // 2
    np.testing.assert_allclose(
        profile.get_lines()[0].get_ydata(), np.clip(sdf[:, line], -sphere_grid.voxel_size, sphere_grid.voxel_size)
    )
    np.testing.assert_allclose(
        np.asarray(panels[0].images[0].get_array()),
        np.clip(sdf, -sphere_grid.voxel_size, sphere_grid.voxel_size).T,
        rtol=1e-6,
    )
    np.testing.assert_allclose(np.asarray(panels[2].images[0].get_array()), sdf.T)
    assert len(image_axes(viz.plot_truncation(sphere_grid))) == 3  # default 1, 2, own
    with pytest.raises(ValueError, match="exceed"):
        viz.plot_truncation(sphere_grid, thresholds=[own + 1])


def test_plot_truncation_of_untruncated_array():
    x = np.linspace(-1, 1, 10)
    field = np.sqrt(x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2) - 0.5
    fig = viz.plot_truncation(field, thresholds=[1, 4], axis="x", index=5)
    panels = image_axes(fig)
    voxel = 2.0 / 10
    np.testing.assert_allclose(
        np.asarray(panels[1].images[0].get_array()), np.clip(field[5], -4 * voxel, 4 * voxel).T, rtol=1e-6
    )
    assert panels[1].images[0].get_clim() == pytest.approx((-4 * voxel, 4 * voxel))


def test_plot_points(sphere_grid):
    fig = viz.plot_points(sphere_grid, n=200, seed=1)
    scatter_axes = [ax for ax in fig.axes if ax.collections and "projection" in ax.get_title()]
    assert len(scatter_axes) == 3
    offsets = scatter_axes[1].collections[0].get_offsets()  # xz projection
    assert offsets.shape == (200, 2)
    # every drawn point is one of the grid's points, projected on (x, z)
    proj = sphere_grid.points[:, [0, 2]]
    assert all(np.any(np.all(np.isclose(proj, o), axis=1)) for o in np.asarray(offsets[:20]))
    rects = [p for p in scatter_axes[0].patches if isinstance(p, Rectangle)]
    assert len(rects) == 1 and rects[0].get_width() == pytest.approx(sphere_grid.aabb[3] - sphere_grid.aabb[0])


def test_plot_triplane_pca_and_channels(tp):
    fig = viz.plot_triplane(tp)
    panels = image_axes(fig)
    assert len(panels) == 3
    for ax, plane in zip(panels, tp.planes):
        np.testing.assert_allclose(
            np.asarray(ax.images[0].get_array()), plane_to_image(plane[0], "pca").swapaxes(0, 1), atol=1e-6
        )
    # true relative sizes: xy is X wide, yz is Y wide
    w = [ax.get_position().width for ax in panels]
    assert w[0] / w[2] == pytest.approx(8 / 6, rel=0.05)
    fig = viz.plot_triplane(tp, channels=[0, 3], batch=1)
    panels = image_axes(fig)
    assert len(panels) == 6
    np.testing.assert_allclose(
        np.asarray(panels[5].images[0].get_array()), plane_to_image(tp.yz[1], 3).swapaxes(0, 1), atol=1e-6
    )
    assert "channel 3" in panels[5].get_title()


def test_plot_losses_raw_and_average():
    hist = {"geo": list(np.linspace(1.0, 0.1, 200)), "tex": list(np.linspace(2.0, 0.5, 200))}
    fig = viz.plot_losses(hist, title="autoencoder")
    ax = fig.axes[0]
    lines = ax.get_lines()
    assert len(lines) == 4 and ax.get_yscale() == "log"
    np.testing.assert_allclose(lines[0].get_ydata(), hist["geo"])
    np.testing.assert_allclose(lines[1].get_ydata(), viz.moving_average(hist["geo"], 4))
    assert lines[1].get_linewidth() > lines[0].get_linewidth()
    fig = viz.plot_losses([0.5, -0.1, 0.2], log=True)  # non-positive values: stays linear
    assert fig.axes[0].get_yscale() == "linear"
    np.testing.assert_allclose(viz.moving_average([1, 2, 3, 4], 2), [1.5, 2.5, 3.5])


def test_plot_schedule_accepts_tensors():
    betas = torch.linspace(1e-4, 0.02, 1000)
    ac = torch.cumprod(1 - betas, 0)
    fig = viz.plot_schedule(ac, betas)
    assert len(fig.axes) == 2
    np.testing.assert_allclose(fig.axes[0].get_lines()[0].get_ydata(), betas.numpy(), rtol=1e-6)
    ys = [line.get_ydata() for line in fig.axes[1].get_lines()]
    np.testing.assert_allclose(ys[0], ac.numpy(), rtol=1e-6)
    np.testing.assert_allclose(ys[2], np.sqrt(1 - ac.numpy()), rtol=1e-5)


def test_plot_denoising(tp):
    steps = [{"step": i, "t": t, "x_t": tp * (1 + i), "x0": tp + i} for i, t in enumerate([999, 500, 0])]
    fig = viz.plot_denoising(steps, plane="xz", channels=2)
    panels = image_axes(fig)
    assert len(panels) == 6
    assert [ax.get_title() for ax in panels[:3]] == ["t = 999", "t = 500", "t = 0"]
    np.testing.assert_allclose(
        np.asarray(panels[4].images[0].get_array()),  # x0 row, second column
        plane_to_image(steps[1]["x0"].xz[0], 2).swapaxes(0, 1),
        atol=1e-6,
    )
    # PCA: one shared basis, so the same plane gives the same picture in every column
    same = [{"step": i, "t": i, "x_t": tp, "x0": tp} for i in range(2)]
    panels = image_axes(viz.plot_denoising(same))
    a, b = (np.asarray(panels[k].images[0].get_array()) for k in (0, 1))
    np.testing.assert_allclose(a, b)
    assert a.shape == (6, 8, 3) and a.min() >= 0 and a.max() <= 1
    # with a reference, every panel is projected on the reference's basis
    ref = Triplane.randn(2, 5, (8, 6, 10), generator=torch.Generator().manual_seed(7))  # other directions
    panels = image_axes(viz.plot_denoising(same, reference=ref))
    mean, basis = pca_basis(ref.xy[0].numpy())
    np.testing.assert_allclose(
        np.asarray(panels[0].images[0].get_array()),
        pca_project(tp.xy[0].numpy(), mean, basis).swapaxes(0, 1),
        atol=1e-6,
    )
    w, h = viz.plot_denoising(steps, plane="yz").get_size_inches()  # 6 × 10 planes: taller than wide panels
    assert h > 2 * (w / 3)
    with pytest.raises(ValueError):
        viz.plot_denoising(steps, plane="zz")


def test_plot_receptive_field():
    rf = rf_square()
    fig = viz.plot_receptive_field(rf, analytic_width=9, title="4 ResBlocks")
    ax = fig.axes[0]
    im = ax.images[0]
    assert isinstance(im.norm, LogNorm)
    assert im.norm.vmin <= 1e-3  # the weak global coupling is on the scale
    drawn = np.ma.filled(im.get_array().astype(float), 0.0)
    np.testing.assert_allclose(drawn, np.where(rf > 0, rf, 0.0).T)
    rect = [p for p in ax.patches if isinstance(p, Rectangle)][0]
    assert rect.get_width() == 9 and rect.get_xy() == pytest.approx((16 - 4.5, 16 - 4.5))
    marker = ax.get_lines()[0]
    assert list(marker.get_xdata()) == [16] and list(marker.get_ydata()) == [16]
    assert viz.measured_width(rf) == 9
    assert "4 ResBlocks" in ax.get_title() and "analytic 9" in ax.get_title() and "measured (≥0.01) 9" in ax.get_title()
    # a faint texel further out counts only when the cut is lower (receptive_field.receptive_field cuts at 1e-3)
    faint = rf.copy()
    faint[16, 16 + 7] = 5e-3
    assert viz.measured_width(faint) == 9 and viz.measured_width(faint, level=2e-3) == 15
    title = viz.plot_receptive_field(faint, level=2e-3).axes[0].get_title()
    assert "measured (≥0.002) 15" in title
    # into an existing axes
    fig2 = plt.figure()
    ax2 = fig2.add_subplot(1, 2, 1)
    assert viz.plot_receptive_field(rf, ax=ax2) is fig2
    plt.close(fig2)


def test_plot_receptive_fields_side_by_side():
    items = [(f"{n} blocks", rf_square(width=w), w) for n, w in [(2, 5), (4, 9), (6, 13)]]
    fig = viz.plot_receptive_fields(items)
    panels = image_axes(fig)
    assert len(panels) == 3
    assert [viz.measured_width(rf) for _, rf, _ in items] == [5, 9, 13]
    assert [p.get_title().endswith(f"measured (≥0.01) {w}") for p, w in zip(panels, [5, 9, 13])] == [True] * 3
    assert all(p.images[0].norm.vmin == panels[0].images[0].norm.vmin for p in panels)


def test_plot_samples_slices(sphere_grid):
    grids = [sphere_grid.sdf, -sphere_grid.sdf, torch.from_numpy(sphere_grid.sdf * 0.5)]
    fig = viz.plot_samples_slices(grids, axis="y", titles=["a", "b", "c"], columns=2)
    panels = image_axes(fig)
    assert len(panels) == 3 and len(fig.axes) == 4  # the fourth cell is switched off
    np.testing.assert_allclose(np.asarray(panels[1].images[0].get_array()), -sphere_grid.sdf[:, 6, :].T)
    assert [p.get_title() for p in panels] == ["a", "b", "c"]
    assert panels[0].collections  # zero contour
    # across x with y up: z → and y ↑; a wide, flat slice gives a wide, flat figure
    fig = viz.plot_samples_slices([sphere_grid.sdf], axis="x")
    ax = image_axes(fig)[0]
    np.testing.assert_allclose(np.asarray(ax.images[0].get_array()), sphere_grid.sdf[sphere_grid.shape[0] // 2])
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("z", "y")
    flat = viz.plot_samples_slices([np.zeros((64, 8, 64), np.float32) + 0.1], axis="z", up=None)
    w, h = flat.get_size_inches()
    assert h < 0.6 * w


def test_plot_texture_and_covered():
    img = np.zeros((8, 4, 3), np.uint8)
    img[:4] = [255, 0, 0]
    fig = viz.plot_texture(img)
    assert len(fig.axes) == 1
    np.testing.assert_allclose(np.asarray(fig.axes[0].images[0].get_array()), img / 255.0)
    assert fig.axes[0].images[0].get_extent() == [0, 1, 0, 1]
    fig = viz.plot_texture(img / 255.0, covered=img[..., 0] > 0)
    assert len(image_axes(fig)) == 2 and "50.0%" in fig.axes[1].get_title()


def test_plot_uv_layout_per_vertex_and_per_corner():
    rng = np.random.default_rng(0)
    uvs = rng.random((30, 2)).astype(np.float32)
    faces = rng.integers(0, 30, size=(20_000, 3))
    fig = viz.plot_uv_layout(uvs, faces, image=np.ones((4, 4, 3)))
    ax = fig.axes[0]
    coll = [c for c in ax.collections if isinstance(c, LineCollection)][0]
    segs = coll.get_segments()
    assert len(segs) == 20_000 and len(ax.images) == 1
    np.testing.assert_allclose(segs[7][:3], uvs[faces[7]])
    np.testing.assert_allclose(segs[7][3], uvs[faces[7][0]])  # closed triangle
    corner = uvs[faces[:5]].copy()
    corner[2] = np.nan  # a face without texture
    fig = viz.plot_uv_layout(corner)
    coll = [c for c in fig.axes[0].collections if isinstance(c, LineCollection)][0]
    assert len(coll.get_segments()) == 4
    with pytest.raises(ValueError):
        viz.plot_uv_layout(uvs)


def test_every_figure_renders(sphere_grid, tp, tmp_path):
    """Drawing (not just building) each figure: catches errors that only appear at render time."""
    figs = [
        viz.plot_grid_slices(sphere_grid),
        viz.plot_truncation(sphere_grid),
        viz.plot_points(sphere_grid),
        viz.plot_triplane(tp),
        viz.plot_receptive_field(rf_square(), 9),
    ]
    for k, fig in enumerate(figs):
        fig.savefig(tmp_path / f"{k}.png", dpi=40)
        assert (tmp_path / f"{k}.png").stat().st_size > 1000


def test_plot_diversity_curve_draws_each_score_and_its_goal():
    from sin3dm_lite.show.viz import plot_diversity_curve

    rows = [{"g_div": 0.01 * i, "lp_fscore": 0.9 - 0.1 * i, "iou_to_input": 1 - 0.05 * i} for i in range(3)]
    fig = plot_diversity_curve([0.2, 0.6, 1.0], rows, goals={"g_div": 0.2})
    ax = fig.axes[0]
    labels = [line.get_label() for line in ax.get_lines() if not line.get_label().startswith("_")]
    assert labels == ["G-Div (diversity)", "IoU to the input", "LP-F (fidelity)"]  # lp_iou absent: not drawn
    curve = next(line for line in ax.get_lines() if line.get_label() == "LP-F (fidelity)")
    assert list(curve.get_ydata()) == [r["lp_fscore"] for r in rows]
    assert any(list(line.get_ydata()) == [0.2, 0.2] for line in ax.get_lines())  # the goal line


# plot_meshes renders off-screen: the render tests' skip rule where libEGL is missing
needs_egl = pytest.mark.skipif(
    sys.platform.startswith("linux") and ctypes.util.find_library("EGL") is None,
    reason="no libEGL on this machine: apt-get install libegl1 libgl1-mesa-dri",
)


def sheet_of(fig):
    """The picture in a ``plot_meshes`` figure, and the PNG the notebook keeps, as arrays."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    return fig.axes[0].images[0].get_array(), np.asarray(Image.open(buf).convert("RGB"))


@needs_egl
def test_plot_meshes_shows_a_textured_mesh_at_the_size_asked():
    from .test_render import seen, textured_cube

    before = plt.get_fignums()
    fig = viz.plot_meshes(textured_cube(), size=64)
    sheet, png = sheet_of(fig)
    assert isinstance(fig, Figure) and plt.get_fignums() == before
    assert png.shape == sheet.shape and 64 <= sheet.shape[0] <= 64 + 12 and 64 <= sheet.shape[1] <= 64 + 12
    assert 0.05 < (sheet.min(2) < 250).mean() < 0.9  # the cube, framed, on white
    assert seen(sheet)["+z"] > 0.02 and seen(sheet)["+y"] > 0.02  # its texture: magenta front, blue top


@needs_egl
def test_plot_meshes_puts_several_side_by_side_in_one_box():
    from .test_render import textured_cube

    cube = textured_cube()
    half = trimesh.creation.box(extents=(0.5, 0.5, 0.5))  # plain geometry: drawn grey
    sheet, _ = sheet_of(
        viz.plot_meshes([cube, half, (half.vertices, half.faces)], ["cube", "trimesh", "pair"], size=48)
    )
    assert sheet.shape[1] >= 3 * 48 and 48 + 12 <= sheet.shape[0] < 2 * 48  # one row of three, labels below
    tiles = [sheet[4:52, 4 + k * 52 : 4 + k * 52 + 48] for k in range(3)]
    filled = [(t.min(2) < 250).sum() for t in tiles]
    assert all(f > 0 for f in filled)
    assert filled[1] < 0.5 * filled[0] and abs(filled[1] - filled[2]) < 0.1 * filled[1]  # one scale for all
    grey = tiles[1][tiles[1].min(2) < 250].astype(int)
    assert np.abs(grey.max(1) - grey.min(1)).max() < 10  # no colour
    sheet, _ = sheet_of(viz.plot_meshes([cube] * 3, size=32, columns=2))
    assert sheet.shape[0] > 2 * 32 and sheet.shape[1] < 3 * 32  # two rows


def test_plot_meshes_without_a_renderer_says_so_in_one_line(monkeypatch):
    from sin3dm_lite import render
    from sin3dm_lite.errors import Sin3DMInputError

    def no_context(*args, **kwargs):
        raise Sin3DMInputError("cannot start an off-screen OpenGL context (no EGL)")

    monkeypatch.setattr(render, "render_hero", no_context)
    fig = viz.plot_meshes([(np.eye(3), np.array([[0, 1, 2]]))])
    assert isinstance(fig, Figure) and not fig.axes and len(fig.texts) == 1  # a line of text, no picture
    assert fig.texts[0].get_text().startswith("no static picture: cannot start") and "EGL" in fig.texts[0].get_text()
    fig.savefig(io.BytesIO(), format="png")
    with pytest.raises(Sin3DMInputError, match="one label per mesh"):
        viz.plot_meshes([(np.eye(3), np.array([[0, 1, 2]]))], labels=["a", "b"])


# --------------------------------------------------------------------------- evaluation figures
def test_plot_iou_matrix_shows_one_minus_iou_and_g_div():
    a = np.zeros((12, 12, 12), bool)
    a[:6] = True
    b = np.roll(a, 3, axis=0)  # IoU 1/3 with a
    fig = viz.plot_iou_matrix([a, b, a], ["a", "b", "a again"])
    ax = fig.axes[0]
    shown = ax.images[0].get_array()
    assert np.ma.getdata(shown)[0, 1] == pytest.approx(2 / 3) and np.ma.getdata(shown)[0, 2] == pytest.approx(0.0)
    assert np.isnan(np.ma.getdata(shown)[1, 1])  # the diagonal is blank
    assert f"{M.g_div([a, b, a]):.3f}" in ax.get_title()
    assert [t.get_text() for t in ax.get_xticklabels()] == ["a", "b", "a again"]


def test_plot_layer_variation_draws_the_input_per_layer_and_g_div_per_layer():
    grids = [np.zeros((8, 6, 4), bool) for _ in range(3)]
    for k, g in enumerate(grids):
        g[:, :3] = True  # the same body
        g[k : k + 2, 3:5] = True  # a block on top, elsewhere in each
    fig = viz.plot_layer_variation(grids[0], grids, axis="y")
    left, right = fig.axes
    assert [b.get_width() for b in left.patches] == [32, 32, 32, 8, 8, 0]
    widths = np.array([b.get_width() for b in right.patches])
    assert widths == pytest.approx(M.g_div_by_layer(grids, 1)) and np.all(widths[:3] == 0) and np.all(widths[3:5] > 0)
    assert f"{M.g_div(grids):.3f}" in right.get_title()
    with pytest.raises(Sin3DMInputError, match="different shapes"):
        viz.plot_layer_variation(grids[0][:4], grids)  # the input on another grid


def test_plot_patch_matches_draws_each_pair_and_the_histogram():
    ref = np.zeros((30, 30, 30), bool)
    ref[:, :, :15] = True
    gen = np.roll(ref, 2, axis=2)
    m = M.patch_matches(ref, gen, n=3)
    fig = viz.plot_patch_matches(m, slices=(2, 5))
    imgs = image_axes(fig)
    assert len(imgs) == 2 * len(m["iou"])
    strip = imgs[0].images[0].get_array()
    assert strip.shape == (11, 2 * 11 + 1)  # two slices (y up, x right) and one gap
    assert f"IoU {m['iou'][0]:.2f}" in imgs[0].get_title()
    hist = [ax for ax in fig.axes if not ax.images][0]
    assert f"{np.mean(m['best_iou'] > 0.95):.0%} above" in hist.get_title()


def test_plot_render_pairs_shows_both_views_and_their_distance():
    a = np.full((20, 20, 3), 255, np.uint8)
    b = a.copy()
    a[5:15, 5:15] = (200, 0, 0)
    b[5:15, 5:15] = (0, 0, 200)
    fig = viz.plot_render_pairs([a, a], [b, a], labels=("red", "blue"))
    imgs = image_axes(fig)
    assert len(imgs) == 6
    assert f"distance {M.colour_distance(a, b):.3f}" in imgs[0].get_title()
    assert "distance 0.000" in imgs[1].get_title()
    with pytest.raises(ValueError):
        viz.plot_render_pairs([a], [a, b])


def test_plot_picture_shows_the_image():
    img = np.zeros((10, 30, 3), np.uint8)
    fig = viz.plot_picture(img, title="sheet")
    assert fig.axes[0].images[0].get_array().shape[:2] == (10, 30) and fig.axes[0].get_title() == "sheet"


def _text(fig):
    return (
        " ".join(t.get_text() for ax in fig.axes for t in ax.texts)
        + " "
        + (fig._suptitle.get_text() if fig._suptitle else "")
    )


@pytest.mark.parametrize("shape", ["grid", "mesh", "box", None])
def test_plot_plane_axes_labels_each_plane_on_its_wall(sphere_grid, shape, tmp_path):
    obj = {
        "grid": sphere_grid,
        "mesh": trimesh.creation.box(extents=(2.0, 1.0, 0.5)),
        "box": np.array([-1.0, -0.5, -0.25, 1.0, 0.5, 0.25]),
        None: None,
    }[shape]
    fig = viz.plot_plane_axes(obj)
    ax3d = [ax for ax in fig.axes if ax.name == "3d"][0]
    text = _text(fig)
    for name, lacking in (("xy", "z"), ("xz", "y"), ("yz", "x")):
        assert f"{name} plane\n(mean over {lacking})" in text
    assert "y (up)" in text and "xz: seen from below (x →, z ↑)" in text  # y up: xz with z ↑ is a mirrored top view
    assert "xy: a side view along z (x →, y ↑: upright)" in text
    assert "slice across y (horizontal): x →, z ↑" in text and "slice across x (vertical): z →, y ↑" in text
    # the planes lie on the walls at the minimum of the axis each lacks
    quads = [c for c in ax3d.collections if type(c).__name__ == "Poly3DCollection"]
    assert len(quads) == 3
    fig.savefig(tmp_path / "axes.png", dpi=40)
    with pytest.raises(ValueError):
        viz.plot_plane_axes(np.zeros(4))


def test_plot_plane_axes_words_follow_the_up_axis():
    text = _text(viz.plot_plane_axes(None, up="z"))
    assert "xy: seen from above (x →, y ↑)" in text and "z (up)" in text
    assert "slice across z (horizontal): x →, y ↑" in text


def test_plot_triplane_conv_shows_the_rollout_of_each_plane(tp, tmp_path):
    from sin3dm_lite.model.unet import rollout_parts

    parts = rollout_parts(tp)
    for plane, lacking, others in (("xy", "z", ("xz", "yz")), ("xz", "y", ("xy", "yz")), ("yz", "x", ("xy", "xz"))):
        fig = viz.plot_triplane_conv(parts, plane)
        assert len(image_axes(fig)) == 8  # 3 planes, 2 pooled strips, 2 expanded, 1 concatenation
        titles = [ax.get_title() for ax in fig.axes]
        assert (
            f"{others[0]}: averaged over {lacking} ↓" in titles and f"{others[1]}: averaged over {lacking} ↓" in titles
        )
        assert any(t.startswith(f"concatenated: {3 * tp.channels} = 3C") for t in titles)
        fig.savefig(tmp_path / f"{plane}.png", dpi=40)
    with pytest.raises(ValueError):
        viz.plot_triplane_conv(parts, "zz")

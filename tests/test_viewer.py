"""The k3d viewers of ``sin3dm_lite.show.viewer``: objects, dtypes, texture bytes and orientation, HTML pages."""

import io

import k3d
import numpy as np
import pytest
import trimesh
from PIL import Image

from sin3dm_lite import viewer
from sin3dm_lite.data.mesh import Material, TexturedMesh, sample_texture


def red_top_blue_bottom(h=8, w=4) -> np.ndarray:
    img = np.zeros((h, w, 3), np.float32)
    img[: h // 2] = [1, 0, 0]
    img[h // 2 :] = [0, 0, 1]
    return img


def textured_quad() -> TexturedMesh:
    """A unit square in the xy plane (y up, facing +z); OBJ uvs = (x, y), so the texture's top is at y = 1."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    return TexturedMesh(
        v,
        f,
        np.zeros(2, np.int64),
        [Material("tex", base_color=np.ones(4, np.float32), image=red_top_blue_bottom())],
        face_uvs=v[f][..., :2].astype(np.float32),
        name="quad",
    )


def k3d_texel(png: bytes, uv: np.ndarray) -> np.ndarray:
    """What k3d shows at ``uv``: it uploads the PNG with flipY = false, so v = 0 is the image's top row."""
    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.float32) / 255.0
    h, w = img.shape[:2]
    rows = np.clip((uv[:, 1] * h).astype(int), 0, h - 1)
    cols = np.clip((uv[:, 0] * w).astype(int), 0, w - 1)
    return img[rows, cols]


def meshes_of(plot):
    return [o for o in plot.objects if isinstance(o, k3d.objects.Mesh)]


def test_to_view_and_pack_colors():
    p = np.array([[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(viewer.to_view(p, "y"), [[1.0, -3.0, 2.0]])  # y (up) becomes k3d's z
    np.testing.assert_array_equal(viewer.to_view(p, "z"), p)
    assert viewer.to_view(p).dtype == np.float32
    with pytest.raises(ValueError):
        viewer.to_view(p, "x")
    packed = viewer.pack_colors(np.array([[1.0, 0.0, 0.0], [0, 128 / 255, 1.0]]))
    assert packed.dtype == np.uint32 and list(packed) == [0xFF0000, 0x0080FF]
    assert list(viewer.pack_colors(np.array([[1, 2, 3]], np.uint8))) == [0x010203]


def test_textured_mesh_plot_texture_and_dtypes():
    quad = textured_quad()
    plot = viewer.mesh_plot(quad)
    (m,) = meshes_of(plot)
    assert m.vertices.dtype == np.float32 and m.indices.dtype == np.uint32 and m.uvs.dtype == np.float32
    assert m.color == 0xFFFFFF and m.texture_file_format == "png" and m.name == "quad"
    assert len(m.colors) == 0 and m.texture_wrap == "clamp"  # uvs inside [0, 1]
    png = bytes(m.texture)
    assert png.startswith(b"\x89PNG")
    decoded = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    np.testing.assert_array_equal(decoded, (red_top_blue_bottom() * 255).astype(np.uint8))
    # up="y": the quad stands up in k3d (y -> z) and its top edge is at z = 1
    assert m.vertices[:, 2].max() == pytest.approx(1.0) and np.allclose(m.vertices[:, 1], 0.0)


def test_texture_orientation_red_on_top():
    """The k3d uvs make the texture's top half (red) land on the quad's top half (k3d z > 0.5)."""
    m = meshes_of(viewer.mesh_plot(textured_quad()))[0]
    uv, tri = m.uvs, m.indices
    # sample inside each face (barycentric points), in k3d's convention, and where they are in space
    bary = np.array([[0.6, 0.2, 0.2], [0.2, 0.6, 0.2], [0.2, 0.2, 0.6], [1 / 3, 1 / 3, 1 / 3]])
    pts_uv = np.einsum("bk,fkd->fbd", bary, uv[tri]).reshape(-1, 2)
    pts_xyz = np.einsum("bk,fkd->fbd", bary, m.vertices[tri]).reshape(-1, 3)
    shown = k3d_texel(bytes(m.texture), pts_uv)
    top = pts_xyz[:, 2] > 0.5
    assert top.any() and (~top).any()
    np.testing.assert_allclose(shown[top], [[1, 0, 0]] * top.sum())
    np.testing.assert_allclose(shown[~top], [[0, 0, 1]] * (~top).sum())
    # and k3d's lookup agrees with our own OBJ-convention lookup at the same surface points
    quad = textured_quad()
    obj_uv = np.stack([pts_xyz[:, 0], pts_xyz[:, 2]], axis=1)  # the quad's OBJ uv is (x, y_data) = (x, z_k3d)
    np.testing.assert_allclose(np.round(sample_texture(quad.materials[0].image, obj_uv)), shown)


def test_uv_seams_split_vertices():
    """One uv per vertex: a vertex with two different corner uvs becomes two k3d vertices."""
    quad = textured_quad()
    quad.face_uvs = quad.face_uvs.copy()
    quad.face_uvs[1, 0] = [0.5, 0.5]  # vertex 0 gets a second uv in face 1
    arrays = viewer.mesh_arrays(quad)
    assert len(arrays["vertices"]) == 5 and arrays["indices"].shape == (2, 3)
    # every corner still finds its own position and uv
    np.testing.assert_allclose(arrays["vertices"][arrays["indices"]], quad.vertices[quad.faces])
    np.testing.assert_allclose(arrays["uvs"][arrays["indices"]], quad.face_uvs)
    quad.face_uvs[0] += 1.0  # tiled uvs: the texture repeats
    assert meshes_of(viewer.mesh_plot(quad))[0].texture_wrap == "repeat"


def test_base_color_factor_baked_into_texture():
    quad = textured_quad()
    quad.materials[0].base_color = np.array([0.5, 1, 1, 1], np.float32)
    img = viewer.mesh_arrays(quad)["image"]
    assert img[0, 0, 0] == pytest.approx(0.5)


def test_vertex_color_fallback():
    quad = textured_quad()
    colors = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], np.float32)
    plain = TexturedMesh(
        quad.vertices,
        quad.faces,
        quad.face_material,
        [Material(base_color=np.ones(4, np.float32))],
        vertex_colors=colors,
    )
    (m,) = meshes_of(viewer.mesh_plot(plain, up="z"))
    assert m.colors.dtype == np.uint32 and len(m.uvs) == 0 and m.texture is None
    np.testing.assert_array_equal(m.vertices, quad.vertices.astype(np.float32))  # up="z": unchanged
    by_pos = {tuple(v): c for v, c in zip(m.vertices, m.colors)}
    assert by_pos[(0.0, 0.0, 0.0)] == 0xFF0000 and by_pos[(1.0, 1.0, 0.0)] == 0x0000FF
    # texture=False on a textured mesh, and a mesh with two textured materials, fall back too
    (m,) = meshes_of(viewer.mesh_plot(textured_quad(), texture=False))
    assert m.texture is None and m.colors.dtype == np.uint32 and len(m.colors) == len(m.vertices)
    two = textured_quad()
    two.materials = [two.materials[0], Material("b", image=np.ones((2, 2, 3), np.float32))]
    two.face_material = np.array([0, 1])
    (m,) = meshes_of(viewer.mesh_plot(two))
    assert m.texture is None and len(m.colors) > 0
    # a plain colour overrides everything
    (m,) = meshes_of(viewer.mesh_plot(textured_quad(), color=0x123456))
    assert m.color == 0x123456 and m.texture is None and len(m.colors) == 0


def test_trimesh_inputs():
    box = trimesh.creation.box()
    box.visual.vertex_colors = np.tile([[10, 20, 30, 255]], (len(box.vertices), 1)).astype(np.uint8)
    (m,) = meshes_of(viewer.mesh_plot(box, name="box"))
    assert m.name == "box" and set(m.colors.tolist()) == {0x0A141E}
    assert m.vertices.dtype == np.float32 and m.indices.dtype == np.uint32
    # a TextureVisuals trimesh keeps its texture; trimesh stores OBJ-convention per-vertex uvs
    quad = textured_quad()
    image = Image.fromarray((red_top_blue_bottom() * 255).astype(np.uint8))
    tm = trimesh.Trimesh(
        quad.vertices,
        quad.faces,
        process=False,
        visual=trimesh.visual.TextureVisuals(uv=quad.vertices[:, :2], image=image),
    )
    (m,) = meshes_of(viewer.mesh_plot(tm))
    assert m.texture is not None
    top = m.vertices[:, 2] > 0.5
    np.testing.assert_allclose(m.uvs[top, 1], 0.0)  # the top edge reads the image's top row in k3d


def test_mesh_plot_adds_to_existing_plot_with_offset():
    plot = viewer.new_plot()
    assert viewer.mesh_plot(textured_quad(), plot=plot, offset=(2, 0, 0)) is plot
    viewer.mesh_plot(textured_quad(), plot=plot, name="second")
    a, b = meshes_of(plot)
    assert a.vertices[:, 0].min() == pytest.approx(2.0) and b.name == "second"


def test_gallery_layout_and_labels():
    quad = textured_quad()
    big = trimesh.creation.box(extents=(2.0, 1.0, 1.0))
    plot = viewer.gallery([quad, big, quad], labels=["a", "b", "c"], spacing=0.5)
    ms = meshes_of(plot)
    texts = [o for o in plot.objects if isinstance(o, k3d.objects.Text)]
    assert len(ms) == 3 and [t.text for t in texts] == ["a", "b", "c"]
    assert viewer.gallery([quad], labels=["x <y>"]).objects[1].text == "x &lt;y&gt;"  # shown as text, not HTML
    xs = [(m.vertices[:, 0].min(), m.vertices[:, 0].max()) for m in ms]
    assert xs[1][0] - xs[0][1] == pytest.approx(0.5) and xs[2][0] - xs[1][1] == pytest.approx(0.5)
    assert xs[1][1] - xs[1][0] == pytest.approx(2.0)  # each mesh keeps its size
    # labels sit outside their mesh's box: at its base, in front of it (towards the camera)
    for t, m in zip(texts, ms):
        lo = m.vertices.min(0)
        assert t.position[1] < lo[1] and t.position[2] <= lo[2] + 1e-6 and t.reference_point == "ct"
    # two columns: the third mesh starts a new row below the first
    ms = meshes_of(viewer.gallery([quad, quad, quad], columns=2))
    assert ms[2].vertices[:, 2].max() < ms[0].vertices[:, 2].min()
    assert ms[2].vertices[:, 0].min() == pytest.approx(ms[0].vertices[:, 0].min())
    with pytest.raises(ValueError):
        viewer.gallery([quad], labels=["a", "b"])


def screen(camera, points) -> np.ndarray:
    """Perspective screen coordinates (right, up) of k3d-frame points seen through a camera vector."""
    eye, target, up = np.array(camera[:3]), np.array(camera[3:6]), np.array(camera[6:])
    f = (target - eye) / np.linalg.norm(target - eye)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    p = np.asarray(points, np.float64) - eye
    depth = p @ f
    assert (depth > 0).all()  # in front of the camera
    return np.stack([p @ r / depth, p @ u / depth], axis=1)


def lowest_on_screen(corners2d: np.ndarray, x: float) -> float:
    """The lower edge of the convex hull of projected box corners at screen x (the min over segments crossing x)."""
    ys = []
    for i in range(len(corners2d)):
        for j in range(len(corners2d)):
            (x0, y0), (x1, y1) = corners2d[i], corners2d[j]
            if min(x0, x1) <= x <= max(x0, x1):
                ys.append(y0 if x1 == x0 else y0 + (y1 - y0) * (x - x0) / (x1 - x0))
    return min(ys) if ys else np.inf


def test_view_camera_looks_from_above_at_an_angle():
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([4.0, 2.0, 1.5])  # k3d frame: z is up
    cam = viewer.view_camera(lo, hi)
    eye, target = np.array(cam[:3]), np.array(cam[3:6])
    np.testing.assert_allclose(target, (lo + hi) / 2)
    assert eye[2] > hi[2]  # above the box top
    assert (eye < lo).any() or (eye > hi).any()  # outside the box
    assert eye[1] < lo[1]  # in front (k3d -y is the data's front, +z)
    elevation = np.degrees(np.arcsin((eye - target)[2] / np.linalg.norm(eye - target)))
    assert elevation == pytest.approx(viewer.VIEW[1]) and 35 <= elevation <= 75  # from above, not straight down
    # the whole box is in view: every corner within the field of view
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    d = (corners - eye) @ ((target - eye) / np.linalg.norm(target - eye))
    off = np.linalg.norm(corners - eye - np.outer(d, (target - eye) / np.linalg.norm(target - eye)), axis=1)
    assert (np.degrees(np.arctan2(off, d)) < 30).all()


def test_gallery_labels_do_not_overlap_the_meshes_on_screen():
    """From the saved page's default camera each label's anchor (its text hangs down from it) lies below every
    mesh's picture, not on it, and the meshes of two rows do not cover each other."""
    quad = textured_quad()
    big = trimesh.creation.box(extents=(2.0, 1.0, 1.0))
    plot = viewer.gallery([big, quad, big, quad], labels=["000", "001", "002", "003"], columns=2)
    cam = viewer.fit_camera(plot)
    boxes = [(m.vertices.min(0), m.vertices.max(0)) for m in meshes_of(plot)]
    texts = [o for o in plot.objects if isinstance(o, k3d.objects.Text)]
    for k, t in enumerate(texts):
        anchor = screen(cam, [t.position])[0]
        for lo, hi in boxes:
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            c2 = screen(cam, corners)
            inside_x = c2[:, 0].min() <= anchor[0] <= c2[:, 0].max()
            assert not inside_x or anchor[1] < lowest_on_screen(c2, anchor[0]) or anchor[1] > c2[:, 1].max(), k
    # rows: the second row's meshes lie wholly below the first row's on screen
    first = screen(cam, [c for lo, hi in boxes[:2] for c in (lo, hi, [lo[0], lo[1], hi[2]], [hi[0], hi[1], lo[2]])])
    second = screen(cam, [c for lo, hi in boxes[2:] for c in (lo, hi, [lo[0], lo[1], hi[2]], [hi[0], hi[1], lo[2]])])
    assert second[:, 1].max() < first[:, 1].min()


def hot_voxel_grid(shape=(4, 5, 6), at=(1, 2, 3)):
    sdf = np.zeros(shape, np.float32)
    sdf[at] = 1.0
    n = np.array(shape, float)
    aabb = np.concatenate([-n / n.max(), n / n.max()])
    lo, hi = aabb[:3], aabb[3:]
    center = lo + (np.array(at) + 0.5) / n * (hi - lo)
    return sdf, aabb, center


@pytest.mark.parametrize("up", ["y", "z"])
def test_volume_plot_places_voxels_right(up):
    sdf, aabb, center = hot_voxel_grid()
    plot = viewer.volume_plot(sdf, aabb, up=up)
    vol = [o for o in plot.objects if isinstance(o, k3d.objects.Volume)][0]
    iso = [o for o in plot.objects if isinstance(o, k3d.objects.MarchingCubes)][0]
    assert vol.volume.dtype == np.float32 and iso.scalar_field.dtype == np.float32 and iso.level == 0.0
    # find the hot voxel in k3d's [z, y, x] array and compute where k3d draws it
    idx_zyx = np.unravel_index(np.argmax(vol.volume), vol.volume.shape)
    n_xyz = np.array(vol.volume.shape[::-1], float)
    mm = np.asarray(vol.model_matrix)  # unit cube [-0.5, 0.5]^3 -> bounds
    unit = (np.array(idx_zyx[::-1]) + 0.5) / n_xyz - 0.5
    world = mm[:3, :3] @ unit + mm[:3, 3]
    np.testing.assert_allclose(world, viewer.to_view(center[None], up)[0], atol=1e-6)
    # marching cubes samples sit on the corners of its bounds: first / last voxel centres
    imm = np.asarray(iso.model_matrix)
    corner = imm[:3, :3] @ (np.array(idx_zyx[::-1]) / (n_xyz - 1) - 0.5) + imm[:3, 3]
    np.testing.assert_allclose(corner, viewer.to_view(center[None], up)[0], atol=1e-6)


def test_volume_plot_options_and_shapegrid_like():
    sdf, aabb, _ = hot_voxel_grid()

    class GridLike:
        pass

    g = GridLike()
    g.sdf, g.aabb = sdf - 0.5, aabb
    plot = viewer.volume_plot(g, volume=False)
    assert [type(o).__name__ for o in plot.objects] == ["MarchingCubes"]
    plot = viewer.volume_plot(sdf, isosurface=False, up="z")
    (vol,) = plot.objects
    np.testing.assert_array_equal(vol.volume, sdf.transpose(2, 1, 0))
    with pytest.raises(ValueError):
        viewer.volume_plot(sdf[0])


def test_points_plot():
    pts = np.random.default_rng(0).random((50, 3))
    plot = viewer.points_plot(pts, colors=np.ones((50, 3)), up="z", point_size=0.02)
    (p,) = plot.objects
    assert p.positions.dtype == np.float32 and p.colors.dtype == np.uint32
    np.testing.assert_allclose(p.positions, pts, rtol=1e-6)
    assert set(p.colors.tolist()) == {0xFFFFFF} and p.point_size == 0.02
    (p,) = viewer.points_plot(pts).objects
    np.testing.assert_allclose(p.positions, viewer.to_view(pts))
    with pytest.raises(ValueError):
        viewer.points_plot(pts, colors=np.ones((3, 3)))


def test_save_html_standalone_page(tmp_path):
    plot = viewer.mesh_plot(textured_quad(), name="my_quad")
    path = viewer.save_html(plot, tmp_path / "sub" / "quad.html")
    assert path.exists() and path.stat().st_size > 500_000  # k3d's JavaScript is embedded
    text = path.read_text()
    assert "k3dCompressed" in text and "CreateK3DAndLoadBinarySnapshot" in text
    assert [p.name for p in path.parent.iterdir()] == ["quad.html"]  # no temp file left behind
    snapshot = viewer.read_snapshot(path)
    (obj,) = snapshot["objects"]
    assert obj["type"] == "Mesh" and obj["name"] == "my_quad"
    np.testing.assert_array_equal(viewer.snapshot_array(obj, "vertices"), meshes_of(plot)[0].vertices)
    assert obj["texture_file_format"] == "png"
    # the page keeps the fitted camera (looking at the quad), the plot gets its auto-fit flag back
    assert snapshot["plot"]["cameraAutoFit"] is False and len(snapshot["plot"]["camera"]) == 9
    assert plot.camera_auto_fit is True
    cam = np.array(snapshot["plot"]["camera"])
    assert cam[1] < cam[4]  # the camera stands in front of the quad (k3d -y) looking towards +y
    assert cam[2] > meshes_of(plot)[0].vertices[:, 2].max()  # and above it
    # without WebGL the page says so instead of staying blank
    assert viewer.NO_WEBGL.split(",")[0] in text and "getContext('webgl')" in text
    assert text.index('id="sin3dm-no-webgl"') < text.index("CreateK3DAndLoadBinarySnapshot", text.index("<body"))


def test_index_page(tmp_path):
    page = viewer.save_html(viewer.mesh_plot(textured_quad()), tmp_path / "s0" / "viewer.html")
    (tmp_path / "s0" / "mesh.obj").write_text("v 0 0 0\n")
    entries = [
        {
            "title": "sample <0>",
            "html_path": page,
            "obj_path": tmp_path / "s0" / "mesh.obj",
            "glb_path": tmp_path / "s0" / "mesh.glb",
            "thumbnail": tmp_path / "s0" / "thumb.png",
        },
        {"title": "sample 1", "snapshot": viewer.points_plot(np.zeros((3, 3)))},
    ]
    index = viewer.index_page(entries, tmp_path / "index.html")
    text = index.read_text()
    assert text.startswith("<!doctype html>")
    assert 'href="s0/viewer.html"' in text and 'href="s0/mesh.obj" download' in text and 'href="s0/mesh.glb"' in text
    assert 'src="s0/thumb.png"' in text
    assert "sample &lt;0&gt;" in text  # titles are escaped
    assert (tmp_path / "sample_1.html").exists() and 'href="sample_1.html"' in text
    assert viewer.read_snapshot(tmp_path / "sample_1.html")["objects"][0]["type"] == "Points"

"""The built-in example shapes: valid, textured, deterministic, the right size."""

from functools import cache

import numpy as np
import pytest

from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.examples import DEFAULT_EXAMPLE, EXAMPLES, build_example, list_examples, write_example

NAMES = list_examples()


@cache
def built(name, seed=0):
    return build_example(name, seed)


def surface_colors(mesh, n=4000):
    _, fi, bc = mesh.surface_points(n, np.random.default_rng(0))
    return fi, bc, mesh.colors_at(fi, bc)


def test_catalogue():
    assert NAMES == list(EXAMPLES)
    assert len(NAMES) >= 3
    assert {"canyon", "wall"} <= set(NAMES)
    assert DEFAULT_EXAMPLE in NAMES
    assert all(isinstance(d, str) and d for d in EXAMPLES.values())


@pytest.mark.parametrize("name", NAMES)
def test_mesh_is_valid(name):
    m = built(name)
    assert m.name == name
    assert 2000 <= len(m.faces) <= 50_000
    assert m.vertices.dtype == np.float64 and m.vertices.shape[1] == 3
    assert m.faces.dtype == np.int64 and m.faces.shape[1] == 3
    assert m.faces.min() >= 0 and m.faces.max() < len(m.vertices)
    assert np.isfinite(m.vertices).all()
    assert np.array_equal(m.face_material, np.zeros(len(m.faces)))
    assert m.face_uvs.shape == (len(m.faces), 3, 2) and m.face_uvs.dtype == np.float32
    assert np.isfinite(m.face_uvs).all()
    assert m.face_uvs.min() >= 0 and m.face_uvs.max() <= 1
    (mat,) = m.materials
    np.testing.assert_array_equal(mat.base_color, [1, 1, 1, 1])
    img = mat.image
    assert img.dtype == np.float32 and img.ndim == 3 and img.shape[2] == 3 and min(img.shape[:2]) >= 256
    assert img.min() >= 0 and img.max() <= 1
    assert m.has_texture


@pytest.mark.parametrize("name", NAMES)
def test_closed_and_outward(name):
    """Each part is closed with outward normals, so a signed distance is well defined."""
    import trimesh

    tm = trimesh.Trimesh(built(name).vertices, built(name).faces, process=False)
    assert tm.is_watertight and tm.is_winding_consistent
    parts = tm.split(only_watertight=False)
    assert len(parts) >= 1 and all(part.volume > 0 for part in parts)  # an inside-out part has volume < 0


@pytest.mark.parametrize("name", NAMES)
def test_texture_shows_structure(name):
    m = built(name)
    assert m.materials[0].image.std() > 0.05
    fi, bc, col = surface_colors(m)
    assert col.std(0).mean() > 0.05
    # the texture holds detail finer than the triangles: interpolating the
    # colours at the three corners of each face misses it
    corners = np.stack([m.colors_at(fi, np.tile(np.eye(3)[k], (len(fi), 1))) for k in range(3)], 1)
    assert np.abs(col - np.einsum("nk,nkc->nc", bc, corners)).mean() > 0.02


@pytest.mark.parametrize("name", NAMES)
def test_proportions(name):
    extent = np.ptp(built(name).vertices, axis=0)
    assert extent.min() > 0
    assert extent.max() / extent.min() < 8


def test_wall_is_volumetric():
    lo, hi = built("wall").bounds
    length, thickness = hi[0] - lo[0], hi[2] - lo[2]  # y is up
    assert thickness >= 0.12 * length


@pytest.mark.parametrize("name", NAMES)
def test_deterministic_per_seed(name):
    a, b = built(name), build_example(name, 0)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.face_uvs, b.face_uvs)
    np.testing.assert_array_equal(a.materials[0].image, b.materials[0].image)
    c = built(name, 1)
    same_geometry = a.vertices.shape == c.vertices.shape and np.allclose(a.vertices, c.vertices)
    assert not same_geometry
    assert not np.array_equal(a.materials[0].image, c.materials[0].image)


def test_unknown_name():
    with pytest.raises(Sin3DMInputError, match="canyon"):
        build_example("no-such-shape")


def test_write_example_round_trip(tmp_path):
    from sin3dm_lite.formats.load import load_mesh

    path = write_example("colonnade", tmp_path)
    assert path == tmp_path / "colonnade.obj"
    assert all((tmp_path / f"colonnade{ext}").exists() for ext in (".obj", ".mtl", ".png"))
    m, back = built("colonnade"), load_mesh(path)
    assert back.faces.shape == m.faces.shape
    np.testing.assert_allclose(back.vertices, m.vertices, atol=1e-5)
    fi, bc, col = surface_colors(m, 1000)
    assert np.abs(back.colors_at(fi, bc) - col).mean() < 0.01

"""Tests of the mesh readers: sin3dm_lite.formats.load and formats/ (loaders, bad input, normalisation) and round trips through export's writers.

Every input is written on the fly into ``tmp_path`` (no binary fixtures).
The texture used throughout has four coloured quadrants so that a lookup can
be checked by eye: in UV space (v up) the top-left quadrant (u < .5, v > .5)
is red, top-right green, bottom-left blue, bottom-right yellow.
"""

from __future__ import annotations

import json
import struct
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from trimesh.visual.material import PBRMaterial

from sin3dm_lite import export
from sin3dm_lite.data.mesh import BOX_MARGIN, DEFAULT_COLOR, Material, TexturedMesh, sample_texture
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.formats.export import save_glb, save_obj, to_trimesh_scene
from sin3dm_lite.formats.images import image_to_array
from sin3dm_lite.formats.load import load_any, load_mesh

RED, GREEN, BLUE, YELLOW = (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0)
CYAN, MAGENTA = (0, 1, 1), (1, 0, 1)


# ------------------------------------------------------------------ helpers
def quadrant_image(tl=RED, tr=GREEN, bl=BLUE, br=YELLOW, size=16) -> np.ndarray:
    """uint8 (size, size, 3): row 0 is the top of the image (v = 1)."""
    h = size // 2
    img = np.zeros((size, size, 3), np.uint8)
    img[:h, :h], img[:h, h:], img[h:, :h], img[h:, h:] = (np.array(c) * 255 for c in (tl, tr, bl, br))
    return img


def save_png(path: Path, arr: np.ndarray) -> Path:
    Image.fromarray(arr).save(path)
    return path


# a unit square (two triangles, UVs covering the texture) plus a pyramid apex
# whose faces use an untextured material
SQUARE_OBJ = """\
# test
mtllib {mtl}
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0.5 0.5 1
vt 0 0
vt 1 0
vt 1 1
vt 0 1
usemtl textured
f 1/1 2/2 3/3
f 1/1 3/3 4/4
usemtl plain
f 1 2 5
f 2 3 5
f 3 4 5
f 4 1 5
"""

SQUARE_MTL = """\
newmtl textured
Kd 0.8 0.8 0.8
map_Kd {tex}

newmtl plain
Kd 0.2 0.4 0.6
"""

# barycentric points on the square: (face, bc, expected quadrant colour)
# face 0 corners have uv (0,0) (1,0) (1,1); face 1: (0,0) (1,1) (0,1)
LOOKUPS = [
    (0, (0.8, 0.1, 0.1), BLUE),  # uv (0.2, 0.1)
    (0, (0.1, 0.8, 0.1), YELLOW),  # uv (0.9, 0.1)
    (1, (0.1, 0.1, 0.8), RED),  # uv (0.1, 0.9)
    (1, (0.1, 0.8, 0.1), GREEN),  # uv (0.8, 0.9)
]


def write_square(folder: Path, tex: str = "tex.png", mtl: str = "square.mtl", image=True) -> Path:
    if image:
        save_png(folder / tex, quadrant_image())
    (folder / mtl).write_text(SQUARE_MTL.format(tex=tex))
    path = folder / "square.obj"
    path.write_text(SQUARE_OBJ.format(mtl=mtl))
    return path


def lookup(mesh: TexturedMesh, face: int, bc) -> np.ndarray:
    return mesh.colors_at(np.array([face]), np.array([bc], float))[0]


def textured_square_trimesh(material) -> trimesh.Trimesh:
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    return trimesh.Trimesh(v, f, visual=trimesh.visual.TextureVisuals(uv=uv, material=material), process=False)


def uint8(*rgba) -> np.ndarray:
    """trimesh reads a list of ints as 0..255 and floats as 0..1: be explicit."""
    return np.round(np.array(rgba, float) * 255).astype(np.uint8)


def random_bary(n: int, rng) -> np.ndarray:
    bc = rng.random((n, 3)) + 0.05
    return bc / bc.sum(1, keepdims=True)


# ======================================================================= OBJ
def test_obj_mtl_png_texture_lookup(tmp_path):
    mesh = load_mesh(write_square(tmp_path))
    assert mesh.name == "square"
    assert mesh.vertices.shape == (5, 3) and mesh.faces.shape == (6, 3)
    np.testing.assert_array_equal(mesh.faces[:2], [[0, 1, 2], [0, 2, 3]])
    assert [m.name for m in mesh.materials] == ["textured", "plain"]
    np.testing.assert_array_equal(mesh.face_material, [0, 0, 1, 1, 1, 1])
    tex = mesh.materials[0]
    assert tex.image.dtype == np.float32 and tex.image.shape == (16, 16, 3)
    np.testing.assert_allclose(tex.base_color[:3], 1.0)  # map_Kd replaces Kd
    assert mesh.has_texture
    for face, bc, expected in LOOKUPS:
        np.testing.assert_allclose(lookup(mesh, face, bc), expected, atol=1e-6)
    # the untextured material gives its Kd
    np.testing.assert_allclose(lookup(mesh, 3, (0.3, 0.3, 0.4)), (0.2, 0.4, 0.6), atol=1e-6)
    # UVs of the side faces are absent (NaN)
    assert np.isnan(mesh.face_uvs[2:]).all()
    assert mesh.normalization.scale == 1.0 and np.all(mesh.normalization.center == 0)


def test_obj_round_trip_through_save_obj(tmp_path):
    mesh = load_mesh(write_square(tmp_path))
    out = save_obj(mesh, tmp_path / "out" / "copy.obj")
    assert out == tmp_path / "out" / "copy.obj"
    names = sorted(p.name for p in out.parent.iterdir())
    assert names == ["copy.mtl", "copy.obj", "copy.png"]  # one textured material: <stem>.png
    text = out.read_text()
    assert "mtllib copy.mtl" in text and "f 1/1 2/2 3/3" in text and "f 1 2 5" in text
    assert text.count("\nvt ") == 4  # per-corner UVs deduplicated, no vertex splitting
    mtl = (out.parent / "copy.mtl").read_text()
    assert "map_Kd copy.png" in mtl and "Kd 0.200000 0.400000 0.600000" in mtl

    again = load_mesh(out)
    np.testing.assert_allclose(again.vertices, mesh.vertices)
    np.testing.assert_array_equal(again.faces, mesh.faces)
    np.testing.assert_array_equal(again.face_material, mesh.face_material)
    np.testing.assert_allclose(again.face_uvs, mesh.face_uvs, equal_nan=True)
    rng = np.random.default_rng(0)
    fi = rng.integers(0, len(mesh.faces), 200)
    bc = random_bary(200, rng)
    np.testing.assert_allclose(again.colors_at(fi, bc), mesh.colors_at(fi, bc), atol=1 / 255)


def test_obj_factor_is_baked_into_written_texture(tmp_path):
    img = quadrant_image().astype(np.float32) / 255
    mesh = TexturedMesh(
        vertices=np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0]], float),
        faces=np.array([[0, 1, 2]]),
        face_material=np.array([0]),
        materials=[Material(name="half", base_color=np.array([0.5, 1, 1, 1], np.float32), image=img)],
        face_uvs=np.array([[[0, 0], [1, 0], [1, 1]]], np.float32),
    )
    again = load_mesh(save_obj(mesh, tmp_path / "h.obj"))
    bc = np.array([[0.1, 0.8, 0.1], [0.8, 0.1, 0.1]])
    np.testing.assert_allclose(again.colors_at([0, 0], bc), mesh.colors_at([0, 0], bc), atol=1 / 255)
    np.testing.assert_allclose(again.colors_at([0], bc[:1])[0], (0.5, 1, 0), atol=1 / 255)


def test_multi_material_obj_uses_every_texture(tmp_path):
    save_png(tmp_path / "a.png", quadrant_image())
    save_png(tmp_path / "b.png", quadrant_image(CYAN, MAGENTA, MAGENTA, CYAN))
    (tmp_path / "two.mtl").write_text("newmtl A\nmap_Kd a.png\nnewmtl B\nKd 1 1 1\nmap_Kd b.png\n")
    (tmp_path / "two.obj").write_text(
        "mtllib two.mtl\n"
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.25 0.25\n"
        "usemtl A\nf 1/1 2/2 3/3\n"
        # the second face shares vertices 2 and 3 but has its own UVs there
        "usemtl B\nf 2/5 5/2 6/3\n"
        "usemtl A\nf 1/1 3/3 4/4\n"
    )
    mesh = load_mesh(tmp_path / "two.obj")
    assert [m.name for m in mesh.materials] == ["A", "B"]
    assert all(m.image is not None for m in mesh.materials)
    np.testing.assert_array_equal(mesh.face_material, [0, 1, 0])
    assert len(mesh.vertices) == 6  # no splitting at the seam
    np.testing.assert_allclose(mesh.face_uvs[1], [[0.25, 0.25], [1, 0], [1, 1]])
    np.testing.assert_allclose(lookup(mesh, 0, (0.1, 0.8, 0.1)), YELLOW, atol=1e-6)
    np.testing.assert_allclose(lookup(mesh, 1, (0.1, 0.8, 0.1)), CYAN, atol=1e-6)  # b.png bottom-right
    np.testing.assert_allclose(lookup(mesh, 1, (0.9, 0.05, 0.05)), MAGENTA, atol=1e-6)  # b.png bottom-left

    out = save_obj(mesh, tmp_path / "w" / "two_out.obj")
    assert sorted(p.name for p in out.parent.iterdir()) == [
        "two_out.mtl",
        "two_out.obj",
        "two_out_0.png",
        "two_out_1.png",
    ]
    again = load_mesh(out)
    np.testing.assert_array_equal(again.face_material, [0, 1, 0])
    bc = np.full((3, 3), 1 / 3)
    np.testing.assert_allclose(again.colors_at([0, 1, 2], bc), mesh.colors_at([0, 1, 2], bc), atol=1 / 255)
    # two materials showing one atlas: one PNG, named by both
    mesh.materials[1].image = mesh.materials[0].image
    out = save_obj(mesh, tmp_path / "shared" / "s.obj")
    assert sorted(p.name for p in out.parent.iterdir()) == ["s.mtl", "s.obj", "s_0.png"]
    assert (out.parent / "s.mtl").read_text().count("map_Kd s_0.png") == 2


def test_obj_without_mtl_gets_default_color(tmp_path):
    p = tmp_path / "plain.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    mesh = load_mesh(p)
    assert len(mesh.materials) == 1 and mesh.face_uvs is None and mesh.vertex_colors is None
    assert not mesh.has_texture
    np.testing.assert_allclose(lookup(mesh, 0, (1 / 3, 1 / 3, 1 / 3)), DEFAULT_COLOR)


def test_obj_with_vertex_colors(tmp_path):
    p = tmp_path / "vc.obj"
    p.write_text("v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nv 0 0 1 1 1 1\nf 1 2 3\nf 1 2 4\n")
    mesh = load_mesh(p)
    np.testing.assert_allclose(mesh.vertex_colors, [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
    np.testing.assert_allclose(lookup(mesh, 0, (1, 0, 0)), RED)
    np.testing.assert_allclose(lookup(mesh, 0, (0.5, 0.5, 0)), (0.5, 0.5, 0))
    again = load_mesh(save_obj(mesh, tmp_path / "o" / "vc2.obj"))
    np.testing.assert_allclose(again.vertex_colors, mesh.vertex_colors, atol=1e-6)
    np.testing.assert_allclose(again.vertices, mesh.vertices)


def test_obj_vertex_colors_0_255_and_partial(tmp_path):
    p = tmp_path / "vc255.obj"
    p.write_text("v 0 0 0 255 0 0\nv 1 0 0 0 255 0\nv 0 1 0\nf 1 2 3\n")
    mesh = load_mesh(p)
    np.testing.assert_allclose(mesh.vertex_colors, [[1, 0, 0], [0, 1, 0], [1, 1, 1]])


def test_obj_dialects(tmp_path):
    """Quads and n-gons, negative indices, v//vn, texture options, Windows paths, CRLF, Tr."""
    sub = tmp_path / "textures"
    sub.mkdir()
    save_png(sub / "Tex File.png", quadrant_image())
    (tmp_path / "d.mtl").write_text(
        "newmtl m\r\nKd 0.1 0.1 0.1\r\nmap_Kd -s 1 1 1 -o 0 0 0 textures\\Tex File.png\r\n"
        "newmtl n\r\nKd 0.5 0.5 0.5\r\nTr 0.25\r\n"
    )
    (tmp_path / "d.obj").write_text(
        "mtllib d.mtl\r\n"
        "v 0 0 0\r\nv 1 0 0\r\nv 1 1 0\r\nv 0 1 0\r\nv 0 0 1\r\n"
        "vt 0 0\r\nvt 1 0\r\nvt 1 1\r\nvt 0 1\r\nvn 0 0 1\r\n"
        "g group\r\ns off\r\nusemtl m\r\nf -5/-4/1 -4/-3/1 -3/-2/1 -2/-1/1\r\n"
        "usemtl n\r\nf 1//1 2//1 5//1\r\nl 1 2\r\n"
    )
    mesh = load_mesh(tmp_path / "d.obj")
    assert len(mesh.faces) == 3  # the quad was fan-triangulated; the line ignored
    np.testing.assert_array_equal(mesh.faces[:2], [[0, 1, 2], [0, 2, 3]])
    assert mesh.materials[0].image is not None
    np.testing.assert_allclose(lookup(mesh, 1, (0.1, 0.1, 0.8)), RED, atol=1e-6)
    assert mesh.materials[1].base_color[3] == pytest.approx(0.75)


def test_obj_face_lines_of_different_lengths(tmp_path):
    """A 2-index line (dropped) and a quad: 6 indices on 2 lines must not be read as two triangles."""
    (tmp_path / "mix.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2\nf 1 2 3 4\n")
    mesh = load_mesh(tmp_path / "mix.obj")
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3]])  # the quad, fan-triangulated


def test_obj_faces_polygons_and_triangles_read_alike(tmp_path):
    """Polygons go through the same index checks as triangles: vt 0 means no uv, the first bad line is named."""
    (tmp_path / "vt0.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nf 1/0 2/0 3/0 4/0\nf 1/1 2/0 4/1\n")
    mesh = load_mesh(tmp_path / "vt0.obj")
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3], [0, 1, 3]])
    assert np.isnan(mesh.face_uvs[:2]).all() and np.isnan(mesh.face_uvs[2, 1]).all()
    np.testing.assert_array_equal(mesh.face_uvs[2, [0, 2]], 0)
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\nf 1 -9 3 4\nf 1 2 x 4\n")
    with pytest.raises(Sin3DMInputError, match="line 6: bad face 'f 1 -9 3 4'"):
        load_mesh(tmp_path / "bad.obj")


def test_obj_uv_scale_option(tmp_path):
    save_png(tmp_path / "t.png", quadrant_image())
    (tmp_path / "s.mtl").write_text("newmtl m\nmap_Kd -s 0.5 0.5 t.png\n")
    (tmp_path / "s.obj").write_text(
        "mtllib s.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 1\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3\n"
    )
    mesh = load_mesh(tmp_path / "s.obj")
    np.testing.assert_allclose(mesh.face_uvs[0], [[0, 0], [0.5, 0], [0, 0.5]])


def test_obj_reader_keeps_what_trimesh_loses(tmp_path):
    """Why ``load_mesh`` parses OBJ/MTL itself instead of using ``trimesh.load`` (checked with trimesh 4.x/5.x).

    trimesh (1) returns the faces grouped by material, so interleaved ``usemtl`` runs lose the
    file's face order (with ``group_material=False, maintain_order=True`` a run even gets another
    run's face), (2) silently drops a ``map_Kd`` that has options (``-s 0.5 0.5 b.png``): the
    texture is lost, not just its scale, and (3) says nothing about a missing texture. It also
    decodes the textures of unused materials, crashes on partial vertex colours and names no line
    in its errors (see the other OBJ tests). This test fails if ``load_mesh`` hands OBJ to trimesh.
    """
    save_png(tmp_path / "a.png", quadrant_image())
    save_png(tmp_path / "b.png", quadrant_image(CYAN, MAGENTA, MAGENTA, CYAN))
    (tmp_path / "m.mtl").write_text(
        "newmtl A\nmap_Kd a.png\nnewmtl B\nmap_Kd -s 0.5 0.5 b.png\nnewmtl C\nKd 0 1 0\nmap_Kd gone.png\n"
    )
    (tmp_path / "m.obj").write_text(
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "usemtl A\nf 1/1 2/2 3/3\nusemtl B\nf 2/1 5/2 6/3\nusemtl A\nf 1/1 3/3 4/4\nusemtl C\nf 3 6 4\n"
    )
    with pytest.warns(UserWarning, match="gone.png"):  # (3)
        mesh = load_mesh(tmp_path / "m.obj")
    assert [m.name for m in mesh.materials] == ["A", "B", "C"]
    np.testing.assert_array_equal(mesh.face_material, [0, 1, 0, 2])  # (1) the file's face order
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [1, 4, 5], [0, 2, 3], [2, 5, 3]])
    assert mesh.materials[1].image is not None  # (2) the texture with options is kept ...
    np.testing.assert_allclose(mesh.face_uvs[1], [[0, 0], [0.5, 0], [0.5, 0.5]])  # ... and so is its scale
    np.testing.assert_allclose(lookup(mesh, 1, (0.8, 0.1, 0.1)), MAGENTA, atol=1e-6)  # b.png at uv (0.1, 0.05)
    np.testing.assert_allclose(lookup(mesh, 3, (1 / 3, 1 / 3, 1 / 3)), (0, 1, 0))  # C falls back to its Kd


def test_obj_writer_keeps_what_trimesh_loses(tmp_path):
    """Why ``save_obj`` writes OBJ/MTL itself instead of using trimesh's OBJ exporter (checked with trimesh 5.x).

    Exporting the same content with trimesh (the per-material scene that ``save_glb`` writes, as
    ``trimesh.load(...).export('x.obj')``) (1) groups the faces by material, so interleaved runs
    lose the mesh's face order, and (2) writes no ``Pr``/``Pm`` factors and no ``map_Pr``/
    ``map_Pm``/``map_Bump``: the PBR maps are lost. ``save_obj`` keeps both (this test fails with
    trimesh's exporter).
    """
    rng = np.random.default_rng(5)
    mr, normal = rng.random((8, 8, 3)).astype(np.float32), rng.random((8, 8, 3)).astype(np.float32)
    mesh = TexturedMesh(
        vertices=np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]], float),
        faces=np.array([[0, 1, 2], [1, 4, 2], [0, 2, 3]]),
        face_material=np.array([0, 1, 0]),
        materials=[
            Material(
                name="A",
                image=quadrant_image().astype(np.float32) / 255,
                metallic=1.0,
                roughness=1.0,
                metallic_roughness_image=mr,
                normal_image=normal,
            ),
            Material(name="B", base_color=np.array([0.2, 0.4, 0.6, 1], np.float32)),
        ],
        face_uvs=rng.random((3, 3, 2)).astype(np.float32),
    )
    (tmp_path / "t").mkdir()
    trimesh.load(save_glb(mesh, tmp_path / "g" / "m.glb"), force="scene").export(tmp_path / "t" / "m.obj")
    theirs = "".join(f.read_text() for f in sorted((tmp_path / "t").glob("*.[om][bt][jl]")))
    assert theirs.count("usemtl") == 2 and "map_Pr" not in theirs and "map_Bump" not in theirs  # trimesh's loss
    again = load_mesh(save_obj(mesh, tmp_path / "o" / "m.obj"))
    np.testing.assert_array_equal(again.face_material, [0, 1, 0])  # (1) the mesh's face order
    np.testing.assert_array_equal(again.faces, mesh.faces)
    a = again.materials[0]  # (2) the PBR maps and factors
    np.testing.assert_allclose(a.metallic_roughness_image[..., 1:], mr[..., 1:], atol=1 / 255)
    np.testing.assert_allclose(a.normal_image, normal, atol=1 / 255)
    assert a.metallic == 1.0 and a.roughness == 1.0
    np.testing.assert_allclose(again.materials[1].base_color, [0.2, 0.4, 0.6, 1], atol=1e-6)


# ====================================================================== glTF
def test_glb_base_color_texture_and_factor(tmp_path):
    mat = PBRMaterial(
        name="quad",
        baseColorTexture=Image.fromarray(quadrant_image()),
        baseColorFactor=uint8(0.5, 1, 1, 1),
        metallicFactor=0.0,
        roughnessFactor=0.5,
    )
    textured_square_trimesh(mat).export(tmp_path / "sq.glb")
    mesh = load_mesh(tmp_path / "sq.glb")
    assert mesh.name == "sq" and len(mesh.materials) == 1
    m = mesh.materials[0]
    assert m.name == "quad" and m.image.shape == (16, 16, 3)
    np.testing.assert_allclose(m.base_color, (128 / 255, 1, 1, 1), atol=1e-6)  # factor quantised by trimesh
    assert m.metallic == 0.0 and m.roughness == 0.5
    assert len(mesh.vertices) == 4  # welded
    for face, bc, expected in LOOKUPS:
        np.testing.assert_allclose(lookup(mesh, face, bc), np.array(expected) * (128 / 255, 1, 1), atol=1e-6)

    # save_glb → load_mesh and trimesh both see the texture and the UVs
    out = save_glb(mesh, tmp_path / "o" / "sq2.glb")
    again = load_mesh(out)
    np.testing.assert_allclose(again.vertices, mesh.vertices)
    rng = np.random.default_rng(1)
    fi, bc = rng.integers(0, 2, 100), random_bary(100, rng)
    np.testing.assert_allclose(again.colors_at(fi, bc), mesh.colors_at(fi, bc), atol=1 / 255)
    tm = trimesh.load(out, force="scene")
    (geom,) = tm.geometry.values()
    assert isinstance(geom.visual, trimesh.visual.TextureVisuals) and geom.visual.uv.shape == (4, 2)
    assert geom.visual.material.baseColorTexture.size == (16, 16)


def _glb_unpacked(glb: bytes) -> tuple[dict, bytes]:
    n = struct.unpack_from("<I", glb, 12)[0]
    return json.loads(glb[20 : 20 + n]), glb[28 + n :]


def _glb_packed(head: dict, binary: bytes) -> bytes:
    binary += b"\0" * (-len(binary) % 4)
    head["buffers"][0]["byteLength"] = len(binary)
    text = json.dumps(head).encode()
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<I", len(text)) + b"JSON" + text + struct.pack("<I", len(binary)) + b"BIN\0" + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def _glb_view(head: dict, binary: bytes, data: bytes) -> tuple[int, bytes]:
    """``data`` appended to the GLB's binary chunk as a new buffer view: its index and the new chunk."""
    binary += b"\0" * (-len(binary) % 4)
    head["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(data)})
    return len(head["bufferViews"]) - 1, binary + data


def _with_uvs(glb: bytes, raw_uv: np.ndarray, dtype, transform: dict | None) -> bytes:
    """``glb`` with its texture coordinates replaced by ``raw_uv`` (glTF's, v down) stored as ``dtype`` (an integer
    type: normalized, as KHR_mesh_quantization stores them) and its base colour texture moved by ``transform``."""
    head, binary = _glb_unpacked(glb)
    data = (raw_uv * (np.iinfo(dtype).max if np.dtype(dtype).kind == "u" else 1)).round(6).astype(dtype).tobytes()
    view, binary = _glb_view(head, binary, data)
    kind = {np.uint16: 5123, np.float32: 5126}[dtype]
    accessor = {"bufferView": view, "componentType": kind, "count": len(raw_uv), "type": "VEC2"}
    head["accessors"].append({**accessor, "normalized": True} if kind != 5126 else accessor)
    head["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = len(head["accessors"]) - 1
    head["extensionsUsed"] = head["extensionsRequired"] = ["KHR_mesh_quantization", "KHR_texture_transform"]
    head["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] = {
        "KHR_texture_transform": transform
    }
    return _glb_packed(head, binary)


def test_a_glb_with_quantized_and_transformed_uvs_reads_the_colours_of_its_plain_twin(tmp_path):
    """gltfpack's default output stores texture coordinates as 16-bit integers read as [0, 1] (KHR_mesh_quantization)
    and a KHR_texture_transform that maps them back to their range; trimesh reads neither (UVs up to 65,535). The
    loader rewrites the file first: the same colours as the plain file's. A rotated transform too, whose matrix is
    the specification's (offset · rotation · scale)."""
    square = textured_square_trimesh(PBRMaterial(baseColorTexture=Image.fromarray(quadrant_image())))
    square.visual.uv = np.array([[0.2, 0.1], [0.7, 0.1], [0.7, 0.6], [0.2, 0.6]])
    (tmp_path / "plain.glb").write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Scene(square)))
    plain = load_mesh(tmp_path / "plain.glb")
    raw = np.c_[square.visual.uv[:, 0], 1 - square.visual.uv[:, 1]]  # as glTF stores them: v down
    lo, hi = raw.min(0), raw.max(0)
    glb = (tmp_path / "plain.glb").read_bytes()
    (tmp_path / "packed.glb").write_bytes(
        _with_uvs(glb, (raw - lo) / (hi - lo), np.uint16, {"offset": lo.tolist(), "scale": (hi - lo).tolist()})
    )
    r, offset, scale = 0.3, np.array([0.1, 0.05]), np.array([0.8, 1.2])
    turn = np.array([[np.cos(r), np.sin(r)], [-np.sin(r), np.cos(r)]])  # the specification's rotation
    stored = np.linalg.solve(turn, (raw - offset).T).T / scale
    transform = {"offset": offset.tolist(), "rotation": r, "scale": scale.tolist()}
    (tmp_path / "turned.glb").write_bytes(_with_uvs(glb, stored, np.float32, transform))
    rng = np.random.default_rng(0)
    fi, bc = rng.integers(0, 2, 200), random_bary(200, rng)
    for name in ("packed.glb", "turned.glb"):
        mesh = load_mesh(tmp_path / name)
        np.testing.assert_allclose(mesh.colors_at(fi, bc), plain.colors_at(fi, bc), atol=2e-3)
    assert np.ptp(plain.colors_at(fi, bc), axis=0).max() > 0.5  # the square spans more than one colour


def test_a_texture_on_the_second_coordinate_set_reads_its_colours(tmp_path):
    """glTF lets a texture name its coordinate set (``texCoord``); trimesh reads TEXCOORD_0 only. A square whose base
    colour uses TEXCOORD_1, TEXCOORD_0 being another mapping (here all one point), reads the plain file's colours."""
    square = textured_square_trimesh(PBRMaterial(baseColorTexture=Image.fromarray(quadrant_image())))
    glb = trimesh.exchange.gltf.export_glb(trimesh.Scene(square))
    (tmp_path / "plain.glb").write_bytes(glb)
    head, binary = _glb_unpacked(glb)
    attributes = head["meshes"][0]["primitives"][0]["attributes"]
    view, binary = _glb_view(head, binary, np.full((4, 2), 0.9, np.float32).tobytes())
    head["accessors"].append({"bufferView": view, "componentType": 5126, "count": 4, "type": "VEC2"})
    attributes["TEXCOORD_1"], attributes["TEXCOORD_0"] = attributes["TEXCOORD_0"], len(head["accessors"]) - 1
    head["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["texCoord"] = 1
    (tmp_path / "second.glb").write_bytes(_glb_packed(head, binary))
    rng = np.random.default_rng(0)
    fi, bc = rng.integers(0, 2, 100), random_bary(100, rng)
    plain, second = load_mesh(tmp_path / "plain.glb"), load_mesh(tmp_path / "second.glb")
    np.testing.assert_allclose(second.colors_at(fi, bc), plain.colors_at(fi, bc), atol=1e-6)


@pytest.mark.parametrize("fallback", [True, False])
def test_a_ktx2_texture_is_read_from_its_png_fallback_or_said_once(tmp_path, fallback):
    """A texture of KHR_texture_basisu names a KTX2 image trimesh cannot decode and, usually, a PNG it reads instead:
    no warning then; without the PNG, one line that names the format and what to export."""
    square = textured_square_trimesh(PBRMaterial(name="m", baseColorTexture=Image.fromarray(quadrant_image())))
    head, binary = _glb_unpacked(trimesh.exchange.gltf.export_glb(trimesh.Scene(square)))
    view, binary = _glb_view(head, binary, b"\xabKTX 20\xbb\r\n\x1a\n" + bytes(64))
    head["images"].append({"bufferView": view, "mimeType": "image/ktx2"})
    texture = head["textures"][0]
    texture["extensions"] = {"KHR_texture_basisu": {"source": len(head["images"]) - 1}}
    if not fallback:
        del texture["source"]
    head["extensionsUsed"] = ["KHR_texture_basisu"]
    (tmp_path / "k.glb").write_bytes(_glb_packed(head, binary))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mesh = load_mesh(tmp_path / "k.glb")
    said = [str(w.message) for w in caught if "KTX2" in str(w.message)]
    if fallback:
        assert [str(w.message) for w in caught] == [] and mesh.materials[0].image is not None
        np.testing.assert_allclose(lookup(mesh, 0, (0.8, 0.1, 0.1)), BLUE, atol=1e-6)
    else:
        assert len(said) == 1 and "baseColorTexture of material 'm'" in said[0] and "PNG or JPEG" in said[0]
        assert mesh.materials[0].image is None


def test_glb_keeps_pbr_maps(tmp_path):
    mr = np.zeros((8, 8, 3), np.uint8)
    mr[..., 1], mr[..., 2] = 128, 255  # roughness .5, metallic 1
    normal = np.zeros((8, 8, 3), np.uint8)
    normal[:] = (128, 128, 255)
    mat = PBRMaterial(
        name="pbr",
        baseColorTexture=Image.fromarray(quadrant_image()),
        metallicFactor=0.3,
        roughnessFactor=0.6,
        metallicRoughnessTexture=Image.fromarray(mr),
        normalTexture=Image.fromarray(normal),
    )
    textured_square_trimesh(mat).export(tmp_path / "pbr.glb")
    m = load_mesh(tmp_path / "pbr.glb").materials[0]
    assert m.metallic == pytest.approx(0.3) and m.roughness == pytest.approx(0.6)
    assert m.metallic_roughness_image.shape == (8, 8, 3) and m.metallic_roughness_image.dtype == np.float32
    np.testing.assert_allclose(m.metallic_roughness_image[0, 0], (0, 128 / 255, 1), atol=1e-6)
    np.testing.assert_allclose(m.normal_image[0, 0], (128 / 255, 128 / 255, 1), atol=1e-6)

    # and save_glb writes them back
    mesh = load_mesh(tmp_path / "pbr.glb")
    m2 = load_mesh(save_glb(mesh, tmp_path / "pbr2.glb")).materials[0]
    np.testing.assert_allclose(m2.metallic_roughness_image, m.metallic_roughness_image, atol=1e-6)
    np.testing.assert_allclose(m2.normal_image, m.normal_image, atol=1e-6)
    assert m2.metallic == pytest.approx(0.3) and m2.roughness == pytest.approx(0.6)


def test_gltf_defaults_for_absent_pbr_factors(tmp_path):
    # glTF: an absent metallicFactor / roughnessFactor means 1.0
    mat = PBRMaterial(name="f", baseColorFactor=uint8(0.2, 0.4, 0.6, 1.0))
    textured_square_trimesh(mat).export(tmp_path / "f.glb")
    m = load_mesh(tmp_path / "f.glb").materials[0]
    assert m.metallic == 1.0 and m.roughness == 1.0 and m.image is None
    np.testing.assert_allclose(m.base_color[:3], (0.2, 0.4, 0.6), atol=1 / 255)


def _two_object_scene():
    red = PBRMaterial(name="red", baseColorFactor=uint8(1, 0, 0, 1), metallicFactor=0.0)
    quad = PBRMaterial(name="quad", baseColorTexture=Image.fromarray(quadrant_image()), metallicFactor=0.0)
    box = trimesh.creation.box(extents=(1, 1, 1))
    box.visual = trimesh.visual.TextureVisuals(material=red)
    scene = trimesh.Scene()
    scene.add_geometry(box, node_name="box", geom_name="box")
    scene.add_geometry(
        textured_square_trimesh(quad),
        node_name="square",
        geom_name="square",
        transform=trimesh.transformations.translation_matrix((10, 0, 0)),
    )
    return scene


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_multi_object_scene_applies_node_transforms(tmp_path, ext):
    scene = _two_object_scene()
    if ext == ".glb":
        scene.export(tmp_path / "scene.glb")
    else:
        for name, blob in scene.export(file_type="gltf").items():
            (tmp_path / ("scene.gltf" if name.endswith(".gltf") else name)).write_bytes(blob)
    mesh = load_mesh(tmp_path / f"scene{ext}")
    names = sorted(m.name for m in mesh.materials)
    assert names == ["quad", "red"]
    assert len(mesh.faces) == 12 + 2
    np.testing.assert_allclose(mesh.bounds, [[-0.5, -0.5, -0.5], [11, 1, 0.5]])
    quad_faces = np.flatnonzero([mesh.materials[i].name == "quad" for i in mesh.face_material])
    red_faces = np.flatnonzero([mesh.materials[i].name == "red" for i in mesh.face_material])
    assert len(quad_faces) == 2 and len(red_faces) == 12
    assert mesh.vertices[np.unique(mesh.faces[quad_faces])][:, 0].min() == pytest.approx(10)
    np.testing.assert_allclose(lookup(mesh, red_faces[0], (1 / 3, 1 / 3, 1 / 3)), RED)
    colors = mesh.colors_at(quad_faces.repeat(2), np.array([(0.8, 0.1, 0.1), (0.1, 0.8, 0.1)] * 2))
    assert {tuple(np.round(c).astype(int)) for c in colors} <= {BLUE, YELLOW, RED, GREEN}


def _glb_with_json(glb: bytes, edit) -> bytes:
    n, _ = struct.unpack_from("<II", glb, 12)
    header = json.loads(glb[20 : 20 + n])
    edit(header)
    js = json.dumps(header).encode()
    js += b" " * (-len(js) % 4)
    rest = glb[20 + n :]
    return (
        struct.pack("<4sII", b"glTF", 2, 20 + len(js) + len(rest)) + struct.pack("<II", len(js), 0x4E4F534A) + js + rest
    )


def test_multi_primitive_mesh(tmp_path):
    a = trimesh.creation.box(extents=(1, 1, 1))
    a.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(name="r", baseColorFactor=uint8(1, 0, 0, 1)))
    b = trimesh.creation.box(extents=(1, 1, 1))
    b.apply_translation((0, 0, 2))
    b.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(name="g", baseColorFactor=uint8(0, 1, 0, 1)))
    scene = trimesh.Scene()
    scene.add_geometry(a, geom_name="a")
    scene.add_geometry(b, geom_name="b")

    def merge(h):  # one glTF mesh with two primitives on one translated node
        h["meshes"] = [{"primitives": h["meshes"][0]["primitives"] + h["meshes"][1]["primitives"]}]
        h["nodes"] = [{"name": "both", "mesh": 0, "translation": [0, 5, 0]}]
        h["scenes"] = [{"nodes": [0]}]
        h["scene"] = 0

    (tmp_path / "prims.glb").write_bytes(_glb_with_json(scene.export(file_type="glb"), merge))
    mesh = load_mesh(tmp_path / "prims.glb")
    assert sorted(m.name for m in mesh.materials) == ["g", "r"]
    assert len(mesh.faces) == 24
    np.testing.assert_allclose(mesh.bounds, [[-0.5, 4.5, -0.5], [0.5, 5.5, 2.5]])


def test_gltf_missing_external_texture_warns(tmp_path):
    mat = PBRMaterial(
        name="quad", baseColorTexture=Image.fromarray(quadrant_image()), baseColorFactor=uint8(0.2, 0.4, 0.6, 1)
    )
    files = trimesh.Scene(textured_square_trimesh(mat)).export(file_type="gltf")
    header = json.loads(files["model.gltf"])
    header["images"] = [{"uri": "gone.png"}]  # point the image at a file that does not exist
    (tmp_path / "m.gltf").write_text(json.dumps(header))
    for name, blob in files.items():
        if name.endswith(".bin"):
            (tmp_path / name).write_bytes(blob)
    with pytest.warns(UserWarning, match="gone.png"):
        mesh = load_mesh(tmp_path / "m.gltf")
    assert mesh.materials[0].image is None
    np.testing.assert_allclose(lookup(mesh, 0, (1 / 3, 1 / 3, 1 / 3)), (0.2, 0.4, 0.6), atol=1 / 255)


def test_glb_corrupt_embedded_texture_warns(tmp_path):
    mat = PBRMaterial(
        name="quad", baseColorTexture=Image.fromarray(quadrant_image()), baseColorFactor=uint8(0.2, 0.4, 0.6, 1)
    )
    glb = bytearray(textured_square_trimesh(mat).export(file_type="glb"))
    n, _ = struct.unpack_from("<II", glb, 12)
    header = json.loads(glb[20 : 20 + n])
    view = header["bufferViews"][header["images"][0]["bufferView"]]
    start = 20 + n + 8 + view.get("byteOffset", 0)
    glb[start : start + view["byteLength"]] = b"\x01" * view["byteLength"]  # overwrite the PNG bytes
    (tmp_path / "bad_tex.glb").write_bytes(bytes(glb))
    with pytest.warns(UserWarning, match="bad_tex.glb.*baseColorTexture.*unreadable"):
        mesh = load_mesh(tmp_path / "bad_tex.glb")
    assert mesh.materials[0].image is None
    np.testing.assert_allclose(lookup(mesh, 0, (1 / 3, 1 / 3, 1 / 3)), (0.2, 0.4, 0.6), atol=1 / 255)


def test_glb_vertex_colors_and_save_glb_multi_material(tmp_path):
    box = trimesh.creation.box(extents=(2, 1, 1))
    cols = np.zeros((8, 4), np.uint8)
    cols[:, 0] = np.arange(8) * 30
    cols[:, 3] = 255
    box.visual.vertex_colors = cols
    box.export(tmp_path / "vc.glb")
    mesh = load_mesh(tmp_path / "vc.glb")
    np.testing.assert_allclose(mesh.vertex_colors[:, 0], np.arange(8) * 30 / 255, atol=1e-6)

    # a two-material mesh: textured square + vertex-coloured box
    sq = load_mesh(write_square(tmp_path))
    out = save_glb(sq, tmp_path / "o" / "sq.glb")
    again = load_mesh(out)
    assert sorted(m.name for m in again.materials) == ["plain", "textured"]
    rng = np.random.default_rng(2)
    fi, bc = rng.integers(0, len(sq.faces), 100), random_bary(100, rng)
    # faces may be reordered (one primitive per material): compare by face position
    order = [
        np.flatnonzero(np.all(np.isclose(again.vertices[again.faces].mean(1), c), axis=1))[0]
        for c in sq.vertices[sq.faces].mean(1)
    ]
    np.testing.assert_allclose(again.colors_at(np.asarray(order)[fi], bc), sq.colors_at(fi, bc), atol=1 / 255)
    assert len(trimesh.load(out, force="scene").geometry) == 2


# ======================================================================= PLY
def test_ply_with_and_without_vertex_colors(tmp_path):
    box = trimesh.creation.box(extents=(1, 2, 3))
    box.export(tmp_path / "plain.ply")
    mesh = load_mesh(tmp_path / "plain.ply")
    assert mesh.vertex_colors is None and len(mesh.faces) == 12
    np.testing.assert_allclose(mesh.bounds, [[-0.5, -1, -1.5], [0.5, 1, 1.5]])
    np.testing.assert_allclose(lookup(mesh, 0, (1 / 3, 1 / 3, 1 / 3)), DEFAULT_COLOR)

    cols = np.full((8, 4), 255, np.uint8)
    cols[:, :3] = np.arange(24).reshape(8, 3) * 10
    box.visual.vertex_colors = cols
    box.export(tmp_path / "col.ply", encoding="ascii")
    mesh = load_mesh(tmp_path / "col.ply")
    np.testing.assert_allclose(mesh.vertex_colors, cols[:, :3] / 255, atol=1e-6)
    f0 = mesh.faces[0]
    np.testing.assert_allclose(lookup(mesh, 0, (1, 0, 0)), cols[f0[0], :3] / 255, atol=1e-6)


def test_ply_face_colors(tmp_path):
    box = trimesh.creation.box()
    fc = np.tile([[255, 0, 0, 255], [0, 0, 255, 255]], (6, 1)).astype(np.uint8)
    box.visual.face_colors = fc
    box.export(tmp_path / "fc.ply")
    mesh = load_mesh(tmp_path / "fc.ply")
    cols = mesh.colors_at(np.arange(12), np.full((12, 3), 1 / 3))
    np.testing.assert_allclose(cols, fc[:, :3] / 255)


def test_ply_with_uvs_but_no_texture_file(tmp_path):
    # trimesh invents a 2x2 grey placeholder texture here; we must not treat it as the surface colour
    square = textured_square_trimesh(trimesh.visual.material.SimpleMaterial())
    (tmp_path / "uv.ply").write_bytes(trimesh.exchange.ply.export_ply(square, encoding="ascii"))
    mesh = load_mesh(tmp_path / "uv.ply")
    assert not mesh.has_texture
    np.testing.assert_allclose(lookup(mesh, 0, (1 / 3, 1 / 3, 1 / 3)), DEFAULT_COLOR)


def test_stl(tmp_path):
    trimesh.creation.icosphere(subdivisions=1).export(tmp_path / "ball.STL")
    mesh = load_mesh(tmp_path / "ball.STL")
    assert len(mesh.faces) == 80 and len(mesh.vertices) == 42  # STL soup welded back


def test_a_two_sided_export_is_read_as_one_surface_and_its_grid_has_the_inside(tmp_path):
    """A two-sided export lists every face again wound the other way: the two cancel in the winding number, and
    the grid would lose the shape's inside. Each triangle is kept once, at its first listing."""
    from sin3dm_lite.data.grid import mesh_to_grid

    box = trimesh.creation.box((1.0, 0.6, 0.4))
    box.export(tmp_path / "box.stl")
    doubled = trimesh.Trimesh(box.vertices, np.vstack([box.faces, box.faces[:, ::-1]]), process=False)
    doubled.export(tmp_path / "two_sided.stl")
    again = np.vstack([box.faces, np.roll(box.faces[:5], 1, axis=1)])  # five listed twice, wound alike
    trimesh.Trimesh(box.vertices, again, process=False).export(tmp_path / "again.stl")
    clean = load_mesh(tmp_path / "box.stl")
    for name, repeats in (("two_sided.stl", 12), ("again.stl", 5)):
        with pytest.warns(UserWarning, match=f"{repeats} of the {12 + repeats} triangles of '{name}' repeat another"):
            mesh = load_mesh(tmp_path / name)
        assert len(mesh.faces) == 12
        np.testing.assert_array_equal(mesh.faces, clean.faces)  # the first listings, in the file's order
    inside = [mesh_to_grid(load_mesh(tmp_path / n), resolution=16).sdf < 0 for n in ("box.stl", "two_sided.stl")]
    assert inside[0].sum() > 100
    np.testing.assert_array_equal(inside[1], inside[0])


def test_a_two_sided_obj_of_quads_is_cut_into_the_same_triangles_both_ways_and_read_once(tmp_path):
    """A quad listed again the other way round, fanned from its own first corner, would be cut along the other
    diagonal: every polygon is fanned from its lowest vertex index instead."""
    from sin3dm_lite.data.grid import mesh_to_grid

    v = "".join(f"v {x} {y} {z}\n" for x in (0, 1) for y in (0, 0.6) for z in (0, 0.4))  # vertex 1 + 4x + 2y + z
    quads = ["2 4 3 1", "7 8 6 5", "5 6 2 1", "4 8 7 3", "3 7 5 1", "6 8 4 2"]  # counter-clockwise seen from outside
    (tmp_path / "box.obj").write_text(v + "".join(f"f {q}\n" for q in quads))
    back = [" ".join(reversed(q.split())) for q in quads]
    (tmp_path / "two.obj").write_text(v + "".join(f"f {q}\n" for q in quads + back))
    box, two = load_mesh(tmp_path / "box.obj"), load_mesh(tmp_path / "two.obj")
    assert len(box.faces) == len(two.faces) == 12
    np.testing.assert_array_equal(two.faces, box.faces)
    np.testing.assert_array_equal(box.faces[:2], [[0, 1, 3], [0, 3, 2]])  # "f 2 4 3 1" fanned from vertex 1
    inside = [mesh_to_grid(m, resolution=16).sdf < 0 for m in (box, two)]
    assert inside[0].sum() > 100
    np.testing.assert_array_equal(inside[1], inside[0])


@pytest.mark.parametrize("ext", ["ply", "off"])
def test_a_two_sided_ply_or_off_of_quads_cut_along_the_other_diagonal_is_read_once(tmp_path, ext):
    """trimesh cuts a PLY's or OFF's quads from their first corner, so a quad listed again the other way round is
    cut along its other diagonal: the flat quad its two triangles make is matched instead (a voxel tower so
    exported kept 0.35 of its grid before). A tetrahedron, whose opposite edges' triangles make the same four
    corners both ways round but not flat, keeps its four faces."""
    from sin3dm_lite.data.grid import mesh_to_grid
    from sin3dm_lite.formats.repair import first_listing

    v = [(x, y, z) for x in (0, 1) for y in (0, 0.6) for z in (0, 0.4)]  # vertex 4x + 2y + z
    quads = [(1, 3, 2, 0), (6, 7, 5, 4), (4, 5, 1, 0), (3, 7, 6, 2), (2, 6, 4, 0), (5, 7, 3, 1)]

    def write(name, qs):
        if ext == "ply":
            head = "ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\n"
            head += f"element face {len(qs)}\nproperty list uchar int vertex_indices\nend_header\n"
        else:
            head = f"OFF\n8 {len(qs)} 0\n"
        lines = [f"{x} {y} {z}\n" for x, y, z in v] + [f"4 {a} {b} {c} {d}\n" for a, b, c, d in qs]
        (tmp_path / f"{name}.{ext}").write_text(head + "".join(lines))
        return load_mesh(tmp_path / f"{name}.{ext}")

    box, two = write("box", quads), write("two", quads + [q[::-1] for q in quads])
    assert len(box.faces) == len(two.faces) == 12
    np.testing.assert_array_equal(two.faces, box.faces)
    inside = [mesh_to_grid(m, resolution=16).sdf < 0 for m in (box, two)]
    assert inside[0].sum() > 100
    np.testing.assert_array_equal(inside[1], inside[0])
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    np.testing.assert_array_equal(
        first_listing(corners, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])), range(4)
    )


def test_an_open_sheet_of_quads_listed_back_along_the_other_diagonals_keeps_its_front_even_at_the_corners():
    """On an open two-sided sheet a corner quad's reverse runs no edge the way a neighbour does (the sign the rule
    starts from): faces two edges from one that does are looked at too. Flat or bent (a rough terrain's quads fold
    along a diagonal), each quad's first listing is kept."""
    from sin3dm_lite.formats.repair import first_listing

    ids = np.arange(16).reshape(4, 4)
    v = np.c_[np.stack(np.meshgrid(np.arange(4), np.arange(4), indexing="ij"), -1).reshape(-1, 2), np.zeros(16)]
    a, b, c, d = ids[:-1, :-1].ravel(), ids[1:, :-1].ravel(), ids[1:, 1:].ravel(), ids[:-1, 1:].ravel()
    front = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    back = np.r_[np.c_[d, c, b], np.c_[d, b, a]]  # each quad again, the other way round, cut along b-d
    np.testing.assert_array_equal(first_listing(v.astype(float), np.r_[front, back]), np.arange(18))
    v[:, 2] = 0.15 * (np.add.outer(np.arange(4), np.arange(4)).ravel() % 2)  # every quad bent, as a rough terrain's
    np.testing.assert_array_equal(first_listing(v.astype(float), np.r_[front, back]), np.arange(18))


def test_quads_of_a_two_sided_soup_are_matched_by_position_whatever_the_vertex_order():
    """Per-face UVs or colours give every quad its own vertices (a soup); the quads are found on the positions the
    corners share, not on the vertex array's own order."""
    from sin3dm_lite.formats.repair import first_listing

    corners = np.array([(x, y, z) for x in (0, 1) for y in (0, 0.6) for z in (0, 0.4)], float)
    quads = [(1, 3, 2, 0), (6, 7, 5, 4), (4, 5, 1, 0), (3, 7, 6, 2), (2, 6, 4, 0), (5, 7, 3, 1)]
    soup = corners[[i for q in quads + [q[::-1] for q in quads] for i in q]]  # 4 vertices of its own per quad
    faces = np.array(
        [(b, b + 1, b + 2) for b in range(0, len(soup), 4)] + [(b, b + 2, b + 3) for b in range(0, len(soup), 4)]
    )
    for seed in range(3):
        order = np.random.default_rng(seed).permutation(len(soup))
        kept = first_listing(soup[order], np.argsort(order)[faces])
        assert sorted(kept) == [*range(6), *range(12, 18)]  # both triangles of each first listing


def test_two_blocks_that_share_a_wall_keep_both_its_sides_and_stay_closed(tmp_path):
    """Two closed blocks that touch list their shared wall twice, once from each side: not a two-sided export (only
    that wall is listed twice), so both stay, the mesh stays closed and the grid is the two blocks' union."""
    from sin3dm_lite.data.grid import mesh_to_grid

    a = trimesh.creation.box((1.0, 1.0, 1.0))
    a.apply_translation([-0.5, 0, 0])
    b = trimesh.Trimesh(
        a.vertices * [-1, 1, 1], a.faces[:, ::-1], process=False
    )  # a mirrored: the shared wall reversed
    trimesh.util.concatenate([a, b]).export(tmp_path / "blocks.stl")
    trimesh.creation.box((2.0, 1.0, 1.0)).export(tmp_path / "whole.stl")
    blocks = load_mesh(tmp_path / "blocks.stl")
    assert len(blocks.faces) == 24
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "open mesh" or "inside out" warning
        inside = mesh_to_grid(blocks, resolution=16).sdf < 0
    np.testing.assert_array_equal(inside, mesh_to_grid(load_mesh(tmp_path / "whole.stl"), resolution=16).sdf < 0)


def test_a_repeated_face_with_its_own_colours_and_uvs_is_a_repeat_too(tmp_path):
    p = tmp_path / "repeat.obj"
    p.write_text(
        "v 0 0 0 1 0 0\nv 1 0 0 1 0 0\nv 0 1 0 1 0 0\nv 0 0 1 1 0 0\n"
        "v 0 0 0 0 0 1\nv 0 1 0 0 0 1\nv 1 0 0 0 0 1\n"
        "f 1 2 3\nf 1 2 4\nf 5 6 7\n"  # the last: the first face again, blue and wound the other way
    )
    mesh = load_mesh(p)
    assert len(mesh.faces) == 2 and len(mesh.vertices) == 4  # the repeat's own vertices are dropped with it
    np.testing.assert_allclose(lookup(mesh, 0, (1 / 3, 1 / 3, 1 / 3)), RED)


@pytest.mark.parametrize("ext", ["ply", "stl", "glb"])
def test_32_bit_coordinates_far_from_the_origin_say_that_the_file_lost_detail(tmp_path, ext):
    """A scan exported in map coordinates: 32-bit floats 5e6 from the origin step by 0.5, a twentieth of a shape 10
    units across; the file itself lost the detail, and the loader says so and how to export it. The same shape as
    text digits (OBJ), or near the origin, loads without a word."""
    ball = trimesh.creation.icosphere(subdivisions=2)
    far = trimesh.Trimesh(ball.vertices * 5 + [5e6, 3.5e6, 100.0], ball.faces)
    far.export(tmp_path / f"far.{ext}")
    with pytest.warns(UserWarning, match=r"'far\.\w+' lies 5e\+06 from the origin.*step by 0\.5 \(5\.0% of its size"):
        load_mesh(tmp_path / f"far.{ext}")
    far.export(tmp_path / "far.obj")
    trimesh.Trimesh(ball.vertices * 5, ball.faces).export(tmp_path / f"near.{ext}")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_mesh(tmp_path / "far.obj")
        load_mesh(tmp_path / f"near.{ext}")


# ================================================================= bad input
def test_missing_file(tmp_path):
    with pytest.raises(Sin3DMInputError, match="not found.*nothere.obj"):
        load_mesh(tmp_path / "nothere.obj")


def test_unsupported_extension(tmp_path):
    (tmp_path / "thing.fbx").write_bytes(b"x")
    with pytest.raises(Sin3DMInputError, match="extension") as e:
        load_mesh(tmp_path / "thing.fbx")
    assert ".obj" in str(e.value) and ".glb" in str(e.value)


def test_directory(tmp_path):
    d = tmp_path / "dir.obj"
    d.mkdir()
    with pytest.raises(Sin3DMInputError, match="directory"):
        load_mesh(d)


@pytest.mark.parametrize("text", ["", "# nothing\n", "v 0 0 0\nv 1 0 0\nv 0 1 0\n"])
def test_obj_without_faces(tmp_path, text):
    (tmp_path / "e.obj").write_text(text)
    with pytest.raises(Sin3DMInputError, match="no triangle faces"):
        load_mesh(tmp_path / "e.obj")


def test_point_cloud_ply(tmp_path):
    trimesh.PointCloud(np.random.default_rng(0).random((20, 3))).export(tmp_path / "pc.ply")
    with pytest.raises(Sin3DMInputError, match="pc.ply.*no triangle faces.*point cloud"):
        load_mesh(tmp_path / "pc.ply")


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf"])
def test_nan_vertices(tmp_path, bad):
    (tmp_path / "n.obj").write_text(f"v 0 0 0\nv 1 0 0\nv 0 {bad} 0\nf 1 2 3\n")
    with pytest.raises(Sin3DMInputError, match="NaN or infinite"):
        load_mesh(tmp_path / "n.obj")


def test_nan_in_unused_vertex_is_ignored(tmp_path):
    (tmp_path / "n.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 0\nv 99 99 99\nf 1 2 3\n")
    mesh = load_mesh(tmp_path / "n.obj")
    assert len(mesh.vertices) == 3 and mesh.bounds.max() == 1


def test_zero_size_bounding_box(tmp_path):
    (tmp_path / "z.obj").write_text("v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n")
    with pytest.raises(Sin3DMInputError, match="zero-size bounding box"):
        load_mesh(tmp_path / "z.obj")


def test_zero_area(tmp_path):
    (tmp_path / "z.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    with pytest.raises(Sin3DMInputError, match="zero surface area"):
        load_mesh(tmp_path / "z.obj")


@pytest.mark.parametrize(
    "name, content, key",
    [
        ("junk.glb", b"this is not a glb file at all", "junk.glb"),
        ("trunc.glb", b"glTF\x02\x00\x00\x00\xff\xff", "trunc.glb"),
        ("junk.gltf", b"{not json", "JSON"),
        ("junk.ply", b"\x8f\x01garbage" * 40, "junk.ply"),
        ("bad.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n", "bad.ply"),
        ("junk.obj", bytes(range(256)) * 4, "binary"),
        ("idx.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "vertex 9"),
        ("word.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", "line 4"),
        ("vbad.obj", b"v 0 0 zero\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "'v'"),
        ("empty.glb", b"", "empty"),
        ("junk.stl", b"\x00\x01garbage" * 10, "corrupt file"),
    ],
)
def test_corrupt_files_give_one_clear_error(tmp_path, name, content, key):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(Sin3DMInputError) as e:
        load_mesh(tmp_path / name)
    assert key in str(e.value)
    # no library traceback is chained onto ours
    assert e.value.__cause__ is None and (e.value.__context__ is None or e.value.__suppress_context__)


def test_gltf_missing_buffer_is_clear(tmp_path):
    files = _two_object_scene().export(file_type="gltf")
    (tmp_path / "nobin.gltf").write_bytes(files["model.gltf"])
    with pytest.raises(Sin3DMInputError, match="nobin.gltf"):
        load_mesh(tmp_path / "nobin.gltf")


def _glb_requiring(extension: str) -> bytes:
    """A box's GLB whose header says its geometry needs ``extension`` (a compression) to be read."""
    data = trimesh.exchange.gltf.export_glb(trimesh.Scene(trimesh.creation.box()))
    n = struct.unpack_from("<I", data, 12)[0]
    head, rest = json.loads(data[20 : 20 + n]), data[20 + n :]
    head["extensionsUsed"] = head["extensionsRequired"] = [extension]
    if extension == "KHR_draco_mesh_compression":
        for prim in head["meshes"][0]["primitives"]:
            prim["extensions"] = {extension: {"bufferView": 0, "attributes": {"POSITION": 0}}}
    text = json.dumps(head).encode()
    text += b" " * (-len(text) % 4)
    return b"glTF" + struct.pack("<III", 2, 20 + len(text) + len(rest), len(text)) + b"JSON" + text + rest


@pytest.mark.parametrize(
    "extension, words",
    [
        ("KHR_draco_mesh_compression", "compressed with Draco .*pip install DracoPy.*Compression off"),
        ("EXT_meshopt_compression", "compressed with meshoptimizer .*export the mesh again without compression"),
    ],
)
def test_a_compressed_glb_that_cannot_be_decoded_says_how_to_read_it(tmp_path, monkeypatch, extension, words):
    """Web GLBs are often compressed: trimesh decodes Draco only with DracoPy (without it: "cannot reshape array")
    and never meshoptimizer (whose bytes it would read as plain geometry). Either is one line that says what to do."""
    monkeypatch.setitem(sys.modules, "DracoPy", None)  # as on a machine without it
    (tmp_path / "web.glb").write_bytes(_glb_requiring(extension))
    with pytest.raises(Sin3DMInputError, match=f"'web.glb' is {words}"):
        load_mesh(tmp_path / "web.glb")
    from sin3dm_lite.cli import main

    assert main(["grid", str(tmp_path / "web.glb"), "--out", str(tmp_path / "g.npz")]) == 2
    assert not (tmp_path / "g.npz").exists()


def test_missing_texture_warns_and_uses_material_color(tmp_path):
    p = write_square(tmp_path, tex="missing.png", image=False)
    with pytest.warns(UserWarning, match="missing.png"):
        mesh = load_mesh(p)
    assert mesh.materials[0].image is None
    np.testing.assert_allclose(lookup(mesh, 0, (1 / 3, 1 / 3, 1 / 3)), (0.8, 0.8, 0.8), atol=1e-6)


def test_a_missing_texture_that_many_materials_name_warns_once(tmp_path):
    """An exporter's absolute path (here a Windows one) in every material: one warning, not one per material."""
    (tmp_path / "two.mtl").write_text(
        "newmtl A\nKd 1 0 0\nmap_Kd D:\\work\\tex\\colors.png\nnewmtl B\nKd 0 0 1\nmap_Kd D:\\work\\tex\\colors.png\n"
    )
    (tmp_path / "two.obj").write_text(
        "mtllib two.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "usemtl A\nf 1/1 2/2 3/3\nusemtl B\nf 1/1 3/3 4/4\n"
    )
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        mesh = load_mesh(tmp_path / "two.obj")
    missing = [str(w.message) for w in said if "colors.png" in str(w.message)]
    assert len(missing) == 1 and "any other material that names it" in missing[0], missing
    assert [m.image for m in mesh.materials] == [None, None]  # each keeps its own colour
    np.testing.assert_allclose(lookup(mesh, 1, (1 / 3, 1 / 3, 1 / 3)), (0, 0, 1), atol=1e-6)


def test_corrupt_texture_warns_and_uses_material_color(tmp_path):
    p = write_square(tmp_path, image=False)
    (tmp_path / "tex.png").write_bytes(b"\x89PNG garbage garbage garbage")
    with pytest.warns(UserWarning, match="tex.png.*could not be read"):
        mesh = load_mesh(p)
    assert mesh.materials[0].image is None
    np.testing.assert_allclose(lookup(mesh, 0, (1 / 3, 1 / 3, 1 / 3)), (0.8, 0.8, 0.8), atol=1e-6)


def test_unused_materials_are_not_loaded(tmp_path, monkeypatch):
    p = write_square(tmp_path)
    mtl = tmp_path / "square.mtl"
    mtl.write_text(mtl.read_text() + "\nnewmtl unused\nmap_Kd missing.png\n")  # no face uses it
    opened = []
    real_open = Image.open
    monkeypatch.setattr(Image, "open", lambda f, *a, **k: (opened.append(Path(f).name), real_open(f, *a, **k))[1])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning about its missing texture either
        mesh = load_mesh(p)
    assert [m.name for m in mesh.materials] == ["textured", "plain"] and opened == ["tex.png"]


def test_missing_mtl_warns(tmp_path):
    p = write_square(tmp_path)
    (tmp_path / "square.mtl").unlink()
    with pytest.warns(UserWarning, match="square.mtl"):
        mesh = load_mesh(p)
    assert not mesh.has_texture


def test_texture_image_modes(tmp_path):
    grey = Image.fromarray(np.full((4, 4), 128, np.uint8), "L")
    np.testing.assert_allclose(image_to_array(grey), 128 / 255)
    rgba = Image.fromarray(np.full((4, 4, 4), (255, 0, 0, 10), np.uint8), "RGBA")
    arr = image_to_array(rgba)
    assert arr.shape == (4, 4, 3) and arr.dtype == np.float32
    np.testing.assert_allclose(arr[0, 0], RED)
    pal = Image.fromarray(quadrant_image()).convert("P")
    np.testing.assert_allclose(image_to_array(pal)[0, 0], RED)
    i16 = Image.fromarray(np.full((4, 4), 65535, np.uint16))
    np.testing.assert_allclose(image_to_array(i16), 1.0)
    big = Image.fromarray(quadrant_image(size=64))
    small = image_to_array(big, max_size=16)
    assert small.shape == (16, 16, 3)
    np.testing.assert_allclose(small[0, 0], RED)


def test_image_arrays_are_scaled_clipped_and_left_alone():
    floats = np.array([[[-0.5, 0.25, np.nan, 0.7], [2.0, 1.0, 0.0, 0.1]]], np.float32)  # RGBA, out of range, NaN
    keep = floats.copy()
    out = image_to_array(floats)
    np.testing.assert_array_equal(out, [[[0.0, 0.25, 0.0], [1.0, 1.0, 0.0]]])
    np.testing.assert_array_equal(floats, keep)  # the caller's array is not modified
    assert out.dtype == np.float32 and out.flags.c_contiguous
    np.testing.assert_array_equal(
        image_to_array(np.array([[7, 255]], np.uint8)), [[[np.float32(7) / 255] * 3, [1.0] * 3]]
    )
    np.testing.assert_array_equal(image_to_array(np.array([[True, False]])), [[[1.0] * 3, [0.0] * 3]])


# ================================================================== writers
def test_save_obj_failure_leaves_nothing(tmp_path, monkeypatch):
    mesh = load_mesh(write_square(tmp_path))
    out_dir = tmp_path / "out"
    out_dir.mkdir()

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(export, "_baked_vertex_colors", boom)  # fails after the PNG and MTL are written
    with pytest.raises(OSError, match="disk full"):
        save_obj(mesh, out_dir / "x.obj")
    assert list(out_dir.iterdir()) == []


def test_save_glb_failure_leaves_nothing(tmp_path, monkeypatch):
    mesh = load_mesh(write_square(tmp_path))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    partial = []

    def write_half_then_fail(self, data):  # the disk fills up halfway through the write
        with open(self, "wb") as f:
            f.write(data[: len(data) // 2])
        partial.append(self.stat().st_size)
        raise OSError("disk full")

    monkeypatch.setattr(Path, "write_bytes", write_half_then_fail)  # what files.atomic_write uses
    with pytest.raises(OSError, match="disk full"):
        save_glb(mesh, out_dir / "x.glb")
    assert partial and partial[0] > 0  # half a file did reach the disk ...
    assert list(out_dir.iterdir()) == []  # ... and was removed


def test_writers_check_suffix(tmp_path):
    mesh = load_mesh(write_square(tmp_path))
    with pytest.raises(Sin3DMInputError, match=r"\.obj"):
        save_obj(mesh, tmp_path / "x.glb")
    with pytest.raises(Sin3DMInputError, match=r"\.glb"):
        save_glb(mesh, tmp_path / "x.obj")


def test_save_obj_pbr_maps_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    mr = rng.random((8, 8, 3)).astype(np.float32)
    mesh = TexturedMesh(
        vertices=np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 1]], float),
        faces=np.array([[0, 1, 2], [0, 1, 3]]),
        face_material=np.array([0, 0]),
        materials=[
            Material(
                name="pbr",
                base_color=np.ones(4, np.float32),
                image=np.ones((8, 8, 3), np.float32),
                metallic=1.0,
                roughness=1.0,
                metallic_roughness_image=mr,
                normal_image=np.tile(np.array([0.5, 0.5, 1.0], np.float32), (8, 8, 1)),
            )
        ],
        face_uvs=rng.random((2, 3, 2)).astype(np.float32),
    )
    out = save_obj(mesh, tmp_path / "p.obj")
    mtl = (tmp_path / "p.mtl").read_text()
    assert "map_Pr p_roughness.png" in mtl and "map_Pm p_metallic.png" in mtl and "map_Bump" in mtl
    m = load_mesh(out).materials[0]
    np.testing.assert_allclose(m.metallic_roughness_image[..., 1:], mr[..., 1:], atol=1 / 255)
    np.testing.assert_allclose(m.normal_image, mesh.materials[0].normal_image, atol=1 / 255)
    assert m.metallic == 1.0 and m.roughness == 1.0


def test_to_trimesh_scene_texture_and_materials(tmp_path):
    save_png(tmp_path / "t.png", quadrant_image())
    (tmp_path / "t.mtl").write_text("newmtl m\nmap_Kd t.png\n")
    (tmp_path / "t.obj").write_text(
        "mtllib t.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    )
    (tm,) = to_trimesh_scene(load_mesh(tmp_path / "t.obj")).geometry.values()
    assert isinstance(tm.visual, trimesh.visual.TextureVisuals)
    assert tm.visual.uv.shape == (4, 2) and tm.visual.material.baseColorTexture.size == (16, 16)
    square = load_mesh(write_square(tmp_path))  # two materials: one geometry each, the plain one without UVs
    textured, plain = to_trimesh_scene(square).geometry.values()
    assert textured.visual.uv is not None and plain.visual.uv is None
    assert len(textured.faces) + len(plain.faces) == len(square.faces)
    np.testing.assert_allclose(plain.visual.material.baseColorFactor[:3], uint8(0.2, 0.4, 0.6), atol=1)


# ========================================================= misc & transforms
def test_sample_texture_wraps_u_and_v():
    img = quadrant_image().astype(np.float32) / 255
    uv = np.array([[0.2, 0.1], [0.2, 1.1], [1.2, -0.9], [-0.8, 2.1]])
    out = sample_texture(img, uv)
    np.testing.assert_allclose(out, np.tile(BLUE, (4, 1)), atol=1e-6)
    np.testing.assert_allclose(sample_texture(img, np.array([[0.9, 0.9], [0.9, -0.1]])), [GREEN, GREEN], atol=1e-6)


def test_sample_texture_is_bilinear_between_texel_centres():
    img = np.array([[0.0, 1.0], [2.0, 3.0]], np.float32)  # 2 × 2, one channel, no channel axis
    # texel centres sit at u, v = 0.25 / 0.75; row 0 is v = 1
    uv = np.array([[0.25, 0.75], [0.75, 0.75], [0.25, 0.25], [0.5, 0.75], [0.5, 0.5], [0.375, 0.625]])
    out = sample_texture(img, uv)
    assert out.shape == (6,) and out.dtype == np.float32
    np.testing.assert_allclose(out, [0.0, 1.0, 2.0, 0.5, 1.5, 0.75], atol=1e-6)
    rgb = sample_texture(np.stack([img, 2 * img, 3 * img], -1), uv)
    assert rgb.shape == (6, 3)
    np.testing.assert_allclose(rgb, out[:, None] * [1, 2, 3], atol=1e-6)


def test_normalized_box_and_inverse():
    box = trimesh.creation.box(extents=(4.0, 2.0, 1.0))
    box.apply_translation((10, -3, 7))
    mesh = TexturedMesh(
        vertices=np.asarray(box.vertices, float),
        faces=np.asarray(box.faces),
        face_material=np.zeros(12, np.int64),
        materials=[Material()],
    )
    n = mesh.normalized()
    lo, hi = n.bounds
    np.testing.assert_allclose((hi - lo).max() * BOX_MARGIN, 2.0)
    np.testing.assert_allclose((lo + hi) / 2, 0, atol=1e-12)
    np.testing.assert_allclose(hi - lo, np.array([4, 2, 1]) * 2 / (4 * 1.03))
    np.testing.assert_allclose(n.normalization.to_original(n.vertices), mesh.vertices, atol=1e-12)
    np.testing.assert_allclose(n.normalization.to_normalized(mesh.vertices), n.vertices, atol=1e-12)
    # normalising twice composes (and stays inverted by to_original)
    nn = n.normalized()
    np.testing.assert_allclose(nn.normalization.to_original(nn.vertices), mesh.vertices, atol=1e-9)


def test_load_any(tmp_path):
    mesh = load_mesh(write_square(tmp_path))
    assert load_any(mesh) is mesh
    assert len(load_any(str(tmp_path / "square.obj")).faces) == 6
    with pytest.raises(Sin3DMInputError, match="TexturedMesh"):
        load_any(42)


def test_loaded_files_produce_no_stray_warnings(tmp_path):
    p = write_square(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_mesh(p)
        load_mesh(save_glb(load_mesh(p), tmp_path / "a.glb"))


def test_gltf_with_embedded_buffers_loads_without_warnings(tmp_path):
    """Images in a buffer view of a data-URI buffer (``embed_buffers``) are found, not reported missing."""
    mat = PBRMaterial(
        name="quad", baseColorTexture=Image.fromarray(quadrant_image()), baseColorFactor=uint8(1, 1, 1, 1)
    )
    files = trimesh.Scene(textured_square_trimesh(mat)).export(file_type="gltf", embed_buffers=True)
    (tmp_path / "emb.gltf").write_bytes(files["model.gltf"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = load_mesh(tmp_path / "emb.gltf")
    for face, bc, color in LOOKUPS:
        np.testing.assert_allclose(lookup(mesh, face, bc), color, atol=1e-6)


# ================================================= files a mesh names outside its folder (issue 35, case 8)
def _outside(tmp_path) -> tuple[Path, Path]:
    """``tmp_path/mesh/`` for the mesh and ``tmp_path/secret/tex.png`` outside it."""
    (tmp_path / "mesh").mkdir()
    (tmp_path / "secret").mkdir()
    save_png(tmp_path / "secret" / "tex.png", quadrant_image())
    return tmp_path / "mesh", tmp_path / "secret" / "tex.png"


@pytest.mark.parametrize("how", ["relative", "absolute", "symlink", "mtllib"])
def test_an_obj_may_not_make_the_loader_read_outside_its_folder(tmp_path, how):
    folder, secret = _outside(tmp_path)
    tex = {"relative": "../secret/tex.png", "absolute": str(secret), "symlink": "link.png", "mtllib": "tex.png"}[how]
    if how == "symlink":
        (folder / "link.png").symlink_to(secret)
    path = write_square(folder, tex=tex, image=False)
    if how == "mtllib":  # the MTL itself outside
        (folder / "square.mtl").rename(tmp_path / "secret" / "square.mtl")
        path.write_text(path.read_text().replace("mtllib square.mtl", "mtllib ../secret/square.mtl"))
    ref = "../secret/square.mtl" if how == "mtllib" else tex
    with pytest.raises(Sin3DMInputError) as e:
        load_mesh(path)
    msg = str(e.value)
    assert "'square.obj' names a file outside its folder: the " in msg and f"'{ref}' is '" in msg
    assert "--allow-outside-paths" in msg and "allow_outside_paths=True" in msg and "\n" not in msg
    assert ("through a symbolic link" in msg) == (how == "symlink")
    mesh = load_mesh(path, allow_outside_paths=True)  # the user says they trust it
    assert mesh.materials[0].image is not None
    np.testing.assert_allclose(lookup(mesh, *LOOKUPS[0][:2]), LOOKUPS[0][2], atol=1e-6)


def test_a_texture_named_outside_but_present_in_the_folder_is_taken_from_the_folder(tmp_path):
    folder, _ = _outside(tmp_path)
    path = write_square(folder, tex="../secret/tex.png", image=False)
    save_png(folder / "tex.png", quadrant_image(bl=CYAN))  # found by its base name, as before
    assert np.allclose(lookup(load_mesh(path), *LOOKUPS[0][:2]), CYAN)


def test_gltf_buffers_and_images_outside_the_folder_are_refused(tmp_path):
    folder, secret = _outside(tmp_path)
    mat = PBRMaterial(name="quad", baseColorTexture=Image.fromarray(quadrant_image()))
    files = trimesh.Scene(textured_square_trimesh(mat)).export(file_type="gltf")
    header = json.loads(files["model.gltf"])
    for name, blob in files.items():
        if name.endswith(".bin"):
            (secret.parent / name).write_bytes(blob)
    for buffer in header["buffers"]:
        buffer["uri"] = f"../secret/{buffer['uri']}"
    (folder / "m.gltf").write_text(json.dumps(header))
    with pytest.raises(Sin3DMInputError, match=r"names a file outside its folder: the glTF buffer '\.\./secret/"):
        load_mesh(folder / "m.gltf")
    assert len(load_mesh(folder / "m.gltf", allow_outside_paths=True).faces) == 2
    for buffer in header["buffers"]:
        buffer["uri"] = buffer["uri"].removeprefix("../secret/")
        (folder / buffer["uri"]).write_bytes(files[buffer["uri"]])
    header["images"] = [{"uri": "../secret/tex.png"}]
    (folder / "m.gltf").write_text(json.dumps(header))
    with pytest.raises(Sin3DMInputError, match=r"the glTF image '\.\./secret/tex\.png' is '"):
        load_mesh(folder / "m.gltf")


def test_a_ply_texture_file_outside_the_folder_is_refused(tmp_path):
    folder, _ = _outside(tmp_path)
    (folder / "t.ply").write_text(
        "ply\nformat ascii 1.0\ncomment TextureFile ../secret/tex.png\nelement vertex 3\n"
        "property float x\nproperty float y\nproperty float z\nelement face 1\n"
        "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    )
    with pytest.raises(Sin3DMInputError, match=r"the texture file '\.\./secret/tex\.png' is '"):
        load_mesh(folder / "t.ply")
    assert len(load_mesh(folder / "t.ply", allow_outside_paths=True).faces) == 1


def test_cli_refuses_outside_paths_in_one_line_unless_allowed(tmp_path, capsys):
    from sin3dm_lite.cli import main

    folder, _ = _outside(tmp_path)
    path = write_square(folder, tex="../secret/tex.png", image=False)
    out = tmp_path / "g.npz"
    assert main(["grid", str(path), "--resolution", "16", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("sin3dm-lite grid: error: 'square.obj' names a file outside its folder") and "\n" not in err
    assert "--allow-outside-paths" in err and not out.exists()
    assert main(["grid", str(path), "--resolution", "16", "--out", str(out), "--allow-outside-paths"]) == 0
    for cmd in ("fit", "render", "evaluate", "calibrate"):  # every command that reads a mesh has the switch
        with pytest.raises(SystemExit):
            main([cmd, "--help"])
        assert "--allow-outside-paths" in capsys.readouterr().out

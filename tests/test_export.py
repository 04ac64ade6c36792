"""Extracted meshes written to OBJ+MTL+PNG and GLB, read back with trimesh; files.atomic_folder."""

import os

import numpy as np
import pytest
import trimesh

from sin3dm_lite import export
from sin3dm_lite import extract as ex
from sin3dm_lite.data.mesh import Normalization
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.formats.export import export_mesh

from .conftest import AABB, SphereDecoder, zero_triplane


@pytest.fixture(scope="module")
def sphere_mesh():
    tp = zero_triplane()
    norm = Normalization(center=np.array([10.0, 0.0, -5.0]), scale=0.25)  # the input file's frame
    return ex.extract_mesh(SphereDecoder(), tp, AABB, normalization=norm, resolution=32, faces=2000, texture_size=256)


def _check_reloaded(loaded: trimesh.Trimesh):
    lo, hi = loaded.bounds
    # radius 0.5 / scale 0.25 = 2 around the centre (10, 0, -5), within a quarter voxel (0.0625 / 0.25)
    assert np.all(lo > [8 - 0.02, -2 - 0.02, -7 - 0.02]) and np.all(hi < [12 + 0.02, 2 + 0.02, -3 + 0.02])
    assert np.all(hi - lo > 3.9)
    uv = loaded.visual.uv
    assert uv is not None and len(uv) == len(loaded.vertices) and uv.min() >= 0 and uv.max() <= 1
    material = loaded.visual.material
    image = getattr(material, "image", None) or getattr(material, "baseColorTexture", None)
    assert image is not None
    pixels = np.asarray(image.convert("RGB"), np.float32) / 255
    assert pixels.shape[:2] == (256, 256) and pixels.std(axis=(0, 1)).min() > 0.05  # not constant


def test_export_obj_and_glb_reload_with_texture(sphere_mesh, tmp_path):
    out = tmp_path / "sample_0"
    paths = export_mesh(sphere_mesh, out)
    assert set(paths) == {"obj", "glb"}
    assert sorted(p.name for p in out.iterdir()) == ["mesh.glb", "mesh.mtl", "mesh.obj", "mesh.png"]
    for fmt in ("obj", "glb"):
        _check_reloaded(trimesh.load(paths[fmt], force="mesh"))
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary folder left


def test_export_into_existing_folder_keeps_other_files(sphere_mesh, tmp_path):
    (tmp_path / "notes.txt").write_text("keep me")
    paths = export_mesh(sphere_mesh, tmp_path, name="shape", formats="glb")
    assert set(paths) == {"glb"} and paths["glb"].exists()
    assert (tmp_path / "notes.txt").read_text() == "keep me"


def test_failed_export_leaves_no_output_folder(sphere_mesh, tmp_path, monkeypatch):
    def broken(mesh, path):
        path.write_bytes(b"half a file")
        raise OSError("disk full")

    monkeypatch.setattr(export, "save_glb", broken)
    with pytest.raises(OSError, match="disk full"):
        export_mesh(sphere_mesh, tmp_path / "out")
    assert list(tmp_path.iterdir()) == []


def test_pbr_maps_reach_the_glb(sphere_mesh, tmp_path):
    from dataclasses import replace

    mat = replace(
        sphere_mesh.materials[0],
        metallic=1.0,
        roughness=1.0,
        metallic_roughness_image=np.full((32, 32, 3), [0.0, 0.8, 0.3], np.float32),
        normal_image=np.full((32, 32, 3), [0.5, 0.5, 1.0], np.float32),
    )
    paths = export_mesh(replace(sphere_mesh, materials=[mat]), tmp_path / "pbr", formats=("glb",))
    loaded = trimesh.load(paths["glb"], force="mesh").visual.material
    assert loaded.metallicRoughnessTexture is not None and loaded.normalTexture is not None


def test_bad_format_and_name_are_clear_errors(sphere_mesh, tmp_path):
    with pytest.raises(Sin3DMInputError, match="format"):
        export_mesh(sphere_mesh, tmp_path / "x", formats=("ply",))
    with pytest.raises(Sin3DMInputError, match="plain file name"):
        export_mesh(sphere_mesh, tmp_path / "x", name="a/b")
    assert list(tmp_path.iterdir()) == []


def test_temporaries_of_another_machine_sharing_the_folder_are_left_alone(tmp_path, monkeypatch):
    """A folder shared between machines (a cluster's home): a PID that runs on the other machine is not running
    here, so only this machine's temporaries are judged by PID; old names without a machine still are."""
    import subprocess
    import sys

    from sin3dm_lite.files import TEMP_PREFIX, machine_tag, make_temp_dir, remove_stale_temps
    from sin3dm_lite.files.atomic import atomic_path, atomic_paths

    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True).stdout)
    monkeypatch.setattr("os.getpid", lambda: dead)  # what the other machine's writer (PID `dead` there) makes
    monkeypatch.setattr("socket.gethostname", lambda: "node-17")
    theirs = make_temp_dir(tmp_path)
    with atomic_path(tmp_path / "model.pt") as their_file, atomic_paths(tmp_path, ["a.json", "b.json"]) as pair:
        their_file.write_bytes(b"half")  # atomic_paths: a run folder's files updated all or none (calibrate)
        monkeypatch.undo()
        remove_stale_temps(tmp_path)
        assert theirs.is_dir() and their_file.is_file()  # the other machine's writer goes on undisturbed
        assert all(t.is_file() for t in pair.values())
    mine, old = tmp_path / f"{TEMP_PREFIX}{dead}@{machine_tag()}-x", tmp_path / f"{TEMP_PREFIX}{dead}-y"
    mine.mkdir(), old.mkdir()
    assert sorted(remove_stale_temps(tmp_path)) == sorted([mine, old]) and theirs.is_dir()


def test_atomic_folder_cleans_up_after_errors_and_killed_writers(tmp_path):
    import subprocess
    import sys

    from sin3dm_lite.files import TEMP_PREFIX, atomic_folder

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    out = tmp_path / "out"
    out.mkdir()
    stale = out / f"{TEMP_PREFIX}{int(dead.stdout)}-abc"  # what a killed writer leaves behind
    stale.mkdir()
    (stale / "half.obj").write_text("v 0 0")
    with pytest.raises(OSError, match="disk full"):
        with atomic_folder(out) as tmp:
            assert tmp.parent == out and tmp.name.startswith(f"{TEMP_PREFIX}{os.getpid()}@")
            (tmp / "a.mtl").write_text("newmtl a")
            raise OSError("disk full")
    assert list(out.iterdir()) == []  # the stale folder went first, the failed one after
    new = tmp_path / "new"
    with atomic_folder(new) as tmp:
        assert tmp.parent == tmp_path  # beside a folder that does not exist yet: it appears in one rename
        (tmp / "a.obj").write_text("# a")
    assert [p.name for p in new.iterdir()] == ["a.obj"] and sorted(p.name for p in tmp_path.iterdir()) == ["new", "out"]

"""Nothing written, replaced or deleted through a link or outside ``--out`` (issue 60, case 1).

A user moved a sample they liked out of the folder and linked it back; ``sample --overwrite``
must refuse in one line and leave what the link points to as it was."""

import hashlib
import json
import os
import shutil
from pathlib import Path

import pytest

from sin3dm_lite import files
from sin3dm_lite.cli import main
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.files import MANIFEST

from .conftest import CHEAP_SAMPLE
from .test_output_folders import one_error_line as one_line  # the same one-line check

CHEAP = [*CHEAP_SAMPLE, "--workers", "0"]


def tree(root: Path) -> dict:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def move_out_and_link_back(ws: Path) -> Path:
    kept = ws / "kept"
    shutil.move(ws / "samples" / "000", kept)
    os.symlink(kept, ws / "samples" / "000")
    return kept


def test_overwrite_with_other_settings_never_replaces_a_linked_samples_mesh(work, capsys):
    kept = move_out_and_link_back(work)
    before = tree(kept)
    code = main(["sample", "run", "--out", "samples", "-n", "1", "--seed", "5", "--overwrite", *CHEAP])
    assert code == 2
    line = one_line(capsys)
    assert "samples/000" in line and "symbolic link" in line
    assert tree(kept) == before


def test_overwrite_never_deletes_a_recorded_file_behind_a_link(work, capsys):
    kept = move_out_and_link_back(work)
    (kept / "important.txt").write_text("the user's notes")
    st = (kept / "important.txt").stat()
    m = json.loads((work / "samples" / MANIFEST).read_text())
    m["files"]["000/important.txt"] = {
        "size": st.st_size,
        "mtime_ns": st.st_mtime_ns,
        "sha256": hashlib.sha256(b"the user's notes").hexdigest(),
        "by": "sample",
    }
    (work / "samples" / MANIFEST).write_text(json.dumps(m))
    assert main(["sample", "run", "--out", "samples", "-n", "1", "--seed", "5", "--overwrite", *CHEAP]) == 2
    assert "symbolic link" in one_line(capsys)
    assert (kept / "important.txt").read_text() == "the user's notes"


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_a_fresh_out_whose_000_links_elsewhere_is_not_written(work, capsys, overwrite):
    elsewhere = work / "elsewhere"
    elsewhere.mkdir()
    (work / "fresh").mkdir()
    os.symlink(elsewhere, work / "fresh" / "000")
    assert main(["sample", "run", "--out", "fresh", "-n", "1", *overwrite, *CHEAP]) == 2
    line = one_line(capsys)
    assert "fresh/000" in line and "symbolic link" in line
    assert list(elsewhere.iterdir()) == []


def test_continuing_a_run_refuses_a_link_to_an_unfinished_sample(work, capsys):
    """The same settings continue a run: sample 001 must not land in a folder linked elsewhere."""
    elsewhere = work / "elsewhere"
    elsewhere.mkdir()
    os.symlink(elsewhere, work / "samples" / "001")
    assert main(["sample", "run", "--out", "samples", "-n", "2", *CHEAP]) == 2
    assert "samples/001" in one_line(capsys)
    assert list(elsewhere.iterdir()) == []


def test_out_itself_may_be_a_link(work, capsys):
    """The rule is about what lies inside ``--out``; ``--out`` may name a folder through a link."""
    os.symlink(work / "samples", work / "alias")
    assert main(["sample", "run", "--out", "alias", "-n", "2", *CHEAP]) == 0
    assert (work / "samples" / "001" / "mesh.obj").is_file()


# ---------------------------------------------------------------- at the moment of writing (a link made meanwhile)
def test_remove_files_refuses_a_link_made_after_the_checks(tmp_path):
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (elsewhere / "mesh.obj").write_text("v 0 0 0\n")
    os.symlink(elsewhere, out / "000")
    with pytest.raises(Sin3DMInputError, match="symbolic link"):
        files.remove_files(out, ["000/mesh.obj"])
    assert (elsewhere / "mesh.obj").is_file()


def test_install_output_refuses_a_link_made_after_the_checks(tmp_path):
    out, elsewhere, tmp = tmp_path / "out", tmp_path / "elsewhere", tmp_path / "tmp"
    for d in (out, elsewhere, tmp / "views"):
        d.mkdir(parents=True)
    (tmp / "views" / "a.png").write_bytes(b"new")
    (elsewhere / "a.png").write_bytes(b"the user's")
    os.symlink(elsewhere, out / "views")
    with pytest.raises(Sin3DMInputError, match="symbolic link"):
        files.install_output(tmp, out, by="render")
    assert (elsewhere / "a.png").read_bytes() == b"the user's"


def test_confined_refuses_paths_outside_and_allows_inside(tmp_path):
    out = tmp_path / "out"
    (out / "000").mkdir(parents=True)
    assert files.confined(out, out / "000" / "mesh.obj") == out / "000" / "mesh.obj"
    with pytest.raises(Sin3DMInputError, match="outside"):
        files.confined(out, out / ".." / "x")
    with pytest.raises(Sin3DMInputError, match="outside"):
        files.confined(out, tmp_path / "x")
    os.symlink(tmp_path / "target.txt", out / "000" / "notes.txt")  # a link as the file itself, dangling too
    with pytest.raises(Sin3DMInputError, match="notes.txt"):
        files.confined(out, out / "000" / "notes.txt")


def test_a_lock_file_that_is_a_link_is_never_written(tmp_path):
    out, victim = tmp_path / "out", tmp_path / "victim.txt"
    out.mkdir()
    victim.write_text("keep me")
    os.symlink(victim, out / files.LOCK)
    with pytest.raises(Sin3DMInputError, match="symbolic link"):
        files.acquire_lock(out)
    assert victim.read_text() == "keep me"


def test_a_manifest_part_that_is_a_link_is_never_appended_to(tmp_path):
    out, victim = tmp_path / "out", tmp_path / "victim.txt"
    out.mkdir()
    victim.write_text("keep me")
    os.symlink(victim, out / files.MANIFEST_PART.format("rank0"))
    with pytest.raises(OSError):
        files.append_manifest_part(out, "rank0", {"index": 0, "files": {}})
    assert victim.read_text() == "keep me"


@pytest.mark.parametrize("name", [files.LOCK, files.MANIFEST_PART.format("rank0")])
def test_a_lock_or_manifest_part_with_another_name_is_never_written(tmp_path, name):
    # a hard link (e.g. a `cp -al` backup made after a kill) shares the content: writing in place would change it
    out, backup = tmp_path / "out", tmp_path / "backup.txt"
    out.mkdir()
    backup.write_text("keep me")
    os.link(backup, out / name)
    with pytest.raises(Sin3DMInputError, match="hard links"):
        if name == files.LOCK:
            files.acquire_lock(out)
        else:
            files.append_manifest_part(out, "rank0", {"index": 0, "files": {}})
    assert backup.read_text() == "keep me"


def test_fit_refuses_a_run_folder_holding_a_link(tmp_path, capsys):
    run, victim = tmp_path / "run", tmp_path / "victim.json"
    run.mkdir()
    victim.write_text("{}")
    os.symlink(victim, run / "config.json")
    assert main(["fit", "wall", "--preset", "tiny", "--out", str(run)]) == 2
    assert "config.json" in one_line(capsys)
    assert victim.read_text() == "{}"

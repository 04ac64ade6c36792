"""Who may write where: one writer per folder, ``--overwrite`` of one command replaces only that command's
files, nothing is written before every flag is checked, and a copied folder stays ours (issue 35)."""

import fcntl
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sin3dm_lite import files
from sin3dm_lite.cli import main
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.files import LOCK, MANIFEST, read_manifest

from .conftest import CHEAP_SAMPLE

CHEAP = [*CHEAP_SAMPLE, "--workers", "0"]


def snapshot(root: Path) -> dict:
    return {
        p.relative_to(root).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns) if p.is_file() else "folder"
        for p in root.rglob("*")
    }


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.strip().splitlines() if ": warning: " not in line]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


class HeldLock:
    """Another writer that has created ``folder/.sin3dm-lock`` and holds it, but has not written it yet."""

    def __init__(self, folder: Path):
        folder.mkdir(parents=True, exist_ok=True)
        self.fd = os.open(folder / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)

    def close(self):
        os.close(self.fd)


# --------------------------------------------------------------------------- case 1: one writer per folder
def test_a_lock_created_but_not_yet_written_is_never_taken_over(tmp_path):
    held = HeldLock(tmp_path / "out")
    try:
        with pytest.raises(Sin3DMInputError, match="being written by another sin3dm-lite process"):
            files.acquire_lock(tmp_path / "out", "output folder")
        assert (tmp_path / "out" / LOCK).read_text() == ""  # left to its writer
    finally:
        held.close()
    files.acquire_lock(tmp_path / "out", "output folder")  # its writer died before writing it: provably stale
    files.release_lock(tmp_path / "out")
    assert not (tmp_path / "out" / LOCK).exists()


def test_a_second_writer_arriving_between_create_and_write_is_refused(tmp_path, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    real, seen = files.locks._write_info, []

    def then_another_writer(fd):  # the second `sample` started at the same moment runs here
        if not seen:
            with pytest.raises(Sin3DMInputError, match="being written by another") as e:
                files.acquire_lock(out, "output folder")
            seen.append(str(e.value))
        real(fd)

    monkeypatch.setattr(files.locks, "_write_info", then_another_writer)
    files.acquire_lock(out, "output folder")
    try:
        assert seen and "just starting" in seen[0]
        assert json.loads((out / LOCK).read_text())["pid"] == os.getpid()
    finally:
        files.release_lock(out)


def test_sample_into_a_folder_another_sample_is_starting_to_write_exits_2(work, capsys):
    held = HeldLock(work / "s")
    try:
        before = snapshot(work)
        assert main(["sample", "run", "--out", "s", "-n", "1", *CHEAP]) == 2
        line = one_error_line(capsys)
        assert "output folder 's' is being written by another sin3dm-lite process" in line and "wait" in line, line
        assert snapshot(work) == before
    finally:
        held.close()


def test_calibrate_refuses_a_run_folder_another_process_writes(work, capsys):
    held = HeldLock(work / "run")
    try:
        before = snapshot(work / "run")
        assert main(["calibrate", "run", "-n", "2"]) == 2
        assert "run folder 'run' is being written by another" in one_error_line(capsys)
        assert snapshot(work / "run") == before
    finally:
        held.close()


# --------------------------------------------------------------------------- case 10: a copied folder stays ours
def test_a_copied_samples_folder_continues_and_overwrites(work, capsys):
    (work / "samples" / LOCK).write_text(json.dumps({"pid": dead_pid(), "host": os.uname().nodename, "since": "then"}))
    assert main(["sample", "run", "--out", "samples", "-n", "2", *CHEAP]) == 0  # continued, not "not empty"
    captured = capsys.readouterr()
    assert "1 of the 2 samples are there already" in captured.out
    assert "output folder 'samples' was locked by process" in captured.err and "run folder" not in captured.err
    shutil.copytree(work / "samples", work / "copy")  # `cp -r`: other inodes and times, same content
    assert main(["sample", "run", "--out", "copy", "-n", "2", *CHEAP]) == 0
    assert "0 new samples" in capsys.readouterr().out
    assert main(["sample", "run", "--out", "copy", "-n", "1", "--overwrite", *CHEAP]) == 0
    assert sorted(p.name for p in (work / "copy").iterdir() if p.is_dir()) == ["000"]
    (work / "copy" / "000" / "latent.pt").write_bytes(b"changed by hand")  # other content: no longer ours
    assert not files.is_ours(work / "copy", "000/latent.pt")


# --------------------------------------------------------------------------- case 3: --overwrite replaces only its own
def test_render_overwrite_into_a_samples_folder_keeps_the_samples(work, capsys):
    samples = work / "samples"
    before = {f: (samples / f).read_bytes() for f in read_manifest(samples)}
    assert main(["render", "canyon", "--views", "2", "--size", "16", "--out", "samples", "--overwrite"]) == 0
    assert {f: (samples / f).read_bytes() for f in before} == before  # meshes, latents, index, settings: all there
    ours = read_manifest(samples)
    assert set(before) | {"view_000.png", "view_001.png", "hero.png", "contact_sheet.png"} == set(ours)
    assert main(["sample", "run", "--out", "samples", "-n", "1", *CHEAP]) == 0  # still a samples folder
    assert "0 new samples" in capsys.readouterr().out
    # a render of fewer views replaces its own older pictures only
    assert main(["render", "canyon", "--views", "1", "--size", "16", "--out", "samples", "--overwrite"]) == 0
    assert not (samples / "view_001.png").exists() and (samples / "000" / "mesh.obj").is_file()
    # sample --overwrite starts its samples over and keeps render's pictures, still recorded as render's
    assert main(["sample", "run", "--out", "samples", "-n", "1", *CHEAP, "--steps", "4", "--overwrite"]) == 0
    assert (samples / "view_000.png").is_file() and files.writer(samples, "view_000.png") == "render"
    assert json.loads((samples / "sampling.json").read_text())["settings"]["steps"] == 4


def test_overwrite_never_replaces_another_commands_file(work, capsys):
    before = snapshot(work)
    assert main(["evaluate", "run", "samples", "--out", "samples/sampling.json", "--overwrite"]) == 2
    line = one_error_line(capsys)
    assert "was written by `sin3dm-lite sample`" in line and "choose another --out" in line, line
    assert snapshot(work) == before
    assert main(["examples", "--write", "wall", "--out", "samples"]) == 0
    # sample --overwrite starts over: removes its own samples, keeps what examples wrote there, still recorded as theirs
    assert main(["sample", "run", "--out", "samples", "-n", "1", "--seed", "1", *CHEAP, "--overwrite"]) == 0
    assert {"wall.obj", "wall.mtl", "wall.png"} <= {p.name for p in (work / "samples").iterdir()}
    assert files.writer(work / "samples", "wall.obj") == "examples"
    assert json.loads((work / "samples" / "sampling.json").read_text())["settings"]["seed"] == 1


# --------------------------------------------------------------------------- case 9: check everything before writing
@pytest.mark.parametrize("out", ["s", "samples"])
def test_steps_beyond_the_schedule_write_nothing_and_the_corrected_command_works(work, capsys, out):
    before = snapshot(work)
    # within the setting's range (1,000,000,000 is refused by the parser), beyond this model's schedule
    assert main(["sample", "run", "--out", out, "-n", "1", *CHEAP, "--steps", "5000"]) == 2
    line = one_error_line(capsys)
    assert "--steps 5000" in line and "ask for 1 to 1000" in line, line
    assert snapshot(work) == before
    assert main(["sample", "run", "--out", out, "-n", "1", *CHEAP, "--steps", "5"]) == (0 if out == "s" else 2)


def test_a_sample_run_that_fails_before_its_first_sample_leaves_nothing(work, capsys, monkeypatch):
    from sin3dm_lite.app import mass

    def fails(*args, **kwargs):
        raise Sin3DMInputError("the decoder ran out of memory (stands for any failure)")

    monkeypatch.setattr(mass, "sample_many", fails)
    before = snapshot(work)
    assert main(["sample", "run", "--out", "s", "-n", "1", *CHEAP]) == 2
    assert snapshot(work) == before  # no folder with a sampling.json that blocks the next command
    (work / "full").mkdir()
    (work / "full" / "theirs.txt").write_text("keep")
    assert main(["sample", "run", "--out", "full", "-n", "1", *CHEAP, "--overwrite"]) == 2
    assert sorted(p.name for p in (work / "full").iterdir()) == ["theirs.txt"]


def test_a_folder_whose_run_was_killed_before_its_first_sample_takes_other_settings(work, capsys):
    out = work / "killed"
    out.mkdir()
    files.write_recorded(
        out / "sampling.json",
        json.dumps({"tool": "sin3dm-lite", "kind": "samples", "run": "run", "settings": {"steps": 1000}}),
    )
    (out / LOCK).write_text(json.dumps({"pid": dead_pid(), "host": os.uname().nodename, "since": "then"}))
    assert main(["sample", "run", "--out", "killed", "-n", "1", *CHEAP]) == 0
    assert json.loads((out / "sampling.json").read_text())["settings"]["steps"] == 3
    assert set(read_manifest(out)) == {
        p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file() and p.name != MANIFEST
    }


# --------------------------------------------------------------------------- a link to nothing, the current folder
@pytest.mark.parametrize(
    "argv, out",
    [
        (["fit", "canyon", "--preset", "tiny"], "dangling"),
        (["sample", "run", "-n", "1", *CHEAP], "dangling"),
        (["render", "canyon", "--views", "1", "--size", "16"], "dangling"),
        (["grid", "canyon", "--resolution", "16"], "dangling.npz"),
        (["evaluate", "run", "samples"], "dangling.json"),
        (["examples", "--write", "wall"], "dangling"),
    ],
)
def test_an_out_that_links_to_nothing_is_refused_and_the_link_stays(work, capsys, argv, out):
    (work / out).symlink_to("nowhere" + Path(out).suffix)  # grid and evaluate replaced the link with their file
    before = snapshot(work)
    assert main([*argv, "--out", out]) == 2
    line = one_error_line(capsys)
    assert f"'{out}' is a symbolic link to 'nowhere" in line and "which does not exist" in line, line
    assert os.readlink(work / out) == "nowhere" + Path(out).suffix and snapshot(work) == before


def test_a_fit_makes_its_run_folder_through_a_link_to_an_empty_folder(work, capsys):
    from sin3dm_lite.app.run_folder import prepare_run

    (work / "elsewhere").mkdir()
    (work / "link").symlink_to("elsewhere")  # refused as "Not a directory"
    prepare_run(Path("link"), "tiny", False, None)
    files.release_lock(Path("link"))
    assert (work / "link").is_symlink() and (work / "elsewhere" / "config.json").is_file()
    (work / "empty").mkdir()
    os.chdir(work / "empty")  # `fit --out .` said "Device or resource busy"
    assert main(["fit", "canyon", "--preset", "tiny", "--out", "."]) == 2
    assert "'.' is the current folder" in one_error_line(capsys) and not any((work / "empty").iterdir())


def test_sample_refuses_an_out_that_holds_the_runs_input_mesh(work, capsys):
    """A run fitted to a sample of another run: --overwrite of that folder replaced the run's own input mesh."""
    report = json.loads((work / "run" / "report.json").read_text())
    report["input_path"] = str(work / "samples" / "000" / "mesh.obj")
    (work / "run" / "report.json").write_text(json.dumps(report))
    before = snapshot(work)
    for out in ("samples", "samples/000"):
        assert main(["sample", "run", "--out", out, "-n", "1", *CHEAP, "--seed", "1", "--overwrite"]) == 2
        line = one_error_line(capsys)
        assert f"--out '{out}' contains the run's input mesh" in line and "choose an --out outside it" in line, line
    assert snapshot(work) == before

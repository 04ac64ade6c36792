"""A command that updates a run folder reads and checks everything first, then replaces its files all
or none (issue 60, case 2: ``calibrate`` with a damaged ``report.json`` rewrote ``model.pt`` and then failed)."""

import errno
import shutil

import pytest

from sin3dm_lite.app import checkpoints
from sin3dm_lite.app.pretrained import pretrained_path
from sin3dm_lite.cli import main
from sin3dm_lite.pipeline import Sin3DM


@pytest.fixture
def run(tmp_path):
    shutil.copytree(pretrained_path(), tmp_path / "run")
    return tmp_path / "run"


def contents(run):
    return {p.name: p.read_bytes() for p in sorted(run.iterdir()) if p.is_file()}


@pytest.mark.parametrize("damage", ['{"cut short', "[1, 2, 3]", ""])
def test_calibrate_with_a_damaged_report_changes_nothing_and_says_so(run, capsys, damage):
    (run / "report.json").write_text(damage)
    before = contents(run)
    assert main(["calibrate", str(run), "-n", "2"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert "report.json' is damaged" in err and "nothing in" in err
    assert contents(run) == before


def test_a_failed_write_of_a_runs_files_changes_none_of_them(run, monkeypatch):
    """model.pt is written first; a failure on a later file (a full disk) leaves the old model.pt in place."""
    model = Sin3DM.load(run)
    model.config = model.config.updated(**{"sampling.diversity": 0.77})
    before = contents(run)

    def full_disk(path, data):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(checkpoints, "write_data", full_disk)
    with pytest.raises(OSError):
        checkpoints.write_model(model, run, {"report.json": "{}"})
    assert contents(run) == before
    assert [p.name for p in run.iterdir() if p.name.startswith(".")] == []  # no temporaries left


def test_a_failed_checkpoint_write_is_the_error_reported_not_the_cleanups(tmp_path, monkeypatch):
    """A run folder made read-only during a fit: the checkpoint's write fails first, then the cleanup cannot
    remove the files or the lock either. The user reads the first failure."""
    import pathlib
    import warnings

    from sin3dm_lite.app import fitting

    from .conftest import micro_config

    run = tmp_path / "run"

    def read_only(trainer, path):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    real_unlink = pathlib.Path.unlink

    def no_unlink(self, missing_ok=False):
        if run in self.parents:
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        return real_unlink(self, missing_ok=missing_ok)

    monkeypatch.setattr(fitting, "save_trainer", read_only)
    monkeypatch.setattr(pathlib.Path, "unlink", no_unlink)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # and the cleanup says nothing over it
        with pytest.raises(PermissionError) as e:
            Sin3DM.fit("wall", preset=micro_config(), out=run, progress=False)
    assert e.value.filename.endswith("autoencoder.pt")


def test_calibrate_refuses_a_run_folder_holding_a_link(run, tmp_path, capsys):
    import os

    elsewhere = tmp_path / "kept_config.json"
    (run / "config.json").rename(elsewhere)
    os.symlink(elsewhere, run / "config.json")
    before = elsewhere.read_bytes()
    assert main(["calibrate", str(run), "-n", "2"]) == 2
    assert "symbolic link" in capsys.readouterr().err
    assert elsewhere.read_bytes() == before and (run / "config.json").is_symlink()

"""When the disk fills up or an export worker dies: one line that says what happened and what to do, exit code 2,
finished samples kept, this run's temporary folders removed (issue 35, cases 6 and 7)."""

import errno
import os
import shutil
import signal
import subprocess
import sys
from collections import namedtuple
from concurrent.futures import ProcessPoolExecutor, wait
from pathlib import Path

import pytest
import torch

from sin3dm_lite.app import mass_workers
from sin3dm_lite.app.mass_folder import finished
from sin3dm_lite.app.mass_workers import export_sample as real_export_sample
from sin3dm_lite.app.pretrained import pretrained_path
from sin3dm_lite.cli import main
from sin3dm_lite.files import LOCK, TEMP_PREFIX, save_torch, shown_path
from sin3dm_lite.pipeline import Sin3DM

from .conftest import CHEAP_SAMPLE

RUN = str(pretrained_path())
CHEAP = CHEAP_SAMPLE
TORCH_DISK_FULL = "[enforce fail at inline_container.cc:672] . unexpected pos 1846784 vs 1846672"
SCRIPT = Path(__file__).parents[1] / "scripts" / "run_notebooks.py"

_calls: list[str] = []


def export_then_die(tmp, latent, aabb, model=None, opts=None):
    """Run in the export worker (pickled by reference): export the first sample, then die like the OOM killer."""
    _calls.append(tmp)
    if len(_calls) > 1:
        os.kill(os.getpid(), signal.SIGKILL)
    return real_export_sample(tmp, latent, aabb, model, opts)


def export_no_space(tmp, latent, aabb, model=None, opts=None):
    """Run in the export worker: the disk is full when the texture is written."""
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(Path(tmp) / "mesh.png"))


def _error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if "error:" in line]
    assert len(lines) == 1, err
    return lines[0].split("error: ", 1)[1]


def _no_leftovers(out: Path) -> None:
    assert not [p.name for p in out.rglob("*") if p.name.startswith((TEMP_PREFIX, LOCK))]


class HandOverAfterTheLast(ProcessPoolExecutor):
    """Hands a sample to the worker only once the one before is done: a worker's death is then met when the next
    sample is handed over (`submit` raises), not while a result is awaited."""

    def submit(self, fn, /, *args, **kwargs):
        wait(getattr(self, "given", []))
        self.given = [*getattr(self, "given", []), super().submit(fn, *args, **kwargs)]
        return self.given[-1]


@pytest.mark.parametrize("met", ["awaiting a result", "handing a sample over"])
def test_a_killed_export_worker_is_one_line_and_the_finished_samples_are_kept(tmp_path, monkeypatch, capsys, met):
    monkeypatch.setattr(mass_workers, "export_sample", export_then_die)  # submitted to the worker by reference
    if met == "handing a sample over":
        monkeypatch.setattr(mass_workers, "ProcessPoolExecutor", HandOverAfterTheLast)
    out = tmp_path / "s"
    assert main(["sample", RUN, "-n", "3", "--out", str(out), "--workers", "1", *CHEAP]) == 2
    msg = _error_line(capsys)
    assert msg.startswith("the export worker process died while exporting sample 001")
    assert "the finished sample is kept" in msg and "run the same command again to continue" in msg
    assert set(finished(out)) == {0} and (out / "000" / "mesh.obj").is_file()
    _no_leftovers(out)
    monkeypatch.undo()
    assert main(["sample", RUN, "-n", "3", "--out", str(out), "--workers", "0", *CHEAP]) == 0  # resumes
    assert "1 of the 3 samples are there already; sampling the other 2" in capsys.readouterr().out
    assert set(finished(out)) == {0, 1, 2}


def test_torch_save_on_a_full_disk_is_one_line_and_leaves_no_temporary_folder(tmp_path, monkeypatch, capsys):
    """torch's own error for a full disk is a RuntimeError about 'unexpected pos' (while the worker's model copy is written)."""

    filled = []  # the disk fills while the model copy is written (the run's disk estimate saw room before)

    def full(obj, f, *args, **kwargs):
        Path(f).write_bytes(b"half a file")
        filled.append(f)
        raise RuntimeError(TORCH_DISK_FULL)

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(torch, "save", full)
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10, 10, 0) if filled else usage(1 << 40, 0, 1 << 40))
    out = tmp_path / "s"
    assert main(["sample", RUN, "-n", "2", "--out", str(out), *CHEAP]) == 2  # default workers: model copied first
    assert _error_line(capsys) == (
        f"no space left on device while writing 'model.pt' in '{out}'; free space or choose another --out"
    )
    _no_leftovers(out)


def test_a_full_disk_in_the_export_worker_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(mass_workers, "export_sample", export_no_space)
    out = tmp_path / "s"
    assert main(["sample", RUN, "-n", "2", "--out", str(out), "--workers", "1", *CHEAP]) == 2
    assert _error_line(capsys) == (
        f"no space left on device while writing 'mesh.png' in '{out}'; free space or choose another --out"
    )
    _no_leftovers(out)
    assert not finished(out)


def test_save_torch_turns_torch_write_failures_into_os_errors(tmp_path, monkeypatch):
    monkeypatch.setattr(torch, "save", lambda *a, **k: (_ for _ in ()).throw(RuntimeError(TORCH_DISK_FULL)))
    with pytest.raises(OSError) as e:  # plenty of space: not called a full disk, torch's words quoted
        save_torch({}, tmp_path / "x.pt")
    assert e.value.errno == errno.EIO and "unexpected pos" in e.value.strerror
    monkeypatch.setattr(shutil, "disk_usage", lambda p: namedtuple("usage", "total used free")(10, 10, 0))
    with pytest.raises(OSError) as e:
        Sin3DM.load(RUN).save(tmp_path / "run")  # the library too, not only the CLI
    assert e.value.errno == errno.ENOSPC and shown_path(e.value.filename) == f"'model.pt' in '{tmp_path / 'run'}'"
    assert not list((tmp_path / "run").iterdir())  # atomic: the half-written file is gone
    monkeypatch.setattr(torch, "save", lambda *a, **k: (_ for _ in ()).throw(RuntimeError("something else")))
    with pytest.raises(RuntimeError, match="something else"):  # not a write failure: left alone
        save_torch({}, tmp_path / "x.pt")


def test_a_failed_write_names_the_file_not_its_temporary(tmp_path):
    from sin3dm_lite.files import atomic_path

    with pytest.raises(OSError) as e, atomic_path(tmp_path / "mesh.obj") as tmp:
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp))  # what a full disk raises mid-write
    assert shown_path(e.value.filename) == f"'mesh.obj' in '{tmp_path}'"
    assert not list(tmp_path.iterdir())


def test_a_real_full_disk(tmp_path):
    """A 2 MB tmpfs (needs root and `unshare`; skipped elsewhere): the model copy does not fit."""
    if shutil.which("unshare") is None or os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root and unshare")
    disk = tmp_path / "disk"
    disk.mkdir()
    cmd = (
        f"mount -t tmpfs -o size=2m tmpfs {disk} || exit 99; {sys.executable} -m sin3dm_lite.cli sample {RUN} "
        f"-n 2 --out {disk}/s {' '.join(CHEAP)}; echo rc=$?; ls -A {disk}/s"
    )
    r = subprocess.run(
        ["unshare", "-m", "sh", "-c", cmd],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    if r.returncode == 99 or "rc=" not in r.stdout:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()[-200:]}")
    assert "rc=2" in r.stdout and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert f"error: no space left on device while writing 'model.pt' in '{disk}/s'; free space" in r.stderr
    assert TEMP_PREFIX not in r.stdout  # the listing of s/: no temporary folder left


def test_a_notebook_whose_write_fails_is_left_whole(tmp_path):
    """``scripts/run_notebooks.py --clear`` (or a run) on a full disk: nbformat.write emptied the notebook first, then failed."""
    import nbformat

    nb = nbformat.v4.new_notebook()
    cell = nbformat.v4.new_code_cell("x = 1\n" * 4000)  # cleared, still larger than the files this process may write
    cell.outputs = [nbformat.v4.new_output("stream", text="1\n" * 100)]
    nb.cells.append(cell)
    nbformat.write(nb, tmp_path / "big.ipynb")
    before = (tmp_path / "big.ipynb").read_bytes()
    code = (
        "import resource, signal, sys; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); "
        "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096)); sys.argv = ['run_notebooks.py', '--clear', "
        f"'big.ipynb']; import runpy; runpy.run_path({str(SCRIPT)!r}, run_name='__main__')"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert "File too large 'big.ipynb'" in r.stderr
    assert (tmp_path / "big.ipynb").read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["big.ipynb"]  # no temporary left

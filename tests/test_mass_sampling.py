"""Mass generation: per-sample seeds, two processes under torchrun, a killed run continued, one sample drawn again."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from sin3dm_lite.app.pretrained import pretrained_path
from sin3dm_lite.files import LOCK, MANIFEST, TEMP_PREFIX, manifest_parts, read_manifest
from sin3dm_lite.pipeline import Sin3DM

from .conftest import CHEAP_SAMPLE

RUN = str(pretrained_path())
SMALL = CHEAP_SAMPLE
N = 4
ENV = {**os.environ, "OMP_NUM_THREADS": "1"}


def _cli(*argv, torchrun: int = 0, **kw) -> subprocess.Popen:
    launcher = []
    if torchrun:
        with socket.socket() as s:  # a free port for the rendezvous
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        launcher = ["-m", "torch.distributed.run", f"--nproc_per_node={torchrun}", f"--master_port={port}"]
    return subprocess.Popen(
        [sys.executable, *launcher, "-m", "sin3dm_lite.cli", *argv],
        env=ENV,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kw,
    )


def _ok(p: subprocess.Popen, timeout=600) -> str:
    out, err = p.communicate(timeout=timeout)
    assert p.returncode == 0, err[-3000:]
    return out


def _run(capsys, *argv) -> tuple[int, str, str]:
    """The CLI in this process (no interpreter and torch to start): exit code, stdout, stderr."""
    from sin3dm_lite.cli import main

    capsys.readouterr()
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _run_ok(capsys, *argv) -> str:
    code, out, err = _run(capsys, *argv)
    assert code == 0, err[-3000:]
    return out


def _latent(folder: Path, i: int) -> dict:
    return torch.load(folder / f"{i:03d}" / "latent.pt", weights_only=True)["triplane"]


def _same(a: dict, b: dict) -> bool:
    return all(torch.allclose(a[k], b[k], atol=1e-5) for k in ("xy", "xz", "yz"))


def _check_folder(out: Path, indices) -> list[dict]:
    """samples.jsonl holds each index once; the folders are exactly those; the manifest lists exactly the files."""
    records = [json.loads(line) for line in (out / "samples.jsonl").read_text().splitlines()]
    assert [r["index"] for r in records] == list(indices)
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == [f"{i:03d}" for i in indices]
    files = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file() and p.name != MANIFEST}
    assert set(read_manifest(out)) == files
    assert set().union(*(r["files"] for r in records)) == {f for f in files if "/" in f}
    assert not [p for p in out.rglob("*") if p.name.startswith((TEMP_PREFIX, LOCK))] and not manifest_parts(out)
    return records


@pytest.fixture(scope="module")
def one_process(tmp_path_factory):
    """The reference: one process (this one), batches of 3 (so batch composition differs from the two-process run)."""
    from sin3dm_lite.cli import main

    out = tmp_path_factory.mktemp("mass") / "one"
    assert main(["sample", RUN, "-n", str(N), "--out", str(out), "--batch", "3", *SMALL]) == 0
    return out


def test_a_sample_depends_on_its_seed_only_not_on_its_batch():
    model = Sin3DM.load(RUN)
    for kw in ({}, {"regenerate": ((0.2, 0.0, 0.0), (0.6, 1.0, 1.0))}, {"method": "ddpm", "diversity": 0.03}):
        batch = model.sample(3, seed=5, steps=4, progress=False, **kw).triplane
        alone = model.sample(1, seed=7, steps=4, progress=False, **kw).triplane
        listed = model.sample(2, seed=[7, 5], steps=4, progress=False, **kw).triplane
        assert all(torch.allclose(p[2:3], q, atol=1e-5) for p, q in zip(batch.planes, alone.planes)), kw
        assert all(torch.allclose(p[0:1], q[1:2], atol=1e-5) for p, q in zip(batch.planes, listed.planes)), kw
        assert not torch.allclose(batch.xy[0], batch.xy[1]), kw


def test_one_process_writes_every_index_once(one_process):
    records = _check_folder(one_process, range(N))
    assert [r["seed"] for r in records] == list(range(N))
    assert json.loads((one_process / "sampling.json").read_text())["settings"]["seed"] == 0


def test_two_processes_with_gloo_give_the_same_samples(one_process, tmp_path):
    out = tmp_path / "two"
    _ok(_cli("sample", RUN, "-n", str(N), "--out", str(out), *SMALL, torchrun=2))
    records = _check_folder(out, range(N))
    assert {r["rank"] for r in records} == {0, 1}
    for i in range(N):
        assert _same(_latent(out, i), _latent(one_process, i)), i


def test_one_sample_drawn_again_alone_is_the_same(one_process, tmp_path, capsys):
    out = tmp_path / "again"
    _run_ok(capsys, "sample", RUN, "--start", "2", "-n", "1", "--out", str(out), *SMALL)
    _check_folder(out, [2])
    assert _same(_latent(out, 2), _latent(one_process, 2))


def test_a_killed_run_continues_and_ends_with_every_index_once(one_process, tmp_path, capsys):
    out = tmp_path / "killed"
    argv = ["sample", RUN, "-n", str(N), "--out", str(out), "--batch", "1", "--workers", "0", *SMALL]
    p = _cli(*argv)
    t0 = time.monotonic()
    while p.poll() is None and time.monotonic() - t0 < 300:  # kill once two samples are done
        lines = sum(len(part.read_text().splitlines()) for part in manifest_parts(out)) if out.is_dir() else 0
        if lines >= 2 and (out / "001").is_dir():  # a sample's line is written before its folder moves into place
            break
        time.sleep(0.02)
    p.send_signal(signal.SIGKILL)
    p.communicate(timeout=120)
    assert p.returncode == -signal.SIGKILL, "the run ended before it was killed; make it slower"
    (out / "000" / "mesh.glb").unlink(missing_ok=True)  # as if killed while that folder was written: redone
    text = _run_ok(capsys, *argv)  # another process (this one) continues the killed one's folder
    assert "already" in text
    _check_folder(out, range(N))
    for i in range(N):
        assert _same(_latent(out, i), _latent(one_process, i)), i
    assert "0 new samples" in _run_ok(capsys, *argv)  # all there: nothing to do
    more = _run_ok(capsys, *argv[:2], "-n", str(N + 1), *argv[4:])  # -n grows: the folder grows
    assert "1 new samples" in more
    _check_folder(out, range(N + 1))


def test_other_settings_are_refused_and_overwrite_starts_over(one_process, tmp_path, capsys):
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(one_process, out)  # new times: the files are still ours by their content
    code, _, err = _run(capsys, "sample", RUN, "-n", "2", "--out", str(out), *SMALL, "--steps", "4")
    assert code == 2 and "other settings (steps: 3 there, 4 now)" in err and len(err.strip().splitlines()) == 1
    (out / "theirs.txt").write_text("keep")
    _run_ok(capsys, "sample", RUN, "-n", "2", "--out", str(out), *SMALL, "--steps", "4", "--overwrite")
    assert (out / "theirs.txt").read_text() == "keep"
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ["000", "001"]
    assert json.loads((out / "sampling.json").read_text())["settings"]["steps"] == 4


PARENT = """
import multiprocessing, os, time
from concurrent.futures import ProcessPoolExecutor
from sin3dm_lite.app.mass_workers import exit_with_parent
pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=exit_with_parent)
print(pool.submit(os.getpid).result(), flush=True)
time.sleep(600)
"""


def test_an_export_worker_ends_with_its_killed_parent():
    # `sample` killed with SIGKILL (or by the OOM killer) while its export worker waited for work: the worker, holding
    # a CPU copy of the model and the terminal's (or a test's) output pipes, used to wait for the next job forever
    p = subprocess.Popen(
        [sys.executable, "-c", PARENT], env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    worker = int(p.stdout.readline())  # the worker is idle now, waiting for the next job
    try:
        p.send_signal(signal.SIGKILL)
        p.communicate(timeout=60)  # EOF on the pipes: the worker, which holds them too, has ended
    finally:
        try:
            os.kill(worker, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert p.returncode == -signal.SIGKILL


def test_the_export_workers_watch_their_parent(monkeypatch, tmp_path):
    from sin3dm_lite.app import mass_workers

    calls = []
    monkeypatch.setattr(mass_workers, "exit_with_parent", lambda: calls.append("watch"))
    monkeypatch.setattr(Sin3DM, "load", staticmethod(lambda path, device: calls.append(("load", path, device))))
    monkeypatch.setattr(mass_workers, "_WORKER", {})
    mass_workers._worker_init(str(tmp_path / "model.pt"), {})
    assert calls == ["watch", ("load", str(tmp_path / "model.pt"), "cpu")]


def test_sigterm_ends_like_ctrl_c_and_leaves_nothing_outside_out(tmp_path):
    """`kill PID` during a run with export workers: one line (what was kept, how to continue), exit 143, no
    multiprocessing leftovers (no `pymp-*` in the temporary folder, no leaked-semaphore warning), and the same
    command continues."""
    import tempfile

    out = tmp_path / "termed"
    tmp = Path(tempfile.mkdtemp(prefix="t", dir="/tmp" if os.path.isdir("/tmp") else None))  # a socket's path is short
    argv = ["sample", RUN, "-n", "6", "--out", str(out), "--batch", "1", "--workers", "1", *SMALL]
    p = subprocess.Popen(
        [sys.executable, "-m", "sin3dm_lite.cli", *argv],
        env={**ENV, "TMPDIR": str(tmp)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    t0 = time.monotonic()
    while p.poll() is None and time.monotonic() - t0 < 300 and not (out / "000").is_dir():
        time.sleep(0.02)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 143, err
    lines = [line for line in err.strip().splitlines() if "it/s]" not in line and "mesh/s]" not in line]
    assert "Traceback" not in err and "leaked" not in err, err
    assert "terminated: the" in lines[-1] and "finished samples" in lines[-1] and "same command again" in lines[-1]
    assert list(tmp.iterdir()) == []
    tmp.rmdir()
    assert not [p for p in out.iterdir() if p.name.startswith(".sin3dm-tmp-")]
    assert (
        subprocess.run([sys.executable, "-m", "sin3dm_lite.cli", *argv], env=ENV, capture_output=True).returncode == 0
    )
    _check_folder(out, range(6))


def test_multiprocessing_temporaries_of_a_killed_run_are_removed_by_the_next(tmp_path, monkeypatch):
    """`kill -9` leaves the pool's temporary folder; the next run removes it (a live process's stays)."""
    import tempfile

    from sin3dm_lite.app import mass_workers
    from sin3dm_lite.files import machine_tag

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    here = machine_tag()
    stale, live = tmp_path / f"sin3dm-mp-{dead.pid}@{here}-x", tmp_path / f"sin3dm-mp-{os.getppid()}@{here}-y"
    old, elsewhere = tmp_path / f"sin3dm-mp-{dead.pid}-z", tmp_path / f"sin3dm-mp-{dead.pid}@0badcafe-w"
    for folder in (stale, live, old, elsewhere):
        folder.mkdir()
    mine = mass_workers.own_mp_temps()
    try:  # another machine's (a shared temporary folder) stays: its PID means nothing here
        assert not stale.exists() and not old.exists() and live.is_dir() and elsewhere.is_dir()
        assert mine.parent == tmp_path and mine.name.startswith(f"sin3dm-mp-{os.getpid()}@{here}-")
    finally:
        mass_workers.drop_mp_temps(mine)
    assert not mine.exists()

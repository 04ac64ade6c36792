"""Bad input and faults: every command × every class of bad input exits 2 with one line and writes nothing.

Also: ``--overwrite`` keeps foreign files, the run-folder lock, and SIGKILLed
``sample``/``fit`` runs after which the next run succeeds with nothing stale left.
"""

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from sin3dm_lite.app.pretrained import pretrained_path, shipped_model
from sin3dm_lite.cli import main
from sin3dm_lite.examples import list_examples
from sin3dm_lite.files import LOCK, MANIFEST, TEMP_PREFIX, read_manifest

from .conftest import CHEAP_SAMPLE

SHIPPED = pretrained_path()
UNSHIPPED = next((name for name in list_examples() if shipped_model(name) is None), None)
SMALL = CHEAP_SAMPLE[:-1]  # with pictures (the tests that need none say --no-pictures)
# `tiny` on a coarser grid with fewer points and 50 denoiser steps: still 150 autoencoder steps with a checkpoint
# every 50, so that a kill 1.5 s after the first checkpoint lands in the training
LIGHT_FIT = [
    "--preset",
    "tiny",
    "--set",
    "grid.resolution=24",
    "grid.n_surface_points=5000",
    "autoencoder.points_per_step=1024",
    "diffusion.steps=50",
]


class RunsCode:
    """A pickle that would run ``touch PWNED`` when unpickled without weights_only."""

    def __reduce__(self):
        return (os.system, ("touch PWNED",))


def _obj(path: Path, vertices, faces) -> None:
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices] + [f"f {a} {b} {c}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def template(tmp_path_factory):
    """Inputs of every kind, built once; each test works on its own copy."""
    root = tmp_path_factory.mktemp("inputs")
    trimesh.creation.box().export(root / "box.obj")
    _obj(root / "sliver.obj", [(0, 0, 0), (1, 0, 0), (0, 1e-4, 0)], [(1, 2, 3)])  # flat, and narrower than a voxel
    tet = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
    _obj(root / "huge.obj", tet[:3] + [(0, 0, 1e300)], [(1, 3, 2), (1, 2, 4), (2, 3, 4), (1, 4, 3)])
    _obj(
        root / "overflow.obj",
        tet + [(-1e308, 0, 0), (1e308, 0, 0)],
        [(1, 3, 2), (1, 2, 4), (2, 3, 4), (1, 4, 3), (5, 6, 3)],
    )
    shutil.copytree(SHIPPED, root / "run")
    model = (root / "run" / "model.pt").read_bytes()
    bundle = torch.load(root / "run" / "model.pt", weights_only=True)
    bad = {
        "truncated": model[: len(model) // 2],
        "random": np.random.default_rng(0).bytes(4096),
    }
    for name, data in bad.items():
        (root / name).mkdir()
        (root / name / "model.pt").write_bytes(data)
    for name, obj in {
        "code": {"format": "sin3dm-lite/1", "x": RunsCode()},
        "missing": {k: v for k, v in bundle.items() if k != "denoiser"},
        "version": {**bundle, "format": "sin3dm-lite/0"},
        "notdict": [torch.zeros(3)],
    }.items():
        (root / name).mkdir()
        torch.save(obj, root / name / "model.pt")
    # a fit run folder whose autoencoder checkpoint is random bytes (for --resume)
    (root / "badresume").mkdir()
    shutil.copy(root / "run" / "config.json", root / "badresume" / "config.json")
    (root / "badresume" / "autoencoder.pt").write_bytes(bad["random"])
    # run folders with trainer checkpoints in the layouts of older versions (before the shared trainer format)
    old_layouts = {
        "autoencoder": {
            "model": {},
            "opt": {},
            "sched": {},
            "gen": torch.zeros(8, dtype=torch.uint8),
            "step": 3,
            "history": {"loss": torch.zeros(3, dtype=torch.float64)},
        },
        "diffusion": {
            "model": {},
            "ema": None,
            "optimizer": {},
            "scheduler": {},
            "generator": torch.zeros(8, dtype=torch.uint8),
            "step_count": 3,
            "history": [0.1, 0.1, 0.1],
            "config": {},
            "seed": 0,
            "h0": {},
        },
    }
    for kind, old in old_layouts.items():
        (root / f"old{kind}").mkdir()
        shutil.copy(root / "run" / "config.json", root / f"old{kind}" / "config.json")
        torch.save(old, root / f"old{kind}" / f"{kind}.pt")
    (root / "full").mkdir()
    (root / "full" / "theirs.txt").write_text("not ours")
    (root / "blocker").write_text("a file where a folder is expected")
    (root / "neighbour.txt").write_text("beside --out")
    (root / "grid.npz").write_bytes(b"someone else's grid")
    (root / "report.json").write_text("{}")  # someone else's report
    # a folder of samples (settings: 3 steps, no pictures) for "other settings" rows
    assert (
        main(
            [
                "sample",
                str(root / "run"),
                "--out",
                str(root / "samples"),
                "-n",
                "1",
                "--workers",
                "0",
                "--no-pictures",
                *SMALL,
            ]
        )
        == 0
    )
    (root / "badsamples" / "000").mkdir(parents=True)
    (root / "badsamples" / "000" / "mesh.obj").write_text("not a mesh\n")
    return root


# ``work``: tests/conftest.py's, a copy of this module's ``template`` as the working folder


def snapshot(root: Path) -> dict:
    """Every path under ``root``, with the size and modification time of files."""
    return {
        p.relative_to(root).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns) if p.is_file() else "folder"
        for p in root.rglob("*")
    }


NOT_WRITABLE = "/proc/sin3dm-out"  # refused even for root

CASES = {
    # sample
    "sample-anchor-alone": (["sample", "run", "--out", "s", "--anchor", "x-"], "needs --outpaint"),
    "sample-device": (["sample", "run", "--out", "s", "--device", "gpu"], "device"),
    "sample-cuda-index": (["sample", "run", "--out", "s", "--device", "cuda:99"], "cuda"),
    "sample-huge-n": (["sample", "run", "--out", "s", "-n", "1000000000"], "at most"),
    "sample-batch-beyond-memory": (
        ["sample", "run", "--out", "s", "--batch", "9000", "--resize", "8", "8", "8"],
        "fit in memory",
    ),
    "sample-start-beyond-limit": (["sample", "run", "--out", "s", "--start", "999999", "-n", "5"], "at most"),
    "sample-negative-start": (["sample", "run", "--out", "s", "--start", "-1"], "0 or more"),
    "sample-zero-batch": (["sample", "run", "--out", "s", "--batch", "0"], "positive"),
    "sample-negative-workers": (["sample", "run", "--out", "s", "--workers", "-2"], "0 or more"),
    "sample-other-settings": (
        ["sample", "run", "--out", "samples", "-n", "1", *SMALL, "--steps", "4", "--no-pictures"],
        "other settings (steps: 3 there, 4 now)",
    ),
    # issue 35: --texture-size 100000 ran 3 minutes into 11 GB, --mesh-resolution 100000 was an ArrayMemoryError
    "sample-huge-texture": (
        ["sample", "run", "--out", "s", "--texture-size", "100000"],
        "--texture-size 100000 is too large: at most",
    ),
    "sample-huge-mesh-resolution": (
        ["sample", "run", "--out", "s", "--mesh-resolution", "100000"],
        "--mesh-resolution 100000 is too large: at most",
    ),
    "sample-texture-too-small": (
        ["sample", "run", "--out", "s", "--texture-size", "8"],
        "argument --texture-size: expected a whole number of at least 16, got 8",
    ),
    "sample-steps-beyond-schedule": (["sample", "run", "--out", "s", "--steps", "5000"], "1000 time steps"),
    "sample-too-few-faces": (
        ["sample", "run", "--out", "s", "--faces", "2"],
        "argument --faces: expected a whole number from 4 to",
    ),
    "demo-huge-texture-many-workers": (
        ["demo", "--out", "s", "--texture-size", "16000", "--workers", "64"],
        "64 exports at once (--workers)",
    ),
    # issue 35: the error spoke of resize factors
    "sample-outpaint-negative": (
        ["sample", "run", "--out", "s", "--outpaint", "-1", "1", "1"],
        "outpaint factors must be from 1 to 8",
    ),
    "sample-outpaint-shrinks": (
        ["sample", "run", "--out", "s", "--outpaint", "0.5", "1", "1"],
        "outpaint factors must be from 1 to 8",
    ),
    "sample-negative-seed": (["sample", "run", "--out", "s", "--seed", "-1"], "seed"),
    "sample-truncated": (["sample", "truncated", "--out", "s"], "not made by this version"),
    "sample-random-bytes": (["sample", "random", "--out", "s"], "not made by this version"),
    "sample-pickled-code": (["sample", "code", "--out", "s"], "not made by this version"),
    "sample-missing-keys": (["sample", "missing", "--out", "s"], "'denoiser' is missing"),
    "sample-other-version": (["sample", "version", "--out", "s"], "sin3dm-lite/0"),
    "sample-not-a-dict": (["sample", "notdict", "--out", "s"], "not made by this version"),
    "sample-out-is-run": (["sample", "run", "--out", "run"], "run folder"),
    "sample-out-inside-run": (["sample", "run", "--out", "run/samples"], "inside the run folder"),
    "sample-out-contains-run": (["sample", "run", "--out", "."], "contains the run folder"),
    "sample-out-not-empty": (["sample", "run", "--out", "full"], "--overwrite"),
    "sample-out-is-file": (["sample", "run", "--out", "neighbour.txt"], "is a file"),
    "sample-out-under-file": (["sample", "run", "--out", "blocker/s"], "is a file"),
    "sample-out-not-writable": (["sample", "run", "--out", NOT_WRITABLE], "cannot write"),
    # demo (the shipped model)
    "demo-device": (["demo", "--out", "s", "--device", "tpu"], "device"),
    "demo-huge-n": (["demo", "--out", "s", "-n", "99999999"], "at most"),
    "demo-out-not-empty": (["demo", "--out", "full"], "--overwrite"),
    "demo-out-inside-shipped": (["demo", "--out", str(SHIPPED / "s")], "shipped model"),
    "demo-out-not-writable": (["demo", "--out", NOT_WRITABLE], "cannot write"),
    "demo-unknown-example": (["demo", "--example", "teapot", "--out", "s"], "unknown example 'teapot'"),
}
if UNSHIPPED is not None:  # an example without a shipped model, while there is one
    CASES["demo-example-not-shipped"] = (["demo", "--example", UNSHIPPED, "--out", "s"], "(shipped: canyon")
CASES |= {
    # fit
    "fit-device": (["fit", "box.obj", "--preset", "tiny", "--out", "r", "--device", "gpu"], "device"),
    "fit-negative-seed": (["fit", "box.obj", "--preset", "tiny", "--out", "r", "--seed", "-3"], "seed"),
    "fit-sliver": (["fit", "sliver.obj", "--preset", "tiny", "--out", "r"], "no inside"),
    "fit-huge-vertex": (["fit", "huge.obj", "--preset", "tiny", "--out", "r"], "too large"),
    "fit-overflowing-box": (["fit", "overflow.obj", "--preset", "tiny", "--out", "r"], "too large"),
    "fit-out-contains-mesh": (["fit", "box.obj", "--preset", "tiny", "--out", "."], "input mesh"),
    # a folder of the user's is no fit to resume: a new or empty one (issue 35: the message suggested --resume)
    "fit-out-not-empty": (
        ["fit", "box.obj", "--preset", "tiny", "--out", "full"],
        "--out 'full' is not empty and holds no fit of sin3dm-lite; choose a new or empty folder",
    ),
    "fit-out-is-a-run": (
        ["fit", "box.obj", "--preset", "tiny", "--out", "run"],
        "holds a fit; continue it with --resume",
    ),
    "fit-resume-not-a-run": (["fit", "box.obj", "--out", "full", "--resume"], "'full' is not a fit's run folder"),
    # issue 35: resuming a canyon run with a cube said "fit done" and mixed the two
    "fit-resume-other-mesh": (
        ["fit", "box.obj", "--preset", "tiny", "--resume", "--out", "run"],
        "cannot resume: 'run' was fitted to 'canyon', not 'box.obj'; resume it with that input",
    ),
    "fit-resume-other-preset": (
        ["fit", "canyon", "--preset", "tiny", "--resume", "--out", "run"],
        "other settings (preset 'small' there, 'tiny' now)",
    ),
    "fit-out-under-file": (["fit", "box.obj", "--preset", "tiny", "--out", "blocker/r"], "is a file"),
    "fit-out-not-writable": (["fit", "box.obj", "--preset", "tiny", "--out", NOT_WRITABLE], "cannot write"),
    "fit-set-negative-steps": (
        ["fit", "box.obj", "--preset", "tiny", "--out", "r", "--set", "autoencoder.steps=-5"],
        "'autoencoder.steps' must be a whole number from 1 to",
    ),
    "fit-set-zero-steps": (
        ["fit", "box.obj", "--preset", "tiny", "--out", "r", "--set", "diffusion.steps=0"],
        "'diffusion.steps' must be a whole number from 1 to",
    ),
    "fit-set-diversity": (
        ["fit", "box.obj", "--preset", "tiny", "--out", "r", "--set", "sampling.diversity=5"],
        "must be a number from 0 to 1",
    ),
    "fit-set-unknown-section": (
        ["fit", "box.obj", "--preset", "tiny", "--out", "r", "--set", "nosuch.key=1"],
        "unknown config setting 'nosuch.key'; settings are SECTION.NAME",
    ),
    "fit-resume-missing": (["fit", "box.obj", "--out", "nothing", "--resume"], "resume"),
    "fit-resume-bad-checkpoint": (["fit", "box.obj", "--out", "badresume", "--resume"], "not made by this version"),
    "fit-resume-old-autoencoder-checkpoint": (
        ["fit", "box.obj", "--out", "oldautoencoder", "--resume"],
        "older version",
    ),
    "fit-resume-old-diffusion-checkpoint": (["fit", "box.obj", "--out", "olddiffusion", "--resume"], "older version"),
    # grid
    "grid-sliver": (["grid", "sliver.obj", "--resolution", "32", "--out", "g.npz"], "no inside"),
    "grid-huge-vertex": (["grid", "huge.obj", "--resolution", "32", "--out", "g.npz"], "too large"),
    "grid-overflowing-box": (["grid", "overflow.obj", "--resolution", "32", "--out", "g.npz"], "too large"),
    "grid-out-exists": (["grid", "box.obj", "--resolution", "32", "--out", "grid.npz"], "--overwrite"),
    "grid-out-foreign-overwrite": (
        ["grid", "box.obj", "--resolution", "32", "--out", "grid.npz", "--overwrite"],
        "not written by sin3dm-lite",
    ),
    "grid-out-under-file": (["grid", "box.obj", "--out", "blocker/g.npz"], "is a file"),
    "grid-out-not-writable": (["grid", "box.obj", "--out", NOT_WRITABLE + ".npz"], "cannot write"),
    # examples
    "examples-unknown": (["examples", "--write", "teapot", "--out", "e"], "unknown example"),
    "examples-negative-seed": (["examples", "--write", "wall", "--out", "e", "--seed", "-1"], "seed"),
    "examples-out-under-file": (["examples", "--write", "wall", "--out", "blocker/e"], "is a file"),
    "examples-out-not-writable": (["examples", "--write", "wall", "--out", NOT_WRITABLE], "cannot write"),
    # render
    "render-missing-mesh": (["render", "nosuch.obj", "--out", "v"], "nosuch.obj"),
    "render-unknown-name": (["render", "teapot", "--out", "v"], "neither a mesh file nor a built-in example"),
    "render-size-too-small": (["render", "box.obj", "--size", "8", "--out", "v"], "--size"),
    "render-too-many-views": (["render", "box.obj", "--views", "1000", "--out", "v"], "--views"),
    "render-elevation": (["render", "box.obj", "--elevation", "90", "--out", "v"], "--elevation"),
    "render-out-not-empty": (["render", "box.obj", "--out", "full"], "--overwrite"),
    "render-out-foreign-overwrite": (["render", "box.obj", "--out", ".", "--overwrite"], "input mesh"),
    "render-out-is-file": (["render", "box.obj", "--out", "neighbour.txt"], "is a file"),
    "render-out-under-file": (["render", "box.obj", "--out", "blocker/v"], "is a file"),
    "render-out-not-writable": (["render", "box.obj", "--out", NOT_WRITABLE], "cannot write"),
    # calibrate (issue 35: a file that is no run folder was "not found")
    "calibrate-file-not-a-run": (
        ["calibrate", "box.obj"],
        "'box.obj' is a file, not a run folder: a run folder is what",
    ),
    "calibrate-unknown-run": (["calibrate", "nosuch"], "run folder 'nosuch' not found"),
    "sample-run-is-a-file": (["sample", "neighbour.txt", "--out", "s"], "is a file, not a run folder"),
    # evaluate
    "evaluate-unknown-run": (["evaluate", "nosuch", "badsamples"], "run folder 'nosuch' not found"),
    "evaluate-missing-samples": (["evaluate", "run", "nosuch"], "samples folder 'nosuch' not found"),
    "evaluate-samples-is-file": (["evaluate", "run", "box.obj"], "is a file"),
    "evaluate-empty-samples": (["evaluate", "run", "full"], "no sample meshes"),
    "evaluate-unreadable-mesh": (["evaluate", "run", "badsamples"], "cannot read sample mesh"),
    "evaluate-missing-weights": (["evaluate", "run", "badsamples", "--weights", "."], "pt_inception"),
    "evaluate-no-weights-folder": (["evaluate", "run", "badsamples", "--weights", "nowhere"], "weights folder"),
    "evaluate-size": (["evaluate", "run", "badsamples", "--size", "8"], "--size"),
    "evaluate-resolution": (["evaluate", "run", "badsamples", "--resolution", "1000"], "--resolution"),
    "evaluate-out-not-json": (["evaluate", "run", "badsamples", "--out", "e.txt"], ".json"),
    "evaluate-out-exists": (["evaluate", "run", "badsamples", "--out", "report.json"], "--overwrite"),
    "evaluate-out-foreign-overwrite": (
        ["evaluate", "run", "badsamples", "--out", "report.json", "--overwrite"],
        "not written by sin3dm-lite",
    ),
    "evaluate-out-inside-run": (["evaluate", "run", "badsamples", "--out", "run/e.json"], "inside the run folder"),
    "evaluate-out-under-file": (["evaluate", "run", "badsamples", "--out", "blocker/e.json"], "is a file"),
    "evaluate-out-not-writable": (["evaluate", "run", "badsamples", "--out", NOT_WRITABLE + ".json"], "cannot write"),
}


PARSER_CASES = (
    "seed",
    "negative-start",
    "zero-batch",
    "negative-workers",
    "outpaint",
    "texture-too-small",
    "too-few-faces",
)  # refused by argparse (SystemExit)


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_exits_2_with_one_line_and_writes_nothing(work, capsys, case):
    argv, words = CASES[case]
    before = snapshot(work)
    by_parser = any(w in case for w in PARSER_CASES)
    with pytest.raises(SystemExit) if by_parser else _nothing() as e:
        code = main(argv)
    if by_parser:  # found by the parser
        code = e.value.code
    err = capsys.readouterr().err
    lines = [line for line in err.strip().splitlines() if ": warning: " not in line]
    assert code == 2, err
    assert len(lines) == 1 and "Traceback" not in err, err
    assert words is None or words in lines[0], lines[0]
    assert "weights_only=False" not in err
    assert snapshot(work) == before  # nothing written, nothing beside --out touched
    assert not (work / "PWNED").exists()  # the pickled code never ran
    assert not [p for p in Path(work).rglob(".sin3dm-*") if p.name != MANIFEST]  # the template's "samples" has one


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_sample_keeps_foreign_files_and_replaces_only_its_own(work, capsys):
    out = work / "full"  # holds theirs.txt
    assert main(["sample", "run", "--out", str(out), "-n", "2", *SMALL]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["theirs.txt"]
    (out / "notes").mkdir()
    (out / "notes" / "mine.md").write_text("keep me")
    assert main(["sample", "run", "--out", str(out), "-n", "2", "--overwrite", *SMALL]) == 0
    ours = set(read_manifest(out))
    assert {"000/mesh.obj", "001/mesh.glb", "index.html"} <= ours and "theirs.txt" not in ours
    assert (out / "theirs.txt").read_text() == "not ours" and (out / "notes" / "mine.md").read_text() == "keep me"
    # fewer samples: our old 001 goes, the foreign files stay
    (out / "000" / "their_edit.blend").write_text("a foreign file inside one of our folders")
    assert main(["sample", "run", "--out", str(out), "-n", "1", "--overwrite", *SMALL]) == 0
    assert not (out / "001").exists() and (out / "000" / "mesh.obj").is_file()
    assert (out / "000" / "their_edit.blend").is_file() and (out / "theirs.txt").is_file()
    pictures = {"contact_sheet.png"} if (out / "contact_sheet.png").exists() else set()  # none without EGL
    assert set(read_manifest(out)) == (
        {f"000/{p.name}" for p in (out / "000").iterdir() if p.name != "their_edit.blend"}
        | {"index.html", "sampling.json", "samples.jsonl"}
        | pictures
    )
    # a foreign file exactly where a new output goes is never replaced
    (out / "index.html").unlink()
    (out / "index.html").write_text("their page")
    before = snapshot(out)
    assert main(["sample", "run", "--out", str(out), "-n", "1", "--overwrite", *SMALL]) == 2
    assert "index.html" in capsys.readouterr().err and snapshot(out) == before
    assert not [p for p in work.rglob(f"{TEMP_PREFIX}*")]


def test_grid_and_examples_overwrite_only_their_own(work, capsys):
    assert main(["grid", "box.obj", "--resolution", "16", "--out", "g/grid.npz"]) == 0
    assert main(["grid", "box.obj", "--resolution", "16", "--out", "g/grid.npz"]) == 2  # exists
    assert main(["grid", "box.obj", "--resolution", "24", "--out", "g/grid.npz", "--overwrite"]) == 0
    with np.load(work / "g" / "grid.npz") as z:
        assert z["sdf"].shape[0] == 24
    assert main(["examples", "--write", "wall", "--out", "e"]) == 0
    assert main(["examples", "--write", "wall", "--out", "e"]) == 2
    (work / "e" / "wall.png").unlink()
    (work / "e" / "wall.png").write_bytes(b"their picture")
    assert main(["examples", "--write", "wall", "--out", "e", "--overwrite"]) == 2
    assert (work / "e" / "wall.png").read_bytes() == b"their picture"
    assert "wall.png" in capsys.readouterr().err


@pytest.mark.filterwarnings("ignore:low reconstruction")  # two training steps
def test_failing_fresh_fit_leaves_no_run_folder(work, capsys):
    assert main(["fit", "sliver.obj", "--preset", "tiny", "--out", "runs/r"]) == 2
    assert not (work / "runs" / "r").exists()
    assert not [p for p in (work / "runs").iterdir()]  # no temporary folder either
    two_steps = ["--set", "autoencoder.steps=2", "diffusion.steps=2"]  # a whole fit, every stage, in seconds
    # the next try works
    assert main(["fit", "box.obj", "--preset", "tiny", "--out", "runs/r", "--seed", "1", *two_steps]) == 0
    assert (work / "runs" / "r" / "model.pt").is_file() and not (work / "runs" / "r" / LOCK).exists()


def _cli(*argv, **kw):
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "sin3dm_lite.cli", *argv],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kw,
    )


def _main(capsys, *argv) -> tuple[int, str]:
    """The CLI in this process (no interpreter and torch to start): exit code and stderr."""
    capsys.readouterr()
    code = main(list(argv))
    return code, capsys.readouterr().err


def test_run_folder_lock_refuses_a_live_writer_and_takes_over_a_dead_ones_lock(work, micro_fit, capsys):
    shutil.copytree(micro_fit[1], work / "r")  # a finished fit of the wall example (the session's)
    (work / "r" / "model.pt").unlink()  # as if interrupted before the end
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (work / "r" / LOCK).write_text(json.dumps({"pid": other.pid, "host": os.uname().nodename, "since": "now"}))
        code, err = _main(capsys, "fit", "wall", "--out", "r", "--resume")
        assert code == 2 and f"PID {other.pid}" in err and len(err.strip().splitlines()) == 1, err
        assert not (work / "r" / "model.pt").exists()
    finally:
        other.kill()
        other.wait()
    code, err = _main(capsys, "fit", "wall", "--out", "r", "--resume")
    assert code == 0, err
    assert "no longer runs; taking it over" in err
    assert (work / "r" / "model.pt").is_file() and not (work / "r" / LOCK).exists()


def _kill_when(p: subprocess.Popen, ready, delay: float, timeout: float = 120) -> None:
    """SIGKILL ``p`` ``delay`` seconds after ``ready()`` first holds (polled every 20 ms); it must still be running."""
    t0 = time.monotonic()
    while not ready() and p.poll() is None and time.monotonic() - t0 < timeout:
        time.sleep(0.02)
    time.sleep(delay)
    p.send_signal(signal.SIGKILL)
    _, err = p.communicate(timeout=120)  # a process it started that outlives it would hold the pipes: fails here
    assert p.returncode == -signal.SIGKILL, f"the run ended before it was killed: {err[-2000:]}"


def _stale(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.name.startswith((TEMP_PREFIX, LOCK)) or ".tmp" in p.name]


@pytest.mark.parametrize("delay", [0.0, random.Random(1).uniform(0.0, 1.0)])
def test_killed_sample_leaves_nothing_stale_and_the_next_run_succeeds(work, delay, capsys):
    p = _cli("sample", "run", "--out", "out/s", "-n", "3", *SMALL, cwd=work)
    _kill_when(p, lambda: (work / "out").is_dir() and any((work / "out").iterdir()), delay)
    (work / "out").mkdir(exist_ok=True)
    (work / "out" / "beside.txt").write_text("keep")
    code, err = _main(capsys, "sample", "run", "--out", "out/s", "-n", "3", "--overwrite", *SMALL)
    assert code == 0, (delay, err)
    assert _stale(work / "out") == [], delay
    s = work / "out" / "s"
    assert set(read_manifest(s)) == {
        p.relative_to(s).as_posix() for p in s.rglob("*") if p.is_file() and p.name != MANIFEST
    }
    assert sorted(p.name for p in s.iterdir() if p.is_dir()) == ["000", "001", "002"]
    assert (work / "out" / "beside.txt").read_text() == "keep"


class _Killed(BaseException):
    """Stands for a SIGKILL at one exact step (the subprocess tests above hit such steps only by chance)."""


def _kill(*_args, **_kwargs):
    raise _Killed


@pytest.mark.parametrize("step", ["before the move", "after the move"])
def test_a_kill_while_a_recorded_file_is_replaced_leaves_it_ours(tmp_path, monkeypatch, step):
    # CI once failed the test above: a kill between writing sampling.json and recording it made the
    # rerun refuse our own file as foreign. Now the record comes first and keeps the old file acceptable.
    from sin3dm_lite import files

    out = tmp_path / "out"
    files.write_recorded(out / "sampling.json", "old")
    real = os.replace
    if step == "before the move":
        monkeypatch.setattr(os, "replace", lambda a, b: _kill() if Path(b).name == "sampling.json" else real(a, b))
    else:
        monkeypatch.setattr(files.manifest, "record_written", _kill)  # what recorded_path calls
    with pytest.raises(_Killed):
        files.write_recorded(out / "sampling.json", "newer")  # another size: a stat the old record cannot match
    monkeypatch.undo()
    assert (out / "sampling.json").read_text() == ("old" if step == "before the move" else "newer")
    assert files.is_ours(out, "sampling.json") and files.foreign_files(out, ["sampling.json"]) == []
    files.write_recorded(out / "sampling.json", "again!")
    assert files.read_manifest(out) == files.file_record(out, ["sampling.json"])  # one state once done


def test_a_kill_while_an_output_folder_is_replaced_leaves_its_files_ours(tmp_path, monkeypatch):
    from sin3dm_lite import files

    out, tmp = tmp_path / "out", tmp_path / "tmp"
    out.mkdir()
    (out / "a.txt").write_text("old a")
    (out / "b.txt").write_text("old b")
    files.record_written(out, ["a.txt", "b.txt"])
    tmp.mkdir()
    (tmp / "a.txt").write_text("new a, longer")
    (tmp / "b.txt").write_text("new b, longer")
    real = os.replace
    monkeypatch.setattr(os, "replace", lambda a, b: _kill() if Path(b).name == "b.txt" else real(a, b))
    with pytest.raises(_Killed):
        files.merge_output(tmp, out)  # killed with a.txt new and b.txt old
    monkeypatch.undo()
    assert [(out / n).read_text() for n in ("a.txt", "b.txt")] == ["new a, longer", "old b"]
    assert files.foreign_files(out, ["a.txt", "b.txt"]) == []


@pytest.mark.parametrize("stage, delay", [("start", 0.0), ("training", random.Random(2).uniform(0.0, 1.5))])
def test_killed_fit_resumes_and_leaves_nothing_stale(work, stage, delay, capsys):
    run = work / "runs" / "r"
    p = _cli("fit", "wall", *LIGHT_FIT, "--out", "runs/r", cwd=work)
    ready = {
        "start": lambda: (work / "runs").is_dir() and any((work / "runs").iterdir()),
        "training": lambda: (run / "autoencoder.pt").exists(),
    }[stage]
    _kill_when(p, ready, delay)
    assert [q.name for q in (work / "runs").iterdir()] in ([], ["r"]) or any(
        q.name.startswith(TEMP_PREFIX) for q in (work / "runs").iterdir()
    )
    resume = ["--resume"] if run.is_dir() else []
    locked = (run / LOCK).exists()
    code, err = _main(capsys, "fit", "wall", *LIGHT_FIT, "--out", "runs/r", *resume)
    assert code == 0, (stage, delay, err)
    assert ("no longer runs; taking it over" in err) == locked, err  # the killed run's lock is taken over
    assert [q.name for q in (work / "runs").iterdir()] == ["r"]  # the killed run's temporary folder is gone
    assert _stale(run) == []
    assert (run / "model.pt").is_file() and json.loads((run / "report.json").read_text())["autoencoder_steps"] > 0
    torch.load(run / "model.pt", weights_only=True)


def test_poor_reconstruction_is_a_warning_with_the_likely_cause():
    from sin3dm_lite.auto.fit_policy import MIN_IOU, MIN_PSNR, warn_if_poor
    from sin3dm_lite.presets import get_preset

    # the fix is a setting of the run's config with its value, as the CLI and Python take it
    switched = get_preset("detail")  # 1,000 autoencoder steps at 96 voxels
    with pytest.warns(UserWarning) as record:
        warn_if_poor({"occupancy_iou": MIN_IOU - 0.2, "color_psnr": 16.2}, switched)  # tiles.obj's: 4x the steps
    iou_text, psnr_text = [str(w.message) for w in record]
    assert "IoU" in iou_text and "PSNR" in psnr_text and "likely cause" in iou_text and "likely cause" in psnr_text
    assert "--set autoencoder.steps=4000" in psnr_text and "grid.resolution" not in psnr_text
    assert "get_preset('detail').updated(**{'autoencoder.steps': 4000})" in psnr_text
    assert "autoencoder.steps=2000 or grid.resolution=144" in iou_text
    with pytest.warns(UserWarning, match=r"steps=8000 .*your Config\.updated"):  # at most 8x the steps
        warn_if_poor({"color_psnr": MIN_PSNR - 5}, switched.updated(name="mine"))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_if_poor({"occupancy_iou": 0.96, "color_psnr": MIN_PSNR + 3}, switched)  # a good fit: silent
        # a black-and-white ball whose colour is sharp at the surface, its edges spread only off it: silent
        warn_if_poor({"color_psnr": MIN_PSNR - 7, "color_psnr_surface": MIN_PSNR + 0.5}, switched)
    with pytest.warns(UserWarning, match=r"PSNR 17\.50 dB at the surface .*steps=2000"):  # the surface's figure
        warn_if_poor({"color_psnr": MIN_PSNR - 7, "color_psnr_surface": MIN_PSNR - 0.5}, switched)

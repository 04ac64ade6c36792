"""The Python API is as strict as the CLI (issue 60): one table of bad values, refused by both with the same words.

Also: a shipped model's name beside a local folder means the same to the CLI and to ``Sin3DM.open``; ``scripts/run_notebooks.py``
refuses what is no notebook; messages name no ``--out`` a command lacks; ``SIN3DM_THREADS`` / ``SIN3DM_WORKERS``
that are no count are said; export workers are capped by their own memory; ``sample`` refuses ``-n`` beyond the
disk; printed commands are shell-quoted; PIL's decompression-bomb warning names its file.
"""

from __future__ import annotations

import json
import shlex
import shutil
import sys
import warnings
from collections import namedtuple
from pathlib import Path

import numpy as np
import pytest

from sin3dm_lite import cli
from sin3dm_lite.app import threads
from sin3dm_lite.app.pretrained import pretrained_path
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.pipeline import Sin3DM

from .conftest import CHEAP_SAMPLE

SHIPPED = pretrained_path()

#: (CLI flags of `sample`, the API call (method, arguments) with the same value, words both messages hold)
SHARED = {
    "n-zero": (["-n", "0"], ("sample", {"n": 0}), "a positive whole number, got 0"),
    "seed-negative": (["--seed", "-1"], ("sample", {"seed": -1}), "a whole number from 0 to 4294967295"),
    "seed-huge": (["--seed", str(2**70)], ("sample", {"seed": 2**70}), "a whole number from 0 to 4294967295"),
    "steps-zero": (["--steps", "0"], ("sample", {"steps": 0}), "a whole number from 1 to 100,000, got 0"),
    "steps-beyond-schedule": (["--steps", "5000"], ("sample", {"steps": 5000}), "more than this model's 1000"),
    "diversity": (["--diversity", "1.5"], ("sample", {"diversity": 1.5}), "a number from 0 to 1, got 1.5"),
    "resize": (["--resize", "2", "1", "9"], ("sample", {"resize": (2, 1, 9)}), "resize factors must be in (0, 8]"),
    "outpaint": (
        ["--outpaint", "0.5", "1", "1"],
        ("sample", {"outpaint": (0.5, 1, 1)}),
        "outpaint factors must be from 1 to 8",
    ),
    "faces-zero": (["--faces", "0"], ("to_mesh", {"faces": 0}), "a whole number from 4 to 100,000,000, got 0"),
    "faces-few": (["--faces", "2"], ("to_mesh", {"faces": 2}), "a whole number from 4 to 100,000,000, got 2"),
    "texture-small": (["--texture-size", "8"], ("to_mesh", {"texture_size": 8}), "a whole number of at least 16"),
    "texture-huge": (["--texture-size", "100000"], ("to_mesh", {"texture_size": 100000}), "100000 is too large"),
    "mesh-resolution-small": (["--mesh-resolution", "8"], ("to_mesh", {"resolution": 8}), "at least 16, got 8"),
    "mesh-resolution-huge": (
        ["--mesh-resolution", "100000"],
        ("to_mesh", {"resolution": 100000}),
        "100000 is too large",
    ),
}

#: what only Python can pass (a float, a string, a bool, a list of two): Sin3DMInputError, never a raw TypeError
API_ONLY = {
    "n-float": ("sample", {"n": 2.5}, "n must be a positive whole number, got 2.5"),
    "n-string": ("sample", {"n": "3"}, "n must be a positive whole number, got '3'"),
    "n-bool": ("sample", {"n": True}, "n must be a positive whole number, got True"),
    "seed-float": ("sample", {"seed": 1.5}, "seed must be a whole number from 0"),
    "seeds-too-many": ("sample", {"seed": [1, 2]}, "2 seeds for 1 samples"),
    "seeds-huge": ("sample", {"seed": [2**70]}, "each of the seeds (seed) must be a whole number from 0 to"),
    "resize-two": ("sample", {"resize": (2, 1)}, "resize takes one number or three (x, y, z)"),
    "resize-text": ("sample", {"resize": "big"}, "resize takes one number or three"),
    "resize-nan": ("sample", {"resize": float("nan")}, "resize takes one number or three"),
    "steps-float": ("sample", {"steps": 2.0}, "steps must be a whole number from 1 to 100,000, got 2.0"),
    "method": ("sample", {"method": "euler"}, "method must be one of 'ddim', 'ddpm'"),
    "to-mesh-list": ("to_mesh", {"samples": []}, "to_mesh takes the Samples that sample() returns"),
    "to-mesh-none": ("to_mesh", {"samples": None}, "to_mesh takes the Samples that sample() returns"),
    "index-beyond": ("to_mesh", {"index": 5}, "index (these samples hold 1) must be a whole number from 0 to 0"),
    "index-negative": ("to_mesh", {"index": -1}, "from 0 to 0, got -1"),
    "vertex-colors": ("to_mesh", {"vertex_colors": "no"}, "vertex_colors must be True or False"),
    "max-samples-two": ("max_samples", {"resize": (2, 1)}, "resize takes one number or three"),
}


@pytest.fixture(scope="module")
def shipped():
    """The shipped canyon model and one sample of it (2 DDIM steps)."""
    model = Sin3DM.load(SHIPPED)
    return model, model.sample(1, steps=2, progress=False)


def _call(shipped, method: str, kw: dict):
    model, samples = shipped
    if method == "sample":
        return model.sample(**({"n": 1, "steps": 2, "progress": False} | kw))
    if method == "max_samples":
        return model.max_samples(**kw)
    kw = {"samples": samples, "index": 0, "resolution": 32, "faces": 500, "texture_size": 64} | kw
    return model.to_mesh(**kw)


def _refused(call) -> str:
    with pytest.raises(Sin3DMInputError) as e:
        call()
    message = str(e.value)
    assert type(e.value) is Sin3DMInputError and "\n" not in message, message
    return message


@pytest.mark.parametrize("case", list(SHARED))
def test_the_api_refuses_the_clis_bad_values_in_the_same_words(shipped, case):
    _, (method, kw), words = SHARED[case]
    assert words in _refused(lambda: _call(shipped, method, kw))


@pytest.mark.parametrize("case", list(SHARED))
def test_the_cli_refuses_the_same_table_and_writes_nothing(tmp_path, capsys, case):
    flags, _, words = SHARED[case]
    out = tmp_path / "s"
    try:
        code = cli.main(["sample", "canyon", "--out", str(out), *flags])
    except SystemExit as e:  # the parser's refusal
        code = e.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and words in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("case", list(API_ONLY))
def test_the_api_refuses_what_only_python_can_pass_in_one_line(shipped, case):
    method, kw, words = API_ONLY[case]
    assert words in _refused(lambda: _call(shipped, method, kw))


def test_good_values_of_every_python_kind_are_taken(shipped):
    model, samples = shipped
    assert len(model.sample(np.int64(1), seed=2**32 - 1, steps=2, progress=False)) == 1  # the last seed; numpy's int
    assert len(model.sample(1, resize=1.5, steps=2, progress=False)) == 1  # one factor for x, y and z
    # the last seed with more samples (seeds 2**32 - 1 and 2**32), and a run's own seeds past it (`sample --seed`)
    assert len(model.sample(2, seed=2**32 - 1, steps=2, progress=False)) == 2
    assert len(model.sample(1, seed=[2**32], steps=2, progress=False)) == 1
    mesh = model.to_mesh(samples, np.int64(0), resolution=32, faces=500, texture_size=64)
    assert len(mesh.faces) > 0


#: `evaluate`'s flags and Sin3DM.evaluate's arguments: the same checks (evaluation.check_views, check_resolutions)
EVALUATE = {
    "views-many": (["--views", "1000"], {"views": 1000}, "a whole number from 1 to 360, got 1000"),
    "size-small": (["--size", "8"], {"size": 8}, "a whole number from 16 to 4,096, got 8"),
    "resolution-large": (["--resolution", "1000"], {"resolution": 1000}, "a whole number from 16 to 512, got 1000"),
    "resolution-second": (["--resolution", "64", "8"], {"resolution": (64, 8)}, "from 16 to 512, got 8"),
}


@pytest.mark.parametrize("case", list(EVALUATE))
def test_evaluate_refuses_the_same_values_from_the_cli_and_the_api(shipped, capsys, case):
    flags, kw, words = EVALUATE[case]
    model, samples = shipped
    assert words in _refused(lambda: model.evaluate(samples, progress=False, **kw))
    assert cli.main(["evaluate", "canyon", "nowhere", *flags]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and flags[0] in err[0], err


def test_evaluate_refuses_what_only_python_can_pass(shipped):
    model, samples = shipped
    for kw, words in (
        ({"views": 2.5}, "views must be a whole number from 1 to 360, got 2.5"),
        ({"size": "big"}, "size must be a whole number from 16 to 4,096, got 'big'"),
        ({"resolution": []}, "resolution must be one grid's voxels or several, got none"),
    ):
        assert words in _refused(lambda kw=kw: model.evaluate(samples, progress=False, **kw))


# --------------------------------------------------------------------------- a shipped name beside a local folder
def _folders(tmp_path, monkeypatch, run: bool) -> None:
    monkeypatch.chdir(tmp_path)
    if run:
        shutil.copytree(SHIPPED, tmp_path / "canyon")  # a run folder named like the shipped model
    else:
        (tmp_path / "canyon").mkdir()  # what `examples --write canyon --out canyon` leaves: a mesh, no model
        (tmp_path / "canyon" / "canyon.obj").write_text("v 0 0 0\n")


@pytest.mark.parametrize("run", [False, True], ids=["mesh-folder", "run-folder"])
def test_a_shipped_name_means_the_shipped_model_to_the_cli_and_the_api_alike(tmp_path, monkeypatch, run):
    from sin3dm_lite.app.runs import resolve_run
    from sin3dm_lite.cli.sample_cli import find_run

    _folders(tmp_path, monkeypatch, run)
    with pytest.warns(UserWarning, match=r"'canyon' is the shipped model canyon_small.*write \./canyon") as said:
        by_cli = find_run("canyon")
    with pytest.warns(UserWarning, match=r"'canyon' is the shipped model canyon_small.*write \./canyon"):
        by_api = resolve_run("canyon", None, tmp_path / "cache")
    assert by_cli == by_api[1] == SHIPPED and by_api[0] == "shipped"
    assert ("run folder" if run else "not the folder") in str(said[0].message)
    if not run:  # ./canyon: the local folder, which holds no model; the message names the shipped one
        with pytest.raises(Sin3DMInputError, match=r"'\./canyon' is a folder without model.pt.*write canyon for"):
            find_run("./canyon")
    if run:  # ./canyon: the local one, for both
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert find_run("./canyon").resolve() == resolve_run("./canyon", None, "cache")[1].resolve()
            assert find_run("./canyon").resolve() == (tmp_path / "canyon").resolve()


def test_sample_of_a_shipped_name_beside_an_example_folder_samples_the_shipped_model(tmp_path, monkeypatch, capsys):
    """Issue 60: after `examples --write canyon --out canyon`, `sample canyon` said "no fitted model at 'canyon'"."""
    _folders(tmp_path, monkeypatch, run=False)
    assert cli.main(["sample", "canyon", "--out", "s", "-n", "1", *CHEAP_SAMPLE]) == 0
    err = capsys.readouterr().err
    assert "warning: 'canyon' is the shipped model canyon_small" in err and (tmp_path / "s" / "000").is_dir()
    assert json.loads((tmp_path / "s" / "sampling.json").read_text())["settings"]


def test_calibrate_of_a_shipped_name_beside_a_run_folder_writes_neither(tmp_path, monkeypatch, capsys):
    """The shipped model is print-only; the local run folder of that name is left alone (``./canyon`` names it)."""
    from sin3dm_lite.cli import evaluate_cli

    _folders(tmp_path, monkeypatch, run=True)
    seen = {}
    monkeypatch.setattr(evaluate_cli, "_calibrate", lambda a, run, shipped: seen.update(run=run, shipped=shipped))
    assert cli.main(["calibrate", "canyon"]) == 0
    assert seen == {"run": SHIPPED, "shipped": True}
    assert cli.main(["calibrate", "./canyon"]) == 0
    assert seen["run"].resolve() == (tmp_path / "canyon").resolve() and not seen["shipped"]


# --------------------------------------------------------------------------- notebooks, and no --out where none is
def _load_script(name: str):
    """A script of scripts/ as a module (they are run from a checkout, not installed)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, Path(__file__).parents[1] / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _notebook(path: Path) -> None:
    import nbformat

    nb = nbformat.v4.new_notebook()
    cell = nbformat.v4.new_code_cell("print(1)")
    cell.outputs = [nbformat.v4.new_output("stream", text="1\n")]
    nb.cells.append(cell)
    nbformat.write(nb, path)


@pytest.mark.parametrize(
    "name, text, words",
    [
        ("userfile.txt", "hello\n", "'userfile.txt' is not a notebook (.ipynb)"),
        ("broken.ipynb", "{nope\n", "'broken.ipynb' is not a readable Jupyter notebook (not JSON)"),
        ("odd.ipynb", '{"cells": 3}', "'odd.ipynb' is not a readable Jupyter notebook (not a notebook's structure)"),
        ("missing.ipynb", None, "notebook 'missing.ipynb' not found"),
    ],
)
@pytest.mark.parametrize("mode", ["--check", "--clear"])
def test_notebooks_refuses_what_is_no_notebook_before_touching_any(
    tmp_path, monkeypatch, capsys, name, text, words, mode
):
    monkeypatch.chdir(tmp_path)
    _notebook(tmp_path / "good.ipynb")
    before = (tmp_path / "good.ipynb").read_bytes()
    if text is not None:
        (tmp_path / name).write_text(text)
    assert _load_script("run_notebooks").main([mode, "good.ipynb", name]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and "Traceback" not in err[0], err
    assert (tmp_path / "good.ipynb").read_bytes() == before  # --clear cleared nothing: every file checked first


def test_a_disk_error_names_no_out_in_commands_without_one(monkeypatch, capsys):
    notebook_run = _load_script("run_notebooks")

    def fail(*args, **kwargs):
        raise PermissionError(13, "Permission denied", "notebooks/01.ipynb")

    monkeypatch.setattr(notebook_run, "run_all", fail)
    assert notebook_run.main([]) == 2
    err = capsys.readouterr().err.strip()
    assert "Permission denied" in err and "--out" not in err
    assert "--out" in cli.disk_error(PermissionError(13, "Permission denied", "x"), None)  # a command with one


def test_calibrate_of_a_locked_run_names_no_out(tmp_path, monkeypatch, capsys):
    from sin3dm_lite.files import locks

    shutil.copytree(SHIPPED, tmp_path / "run")
    monkeypatch.setattr(locks, "_try_lock", lambda fd: False)  # another process holds it
    assert cli.main(["calibrate", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is being written by another sin3dm-lite process" in err[0] and "--out" not in err[0]


# --------------------------------------------------------------------------- environment variables
@pytest.mark.parametrize("value", ["0", "-1", "abc", "1.5"])
def test_sin3dm_threads_that_is_no_count_is_said(capsys, value):
    env = {"SIN3DM_THREADS": value}
    assert threads.chosen_threads(env) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"SIN3DM_THREADS='{value}'" in err[0] and "using 1" in err[0], err
    assert env["SIN3DM_THREADS"] == "1"  # what processes started from here read: said once
    assert threads.chosen_threads(env) == 1 and not capsys.readouterr().err


def test_sin3dm_threads_above_the_cores_is_capped_and_said(capsys, monkeypatch):
    monkeypatch.setattr(threads, "usable_cores", lambda: 2)
    env = {"SIN3DM_THREADS": "99999"}
    assert threads.apply_policy(env)["OMP_NUM_THREADS"] == "2"
    err = capsys.readouterr().err
    assert "SIN3DM_THREADS='99999' is more than the CPU cores" in err and "using 2" in err


def test_sin3dm_workers_that_is_no_count_is_said(capsys, monkeypatch):
    monkeypatch.setattr(threads, "usable_cores", lambda: 3)
    assert threads.export_workers({"SIN3DM_WORKERS": "abc"}) == 3
    assert "SIN3DM_WORKERS='abc' is not a whole number of at least 0; using 3" in capsys.readouterr().err


# --------------------------------------------------------------------------- memory and disk, estimated first
WORKER_PROBE = """
import sys, numpy as np, torch
from sin3dm_lite.app import mass_workers
saved = torch.load(sys.argv[2], weights_only=True)
opts = {"mesh_resolution": 32, "faces": 500, "texture_size": 64, "pictures": False, "box": None}
mass_workers._worker_init(sys.argv[1], opts)
mass_workers.export_sample(sys.argv[3], saved["triplane"], saved["aabb"].numpy())
print(next(int(line.split()[1]) * 1024 for line in open("/proc/self/status") if line.startswith("VmHWM:")))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
def test_a_started_export_worker_takes_no_more_than_its_estimate(shipped, tmp_path):
    """A process that does what an export worker does (its model copy, one small export): its peak resident
    memory is within :func:`mass_workers.worker_bytes`, the share of the memory each worker is counted for."""
    import subprocess

    import torch

    from sin3dm_lite.app.mass_workers import worker_bytes

    model, samples = shipped
    latent = {"triplane": samples.triplane[0].clone().state_dict(), "aabb": torch.from_numpy(samples.aabb)}
    torch.save(latent, tmp_path / "latent.pt")
    (tmp_path / "out").mkdir()
    argv = [sys.executable, "-c", WORKER_PROBE, str(SHIPPED / "model.pt"), str(tmp_path / "latent.pt")]
    done = subprocess.run([*argv, str(tmp_path / "out")], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    peak, estimate = int(done.stdout.split()[-1]), worker_bytes(model)
    assert 0.5 * estimate < peak <= estimate, (peak, estimate)  # the estimate, not far above what it takes


@pytest.mark.parametrize("asked", ["--workers", "SIN3DM_WORKERS"])
def test_workers_beyond_what_memory_holds_are_capped_in_one_line(shipped, monkeypatch, asked):
    from sin3dm_lite.app import device, mass
    from sin3dm_lite.app.mass_workers import worker_bytes
    from sin3dm_lite.app.request import SampleRequest
    from sin3dm_lite.app.sampling import export_bytes

    model, _ = shipped
    plan = model.plan()
    r = SampleRequest().resolve(model.config.sampling)
    each = worker_bytes(model) + export_bytes(r.mesh_resolution, r.texture_size, plan.aabb)
    monkeypatch.setattr(device, "memory_available", lambda kind="cpu": 2 * 3.5 * each)  # half of it: 3 workers
    if asked == "SIN3DM_WORKERS":
        monkeypatch.setenv("SIN3DM_WORKERS", "999")
        req = SampleRequest(n=5000)
    else:
        req = SampleRequest(n=5000, workers=1000)
    with pytest.warns(UserWarning, match=r"(--workers 1000|SIN3DM_WORKERS=999): memory holds 3 export workers") as w:
        mass.check_sample_sizes(model, plan, req)
    assert req.workers == 3 and len(w) == 1 and "using 3" in str(w[0].message)


def test_sample_says_its_disk_estimate_first_and_it_is_near_what_is_written(tmp_path, capsys):
    from sin3dm_lite.app.mass import sample_bytes
    from sin3dm_lite.app.request import SampleRequest

    out = tmp_path / "s"
    assert cli.main(["sample", "canyon", "--out", str(out), "-n", "2", *CHEAP_SAMPLE]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith("[sample] about ") and "a sample on disk" in first and "for the 2 to write" in first
    model = Sin3DM.load(SHIPPED)
    flags = dict(zip(["steps", "mesh_resolution", "faces", "texture_size"], [3, 32, 500, 64]))
    estimate = sample_bytes(model, model.plan(), SampleRequest(n=2, no_pictures=True, **flags))
    written = sum(p.stat().st_size for p in (out / "000").iterdir())
    assert 0.7 * written < estimate < 3 * written, (estimate, written)


def test_sample_refuses_what_cannot_fit_on_the_disk_naming_the_largest_n(tmp_path, monkeypatch, capsys):
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(10**9, 10**9 - 10**6, 10**6))  # 1 MB free
    out = tmp_path / "s"
    assert cli.main(["sample", "canyon", "--out", str(out), "-n", "999999", *CHEAP_SAMPLE]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "-n 999999 needs about" in err[0] and "1 MB free" in err[0], err
    most = int(err[0].split("at most -n ")[1].split()[0])
    assert 1 <= most < 20 and not out.exists()


def test_overwrite_counts_the_space_its_own_old_samples_free(tmp_path, monkeypatch, capsys):
    """`--overwrite` first removes the samples an earlier run wrote: their space counts as free."""
    out = tmp_path / "s"
    assert cli.main(["sample", "canyon", "--out", str(out), "-n", "4", *CHEAP_SAMPLE]) == 0
    ours = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(10**9, 10**9, ours // 8))  # half a sample free
    capsys.readouterr()
    assert (
        cli.main(["sample", "canyon", "--out", str(out), "-n", "2", "--seed", "7", "--overwrite", *CHEAP_SAMPLE]) == 0
    )
    assert cli.main(["sample", "canyon", "--out", str(tmp_path / "t"), "-n", "2", *CHEAP_SAMPLE]) == 2  # no room


def test_calibration_options_and_occupancy_resolutions_are_checked_in_one_line():
    from sin3dm_lite.evaluate.calibrate import calibrate_diversity

    grid = np.zeros((8, 8, 8), bool)
    for bad, words in (
        ({"n": 10**9}, "2 to 64 samples"),
        ({"seed": -1}, "seed"),
        ({"seed": 2**40}, "seed"),
        ({"lowest": "0.1"}, "lowest"),
        ({"step": float("nan")}, "step"),
    ):
        with pytest.raises(Sin3DMInputError, match=words):
            calibrate_diversity(lambda d, n, s: [grid] * n, grid, progress=False, **bad)
    model = Sin3DM.load(SHIPPED)
    samples = model.input_sample()
    for bad in (2.5, 10**6, [], "64"):
        with pytest.raises(Sin3DMInputError, match="resolution"):
            model.occupancy(samples, resolution=bad)


# --------------------------------------------------------------------------- small ones
def test_the_next_command_after_a_fit_is_shell_quoted(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    model = Sin3DM.load(SHIPPED)
    monkeypatch.setattr(Sin3DM, "fit", classmethod(lambda cls, *a, **k: model))
    assert cli.main(["fit", "canyon", "--out", "my runs/canyon run"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("next: "))
    argv = shlex.split(line.removeprefix("next: "))
    assert argv == ["sin3dm-lite", "sample", "my runs/canyon run", "-n", "4", "--out", "my runs/canyon run-samples"]


def test_a_decompression_bomb_warning_names_the_texture(tmp_path, monkeypatch):
    from PIL import Image

    from sin3dm_lite.formats.load import load_mesh

    (tmp_path / "m.obj").write_text(
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl a\n"
        "f 1/1 3/3 2/2\nf 1/1 2/2 4/3\nf 1/1 4/3 3/2\nf 2/1 3/2 4/3\n"
    )
    (tmp_path / "m.mtl").write_text("newmtl a\nmap_Kd big.png\n")
    Image.new("RGB", (64, 64), (200, 30, 30)).save(tmp_path / "big.png")
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 3000)  # 4,096 pixels: over PIL's limit, under twice it
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_mesh(tmp_path / "m.obj")
    said = [str(w.message) for w in caught]
    assert not [w for w in caught if issubclass(w.category, Image.DecompressionBombWarning)], said
    assert any("texture file 'big.png'" in s and "very large image" in s and "m.mtl" in s for s in said), said

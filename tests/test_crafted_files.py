"""Files from a stranger: a crafted ``model.pt``, config or run folder, and paths that are not regular files.

Every case exits 2 with one line that names the file and what is wrong, before anything is built or written:
a config that would build a network larger than memory, weights whose shapes differ from the config, boxes that
are huge, NaN or flat, text where a checkpoint belongs (a Git LFS pointer, an HTML page), a FIFO or a device as a
mesh, a texture, a checkpoint or a run's json (which would block forever), and a resume whose config.json was
emptied or edited away from what the run recorded.
"""

import json
import os
import shutil
import threading
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from sin3dm_lite.app.pretrained import pretrained_path
from sin3dm_lite.cli import main
from sin3dm_lite.errors import Sin3DMInputError
from sin3dm_lite.pipeline import Sin3DM

from .conftest import CHEAP_SAMPLE

SHIPPED = pretrained_path()
BUNDLE = torch.load(SHIPPED / "model.pt", weights_only=True)


def _run(root: Path, name: str, bundle: dict | None = None, raw: bytes | None = None) -> str:
    """A run folder ``root/name`` with the shipped config.json and a crafted model.pt; returns its name."""
    run = root / name
    run.mkdir()
    shutil.copy(SHIPPED / "config.json", run / "config.json")
    if raw is not None:
        (run / "model.pt").write_bytes(raw)
    else:
        torch.save(bundle, run / "model.pt")
    return name


def _config(**changes) -> str:
    cfg = json.loads(BUNDLE["config"])
    for key, value in changes.items():
        section, leaf = key.split(".")
        cfg[section][leaf] = value
    return json.dumps(cfg)


LFS = b"version https://git-lfs.github.com/spec/v1\noid sha256:4d7a2146\nsize 6112873\n"
HTML = b"<!DOCTYPE html>\n<html><head><title>model.pt</title></head><body>Sign in</body></html>\n"

#: name → (the crafted model.pt: a bundle or raw bytes, words of the one line)
MODELS = {
    "huge-network": (
        {**BUNDLE, "config": _config(**{"diffusion.base_channels": 4096, "diffusion.n_resblocks": 64})},
        "its config asks for",
    ),
    "weights-of-another-config": (
        {**BUNDLE, "config": _config(**{"diffusion.base_channels": 48})},
        "its denoiser weight 'in_conv.convs.0.weight' has shape (32, 12, 1, 1), its config asks for (48, 12, 1, 1)",
    ),
    "config-out-of-limits": ({**BUNDLE, "config": _config(**{"diffusion.n_resblocks": 10**6})}, "n_resblocks"),
    "config-not-json": ({**BUNDLE, "config": "{"}, "its config is not a JSON object"),
    "config-emptied": ({**BUNDLE, "config": "{}"}, "its config lacks the setting"),
    "aabb-huge": ({**BUNDLE, "aabb": BUNDLE["aabb"] * 1e30}, "its box (aabb)"),
    "aabb-nan": ({**BUNDLE, "aabb": BUNDLE["aabb"] * float("nan")}, "its box (aabb) is not six finite numbers"),
    "aabb-flat": ({**BUNDLE, "aabb": BUNDLE["aabb"] * 0}, "sides longer than"),
    "aabb-shape": ({**BUNDLE, "aabb": torch.zeros(2, 3)}, "its box (aabb) is not six finite numbers"),
    "aabb-not-tensor": ({**BUNDLE, "aabb": "box"}, "its box (aabb)"),
    "center-inf": ({**BUNDLE, "center": BUNDLE["center"] * float("inf")}, "its centre"),
    "scale-zero": ({**BUNDLE, "scale": 0.0}, "its scale 0.0"),
    "scale-text": ({**BUNDLE, "scale": "1"}, "its scale"),
    "rotation-mirror": ({**BUNDLE, "rotation": torch.diag(torch.tensor([1.0, 1.0, -1.0]))}, "its rotation"),
    "rotation-text": ({**BUNDLE, "rotation": "turned"}, "its rotation is not a 3 × 3 rotation"),
    "color-channels": ({**BUNDLE, "color_channels": 7}, "color_channels is 7"),
    "threshold-nan": (
        {**BUNDLE, "decoder": {**BUNDLE["decoder"], "threshold": torch.tensor(float("nan"))}},
        "threshold",
    ),
    "latent-nan": (
        {**BUNDLE, "latent": {**BUNDLE["latent"], "xy": BUNDLE["latent"]["xy"] * float("nan")}},
        "its latent holds NaN",
    ),
    "latent-sides-disagree": (
        {**BUNDLE, "latent": {**BUNDLE["latent"], "xy": torch.zeros(1, 12, 5, 16)}},
        "are not one latent",
    ),
    "latent-missing-plane": ({**BUNDLE, "latent": {"xy": BUNDLE["latent"]["xy"]}}, "three planes"),
    "report-a-list": ({**BUNDLE, "report": "[1, 2]"}, "its report is not a JSON object"),
    "report-grid-shape": (
        {**BUNDLE, "report": json.dumps({"grid_shape": [10**9, 1, 1]})},
        "its report's grid_shape [1000000000, 1, 1] is not three whole numbers",
    ),
    "decoder-not-tensors": ({**BUNDLE, "decoder": {"threshold": 0.1}}, "its decoder is not a dictionary of tensors"),
    "denoiser-extra-weight": (
        {**BUNDLE, "denoiser": {**BUNDLE["denoiser"], "extra.weight": torch.zeros(1)}},
        "'extra.weight', which its config has no place for",
    ),
    "text-starting-with-r": (b"readme: not a checkpoint\n", "(it is text)"),
    "git-lfs-pointer": (LFS, "is a Git LFS pointer, not the file itself; run `git lfs pull`"),
    "html-page": (HTML, "is an HTML page, not a checkpoint; download the file itself"),
    "empty": (b"", "(it is empty)"),
}


def _one_line(capsys, code: int) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.strip().splitlines() if ": warning: " not in line]
    assert code == 2, err
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture
def real_nets_stay_small(monkeypatch):
    """Building a real (not meta) denoiser wider than the shipped one fails at once: the old code built the crafted
    network in memory (hundreds of GiB); the new one lays it out on the meta device only."""
    from sin3dm_lite.model import unet

    init = unet.TriplaneUNet.__init__

    def guarded(self, latent_channels, cfg):
        if cfg.base_channels * cfg.n_resblocks > 32 * 2 * 4 and torch.get_default_device().type != "meta":
            raise AssertionError("a crafted network was built in memory")
        init(self, latent_channels, cfg)

    monkeypatch.setattr(unet.TriplaneUNet, "__init__", guarded)


@pytest.mark.parametrize("case", list(MODELS))
def test_crafted_model_is_refused_in_one_line_naming_the_file(
    tmp_path, monkeypatch, capsys, real_nets_stay_small, case
):
    content, words = MODELS[case]
    monkeypatch.chdir(tmp_path)
    bundle, raw = (None, content) if isinstance(content, bytes) else (content, None)
    run = _run(tmp_path, "run", bundle, raw)
    line = _one_line(capsys, main(["sample", run, "--out", "s", "-n", "1", "--workers", "0", *CHEAP_SAMPLE]))
    assert words in line and f"'{run}/model.pt'" in line, line
    assert not (tmp_path / "s").exists()
    with pytest.raises(Sin3DMInputError, match="model.pt"):  # the Python API: the same check
        Sin3DM.load(tmp_path / run)


def test_model_pt_linked_to_a_text_file_is_named_as_text(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("remember: the real model is on the other disk\n")
    run = tmp_path / "run"
    run.mkdir()
    (run / "model.pt").symlink_to(tmp_path / "notes.txt")
    with pytest.raises(Sin3DMInputError, match=r"\(it is text\)"):
        Sin3DM.load(run)


# --------------------------------------------------------------------------- not regular files
def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


def _within(seconds: float, fn):
    """``fn()``'s result, or a failure if it does not return within ``seconds`` (a FIFO blocks an open forever)."""
    out: dict = {}

    def call():
        try:
            out["value"] = fn()
        except BaseException as e:  # noqa: BLE001 - handed to the test
            out["error"] = e

    t = threading.Thread(target=call, daemon=True)
    t.start()
    t.join(seconds)
    if t.is_alive():
        # unblock the reader: open each FIFO under the test folder for writing and close it
        pytest.fail(f"still blocked after {seconds} s")
    if "error" in out:
        raise out["error"]
    return out["value"]


@pytest.fixture
def unblock(tmp_path):
    """After the test: open every FIFO under ``tmp_path`` for writing once, so that a reader the old code left
    blocked in a thread returns."""
    yield
    for p in tmp_path.rglob("*"):
        if p.is_fifo():
            try:
                fd = os.open(p, os.O_WRONLY | os.O_NONBLOCK)
                os.close(fd)
            except OSError:
                pass


@pytest.mark.parametrize("command", ["grid", "fit"])
def test_fifo_as_mesh_is_refused_at_once(tmp_path, monkeypatch, capsys, unblock, command):
    monkeypatch.chdir(tmp_path)
    _fifo(tmp_path / "shape.obj")
    argv = (
        ["grid", "shape.obj", "--resolution", "32", "--out", "g.npz"]
        if command == "grid"
        else ["fit", "shape.obj", "--preset", "tiny", "--out", "r"]
    )
    line = _one_line(capsys, _within(20, lambda: main(argv)))
    assert "'shape.obj' is a named pipe (FIFO), not a regular file" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shape.obj"]


def test_device_as_mesh_is_refused(tmp_path):
    from sin3dm_lite.formats.load import load_mesh

    (tmp_path / "zero.obj").symlink_to("/dev/zero")
    with pytest.raises(Sin3DMInputError, match=r"is a character device \(a link to '/dev/zero'\), not a regular"):
        _within(20, lambda: load_mesh(tmp_path / "zero.obj"))


def test_fifo_as_texture_mtl_or_gltf_buffer_is_refused(tmp_path, unblock):
    from sin3dm_lite.formats.load import load_mesh

    box = trimesh.creation.box()
    lines = [f"v {x} {y} {z}" for x, y, z in box.vertices] + ["vt 0 0", "vt 1 0", "vt 0 1"]
    lines += [f"f {a + 1}/1 {b + 1}/2 {c + 1}/3" for a, b, c in box.faces]
    (tmp_path / "box.obj").write_text("mtllib box.mtl\nusemtl m\n" + "\n".join(lines) + "\n")
    _fifo(tmp_path / "box.mtl")
    with pytest.raises(Sin3DMInputError, match="box.mtl' is a named pipe"):
        _within(20, lambda: load_mesh(tmp_path / "box.obj"))
    (tmp_path / "box.mtl").unlink()
    (tmp_path / "box.mtl").write_text("newmtl m\nmap_Kd tex.png\n")
    _fifo(tmp_path / "tex.png")
    with pytest.raises(Sin3DMInputError, match="tex.png' is a named pipe"):
        _within(20, lambda: load_mesh(tmp_path / "box.obj"))
    gltf = {
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "data.bin", "byteLength": 36}],
    }
    (tmp_path / "scene.gltf").write_text(json.dumps(gltf))
    _fifo(tmp_path / "data.bin")
    with pytest.raises(Sin3DMInputError, match="data.bin' is a named pipe"):
        _within(20, lambda: load_mesh(tmp_path / "scene.gltf"))


def test_fifo_as_model_pt_is_refused(tmp_path, unblock):
    run = tmp_path / "run"
    run.mkdir()
    _fifo(run / "model.pt")
    with pytest.raises(Sin3DMInputError, match="model.pt' is a named pipe"):
        _within(20, lambda: Sin3DM.load(run))


# --------------------------------------------------------------------------- a resume's config
def _edit(path: Path, **changes) -> None:
    d = json.loads(path.read_text())
    for key, value in changes.items():
        node = d
        *parents, leaf = key.split("/")
        for p in parents:
            node = node[p]
        node[leaf] = value
    path.write_text(json.dumps(d))


def _grid_with(path: Path, **arrays) -> None:
    """Rewrite the grid file ``path`` with ``arrays`` replaced; ``sdf=None``: an sdf whose header declares 10^15
    values (a few bytes follow it: a reader that trusts the header allocates petabytes)."""
    import zipfile

    with np.load(path) as z:
        entries = {k: z[k] for k in z.files}
    entries.update(arrays)
    entries = {k: v for k, v in entries.items() if v is not None}
    np.savez(path.with_suffix(".tmp.npz"), **entries)
    path.with_suffix(".tmp.npz").replace(path)
    if "sdf" in arrays and arrays["sdf"] is None:
        header = {"descr": "<f4", "fortran_order": False, "shape": (10**5, 10**5, 10**5)}
        with zipfile.ZipFile(path, "a") as zf:
            import io

            buf = io.BytesIO()
            np.lib.format.write_array_header_2_0(buf, header)
            zf.writestr("sdf.npy", buf.getvalue() + b"\0" * 64)


def _snapshot(root: Path) -> dict:
    return {p.name: (p.stat().st_size, p.stat().st_mtime_ns) for p in root.iterdir()}


#: name → (what is done to the copied run folder, words of the one line)
RESUMES = {
    "config-emptied": (
        lambda r: (r / "config.json").write_text("{}"),
        "'r/config.json' is damaged (it is an empty JSON object); it holds",
    ),
    "config-a-list": (lambda r: (r / "config.json").write_text("[1, 2, 3]"), "(it is not a JSON object)"),
    "config-truncated": (
        lambda r: (r / "config.json").write_text((r / "config.json").read_text()[:100]),
        "cannot be read as JSON",
    ),
    "config-without-grid": (
        lambda r: _edit(r / "config.json", grid={}),
        "it lacks the setting 'grid.resolution'",
    ),
    "config-other-steps": (
        lambda r: _edit(r / "config.json", **{"autoencoder/steps": 500}),
        "no longer holds the settings the fit recorded in input.json (autoencoder.steps 500 there, 30 recorded)",
    ),
    "config-other-grid": (
        lambda r: _edit(r / "config.json", **{"grid/resolution": 32}),
        "(grid.resolution 32 there, 24 recorded)",
    ),
    "config-and-record-other-grid": (
        lambda r: (
            _edit(r / "config.json", **{"grid/resolution": 32}),
            _edit(r / "input.json", **{"config/grid/resolution": 32}),
        ),
        "asks for grid.resolution 32, but the run's grid.npz has 24 voxels",
    ),
    "config-and-record-other-steps": (
        lambda r: (
            _edit(r / "config.json", **{"autoencoder/steps": 500}),
            _edit(r / "input.json", **{"config/autoencoder/steps": 500}),
        ),
        "'r/autoencoder.pt' was trained with other settings than the run's config.json (autoencoder.steps 30 there, "
        "500 in config.json)",
    ),
    "checkpoint-step-negative": (
        lambda r: torch.save(
            {**torch.load(r / "diffusion.pt", weights_only=True), "step": -(10**9)}, r / "diffusion.pt"
        ),
        "'r/diffusion.pt' was not made by this version of sin3dm-lite (its step -1000000000 is not a whole number",
    ),
    "grid-nan-box": (
        lambda r: _grid_with(r / "grid.npz", aabb=np.full(6, np.nan, np.float32)),
        "(its box (aabb) is not six finite numbers of a box inside [-1, 1]); delete it: the resumed fit makes it again",
    ),
    "grid-declares-petabytes": (
        lambda r: _grid_with(r / "grid.npz", sdf=None),
        "its array 'sdf.npy' declares 1,000,000,000,000,000 values",
    ),
    "config-a-fifo": (
        lambda r: ((r / "config.json").unlink(), os.mkfifo(r / "config.json")),
        "'r/config.json' is a named pipe (FIFO), not a regular file",
    ),
    "record-damaged": (lambda r: (r / "input.json").write_text("{"), "'r/input.json' is damaged"),
    "record-emptied": (lambda r: (r / "input.json").write_text("{}"), "'r/input.json' is damaged"),
}


@pytest.mark.parametrize("case", list(RESUMES))
def test_resume_with_a_damaged_or_edited_config_is_refused(micro_fit, tmp_path, monkeypatch, capsys, unblock, case):
    damage, words = RESUMES[case]
    monkeypatch.chdir(tmp_path)
    shutil.copytree(micro_fit[1], tmp_path / "r")
    damage(tmp_path / "r")
    before = _snapshot(tmp_path / "r")
    line = _one_line(capsys, _within(60, lambda: main(["fit", "wall", "--out", "r", "--resume"])))
    assert words in line, line
    if not case.startswith("checkpoint"):  # the right advice for a trainer checkpoint, not for the config
        assert "delete it to restart" not in line
    assert _snapshot(tmp_path / "r") == before


@pytest.mark.filterwarnings("ignore:low reconstruction")
def test_resume_with_other_sampling_defaults_goes_on(micro_fit, tmp_path, monkeypatch, capsys):
    """Sampling's defaults shape no checkpoint: a config.json edited there still resumes."""
    monkeypatch.chdir(tmp_path)
    shutil.copytree(micro_fit[1], tmp_path / "r")
    _edit(tmp_path / "r" / "config.json", **{"sampling/mesh_resolution": 40})
    assert main(["fit", "wall", "--out", "r", "--resume"]) == 0, capsys.readouterr().err


# --------------------------------------------------------------------------- small ones
def test_grid_does_not_call_a_fits_own_grid_foreign(micro_fit, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    shutil.copytree(micro_fit[1], tmp_path / "r")
    trimesh.creation.box().export(tmp_path / "box.obj")
    before = _snapshot(tmp_path / "r")
    line = _one_line(capsys, main(["grid", "box.obj", "--resolution", "32", "--out", "r/grid.npz", "--overwrite"]))
    assert "'r/grid.npz' is the grid of the fit in 'r'" in line and "not written by sin3dm-lite" not in line, line
    assert _snapshot(tmp_path / "r") == before


def test_a_size_from_the_models_config_is_named_as_such(tmp_path, monkeypatch, capsys):
    """A mesh resolution too large for memory that came from the model's config, not the command line, is named
    as the config's setting (the old message spoke of a --mesh-resolution the user never gave)."""
    from sin3dm_lite.app import device

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(device, "memory_available", lambda _device: 2 << 30)
    run = _run(tmp_path, "run", {**BUNDLE, "config": _config(**{"sampling.mesh_resolution": 2048})})
    line = _one_line(capsys, main(["sample", run, "--out", "s", "-n", "1", "--workers", "0", "--steps", "3"]))
    assert "sampling.mesh_resolution of the model's config (used without --mesh-resolution) 2048 is too large" in line
    assert not (tmp_path / "s").exists()


def test_fit_with_a_network_beyond_memory_is_refused_before_any_work(
    tmp_path, monkeypatch, capsys, real_nets_stay_small
):
    """The same estimate for a fit: --set (or a config.json and input.json edited together) that asks for a denoiser
    of terabytes is refused before the grid is made, and no run folder is left."""
    monkeypatch.chdir(tmp_path)
    argv = ["fit", "wall", "--preset", "tiny", "--out", "r", "--set", "grid.resolution=24", "autoencoder.steps=2"]
    argv += ["diffusion.base_channels=4096", "diffusion.n_resblocks=64"]
    line = _one_line(capsys, main(argv))
    assert "the config's denoiser (diffusion.base_channels 4096, n_resblocks 64" in line and "GiB to train" in line
    assert list(tmp_path.iterdir()) == []

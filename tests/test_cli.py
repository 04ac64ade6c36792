"""The sin3dm-lite command: outputs and one-line errors with exit code 2."""

import json

import numpy as np
import pytest
import trimesh

from sin3dm_lite.cli import main
from sin3dm_lite.examples import list_examples

from .conftest import CHEAP_SAMPLE


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_examples_list_and_write(capsys, tmp_path):
    code, out, _ = run(capsys, "examples")
    assert code == 0 and all(name in out for name in list_examples())
    code, out, _ = run(capsys, "examples", "--write", "wall", "--out", str(tmp_path))
    assert code == 0
    assert (tmp_path / "wall.obj").is_file() and (tmp_path / "wall.mtl").is_file()
    m = trimesh.load(tmp_path / "wall.obj", force="mesh")
    assert len(m.faces) > 1000


def test_grid_command_writes_the_npz(capsys, tmp_path):
    mesh = tmp_path / "box.obj"
    trimesh.creation.box(extents=(1, 0.5, 0.5)).export(mesh)
    out = tmp_path / "grid.npz"
    code, text, _ = run(capsys, "grid", str(mesh), "--resolution", "32", "--out", str(out))
    assert code == 0 and "(32, 16, 16)" in text
    with np.load(out) as z:
        assert z["sdf"].shape == (32, 16, 16) and z["sdf"].dtype == np.float32
        assert z["color"].shape == (32, 16, 16, 3) and 0 <= z["color"].min() and z["color"].max() <= 1
        assert z["aabb"].shape == (6,)
        assert "center" in z and "scale" in z


def test_grid_command_turns_a_z_up_mesh_upright(capsys, tmp_path):
    """`grid --up z`: a box long in z (a tower modelled Z-up) becomes a grid long in y, as a Y-up file would."""
    mesh = tmp_path / "tower.stl"
    trimesh.creation.box(extents=(0.5, 0.5, 1.0)).export(mesh)
    for up, shape in ((None, "(16, 16, 32)"), ("z", "(16, 32, 16)")):
        out = tmp_path / f"grid_{up}.npz"
        code, text, _ = run(
            capsys, "grid", str(mesh), "--resolution", "32", "--out", str(out), *(["--up", up] if up else [])
        )
        assert code == 0 and shape in text


@pytest.mark.parametrize(
    "argv, words",
    [
        (["grid", "missing.obj", "--out", "g.npz"], "not found"),
        (["grid", "mesh.xyz", "--out", "g.npz"], "extension"),
        (["grid", "box.obj", "--resolution", "8", "--out", "g.npz"], "resolution"),
        (["grid", "box.obj", "--resolution", "100000", "--out", "g.npz"], "resolution"),
        (["grid", "box.obj", "--out", "g.txt"], ".npz"),
        (["sample", "no_run_here", "--out", "s"], "run folder"),
        (["fit", "no_such_thing", "--preset", "tiny", "--out", "r"], "example"),
        (["fit", "box.obj", "--out", "r", "--resume"], "resume"),
    ],
)
def test_bad_input_exits_2_with_one_line_and_no_output(capsys, tmp_path, monkeypatch, argv, words):
    monkeypatch.chdir(tmp_path)
    trimesh.creation.box().export(tmp_path / "box.obj")
    (tmp_path / "mesh.xyz").write_text("1 2 3\n")
    before = set(p.name for p in tmp_path.iterdir())
    code, _, err = run(capsys, *argv)
    assert code == 2
    assert words in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert set(p.name for p in tmp_path.iterdir()) == before  # no half-written output


@pytest.mark.parametrize("resize", [["0", "1", "1"], ["-2", "1", "1"], ["a", "1", "1"]])
def test_bad_resize_is_rejected_by_the_parser(capsys, resize):
    with pytest.raises(SystemExit) as e:
        main(["sample", "run", "--out", "s", "--resize", *resize])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--resize" in err and ("positive" in err or "number" in err or "(0, 8]" in err)


def test_demo_with_the_shipped_model_writes_meshes_and_a_viewer_page(capsys, tmp_path):
    out = tmp_path / "demo"
    code, text, _ = run(
        capsys,
        "demo",
        "--out",
        str(out),
        "-n",
        "2",
        "--steps",
        "5",
        "--mesh-resolution",
        "48",
        "--faces",
        "1500",
        "--texture-size",
        "128",
    )
    assert code == 0 and "index.html" in text
    for i in ("000", "001"):
        m = trimesh.load(out / i / "mesh.obj", force="mesh")
        assert len(m.faces) > 100 and m.visual.uv is not None
        assert (out / i / "mesh.glb").is_file()
    assert (out / "index.html").stat().st_size > 100_000
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp folder left


def test_sample_diversity_zero_gives_the_input_back(capsys, tmp_path):
    """`--diversity 0` regenerates nothing: the mesh is the shipped model's reconstruction of its input."""
    from sin3dm_lite.app.pretrained import pretrained_path
    from sin3dm_lite.pipeline import Sin3DM

    out = tmp_path / "closest"
    code, _, _ = run(
        capsys,
        "sample",
        str(pretrained_path()),
        "--out",
        str(out),
        "-n",
        "1",
        "--diversity",
        "0",
        "--mesh-resolution",
        "40",
        "--faces",
        "1500",
        "--texture-size",
        "64",
    )
    assert code == 0
    got = trimesh.load(out / "000" / "mesh.obj", force="mesh")
    model = Sin3DM.load(pretrained_path())
    ref = model.to_mesh(model.input_sample(), 0, resolution=40, faces=1500, vertex_colors=True)
    unique = lambda v: np.unique(np.round(np.asarray(v), 4), axis=0)  # noqa: E731  the OBJ splits vertices at UV seams
    np.testing.assert_allclose(unique(got.vertices), unique(ref.vertices), atol=2e-4)


@pytest.mark.parametrize("value", ["-0.1", "1.5", "much"])
def test_bad_diversity_is_rejected_by_the_parser(capsys, value):
    flag = "--diversity"
    with pytest.raises(SystemExit) as e:
        main(["sample", "run", "--out", "s", flag, value])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert flag in err and len(err.strip().splitlines()) == 1


# ----------------------------------------------------------------------------- help, version, formats
def _flat(text: str) -> str:
    return " ".join(text.split())


def test_no_arguments_prints_the_help_and_succeeds(capsys):
    from sin3dm_lite.cli import COMMANDS

    code, out, err = run(capsys)
    assert code == 0 and err == "" and out.startswith("usage: sin3dm-lite")
    for name, line in COMMANDS.items():  # every command with its one-line description
        assert f"{name} {line}" in _flat(out), name
    assert "--version" in out


def test_version(capsys):
    from importlib import metadata

    from sin3dm_lite.cli import package_version

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out == f"sin3dm-lite {package_version()}\n"
    assert package_version() == metadata.version("sin3dm-lite")


def _subparsers():
    import argparse

    from sin3dm_lite.cli import build_parser

    (sub,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return sub.choices


def test_an_option_of_several_values_given_twice_keeps_both():
    """Every option that takes several values (`fit --set`, `evaluate --resolution`, ...) adds what a second use
    gives to the first; argparse's default keeps only the last, silently."""
    import argparse

    from sin3dm_lite.cli import build_parser

    lists = [
        (name, a.option_strings[0])
        for name, parser in _subparsers().items()
        for a in parser._actions
        if a.option_strings and a.nargs == "+"
    ]
    assert ("fit", "--set") in lists and ("evaluate", "--resolution") in lists
    for name, option in lists:
        (action,) = [a for a in _subparsers()[name]._actions if option in a.option_strings]
        assert isinstance(action, argparse._ExtendAction), f"{name} {option}"
    a = build_parser().parse_args(["evaluate", "RUN", "S", "--resolution", "64", "--resolution", "128"])
    assert a.resolution == [64, 128]


@pytest.mark.parametrize("command", ["examples", "grid", "fit", "sample", "demo", "render", "evaluate"])
def test_every_command_has_a_description_and_every_option_its_default(capsys, command):
    import argparse

    from sin3dm_lite.cli import COMMANDS

    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "\n" not in COMMANDS[command] and COMMANDS[command] in _flat(out)
    parser = _subparsers()[command]
    fmt = parser._get_formatter()
    groups = {id(a): g.title for g in parser._action_groups for a in g._group_actions}
    for action in parser._actions:
        if (
            not action.option_strings
            or isinstance(action, (argparse._HelpAction, argparse._StoreTrueAction))
            or action.required
        ):
            continue
        text = fmt._expand_help(action)
        if action.default is None and "default" in (groups.get(id(action)) or ""):
            continue  # --resize/--outpaint/...: their group's title says what happens without them
        assert text.count("default") == 1, (action.option_strings, text)  # shown, and only once


def test_the_help_lists_exactly_the_formats_that_load(tmp_path, capsys):
    """``READABLE`` names every suffix the loader takes and no other; one tiny mesh of each loads."""
    import re

    from sin3dm_lite.formats.load import READABLE, SUPPORTED_EXTENSIONS, load_mesh

    words = {w.lower() for w in re.findall(r"[A-Za-z]+", READABLE)} - {"mtl"}
    assert words == {ext[1:] for ext in SUPPORTED_EXTENSIONS}
    box = trimesh.creation.box(extents=(1.0, 0.5, 0.25))
    for ext in SUPPORTED_EXTENSIONS:
        path = tmp_path / f"box{ext}"
        if ext == ".gltf":  # a .gltf is a JSON file plus its buffers
            for name, data in box.export(file_type="gltf").items():
                (tmp_path / (path.name if name.endswith(".gltf") else name)).write_bytes(data)
        else:
            box.export(path)
        m = load_mesh(path)
        assert len(m.faces) == 12, ext
        np.testing.assert_allclose(m.vertices.max(0) - m.vertices.min(0), [1.0, 0.5, 0.25], atol=1e-6)
    for command in ("grid", "fit", "render"):  # each command that reads a mesh says so
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert READABLE in _flat(capsys.readouterr().out), command


@pytest.mark.filterwarnings("ignore:low reconstruction")  # a micro fit
def test_demo_example_with_train_fits_that_example(capsys, tmp_path, monkeypatch):
    """`demo --example wall --train` fits the wall (the micro settings here, to be quick) and writes its samples."""
    from sin3dm_lite.cli import sample_cli

    from .conftest import micro_config

    monkeypatch.setattr(sample_cli, "DEMO_PRESET", micro_config())
    out = tmp_path / "demo"
    code, text, err = run(
        capsys,
        "demo",
        "--example",
        "wall",
        "--train",
        "--out",
        str(out),
        "-n",
        "1",
        *CHEAP_SAMPLE,
    )
    assert code == 0, err
    assert (out / "000" / "mesh.obj").is_file() and (out / "index.html").is_file()
    assert "decode, texture, export" in err  # the progress bar over the per-mesh work
    assert "[demo] 1/1:" in text


def test_demo_of_an_example_without_a_shipped_model_says_what_to_do(capsys, tmp_path, monkeypatch):
    """Every built-in example may have a shipped model; hide the wall's to see the message for one that has none."""
    from sin3dm_lite.app import pretrained

    real = pretrained.shipped_model
    monkeypatch.setattr(
        pretrained, "shipped_model", lambda name: None if name in ("wall", "wall_small") else real(name)
    )
    code, out, err = run(capsys, "demo", "--example", "wall", "--out", str(tmp_path / "s"))
    assert code == 2 and "no shipped model of 'wall'" in err and "--train" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "s").exists()


class _FitCalled(Exception):
    pass


def _preset_fit_gets(tmp_path, monkeypatch, *argv, machine: str = "small"):
    """Run `sin3dm-lite fit ...` up to Sin3DM.fit and return the preset (a Config) it would fit with; without
    --preset the machine's default is pinned to ``machine`` (no timing: tests/test_fit_default.py tests the choice)."""
    from sin3dm_lite.auto import fit_default
    from sin3dm_lite.data.config import Config
    from sin3dm_lite.pipeline import Sin3DM
    from sin3dm_lite.presets import get_preset

    monkeypatch.setattr(
        fit_default, "default_preset", lambda device=None, mesh=None, **kw: fit_default.DefaultPreset(machine, "pinned")
    )
    seen = {}

    def fake_fit(mesh, preset, **kw):
        seen["preset"] = preset
        raise _FitCalled

    monkeypatch.setattr(Sin3DM, "fit", staticmethod(fake_fit))
    with pytest.raises(_FitCalled):
        main(["fit", *argv, "--out", str(tmp_path / "run")])
    return seen["preset"] if isinstance(seen["preset"], Config) else get_preset(seen["preset"])


def test_fit_set_changes_the_preset_and_names_a_bad_setting(capsys, tmp_path, monkeypatch):
    """`fit --set diffusion.rollout=true` fits small with the rollout, with one `--set` or several; a misspelt
    setting is one line, no folder."""
    cfg = _preset_fit_gets(tmp_path, monkeypatch, "wall", "--set", "diffusion.rollout=true", "diffusion.steps=1500")
    assert cfg.name == "small" and cfg.diffusion.rollout is True and cfg.diffusion.steps == 1500
    # one --set a setting: each is kept, not only the last
    cfg = _preset_fit_gets(
        tmp_path, monkeypatch, "wall", "--set", "diffusion.rollout=true", "--set", "diffusion.steps=900"
    )
    assert cfg.diffusion.rollout is True and cfg.diffusion.steps == 900
    code, _, err = run(capsys, "fit", "wall", "--out", str(tmp_path / "bad"), "--set", "diffusion.rolout=true")
    assert code == 2 and "unknown config setting 'diffusion.rolout'" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "bad").exists()


@pytest.mark.filterwarnings("ignore:low reconstruction")  # a few training steps
def test_a_fit_says_its_colour_psnr_over_the_band_and_at_the_surface(capsys, tmp_path):
    """The fit's last line gives the reconstruction's colour PSNR over the truncation band and at the surface, the
    colour a baked texture shows (the figure the low-quality warning judges)."""
    settings = ["autoencoder.steps=20", "diffusion.steps=2", "sampling.steps=2", "sampling.mesh_resolution=24"]
    code, out, _ = run(capsys, "fit", "wall", "--preset", "tiny", "--out", str(tmp_path / "r"), "--set", *settings)
    rec = json.loads((tmp_path / "r" / "report.json").read_text())["reconstruction"]
    line = f"colour PSNR {rec['color_psnr']:.1f} dB ({rec['color_psnr_surface']:.1f} at the surface)"
    assert code == 0 and line in out


@pytest.mark.filterwarnings("ignore:low reconstruction")  # a few training steps
def test_a_mesh_without_colour_fits_its_geometry_only_and_its_samples_keep_the_grey(capsys, tmp_path, monkeypatch):
    """An STL has no colour: the fit says the autoencoder learns the geometry alone, reports the colour as kept
    (not a PSNR), records it in the report, and its meshes are the default grey."""
    from sin3dm_lite.data.mesh import DEFAULT_COLOR
    from sin3dm_lite.pipeline import Sin3DM

    trimesh.creation.box(extents=(1.0, 0.6, 0.4)).export(tmp_path / "box.stl")
    settings = ["autoencoder.steps=80", "diffusion.steps=2", "sampling.steps=2", "sampling.mesh_resolution=24"]
    code, out, _ = run(
        capsys, "fit", str(tmp_path / "box.stl"), "--preset", "tiny", "--out", str(tmp_path / "r"), "--set", *settings
    )
    assert code == 0
    assert "[fit] 'box' has one colour (0.70, 0.70, 0.70; a mesh without colour gets this grey)" in out
    # an STL does not say its up axis: the fit says how to turn it, once
    assert out.count("[fit] STL files do not say which way is up") == 1 and "--up z" in out
    assert "one colour, kept" in out and "colour PSNR" not in out
    model = Sin3DM.load(tmp_path / "r")
    # the last line names what the autoencoder trained in, as the report records it
    assert f"(autoencoder in {model.report['precision']['autoencoder']}):" in out
    np.testing.assert_allclose(model.report["single_color"], DEFAULT_COLOR, atol=1e-6)
    mesh = model.to_mesh(model.input_sample(), 0)  # the input's latent (a 2-step denoiser's samples are noise)
    colors = mesh.vertex_colors if mesh.vertex_colors is not None else mesh.materials[0].image
    rgb = colors.reshape(-1, colors.shape[-1])[:, :3]
    np.testing.assert_allclose(rgb, np.broadcast_to(DEFAULT_COLOR, rgb.shape), atol=2 / 255)


def test_warnings_are_one_line_and_a_librarys_syntax_warnings_are_not_shown(capsys, monkeypatch):
    """A warning about the user's input reaches them as one line; a library's SyntaxWarning (its source compiled on
    first import, e.g. without .pyc files) says nothing about their shape and is not printed."""
    import warnings

    import sin3dm_lite.cli as cli

    def command(a):
        warnings.simplefilter("always")
        warnings.warn_explicit("invalid escape sequence '\\#'", SyntaxWarning, "/site/pcu/_geometry.py", 9)
        warnings.warn("3 faces of 'x' are wound against their neighbours", stacklevel=2)

    monkeypatch.setattr(cli, "run_command", command)
    code, _, err = run(capsys, "examples")
    assert code == 0
    assert err.splitlines() == ["sin3dm-lite examples: warning: 3 faces of 'x' are wound against their neighbours"]


@pytest.mark.filterwarnings("ignore:low reconstruction")  # a few training steps
def test_a_z_up_mesh_fitted_with_up_z_stands_upright_and_is_judged_against_its_file(capsys, tmp_path):
    """`fit --up z` turns a Z-up tower so that it stands along y: the run records grid.up, the fit says so, the
    samples it writes are long in y, and the input file (still Z-up) is turned the same way when samples are
    compared with it. A resumed fit keeps its run's up axis."""
    from sin3dm_lite.formats.load import load_mesh
    from sin3dm_lite.pipeline import Sin3DM

    mesh = tmp_path / "tower.stl"
    trimesh.creation.box(extents=(0.4, 0.6, 1.0)).export(mesh)
    settings = ["autoencoder.steps=80", "diffusion.steps=2", "sampling.steps=2", "sampling.mesh_resolution=24"]
    run_dir = tmp_path / "r"
    code, out, _ = run(
        capsys, "fit", str(mesh), "--preset", "tiny", "--up", "z", "--out", str(run_dir), "--set", *settings
    )
    assert code == 0 and "[fit] 'tower' turned Z-up to Y-up: its samples are written Y-up" in out
    assert "which way is up" not in out  # told, so not asked
    assert json.loads((run_dir / "config.json").read_text())["grid"]["up"] == "z"
    model = Sin3DM.load(run_dir)
    size = np.ptp(model.to_mesh(model.input_sample(), 0).vertices, axis=0)
    assert size[1] > 1.4 * size[2]  # its height along y, as the box's 1.0 against 0.6
    occupied = model.input_occupancy(load_mesh(mesh), resolution=32).any(axis=(0, 2)).mean()
    model.config.grid.up = "y"  # read as it lies: the box's 0.6 along y
    unturned = model.input_occupancy(load_mesh(mesh), resolution=32).any(axis=(0, 2)).mean()
    assert occupied > 0.75 and unturned < 0.7 * occupied  # the Z-up file fills the box along y: turned as in the fit
    code, _, err = run(capsys, "fit", str(mesh), "--up", "z", "--out", str(run_dir), "--resume")
    assert code == 2 and "up is for a new fit" in err


@pytest.mark.filterwarnings("ignore:low reconstruction")  # a few training steps
def test_a_mesh_whose_walls_lie_across_the_axes_is_fitted_turned_and_its_samples_turned_back(capsys, tmp_path):
    """A box turned 30° about y: the fit says it turns the walls along x and z, records grid.turn, keeps the turn
    in the model (saved and loaded), and writes its samples turned back, where the input lies; `--turn 0` fits it
    as it lies."""
    from sin3dm_lite.formats.load import load_mesh
    from sin3dm_lite.pipeline import Sin3DM

    from .conftest import textured

    box = textured(trimesh.creation.box(extents=(1.0, 0.6, 0.4))).turned_about_y(30.0)
    path = tmp_path / "slab.stl"
    trimesh.Trimesh(box.vertices, box.faces).export(path)
    settings = ["autoencoder.steps=150", "diffusion.steps=2", "sampling.steps=2", "sampling.mesh_resolution=32"]
    code, out, _ = run(capsys, "fit", str(path), "--preset", "tiny", "--out", str(tmp_path / "r"), "--set", *settings)
    assert code == 0 and "[fit] the walls of 'slab' lie 30° off the x and z axes: turned along them" in out
    assert json.loads((tmp_path / "r" / "config.json").read_text())["grid"]["turn"] == pytest.approx(-30.0)
    model = Sin3DM.load(tmp_path / "r")
    assert not np.allclose(model.normalization.rotation, np.eye(3))
    input_box = np.ptp(load_mesh(path).vertices, axis=0)
    sample = model.to_mesh(model.input_sample(), 0)  # the input's own latent, decoded and turned back
    np.testing.assert_allclose(np.ptp(sample.vertices, axis=0), input_box, rtol=0.12)
    flat = model.to_mesh(model.input_sample(), 0, original_coords=False)  # in the model's frame: along x and z
    size = np.ptp(flat.vertices, axis=0)
    assert size[0] / size[2] > 2.0  # 1.0 against 0.4, where the turned input's box is about 1.07 against 0.85
    code, out, _ = run(
        capsys, "fit", str(path), "--preset", "tiny", "--turn", "0", "--out", str(tmp_path / "r0"), "--set", *settings
    )
    assert code == 0 and "off the x and z axes" not in out
    assert json.loads((tmp_path / "r0" / "config.json").read_text())["grid"]["turn"] == 0.0

"""``sin3dm-lite evaluate`` and ``Sin3DM.evaluate`` on the shipped model of the wall with two samples."""

import json

import numpy as np
import pytest

from sin3dm_lite import Sin3DM, get_preset, pretrained_path
from sin3dm_lite.cli import main
from sin3dm_lite.files import read_manifest

GEOMETRY = {"g_div", "lp_iou", "lp_fscore", "lp_iou_any_offset", "lp_fscore_any_offset", "iou_to_input"}
KEYS = GEOMETRY | {"ssfid", "patch_swd", "render_div", "sifid", "lpips"}


@pytest.fixture(scope="module")
def tiny_samples(tmp_path_factory):
    """The shipped model of the wall example with the ``tiny`` preset's sampling settings (meshes at 48 voxels),
    saved as a run folder, and two samples of it, written by the CLI.

    No fit to wait for. (A fit much smaller than ``tiny`` would do for the plumbing, but its samples are hardly
    walls, IoU to the input 0.38 against the shipped model's 0.87: the checks below would pass on degenerate
    scores.)"""
    root = tmp_path_factory.mktemp("evaluate")
    model = Sin3DM.load(pretrained_path("wall_small"))
    model.config.sampling = get_preset("tiny").sampling
    model.save(root / "run")
    assert (
        main(
            [
                "sample",
                str(root / "run"),
                "-n",
                "2",
                "--out",
                str(root / "samples"),
                "--steps",
                "5",
                "--faces",
                "1500",
                "--texture-size",
                "128",
                "--no-pictures",
            ]
        )
        == 0
    )
    return root


def test_evaluate_writes_the_metrics_as_json(tiny_samples, capsys):
    out = tiny_samples / "report" / "evaluation.json"
    capsys.readouterr()
    code = main(
        [
            "evaluate",
            str(tiny_samples / "run"),
            str(tiny_samples / "samples"),
            "--out",
            str(out),
            "--views",
            "4",
            "--size",
            "96",
            "--resolution",
            "32",
        ]
    )
    text = capsys.readouterr().out
    assert code == 0 and "G-Div" in text and "LP-IoU" in text and "ssfid" in text
    r = json.loads(out.read_text())
    assert r["samples"] == 2 and r["views"] == 4 and r["size"] == 96 and r["resolution"] == 32
    m = r["metrics"]
    assert set(m) == KEYS
    for k in ("g_div", "lp_iou", "lp_fscore", "iou_to_input"):
        assert 0 <= m[k] <= 1, k
    assert m["iou_to_input"] > 0.3  # the samples are walls like the input
    assert m["ssfid"] is None and "Clsshapenet_128.pth" in r["skipped"]["ssfid"]
    if "texture" in r["skipped"]:  # no off-screen renderer here: said in one line, the geometry is still there
        assert m["patch_swd"] is None and "texture metrics skipped" in text
    else:
        assert 0 <= m["patch_swd"] < 1 and 0 <= m["render_div"] <= 1
        assert m["sifid"] is None and m["lpips"] is None and "--weights" in r["skipped"]["sifid"]
    assert "evaluation.json" in read_manifest(out.parent)
    # the file is ours: refused without --overwrite, replaced with it
    argv = [
        "evaluate",
        str(tiny_samples / "run"),
        str(tiny_samples / "samples"),
        "--out",
        str(out),
        "--views",
        "2",
        "--size",
        "64",
        "--resolution",
        "32",
    ]
    assert main(argv) == 2 and "--overwrite" in capsys.readouterr().err
    assert main(argv + ["--overwrite"]) == 0 and json.loads(out.read_text())["views"] == 2


def test_evaluate_reports_the_papers_grid_and_the_fits_own_by_default(tiny_samples, capsys):
    """Without --resolution: every metric at the paper's 128 voxels, the geometry again on the fit's 64-voxel grid,
    as a second column and in ``geometry_at``, the same numbers an evaluation at 64 alone gives."""
    run, samples, out = str(tiny_samples / "run"), str(tiny_samples / "samples"), tiny_samples / "both"
    small = ["--views", "2", "--size", "48"]
    capsys.readouterr()
    assert main(["evaluate", run, samples, "--out", str(out / "both.json"), *small]) == 0
    header = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("metric"))
    assert header.split()[1:5] == ["128", "voxels", "64", "voxels"]
    r = json.loads((out / "both.json").read_text())
    assert r["resolution"] == 128 and set(r["geometry_at"]) == {"64"} and r["geometry_at"]["64"]["voxels"] == 64
    at64 = r["geometry_at"]["64"]["metrics"]
    assert set(at64) == GEOMETRY and all(0 <= v <= 1 for v in at64.values())
    # the input's patches at every voxel include those on the paper's lattice: the variant never scores lower
    assert at64["lp_iou_any_offset"] >= at64["lp_iou"] and at64["lp_fscore_any_offset"] >= at64["lp_fscore"]
    assert main(["evaluate", run, samples, "--out", str(out / "64.json"), "--resolution", "64", *small]) == 0
    alone = json.loads((out / "64.json").read_text())
    assert "geometry_at" not in alone and {k: alone["metrics"][k] for k in at64} == at64
    assert main(["evaluate", run, samples, "--resolution", "32", "600"]) == 2
    err = capsys.readouterr().err
    assert "600" in err and len(err.strip().splitlines()) == 1
    # the paper's voxels sample twice as fine: 300 voxels would be 600 sub-voxels a side, refused before any work
    assert main(["evaluate", run, samples, "--resolution", "300", "--out", str(out / "300.json")]) == 2
    err = capsys.readouterr().err
    assert "600 a side" in err and "--voxels centres" in err and len(err.strip().splitlines()) == 1
    assert not (out / "300.json").exists()


def test_the_facade_evaluates_samples_it_just_drew(tiny_samples):
    from sin3dm_lite import Sin3DM

    model = Sin3DM.load(tiny_samples / "run")
    samples = model.sample(2, steps=3, seed=1, progress=False)
    r = model.evaluate(samples, resolution=32, views=2, size=64, progress=False)
    assert r["samples"] == 2 and 0 <= r["metrics"]["g_div"] <= 1 and 0 <= r["metrics"]["lp_iou"] <= 1
    # Sin3DM.occupancy voxelises each sample's mesh the way it is told (the paper's: solid where any sub-voxel is)
    from sin3dm_lite import metrics

    mesh = model.to_mesh(samples, 0, original_coords=False, vertex_colors=True)
    for k in (1, 2):
        grid = model.occupancy(samples, 32, supersample=k)[0]
        assert np.array_equal(grid, metrics.voxelize(mesh, samples.aabb, 32, supersample=k))
    assert (model.occupancy(samples, 32, supersample=2)[0] & ~model.occupancy(samples, 32)[0]).any()


def test_without_a_renderer_only_the_geometry_is_reported(tiny_samples, capsys, monkeypatch):
    import sin3dm_lite.evaluate.render

    monkeypatch.setattr(sin3dm_lite.evaluate.render, "renderer_problem", lambda: "no EGL here (test)")
    capsys.readouterr()
    assert main(["evaluate", str(tiny_samples / "run"), str(tiny_samples / "samples"), "--resolution", "32"]) == 0
    text = capsys.readouterr().out
    assert [line for line in text.splitlines() if "texture metrics skipped: no EGL here (test)" in line]
    assert "g_div" in text and not (tiny_samples / "samples" / "evaluation.json").exists()


def test_evaluate_voxelises_as_the_paper_unless_told_the_centres(tiny_samples, capsys, monkeypatch):
    """By default input and samples become voxels as in the paper's evaluation code (solid where any of a voxel's
    2³ sub-voxels is inside); ``--voxels centres`` samples the voxel centres. Each result is the metrics of the grids
    voxelised that way."""
    import numpy as np

    import sin3dm_lite.evaluate.render
    from sin3dm_lite import metrics
    from sin3dm_lite.cli.evaluate_cli import sample_mesh_files
    from sin3dm_lite.formats.load import load_any

    monkeypatch.setattr(sin3dm_lite.evaluate.render, "renderer_problem", lambda: "no EGL here (test)")
    run, samples, out = tiny_samples / "run", tiny_samples / "samples", tiny_samples / "voxels"
    results = {}
    for how in ("paper", "centres"):
        args = ["evaluate", str(run), str(samples), "--resolution", "32", "--out", str(out / f"{how}.json")]
        capsys.readouterr()
        assert main(args + ([] if how == "paper" else ["--voxels", how])) == 0
        shown = {"paper": "(the paper's voxels: any of 2³ points inside)", "centres": "(the voxel centres)"}[how]
        assert shown in capsys.readouterr().out
        results[how] = json.loads((out / f"{how}.json").read_text())
    assert results["paper"]["supersample"] == 2 and results["centres"]["supersample"] == 1
    model = Sin3DM.load(run)
    meshes = [load_any(f) for f in sample_mesh_files(samples)]
    normed = [(model.normalization.to_normalized(np.asarray(m.vertices, np.float64)), m.faces) for m in meshes]
    lo = np.minimum(model.aabb[:3], np.min([v.min(0) for v, _ in normed], axis=0))
    hi = np.maximum(model.aabb[3:], np.max([v.max(0) for v, _ in normed], axis=0))
    box = np.concatenate([lo, hi])
    res = int(round(32 * (hi - lo).max() / (model.aabb[3:] - model.aabb[:3]).max()))
    for how, k in (("paper", 2), ("centres", 1)):
        ref = model.input_occupancy(model.input_mesh(), res, aabb=box, supersample=k)
        want = metrics.geometry_scores(ref, [metrics.voxelize(m, box, res, supersample=k) for m in normed])
        got = results[how]["metrics"]
        assert {key: got[key] for key in GEOMETRY} == pytest.approx(want)
    assert results["paper"]["metrics"] != results["centres"]["metrics"]


def test_samples_larger_than_the_input_cannot_grow_the_grid_past_what_fits(tiny_samples):
    """Retargeted samples grow the evaluation box at the input's voxel size; with the paper's voxels a grid whose
    sub-voxels would pass 512 a side is refused in one clear error instead of filling the memory."""
    from dataclasses import replace

    from sin3dm_lite.cli.evaluate_cli import sample_mesh_files
    from sin3dm_lite.errors import Sin3DMInputError
    from sin3dm_lite.formats.load import load_any

    model = Sin3DM.load(tiny_samples / "run")
    meshes = [load_any(f) for f in sample_mesh_files(tiny_samples / "samples")]
    centre = model.normalization.to_original(model.aabb.reshape(2, 3)).mean(axis=0)
    bigger = [replace(m, vertices=(m.vertices - centre) * 2.5 + centre) for m in meshes]  # a box 2.5x as wide
    with pytest.raises(Sin3DMInputError, match=r"a side, more than 512.*--voxels centres"):
        model.evaluate(bigger, resolution=128, views=1, size=16, progress=False)

"""The preset a fit takes when none is named: this machine's and this shape's, said first with why and how long."""

import warnings

import numpy as np
import pytest
import torch

from sin3dm_lite.auto import fit_default
from sin3dm_lite.cli import main
from sin3dm_lite.presets import get_preset


@pytest.mark.parametrize(
    "cuda, share, fast, preset, why",
    [
        (True, None, True, "paper", "this machine (a CUDA GPU, NVIDIA H200: the paper's settings)"),
        (False, 0.4, True, "small", "this machine (a CPU whose bf16 runs in 0.4x fp32's time: the autoencoder in"),
        (False, 1.6, False, "quick", "this machine (a CPU whose native bf16 runs in 1.6x fp32's time, no faster"),
        (False, None, False, "quick", "this machine (a CPU without native bf16: a light autoencoder"),
    ],
    ids=["gpu", "cpu-fast-bf16", "cpu-slow-bf16", "cpu-avx2"],
)
def test_the_default_preset_follows_the_machine(monkeypatch, cuda, share, fast, preset, why):
    dev = torch.device("cuda" if cuda else "cpu")
    monkeypatch.setattr(fit_default, "get_device", lambda device=None: dev)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda d=None: "NVIDIA H200")
    monkeypatch.setattr(fit_default, "cpu_bf16_share", lambda: share)
    monkeypatch.setattr(fit_default, "bf16_is_fast", lambda d: fast)
    name, said = fit_default.choose_preset()
    assert name == preset and said.startswith(why)
    chosen = fit_default.default_preset(timed=False)
    assert chosen.name == preset and chosen.lines() == [
        f"[fit] no preset named: '{preset}' for {said}; name one to choose another (CLI --preset NAME)"
    ]


def test_the_estimate_times_a_few_steps_of_each_network_and_scales_them_by_the_steps():
    """A few real steps of tiny's autoencoder and denoiser; the estimate grows with the steps, the grid and the
    calibration add their share, and the random state is left as it was."""
    torch.manual_seed(3)
    before = torch.rand(4)
    torch.manual_seed(3)
    tiny = get_preset("tiny")
    est = fit_default.estimate_fit(tiny)
    assert torch.equal(torch.rand(4), before)
    assert est["autoencoder"] > 0 and est["denoiser"] > 0
    # tiny does not calibrate: the grid alone
    assert est["other"] == pytest.approx(fit_default.OTHER_SHARE_GRID * (est["autoencoder"] + est["denoiser"]))
    assert est["total"] == pytest.approx(est["autoencoder"] + est["denoiser"] + est["other"])
    longer = fit_default.estimate_fit(tiny.updated(**{"autoencoder.steps": 100 * tiny.autoencoder.steps}))
    assert longer["autoencoder"] > 10 * est["autoencoder"]  # 100x the steps (timing noise aside)
    line = fit_default.DefaultPreset("quick", "why", {"autoencoder": 60, "denoiser": 120, "other": 27, "total": 207})
    assert line.lines()[1] == (
        "[fit] it should take about 3 min here (autoencoder 1.0 + denoiser 2.0 + grid and calibration 0.5 min, from "
        "5 steps of each timed just now)"
    )
    paper = fit_default.DefaultPreset("paper", "why", {"autoencoder": 60, "denoiser": 120, "other": 2, "total": 182})
    assert "+ grid 0.0 min, from" in paper.lines()[1]  # it does not calibrate: no calibration is promised


def test_a_step_is_timed_as_the_mean_of_several_after_the_first_ones(monkeypatch):
    """A fit costs the mean of its steps: on a shared machine some steps run slower, and the fastest of a few is the
    estimate's best case (which fell 8-43 % short of the autoencoder's time in three real fits). The first two steps
    allocate and are not timed."""
    clock = [0.0]
    durations = iter([9.0, 9.0, 1.0, 1.0, 1.0, 1.0, 6.0])

    class Trainer:
        def step(self):
            clock[0] += next(durations)

    monkeypatch.setattr(fit_default.time, "perf_counter", lambda: clock[0])
    assert fit_default.TIMED_STEPS == 5
    assert fit_default._seconds_per_step(Trainer()) == pytest.approx(2.0)


def test_the_estimate_of_a_compiled_denoiser_is_its_share_of_the_eager_step_plus_the_compile(monkeypatch):
    """`paper` compiles its denoiser (on a GPU 0.63 of the eager step after about 90 s); the estimate times the
    eager step, so it scales it and adds the compile, or it overstates a GPU fit by a third."""
    monkeypatch.setattr(fit_default, "_seconds_per_step", lambda trainer: 0.01)
    tiny = get_preset("tiny")
    eager = fit_default.estimate_fit(tiny)
    compiled = fit_default.estimate_fit(tiny.updated(**{"diffusion.compile": True}))
    assert eager["denoiser"] == pytest.approx(0.01 * tiny.diffusion.steps)
    share, seconds = fit_default.COMPILED_SHARE["cpu"], fit_default.COMPILE_S["cpu"]
    assert compiled["denoiser"] == pytest.approx(share * eager["denoiser"] + seconds)
    assert compiled["autoencoder"] == eager["autoencoder"]


class _FitCalled(Exception):
    pass


def _quick_here(monkeypatch, seconds=(120, 60, 27)):
    """The default picks `quick` here, estimated at ``seconds`` for the autoencoder, the denoiser and the rest."""
    monkeypatch.setattr(fit_default, "choose_preset", lambda device=None: ("quick", "this machine (test)"))
    monkeypatch.setattr(
        fit_default,
        "estimate_fit",
        lambda cfg, device=None, box=None, one_colour=False, calibrated=True: dict(
            zip(("autoencoder", "denoiser", "other", "total"), (*seconds, sum(seconds)))
        ),
    )


def _fit_cli(monkeypatch, tmp_path, capsys, *argv, seconds=(120, 60, 27)):
    """`sin3dm-lite fit wall ...` up to Sin3DM.fit: (the preset it was handed, what was printed before); the
    estimate: ``seconds`` of the autoencoder, the denoiser and the rest."""
    from sin3dm_lite.pipeline import Sin3DM

    seen = {}

    def fake_fit(mesh, preset, **kw):
        seen["preset"], seen["printed"] = preset, capsys.readouterr().out
        _fit_cli.budget = kw.get("budget")  # what the fit keeps to again after its autoencoder
        raise _FitCalled

    monkeypatch.setattr(Sin3DM, "fit", staticmethod(fake_fit))
    _quick_here(monkeypatch, seconds)
    with pytest.raises(_FitCalled):
        main(["fit", "wall", "--out", str(tmp_path / "run"), *argv])
    return seen["preset"], seen["printed"]


def test_fit_without_a_preset_says_first_what_it_picked_why_and_how_long(monkeypatch, tmp_path, capsys):
    preset, printed = _fit_cli(monkeypatch, tmp_path, capsys)
    assert preset == "quick"
    first = printed.splitlines()[0]
    assert first.startswith("[fit] no preset named: 'quick' for this machine (test) and this shape (")
    assert first.endswith(
        "of it in thin parts: its 64-voxel grid holds it); name one to choose another (CLI --preset NAME)"
    )
    assert printed.splitlines()[1:2] == [
        "[fit] it should take about 3 min here (autoencoder 2.0 + denoiser 1.0 + grid and calibration 0.5 min, from "
        "5 steps of each timed just now)",
    ]
    preset, _ = _fit_cli(monkeypatch, tmp_path, capsys, "--set", "diffusion.steps=5")  # settings on the default
    assert preset.name == "quick" and preset.diffusion.steps == 5


def test_an_explicit_preset_always_wins_and_is_not_timed(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(fit_default, "estimate_fit", lambda *a, **k: pytest.fail("timed a preset the user named"))
    preset, printed = _fit_cli(monkeypatch, tmp_path, capsys, "--preset", "small")
    assert preset == "small" and "no preset named" not in printed


def test_the_estimates_share_for_grid_and_calibration_follows_where_the_fit_calibrates():
    """The 128-voxel calibration of the finer presets takes a larger share than the presets judged on their own grid;
    `paper` and `tiny` (no calibration) only build their grid."""
    names = ("tiny", "small", "quick", "detail", "fine", "paper")
    shares = {n: fit_default.other_share(get_preset(n)) for n in names}
    assert shares == {
        "tiny": fit_default.OTHER_SHARE_GRID,
        "small": fit_default.OTHER_SHARE,
        "quick": fit_default.OTHER_SHARE,
        "detail": fit_default.OTHER_SHARE_AT_128,
        "fine": fit_default.OTHER_SHARE_AT_128,
        "paper": fit_default.OTHER_SHARE_GRID,
    }
    assert fit_default.OTHER_SHARE_AT_128 > fit_default.OTHER_SHARE > fit_default.OTHER_SHARE_GRID


def test_a_time_budget_trains_both_networks_for_a_share_of_their_steps(monkeypatch, tmp_path, capsys):
    """`fit --minutes N`: the estimate (207 s: 120 + 60 of training, 27 of grid and calibration) is kept within N
    minutes by the same share of each network's steps; one that fits changes nothing."""
    preset, printed = _fit_cli(monkeypatch, tmp_path, capsys, "--minutes", "2.5")  # (150 - 27) / 180 = 68 %
    quick = get_preset("quick")
    assert preset.autoencoder.steps == 700 and preset.diffusion.steps == 700  # 68 % of 1,000, to 50 steps
    assert preset.grid == quick.grid and preset.sampling == quick.sampling
    assert printed.splitlines()[2] == (
        "[fit] to keep within 2.5 min: 700 autoencoder and 700 denoiser steps (68% of the preset's 1,000 and 1,000)"
    )
    preset, printed = _fit_cli(monkeypatch, tmp_path, capsys, "--minutes", "4")
    assert preset == "quick" and "[fit] within 4 min: the preset's steps as they are" in printed
    preset, _ = _fit_cli(monkeypatch, tmp_path, capsys, "--minutes", "2.5", "--set", "diffusion.steps=900")
    assert preset.autoencoder.steps == 700 and preset.diffusion.steps == 900  # what --set names wins
    preset, printed = _fit_cli(monkeypatch, tmp_path, capsys, "--preset", "small", "--minutes", "2.5")
    assert preset.name == "small" and preset.autoencoder.steps == 1350  # a named preset is timed for the budget
    assert "no preset named" not in printed


def test_the_default_keeps_to_about_eleven_minutes_on_a_slower_cpu(monkeypatch, tmp_path, capsys):
    """Where this machine's estimate for the default is longer than DEFAULT_MINUTES, both networks train for a
    share of their steps, never below DEFAULT_LEAST_SHARE (and then it says how long); a named preset, a budget or
    settings of one's own keep the preset's steps."""
    assert fit_default.DEFAULT_MINUTES == 11 and fit_default.DEFAULT_LEAST_SHARE == 0.8
    preset, printed = _fit_cli(monkeypatch, tmp_path, capsys, seconds=(400, 300, 60))  # (660 - 60) / 700 = 86 %
    assert preset.autoencoder.steps == 850 and preset.diffusion.steps == 850 and preset.grid == get_preset("quick").grid
    assert printed.splitlines()[1:3] == [
        "[fit] it should take about 13 min here (autoencoder 6.7 + denoiser 5.0 + grid and calibration 1.0 min, from "
        "5 steps of each timed just now)",
        "[fit] the default keeps to about 11 min on a CPU: 850 autoencoder and 850 denoiser steps (86% of the "
        "preset's 1,000 and 1,000); --preset quick trains all of them, --minutes N keeps to N",
    ]
    budget = _fit_cli.budget  # kept again after the autoencoder: the default's minutes and floor, the preset's steps
    assert (budget.minutes, budget.least, budget.steps) == (11, 0.8, (1000, 1000))
    assert budget.seconds == {"autoencoder": 400, "denoiser": 300, "other": 60, "total": 760}
    preset, printed = _fit_cli(monkeypatch, tmp_path, capsys, seconds=(1000, 800, 200))  # 26 % would do: 80 %
    assert preset.autoencoder.steps == 800 and "(80% of the preset's 1,000 and 1,000), about 27 min here" in printed
    for argv in (["--preset", "quick"], ["--set", "diffusion.steps=900"], ["--minutes", "30"]):
        preset, printed = _fit_cli(monkeypatch, tmp_path, capsys, *argv, seconds=(400, 300, 60))
        steps = preset.autoencoder.steps if not isinstance(preset, str) else get_preset(preset).autoencoder.steps
        assert steps == 1000 and "the default keeps" not in printed, argv
        assert (_fit_cli.budget is None) == (argv[0] != "--minutes"), argv  # a named preset or --set: no budget
    preset, printed = _fit_cli(monkeypatch, tmp_path, capsys, seconds=(400, 250, 20))  # 98 %: the same steps
    assert preset == "quick" and "the default keeps" not in printed
    paper = {"autoencoder": 9e3, "denoiser": 9e3, "other": 0, "total": 2e4}
    assert fit_default.default_budget(get_preset("paper"), paper) == ({}, None)  # a GPU's preset: the paper's steps


@pytest.mark.parametrize(
    "argv, says",
    [
        (
            ["--minutes", "1"],
            "'quick' cannot fit within 1 min here: at half of its training steps it needs about 2 min; give "
            "--minutes 2 or more",
        ),
        (["--minutes", "0"], "argument --minutes: expected a number above 0, got 0.0"),
        (["--minutes", "3", "--resume"], "--minutes is for a new fit"),
    ],
)
def test_a_budget_the_fit_cannot_keep_is_refused_in_one_line_before_it_starts(
    monkeypatch, tmp_path, capsys, argv, says
):
    from sin3dm_lite.pipeline import Sin3DM

    monkeypatch.setattr(Sin3DM, "fit", staticmethod(lambda *a, **k: pytest.fail("fitted")))
    _quick_here(monkeypatch)
    if "--resume" in argv:
        (tmp_path / "run").mkdir()
    try:
        code = main(["fit", "wall", "--out", str(tmp_path / "run"), *argv])
    except SystemExit as e:  # argparse's own errors
        code = e.code
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert says in err and len(err.splitlines()) == 1
    assert not (tmp_path / "run").exists() or "--resume" in argv


def test_a_missing_input_fails_before_the_timing(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(fit_default, "estimate_fit", lambda *a, **k: pytest.fail("timed before checking the input"))
    assert main(["fit", str(tmp_path / "gone.obj"), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "gone.obj" in err and len(err.strip().splitlines()) == 1 and not (tmp_path / "r").exists()


def test_the_python_fit_without_a_preset_takes_the_machines_and_says_so(monkeypatch, capsys):
    """`Sin3DM.fit(mesh)` without ``preset``: the same default, said first (after the input is read)."""
    from sin3dm_lite.app import fitting
    from sin3dm_lite.pipeline import Sin3DM

    seen = {}

    def prepare_run(run, preset, *args):
        seen["preset"] = preset
        raise _FitCalled

    said = fit_default.DefaultPreset("quick", "this machine (test)")
    monkeypatch.setattr(fitting, "default_preset", lambda device=None, mesh=None, timed=True, *frame: said)
    monkeypatch.setattr(fitting, "prepare_run", prepare_run)
    with pytest.raises(_FitCalled):
        Sin3DM.fit("wall", progress=True)
    assert seen["preset"] == "quick" and capsys.readouterr().out.startswith(said.lines()[0])
    with pytest.raises(_FitCalled):
        Sin3DM.fit("wall", preset="tiny", progress=True)
    assert seen["preset"] == "tiny" and "no preset named" not in capsys.readouterr().out


@pytest.mark.parametrize(
    "source, machine, chosen",
    [
        ("canyon", "small", "small"),  # terraces and strata: thick parts
        ("colonnade", "small", "detail"),  # columns
        ("ruin", "small", "detail"),  # a ruined tower: walls 2.5 voxels thick at 64
        ("ruin", "quick", "fine"),  # the same on a CPU without fast bf16
        ("ruin6", "small", "detail"),  # the same tower with walls 6 voxels thick: under 7 in every direction
        ("ruin8", "small", "small"),  # walls 8 voxels thick: 64 voxels hold them
        ("ruin", "paper", "paper"),  # a GPU's 256 voxels hold any of them: not measured
    ],
)
def test_a_shape_mostly_of_thin_parts_gets_the_finer_grid(source, machine, chosen):
    """The shape rule: more than half of the solid in parts under 7 voxels thick at 64 → the finer preset."""
    from sin3dm_lite.examples import build_example
    from sin3dm_lite.examples.ruin import build_ruin

    towers = {"ruin": lambda: build_ruin(0), "ruin6": lambda: build_ruin(3, wall_voxels=6)}
    mesh = {**towers, "ruin8": lambda: build_ruin(3, wall_voxels=8)}.get(source, lambda: build_example(source))()
    name, why, share = fit_default.for_shape(machine, mesh)
    assert name == chosen
    if machine == "paper":
        assert why == "" and share is None
    else:
        assert (share > fit_default.MOSTLY_THIN) == (chosen != machine) and f"{share:.0%}" in why


@pytest.mark.parametrize("walls, chosen, wrong", [(6, "detail", 1.0), (8, "small", 0.2), (8, "small", 1.0)])
def test_a_real_meshs_faults_do_not_move_the_shape_rule(walls, chosen, wrong):
    """A real mesh is rarely the clean, closed, textured one we generate: the rule reads the same tower as a
    triangle soup with no texture, faces shuffled and unwelded, a fifth (or all) of them wound the wrong way and
    the floor left open, and takes the same preset (the faces are wound as their neighbours, an open part inside
    out is turned round, and the winding number gives the inside of the open mesh)."""
    from sin3dm_lite.data.mesh import Material, TexturedMesh
    from sin3dm_lite.examples.ruin import build_ruin

    mesh = build_ruin(3, wall_voxels=walls)
    rng = np.random.default_rng(0)
    tri = mesh.vertices[mesh.faces]  # [F, 3, 3]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    floor = (tri[:, :, 1].mean(1) < mesh.vertices[:, 1].min() + 0.5) & (normal[:, 1] < 0)  # y is up
    tri = tri[~floor][rng.permutation(int((~floor).sum()))]
    flip = rng.random(len(tri)) < wrong
    tri = np.where(flip[:, None, None], tri[:, ::-1], tri)
    soup = TexturedMesh(
        tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3), np.zeros(len(tri), np.int64), [Material()]
    )
    assert floor.any() and len(soup.faces) < len(mesh.faces)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        faulty = fit_default.thin_share(soup, get_preset("small"))
    assert not caught  # the fit's own grid says what is wrong with the mesh, once
    assert abs(faulty - fit_default.thin_share(mesh, get_preset("small"))) < 0.1
    assert fit_default.for_shape("small", soup)[0] == chosen


def test_the_estimate_times_a_shape_of_one_colour_as_its_fit_trains_it(monkeypatch):
    """A mesh of one colour (a mesh without colour gets the default grey) trains its autoencoder on the geometry
    alone, about half a step's work; the estimate times that case on a grey timing grid, a coloured mesh on a
    coloured one."""
    import trimesh

    from sin3dm_lite.examples import build_example
    from sin3dm_lite.model import autoencoder

    from .conftest import textured

    grey, coloured = textured(trimesh.creation.box()), build_example("wall")
    assert fit_default.one_colour(grey) and not fit_default.one_colour(coloured) and not fit_default.one_colour(None)
    timed = []

    class Timed(Exception):
        pass

    def record(grid, *args, **kwargs):
        timed.append(grid.single_color() is not None)
        raise Timed

    monkeypatch.setattr(autoencoder, "AutoencoderTrainer", record)
    for mesh in (grey, coloured):
        with pytest.raises(Timed):
            fit_default.default_preset("cpu", mesh)
    assert timed == [True, False]


def test_a_flat_mesh_keeps_the_machines_preset_and_is_not_calibrated():
    """A flat mesh (a textured floor or field) is one slab: not a shape of thin parts that a finer grid keeps whole,
    and no calibration on patch scores, which every setting's slab keeps alike; a mesh with relief is as before."""
    from sin3dm_lite.auto.calibration import calibrates
    from sin3dm_lite.data.mesh import Material, TexturedMesh

    x, z = np.meshgrid(np.linspace(-1, 1, 12), np.linspace(-1, 1, 12))
    i = np.arange(144).reshape(12, 12)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    for height, flat in ((0.001, True), (0.3, False)):
        v = np.stack([x, height * np.sin(3 * x), z], -1).reshape(-1, 3)
        sheet = TexturedMesh(v, faces, np.zeros(len(faces), np.int64), [Material()], name="sheet")
        name, why, share = fit_default.for_shape("quick", sheet)
        assert (name == "quick" and "flat" in why and share is None) if flat else name == "fine"
        assert calibrates(get_preset("quick"), sheet) is not flat
    assert calibrates(get_preset("quick"))  # a mesh not known (a resumed run's grid): as the preset does


def test_the_estimate_times_a_grid_of_the_voxels_the_fit_will_train(monkeypatch):
    """The training grid keeps a margin of empty voxels around the shape, and a flat mesh's box is as thick as its
    slab: the estimate's timing grid has the fit's own voxel counts (the steps' cost follows them), for a box, a
    long thin part and a flat sheet."""
    import trimesh

    from sin3dm_lite.data.grid import mesh_to_grid
    from sin3dm_lite.model import autoencoder

    from .conftest import textured

    timed = []

    class Timed(Exception):
        pass

    def record(grid, *args, **kwargs):
        timed.append(grid.sdf.shape)
        raise Timed

    monkeypatch.setattr(autoencoder, "AutoencoderTrainer", record)
    cfg = get_preset("tiny")
    for extents in ((2.0, 1.0, 1.3), (0.2, 3.0, 0.25), (2.0, 0.001, 1.5)):
        mesh = textured(trimesh.creation.box(extents=extents))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            grid = mesh_to_grid(mesh, cfg.grid.resolution, n_surface_points=2000, margin_voxels=cfg.grid.margin_voxels)
        with pytest.raises(Timed):
            fit_default.estimate_fit(cfg, "cpu", fit_default.proportions(mesh))
        assert timed[-1] == grid.sdf.shape


def test_a_fit_behind_its_budget_after_the_autoencoder_trains_fewer_denoiser_steps(monkeypatch):
    """The budget is kept once more when the autoencoder is done: the rest is taken as much slower as that stage
    was than its estimate, and the denoiser loses steps to end in time, never below the budget's least share."""
    now = {"t": 0.0}
    monkeypatch.setattr(fit_default.time, "monotonic", lambda: now["t"])
    seconds = {"autoencoder": 200.0, "denoiser": 300.0, "other": 100.0, "total": 600.0}
    budget = fit_default.Budget(11, seconds, (1000, 1000), 0.8, start=0.0)
    now["t"] = 210.0  # on time: 200 s as estimated (and 10 s of grid)
    assert budget.denoiser_steps(1000, 200.0, 1000) == (1000, None)
    now["t"] = 290.0  # 1.4x slower: 290 + 420 + 140 = 850 s; 660 - 290 - 140 = 230 s leave 230 / 0.42 = 547 steps
    assert budget.denoiser_steps(1000, 280.0, 1000) == (
        800,
        "[fit] the autoencoder took 4.7 min, 1.4x its estimate: to keep within 11 min the denoiser trains 800 of "
        "its 1,000 steps, about 13 min in all (fewer steps would lose patches)",
    )
    loose = fit_default.Budget(11, seconds, (1000, 1000), 0.5, start=0.0)
    assert loose.denoiser_steps(1000, 280.0, 1000)[0] == 500  # 547, to 50 steps below
    assert loose.denoiser_steps(1000, 280.0, 400) == (400, None)  # never more than planned
    now["t"] = 250.0  # late by less than LATE_S: left as it is
    assert loose.denoiser_steps(1000, 205.0, 1000) == (1000, None)

    # a stage more (a second denoiser): the user's --minutes holds it out where it would end past them, the
    # default's budget does not
    cfg = get_preset("tiny")
    strict = fit_default.Budget.within(cfg, seconds, 11, start=0.0)
    default = fit_default.Budget.by_default(cfg.updated(name="quick"), seconds, start=0.0)
    assert strict.strict and default is not None and not default.strict
    now["t"] = 500.0
    assert strict.allows(160.0 + fit_default.LATE_S) and not strict.allows(200.0 + fit_default.LATE_S)
    assert default.allows(10_000.0)


def test_the_denoiser_steps_a_late_fit_keeps_are_recorded_for_a_resume(monkeypatch, tmp_path, capsys):
    """A real tiny fit whose autoencoder ran far past its (faked) estimate: the denoiser trains the least share of
    its steps, and config.json, input.json and the checkpoint all say so, so that a resume trains to the same end."""
    import json

    from sin3dm_lite.app.run_folder import check_config_matches_run, read_run_config

    est = {"autoencoder": 0.05, "denoiser": 5.0, "other": 0.0, "total": 5.05}
    monkeypatch.setattr(fit_default, "estimate_fit", lambda *a, **k: dict(est))
    run = tmp_path / "run"
    assert main(["fit", "wall", "--preset", "tiny", "--minutes", "0.1", "--out", str(run)]) in (0, None)
    printed = capsys.readouterr().out
    assert "[fit] within 0.1 min: the preset's steps as they are" in printed
    assert "its estimate: to keep within 0.1 min the denoiser trains 100 of its 150 steps" in printed
    cfg = read_run_config(run / "config.json")
    assert cfg.diffusion.steps == 100 and cfg.autoencoder.steps == 150
    assert json.loads((run / "input.json").read_text())["config"]["diffusion"]["steps"] == 100
    assert json.loads((run / "report.json").read_text())["diffusion_steps"] == 100
    check_config_matches_run(run, cfg)  # what a resume checks first
    fit = {}
    monkeypatch.setattr("sin3dm_lite.pipeline.Sin3DM.fit", staticmethod(lambda *a, **k: fit.update(k) or _stop()))
    with pytest.raises(_FitCalled):
        main(["fit", "wall", "--preset", "tiny", "--minutes", "0.1", "--out", str(tmp_path / "b")])
    assert fit["budget"].minutes == 0.1
    with pytest.raises(_FitCalled):  # the denoiser's steps as --set names them: not cut again
        main(
            [
                "fit",
                "wall",
                "--preset",
                "tiny",
                "--minutes",
                "0.1",
                "--set",
                "diffusion.steps=120",
                "--out",
                str(tmp_path / "c"),
            ]
        )
    assert fit["budget"] is None


def _stop():
    raise _FitCalled


@pytest.mark.parametrize("degrees", [30.0, -44.0, 10.0])
def test_walls_across_the_axes_are_measured_and_a_round_shape_is_not_turned(degrees):
    """``wall_directions`` finds the turn that lines a box's walls up with x and z (the same for a box turned by a
    right angle more) and how well they agree; a cylinder's walls agree on nothing, so ``choose_turn`` leaves it, a
    turned box it turns (and says so), and a turn asked for wins."""
    import trimesh

    from sin3dm_lite.auto.fit_policy import WALLS_AGREE, as_fitted, choose_turn, wall_directions

    from .conftest import textured

    box = textured(trimesh.creation.box(extents=(1.0, 0.6, 0.4)))
    said = []
    for extra in (0.0, 90.0):
        turned = box.turned_about_y(degrees + extra)
        found, agree = wall_directions(turned)
        assert found == pytest.approx(-degrees, abs=1e-6) and agree > 0.99
        assert choose_turn(turned, None, get_preset("quick"), said.append) == pytest.approx(-degrees, abs=0.01)
        # the time estimate measures the box the fit grids: the turned one's, not the box around it as it lies
        fitted = sorted(fit_default.proportions(as_fitted(turned)))  # along x and z, or z and x
        assert fitted == pytest.approx(sorted(fit_default.proportions(box)), abs=1e-3)
    assert len(said) == 2 and "off the x and z axes" in said[0]
    cylinder = textured(trimesh.creation.cylinder(radius=0.4, height=1.0, sections=64)).turned_upright("z")
    assert wall_directions(cylinder)[1] < 0.1 < WALLS_AGREE
    assert choose_turn(cylinder, None, get_preset("quick"), said.append) == 0.0
    assert choose_turn(box.turned_about_y(degrees), 0, get_preset("quick"), said.append) == 0.0 and len(said) == 2

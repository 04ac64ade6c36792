"""``sin3dm-lite examples``, ``grid`` and ``fit``: from a mesh (or a built-in example) to a fitted run."""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from shlex import quote

from ..errors import Sin3DMInputError


def cmd_examples(a) -> None:
    from .. import examples

    if a.write:
        from ..files import check_writable, clash_error, foreign_files, make_temp_dir, merge_output, remove_stale_temps

        if a.write not in examples.list_examples():
            raise Sin3DMInputError(f"unknown example '{a.write}'; choose one of: {', '.join(examples.list_examples())}")
        out = Path(a.out)
        if out.exists() and not out.is_dir():
            raise Sin3DMInputError(f"--out '{out}' is a file; give a folder to write the example into")
        names = [f"{a.write}{ext}" for ext in (".obj", ".mtl", ".png")]
        there = [n for n in names if (out / n).exists()]
        if there and not a.overwrite:
            raise Sin3DMInputError(
                f"'{out / there[0]}' exists; pass --overwrite to replace it if sin3dm-lite wrote it, "
                "or choose another --out"
            )
        clash = foreign_files(out, names, by="examples") if out.is_dir() else []
        if clash:
            raise clash_error(out, clash[0], by="examples")
        check_writable(out)
        out.mkdir(parents=True, exist_ok=True)
        remove_stale_temps(out)
        tmp = make_temp_dir(out)
        try:
            path = examples.write_example(a.write, tmp, seed=a.seed)
            merge_output(tmp, out, by="examples")
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        path = out / path.name
        print(f"wrote {path} (+ .mtl and .png): open it in Blender with File › Import › Wavefront (.obj)")
        return
    for name in examples.list_examples():
        marker = " (default)" if name == examples.DEFAULT_EXAMPLE else ""
        print(f"{name:10s} {examples.EXAMPLES[name]}{marker}")


def cmd_grid(a) -> None:
    from ..data.grid import check_resolution, mesh_to_grid, save_grid
    from ..data.source import resolve_mesh
    from ..files import check_not_overlapping, check_writable, clash_error, is_ours, recorded_path, remove_stale_temps

    out = Path(a.out)
    if out.suffix != ".npz":
        raise Sin3DMInputError(f"--out must be a .npz file, got '{out}'")
    check_resolution(a.resolution)
    if Path(a.mesh).exists():
        check_not_overlapping(out, {"input mesh": Path(a.mesh)})
    if out.is_dir():
        raise Sin3DMInputError(f"--out '{out}' is a folder; give a file name like {out / 'grid.npz'}")
    if out.exists() and not a.overwrite:
        raise Sin3DMInputError(
            f"'{out}' exists; pass --overwrite to replace it (only if sin3dm-lite wrote it) or choose another --out"
        )
    if out.name == "grid.npz" and (out.parent / "config.json").is_file():  # a fit's own grid, not a foreign file
        raise Sin3DMInputError(
            f"'{out}' is the grid of the fit in '{out.parent}' (written by `sin3dm-lite fit`, which trains on it and "
            "resumes from it); `grid` does not replace it: choose another --out"
        )
    if out.exists() and not is_ours(out.parent, out.name, by="grid"):
        raise clash_error(out.parent, out.name, by="grid")
    check_writable(out)
    mesh = resolve_mesh(a.mesh, allow_outside_paths=a.allow_outside_paths)
    grid = mesh_to_grid(mesh.turned_upright(a.up or "y"), a.resolution)
    remove_stale_temps(out.parent)
    with recorded_path(out, by="grid") as tmp:
        save_grid(grid, tmp)
    print(f"wrote {out}: sdf {grid.shape}, color {grid.color.shape}, box {[round(float(x), 3) for x in grid.aabb]}")


def cmd_fit(a) -> None:
    from ..auto.fit_default import Budget, default_budget, default_preset
    from ..data.config import parse_settings
    from ..pipeline import Sin3DM
    from ..presets import get_preset

    if a.resume and not Path(a.out).is_dir():
        raise Sin3DMInputError(f"cannot resume: run folder '{a.out}' not found; start a new fit without --resume")
    started = time.monotonic()  # the fit's clock: its time budget and the total said at the end
    changes = parse_settings(a.set)
    if a.minutes is not None and a.resume:
        raise Sin3DMInputError("--minutes is for a new fit: a resumed fit keeps its run's steps; leave out --minutes")
    needs_mesh = not a.resume and (a.preset is None or a.minutes is not None)  # the default or a budget: read once
    mesh = input_mesh(a) if needs_mesh else None
    chosen = None
    if not (a.preset or a.resume):  # the default for this machine and shape, said first: which, why, how long
        chosen = default_preset(a.device, mesh, up=a.up, turn=a.turn)
        print("\n".join(chosen.lines()), flush=True)
    name = a.preset or (chosen.name if chosen else None)  # None: the run's own (Sin3DM.fit)
    budget = None  # kept again once the autoencoder has trained
    if a.minutes is not None:
        budgeted, budget = time_budget(a, mesh, name, chosen, changes, started)
        budget = None if "diffusion.steps" in changes else budget  # the denoiser's steps as --set names them
        changes = {**budgeted, **changes}  # what --set names explicitly wins
    elif chosen is not None and not changes:  # the default keeps to its own budget
        changes, line = default_budget(get_preset(chosen.name), chosen.seconds)
        if line:
            print(line, flush=True)
        budget = Budget.by_default(get_preset(chosen.name), chosen.seconds, started)
    base = get_preset(name or "small")
    preset = base.updated(**changes) if changes else name
    model = Sin3DM.fit(
        a.mesh,
        preset=preset,
        out=a.out,
        resume=a.resume,
        seed=a.seed,
        device=a.device,
        pbr=a.pbr,
        allow_outside_paths=a.allow_outside_paths,
        calibrate=a.calibrate,
        budget=budget,
        up=a.up,
        turn=a.turn,
    )
    r = model.report["reconstruction"]
    at = r.get("color_psnr_surface")  # a resumed old run may not have it
    surface = f" ({at:.1f} at the surface)" if at is not None else ""
    colour = "one colour, kept" if "single_color" in model.report else f"colour PSNR {r['color_psnr']:.1f} dB{surface}"
    ae_precision = model.report.get("precision", {}).get("autoencoder")  # a resumed old run may not say
    samples = Path(a.out).with_name(Path(a.out).name + "-samples")
    print(
        f"fit done in {time.monotonic() - started:.0f} s{f' (autoencoder in {ae_precision})' if ae_precision else ''}: "
        f"occupancy IoU {r['occupancy_iou']:.3f}, "
        f"sign accuracy {r['sign_accuracy']:.3f}, {colour}; samples default to diversity "
        f"{model.config.sampling.diversity:g}{' (calibrated for this shape)' if 'calibration' in model.report else ''}"
        "\n"
        f"next: sin3dm-lite sample {quote(a.out)} -n 4 --out {quote(str(samples))}"
    )


def input_mesh(a):
    """The input mesh, read for the default's choice and the time budget: a bad input or ``--out`` fails here,
    before any timing."""
    from ..app.run_folder import check_run_folder
    from ..data.source import resolve_mesh

    check_run_folder(Path(a.out), a.mesh, False)
    return resolve_mesh(a.mesh, allow_outside_paths=a.allow_outside_paths)


def time_budget(a, mesh, name: str, chosen, changes: dict, started: float):
    """``--minutes``: fewer training steps where the fit's estimate is longer (:func:`fit_default.within_minutes`),
    said before the fit starts, and the :class:`~fit_default.Budget` that the fit keeps to again after its
    autoencoder. The default's estimate is used as it is; a named preset or ``--set`` is timed here."""
    from ..auto.fit_default import Budget, estimate_fit, one_colour, proportions, within_minutes
    from ..auto.fit_policy import as_fitted
    from ..presets import get_preset

    cfg = get_preset(name).updated(**changes) if changes else get_preset(name)
    seconds = chosen.seconds if chosen is not None and not changes else None
    seconds = seconds or estimate_fit(cfg, a.device, proportions(as_fitted(mesh, a.up, a.turn)), one_colour(mesh))
    budget, line = within_minutes(cfg, seconds, a.minutes)
    print(line, flush=True)
    return budget, Budget.within(cfg, seconds, a.minutes, started)

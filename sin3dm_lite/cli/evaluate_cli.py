"""``sin3dm-lite render``, ``evaluate`` and ``calibrate``: pictures of a mesh, the paper's metrics of
samples, and the diversity a run keeps its input's patches at."""

from __future__ import annotations

import shlex
import shutil
import time
from pathlib import Path

from ..errors import Sin3DMInputError
from .sample_cli import find_run


def cmd_render(a) -> None:
    from ..data.source import resolve_mesh
    from ..evaluate.evaluation import check_views
    from ..evaluate.render import contact_sheet, render_hero, render_views, view_names
    from ..files import (
        check_not_overlapping,
        check_output_folder,
        check_writable,
        install_output,
        make_temp_dir,
        remove_stale_temps,
    )
    from ..formats.images import png_bytes

    out = Path(a.out)
    check_views(a.views, a.size, ("--views", "--size"))
    if not -89 <= a.elevation <= 89:
        raise Sin3DMInputError(f"--elevation must be from -89 to 89 degrees, got {a.elevation}")
    names = view_names(a.views) + ["contact_sheet.png"]
    if Path(a.mesh).exists():
        check_not_overlapping(out, {"input mesh": Path(a.mesh)})
    check_output_folder(out, a.overwrite, names, by="render")
    check_writable(out)
    mesh = resolve_mesh(a.mesh, allow_outside_paths=a.allow_outside_paths)
    t0 = time.perf_counter()
    views = render_views(mesh, n_views=a.views, size=a.size, elevation=a.elevation)
    hero = render_hero(mesh, size=a.size)
    sheet = contact_sheet(
        views + [hero], [f"azimuth {360 * k / a.views:g}" for k in range(a.views)] + ["hero"], crop=True
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(out.parent)
    tmp = make_temp_dir(out.parent)
    try:
        for name, img in zip(names, views + [hero, sheet]):
            (tmp / name).write_bytes(png_bytes(img))
        install_output(tmp, out, by="render")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"wrote {a.views} views + hero.png + contact_sheet.png to {out} ({time.perf_counter() - t0:.1f} s)")


MESH_NAMES = ("mesh.obj", "mesh.glb")  # what `sample` writes into each NNN/ folder, in order of preference


def sample_mesh_files(folder: Path) -> list[Path]:
    """The mesh of each ``NNN/`` sample folder in ``folder`` (``mesh.obj``, else ``mesh.glb``), in order."""
    if not folder.is_dir():
        what = "is a file" if folder.exists() else "not found"
        raise Sin3DMInputError(f"samples folder '{folder}' {what}; give the --out folder of `sin3dm-lite sample`")
    files = []
    for d in sorted((d for d in folder.iterdir() if d.is_dir() and d.name.isdigit()), key=lambda d: int(d.name)):
        found = next((d / n for n in MESH_NAMES if (d / n).is_file()), None)
        if found is not None:
            files.append(found)
    if not files:
        raise Sin3DMInputError(
            f"no sample meshes in '{folder}' (expected NNN/mesh.obj or NNN/mesh.glb, as "
            "`sin3dm-lite sample` writes); sample first, then evaluate that folder"
        )
    return files


def print_evaluation(result: dict) -> None:
    """The metrics as a table: our name, the value, the paper's name and which way is better; then what was skipped."""
    from ..evaluate.evaluation import voxels_said
    from ..evaluate.metrics import results_table

    others = result.get("geometry_at", {})
    voxels = ", ".join(map(str, [result["resolution"], *(g["voxels"] for g in others.values())]))
    how = voxels_said(result.get("supersample", 1))
    print(f"{result['samples']} samples, {voxels} voxels ({how}), {result['views']} views of {result['size']}²")
    columns = {f"{result['resolution']} voxels" if others else "value": result}
    columns.update({f"{g['voxels']} voxels": g for g in others.values()})  # the geometry alone: the rest '-'
    print(results_table(columns, digits=4))
    for key, why in result["skipped"].items():
        print(f"  {key}: {why}")


def cmd_evaluate(a) -> None:
    import json

    from ..data.source import resolve_mesh
    from ..evaluate.evaluation import check_fine_grid, check_resolutions, check_views
    from ..evaluate.metrics import load_feature_weights
    from ..files import check_not_overlapping, check_writable, clash_error, is_ours, write_recorded
    from ..formats.load import load_any
    from ..pipeline import Sin3DM

    check_views(a.views, a.size, ("--views", "--size"))
    if a.resolution:
        check_resolutions(a.resolution, "--resolution")
    supersample = _supersample(a.voxels)
    check_fine_grid(a.resolution or [128], supersample)
    run = find_run(a.run)
    files = sample_mesh_files(Path(a.samples))
    out = Path(a.out) if a.out else None
    if out is not None:
        if out.suffix != ".json":
            raise Sin3DMInputError(f"--out must be a .json file, got '{out}'")
        check_not_overlapping(out, {"run folder": run})
        if out.is_dir():
            raise Sin3DMInputError(f"--out '{out}' is a folder; give a file name like {out / 'evaluation.json'}")
        if out.exists() and not a.overwrite:
            raise Sin3DMInputError(
                f"'{out}' exists; pass --overwrite to replace it (only if sin3dm-lite wrote it) or choose another --out"
            )
        if out.exists() and not is_ours(out.parent, out.name, by="evaluate"):
            raise clash_error(out.parent, out.name, by="evaluate")
        check_writable(out)
    nets = load_feature_weights(a.weights) if a.weights else None  # a missing file fails before the long work
    model = Sin3DM.load(run)
    allow = a.allow_outside_paths
    reference = model.input_mesh(allow) if a.input is None else resolve_mesh(a.input, allow_outside_paths=allow)
    meshes = []
    for f in files:
        try:
            meshes.append(load_any(f))
        except Sin3DMInputError as e:
            raise Sin3DMInputError(f"cannot read sample mesh '{f}': {e}") from None
    t0 = time.perf_counter()
    grids = a.resolution or [128, model.grid_resolution]  # the paper's, and the fit's own grid beside it
    result = model.evaluate(
        meshes, reference, resolution=grids, views=a.views, size=a.size, weights=nets, supersample=supersample
    )
    result.update(run=str(run), samples_folder=str(a.samples), files=[str(f) for f in files])
    print_evaluation(result)
    if out is not None:
        write_recorded(out, json.dumps(result, indent=2), by="evaluate")
        print(f"wrote {out} ({time.perf_counter() - t0:.1f} s)")


def cmd_calibrate(a) -> None:
    from ..app.pretrained import is_shipped
    from ..files import acquire_lock, check_writable, refuse_links, release_lock

    run = find_run(a.run)
    shipped = is_shipped(run)  # part of the installed package: print only
    if not shipped:  # calibrate replaces files there: never through a link, never beside a fit --resume
        check_writable(run, option="run folder")
        refuse_links(run, option="run folder")
        acquire_lock(run, "run folder", option=None)
    try:
        _calibrate(a, run, shipped)
    finally:
        if not shipped:
            release_lock(run)


def _supersample(voxels: str) -> int:
    """``--voxels``' sub-voxels a side: the paper's 2, the centres' 1."""
    from ..evaluate.geometry import PAPER_SUPERSAMPLE

    return {"paper": PAPER_SUPERSAMPLE, "centres": 1}[voxels]


def run_report(run: Path) -> dict | None:
    """The run's ``report.json`` (None without one), read and checked before a command changes the run: a damaged
    one refuses here, before the long work."""
    from ..files.inputs import json_or_why

    path = run / "report.json"
    if not path.exists() and not path.is_symlink():
        return None
    report, why = json_or_why(path, "a run's report")  # a FIFO or a device is refused, not read
    if why is None and not isinstance(report, dict):
        why = f"it holds a JSON {type(report).__name__}, not a record"
    if why is not None:
        raise Sin3DMInputError(
            f"'{path}' is damaged ({why}); nothing in '{run}' was changed: restore that file from a copy, or "
            "delete it (a record only: the run samples without it) and calibrate again"
        )
    return report


def _calibrate(a, run: Path, shipped: bool) -> None:
    import json

    from ..app.checkpoints import write_model
    from ..auto.calibration import default_goals, judged_at
    from ..data.grid import load_grid
    from ..data.source import resolve_mesh
    from ..evaluate.evaluation import voxels_said
    from ..pipeline import Sin3DM

    report = None if shipped else run_report(run)  # everything read and checked before the work
    model = Sin3DM.load(run)
    # by default where the fit judged; on the training grid (the input voxelised by the voxel centres' signs) no mesh
    # file is needed, elsewhere the input mesh is voxelised there
    resolution = a.resolution or judged_at(model.config)
    on_grid = resolution in (None, model.grid_resolution) and a.input is None and (run / "grid.npz").is_file()
    on_grid = on_grid and a.voxels != "paper"  # the training grid holds the voxel centres' signs
    reference = load_grid(run / "grid.npz").sdf < 0 if on_grid else None
    default = default_goals(resolution or model.grid_resolution)
    goals = {
        "lp_iou": default["lp_iou"] if a.lp_iou is None else a.lp_iou,
        "lp_fscore": default["lp_fscore"] if a.lp_f is None else a.lp_f,
    }
    before = model.config.sampling.diversity
    t0 = time.perf_counter()
    input_mesh = None
    if reference is None:  # the input mesh is read here, with --allow-outside-paths if given
        allow = a.allow_outside_paths
        input_mesh = model.input_mesh(allow) if a.input is None else resolve_mesh(a.input, allow_outside_paths=allow)
    supersample = _supersample(a.voxels) if a.voxels else None  # calibrate_model's: on the grid the centres
    cal = model.calibrate(
        reference,
        input_mesh=input_mesh,
        resolution=None if on_grid else resolution or model.grid_resolution,
        supersample=None if on_grid else supersample,
        goals=goals,
        n=a.n,
        seed=a.seed,
    )
    took = time.perf_counter() - t0
    if shipped:
        print(
            f"{a.run}: diversity {cal.diversity:g} "
            f"{'would keep the goals' if cal.kept_goals else f'is the fallback ({cal.missed})'} "
            f"({took:.0f} s); a shipped model is not "
            f"changed: sample it with --diversity {cal.diversity:g}"
        )
        return
    also = {} if report is None else {"report.json": json.dumps({**report, "calibration": cal.to_dict()}, indent=2)}
    write_model(model, run, also)  # model.pt, config.json and report.json: all or none
    print(
        f"{run}: diversity {before:g} → {cal.diversity:g}, judged at "
        f"{cal.resolution} voxels ({voxels_said(cal.supersample)}, {took:.0f} s), "
        f"saved in its config.json; `sin3dm-lite sample {shlex.quote(str(run))}` uses it, --diversity overrides it"
    )

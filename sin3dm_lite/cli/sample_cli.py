"""``sin3dm-lite sample`` and ``sin3dm-lite demo``: many samples into a folder (:mod:`sin3dm_lite.app.mass`),
their flags turned into a :class:`request.SampleRequest` (:func:`sample_request`)."""

from __future__ import annotations

import shlex
from pathlib import Path

from ..errors import Sin3DMInputError

DEMO_PRESET = "small"
#: the flags a :class:`request.SampleRequest` takes as they are
REQUEST_FLAGS = "n start seed steps diversity faces mesh_resolution texture_size no_pictures overwrite batch workers"


def check_sample_output(out: Path, a, protected: dict) -> None:
    """Everything about ``--out``, ``-n`` and ``--start`` that can fail, checked before any work or writing (a
    folder of our samples passes: its settings are compared once the model is loaded)."""
    from ..app.mass_folder import MAX_RUN_SAMPLES, WRITER, read_settings, sample_output_names
    from ..files import check_not_overlapping, check_output_folder, check_writable

    if a.start + a.n > MAX_RUN_SAMPLES:
        raise Sin3DMInputError(
            f"-n {a.n} (from --start {a.start}) is too many samples: indices go up to at most "
            f"{MAX_RUN_SAMPLES - 1} per output folder; use several --out folders with other --seed"
        )
    check_not_overlapping(out, protected)
    if not (out.is_dir() and read_settings(out) is not None and not a.overwrite):
        check_output_folder(out, a.overwrite, sample_output_names(out, sample_request(a)), by=WRITER)
    check_writable(out)


def sample_request(a):
    """The sampling flags of ``sample`` / ``demo`` as a :class:`request.SampleRequest` (the library takes no argparse)."""
    from ..app.request import SampleRequest

    defaults = SampleRequest()
    method = "ddpm" if getattr(a, "ddpm", False) else None  # --ddpm; else the model's
    flags = {k: getattr(a, k, getattr(defaults, k)) for k in REQUEST_FLAGS.split()}
    return SampleRequest(**flags, method=method, control=control_args(a))


def control_args(a) -> dict:
    """The ``Sin3DM.plan`` arguments of the controlled-generation flags."""
    if a.outpaint:
        return {"outpaint": tuple(a.outpaint), "anchor": a.anchor or "center"}
    if getattr(a, "anchor", None) is not None:
        raise Sin3DMInputError(
            f"--anchor {a.anchor} says where the input stays when outpainting, and needs --outpaint SX SY SZ; "
            "add --outpaint, or leave --anchor out"
        )
    if a.regenerate:
        return {"regenerate": (tuple(a.regenerate[:3]), tuple(a.regenerate[3:]))}
    if a.duplicate:
        return {"duplicate": ((tuple(a.duplicate[:3]), tuple(a.duplicate[3:6])), tuple(a.duplicate[6:]))}
    return {"resize": tuple(a.resize) if a.resize else (1.0, 1.0, 1.0)}


def find_run(name: str) -> Path:
    """A run folder, or the shipped model called ``name`` (:func:`runs.shipped_or_folder`); one-line error if
    neither."""
    from ..app.pretrained import shipped_names
    from ..app.runs import shipped_or_folder

    found = shipped_or_folder(name)
    if found is not None:
        return found[1]
    run = Path(name)
    if run.exists() and not run.is_dir():
        raise Sin3DMInputError(
            f"'{name}' is a file, not a run folder: a run folder is what `sin3dm-lite fit MESH --out "
            f"DIR` writes (config.json, model.pt, report.json, ...); give that folder, or a shipped "
            f"model's name ({', '.join(shipped_names())})"
        )
    if not run.is_dir():
        raise Sin3DMInputError(
            f"run folder '{name}' not found; fit one first with `sin3dm-lite fit MESH --out "
            f"{shlex.quote(name)}`, or name a shipped model ({', '.join(shipped_names())})"
        )
    from ..app.pretrained import shipped_model

    shipped = shipped_model(run.name)
    other = f", or write {run.name} for the shipped model {shipped.name}" if shipped is not None else ""
    raise Sin3DMInputError(
        f"'{name}' is a folder without model.pt, not a finished run folder: finish its fit with "
        f"`sin3dm-lite fit MESH --out {shlex.quote(name)} --resume`{other}"
    )


def cmd_sample(a) -> None:
    from ..app.device import get_device
    from ..app.mass import write_samples
    from ..app.mass_workers import start_ranks, stop_ranks
    from ..pipeline import Sin3DM

    run = find_run(a.run)
    get_device(a.device)
    protected = {"run folder": run, **fitted_mesh(run)}
    check_sample_output(Path(a.out), a, protected)  # every rank, before any rank writes
    ranks, device = start_ranks(a.device)
    try:
        model = Sin3DM.load(run, device=device)
        r = write_samples(model, Path(a.out), sample_request(a), ranks=ranks, run=str(run))
    finally:
        stop_ranks(ranks)
    if ranks.rank == 0:
        rate = 60 * r["new"] / r["seconds"] if r["seconds"] > 0 and r["new"] else 0.0
        where = f" on {ranks.world} processes" if ranks.world > 1 else ""
        print(
            f"wrote {r['pending']} new samples{where} ({rate:.1f} meshes/min on rank 0); {a.out} holds {r['total']}: "
            f"NNN/mesh.obj|.glb, samples.jsonl; open {Path(a.out) / 'index.html'} in a browser"
        )


def fitted_mesh(run: Path) -> dict:
    """``{"run's input mesh": path}`` of the mesh file the run was fitted to, while it is there (``--out`` may not
    hold it), else ``{}``."""
    from ..app.run_folder import read_report

    path = read_report(run).get("input_path")
    return {"run's input mesh": Path(path)} if isinstance(path, str) and Path(path).is_file() else {}


def cmd_demo(a) -> None:
    from .. import examples
    from ..app.device import get_device
    from ..app.mass import write_samples
    from ..app.pretrained import shipped_model
    from ..pipeline import Sin3DM

    if a.example not in examples.list_examples():
        raise Sin3DMInputError(f"unknown example '{a.example}'; choose one of: {', '.join(examples.list_examples())}")
    shipped = None if a.train else shipped_model(a.example)
    if not a.train and shipped is None:
        have = [n for n in examples.list_examples() if shipped_model(n) is not None]
        raise Sin3DMInputError(
            f"no shipped model of '{a.example}' (shipped: {', '.join(have) or 'none'}); add "
            f"--train to fit it first with the '{DEMO_PRESET}' preset, or pick --example "
            f"{examples.DEFAULT_EXAMPLE}"
        )
    out = Path(a.out)
    get_device(a.device)
    check_sample_output(out, a, {} if a.train else {"shipped model folder": shipped})
    if a.train:
        model = Sin3DM.fit(a.example, preset=DEMO_PRESET, out=None, device=a.device)
    else:
        model = Sin3DM.load(shipped, device=a.device)
        print(f"[demo] loaded the shipped '{DEMO_PRESET}' model of the '{a.example}' example")
    write_samples(model, out, sample_request(a), label="demo", run=str(shipped or "trained by demo"))
    print(
        f"[demo] done: {a.n} new shapes in {out}/NNN/ (mesh.obj + mesh.mtl + mesh.png, mesh.glb)\n"
        f"[demo] look at them: open {out / 'index.html'} in a browser, or import mesh.obj in Blender"
    )

"""The ``sin3dm-lite`` command.

    sin3dm-lite examples [--write NAME --out DIR]      list / write the built-in example shapes
    sin3dm-lite grid MESH --resolution N --out FILE.npz mesh → TSDF + colour grid
    sin3dm-lite fit MESH_OR_EXAMPLE --preset small --out RUN_DIR [--resume]
    sin3dm-lite sample RUN_DIR -n 4 --out DIR [--resize SX SY SZ] [--diversity D]
    torchrun --nproc_per_node=N -m sin3dm_lite.cli sample RUN_DIR -n 1000 --out DIR   sharded (see mass.py)
    sin3dm-lite demo [--example NAME] [--out DIR] [--train]   the whole method on a built-in example
    sin3dm-lite render MESH --views 8 --size 512 --out DIR   PNG views (no display or GPU needed)
    sin3dm-lite evaluate RUN SAMPLES_DIR [--out report.json] [--weights DIR]   the paper's metrics
    sin3dm-lite calibrate RUN_DIR [-n 8]                choose the run's diversity for its shape (fit does it too)
    sin3dm-lite --version                               the installed version

With no arguments it prints the help; every option's help shows its default.

Every user error prints one line naming the problem and the fix, and exits
with code 2 (no traceback).

No command deletes or overwrites a file it did not write: an output folder
that is not empty is refused unless ``--overwrite`` is given, and then only
the files its manifest (``.sin3dm-manifest.json``, written by this tool) lists
as written there by the same command are replaced (``render --overwrite`` into a
folder of samples keeps the samples). Outputs are checked (writable, not overlapping the run
folder or the input) before the long work starts; results are written into a
temporary folder beside the target (``.sin3dm-tmp-<pid>-*``, removed by the
next run if the process was killed) and moved into place at the end.
``sample`` and ``demo`` move each sample folder into place as it finishes and
continue a folder of samples with the same settings (:mod:`sin3dm_lite.mass`).
"""
from __future__ import annotations

import argparse
import shutil
import sys
import time
import warnings
from pathlib import Path

from .errors import Sin3DMInputError

DEMO_PRESET = "small"


def _int_at_least(low: int, what: str):
    """An argparse type: a whole number ≥ ``low``; ``what`` names the range in the error."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
        if v < low:
            raise argparse.ArgumentTypeError(f"expected {what}, got {v}")
        return v

    return parse


_positive_int = _int_at_least(1, "a positive number")
_whole = _int_at_least(0, "0 or more")


def _factor(what: str, low: float, low_included: bool):
    """An argparse type: a size factor up to 8 above ``low``; ``what`` names the flag in the error."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
        if not ((low <= v if low_included else low < v) and v <= 8):
            raise argparse.ArgumentTypeError(f"{what}, got {v:g}")
        return v

    return parse


_resize_factor = _factor("resize factors must be in (0, 8]", 0.0, False)
_outpaint_factor = _factor("outpaint factors must be from 1 to 8 (outpainting grows the box; --resize shrinks it)",
                           1.0, True)


def _unit_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number from 0 to 1, got '{text}'") from None
    if not (0 <= v <= 1):
        raise argparse.ArgumentTypeError(f"diversity must be from 0 (the input) to 1 (pure noise), got {v}")
    return v


class _Formatter(argparse.HelpFormatter):
    """Every option's help ends with its default, unless it already names one or has none worth saying.

    Like ``argparse.ArgumentDefaultsHelpFormatter``, but an option whose help
    already says "default" is left alone, and flags (``store_true``), required
    options and options whose default is None get nothing appended: their help
    says in words what happens without them ("default: the preset's").
    """

    def _get_help_string(self, action):
        text = action.help or ""
        if ("default" in text or not action.option_strings or action.required
                or any(action.default is x for x in (None, False, argparse.SUPPRESS))):  # `is`: 0 == False
            return text
        return f"{text} (default: %(default)s)"


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line (no usage block), exit code 2; help with defaults (:class:`_Formatter`)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def package_version() -> str:
    """The installed package's version (its metadata), else the source tree's ``__version__``."""
    from importlib import metadata

    try:
        return metadata.version("sin3dm-lite")
    except metadata.PackageNotFoundError:
        import sin3dm_lite

        return getattr(sin3dm_lite, "__version__", "unknown")


#: each command's one-line description: its line in ``sin3dm-lite --help`` and the top of ``sin3dm-lite CMD --help``
COMMANDS = {
    "examples": "list the built-in example shapes, or write one as OBJ/MTL/PNG",
    "grid": "turn a mesh into the truncated SDF + colour grid (.npz)",
    "fit": "fit the autoencoder and the diffusion model to one mesh",
    "sample": "generate textured meshes from a fitted run folder",
    "demo": "the whole method on a built-in example: load its shipped model (or --train), sample, export",
    "render": "PNG pictures of a mesh: the paper's views around it, a hero view, a contact sheet",
    "evaluate": "the paper's geometry and texture metrics of sample meshes against the input",
    "calibrate": "choose a run's diversity: the most varied setting whose samples keep the input's patches",
    "notebooks": "run the notebooks top to bottom at reading settings and keep their outputs (for the course's authors)",
}


def build_parser() -> argparse.ArgumentParser:
    from .data import examples
    from .data.config import PRESETS
    from .data.mesh_io import READABLE

    p = _Parser(prog="sin3dm-lite", description="Sin3DM: learn a diffusion model from one textured mesh.",
                epilog=f"Readable mesh formats: {READABLE}. Start with `sin3dm-lite demo`; "
                       "`sin3dm-lite CMD --help` describes one command.")
    p.add_argument("--version", action="version", version=f"sin3dm-lite {package_version()}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=COMMANDS[name], description=COMMANDS[name])

    mesh_help = f"mesh file ({READABLE}) or built-in example name"

    e = command("examples")
    e.add_argument("--write", metavar="NAME", help="example to write (default: list them)")
    e.add_argument("--out", default=".", help="folder for --write (default: current folder)")
    e.add_argument("--seed", type=_seed, default=0, help="variant of the example")
    e.add_argument("--overwrite", action="store_true", help="replace files of the example that sin3dm-lite wrote before")

    g = command("grid")
    g.add_argument("mesh", help=mesh_help)
    g.add_argument("--resolution", type=int, default=128, help="voxels along the longest side, 16-512")
    g.add_argument("--out", required=True, help="output .npz file")
    g.add_argument("--overwrite", action="store_true", help="replace an existing grid file that sin3dm-lite wrote")
    _outside_paths_arg(g)

    f = command("fit")
    f.add_argument("mesh", help=mesh_help)
    f.add_argument("--preset", choices=list(PRESETS), default=None,
                   help="training sizes and steps (default: small; with --resume, the run's own)")
    f.add_argument("--out", required=True, help="run folder (new, or existing with --resume)")
    f.add_argument("--resume", action="store_true", help="continue an interrupted fit from its checkpoints")
    f.add_argument("--pbr", action=argparse.BooleanOptionalAction, default=None,
                   help="learn metallic, roughness and normals too (default: when the mesh has PBR maps; "
                        "--pbr on a mesh without maps learns its constant factors and geometric normals)")
    f.add_argument("--seed", type=_seed, default=None, help="random seed (default: the preset's)")
    f.add_argument("--thin-switch", action=argparse.BooleanOptionalAction, default=True,
                   help="on a shape with many thin parts, fit small at the 'detail' settings (96 voxels, wider "
                        "denoiser field); --no-thin-switch keeps the preset's grid")
    f.add_argument("--rollout-switch", action=argparse.BooleanOptionalAction, default=True,
                   help="when the calibration keeps the input's patches even from pure noise (a wall, dunes), "
                        "train the denoiser again with the cross-plane rollout (crisper detail, ~45 s more on small); "
                        "--no-rollout-switch keeps the plain denoiser")
    f.add_argument("--set", nargs="+", default=[], metavar="SETTING=VALUE",
                   help="change settings of the preset, e.g. --set diffusion.rollout=true (crisper brick-like "
                        "textures, docs/levers.md) diffusion.steps=3000; names as in the run's config.json")
    f.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    _outside_paths_arg(f)

    s = command("sample")
    _sample_args(s)
    s.add_argument("run", help="run folder written by `sin3dm-lite fit`, or a shipped model's name (e.g. canyon)")
    s.add_argument("--out", required=True,
                   help="output folder (new, empty, or one this command wrote with the same settings: continued; "
                        "see --overwrite)")

    d = command("demo")
    _sample_args(d, n_default=4)
    d.add_argument("--example", default=examples.DEFAULT_EXAMPLE, metavar="NAME",
                   help=f"built-in example: {', '.join(examples.list_examples())} (only those with a shipped model "
                        "run without --train)")
    d.add_argument("--out", default="sin3dm-demo", help="output folder (default: ./sin3dm-demo)")
    d.add_argument("--train", action="store_true",
                   help=f"fit the example from scratch with the '{DEMO_PRESET}' preset instead of loading its shipped model")

    r = command("render")
    r.add_argument("mesh", help=mesh_help)
    r.add_argument("--views", type=_positive_int, default=8, help="views around the shape, azimuth every 360/N degrees")
    r.add_argument("--size", type=_positive_int, default=512, help="image width and height in pixels, 16-4096")
    r.add_argument("--elevation", type=_float, default=45.0, help="camera elevation in degrees, -89 to 89")
    r.add_argument("--out", required=True, help="output folder (new or empty; see --overwrite)")
    r.add_argument("--overwrite", action="store_true",
                   help="write into a non-empty --out, replacing only the files sin3dm-lite wrote there before")
    _outside_paths_arg(r)

    v = command("evaluate")
    v.add_argument("run", help="run folder written by `sin3dm-lite fit`, or a shipped model's name (e.g. canyon)")
    v.add_argument("samples", help="folder written by `sin3dm-lite sample` (NNN/mesh.obj or .glb)")
    v.add_argument("--input", default=None, help="the mesh the run was fitted to (default: the run's built-in example)")
    v.add_argument("--out", default=None, help="write the results as JSON to this .json file (default: print only)")
    v.add_argument("--overwrite", action="store_true", help="replace an --out file that sin3dm-lite wrote before")
    v.add_argument("--weights", default=None, metavar="DIR",
                   help="folder with InceptionV3 / AlexNet / LPIPS weights for SIFID and LPIPS, never downloaded "
                        "(default: none; weight-free stand-ins instead)")
    v.add_argument("--views", type=_positive_int, default=8, help="views per mesh, azimuth every 360/N degrees")
    v.add_argument("--size", type=_positive_int, default=256, help="render size in pixels, 16-4096; the paper uses 512")
    v.add_argument("--resolution", type=_positive_int, default=64,
                   help="voxels along the longest side for the geometry metrics, 16-512; the paper uses 128")
    _outside_paths_arg(v)

    c = command("calibrate")
    c.add_argument("run", help="run folder written by `sin3dm-lite fit` (a shipped model's name: print only)")
    c.add_argument("--input", default=None,
                   help="the mesh the run was fitted to, when the run has no grid.npz (default: the run's grid)")
    c.add_argument("-n", type=_int_at_least(2, "at least 2 (G-Div compares them)"), default=8,
                   help="samples per setting tried")
    c.add_argument("--seed", type=_seed, default=10_000,
                   help="first sample seed (the k-th setting drawn takes seeds from seed + 1000·k)")
    c.add_argument("--lp-iou", type=_unit_score, default=None, help="LP-IoU the samples must keep (default: 0.55)")
    c.add_argument("--lp-f", type=_unit_score, default=None, help="LP-F the samples must keep (default: 0.70)")
    _outside_paths_arg(c)

    n = command("notebooks")
    n.add_argument("notebooks", nargs="*", type=Path, help="notebooks to run (default: every notebooks/*.ipynb)")
    n.add_argument("--fast", action="store_true", help="run with SIN3DM_FAST=1 (to try it; the tests refuse such outputs)")
    n.add_argument("--check", action="store_true", help="run nothing: list notebooks whose outputs are stale or missing")
    n.add_argument("--clear", action="store_true", help="run nothing: remove every output and the recorded digest")
    n.add_argument("--timeout", type=int, default=1800, help="seconds one cell may take (default 1800)")
    return p


def _outside_paths_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--allow-outside-paths", action="store_true",
                   help="let the mesh file name textures, material libraries and buffers outside its own folder "
                        "(refused by default: a mesh from the internet must not make sin3dm-lite read other files)")


def _sample_args(s: argparse.ArgumentParser, n_default: int = 4) -> None:
    s.add_argument("-n", type=_positive_int, default=n_default,
                   help="number of samples; each lands in --out as it finishes, and the same command again continues")
    s.add_argument("--start", type=_whole, default=0,
                   help="index of the first sample (sample i comes from seed + i: `--start 7 -n 1` draws sample 7 again)")
    s.add_argument("--batch", type=_positive_int, default=None,
                   help="samples per denoiser call (default: 8, fewer if memory is short)")
    s.add_argument("--workers", type=_whole, default=1,
                   help="processes that decode, texture and export meshes while the next batch is sampled "
                        "(0: in the sampling process)")
    ctl = s.add_argument_group("controlled generation (one at a time, default: none, samples the input's size; "
                               "boxes are fractions 0-1 of the model's box along x, y, z)").add_mutually_exclusive_group()
    ctl.add_argument("--resize", nargs=3, type=_resize_factor, metavar=("SX", "SY", "SZ"), default=None,
                     help="retarget: scale factors of the x, y, z size")
    ctl.add_argument("--outpaint", nargs=3, type=_outpaint_factor, metavar=("SX", "SY", "SZ"), default=None,
                     help="grow the box by these factors (each >= 1), keep the input, generate the rest")
    ctl.add_argument("--regenerate", nargs=6, type=_float, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"), default=None,
                     help="resample this box, keep everything else (the box must reach the faces along one axis)")
    ctl.add_argument("--duplicate", nargs=9, type=_float, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1", "TX", "TY", "TZ"),
                     default=None, help="copy this box so its low corner lands at TX TY TZ; generate around both copies")
    s.add_argument("--anchor", default="center", choices=["center", "x-", "x+", "y-", "y+", "z-", "z+"],
                   help="with --outpaint: where the input stays, the centre or the face it sticks to")
    s.add_argument("--diversity", type=_unit_float, default=None,
                   help="0 = the input, 1 = from pure noise (the paper; default: the run's setting); "
                        "lower values keep more of the input's layout")
    s.add_argument("--steps", type=_positive_int, default=None, help="DDIM steps (default: the preset's)")
    s.add_argument("--ddpm", action="store_true", help="use full DDPM sampling (all timesteps) instead of DDIM")
    s.add_argument("--seed", type=_seed, default=0, help="random seed; the same seed gives the same samples")
    s.add_argument("--faces", type=_positive_int, default=None, help="face budget per mesh (default: the preset's)")
    s.add_argument("--texture-size", type=_positive_int, default=None,
                   help="texture image size in pixels (default: the preset's)")
    s.add_argument("--mesh-resolution", type=_positive_int, default=None,
                   help="decode grid along the longest side (default: the preset's)")
    s.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    s.add_argument("--overwrite", action="store_true",
                   help="write into a non-empty --out, first removing the files sin3dm-lite wrote there before "
                        "(without it, a folder of samples with the same settings is continued)")
    s.add_argument("--no-pictures", action="store_true",
                   help="skip NNN/preview.png and contact_sheet.png (rendered off-screen; they need Mesa's EGL on Linux)")


def _unit_score(text: str) -> float:
    v = _float(text)
    if not 0 <= v <= 1:
        raise argparse.ArgumentTypeError(f"a patch score is from 0 to 1, got {v}")
    return v


def _float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if v != v or v in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number, got '{text}'")
    return v


def _seed(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if not 0 <= v < 2**32:
        raise argparse.ArgumentTypeError(f"seeds run from 0 to {2**32 - 1}, got {v}")
    return v


# --------------------------------------------------------------------------- commands
def cmd_examples(a) -> None:
    from .data import examples

    if a.write:
        from .files import check_writable, clash_error, foreign_files, make_temp_dir, merge_output, remove_stale_temps

        if a.write not in examples.list_examples():
            raise Sin3DMInputError(f"unknown example '{a.write}'; choose one of: {', '.join(examples.list_examples())}")
        out = Path(a.out)
        if out.exists() and not out.is_dir():
            raise Sin3DMInputError(f"--out '{out}' is a file; give a folder to write the example into")
        names = [f"{a.write}{ext}" for ext in (".obj", ".mtl", ".png")]
        there = [n for n in names if (out / n).exists()]
        if there and not a.overwrite:
            raise Sin3DMInputError(f"'{out / there[0]}' exists; pass --overwrite to replace it if sin3dm-lite wrote it, "
                                   "or choose another --out")
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
    from .data.grid import mesh_to_grid, save_grid
    from .files import check_not_overlapping, check_writable, clash_error, is_ours, recorded_path, remove_stale_temps
    from .pipeline import resolve_mesh

    out = Path(a.out)
    if out.suffix != ".npz":
        raise Sin3DMInputError(f"--out must be a .npz file, got '{out}'")
    from .data.grid import check_resolution

    check_resolution(a.resolution)
    if Path(a.mesh).exists():
        check_not_overlapping(out, {"input mesh": Path(a.mesh)})
    if out.is_dir():
        raise Sin3DMInputError(f"--out '{out}' is a folder; give a file name like {out / 'grid.npz'}")
    if out.exists() and not a.overwrite:
        raise Sin3DMInputError(f"'{out}' exists; pass --overwrite to replace it (only if sin3dm-lite wrote it) or choose another --out")
    if out.exists() and not is_ours(out.parent, out.name, by="grid"):
        raise clash_error(out.parent, out.name, by="grid")
    check_writable(out)
    mesh = resolve_mesh(a.mesh, allow_outside_paths=a.allow_outside_paths)
    grid = mesh_to_grid(mesh, a.resolution)
    remove_stale_temps(out.parent)
    with recorded_path(out, by="grid") as tmp:
        save_grid(grid, tmp)
    print(f"wrote {out}: sdf {grid.shape}, color {grid.color.shape}, box {[round(float(x), 3) for x in grid.aabb]}")


def cmd_fit(a) -> None:
    from .data.config import get_preset, parse_settings
    from .pipeline import Sin3DM

    if a.resume and not Path(a.out).is_dir():
        raise Sin3DMInputError(f"cannot resume: run folder '{a.out}' not found; start a new fit without --resume")
    t0 = time.perf_counter()
    changes = parse_settings(a.set)
    if not a.thin_switch:
        changes["thin_parts"] = {}
    if not a.rollout_switch:
        changes["rollout_switch"] = {}
    name = a.preset or (None if a.resume else "small")  # None: the run's own (Sin3DM.fit)
    preset = get_preset(name or "small").updated(**changes) if changes else name
    model = Sin3DM.fit(a.mesh, preset=preset, out=a.out, resume=a.resume, seed=a.seed, device=a.device, pbr=a.pbr,
                       allow_outside_paths=a.allow_outside_paths)
    r = model.report["reconstruction"]
    print(
        f"fit done in {time.perf_counter() - t0:.0f} s: occupancy IoU {r['occupancy_iou']:.3f}, "
        f"sign accuracy {r['sign_accuracy']:.3f}, colour PSNR {r['color_psnr']:.1f} dB; samples default to diversity "
        f"{model.config.sampling.diversity:g}{' (calibrated for this shape)' if 'calibration' in model.report else ''}\n"
        f"next: sin3dm-lite sample {a.out} -n 4 --out {Path(a.out).with_name(Path(a.out).name + '-samples')}"
    )


def check_sample_output(out: Path, a, protected: dict) -> None:
    """Everything about ``--out``, ``-n`` and ``--start`` that can fail, checked before any work or writing.

    A folder holding a sample run of ours (``sampling.json``) passes here; its
    settings are compared once the model is loaded (:func:`mass.check_folder`).
    """
    from .files import check_not_overlapping, check_output_folder, check_writable
    from .mass import MAX_RUN_SAMPLES, WRITER, read_settings, sample_output_names

    if a.start + a.n > MAX_RUN_SAMPLES:
        raise Sin3DMInputError(f"-n {a.n} (from --start {a.start}) is too many samples: indices go up to at most "
                               f"{MAX_RUN_SAMPLES - 1} per output folder; use several --out folders with other --seed")
    check_not_overlapping(out, protected)
    if not (out.is_dir() and read_settings(out) is not None and not a.overwrite):
        check_output_folder(out, a.overwrite, sample_output_names(out, sample_request(a)), by=WRITER)
    check_writable(out)


def sample_request(a):
    """The sampling flags of ``sample`` / ``demo`` as a :class:`mass.SampleRequest` (the library takes no argparse)."""
    from .request import SampleRequest

    keys = ("n", "start", "seed", "steps", "diversity", "faces", "mesh_resolution", "texture_size",
            "no_pictures", "overwrite", "batch", "workers")
    defaults = SampleRequest()
    method = "ddpm" if getattr(a, "ddpm", False) else None  # --ddpm; else the model's
    return SampleRequest(**{k: getattr(a, k, getattr(defaults, k)) for k in keys}, method=method, control=control_args(a))


def control_args(a) -> dict:
    """The ``Sin3DM.plan`` arguments of the controlled-generation flags."""
    if a.outpaint:
        return {"outpaint": tuple(a.outpaint), "anchor": a.anchor}
    if a.regenerate:
        return {"regenerate": (tuple(a.regenerate[:3]), tuple(a.regenerate[3:]))}
    if a.duplicate:
        return {"duplicate": ((tuple(a.duplicate[:3]), tuple(a.duplicate[3:6])), tuple(a.duplicate[6:]))}
    return {"resize": tuple(a.resize) if a.resize else (1.0, 1.0, 1.0)}


def find_run(name: str) -> Path:
    """A run folder, or the shipped model called ``name``; one-line error if neither."""
    from .pretrained import shipped_model, shipped_names

    run = Path(name)
    if run.is_file() and run.name == "model.pt":  # the run folder's model, as Sin3DM.load takes it
        run = run.parent
    if run.exists() and not run.is_dir():
        raise Sin3DMInputError(f"'{name}' is a file, not a run folder: a run folder is what `sin3dm-lite fit MESH --out "
                               f"DIR` writes (config.json, model.pt, report.json, ...); give that folder, or a shipped "
                               f"model's name ({', '.join(shipped_names())})")
    if not run.is_dir():
        run = shipped_model(name)
        if run is None:
            raise Sin3DMInputError(f"run folder '{name}' not found; fit one first with `sin3dm-lite fit MESH --out "
                                   f"{name}`, or name a shipped model ({', '.join(shipped_names())})")
    return run


def cmd_sample(a) -> None:
    from .device import get_device
    from .mass import start_ranks, stop_ranks, write_samples
    from .pipeline import Sin3DM

    run = find_run(a.run)
    get_device(a.device)
    check_sample_output(Path(a.out), a, {"run folder": run})  # every rank, before any rank writes
    ranks, device = start_ranks(a.device)
    try:
        model = Sin3DM.load(run, device=device)
        r = write_samples(model, Path(a.out), sample_request(a), ranks=ranks, run=str(run))
    finally:
        stop_ranks(ranks)
    if ranks.rank == 0:
        rate = 60 * r["new"] / r["seconds"] if r["seconds"] > 0 and r["new"] else 0.0
        where = f" on {ranks.world} processes" if ranks.world > 1 else ""
        print(f"wrote {r['pending']} new samples{where} ({rate:.1f} meshes/min on rank 0); {a.out} holds {r['total']}: "
              f"NNN/mesh.obj|.glb, samples.jsonl; open {Path(a.out) / 'index.html'} in a browser")


def cmd_demo(a) -> None:
    from .data import examples
    from .device import get_device
    from .mass import write_samples
    from .pipeline import Sin3DM
    from .pretrained import shipped_model

    if a.example not in examples.list_examples():
        raise Sin3DMInputError(f"unknown example '{a.example}'; choose one of: {', '.join(examples.list_examples())}")
    shipped = None if a.train else shipped_model(a.example)
    if not a.train and shipped is None:
        have = [n for n in examples.list_examples() if shipped_model(n) is not None]
        raise Sin3DMInputError(f"no shipped model of '{a.example}' (shipped: {', '.join(have) or 'none'}); add "
                               f"--train to fit it first with the '{DEMO_PRESET}' preset, or pick --example "
                               f"{examples.DEFAULT_EXAMPLE}")
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


MAX_VIEWS = 360


def cmd_render(a) -> None:
    from .evaluate.render import contact_sheet, render_hero, render_views, view_names
    from .files import (
        check_not_overlapping,
        check_output_folder,
        check_writable,
        install_output,
        make_temp_dir,
        remove_stale_temps,
    )
    from .pipeline import resolve_mesh
    from .show.viewer import png_bytes

    out = Path(a.out)
    if a.views > MAX_VIEWS:
        raise Sin3DMInputError(f"--views {a.views} is too many; ask for at most {MAX_VIEWS}")
    if not 16 <= a.size <= 4096:
        raise Sin3DMInputError(f"--size must be from 16 to 4096 pixels, got {a.size}")
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
    sheet = contact_sheet(views + [hero], [f"azimuth {360 * k / a.views:g}" for k in range(a.views)] + ["hero"])
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
        raise Sin3DMInputError(f"no sample meshes in '{folder}' (expected NNN/mesh.obj or NNN/mesh.glb, as "
                               "`sin3dm-lite sample` writes); sample first, then evaluate that folder")
    return files


def print_evaluation(result: dict) -> None:
    """The metrics as a table: our name, the value, the paper's name and which way is better; then what was skipped."""
    from .evaluate.metrics import results_table

    print(f"{result['samples']} samples, {result['resolution']} voxels, {result['views']} views of {result['size']}²")
    print(results_table({"value": result}, digits=4))
    for key, why in result["skipped"].items():
        print(f"  {key}: {why}")


def cmd_evaluate(a) -> None:
    import json

    from .data.mesh_io import load_any
    from .evaluate.metrics import load_feature_weights
    from .files import check_not_overlapping, check_writable, clash_error, is_ours, write_recorded
    from .pipeline import Sin3DM, resolve_mesh

    if a.views > MAX_VIEWS:
        raise Sin3DMInputError(f"--views {a.views} is too many; ask for at most {MAX_VIEWS}")
    if not 16 <= a.size <= 4096:
        raise Sin3DMInputError(f"--size must be from 16 to 4096 pixels, got {a.size}")
    if not 16 <= a.resolution <= 512:
        raise Sin3DMInputError(f"--resolution must be from 16 to 512 voxels, got {a.resolution}")
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
            raise Sin3DMInputError(f"'{out}' exists; pass --overwrite to replace it (only if sin3dm-lite wrote it) "
                                   "or choose another --out")
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
    result = model.evaluate(meshes, reference, resolution=a.resolution, views=a.views, size=a.size, weights=nets)
    result.update(run=str(run), samples_folder=str(a.samples), files=[str(f) for f in files])
    print_evaluation(result)
    if out is not None:
        write_recorded(out, json.dumps(result, indent=2), by="evaluate")
        print(f"wrote {out} ({time.perf_counter() - t0:.1f} s)")


def cmd_calibrate(a) -> None:
    from .files import acquire_lock, check_writable, release_lock

    run = find_run(a.run)
    shipped = not Path(a.run).exists()  # a shipped model's folder is part of the installed package: print only
    if not shipped:
        check_writable(run)
        acquire_lock(run, "run folder")  # calibrate rewrites config.json, model.pt and report.json: no fit --resume meanwhile
    try:
        _calibrate(a, run, shipped)
    finally:
        if not shipped:
            release_lock(run)


def _calibrate(a, run: Path, shipped: bool) -> None:
    import json

    from .data.grid import load_grid
    from .evaluate.calibrate import GOALS
    from .files import atomic_write
    from .pipeline import Sin3DM, resolve_mesh

    model = Sin3DM.load(run)
    # the training grid is the input voxelised at the fit's resolution, and needs no mesh file; without it, the mesh
    reference = load_grid(run / "grid.npz").sdf < 0 if (run / "grid.npz").is_file() and a.input is None else None
    goals = {"lp_iou": GOALS["lp_iou"] if a.lp_iou is None else a.lp_iou,
             "lp_fscore": GOALS["lp_fscore"] if a.lp_f is None else a.lp_f}
    before = model.config.sampling.diversity
    t0 = time.perf_counter()
    input_mesh = None
    if reference is None:  # the input mesh is read here, with --allow-outside-paths if given
        allow = a.allow_outside_paths
        input_mesh = model.input_mesh(allow) if a.input is None else resolve_mesh(a.input, allow_outside_paths=allow)
    cal = model.calibrate(reference, input_mesh=input_mesh, goals=goals, n=a.n, seed=a.seed)
    took = time.perf_counter() - t0
    if shipped:
        print(f"{a.run}: diversity {cal.diversity:g} would keep the goals ({took:.0f} s); a shipped model is not "
              f"changed: sample it with --diversity {cal.diversity:g}")
        return
    model.save(run)
    if (run / "report.json").is_file():
        report = json.loads((run / "report.json").read_text())
        report["calibration"] = cal.to_dict()
        atomic_write(run / "report.json", json.dumps(report, indent=2))
    print(f"{run}: diversity {before:g} → {cal.diversity:g} ({took:.0f} s), saved in its config.json; "
          f"`sin3dm-lite sample {run}` uses it, --diversity overrides it")


def disk_error(e: OSError, out: str | None = None) -> str:
    """One line for a failed write or read (in this process or in an export worker): what, where and the fix.

    ``out``: the command's ``--out``, named when the error names no file (a ``write`` on a full disk).
    """
    import errno

    from .files import shown_path

    where = f" {shown_path(e.filename)}" if e.filename else ""
    if e.errno in (errno.ENOSPC, errno.EDQUOT):
        what = "no space left on device" if e.errno == errno.ENOSPC else "disk quota exceeded"
        where = where or (f" into '{out}'" if out else " the output")
        return f"{what} while writing{where}; free space or choose another --out"
    return f"{e.strerror or e}{where}; check that path (permissions, free space) or choose another --out"


def cmd_notebooks(a) -> None:
    from .notebook_run import run_all

    code = run_all(a.notebooks, fast=a.fast, check=a.check, clear=a.clear, timeout=a.timeout)
    if code:
        raise SystemExit(code)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv:  # no command: the help, as a successful answer
        parser.print_help()
        return 0
    a = parser.parse_args(argv)
    show = warnings.showwarning

    def one_line(message, category, filename, lineno, file=None, line=None):  # warnings as one line, no source
        print(f"sin3dm-lite {a.command}: warning: {message}", file=sys.stderr)

    warnings.showwarning = one_line
    try:
        {"examples": cmd_examples, "grid": cmd_grid, "fit": cmd_fit, "sample": cmd_sample, "demo": cmd_demo,
         "render": cmd_render, "evaluate": cmd_evaluate,
         "calibrate": cmd_calibrate, "notebooks": cmd_notebooks}[a.command](a)
    except Sin3DMInputError as e:
        print(f"sin3dm-lite {a.command}: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # the disk, not the code: a full disk, a folder made read-only meanwhile
        print(f"sin3dm-lite {a.command}: error: {disk_error(e, getattr(a, 'out', None))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    finally:
        warnings.showwarning = show
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

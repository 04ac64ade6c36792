"""The ``sin3dm-lite`` argument parser: one function per command, each option's help with its default.

Argument errors are one line and exit code 2; the option types (:mod:`.values_cli`) refuse what no command could
use before any work.
"""

from __future__ import annotations

import argparse

from .values_cli import (
    finite_float,
    int_at_least,
    outpaint_factor,
    positive_float,
    positive_int,
    resize_factor,
    sampling_setting,
    seed_int,
    unit_float,
    unit_score,
    whole,
)


class _Formatter(argparse.HelpFormatter):
    """Every option's help ends with its default, unless it already says "default" or has none worth saying (flags,
    required options, a default of None: their help says in words what happens without them)."""

    def _get_help_string(self, action):
        text = action.help or ""
        if (
            "default" in text
            or not action.option_strings
            or action.required
            or any(action.default is x for x in (None, False, argparse.SUPPRESS))
        ):  # `is`: 0 == False
            return text
        return f"{text} (default: %(default)s)"


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line (no usage block), exit code 2; help with defaults."""

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
}


def build_parser() -> argparse.ArgumentParser:
    from ..formats.load import READABLE

    p = _Parser(
        prog="sin3dm-lite",
        description="Sin3DM: learn a diffusion model from one textured mesh.",
        epilog=f"Readable mesh formats: {READABLE}. Start with `sin3dm-lite demo`; "
        "`sin3dm-lite CMD --help` describes one command.",
    )
    p.add_argument("--version", action="version", version=f"sin3dm-lite {package_version()}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    adders = {
        "examples": _examples_args,
        "grid": _grid_args,
        "fit": _fit_args,
        "sample": _sample_command_args,
        "demo": _demo_args,
        "render": _render_args,
        "evaluate": _evaluate_args,
        "calibrate": _calibrate_args,
    }
    for name, description in COMMANDS.items():  # in this order in `sin3dm-lite --help`
        adders[name](sub.add_parser(name, help=description, description=description))
    return p


def _mesh_help() -> str:
    from ..formats.load import READABLE

    return f"mesh file ({READABLE}) or built-in example name"


def _examples_args(e: argparse.ArgumentParser) -> None:
    e.add_argument("--write", metavar="NAME", help="example to write (default: list them)")
    e.add_argument("--out", default=".", help="folder for --write (default: current folder)")
    e.add_argument("--seed", type=seed_int, default=0, help="variant of the example")
    e.add_argument(
        "--overwrite", action="store_true", help="replace files of the example that sin3dm-lite wrote before"
    )


def _grid_args(g: argparse.ArgumentParser) -> None:
    g.add_argument("mesh", help=_mesh_help())
    g.add_argument("--resolution", type=int, default=128, help="voxels along the longest side, 16-512")
    g.add_argument("--out", required=True, help="output .npz file")
    g.add_argument("--overwrite", action="store_true", help="replace an existing grid file that sin3dm-lite wrote")
    _up_arg(g)
    _outside_paths_arg(g)


def _up_arg(p: argparse.ArgumentParser) -> None:
    from ..data.mesh import UP_TURNS

    p.add_argument(
        "--up",
        choices=list(UP_TURNS),
        default=None,
        help="the mesh's up axis, turned to Y before the grid: z for a model made Z-up (Blender, most CAD and STL "
        "files), so that the pictures and the written samples stand upright (default: y, as OBJ and glTF; "
        "the grid.up setting)",
    )


def _fit_args(f: argparse.ArgumentParser) -> None:
    from ..presets import PRESETS

    f.add_argument("mesh", help=_mesh_help())
    f.add_argument(
        "--preset",
        choices=list(PRESETS),
        default=None,
        help="training sizes and steps (default: for this machine and shape: paper on a CUDA GPU; on a CPU small "
        "where bf16 is fast, quick elsewhere, or their finer detail / fine for a shape mostly of thin parts; the "
        "fit's first lines say which, why and how long; with --resume, the run's own)",
    )
    f.add_argument("--out", required=True, help="run folder (new, or existing with --resume)")
    f.add_argument("--resume", action="store_true", help="continue an interrupted fit from its checkpoints")
    f.add_argument(
        "--pbr",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="learn metallic, roughness and normals too (default: when the mesh has PBR maps; "
        "--pbr on a mesh without maps learns its constant factors and geometric normals)",
    )
    f.add_argument("--seed", type=seed_int, default=None, help="random seed (default: the preset's)")
    f.add_argument(
        "--calibrate",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="after training, choose the run's diversity: the most varied setting whose samples keep the input's "
        "patches (default: on for the CPU presets small, quick, detail and fine)",
    )
    f.add_argument(
        "--minutes",
        type=positive_float,
        default=None,
        metavar="N",
        help="keep the fit within about N minutes: where the fit's estimate for this machine is longer, both "
        "networks train for fewer steps (at least half of the preset's; a shorter budget is refused; default: "
        "without --preset, about 11 minutes on a CPU, at least 80%% of the steps; with one, the preset's steps), "
        "and the denoiser fewer again where the autoencoder ran late",
    )
    f.add_argument(
        "--set",
        nargs="+",
        action="extend",
        default=[],
        metavar="SETTING=VALUE",
        help="change settings of the preset, e.g. --set diffusion.rollout=true diffusion.steps=3000 (or one --set "
        "each); names as in "
        "the run's config.json (docs/presets.md says what each does)",
    )
    _up_arg(f)
    f.add_argument(
        "--turn",
        type=float,
        default=None,
        metavar="DEG",
        help="turn the mesh DEG degrees about its up axis before the grid; samples are turned back (default: where "
        "its walls agree on two directions at right angles off x and z, the turn that lines them up; 0: as it lies)",
    )
    f.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    _outside_paths_arg(f)


def _sample_command_args(s: argparse.ArgumentParser) -> None:
    _sample_args(s)
    s.add_argument(
        "run",
        help="run folder written by `sin3dm-lite fit`, or a shipped model's name (e.g. canyon; ./canyon: a local "
        "folder of that name)",
    )
    s.add_argument(
        "--out",
        required=True,
        help="output folder (new, empty, or one this command wrote with the same settings: continued; see --overwrite)",
    )


def _demo_args(d: argparse.ArgumentParser) -> None:
    from .. import examples
    from .sample_cli import DEMO_PRESET

    _sample_args(d, n_default=4)
    d.add_argument(
        "--example",
        default=examples.DEFAULT_EXAMPLE,
        metavar="NAME",
        help=f"built-in example: {', '.join(examples.list_examples())} (only those with a shipped model "
        "run without --train)",
    )
    d.add_argument("--out", default="sin3dm-demo", help="output folder (default: ./sin3dm-demo)")
    d.add_argument(
        "--train",
        action="store_true",
        help=f"fit the example from scratch with the '{DEMO_PRESET}' preset instead of loading its shipped model",
    )


def _render_args(r: argparse.ArgumentParser) -> None:
    r.add_argument("mesh", help=_mesh_help())
    r.add_argument("--views", type=positive_int, default=8, help="views around the shape, azimuth every 360/N degrees")
    r.add_argument("--size", type=positive_int, default=512, help="image width and height in pixels, 16-4096")
    r.add_argument("--elevation", type=finite_float, default=45.0, help="camera elevation in degrees, -89 to 89")
    r.add_argument("--out", required=True, help="output folder (new or empty; see --overwrite)")
    r.add_argument(
        "--overwrite",
        action="store_true",
        help="write into a non-empty --out, replacing only the files sin3dm-lite wrote there before",
    )
    _outside_paths_arg(r)


def _evaluate_args(v: argparse.ArgumentParser) -> None:
    v.add_argument("run", help="run folder written by `sin3dm-lite fit`, or a shipped model's name (e.g. canyon)")
    v.add_argument("samples", help="folder written by `sin3dm-lite sample` (NNN/mesh.obj or .glb)")
    v.add_argument("--input", default=None, help="the mesh the run was fitted to (default: the run's built-in example)")
    v.add_argument("--out", default=None, help="write the results as JSON to this .json file (default: print only)")
    v.add_argument("--overwrite", action="store_true", help="replace an --out file that sin3dm-lite wrote before")
    v.add_argument(
        "--weights",
        default=None,
        metavar="DIR",
        help="folder with InceptionV3 / AlexNet / LPIPS weights for SIFID and LPIPS, never downloaded "
        "(default: none; weight-free stand-ins instead)",
    )
    v.add_argument("--views", type=positive_int, default=8, help="views per mesh, azimuth every 360/N degrees")
    v.add_argument("--size", type=positive_int, default=256, help="render size in pixels, 16-4096; the paper uses 512")
    v.add_argument(
        "--resolution",
        type=positive_int,
        nargs="+",
        action="extend",
        default=None,
        help="voxels along the longest side for the geometry metrics, 16-512, one grid or several (the first gets "
        "every metric); default: 128, the paper's, and the fit's own grid beside it",
    )
    v.add_argument(
        "--voxels",
        choices=("paper", "centres"),
        default="paper",
        help="how meshes become voxels: 'paper' (default; the paper's evaluation code: a voxel is solid when any of "
        "its 2x2x2 sub-voxels is inside; --resolution up to 256) or 'centres' (the voxel centre alone: stricter on "
        "walls 1-2 voxels thick; up to 512)",
    )
    _outside_paths_arg(v)


def _calibrate_args(c: argparse.ArgumentParser) -> None:
    c.add_argument("run", help="run folder written by `sin3dm-lite fit` (a shipped model's name: print only)")
    c.add_argument(
        "--input",
        default=None,
        help="the mesh the run was fitted to, when the run has no grid.npz (default: the run's grid)",
    )
    c.add_argument(
        "-n", type=int_at_least(2), default=8, help="samples per setting tried (at least 2: G-Div compares them)"
    )
    c.add_argument(
        "--seed",
        type=seed_int,
        default=10_000,
        help="first sample seed (the k-th setting drawn takes seeds from seed + 1000·k)",
    )
    for flag, name, goal, share in (("--lp-iou", "LP-IoU", "0.55", "65"), ("--lp-f", "LP-F", "0.70", "85")):
        keep = (
            f"{name} the samples must keep, at most (default: {share}%% of what a near copy keeps, at most {goal} on a "
            "training grid; at 128 voxels the share alone)"
        )
        c.add_argument(flag, type=unit_score, default=None, help=keep)
    c.add_argument(
        "--resolution",
        type=int_at_least(16),
        default=None,
        help="voxels along the longest side where the samples are judged (default: where the fit judged them: the "
        "training grid, or for `detail` and `fine` 128 voxels, the paper's); 128 judges against the input "
        "mesh as the paper measures, in about 4x the time of a 64-voxel training grid",
    )
    c.add_argument(
        "--voxels",
        choices=("paper", "centres"),
        default=None,
        help="the voxels judged, as for `evaluate`: 'paper' (the default with --resolution: any of 2x2x2 "
        "sub-voxels inside, what evaluate reports) or 'centres' (the default on the fit's grid, the training grid's)",
    )
    _outside_paths_arg(c)


def _outside_paths_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--allow-outside-paths",
        action="store_true",
        help="let the mesh file name textures, material libraries and buffers outside its own folder "
        "(refused by default: a mesh from the internet must not make sin3dm-lite read other files)",
    )


def _sample_args(s: argparse.ArgumentParser, n_default: int = 4) -> None:
    """The flags of ``sample`` and ``demo``, in the order ``--help`` lists them: how many samples (and how), the
    controlled generation, the sampler, and the output meshes."""
    _run_args(s, n_default)
    _control_args(s)
    _sampler_args(s)
    _output_args(s)


def _run_args(s: argparse.ArgumentParser, n_default: int) -> None:
    s.add_argument(
        "-n",
        type=positive_int,
        default=n_default,
        help="number of samples; each lands in --out as it finishes, and the same command again continues",
    )
    s.add_argument(
        "--start",
        type=whole,
        default=0,
        help="index of the first sample (sample i comes from seed + i: `--start 7 -n 1` draws sample 7 again)",
    )
    s.add_argument(
        "--batch",
        type=positive_int,
        default=None,
        help="samples per denoiser call (default: 8, fewer if memory is short)",
    )
    s.add_argument(
        "--workers",
        type=whole,
        default=None,
        help="processes that decode, texture and export meshes while the next batch is sampled "
        "(default: one per CPU core, at most 4, shared among torchrun ranks, or SIN3DM_WORKERS; 0: in the sampling process)",
    )


def _control_args(s: argparse.ArgumentParser) -> None:
    ctl = s.add_argument_group(
        "controlled generation (one at a time, default: none, samples the input's size; "
        "boxes are fractions 0-1 of the model's box along x, y, z)"
    ).add_mutually_exclusive_group()
    ctl.add_argument(
        "--resize",
        nargs=3,
        type=resize_factor,
        metavar=("SX", "SY", "SZ"),
        default=None,
        help="retarget: scale factors of the x, y, z size",
    )
    ctl.add_argument(
        "--outpaint",
        nargs=3,
        type=outpaint_factor,
        metavar=("SX", "SY", "SZ"),
        default=None,
        help="grow the box by these factors (each >= 1), keep the input, generate the rest",
    )
    ctl.add_argument(
        "--regenerate",
        nargs=6,
        type=finite_float,
        metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
        default=None,
        help="resample this box, keep everything else (the box must reach the faces along one axis)",
    )
    ctl.add_argument(
        "--duplicate",
        nargs=9,
        type=finite_float,
        metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1", "TX", "TY", "TZ"),
        default=None,
        help="copy this box so its low corner lands at TX TY TZ; generate around both copies",
    )
    s.add_argument(
        "--anchor",
        default=None,
        choices=["center", "x-", "x+", "y-", "y+", "z-", "z+"],
        help="with --outpaint: where the input stays, the centre or the face it sticks to (default: center)",
    )


def _sampler_args(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--diversity",
        type=unit_float,
        default=None,
        help="0 = the input, 1 = from pure noise (the paper; default: the run's setting); "
        "lower values keep more of the input's layout",
    )
    s.add_argument(
        "--steps", type=sampling_setting("sampling.steps"), default=None, help="DDIM steps (default: the preset's)"
    )
    s.add_argument("--ddpm", action="store_true", help="use full DDPM sampling (all timesteps) instead of DDIM")
    s.add_argument("--seed", type=seed_int, default=0, help="random seed; the same seed gives the same samples")


def _output_args(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--faces",
        type=sampling_setting("sampling.faces"),
        default=None,
        help="face budget per mesh (default: the preset's)",
    )
    s.add_argument(
        "--texture-size",
        type=sampling_setting("sampling.texture_size", False),
        default=None,
        help="texture image size in pixels (default: the preset's)",
    )
    s.add_argument(
        "--mesh-resolution",
        type=sampling_setting("sampling.mesh_resolution", False),
        default=None,
        help="decode grid along the longest side (default: the preset's)",
    )
    s.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    s.add_argument(
        "--overwrite",
        action="store_true",
        help="write into a non-empty --out, first removing the files sin3dm-lite wrote there before "
        "(without it, a folder of samples with the same settings is continued)",
    )
    s.add_argument(
        "--no-pictures",
        action="store_true",
        help="skip NNN/preview.png and contact_sheet.png (rendered off-screen; they need Mesa's EGL on Linux)",
    )

"""The ``sin3dm-lite`` command.

    sin3dm-lite examples [--write NAME --out DIR]      list / write the built-in example shapes
    sin3dm-lite grid MESH --resolution N --out FILE.npz mesh → TSDF + colour grid
    sin3dm-lite fit MESH_OR_EXAMPLE --preset small --out RUN_DIR [--resume]
    sin3dm-lite sample RUN_DIR -n 4 --out DIR [--resize SX SY SZ] [--diversity D]
    sin3dm-lite demo [--out DIR] [--train]              the whole method on the default example

Every user error prints one line naming the problem and the fix, and exits
with code 2 (no traceback).
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

from .errors import Sin3DMInputError

DEMO_PRESET = "small"


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {v}")
    return v


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not (0 < v <= 8):
        raise argparse.ArgumentTypeError(f"resize factors must be in (0, 8], got {v}")
    return v


def _unit_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number from 0 to 1, got '{text}'") from None
    if not (0 <= v <= 1):
        raise argparse.ArgumentTypeError(f"diversity must be from 0 (the input) to 1 (pure noise), got {v}")
    return v


def build_parser() -> argparse.ArgumentParser:
    from .config import PRESETS

    p = argparse.ArgumentParser(prog="sin3dm-lite", description="Sin3DM: learn a diffusion model from one textured mesh.")
    sub = p.add_subparsers(dest="command", required=True)

    e = sub.add_parser("examples", help="list the built-in example shapes, or write one as OBJ/MTL/PNG")
    e.add_argument("--write", metavar="NAME", help="example to write")
    e.add_argument("--out", default=".", help="folder for --write (default: current folder)")
    e.add_argument("--seed", type=int, default=0)

    g = sub.add_parser("grid", help="turn a mesh into the truncated SDF + colour grid (.npz)")
    g.add_argument("mesh", help="mesh file (OBJ, GLB/glTF, PLY) or example name")
    g.add_argument("--resolution", type=int, default=128, help="voxels along the longest side (16-512)")
    g.add_argument("--out", required=True, help="output .npz file")

    f = sub.add_parser("fit", help="fit the autoencoder and the diffusion model to one mesh")
    f.add_argument("mesh", help="mesh file (OBJ, GLB/glTF, PLY) or example name")
    f.add_argument("--preset", choices=list(PRESETS), default="small")
    f.add_argument("--out", required=True, help="run folder (new, or existing with --resume)")
    f.add_argument("--resume", action="store_true", help="continue an interrupted fit from its checkpoints")
    f.add_argument("--seed", type=int, default=None)
    f.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")

    s = sub.add_parser("sample", help="generate textured meshes from a fitted run folder")
    _sample_args(s)
    s.add_argument("run", help="run folder written by `sin3dm-lite fit`")
    s.add_argument("--out", required=True, help="output folder")

    d = sub.add_parser("demo", help="the whole method on the default example: load (or --train), sample, export")
    _sample_args(d, n_default=4)
    d.add_argument("--out", default="sin3dm-demo", help="output folder (default: ./sin3dm-demo)")
    d.add_argument("--train", action="store_true", help=f"fit from scratch with the '{DEMO_PRESET}' preset")
    return p


def _sample_args(s: argparse.ArgumentParser, n_default: int = 4) -> None:
    s.add_argument("-n", type=_positive_int, default=n_default, help="number of samples")
    s.add_argument("--resize", nargs=3, type=_positive_float, metavar=("SX", "SY", "SZ"), default=None,
                   help="retarget: scale factors of the x, y, z size")
    s.add_argument("--diversity", type=_unit_float, default=None,
                   help="0 = the input, 1 = from pure noise (the paper; default: the run's setting); "
                        "lower values keep more of the input's layout")
    s.add_argument("--steps", type=_positive_int, default=None, help="DDIM steps (default: the preset's)")
    s.add_argument("--ddpm", action="store_true", help="use full DDPM sampling (all timesteps) instead of DDIM")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--faces", type=_positive_int, default=None, help="face budget per mesh")
    s.add_argument("--texture-size", type=_positive_int, default=None, help="texture image size in pixels")
    s.add_argument("--mesh-resolution", type=_positive_int, default=None,
                   help="decode grid along the longest side (default: the preset's)")
    s.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")


# --------------------------------------------------------------------------- commands
def cmd_examples(a) -> None:
    from . import examples

    if a.write:
        path = examples.write_example(a.write, a.out, seed=a.seed)
        print(f"wrote {path} (+ .mtl and .png): open it in Blender with File › Import › Wavefront (.obj)")
        return
    for name in examples.list_examples():
        marker = " (default)" if name == examples.DEFAULT_EXAMPLE else ""
        print(f"{name:10s} {examples.EXAMPLES[name]}{marker}")


def cmd_grid(a) -> None:
    from .grid import mesh_to_grid, save_grid
    from .pipeline import resolve_mesh

    out = Path(a.out)
    if out.suffix != ".npz":
        raise Sin3DMInputError(f"--out must be a .npz file, got '{out}'")
    from .grid import _check_resolution

    _check_resolution(a.resolution)
    mesh = resolve_mesh(a.mesh)
    grid = mesh_to_grid(mesh, a.resolution)
    save_grid(grid, out)
    print(f"wrote {out}: sdf {grid.shape}, color {grid.color.shape}, box {[round(float(x), 3) for x in grid.aabb]}")


def cmd_fit(a) -> None:
    from .pipeline import Sin3DM

    t0 = time.perf_counter()
    model = Sin3DM.fit(a.mesh, preset=a.preset, out=a.out, resume=a.resume, seed=a.seed, device=a.device)
    r = model.report["reconstruction"]
    print(
        f"fit done in {time.perf_counter() - t0:.0f} s: occupancy IoU {r['occupancy_iou']:.3f}, "
        f"sign accuracy {r['sign_accuracy']:.3f}, colour PSNR {r['color_psnr']:.1f} dB\n"
        f"next: sin3dm-lite sample {a.out} -n 4 --out {Path(a.out) / 'samples'}"
    )


def write_samples(model, out: Path, a, label: str = "sample") -> Path:
    """Sample, decode and export into ``out`` (written in a temp folder, moved into place at the end)."""
    from .export import export_mesh
    from .viewer import gallery, save_html

    out = Path(out)
    if out.exists() and any(out.iterdir()) and not (out / "index.html").exists():
        raise Sin3DMInputError(f"output folder '{out}' exists and holds other files; choose another --out")
    resize = tuple(a.resize) if a.resize else (1.0, 1.0, 1.0)
    t0 = time.perf_counter()
    samples = model.sample(a.n, resize=resize, steps=a.steps, method="ddpm" if a.ddpm else None, seed=a.seed,
                           diversity=a.diversity)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".sin3dm-", dir=out.parent))
    tmp.chmod(0o755)  # mkdtemp makes it private; the result is an ordinary folder
    try:
        meshes = []
        for i in range(len(samples)):
            mesh = model.to_mesh(samples, i, resolution=a.mesh_resolution, faces=a.faces, texture_size=a.texture_size)
            export_mesh(mesh, tmp / f"{i:03d}", name="mesh")
            meshes.append(mesh)
            print(f"[{label}] {i + 1}/{len(samples)}: {len(mesh.faces):,} faces  ({time.perf_counter() - t0:.0f} s)")
        save_html(gallery(meshes, labels=[f"{i:03d}" for i in range(len(meshes))]), tmp / "index.html")
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def cmd_sample(a) -> None:
    from .pipeline import Sin3DM

    run = Path(a.run)
    if not run.is_dir():
        raise Sin3DMInputError(f"run folder '{run}' not found; fit one first with `sin3dm-lite fit MESH --out {run}`")
    model = Sin3DM.load(run, device=a.device)
    out = write_samples(model, Path(a.out), a)
    print(f"wrote {a.n} samples to {out}/NNN/mesh.obj|.glb; open {out / 'index.html'} in a browser")


def cmd_demo(a) -> None:
    from . import examples
    from .pipeline import Sin3DM
    from .pretrained import pretrained_path

    out = Path(a.out)
    if a.train:
        model = Sin3DM.fit(examples.DEFAULT_EXAMPLE, preset=DEMO_PRESET, out=None, device=a.device)
    else:
        model = Sin3DM.load(pretrained_path(), device=a.device)
        print(f"[demo] loaded the shipped '{DEMO_PRESET}' model of the '{examples.DEFAULT_EXAMPLE}' example")
    write_samples(model, out, a, label="demo")
    print(
        f"[demo] done: {a.n} new shapes in {out}/NNN/ (mesh.obj + mesh.mtl + mesh.png, mesh.glb)\n"
        f"[demo] look at them: open {out / 'index.html'} in a browser, or import mesh.obj in Blender"
    )


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    a = parser.parse_args(argv)
    try:
        {"examples": cmd_examples, "grid": cmd_grid, "fit": cmd_fit, "sample": cmd_sample, "demo": cmd_demo}[a.command](a)
    except Sin3DMInputError as e:
        print(f"sin3dm-lite {a.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

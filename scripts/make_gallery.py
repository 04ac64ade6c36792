"""The README's pictures, made from the shipped models (no fitting).

    python scripts/make_gallery.py                    # every picture into docs/img/
    python scripts/make_gallery.py --only control pbr # some of them
    python scripts/make_gallery.py --list             # what each one shows
    python scripts/make_gallery.py --only tower --tower RUN MESH   # a fitted run of a tower (not shipped)

One function per picture, each taking the output folder and returning the
files it wrote; ``PICTURES`` lists them in the README's order. To add a
picture (the 2D lesson's, say), write ``def picture_2d(out: Path) -> list[Path]``
with the library's plotting functions and add it to ``PICTURES``.

Everything comes from the library: ``Sin3DM.open`` loads a shipped model,
``Sin3DM.sample`` / ``to_mesh`` make the shapes, :mod:`sin3dm_lite.evaluate.render`
draws them off-screen and :mod:`sin3dm_lite.show.viz` draws the rest. Samples use
fixed seeds, so a rerun on the same code gives the same shapes. A PNG over
``MAX_BYTES`` is written with a 256-colour palette instead (none is, today:
44-215 KB). Cost: about 2 minutes of CPU time with ``OMP_NUM_THREADS=1``
(114 s on a 2-core AVX2 AMD EPYC, 2026-11-26); that run took 6.5 minutes of
wall time because the machine was shared (load average 7).
"""

from __future__ import annotations

import argparse
import io
import time
from pathlib import Path

import numpy as np

from sin3dm_lite import Sin3DM, build_example, viz
from sin3dm_lite.evaluate.render import contact_sheet, render_hero

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "img"
MAX_BYTES = 400_000
SIZE = 280  # pixels per rendered view
MESH = dict(resolution=80, faces=10_000, texture_size=384)  # enough for a 280-pixel view, a third of export's time


# --------------------------------------------------------------------------- helpers
def _box(meshes) -> np.ndarray:
    """One box around all meshes, so that the views share a scale (sizes compare)."""
    corners = np.concatenate([np.asarray(m.vertices, np.float64) for m in meshes])
    return np.stack([corners.min(0), corners.max(0)])


def _trim(images, pad: int = 6) -> list[np.ndarray]:
    """Crop the white around the shapes, by the same rows and columns in every image (the scale stays shared)."""
    drawn = np.any([np.any(im < 250, axis=2) for im in images], axis=0)
    rows, cols = np.nonzero(drawn.any(1))[0], np.nonzero(drawn.any(0))[0]
    if len(rows) == 0:
        return list(images)
    r0, r1 = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, drawn.shape[0])
    c0, c1 = max(cols[0] - pad, 0), min(cols[-1] + pad + 1, drawn.shape[1])
    return [im[r0:r1, c0:c1] for im in images]


def _views(meshes, labels, columns: int) -> np.ndarray:
    """The meshes' three-quarter views in one box, trimmed alike, as a labelled contact sheet."""
    box = _box(meshes)
    return contact_sheet(_trim([render_hero(m, size=SIZE, box=box) for m in meshes]), labels, columns=columns)


def _stack(sheets) -> np.ndarray:
    """Contact sheets one under another (white where one is narrower)."""
    width = max(s.shape[1] for s in sheets)
    rows = [np.pad(s, ((0, 0), (0, width - s.shape[1]), (0, 0)), constant_values=255) for s in sheets]
    return np.concatenate(rows, axis=0)


def _png(image_or_figure, path: Path) -> Path:
    """Write an RGB array or a matplotlib figure (at 100 dpi) as a PNG of at most MAX_BYTES."""
    from PIL import Image

    if isinstance(image_or_figure, np.ndarray):
        img = Image.fromarray(image_or_figure)
    else:
        buf = io.BytesIO()
        image_or_figure.savefig(buf, format="png", dpi=100, bbox_inches="tight", facecolor="white")
        img = Image.open(buf).convert("RGB")
    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=True)
    if buf.tell() > MAX_BYTES:  # renders have many shades: a palette keeps them recognisable at a third of the size
        buf = io.BytesIO()
        img.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.FLOYDSTEINBERG).save(
            buf, format="PNG", optimize=True
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(buf.getvalue())
    return path


# --------------------------------------------------------------------------- pictures
def picture_samples(out: Path, examples=("canyon", "colonnade", "wall"), n: int = 3) -> list[Path]:
    """Each built-in input beside ``n`` random samples of its shipped model (one row per example)."""
    rows = []
    for name in examples:
        model = Sin3DM.open(name, progress=False)
        samples = model.sample(n, seed=0, progress=False)
        meshes = [build_example(name), *model.to_mesh(samples, **MESH)]
        d = model.config.sampling.diversity
        rows.append(
            _views(meshes, [f"{name}: input", *(f"sample {i} (diversity {d:g})" for i in range(n))], columns=n + 1)
        )
    return [_png(_stack(rows), out / "samples.png")]


def picture_control(out: Path, name: str = "canyon") -> list[Path]:
    """Controlled generation on one shipped model: the input, retargeted, outpainted, edited, duplicated.

    Also the outpainting request on the three planes (``viz.plot_plan``): red is what the sampler generates.
    """
    model = Sin3DM.open(name, progress=False)
    requests = [
        ("resized to 2 x 1 x 1", dict(resize=(2.0, 1.0, 1.0), seed=0)),
        ("outpainted 1.5 x in x, input at x-", dict(outpaint=(1.5, 1.0, 1.0), anchor="x-", seed=0)),
        ("middle third regenerated", dict(regenerate=((0.35, 0.0, 0.0), (0.65, 1.0, 1.0)), seed=1)),
        ("left third copied to x = 0.6", dict(duplicate=(((0.0, 0.0, 0.0), (0.3, 1.0, 1.0)), (0.6, 0.0, 0.0)), seed=2)),
    ]
    meshes, labels, plans = [build_example(name)], [f"{name}: input"], {}
    for label, kw in requests:
        s = model.sample(1, progress=False, **kw)
        meshes.append(model.to_mesh(s, 0, **MESH))
        labels.append(label)
        plans[label] = s
    # one box for the two long results, one for the rest: sizes compare within a row
    sheet = _stack(
        [
            _views(meshes[:3], labels[:3], columns=3),
            _views([meshes[0], *meshes[3:]], [labels[0], *labels[3:]], columns=3),
        ]
    )
    outp = plans[requests[1][0]]
    fig = viz.plot_plan(
        outp.plan, outp, title="outpainting on the three planes: red = generated, clear = kept from the input's latent"
    )
    return [_png(sheet, out / "control.png"), _png(fig, out / "control_plan.png")]


def picture_pbr(out: Path, name: str = "tiles", n: int = 2) -> list[Path]:
    """The PBR model: the input and samples rendered with their maps, and one sample's four maps painted on it.

    The second row shows each of ``viz.pbr_map_images``' maps (base colour, metallic, roughness, normal)
    as the only texture of sample 0, so the reader sees where on the shape each map puts what.
    """
    from dataclasses import replace

    model = Sin3DM.open(name, progress=False)
    samples = model.sample(n, seed=0, progress=False)
    meshes = model.to_mesh(samples, **MESH)
    rendered = _views(
        [build_example(name), *meshes],
        [f"{name}: input (PBR render)", *(f"sample {i}" for i in range(n))],
        columns=n + 1,
    )
    sample = meshes[0]
    maps = viz.pbr_map_images(sample)
    painted = []
    for img in maps.values():
        rgb = np.repeat(img[..., None], 3, axis=2) if img.ndim == 2 else np.asarray(img[..., :3])
        plain = [
            replace(
                m,
                image=rgb.astype(np.float32),
                base_color=np.ones(4, np.float32),
                metallic=0.0,
                roughness=1.0,
                metallic_roughness_image=None,
                normal_image=None,
            )
            for m in sample.materials
        ]
        painted.append(replace(sample, materials=plain))
    maps_row = _views(painted, [f"sample 0: {label}" for label in maps], columns=len(maps))
    return [_png(_stack([rendered, maps_row]), out / "pbr.png")]


def picture_2d(out: Path, size: int = 24) -> list[Path]:
    """The 2D lesson (notebook 00b): one image, and samples of a denoiser with a small and with a large field.

    The large field sees the whole image and copies it; the small one recombines its pebbles.
    """
    from sin3dm_lite import lesson2d

    image = lesson2d.pebbles(size, seed=0)
    rows, samples = ["input"], [image[None]]
    for field, steps in (("small", 600), ("large", 200)):
        cfg = lesson2d.lesson_config(field, steps, 32)
        model, _ = lesson2d.fit_image(image, cfg)
        samples.append(lesson2d.sample_images(model, (size, size), n=4, steps=25, seed=0))
        rows.append(f"{field} field ({lesson2d.receptive_field_width(cfg)} px)")
    return [_png(lesson2d.plot_images(samples, rows=rows), out / "lesson2d.png")]


#: the fitted run and its input mesh for :func:`picture_tower` (``--tower RUN MESH``): a tower is not shipped
TOWER: list[str] = []


def picture_tower(out: Path, n: int = 4) -> list[Path]:
    """A ruined tower's run (``--tower RUN MESH``): the input and ``n`` samples at the run's default, then at 1."""
    if not TOWER:
        print("  tower: skipped (give --tower RUN MESH: a fit of benchmarks/make_test_meshes.py's ruins)")
        return []
    from sin3dm_lite.formats.load import load_mesh

    model, mesh = Sin3DM.load(TOWER[0]), load_mesh(TOWER[1])
    rows = []
    for d in (model.config.sampling.diversity, 1.0):
        meshes = [mesh, *model.to_mesh(model.sample(n, seed=0, diversity=d, progress=False), **MESH)]
        rows.append(_views(meshes, ["input", *(f"sample {i} (diversity {d:g})" for i in range(n))], columns=n + 1))
    return [_png(_stack(rows), out / "tower.png")]


PICTURES = {
    "samples": picture_samples,
    "control": picture_control,
    "pbr": picture_pbr,
    "tower": picture_tower,
    "2d": picture_2d,
}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", choices=list(PICTURES), help="make only these pictures")
    parser.add_argument("--out", type=Path, default=OUT, help=f"folder for the PNGs (default: {OUT.relative_to(ROOT)})")
    parser.add_argument("--list", action="store_true", help="say what each picture shows, make none")
    parser.add_argument("--tower", nargs=2, metavar=("RUN", "MESH"), default=[], help="the run for the tower picture")
    args = parser.parse_args(argv)
    TOWER[:] = args.tower
    if args.list:
        for key, fn in PICTURES.items():
            print(f"{key:8s} {fn.__doc__.splitlines()[0]}")
        return
    start, cpu = time.perf_counter(), time.process_time()
    for key in args.only or PICTURES:
        t, c = time.perf_counter(), time.process_time()
        for path in PICTURES[key](args.out):
            print(f"{path}  {path.stat().st_size / 1e3:.0f} KB", flush=True)
        print(f"  {key}: {time.perf_counter() - t:.0f} s ({time.process_time() - c:.0f} s of CPU)", flush=True)
    print(f"all: {time.perf_counter() - start:.0f} s ({time.process_time() - cpu:.0f} s of CPU in this process)")


if __name__ == "__main__":
    main()

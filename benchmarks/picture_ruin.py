"""The README's ruin picture: the input and samples of two fits of a ruin-like shape, two views each.

    python benchmarks/make_test_meshes.py meshes
    sin3dm-lite fit meshes/ruin.obj --preset quick --out runs/ruin_walls
    sin3dm-lite fit meshes/ruin.obj --preset quick --set "thin_walls={}" --out runs/ruin_narrow
    python benchmarks/picture_ruin.py runs/ruin_walls runs/ruin_narrow meshes/ruin.obj docs/img/ruin_walls.png

Top row: the input and three samples (seed 0, the run's default) of the first run; bottom row: the second run's
reconstruction (its own latent, decoded) and three of its samples. Each shape from behind (the door's side) and
from the side, 30° up.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from PIL import Image

from sin3dm_lite import Sin3DM
from sin3dm_lite.data.source import resolve_mesh
from sin3dm_lite.evaluate.render import contact_sheet, render_views


def two_views(mesh, size: int = 220) -> list:
    """The views at azimuth 270° (the door) and 180°, 30° up."""
    views = render_views(mesh, n_views=4, size=size, elevation=30.0)
    return [views[3], views[2]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("wide", help="the run of the top row (quick's default)")
    ap.add_argument("narrow", help="the run of the bottom row")
    ap.add_argument("mesh", help="the input mesh")
    ap.add_argument("out", help="the PNG to write")
    a = ap.parse_args()
    torch.set_num_threads(2)
    images, labels = [], []
    for row, run in enumerate((a.wide, a.narrow)):
        model = Sin3DM.load(run)
        first = resolve_mesh(a.mesh) if row == 0 else model.to_mesh(model.input_sample(), vertex_colors=True)[0]
        shapes = [("input" if row == 0 else "reconstruction", first)]
        samples = model.to_mesh(model.sample(3, seed=0, progress=False), vertex_colors=True)
        shapes += [(f"{model.config.name}, sample {i}", m) for i, m in enumerate(samples)]
        for label, mesh in shapes:
            images += two_views(mesh)
            labels += [label, ""]
    sheet = Image.fromarray(contact_sheet(images, labels, columns=8)).quantize(colors=128)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    sheet.save(a.out, optimize=True)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()

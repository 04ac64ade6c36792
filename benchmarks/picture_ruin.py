"""The README's ruin picture: the input, its reconstruction and samples of one fit of a ruin-like shape, two views each.

    python benchmarks/make_test_meshes.py meshes
    sin3dm-lite fit meshes/ruin.obj --preset quick --out runs/ruin
    python benchmarks/picture_ruin.py runs/ruin meshes/ruin.obj docs/img/ruin_walls.png

Top row: the input and three samples (seed 0, the run's default: snapping that prefers the input's patch from
the same place, ``sampling.snap_place``); bottom row: the reconstruction (the run's own latent, decoded) and the
same three samples snapped without that preference (``snap_place`` 0). Each shape from the door's side and from
the side of a window, 30° up.
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
    """The views at azimuth 270° (the door, a window inside) and 0° (a window), 30° up."""
    views = render_views(mesh, n_views=4, size=size, elevation=30.0)
    return [views[3], views[0]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", help="a quick fit of the ruin (its thin-walls switch on)")
    ap.add_argument("mesh", help="the input mesh")
    ap.add_argument("out", help="the PNG to write")
    a = ap.parse_args()
    torch.set_num_threads(2)
    model = Sin3DM.load(a.run)
    place = model.config.sampling.snap_place
    images, labels = [], []
    for row in range(2):
        first = resolve_mesh(a.mesh) if row == 0 else model.to_mesh(model.input_sample(), vertex_colors=True)[0]
        shapes = [("input" if row == 0 else "reconstruction", first)]
        model.config = model.config.updated(**{"sampling.snap_place": place if row == 0 else 0.0})
        samples = model.to_mesh(model.sample(3, seed=0, progress=False), vertex_colors=True)
        said = f"snap_place {model.config.sampling.snap_place:g}"
        shapes += [(f"sample {i}, {said}", m) for i, m in enumerate(samples)]
        for label, mesh in shapes:
            images += two_views(mesh)
            labels += [label, ""]
    sheet = Image.fromarray(contact_sheet(images, labels, columns=8)).quantize(colors=128)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    sheet.save(a.out, optimize=True)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()

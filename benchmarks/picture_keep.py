"""The square keep's trade between whole walls and variation, as a picture (docs/thin-parts.md).

    python benchmarks/make_test_meshes.py meshes
    sin3dm-lite fit meshes/keep.obj --preset quick --out runs/keep
    python benchmarks/picture_keep.py runs/keep meshes/keep.obj docs/img/keep_fields.png

Rows, each from the door's side, 30° up: the input keep and three of its family (the generator's seeds 1-3: other
broken tops over the same walls, what one would like the samples to be); then four samples of three denoisers
trained on the run's latent: 4 ResBlocks (a 17-texel field, the thin-walls switch's wide field) from pure noise;
3 ResBlocks trained 800 steps (13 texels) from pure noise; and the run's own denoiser (for the keep the fit's
fallback, 2 ResBlocks, 9 texels) at its calibrated diversity. The first copies the keep; the last tears its walls.
About a minute on 2 cores (two denoisers retrained).
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import numpy as np
import torch
from bench_levers import retrain
from PIL import Image

from sin3dm_lite import Sin3DM
from sin3dm_lite.data.ruin import build_ruin
from sin3dm_lite.data.source import resolve_mesh
from sin3dm_lite.evaluate.render import contact_sheet, render_views

#: the denoisers of the rows after the family: a label and the settings retrained with (None: the run's own)
ROWS = (
    ("17 texels", {"n_resblocks": 4, "steps": 1500}, 1.0),
    ("13 texels, 800 steps", {"n_resblocks": 3, "steps": 800}, 1.0),
    ("the fit's 9 texels", None, None),
)


def door_view(mesh, size: int) -> np.ndarray:
    """The view at azimuth 270° (the keep's door), 30° up."""
    return render_views(mesh, n_views=4, size=size, elevation=30.0)[3]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", help="a quick fit of the square keep (benchmarks/make_test_meshes.py keep.obj)")
    ap.add_argument("mesh", help="the run's input mesh (keep.obj)")
    ap.add_argument("out", help="the PNG to write")
    ap.add_argument("--size", type=int, default=160)
    a = ap.parse_args()
    torch.set_num_threads(2)
    run = Sin3DM.load(a.run)
    images = [door_view(resolve_mesh(a.mesh), a.size)]
    images += [door_view(build_ruin(seed, square=True), a.size) for seed in (1, 2, 3)]
    labels = ["the input keep", "its family: seed 1", "seed 2", "seed 3"]
    for label, changes, diversity in ROWS:
        model = run
        if changes is not None:
            model = copy.copy(run)
            d = {f"diffusion.{k}": v for k, v in changes.items()}
            d.update({"diffusion.base_channels": 16, "diffusion.batch_size": 4})
            retrain(model, Path(a.run), run.config.updated(**d))
        diversity = diversity if diversity is not None else run.config.sampling.diversity
        samples = model.sample(4, seed=0, diversity=diversity, progress=False)
        images += [door_view(m, a.size) for m in model.to_mesh(samples, vertex_colors=True)]
        labels += [f"{label} at {diversity:g}", "", "", ""]
        print(f"{label}: done", flush=True)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    sheet = Image.fromarray(contact_sheet(images, labels, columns=4))
    sheet.quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(a.out, optimize=True)  # a docs picture: small
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()

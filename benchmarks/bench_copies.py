"""Do a run's samples vary at all? The distance of its samples from pure noise to the input's latent.

    python benchmarks/bench_copies.py RUN [RUN ...]
    python benchmarks/bench_copies.py --shipped

For each fitted run folder (or each shipped model): ``fit_policy.from_noise_distance``, the mean squared
difference of 4 samples' latents (diversity 1, seed 0) from the input's over its variance, over all channels
and over the 4 geometry channels alone; a calibrated fit warns below ``fit_policy.COPIES_DISTANCE``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from types import SimpleNamespace

import torch

from sin3dm_lite import Sin3DM
from sin3dm_lite.fit_policy import COPIES_DISTANCE, from_noise_distance

SHIPPED = Path(__file__).resolve().parents[1] / "sin3dm_lite" / "shipped"


def geometry_only(model) -> SimpleNamespace:
    """The model's latent and samples cut to their geometry channels (the first ``geo_channels``)."""
    g = model.config.autoencoder.geo_channels

    def cut(tp):
        return tp.zip_map(tp, lambda a, _: a[:, :g])

    return SimpleNamespace(
        latent=cut(model.latent), sample=lambda n, **kw: SimpleNamespace(triplane=cut(model.sample(n, **kw).triplane))
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="*", help="fitted run folders")
    ap.add_argument("--shipped", action="store_true", help="the shipped models")
    a = ap.parse_args()
    torch.set_num_threads(2)
    runs = [*map(Path, a.runs), *(sorted(p for p in SHIPPED.iterdir() if p.is_dir()) if a.shipped else [])]
    print(f"copies below {COPIES_DISTANCE}")
    print("| run | config | all channels | geometry channels |")
    print("|---|---|---|---|")
    for run in runs:
        model = Sin3DM.load(run)
        print(
            f"| {run.name} | {model.config.name} | {from_noise_distance(model):.3f} | "
            f"{from_noise_distance(geometry_only(model)):.3f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()

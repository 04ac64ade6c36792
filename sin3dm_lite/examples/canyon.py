"""The canyon: a river cut into a block, terraced cliffs banded with rock strata (the quickstart's input)."""

from __future__ import annotations

import numpy as np

from ..data.mesh import TexturedMesh
from .geometry import grid_solid
from .texture import AtlasBuilder, Noise, mix, palette, smooth


def build_canyon(rng: np.random.Generator) -> TexturedMesh:
    """A river canyon in a 4 × 2 block: terraced cliffs on both banks, strata on every cliff face."""
    length, depth, floor = 4.0, 2.0, 0.3
    noise = Noise(rng)
    n_steps = 4
    phase, amp = rng.uniform(0, 2 * np.pi), rng.uniform(0.12, 0.25)
    step_at = 0.14 + 0.21 * np.arange(n_steps) + rng.uniform(-0.03, 0.03, n_steps)  # distance from the river
    step_rise = rng.uniform(0.2, 0.34, n_steps)

    def centre(x):
        return depth / 2 + amp * np.sin(2 * np.pi * x / length + phase) + 0.2 * (noise.fbm(x * 0.7, 3.1) - 0.5)

    def height(x, y):
        off = y - centre(x)
        dist, side = np.abs(off), (off > 0).astype(np.float32)
        h = np.full(np.shape(x), floor, np.float32)
        wander = 0.14 * (noise.fbm(x * 1.2, 5.0 * side) - 0.5)  # the cliff lines of one bank wander together
        for k in range(n_steps):
            edge = step_at[k] + wander + 0.06 * (noise.fbm(x * 2.0, 11.0 * k + 5.0 * side + 60, octaves=3) - 0.5)
            # the step's rise varies along x
            rise = step_rise[k] * (0.55 + 0.9 * noise.fbm(x * 0.6 + 40.0 * k, 7.7 + 3.0 * side, octaves=2))
            h = h + rise * smooth((dist - edge) / 0.05 + 0.5)
        return h + 0.03 * (noise.fbm(x * 5, y * 5) - 0.5)

    # rock strata: layers of random thickness and colour, stacked from the bottom
    tops = np.cumsum(rng.uniform(0.025, 0.13, 80))
    rock = [
        [0.72, 0.36, 0.22],
        [0.84, 0.56, 0.34],
        [0.92, 0.80, 0.60],
        [0.60, 0.27, 0.17],
        [0.78, 0.46, 0.30],
        [0.56, 0.42, 0.34],
        [0.95, 0.88, 0.74],
        [0.68, 0.52, 0.40],
    ]
    layer_color = palette(rng, rock, len(tops) + 1)

    def strata(z, p):
        zz = z + 0.04 * (noise.fbm(p * 2.0, z * 2.0 + 50.0) - 0.5)  # layers bend a little
        col = layer_color[np.searchsorted(tops, zz)]
        lamination = 1 + 0.07 * np.sin(zz * 2 * np.pi / 0.017)
        grain = 0.82 + 0.36 * noise.fbm(p * 37.0, zz * 90.0, octaves=2)
        return col * (lamination * grain)[..., None]

    def paint(chart, p, q):
        direction = chart.split(":")[1]
        if direction in ("+x", "-x", "+y", "-y"):  # cliffs and the block's sides: (p, q) = (y or x, z)
            return strata(q, p)
        if direction == "-z":  # the underside
            return np.float32([0.35, 0.22, 0.16]) * (0.9 + 0.2 * noise(p * 20, q * 20))[..., None]
        x, y = p, q  # +z: the ground seen from above
        h = height(x, y)
        sand = np.float32([0.86, 0.71, 0.50])
        col = mix(strata(h, x) * 1.08, sand, 0.25 + 0.3 * noise.fbm(x * 6, y * 6))
        shrub = noise(x * 60.0, y * 60.0) * noise.fbm(x * 3, y * 3 + 9) > 0.45
        col[shrub] = col[shrub] * 0.35 + np.float32([0.18, 0.26, 0.10])
        river = np.clip((floor + 0.05 - h) / 0.04, 0, 1) * smooth((0.1 - np.abs(y - centre(x))) / 0.04)
        ripple = 0.9 + 0.15 * noise(x * 40, y * 8)
        water = np.float32([0.22, 0.44, 0.46]) * ripple[..., None]
        return mix(col, water, river)

    nx, ny = 128, 64
    x, y = np.meshgrid(np.linspace(0, length, nx + 1), np.linspace(0, depth, ny + 1), indexing="ij")
    top = np.stack([x, y, height(x, y)], -1)
    bottom = np.stack([x, y, np.zeros_like(x)], -1)
    atlas = AtlasBuilder()
    atlas.add_box_projected("rock", *grid_solid(top, bottom))
    return atlas.build("canyon", paint, size=(1024, 1024), detail=lambda c: 0.1 if c.endswith("-z") else 1.0)

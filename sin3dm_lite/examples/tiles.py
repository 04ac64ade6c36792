"""The tiles: a PBR floor of brushed and hammered steel tiles and chipped painted ones in rough grout.

Every map follows the tile pattern: base colour (steel, chipped paint, dark grout), metallic (1 on steel and
the chips), roughness (low on steel, higher on paint, highest in the grout) and a tangent-space normal map
(brushing grooves, hammer dimples, the paint's edge around each chip; the bevels are geometry).
"""

from __future__ import annotations

import numpy as np

from ..data.mesh import TexturedMesh
from .geometry import grid_solid, joint_nodes
from .texture import AtlasBuilder, Noise, mix, palette, smooth

PAINTS = [[0.72, 0.18, 0.14], [0.16, 0.38, 0.62], [0.85, 0.68, 0.20], [0.20, 0.48, 0.30], [0.88, 0.86, 0.80]]
STEEL = np.float32([0.70, 0.71, 0.73])


def build_tiles(rng: np.random.Generator) -> TexturedMesh:
    """A 3.2 × 2 m floor slab, 0.45 m thick, of 0.4 m tiles: steel tiles and chipped painted ones (PBR)."""
    return _Tiles(rng).build()


class _Tiles:
    """One floor: the random kind, raise, colour, roughness and brushing angle of every tile, and its maps."""

    size_x, size_y, thick = 3.2, 2.0, 0.45
    tile, grout, bevel = 0.4, 0.03, 0.03

    def __init__(self, rng: np.random.Generator):
        self.noise = Noise(rng)
        nx, ny = self.nx, self.ny = int(round(self.size_x / self.tile)), int(round(self.size_y / self.tile))
        # 0 brushed steel, 1 hammered steel, 2 painted
        self.kind = kind = rng.choice(3, size=(nx, ny), p=[0.3, 0.2, 0.5])
        self.raise_ = rng.uniform(0.03, 0.05, (nx, ny))
        self.paint_col = palette(rng, PAINTS, nx * ny, jitter=0.1).reshape(nx, ny, 3)
        self.roughness = np.where(
            kind == 0,
            rng.uniform(0.2, 0.35, (nx, ny)),
            np.where(kind == 1, rng.uniform(0.35, 0.5, (nx, ny)), rng.uniform(0.55, 0.75, (nx, ny))),
        )
        self.brush_angle = rng.uniform(0, np.pi, (nx, ny))

    def build(self) -> TexturedMesh:
        t = self.tile  # grid lines dense at every grout joint and bevel, sparse across the tile
        nodes = lambda n: joint_nodes(0.0, t, n, self.grout, self.bevel, [t / 4, t / 2, 3 * t / 4])
        X, Y = np.meshgrid(nodes(self.nx), nodes(self.ny), indexing="ij")
        i, j, dist = self.cell(X, Y)
        top = np.stack([X, Y, self.thick - 0.05 + self.raise_[i, j] * smooth(dist / self.bevel)], -1)
        bottom = np.stack([X, Y, np.zeros_like(X)], -1)
        vertices, faces = grid_solid(top, bottom)
        axis = np.full(len(faces), -1)
        axis[: 2 * (X.shape[0] - 1) * (X.shape[1] - 1)] = 2  # the tiled sheet (bevels too) projects along z
        atlas = AtlasBuilder()
        atlas.add_box_projected("floor", vertices, faces, axis=axis)
        return atlas.build(
            "tiles", self.paint, size=(1024, 1024), pbr=self.pbr, detail=lambda c: 1.0 if c.endswith("+z") else 0.15
        )

    def cell(self, x, y):
        """Tile index and distance to the grout (negative in the grout)."""
        tile = self.tile
        i = np.clip(np.floor(x / tile).astype(np.int64), 0, self.nx - 1)
        j = np.clip(np.floor(y / tile).astype(np.int64), 0, self.ny - 1)
        u, v = x - i * tile, y - j * tile
        return i, j, np.minimum(np.minimum(u, tile - u), np.minimum(v, tile - v)) - self.grout / 2

    def chips(self, x, y):
        """How much paint is left in [0, 1] (0: chipped down to the steel)."""
        return smooth((0.6 - self.noise.fbm(x * 6 + 40, y * 6, octaves=4)) / 0.03)

    def fine_height(self, x, y, i, j):
        """Detail the normal map carries (metres): brushing, dimples, paint thickness."""
        noise, kind = self.noise, self.kind
        a = self.brush_angle[i, j]
        brushed = 0.0015 * noise(80 * (x * np.cos(a) + y * np.sin(a)), 2 * (y * np.cos(a) - x * np.sin(a)))
        dimples = 0.004 * np.abs(np.sin(x * 45 + j) * np.sin(y * 45 + i)) * (0.5 + noise(x * 20, y * 20))
        painted = 0.002 * (1 - self.chips(x, y))
        return np.where(kind[i, j] == 0, brushed, np.where(kind[i, j] == 1, dimples, -painted))

    def paint(self, chart, p, q):
        noise = self.noise
        if chart.split(":")[1] != "+z":  # sides and bottom: concrete
            return np.float32([0.5, 0.49, 0.46]) * (0.85 + 0.3 * noise.fbm(p * 10, q * 10 + 9))[..., None]
        i, j, dist = self.cell(p, q)
        grime = (0.85 + 0.25 * noise.fbm(p * 25, q * 25, octaves=3))[..., None]
        metal = STEEL * (0.9 + 0.15 * noise(p * 60, q * 60))[..., None]
        painted = mix(metal, self.paint_col[i, j], self.chips(p, q)) * grime
        col = np.where((self.kind[i, j] == 2)[..., None], painted, metal)
        return np.where((dist < 0)[..., None], np.float32([0.24, 0.23, 0.22]) * grime, col)

    def pbr(self, chart, p, q):
        if chart.split(":")[1] != "+z":
            flat = np.zeros(p.shape + (3,), np.float32)
            flat[..., 2] = 1
            return np.zeros(p.shape, np.float32), np.full(p.shape, 0.9, np.float32), flat
        kind, roughness = self.kind, self.roughness
        i, j, dist = self.cell(p, q)
        left = np.where(kind[i, j] == 2, self.chips(p, q), 0.0)  # paint left
        metal = np.where(dist < 0, 0.0, 1 - left)
        rough = np.where(
            dist < 0, 0.95, np.where(kind[i, j] == 2, left * roughness[i, j] + (1 - left) * 0.3, roughness[i, j])
        )
        h = np.where(dist < 0, 0.0, self.fine_height(p, q, i, j))
        dh_dq, dh_dp = np.gradient(h, q[:, 0], p[0, :])  # rows follow q, columns p
        normal = np.stack([-dh_dp, -dh_dq, np.ones_like(h)], -1)
        return metal, rough, normal / np.linalg.norm(normal, axis=-1, keepdims=True)

"""The wall: a crenellated brick wall, protruding bricks of varied colour in grey mortar, merlons of varied width."""

from __future__ import annotations

import numpy as np

from ..data.mesh import TexturedMesh
from .geometry import grid_solid, joint_nodes
from .texture import AtlasBuilder, Noise, palette, smooth

BRICKS = [
    [0.62, 0.25, 0.18],
    [0.70, 0.33, 0.22],
    [0.55, 0.22, 0.17],
    [0.76, 0.43, 0.30],
    [0.46, 0.20, 0.16],
    [0.66, 0.37, 0.27],
    [0.58, 0.30, 0.25],
]
GREY = np.float32([0.66, 0.64, 0.60])


def build_wall(rng: np.random.Generator) -> TexturedMesh:
    """A 4 m brick wall, 0.6 m thick: five courses of protruding bricks, merlons of varied width on top."""
    return _Wall(rng).build()


class _Wall:
    """One wall: its measures, the random tables of its bricks (drawn in a fixed order), its surface and paint."""

    length, thick = 4.0, 0.6
    course, brick, mortar, bevel = 0.25, 0.6, 0.035, 0.035
    n_body = 5
    n_c, n_b = 8, 10  # table sizes: courses, bricks per course

    def __init__(self, rng: np.random.Generator):
        n_c, n_b = self.n_c, self.n_b
        self.rng = rng
        self.noise = Noise(rng)
        self.shift = rng.uniform(0, self.brick, n_c)  # each course's running-bond offset
        self.protrude = rng.uniform(0.02, 0.05, (2, n_c, n_b))  # (side, course, brick)
        self.protrude[rng.random(self.protrude.shape) < 0.12] += 0.05  # a few bricks stick out
        self.brick_color = palette(rng, BRICKS, 2 * n_c * n_b, jitter=0.12).reshape(2, n_c, n_b, 3)

    def build(self) -> TexturedMesh:
        rng, length = self.rng, self.length
        atlas = AtlasBuilder()
        atlas.add_box_projected("body", *self.slab(0.0, length, 0.0, self.n_body))
        # merlons: widths and gaps drawn at random, then scaled to span the wall end to end
        widths, gaps = rng.uniform(0.5, 0.8, 5), rng.uniform(0.3, 0.5, 4)
        scale = length / (widths.sum() + gaps.sum())
        x = 0.0
        body_h = self.n_body * self.course
        for i, w in enumerate(widths):
            n_courses = 2 if rng.random() > 0.2 else 1  # now and then a broken-down merlon
            atlas.add_box_projected(f"merlon{i}", *self.slab(x, x + w * scale, body_h, n_courses))
            x += (w + (gaps[i] if i < len(gaps) else 0)) * scale
        return atlas.build("wall", self.paint, size=(1024, 1024), detail=lambda c: 0.1 if c.endswith("-z") else 1.0)

    # ------------------------------------------------------------------ the surface
    def cell(self, x, z, width, offset):
        """Which brick (course, index) a face point is in and its distance to the mortar (negative in mortar)."""
        course = self.course
        c = np.clip(np.floor(z / course).astype(np.int64), 0, self.n_c - 1)
        xs = x + offset[c]
        j = np.floor(xs / width).astype(np.int64)
        u, v = xs - j * width, z - c * course
        dist = np.minimum(np.minimum(u, width - u), np.minimum(v, course - v)) - self.mortar / 2
        return c, j % self.n_b, dist

    def bump(self, x, z, side):
        c, j, dist = self.cell(x, z, self.brick, self.shift)
        return self.protrude[side, c, j] * smooth(dist / self.bevel)

    def slab(self, x0, x1, z0, n_courses):
        thick = self.thick
        x = np.linspace(x0, x1, int(np.ceil((x1 - x0) / 0.025)) + 1)
        # rows dense at every mortar joint and bevel, sparse across the brick face
        z = joint_nodes(z0, self.course, n_courses, self.mortar, self.bevel, [self.course / 2])
        X, Z = np.meshgrid(x, z, indexing="ij")
        front = np.stack([X, -thick / 2 - self.bump(X, Z, 0), Z], -1)
        back = np.stack([X, thick / 2 + self.bump(X, Z, 1), Z], -1)
        vertices, faces = grid_solid(front, back)
        axis = np.full(len(faces), -1)
        axis[: 4 * (X.shape[0] - 1) * (X.shape[1] - 1)] = 1  # the two brick sheets (bevels too) project along y
        return vertices, faces, axis

    # ------------------------------------------------------------------ the paint
    def masonry(self, x, z, side, width, offset):
        noise = self.noise
        c, j, dist = self.cell(x, z, width, offset)
        col = self.brick_color[side, c, j] * (0.8 + 0.35 * noise.fbm(x * 30 + 7 * side, z * 30, octaves=3))[..., None]
        col = col * (0.75 + 0.25 * smooth(dist / 0.03))[..., None]  # darker towards the edges
        mortar_col = GREY * (0.85 + 0.25 * noise(x * 80, z * 80))[..., None]
        return np.where((dist < 0)[..., None], mortar_col, col)

    def paint(self, chart, p, q):
        direction, thick, noise = chart.split(":")[1], self.thick, self.noise
        if direction in ("+y", "-y"):  # front / back faces: (p, q) = (x, z)
            return self.masonry(p, q, int(direction == "+y"), self.brick, self.shift)
        if direction in ("+x", "-x"):  # wall ends: brick ends across the thickness
            return self.masonry(p + thick / 2, q, int(direction == "+x"), thick, (np.arange(self.n_c) % 2) * thick / 2)
        if direction == "+z":  # coping slabs along the top
            j = np.floor(p / 0.3)
            u = p - j * 0.3
            slab = np.float32([0.72, 0.70, 0.64]) * (0.85 + 0.3 * noise.fbm(p * 12, q * 12))[..., None]
            lichen = noise.fbm(p * 4 + 3, q * 4) > 0.62
            slab[lichen] = slab[lichen] * 0.6 + np.float32([0.25, 0.3, 0.1])
            return np.where((np.minimum(u, 0.3 - u) < 0.012)[..., None], GREY * 0.8, slab)
        return np.broadcast_to(GREY * 0.7, p.shape + (3,))

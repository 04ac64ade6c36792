"""Procedurally generated textured example shapes, the package's built-in inputs.

Sin3DM learns from *one* shape, so it can only produce variations of what that
shape repeats: its denoiser sees a local window of the triplane, learns the
statistics of those patches, and recombines them. Good inputs therefore have
local structure that recurs with variation: rock strata and terraces along a
canyon, bricks and merlons along a wall, columns along a colonnade. Each
example here is built from numpy in well under a second, is deterministic for a
seed (another seed gives another variant), and carries a real UV texture whose
detail (thin strata, mortar lines, painted bands) is finer than its triangles.

How the texture is made: every face is assigned to a *chart*, a flat 2D
coordinate system measured in world units (the box projection along the face's
dominant normal axis, or the unrolled angle × height of a turned column). Each
chart gets a rectangle of one texture atlas, and a paint function fills that
rectangle by evaluating the procedural pattern at the world position of every
texel, so the colour on the surface agrees with the geometry (a brick's colour
sits on the brick's bump).
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..errors import Sin3DMInputError
from .mesh import Material, TexturedMesh

#: name -> one-line description of each built-in example.
EXAMPLES = {
    # all examples are y-up, like OBJ and glTF files (Blender turns them z-up on import)
    "canyon": "a river canyon cut into a block: terraced cliffs banded with rock strata, steps varying along its length",
    "wall": "a crenellated brick wall: protruding bricks of varied colour in grey mortar, merlons of varied width",
    "colonnade": "four turned columns with painted rings on a stepped base, carrying a beam with a triglyph frieze",
    "tiles": "a PBR tiled floor: brushed and hammered steel tiles and chipped painted tiles in rough grout "
             "(metallic, roughness and normal maps)",
}

#: The input the quickstart uses.
DEFAULT_EXAMPLE = "canyon"


def list_examples() -> list[str]:
    """Names accepted by :func:`build_example`."""
    return list(EXAMPLES)


def build_example(name: str, seed: int = 0) -> TexturedMesh:
    """Build the example ``name``; ``seed`` picks the variant (same seed, same mesh)."""
    if name not in _BUILDERS:
        raise Sin3DMInputError(f"unknown example '{name}'; choose one of: {', '.join(list_examples())}")
    rng = np.random.default_rng(seed)
    mesh = _BUILDERS[name](rng)  # built z-up
    # y-up, like OBJ and glTF files: (x, y, z) → (x, z, −y), a rotation (faces keep their winding)
    mesh.vertices = np.stack([mesh.vertices[:, 0], mesh.vertices[:, 2], -mesh.vertices[:, 1]], axis=1)
    return mesh


def write_example(name: str, out_dir, seed: int = 0) -> Path:
    """Write ``out_dir/<name>.obj`` (+ ``.mtl`` and ``.png``) for Blender or any viewer; returns the OBJ path."""
    from .export import save_obj

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return save_obj(build_example(name, seed), out_dir / f"{name}.obj")


# =========================================================================== noise
class _Noise:
    """Smooth value noise: random values on a periodic integer lattice, smoothly interpolated."""

    def __init__(self, rng: np.random.Generator, size: int = 256):
        self.table = rng.random((size, size)).astype(np.float32)
        self.size = size

    def __call__(self, p, q=0.0) -> np.ndarray:
        p, q = np.broadcast_arrays(np.asarray(p, np.float32), np.asarray(q, np.float32))
        ip, iq = np.floor(p), np.floor(q)
        fp, fq = _smooth(p - ip), _smooth(q - iq)
        i0, j0 = ip.astype(np.int64) % self.size, iq.astype(np.int64) % self.size
        i1, j1 = (i0 + 1) % self.size, (j0 + 1) % self.size
        t = self.table
        top = t[i0, j0] * (1 - fq) + t[i0, j1] * fq
        bot = t[i1, j0] * (1 - fq) + t[i1, j1] * fq
        return top * (1 - fp) + bot * fp

    def fbm(self, p, q=0.0, octaves: int = 4) -> np.ndarray:
        """Sum of octaves (each twice the frequency, half the amplitude), in [0, 1]."""
        p, q = np.asarray(p, np.float32), np.asarray(q, np.float32)
        out, amp, total = 0.0, 1.0, 0.0
        for k in range(octaves):
            out = out + amp * self(p * 2**k + 17.3 * k, q * 2**k + 31.7 * k)
            total += amp
            amp *= 0.5
        return out / total


def _smooth(t):
    """Smoothstep on [0, 1] (input clipped)."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


# ======================================================================== geometry
def _grid_solid(front: np.ndarray, back: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A closed solid from two ``(n, m, 3)`` point grids joined along their borders.

    The front and back sheets are triangulated cell by cell and a strip of
    quads joins their boundary loops, so every edge is shared by exactly two
    triangles (watertight). A heightfield block is ``front = top``,
    ``back = bottom``; a box is the 2 × 2 case.
    """
    n, m = front.shape[:2]
    idx = np.arange(n * m).reshape(n, m)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tf = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    tb = tf[:, ::-1] + n * m
    loop = np.concatenate([idx[:, 0], idx[-1, 1:], idx[-2::-1, -1], idx[0, -2:0:-1]])
    f0, f1 = loop, np.roll(loop, -1)
    strips = np.concatenate([np.stack([f1, f0, f0 + n * m], 1), np.stack([f1, f0 + n * m, f1 + n * m], 1)])
    vertices = np.concatenate([front.reshape(-1, 3), back.reshape(-1, 3)]).astype(np.float64)
    return vertices, np.concatenate([tf, tb, strips]).astype(np.int64)


def _box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box (12 triangles)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    xy = np.stack(np.meshgrid([x0, x1], [y0, y1], indexing="ij"), -1)
    top = np.concatenate([xy, np.full((2, 2, 1), z1)], -1)
    bottom = np.concatenate([xy, np.full((2, 2, 1), z0)], -1)
    return _grid_solid(top, bottom)


def _revolve(r: np.ndarray, z: np.ndarray, center, n_seg: int, r_ref: float):
    """Closed solid of revolution of the profile ``(r[k], z[k])`` about a vertical axis.

    Returns vertices, faces and per-corner chart coordinates ``(F, 3, 2)``:
    ``p = angle × r_ref`` (unrolled, no seam inside a face) and ``q = z``.
    """
    k_n = len(r)
    th = 2 * np.pi * np.arange(n_seg + 1) / n_seg  # θ_j, with θ_n = 2π for the last segment
    ring = np.stack([center[0] + r[:, None] * np.cos(th[:-1]), center[1] + r[:, None] * np.sin(th[:-1]),
                     np.broadcast_to(z[:, None], (k_n, n_seg))], -1).reshape(-1, 3)
    poles = np.array([[center[0], center[1], z[0]], [center[0], center[1], z[-1]]])
    vertices = np.concatenate([ring, poles])
    bot, top = k_n * n_seg, k_n * n_seg + 1

    k, j = np.meshgrid(np.arange(k_n - 1), np.arange(n_seg), indexing="ij")
    k, j = k.ravel(), j.ravel()
    jn = (j + 1) % n_seg
    a, b, c, d = k * n_seg + j, k * n_seg + jn, (k + 1) * n_seg + jn, (k + 1) * n_seg + j
    # (corner vertex, corner angle index, corner profile index) for each triangle type
    faces = [np.stack([a, b, c], 1), np.stack([a, c, d], 1)]
    th_idx = [np.stack([j, j + 1, j + 1], 1), np.stack([j, j + 1, j], 1)]
    z_idx = [np.stack([k, k, k + 1], 1), np.stack([k, k + 1, k + 1], 1)]
    js = np.arange(n_seg)
    faces += [np.stack([np.full(n_seg, bot), (js + 1) % n_seg, js], 1),
              np.stack([np.full(n_seg, top), (k_n - 1) * n_seg + js, (k_n - 1) * n_seg + (js + 1) % n_seg], 1)]
    th_idx += [np.stack([js + 0.5, js + 1, js], 1), np.stack([js + 0.5, js, js + 1], 1)]
    z_idx += [np.zeros((n_seg, 3), np.int64), np.full((n_seg, 3), k_n - 1)]
    faces = np.concatenate(faces)
    p = np.concatenate(th_idx) * (2 * np.pi / n_seg) * r_ref
    q = z[np.concatenate(z_idx)]
    return vertices, faces.astype(np.int64), np.stack([p, q], -1)


def _signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    t = vertices[faces]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6)


# ==================================================================== UV atlas
_BOX_AXES = {0: (1, 2), 1: (0, 2), 2: (0, 1)}  # projected axis -> the two chart axes (p, q)


class _AtlasBuilder:
    """Collects closed parts, each face tagged with a chart; bakes one texture atlas for all of them."""

    def __init__(self):
        self.vertices, self.faces, self.charts, self.pq = [], [], [], []
        self.n_vertices = 0

    def _append(self, vertices, faces, chart_names, pq):
        if _signed_volume(vertices, faces) < 0:  # make the normals point outwards
            faces, pq = faces[:, ::-1], pq[:, ::-1]
        self.vertices.append(vertices)
        self.faces.append(faces + self.n_vertices)
        self.charts.extend(chart_names)
        self.pq.append(pq)
        self.n_vertices += len(vertices)

    def add_box_projected(self, part: str, vertices, faces, axis=None):
        """Each face goes to chart ``part:+x`` … ``part:-z`` by its dominant normal; (p, q) = the other two axes.

        ``axis`` (``(F,)``, -1 = automatic) forces the projection axis of some
        faces, e.g. every face of a displaced sheet, bumps included, along the
        sheet's normal so that the sheet maps to its chart without overlaps.
        """
        if _signed_volume(vertices, faces) < 0:
            faces = faces[:, ::-1]
        tri = vertices[faces]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        auto = np.abs(normal).argmax(1)
        axis = auto if axis is None else np.where(np.asarray(axis) >= 0, axis, auto)
        sign = np.where(normal[np.arange(len(faces)), axis] >= 0, "+", "-")
        names = [f"{part}:{s}{'xyz'[a]}" for s, a in zip(sign, axis)]
        pq = np.empty((len(faces), 3, 2))
        for a, (ip, iq) in _BOX_AXES.items():
            sel = axis == a
            pq[sel] = tri[sel][:, :, [ip, iq]]
        self._append(vertices, faces, names, pq)

    def add_charted(self, chart: str, vertices, faces, pq):
        """A part whose faces all lie in one chart with the given per-corner (p, q)."""
        self._append(vertices, faces, [chart] * len(faces), pq)

    def build(self, name: str, paint: Callable[[str, np.ndarray, np.ndarray], np.ndarray],
              size: tuple[int, int] = (1024, 1024), pad: int = 4,
              detail: Callable[[str], float] = lambda chart: 1.0, pbr: Callable | None = None) -> TexturedMesh:
        """Pack the charts into a ``size = (height, width)`` image, paint it, assign UVs.

        All charts share one texel size, divided by ``detail(chart)``: give
        hidden faces (the underside of a base) a small value, showpieces a large one.
        ``pbr(chart, p, q) -> (metallic, roughness, normal)`` paints PBR maps over
        the same layout: metallic and roughness ``(h, w)`` in [0, 1], the
        tangent-space unit normal ``(h, w, 3)`` with x along ``p`` and y along
        ``q`` (the chart's ``u`` and ``v`` directions, see ``mesh_io.tangent_frames``).
        """
        height, width = size
        pq = np.concatenate(self.pq)
        charts = np.array(self.charts)
        names = sorted(set(self.charts))
        ranges = {c: (pq[charts == c].reshape(-1, 2).min(0), pq[charts == c].reshape(-1, 2).max(0)) for c in names}
        area = sum(float(np.prod(hi - lo)) * detail(c) ** 2 for c, (lo, hi) in ranges.items())
        texel = np.sqrt(area / (0.8 * width * height))
        while True:  # shelf packing: tallest charts first, rows left to right; grow texels until it fits
            size_of = {c: texel / detail(c) for c in names}
            dims = {c: (np.ceil((hi - lo) / size_of[c]).astype(int) + 2 * pad) for c, (lo, hi) in ranges.items()}
            order = sorted(names, key=lambda c: -dims[c][1])
            place, x, y, row_h = {}, 0, 0, 0
            for c in order:
                w, h = dims[c]
                if x + w > width:
                    x, y, row_h = 0, y + row_h, 0
                place[c] = (x, y)
                x, row_h = x + w, max(row_h, h)
            if y + row_h <= height and all(d[0] <= width for d in dims.values()):
                break
            texel *= 1.05

        image = np.full((height, width, 3), 0.5, np.float32)
        if pbr is not None:  # glTF layout: roughness in G, metallic in B; a flat normal is (0.5, 0.5, 1)
            mr_image = np.tile(np.float32([1, 1, 0]), (height, width, 1))
            normal_image = np.tile(np.float32([0.5, 0.5, 1]), (height, width, 1))
        uv = np.empty_like(pq, dtype=np.float64)
        for c in names:
            (lo, hi), (w, h), (x0, y0), ts = ranges[c], dims[c], place[c], size_of[c]
            p = lo[0] - pad * ts + (np.arange(w) + 0.5) * ts
            q = hi[1] + pad * ts - (np.arange(h) + 0.5) * ts
            P, Q = np.meshgrid(p.astype(np.float32), q.astype(np.float32))
            image[y0:y0 + h, x0:x0 + w] = np.clip(paint(c, P, Q), 0, 1)
            if pbr is not None:
                metal, rough, normal = pbr(c, P, Q)
                mr_image[y0:y0 + h, x0:x0 + w, 1] = np.clip(rough, 0, 1)
                mr_image[y0:y0 + h, x0:x0 + w, 2] = np.clip(metal, 0, 1)
                normal_image[y0:y0 + h, x0:x0 + w] = np.clip(normal * 0.5 + 0.5, 0, 1)
            sel = charts == c
            uv[sel, :, 0] = (x0 + pad + (pq[sel, :, 0] - lo[0]) / ts) / width
            uv[sel, :, 1] = 1 - (y0 + pad + (hi[1] - pq[sel, :, 1]) / ts) / height

        faces = np.concatenate(self.faces)
        material = Material(name=f"{name}_material", base_color=np.array([1, 1, 1, 1], np.float32), image=image)
        if pbr is not None:
            material.metallic, material.roughness = 1.0, 1.0  # the factors that multiply the maps (glTF)
            material.metallic_roughness_image, material.normal_image = mr_image, normal_image
        return TexturedMesh(
            vertices=np.concatenate(self.vertices).astype(np.float64),
            faces=faces.astype(np.int64),
            face_material=np.zeros(len(faces), np.int64),
            materials=[material],
            face_uvs=uv.astype(np.float32),
            name=name,
        )


def _palette(rng, colors, n, jitter=0.08) -> np.ndarray:
    """``n`` colours drawn from ``colors`` with a random brightness jitter each."""
    base = np.asarray(colors, np.float32)[rng.integers(0, len(colors), n)]
    return np.clip(base * rng.uniform(1 - jitter, 1 + jitter, (n, 1)), 0, 1).astype(np.float32)


def _mix(a, b, t):
    """Linear blend of colour arrays; ``t`` broadcasts over the last axis."""
    t = np.asarray(t, np.float32)[..., None]
    return np.asarray(a, np.float32) * (1 - t) + np.asarray(b, np.float32) * t


# ========================================================================= canyon
def _canyon(rng: np.random.Generator) -> TexturedMesh:
    """A river canyon in a 4 × 2 block: terraced cliffs on both banks, strata on every cliff face."""
    length, depth, floor = 4.0, 2.0, 0.3
    noise = _Noise(rng)
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
            rise = step_rise[k] * (0.55 + 0.9 * noise.fbm(x * 0.6 + 40.0 * k, 7.7 + 3.0 * side, octaves=2))  # varies along x
            h = h + rise * _smooth((dist - edge) / 0.05 + 0.5)
        return h + 0.03 * (noise.fbm(x * 5, y * 5) - 0.5)

    # rock strata: layers of random thickness and colour, stacked from the bottom
    tops = np.cumsum(rng.uniform(0.025, 0.13, 80))
    rock = [[0.72, 0.36, 0.22], [0.84, 0.56, 0.34], [0.92, 0.80, 0.60], [0.60, 0.27, 0.17],
            [0.78, 0.46, 0.30], [0.56, 0.42, 0.34], [0.95, 0.88, 0.74], [0.68, 0.52, 0.40]]
    layer_color = _palette(rng, rock, len(tops) + 1)

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
        col = _mix(strata(h, x) * 1.08, sand, 0.25 + 0.3 * noise.fbm(x * 6, y * 6))
        shrub = noise(x * 60.0, y * 60.0) * noise.fbm(x * 3, y * 3 + 9) > 0.45
        col[shrub] = col[shrub] * 0.35 + np.float32([0.18, 0.26, 0.10])
        river = np.clip((floor + 0.05 - h) / 0.04, 0, 1) * _smooth((0.1 - np.abs(y - centre(x))) / 0.04)
        ripple = 0.9 + 0.15 * noise(x * 40, y * 8)
        water = np.float32([0.22, 0.44, 0.46]) * ripple[..., None]
        return _mix(col, water, river)

    nx, ny = 128, 64
    x, y = np.meshgrid(np.linspace(0, length, nx + 1), np.linspace(0, depth, ny + 1), indexing="ij")
    top = np.stack([x, y, height(x, y)], -1)
    bottom = np.stack([x, y, np.zeros_like(x)], -1)
    atlas = _AtlasBuilder()
    atlas.add_box_projected("rock", *_grid_solid(top, bottom))
    return atlas.build("canyon", paint, size=(1024, 1024), detail=lambda c: 0.1 if c.endswith("-z") else 1.0)


# =========================================================================== wall
def _wall(rng: np.random.Generator) -> TexturedMesh:
    """A 4 m brick wall, 0.6 m thick: five courses of protruding bricks, merlons of varied width on top."""
    length, thick = 4.0, 0.6
    course, brick, mortar, bevel = 0.25, 0.6, 0.035, 0.035
    n_body = 5
    body_h = n_body * course
    noise = _Noise(rng)
    n_c, n_b = 8, 10  # table sizes: courses, bricks per course
    shift = rng.uniform(0, brick, n_c)  # each course's running-bond offset
    protrude = rng.uniform(0.02, 0.05, (2, n_c, n_b))  # (side, course, brick)
    protrude[rng.random(protrude.shape) < 0.12] += 0.05  # a few bricks stick out
    bricks = [[0.62, 0.25, 0.18], [0.70, 0.33, 0.22], [0.55, 0.22, 0.17], [0.76, 0.43, 0.30],
              [0.46, 0.20, 0.16], [0.66, 0.37, 0.27], [0.58, 0.30, 0.25]]
    brick_color = _palette(rng, bricks, 2 * n_c * n_b, jitter=0.12).reshape(2, n_c, n_b, 3)
    grey = np.float32([0.66, 0.64, 0.60])

    def cell(x, z, width, offset):
        """Which brick (course, index) a face point is in and its distance to the mortar (negative in mortar)."""
        c = np.clip(np.floor(z / course).astype(np.int64), 0, n_c - 1)
        xs = x + offset[c]
        j = np.floor(xs / width).astype(np.int64)
        u, v = xs - j * width, z - c * course
        dist = np.minimum(np.minimum(u, width - u), np.minimum(v, course - v)) - mortar / 2
        return c, j % n_b, dist

    def bump(x, z, side):
        c, j, dist = cell(x, z, brick, shift)
        return protrude[side, c, j] * _smooth(dist / bevel)

    def masonry(x, z, side, width, offset):
        c, j, dist = cell(x, z, width, offset)
        col = brick_color[side, c, j] * (0.8 + 0.35 * noise.fbm(x * 30 + 7 * side, z * 30, octaves=3))[..., None]
        col = col * (0.75 + 0.25 * _smooth(dist / 0.03))[..., None]  # darker towards the edges
        mortar_col = grey * (0.85 + 0.25 * noise(x * 80, z * 80))[..., None]
        return np.where((dist < 0)[..., None], mortar_col, col)

    def paint(chart, p, q):
        direction = chart.split(":")[1]
        if direction in ("+y", "-y"):  # front / back faces: (p, q) = (x, z)
            return masonry(p, q, int(direction == "+y"), brick, shift)
        if direction in ("+x", "-x"):  # wall ends: brick ends across the thickness
            return masonry(p + thick / 2, q, int(direction == "+x"), thick, (np.arange(n_c) % 2) * thick / 2)
        if direction == "+z":  # coping slabs along the top
            j = np.floor(p / 0.3)
            u = p - j * 0.3
            slab = np.float32([0.72, 0.70, 0.64]) * (0.85 + 0.3 * noise.fbm(p * 12, q * 12))[..., None]
            lichen = noise.fbm(p * 4 + 3, q * 4) > 0.62
            slab[lichen] = slab[lichen] * 0.6 + np.float32([0.25, 0.3, 0.1])
            return np.where((np.minimum(u, 0.3 - u) < 0.012)[..., None], grey * 0.8, slab)
        return np.broadcast_to(grey * 0.7, p.shape + (3,))

    def z_nodes(z0, n_courses):
        """Rows of the surface grid: dense at every mortar joint and bevel, sparse across the brick face."""
        inner = [0.0, mortar / 2, mortar / 2 + bevel / 2, mortar / 2 + bevel, course / 2,
                 course - mortar / 2 - bevel, course - mortar / 2 - bevel / 2, course - mortar / 2]
        return np.array([z0 + k * course + t for k in range(n_courses) for t in inner] + [z0 + n_courses * course])

    def slab(x0, x1, z0, n_courses):
        x = np.linspace(x0, x1, int(np.ceil((x1 - x0) / 0.025)) + 1)
        X, Z = np.meshgrid(x, z_nodes(z0, n_courses), indexing="ij")
        front = np.stack([X, -thick / 2 - bump(X, Z, 0), Z], -1)
        back = np.stack([X, thick / 2 + bump(X, Z, 1), Z], -1)
        vertices, faces = _grid_solid(front, back)
        axis = np.full(len(faces), -1)
        axis[: 4 * (X.shape[0] - 1) * (X.shape[1] - 1)] = 1  # the two brick sheets (bevels too) project along y
        return vertices, faces, axis

    atlas = _AtlasBuilder()
    atlas.add_box_projected("body", *slab(0.0, length, 0.0, n_body))
    # merlons: widths and gaps drawn at random, then scaled to span the wall end to end
    widths, gaps = rng.uniform(0.5, 0.8, 5), rng.uniform(0.3, 0.5, 4)
    scale = length / (widths.sum() + gaps.sum())
    x = 0.0
    for i, w in enumerate(widths):
        n_courses = 2 if rng.random() > 0.2 else 1  # now and then a broken-down merlon
        atlas.add_box_projected(f"merlon{i}", *slab(x, x + w * scale, body_h, n_courses))
        x += (w + (gaps[i] if i < len(gaps) else 0)) * scale
    return atlas.build("wall", paint, size=(1024, 1024), detail=lambda c: 0.1 if c.endswith("-z") else 1.0)


# ====================================================================== colonnade
def _colonnade(rng: np.random.Generator) -> TexturedMesh:
    """Four columns on a two-step base carrying a beam; each column has its own rings and colours."""
    n_col, spacing = 4, 1.2
    half = n_col * spacing / 2 + 0.3
    step_h, plinth_h, abacus_h, beam_h, cornice_h = 0.25, 0.12, 0.14, 0.45, 0.14
    shaft_h = 2.2
    noise = _Noise(rng)
    paints = [[0.70, 0.22, 0.16], [0.16, 0.28, 0.58], [0.82, 0.62, 0.18], [0.20, 0.46, 0.32], [0.55, 0.20, 0.40]]
    stone = np.float32([0.86, 0.80, 0.68])
    marble = np.float32([0.93, 0.91, 0.86])

    def stone_blocks(p, q, w, h, base=stone, offset=0.0):
        """Ashlar: blocks of ``w × h`` with thin dark joints and a grainy surface."""
        row = np.floor(q / h)
        pp = p + offset * (row % 2)
        u, v = pp - np.floor(pp / w) * w, q - row * h
        col = base * (0.85 + 0.25 * noise.fbm(p * 8 + row, q * 8, octaves=3))[..., None]
        joint = np.minimum(np.minimum(u, w - u), np.minimum(v, h - v)) < 0.012
        return np.where(joint[..., None], base * 0.55, col)

    columns = []
    z_base = 2 * step_h
    atlas = _AtlasBuilder()
    atlas.add_box_projected("step0", *_box((-half, -0.8, 0), (half, 0.8, step_h)))
    atlas.add_box_projected("step1", *_box((-half + 0.15, -0.65, step_h), (half - 0.15, 0.65, z_base)))
    for i in range(n_col):
        cx = (i - (n_col - 1) / 2) * spacing
        z0 = z_base + plinth_h
        rings = np.sort(rng.choice(np.arange(0.2, 0.8, 0.12), rng.integers(1, 4), replace=False)) * shaft_h
        spec = dict(
            rings=rings, ring_colors=_palette(rng, paints, len(rings)), flare=rng.uniform(0.30, 0.36),
            flutes=int(rng.choice([12, 16, 20])), band=_palette(rng, paints, 2), z0=z0,
        )
        columns.append(spec)
        # profile r(z): torus base, tapering shaft with raised rings, neck, flared capital (echinus)
        t = np.linspace(0, shaft_h, int(shaft_h / 0.025) + 1)
        r = 0.24 - 0.035 * (t / shaft_h) ** 2
        r = r + 0.06 * np.sqrt(np.clip(1 - ((t - 0.07) / 0.07) ** 2, 0, 1))  # base torus
        for zr in rings:
            r = r + 0.06 * np.sin(np.pi * np.clip((t - zr) / 0.16, 0, 1))
        ech = np.clip((t - (shaft_h - 0.2)) / 0.2, 0, 1)
        r = r + (spec["flare"] - 0.205) * np.sin(ech * np.pi / 2) ** 1.5
        atlas.add_box_projected(f"col{i}.plinth", *_box((cx - 0.32, -0.32, z_base), (cx + 0.32, 0.32, z0)))
        atlas.add_charted(f"col{i}.shaft", *_revolve(r, z0 + t, (cx, 0.0), 32, 0.24))
        z1 = z0 + shaft_h
        atlas.add_box_projected(f"col{i}.abacus", *_box((cx - 0.38, -0.38, z1), (cx + 0.38, 0.38, z1 + abacus_h)))
    z_beam = z_base + plinth_h + shaft_h + abacus_h
    atlas.add_box_projected("beam", *_box((-half + 0.15, -0.45, z_beam), (half - 0.15, 0.45, z_beam + beam_h)))
    z_cornice = z_beam + beam_h
    atlas.add_box_projected("cornice", *_box((-half + 0.05, -0.55, z_cornice), (half - 0.05, 0.55, z_cornice + cornice_h)))
    triglyph = rng.uniform(0.25, 0.55, 3) * np.float32([0.4, 0.6, 1.0])  # frieze colours
    metope = _palette(rng, paints, 1)[0]

    def shaft(spec, p, q):
        theta, z = p / 0.24, q - spec["z0"]
        veins = np.abs(np.sin(6 * noise.fbm(p * 2.5, q * 1.2) * np.pi + p * 3)) < 0.06
        col = marble * (0.9 + 0.12 * np.cos(spec["flutes"] * theta))[..., None]  # painted flutes
        col[veins] *= np.float32([0.72, 0.72, 0.76])
        for zr, rc in zip(spec["rings"], spec["ring_colors"]):
            inside = (z > zr) & (z < zr + 0.16)
            chevron = ((theta * 8 / np.pi + 10 * np.abs(z - zr - 0.08)) % 2) < 1
            col[inside] = np.where(chevron[inside][:, None], rc, rc * 0.55 + 0.4)
        base = z < 0.14
        cap = z > shaft_h - 0.2
        eggs = np.cos(12 * theta) * np.sin(np.pi * np.clip((z - shaft_h + 0.2) / 0.2, 0, 1)) > 0.35
        col[base] = spec["band"][0] * (0.8 + 0.3 * noise(p[base] * 30, q[base] * 30))[:, None]
        col[cap] = np.where(eggs[cap][:, None], spec["band"][1], np.float32([0.85, 0.68, 0.25]))
        neck = (z > shaft_h - 0.26) & (z <= shaft_h - 0.2)
        col[neck] = spec["band"][1] * 0.8
        return col

    def frieze(p, q):
        """Front and back of the beam: plain architrave below, triglyphs and painted metopes above."""
        z = q - z_beam
        col = stone_blocks(p, q, 1.2, beam_h * 0.45)
        upper = z > beam_h * 0.45
        u = (p + spacing / 4) % (spacing / 2) / (spacing / 2)  # two panels per column spacing
        is_tri = (u < 0.4) & upper
        grooves = ((u * 10).astype(int) % 3 == 1) & is_tri
        col[is_tri] = triglyph
        col[grooves] = triglyph * 0.5
        is_met = upper & ~is_tri
        disc = ((u - 0.7) * spacing / 2) ** 2 + (z - beam_h * 0.72) ** 2 < 0.07**2
        col[is_met] = metope * (0.85 + 0.2 * noise(p[is_met] * 20, q[is_met] * 20))[:, None]
        col[is_met & disc] = np.float32([0.95, 0.92, 0.8])
        col[np.abs(z - beam_h * 0.45) < 0.015] = stone * 0.5
        return col

    def paint(chart, p, q):
        part, direction = chart.split(":") if ":" in chart else (chart, "")
        if part.startswith("col") and part.endswith(".shaft"):
            return shaft(columns[int(part[3:].split(".")[0])], p, q)
        if part.startswith("col"):  # plinth and abacus: dark stone, sides with a painted band
            spec = columns[int(part[3:].split(".")[0])]
            col = stone_blocks(p, q, 2.0, 2.0, base=np.float32([0.55, 0.5, 0.45]))
            if direction[1] in "xy":
                if part.endswith("plinth"):  # a wave line on a coloured band
                    mid = z_base + plinth_h / 2
                    col[np.abs(q - mid) < 0.035] = spec["band"][0]
                    col[np.abs(q - mid - 0.02 * np.sin(p * 40)) < 0.007] = np.float32([0.95, 0.92, 0.85])
                else:  # abacus: gold dots on a coloured band
                    mid = spec["z0"] + shaft_h + abacus_h / 2
                    col[np.abs(q - mid) < 0.045] = spec["band"][1]
                    dot = ((p % 0.1) - 0.05) ** 2 + (q - mid) ** 2 < 0.022**2
                    col[dot] = np.float32([0.9, 0.72, 0.25])
            return col
        if part == "beam" and direction in ("+y", "-y", "+x", "-x"):
            return frieze(p, q)
        if part == "cornice" and direction in ("+y", "-y", "+x", "-x"):
            dentil = ((p * 10) % 1 < 0.5) & ((q - z_cornice) < cornice_h * 0.5)
            col = stone_blocks(p, q, 3.0, 3.0)
            col[dentil] *= 0.6
            return col
        if direction == "+z":  # floor tiles of the steps, roof slabs
            return stone_blocks(p, q, 0.4, 0.4, offset=0.2)
        return stone_blocks(p, q, 0.8, step_h, offset=0.4)  # sides of the steps, undersides

    hidden = ("step0:-z", "step1:-z", "beam:+z", "plinth:-z", "abacus:+z")

    def detail(chart):
        return 0.1 if chart.endswith(hidden) else 1.6 if chart.endswith("shaft") else 1.0

    return atlas.build("colonnade", paint, size=(1024, 1024), detail=detail)


# ========================================================================== tiles
def _tiles(rng: np.random.Generator) -> TexturedMesh:
    """A 3.2 × 2 m floor slab, 0.45 m thick, of 0.4 m tiles: steel tiles and chipped painted ones (PBR).

    What each map shows, all varying with the tile pattern:

    * base colour: steel grey; paint from a palette, chipped where noise says so (steel shows through);
      dark grout;
    * metallic: 1 on steel and on the chips, 0 on paint and grout;
    * roughness: low on steel (brushed tiles 0.2-0.35, hammered ones 0.35-0.5), 0.55-0.75 on paint, 0.95 grout;
    * normal (tangent space): brushing grooves or hammer dimples on steel tiles, the raised edge of
      the paint around each chip. The tiles' bevels are geometry, not map.
    """
    size_x, size_y, thick = 3.2, 2.0, 0.45
    tile, grout, bevel = 0.4, 0.03, 0.03
    noise = _Noise(rng)
    nx, ny = int(round(size_x / tile)), int(round(size_y / tile))
    kind = rng.choice(3, size=(nx, ny), p=[0.3, 0.2, 0.5])  # 0 brushed steel, 1 hammered steel, 2 painted
    raise_ = rng.uniform(0.03, 0.05, (nx, ny))
    paints = [[0.72, 0.18, 0.14], [0.16, 0.38, 0.62], [0.85, 0.68, 0.20], [0.20, 0.48, 0.30], [0.88, 0.86, 0.80]]
    paint_col = _palette(rng, paints, nx * ny, jitter=0.1).reshape(nx, ny, 3)
    roughness = np.where(kind == 0, rng.uniform(0.2, 0.35, (nx, ny)),
                         np.where(kind == 1, rng.uniform(0.35, 0.5, (nx, ny)), rng.uniform(0.55, 0.75, (nx, ny))))
    brush_angle = rng.uniform(0, np.pi, (nx, ny))
    steel = np.float32([0.70, 0.71, 0.73])

    def cell(x, y):
        """Tile index and distance to the grout (negative in the grout)."""
        i = np.clip(np.floor(x / tile).astype(np.int64), 0, nx - 1)
        j = np.clip(np.floor(y / tile).astype(np.int64), 0, ny - 1)
        u, v = x - i * tile, y - j * tile
        return i, j, np.minimum(np.minimum(u, tile - u), np.minimum(v, tile - v)) - grout / 2

    def chips(x, y):
        """How much paint is left in [0, 1] (0: chipped down to the steel)."""
        return _smooth((0.6 - noise.fbm(x * 6 + 40, y * 6, octaves=4)) / 0.03)

    def fine_height(x, y, i, j):
        """Detail the normal map carries (metres): brushing, dimples, paint thickness."""
        a = brush_angle[i, j]
        brushed = 0.0015 * noise(80 * (x * np.cos(a) + y * np.sin(a)), 2 * (y * np.cos(a) - x * np.sin(a)))
        dimples = 0.004 * np.abs(np.sin(x * 45 + j) * np.sin(y * 45 + i)) * (0.5 + noise(x * 20, y * 20))
        painted = 0.002 * (1 - chips(x, y))
        return np.where(kind[i, j] == 0, brushed, np.where(kind[i, j] == 1, dimples, -painted))

    def paint(chart, p, q):
        if chart.split(":")[1] != "+z":  # sides and bottom: concrete
            return np.float32([0.5, 0.49, 0.46]) * (0.85 + 0.3 * noise.fbm(p * 10, q * 10 + 9))[..., None]
        i, j, dist = cell(p, q)
        grime = (0.85 + 0.25 * noise.fbm(p * 25, q * 25, octaves=3))[..., None]
        metal = steel * (0.9 + 0.15 * noise(p * 60, q * 60))[..., None]
        painted = _mix(metal, paint_col[i, j], chips(p, q)) * grime
        col = np.where((kind[i, j] == 2)[..., None], painted, metal)
        return np.where((dist < 0)[..., None], np.float32([0.24, 0.23, 0.22]) * grime, col)

    def pbr(chart, p, q):
        if chart.split(":")[1] != "+z":
            flat = np.zeros(p.shape + (3,), np.float32)
            flat[..., 2] = 1
            return np.zeros(p.shape, np.float32), np.full(p.shape, 0.9, np.float32), flat
        i, j, dist = cell(p, q)
        left = np.where(kind[i, j] == 2, chips(p, q), 0.0)  # paint left
        metal = np.where(dist < 0, 0.0, 1 - left)
        rough = np.where(dist < 0, 0.95, np.where(kind[i, j] == 2, left * roughness[i, j] + (1 - left) * 0.3,
                                                  roughness[i, j]))
        h = np.where(dist < 0, 0.0, fine_height(p, q, i, j))
        dh_dq, dh_dp = np.gradient(h, q[:, 0], p[0, :])  # rows follow q, columns p
        normal = np.stack([-dh_dp, -dh_dq, np.ones_like(h)], -1)
        return metal, rough, normal / np.linalg.norm(normal, axis=-1, keepdims=True)

    def nodes(n_tiles):
        """Grid lines dense at every grout joint and bevel, sparse across the tile."""
        inner = [0.0, grout / 2, grout / 2 + bevel / 2, grout / 2 + bevel, tile / 4, tile / 2, 3 * tile / 4,
                 tile - grout / 2 - bevel, tile - grout / 2 - bevel / 2, tile - grout / 2]
        return np.array([k * tile + t for k in range(n_tiles) for t in inner] + [n_tiles * tile])

    X, Y = np.meshgrid(nodes(nx), nodes(ny), indexing="ij")
    i, j, dist = cell(X, Y)
    top = np.stack([X, Y, thick - 0.05 + raise_[i, j] * _smooth(dist / bevel)], -1)
    bottom = np.stack([X, Y, np.zeros_like(X)], -1)
    vertices, faces = _grid_solid(top, bottom)
    axis = np.full(len(faces), -1)
    axis[: 2 * (X.shape[0] - 1) * (X.shape[1] - 1)] = 2  # the tiled sheet (bevels too) projects along z
    atlas = _AtlasBuilder()
    atlas.add_box_projected("floor", vertices, faces, axis=axis)
    return atlas.build("tiles", paint, size=(1024, 1024), pbr=pbr, detail=lambda c: 1.0 if c.endswith("+z") else 0.15)


_BUILDERS: dict[str, Callable[[np.random.Generator], TexturedMesh]] = {
    "canyon": _canyon,
    "wall": _wall,
    "colonnade": _colonnade,
    "tiles": _tiles,
}

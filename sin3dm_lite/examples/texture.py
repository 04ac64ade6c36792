"""Painting the example shapes: value noise, colour helpers and the UV atlas every example is baked into.

Every face belongs to a *chart*, flat 2D coordinates in world units (the box projection along the face's
dominant normal axis, or a turned column's unrolled angle × height). Each chart gets a rectangle of one
atlas (:class:`AtlasBuilder`), painted by evaluating the pattern at every texel's world position, so the
colour agrees with the geometry (a brick's colour sits on the brick's bump).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..data.mesh import Material, TexturedMesh
from .geometry import signed_volume


class Noise:
    """Smooth value noise: random values on a periodic integer lattice, smoothly interpolated."""

    def __init__(self, rng: np.random.Generator, size: int = 256):
        self.table = rng.random((size, size)).astype(np.float32)
        self.size = size

    def __call__(self, p, q=0.0) -> np.ndarray:
        p, q = np.broadcast_arrays(np.asarray(p, np.float32), np.asarray(q, np.float32))
        ip, iq = np.floor(p), np.floor(q)
        fp, fq = smooth(p - ip), smooth(q - iq)
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


def smooth(t):
    """Smoothstep on [0, 1] (input clipped)."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def palette(rng, colors, n, jitter=0.08) -> np.ndarray:
    """``n`` colours drawn from ``colors`` with a random brightness jitter each."""
    base = np.asarray(colors, np.float32)[rng.integers(0, len(colors), n)]
    return np.clip(base * rng.uniform(1 - jitter, 1 + jitter, (n, 1)), 0, 1).astype(np.float32)


def mix(a, b, t):
    """Linear blend of colour arrays; ``t`` broadcasts over the last axis."""
    t = np.asarray(t, np.float32)[..., None]
    return np.asarray(a, np.float32) * (1 - t) + np.asarray(b, np.float32) * t


_BOX_AXES = {0: (1, 2), 1: (0, 2), 2: (0, 1)}  # projected axis -> the two chart axes (p, q)


class AtlasBuilder:
    """Collects closed parts, each face tagged with a chart; bakes one texture atlas for all of them."""

    def __init__(self):
        self.vertices, self.faces, self.charts, self.pq = [], [], [], []
        self.n_vertices = 0

    def _append(self, vertices, faces, chart_names, pq):
        if signed_volume(vertices, faces) < 0:  # make the normals point outwards
            faces, pq = faces[:, ::-1], pq[:, ::-1]
        self.vertices.append(vertices)
        self.faces.append(faces + self.n_vertices)
        self.charts.extend(chart_names)
        self.pq.append(pq)
        self.n_vertices += len(vertices)

    def add_box_projected(self, part: str, vertices, faces, axis=None):
        """Each face goes to chart ``part:+x`` … ``part:-z`` by its dominant normal; (p, q) = the other two axes.

        ``axis`` (``(F,)``, -1 = automatic) forces the projection axis of some faces, e.g. a displaced sheet's
        along its normal, bumps included, so that the sheet maps to its chart without overlaps.
        """
        if signed_volume(vertices, faces) < 0:
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

    def build(
        self,
        name: str,
        paint: Callable[[str, np.ndarray, np.ndarray], np.ndarray],
        size: tuple[int, int] = (1024, 1024),
        pad: int = 4,
        detail: Callable[[str], float] = lambda chart: 1.0,
        pbr: Callable | None = None,
    ) -> TexturedMesh:
        """Pack the charts into a ``size = (height, width)`` image, paint it, assign UVs.

        All charts share one texel size, divided by ``detail(chart)`` (small for hidden faces, large for
        showpieces). ``pbr(chart, p, q) -> (metallic, roughness, normal)`` paints PBR maps over the same
        layout: metallic and roughness ``(h, w)`` in [0, 1], the tangent-space unit normal ``(h, w, 3)`` with
        x along ``p`` and y along ``q`` (the chart's ``u`` and ``v`` directions).
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
            image[y0 : y0 + h, x0 : x0 + w] = np.clip(paint(c, P, Q), 0, 1)
            if pbr is not None:
                metal, rough, normal = pbr(c, P, Q)
                mr_image[y0 : y0 + h, x0 : x0 + w, 1] = np.clip(rough, 0, 1)
                mr_image[y0 : y0 + h, x0 : x0 + w, 2] = np.clip(metal, 0, 1)
                normal_image[y0 : y0 + h, x0 : x0 + w] = np.clip(normal * 0.5 + 0.5, 0, 1)
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

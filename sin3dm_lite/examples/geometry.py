"""The solids the example shapes are made of: closed point-grid sheets, boxes, solids of revolution.

Every part is closed (each edge shared by two triangles), so a winding number tells inside from outside.
"""

from __future__ import annotations

import numpy as np


def grid_solid(front: np.ndarray, back: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A closed solid from two ``(n, m, 3)`` point grids joined along their borders.

    Both sheets are triangulated cell by cell and a strip of quads joins their boundary loops (watertight).
    A heightfield block is ``front = top``, ``back = bottom``; a box is the 2 × 2 case.
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


def joint_nodes(start: float, period: float, n: int, joint: float, bevel: float, middle: list[float]) -> np.ndarray:
    """Grid lines over ``n`` periods from ``start``: dense at every joint and its bevels, ``middle`` across the face."""
    j = joint / 2
    inner = [0.0, j, j + bevel / 2, j + bevel, *middle, period - j - bevel, period - j - bevel / 2, period - j]
    return np.array([start + k * period + t for k in range(n) for t in inner] + [start + n * period])


def box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box (12 triangles)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    xy = np.stack(np.meshgrid([x0, x1], [y0, y1], indexing="ij"), -1)
    top = np.concatenate([xy, np.full((2, 2, 1), z1)], -1)
    bottom = np.concatenate([xy, np.full((2, 2, 1), z0)], -1)
    return grid_solid(top, bottom)


def revolve(r: np.ndarray, z: np.ndarray, center, n_seg: int, r_ref: float):
    """Closed solid of revolution of the profile ``(r[k], z[k])`` about a vertical axis.

    Returns vertices, faces and per-corner chart coordinates ``(F, 3, 2)``:
    ``p = angle × r_ref`` (unrolled, no seam inside a face) and ``q = z``.
    """
    k_n = len(r)
    th = 2 * np.pi * np.arange(n_seg + 1) / n_seg  # θ_j, with θ_n = 2π for the last segment
    ring = np.stack(
        [
            center[0] + r[:, None] * np.cos(th[:-1]),
            center[1] + r[:, None] * np.sin(th[:-1]),
            np.broadcast_to(z[:, None], (k_n, n_seg)),
        ],
        -1,
    ).reshape(-1, 3)
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
    faces += [
        np.stack([np.full(n_seg, bot), (js + 1) % n_seg, js], 1),
        np.stack([np.full(n_seg, top), (k_n - 1) * n_seg + js, (k_n - 1) * n_seg + (js + 1) % n_seg], 1),
    ]
    th_idx += [np.stack([js + 0.5, js + 1, js], 1), np.stack([js + 0.5, js, js + 1], 1)]
    z_idx += [np.zeros((n_seg, 3), np.int64), np.full((n_seg, 3), k_n - 1)]
    faces = np.concatenate(faces)
    p = np.concatenate(th_idx) * (2 * np.pi / n_seg) * r_ref
    q = z[np.concatenate(z_idx)]
    return vertices, faces.astype(np.int64), np.stack([p, q], -1)


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    t = vertices[faces]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6)


def y_up(vertices: np.ndarray) -> np.ndarray:
    """z-up vertices turned y-up, like OBJ and glTF: (x, y, z) → (x, z, −y), a rotation (faces keep their winding)."""
    return np.stack([vertices[:, 0], vertices[:, 2], -vertices[:, 1]], axis=1)

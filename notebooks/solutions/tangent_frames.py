"""Exercise (notebook 08): each face's tangent frame (T, B, N) for tangent-space normal maps."""

import numpy as np


def tangent_frames(vertices, faces, face_uvs):
    """``vertices (V, 3)``, ``faces (F, 3)``, ``face_uvs (F, 3, 2)`` → T, B, N, each ``(F, 3)`` unit vectors."""
    tri = vertices[faces]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.cross(e1, e2)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d1, d2 = face_uvs[:, 1] - face_uvs[:, 0], face_uvs[:, 2] - face_uvs[:, 0]  # (du, dv) along e1 and e2
    det = (d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1])[:, None]
    t = (e1 * d2[:, 1:] - e2 * d1[:, 1:]) / det  # where u grows
    v = (e2 * d1[:, :1] - e1 * d2[:, :1]) / det  # where v grows
    t -= np.sum(t * n, axis=1, keepdims=True) * n  # perpendicular to N (Gram-Schmidt)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(n, t)
    b[np.sum(b * v, axis=1) < 0] *= -1  # a mirrored UV triangle: v grows the other way
    return t, b, n

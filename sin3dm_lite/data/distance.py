"""Distance to a mesh and inside / outside, the two questions the grid asks at every voxel.

:class:`Distance` answers them for one mesh: exact unsigned point-to-triangle
distances (with the closest face and its barycentrics, where the grid reads
the surface colour) and the generalised winding number, which tells inside
from outside even for open or multi-part meshes. Closed parts that are
inside out are turned round first (:func:`_orient_outward`).
The metrics ask it of the input mesh at every sub-voxel of an open mesh
(:func:`sin3dm_lite.evaluate.geometry.input_occupancy`).
"""

from __future__ import annotations

import numpy as np
import point_cloud_utils as pcu

from .mesh import TexturedMesh, component_labels, unique_rows


class Distance:
    """Truncated signed distance to a mesh, computed only where it matters.

    Exact point-to-triangle distances are the expensive part, and far from the
    surface the TSDF is just ``±threshold``. The sign comes from
    point-cloud-utils' fast winding number (inside where it exceeds ½), which
    is robust for open or multi-part meshes, where "make it watertight" tricks
    fail. (pcu's ``signed_distance_to_mesh`` is not used: its distances are
    approximate, and far off on open meshes.)
    """

    def __init__(self, mesh: TexturedMesh, chunk: int = 1 << 20):
        self.v = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
        faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
        self.f, self.closed, self.flipped, self.closed_parts = _orient_outward(self.v, faces)
        self.chunk = chunk

    def winding(self, p: np.ndarray) -> np.ndarray:
        """Generalised winding number: 1 inside a closed surface, 0 outside, in between near holes."""
        if len(p) == 0:
            return np.zeros(0, np.float64)
        return pcu.triangle_soup_fast_winding_number(self.v, self.f, np.ascontiguousarray(p, dtype=np.float64))

    def closest(self, p: np.ndarray):
        """Unsigned distance, closest face and its barycentrics for every point (chunked)."""
        p = np.ascontiguousarray(p, dtype=np.float64)
        d = np.empty(len(p), np.float64)
        fi = np.empty(len(p), np.int64)
        bc = np.empty((len(p), 3), np.float64)
        for a in range(0, len(p), self.chunk):
            d[a : a + self.chunk], fi[a : a + self.chunk], bc[a : a + self.chunk] = pcu.closest_points_on_mesh(
                p[a : a + self.chunk], self.v, self.f
            )
        return d, fi, bc


def _orient_outward(vertices: np.ndarray, faces: np.ndarray):
    """Turn closed parts that are inside out (faces wound clockwise seen from outside) the right way round.

    The winding number is +1 inside a surface whose faces wind
    counter-clockwise seen from outside (outward normals) and -1 inside one
    wound the other way, so an inside-out file would come out with no inside
    at all. Each connected part (vertices joined by position) that is closed
    (every edge used as often in one direction as in the other, as in a
    watertight, consistently wound surface) and encloses a negative volume
    gets its faces flipped; open parts are left alone (their volume has no
    reliable sign). On a closed mesh the winding number is a whole number
    that changes only across the surface.

    Returns ``(faces, closed, flipped, closed_parts)``: the faces, whether the
    whole mesh is closed, how many parts were flipped and how many are closed.
    """
    _, weld = unique_rows(vertices)  # vertices split at UV seams are one point here
    fw = weld[faces]
    n = int(fw.max()) + 1
    part = component_labels(n, fw)  # (F,) the part of every face
    parts = int(part.max()) + 1
    edges = fw[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    # a closed, consistently wound surface uses every edge as often a → b as b → a
    key = np.minimum(edges[:, 0], edges[:, 1]) * n + np.maximum(edges[:, 0], edges[:, 1])
    _, inverse = np.unique(key, return_inverse=True)
    balance = np.bincount(inverse.reshape(-1), np.where(edges[:, 0] < edges[:, 1], 1.0, -1.0))
    open_edge = balance[inverse.reshape(-1)] != 0  # (3F,)
    open_part = np.bincount(part.repeat(3)[open_edge], minlength=parts) > 0
    tri = vertices[faces]  # a closed part's enclosed volume (× 6) does not depend on the origin
    volume = np.bincount(part, np.einsum("fi,fi->f", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])), parts)
    has_faces = np.bincount(part, minlength=parts) > 0  # (labels of vertices without faces are skipped)
    closed = has_faces & ~open_part
    flip = closed & (volume < 0)
    faces = np.where(flip[part][:, None], faces[:, ::-1], faces)
    return np.ascontiguousarray(faces), not open_part.any(), int(flip.sum()), int(closed.sum())

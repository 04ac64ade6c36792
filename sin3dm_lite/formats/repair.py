"""What a mesh file gets wrong that the grid cannot see past: the same surface listed twice.

A *two-sided* export lists every face again wound the other way round. The two listings cancel in the generalised
winding number that tells the grid inside from outside, so the shape would lose its inside (a slab of a tower, or
nothing). :func:`first_listing` keeps each triangle once; the loader applies it to every file
(:func:`~sin3dm_lite.formats.common.assemble`), :func:`listed_once` to a ``TexturedMesh`` built in Python (the grid
and the metrics' input occupancy call it).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..data.mesh import TexturedMesh, component_labels, unique_rows

#: the cosine of the largest fold between a quad's two triangles: a bent quad listed back along its other diagonal
#: makes a thin tetrahedron with its first listing (a rough terrain's quads fold by 10-30°); a box's corner or a
#: tetrahedron-shaped part (folds of 70° and more) is not a quad listed twice
FOLD_COS = 0.7071  # 45°


def listed_once(mesh: TexturedMesh) -> TexturedMesh:
    """``mesh`` with each triangle listed once (:func:`first_listing`), as the loader reads a file."""
    keep = first_listing(mesh.vertices, mesh.faces)
    if len(keep) == len(mesh.faces):
        return mesh
    uvs = None if mesh.face_uvs is None else mesh.face_uvs[keep]
    return replace(mesh, faces=mesh.faces[keep], face_material=mesh.face_material[keep], face_uvs=uvs)


def first_listing(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The faces to keep, in file order: a triangle listed again (corners joined by position alone, so a repeat with
    other colours or UVs is a repeat too) is kept once where it is wound alike, or where most of its part is listed
    twice (a two-sided export, whose pairs would cancel in the winding number and leave no inside). A flat quad
    listed again the other way round and cut along its other diagonal (:func:`_reversed_quads`: a PLY or OFF file of
    quads, which trimesh cuts from each quad's first corner) is a repeat wound against its first listing too.
    Elsewhere a pair wound against each other is two solids' shared wall and both stay: they cancel, as a wall
    inside a solid should."""
    if len(faces) == 0:
        return np.arange(0)
    where, at = unique_rows(vertices)  # corners joined by position: `tri` numbers the distinct positions
    tri = at[faces]
    first, group = unique_rows(np.sort(tri, axis=1))
    odd = ((tri[:, 0] > tri[:, 1]).astype(np.int64) + (tri[:, 0] > tri[:, 2]) + (tri[:, 1] > tri[:, 2])) % 2
    keep = np.zeros(len(faces), bool)
    keep[first] = True
    against = ~keep & (odd != odd[first[group]])  # a later listing wound against the first
    twinned = np.zeros(len(faces), bool)
    twinned[against] = twinned[first[group[against]]] = True
    later, earlier = _reversed_quads(
        np.asarray(vertices, np.float64)[where], tri, _on_doubled_edges(tri, keep & ~twinned)
    )
    against[later] = twinned[later] = twinned[earlier] = True
    keep[later] = False
    if against.any():
        part = component_labels(int(tri.max()) + 1, tri)
        keep |= against & (np.bincount(part, twinned) <= np.bincount(part) / 2)[part]
    return np.flatnonzero(keep)


def _on_doubled_edges(tri: np.ndarray, among: np.ndarray) -> np.ndarray:
    """The faces of ``among`` with an edge that another of them runs the same way (where a surface and its reverse
    overlap: a consistently wound surface runs each edge once each way), and the faces two edges from them (at a
    sheet's corner a quad's reverse shares no edge's direction with its neighbours)."""
    faces = np.flatnonzero(among)
    t = tri[faces]
    n = np.int64(tri.max()) + 1
    u, v = t.ravel(), np.roll(t, -1, axis=1).ravel()
    _, inverse, count = np.unique(u * n + v, return_inverse=True, return_counts=True)
    near = (count[inverse] > 1).reshape(-1, 3).any(1)
    if not near.any():
        return faces[near]
    _, side = np.unique(np.minimum(u, v) * n + np.maximum(u, v), return_inverse=True)  # undirected edges
    side = side.reshape(-1, 3)
    for _ in range(2):  # two steps across shared edges
        touched = np.zeros(side.max() + 1, bool)
        touched[side[near]] = True
        near |= touched[side].any(1)
    return faces[near]


def _reversed_quads(vertices: np.ndarray, tri: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Among ``faces`` (rows of ``tri``, which numbers the distinct positions ``vertices``), the two triangles of
    each flat quad listed a second time wound the other way, and those of its first listing: two triangles that share
    an edge (wound against each other along it, folded by less than 45°: :data:`FOLD_COS`) make a quad, the cycle of
    its four corners."""
    t = tri[faces]
    # every directed edge u → v of a face, with the face's third corner p; a partner runs v → u, its third corner q
    u, v, p = t.T, np.roll(t, -1, axis=1).T, np.roll(t, -2, axis=1).T
    u, v, p, owner = u.ravel(), v.ravel(), p.ravel(), np.tile(np.arange(len(t)), 3)
    order = np.lexsort((np.maximum(u, v), np.minimum(u, v)))
    a, b = order[:-1], order[1:]  # neighbours in the sort: edges shared by two faces (more shown by a longer run)
    for step in (2, 3):
        a, b = np.r_[a, order[:-step]], np.r_[b, order[step:]]
    pair = (u[a] == v[b]) & (v[a] == u[b]) & (p[a] != p[b])
    a, b = a[pair], b[pair]
    e = vertices[t]
    normal = np.cross(e[:, 1] - e[:, 0], e[:, 2] - e[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    flat = np.einsum("ij,ij->i", normal[owner[a]], normal[owner[b]]) > FOLD_COS
    a, b = a[flat], b[flat]
    cycle = np.stack([v[a], p[a], u[a], p[b]], axis=1)  # a's corners v → p → u, then b's u → q → v
    start = np.argmin(cycle, axis=1)
    cycle = np.take_along_axis(cycle, (start[:, None] + np.arange(4)) % 4, axis=1)
    forward = cycle[:, 1] < cycle[:, 3]
    key = np.where(forward[:, None], cycle, cycle[:, [0, 3, 2, 1]])  # the same for both windings
    quad = np.stack([owner[a], owner[b]], axis=1)
    _, group = unique_rows(key)
    listed = np.full((len(key), 2), len(t))  # each group's first listing (its lowest face) each way round
    np.minimum.at(listed, (group, forward.astype(np.int64)), quad.min(1))
    both = (listed[group] < len(t)).all(1)  # the same corners wound both ways round
    later = both & (quad.min(1) > listed[group, (~forward).astype(np.int64)])
    return faces[np.unique(quad[later])], faces[np.unique(quad[both & ~later])]

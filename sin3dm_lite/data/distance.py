"""Distance to a mesh and inside / outside, the two questions the grid asks at every voxel.

:class:`Distance` answers them for one mesh: exact unsigned point-to-triangle
distances (with the closest face and its barycentrics, where the grid reads
the surface colour) and the generalised winding number, which tells inside
from outside even for open or multi-part meshes. Badly wound faces read as
holes to the winding number, so they are first made to agree with their
neighbours, and inside-out parts are turned round (:func:`_orient_outward`).
Open sheets that enclose no volume (a ground plane, a wall of one polygon)
have no inside to find, and parts thinner than a voxel have an inside that no
voxel centre may hit: the grid would lose both, so they become slabs 1/32 of
the shape's longest side thick (:meth:`Distance.find_slabs`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import point_cloud_utils as pcu

from .box import SHEET_HALF
from .mesh import TexturedMesh, component_labels, unique_rows


class Turned(NamedTuple):
    """What :func:`_orient_outward` turned: faces wound against their neighbours, and parts inside out (of all)."""

    faces: int
    parts: int
    of_parts: int


class Slabs(NamedTuple):
    """What :meth:`Distance.find_slabs` made slabs of, as shares of the surface's area."""

    sheets: float
    thin: float


class Distance:
    """Exact unsigned distance to a mesh and its inside / outside.

    The sign comes from point-cloud-utils' fast winding number (inside where it
    exceeds ½), which is robust for open or multi-part meshes.
    """

    def __init__(self, mesh: TexturedMesh, chunk: int = 1 << 20):
        self.v = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
        faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
        self.f, self.closed, self.turned_round, self._open = _orient_outward(self.v, faces)
        self.corners_reversed = (self.f != faces).any(1)  # faces wound the other way round
        self.chunk = chunk
        self.sheet: np.ndarray | None = None  # (F,) the open sheets (find_slabs), left out of the winding number
        self.reach: np.ndarray | None = None  # (F,) how far each face's slab reaches (find_slabs), 0: none
        self._unit: np.ndarray | None = None  # (F, 3) the faces' unit normals (find_slabs)

    def find_slabs(self) -> Slabs:
        """Make slabs of what a grid's voxel centres would lose, and return those parts' shares of the surface's area.

        **Open sheets** that enclose no volume (a ground plane, a wall of one polygon, a lone height field). Across a
        face the winding number jumps by 1, so the mean of its two sides says what the face bounds: ½ where it has
        the inside behind it (0 in front, 1 behind), about 0 where it has none (a lone sheet: -½, ½). An open part
        (faces joined by edges; a closed one always bounds its volume) most of whose area reads below
        :data:`SHEET_MEAN` is a sheet (a triangle soup's pieces, which together close a volume, read ½). It has no
        inside to find, so it leaves the winding number (:meth:`winding`) and becomes a slab :data:`SHEET_HALF`
        either side of it.

        **Thin parts**: a board or a sheet of metal modelled with a thickness under a voxel has an inside, but no
        voxel centre may fall in it. Behind a face, at depth ``h``, the winding number reads inside while the part
        is thicker than ``h``: a part most of whose area reads outside at :data:`THIN_DEPTHS`' deepest is thin, and
        its thin faces become a slab as thick as an open sheet's (the union reaches ``SHEET_HALF - t/2`` beyond
        each, ``t`` the face's thickness to the nearest of the shallower depths). Parts thicker than that, the few
        thin faces of a thick part (its sharp edges) and the faces of a thin part thick along it (the rim of a hole
        through a board) keep their surface.

        The slabs are the same on every grid, the training grid's and the metrics' (:meth:`thicken`). Called once.
        """
        tri = self.v[self.f]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area = np.linalg.norm(normal, axis=1)
        open_faces, part = self._open
        sheet = self._sheets(tri, normal, area, open_faces, part)
        self.sheet = sheet if sheet.any() else None
        reach = np.where(sheet, SHEET_HALF, 0.0)
        thin_reach = self._thin_faces(tri, normal, area, part, ~sheet)
        thin = thin_reach > 0
        reach[thin] = thin_reach[thin]
        self.reach = reach if reach.any() else None
        self._unit = normal / np.maximum(area, 1e-300)[:, None]
        total = max(float(area.sum()), 1e-300)
        return Slabs(float(area[sheet].sum() / total), float(area[thin].sum() / total))

    def _sheets(self, tri, normal, area, open_faces, part) -> np.ndarray:
        """``(F,)`` the faces of open parts that enclose no volume (:meth:`find_slabs`)."""
        sheet = np.zeros(len(self.f), bool)
        if not open_faces.any():
            return sheet
        parts = part.max() + 1
        ask = _spread(part, open_faces & (area > 0), np.full(parts, SHEET_FACES))
        off = OFF_FACE * float(np.ptp(self.v, axis=0).max()) * normal[ask] / area[ask, None]
        centre = tri[ask].mean(1)
        w = self.winding(np.concatenate([centre - off, centre + off]))
        none = (w[: len(ask)] + w[len(ask) :]) / 2 < SHEET_MEAN
        return open_faces & (_area_share(part, ask, area, none, parts) > 0.5)[part]

    def _thin_faces(self, tri, normal, area, part, asked) -> np.ndarray:
        """``(F,)`` how far each face of a thin part reaches beyond it (:meth:`find_slabs`), 0 elsewhere. About
        :data:`THIN_FACES` of the ``asked`` faces, spread through the parts, say which parts are thin; then every
        face of those (up to :data:`THIN_ALL`) is asked, so that the rim of a hole through a board, thick along the
        board, keeps the hole open."""
        parts = part.max() + 1
        reach = np.zeros(len(self.f))
        count = np.bincount(part[asked], minlength=parts)
        cap = np.maximum(THIN_LEAST, np.round(THIN_FACES * count / max(count.sum(), 1))).astype(np.int64)
        ask = _spread(part, asked & (area > 0), cap)
        if len(ask) == 0:
            return reach
        centre, unit = tri[ask].mean(1), normal[ask] / area[ask, None]
        outside = self.winding(centre - THIN_DEPTHS[-1] * unit) <= 0.5  # which parts: the deepest depth says
        is_thin = _area_share(part, ask, area, outside, parts) > 0.5
        rest = np.flatnonzero(asked & (area > 0) & is_thin[part])
        if len(rest) == 0:
            return reach
        if len(rest) > THIN_ALL:  # too many to ask them all: each face of a thin part takes its part's mean
            sel = is_thin[part[ask]]
            a = area[ask][sel] * outside[sel]
            each = self._probe(centre[sel], unit[sel], self.winding)
            mean = np.bincount(part[ask][sel], a * each, parts) / np.maximum(
                np.bincount(part[ask][sel], a, parts), 1e-300
            )
            reach[rest] = mean[part[rest]]
            return reach
        # each thin part asked alone: behind a board's face where another board joins it, the other's inside
        # would read as the board's own
        rest = rest[np.argsort(part[rest], kind="stable")]
        order, start = _by_part(part, parts)
        for faces in np.split(rest, np.flatnonzero(np.diff(part[rest])) + 1):
            own = self.f[order[start[part[faces[0]]] : start[part[faces[0]] + 1]]]
            reach[faces] = self._probe(
                tri[faces].mean(1),
                normal[faces] / area[faces, None],
                lambda q, own=own: winding_number(self.v, own, q),
            )
        return reach

    @staticmethod
    def _probe(centre: np.ndarray, unit: np.ndarray, winding) -> np.ndarray:
        """How far the slab of each face (``centre``, outward ``unit`` normal) reaches: 0 where ``winding`` (a
        winding number) still reads inside at :data:`THIN_DEPTHS`' deepest behind it, else ``SHEET_HALF - t / 2``,
        ``t`` the deepest of the shallower depths down to which it reads inside."""
        reach = np.zeros(len(centre))
        thin = winding(centre - THIN_DEPTHS[-1] * unit) <= 0.5
        if thin.any():
            c, u = centre[thin], unit[thin]
            inside = winding(np.concatenate([c - h * u for h in THIN_DEPTHS[:-1]])).reshape(-1, len(c)) > 0.5
            depth = np.array([0.0, *THIN_DEPTHS[:-1]])[np.cumprod(inside, axis=0).sum(0)]  # inside all the way
            reach[thin] = SHEET_HALF - depth / 2
        return reach

    def thicken(self, sdf: np.ndarray, p: np.ndarray, d: np.ndarray, fi: np.ndarray, threshold: float) -> tuple:
        """``sdf`` at points ``p`` (signed by the winding number, truncated at ``threshold``) with the slabs of
        :meth:`find_slabs` (:meth:`slab_depth`): where the closest face (``fi``, at distance ``d``) has one, the
        union ``min(sdf, depth)``, truncated at ``±threshold`` like the rest (a slab may be thicker than the band:
        at 256 voxels). Returns the new SDF and where the closest face has a slab."""
        if self.reach is None:
            return sdf, np.zeros(len(sdf), bool)
        depth, on = self.slab_depth(p, d, fi)
        return np.where(on, np.minimum(sdf, np.clip(depth, -threshold, threshold)), sdf), on

    def slab_depth(self, p: np.ndarray, d: np.ndarray, fi: np.ndarray) -> tuple:
        """The signed distance ``d - reach`` of points ``p`` to the slab of their closest face ``fi`` (at distance
        ``d``), and where that face has one. A slab is its face pushed out along the normal, not rounded past the
        face's edge: a point whose way to the face leans more than :data:`SLAB_LEAN` off the normal (beyond the
        rim of a hole, past a sheet's end) is outside it, as far as it is from the face."""
        reach = self.reach[fi]
        on = (reach > 0) & np.isfinite(d)
        depth = np.array(d, np.float64)
        at, f = np.flatnonzero(on), fi[on]  # most points of a grid are near no slab
        height = np.abs(np.einsum("ij,ij->i", np.asarray(p, np.float64)[at] - self.v[self.f[f, 0]], self._unit[f]))
        depth[at] = np.where(height >= np.cos(SLAB_LEAN) * d[at], d[at] - reach[at], d[at])
        return depth, on

    def slab_decides(self, p: np.ndarray, d: np.ndarray, fi: np.ndarray) -> np.ndarray:
        """Where the slab alone gives :meth:`thicken`'s value, whatever the winding number says: closer to the face
        than half its reach (``d - reach < -d``), so that a caller may skip the winding number there."""
        if self.reach is None:
            return np.zeros(len(d), bool)
        depth, on = self.slab_depth(p, d, fi)
        return on & (depth < -d)

    @property
    def reach_max(self) -> float:
        """How far the farthest slab reaches beyond its face (0 without slabs)."""
        return 0.0 if self.reach is None else float(self.reach.max())

    def in_slab(self, points: np.ndarray) -> np.ndarray:
        """Which ``points`` lie inside the slabs of :meth:`find_slabs`."""
        if self.reach is None or len(points) == 0:
            return np.zeros(len(points), bool)
        d, fi, _ = self.closest(points)
        depth, on = self.slab_depth(points, d, fi)
        return on & (depth < 0)

    def winding(self, p: np.ndarray) -> np.ndarray:
        """Generalised winding number: 1 inside a closed surface, 0 outside, in between near holes (sheets left out)."""
        solid = self.f if self.sheet is None else self.f[~self.sheet]  # sheets have no inside (find_slabs)
        return winding_number(self.v, solid, p)

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
        back = self.corners_reversed[fi]
        bc[back] = bc[back][:, ::-1]  # barycentrics in the mesh's own corner order
        return d, fi, bc


def _orient_outward(vertices: np.ndarray, faces: np.ndarray):
    """Wind every face the way its neighbours are wound, then turn the parts that are inside out.

    The winding number is +1 inside a surface whose faces wind counter-clockwise seen from outside and -1 inside
    one wound the other way: a face wound against its neighbours punches a hole into the inside, and an inside-out
    part has no inside at all. So, on the vertices joined by position (a UV seam splits none):

    1. every face is wound as its neighbours across each edge that two faces share (:func:`_agreeing_winding`);
    2. a *closed* part (every edge used as often in one direction as in the other) that encloses a negative
       volume is turned round; so is an *open* part whose faces mostly have the outside behind them
       (:func:`_inside_out`).

    Returns ``(faces, closed, turned, (open, part))``: the faces, whether the whole mesh is closed,
    :class:`Turned`, the faces of open parts (where :meth:`Distance.find_slabs` looks) and every face's part.
    """
    _, weld = unique_rows(vertices)  # vertices split at UV seams are one point here
    against = _agreeing_winding(weld[faces])
    faces = np.where(against[:, None], faces[:, ::-1], faces)
    fw = weld[faces]
    part = component_labels(int(fw.max()) + 1, fw)  # (F,) the part of every face
    parts = int(part.max()) + 1
    edges, key = _edges(fw)
    # a closed, consistently wound surface uses every edge as often a → b as b → a
    _, inverse = np.unique(key, return_inverse=True)
    balance = np.bincount(inverse.reshape(-1), np.where(edges[:, 0] < edges[:, 1], 1.0, -1.0))
    open_edge = balance[inverse.reshape(-1)] != 0  # (3F,)
    open_part = np.bincount(part.repeat(3)[open_edge], minlength=parts) > 0
    tri = vertices[faces]  # a closed part's enclosed volume (× 6) does not depend on the origin
    volume = np.bincount(part, np.einsum("fi,fi->f", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])), parts)
    has_faces = np.bincount(part, minlength=parts) > 0  # (labels of vertices without faces are skipped)
    closed = has_faces & ~open_part
    flip = (closed & (volume < 0)) | _inside_out(vertices, faces, part, has_faces & open_part)
    faces = np.where(flip[part][:, None], faces[:, ::-1], faces)
    turned = Turned(int(against.sum()), int(flip.sum()), int(has_faces.sum()))
    return np.ascontiguousarray(faces), not open_part.any(), turned, ((has_faces & open_part)[part], part)


def _edges(fw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The faces' directed edges ``(3F, 2)`` (face f's are rows 3f, 3f+1, 3f+2) and a key per undirected edge."""
    edges = fw[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    return edges, np.minimum(edges[:, 0], edges[:, 1]) * (int(fw.max()) + 1) + np.maximum(edges[:, 0], edges[:, 1])


def _agreeing_winding(fw: np.ndarray) -> np.ndarray:
    """Which faces to turn so that two faces sharing an edge run it opposite ways, as in a surface whose faces
    all face out (or all in): ``(F,)`` bool, for faces ``fw`` on welded vertices.

    Faces are linked across each edge that exactly two of them share (an edge of three or more says nothing), by
    "wound alike" or "wound against each other". Each linked piece is two-coloured at once with the usual
    trick: a graph of two nodes per face (as wound, turned), "alike" joining as-wound to as-wound and turned to
    turned, "against" as-wound to turned; its connected components are the piece's two consistent windings, and
    the one most of the piece's faces already have is kept. A piece that admits none (a Möbius strip) is left.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    nf = len(fw)
    edges, key = _edges(fw)
    order = np.argsort(key, kind="stable")
    k = key[order]
    same = k[1:] == k[:-1]  # neighbours in sorted order with the same edge
    pair = same & ~np.r_[False, same[:-1]] & ~np.r_[same[1:], False]  # runs of exactly two
    a, b = order[:-1][pair], order[1:][pair]
    fa, fb = a // 3, b // 3
    alike = edges[a, 0] != edges[b, 0]  # opposite directions along the shared edge: wound alike
    src = np.concatenate([fa, fa + nf])
    dst = np.concatenate([np.where(alike, fb, fb + nf), np.where(alike, fb + nf, fb)])
    graph = coo_matrix((np.ones(len(src), np.int8), (src, dst)), shape=(2 * nf, 2 * nf))
    _, label = connected_components(graph, directed=False)
    wound, turned = label[:nf], label[nf:]
    piece = np.minimum(wound, turned)  # the same for both windings of a piece
    first = wound == piece  # this face, as wound, is in the piece's first winding
    keep_first = 2 * np.bincount(piece, first, len(label)) >= np.bincount(piece, minlength=len(label))
    return (first != keep_first[piece]) & (wound != turned)


#: below this mean of a face's two sides' winding numbers the face bounds no volume (a bounding face's is ½)
SHEET_MEAN = 0.25
#: how many faces of each open part :meth:`Distance.find_slabs` asks at most
SHEET_FACES = 4096
#: the depths behind a face at which :meth:`Distance.find_slabs` asks whether the part is still inside: a part
#: thinner than the deepest (3/4 of an open sheet's slab) is thin
THIN_DEPTHS = (SHEET_HALF / 2, SHEET_HALF, 3 * SHEET_HALF / 2)
#: about how many faces :meth:`Distance.find_slabs` asks to find the thin parts (shared by the parts as their faces
#: are), the least of each part, and the most faces of thin parts it then asks one by one
THIN_FACES, THIN_LEAST, THIN_ALL = 16_384, 4, 262_144


def winding_number(v: np.ndarray, f: np.ndarray, p: np.ndarray) -> np.ndarray:
    """point-cloud-utils' fast winding number of the triangles ``f`` over ``v`` at the points ``p``, one per point
    (it returns a bare number for a single point and refuses none)."""
    p = np.ascontiguousarray(p, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0 or len(f) == 0:
        return np.zeros(len(p), np.float64)
    return np.reshape(pcu.triangle_soup_fast_winding_number(v, f, p), len(p))


def _by_part(part: np.ndarray, parts: int) -> tuple[np.ndarray, np.ndarray]:
    """The faces in order of their part (stable) and where each part starts in it (``parts + 1``): part ``p``'s
    faces are ``order[start[p] : start[p + 1]]``."""
    return np.argsort(part, kind="stable"), np.r_[0, np.cumsum(np.bincount(part, minlength=parts))]


def _spread(part: np.ndarray, mask: np.ndarray, cap: np.ndarray) -> np.ndarray:
    """The ``mask``ed faces to ask, at most about ``cap[p]`` of each part ``p``, evenly spread through it."""
    order, start = _by_part(part, len(cap))
    rank = np.empty(len(part), np.int64)
    rank[order] = np.arange(len(part)) - start[part[order]]
    return np.flatnonzero(mask & (rank % np.maximum(1, np.diff(start) // np.maximum(cap, 1))[part] == 0))


def _area_share(part: np.ndarray, ask: np.ndarray, area: np.ndarray, yes: np.ndarray, parts: int) -> np.ndarray:
    """``(parts,)`` the share of each part's asked area (faces ``ask``) where ``yes``."""
    asked_area = np.maximum(np.bincount(part[ask], area[ask], parts), 1e-300)
    return np.bincount(part[ask], area[ask] * yes, parts) / asked_area


#: a point is in a face's slab only if its way to the face leans at most this far off the face's normal (radians):
#: a curved sheet's faces meet at smaller angles, the rim of a hole at a right angle
SLAB_LEAN = np.pi / 6

#: how many faces of an open part :func:`_inside_out` asks at most, and how far off the face (a share of the part)
ASKED_FACES, OFF_FACE = 256, 1e-4


def _inside_out(vertices: np.ndarray, faces: np.ndarray, part: np.ndarray, asked: np.ndarray) -> np.ndarray:
    """Which of the ``asked`` (open) parts have their outside behind their faces: ``(parts,)`` bool.

    An open part has no volume to go by. Just off a face, the face itself adds ±½ to the part's winding number
    (+ behind it, - in front); the rest of the part adds about +½ on both sides where its normals point out and
    about -½ where they point in. So the mean of the two sides, taken at a few faces, is the rest's share: a
    part is turned round where its median is below -¼ (a flat sheet, with no inside, gives 0 and stays).
    """
    out = np.zeros(len(asked), bool)
    order, start = _by_part(part, len(asked))
    count = np.diff(start)
    for p in np.flatnonzero(asked & (count >= 8)):  # a few faces say too little (and a soup has many parts)
        used, f = np.unique(faces[order[start[p] : start[p + 1]]], return_inverse=True)  # the part alone
        v, f = vertices[used], f.reshape(-1, 3)
        tri = v[f[:: max(1, len(f) // ASKED_FACES)]]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(normal, axis=1)
        if (length > 0).sum() < 8:
            continue
        off = OFF_FACE * float(np.ptp(v, axis=0).max()) * normal[length > 0] / length[length > 0, None]
        centre = tri[length > 0].mean(1)
        w = winding_number(v, f, np.concatenate([centre - off, centre + off]))
        out[p] = np.median((w[: len(centre)] + w[len(centre) :]) / 2) < -0.25
    return out

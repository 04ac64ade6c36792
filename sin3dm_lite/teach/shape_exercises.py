"""Exercises on the shape side: the grid's box (notebook 01), retargeting (00), an edit's masks (06), tangent
frames (08).

Like :mod:`~sin3dm_lite.teach.exercises`: each check compares your function with the package's own code on
random inputs, prints one line when they agree and raises :class:`~sin3dm_lite.teach.checking.ExerciseError`
when they do not, saying where and, for the usual mistakes, why. Solutions are in ``notebooks/solutions/``.
"""

from __future__ import annotations

import numpy as np

from ..data.box import centred_box, grid_shape
from ..data.mesh import tangent_frames
from ..generate.control import regenerate, retarget
from ..model.triplane import PLANE_AXES, PLANES, Triplane
from .checking import ExerciseError, as_array, call, matching_hint, parts, passed, tolerance


def _counts(name: str, value, what: str) -> tuple[int, ...]:
    """Voxel or texel counts as a tuple of three ints, or an ExerciseError (a count is a whole number)."""
    arr = as_array(f"{name} ({what})", value, (3,))
    if not np.all(arr == np.round(arr)):
        raise ExerciseError(f"your {name} gives {what} {arr.tolist()}: counts are whole numbers")
    return tuple(int(v) for v in arr)


def _box6(name: str, value) -> np.ndarray:
    """A box as six floats (xmin, ymin, zmin, xmax, ymax, zmax), or an ExerciseError."""
    try:
        flat = np.asarray(value.detach().cpu() if hasattr(value, "detach") else value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ExerciseError(f"your {name} returned a {type(value).__name__}, expected six numbers") from None
    return as_array(name, flat, (6,))


# ----------------------------------------------------------------------------- the grid (notebook 01)
def _box_cases(rng: np.random.Generator) -> list[tuple[np.ndarray, int]]:
    cases = [(np.array([1.9417, 0.7458, 0.9709]), r) for r in (64, 128, 256)]  # the normalised canyon
    while len(cases) < 30:
        e, res = rng.uniform(0.1, 2.0, 3), int(rng.choice([32, 64, 96, 128, 256]))
        share = res * e / e.max()
        if np.all(np.floor(share + 1e-3) == np.floor(share)):  # no share within 1e-3 of a whole number
            cases.append((e, res))
    # flat sheets: the thin axis's share is under one voxel, so only "at least 8" gives it a grid
    return cases + [(np.array([1.8, 0.9, 0.004]), 128), (np.array([0.02, 1.5, 0.7]), 64)]


def check_grid_box(fn, seed: int = 0) -> None:
    """``fn(extent, resolution) -> (shape, aabb)``: the voxel counts and the box of a shape's grid.

    ``extent`` holds the normalised shape's side lengths along x, y, z; ``resolution`` (a multiple of 8)
    is the number of voxels along the longest side. Every other axis gets ``int(resolution · extent /
    longest extent)`` voxels (rounded down), then every count is rounded up to a multiple of 8 (at least
    8). The box ``(xmin, ymin, zmin, xmax, ymax, zmax)`` is ``±n_axis / n_max``: the longest side spans
    [-1, 1] and every voxel is a cube.
    """
    cases = _box_cases(np.random.default_rng(seed))
    for extent, res in cases:
        want_shape = grid_shape(extent, res, multiple=8)
        want_box = centred_box(want_shape).astype(np.float64)
        shape, box = parts("grid_box", call("grid_box", fn, extent.copy(), res), 2, "two things: (shape, aabb)")
        shape = _counts("grid_box", shape, "shape")
        where = f"for extent {extent.round(4).tolist()} at resolution {res}"
        if shape != want_shape:
            share = res * extent / extent.max()
            rounded = np.maximum(8, np.ceil(np.round(share) / 8) * 8)
            to_nearest = np.maximum(8, np.round(np.floor(share) / 8) * 8)
            hints = {
                "every axis gets at least 8 voxels (np.maximum(8, ...)): a flat sheet's thin side still needs a grid "
                "around it": np.ceil(np.floor(share) / 8) * 8,
                "int(...) rounds down: a share of 24.6 voxels is 24 before it is rounded up to a multiple of 8": rounded,
                "round each count UP to a multiple of 8 (8, 16, 24, ...)": np.floor(share),
                "round each count up to a multiple of 8 (np.ceil(n / 8) * 8), not to the nearest one": to_nearest,
            }
            raise ExerciseError(
                f"{where} your shape is {shape}, the library's {want_shape}"
                + matching_hint(np.array(shape, float), hints, 0, np.array(want_shape, float))
            )
        got_box = _box6("grid_box (aabb)", box)
        if not np.allclose(got_box, want_box, rtol=0, atol=1e-6):
            half = extent / extent.max()
            extent_box, unit_box = np.concatenate([-half, half]), np.array([-1.0] * 3 + [1.0] * 3)
            hints = {
                "the box follows the voxel counts, ±n_axis / n_max, not the shape's extent: the counts were "
                "rounded up, so the box holds a little room around the shape and every voxel stays a cube": extent_box,
                "only the longest axis spans [-1, 1]: the others span ±n_axis / n_max": unit_box,
                "the order is (xmin, ymin, zmin, xmax, ymax, zmax)": want_box.reshape(2, 3).T.reshape(-1),
            }
            raise ExerciseError(
                f"{where} (shape {shape}) your box is {got_box.round(4).tolist()}, the library's "
                f"{want_box.round(4).tolist()}" + matching_hint(got_box, hints, 1e-6)
            )
    print(
        f"✓ your grid_box matches the library on {len(cases)} extents and resolutions (the canyon at 64 voxels: "
        f"{grid_shape(cases[0][0], 64, multiple=8)})"
    )


# ----------------------------------------------------------------------------- retargeting (notebook 00)
def _retarget_cases(rng: np.random.Generator) -> list[tuple[tuple[int, int, int], np.ndarray]]:
    canyon = (32, 16, 20)
    cases = [(canyon, np.array(f, float)) for f in ((1.5, 1, 1), (1, 1, 1.5), (1, 1, 0.6), (0.1, 1, 1))]
    while len(cases) < 24:
        res, f = tuple(int(v) for v in rng.integers(6, 41, 3)), rng.uniform(0.3, 2.5, 3)
        if np.all(np.abs((np.array(res) * f) % 1 - 0.5) > 1e-3):  # no count halfway between two whole numbers
            cases.append((res, f))
    return cases


def check_retarget(fn, seed: int = 0) -> None:
    """``fn(resolution, aabb, factors) -> (new_resolution, new_aabb)``: the latent and box of a resized sample.

    ``resolution`` is the latent's texels ``(X, Y, Z)``, ``aabb`` its box ``(xmin, ymin, zmin, xmax, ymax,
    zmax)`` (centred on the origin), ``factors`` the resize per axis. Each count is rounded to the nearest
    whole texel (at least 4); the box is scaled about its centre by new / old texels per axis, so every
    texel keeps its size in space.
    """
    cases = _retarget_cases(np.random.default_rng(seed))
    for res, f in cases:
        aabb = centred_box(res)
        plan = retarget(Triplane.randn(1, 1, res), aabb, f)
        out = call("retarget", fn, tuple(res), aabb.copy(), tuple(float(v) for v in f))
        new_res, new_box = parts("retarget", out, 2, "two things: (new_resolution, new_aabb)")
        new_res = _counts("retarget", new_res, "new_resolution")
        where = f"for latent {res} and factors {tuple(round(float(v), 3) for v in f)}"
        if new_res != plan.resolution:
            exact = np.array(res) * f
            hints = {
                "round to the nearest whole texel (np.round), not down": np.maximum(4, np.floor(exact)),
                "a latent keeps at least 4 texels per axis (np.maximum(4, ...))": np.round(exact),
            }
            raise ExerciseError(
                f"{where} your latent is {new_res}, the library's {plan.resolution}"
                + matching_hint(np.array(new_res, float), hints, 0)
            )
        got = _box6("retarget (new_aabb)", new_box)
        want = plan.aabb.astype(np.float64)
        if not np.allclose(got, want, rtol=1e-5, atol=1e-6):
            lo, hi = aabb[:3].astype(np.float64), aabb[3:].astype(np.float64)
            scale = np.array(plan.resolution) / np.array(res)
            one_corner = np.concatenate([lo, lo + (hi - lo) * scale])
            hints = {
                "scale the box by new / old texels (the rounded ratio), not by the factor asked for: then every "
                "texel keeps its size": np.concatenate([lo * f, hi * f]),
                "the box grows about its centre (the origin): scale both corners": one_corner,
            }
            raise ExerciseError(
                f"{where} (latent {new_res}) your box is {got.round(4).tolist()}, the library's "
                f"{want.round(4).tolist()}" + matching_hint(got, hints, 1e-5)
            )
    print(
        f"✓ your retarget matches the library on {len(cases)} latents and factors (the canyon ×1.5 along x: "
        f"{retarget(Triplane.randn(1, 1, (32, 16, 20)), centred_box((32, 16, 20)), (1.5, 1, 1)).resolution})"
    )


# ----------------------------------------------------------------------------- local editing (notebook 06)
def _mask_cases(rng: np.random.Generator) -> list[tuple[tuple[int, int, int], tuple, float]]:
    canyon, slab, column = (32, 16, 20), ((0.35, 0.0, 0.0), (0.65, 1.0, 1.0)), ((0.35, 0.0, 0.0), (0.65, 0.6, 1.0))
    cases = [(canyon, slab, 2.0), (canyon, slab, 0.0), (canyon, column, 2.0)]
    while len(cases) < 30:
        res = tuple(int(v) for v in rng.integers(6, 41, 3))
        spans = rng.random(3) < 0.4
        spans[rng.integers(3)] = True  # at least one axis spanned: the box must reach two opposite faces
        lo, hi = np.zeros(3), np.ones(3)
        for a in np.flatnonzero(~spans):
            lo[a], hi[a] = np.sort(rng.uniform(0, 1, 2))
            if round(hi[a] * res[a]) - round(lo[a] * res[a]) < 1:
                lo[a], hi[a] = 0.2, 0.6
        cases.append((res, (tuple(lo.tolist()), tuple(hi.tolist())), float(rng.choice([0, 1, 2, 2, 3.5]))))
    return cases


def _mask_hint(got: np.ndarray, want: np.ndarray, plane: str, spans_third: bool, border: float) -> str:
    if not spans_third and np.all(want == 1):
        third = "xyz"[3 - sum(PLANE_AXES[plane])]
        return (
            f"\n  hint: a texel of the {plane} plane is shared by every point along {third}; the box does not span "
            f"{third} from 0 to 1, so the {plane} plane must be kept whole (1 everywhere)"
        )
    if np.allclose(got, 1 - want, atol=1e-6):
        return "\n  hint: 1 means keep: the box's shadow is 0 (freed), everything else 1"
    ramp = (want > 0) & (want < 1)
    if border > 0 and ramp.any() and np.allclose(got[~ramp], want[~ramp], atol=1e-6):
        return (
            "\n  hint: the ramp lies outside the box: a texel whose centre is d texels outside the box's texels "
            "is freed by clip(1 - d / border, 0, 1), and its keep weight is 1 minus that"
        )
    return ""


def check_regenerate_mask(fn, seed: int = 0) -> None:
    """``fn(resolution, box, border) -> (xy, xz, yz)``: the keep masks of a local edit, one 2D array per plane.

    ``resolution = (X, Y, Z)`` texels; ``box = ((x0, y0, z0), (x1, y1, z1))`` in fractions [0, 1] of the
    model's box; along each axis the box holds texels ``round(lo · n)`` to ``round(hi · n)`` (exclusive).
    A plane is freed (mask 0) in the box's shadow only if the box spans the whole third axis (from 0 to
    1), else kept whole (1). Around the shadow the free part ramps over ``border`` texels: a texel whose
    centre ``k + 0.5`` lies ``d`` texels outside the box's range along an axis has a profile value
    ``clip(1 - d / border, 0, 1)`` (``d == 0`` for ``border == 0``); the plane frees the product of its
    two axes' profiles and keeps ``1 -`` that. Shapes: xy ``[X, Y]``, xz ``[X, Z]``, yz ``[Y, Z]``.
    """
    cases = _mask_cases(np.random.default_rng(seed))
    worst = 0.0
    for res, box, border in cases:
        plan = regenerate(Triplane.randn(1, 1, res), centred_box(res), box, border)
        out = call("regenerate_mask", fn, tuple(res), box, border)
        parts("regenerate_mask", out, 3, "three masks: (xy, xz, yz)")
        spans = [round(lo * n) == 0 and round(hi * n) == n for lo, hi, n in zip(*box, res)]
        for plane, (a, b), got, want in zip(PLANES, PLANE_AXES.values(), out, plan.mask.planes):
            want = want[0, 0].numpy().astype(np.float64)
            got = as_array(f"regenerate_mask ({plane})", got, want.shape)
            err = np.abs(got - want)
            if err.max() > 1e-6:
                i, j = np.unravel_index(int(err.argmax()), err.shape)
                raise ExerciseError(
                    f"for latent {res}, box {box}, border {border:g}: your {plane} mask differs at texel ({i}, {j}): "
                    f"yours {got[i, j]:.3g}, the library's {want[i, j]:.3g}"
                    + _mask_hint(got, want, plane, spans[3 - a - b], border)
                )
            worst = max(worst, float(err.max()))
    passed("regenerate_mask", len(cases) * 3, worst)


# ----------------------------------------------------------------------------- tangent frames (notebook 08)
def _triangles(rng: np.random.Generator, n: int = 60) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` well-shaped random triangles in 3D with random UV triangles (about half of them mirrored)."""
    tris, uvs = [], []
    while len(tris) < n:
        tri, uv = rng.normal(size=(3, 3)), rng.uniform(0, 1, (3, 2))
        d1, d2 = uv[1] - uv[0], uv[2] - uv[0]
        if (
            np.linalg.norm(np.cross(tri[1] - tri[0], tri[2] - tri[0])) > 0.2
            and abs(d1[0] * d2[1] - d2[0] * d1[1]) > 0.02
        ):
            tris.append(tri)
            uvs.append(uv)
    return np.concatenate(tris), np.arange(3 * n).reshape(n, 3), np.stack(uvs)


def _frame_hint(which: str, got: np.ndarray, t: np.ndarray, b: np.ndarray, n: np.ndarray, vdir: np.ndarray) -> str:
    unit = vdir / np.linalg.norm(vdir, axis=1, keepdims=True)
    hints = {
        "N": {"N = e1 × e2 (e1 = v1 - v0, e2 = v2 - v0), made unit length: counter-clockwise faces face you": -n},
        "T": {
            "T is where u grows, B where v grows: you swapped them": unit,
            "T is where u grows, B where v grows: you swapped T and B": b,
            "solve e1 = du1·T + dv1·B, e2 = du2·T + dv2·B for T; a negative determinant flips both solutions, "
            "T must keep its sign": -t,
        },
        "B": {
            "on faces whose UV triangle is mirrored (determinant < 0) v grows the other way: flip B = N × T where "
            "it points against the v direction from the solve": np.cross(n, t),
            "B is ±N × T, perpendicular to T; the v direction from the solve is not, where the UV map shears "
            "the triangle": unit,
            "B = N × T, not T × N": -b,
        },
    }[which]
    return matching_hint(got, hints, 1e-6)


def check_tangent_frames(fn, seed: int = 0) -> None:
    """``fn(vertices, faces, face_uvs) -> (T, B, N)``: each face's tangent frame, three ``(F, 3)`` unit vectors.

    ``vertices (V, 3)``, ``faces (F, 3)`` vertex indices, ``face_uvs (F, 3, 2)`` the UV of each corner.
    ``N`` is the face normal ``e1 × e2`` (``e1 = v1 - v0``, ``e2 = v2 - v0``), unit length. ``T`` and the
    v direction solve ``e1 = du1·T + dv1·V``, ``e2 = du2·T + dv2·V`` (``du1, dv1`` the UV change along
    ``e1``); ``T`` is made perpendicular to ``N`` and unit length; ``B = N × T``, flipped where it points
    against ``V`` (a mirrored UV triangle). Every face here has a usable UV triangle.
    """
    vertices, faces, uvs = _triangles(np.random.default_rng(seed))
    t, b, n = tangent_frames(vertices, faces, uvs)
    out = call("tangent_frames", fn, vertices.copy(), faces.copy(), uvs.copy())
    parts("tangent_frames", out, 3, "three arrays: (T, B, N)")
    tri = vertices[faces]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    d1, d2 = uvs[:, 1] - uvs[:, 0], uvs[:, 2] - uvs[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    vdir = (e2 * d1[:, :1] - e1 * d2[:, :1]) / det[:, None]
    worst = 0.0
    for which, got, want in zip("NTB", (out[2], out[0], out[1]), (n, t, b)):  # N first: T and B build on it
        tol = tolerance(got, 1e-6)  # float32 frames are welcome
        got = as_array(f"tangent_frames ({which})", got, want.shape)
        err = np.abs(got - want).max(1)
        if err.max() > tol:
            f = int(err.argmax())
            mirrored = (
                f" (its UV triangle is mirrored: {int((det < 0).sum())} of {len(faces)} are)" if det[f] < 0 else ""
            )
            raise ExerciseError(
                f"your {which} differs on {int((err > tol).sum())} of {len(faces)} faces; on face {f}"
                f"{mirrored}: yours {got[f].round(4).tolist()}, the library's {want[f].round(4).tolist()}"
                + _frame_hint(which, got, t, b, n, vdir)
            )
        worst = max(worst, float(err.max()))
    passed("tangent_frames", len(faces), worst)


__all__ = ["check_grid_box", "check_regenerate_mask", "check_retarget", "check_tangent_frames"]

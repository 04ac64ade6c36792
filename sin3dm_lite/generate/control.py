"""Controlled generation (the paper's Sec. 4.4): retargeting, outpainting, local editing, patch duplication.

The denoiser never sees the task: every operation here only chooses **what to
sample** — the latent's size, and a *known* latent ``y0`` with a soft *mask*
``m`` (1 = keep). The masked sampler (``diffusion.sample``) then pastes the
known part, noised to the current step's level, over the sample after every
denoising step (``x_{t-1} ← m·q(y0, t-1) + (1-m)·x_{t-1}``) and exactly at the
end, so the free part grows around the kept part and blends into it. As in
the paper, the mask's borders between 0 and 1 are linear ramps, here
``border`` texels wide and inside the kept part.

A box is a pair of corners given as fractions of the model's box ([0, 1]³
along x, y, z as in the mesh file). Each function returns a :class:`Plan` that
``Sin3DM.sample(plan=...)`` (or the keyword shortcuts ``resize=``,
``outpaint=``, ``regenerate=``, ``duplicate=``) carries out.

* :func:`retarget` — another size: noise of another shape, no mask;
* :func:`outpaint` — a larger box with the input kept where it was
  (``anchor``: the centre, or the face it sticks to), the rest generated;
* :func:`regenerate` — local editing: a box that reaches the model's faces
  along at least one axis resampled, everything else kept;
* :func:`duplicate` — a part of the input copied to another place, kept there
  and at its source, everything else generated around the two copies;
* :func:`keep_planes` — whole planes of the input's latent kept, the others
  generated (not in the paper: it shows which plane holds the variation).

A triplane mask is three 2D masks, the box's shadow on each plane, so a
point outside a 3D box but inside its shadow on one plane has that plane's
features from the edit and the other two from outside it. :meth:`Plan.kept`
gives the voxels all three planes keep: there the latent is exactly the
input's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import Sin3DMInputError
from ..model.triplane import PLANE_AXES, PLANES, Triplane

ANCHORS = ("center", "x-", "x+", "y-", "y+", "z-", "z+")
BORDER = 2  # texels of linear ramp between kept and generated


@dataclass
class Plan:
    """What to sample: the latent size, the result's box, and optionally a known latent with its mask.

    ``known`` and ``mask`` (1 = keep) have the result's size; ``start`` is the latent the diversity knob noises
    when it is below 1 (the input's, placed like the result). ``kind`` and ``request`` say what was asked.
    """

    kind: str
    resolution: tuple[int, int, int]
    aabb: np.ndarray
    start: Triplane
    known: Triplane | None = None
    mask: Triplane | None = None
    request: dict | None = None

    def kept(self, shape: tuple[int, int, int] | None = None) -> np.ndarray:
        """Bool grid (the latent's texels, or ``shape`` voxels over the same box) where all three planes keep ``known``."""
        res = self.resolution if shape is None else tuple(shape)
        if self.mask is None:
            return np.zeros(res, bool)
        full = [(p[0, 0].cpu().numpy() >= 1.0) for p in self.mask.planes]
        idx = [np.minimum((np.arange(n) + 0.5) / n * r, r - 1).astype(int) for n, r in zip(res, self.resolution)]
        out = np.ones(res, bool)
        for (a, b), m in zip(PLANE_AXES.values(), full):
            view = m[np.ix_(idx[a], idx[b])]
            out &= np.expand_dims(view, axis=3 - a - b)  # broadcast along the third axis
        return out


# ----------------------------------------------------------------------------- checks
def _fmt(v) -> str:
    return "(" + ", ".join(f"{float(x):g}" for x in np.ravel(v)) + ")"


def _factors(factors, what: str, at_least: float = 0.0) -> np.ndarray:
    """The size factors ``what`` (resize, outpaint) checked by :func:`values.factors` (what the CLI's flags call)."""
    from ..app.values import factors as checked

    return np.array(checked(factors, what, at_least, at_least > 0), np.float64)


def texel_range(lo: float, hi: float, n: int) -> tuple[int, int]:
    """Texels ``[a, b)`` of an axis of ``n`` texels covered by the fraction interval ``[lo, hi]``."""
    return int(round(lo * n)), int(round(hi * n))


def _box(box, res, what: str) -> list[tuple[int, int]]:
    """A box ``((x0, y0, z0), (x1, y1, z1))`` in fractions [0, 1] → texel ranges per axis, checked."""
    try:
        lo, hi = (np.asarray(c, dtype=np.float64).reshape(3) for c in box)
    except (TypeError, ValueError):
        raise Sin3DMInputError(f"{what} must be two corners (x0, y0, z0), (x1, y1, z1), got {box!r}") from None
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))) or np.any(lo < 0) or np.any(hi > 1):
        raise Sin3DMInputError(
            f"the corners of {what} must be fractions of the model's box in [0, 1], got {_fmt(lo)} to {_fmt(hi)}"
        )
    ranges = [texel_range(a, b, n) for a, b, n in zip(lo, hi, res)]
    empty = [(ax, n) for ax, (a, b), n in zip("xyz", ranges, res) if b - a < 1]
    if empty:
        raise Sin3DMInputError(
            f"{what} {_fmt(lo)} to {_fmt(hi)} is empty along {', '.join(ax for ax, _ in empty)} at "
            f"this latent's {res[0]}×{res[1]}×{res[2]} texels; make it larger (at least "
            f"{', '.join(f'1/{n} along {ax}' for ax, n in empty)})"
        )
    return ranges


# ----------------------------------------------------------------------------- masks
def _profile(n: int, a: int, b: int, border: float, ramp_lo: bool = True, ramp_hi: bool = True) -> np.ndarray:
    """1 on texels ``[a, b)``, ramping linearly to 0 over ``border`` texels inside each end that has a ramp, 0 outside.

    A part narrower than two borders gets a narrower ramp, so its middle texel(s) are still kept whole.
    """
    k = np.arange(n) + 0.5
    v = np.zeros(n)
    inside = (k > a) & (k < b)
    d = np.full(n, np.inf)
    if border > 0 and ramp_lo:
        d = np.minimum(d, k - a)
    if border > 0 and ramp_hi:
        d = np.minimum(d, b - k)
    if inside.any():
        border = min(border, float(d[inside].max()))  # a narrow part keeps at least its middle texel(s) whole
    v[inside] = np.clip(d[inside] / border, 0, 1) if border > 0 else 1.0
    return v


def _outside_profile(n: int, a: int, b: int, border: float) -> np.ndarray:
    """1 on texels ``[a, b)``, ramping to 0 over ``border`` texels *outside* it (for a region to be replaced)."""
    k = np.arange(n) + 0.5
    d = np.maximum(np.maximum(a - k, k - b), 0)
    return (d == 0).astype(np.float64) if border <= 0 else np.clip(1 - d / border, 0, 1)


def _mask(profiles: list[np.ndarray]) -> Triplane:
    """The triplane mask whose planes are the outer products of the per-axis ``profiles``."""
    return Triplane(
        *(torch.from_numpy(np.outer(profiles[a], profiles[b])).float()[None, None] for a, b in PLANE_AXES.values())
    )


def _union(m1: Triplane, m2: Triplane) -> Triplane:
    return m1.zip_map(m2, torch.maximum)


def _box_aabb(aabb: np.ndarray, base_res, lo_texel, new_res) -> np.ndarray:
    """Normalised box of a latent of ``new_res`` texels whose texel 0 is texel ``lo_texel`` of the input's latent."""
    aabb = np.asarray(aabb, np.float64)
    size = (aabb[3:] - aabb[:3]) / np.asarray(base_res, np.float64)  # normalised units per texel
    lo = aabb[:3] + np.asarray(lo_texel, np.float64) * size
    return np.concatenate([lo, lo + np.asarray(new_res) * size]).astype(np.float32)


# ----------------------------------------------------------------------------- the operations
def retarget(latent: Triplane, aabb, factors) -> Plan:
    """Another size: ``factors`` per axis (x, y, z) of the input's box, the latent rounded to whole texels.

    The denoiser is fully convolutional, so noise of another shape gives a
    shape of another size; nothing is kept. The box grows or shrinks about its
    centre.
    """
    f = _factors(factors, "resize")
    base = np.array(latent.resolution)
    res = tuple(int(r) for r in np.maximum(4, np.round(base * f)))
    scale = np.array(res) / base
    aabb = np.asarray(aabb, np.float32)
    box = np.concatenate([aabb[:3] * scale, aabb[3:] * scale]).astype(np.float32)
    return Plan("retarget", res, box, latent.resized(res), request={"factors": tuple(float(x) for x in f)})


def _anchor_offset(anchor: str, base, res) -> np.ndarray:
    if anchor not in ANCHORS:
        raise Sin3DMInputError(f"unknown anchor '{anchor}'; choose one of: {', '.join(ANCHORS)}")
    off = (np.array(res) - np.array(base)) // 2
    if anchor != "center":
        axis = "xyz".index(anchor[0])
        off[axis] = 0 if anchor[1] == "-" else res[axis] - base[axis]
    return off


def outpaint(latent: Triplane, aabb, factors, anchor: str = "center", border: float = BORDER, trim: int = 0) -> Plan:
    """A box ``factors`` (each ≥ 1) times the input's, the input kept where it was, the rest generated.

    ``anchor`` says where the input sits in the larger box: ``"center"``, or
    a face it sticks to (``"x-"``: the input's low-x face stays the box's,
    so the shape grows towards +x). The result's box extends the input's box.
    The paper pads ``y0`` with zeros; here the padding repeats the input's
    edge texels, which only matters for ``start``, never where the mask keeps.

    ``trim`` texels of the input are not kept on each side that grows: the
    model's box holds a few voxels of empty margin around the shape; kept, they
    would separate the input from what grows out of it by a crack.
    """
    f = _factors(factors, "outpaint", at_least=1.0)
    base = np.array(latent.resolution)
    res = tuple(int(r) for r in np.maximum(base, np.round(base * f)))
    off = _anchor_offset(anchor, base, res)
    pads = [(int(o), int(r - b - o)) for o, r, b in zip(off, res, base)]
    planes = []
    for name, (a, b) in zip(PLANES, PLANE_AXES.values()):
        p = getattr(latent, name)
        # F.pad takes the last dimension first: (b_lo, b_hi, a_lo, a_hi); "replicate" repeats the edge texels
        planes.append(torch.nn.functional.pad(p, (*pads[b], *pads[a]), mode="replicate"))
    known = Triplane(*planes)
    profiles = []
    for r, o, n in zip(res, off, base):
        lo = o + trim if o > 0 else o  # a side that grows gives up its margin
        hi = o + n - trim if o + n < r else o + n
        if hi - lo < 1:
            raise Sin3DMInputError(
                f"nothing of the input is left to keep after trimming {trim} texels of margin; "
                "the latent is too small to outpaint"
            )
        profiles.append(_profile(r, lo, hi, border, ramp_lo=o > 0, ramp_hi=o + n < r))
    request = {"factors": tuple(float(x) for x in f), "anchor": anchor, "trim": trim}
    return Plan("outpaint", res, _box_aabb(aabb, base, -off, res), known, known, _mask(profiles), request)


def regenerate(latent: Triplane, aabb, box, border: float = BORDER) -> Plan:
    """Local editing: resample the inside of ``box`` (fractions of the model's box), keep everything else.

    A plane's texel is shared by the whole line of points across it, so it is
    kept wherever that line passes through the kept part: a plane is freed
    (inside the box's shadow) only when the box spans the whole axis across
    it. "Regenerate the middle third along x" therefore frees the xy and xz
    planes there and keeps the yz plane; the box must reach the model's faces
    along at least one axis. The mask ramps from 0 at the box's faces to 1
    ``border`` texels outside them, so the new part blends into the kept one.
    """
    res = latent.resolution
    ranges = _box(box, res, "the box to regenerate")
    spans = [a == 0 and b == n for (a, b), n in zip(ranges, res)]
    if not any(spans):
        raise Sin3DMInputError(
            "the box to regenerate must reach the model's box faces along at least one axis (e.g. z from 0 to 1): "
            "a triplane shares each plane's features with the whole line across it, so a pocket inside the shape "
            "cannot be resampled on its own"
        )
    prof = [_outside_profile(n, a, b, border) for n, (a, b) in zip(res, ranges)]
    planes = []
    for a, b in PLANE_AXES.values():
        free = np.outer(prof[a], prof[b]) if spans[3 - a - b] else np.zeros((res[a], res[b]))
        planes.append(torch.from_numpy(1 - free).float()[None, None])
    request = {"box": [list(map(float, c)) for c in box]}
    return Plan("regenerate", res, np.asarray(aabb, np.float32).copy(), latent, latent, Triplane(*planes), request)


def keep_planes(latent: Triplane, aabb, planes) -> Plan:
    """Keep whole planes of the input's latent (``"xz"``, or several: ``["xy", "yz"]``) and sample the others.

    Not one of the paper's operations: a way to see which plane holds a shape's variation. A plane's texel
    is shared by the whole line of points across it, so the ground plan (``xz``, y up) decides what lies where
    in every horizontal slice at once: kept, the samples keep the input's layout.
    """
    names = [planes] if isinstance(planes, str) else list(planes)
    unknown = [p for p in names if p not in PLANES]
    if unknown or not names:
        raise Sin3DMInputError(f"planes to keep: one or more of {', '.join(PLANES)} (got {names!r})")
    mask = Triplane(*[torch.full((1, 1, *p.shape[-2:]), float(n in names)) for n, p in zip(PLANES, latent.planes)])
    request = {"planes": [p for p in PLANES if p in names]}
    return Plan("keep planes", latent.resolution, np.asarray(aabb, np.float32).copy(), latent, latent, mask, request)


def duplicate(latent: Triplane, aabb, box, to, border: float = BORDER, trim: int = 0) -> Plan:
    """Patch duplication: copy the part of the input in ``box`` so that its low corner lands at ``to``.

    Both fractions of the model's box. The copy and its source are kept (the
    paper: "the mask m corresponds to the regions of the copied patches"),
    everything else is generated around them. Each plane copies the box's
    shadow, so inside the destination box the latent is the source's exactly.

    Where the box reaches a face of the model's box that the copy does not,
    ``trim`` texels there (the empty margin) are left out of the copy.
    """
    res = latent.resolution
    src = _box(box, res, "the box to copy")
    try:
        to = np.asarray(to, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise Sin3DMInputError(f"the place to copy to must be a corner (x, y, z), got {to!r}") from None
    if not np.all(np.isfinite(to)) or np.any(to < 0):
        raise Sin3DMInputError(f"the place to copy to must be fractions of the model's box in [0, 1], got {_fmt(to)}")
    dst = [(int(round(t * n)), int(round(t * n)) + (b - a)) for t, n, (a, b) in zip(to, res, src)]
    over = [ax for ax, (a, b), n in zip("xyz", dst, res) if b > n]
    if over:
        raise Sin3DMInputError(
            f"the copy of the box does not fit when its low corner is at {_fmt(to)}: it leaves "
            f"the model's box along {', '.join(over)}; move it or make the box smaller"
        )
    for ax, n in enumerate(res):  # leave the margin behind where the copy moves away from a face
        (a, b), (c, d) = src[ax], dst[ax]
        if a == 0 and c > 0 and b - a > trim:
            src[ax], dst[ax] = (a + trim, b), (c + trim, d)
        (a, b), (c, d) = src[ax], dst[ax]
        if b == n and d < n and b - a > trim:
            src[ax], dst[ax] = (a, b - trim), (c, d - trim)
    if all(d[0] < s[1] and s[0] < d[1] for d, s in zip(dst, src)):
        raise Sin3DMInputError("the copy overlaps the box it copies; move it further away")
    planes = []
    for name, (a, b) in zip(PLANES, PLANE_AXES.values()):
        p = getattr(latent, name).clone()
        p[..., dst[a][0] : dst[a][1], dst[b][0] : dst[b][1]] = getattr(latent, name)[
            ..., src[a][0] : src[a][1], src[b][0] : src[b][1]
        ]
        planes.append(p)
    known = Triplane(*planes)
    keep_src = _mask([_profile(n, a, b, border, a > 0, b < n) for n, (a, b) in zip(res, src)])
    keep_dst = _mask([_profile(n, a, b, border, a > 0, b < n) for n, (a, b) in zip(res, dst)])
    request = {"box": [list(map(float, c)) for c in box], "to": tuple(float(t) for t in to), "trim": trim}
    return Plan(
        "duplicate", res, np.asarray(aabb, np.float32).copy(), known, known, _union(keep_src, keep_dst), request
    )


__all__ = ["ANCHORS", "BORDER", "Plan", "duplicate", "outpaint", "regenerate", "retarget", "texel_range"]

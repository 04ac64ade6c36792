"""Geometry metrics of the paper's evaluation that need no pre-trained network.

Everything works on *occupancy grids*: boolean ``(X, Y, Z)`` arrays on the
same cell-centred grid that :mod:`sin3dm_lite.extract` decodes on (``resolution``
voxels along the longest side of a box, the paper uses 128).

* :func:`voxelize` — mesh → occupancy grid; :func:`input_occupancy` — the
  same for the input mesh (open meshes too), the reference of the LP metrics.
* :func:`iou`, :func:`g_div` — whole-shape overlap and the diversity score
  G-Div = mean pairwise ``1 − IoU`` among generated shapes. Whole-shape
  comparisons need every grid to have the same shape, so retargeted samples
  (another box) cannot enter G-Div with the others.
* :func:`lp_iou`, :func:`lp_fscore` (:func:`lp_scores` computes both) — local
  patch quality: does every small piece of a generated shape look like *some*
  piece of the reference? These only compare 11³ patches, so they work for
  shapes of any grid size as long as the voxel size is the same.

Texture metrics compare *renders* (:func:`sin3dm_lite.render.render_views`:
the paper's 8 views, azimuth every 45°, elevation 45°, all framed by the
input's box) view by view:

* weight-free, always available: :func:`patch_swd` (our stand-in for the
  paper's T-Qual = SIFID) and :func:`render_div` (our stand-in for T-Div =
  LPIPS); :func:`t_qual` and :func:`t_div` average any image distance the
  paper's way;
* with pre-trained weights given *by path* (never downloaded):
  :func:`sifid` (InceptionV3's first block) and :func:`lpips` (AlexNet +
  LPIPS's linear layers), loaded by :func:`load_feature_weights`.

G-Qual = SSFID needs SSG's 3D voxel encoder pre-trained on ShapeNet, whose
weights are not published in a loadable form: it is not here (see
:data:`SSFID_UNAVAILABLE`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..errors import Sin3DMInputError
from ..data.box import as_aabb, axis_centres, grid_shape, to_index
from ..generate.extract import rasterize_triangles

#: Tiny shift (in voxels) of the mesh against the ray grid: marching-cubes vertices of the same grid lie
#: exactly on the rays, and a ray through an edge would be counted twice.
_RAY_JITTER = np.array([3.1e-6, 2.3e-6])


def _verts_faces(mesh) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(mesh, (tuple, list)):
        verts, faces = mesh
    else:  # TexturedMesh, trimesh.Trimesh
        verts, faces = mesh.vertices, mesh.faces
    return np.asarray(verts, np.float64), np.asarray(faces, np.int64)


# ----------------------------------------------------------------------------- the autoencoder's reconstruction
def reconstruction_metrics(reconstruction, grid) -> dict[str, float]:
    """How well a reconstruction (``decode.reconstructed_grid``, both ``ShapeGrid``) reproduces the input grid.

    * ``sign_accuracy``: share of voxels where the decoded SDF has the input's sign;
    * ``occupancy_iou``: IoU of the inside voxels (SDF < 0);
    * ``occupancy_iou_quarter_voxel``: the same IoU leaving out voxels whose centre lies
      within a quarter voxel of the input surface. Their sign flips with any sub-voxel
      shift of the surface, and a mesh whose flat faces run along a layer of voxel
      centres (a block filling its box) has thousands of them;
    * ``color_l1`` / ``color_psnr``: colour error on voxels within the truncation band.

    PBR grids (``grid.has_pbr``) add, on the same voxels: ``metallic_l1``,
    ``roughness_l1``, ``normal_angle_deg`` (mean angle between the decoded
    and the input normal) and ``metallic_iou`` (IoU of the ``metallic > 0.5``
    voxels: are the metal parts in the same places?).
    """
    sdf, col = reconstruction.sdf, reconstruction.color[..., :3]
    gt_in, pr_in = grid.sdf < 0, sdf < 0
    clear = np.abs(grid.sdf) >= 0.25 * grid.voxel_size
    band = np.abs(grid.sdf) < grid.threshold
    err = col[band] - grid.color[band][:, :3]
    mse = float((err**2).mean()) if band.any() else float("nan")
    out = {
        "sign_accuracy": float((gt_in == pr_in).mean()),
        "occupancy_iou": iou(gt_in, pr_in),
        "occupancy_iou_quarter_voxel": iou(gt_in[clear], pr_in[clear]),
        "color_l1": float(np.abs(err).mean()) if band.any() else float("nan"),
        "color_psnr": float(10 * math.log10(1.0 / max(mse, 1e-12))),
    }
    if getattr(grid, "has_pbr", False) and reconstruction.color.shape[-1] == grid.color.shape[-1] and band.any():
        rec, ref = reconstruction.color[band], grid.color[band]
        n_rec, n_ref = rec[:, 5:8] * 2 - 1, ref[:, 5:8] * 2 - 1
        n_rec = n_rec / np.maximum(np.linalg.norm(n_rec, axis=1, keepdims=True), 1e-8)
        n_ref = n_ref / np.maximum(np.linalg.norm(n_ref, axis=1, keepdims=True), 1e-8)
        cos = np.clip(np.einsum("ij,ij->i", n_rec, n_ref), -1, 1)
        out.update(
            metallic_l1=float(np.abs(rec[:, 3] - ref[:, 3]).mean()),
            roughness_l1=float(np.abs(rec[:, 4] - ref[:, 4]).mean()),
            normal_angle_deg=float(np.degrees(np.arccos(cos)).mean()),
            metallic_iou=iou(ref[:, 3] > 0.5, rec[:, 3] > 0.5),
        )
    return out


# ----------------------------------------------------------------------------- voxelisation
def voxelize(mesh, aabb, resolution: int = 128) -> np.ndarray:
    """Occupancy of the voxel centres of a grid over ``aabb`` → bool ``(X, Y, Z)``.

    Ray casting along +z through every column of voxel centres: each triangle
    the ray crosses adds +1 (leaving the shape, normal pointing up) or −1
    (entering); a voxel is inside when the crossings above it do not cancel
    (a winding number along the ray). This fills closed shells, handles
    nested or overlapping closed pieces, and does not care whether the whole
    mesh is oriented inwards or outwards; it needs a closed mesh (marching
    cubes output is).

    Args:
        mesh: a ``TexturedMesh``, ``trimesh.Trimesh`` or ``(verts, faces)``,
            in the same coordinates as ``aabb`` (normalised coordinates: use
            ``extract_mesh(..., original_coords=False)``).
        resolution: voxels along the box's longest side (the paper uses 128).
    """
    verts, faces = _verts_faces(mesh)
    box = as_aabb(aabb)
    shape = grid_shape(box, resolution)
    nx, ny, nz = shape
    # continuous voxel index: voxel centre k sits at k
    idx = to_index(verts, box, shape)
    idx[:, :2] += _RAY_JITTER
    tri = idx[faces]
    f, x, y, bary = rasterize_triangles(tri[:, :, :2], nx, ny, eps=0.0)
    ab, ac = tri[:, 1, :2] - tri[:, 0, :2], tri[:, 2, :2] - tri[:, 0, :2]
    sign = np.sign(ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])[f]  # z of the normal: +1 exit, −1 entry
    z_hit = np.einsum("nk,nk->n", bary, tri[f, :, 2])
    m = np.clip(np.ceil(z_hit), 0, nz).astype(np.int64)  # the hit lies above voxels k < m
    acc = np.bincount((x * ny + y) * (nz + 1) + m, weights=sign, minlength=nx * ny * (nz + 1))
    acc = acc.reshape(nx, ny, nz + 1)
    winding = np.cumsum(acc[..., ::-1], axis=-1)[..., ::-1]  # winding[k] = sum of acc[m] for m >= k
    return np.abs(np.rint(winding[..., 1:])) > 0


def input_occupancy(mesh, aabb, resolution: int = 128) -> np.ndarray:
    """The *input* mesh as an occupancy grid: inside (winding number > ½) at every voxel centre.

    This is the reference the paper's LP-IoU / LP-F compare against. Unlike
    :func:`voxelize` it needs no closed mesh (a user's open scan works). The
    mesh (a ``TexturedMesh``, ``trimesh.Trimesh`` or ``(verts, faces)``) must be in the same (normalised) coordinates as ``aabb``, e.g.
    ``mesh.normalized()`` for the box a fit used.
    """
    from ..data.grid import inside

    box = as_aabb(aabb)
    shape = grid_shape(box, resolution)
    axes = [axis_centres(box, shape, a) for a in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return inside(*_verts_faces(mesh), centres).reshape(shape)


# ----------------------------------------------------------------------------- whole-shape overlap
def check_same_grid(grids: list[np.ndarray]) -> None:
    """Refuse occupancy grids of different shapes (one clear error): they cannot be compared voxel by voxel."""
    shapes = {tuple(np.shape(g)) for g in grids}
    if len(shapes) > 1:
        raise Sin3DMInputError(
            f"occupancy grids of different shapes {sorted(shapes)} cannot be compared voxel by voxel; "
            "voxelise every shape in the same box and resolution (retargeted samples need their own set)"
        )


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two occupancy grids of the same shape (1.0 when both are empty)."""
    check_same_grid([a, b])
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    union = np.logical_or(a, b).sum()
    return 1.0 if union == 0 else float(np.logical_and(a, b).sum() / union)


def pairwise_iou(grids) -> np.ndarray:
    """``(n, n)`` IoU matrix of occupancy grids that share one shape."""
    grids = [np.asarray(g, bool) for g in grids]
    check_same_grid(grids)
    grids = [g.reshape(-1) for g in grids]
    n = len(grids)
    out = np.ones((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            union = np.count_nonzero(grids[i] | grids[j])
            out[i, j] = out[j, i] = 1.0 if union == 0 else np.count_nonzero(grids[i] & grids[j]) / union
    return out


def g_div(grids) -> float:
    """G-Div: mean of ``1 − IoU`` over all pairs of generated shapes (0 = all identical, 1 = all disjoint).

    The grids must share one shape (same box and resolution); retargeted
    samples are not comparable to the others.
    """
    grids = list(grids)
    if len(grids) < 2:
        raise Sin3DMInputError(f"g_div needs at least two shapes, got {len(grids)}")
    m = pairwise_iou(grids)
    i, j = np.triu_indices(len(grids), k=1)
    return float(np.mean(1.0 - m[i, j]))


def g_div_by_layer(grids, axis: int = 1) -> np.ndarray:
    """G-Div split over the layers of the grid along ``axis`` (1, y: heights): where the samples differ.

    ``1 − IoU(a, b) = |a xor b| / |a ∪ b|``, and the voxels two samples
    disagree on are a sum over layers. Entry ``k`` is the mean over pairs of
    the disagreeing voxels in layer ``k`` divided by the pair's union, so the
    entries sum to :func:`g_div`. A wall's samples keep its brick body and
    differ almost only in the layers of its top; a canyon's differ at every
    height its river and terraces reach.
    """
    grids = [np.asarray(g, bool) for g in grids]
    if len(grids) < 2:
        raise Sin3DMInputError(f"g_div_by_layer needs at least two shapes, got {len(grids)}")
    check_same_grid(grids)
    if axis not in (0, 1, 2):
        raise Sin3DMInputError(f"axis must be 0, 1 or 2 (x, y, z), got {axis!r}")
    other = tuple(a for a in range(3) if a != axis)
    out = np.zeros(grids[0].shape[axis])
    i, j = np.triu_indices(len(grids), k=1)
    for a, b in zip(i, j):
        union = np.count_nonzero(grids[a] | grids[b])
        if union:
            out += (grids[a] ^ grids[b]).sum(other) / union
    return out / len(i)


def variation_scores(reference: np.ndarray, samples) -> dict:
    """How far samples stray from the input and from each other (occupancy grids in one box).

    Returns ``iou_to_input`` (mean IoU of each sample with ``reference``: near 1
    means copies of the input), ``per_sample_iou`` (the list) and ``g_div``
    (:func:`g_div` of the samples; None for a single sample).
    """
    samples = list(samples)
    per = [iou(s, reference) for s in samples]
    return {"iou_to_input": float(np.mean(per)), "per_sample_iou": per,
            "g_div": g_div(samples) if len(samples) > 1 else None}


def reconstruction_iou(mesh_a, mesh_b, aabb, resolution: int = 128) -> float:
    """IoU of two meshes voxelised in the same box (e.g. the input and its autoencoder reconstruction)."""
    return iou(voxelize(mesh_a, aabb, resolution), voxelize(mesh_b, aabb, resolution))


# ----------------------------------------------------------------------------- local patches
def extract_patches(grid: np.ndarray, patch: int = 11, stride: int = 5, center: int = 3) -> np.ndarray:
    """Surface patches of an occupancy grid → bool ``(n, patch**3)``.

    The grid is zero-padded by ``patch // 2`` on every side, so patches are
    centred on voxels ``0, stride, 2·stride, ...`` of each axis. A patch is
    kept when its central ``center³`` block holds both occupied and empty
    voxels, i.e. it straddles the surface.
    """
    g = np.pad(np.asarray(grid, bool), patch // 2)
    windows = np.lib.stride_tricks.sliding_window_view(g, (patch,) * 3)[::stride, ::stride, ::stride]
    c0 = (patch - center) // 2
    count = windows[..., c0:c0 + center, c0:c0 + center, c0:c0 + center].sum(axis=(-3, -2, -1))
    valid = (count > 0) & (count < center**3)
    return windows[valid].reshape(-1, patch**3)


def _best_matches(gen: np.ndarray, ref: np.ndarray, max_entries: int = 2**23,
                  return_index: bool = False) -> tuple[np.ndarray, ...]:
    """For every generated patch, the best IoU and the best F-score against all reference patches
    (and, with ``return_index``, the index of the reference patch with the best IoU)."""
    g, r = gen.astype(np.float32), ref.astype(np.float32)
    gs, rs = g.sum(1), r.sum(1)
    best_iou = np.zeros(len(g), np.float64)
    best_f = np.zeros(len(g), np.float64)
    best_at = np.zeros(len(g), np.int64)
    rows = max(1, max_entries // max(len(r), 1))
    for s in range(0, len(g), rows):
        inter = g[s:s + rows] @ r.T  # (m, n_ref) overlap counts, exact in float32
        size_sum = gs[s:s + rows, None] + rs[None, :]
        ious = inter / (size_sum - inter)
        best_at[s:s + rows] = ious.argmax(axis=1)
        best_iou[s:s + rows] = ious.max(axis=1)
        best_f[s:s + rows] = (2 * inter / size_sum).max(axis=1)
    return (best_iou, best_f, best_at) if return_index else (best_iou, best_f)


def lp_scores(reference: np.ndarray, generated, patch: int = 11, stride: int = 5, center: int = 3,
              max_patches: int = 1000, threshold: float = 0.95, seed: int = 0) -> dict:
    """LP-IoU and LP-F-score (REFERENCE.md "Evaluation", from the SSG / Sin3DM evaluation).

    For each generated shape: take its surface patches (:func:`extract_patches`),
    keep at most ``max_patches`` of them chosen at random (``seed``), and find
    for each the best match among *all* reference patches:

    * IoU of two patches ``g`` and ``r`` (sets of occupied voxels):
      ``|g ∩ r| / |g ∪ r|``;
    * F-score: precision ``P = |g ∩ r| / |g|`` (how much of the generated
      patch's occupied voxels the reference has), recall ``R = |g ∩ r| / |r|``,
      ``F = 2PR / (P + R) = 2|g ∩ r| / (|g| + |r|)``.

    The shape's score is the fraction of its patches whose best match is above
    ``threshold`` (strictly); the metric is the mean over generated shapes.
    A generated shape without surface patches scores 0.

    Returns:
        dict with ``lp_iou``, ``lp_fscore`` (the metrics), ``lp_iou_mean_best``,
        ``lp_fscore_mean_best`` (mean best match, a softer number) and the
        per-shape lists ``per_shape_iou``, ``per_shape_fscore``.
    """
    if isinstance(generated, np.ndarray) and generated.ndim == 3:
        generated = [generated]
    ref = extract_patches(reference, patch, stride, center)
    if len(ref) == 0:
        raise Sin3DMInputError("the reference occupancy grid has no surface patches (is it empty or full?)")
    rng = np.random.default_rng(seed)
    per_iou, per_f, mean_iou, mean_f = [], [], [], []
    for grid in generated:
        gen = extract_patches(grid, patch, stride, center)
        if len(gen) > max_patches:
            gen = gen[rng.choice(len(gen), max_patches, replace=False)]
        if len(gen) == 0:
            best_iou = best_f = np.zeros(1)
        else:
            best_iou, best_f = _best_matches(gen, ref)
        per_iou.append(float(np.mean(best_iou > threshold)))
        per_f.append(float(np.mean(best_f > threshold)))
        mean_iou.append(float(best_iou.mean()))
        mean_f.append(float(best_f.mean()))
    return {
        "lp_iou": float(np.mean(per_iou)),
        "lp_fscore": float(np.mean(per_f)),
        "lp_iou_mean_best": float(np.mean(mean_iou)),
        "lp_fscore_mean_best": float(np.mean(mean_f)),
        "per_shape_iou": per_iou,
        "per_shape_fscore": per_f,
    }


def lp_iou(reference: np.ndarray, generated, patch: int = 11, stride: int = 5, center: int = 3,
           max_patches: int = 1000, threshold: float = 0.95, seed: int = 0) -> float:
    """LP-IoU: mean fraction of generated patches whose best reference IoU exceeds ``threshold``.

    See :func:`lp_scores`, which computes LP-IoU and LP-F-score in one pass.
    """
    return lp_scores(reference, generated, patch, stride, center, max_patches, threshold, seed)["lp_iou"]


def lp_fscore(reference: np.ndarray, generated, patch: int = 11, stride: int = 5, center: int = 3,
              max_patches: int = 1000, threshold: float = 0.95, seed: int = 0) -> float:
    """LP-F-score: as :func:`lp_iou` with the patch F-score (Dice) instead of IoU; see :func:`lp_scores`."""
    return lp_scores(reference, generated, patch, stride, center, max_patches, threshold, seed)["lp_fscore"]


def patch_matches(reference: np.ndarray, generated: np.ndarray, n: int = 4, patch: int = 11, stride: int = 5,
                  center: int = 3, max_patches: int = 1000, seed: int = 0) -> dict:
    """What LP-IoU compares, for a picture: ``n`` surface patches of one generated grid and their best input patch.

    The patches are those :func:`lp_scores` takes (same ``patch``, ``stride``,
    ``center``, ``max_patches`` and ``seed``); the ``n`` shown are spread evenly
    over the range of best IoU, from the worst-matched patch to the best one.

    Returns ``generated`` and ``matched`` (``(n, patch, patch, patch)`` bool: the
    generated patches and, for each, the input patch with the highest IoU),
    their ``iou`` and ``fscore`` (``(n,)``), ``best_iou`` (every compared patch's
    best IoU: LP-IoU is the share of these above the threshold) and ``threshold``.
    """
    ref = extract_patches(reference, patch, stride, center)
    gen = extract_patches(generated, patch, stride, center)
    if len(ref) == 0 or len(gen) == 0:
        raise Sin3DMInputError("both occupancy grids need surface patches (is one of them empty or full?)")
    if len(gen) > max_patches:  # the same subset lp_scores draws for a first (or only) shape
        gen = gen[np.random.default_rng(seed).choice(len(gen), max_patches, replace=False)]
    best_iou, _, best_at = _best_matches(gen, ref, return_index=True)
    order = np.argsort(best_iou, kind="stable")
    pick = order[np.unique(np.round(np.linspace(0, len(order) - 1, min(n, len(order)))).astype(int))]
    g, r = gen[pick].astype(np.float64), ref[best_at[pick]].astype(np.float64)
    inter = (g * r).sum(1)
    cube = (len(pick), patch, patch, patch)
    return {"generated": gen[pick].reshape(cube), "matched": ref[best_at[pick]].reshape(cube),
            "iou": best_iou[pick], "fscore": 2 * inter / (g.sum(1) + r.sum(1)), "best_iou": best_iou,
            "threshold": 0.95}


# ----------------------------------------------------------------------------- geometry, all at once
def geometry_scores(reference: np.ndarray, samples) -> dict:
    """The paper's weight-free geometry metrics of generated shapes against the input (occupancy grids, one box).

    * ``g_div`` — G-Div: mean pairwise ``1 − IoU`` among the samples (higher = more diverse; None for one sample);
    * ``lp_iou``, ``lp_fscore`` — LP-IoU / LP-F: share of the samples' local 11³ patches that have a near-exact
      match (> 0.95) somewhere in the input (higher = locally more plausible), see :func:`lp_scores`;
    * ``iou_to_input`` — mean IoU of each sample with the input (near 1 = copies of the input).
    """
    samples = list(samples)
    lp, var = lp_scores(reference, samples), variation_scores(reference, samples)
    return {"g_div": var["g_div"], "lp_iou": lp["lp_iou"], "lp_fscore": lp["lp_fscore"],
            "iou_to_input": var["iou_to_input"]}


# ----------------------------------------------------------------------------- texture: weight-free
#: renders have a white background (render.BACKGROUND); pixels of exactly this colour are not the shape
BACKGROUND = 255


def _image(img) -> torch.Tensor:
    """An ``(H, W, 3)`` uint8 picture (or floats in [0, 1]) → float tensor ``(1, 3, H, W)`` in [0, 1]."""
    a = np.asarray(img)
    if a.ndim != 3 or a.shape[2] < 3:
        raise Sin3DMInputError(f"expected an (H, W, 3) picture, got an array of shape {a.shape}")
    a = a[..., :3].astype(np.float32) / (255.0 if a.dtype == np.uint8 else 1.0)
    return torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)[None]


def foreground(img) -> np.ndarray:
    """Pixels of a render that show the shape: ``(H, W)`` bool, every pixel not of the white background."""
    a = np.asarray(img)
    white = BACKGROUND if a.dtype == np.uint8 else 1.0
    return np.any(a[..., :3] != white, axis=-1)


def _patch_set(x: torch.Tensor, mask: torch.Tensor, patch: int, max_patches: int, seed: int) -> torch.Tensor:
    """Patches of ``x`` ``(1, 3, H, W)`` centred on ``mask`` pixels (all pixels if none) → ``(n, 3·patch²)``.

    Outside the picture counts as background (white).
    """
    centres = mask.reshape(-1).nonzero()[:, 0]
    if len(centres) == 0:
        centres = torch.arange(mask.numel())
    if len(centres) > max_patches:  # the same subset for the same count: identical pictures stay identical
        centres = centres[torch.randperm(len(centres), generator=torch.Generator().manual_seed(seed))[:max_patches]]
    w = x.shape[-1]
    r = torch.arange(patch)
    ys = (centres // w)[:, None, None] + r[None, :, None]  # rows of the padded picture, (n, p, 1)
    xs = (centres % w)[:, None, None] + r[None, None, :]
    padded = F.pad(x[0], (patch // 2,) * 4, value=1.0)
    return padded[:, ys, xs].permute(1, 0, 2, 3).reshape(len(centres), -1)  # (n, 3·p·p)


def _quantiles(sorted_values: torch.Tensor, m: int) -> torch.Tensor:
    """``m`` evenly spaced quantiles of each column of a sorted ``(n, P)`` tensor (linear interpolation)."""
    n = len(sorted_values)
    if n == m:
        return sorted_values
    pos = torch.linspace(0, n - 1, m, dtype=torch.float64)
    lo = pos.floor().long()
    hi = torch.clamp(lo + 1, max=n - 1)
    w = (pos - lo).to(sorted_values.dtype)[:, None]
    return sorted_values[lo] * (1 - w) + sorted_values[hi] * w


@torch.no_grad()
def patch_swd(a, b, patch: int = 7, levels: int = 3, projections: int = 128, max_patches: int = 4096,
              seed: int = 0) -> float:
    """Sliced Wasserstein distance between the multi-scale patch distributions of two renders (0 = same patches).

    Our weight-free stand-in for the paper's **T-Qual = SIFID** — *not* SIFID
    (no Inception features; numbers are not comparable with the paper's).
    Like SIFID it compares the *distribution* of local appearance, not pixel
    positions: a sample whose texture is made of the input's pieces, moved
    around, scores low; wrong colours, blur or noise score high.

    On each of ``levels`` levels of an image pyramid (2×2 average pooling) take
    the ``patch × patch`` RGB patches centred on shape pixels (not the white
    background; at most ``max_patches``, a fixed random subset), project both
    sets on ``projections`` random unit directions (fixed ``seed``), and average
    the 1D Wasserstein-1 distances (mean absolute difference of the sorted
    projections); the result is the mean over levels, in colour units (0–1).
    """
    xa, xb = _image(a), _image(b)
    ma = torch.from_numpy(foreground(a))[None, None].float()
    mb = torch.from_numpy(foreground(b))[None, None].float()
    dirs = torch.randn(3 * patch * patch, projections, generator=torch.Generator().manual_seed(seed))
    dirs /= dirs.norm(dim=0, keepdim=True)
    total = 0.0
    for level in range(levels):
        if level:
            xa, xb, ma, mb = (F.avg_pool2d(t, 2) for t in (xa, xb, ma, mb))
        # (n, P) projections, sorted per direction (numpy's sort: torch's along dim 0 is ten times slower here)
        pa = torch.from_numpy(np.sort((_patch_set(xa, ma > 0.5, patch, max_patches, seed + level) @ dirs).numpy(), 0))
        pb = torch.from_numpy(np.sort((_patch_set(xb, mb > 0.5, patch, max_patches, seed + level) @ dirs).numpy(), 0))
        m = max(len(pa), len(pb))
        total += float((_quantiles(pa, m) - _quantiles(pb, m)).abs().mean())
    return total / levels


def colour_distance(a, b) -> float:
    """Mean absolute colour difference (0–1) of two renders of one view, over the pixels where either shows the shape.

    The pixel-aligned distance behind :func:`render_div`; 0 for identical
    pictures, 1 between black and white.
    """
    fa, fb = foreground(a), foreground(b)
    union = fa | fb
    if not union.any():
        return 0.0
    d = np.abs(_image(a)[0].numpy() - _image(b)[0].numpy()).mean(axis=0)
    return float(d[union].mean())


def degraded(image, kind: str = "wash", amount: float = 0.6, seed: int = 0) -> np.ndarray:
    """A render changed in a known way, to see what the texture metrics react to (the background stays white).

    * ``"wash"``: the shape's colours pulled towards their mean by ``amount`` (0 = unchanged, 1 = one flat colour);
    * ``"shuffle"``: the shape's pixels permuted among themselves (the same colours, no patterns left).
    """
    img = np.asarray(image)
    img = (img if img.dtype == np.uint8 else np.round(np.clip(img, 0, 1) * 255)).astype(np.uint8)[..., :3].copy()
    fg = foreground(img)
    if kind == "wash":
        if not 0 <= amount <= 1:
            raise Sin3DMInputError(f"amount must be from 0 to 1, got {amount}")
        px = img[fg].astype(np.float64)
        washed = np.round((1 - amount) * px + amount * px.mean(0)) if len(px) else px
        img[fg] = np.minimum(washed, 254).astype(np.uint8)  # never pure white: still the shape
    elif kind == "shuffle":
        img[fg] = img[fg][np.random.default_rng(seed).permutation(int(fg.sum()))]
    else:
        raise Sin3DMInputError(f"kind must be 'wash' or 'shuffle', got {kind!r}")
    return img


def _check_views(reference_views, sample_views) -> None:
    counts = {len(v) for v in sample_views} | ({len(reference_views)} if reference_views is not None else set())
    if len(counts) > 1:
        raise Sin3DMInputError(f"every shape needs the same number of views, got {sorted(counts)}")


def t_qual(reference_views, sample_views, distance=patch_swd) -> float:
    """The paper's T-Qual average for any image ``distance``: mean over views ``i`` and samples ``j`` of
    ``distance(reference_views[i], sample_views[j][i])`` (lower = closer to the input).

    With :func:`sifid` this is T-Qual itself; with :func:`patch_swd` (the default) our weight-free stand-in.
    """
    sample_views = list(sample_views)
    _check_views(reference_views, sample_views)
    return float(np.mean([distance(r, s[i]) for s in sample_views for i, r in enumerate(reference_views)]))


def t_div(sample_views, distance=colour_distance) -> float:
    """The paper's T-Div average for any image ``distance``: mean over views and over all pairs of samples
    of the distance between their pictures of that view (higher = more diverse; needs two samples).

    With :func:`lpips` this is T-Div itself; with :func:`colour_distance` (the default) :func:`render_div`.
    """
    sample_views = list(sample_views)
    if len(sample_views) < 2:
        raise Sin3DMInputError(f"texture diversity needs at least two samples, got {len(sample_views)}")
    _check_views(None, sample_views)
    n = len(sample_views)
    return float(np.mean([distance(sample_views[j][i], sample_views[k][i])
                          for i in range(len(sample_views[0])) for j in range(n) for k in range(j + 1, n)]))


def render_div(sample_views) -> float:
    """Texture diversity: mean pairwise :func:`colour_distance` among the samples' renders, view by view.

    Our weight-free stand-in for the paper's **T-Div = LPIPS** (mean pairwise
    LPIPS), *not* LPIPS: 0 when all samples look the same from every view,
    higher as their colours and silhouettes differ (0–1, in colour units).
    """
    return t_div(sample_views, colour_distance)


# ----------------------------------------------------------------------------- texture: pre-trained features
#: where the weight files come from (documentation only: nothing is downloaded)
INCEPTION_FILES = {
    "pt_inception-2015-12-05-6726825d.pth":
        "https://github.com/mseitzer/pytorch-fid/releases/download/fid_weights/pt_inception-2015-12-05-6726825d.pth",
    "inception_v3_google-0cc3c7bd.pth": "https://download.pytorch.org/models/inception_v3_google-0cc3c7bd.pth",
}
ALEXNET_FILE = ("alexnet-owt-7be5be79.pth", "https://download.pytorch.org/models/alexnet-owt-7be5be79.pth")
LPIPS_FILE = ("alex.pth", "https://github.com/richzhang/PerceptualSimilarity/raw/master/lpips/weights/v0.1/alex.pth")
SSFID_UNAVAILABLE = ("not implemented: G-Qual (SSFID) needs SSG's 3D CNN pre-trained on ShapeNet voxels "
                     "(Wu & Zheng 2022), a network and weights this package does not have")


class BasicConv2d(nn.Module):
    """Inception's conv (no bias) + BatchNorm (eps 0.001) + ReLU; names as in torchvision / pytorch-fid."""

    def __init__(self, cin: int, cout: int, stride: int = 1, padding: int = 0):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, 3, stride=stride, padding=padding, bias=False)
        self.bn = nn.BatchNorm2d(cout, eps=0.001)

    def forward(self, x):
        return F.relu(self.bn(self.conv(x)))


class InceptionStem(nn.Module):
    """InceptionV3 up to its first max-pool: the 64-channel features SinGAN's SIFID compares."""

    def __init__(self):
        super().__init__()
        self.Conv2d_1a_3x3 = BasicConv2d(3, 32, stride=2)
        self.Conv2d_2a_3x3 = BasicConv2d(32, 32)
        self.Conv2d_2b_3x3 = BasicConv2d(32, 64, padding=1)

    def forward(self, x):  # (B, 3, H, W) in [0, 1] → (B, 64, ~H/4, ~W/4)
        x = 2 * x - 1  # pytorch-fid's input scaling (torchvision's transform_input amounts to the same)
        x = self.Conv2d_2b_3x3(self.Conv2d_2a_3x3(self.Conv2d_1a_3x3(x)))
        return F.max_pool2d(x, 3, stride=2)


class _Lin(nn.Module):
    """LPIPS's NetLinLayer: dropout + 1×1 conv to one channel (keys ``linK.model.1.weight``)."""

    def __init__(self, cin: int):
        super().__init__()
        self.model = nn.Sequential(nn.Dropout(), nn.Conv2d(cin, 1, 1, bias=False))


class LPIPSAlex(nn.Module):
    """LPIPS v0.1 with AlexNet: torchvision's ``features`` layers (same indices) + the five linear layers."""

    TAPS = (1, 4, 7, 9, 11)  # the ReLU outputs LPIPS compares
    CHANNELS = (64, 192, 384, 256, 256)

    def __init__(self):
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(3, 64, 11, stride=4, padding=2), nn.ReLU(), nn.MaxPool2d(3, 2),
            nn.Conv2d(64, 192, 5, padding=2), nn.ReLU(), nn.MaxPool2d(3, 2),
            nn.Conv2d(192, 384, 3, padding=1), nn.ReLU(),
            nn.Conv2d(384, 256, 3, padding=1), nn.ReLU(),
            nn.Conv2d(256, 256, 3, padding=1), nn.ReLU(),
        )
        for k, c in enumerate(self.CHANNELS):
            self.add_module(f"lin{k}", _Lin(c))
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188])[None, :, None, None], persistent=False)
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450])[None, :, None, None], persistent=False)

    def taps(self, x):
        """Unit-normalised (over channels) features of the five ReLUs of ``x`` in [0, 1]."""
        x = ((2 * x - 1) - self.shift) / self.scale
        out = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in self.TAPS:
                out.append(x / (x.pow(2).sum(1, keepdim=True).sqrt() + 1e-10))
        return out

    def forward(self, a, b):  # (B, 3, H, W) each, in [0, 1] → (B,)
        return sum(getattr(self, f"lin{k}").model((fa - fb) ** 2).mean(dim=(2, 3))[:, 0]
                   for k, (fa, fb) in enumerate(zip(self.taps(a), self.taps(b))))


@dataclass
class FeatureNets:
    """The pre-trained networks of the paper's texture metrics (see :func:`load_feature_weights`)."""

    inception: InceptionStem
    lpips: LPIPSAlex


def _read_weights(path: Path, url: str) -> dict:
    try:
        sd = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - truncated, not a checkpoint, holds code: one clear message
        raise Sin3DMInputError(f"cannot read weights '{path}' ({type(e).__name__}); get the original file from {url}") from None
    if not isinstance(sd, dict):
        raise Sin3DMInputError(f"weights '{path}' hold a {type(sd).__name__}, not a state dict; get the original from {url}")
    return sd


def _load_into(module: nn.Module, sd: dict, path: Path, url: str, prefix: str = "") -> None:
    """Copy the entries ``module`` needs from ``sd`` (other keys ignored); one-line error if any is missing or misshapen."""
    want = {k: v for k, v in module.state_dict().items() if not k.endswith("num_batches_tracked")}
    picked = {}
    for k, v in want.items():
        got = sd.get(prefix + k)
        if not isinstance(got, torch.Tensor) or tuple(got.shape) != tuple(v.shape):
            what = "is missing" if got is None else f"has shape {tuple(getattr(got, 'shape', ()))}, not {tuple(v.shape)}"
            raise Sin3DMInputError(f"weights '{path}' do not match: '{prefix + k}' {what}; get the original file from {url}")
        picked[k] = got.float()
    module.load_state_dict(picked, strict=False)


def load_feature_weights(weights_dir) -> FeatureNets:
    """Load the networks behind SIFID and LPIPS from files in ``weights_dir`` (nothing is downloaded).

    The folder must hold, under their standard names: InceptionV3
    (``pt_inception-2015-12-05-6726825d.pth`` of pytorch-fid, or torchvision's
    ``inception_v3_google-0cc3c7bd.pth``), torchvision's AlexNet
    (``alexnet-owt-7be5be79.pth``) and LPIPS's linear layers (``alex.pth``,
    ``lpips/weights/v0.1`` of the lpips project). Only the entries used are
    read (``torch.load(..., weights_only=True)``). A missing file or one whose
    keys do not match gives a one-line :class:`Sin3DMInputError` naming it and where to get it.
    """
    folder = Path(weights_dir)
    if not folder.is_dir():
        raise Sin3DMInputError(f"weights folder '{folder}' not found; give a folder holding "
                               f"{next(iter(INCEPTION_FILES))}, {ALEXNET_FILE[0]} and {LPIPS_FILE[0]}")
    inception = next(((folder / n, u) for n, u in INCEPTION_FILES.items() if (folder / n).is_file()), None)
    if inception is None:
        name, url = next(iter(INCEPTION_FILES.items()))
        raise Sin3DMInputError(f"'{folder / name}' not found (InceptionV3 for SIFID); download it from {url} "
                               f"(or torchvision's {list(INCEPTION_FILES)[1]}) into '{folder}'")
    for name, url in (ALEXNET_FILE, LPIPS_FILE):
        if not (folder / name).is_file():
            raise Sin3DMInputError(f"'{folder / name}' not found (for LPIPS); download it from {url} into '{folder}'")
    nets = FeatureNets(InceptionStem(), LPIPSAlex())
    _load_into(nets.inception, _read_weights(*inception), *inception)
    _load_into(nets.lpips.features, _read_weights(folder / ALEXNET_FILE[0], ALEXNET_FILE[1]), folder / ALEXNET_FILE[0],
               ALEXNET_FILE[1], prefix="features.")
    lin = nn.ModuleDict({f"lin{k}": getattr(nets.lpips, f"lin{k}") for k in range(5)})
    _load_into(lin, _read_weights(folder / LPIPS_FILE[0], LPIPS_FILE[1]), folder / LPIPS_FILE[0], LPIPS_FILE[1])
    nets.inception.eval()
    nets.lpips.eval()
    return nets


def frechet_distance(f1: np.ndarray, f2: np.ndarray) -> float:
    """Fréchet distance of two Gaussians fitted to feature sets ``(n, d)``:
    ``|μ1 − μ2|² + tr(C1 + C2 − 2 (C1^½ C2 C1^½)^½)`` (symmetric form, eigenvalues clipped at 0)."""
    f1, f2 = np.asarray(f1, np.float64), np.asarray(f2, np.float64)
    mu1, mu2 = f1.mean(0), f2.mean(0)
    c1, c2 = np.cov(f1, rowvar=False), np.cov(f2, rowvar=False)
    w, v = np.linalg.eigh(c1)
    s1 = (v * np.sqrt(np.clip(w, 0, None))) @ v.T
    cross = np.sqrt(np.clip(np.linalg.eigvalsh(s1 @ c2 @ s1), 0, None)).sum()
    return float(max(((mu1 - mu2) ** 2).sum() + np.trace(c1) + np.trace(c2) - 2 * cross, 0.0))


@torch.no_grad()
def sifid(a, b, nets: FeatureNets) -> float:
    """SIFID (SinGAN's single-image FID; the paper's **T-Qual** per view): Fréchet distance between the
    64-channel features of InceptionV3's first block at every position of one picture and of the other
    (lower = the same local appearance). Pictures at their own size (no resize to 299)."""
    fa, fb = (nets.inception(_image(x))[0].flatten(1).T.numpy() for x in (a, b))
    return frechet_distance(fa, fb)


@torch.no_grad()
def lpips(a, b, nets: FeatureNets) -> float:
    """LPIPS v0.1 (AlexNet), the paper's **T-Div** per pair: learned, weighted distance of unit-normalised
    deep features, averaged over the picture (0 = identical; higher = perceptually more different)."""
    return float(nets.lpips(_image(a), _image(b))[0])


#: the metrics of ``Sin3DM.evaluate``: (key, the paper's name, which way is better), in the order tables show them
METRICS = (("g_div", "G-Div", "higher = more diverse shapes"),
           ("lp_iou", "LP-IoU", "higher = local geometry like the input's"),
           ("lp_fscore", "LP-F", "higher = local geometry like the input's"),
           ("iou_to_input", "not in the paper", "near 1 = copies of the input"),
           ("ssfid", "G-Qual (SSFID)", "lower = better"),
           ("patch_swd", "T-Qual stand-in", "lower = texture patches like the input's (weight-free, not SIFID)"),
           ("render_div", "T-Div stand-in", "higher = more varied renders (weight-free, not LPIPS)"),
           ("sifid", "T-Qual (SIFID)", "lower = better"),
           ("lpips", "T-Div (LPIPS)", "higher = more diverse textures"))


def results_table(columns: dict, digits: int = 3) -> str:
    """Several evaluations side by side as a text table: one row per metric of :data:`METRICS`, one column each.

    ``columns`` maps a column label to a ``Sin3DM.evaluate`` result (or its
    ``"metrics"`` dict); a metric that was not computed shows as ``-``.
    """
    if not columns:
        raise Sin3DMInputError("results_table needs at least one column")
    values = {label: r.get("metrics", r) for label, r in columns.items()}
    width = max(10, digits + 4, *(len(label) for label in values))
    lines = [f"{'metric':14s} " + " ".join(f"{label:>{width}s}" for label in values) + "  paper's name: meaning"]
    for key, paper, meaning in METRICS:
        cells = ["-" if m.get(key) is None else f"{m[key]:.{digits}f}" for m in values.values()]
        lines.append(f"{key:14s} " + " ".join(f"{c:>{width}s}" for c in cells) + f"  {paper}: {meaning}")
    return "\n".join(lines)


def texture_scores(reference_views, sample_views, nets: FeatureNets | None = None) -> dict:
    """The texture metrics of renders, view by view: ``patch_swd`` and ``render_div`` always, ``sifid`` and
    ``lpips`` (the paper's T-Qual and T-Div) with ``nets``; the diversities are None for one sample."""
    sample_views = list(sample_views)
    several = len(sample_views) > 1
    out = {"patch_swd": t_qual(reference_views, sample_views, patch_swd),
           "render_div": render_div(sample_views) if several else None}
    if nets is not None:
        out["sifid"] = t_qual(reference_views, sample_views, lambda x, y: sifid(x, y, nets))
        out["lpips"] = t_div(sample_views, lambda x, y: lpips(x, y, nets)) if several else None
    return out


__all__ = [
    "FeatureNets",
    "check_same_grid",
    "InceptionStem",
    "LPIPSAlex",
    "SSFID_UNAVAILABLE",
    "METRICS",
    "colour_distance",
    "degraded",
    "extract_patches",
    "foreground",
    "frechet_distance",
    "geometry_scores",
    "load_feature_weights",
    "lpips",
    "patch_swd",
    "render_div",
    "sifid",
    "t_div",
    "t_qual",
    "texture_scores",
    "g_div",
    "input_occupancy",
    "iou",
    "lp_fscore",
    "lp_iou",
    "lp_scores",
    "pairwise_iou",
    "patch_matches",
    "reconstruction_metrics",
    "reconstruction_iou",
    "results_table",
    "variation_scores",
    "voxelize",
]

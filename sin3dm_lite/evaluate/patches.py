"""Local patches (no network): the paper's LP-IoU / LP-F-score, and what they compare.

A generated shape is *locally* like the input when each of its small surface patches (11³ voxels at 128 voxels
along the longest side) appears, almost voxel for voxel, somewhere in the input. :func:`lp_scores` is the paper's
measure (SSG's evaluation code: patches on a stride-5 lattice in both shapes); :func:`lp_scores_any_offset` is a
labelled variant, not in the paper, that matches the input's patches at *every* voxel.
"""

from __future__ import annotations

import numpy as np

from ..errors import Sin3DMInputError


def extract_patches(grid: np.ndarray, patch: int = 11, stride: int = 5, center: int = 3) -> np.ndarray:
    """Surface patches of an occupancy grid → bool ``(n, patch**3)``.

    The grid is zero-padded by ``patch // 2``, so patches are centred on voxels ``0, stride, 2·stride, ...`` of
    each axis; a patch is kept when it straddles the surface (:func:`_surface`).
    """
    return _surface_rows(_windows(grid, patch)[::stride, ::stride, ::stride], patch, center)


def _windows(grid: np.ndarray, patch: int) -> np.ndarray:
    """Every ``patch³`` window of the zero-padded grid, window ``(i, j, k)`` centred on voxel ``(i, j, k)`` (a view)."""
    g = np.pad(np.asarray(grid, bool), patch // 2)
    return np.lib.stride_tricks.sliding_window_view(g, (patch,) * 3)


def _surface(windows: np.ndarray, patch: int, center: int) -> np.ndarray:
    """Which windows straddle the surface: their central ``center³`` block holds both occupied and empty voxels."""
    c0 = (patch - center) // 2
    count = windows[..., c0 : c0 + center, c0 : c0 + center, c0 : c0 + center].sum(axis=(-3, -2, -1))
    return (count > 0) & (count < center**3)


def _surface_rows(windows: np.ndarray, patch: int, center: int) -> np.ndarray:
    """The windows that straddle the surface (:func:`_surface`), one per row."""
    return windows[_surface(windows, patch, center)].reshape(-1, patch**3)


def _best_matches(
    gen: np.ndarray, ref: np.ndarray, max_entries: int = 2**23, return_index: bool = False
) -> tuple[np.ndarray, ...]:
    """For every generated patch, the best IoU and the best F-score against all reference patches
    (and, with ``return_index``, the index of the reference patch with the best IoU)."""
    g, r = gen.astype(np.float32), ref.astype(np.float32)
    gs, rs = g.sum(1), r.sum(1)
    best_iou = np.zeros(len(g), np.float64)
    best_f = np.zeros(len(g), np.float64)
    best_at = np.zeros(len(g), np.int64)
    rows = max(1, max_entries // max(len(r), 1))
    for s in range(0, len(g), rows):
        inter = g[s : s + rows] @ r.T  # (m, n_ref) overlap counts, exact in float32
        size_sum = gs[s : s + rows, None] + rs[None, :]
        ious = inter / (size_sum - inter)
        best_at[s : s + rows] = ious.argmax(axis=1)
        best_iou[s : s + rows] = ious.max(axis=1)
        best_f[s : s + rows] = (2 * inter / size_sum).max(axis=1)
    return (best_iou, best_f, best_at) if return_index else (best_iou, best_f)


#: the error when the input's grid has no patch to compare against
_NO_PATCHES = "the reference occupancy grid has no surface patches (is it empty or full?)"


def _reference_patches(reference: np.ndarray, patch: int, stride: int, center: int) -> np.ndarray:
    ref = extract_patches(reference, patch, stride, center)
    if len(ref) == 0:
        raise Sin3DMInputError(_NO_PATCHES)
    return ref


def _grids(generated) -> list:
    """The generated shapes as a list of grids (one 3D grid, or any sequence of them)."""
    return [generated] if isinstance(generated, np.ndarray) and generated.ndim == 3 else list(generated)


def _drawn_patches(generated, patch: int, stride: int, center: int, max_patches: int, seed: int):
    """Per generated shape (one grid or a list), its surface patches, at most ``max_patches`` drawn at random."""
    rng = np.random.default_rng(seed)
    for grid in _grids(generated):
        gen = extract_patches(grid, patch, stride, center)
        yield gen[rng.choice(len(gen), max_patches, replace=False)] if len(gen) > max_patches else gen


def lp_scores(
    reference: np.ndarray,
    generated,
    patch: int = 11,
    stride: int = 5,
    center: int = 3,
    max_patches: int = 1000,
    threshold: float = 0.95,
    seed: int = 0,
) -> dict:
    """LP-IoU and LP-F-score, as the SSG / Sin3DM evaluation computes them.

    For each generated shape: take its surface patches (:func:`extract_patches`), keep at most ``max_patches`` of
    them chosen at random (``seed``), and find for each the best match among *all* reference patches, by IoU
    ``|g ∩ r| / |g ∪ r|`` and by F-score ``2|g ∩ r| / (|g| + |r|)``. The shape's score is the fraction of its patches
    whose best match is above ``threshold``; the metric is the mean over shapes (a shape without patches scores 0).

    Returns:
        dict with ``lp_iou``, ``lp_fscore`` (the metrics), ``lp_iou_mean_best``, ``lp_fscore_mean_best`` (mean
        best match, a softer number) and the per-shape lists ``per_shape_iou``, ``per_shape_fscore``.
    """
    ref = _reference_patches(reference, patch, stride, center)
    per_iou, per_f, mean_iou, mean_f = [], [], [], []
    for gen in _drawn_patches(generated, patch, stride, center, max_patches, seed):
        best_iou, best_f = _best_matches(gen, ref) if len(gen) else (np.zeros(1), np.zeros(1))
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


def lp_iou(
    reference: np.ndarray,
    generated,
    patch: int = 11,
    stride: int = 5,
    center: int = 3,
    max_patches: int = 1000,
    threshold: float = 0.95,
    seed: int = 0,
) -> float:
    """LP-IoU: mean fraction of generated patches whose best reference IoU exceeds ``threshold`` (:func:`lp_scores`)."""
    return lp_scores(reference, generated, patch, stride, center, max_patches, threshold, seed)["lp_iou"]


def lp_fscore(
    reference: np.ndarray,
    generated,
    patch: int = 11,
    stride: int = 5,
    center: int = 3,
    max_patches: int = 1000,
    threshold: float = 0.95,
    seed: int = 0,
) -> float:
    """LP-F-score: as :func:`lp_iou` with the patch F-score (Dice) instead of IoU; see :func:`lp_scores`."""
    return lp_scores(reference, generated, patch, stride, center, max_patches, threshold, seed)["lp_fscore"]


def patch_matches(
    reference: np.ndarray,
    generated: np.ndarray,
    n: int = 4,
    patch: int = 11,
    stride: int = 5,
    center: int = 3,
    max_patches: int = 1000,
    seed: int = 0,
) -> dict:
    """What LP-IoU compares, for a picture: ``n`` surface patches of one generated grid and their best input patch.

    The patches are those :func:`lp_scores` takes; the ``n`` shown are spread evenly over the range of best IoU.
    Returns ``generated`` and ``matched`` (``(n, patch, patch, patch)`` bool), their ``iou`` and ``fscore``
    (``(n,)``), ``best_iou`` (every compared patch's best IoU) and ``threshold``.
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
    return {
        "generated": gen[pick].reshape(cube),
        "matched": ref[best_at[pick]].reshape(cube),
        "iou": best_iou[pick],
        "fscore": 2 * inter / (g.sum(1) + r.sum(1)),
        "best_iou": best_iou,
        "threshold": 0.95,
    }


def lp_misses_by_band(
    reference: np.ndarray,
    generated,
    bands: int = 5,
    axis: int = 1,
    patch: int = 11,
    stride: int = 5,
    center: int = 3,
    threshold: float = 0.95,
) -> dict:
    """Where LP-IoU's misses are: the generated surface patches in ``bands`` slabs along ``axis`` (1: up), and the
    share of each slab's patches whose best IoU against the input's is not above ``threshold``.

    The slabs split the reference's occupied extent along ``axis`` evenly (patches beyond it join the end slabs);
    every surface patch counts (no subset drawn). Returns ``share`` (of all patches, per slab, bottom first),
    ``missed`` (per slab) and ``lp_iou`` (1 - the overall share missed; NaN when no grid has a surface patch).
    """
    ref = _reference_patches(reference, patch, stride, center)
    solid = np.flatnonzero(np.asarray(reference, bool).any(axis=tuple(a for a in range(3) if a != axis)))
    lo, hi = solid.min(), solid.max()
    count, missed = np.zeros(bands), np.zeros(bands)
    for grid in _grids(generated):
        win = _windows(grid, patch)[::stride, ::stride, ::stride]
        surface = _surface(win, patch, center)
        if not surface.any():
            continue
        best_iou, _ = _best_matches(win[surface].reshape(-1, patch**3), ref)
        at = np.argwhere(surface)[:, axis] * stride
        band = np.clip(((at - lo) / max(hi - lo + 1, 1) * bands).astype(int), 0, bands - 1)
        count += np.bincount(band, minlength=bands)
        missed += np.bincount(band, weights=best_iou <= threshold, minlength=bands)
    total = count.sum()
    return {
        "share": (count / max(total, 1.0)).tolist(),
        "missed": (missed / np.maximum(count, 1)).tolist(),
        "lp_iou": float(1 - missed.sum() / total) if total else float("nan"),
    }


#: the largest grid side :func:`lp_scores_any_offset` takes (the paper's 128, and retargeted boxes up to 1.5×)
ANY_OFFSET_MAX_VOXELS = 192


def _distinct_patches_at_every_voxel(grid: np.ndarray, patch: int, center: int) -> np.ndarray:
    """The surface patches centred on every voxel of ``grid``, each distinct one once → bool ``(n, patch**3)``.

    Taken a slab of 8 voxels at a time and kept bit-packed until the end, so memory grows with the number of
    distinct patches, not with all of them."""
    windows = _windows(grid, patch)
    packed = []
    for x in range(0, windows.shape[0], 8):  # the same surface test as extract_patches, so stride 5 ⊂ stride 1
        rows = np.packbits(_surface_rows(windows[x : x + 8], patch, center), axis=1)
        packed.append(rows[_first_of_each(rows)])
    packed = np.ascontiguousarray(np.concatenate(packed))
    if len(packed) == 0:
        raise Sin3DMInputError(_NO_PATCHES)
    return np.unpackbits(packed[np.sort(_first_of_each(packed))], axis=1, count=patch**3).astype(bool)


def _first_of_each(rows: np.ndarray) -> np.ndarray:
    """The index of each distinct row's first occurrence (rows sorted by their bytes)."""
    return np.unique(rows.view(np.dtype((np.void, rows.shape[1]))).ravel(), return_index=True)[1]


def lp_scores_any_offset(
    reference: np.ndarray,
    generated,
    patch: int = 11,
    stride: int = 5,
    center: int = 3,
    max_patches: int = 1000,
    threshold: float = 0.95,
    seed: int = 0,
) -> dict:
    """LP-IoU and LP-F with the input's patches at *every* voxel: **not the paper's metric**, a labelled variant.

    :func:`lp_scores` takes both shapes' patches on one stride-5 lattice, so a perfect copy moved by one voxel loses
    most of its patches; here the patches :func:`lp_scores` draws are matched against the input's centred on every
    voxel. The search is exact but pruned: identical input patches are kept once, and each generated patch meets
    only input patches whose voxel count could reach the threshold. Returns ``lp_iou_any_offset``,
    ``lp_fscore_any_offset`` and the per-shape lists ``per_shape_iou``, ``per_shape_fscore``.
    """
    if not 0.0 < threshold < 1.0:
        raise Sin3DMInputError(f"threshold must lie between 0 and 1, got {threshold!r}")
    if max(np.shape(reference)) > ANY_OFFSET_MAX_VOXELS:
        raise Sin3DMInputError(
            f"lp_scores_any_offset takes grids of at most {ANY_OFFSET_MAX_VOXELS} voxels a side (its search holds "
            f"every distinct input patch in memory), got {np.shape(reference)}; evaluate at 128, as the paper does"
        )
    ref = _distinct_patches_at_every_voxel(reference, patch, center)
    ref_count = ref.sum(1, dtype=np.int64)
    order = np.argsort(ref_count, kind="stable")
    ref, ref_count = ref[order].astype(np.float32), ref_count[order]
    per_iou, per_f = [], []
    for gen in _drawn_patches(generated, patch, stride, center, max_patches, seed):
        hit_iou, hit_f = np.zeros(len(gen), bool), np.zeros(len(gen), bool)
        count = gen.sum(1, dtype=np.int64)
        by_count = np.argsort(count, kind="stable")
        for s in range(0, len(by_count), 64):  # generated patches of similar counts share one candidate range
            rows = by_count[s : s + 64]
            lo = np.searchsorted(ref_count, count[rows].min() * threshold / (2 - threshold), "left")
            hi = np.searchsorted(ref_count, count[rows].max() * (2 - threshold) / threshold, "right")
            if hi > lo:
                inter = gen[rows].astype(np.float32) @ ref[lo:hi].T  # exact overlap counts
                size_sum = count[rows, None] + ref_count[None, lo:hi]
                hit_iou[rows] = (inter / (size_sum - inter) > threshold).any(1)
                hit_f[rows] = (2 * inter / size_sum > threshold).any(1)
        per_iou.append(float(hit_iou.mean()) if len(gen) else 0.0)
        per_f.append(float(hit_f.mean()) if len(gen) else 0.0)
    return {
        "lp_iou_any_offset": float(np.mean(per_iou)),
        "lp_fscore_any_offset": float(np.mean(per_f)),
        "per_shape_iou": per_iou,
        "per_shape_fscore": per_f,
    }

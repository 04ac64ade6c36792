"""Texture metrics without weights on rendered views (:func:`~sin3dm_lite.evaluate.render.render_views`, framed by
the input's box), and the paper's averages over views.

:func:`patch_swd` and :func:`render_div` are weight-free stand-ins for the paper's T-Qual (SIFID) and T-Div (LPIPS);
:func:`t_qual` and :func:`t_div` average any image distance the paper's way; :func:`degraded` spoils a render in a
known way, to see what a metric reacts to.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np
import torch
import torch.nn.functional as F

from ..errors import Sin3DMInputError

#: renders have a white background (render.BACKGROUND); pixels of exactly this colour are not the shape
BACKGROUND = 255


def image_tensor(img) -> torch.Tensor:
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
    """Patches of ``x`` ``(1, 3, H, W)`` centred on ``mask`` pixels (all pixels if none) → ``(n, 3·patch²)``;
    outside the picture counts as background (white)."""
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
def patch_swd(
    a, b, patch: int = 7, levels: int = 3, projections: int = 128, max_patches: int = 4096, seed: int = 0
) -> float:
    """Sliced Wasserstein distance between the multi-scale patch distributions of two renders (0 = same patches).

    Our weight-free stand-in for the paper's **T-Qual = SIFID** (numbers not comparable): like SIFID it compares
    the *distribution* of local appearance. On each level of an image pyramid, the ``patch × patch`` RGB patches
    centred on shape pixels (at most ``max_patches``) are projected on ``projections`` random directions and the
    1D Wasserstein-1 distances of the sorted projections averaged; the result is the mean over levels (0–1).
    """
    xa, xb = image_tensor(a), image_tensor(b)
    ma = torch.from_numpy(foreground(a))[None, None].float()
    mb = torch.from_numpy(foreground(b))[None, None].float()
    dirs = torch.randn(3 * patch * patch, projections, generator=torch.Generator().manual_seed(seed))
    dirs /= dirs.norm(dim=0, keepdim=True)
    total = 0.0
    for level in range(levels):
        if level:
            xa, xb, ma, mb = (F.avg_pool2d(t, 2) for t in (xa, xb, ma, mb))
        # (n, P) projections, sorted per direction (numpy's sort: torch's along dim 0 is much slower)
        pa = torch.from_numpy(np.sort((_patch_set(xa, ma > 0.5, patch, max_patches, seed + level) @ dirs).numpy(), 0))
        pb = torch.from_numpy(np.sort((_patch_set(xb, mb > 0.5, patch, max_patches, seed + level) @ dirs).numpy(), 0))
        m = max(len(pa), len(pb))
        total += float((_quantiles(pa, m) - _quantiles(pb, m)).abs().mean())
    return total / levels


def colour_distance(a, b) -> float:
    """Mean absolute colour difference (0–1) of two renders of one view, over the pixels where either shows the shape
    (the pixel-aligned distance behind :func:`render_div`)."""
    fa, fb = foreground(a), foreground(b)
    union = fa | fb
    if not union.any():
        return 0.0
    d = np.abs(image_tensor(a)[0].numpy() - image_tensor(b)[0].numpy()).mean(axis=0)
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

    With :func:`sifid` this is T-Qual itself; with :func:`patch_swd` (the default) our weight-free stand-in."""
    sample_views = list(sample_views)
    _check_views(reference_views, sample_views)
    return float(np.mean([distance(r, s[i]) for s in sample_views for i, r in enumerate(reference_views)]))


def t_div(sample_views, distance=colour_distance) -> float:
    """The paper's T-Div average for any image ``distance``: mean over views and over all pairs of samples
    of the distance between their pictures of that view (higher = more diverse; needs two samples).

    With :func:`lpips` this is T-Div itself; with :func:`colour_distance` (the default) :func:`render_div`."""
    sample_views = list(sample_views)
    if len(sample_views) < 2:
        raise Sin3DMInputError(f"texture diversity needs at least two samples, got {len(sample_views)}")
    _check_views(None, sample_views)
    pairs = [distance(a[i], b[i]) for i in range(len(sample_views[0])) for a, b in combinations(sample_views, 2)]
    return float(np.mean(pairs))


def render_div(sample_views) -> float:
    """Texture diversity: mean pairwise :func:`colour_distance` among the samples' renders, view by view.

    Our weight-free stand-in for the paper's **T-Div = LPIPS**, *not* LPIPS: 0 when all samples look the same from
    every view, higher as their colours and silhouettes differ.
    """
    return t_div(sample_views, colour_distance)

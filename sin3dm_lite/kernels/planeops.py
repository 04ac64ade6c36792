"""The rollout's repeated means in a TriplaneConv, convolved in 1D and added without building full-size copies.

In the cross-plane rollout (the paper's Fig. 3b) each plane's Conv2d also reads the two other planes mean-pooled
along the axis this plane lacks, each repeated along one of its axes. A repeated mean is constant along its axis,
so its convolution's output there changes only within ``k//2`` texels of the borders: :func:`conv_repeated`
computes its ``k`` distinct values with one 1D convolution, :func:`add_repeated` adds them, repeated, to the
plane's own output (:class:`~sin3dm_lite.model.unet.TriplaneConv` convolves the parts apart: the convolution is
linear).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F


def conv_repeated(v: torch.Tensor, w: torch.Tensor, size) -> tuple[torch.Tensor, int | None]:
    """The convolution (``padding=k//2``) of a pooled mean ``v`` ``[B,C,A,1]`` or ``[B,C,1,B']`` repeated to
    ``size``, kept short: ``(y, dim)`` with ``y`` ``k`` texels long along the repeated axis ``dim`` (its first
    ``k//2`` texels, the middle value, its last ``k//2``), or ``(full output, None)`` when ``size`` is that short.
    Output texel ``j`` sees the kernel rows (or columns) inside the plane, all on the same input: one 1D convolution
    with those rows summed gives it (the same values up to rounding).
    """
    k, p = w.shape[-1], w.shape[-1] // 2
    dim = 3 if v.shape[3] == 1 else 2  # the axis v is repeated along
    if size[dim - 2] <= k:
        return F.conv2d(v.expand(-1, -1, *size), w, padding=p), None
    if torch.is_autocast_enabled(v.device.type):  # bf16: the 2D convolution of a k-texel strip gives the same
        strip = [k if d == dim else size[d - 2] for d in (2, 3)]
        return F.conv2d(v.expand(-1, -1, *strip), w, padding=p), dim
    # the summed kernel of each output class j: the taps t with p <= j + t <= 3p ([k·out, C, k])
    kern = torch.cat([w.narrow(dim, max(0, p - j), k - abs(p - j)).sum(dim) for j in range(k)])
    y = F.conv1d(v.squeeze(dim), kern, padding=p)  # [B, k·out, m]
    return y.unflatten(1, (k, w.shape[0])).movedim(1, dim), dim  # [B, out, k, m] or [B, out, m, k]


def add_repeated(base: torch.Tensor, parts: list[tuple[torch.Tensor, int | None]]) -> torch.Tensor:
    """``base`` plus each of :func:`conv_repeated`'s outputs repeated to ``base``'s size, added in place: ``base``
    must be a fresh result that nothing else reads (the plane's own convolution's output)."""
    full = [y for y, dim in parts if dim is None]
    short = [(y, dim) for y, dim in parts if dim is not None]
    if torch.is_autocast_enabled(base.device.type):  # bf16: in-place broadcast adds are slow, build them full
        full += [_repeated(y, dim, base.shape[dim]) for y, dim in short]
        short = []
    for y in full:
        base = base + y
    return _AddRepeated.apply(base, *(t for y, dim in short for t in (y, dim))) if short else base


def _repeated(y: torch.Tensor, dim: int, n: int) -> torch.Tensor:
    """``y`` (``k`` texels along ``dim``) repeated to ``n`` texels there: the middle one fills the middle."""
    p = y.shape[dim] // 2
    mid = y.narrow(dim, p, 1).expand(*[n - 2 * p if d == dim else -1 for d in range(y.dim())])
    return torch.cat([y.narrow(dim, 0, p), mid, y.narrow(dim, p + 1, p)], dim)


def _regions(n: int, k: int) -> list[tuple[int, int, int, int]]:
    """``(start, length, class start, class length)`` of the three regions along a repeated axis of ``n`` texels:
    the first ``k//2`` texels (their own values), the middle (the middle value) and the last ``k//2``."""
    p = k // 2
    return [(0, p, 0, p), (p, n - 2 * p, p, 1), (n - p, p, p + 1, p)]


class _AddRepeated(torch.autograd.Function):
    @staticmethod
    def forward(ctx, base, *pairs):
        ys, dims = pairs[0::2], pairs[1::2]
        for y, dim in zip(ys, dims):
            for a, n, c, m in _regions(base.shape[dim], y.shape[dim]):
                base.narrow(dim, a, n).add_(y.narrow(dim, c, m))
        ctx.mark_dirty(base)
        ctx.shapes = [(dim, y.shape[dim]) for y, dim in zip(ys, dims)]
        return base

    @staticmethod
    def backward(ctx, g):
        grads = [g]
        for dim, k in ctx.shapes:
            pieces = [
                g.narrow(dim, a, n) if m == n else g.narrow(dim, a, n).sum(dim, keepdim=True)
                for a, n, c, m in _regions(g.shape[dim], k)
            ]
            grads += [torch.cat(pieces, dim), None]
        return tuple(grads)

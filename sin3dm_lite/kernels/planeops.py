"""The rollout's repeated means in a TriplaneConv, convolved in 1D and added without building full-size copies;
the U-Net's 1×1 convolutions and bilinear upsampling as products (:func:`conv_same`, :func:`resize_bilinear`), and
its time-step modulation folded into the GroupNorm before it (:func:`group_norm_modulated`).

In the cross-plane rollout (the paper's Fig. 3b) each plane's Conv2d also reads the two other planes mean-pooled
along the axis this plane lacks, each repeated along one of its axes. A repeated mean is constant along its axis,
so its convolution's output there changes only within ``k//2`` texels of the borders: :func:`conv_repeated`
computes its ``k`` distinct values with one 1D convolution, :func:`add_repeated` adds them, repeated, to the
plane's own output (:class:`~sin3dm_lite.model.unet.TriplaneConv` convolves the parts apart: the convolution is
linear).
"""

from __future__ import annotations

from functools import lru_cache

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
    # the summed kernel of each output class j: the taps t with p <= j + t <= 3p ([k·out, C, k]), added as whole
    # contiguous slabs (taps first): a strided sum over a 3-tap axis is several times slower, its backward too
    taps = w.movedim(dim, 0).contiguous().unbind(0)  # k × [out, C, k] (unbind: one stack in the backward)
    kern = torch.cat([sum(taps[max(0, p - j) + 1 : 3 * p - j + 1], taps[max(0, p - j)]) for j in range(k)])
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


def resize_bilinear(p: torch.Tensor, size) -> torch.Tensor:
    """``F.interpolate(p, size, mode="bilinear", align_corners=False)`` on the CPU as two small products,
    ``A_rows @ p @ A_colsᵀ`` with each axis' interpolation weights as a matrix (two nonzeros a row): the same values
    up to rounding, forward and backward several times faster than the CPU's upsampling kernel (whose backward
    scatters). Other devices, and ``torch.compile`` (which fuses its own), take ``F.interpolate``."""
    if p.device.type != "cpu" or torch.compiler.is_compiling():
        return F.interpolate(p, size=tuple(size), mode="bilinear", align_corners=False)
    rows, cols = (_bilinear_weights(n, int(m), p.dtype) for n, m in zip(p.shape[-2:], size))
    return rows @ (p @ cols.t())  # [.., A, B] -> [.., A, m] -> [.., n, m]


@lru_cache(maxsize=64)
def _bilinear_weights(n_in: int, n_out: int, dtype: torch.dtype) -> torch.Tensor:
    """``[n_out, n_in]``: bilinear interpolation along one axis as ``F.interpolate`` computes it for ``size``
    (``align_corners=False``: source position ``(i + ½)·n_in/n_out − ½``, clamped at 0 and at the last texel)."""
    src = ((torch.arange(n_out, dtype=torch.float64) + 0.5) * (n_in / n_out) - 0.5).clamp(min=0)
    i0 = src.floor().long().clamp(max=n_in - 1)
    i1, frac = (i0 + 1).clamp(max=n_in - 1), src - i0
    w = torch.zeros(n_out, n_in, dtype=torch.float64)
    w.index_put_((torch.arange(n_out), i0), 1 - frac, accumulate=True)
    w.index_put_((torch.arange(n_out), i1), frac, accumulate=True)
    return w.to(dtype)


def conv_same(p: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """``F.conv2d`` with 'same' padding (odd kernels); a 1×1 kernel on the CPU as one batched product
    ``weight @ p`` over the texels, whose backward is two products (oneDNN's 1×1 backward was slower); under
    ``torch.compile`` the plain convolution."""
    k = weight.shape[-1]
    if k != 1 or p.device.type != "cpu" or torch.compiler.is_compiling():
        return F.conv2d(p, weight, bias, padding=k // 2)
    (b, c, h, w), o = p.shape, len(weight)
    wb, pb = weight.view(o, c).expand(b, o, c), p.reshape(b, c, h * w)
    out = torch.bmm(wb, pb) if bias is None else torch.baddbmm(bias[None, :, None].expand(b, o, h * w), wb, pb)
    return out.view(b, o, h, w)  # [B, out, H, W]


def group_norm_modulated(norm: torch.nn.GroupNorm, p: torch.Tensor, scale: torch.Tensor, shift: torch.Tensor):
    """``norm(p)·(1+scale)+shift`` with ``scale``/``shift`` ``[B, C]``, in one GroupNorm: one of ``[1, B·C, ., .]`` with
    ``B·G`` groups normalises the same groups, and its per-channel weight and bias can then differ per sample. One pass
    over the plane instead of three (the norm, the multiply-add, and their backward's reductions); the same values
    up to rounding."""
    b, c = p.shape[:2]
    weight = (norm.weight * (1 + scale)).reshape(b * c)  # [B·C]
    bias = (norm.bias * (1 + scale) + shift).reshape(b * c)
    y = F.group_norm(p.reshape(1, b * c, *p.shape[2:]), b * norm.num_groups, weight, bias, norm.eps)
    return y.reshape(p.shape)

"""The denoiser: a small fully convolutional U-Net that works on the three planes at once.

Sin3DM learns from *one* shape, so the denoiser must not see the whole latent
at once: with a receptive field as large as the map it memorises the input and
every sample is a copy. The paper's network is a one-level U-Net of four
``TriplaneResBlock``\\ s (64 → pool → 128, 128 → upsample → 64) whose receptive
field covers "roughly 40 % of a 128-wide map". Its convolutions are
``TriplaneConv``\\ s: each plane also sees the other two planes averaged along the
axis they share, so the three planes stay consistent with one another.

Shapes: a ``Triplane`` holds ``xy [B,C,X,Y]``, ``xz [B,C,X,Z]``, ``yz [B,C,Y,Z]``;
every layer here keeps that structure, so odd and non-square sizes just work.
"""

from __future__ import annotations

import math

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..data.config import DiffusionConfig
from ..kernels.planeops import add_repeated, conv_repeated, conv_same, group_norm_modulated, resize_bilinear
from .triplane import PLANE_AXES, PLANES, Triplane


# ------------------------------------------------------------------ building blocks
def rollout_parts(tp: Triplane, detach_means: bool = False, concat: bool = True) -> dict[str, dict]:
    """The rollout of a TriplaneConv taken apart (the paper's Fig. 3b): what each plane's Conv2d is fed.

    For each plane (key ``"xy"``, ``"xz"``, ``"yz"``) a dict with

    * ``"plane"``: the plane itself ``[B, C, A, B']``;
    * ``"sources"``: the names of the two other planes, e.g. ``("xz", "yz")`` for xy;
    * ``"axis"``: the axis the two others are averaged over, the one this plane lacks (``"z"`` for xy);
    * ``"pooled"``: each other plane mean-pooled over that axis, a feature per texel of the axis it
      shares with this plane, kept as ``[B, C, A, 1]`` (along this plane's first axis) or
      ``[B, C, 1, B']`` (along its second): for xy, ``mean_z(xz)`` is ``[B, C, X, 1]`` and
      ``mean_z(yz)`` is ``[B, C, 1, Y]``;
    * ``"expanded"``: each pooled feature repeated along the other axis to the plane's size ``[B, C, A, B']``;
    * ``"input"``: ``[plane, expanded_1, expanded_2]`` concatenated on channels, ``[B, 3C, A, B']``
      (only with ``concat``; ``TriplaneConv`` convolves the pieces without building it).

    ``detach_means`` blocks gradients through the means (to measure the purely local receptive field).
    """
    src = tp.detach() if detach_means else tp  # sources of the means
    planes, sources = dict(zip(PLANES, tp.planes)), dict(zip(PLANES, src.planes))
    parts = {}
    for name in PLANES:
        a, b = PLANE_AXES[name]
        lacking = 3 - a - b  # the axis this plane does not have
        own = planes[name]
        others = tuple(n for n in PLANES if n != name)
        pooled, expanded = [], []
        for other in others:
            axes = PLANE_AXES[other]
            d, src = 2 + axes.index(lacking), sources[other]  # fp32: the mean as a sum / n (its backward a view)
            v = src.mean(d) if torch.is_autocast_enabled(src.device.type) else src.sum(d) / src.shape[d]  # [B, C, n]
            v = v[:, :, :, None] if (set(axes) - {lacking}) == {a} else v[:, :, None, :]  # [B,C,A,1] or [B,C,1,B']
            pooled.append(v)
            expanded.append(v.expand(-1, -1, *own.shape[-2:]))
        parts[name] = {
            "plane": own,
            "sources": others,
            "axis": "xyz"[lacking],
            "pooled": tuple(pooled),
            "expanded": tuple(expanded),
        }
        if concat:
            parts[name]["input"] = torch.cat([own, *expanded], 1)
    return parts


def cross_plane_inputs(tp: Triplane, detach_means: bool = False) -> Triplane:
    """The "rollout": append to each plane the other two planes, mean-pooled along the axis it lacks.

    ``xy [X,Y]`` gets ``mean_z(xz)`` (a feature per x, repeated along y) and
    ``mean_z(yz)`` (a feature per y, repeated along x); likewise for ``xz`` and
    ``yz``. Channels go from C to 3C; sizes do not change. :func:`rollout_parts`
    returns the pieces (and says what ``detach_means`` does).
    """
    parts = rollout_parts(tp, detach_means)
    return Triplane(*(parts[name]["input"] for name in PLANES))  # each [B, 3C, ., .]


class TriplaneConv(nn.Module):
    """Three ``Conv2d`` (one per plane, stride 1, 'same' padding); with ``rollout`` each sees the others too."""

    local_only = False  # set on a copy by `receptive_field`: no gradient through the cross-plane means

    def __init__(self, in_ch: int, out_ch: int, kernel_size: int, rollout: bool = True):
        super().__init__()
        if kernel_size % 2 != 1:
            raise ValueError("TriplaneConv needs an odd kernel size to keep the plane size")
        self.rollout, self.kernel_size = rollout, kernel_size
        conv_in = 3 * in_ch if rollout else in_ch
        self.convs = nn.ModuleList(nn.Conv2d(conv_in, out_ch, kernel_size, padding=kernel_size // 2) for _ in PLANES)

    def forward(self, tp: Triplane) -> Triplane:
        if not self.rollout:
            return Triplane(*(conv_same(p, conv.weight, conv.bias) for conv, p in zip(self.convs, tp.planes)))
        # conv(cross_plane_inputs(tp)) without the cat: the convolution is linear, so it splits into the plane's own
        # channels and the two repeated means, whose outputs vary along their axis only within k//2 texels of the
        # borders (zero padding): k distinct values per texel, one 1D convolution added repeated (kernels/planeops.py)
        parts = rollout_parts(tp, self.local_only, concat=False)
        out = []
        for name, conv in zip(PLANES, self.convs):
            own, (v1, v2), size = parts[name]["plane"], parts[name]["pooled"], parts[name]["plane"].shape[-2:]
            w, w1, w2 = conv.weight.split(own.shape[1], dim=1)  # [out, 3c, k, k]: the plane's channels, the means'
            o = conv_same(own, w, conv.bias)  # F.conv2d, 'same' padding (kernels/planeops.py)
            out.append(add_repeated(o, [conv_repeated(v1, w1, size), conv_repeated(v2, w2, size)]))
        return Triplane(*out)  # [B, out, ., .]


def num_groups(ch: int, max_groups: int = 32) -> int:
    """The largest group count ≤ ``max_groups`` that divides ``ch`` (32 for 64 channels, 12 for 12)."""
    return max(g for g in range(1, min(max_groups, ch) + 1) if ch % g == 0)


class TriplaneGroupNorm(nn.Module):
    """GroupNorm applied to each plane on its own (statistics per plane, one affine per plane)."""

    local_only = False  # set on a copy by `receptive_field`: no gradient through the statistics

    def __init__(self, ch: int):
        super().__init__()
        self.norms = nn.ModuleList(nn.GroupNorm(num_groups(ch), ch) for _ in PLANES)

    def forward(self, tp: Triplane) -> Triplane:
        if self.local_only:
            return Triplane(*(_norm_fixed_stats(norm, p) for norm, p in zip(self.norms, tp.planes)))
        return Triplane(*(norm(p) for norm, p in zip(self.norms, tp.planes)))

    def modulated(self, tp: Triplane, scale: torch.Tensor, shift: torch.Tensor) -> Triplane:
        """``norm(p)·(1+scale)+shift`` per plane, ``scale`` and ``shift`` ``[B, C]`` (the time step's modulation)."""
        if self.local_only:
            return self(tp).map(lambda p: torch.addcmul(shift[:, :, None, None], p, 1 + scale[:, :, None, None]))
        return Triplane(*(group_norm_modulated(n, p, scale, shift) for n, p in zip(self.norms, tp.planes)))


def _norm_fixed_stats(norm: nn.GroupNorm, p: torch.Tensor) -> torch.Tensor:
    """``norm(p)`` with mean and variance treated as constants (same values, only local gradients)."""
    q = p.reshape(p.shape[0], norm.num_groups, -1)  # [B, G, C/G * A * B]
    mean, var = q.mean(-1, keepdim=True).detach(), q.var(-1, unbiased=False, keepdim=True).detach()
    q = ((q - mean) / torch.sqrt(var + norm.eps)).reshape(p.shape)
    return q * norm.weight[:, None, None] + norm.bias[:, None, None]


def _zero_(module: nn.Module) -> nn.Module:
    for p in module.parameters():
        nn.init.zeros_(p)
    return module


class TriplaneResBlock(nn.Module):
    """The DDPM residual block on triplanes: GN → SiLU → conv3 → GN·(1+scale)+shift → SiLU → conv3, + shortcut.

    The time step enters as a per-channel scale and shift after the second
    norm (``x·(1+s)+b``). The last conv starts at zero, so a fresh block is the
    identity (or its 1x1 shortcut) and the network starts as a shallow one.
    """

    def __init__(self, in_ch: int, out_ch: int, time_dim: int, rollout: bool = True):
        super().__init__()
        self.norm1, self.conv1 = TriplaneGroupNorm(in_ch), TriplaneConv(in_ch, out_ch, 3, rollout)
        self.emb = nn.Sequential(nn.SiLU(), nn.Linear(time_dim, 2 * out_ch))
        self.norm2, self.conv2 = TriplaneGroupNorm(out_ch), _zero_(TriplaneConv(out_ch, out_ch, 3, rollout))
        self.shortcut = TriplaneConv(in_ch, out_ch, 1, rollout=False) if in_ch != out_ch else nn.Identity()

    def forward(self, x: Triplane, emb: torch.Tensor) -> Triplane:
        h = self.conv1(self.norm1(x).map(F.silu))  # [B, out, ., .]
        scale, shift = self.emb(emb).chunk(2, dim=1)  # [B, out] each
        h = self.norm2.modulated(h, scale, shift).map(F.silu)  # norm(h)·(1+scale)+shift
        return self.shortcut(x) + self.conv2(h)


def timestep_embedding(t: torch.Tensor, dim: int, max_period: float = 10_000.0) -> torch.Tensor:
    """Sinusoidal embedding of integer time steps ``t [B]`` → ``[B, dim]`` (cosines then sines)."""
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, device=t.device, dtype=torch.float32) / half)
    args = t.float()[:, None] * freqs[None]  # [B, half]
    emb = torch.cat([torch.cos(args), torch.sin(args)], dim=1)
    return F.pad(emb, (0, dim % 2))


def block_layout(n_resblocks: int, downsample: bool) -> tuple[int, int, int]:
    """How many ResBlocks run (before the pool, at half resolution, after the upsample).

    With downsampling, ``n // 4`` blocks sit on each full-resolution side and the
    rest in the half-resolution bottleneck, where each block widens the
    receptive field twice as much: 2 → (0, 2, 0), 4 → (1, 2, 1) (the paper's
    table), 6 → (1, 4, 1), 8 → (2, 4, 2). Without downsampling all blocks form
    one full-resolution stack: n → (n, 0, 0).
    """
    if n_resblocks < 1:
        raise ValueError("the U-Net needs at least one ResBlock")
    if not downsample:
        return n_resblocks, 0, 0
    side = n_resblocks // 4
    return side, n_resblocks - 2 * side, side


# ------------------------------------------------------------------------- the U-Net
def _downsample(p: torch.Tensor) -> torch.Tensor:
    """2×2 average pooling; on an odd size the last window is partial (averages what is there)."""
    return F.avg_pool2d(p, 2, ceil_mode=True)


def _upsample_and_concat(p: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
    """Bilinear upsampling to the skip's exact size (odd sizes too), then ``[upsampled, skip]`` on channels."""
    up = resize_bilinear(p, skip.shape[-2:])  # F.interpolate(bilinear, align_corners=False), faster on a CPU
    return torch.cat([up, skip], 1)


class TriplaneUNet(nn.Module):
    """Sin3DM's denoiser: a one-level, attention-free U-Net of TriplaneResBlocks.

    ``cfg.downsample=True`` (the paper, n=4)::

        TriplaneConv1x1(C→64) → ResBlock(64) ─────────────────────────┐ skip
          → avg-pool /2 → ResBlock(128) → ResBlock(128) → bilinear ×2 ─┴ concat (192)
          → ResBlock(192→64) → GN+SiLU+TriplaneConv1x1(64→C)

    Other block counts follow :func:`block_layout`. The skip is *concatenated*
    (as in the DDPM U-Net): the up block then sees the fine features next to the
    upsampled coarse ones, and the parameter count matches the paper's ≈ 7 M.
    When no block follows the upsample, the output head reads the concatenation.
    ``cfg.downsample=False`` gives a plain stack of n full-resolution blocks at
    ``base_channels`` (no pool, no skip): its receptive field is ``1 + 4n`` texels
    whatever the latent size. The output conv starts at zero, so a fresh
    network predicts exactly 0.
    """

    def __init__(self, latent_channels: int, cfg: DiffusionConfig):
        super().__init__()
        self.cfg, self.latent_channels = cfg, latent_channels
        c, r, tdim = cfg.base_channels, cfg.rollout, 4 * cfg.time_embed_dim
        n_down, n_mid, n_up = block_layout(cfg.n_resblocks, cfg.downsample)
        self.time_mlp = nn.Sequential(nn.Linear(cfg.time_embed_dim, tdim), nn.SiLU(), nn.Linear(tdim, tdim))
        self.in_conv = TriplaneConv(latent_channels, c, 1, r)
        self.down = nn.ModuleList(TriplaneResBlock(c, c, tdim, r) for _ in range(n_down))
        self.mid = nn.ModuleList(TriplaneResBlock(c if i == 0 else 2 * c, 2 * c, tdim, r) for i in range(n_mid))
        up_in = [3 * c if n_mid else c] + [c] * max(n_up - 1, 0)  # concat(upsampled 2c, skip c) → c
        self.up = nn.ModuleList(TriplaneResBlock(ch, c, tdim, r) for ch in up_in[:n_up])
        head_ch = c if (n_up or not n_mid) else 3 * c
        self.out_norm = TriplaneGroupNorm(head_ch)
        self.out_conv = _zero_(TriplaneConv(head_ch, latent_channels, 1, r))

    def forward(self, x: Triplane, t: torch.Tensor) -> Triplane:
        emb = self.time_mlp(timestep_embedding(t, self.cfg.time_embed_dim).to(x.xy.dtype))  # [B, 4*temb]
        h = self.in_conv(x)  # [B, c, X, Y] ...
        for blk in self.down:
            h = blk(h, emb)
        if self.mid:
            skip = h
            h = h.map(_downsample)  # [B, c, ⌈X/2⌉, ⌈Y/2⌉] ...
            for blk in self.mid:
                h = blk(h, emb)  # [B, 2c, ⌈X/2⌉, ⌈Y/2⌉] ...
            h = h.zip_map(skip, _upsample_and_concat)  # [B, 3c, X, Y] ...
        for blk in self.up:
            h = blk(h, emb)  # [B, c, X, Y] ...
        return self.out_conv(self.out_norm(h).map(F.silu))  # [B, C, X, Y] ...


__all__ = [
    "TriplaneConv",
    "TriplaneGroupNorm",
    "TriplaneResBlock",
    "TriplaneUNet",
    "block_layout",
    "cross_plane_inputs",
    "num_groups",
    "rollout_parts",
    "timestep_embedding",
]

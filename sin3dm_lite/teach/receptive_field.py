"""The denoiser's receptive field: how many latent texels one output texel sees (notebook 04).

Sin3DM's denoiser must not see the whole latent, or it memorises the shape and every sample is a copy.
The field is known two ways here: from the layers' kernel sizes and strides (:func:`layer_walk`,
:func:`layers_receptive_field`), and measured as the gradient of one output texel with respect to every
input texel (:func:`receptive_field`). The method itself needs none of it.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn as nn

from ..data.config import DiffusionConfig
from ..model.triplane import PLANES, Triplane
from ..model.unet import TriplaneConv, TriplaneGroupNorm, TriplaneUNet


def layer_walk(model: TriplaneUNet) -> list[tuple[str, int]]:
    """The layers on the deepest path, as ``("conv", k)``, ``("down", 2)``, ``("up", 2)``."""
    convs = lambda blocks: [("conv", b.conv1.kernel_size) for b in blocks for _ in range(2)]  # noqa: E731
    ops = [("conv", model.in_conv.kernel_size)] + convs(model.down)
    if model.mid:
        ops += [("down", 2)] + convs(model.mid) + [("up", 2)]
    return ops + convs(model.up) + [("conv", model.out_conv.kernel_size)]


def analytic_receptive_field(model: TriplaneUNet) -> int:
    """Receptive-field width in input texels of the denoiser, from its :func:`layer_walk`."""
    return layers_receptive_field(layer_walk(model))


def layers_receptive_field(layers: list[tuple[str, int]]) -> int:
    """Receptive-field width in input texels of a chain of layers, from kernel sizes and strides alone.

    Walk the layers keeping the width ``r`` (texels one output texel sees) and the jump ``j`` (input texels
    between neighbouring texels of the current layer): a k×k conv adds ``(k-1)·j``; a 2×2 average pool adds
    ``j`` and doubles ``j``; a bilinear ×2 upsample mixes two neighbouring coarse texels, so it adds the coarse
    ``j`` and then halves it. Only the local convolution paths count, not the (global) cross-plane means and
    GroupNorm statistics. Paper network (n=4): 1 → +4 → pool +1 (j=2) → +16 → up +2 → +4 = 28.
    """
    r, j = 1, 1
    for op, k in layers:
        if op == "conv":
            r += (k - 1) * j
        elif op == "down":
            r, j = r + (k - 1) * j, j * k
        else:  # "up"
            r, j = r + j, j // k
    return r


@dataclass
class ReceptiveField:
    """Computed and measured receptive field of the denoiser on one plane.

    * ``analytic``: width in texels from the layer walk (:func:`analytic_receptive_field`).
    * ``measured_map``: ``(A, B)`` |∂ centre output texel / ∂ input plane|, summed over channels, max 1.
    * ``local_map``: the same through the convolutions only (GroupNorm statistics and cross-plane means
      held constant).
    * ``measured_width``: side of the box holding the ``local_map`` texels above ``threshold`` of its max
      (≤ ``analytic``: the faint edge drops out); ``support_width``: the same for any non-zero value.
    * ``global_fraction``: share of ``measured_map`` texels with a non-zero gradient (GroupNorm and the
      cross-plane means reach every texel).
    * ``coupling`` / ``coupling_max``: median / largest ``measured_map`` value outside the analytic box,
      relative to the peak: how strong that global part is.
    * ``fraction``: ``analytic / plane_width`` (above 1 when the field is wider than the plane).
    """

    analytic: int
    measured_map: np.ndarray
    local_map: np.ndarray
    measured_width: int
    support_width: int
    global_fraction: float
    coupling: float
    coupling_max: float
    fraction: float
    plane: str
    plane_width: int
    threshold: float


def _texel_gradient(net: TriplaneUNet, x: Triplane, t: torch.Tensor, k: int, texel: tuple[int, int]) -> np.ndarray:
    """|∂ (``texel`` of output plane k, summed over channels) / ∂ input plane k|, summed over channels, max 1."""
    x = x.map(lambda p: p.detach().requires_grad_())
    out = net(x, t).planes[k]  # [1, C, A, B]
    out[0, :, texel[0], texel[1]].sum().backward()
    g = x.planes[k].grad[0].abs().sum(0).numpy()  # (A, B)
    return g / g.max()


def _box_width(m: np.ndarray) -> int:
    rows, cols = np.nonzero(m)
    return int(max(rows.max() - rows.min(), cols.max() - cols.min()) + 1)


def _probe_copy(model: TriplaneUNet, seed: int) -> tuple[TriplaneUNet, torch.Generator]:
    """A float64 CPU copy of the network, with random weights where a layer starts at zero (else the gradient
    would be 0), and the generator (seeded ``seed``) that drew them, for the input to draw from next."""
    net = copy.deepcopy(model).to("cpu", torch.float64).eval()
    gen = torch.Generator().manual_seed(seed)
    for m in net.modules():
        if isinstance(m, nn.Conv2d) and not m.weight.any():
            bound = 1 / math.sqrt(m.weight[0].numel())
            m.weight.data.uniform_(-bound, bound, generator=gen)
    return net, gen


def receptive_field(
    model_or_cfg: TriplaneUNet | DiffusionConfig,
    resolution: int | tuple[int, int, int] = (32, 32, 32),
    latent_channels: int = 12,
    plane: str = "xy",
    t: int | None = None,
    threshold: float = 1e-3,
    seed: int = 0,
    texel: tuple[int, int] | None = None,
) -> ReceptiveField:
    """Receptive field of the denoiser at ``resolution``: the computed width and measured gradient maps.

    The field is that of one output texel of ``plane``, ``texel = (i, j)`` (the centre by default),
    measured by backpropagating to the input plane on a float64 copy of the network (``model_or_cfg``: a
    trained model, or a config built with random weights). The gradient falls off towards the border of
    the computed field, so the measured width is a little smaller. GroupNorm statistics and the cross-plane
    means couple every texel to every other one, weakly: the local width is measured with both switched off
    (``local_map``) and the global part reported on its own (``global_fraction``, ``coupling``).
    """
    if isinstance(model_or_cfg, DiffusionConfig):
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            model = TriplaneUNet(latent_channels, model_or_cfg)
    else:
        model = model_or_cfg
    res = (resolution,) * 3 if isinstance(resolution, int) else tuple(resolution)
    net, gen = _probe_copy(model, seed)
    x = Triplane.randn(1, net.latent_channels, res, generator=gen).to(torch.float64)
    t_, k = torch.tensor([net.cfg.timesteps // 2 if t is None else t]), PLANES.index(plane)
    a, b = x.planes[k].shape[-2:]
    ca, cb = (a // 2, b // 2) if texel is None else (int(texel[0]), int(texel[1]))
    if not (0 <= ca < a and 0 <= cb < b):
        raise ValueError(f"texel {texel} is outside the {plane} plane of {a}×{b} texels")
    full = _texel_gradient(net, x, t_, k, (ca, cb))
    for m in net.modules():
        if isinstance(m, (TriplaneConv, TriplaneGroupNorm)):
            m.local_only = True
    local = _texel_gradient(net, x, t_, k, (ca, cb))
    analytic = analytic_receptive_field(net)
    h = analytic // 2
    outside = np.ones_like(full, dtype=bool)
    outside[max(ca - h, 0) : ca + h + 1, max(cb - h, 0) : cb + h + 1] = False
    return ReceptiveField(
        analytic=analytic,
        measured_map=full,
        local_map=local,
        measured_width=_box_width(local > threshold),
        support_width=_box_width(local > 0),
        global_fraction=float((full > 0).mean()),
        coupling=float(np.median(full[outside])) if outside.any() else 0.0,
        coupling_max=float(full[outside].max()) if outside.any() else 0.0,
        fraction=analytic / max(a, b),
        plane=plane,
        plane_width=max(a, b),
        threshold=threshold,
    )


__all__ = ["ReceptiveField", "analytic_receptive_field", "layer_walk", "layers_receptive_field", "receptive_field"]

"""CPU fast paths of the decoder's point MLPs under bf16 autocast.

Autocast casts each ``Linear``'s input and writes fresh bf16 outputs that each ReLU, the skip concatenation and the
backward read and write again. Here the points go through the six layers in chunks, the weights cast once per
call, the bias and ReLU fused into oneDNN's product (:func:`linear_relu`), the skip written beside its layer's
output. Without gradients (a decode) the values are bit for bit autocast's; with gradients (a training step) the
weight and bias gradients are summed in fp32 chunk by chunk. :func:`mlp_bf16_ok` says when it applies.
"""

from __future__ import annotations

import functools

import torch
import torch.nn as nn

from . import pointops

BF16 = torch.bfloat16
#: rows per chunk of a decode: the decoder's CPU batch (``decode.CHUNK``), in one piece
INFER_CHUNK = 8192
#: rows per chunk of a training step: a chunk's ``[CHUNK, 256]`` bf16 activations stay in L2
TRAIN_CHUNK = 1024


def mlp_bf16_ok(x: torch.Tensor, module: nn.Module) -> bool:
    """Whether :func:`skip_mlp_bf16` applies to ``module`` on ``x``: the CPU under bf16 autocast, fp32 parameters;
    without gradients an input laid out as ``F.linear`` folds it (2D, contiguous, or one batch item)."""
    if not (
        pointops.ENABLED
        and x.device.type == "cpu"
        and torch.is_autocast_enabled("cpu")
        and torch.get_autocast_dtype("cpu") == BF16
        and all(p.dtype == torch.float32 for p in module.parameters())
    ):
        return False
    laid_out = x.dim() == 2 or x.is_contiguous() or (x.dim() == 3 and x.shape[0] == 1)
    return laid_out or pointops.wants_grad(x, module.parameters())


def skip_mlp_bf16(x: torch.Tensor, a: nn.Sequential, b: nn.Sequential, out: nn.Linear) -> torch.Tensor:
    """:class:`~sin3dm_lite.model.autoencoder.SkipMLP`'s forward under bf16 autocast, chunk by chunk → bf16, as
    autocast returns it. With gradients wanted, a training step's (:class:`_SkipMLPBf16`); without, a decode's."""
    layers = pointops._layers(a, b, out)
    params = [t for lin in layers for t in (lin.weight, lin.bias)]
    flat = x.reshape(-1, x.shape[-1])
    with torch.autocast("cpu", enabled=False):
        if pointops.wants_grad(x, params):
            y = _SkipMLPBf16.apply(flat, *params)
        else:
            y = _decode(flat, [t.detach() for t in params], fused_first=x.dim() == 2 or x.is_contiguous())
    return y.reshape(*x.shape[:-1], y.shape[-1])


def _decode(flat: torch.Tensor, params: list[torch.Tensor], fused_first: bool) -> torch.Tensor:
    """The forward without gradients, bit for bit autocast's, its buffers reused from chunk to chunk."""
    w, bias = [p.to(BF16) for p in params[0::2]], [p.to(BF16) for p in params[1::2]]
    xb = flat.to(BF16)
    n, c_in = xb.shape
    h, rows = w[0].shape[0], min(n, INFER_CHUNK)
    bufs, z = (xb.new_empty(rows, h), xb.new_empty(rows, h)), xb.new_empty(rows, h + c_in)
    y = xb.new_empty(n, w[5].shape[0])
    for s in range(0, n, INFER_CHUNK):
        e = min(n, s + INFER_CHUNK)
        _chunk(xb[s:e], w, bias, z[: e - s], y[s:e], fused_first, tuple(b[: e - s] for b in bufs))
    return y


def _chunk(xc, w, bias, zc, out, fused_first: bool = True, bufs=(None, None)):
    """One chunk of points ``xc`` (bf16) through the six layers, as autocast computes them: each ``Linear`` an
    ``addmm`` fused with its ReLU, but the first on a strided 3D input the product and then the bias, as
    ``F.linear`` computes it (``fused_first`` False); the skip ``[y2 | x]`` written into ``zc``, the output into
    ``out``. Returns the post-ReLU activations ``y0, y1, y3, y4`` (with ``bufs``, where torch's own path writes
    them: ``y3`` over ``y0``'s buffer, ``y4`` over ``y1``'s)."""
    h = w[0].shape[0]
    if fused_first:
        y0 = linear_relu(xc, w[0], bias[0], bufs[0])
    else:
        y0 = torch.mm(xc, w[0].t(), out=bufs[0]).add_(bias[0]).relu_()
    y1 = linear_relu(y0, w[1], bias[1], bufs[1])
    torch.addmm(bias[2], y1, w[2].t(), out=zc[:, :h]).relu_()
    zc[:, h:] = xc
    y3 = linear_relu(zc, w[3], bias[3], bufs[0])
    y4 = linear_relu(y3, w[4], bias[4], bufs[1])
    torch.addmm(bias[5], y4, w[5].t(), out=out)
    return y0, y1, y3, y4


class _SkipMLPBf16(torch.autograd.Function):
    """A training step's forward in bf16 chunks (the post-ReLU activations kept per chunk, the skip buffer
    ``z = [y2 | x]`` whole) and its backward: per chunk and layer the bias and weight gradients (fp32 sums), the
    input's gradient through the ReLU's mask in place."""

    @staticmethod
    def forward(ctx, x, *params):
        w = [p.to(BF16) for p in params[0::2]]
        bias = [p.to(BF16) for p in params[1::2]]
        xb = x.to(BF16)
        n, c_in = xb.shape
        h = w[0].shape[0]
        y, z = xb.new_empty(n, w[5].shape[0]), xb.new_empty(n, h + c_in)
        acts = [
            _chunk(xb[s : s + TRAIN_CHUNK], w, bias, z[s : s + TRAIN_CHUNK], y[s : s + TRAIN_CHUNK])
            for s in range(0, n, TRAIN_CHUNK)
        ]
        ctx.save_for_backward(xb, z, *w)
        ctx.acts, ctx.x_dtype = acts, x.dtype
        return y

    @staticmethod
    def backward(ctx, gy):
        xb, z, *w = ctx.saved_tensors
        need_x, need = ctx.needs_input_grad[0], ctx.needs_input_grad[1:]
        gw = [torch.zeros(m.shape) if need[2 * i] else None for i, m in enumerate(w)]
        gb = [torch.zeros(m.shape[0]) if need[2 * i + 1] else None for i, m in enumerate(w)]
        gx = torch.empty(xb.shape, dtype=ctx.x_dtype) if need_x else None
        h = w[0].shape[0]
        gy = gy.to(BF16).contiguous()
        for k, s in enumerate(range(0, len(xb), TRAIN_CHUNK)):
            e = min(len(xb), s + TRAIN_CHUNK)
            y0, y1, y3, y4 = ctx.acts[k]
            ins = (xb[s:e], y0, y1, z[s:e], y3, y4)  # each layer's input
            g, skip = gy[s:e], None  # skip: the gradient of x's copy in the concatenation, from layer 3
            for i in range(5, -1, -1):
                if gb[i] is not None:
                    gb[i] += g.sum(0)  # summed in fp32 within the chunk, rounded once
                if gw[i] is not None:
                    gw[i] += torch.mm(g.t(), ins[i])
                if i == 0:
                    if gx is not None:
                        gx[s:e] = torch.mm(g, w[0]).add_(skip)
                    break
                g = torch.mm(g, w[i])
                a = ins[i]
                if i == 3:  # the concatenation [y2 | x]: the gradient of y2 goes on, x's waits for layer 0
                    skip, g, a = g[:, h:], g[:, :h], a[:, :h]
                g = torch.ops.aten.threshold_backward.grad_input(g, a, 0, grad_input=g)  # the ReLU's, in place
        return (gx, *[t for pair in zip(gw, gb) for t in pair])


def linear_relu(x: torch.Tensor, w: torch.Tensor, bias: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """``relu(F.linear(x, w, bias))``: oneDNN's product with the bias and the ReLU fused into it where torch has it
    (the values of ``addmm`` then ``relu_``, without a second pass over the output), else ``addmm`` (into ``out``,
    if given) and ``relu_``."""
    if fused_linear_ok(x.dtype):
        return torch.ops.mkldnn._linear_pointwise(x, w, bias, "relu", [], "")
    return torch.addmm(bias, x, w.t(), out=out).relu_()


@functools.cache
def fused_linear_ok(dtype: torch.dtype) -> bool:
    """Whether this CPU runs oneDNN's fused product, bias and ReLU (a private torch op) in ``dtype`` with the values
    of ``addmm`` then ``relu_``: tried once on a small product."""
    if not (torch.backends.mkldnn.is_available() and hasattr(torch.ops.mkldnn, "_linear_pointwise")):
        return False
    gen = torch.Generator().manual_seed(0)
    x, w, b = (torch.randn(*shape, generator=gen).to(dtype) for shape in ((40, 24), (16, 24), (16,)))
    try:
        fused = torch.ops.mkldnn._linear_pointwise(x, w, b, "relu", [], "")
    except Exception:  # noqa: BLE001 (a private op: any failure means torch's own path)
        return False
    return torch.equal(fused, torch.addmm(b, x, w.t()).relu_())

"""CPU fast paths for the decoder's per-point work: the point MLPs and the triplane lookup, chunk by chunk.

Layer by layer over all the points, every activation of the point MLPs is a large tensor streamed through memory
by each product, ReLU and gradient. Here the points go through the network in chunks of :data:`CHUNK` rows whose
activations stay in cache from layer to layer, the activations a backward needs written once into preallocated
buffers: the same network in a different order (rounding in the last bits differs).

The lookup keeps ``grid_sample``'s forward; its backward treats the three planes' bilinear samples as one gather
of 12 rows (4 corners × 3 planes) from a channel-last table: 12 ``index_add_`` per chunk. Both run on the CPU in
fp32 (under bf16 autocast the MLPs take :mod:`.bf16ops`): :func:`mlp_fast_ok` and :func:`lookup_fast_ok` say when.
"""

from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

#: the fast paths on or off (off: the plain modules everywhere; the tests and the benchmark compare the two)
ENABLED = True
#: points per chunk: a layer's ``[CHUNK, 256]`` fp32 input and output stay in L2
CHUNK = 1024


def wants_grad(x: torch.Tensor, params) -> bool:
    """Whether a call on ``x`` with ``params`` builds a graph: gradients on, and the input or a parameter wants one."""
    return torch.is_grad_enabled() and (x.requires_grad or any(p.requires_grad for p in params))


def mlp_fast_ok(x: torch.Tensor, module: nn.Module) -> bool:
    """Whether the chunked path applies to ``module`` on ``x``: fp32 input and parameters on the CPU, no
    autocast."""
    return (
        ENABLED
        and x.device.type == "cpu"
        and x.dtype == torch.float32
        and not torch.is_autocast_enabled("cpu")
        and all(p.dtype == torch.float32 for p in module.parameters())
    )


def _layers(a: nn.Sequential, b: nn.Sequential, out: nn.Linear) -> list[nn.Linear]:
    return [a[0], a[2], a[4], b[0], b[2], out]


class Workspace:
    """The activation buffers of one MLP's last backward, for its next forward: a step writes into pages it already
    has instead of fresh ones (which the kernel zeroes on first write). A buffer is handed out again only after the
    backward that read it; a graph run backward twice after another forward fails loudly, never silently."""

    def __init__(self) -> None:
        self.free: list[torch.Tensor] = []

    def take(self, rows: int, cols: int, like: torch.Tensor) -> torch.Tensor:
        fits = [
            i for i, b in enumerate(self.free) if b.shape[1] == cols and b.shape[0] >= rows and b.dtype == like.dtype
        ]
        if not fits:
            return like.new_empty(rows, cols)
        return self.free.pop(min(fits, key=lambda i: self.free[i].shape[0]))[:rows]

    def give(self, bufs) -> None:
        self.free = [b if b._base is None else b._base for b in bufs]


def skip_mlp(
    x: torch.Tensor, a: nn.Sequential, b: nn.Sequential, out: nn.Linear, workspace: Workspace | None = None
) -> torch.Tensor:
    """:class:`~sin3dm_lite.model.autoencoder.SkipMLP`'s forward, ``out(b(cat(a(x), x)))`` with ReLUs, chunked
    (``workspace``: where the backward leaves its buffers for the next forward)."""
    layers = _layers(a, b, out)
    params = [t for lin in layers for t in (lin.weight, lin.bias)]
    flat = x.reshape(-1, x.shape[-1]).contiguous()
    if wants_grad(x, params):
        y = _SkipMLPFunction.apply(flat, workspace, *params)
    else:
        y = _forward(flat, [t.detach() for t in params], None)[0]
    return y.reshape(*x.shape[:-1], y.shape[-1])


def _forward(x: torch.Tensor, params: list[torch.Tensor], save: Workspace | bool | None):
    """The forward chunk by chunk → the output and, with ``save`` (a :class:`Workspace` or True), the post-ReLU
    activations: ``y0, y1``, the skip buffer ``z = [y2 | x]`` and ``y3, y4``."""
    w = params[0::2]
    bias = params[1::2]
    n, c_in = x.shape
    h = w[0].shape[0]
    save = save if isinstance(save, Workspace) else Workspace() if save else None
    if save is None:  # without saving, one chunk's buffers are reused
        acts = [x.new_empty(min(n, CHUNK), h + c_in if i == 2 else h) for i in range(5)]
    else:
        acts = [save.take(n, h + c_in if i == 2 else h, x) for i in range(5)]
    y = x.new_empty(n, w[5].shape[0])
    wt = [m.t() for m in w]
    for s in range(0, n, CHUNK):
        e = min(n, s + CHUNK)
        r = slice(s, e) if save is not None else slice(0, e - s)
        xc = x[s:e]
        y0, y1, z, y3, y4 = (t[r] for t in acts)
        torch.mm(xc, wt[0], out=y0).add_(bias[0]).relu_()  # the bias added in cache: an addmm into `out` would
        torch.mm(y0, wt[1], out=y1).add_(bias[1]).relu_()  # first copy it there from memory
        torch.mm(y1, wt[2], out=z[:, :h]).add_(bias[2]).relu_()
        z[:, h:] = xc
        torch.mm(z, wt[3], out=y3).add_(bias[3]).relu_()
        torch.mm(y3, wt[4], out=y4).add_(bias[4]).relu_()
        torch.addmm(bias[5], y4, wt[5], out=y[s:e])
    return y, acts


class _SkipMLPFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x, workspace, *params):
        y, acts = _forward(x, list(params), workspace or True)
        ctx.save_for_backward(x, *params[0::2], *acts)
        ctx.workspace = workspace
        return y

    @staticmethod
    def backward(ctx, gy):
        x, *rest = ctx.saved_tensors
        w, (y0, y1, z, y3, y4) = rest[:6], rest[6:]
        need_x, need = ctx.needs_input_grad[0], ctx.needs_input_grad[2:]
        gw = [torch.zeros_like(m) if need[2 * i] else None for i, m in enumerate(w)]
        gb = [w[i].new_zeros(w[i].shape[0]) if need[2 * i + 1] else None for i in range(6)]
        gx = torch.empty_like(x) if need_x else None
        h = w[0].shape[0]
        gy = gy.contiguous()
        ins = (None, y0, y1, z, y3, y4)  # each layer's input (layer 0's is x)
        # each chunk's gradients go through three scratch buffers: layer 3's input gradient (its skip part is
        # read at layer 0) and two that the other layers take turns on
        scratch = [x.new_empty(min(len(x), CHUNK), h) for _ in range(2)]
        zg = x.new_empty(min(len(x), CHUNK), z.shape[1])
        for s in range(0, len(x), CHUNK):
            e = min(len(x), s + CHUNK)
            g = gy[s:e]
            for i in range(5, -1, -1):
                a = x[s:e] if i == 0 else ins[i][s:e]
                if gb[i] is not None:
                    gb[i] += g.sum(0)
                if gw[i] is not None:
                    gw[i].addmm_(g.t(), a)
                if i == 0:
                    if gx is not None:
                        torch.addmm(zg[: e - s, h:], g, w[0], out=gx[s:e])
                    break
                g = torch.mm(g, w[i], out=zg[: e - s] if i == 3 else scratch[i % 2][: e - s])
                if i == 3:  # the concatenation [y2 | x]: the gradient of y2 goes on, x's waits for layer 0
                    g, a = g[:, :h], a[:, :h]
                g = torch.ops.aten.threshold_backward.grad_input(g, a, 0, grad_input=g)  # the ReLU's, in place
        if ctx.workspace is not None:
            ctx.workspace.give([y0, y1, z, y3, y4])
        grads = [t for pair in zip(gw, gb) for t in pair]
        return (gx, None, *grads)


def lookup_fast_ok(planes: tuple[torch.Tensor, ...], points: torch.Tensor) -> bool:
    """Whether :func:`lookup_sum` applies: CPU, fp32 planes (or bf16 ones under autocast, which samples in fp32),
    no gradient wanted for the points."""
    autocast = torch.is_autocast_enabled("cpu")
    return (
        ENABLED
        and points.device.type == "cpu"
        and not points.requires_grad
        and all(p.dtype == torch.float32 or (autocast and p.dtype == torch.bfloat16) for p in planes)
    )


def corner_weights(planes, points: torch.Tensor, axes) -> tuple[torch.Tensor, torch.Tensor]:
    """Rows of the channel-last table (:func:`lookup_sum`) and bilinear weights of each point's 12 corners,
    ``[12, B·N]`` each: ``grid_sample``'s bilinear rule (``align_corners=False``, border padding)."""
    bsz, n = points.shape[:2]
    rows = sum(p.shape[2] * p.shape[3] for p in planes)
    batch_off = (torch.arange(bsz, device=points.device) * rows)[:, None]
    pts = points.to(torch.float32)
    idx, wts, off = [], [], 0
    for plane, (row, col) in zip(planes, axes):
        size_a, size_b = plane.shape[2], plane.shape[3]
        u = (((pts[..., row] + 1) * size_a - 1) / 2).clamp(0, size_a - 1)
        v = (((pts[..., col] + 1) * size_b - 1) / 2).clamp(0, size_b - 1)
        u0, v0 = u.floor(), v.floor()
        fu, fv = u - u0, v - v0
        i0, j0 = u0.long(), v0.long()
        i1, j1 = (i0 + 1).clamp(max=size_a - 1), (j0 + 1).clamp(max=size_b - 1)
        base = batch_off + off
        idx += [base + i0 * size_b + j0, base + i0 * size_b + j1, base + i1 * size_b + j0, base + i1 * size_b + j1]
        wts += [(1 - fu) * (1 - fv), (1 - fu) * fv, fu * (1 - fv), fu * fv]
        off += size_a * size_b
    return torch.stack(idx).reshape(12, bsz * n), torch.stack(wts).reshape(12, bsz * n)


def lookup_sum(planes, points: torch.Tensor, axes) -> torch.Tensor:
    """The three planes' bilinear features at ``points [B, N, 3]``, added → ``[B, N, C]``: the values of
    ``grid_sample``, the backward a gather's (:class:`_GatherFunction`). Planes in bf16 (under autocast) are sampled
    in fp32 at the points' fp32 coordinates, without rounding the coordinates to bf16 as autocast would."""
    planes = [p.float() for p in planes]
    if not (torch.is_grad_enabled() and any(p.requires_grad for p in planes)):
        return _sampled_sum([p.detach() for p in planes], points, axes)
    bsz, n = points.shape[:2]
    c = planes[0].shape[1]
    table = torch.cat([p.flatten(2) for p in planes], dim=2).transpose(1, 2).reshape(-1, c)  # [B·rows, C]
    idx, wts = corner_weights(planes, points, axes)
    return _GatherFunction.apply(table, idx, wts, points, axes, *(p.detach() for p in planes))


def _sampled_sum(planes, points: torch.Tensor, axes) -> torch.Tensor:
    """``grid_sample`` on each plane at the points' projections, added (``Triplane.lookup``'s plain path)."""
    out = None
    for plane, (row, col) in zip(planes, axes):
        grid = torch.stack([points[..., col], points[..., row]], dim=-1).unsqueeze(1).to(plane.dtype)
        f = F.grid_sample(plane, grid, mode="bilinear", padding_mode="border", align_corners=False)
        out = f[:, :, 0].transpose(1, 2) if out is None else out + f[:, :, 0].transpose(1, 2)
    return out


class _GatherFunction(torch.autograd.Function):
    """Forward: ``grid_sample``'s values; backward: the adjoint of the 12-corner gather from the channel-last
    table, ``index_add_`` chunk by chunk (the plain backward scatters into channel-first planes)."""

    @staticmethod
    def forward(ctx, table, idx, wts, points, axes, *planes):
        ctx.save_for_backward(idx, wts)
        ctx.rows = table.shape[0]
        return _sampled_sum(planes, points, axes)

    @staticmethod
    def backward(ctx, g):
        idx, wts = ctx.saved_tensors
        g = g.reshape(-1, g.shape[-1])
        grad = g.new_zeros(ctx.rows, g.shape[1])
        rows = g.new_empty(min(idx.shape[1], CHUNK), g.shape[1])
        for s in range(0, idx.shape[1], CHUNK):
            e = min(idx.shape[1], s + CHUNK)
            for k in range(12):
                grad.index_add_(0, idx[k, s:e], torch.mul(g[s:e], wts[k, s:e, None], out=rows[: e - s]))
        return grad, None, None, None, None, None, None, None

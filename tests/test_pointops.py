"""The CPU fast paths of the decoder (model/pointops.py) against the plain modules: the same values and gradients."""

from __future__ import annotations

import pytest
import torch

from sin3dm_lite.kernels import bf16ops, pointops
from sin3dm_lite.model.autoencoder import SkipMLP
from sin3dm_lite.model.triplane import PLANE_AXES, PLANES, Triplane, lookup_plane


def _close(a: torch.Tensor, b: torch.Tensor, rel: float = 1e-5) -> None:
    scale = b.detach().abs().max().clamp_min(1e-12)
    assert float((a - b).abs().max().detach() / scale) < rel


def _reference_mlp(m: SkipMLP, x: torch.Tensor) -> torch.Tensor:
    return m.out(m.b(torch.cat([m.a(x), x], dim=-1)))


@pytest.mark.parametrize("n", [1, pointops.CHUNK, 2 * pointops.CHUNK + 37])
def test_skip_mlp_fast_path_matches_the_modules(n):
    torch.manual_seed(0)
    m = SkipMLP(16, 32, 3)
    for p in m.parameters():  # non-zero everywhere, so every gradient is checked
        torch.nn.init.normal_(p, std=0.3)
    x = torch.randn(1, n, 16, requires_grad=True)
    assert pointops.mlp_fast_ok(x, m)
    y = m(x)
    ref = _reference_mlp(m, x)
    _close(y, ref)
    g = torch.randn_like(ref)
    params = [x, *m.parameters()]
    for a, b in zip(torch.autograd.grad(y, params, g), torch.autograd.grad(ref, params, g)):
        assert a.shape == b.shape
        _close(a, b)
    with torch.no_grad():  # the forward-only path
        _close(m(x), ref)


def test_skip_mlp_fast_path_with_frozen_parameters():
    """A held colour head (no parameter needs a gradient): only the input's gradient, the same as the modules'."""
    torch.manual_seed(1)
    m = SkipMLP(8, 16, 3).requires_grad_(False)
    x = torch.randn(700, 8, requires_grad=True)
    g = torch.randn(700, 3)
    (a,) = torch.autograd.grad(m(x), x, g)
    (b,) = torch.autograd.grad(_reference_mlp(m, x), x, g)
    _close(a, b)


def test_lookup_fast_path_matches_grid_sample():
    torch.manual_seed(2)
    tp = Triplane.randn(2, 5, (6, 4, 3)).map(lambda p: p.requires_grad_())
    pts = torch.rand(2, 3000, 3) * 2.4 - 1.2  # some outside the box: the border rule too
    pts[0, :4] = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1 / 6, 0.25, -1 / 3]])
    assert pointops.lookup_fast_ok(tp.planes, pts)
    fast = tp.lookup(pts, reduce="sum")
    ref = sum(lookup_plane(p, pts, PLANE_AXES[n]) for n, p in zip(PLANES, tp.planes))
    _close(fast, ref)
    g = torch.randn_like(ref)
    for a, b in zip(torch.autograd.grad(fast, tp.planes, g), torch.autograd.grad(ref, tp.planes, g)):
        _close(a, b)


def test_lookup_under_autocast_samples_bf16_planes_at_fp32_coordinates():
    """A training step's lookup under bf16 autocast (its planes come out of bf16 convolutions): the gather's
    backward, the values of ``grid_sample`` on the planes cast to fp32 at the points' own fp32 coordinates (the plain
    path rounded the coordinates to bf16 first), and the planes' gradients those of that fp32 lookup."""
    torch.manual_seed(8)
    ref_planes = Triplane.randn(1, 5, (40, 36, 30)).map(lambda p: p.requires_grad_())
    bf = ref_planes.map(lambda p: p.detach().to(torch.bfloat16).requires_grad_())
    pts = torch.rand(1, 2000, 3) * 2 - 1
    with torch.autocast("cpu", dtype=torch.bfloat16):
        assert pointops.lookup_fast_ok(bf.planes, pts)
        fast = bf.lookup(pts, reduce="sum")
    cast = bf.map(lambda p: p.float())
    ref = sum(lookup_plane(p, pts, PLANE_AXES[n]) for n, p in zip(PLANES, cast.planes))
    assert fast.dtype == torch.float32
    _close(fast, ref)
    coarse = sum(lookup_plane(p, pts.to(torch.bfloat16).float(), PLANE_AXES[n]) for n, p in zip(PLANES, cast.planes))
    assert float((coarse - ref).abs().max()) > 1e-3  # rounded coordinates would have shown
    g = torch.randn_like(ref)
    for a, b in zip(torch.autograd.grad(fast, bf.planes, g), torch.autograd.grad(ref, cast.planes, g)):
        assert a.dtype == torch.bfloat16
        _close(a.float(), b, rel=1e-2)


def test_lookup_with_point_gradients_keeps_grid_sample():
    tp = Triplane.randn(1, 4, (4, 4, 4))
    pts = torch.rand(1, 10, 3, requires_grad=True)
    assert not pointops.lookup_fast_ok(tp.planes, pts)
    (g,) = torch.autograd.grad(tp.lookup(pts, reduce="sum").sum(), pts)
    assert g.abs().sum() > 0


def test_autoencoder_steps_are_the_same_with_and_without_the_fast_paths(box_grid, monkeypatch):
    """From the same seed (3,000 points: chunks and a remainder): the same losses over two steps, and the same
    gradients of every parameter in the first."""
    from sin3dm_lite.model.autoencoder import AutoencoderTrainer

    from .conftest import tiny_ae_cfg

    runs = []
    for enabled in (False, True):
        monkeypatch.setattr(pointops, "ENABLED", enabled)
        tr = AutoencoderTrainer(box_grid, tiny_ae_cfg(points_per_step=3000, precision="fp32"), seed=3)
        tr.model.train()
        tr.losses()["loss"].backward()
        grads = [p.grad.clone() for p in tr.model.parameters()]
        tr.generator.manual_seed(3)  # the first step's points again
        tr.step()
        tr.step()
        runs.append((tr.history, grads))
    (ref_h, ref_g), (fast_h, fast_g) = runs
    for k in ("loss", "sdf", "color"):
        assert fast_h[k] == pytest.approx(ref_h[k], rel=1e-5)
    for a, b in zip(fast_g, ref_g):
        # relative to the tensor's largest gradient; a bias before an InstanceNorm gets rounding noise only
        assert float((a - b).abs().max()) <= 1e-5 * float(b.abs().max()) + 1e-8


def test_kept_buffers_are_reused_and_a_stale_graph_fails_loudly():
    """Training mode keeps a backward's buffers for the next forward: the same values as a fresh forward, and a
    graph whose buffers were reused cannot be run backward again (an error, not wrong gradients)."""
    torch.manual_seed(4)
    m = SkipMLP(8, 16, 1).train()
    x = torch.randn(1500, 8, requires_grad=True)
    y1 = m(x)
    y1.sum().backward(retain_graph=True)
    kept = [b.data_ptr() for b in m._workspace.free]
    assert len(kept) == 5
    y2 = m(x * 2)  # writes into the kept buffers
    assert not m._workspace.free
    _close(y2, _reference_mlp(m, x * 2))
    with pytest.raises(RuntimeError, match="modified by an inplace operation"):
        y1.sum().backward()
    m.eval()
    assert m._workspace is None


@pytest.mark.parametrize("fused", [True, False])
@pytest.mark.parametrize("layout", ["contiguous", "lookup", "flat"])
@pytest.mark.parametrize("n", [1, 37, bf16ops.INFER_CHUNK + 100])
def test_bf16_decode_path_is_autocasts_bit_for_bit(layout, n, fused, monkeypatch):
    """Under bf16 autocast without gradients (a decode), the same bf16 values as the plain modules under autocast,
    bit for bit, whatever the input's layout: contiguous, the lookup's strided ``[1, N, C]`` (``F.linear`` then
    adds the bias after the product) or 2D, with oneDNN's fused product and ReLU or without (a CPU without
    AVX-512 has none in bf16)."""
    if fused and not bf16ops.fused_linear_ok(torch.bfloat16):
        pytest.skip("oneDNN has no bf16 product on this CPU")
    if not fused:
        monkeypatch.setattr(bf16ops, "fused_linear_ok", lambda dtype: False)
    torch.manual_seed(5)
    m = SkipMLP(24, 64, 3).eval()
    x = {
        "contiguous": torch.randn(1, n, 24),
        "lookup": torch.randn(1, 24, n).transpose(1, 2),
        "flat": torch.randn(n, 24),
    }[layout]
    with torch.autocast("cpu", dtype=torch.bfloat16):
        with torch.no_grad():
            assert bf16ops.mlp_bf16_ok(x, m)
            fast = m(x)
            ref = _reference_mlp(m, x)
    assert fast.dtype == ref.dtype == torch.bfloat16 and fast.shape == ref.shape
    assert torch.equal(fast, ref)
    assert not bf16ops.mlp_bf16_ok(x, m)  # no autocast: the fp32 paths


@pytest.mark.parametrize("frozen", [False, True])
def test_bf16_training_path_is_as_close_to_fp32_as_autocast(frozen):
    """A training step's MLP under bf16 autocast: the output and every gradient (input, weights, biases) as close to
    the fp32 module's as the plain modules under autocast are, within a fifth more (bf16 keeps 8 bits: both are a
    tenth off on random gradients); a held head (frozen parameters) gives the input's gradient only."""
    torch.manual_seed(6)
    m = SkipMLP(24, 64, 3).requires_grad_(not frozen)
    for p in m.parameters():
        torch.nn.init.normal_(p, std=0.2)
    n = 2 * bf16ops.TRAIN_CHUNK + 37
    x = torch.randn(1, 24, n).transpose(1, 2).requires_grad_()  # the lookup's layout
    g = torch.randn(1, n, 3)
    wrt = [x] if frozen else [x, *m.parameters()]

    def run(module_forward, bf16: bool):
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            y = module_forward(x)
        return [y.float(), *torch.autograd.grad(y.float(), wrt, g)]

    ref = run(lambda v: _reference_mlp(m, v), False)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        assert bf16ops.mlp_bf16_ok(x, m)
    fast = run(m, True)
    plain = run(lambda v: _reference_mlp(m, v), True)
    for f, p, r in zip(fast, plain, ref):
        assert f.shape == r.shape
        err_fast, err_plain = (float((t - r).norm() / r.norm()) for t in (f, p))
        assert err_fast <= 1.2 * err_plain + 1e-3, (err_fast, err_plain)
        assert err_fast < 0.25


def test_bf16_training_path_runs_backward_twice_with_a_kept_graph():
    """``retain_graph=True`` (as a user computing two losses' gradients may): the second backward adds the same."""
    torch.manual_seed(7)
    m = SkipMLP(8, 16, 2)
    x = torch.randn(1, 3000, 8, requires_grad=True)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        y = m(x)
    y.float().sum().backward(retain_graph=True)
    first = x.grad.clone()
    y.float().sum().backward()
    assert torch.allclose(x.grad, 2 * first)

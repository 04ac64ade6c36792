"""The triplane denoiser: shapes on odd / non-square planes, zero init, cross-plane coupling, receptive field."""

import pytest
import torch

from sin3dm_lite.app.device import count_parameters
from sin3dm_lite.data.config import DiffusionConfig
from sin3dm_lite.kernels.planeops import conv_same, resize_bilinear
from sin3dm_lite.model.triplane import Triplane
from sin3dm_lite.model.unet import (
    TriplaneConv,
    TriplaneGroupNorm,
    TriplaneResBlock,
    TriplaneUNet,
    block_layout,
    cross_plane_inputs,
    num_groups,
    rollout_parts,
)
from sin3dm_lite.teach.receptive_field import analytic_receptive_field, receptive_field

RESOLUTIONS = [(13, 7, 10), (16, 12, 8)]


def shapes(tp: Triplane):
    return [tuple(p.shape) for p in tp.planes]


def expected(b, c, res):
    x, y, z = res
    return [(b, c, x, y), (b, c, x, z), (b, c, y, z)]


@pytest.mark.parametrize("res", RESOLUTIONS)
@pytest.mark.parametrize("rollout", [True, False])
@pytest.mark.parametrize("k", [1, 3])
def test_triplane_conv_shapes(res, rollout, k):
    conv = TriplaneConv(5, 7, k, rollout=rollout)
    assert conv.convs[0].in_channels == (15 if rollout else 5)
    assert shapes(conv(Triplane.randn(2, 5, res))) == expected(2, 7, res)


@pytest.mark.parametrize("k", [1, 3, 5])
@pytest.mark.parametrize("res", [(13, 7, 10), (2, 9, 4), (1, 6, 6)])
def test_rollout_conv_equals_the_conv_of_the_concatenated_input(k, res):
    # TriplaneConv convolves the plane and the two repeated means apart (cheaper): the same values and
    # gradients as the paper's Conv2d of the 3C-channel concatenation, borders included
    torch.manual_seed(0)
    conv = TriplaneConv(4, 5, k, rollout=True)
    x = Triplane.randn(2, 4, res).map(lambda p: p.requires_grad_())
    ref = Triplane(*(c(p) for c, p in zip(conv.convs, cross_plane_inputs(x).planes)))
    out = conv(x)
    for a, b in zip(out.planes, ref.planes):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)
    g_out = torch.autograd.grad(sum((o * o).sum() for o in out.planes), x.planes + tuple(conv.parameters()))
    g_ref = torch.autograd.grad(sum((o * o).sum() for o in ref.planes), x.planes + tuple(conv.parameters()))
    for a, b in zip(g_out, g_ref):
        torch.testing.assert_close(a, b, atol=1e-4, rtol=1e-4)


def _perturbed_outputs(rollout: bool, plane: int):
    torch.manual_seed(0)
    conv = TriplaneConv(3, 4, 1, rollout=rollout)
    x = Triplane.randn(1, 3, (6, 5, 4))
    planes = list(x.clone().planes)
    planes[plane][0, :, 2, 1] += 1.0  # one texel of one plane
    return conv(x), conv(Triplane(*planes))


def test_rollout_couples_planes_along_the_shared_axis():
    # yz texel (y=2, z=1) → mean over z of yz → xy sees it in column y=2 for every x, nowhere else
    a, b = _perturbed_outputs(rollout=True, plane=2)
    changed = (a.xy - b.xy).abs().sum(1)[0] > 0  # [X, Y]
    assert changed[:, 2].all() and not changed[:, [0, 1, 3, 4]].any()
    # xz texel (x=2, z=1) → mean over z of xz → xy row x=2
    a, b = _perturbed_outputs(rollout=True, plane=1)
    changed = (a.xy - b.xy).abs().sum(1)[0] > 0
    assert changed[2, :].all() and not changed[[0, 1, 3, 4, 5], :].any()
    # without rollout the planes are independent
    a, b = _perturbed_outputs(rollout=False, plane=2)
    assert torch.equal(a.xy, b.xy) and torch.equal(a.xz, b.xz) and not torch.equal(a.yz, b.yz)


def test_num_groups_divides_channels():
    assert [num_groups(c) for c in (64, 128, 192, 12, 16, 4, 48, 1)] == [32, 32, 32, 12, 16, 4, 24, 1]


@pytest.mark.parametrize("k", [1, 3])
@pytest.mark.parametrize("with_bias", [True, False])
def test_conv_same_is_conv2d(k, with_bias):
    # the 1×1 convolution as a batched product: F.conv2d's values and gradients
    x = torch.randn(3, 5, 7, 4, dtype=torch.float64, requires_grad=True)
    w = torch.randn(6, 5, k, k, dtype=torch.float64, requires_grad=True)
    b = torch.randn(6, dtype=torch.float64, requires_grad=True) if with_bias else None
    g = torch.randn(3, 6, 7, 4, dtype=torch.float64)
    inputs = [x, w] + ([b] if with_bias else [])
    ref = torch.nn.functional.conv2d(x, w, b, padding=k // 2)
    out = conv_same(x, w, b)
    assert torch.allclose(out, ref, atol=1e-12)
    for u, v in zip(torch.autograd.grad((out * g).sum(), inputs), torch.autograd.grad((ref * g).sum(), inputs)):
        assert torch.allclose(u, v, atol=1e-12)


@pytest.mark.parametrize("size", [(14, 10), (13, 9), (7, 5), (20, 3)])
def test_bilinear_resize_is_interpolate(size):
    # the U-Net's upsampling as two products: F.interpolate's values and gradients, odd sizes and shrinking too
    x = torch.randn(2, 3, 7, 5, dtype=torch.float64, requires_grad=True)
    g = torch.randn(2, 3, *size, dtype=torch.float64)
    ref = torch.nn.functional.interpolate(x, size=size, mode="bilinear", align_corners=False)
    out = resize_bilinear(x, size)
    assert out.shape == ref.shape and torch.allclose(out, ref, atol=1e-12)
    assert torch.allclose(*(torch.autograd.grad((y * g).sum(), x)[0] for y in (out, ref)), atol=1e-12)


@pytest.mark.parametrize("ch", [8, 12, 64])
def test_modulated_norm_is_the_norm_then_the_time_steps_scale_and_shift(ch):
    # the per-sample scale and shift folded into one GroupNorm: the same values and gradients as norm, then p·(1+s)+b
    torch.manual_seed(0)
    norm = TriplaneGroupNorm(ch).double()
    for n in norm.norms:
        torch.nn.init.normal_(n.weight), torch.nn.init.normal_(n.bias)
    x = Triplane(*(p.double().requires_grad_() for p in Triplane.randn(3, ch, (9, 6, 5)).planes))
    scale, shift = (torch.randn(3, ch, dtype=torch.float64, requires_grad=True) for _ in range(2))
    inputs = [*x.planes, scale, shift, *norm.parameters()]

    ref = norm(x).map(lambda p: p * (1 + scale[:, :, None, None]) + shift[:, :, None, None])
    out = norm.modulated(x, scale, shift)
    assert all(torch.allclose(p, q, atol=1e-12) for p, q in zip(out.planes, ref.planes))
    grads = [torch.autograd.grad(sum((p * p.detach().sin()).sum() for p in tp.planes), inputs) for tp in (out, ref)]
    assert all(torch.allclose(g, h, atol=1e-10) for g, h in zip(*grads))  # every input's and parameter's


@pytest.mark.parametrize("res", RESOLUTIONS)
def test_resblock_shapes_and_identity_at_init(res):
    emb = torch.randn(2, 32)
    x = Triplane.randn(2, 8, res)
    same = TriplaneResBlock(8, 8, 32)
    assert all(torch.equal(p, q) for p, q in zip(same(x, emb).planes, x.planes))  # zero-init last conv: identity
    wider = TriplaneResBlock(8, 12, 32)
    assert shapes(wider(x, emb)) == expected(2, 12, res)


def test_block_layout():
    assert [block_layout(n, True) for n in (2, 4, 6, 8)] == [(0, 2, 0), (1, 2, 1), (1, 4, 1), (2, 4, 2)]
    assert block_layout(2, False) == (2, 0, 0) and block_layout(6, False) == (6, 0, 0)
    with pytest.raises(ValueError):
        block_layout(0, True)


@pytest.mark.parametrize("res", RESOLUTIONS)
@pytest.mark.parametrize("downsample", [True, False])
@pytest.mark.parametrize("n", [2, 4, 6])
def test_unet_shapes_and_zero_output_at_init(res, downsample, n):
    net = TriplaneUNet(4, DiffusionConfig(base_channels=8, n_resblocks=n, downsample=downsample, time_embed_dim=16))
    out = net(Triplane.randn(2, 4, res), torch.tensor([0, 999]))
    assert shapes(out) == expected(2, 4, res)
    assert all(torch.equal(p, torch.zeros_like(p)) for p in out.planes)  # "zero-init identity" for x0-prediction


def test_unet_trains_through_every_block():
    net = TriplaneUNet(4, DiffusionConfig(base_channels=8, n_resblocks=4, time_embed_dim=16))
    opt = torch.optim.SGD(net.parameters(), lr=0.1)
    x = Triplane.randn(2, 4, (9, 6, 7))
    for _ in range(2):  # step 1 moves the output conv off zero, step 2 reaches the blocks behind it
        opt.zero_grad()
        sum((p - 1).square().mean() for p in net(x, torch.tensor([5, 50])).planes).backward()
        opt.step()
    blocks = [*net.down, *net.mid, *net.up]
    assert len(blocks) == 4
    # every zero-initialised conv (all three planes of each block's conv2) has moved off zero
    assert all(conv.weight.abs().sum() > 0 for blk in blocks for conv in blk.conv2.convs)


def test_paper_unet_has_about_7m_parameters():
    net = TriplaneUNet(12, DiffusionConfig())
    n = count_parameters(net)
    assert n == sum(p.numel() for p in net.parameters()) and 6.5e6 < n < 7.5e6
    net.out_conv.requires_grad_(False)
    assert count_parameters(net, trainable_only=True) == n - count_parameters(net.out_conv)


def test_analytic_receptive_field_by_hand():
    rf = lambda **kw: analytic_receptive_field(TriplaneUNet(4, DiffusionConfig(base_channels=8, **kw)))  # noqa: E731
    # 1x1 in (1) + 2 blocks × two 3x3 convs (+2 each → 9) + 1x1 out
    assert rf(n_resblocks=2, downsample=False) == 9
    assert rf(n_resblocks=6, downsample=False) == 25
    # the paper's n=4: 1x1 in → 1; ResBlock(64): +2 +2 → 5; avg-pool 2: +1 → 6, one texel now spans 2;
    # two ResBlocks(128) = four 3x3 convs at spacing 2: +4·2·2 → 22; bilinear ×2 blends two coarse
    # texels (2 apart): +2 → 24, spacing 1; ResBlock(64): +4 → 28; 1x1 out → 28 (REFERENCE: 28×28 measured)
    assert rf(n_resblocks=4, downsample=True) == 28
    # n=2 → layout (0, 2, 0): 1 → pool +1 → 2 → four convs at spacing 2: +16 → 18 → up +2 → 20
    assert rf(n_resblocks=2, downsample=True) == 20


@pytest.mark.parametrize("n,downsample,size", [(2, False, 24), (2, True, 32)])
def test_measured_receptive_field_matches_analytic_without_rollout(n, downsample, size):
    cfg = DiffusionConfig(base_channels=16, n_resblocks=n, downsample=downsample, rollout=False)
    rf = receptive_field(cfg, size, latent_channels=4)
    assert rf.support_width == rf.analytic
    assert rf.measured_width == rf.analytic
    assert rf.measured_map.shape == (size, size) and rf.measured_map.max() == 1.0


def test_receptive_field_reports_global_coupling():
    cfg = DiffusionConfig(base_channels=32, n_resblocks=2, downsample=False)
    rf = receptive_field(cfg, 32, latent_channels=12)
    assert rf.analytic == 9 and rf.support_width == 9 and rf.fraction == 9 / 32
    assert rf.global_fraction == 1.0  # GroupNorm and the rollout reach every texel ...
    assert 0 < rf.coupling < 0.1 and rf.coupling_max < 0.5  # ... but weakly
    assert rf.local_map[rf.local_map > 0].size == 81  # the convolution-only gradient is exactly 9×9


def test_receptive_field_of_a_model_on_a_non_square_plane_leaves_the_model_alone():
    net = TriplaneUNet(4, DiffusionConfig(base_channels=8, n_resblocks=2, downsample=True))
    before = {k: v.clone() for k, v in net.state_dict().items()}
    rf = receptive_field(net, (20, 12, 16), plane="yz")
    assert rf.measured_map.shape == (12, 16) and rf.plane_width == 16 and rf.analytic == 20
    assert all(torch.equal(before[k], v) for k, v in net.state_dict().items())
    assert next(net.parameters()).dtype == torch.float32


def test_rollout_parts_are_the_pieces_of_the_conv_input():
    torch.manual_seed(0)
    x, y, z = 6, 5, 4
    tp = Triplane.randn(2, 3, (x, y, z))
    parts = rollout_parts(tp)
    joined = cross_plane_inputs(tp)
    for name, plane in zip(("xy", "xz", "yz"), joined.planes):
        assert torch.equal(parts[name]["input"], plane)
    xy = parts["xy"]
    assert xy["sources"] == ("xz", "yz") and xy["axis"] == "z"
    assert [tuple(p.shape) for p in xy["pooled"]] == [(2, 3, x, 1), (2, 3, 1, y)]  # a feature per x, one per y
    torch.testing.assert_close(xy["pooled"][0][..., 0], tp.xz.mean(3))
    torch.testing.assert_close(xy["pooled"][1][:, :, 0], tp.yz.mean(3))
    assert all(tuple(e.shape) == (2, 3, x, y) for e in xy["expanded"])
    yz = parts["yz"]
    assert yz["axis"] == "x" and [tuple(p.shape) for p in yz["pooled"]] == [(2, 3, y, 1), (2, 3, 1, z)]
    torch.testing.assert_close(yz["pooled"][1][:, :, 0], tp.xz.mean(2))


def test_the_presets_fields_are_a_share_of_their_latents():
    # docs/paper-notes.md, last section: the field must shrink with the latent, or every sample copies the input
    from sin3dm_lite.presets import get_preset

    share = {}
    for name in ("small", "detail", "paper"):
        cfg = get_preset(name)
        latent = cfg.grid.resolution // 2
        share[name] = analytic_receptive_field(TriplaneUNet(cfg.autoencoder.latent_channels, cfg.diffusion)) / latent
    assert share["small"] == 9 / 32 and share["detail"] == 17 / 48 and share["paper"] == 28 / 128
    assert max(share.values()) < 0.4  # none sees nearly the whole latent (the paper's network at 32 texels: 28/32)

"""Every exercise check passes on its solution (notebooks/solutions/) and fails, naming the difference, on wrong answers."""

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from sin3dm_lite import exercises as ex
from sin3dm_lite.teach import loop_exercises as lx
from sin3dm_lite.teach import shape_exercises as sx

SOLUTIONS = Path(__file__).parents[1] / "notebooks" / "solutions"


def solution(module: str, name: str):
    spec = importlib.util.spec_from_file_location(f"solutions_{module}", SOLUTIONS / f"{module}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return getattr(mod, name)


CHECKS = [
    (ex.check_q_sample, "q_sample", "q_sample"),
    (ex.check_ddpm_posterior, "ddpm_posterior", "posterior"),
    (ex.check_ddim_step, "ddim_step", "ddim_step"),
    (ex.check_triplane_lookup, "triplane_lookup", "lookup"),
    (ex.check_receptive_field, "receptive_field", "receptive_field"),
    (ex.check_rollout, "rollout", "rollout_xy"),
    (ex.check_best_patch_iou, "lp_iou", "best_patch_iou"),
    (sx.check_grid_box, "grid_box", "grid_box"),
    (sx.check_retarget, "retarget", "retarget"),
    (sx.check_regenerate_mask, "regenerate_mask", "regenerate_mask"),
    (sx.check_tangent_frames, "tangent_frames", "tangent_frames"),
    (lx.check_training_step, "training_step", "training_step"),
    (lx.check_ddim_loop, "ddim_loop", "ddim_sample"),
    (lx.check_masked_step, "masked_step", "masked_step"),
]


@pytest.mark.parametrize("check,module,name", CHECKS, ids=[c[1] for c in CHECKS])
def test_the_solution_passes(check, module, name, capsys):
    check(solution(module, name))
    assert capsys.readouterr().out.startswith("✓ your")


def test_every_check_has_a_solution_and_a_notebook_uses_it():
    checks = {n for n in [*ex.__all__, *sx.__all__, *lx.__all__] if n.startswith("check_")}
    assert checks == {c[0].__name__ for c in CHECKS}
    assert {p.stem for p in SOLUTIONS.glob("*.py")} - {"__init__"} == {c[1] for c in CHECKS}
    cells = "".join(p.read_text(encoding="utf-8") for p in (SOLUTIONS.parent).glob("*.ipynb"))
    for check, module, name in CHECKS:
        assert f"{check.__name__}({name})" in cells, f"no notebook runs {check.__name__}"
        assert f"from solutions.{module} import {name}" in cells


def fails(check, fn, *words):
    with pytest.raises(ex.ExerciseError) as err:
        check(fn)
    for w in words:
        assert w in str(err.value), str(err.value)
    return str(err.value)


# ----------------------------------------------------------------------------- wrong answers
def test_q_sample_without_square_roots():
    def wrong(x0, t, noise, ab):
        a = ab[t].reshape(-1, 1, 1, 1).float()
        return a * x0 + (1 - a) * noise

    msg = fails(ex.check_q_sample, wrong, "your q_sample differs at t=", "max error", "did you use √ᾱ_t")
    assert "t=0 " not in msg  # ᾱ_0 ≈ 1: the first step barely differs; the report names the worst one


def test_q_sample_off_by_one_and_a_crash():
    fails(
        ex.check_q_sample,
        lambda x0, t, n, ab: solution("q_sample", "q_sample")(x0, (t + 1).clamp(max=999), n, ab),
        "off by one",
    )
    fails(
        ex.check_q_sample,
        lambda x0, t, n, ab: ab[t].sqrt() * x0 + (1 - ab[t]).sqrt() * n,
        "your q_sample raised RuntimeError",
        "[B, 1, 1, 1]",
    )
    fails(ex.check_q_sample, lambda x0, t, n, ab: x0[0], "returned shape")


def test_posterior_that_reads_the_last_alpha_bar_at_t0():
    right = solution("ddpm_posterior", "posterior")

    def wrong(x0, x_t, t, betas, ab):
        ab_prev = ab[t - 1]  # t = 0 reads ab[-1], the last value
        a = lambda v: v.reshape(-1, 1, 1, 1).float()  # noqa: E731
        mean, _ = right(x0, x_t, t, betas, ab)
        return mean, a(betas[t] * (1 - ab_prev) / (1 - ab[t]))

    fails(ex.check_ddpm_posterior, wrong, "posterior variance differs at t=0", "alphas_cumprod[-1]")
    fails(ex.check_ddpm_posterior, lambda *a: right(*a)[0], "two things")


def test_ddim_step_wrong_last_step_and_wrong_noise():
    def last_wrong(x_t, x0, t, t_prev, ab):
        a = ab[t].reshape(-1, 1, 1, 1).float()
        eps = (x_t - a.sqrt() * x0) / (1 - a).sqrt()
        ap = float(ab[t_prev])  # -1 → ᾱ_{T-1}
        return math.sqrt(ap) * x0 + math.sqrt(1 - ap) * eps

    fails(ex.check_ddim_step, last_wrong, "t_prev=-1", "alphas_cumprod[-1]")

    def no_eps(x_t, x0, t, t_prev, ab):
        ap = float(ab[max(t_prev, 0)])
        return math.sqrt(ap) * x0 + math.sqrt(1 - ap) * x_t

    fails(ex.check_ddim_step, no_eps, "999→979", "keep the noise direction")


def test_lookup_with_swapped_axes_corners_or_zero_padding():
    right = solution("triplane_lookup", "lookup")

    def variant(swap=False, corners=False, padding="border"):
        def fn(xy, xz, yz, points):
            feats = []
            for plane, (row, col) in ((xy, (0, 1)), (xz, (0, 2)), (yz, (1, 2))):
                uv = (points[..., row], points[..., col]) if swap else (points[..., col], points[..., row])
                grid = torch.stack(uv, -1)[:, None]
                f = F.grid_sample(plane, grid, padding_mode=padding, align_corners=corners)
                feats.append(f[:, :, 0].transpose(1, 2))
            return torch.stack(feats, 2)

        return fn

    ex.check_triplane_lookup(variant())  # the variant machinery itself is right
    fails(ex.check_triplane_lookup, variant(swap=True), "xy, xz, yz plane(s)", "(column, row)")
    fails(ex.check_triplane_lookup, variant(corners=True), "align_corners=False")
    fails(ex.check_triplane_lookup, variant(padding="zeros"), "only points near or outside", "border")
    fails(ex.check_triplane_lookup, lambda xy, xz, yz, p: right(xy, xz, yz, p)[:, :, [0, 2, 1]], "xz, yz plane(s)")


def test_receptive_field_without_the_jump():
    def no_jump(layers):
        return 1 + sum(k - 1 if op == "conv" else 1 if op == "down" else 0 for op, k in layers)

    fails(ex.check_receptive_field, no_jump, "your receptive_field says", "the library", "(k-1)·j")
    fails(ex.check_receptive_field, lambda layers: 1 + 2 * len(layers), "your receptive_field says")


def test_rollout_in_the_wrong_order_or_summed():
    def swapped(xy, xz, yz):
        return torch.cat([xy, yz.mean(3)[:, :, None].expand_as(xy), xz.mean(3, keepdim=True).expand_as(xy)], 1)

    def summed(xy, xz, yz):
        return torch.cat([xy, xz.sum(3, keepdim=True).expand_as(xy), yz.sum(3)[:, :, None].expand_as(xy)], 1)

    fails(ex.check_rollout, swapped, "channels 3..5 (the mean of xz over z)", "[xy, from xz, from yz]")
    fails(ex.check_rollout, summed, "channels 3..5", "mean")
    fails(ex.check_rollout, lambda xy, xz, yz: torch.cat([xy, xz.mean(2)], 1), "raised", "average both over z")


def test_best_patch_iou_dice_or_mean():
    def dice(gen, ref):
        g, r = gen.astype(float), ref.astype(float)
        return (2 * g @ r.T / (g.sum(1)[:, None] + r.sum(1)[None])).max(1)

    def mean_match(gen, ref):
        g, r = gen.astype(float), ref.astype(float)
        inter = g @ r.T
        return (inter / (g.sum(1)[:, None] + r.sum(1)[None] - inter)).mean(1)

    fails(ex.check_best_patch_iou, dice, "your mean best IoU", "F-score")
    fails(ex.check_best_patch_iou, mean_match, "BEST match")
    fails(ex.check_best_patch_iou, lambda gen, ref: np.zeros(len(ref)), "returned shape")


# ----------------------------------------------------------------------------- the shape side
def test_grid_box_rounded_wrongly_or_boxed_by_the_extent():
    right = solution("grid_box", "grid_box")

    def rounded(extent, res):
        e = np.asarray(extent)
        return tuple(int(max(8, np.ceil(round(res * v / e.max()) / 8) * 8)) for v in e), right(extent, res)[1]

    def no_multiple(extent, res):
        e = np.asarray(extent)
        return tuple(int(v) for v in np.floor(res * e / e.max())), right(extent, res)[1]

    def box_of_extent(extent, res):
        e = np.asarray(extent) / max(extent)
        return right(extent, res)[0], np.concatenate([-e, e])

    fails(sx.check_grid_box, rounded, "your shape is", "rounds down")
    fails(sx.check_grid_box, no_multiple, "your shape is", "UP to a multiple of 8")
    fails(sx.check_grid_box, box_of_extent, "your box is", "follows the voxel counts")
    fails(sx.check_grid_box, lambda e, r: right(e, r)[0], "two things")
    fails(sx.check_grid_box, lambda e, r: ((64, 24.5, 32), right(e, r)[1]), "whole numbers")


def test_retarget_scaled_by_the_factor_or_without_the_minimum():
    right = solution("retarget", "retarget")

    def by_factor(res, aabb, f):
        new, _ = right(res, aabb, f)
        return new, np.concatenate([aabb[:3] * np.array(f), aabb[3:] * np.array(f)])

    def no_minimum(res, aabb, f):
        new = np.round(np.array(res) * np.array(f))
        return tuple(int(v) for v in new), np.concatenate([aabb[:3], aabb[3:]]) * np.tile(new / np.array(res), 2)

    def floored(res, aabb, f):
        new = np.maximum(4, np.floor(np.array(res) * np.array(f)))
        return tuple(int(v) for v in new), right(res, aabb, f)[1]

    fails(sx.check_retarget, by_factor, "your box is", "not by the factor")
    fails(sx.check_retarget, no_minimum, "(0.1, 1.0, 1.0)", "at least 4 texels")
    fails(sx.check_retarget, floored, "your latent is", "nearest whole texel")


def test_regenerate_mask_that_frees_every_plane_or_is_inverted():
    right = solution("regenerate_mask", "regenerate_mask")

    def every_plane(res, box, border):  # the box's shadow freed on all three planes, spanned or not
        profiles = []
        for lo, hi, n in zip(*box, res):
            a, b, c = round(lo * n), round(hi * n), np.arange(n) + 0.5
            d = np.maximum(np.maximum(a - c, c - b), 0)
            profiles.append((d == 0).astype(float) if border <= 0 else np.clip(1 - d / border, 0, 1))
        return tuple(1 - np.outer(profiles[p], profiles[q]) for p, q in ((0, 1), (0, 2), (1, 2)))

    def no_ramp(res, box, border):
        return right(res, box, 0.0)

    fails(sx.check_regenerate_mask, every_plane, "mask differs", "must be kept whole")
    fails(sx.check_regenerate_mask, lambda r, b, w: tuple(1 - m for m in right(r, b, w)), "1 means keep")
    fails(sx.check_regenerate_mask, no_ramp, "border 2", "the ramp lies outside the box")
    fails(sx.check_regenerate_mask, lambda r, b, w: right(r, b, w)[:2], "three masks")


def test_tangent_frames_with_the_usual_mistakes():
    right = solution("tangent_frames", "tangent_frames")

    def never_flipped(v, f, uv):
        t, _, n = right(v, f, uv)
        return t, np.cross(n, t), n

    def solved_v(v, f, uv):
        t, _, n = right(v, f, uv)
        tri = v[f]
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        det = (d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1])[:, None]
        b = (e2 * d1[:, :1] - e1 * d2[:, :1]) / det
        return t, b / np.linalg.norm(b, axis=1, keepdims=True), n

    def clockwise(v, f, uv):
        t, b, n = right(v, f, uv)
        return t, b, -n

    fails(sx.check_tangent_frames, never_flipped, "your B differs", "mirrored", "flip B")
    fails(sx.check_tangent_frames, solved_v, "your B differs", "perpendicular to T")
    fails(sx.check_tangent_frames, clockwise, "your N differs on 60 of 60 faces", "counter-clockwise")
    fails(sx.check_tangent_frames, lambda v, f, uv: right(v, f, uv)[:2], "three arrays")


def test_tangent_frames_with_t_and_b_swapped():
    right = solution("tangent_frames", "tangent_frames")
    fails(
        sx.check_tangent_frames,
        lambda v, f, uv: (lambda t, b, n: (b, t, n))(*right(v, f, uv)),
        "your T differs",
        "swapped T and B",
    )


# ----------------------------------------------------------------------------- float32 answers, named mistakes
def as_float32(fn):
    """The solution computed in float32: every float table and input cast before the first operation."""

    def cast(v):
        if isinstance(v, torch.Tensor) and v.is_floating_point():
            return v.float()
        if isinstance(v, np.ndarray) and v.dtype.kind == "f":
            return v.astype(np.float32)
        return v

    def wrapped(*args):
        out = fn(*(cast(a) for a in args))
        return tuple(cast(o) for o in out) if isinstance(out, tuple) else cast(out)

    return wrapped


@pytest.mark.parametrize("check,module,name", CHECKS, ids=[c[1] for c in CHECKS])
def test_a_float32_solution_passes(check, module, name, capsys):
    check(as_float32(solution(module, name)))
    assert capsys.readouterr().out.startswith("✓ your")


def test_a_float32_ddim_step_that_casts_the_tables_first_passes(capsys):
    def ddim32(x_t, x0, t, t_prev, ab):
        ab = ab.float()
        a = ab[t].reshape(-1, 1, 1, 1)
        eps = (x_t - a.sqrt() * x0) / (1 - a).sqrt()
        ap = ab[t_prev] if t_prev >= 0 else torch.tensor(1.0)
        return ap.sqrt() * x0 + (1 - ap).sqrt() * eps

    ex.check_ddim_step(ddim32)
    assert capsys.readouterr().out.startswith("✓ your ddim_step")


def test_half_precision_is_refused_by_name():
    fails(ex.check_q_sample, lambda *a: solution("q_sample", "q_sample")(*a).half(), "float32 or float64")


def test_q_sample_with_t_minus_one():
    def t_minus_one(x0, t, noise, ab):
        a = ab[t - 1].reshape(-1, 1, 1, 1).float()  # at t = 0 this reads ab[-1]
        return a.sqrt() * x0 + (1 - a).sqrt() * noise

    fails(ex.check_q_sample, t_minus_one, "not [t-1]")


def test_ddim_step_without_the_square_root_on_the_noise_term():
    def no_sqrt(x_t, x0, t, t_prev, ab):
        a = ab[t].reshape(-1, 1, 1, 1).float()
        eps = (x_t - a.sqrt() * x0) / (1 - a).sqrt()
        ap = float(ab[t_prev]) if t_prev >= 0 else 1.0
        return math.sqrt(ap) * x0 + (1 - ap) * eps

    msg = fails(ex.check_ddim_step, no_sqrt, "√(1-ᾱ_prev)·ε̂", "left out the square root", "20→0")
    assert "max error 0.000" not in msg  # the worst step is reported, not the first (t = 999, where it is tiny)


def test_posterior_with_the_papers_variance_is_named_and_accepted_when_asked(capsys):
    right = solution("ddpm_posterior", "posterior")

    def beta_var(x0, x_t, t, betas, ab):
        return right(x0, x_t, t, betas, ab)[0], betas[t].reshape(-1, 1, 1, 1).float()

    fails(ex.check_ddpm_posterior, beta_var, "posterior variance differs", "β_t, the paper's", "variance='beta'")
    ex.check_ddpm_posterior(beta_var, variance="beta")
    assert capsys.readouterr().out.startswith("✓ your posterior")
    fails(lambda fn: ex.check_ddpm_posterior(fn, variance="beta"), right, "you asked for the paper's β_t")

    def fixed_large(x0, x_t, t, betas, ab):  # guided-diffusion's: β_t, and β̃_1 at t = 0
        mean, _ = right(x0, x_t, t, betas, ab)
        beta_tilde_1 = betas[1] * (1 - ab[0]) / (1 - ab[1])
        return mean, torch.where(t == 0, beta_tilde_1, betas[t]).reshape(-1, 1, 1, 1)

    ex.check_ddpm_posterior(fixed_large, variance="beta")
    assert capsys.readouterr().out.startswith("✓ your posterior")


def test_lookup_that_swaps_yz_and_xz_names_them():
    right = solution("triplane_lookup", "lookup")
    msg = fails(
        ex.check_triplane_lookup, lambda xy, xz, yz, p: right(xy, xz, yz, p)[:, :, [0, 2, 1]], "xz, yz plane(s)"
    )
    assert "your xz features are the library's yz" in msg and "your yz features are the library's xz" in msg

    def yz_transposed(xy, xz, yz, p):
        out = right(xy, xz, yz, p).clone()
        grid = torch.stack([p[..., 1], p[..., 2]], -1)[:, None]  # (y, z) as (x, y): rows and columns swapped
        out[:, :, 2] = F.grid_sample(yz, grid, padding_mode="border", align_corners=False)[:, :, 0].transpose(1, 2)
        return out

    msg = fails(
        ex.check_triplane_lookup, yz_transposed, "on the yz plane(s)", "on yz you read at (y, z)", "pass (z, y)"
    )
    assert "xz" not in msg.split("hint")[1]


def test_grid_box_without_the_minimum_of_eight():
    def no_minimum(extent, res):
        e = np.asarray(extent, np.float64)
        shape = tuple(int(np.ceil(np.floor(res * v / e.max()) / 8) * 8) for v in e)
        half = np.array(shape) / max(shape)
        return shape, np.concatenate([-half, half])

    fails(sx.check_grid_box, no_minimum, "your shape is", "at least 8 voxels")


def test_best_patch_iou_sorted_has_the_right_values_for_the_wrong_patches():
    right = solution("lp_iou", "best_patch_iou")
    fails(ex.check_best_patch_iou, lambda g, r: np.sort(right(g, r)), "generated patches", "do not sort")


# ----------------------------------------------------------------------------- the loops
def test_training_step_with_the_usual_mistakes():
    def step(target="x0", zero_grad=True, update=True, noise_first=False):
        def fn(denoise, opt, x0, ab, g):
            if noise_first:
                noise = torch.randn(x0.shape, generator=g)
                t = torch.randint(0, len(ab), (x0.shape[0],), generator=g)
            else:
                t = torch.randint(0, len(ab), (x0.shape[0],), generator=g)
                noise = torch.randn(x0.shape, generator=g)
            a = ab[t].reshape(-1, 1, 1, 1).float()
            loss = F.mse_loss(denoise(a.sqrt() * x0 + (1 - a).sqrt() * noise, t), x0 if target == "x0" else noise)
            if zero_grad:
                opt.zero_grad()
            if update:
                loss.backward()
                opt.step()
            return loss.item()

        return fn

    lx.check_training_step(step())  # the variant machinery itself is right
    fails(lx.check_training_step, step(target="eps"), "your loss is", "not the noise")
    fails(lx.check_training_step, step(zero_grad=False), "step 2", "zero_grad")
    fails(lx.check_training_step, step(update=False), "did not move")
    fails(lx.check_training_step, step(noise_first=True), "your loss is", "draw t first")
    fails(lx.check_training_step, lambda *a: None, "return the loss as a number")


def test_ddim_loop_without_clipping_or_the_last_step():
    def loop(clip=True, last=True):
        def fn(denoise, x, ts, ab):
            targets = list(ts[1:]) + ([-1] if last else [])
            for t, t_prev in zip(ts, targets):
                x0 = denoise(x, torch.full((x.shape[0],), t))
                x0 = x0.clamp(-1, 1) if clip else x0
                a, ap = float(ab[t]), float(ab[t_prev]) if t_prev >= 0 else 1.0
                x = ap**0.5 * x0 + (1 - ap) ** 0.5 * (x - a**0.5 * x0) / (1 - a) ** 0.5
            return x

        return fn

    with torch.no_grad():
        lx.check_ddim_loop(loop())  # the variant machinery itself is right
        fails(lx.check_ddim_loop, loop(clip=False), "your ddim_sample differs", "clip")
        fails(lx.check_ddim_loop, loop(last=False), "your ddim_sample differs", "t_prev = -1")


def test_masked_step_with_the_usual_mistakes():
    right = solution("masked_step", "masked_step")
    fails(lx.check_masked_step, lambda x, k, m, tp, ab, n: right(x, k, 1 - m, tp, ab, n), "1 means keep")
    fails(lx.check_masked_step, lambda x, k, m, tp, ab, n: m * k + (1 - m) * x, "t_prev=979", "noise the known")

    def last_wrong(x, k, m, tp, ab, n):
        a = float(ab[tp])
        return m * (a**0.5 * k + (1 - a) ** 0.5 * n) + (1 - m) * x

    fails(lx.check_masked_step, last_wrong, "t_prev=-1", "paste known itself")

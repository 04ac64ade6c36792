"""Every exercise check passes on its solution (notebooks/solutions/) and fails, naming the difference, on wrong answers."""
import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from sin3dm_lite import exercises as ex

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
]


@pytest.mark.parametrize("check,module,name", CHECKS, ids=[c[1] for c in CHECKS])
def test_the_solution_passes(check, module, name, capsys):
    check(solution(module, name))
    assert capsys.readouterr().out.startswith("✓ your")


def test_every_check_has_a_solution_and_a_notebook_uses_it():
    checks = {n for n in ex.__all__ if n.startswith("check_")}
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
    fails(ex.check_q_sample, lambda x0, t, n, ab: solution("q_sample", "q_sample")(x0, (t + 1).clamp(max=999), n, ab),
          "off by one")
    fails(ex.check_q_sample, lambda x0, t, n, ab: ab[t].sqrt() * x0 + (1 - ab[t]).sqrt() * n,
          "your q_sample raised RuntimeError", "[B, 1, 1, 1]")
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

    fails(ex.check_ddim_step, no_eps, "from t=999 to t_prev=979", "keep the noise direction")


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

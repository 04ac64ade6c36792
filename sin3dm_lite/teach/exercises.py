"""Exercises: write a piece of the method yourself, then ``check_…`` it against the library.

Each check calls your function on random inputs, compares its answer with the
package's own code (the code the trainer and the sampler run), prints one
line when they agree and raises :class:`ExerciseError` when they do not,
saying where (which time step, plane, point or layer chain) and by how much;
for the usual mistakes it adds a hint ("did you use √ᾱ_t?").

======================================  ===================================  ==========================
check                                   you write                            the library's version
======================================  ===================================  ==========================
:func:`check_q_sample`                  ``q_sample(x0, t, noise, ab)``       ``NoiseSchedule.q_sample``
:func:`check_ddpm_posterior`            ``posterior(x0, x_t, t, betas, ab)``  ``NoiseSchedule.posterior``
:func:`check_ddim_step`                 ``ddim_step(x_t, x0, t, t_prev, ab)``  ``NoiseSchedule.ddim_step``
:func:`check_triplane_lookup`           ``lookup(xy, xz, yz, points)``       ``Triplane.lookup``
:func:`check_receptive_field`           ``receptive_field(layers)``          ``receptive_field.layers_receptive_field``
:func:`check_rollout`                   ``rollout_xy(xy, xz, yz)``           ``unet.cross_plane_inputs``
:func:`check_best_patch_iou`            ``best_patch_iou(gen, ref)``         ``metrics.lp_scores``
======================================  ===================================  ==========================

The shape side (the grid's box, retargeting, an edit's masks, tangent frames) is in
:mod:`~sin3dm_lite.teach.shape_exercises`, what the checks share in :mod:`~sin3dm_lite.teach.checking`.
Solutions are in ``notebooks/solutions/``; ``tests/test_exercises.py`` runs
every check against its solution and against wrong answers.
"""

from __future__ import annotations

import numpy as np
import torch

from ..data.config import DiffusionConfig
from ..evaluate.metrics import extract_patches, lp_scores
from ..model.schedule import NoiseSchedule
from ..model.triplane import PLANES, Triplane
from ..model.unet import TriplaneUNet, cross_plane_inputs
from .checking import ExerciseError, as64, call, matching_hint, passed
from .receptive_field import layer_walk, layers_receptive_field


# ----------------------------------------------------------------------------- the forward process
def check_q_sample(fn, seed: int = 0, tol: float = 1e-5) -> None:
    """``fn(x0, t, noise, alphas_cumprod) -> x_t``: noise ``x0 [B,C,H,W]`` to step ``t [B]`` in one go.

    ``x_t = √ᾱ_t · x0 + √(1-ᾱ_t) · noise``, with ``ᾱ_t = alphas_cumprod[t]`` (float64, ``t`` from 0 to T-1).
    """
    sch, g = NoiseSchedule(), torch.Generator().manual_seed(seed)
    t = torch.cat([torch.tensor([0, 999, 731]), torch.randint(0, 1000, (5,), generator=g)])
    x0, noise = Triplane.randn(8, 3, (5, 6, 7), generator=g), Triplane.randn(8, 3, (5, 6, 7), generator=g)
    want = sch.q_sample(x0, t, noise)
    worst = 0.0
    for name, p, n, w in zip(PLANES, x0.planes, noise.planes, want.planes):
        got = as64(
            "q_sample",
            call(
                "q_sample",
                fn,
                p.clone(),
                t.clone(),
                n.clone(),
                sch.alphas_cumprod.clone(),
                hint="ᾱ_t is one number per sample: index it with t, reshape to [B, 1, 1, 1]",
            ),
            w,
        )
        err = (got - w.double()).abs().amax((1, 2, 3))
        if float(err.max()) > tol:
            b = int(err.argmax())
            ab = sch.alphas_cumprod[t].reshape(-1, 1, 1, 1)
            shift = lambda d: sch.alphas_cumprod[(t + d).clamp(0, 999)].reshape(-1, 1, 1, 1)  # noqa: E731
            hints = {
                "did you use √ᾱ_t and √(1-ᾱ_t)? You used ᾱ_t and 1-ᾱ_t.": ab * p + (1 - ab) * n,
                "the image gets √ᾱ_t and the noise √(1-ᾱ_t), not the other way round.": (1 - ab).sqrt() * p
                + ab.sqrt() * n,
                "off by one: ᾱ_t is alphas_cumprod[t] (t counts from 0).": shift(-1).sqrt() * p
                + (1 - shift(-1)).sqrt() * n,
                "off by one: ᾱ_t is alphas_cumprod[t], not [t+1].": shift(1).sqrt() * p + (1 - shift(1)).sqrt() * n,
            }
            raise ExerciseError(
                f"your q_sample differs at t={int(t[b])} on the {name} plane: max error "
                f"{float(err[b]):.3g}" + matching_hint(got, hints, 1e-4)
            )
        worst = max(worst, float(err.max()))
    passed("q_sample", len(t) * 3, worst)


# ----------------------------------------------------------------------------- reverse steps
def check_ddpm_posterior(fn, seed: int = 0, tol: float = 1e-5) -> None:
    """``fn(x0, x_t, t, betas, alphas_cumprod) -> (mean, variance)``: one DDPM reverse step, q(x_{t-1} | x_t, x0).

    ``mean = β_t √ᾱ_{t-1} / (1-ᾱ_t) · x0 + (1-ᾱ_{t-1}) √α_t / (1-ᾱ_t) · x_t``,
    ``variance = β_t (1-ᾱ_{t-1}) / (1-ᾱ_t)``, with ``α_t = 1-β_t`` and ``ᾱ_{-1} = 1``.
    The variance may be ``[B, 1, 1, 1]`` or the mean's shape.
    """
    sch, g = NoiseSchedule(), torch.Generator().manual_seed(seed)
    t = torch.cat([torch.tensor([0, 1, 999, 500]), torch.randint(0, 1000, (4,), generator=g)])
    x0, x_t = Triplane.randn(8, 3, (5, 6, 7), generator=g), Triplane.randn(8, 3, (5, 6, 7), generator=g)
    mean, var = sch.posterior(x0, x_t, t)
    worst = 0.0
    for name, a, b, w in zip(PLANES, x0.planes, x_t.planes, mean.planes):
        out = call(
            "posterior",
            fn,
            a.clone(),
            b.clone(),
            t.clone(),
            sch.betas.clone(),
            sch.alphas_cumprod.clone(),
            hint="the tables are indexed per sample: reshape ᾱ_t, β_t, ... to [B, 1, 1, 1]",
        )
        if not (isinstance(out, (tuple, list)) and len(out) == 2):
            raise ExerciseError("your posterior should return two things: (mean, variance)")
        got_mean = as64("posterior (mean)", out[0], w)
        got_var = torch.as_tensor(out[1]).double()
        try:
            got_var = torch.broadcast_to(got_var, w.shape)
        except RuntimeError:
            raise ExerciseError(
                f"your variance has shape {tuple(got_var.shape)}: give one value per sample, [B, 1, 1, 1]"
            ) from None
        for what, got, want in (("mean", got_mean, w.double()), ("variance", got_var, var.double().expand(w.shape))):
            err = (got - want).abs().amax((1, 2, 3))
            if float(err.max()) > tol:
                i = int(err.argmax())
                hint = (
                    "\n  hint: at t = 0 there is no earlier step: ᾱ_{t-1} is 1 there (alphas_cumprod[-1] in Python"
                    " is the LAST value, ᾱ_{T-1})"
                    if int(t[i]) == 0 and float(err[t != 0].max()) <= tol
                    else ""
                )
                raise ExerciseError(
                    f"your posterior {what} differs at t={int(t[i])} on the {name} plane: max error "
                    f"{float(err[i]):.3g}" + hint
                )
            worst = max(worst, float(err.max()))
    passed("posterior", len(t) * 3, worst)


def check_ddim_step(fn, seed: int = 0, tol: float = 1e-5) -> None:
    """``fn(x_t, x0, t, t_prev, alphas_cumprod) -> x_{t_prev}``: one deterministic DDIM step (η = 0).

    The noise that ``x_t`` and the predicted ``x0`` imply, ``ε̂ = (x_t - √ᾱ_t·x0) / √(1-ᾱ_t)``, is kept and
    the blend moves to ``ᾱ_{t_prev}``: ``√ᾱ_prev·x0 + √(1-ᾱ_prev)·ε̂``. ``t [B]`` is a tensor, ``t_prev`` an
    int; ``t_prev = -1`` is the last step, to the clean latent (ᾱ = 1).
    """
    sch, g = NoiseSchedule(), torch.Generator().manual_seed(seed)
    worst, cases = 0.0, 0
    for t, t_prev in ((999, 979), (731, 711), (500, 250), (20, 0), (0, -1)):
        x_t, x0 = Triplane.randn(4, 3, (5, 6, 7), generator=g), Triplane.randn(4, 3, (5, 6, 7), generator=g)
        tt = torch.full((4,), t)
        want = sch.ddim_step(x0, x_t, tt, t_prev)
        for name, a, b, w in zip(PLANES, x_t.planes, x0.planes, want.planes):
            got = as64(
                "ddim_step",
                call("ddim_step", fn, a.clone(), b.clone(), tt.clone(), t_prev, sch.alphas_cumprod.clone()),
                w,
            )
            err = float((got - w.double()).abs().max())
            if err > tol:
                if t_prev < 0:  # every earlier step agreed: the last one is the special case
                    hint = (
                        "\n  hint: alphas_cumprod[-1] is ᾱ_{T-1} (Python counts from the end): at t_prev = -1 "
                        "use ᾱ = 1, which returns x0."
                    )
                else:
                    ap = sch.alphas_cumprod[t_prev]
                    hint = matching_hint(
                        got,
                        {
                            "keep the noise direction: ε̂ = (x_t - √ᾱ_t·x0) / √(1-ᾱ_t), not x_t itself.": ap.sqrt() * b
                            + (1 - ap).sqrt() * a
                        },
                        1e-4,
                    )
                raise ExerciseError(
                    f"your ddim_step differs from t={t} to t_prev={t_prev} on the {name} plane: max error "
                    f"{err:.3g}" + hint
                )
            worst, cases = max(worst, err), cases + 4
    passed("ddim_step", cases, worst)


# ----------------------------------------------------------------------------- the triplane
def check_triplane_lookup(fn, seed: int = 0, tol: float = 1e-5) -> None:
    """``fn(xy, xz, yz, points) -> [B, N, 3, C]``: each point's bilinear feature on the three planes.

    Planes ``xy [B,C,X,Y]``, ``xz [B,C,X,Z]``, ``yz [B,C,Y,Z]``; points ``[B, N, 3]`` in box coordinates [-1, 1].
    A point's feature on ``xz`` is read at ``(x, z)``, row = x, column = z. Texel ``i`` of ``n`` sits at
    ``-1 + (2i+1)/n``; points outside the box read the border texel. Output order: xy, xz, yz.
    """
    g = torch.Generator().manual_seed(seed)
    tp = Triplane.randn(2, 4, (5, 7, 6), generator=g)
    inside = torch.rand(2, 60, 3, generator=g) * 2 - 1
    outside = torch.rand(2, 20, 3, generator=g) * 2.6 - 1.3
    points = torch.cat([inside, outside], 1)
    want = tp.lookup(points)  # [B, N, 3, C]
    got = as64("lookup", call("lookup", fn, tp.xy.clone(), tp.xz.clone(), tp.yz.clone(), points.clone()), want)
    err = (got - want.double()).abs().amax(-1)  # [B, N, 3]
    if float(err.max()) > tol:
        bad = [n for k, n in enumerate(PLANES) if float(err[..., k].max()) > tol]
        deep = (points.abs() < 0.6).all(-1)  # [B, N]: points well inside, away from the border texels
        if not float(err[deep].max()) > tol:
            hint = (
                "only points near or outside the box's border differ: there, repeat the border texel "
                "(padding_mode='border'), do not blend with zeros"
            )
        else:
            hint = (
                "F.grid_sample reads (x, y) = (column, row), so for xz pass (z, x); texel centres are at "
                "-1 + (2i+1)/n (align_corners=False)"
            )
        b, n, k = np.unravel_index(int(err.argmax()), err.shape)
        raise ExerciseError(
            f"your lookup differs on the {', '.join(bad)} plane(s): max error {float(err.max()):.3g} "
            f"at point {points[b, n].numpy().round(3).tolist()} on {PLANES[k]}\n  hint: {hint}"
        )
    passed("lookup", points.shape[0] * points.shape[1], float(err.max()))


def check_rollout(fn, seed: int = 0, tol: float = 1e-6) -> None:
    """``fn(xy, xz, yz) -> [B, 3C, X, Y]``: what the xy plane's Conv2d sees in a TriplaneConv (paper Fig. 3b).

    ``[xy, mean_z(xz) repeated along y, mean_z(yz) repeated along x]`` on the channel axis: xy lacks z, so
    the two other planes are averaged over z; ``mean_z(xz)`` is a feature per x, ``mean_z(yz)`` one per y.
    """
    g = torch.Generator().manual_seed(seed)
    tp = Triplane.randn(2, 3, (5, 6, 7), generator=g)
    want = cross_plane_inputs(tp).xy
    got = as64(
        "rollout_xy",
        call(
            "rollout_xy",
            fn,
            tp.xy.clone(),
            tp.xz.clone(),
            tp.yz.clone(),
            hint="xz is [B, C, X, Z] and yz [B, C, Y, Z]: average both over z, their last axis",
        ),
        want,
    )
    c = tp.channels
    for k, part in enumerate(("the plane itself", "the mean of xz over z", "the mean of yz over z")):
        err = float((got[:, k * c : (k + 1) * c] - want[:, k * c : (k + 1) * c].double()).abs().max())
        if err > tol:
            hint = ""
            if (
                k
                and float((got[:, k * c : (k + 1) * c] - want[:, (3 - k) * c : (4 - k) * c].double()).abs().max())
                <= tol
            ):
                hint = "\n  hint: the order is [xy, from xz, from yz]"
            elif (
                k
                and float((got[:, k * c : (k + 1) * c] - 7 * want[:, k * c : (k + 1) * c].double()).abs().max()) <= 1e-5
            ):
                hint = "\n  hint: average over z (mean), do not sum"
            raise ExerciseError(
                f"your rollout_xy differs in channels {k * c}..{(k + 1) * c - 1} ({part}): max error {err:.3g}" + hint
            )
    passed("rollout_xy", 2 * 3 * c * 5 * 6, float((got - want.double()).abs().max()))


# ----------------------------------------------------------------------------- the denoiser
def _random_chain(rng: np.random.Generator) -> list[tuple[str, int]]:
    """A random valid layer chain: convs (k = 1, 3, 5) with up to two nested pool / upsample pairs."""
    chain, depth = [], 0
    for _ in range(int(rng.integers(3, 12))):
        r = rng.random()
        if r < 0.2 and depth < 2:
            chain.append(("down", 2))
            depth += 1  # noqa: E702
        elif r < 0.35 and depth > 0:
            chain.append(("up", 2))
            depth -= 1  # noqa: E702
        else:
            chain.append(("conv", int(rng.choice([1, 3, 3, 5]))))
    return chain + [("up", 2)] * depth


def check_receptive_field(fn, seed: int = 0) -> None:
    """``fn(layers) -> int``: the receptive-field width (input texels) of a chain of layers.

    ``layers`` is a list of ``("conv", k)`` (k×k, stride 1), ``("down", 2)`` (2×2 average pool) and
    ``("up", 2)`` (bilinear ×2), as :func:`~sin3dm_lite.receptive_field.layer_walk` lists the denoiser's. Keep the
    width ``r`` and the jump ``j`` (input texels between neighbouring texels of the current layer).
    """
    chains = []
    for n in (1, 2, 4, 6, 8):
        for down in (False, True):
            model = TriplaneUNet(2, DiffusionConfig(base_channels=4, time_embed_dim=4, n_resblocks=n, downsample=down))
            chains.append(layer_walk(model))
    rng = np.random.default_rng(seed)
    chains += [_random_chain(rng) for _ in range(20)]
    for layers in chains:
        want = layers_receptive_field(layers)
        got = call("receptive_field", fn, list(layers))
        if got != want:
            no_jump = 1 + sum(k - 1 if op == "conv" else 1 if op == "down" else 0 for op, k in layers)
            hint = (
                (
                    "\n  hint: after a 2×2 pool, neighbouring texels are j = 2 input texels apart: a k×k conv there adds "
                    "(k-1)·j, and the upsample adds the coarse j before halving it"
                )
                if got == no_jump
                else ""
            )
            raise ExerciseError(f"for layers {layers} your receptive_field says {got}, the library {want}" + hint)
    print(
        f"✓ your receptive_field matches the library on {len(chains)} layer chains "
        f"(10 of them the denoiser's; the paper's n = 4 network: {layers_receptive_field(chains[5])} texels)"
    )


# ----------------------------------------------------------------------------- evaluation
def _terrain(rng: np.random.Generator, size: int = 20) -> np.ndarray:
    """An occupancy grid ``(size,)*3``: solid below a bumpy height field over x, z (y up)."""
    x = np.linspace(0, 2 * np.pi, size)
    a, b = rng.uniform(0.5, 2.5, 2)
    h = size / 2 + 3 * np.sin(a * x + rng.uniform(0, 6))[:, None] + 2 * np.cos(b * x + rng.uniform(0, 6))[None, :]
    h = h + rng.normal(0, 0.7, h.shape)
    return np.arange(size)[None, :, None] < h[:, None, :]


def check_best_patch_iou(fn, seed: int = 0, patch: int = 7, stride: int = 3, threshold: float = 0.8123) -> None:
    """``fn(gen, ref) -> (m,)``: for each generated patch (rows of ``gen``, bool ``(m, P)``), its best IoU
    ``|g ∩ r| / |g ∪ r|`` against ALL reference patches (rows of ``ref``, ``(n, P)``): LP-IoU's patch match.

    The check turns your answer into LP-IoU (the share of patches whose best match is above the threshold)
    and the mean best IoU, and compares both with :func:`~sin3dm_lite.metrics.lp_scores` on random terrains.
    (The threshold is one no IoU of two 7³ patches can equal: at a tie, float rounding would decide.)
    """
    rng = np.random.default_rng(seed)
    for case in range(3):
        ref_grid, gen_grid = _terrain(rng), _terrain(rng)
        ref, gen = extract_patches(ref_grid, patch, stride), extract_patches(gen_grid, patch, stride)
        want = lp_scores(ref_grid, gen_grid, patch, stride, max_patches=10**6, threshold=threshold)
        best = call("best_patch_iou", fn, gen.copy(), ref.copy())
        best = np.asarray(best, np.float64)
        if best.shape != (len(gen),):
            raise ExerciseError(
                f"your best_patch_iou returned shape {best.shape}, expected ({len(gen)},): one best "
                f"IoU per generated patch (the best over the {len(ref)} reference patches)"
            )
        got_mean, got_lp = float(best.mean()), float(np.mean(best > threshold))
        if abs(got_mean - want["lp_iou_mean_best"]) > 1e-6 or abs(got_lp - want["lp_iou"]) > 1e-9:
            g, r = gen.astype(np.float64), ref.astype(np.float64)
            inter = g @ r.T
            union = g.sum(1)[:, None] + r.sum(1)[None] - inter
            hints = {
                "that is the F-score (Dice), 2|g∩r| / (|g|+|r|); IoU divides |g∩r| by the union |g|+|r|-|g∩r|": (
                    2 * inter / (g.sum(1)[:, None] + r.sum(1)[None])
                ).max(1),
                "take the BEST match (max over the reference patches), not the mean": (inter / union).mean(1),
            }
            hint = next((f"\n  hint: {h}" for h, v in hints.items() if np.allclose(best, v, atol=1e-6)), "")
            raise ExerciseError(
                f"terrain {case}: your mean best IoU is {got_mean:.4f} (LP-IoU {got_lp:.3f}), the "
                f"library's {want['lp_iou_mean_best']:.4f} (LP-IoU {want['lp_iou']:.3f})" + hint
            )
    print(
        f"✓ your best_patch_iou gives the library's LP-IoU on 3 random terrains (last: {want['lp_iou']:.3f}, "
        f"mean best IoU {want['lp_iou_mean_best']:.3f})"
    )


__all__ = [
    "ExerciseError",
    "check_best_patch_iou",
    "check_ddim_step",
    "check_ddpm_posterior",
    "check_q_sample",
    "check_receptive_field",
    "check_rollout",
    "check_triplane_lookup",
]

"""Exercises: write a piece of the method yourself, then ``check_…`` it against the library.

Each check calls your function on random inputs, compares its answer with the package's own code (what the
trainer and the sampler run), prints one line when they agree and raises :class:`ExerciseError` when they do
not, saying where and by how much, with a hint for the usual mistakes. The shape side is in
:mod:`~sin3dm_lite.teach.shape_exercises`, the loops in :mod:`~sin3dm_lite.teach.loop_exercises`;
solutions are in ``notebooks/solutions/``.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from ..data.config import DiffusionConfig
from ..evaluate.metrics import extract_patches, lp_scores
from ..evaluate.patches import patch_matches
from ..model.schedule import NoiseSchedule
from ..model.triplane import PLANE_AXES, PLANES, Triplane
from ..model.unet import TriplaneUNet, cross_plane_inputs
from .checking import ExerciseError, as64, call, matching_hint, parts, passed, tolerance
from .receptive_field import layer_walk, layers_receptive_field


# ----------------------------------------------------------------------------- the forward process
def _per_sample(v: torch.Tensor) -> torch.Tensor:
    return v.reshape(-1, 1, 1, 1)


def _fail(what: str, err: torch.Tensor, t, name: str, hint: str) -> ExerciseError:
    """The error for the worst sample of ``err [B]`` (max errors per sample), with the step it was at."""
    b = int(err.argmax())
    return ExerciseError(
        f"your {what} differs at t={int(t[b])} on the {name} plane: max error {float(err[b]):.3g}" + hint
    )


def check_q_sample(fn, seed: int = 0, tol: float = 1e-5) -> None:
    """``fn(x0, t, noise, alphas_cumprod) -> x_t``: noise ``x0 [B,C,H,W]`` to step ``t [B]`` in one go.

    ``x_t = √ᾱ_t · x0 + √(1-ᾱ_t) · noise``, with ``ᾱ_t = alphas_cumprod[t]`` (float64, ``t`` from 0 to T-1).
    """
    sch, g = NoiseSchedule(), torch.Generator().manual_seed(seed)
    t = torch.cat([torch.tensor([0, 999, 731]), torch.randint(0, 1000, (5,), generator=g)])
    x0, noise = Triplane.randn(8, 3, (5, 6, 7), generator=g), Triplane.randn(8, 3, (5, 6, 7), generator=g)
    want, ab, worst = sch.q_sample(x0, t, noise), sch.alphas_cumprod, 0.0
    hint = "ᾱ_t is one number per sample: index it with t, reshape to [B, 1, 1, 1]"
    for name, p, n, w in zip(PLANES, x0.planes, noise.planes, want.planes):
        raw = call("q_sample", fn, *(v.clone() for v in (p, t, n, ab)), hint=hint)
        got, w = as64("q_sample", raw, w), w.double()
        p, n, tol_ = p.double(), n.double(), tolerance(raw, tol, float(w.abs().max()))
        err = (got - w).abs().amax((1, 2, 3))
        if float(err.max()) > tol_:
            a, up, down = (_per_sample(ab[k]) for k in (t, (t + 1).clamp(max=999), t - 1))  # t - 1 wraps at 0
            swapped = (1 - a).sqrt() * p + a.sqrt() * n
            hints = {
                "did you use √ᾱ_t and √(1-ᾱ_t)? You used ᾱ_t and 1-ᾱ_t.": a * p + (1 - a) * n,
                "the image gets √ᾱ_t and the noise √(1-ᾱ_t), not the other way round.": swapped,
                "off by one: ᾱ_t is alphas_cumprod[t], not [t+1].": up.sqrt() * p + (1 - up).sqrt() * n,
                "off by one: ᾱ_t is alphas_cumprod[t], not [t-1] (t counts from 0; at t = 0, [t-1] is the LAST "
                "value).": down.sqrt() * p + (1 - down).sqrt() * n,
            }
            raise _fail("q_sample", err, t, name, matching_hint(got, hints, tol_, w))
        worst = max(worst, float(err.max()))
    passed("q_sample", len(t) * 3, worst)


# ----------------------------------------------------------------------------- reverse steps
def _posterior_wrong(sch: NoiseSchedule, t: torch.Tensor, x0: torch.Tensor, x_t: torch.Tensor) -> dict:
    """The usual mistakes in the posterior's mean, each as the mean it gives."""
    at = lambda v: _per_sample(v[t])
    ab, ab_prev, beta = at(sch.alphas_cumprod), _per_sample(sch.alphas_cumprod[t - 1]), at(sch.betas)
    right_prev = at(sch.alphas_cumprod_prev)
    c0 = lambda p: beta * p.sqrt() / (1 - ab)
    ct = lambda p, a: (1 - p) * a / (1 - ab)
    no_root = beta * right_prev / (1 - ab) * x0 + ct(right_prev, (1 - beta).sqrt()) * x_t
    return {
        "at t = 0 there is no earlier step: ᾱ_{t-1} is 1 there (alphas_cumprod[t-1] at t = 0 is alphas_cumprod[-1], "
        "the LAST value, ᾱ_{T-1})": c0(ab_prev) * x0 + ct(ab_prev, (1 - beta).sqrt()) * x_t,
        "x_t's coefficient holds √α_t = √(1-β_t), not α_t": c0(right_prev) * x0 + ct(right_prev, 1 - beta) * x_t,
        "x0's coefficient holds √ᾱ_{t-1}, not ᾱ_{t-1}": no_root,
    }


def check_ddpm_posterior(fn, seed: int = 0, tol: float = 1e-5, variance: str = "posterior") -> None:
    """``fn(x0, x_t, t, betas, alphas_cumprod) -> (mean, variance)``: one DDPM reverse step, q(x_{t-1} | x_t, x0).

    ``mean = β_t √ᾱ_{t-1} / (1-ᾱ_t) · x0 + (1-ᾱ_{t-1}) √α_t / (1-ᾱ_t) · x_t``, with ``α_t = 1-β_t`` and
    ``ᾱ_{-1} = 1``. ``variance="posterior"`` (this library's sampler) checks the posterior's own
    ``β̃_t = β_t (1-ᾱ_{t-1}) / (1-ᾱ_t)``; ``variance="beta"`` the paper's σ_t² = β_t (as guided-diffusion's
    fixed large variance, which at t = 0 takes β̃_1: either is accepted there). The variance may be
    ``[B, 1, 1, 1]`` or the mean's shape; it is compared relative to its size.
    """
    if variance not in ("posterior", "beta"):
        raise ExerciseError(f"variance is 'posterior' (β̃_t) or 'beta' (β_t), not {variance!r}")
    sch, g = NoiseSchedule(), torch.Generator().manual_seed(seed)
    t = torch.cat([torch.tensor([0, 1, 999, 500]), torch.randint(0, 1000, (4,), generator=g)])
    x0, x_t = Triplane.randn(8, 3, (5, 6, 7), generator=g), Triplane.randn(8, 3, (5, 6, 7), generator=g)
    mean, var = sch.posterior(x0, x_t, t)
    beta_t, post = _per_sample(sch.betas[t]), var.double()
    want_var = post if variance == "posterior" else beta_t
    fixed_large = torch.where(_per_sample(t) == 0, sch.posterior_variance[1], beta_t)  # guided-diffusion's β
    worst, per_sample = 0.0, "the tables are indexed per sample: reshape ᾱ_t, β_t, ... to [B, 1, 1, 1]"
    for name, a, b, w in zip(PLANES, x0.planes, x_t.planes, mean.planes):
        out = call("posterior", fn, *(v.clone() for v in (a, b, t, sch.betas, sch.alphas_cumprod)), hint=per_sample)
        parts("posterior", out, 2, "two things: (mean, variance)")
        got, w = as64("posterior (mean)", out[0], w), w.double()
        tol_ = tolerance(out[0], tol, float(w.abs().max()))
        err = (got - w).abs().amax((1, 2, 3))
        if float(err.max()) > tol_:
            hint = matching_hint(got, _posterior_wrong(sch, t, a.double(), b.double()), tol_, w)
            raise _fail("posterior mean", err, t, name, hint)
        got_var = torch.as_tensor(out[1]).double()
        try:
            got_var = torch.broadcast_to(got_var, w.shape).amax((1, 2, 3)) if got_var.dim() else got_var.expand(len(t))
        except RuntimeError:
            raise ExerciseError(
                f"your variance has shape {tuple(got_var.shape)}: give one value per sample, [B, 1, 1, 1]"
            ) from None
        rel = lambda ref, v=got_var: (v - ref.reshape(-1)).abs() / ref.reshape(-1).clamp(min=1e-8)
        vtol = tolerance(out[1] if isinstance(out[1], torch.Tensor) else got_var, tol)  # relative to the variance
        ok = rel(want_var) <= vtol
        if variance == "beta":  # at t = 0 the authors' code takes β̃_1: accepted too
            ok = ok | (rel(fixed_large) <= vtol)
        if not bool(ok.all()):
            err = torch.where(ok, 0.0, rel(want_var))
            wraps = _per_sample(sch.betas[t] * (1 - sch.alphas_cumprod[t - 1]) / (1 - sch.alphas_cumprod[t]))
            hints = {
                "that is β_t, the paper's σ_t² (the authors' code uses it too); this library's sampler uses the "
                "posterior's own variance β̃_t. To check the paper's choice: check_ddpm_posterior(posterior, "
                "variance='beta')": beta_t,
                "that is β̃_t, the posterior's variance; you asked for the paper's β_t": post,
                "at t = 0 there is no earlier step: ᾱ_{t-1} is 1 there (alphas_cumprod[-1] in Python is the LAST "
                "value, ᾱ_{T-1})": wraps,
            }
            hint = next((f"\n  hint: {h}" for h, v in hints.items() if bool((rel(v)[~ok] <= vtol).all())), "")
            raise _fail("posterior variance", err, t, name, hint)
        worst = max(worst, float(err.max()))
    passed("posterior", len(t) * 3, worst)


def _ddim_wrong(ab: torch.Tensor, t: int, t_prev: int, x_t: torch.Tensor, x0: torch.Tensor) -> dict:
    """The usual mistakes in one DDIM step, each as the step it gives."""
    a, ap = float(ab[t]), float(ab[t_prev]) if t_prev >= 0 else 1.0
    eps = (x_t - a**0.5 * x0) / (1 - a) ** 0.5
    last = float(ab[t_prev])  # at t_prev = -1: ᾱ_{T-1}
    wrapped = last**0.5 * x0 + (1 - last) ** 0.5 * eps
    keep_x_t = ap**0.5 * x0 + (1 - ap) ** 0.5 * x_t
    eps_no_root = ap**0.5 * x0 + (1 - ap) ** 0.5 * (x_t - a**0.5 * x0) / (1 - a)
    return {
        "keep the noise direction: ε̂ = (x_t - √ᾱ_t·x0) / √(1-ᾱ_t), not x_t itself.": keep_x_t,
        "the noise term is √(1-ᾱ_prev)·ε̂: you left out the square root.": ap**0.5 * x0 + (1 - ap) * eps,
        "ε̂ divides by √(1-ᾱ_t), not by 1-ᾱ_t: you left out the square root.": eps_no_root,
        "the clean term is √ᾱ_prev·x0: you left out the square root.": ap * x0 + (1 - ap) ** 0.5 * eps,
        "alphas_cumprod[-1] is ᾱ_{T-1} (Python counts from the end): at t_prev = -1 use ᾱ = 1, which returns x0.": wrapped,
    }


def check_ddim_step(fn, seed: int = 0, tol: float = 1e-5) -> None:
    """``fn(x_t, x0, t, t_prev, alphas_cumprod) -> x_{t_prev}``: one deterministic DDIM step (η = 0).

    The noise that ``x_t`` and the predicted ``x0`` imply, ``ε̂ = (x_t - √ᾱ_t·x0) / √(1-ᾱ_t)``, is kept and
    the blend moves to ``ᾱ_{t_prev}``: ``√ᾱ_prev·x0 + √(1-ᾱ_prev)·ε̂``. ``t [B]`` is a tensor, ``t_prev`` an
    int; ``t_prev = -1`` is the last step, to the clean latent (ᾱ = 1). The worst step is reported.
    """
    sch, g = NoiseSchedule(), torch.Generator().manual_seed(seed)
    ab, results, worst, cases = sch.alphas_cumprod, [], 0.0, 0
    for t, t_prev in ((999, 979), (731, 711), (500, 250), (20, 0), (0, -1)):
        x_t, x0 = Triplane.randn(4, 3, (5, 6, 7), generator=g), Triplane.randn(4, 3, (5, 6, 7), generator=g)
        tt = torch.full((4,), t)
        want = sch.ddim_step(x0, x_t, tt, t_prev)
        for name, a, b, w in zip(PLANES, x_t.planes, x0.planes, want.planes):
            raw = call("ddim_step", fn, a.clone(), b.clone(), tt.clone(), t_prev, ab.clone())
            got, w = as64("ddim_step", raw, w), w.double()
            tol_ = tolerance(raw, tol, float(w.abs().max()))
            err = float((got - w).abs().max())
            results.append(
                (err / tol_, err, t, t_prev, name, got, w, _ddim_wrong(ab, t, t_prev, a.double(), b.double()), tol_)
            )
            worst, cases = max(worst, err), cases + 4
    bad = [r for r in results if r[0] > 1]
    if bad:
        _, err, t, t_prev, name, *_ = max(bad, key=lambda r: r[0])
        explains = {  # how many wrong steps each usual mistake explains
            text: sum(bool(matching_hint(r[5], {text: r[7][text]}, r[8], r[6], rtol=1e-2)) for r in bad)
            for text in bad[0][7]
        }
        text = max(explains, key=explains.get)
        hint = f"\n  hint: {text}" if explains[text] else ""
        steps = ", ".join(dict.fromkeys(f"{r[2]}→{r[3]}" for r in bad))
        raise ExerciseError(
            f"your ddim_step differs from t={t} to t_prev={t_prev} on the {name} plane: max error {err:.3g} "
            f"(wrong steps: {steps})" + hint
        )
    passed("ddim_step", cases, worst)


# ----------------------------------------------------------------------------- the triplane
def _lookup_hints(tp: Triplane, points: torch.Tensor, got: torch.Tensor, want: torch.Tensor, k: int, tol: float) -> str:
    """Why plane ``k`` of the student's lookup is wrong: another plane's features, (row, col) swapped, corners."""
    plane, (row, col), axis = PLANES[k], PLANE_AXES[PLANES[k]], "xyz"

    def read(rc, corners=False, padding="border"):
        grid = torch.stack([points[..., rc[1]], points[..., rc[0]]], -1)[:, None]
        f = F.grid_sample(tp.planes[k], grid, padding_mode=padding, align_corners=corners)
        return f[:, :, 0].transpose(1, 2)  # [B, N, C]

    hints = {
        f"your {plane} features are the library's {other}: the output order is xy, xz, yz ([B, N, 3, C], "
        f"plane {k} is {plane})": want[:, :, j]
        for j, other in enumerate(PLANES)
        if j != k
    }
    hints |= {
        f"on {plane} you read at ({axis[row]}, {axis[col]}) as (x, y) for grid_sample, which reads (x, y) = "
        f"(column, row): pass ({axis[col]}, {axis[row]})": read((col, row)),
        "texel centres are at -1 + (2i+1)/n: use align_corners=False": read((row, col), corners=True),
        "only points near or outside the box's border differ: there, repeat the border texel "
        "(padding_mode='border'), do not blend with zeros": read((row, col), padding="zeros"),
    }
    return matching_hint(got[:, :, k], hints, tol, want[:, :, k])


def check_triplane_lookup(fn, seed: int = 0, tol: float = 1e-5) -> None:
    """``fn(xy, xz, yz, points) -> [B, N, 3, C]``: each point's bilinear feature on the three planes.

    Planes ``xy [B,C,X,Y]``, ``xz [B,C,X,Z]``, ``yz [B,C,Y,Z]``; points ``[B, N, 3]`` in box coordinates [-1, 1].
    A point's feature on ``xz`` is read at ``(x, z)``, row = x, column = z. Texel ``i`` of ``n`` sits at
    ``-1 + (2i+1)/n``; points outside the box read the border texel. Output order: xy, xz, yz.
    """
    g = torch.Generator().manual_seed(seed)
    tp = Triplane.randn(2, 4, (5, 7, 6), generator=g)
    inside = torch.rand(2, 60, 3, generator=g) * 2 - 1
    points = torch.cat([inside, torch.rand(2, 20, 3, generator=g) * 2.6 - 1.3], 1)  # and outside
    want = tp.lookup(points)  # [B, N, 3, C]
    raw = call("lookup", fn, tp.xy.clone(), tp.xz.clone(), tp.yz.clone(), points.clone())
    got, tol_ = as64("lookup", raw, want), tolerance(raw, tol, float(want.abs().max()))
    err = (got - want.double()).abs().amax(-1)  # [B, N, 3]
    if float(err.max()) > tol_:
        bad = [k for k in range(3) if float(err[..., k].max()) > tol_]
        hints = "".join(dict.fromkeys(_lookup_hints(tp, points, got, want.double(), k, tol_) for k in bad))
        b, n, k = np.unravel_index(int(err.argmax()), err.shape)
        raise ExerciseError(
            f"your lookup differs on the {', '.join(PLANES[k] for k in bad)} plane(s): max error "
            f"{float(err.max()):.3g} at point {points[b, n].numpy().round(3).tolist()} on {PLANES[k]}"
            + (hints or "\n  hint: F.grid_sample reads (x, y) = (column, row); texel centres are at -1 + (2i+1)/n")
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
    hint = "xz is [B, C, X, Z] and yz [B, C, Y, Z]: average both over z, their last axis"
    got = as64("rollout_xy", call("rollout_xy", fn, *(p.clone() for p in tp.planes), hint=hint), want)
    c = tp.channels
    part_of = lambda x, k: x[:, k * c : (k + 1) * c].double()  # the channels from plane k
    for k, part in enumerate(("the plane itself", "the mean of xz over z", "the mean of yz over z")):
        mine = part_of(got, k)
        err = float((mine - part_of(want, k)).abs().max())
        if err > tol:
            hint = ""
            if k and float((mine - part_of(want, 3 - k)).abs().max()) <= tol:
                hint = "\n  hint: the order is [xy, from xz, from yz]"
            elif k and float((mine - 7 * part_of(want, k)).abs().max()) <= 1e-5:
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
            depth += 1
        elif r < 0.35 and depth > 0:
            chain.append(("up", 2))
            depth -= 1
        else:
            chain.append(("conv", int(rng.choice([1, 3, 3, 5]))))
    return chain + [("up", 2)] * depth


def check_receptive_field(fn, seed: int = 0) -> None:
    """``fn(layers) -> int``: the receptive-field width (input texels) of a chain of layers.

    ``layers`` is a list of ``("conv", k)`` (k×k, stride 1), ``("down", 2)`` (2×2 average pool) and
    ``("up", 2)`` (bilinear ×2), as :func:`~sin3dm_lite.receptive_field.layer_walk` lists the denoiser's. Keep the
    width ``r`` and the jump ``j`` (input texels between neighbouring texels of the current layer).
    """
    chains = [
        layer_walk(TriplaneUNet(2, DiffusionConfig(base_channels=4, time_embed_dim=4, n_resblocks=n, downsample=down)))
        for n in (1, 2, 4, 6, 8)
        for down in (False, True)
    ]
    rng = np.random.default_rng(seed)
    chains += [_random_chain(rng) for _ in range(20)]
    for layers in chains:
        want = layers_receptive_field(layers)
        got = call("receptive_field", fn, list(layers))
        if got != want:
            no_jump = 1 + sum(k - 1 if op == "conv" else 1 if op == "down" else 0 for op, k in layers)
            hint = (
                "\n  hint: after a 2×2 pool, neighbouring texels are j = 2 input texels apart: a k×k conv there adds "
                "(k-1)·j, and the upsample adds the coarse j before halving it"
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
    (No IoU of two 7³ patches can equal the threshold: at a tie, float rounding would decide.)
    """
    rng = np.random.default_rng(seed)
    for case in range(3):
        ref_grid, gen_grid = _terrain(rng), _terrain(rng)
        ref, gen = extract_patches(ref_grid, patch, stride), extract_patches(gen_grid, patch, stride)
        want = lp_scores(ref_grid, gen_grid, patch, stride, max_patches=10**6, threshold=threshold)
        best = np.asarray(call("best_patch_iou", fn, gen.copy(), ref.copy()), np.float64)
        if best.shape != (len(gen),):
            raise ExerciseError(
                f"your best_patch_iou returned shape {best.shape}, expected ({len(gen)},): one best "
                f"IoU per generated patch (the best over the {len(ref)} reference patches)"
            )
        got_mean, got_lp = float(best.mean()), float(np.mean(best > threshold))
        per_patch = patch_matches(ref_grid, gen_grid, 1, patch, stride, max_patches=10**6)["best_iou"]
        wrong = np.abs(best - per_patch) > 1e-6
        if wrong.any():
            g, r = gen.astype(np.float64), ref.astype(np.float64)
            inter, sizes = g @ r.T, g.sum(1)[:, None] + r.sum(1)[None]
            best_dice, iou = (2 * inter / sizes).max(1), inter / (sizes - inter)
            by_ref = iou.max(0)[: len(gen)] if len(ref) >= len(gen) else per_patch + 1  # else: a value none matches
            hints = {
                "that is the F-score (Dice), 2|g∩r| / (|g|+|r|); IoU divides |g∩r| by the union |g|+|r|-|g∩r|": best_dice,
                "take the BEST match (max over the reference patches), not the mean": iou.mean(1),
                "the right values in another order: keep one value per generated patch, in the order of gen's rows "
                "(do not sort them)": np.sort(per_patch),
                "that is each REFERENCE patch's best match (max over gen); LP-IoU asks, for each generated patch, "
                "for its best match among the input's": by_ref,
            }
            hint = matching_hint(best, hints, 1e-6, per_patch)
            i = int(np.flatnonzero(wrong)[0])
            raise ExerciseError(
                f"terrain {case}: your best IoU differs on {int(wrong.sum())} of {len(gen)} generated patches; "
                f"patch {i}: yours {best[i]:.4f}, the library's {per_patch[i]:.4f} (your mean best IoU "
                f"{got_mean:.4f}, LP-IoU {got_lp:.3f}; the library's {want['lp_iou_mean_best']:.4f}, "
                f"{want['lp_iou']:.3f})" + hint
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

"""Exercises that write the loops: the training step and the DDIM loop (notebook 00b), the masked step (06).

The 2D loops work on images ``[B, 3, H, W]`` in [-1, 1] and a ``denoise(x_t, t) -> x̂0`` function
(:func:`image_denoiser`: the package's ``TriplaneUNet`` on the ``xy`` plane of a flat triplane). Each check
runs your function next to the library, on the same model and random numbers, and names what differs.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ..data.config import DiffusionConfig
from ..model.diffusion import sample
from ..model.schedule import NoiseSchedule, ddim_timesteps
from ..model.triplane import PLANES, Triplane
from ..model.unet import TriplaneUNet
from .checking import ExerciseError, as64, call, matching_hint, passed, tolerance


def _flat(images: torch.Tensor) -> Triplane:
    """Images ``[B, C, H, W]`` as the xy plane of a flat triplane (xz, yz: one texel of zeros)."""
    b, c, h, w = images.shape
    return Triplane(images, images.new_zeros(b, c, h, 1), images.new_zeros(b, c, w, 1))


def image_denoiser(model: TriplaneUNet):
    """``denoise(x_t [B, 3, H, W], t [B]) -> x̂0 [B, 3, H, W]``: the denoiser on images (the xy plane of a flat triplane)."""
    return lambda x_t, t: model(_flat(x_t), t).xy


def _tiny_model(seed: int = 0) -> TriplaneUNet:
    """A small 2D denoiser with random weights everywhere (a fresh one answers 0: its last convolutions start at 0)."""
    g = torch.Generator().manual_seed(seed)
    cfg = DiffusionConfig(base_channels=8, time_embed_dim=8, n_resblocks=1, downsample=False, rollout=False)
    model = TriplaneUNet(3, cfg)
    with torch.no_grad():
        for p in model.parameters():
            p.copy_(torch.randn(p.shape, generator=g) * 0.3)
        for p in model.out_conv.parameters():  # answers beyond [-1, 1], so that clipping shows
            p.mul_(4.0)
    return model


# ----------------------------------------------------------------------------- the training step (00b)
def _reference_step(model, opt, x0, ab, g, target: str = "x0", zero_grad: bool = True) -> float:
    """One training step from the library's pieces: t, then noise, from ``g``; q_sample; MSE to x0; a step."""
    t = torch.randint(0, len(ab), (x0.shape[0],), generator=g)
    noise = torch.randn(x0.shape, generator=g)
    x_t = NoiseSchedule().q_sample(_flat(x0), t, _flat(noise))
    loss = F.mse_loss(image_denoiser(model)(x_t.xy, t), x0 if target == "x0" else noise)
    if zero_grad:
        opt.zero_grad()
    loss.backward()
    opt.step()
    return loss.item()


def _params(model) -> torch.Tensor:
    return torch.cat([p.detach().reshape(-1) for p in model.parameters()]).double()


def check_training_step(fn, seed: int = 0) -> None:
    """``fn(denoise, optimizer, x0, alphas_cumprod, generator) -> loss``: one step of training on a batch of images.

    Draw ``t = torch.randint(0, T, (B,), generator=generator)`` first, then ``noise = torch.randn(x0.shape,
    generator=generator)``; noise the batch to ``x_t`` (your ``q_sample``); the loss is the mean squared error
    between ``denoise(x_t, t)`` and the clean ``x0`` (x0-prediction); clear the old gradients, backpropagate,
    step the optimizer; return the loss as a number. Checked over two steps against the library's pieces.
    """
    ab = NoiseSchedule().alphas_cumprod
    x0 = torch.rand(4, 3, 8, 8, generator=torch.Generator().manual_seed(seed)) * 2 - 1
    models = {k: _tiny_model(seed) for k in ("yours", "library", "eps", "accumulate")}
    # plain SGD: Adam divides by the gradient's size, which would turn float rounding of tiny gradients into steps
    opts = {k: torch.optim.SGD(m.parameters(), lr=0.05) for k, m in models.items()}
    gens = {k: torch.Generator().manual_seed(seed + 1) for k in models}
    start = _params(models["yours"])
    for step in range(2):
        got = call(
            "training_step", fn, image_denoiser(models["yours"]), opts["yours"], x0.clone(), ab.clone(), gens["yours"]
        )
        want = _reference_step(models["library"], opts["library"], x0, ab, gens["library"])
        eps = _reference_step(models["eps"], opts["eps"], x0, ab, gens["eps"], target="eps")
        _reference_step(models["accumulate"], opts["accumulate"], x0, ab, gens["accumulate"], zero_grad=False)
        if not isinstance(got, (float, int)) and not (isinstance(got, torch.Tensor) and got.numel() == 1):
            raise ExerciseError(f"your training_step returned a {type(got).__name__}: return the loss as a number")
        got = float(got)
        if abs(got - want) > 1e-5 * max(1.0, abs(want)):
            hint = (
                "the target is the clean image x0 (the paper's x0-prediction), not the noise"
                if abs(got - eps) < 1e-5
                else (
                    f"draw t first (torch.randint(0, {len(ab)}, (B,), generator=generator)), then the noise "
                    "(torch.randn(x0.shape, generator=generator)), and noise x0 with √ᾱ_t and √(1-ᾱ_t)"
                )
            )
            raise ExerciseError(f"step {step + 1}: your loss is {got:.6f}, the library's {want:.6f}\n  hint: {hint}")
        mine, ref = _params(models["yours"]), _params(models["library"])
        if float((mine - ref).abs().max()) > 1e-5:
            if float((mine - start).abs().max()) == 0:
                hint = "the weights did not move: call loss.backward() and optimizer.step()"
            elif float((mine - _params(models["accumulate"])).abs().max()) <= 1e-5:
                hint = "clear the old gradients (optimizer.zero_grad()) before loss.backward(): they add up"
            else:
                hint = "zero the gradients, backpropagate the loss you return, then step the optimizer once"
            raise ExerciseError(
                f"step {step + 1}: your loss is right but the weights differ from the library's by up to "
                f"{float((mine - ref).abs().max()):.3g}\n  hint: {hint}"
            )
    print(f"✓ your training_step matches the library over 2 steps (losses {got:.4f}; the weights agree)")


# ----------------------------------------------------------------------------- the DDIM loop (00b)
def check_ddim_loop(fn, seed: int = 0, steps: int = 6) -> None:
    """``fn(denoise, x_T, timesteps, alphas_cumprod) -> x0``: DDIM sampling (η = 0) from the noise ``x_T``.

    For each ``t`` in ``timesteps`` (falling, e.g. ``[999, 799, ..., 0]``): predict ``x̂0 = denoise(x, t)``
    with ``t`` as a ``[B]`` tensor, clip it to [-1, 1], and take one DDIM step to the next time step in the
    list, or to ``-1`` (ᾱ = 1, the clean image) after the last: your ``ddim_step``. Returns the final image,
    compared with the package's sampler on the same model and noise.
    """
    model, ab = _tiny_model(seed).eval(), NoiseSchedule().alphas_cumprod
    ts = ddim_timesteps(1000, steps)
    with torch.no_grad():
        want, inter = sample(
            model,
            None,
            (8, 10, 1),
            n=2,
            steps=steps,
            seed=torch.Generator().manual_seed(seed),
            progress=False,
            return_intermediates=list(range(steps)),
        )
        x_T = torch.randn((2, 3, 8, 10), generator=torch.Generator().manual_seed(seed))  # the sampler's first draw
        raw = call("ddim_sample", fn, image_denoiser(model), x_T.clone(), list(ts), ab.clone())
    got, w = as64("ddim_sample", raw, want.xy), want.xy.double()
    tol = tolerance(raw, 1e-5, float(w.abs().max()))
    err = float((got - w).abs().max())
    if err > tol:
        before_last = inter[-1]["x_t"].xy  # the input of the last step
        hints = {
            "the loop ends with a step to t_prev = -1 (ᾱ = 1): return what that step gives, the clean image": before_last,
            "clip the predicted x̂0 to [-1, 1] at every step, as the sampler does": _unclipped(model, x_T, ts, ab),
        }
        raise ExerciseError(
            f"your ddim_sample differs from the sampler's: max error {err:.3g} after {steps} steps ({ts})"
            + matching_hint(got, hints, max(tol, 1e-4), w)
        )
    passed("ddim_sample", 2 * steps, err)


@torch.no_grad()
def _unclipped(model, x, ts, ab) -> torch.Tensor:
    """The DDIM loop without clipping x̂0 (a usual mistake)."""
    for i, t in enumerate(ts):
        tt = torch.full((x.shape[0],), t)
        x0 = image_denoiser(model)(x, tt)
        a, ap = float(ab[t]), float(ab[ts[i + 1]]) if i + 1 < len(ts) else 1.0
        x = ap**0.5 * x0 + (1 - ap) ** 0.5 * (x - a**0.5 * x0) / (1 - a) ** 0.5
    return x


# ----------------------------------------------------------------------------- masked replacement (06)
def check_masked_step(fn, seed: int = 0) -> None:
    """``fn(x, known, mask, t_prev, alphas_cumprod, noise) -> x``: after a reverse step to ``t_prev``, put back
    what is kept: ``mask · q_sample(known, t_prev, noise) + (1 - mask) · x``; at ``t_prev = -1`` (the end) the
    known latent itself, ``mask · known + (1 - mask) · x``. One plane ``[B, C, H, W]`` at a time; ``mask`` is
    ``[1, 1, H, W]`` with 1 = keep. This is what ``sample(..., known=, mask=)`` does after every step.
    """
    sch, g = NoiseSchedule(), torch.Generator().manual_seed(seed)
    ab, worst = sch.alphas_cumprod, 0.0
    for t_prev in (979, 500, 20, 0, -1):
        x, known = Triplane.randn(2, 3, (6, 5, 4), generator=g), Triplane.randn(1, 3, (6, 5, 4), generator=g)
        noise = Triplane.randn(2, 3, (6, 5, 4), generator=g)
        mask = Triplane(*(torch.rand((1, 1, *p.shape[2:]), generator=g).round() for p in known.planes))
        keep = sch.q_sample(known.repeat(2), t_prev, noise) if t_prev >= 0 else known.repeat(2)
        for name, xp, kp, mp, np_, kept in zip(PLANES, x.planes, known.planes, mask.planes, noise.planes, keep.planes):
            want = (mp * kept + (1 - mp) * xp).double()
            raw = call("masked_step", fn, xp.clone(), kp.clone(), mp.clone(), t_prev, ab.clone(), np_.clone())
            got = as64("masked_step", raw, want)
            tol = tolerance(raw, 1e-6, float(want.abs().max()))
            err = float((got - want).abs().max())
            if err > tol:
                a = float(ab[t_prev])  # at t_prev = -1: the LAST ᾱ (a usual mistake)
                inverted, unnoised = (1 - mp) * kept + mp * xp, mp * kp + (1 - mp) * xp
                wrapped = mp * (a**0.5 * kp + (1 - a) ** 0.5 * np_) + (1 - mp) * xp
                hints = {
                    "1 means keep: the mask's 1s take the (noised) known latent, its 0s keep your sample": inverted,
                    "noise the known latent to t_prev before pasting it: x is noisy at t_prev, so is what you paste": unnoised,
                    "at t_prev = -1 the sample is clean: paste known itself (alphas_cumprod[-1] is ᾱ_{T-1})": wrapped,
                }
                raise ExerciseError(
                    f"your masked_step differs at t_prev={t_prev} on the {name} plane: max error {err:.3g}"
                    + matching_hint(got, hints, max(tol, 1e-5), want)
                )
            worst = max(worst, err)
    passed("masked_step", 5 * 3, worst)


__all__ = ["check_ddim_loop", "check_masked_step", "check_training_step", "image_denoiser"]

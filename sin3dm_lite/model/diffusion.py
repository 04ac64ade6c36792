"""Diffusion on the triplane latent: training, DDPM / DDIM sampling, masked sampling.

The forward process blends the latent with Gaussian noise,
``x_t = √ᾱ_t · x0 + √(1-ᾱ_t) · ε`` (T = 1000 steps, linear β: the schedule and
the steps a sampler visits are in :mod:`.schedule`), and the U-Net
learns to undo it. With a single training example Sin3DM lets the network
predict the clean latent ``x0`` itself rather than the noise ε (ε-prediction is
kept as the paper's ablation); the loss is the MSE to that target, averaged
within each plane and summed over the three planes. Because the network is
fully convolutional, sampling noise of another size gives a retargeted shape,
and pasting a noised known latent into part of ``x_t`` at every step gives
outpainting, patch duplication and local editing without touching the sampler.

Not in the paper: the latent may be scaled before the diffusion (``DiffusionConfig.latent_scale``, latent
diffusion's scale factor). The trainer and :func:`sample` scale; everything outside them sees the encoder's units.
"""

from __future__ import annotations

import copy
import dataclasses
import warnings
from collections.abc import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from ..app.device import PRECISIONS, autocast
from ..data.config import DiffusionConfig
from ..errors import Sin3DMInputError
from .schedule import NoiseSchedule, sampling_timesteps, start_step
from .training import Trainer, checkpoint_problem
from .triplane import PLANE_AXES, Triplane
from .unet import TriplaneUNet


# ------------------------------------------------------------------------ training
def unit_scale(h0: Triplane) -> float:
    """The factor that gives the latent ``h0`` unit variance (all planes' values together)."""
    return 1.0 / max(float(torch.cat([p.detach().flatten().float() for p in h0.planes]).std()), 1e-6)


def latent_scale(model) -> float:
    """The factor a denoiser's latents were scaled by for its training (``cfg.latent_scale``; 1 without one)."""
    scale = float(getattr(getattr(model, "cfg", None), "latent_scale", 1.0))
    if scale <= 0:
        raise Sin3DMInputError("this denoiser's config has latent_scale 0 (unit variance) unresolved: train it first")
    return scale


def diffusion_loss(
    model: TriplaneUNet, schedule: NoiseSchedule, x0: Triplane, t: torch.Tensor, noise: Triplane, prediction: str = "x0"
) -> torch.Tensor:
    """MSE between the network output on ``x_t`` and its target (x0 or ε): mean within a plane, sum over planes."""
    pred = model(schedule.q_sample(x0, t, noise), t)
    return triplane_mse(pred, x0 if prediction == "x0" else noise)


def triplane_mse(a: Triplane, b: Triplane) -> torch.Tensor:
    """Mean squared difference within each plane, summed over the three planes (the training loss's form)."""
    return sum(F.mse_loss(p, q) for p, q in zip(a.planes, b.planes))


class DiffusionTrainer(Trainer):
    """Trains the denoiser on one latent ``h0``, resumable bit for bit (:class:`Trainer`).

    Every step draws a batch of ``cfg.batch_size`` copies of ``h0``, each with
    its own time step and noise. AdamW, learning rate
    annealed linearly to 0 over ``cfg.steps``, and an EMA copy of the weights
    (``cfg.ema_decay = 0``: none). The checkpoint adds ``ema`` and ``h0``, so
    :meth:`from_state_dict` rebuilds the trainer from it alone.
    """

    kind = "diffusion"

    def __init__(self, h0: Triplane, cfg: DiffusionConfig, device: str | torch.device | None = None, seed: int = 0):
        if h0.batch != 1:
            raise Sin3DMInputError(f"the diffusion model trains on one latent; got a batch of {h0.batch} (use h0[0])")
        if cfg.prediction not in ("x0", "eps"):
            raise Sin3DMInputError(f"unknown prediction '{cfg.prediction}'; use 'x0' (the paper) or 'eps'")
        if cfg.precision not in PRECISIONS:
            raise Sin3DMInputError(f"unknown diffusion precision '{cfg.precision}'; use one of {', '.join(PRECISIONS)}")
        if cfg.latent_scale == 0:  # unit variance: the number found here is what the config records
            cfg = dataclasses.replace(cfg, latent_scale=unit_scale(h0))
        super().__init__(cfg, device, seed)
        self.h0 = h0.detach().to(self.device, torch.float32).clone()  # what the checkpoint keeps
        self.target = self.h0 if cfg.latent_scale == 1 else self.h0 * cfg.latent_scale  # what the denoiser learns
        self.schedule = NoiseSchedule.from_config(cfg)
        self.model = self.init_model(lambda: TriplaneUNet(h0.channels, cfg))
        self.ema = copy.deepcopy(self.model).requires_grad_(False).eval() if cfg.ema_decay > 0 else None
        # the training forward, compiled when asked (the same module and weights; sampling uses it uncompiled)
        self.train_forward = torch.compile(self.model) if cfg.compile else self.model
        self._compile_checked = False  # True once a compiled step ran (later errors are the training's own)
        self.optimizer = self.adamw(self.model.parameters(), lr=cfg.lr)
        steps = max(cfg.steps, 1)
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(self.optimizer, lambda s: max(0.0, 1.0 - s / steps))

    @property
    def model_for_sampling(self) -> TriplaneUNet:
        """The EMA weights when EMA is on, else the raw ones; in eval mode."""
        return (self.ema if self.ema is not None else self.model).eval()

    def losses(self) -> dict[str, torch.Tensor]:
        """The denoising loss on a batch of noised copies of ``h0``."""
        b, g = self.cfg.batch_size, self.generator
        x0 = self.target.repeat(b)
        t = torch.randint(0, self.schedule.timesteps, (b,), generator=g, device=self.device)
        noise = Triplane.randn_like(x0, generator=g)

        def loss() -> torch.Tensor:
            with autocast(self.device, self.cfg.precision):  # the MSE itself runs in fp32 under autocast
                return diffusion_loss(self.train_forward, self.schedule, x0, t, noise, self.cfg.prediction).float()

        if self.train_forward is self.model or self._compile_checked:
            return {"loss": loss()}
        try:  # the first compiled step: torch.compile needs a working Triton / C++ toolchain
            out = loss()
        except Exception as e:
            warnings.warn(
                f"torch.compile of the denoiser failed here ({type(e).__name__}); training it uncompiled "
                "(set diffusion.compile=false to skip the attempt)",
                stacklevel=2,
            )
            self.train_forward = self.model
            out = loss()  # the same batch, eagerly
        self._compile_checked = True
        return {"loss": out}

    def after_step(self) -> None:
        if self.ema is not None:  # one fused update over all weights (a loop of small kernels is slow on a GPU)
            with torch.no_grad():
                torch._foreach_lerp_(
                    list(self.ema.parameters()), list(self.model.parameters()), 1.0 - self.cfg.ema_decay
                )

    def extra_state(self) -> dict:
        return {"ema": self.ema.state_dict() if self.ema is not None else None, "h0": self.h0.state_dict()}

    def load_extra_state(self, sd: dict) -> None:
        if self.ema is not None:
            self.ema.load_state_dict(sd["ema"])

    @classmethod
    def from_state_dict(cls, sd: dict, device: str | torch.device | None = None) -> DiffusionTrainer:
        """Rebuild a trainer (latent, config, seed) from a ``state_dict()`` and load it."""
        why = checkpoint_problem(sd, cls.kind)
        if why is not None:
            raise Sin3DMInputError(f"not a diffusion checkpoint of this version of sin3dm-lite: {why}")
        trainer = cls(Triplane.from_state_dict(sd["h0"]), DiffusionConfig(**sd["config"]), device, sd["seed"])
        trainer.load_state_dict(sd)
        return trainer


def fit_diffusion(
    h0: Triplane, cfg: DiffusionConfig, device: str | torch.device | None = None, seed: int = 0, progress: bool = True
) -> tuple[TriplaneUNet, dict[str, list[float]]]:
    """Train a denoiser on ``h0`` for ``cfg.steps`` steps; returns (model for sampling, loss history)."""
    trainer = DiffusionTrainer(h0, cfg, device=device, seed=seed)
    trainer.run(progress=progress)
    return trainer.model_for_sampling, trainer.history


# ------------------------------------------------------------------------ sampling
def _steps_to_record(which: int | Sequence[int] | None, n_steps: int) -> set[int]:
    if which is None:
        return set()
    if isinstance(which, int):  # k evenly spaced steps, first and last included
        return {n_steps - 1} if which == 1 else set(np.round(np.linspace(0, n_steps - 1, which)).astype(int).tolist())
    return {i % n_steps for i in which}


def _blend(mask: Triplane, keep: Triplane, x: Triplane) -> Triplane:
    """``mask·keep + (1-mask)·x`` plane by plane (exactly ``keep`` where ``mask`` is 1)."""
    return Triplane(*(m * k + (1 - m) * p for m, k, p in zip(mask.planes, keep.planes, x.planes)))


@torch.no_grad()
def predict_clean(
    model, schedule: NoiseSchedule, x_t: Triplane, t: torch.Tensor, prediction: str = "x0", clip: bool = True
) -> Triplane:
    """The network's estimate of the clean latent x0 from ``x_t`` (converted from ε for an ε-model), in the
    denoiser's units; ``clip`` keeps it in [-1, 1] (times :func:`latent_scale`): the latent is a tanh output."""
    out = model(x_t, t)
    x0 = out if prediction == "x0" else schedule.predict_x0(x_t, t, out)
    bound = latent_scale(model)
    return x0.map(lambda p: p.clamp(-bound, bound)) if clip else x0


class SampleNoise:
    """Gaussian noise for a batch where sample ``i`` comes from its own generator seeded ``seeds[i]``.

    ``seed`` is an int (samples ``seed, seed+1, ...``), a list of seeds, or one
    ``torch.Generator`` shared by the whole batch. Per-sample noise is drawn on
    the CPU and moved to the device, so a sample is the same on any device and in any batch.
    """

    def __init__(self, seed: int | Sequence[int] | torch.Generator, n: int):
        if isinstance(seed, torch.Generator):
            self.shared, self.gens = seed, None
            return
        seeds = list(range(int(seed), int(seed) + n)) if isinstance(seed, (int, np.integer)) else [int(s) for s in seed]
        if len(seeds) != n:
            raise Sin3DMInputError(f"{len(seeds)} seeds for {n} samples; give one seed per sample")
        self.shared, self.gens = None, [torch.Generator().manual_seed(s) for s in seeds]

    def draw(self, like: Triplane, device) -> Triplane:
        """Noise of ``like``'s shape (which may live on the ``meta`` device) on ``device``."""
        if self.gens is None:
            return like.map(lambda p: torch.randn(p.shape, generator=self.shared, device=self.shared.device).to(device))
        return like.map(
            lambda p: torch.cat([torch.randn((1, *p.shape[1:]), generator=g) for g in self.gens]).to(device)
        )

    def like(self, tp: Triplane) -> Triplane:
        return self.draw(tp, tp.device).to(dtype=tp.xy.dtype)


def sample(
    model: TriplaneUNet,
    schedule: NoiseSchedule | None,
    resolution: tuple[int, int, int],
    n: int = 1,
    latent_channels: int | None = None,
    method: str = "ddim",
    steps: int = 50,
    seed: int | Sequence[int] | torch.Generator = 0,
    clip: bool = True,
    known: Triplane | None = None,
    mask: Triplane | None = None,
    return_intermediates: int | Sequence[int] | None = None,
    progress: bool = True,
    device: str | torch.device | None = None,
    prediction: str | None = None,
    start: Triplane | None = None,
    diversity: float = 1.0,
    denoised_fn: Callable[[Triplane, int], Triplane] | None = None,
) -> Triplane | tuple[Triplane, list[dict]]:
    """Draw ``n`` latents of spatial size ``resolution = (X, Y, Z)`` from noise.

    ``method="ddpm"`` walks all T steps with the posterior mean and variance; ``"ddim"`` (η = 0, deterministic
    given the start noise) jumps through ``steps`` respaced time steps. The predicted x0 is clipped to [-1, 1] (the
    latent is a tanh output). Any ``resolution`` works (retargeting).

    Masked generation: with ``known`` (a latent of the same size) and ``mask`` (values in [0, 1], 1 = keep
    ``known``; batch and channels broadcast), after every step ``x_{t-1} ← m·q_sample(known, t-1) + (1-m)·x_{t-1}``
    and at the end ``x0 ← m·known + (1-m)·x0``. See :func:`soft_mask`.

    The diversity ↔ fidelity knob (SDEdit-style): with ``start`` (a latent of this size, usually the input's) and
    ``diversity < 1`` the walk begins at step ``t0 = diversity · (T-1)`` (:func:`start_step`) from
    ``q_sample(start, t0)``, the start latent noised to that step, instead of from pure noise at T-1. Low values
    keep the input's layout and regenerate only fine detail, 1 is the paper's unconditional sampling; 0 returns
    ``start`` itself.

    ``denoised_fn(x0, t)`` (improved-diffusion's hook, not in the paper) may change each step's estimate of the
    clean latent before the step uses it (and before it is recorded).

    Seeds (:class:`SampleNoise`): sample ``i`` draws all its noise from its own generator seeded ``seed + i`` (or
    ``seed[i]``), so ``sample(n=4, seed=0)[2]`` equals ``sample(n=1, seed=2)`` on any device, up to float rounding.

    ``return_intermediates``: an int k (k evenly spaced steps, first and last included) or step indices; then
    returns ``(latents, [{"step", "t", "x_t", "x0"}, ...])`` with CPU tensors, ``x_t`` the input of that step and
    ``x0`` its (clipped) prediction. ``schedule=None`` and ``prediction=None`` take the model's config;
    ``device=None`` the model's device. Latents go in and out in the encoder's units (:func:`latent_scale`).
    """
    device = torch.device(device) if device is not None else next(model.parameters()).device
    schedule = schedule or NoiseSchedule.from_config(model.cfg)
    prediction = prediction or getattr(getattr(model, "cfg", None), "prediction", "x0")
    channels, noise = latent_channels or model.latent_channels, SampleNoise(seed, n)
    t0 = start_step(schedule, diversity)
    if t0 < schedule.timesteps - 1 and start is None:
        raise Sin3DMInputError("diversity below 1 starts from a noised latent: pass `start` (e.g. the input's latent)")
    if t0 < 0:  # diversity 0: nothing is regenerated
        return (_batch_of(start, n, device), []) if return_intermediates is not None else _batch_of(start, n, device)
    ts = sampling_timesteps(schedule, method, steps, t0)
    record, intermediates = _steps_to_record(return_intermediates, len(ts)), []
    known, mask = _known_and_mask(known, mask, device)
    scale, start, known, denoised_fn = _in_denoiser_units(model, start, known, denoised_fn)
    x = _first_latent(schedule, noise, n, channels, resolution, device, t0, start)
    if known is not None:
        x = _blend(mask, schedule.q_sample(known, ts[0], noise.like(x)), x)
    for i, t in enumerate(tqdm(ts, disable=not progress, desc=method)):
        tt = torch.full((n,), t, dtype=torch.long, device=device)
        x0 = predict_clean(model, schedule, x, tt, prediction, clip)
        if denoised_fn is not None:
            x0 = denoised_fn(x0, t)
        if i in record:
            intermediates.append(_recorded(i, t, x, x0, scale))
        t_prev = ts[i + 1] if i + 1 < len(ts) else -1
        x = _step(schedule, method, x, x0, tt, t, t_prev, noise)
        if known is not None:
            keep = schedule.q_sample(known, t_prev, noise.like(x)) if t_prev >= 0 else known
            x = _blend(mask, keep, x)
    x = _unscaled(x, scale)
    return (x, intermediates) if return_intermediates is not None else x


def _recorded(step: int, t: int, x: Triplane, x0: Triplane, scale: float) -> dict:
    """One intermediate of :func:`sample`: the step's input and its estimate of x0, on the CPU, in the encoder's units."""
    return {"step": step, "t": t, "x_t": _unscaled(x, scale).cpu(), "x0": _unscaled(x0, scale).cpu()}


def _unscaled(x: Triplane, scale: float) -> Triplane:
    """A latent in the denoiser's units back in the encoder's."""
    return x if scale == 1 else x.map(lambda p: p / scale)


def _in_denoiser_units(model, start: Triplane | None, known: Triplane | None, denoised_fn):
    """The scale of ``model``'s latent (:func:`latent_scale`), and the start and known latents and ``denoised_fn``
    (which takes and gives the encoder's units) for a walk in the denoiser's units."""
    scale = latent_scale(model)
    if scale == 1:
        return scale, start, known, denoised_fn
    start, known = (None if z is None else z * scale for z in (start, known))
    return scale, start, known, denoised_fn and (lambda x0, t: denoised_fn(_unscaled(x0, scale), t) * scale)


def _batch_of(start: Triplane, n: int, device) -> Triplane:
    """``start`` as float32 on ``device``, one copy per sample if it holds a single latent."""
    x = start.to(device, torch.float32)
    return x.repeat(n) if x.batch == 1 else x


def _known_and_mask(known: Triplane | None, mask: Triplane | None, device):
    """Masked sampling's inputs on ``device`` (both or neither)."""
    if (known is None) != (mask is None):
        raise Sin3DMInputError("masked sampling needs both `known` and `mask`")
    if known is not None:
        known, mask = known.to(device, torch.float32), mask.to(device, torch.float32)
    return known, mask


def _first_latent(
    schedule: NoiseSchedule,
    noise: SampleNoise,
    n: int,
    channels: int,
    resolution,
    device,
    t0: int,
    start: Triplane | None,
) -> Triplane:
    """Where the walk starts: x_T from the samples' own noise, or, below full diversity, the start latent noised to t0."""
    # x_T; the shape from an empty meta tensor (a meta randn would import torch._dynamo, seconds per process)
    x = noise.draw(Triplane.empty(n, channels, tuple(resolution), device="meta"), device)
    if t0 < schedule.timesteps - 1:  # x_t0 = the start latent noised to t0
        if start.resolution != tuple(resolution):
            raise Sin3DMInputError(f"start latent is {start.resolution}, the samples are {tuple(resolution)}")
        x = schedule.q_sample(_batch_of(start, n, device), t0, x)
    return x


def _step(
    schedule: NoiseSchedule,
    method: str,
    x: Triplane,
    x0: Triplane,
    tt: torch.Tensor,
    t: int,
    t_prev: int,
    noise: SampleNoise,
) -> Triplane:
    """One reverse step from x_t to x_{t_prev}, given the predicted x0: DDPM's posterior draw or DDIM's (η = 0) jump."""
    if method == "ddpm":
        mean, var = schedule.posterior(x0, x, tt)
        return mean + noise.like(x) * var.sqrt() if t > 0 else mean
    return schedule.ddim_step(x0, x, tt, t_prev)  # DDIM, η = 0: keep the predicted noise direction, move to ᾱ_{t_prev}


def soft_mask(
    shape_or_resolution: Triplane | tuple[int, int, int],
    box: tuple[Sequence[float], Sequence[float]],
    border: float = 0.1,
    invert: bool = False,
    device: str | torch.device | None = None,
) -> Triplane:
    """A mask Triplane (planes ``[1, 1, ., .]``) that is 1 inside a 3D box and fades linearly to 0 outside it.

    ``box = ((x0, y0, z0), (x1, y1, z1))`` in box coordinates [-1, 1]; each
    plane gets the box's projection (xy: its x and y ranges). ``border`` is the
    width of the linear ramp outside the box (0: a hard edge). ``invert=True``
    returns ``1 - mask`` (keep everything but the box, e.g. to regenerate it).
    """
    if isinstance(shape_or_resolution, Triplane):
        res, device = shape_or_resolution.resolution, device or shape_or_resolution.device
    else:
        res = tuple(shape_or_resolution)
    lo, hi = box

    def profile(axis: int) -> torch.Tensor:  # [n]: 1 inside [lo, hi], linear ramp of width `border` outside
        n = res[axis]
        u = -1 + (2 * torch.arange(n, dtype=torch.float32) + 1) / n  # texel centres
        d = torch.clamp(torch.maximum(lo[axis] - u, u - hi[axis]), min=0)
        return (d == 0).float() if border <= 0 else torch.clamp(1 - d / border, 0, 1)

    prof = [profile(a) for a in range(3)]
    planes = [(prof[a][:, None] * prof[b][None, :])[None, None] for a, b in PLANE_AXES.values()]
    return Triplane(*((1 - p) if invert else p for p in planes)).to(device or "cpu")


__all__ = [
    "DiffusionTrainer",
    "diffusion_loss",
    "fit_diffusion",
    "sample",
    "SampleNoise",
    "soft_mask",
]

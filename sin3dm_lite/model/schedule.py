"""The noise schedule of the diffusion model and the time steps a sampler visits.

The forward process blends the latent with Gaussian noise,
``x_t = √ᾱ_t · x0 + √(1-ᾱ_t) · ε`` (T = 1000 steps, linear β).
:class:`NoiseSchedule` holds the tables and the closed forms of one forward
jump and one reverse step (DDPM's posterior, DDIM's η = 0 step);
:func:`sampling_timesteps` lists the steps DDPM or DDIM visit, and
:func:`start_step` turns the diversity knob into the step a sample starts
from. Training and the samplers themselves are in :mod:`.diffusion`.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from ..data.config import DiffusionConfig
from ..errors import Sin3DMInputError
from .triplane import Triplane


class NoiseSchedule:
    """Linear β schedule and the closed forms of the DDPM forward / reverse steps (tables in float64)."""

    def __init__(self, timesteps: int = 1000, beta_start: float = 1e-4, beta_end: float = 0.02):
        self.timesteps = timesteps
        self.betas = torch.linspace(beta_start, beta_end, timesteps, dtype=torch.float64)
        self.alphas = 1.0 - self.betas
        self.alphas_cumprod = torch.cumprod(self.alphas, 0)  # ᾱ_t, falls from ≈1 to ≈4e-5
        self.alphas_cumprod_prev = F.pad(self.alphas_cumprod[:-1], (1, 0), value=1.0)  # ᾱ_{t-1}, ᾱ_{-1} = 1
        # q(x_{t-1} | x_t, x0) = N(c0·x0 + ct·x_t, σ²_t)
        self.posterior_variance = self.betas * (1 - self.alphas_cumprod_prev) / (1 - self.alphas_cumprod)
        self.posterior_coef_x0 = self.betas * self.alphas_cumprod_prev.sqrt() / (1 - self.alphas_cumprod)
        self.posterior_coef_xt = (1 - self.alphas_cumprod_prev) * self.alphas.sqrt() / (1 - self.alphas_cumprod)

    @classmethod
    def from_config(cls, cfg: DiffusionConfig) -> NoiseSchedule:
        return cls(cfg.timesteps, cfg.beta_start, cfg.beta_end)

    def alpha_bar(self, t: torch.Tensor | int) -> torch.Tensor:
        """ᾱ_t (float64, same shape as ``t``); ``t = -1`` means "clean" (ᾱ = 1)."""
        t = torch.as_tensor(t, device="cpu")
        return torch.where(t >= 0, self.alphas_cumprod[t.clamp(min=0)], torch.ones((), dtype=torch.float64))

    @staticmethod
    def _at(values: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
        """Per-sample ``values [B]`` (or a scalar) as ``[B, 1, 1, 1]``, in ``like``'s dtype and on its device."""
        return values.reshape(-1, 1, 1, 1).to(like.device, like.dtype)

    def _scales(self, t: torch.Tensor | int, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``√ᾱ_t`` and ``√(1-ᾱ_t)``, each ``[B, 1, 1, 1]``."""
        ab = self.alpha_bar(t)
        return self._at(ab.sqrt(), like), self._at((1 - ab).sqrt(), like)

    def q_sample(self, x0: Triplane, t: torch.Tensor | int, noise: Triplane) -> Triplane:
        """Noise ``x0`` to step ``t`` in one go: ``√ᾱ_t·x0 + √(1-ᾱ_t)·noise`` (``t`` per sample or one int)."""
        a, s = self._scales(t, x0.xy)
        return x0.zip_map(noise, lambda p, n: a * p + s * n)

    def predict_x0(self, x_t: Triplane, t: torch.Tensor, eps: Triplane) -> Triplane:
        """Invert ``q_sample`` for x0 given the noise (used with ε-prediction)."""
        a, s = self._scales(t, x_t.xy)
        return x_t.zip_map(eps, lambda p, e: (p - s * e) / a)

    def predict_eps(self, x_t: Triplane, t: torch.Tensor, x0: Triplane) -> Triplane:
        """Invert ``q_sample`` for the noise given x0 (used by DDIM)."""
        a, s = self._scales(t, x_t.xy)
        return x_t.zip_map(x0, lambda p, x: (p - a * x) / s)

    def ddim_step(self, x0: Triplane, x_t: Triplane, t: torch.Tensor, t_prev: int) -> Triplane:
        """One DDIM step (η = 0), ``x_t`` → ``√ᾱ_prev·x0 + √(1-ᾱ_prev)·ε̂`` (``t_prev = -1``: the clean end)."""
        eps, ab_prev = self.predict_eps(x_t, t, x0), float(self.alpha_bar(t_prev))
        return x0.zip_map(eps, lambda a, e: math.sqrt(ab_prev) * a + math.sqrt(1 - ab_prev) * e)

    def posterior(self, x0: Triplane, x_t: Triplane, t: torch.Tensor) -> tuple[Triplane, torch.Tensor]:
        """Mean (a Triplane) and variance ``[B,1,1,1]`` of q(x_{t-1} | x_t, x0): one DDPM reverse step."""
        t = torch.as_tensor(t, device="cpu")
        tables = (self.posterior_coef_x0, self.posterior_coef_xt, self.posterior_variance)
        c0, ct, var = (self._at(v[t], x_t.xy) for v in tables)
        return x0.zip_map(x_t, lambda a, b: c0 * a + ct * b), var


# ------------------------------------------------------------------------ the steps a sampler visits
def ddim_timesteps(timesteps: int, steps: int) -> list[int]:
    """``steps`` time steps from T-1 down to 0, evenly spaced (one step: just T-1)."""
    if not 1 <= steps <= timesteps:
        raise Sin3DMInputError(f"DDIM needs between 1 and {timesteps} steps, got {steps}")
    return [int(t) for t in np.round(np.linspace(timesteps - 1, 0, steps))] if steps > 1 else [timesteps - 1]


def start_step(schedule: NoiseSchedule, diversity: float) -> int:
    """The time step a sample starts from for a diversity in [0, 1]: ``round(diversity · (T-1))``, -1 for 0.

    The knob is the share of the reverse process that runs. 1 starts at T-1
    from pure noise (the paper); 0 runs nothing and returns the input. With
    the linear β schedule the noise share ``1 - ᾱ_t0`` rises fast: 0.1 → 0.10,
    0.3 → 0.61, 0.5 → 0.92, 0.7 → 0.99, so most of the variation comes from
    settings above ~0.3, where the input's large shapes are drowned.
    """
    if isinstance(diversity, bool) or not (isinstance(diversity, (int, float)) and 0.0 <= float(diversity) <= 1.0):
        raise Sin3DMInputError(f"diversity must be a number from 0 (the input) to 1 (pure noise), got {diversity!r}")
    if diversity <= 0.0:
        return -1
    return max(0, int(round(float(diversity) * (schedule.timesteps - 1))))


def sampling_timesteps(schedule: NoiseSchedule, method: str, steps: int, t_start: int | None = None) -> list[int]:
    """The time steps a sampler visits, from ``t_start`` (default T-1) down to 0.

    DDPM visits every step; DDIM ``steps`` evenly spaced ones over the full
    range, fewer when it starts lower (the same spacing, at least one step).
    """
    top = schedule.timesteps - 1 if t_start is None else t_start
    if method == "ddpm":
        return list(range(top, -1, -1))
    if method != "ddim":
        raise Sin3DMInputError(f"unknown sampling method '{method}'; use 'ddim' or 'ddpm'")
    ts = ddim_timesteps(schedule.timesteps, steps)
    if top == schedule.timesteps - 1:
        return ts
    k = max(1, int(round(steps * (top + 1) / schedule.timesteps)))
    return [int(t) for t in np.round(np.linspace(top, 0, k))] if k > 1 else [top]


__all__ = ["NoiseSchedule", "ddim_timesteps", "sampling_timesteps", "start_step"]

"""Exercise (notebook 05): one deterministic DDIM step (η = 0)."""

import math


def ddim_step(x_t, x0, t, t_prev: int, alphas_cumprod):
    """From ``x_t`` to ``x_{t_prev}``: keep the noise that ``x_t`` and ``x0`` imply, move to ᾱ_{t_prev}."""
    ab = alphas_cumprod[t].reshape(-1, 1, 1, 1).to(x_t.dtype)
    eps = (x_t - ab.sqrt() * x0) / (1 - ab).sqrt()  # the noise x_t holds if x0 is right
    ab_prev = float(alphas_cumprod[t_prev]) if t_prev >= 0 else 1.0  # t_prev = -1: the clean end
    return math.sqrt(ab_prev) * x0 + math.sqrt(1 - ab_prev) * eps

"""Exercise (notebook 05): one DDPM reverse step, the posterior q(x_{t-1} | x_t, x0)."""

import torch


def posterior(x0, x_t, t, betas, alphas_cumprod):
    """Mean and variance of q(x_{t-1} | x_t, x0); ᾱ_{t-1} is 1 at t = 0 (there is no earlier step)."""
    ab = alphas_cumprod[t]
    ab_prev = torch.where(t > 0, alphas_cumprod[(t - 1).clamp(min=0)], torch.ones_like(ab))
    beta = betas[t]
    coef_x0 = beta * ab_prev.sqrt() / (1 - ab)
    coef_xt = (1 - ab_prev) * (1 - beta).sqrt() / (1 - ab)
    var = beta * (1 - ab_prev) / (1 - ab)
    at = lambda v: v.reshape(-1, 1, 1, 1).to(x0.dtype)  # noqa: E731  one value per sample
    return at(coef_x0) * x0 + at(coef_xt) * x_t, at(var)

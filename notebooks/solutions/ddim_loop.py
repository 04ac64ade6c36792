"""Exercise (notebook 00b): the DDIM sampling loop (η = 0), from pure noise to an image."""

import torch


@torch.no_grad()
def ddim_sample(denoise, x_T, timesteps, alphas_cumprod):
    """Walk ``timesteps`` (falling) from the noise ``x_T``: predict x̂0, clip it, one DDIM step to the next t."""
    x = x_T
    for i, t in enumerate(timesteps):
        tt = torch.full((x.shape[0],), t)
        x0 = denoise(x, tt).clamp(-1, 1)  # the prediction, in the image's range
        ab = float(alphas_cumprod[t])
        ab_prev = float(alphas_cumprod[timesteps[i + 1]]) if i + 1 < len(timesteps) else 1.0  # the end: ᾱ = 1
        eps = (x - ab**0.5 * x0) / (1 - ab) ** 0.5  # the noise x holds if x0 is right
        x = ab_prev**0.5 * x0 + (1 - ab_prev) ** 0.5 * eps  # the DDIM step (notebook 05)
    return x

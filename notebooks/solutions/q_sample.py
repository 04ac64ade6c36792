"""Exercise (notebook 00b): the forward process q(x_t | x_0) in one go."""

import torch


def q_sample(x0: torch.Tensor, t: torch.Tensor, noise: torch.Tensor, alphas_cumprod: torch.Tensor) -> torch.Tensor:
    """``x_t = √ᾱ_t · x0 + √(1-ᾱ_t) · noise`` for a batch ``x0 [B, C, H, W]`` with one step ``t[b]`` per sample."""
    ab = alphas_cumprod[t].reshape(-1, 1, 1, 1).to(x0.dtype)  # ᾱ_t, one per sample, [B, 1, 1, 1]
    return ab.sqrt() * x0 + (1 - ab).sqrt() * noise

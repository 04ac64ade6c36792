"""Exercise (notebook 00b): one training step of the denoiser on a batch of copies of the image."""

import torch
import torch.nn.functional as F


def training_step(denoise, optimizer, x0, alphas_cumprod, generator) -> float:
    """Noise ``x0 [B, 3, H, W]`` to random steps, predict the clean image, one optimizer step; returns the loss."""
    t = torch.randint(0, len(alphas_cumprod), (x0.shape[0],), generator=generator)  # one step per image
    noise = torch.randn(x0.shape, generator=generator)
    ab = alphas_cumprod[t].reshape(-1, 1, 1, 1).to(x0.dtype)
    x_t = ab.sqrt() * x0 + (1 - ab).sqrt() * noise  # q_sample (exercise 1)
    loss = F.mse_loss(denoise(x_t, t), x0)  # x0-prediction: the target is the clean image
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    return loss.item()

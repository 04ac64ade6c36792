"""The method in 2D, for a first lesson: a diffusion model learned from ONE image (notebook 00b).

A denoiser trained on a single example learns what its receptive field lets it see: if one output pixel
sees the whole image, every sample is a copy; if it sees a small window, it learns what *patches* look
like, not where they go, and samples recombine them. Nothing here is a second implementation: an image
``[3, H, W]`` is the ``xy`` plane of a flat triplane (``Z = 1``, ``xz``/``yz`` one texel of zeros), and
without the cross-plane rollout (``DiffusionConfig.rollout=False``) the package's ``TriplaneUNet``, schedule,
trainer and DDIM sampler run on it as a plain 2D diffusion model.
"""

from __future__ import annotations

from dataclasses import replace

import matplotlib.pyplot as plt
import numpy as np
import torch
from matplotlib.figure import Figure

from ..data.config import DiffusionConfig
from ..model.diffusion import fit_diffusion, sample
from ..model.schedule import NoiseSchedule
from ..model.triplane import Triplane
from ..model.unet import TriplaneUNet
from .receptive_field import analytic_receptive_field

#: the two denoisers of the lesson (training length and width are set by :func:`lesson_config`)
FIELDS = {
    "small": dict(n_resblocks=2, downsample=False),  # 2 full-resolution ResBlocks: 9 pixels
    "large": dict(n_resblocks=4, downsample=True),  # the paper's one-level U-Net: 28 pixels
}


# ----------------------------------------------------------------------------- the image
def pebbles(size: int = 24, n: int = 10, seed: int = 0) -> np.ndarray:
    """A procedural texture ``(size, size, 3)`` in [0, 1]: round pebbles of four colours on sand.

    The pebbles do not overlap: a clear local vocabulary (a pebble, its rim, sand) and a layout that a copy
    reproduces and a recombination does not.
    """
    rng = np.random.default_rng(seed)
    img = np.zeros((size, size, 3)) + np.array([0.86, 0.79, 0.62])
    img += rng.normal(0, 0.02, img.shape)  # grainy sand
    colours = np.array([[0.80, 0.22, 0.20], [0.20, 0.45, 0.80], [0.22, 0.60, 0.30], [0.92, 0.70, 0.12]])
    yy, xx = np.mgrid[0:size, 0:size] + 0.5
    placed: list[tuple[float, float, float]] = []
    for _ in range(200 * n):
        if len(placed) == n:
            break
        r = rng.uniform(1.8, 2.8)
        cy, cx = rng.uniform(r, size - r, 2)
        if all((cy - y) ** 2 + (cx - x) ** 2 > (r + q + 1.0) ** 2 for y, x, q in placed):
            placed.append((cy, cx, r))
    for k, (cy, cx, r) in enumerate(placed):
        d = np.sqrt((yy - cy) ** 2 + (xx - cx) ** 2)
        img[d < r + 0.6] *= 0.55  # a dark rim
        img[d < r] = colours[k % 4] * (1.0 - 0.25 * (d[d < r] / r) ** 2)[:, None]  # shaded towards the rim
    return np.clip(img, 0, 1).astype(np.float32)


def image_to_triplane(image: np.ndarray) -> Triplane:
    """``(H, W, 3)`` in [0, 1] → a flat Triplane: ``xy [1, 3, H, W]`` in [-1, 1], ``xz``/``yz`` one texel of zeros."""
    x = torch.as_tensor(np.asarray(image, np.float32)).permute(2, 0, 1)[None] * 2 - 1  # [1, 3, H, W]
    h, w = x.shape[-2:]
    return Triplane(x, torch.zeros(1, 3, h, 1), torch.zeros(1, 3, w, 1))


def triplane_to_images(tp: Triplane) -> np.ndarray:
    """The ``xy`` planes of a batch back to images ``(B, H, W, 3)`` in [0, 1] (clipped: noisy ones overshoot)."""
    return ((tp.xy.detach().cpu().permute(0, 2, 3, 1).numpy() + 1) / 2).clip(0, 1)


# ----------------------------------------------------------------------------- forward process
def noised(image: np.ndarray, schedule: NoiseSchedule, ts, seed: int = 0) -> np.ndarray:
    """The image at each step of ``ts`` of the forward process, ``√ᾱ_t·x0 + √(1-ᾱ_t)·ε``: ``(len(ts), H, W, 3)``.

    One noise image ``ε`` (from ``seed``) for all steps; ``t = -1`` is the clean image.
    """
    x0 = image_to_triplane(image)
    eps = Triplane.randn_like(x0, generator=torch.Generator().manual_seed(seed))
    return np.concatenate([triplane_to_images(schedule.q_sample(x0, int(t), eps)) for t in ts])


def signal_to_noise(schedule: NoiseSchedule, t: int) -> tuple[float, float]:
    """``(√ᾱ_t, √(1-ᾱ_t))``: how much of the image and how much noise ``x_t`` holds."""
    ab = float(schedule.alpha_bar(int(t)))
    return ab**0.5, (1 - ab) ** 0.5


# ----------------------------------------------------------------------------- the two denoisers
def lesson_config(field: str, steps: int, channels: int = 32) -> DiffusionConfig:
    """The denoiser for ``field`` ("small" or "large", :data:`FIELDS`): no rollout, raw weights, a short run."""
    return replace(
        DiffusionConfig(
            base_channels=channels, time_embed_dim=32, rollout=False, steps=steps, batch_size=8, lr=2e-3, ema_decay=0.0
        ),
        **FIELDS[field],
    )


def receptive_field_width(cfg: DiffusionConfig) -> int:
    """Pixels one output pixel sees, from the layers (:func:`~sin3dm_lite.receptive_field.analytic_receptive_field`)."""
    return analytic_receptive_field(TriplaneUNet(3, cfg))


def fit_image(image: np.ndarray, cfg: DiffusionConfig, seed: int = 0):
    """Train the package's denoiser on one image; returns ``(model, loss history)`` (the trainer's own loop)."""
    return fit_diffusion(image_to_triplane(image), cfg, device="cpu", seed=seed, progress=False)


def sample_images(model, size: tuple[int, int], n: int = 4, steps: int = 25, seed: int = 0) -> np.ndarray:
    """``n`` new images ``(n, H, W, 3)`` from pure noise with the package's DDIM sampler (any size: retargeting)."""
    h, w = size
    return triplane_to_images(sample(model, None, (h, w, 1), n=n, steps=steps, seed=seed, progress=False))


# ----------------------------------------------------------------------------- copy or recombine?
def _patches(images: np.ndarray, patch: int) -> torch.Tensor:
    """All ``patch × patch`` windows of ``(B, H, W, 3)`` images → ``[B, L, 3·patch²]``."""
    x = torch.as_tensor(np.asarray(images, np.float64)).permute(0, 3, 1, 2)  # float64: exact zeros for equal windows
    return torch.nn.functional.unfold(x, patch).transpose(1, 2)


def nearest_patch_distance(samples: np.ndarray, image: np.ndarray, patch: int) -> np.ndarray:
    """For each sample, the mean over its ``patch × patch`` windows of the RMS colour difference to the
    closest window anywhere in ``image``: ``(B,)``. Near 0: every window of the sample is in the input.

    Small windows measure "looks like the input locally"; windows as large as the image "is a copy".
    """
    ref = _patches(np.asarray(image)[None], patch)[0]  # [L, D]
    gen = _patches(samples, patch)  # [B, L', D]
    d = torch.cdist(gen, ref[None].expand(len(gen), -1, -1))  # [B, L', L]
    return (d.min(-1).values / ref.shape[1] ** 0.5).mean(-1).numpy()


def patch_distance_curve(samples: np.ndarray, image: np.ndarray, patches) -> np.ndarray:
    """:func:`nearest_patch_distance` averaged over samples, for each window size: ``(len(patches),)``."""
    return np.array([nearest_patch_distance(samples, image, p).mean() for p in patches])


# ----------------------------------------------------------------------------- pictures
def _figure(width: float, height: float) -> Figure:
    fig = plt.figure(figsize=(width, height), layout="constrained")
    plt.close(fig)  # shown once, as the cell's value
    return fig


def plot_images(images, titles=None, rows: list[str] | None = None, width: float = 1.6) -> Figure:
    """A grid of images: ``images`` is a list of ``(N, H, W, 3)`` rows (or one row); ``rows`` labels them."""
    grid = [list(r) for r in (images if isinstance(images, (list, tuple)) else [images])]
    cols = max(len(r) for r in grid)
    fig = _figure(width * cols, width * len(grid) + 0.3)
    axes = fig.subplots(len(grid), cols, squeeze=False)
    for i, row in enumerate(grid):
        for j in range(cols):
            ax = axes[i, j]
            ax.set_axis_off()
            if j < len(row):
                ax.imshow(row[j], interpolation="nearest")
                if titles is not None and i == 0 and j < len(titles):
                    ax.set_title(titles[j], fontsize=8)
        if rows:
            axes[i, 0].text(-0.08, 0.5, rows[i], transform=axes[i, 0].transAxes, ha="right", va="center", fontsize=9)
    return fig


def plot_noised(image: np.ndarray, schedule: NoiseSchedule, t: int, seed: int = 0) -> Figure:
    """One step of the forward process (the slider's picture): ``x_t`` next to its share of signal and noise."""
    signal, noise = signal_to_noise(schedule, t)
    fig = _figure(6.0, 2.8)
    left, right = fig.subplots(1, 2, width_ratios=[1, 1.3])
    left.imshow(noised(image, schedule, [t], seed)[0], interpolation="nearest")
    left.set_axis_off()
    left.set_title(f"x_t at t = {t}", fontsize=9)
    right.bar(["√ᾱ_t (image)", "√(1-ᾱ_t) (noise)"], [signal, noise], color=["C2", "C1"])
    right.set_ylim(0, 1.05)
    right.set_title(f"ᾱ_t = {signal**2:.3f}", fontsize=9)
    return fig


def plot_patch_curve(patches, curves: dict[str, np.ndarray], fields: dict[str, int] | None = None) -> Figure:
    """Nearest-patch distance against window size, one line per denoiser (dotted: its receptive field)."""
    fig = _figure(5.5, 3.2)
    ax = fig.subplots()
    for i, (name, values) in enumerate(curves.items()):
        ax.plot(patches, values, "o-", color=f"C{i}", label=name)
        if fields and name in fields:
            ax.axvline(fields[name], color=f"C{i}", ls=":", lw=1)
    ax.set_xlabel("window size (pixels)")
    ax.set_ylabel("distance to the nearest input window")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


__all__ = [
    "FIELDS",
    "fit_image",
    "image_to_triplane",
    "lesson_config",
    "nearest_patch_distance",
    "noised",
    "patch_distance_curve",
    "pebbles",
    "plot_images",
    "plot_noised",
    "plot_patch_curve",
    "receptive_field_width",
    "sample_images",
    "signal_to_noise",
    "triplane_to_images",
]

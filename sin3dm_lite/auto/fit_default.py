"""The preset a fit takes when none is named: the one this machine runs well, said first with why and how long.

* a CUDA GPU: ``paper`` (the paper's settings; its denoiser in bf16 and compiled);
* a CPU where bf16 measures faster than fp32 (:func:`~sin3dm_lite.app.device.bf16_is_fast`): ``small``, whose
  paper-width autoencoder then runs in bf16;
* any other CPU: ``quick``, a light autoencoder in fp32 (``small``'s takes about 4x as long there).

A preset named by the user always wins. The time is an estimate from a few training steps of the chosen preset
timed here, on a synthetic shape at its grid (:func:`estimate_fit`), so it follows this machine, its threads
and whatever else runs on it now; the grid and the calibration add a share of the training
(:data:`OTHER_SHARE`, docs/presets.md). A shape of thin parts may switch settings, which can change the time.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from ..app.device import bf16_is_fast, cpu_bf16_share, get_device
from ..data.config import Config
from ..presets import get_preset

#: the grid and the calibration beside the two trainings: in the fits of docs/performance.md they took 5-20 % of
#: the training's time
OTHER_SHARE = 0.15
#: training steps timed per network (after one untimed step)
TIMED_STEPS = 3


@dataclass
class DefaultPreset:
    """What :func:`choose_preset` picked for this machine and why, and the fit's estimated seconds per stage."""

    name: str
    why: str
    seconds: dict | None = None  # {"autoencoder", "denoiser", "other", "total"}

    def lines(self) -> list[str]:
        """What ``fit`` says first: the preset and why, then how long."""
        said = [
            f"[fit] no preset named: '{self.name}' for this machine ({self.why}); name one to choose another "
            "(CLI --preset NAME)"
        ]
        if self.seconds:
            s = {k: v / 60 for k, v in self.seconds.items()}
            said.append(
                f"[fit] it should take about {s['total']:.0f} min here (autoencoder {s['autoencoder']:.1f} + "
                f"denoiser {s['denoiser']:.1f} + grid and calibration {s['other']:.1f} min, from "
                f"{TIMED_STEPS} steps of each timed just now)"
            )
        return said


def choose_preset(device=None) -> tuple[str, str]:
    """``(preset name, why in words)`` for ``device`` (default: CUDA if present, else the CPU)."""
    dev = get_device(device)
    if dev.type == "cuda":
        return "paper", f"a CUDA GPU, {torch.cuda.get_device_name(dev)}: the paper's settings"
    share = cpu_bf16_share()
    if bf16_is_fast(dev):
        return "small", f"a CPU whose bf16 runs in {share:.1f}x fp32's time: small's paper-width autoencoder in bf16"
    why = "no native bf16" if share is None else f"native bf16, but at {share:.1f}x fp32's time here"
    return "quick", f"a CPU without fast bf16 ({why}): quick's light autoencoder in fp32"


def default_preset(device=None, timed: bool = True) -> DefaultPreset:
    """The preset a fit without one takes on ``device``, and (``timed``) its estimated time (:func:`estimate_fit`)."""
    name, why = choose_preset(device)
    return DefaultPreset(name, why, estimate_fit(get_preset(name), device) if timed else None)


def timing_grid(resolution: int, n_points: int = 20_000):
    """A synthetic shape for timing: a ball in a box of ``resolution`` × half × half voxels (about the built-ins'
    proportions), coloured by position (a step's cost depends on the grid's size and the points, not on the shape)."""
    from ..data.grid import ShapeGrid
    from ..data.mesh import Normalization

    dims = np.array([resolution, max(8, resolution // 2), max(8, resolution // 2)])
    half = dims / dims.max()
    aabb = np.concatenate([-half, half]).astype(np.float32)
    thr = 6.0 / dims.max()
    g = ShapeGrid(
        np.zeros(tuple(dims), np.float32), np.zeros((*dims, 3), np.float32), aabb, thr, Normalization.identity()
    )
    c = g.voxel_centers()
    radius = 0.5 * half.min()
    g.sdf = np.clip(np.linalg.norm(c, axis=-1) - radius, -thr, thr).astype(np.float32)
    g.color = np.where((np.abs(g.sdf) < thr)[..., None], (c + 1) / 2, 0).astype(np.float32)
    p = np.random.default_rng(0).normal(size=(n_points, 3))
    g.points = (p / np.linalg.norm(p, axis=1, keepdims=True) * radius).astype(np.float32)
    g.point_sdf = np.zeros(n_points, np.float32)
    g.point_color = ((g.points + 1) / 2).astype(np.float32)
    return g


def _seconds_per_step(trainer) -> float:
    """The fastest of :data:`TIMED_STEPS` steps of ``trainer`` after two untimed ones (the first ones allocate)."""
    trainer.step()
    trainer.step()
    times = []
    for _ in range(TIMED_STEPS):
        t0 = time.perf_counter()
        trainer.step()
        times.append(time.perf_counter() - t0)
    return min(times)


def estimate_fit(cfg: Config, device=None) -> dict:
    """About how long a fit of ``cfg`` takes on ``device``: a few steps of its autoencoder and its denoiser timed on
    :func:`timing_grid` (the denoiser uncompiled: on a GPU the compiled one runs faster), times their steps, plus
    :data:`OTHER_SHARE` for the grid and the calibration. Seconds: ``autoencoder``, ``denoiser``, ``other``,
    ``total``. The random state is left as it was."""
    from ..model.autoencoder import AutoencoderTrainer
    from ..model.diffusion import DiffusionTrainer

    dev = get_device(device)
    with torch.random.fork_rng(devices=[dev] if dev.type == "cuda" else []):
        grid = timing_grid(cfg.grid.resolution)
        ae = AutoencoderTrainer(grid, cfg.updated(**{"autoencoder.pbr": False}).autoencoder, dev, 0)
        ae_s = _seconds_per_step(ae) * cfg.autoencoder.steps
        dm = DiffusionTrainer(ae.latent(), cfg.updated(**{"diffusion.compile": False}).diffusion, dev, 0)
        dn_s = _seconds_per_step(dm) * cfg.diffusion.steps
    other = OTHER_SHARE * (ae_s + dn_s)
    return {"autoencoder": ae_s, "denoiser": dn_s, "other": other, "total": ae_s + dn_s + other}


__all__ = ["OTHER_SHARE", "DefaultPreset", "choose_preset", "default_preset", "estimate_fit", "timing_grid"]

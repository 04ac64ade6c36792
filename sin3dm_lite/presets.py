"""The named presets, each a literal :class:`~sin3dm_lite.data.config.Config`: what a fit trains, nothing decided.

=========  ==========================================================================================================
``tiny``   CI and notebook tests: every stage in seconds on 2 CPU cores; rough shapes, it exercises the code paths.
``small``  a CPU with fast bf16: a 64-voxel grid, the paper-width autoencoder, a one-level denoiser with a 9-texel
           field and no cross-plane rollout, sampled from the input's latent noised to 0.7 (calibrated per shape).
``quick``  ``small`` with a light autoencoder (128-wide MLPs, 4,096 points) in fp32, for CPUs without fast bf16.
``detail`` ``small`` at 96 voxels with 4 ResBlocks (a 17-texel field) and the paper's cross-plane rollout, sampled
           from pure noise: for shapes whose parts are thin (walls, columns), which a 32-texel latent smears.
``fine``   ``detail``'s grid and denoiser with ``quick``'s light autoencoder: thin parts on a CPU without fast bf16.
``paper``  the paper's numbers (256 voxels, 25k + 25k steps) for one GPU.
=========  ==========================================================================================================

Without a named preset a fit takes :mod:`sin3dm_lite.auto.fit_default`'s choice for this machine and shape.
"""

from __future__ import annotations

import os

from .data.config import AutoencoderConfig, Config, DiffusionConfig, GridConfig, SamplingConfig
from .errors import Sin3DMInputError


def _tiny() -> Config:
    return Config(
        name="tiny",
        grid=GridConfig(resolution=32, n_surface_points=50_000, near_surface_sigma=0.01, margin_voxels=3.25),
        autoencoder=AutoencoderConfig(decoder_channels=32, mlp_hidden=64, steps=150, points_per_step=4096),
        diffusion=DiffusionConfig(
            base_channels=16, n_resblocks=2, downsample=False, steps=150, batch_size=4, lr=2e-3, ema_decay=0.0
        ),
        sampling=SamplingConfig(steps=10, mesh_resolution=48, faces=3000, texture_size=256),
        checkpoint_every=50,
    )


def _small() -> Config:
    # The paper's σ (a wider band erodes the surface); no rollout: on a 32-texel latent the plane means tell every
    # texel the global layout, and samples copy the input. The learning rate decays to √0.1 of its start, not the
    # paper's 0.1: in a run a tenth as long, the paper's decay leaves the last steps too slow to sharpen fine relief.
    return Config(
        name="small",
        grid=GridConfig(resolution=64, n_surface_points=300_000, margin_voxels=3.25),
        autoencoder=AutoencoderConfig(steps=2000, points_per_step=8192, lr_final_factor=0.316),
        diffusion=DiffusionConfig(
            base_channels=32,
            n_resblocks=2,
            downsample=False,
            rollout=False,
            steps=2000,
            batch_size=8,
            lr=1e-3,
            ema_decay=0.0,
        ),
        sampling=SamplingConfig(steps=50, mesh_resolution=128, faces=20_000, texture_size=1024, diversity=0.7),
        checkpoint_every=250,
    )


#: ``quick``'s light autoencoder in place of ``small``'s (its MLPs are most of a fit, in fp32 without fast bf16),
#: with 512² textures: its colour is blurrier anyway.
LIGHT_AUTOENCODER = {
    "autoencoder.mlp_hidden": 128,
    "autoencoder.points_per_step": 4096,
    "autoencoder.color_points": 2048,
    "autoencoder.steps": 1000,
    "sampling.texture_size": 512,
}


def _quick() -> Config:
    return _small().updated(name="quick", **{**LIGHT_AUTOENCODER, "diffusion.steps": 1000})


def _detail() -> Config:
    # A thin part has half again as many texels at 96 voxels, and 4 ResBlocks keep the field's share of the
    # latent; the cross-plane rollout makes the three planes agree on where a wall or a column stands.
    return _small().updated(
        name="detail",
        **{
            "grid.resolution": 96,
            "autoencoder.steps": 1000,
            "diffusion.n_resblocks": 4,
            "diffusion.rollout": True,
            "diffusion.steps": 1000,
            "diffusion.precision": "auto",
            "sampling.diversity": 1.0,
        },
    )


def _fine() -> Config:
    # Without fast bf16 the 96-voxel denoiser runs in fp32: batches of 4 instead of 8 halve its time.
    return _detail().updated(name="fine", **{**LIGHT_AUTOENCODER, "diffusion.batch_size": 4})


def _paper() -> Config:
    return Config(
        name="paper",
        grid=GridConfig(resolution=256, n_surface_points=2_000_000),
        autoencoder=AutoencoderConfig(),
        diffusion=DiffusionConfig(precision="auto", compile=True),
        sampling=SamplingConfig(steps=100, mesh_resolution=256, faces=50_000, texture_size=2048),
        checkpoint_every=2500,
    )


PRESETS = {"tiny": _tiny, "small": _small, "quick": _quick, "detail": _detail, "fine": _fine, "paper": _paper}


def get_preset(name: str) -> Config:
    """Return a fresh copy of a named preset (:data:`PRESETS`)."""
    if name not in PRESETS:
        raise Sin3DMInputError(f"unknown preset '{name}'; choose one of: {', '.join(PRESETS)}")
    return PRESETS[name]()


def fast_mode() -> bool:
    """True when the ``SIN3DM_FAST`` environment variable asks for tiny settings (CI, tests)."""
    return os.environ.get("SIN3DM_FAST", "0") not in ("", "0", "false", "False")


def notebook_preset() -> Config:
    """The preset a notebook uses: ``tiny`` under ``SIN3DM_FAST=1``, else ``small``."""
    return get_preset("tiny" if fast_mode() else "small")

"""The five named presets, each a :class:`~sin3dm_lite.data.config.Config`.

* ``tiny``  – for CI and notebook tests: every stage in seconds on 2 CPU cores.
  The shapes it makes are rough; it exists to exercise the code paths.
* ``small`` – for a laptop CPU: the whole fit in about 4-4.5 minutes on 2 cores,
  a 64-voxel grid and a 32-texel latent. Its U-Net has no downsampling level and
  no cross-plane rollout so that what it sees shrinks with the latent
  (docs/paper-notes.md, last section: with the paper's network on a 32-wide latent
  every sample is a copy). The fit ends by choosing the diversity knob for the
  shape (``sampling.calibrate``: the most varied setting whose samples keep the
  input's patches, :mod:`sin3dm_lite.calibrate`), which the run's config keeps.
  On a shape with many thin parts (columns, slats: :meth:`ShapeGrid.thin_share`)
  the fit switches by itself to ``detail``'s settings (``Config.thin_parts``),
  which keep them in about the same time; the run's config is then named
  ``small+thin``. A shape that is almost all thin walls (a ruined tower) gets
  ``quick``'s thin-walls settings on ``small``'s own grid and autoencoder
  instead (``small+walls``): ``detail``'s copy such a shape and close its windows.
* ``quick`` – ``small`` with a light autoencoder (MLP heads 128 wide, 4,096 points,
  the colour loss on 2,048 of them, 1,000 steps) and 1,000 denoiser steps, for CPUs without native bf16 (AVX2
  only, most laptops), where ``small``'s paper-width autoencoder alone takes
  about 20 minutes on 2 cores: the whole fit in about 5 minutes there, samples
  of the same shape and variation, but blurrier texture (a brick wall loses its
  vertical mortar joints), baked into 512² textures. ``Sin3DM.fit`` suggests it on such a CPU. Its
  thin-part switch keeps the grid (the finer settings take about 5x its fit there)
  and snaps the samples to the input's latent patches (``sampling.snap``); the fit
  names ``--thin-switch``, which asks for the finer settings too. On a shape that is almost
  all thin walls it also tries a wider denoiser field (``Config.thin_walls``).
* ``detail`` – ``small`` at 96 voxels (a 48-texel latent) with 4 ResBlocks (a
  17-texel field, about the same share of the latent) and the paper's
  cross-plane rollout (the three planes agree where a column stands), sampled
  from pure noise: for shapes with parts 2-3 voxels thin at 64 (columns,
  railings), which ``small``'s 32-texel latent smears; its fit takes about as
  long as ``small``'s.
  ``small`` picks it by itself for such shapes; naming it forces it on any
  shape, but shapes whose global layout should vary (the canyon) copy the
  input with it.
* ``paper`` – the paper's numbers (256 grid, 25k + 25k steps) for one GPU; on CUDA
  the denoiser trains under bf16 autocast and ``torch.compile`` (about 25 min for
  the whole fit; docs/performance.md has the measured times).
"""

from __future__ import annotations

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


#: ``quick``'s thin-part switch: the same fit, its samples snapped to the input's latent patches (the calibration
#: then picks the diversity for the snapped sampler). On the thin-walled ruin and the colonnade it gives more
#: variation and more of the input's patches at 128 voxels (docs/thin-parts.md); no extra fit time. The snapped
#: samples take their fine detail from the input's patches, and a denoiser batch of 6 instead of 8 kept the same
#: figures on the ruin, the colonnade and tiles.obj: a fifth less denoiser time (docs/presets.md).
QUICK_THIN_CHANGES = {"sampling.snap": 1.0, "diffusion.batch_size": 6}
#: ``quick``'s thin-walls switch, on top of its thin-part switch, for a shape that is almost all thin walls (a ruined
#: tower): 4 ResBlocks of 16 channels for 1,500 steps on batches of 4, a 17-texel field instead of 9, which keeps a
#: stepped top that 9 texels round into a slanted rim, in about the narrower denoiser's time (a step of 4 × 16 on 4
#: costs two thirds of one of 2 × 32 on 6; 4 × 32 would cost 1.75x; batches of 4 instead of 6 scored the same on
#: both test ruins, docs/thin-parts.md). On trial: a shape whose layout that field holds whole (a square keep)
#: makes only copies with it, which the fit sees after 150 steps and undoes (fit_policy.are_copies;
#: docs/thin-parts.md). Its autoencoder adds free geometry planes to the encoder's (``autoencoder.residual_planes``):
#: the ruin's reconstruction keeps its windows (260-266 of the input's 277 window cells at 128 voxels against 0-149)
#: and its stepped top's risers; with the paper's 5×5 plane convolutions its samples keep some of the windows too,
#: with 3×3 ones (a fifth less autoencoder time without AVX-512) none. The denoiser then returns plain wall where a
#: window was (a rare patch); snapping that prefers the input's window from the same place (``sampling.snap_place``,
#: 0.3 per texel²) brings it back: 8 of 8 samples with windows at the same G-Div and LP (docs/thin-parts.md "Where
#: the windows go").
QUICK_WALLS_CHANGES = {
    "diffusion.n_resblocks": 4,
    "diffusion.base_channels": 16,
    "diffusion.steps": 1500,
    "diffusion.batch_size": 4,
    "autoencoder.residual_planes": True,
    "sampling.snap_place": 0.3,
}

#: what ``detail`` changes in ``small``; ``small`` switches to it by itself on shapes with many thin parts
DETAIL_CHANGES = {
    "grid.resolution": 96,
    "diffusion.n_resblocks": 4,
    "diffusion.rollout": True,
    "diffusion.steps": 1250,
    "diffusion.batch_size": 8,  # small's; named so that quick --thin-switch does not keep its snapped batch of 6
    "autoencoder.steps": 1000,
    "sampling.diversity": 1.0,
}


#: what ``small`` changes when its calibration keeps the goals from pure noise (Config.rollout_switch)
ROLLOUT_CHANGES = {"diffusion.rollout": True, "diffusion.steps": 1250}


def _small() -> Config:
    # Why these numbers (the evidence: docs/presets.md, docs/calibration.md, docs/thin-parts.md, docs/lab-notes.md):
    # * grid: the paper's σ 0.005 (a wider band erodes the surface); a margin of 3.25 voxels so that the shape's
    #   sides stay out of the latent's clamped outer texel, and not a whole number, which would put the faces of
    #   simply proportioned shapes exactly on voxel centres, where inside/outside is a coin toss;
    # * autoencoder: the paper's decoder width; 2,000 steps, which thin columns need;
    # * denoiser: one level, no cross-plane rollout: on a 32-texel latent the plane means tell every texel the
    #   global layout, and samples copy the input;
    # * sampling: diversity 0.7 (start at t = 700 from the input's latent, noised), then calibrated per shape,
    #   because the knob's curve is steep and differs between shapes;
    # * thin_parts: shapes with many thin parts get the 'detail' settings (see _detail) in about the same time;
    # * rollout_switch: a shape whose calibration keeps the goals from pure noise gets its denoiser trained again
    #   with the rollout (Sin3DM.fit), which keeps regular patterns (bricks) whole.
    small = Config(
        name="small",
        grid=GridConfig(resolution=64, n_surface_points=300_000, margin_voxels=3.25),
        autoencoder=AutoencoderConfig(steps=2000, points_per_step=8192),
        diffusion=DiffusionConfig(
            base_channels=32,
            n_resblocks=2,
            downsample=False,
            steps=2000,
            batch_size=8,
            lr=1e-3,
            ema_decay=0.0,
            rollout=False,
        ),
        sampling=SamplingConfig(
            steps=50, mesh_resolution=128, faces=20_000, texture_size=1024, diversity=0.7, calibrate=True
        ),
        checkpoint_every=250,
        thin_parts=dict(DETAIL_CHANGES),
        rollout_switch=dict(ROLLOUT_CHANGES),
    )
    # * thin_walls: a shape of thin walls only (a ruined tower) gets quick's thin-walls settings on small's own grid
    #   and autoencoder instead of detail's, which copy such a shape and lose its windows (docs/thin-parts.md)
    return small.updated(thin_walls=small_walls_changes(small))


def small_walls_changes(small: Config) -> dict:
    """``small``'s thin-walls switch: every setting ``detail`` changes back to ``small``'s own (64 voxels, no rollout),
    then ``quick``'s thin-part and thin-walls switches (snapped samples, the wider field on trial, the free planes,
    the same-place preference). It replaces the thin-part settings rather than adding to them."""
    own = small.settings()
    return {**{k: own[k] for k in DETAIL_CHANGES}, **QUICK_THIN_CHANGES, **QUICK_WALLS_CHANGES}


def _detail() -> Config:
    """``small`` at 96 voxels with 4 ResBlocks and the rollout, sampled from pure noise: for shapes with thin parts."""
    # A 2-3-voxel column is 1-1.5 texels of a 32-texel latent, too thin to keep; at 96 voxels it is 2-3 texels, and
    # the receptive field grows with the latent (4 ResBlocks). The cross-plane rollout (TriplaneConv as in the
    # paper) makes the three planes agree on where a column stands; without it some samples decode a stub hanging
    # from the beam. 1,000 autoencoder and 1,250 rollout denoiser steps keep the fit as long as small's. Not for
    # every shape: the canyon's samples copy it with these settings. Measured in docs/thin-parts.md.
    return _small().for_thin_parts().updated(name="detail")


def _quick() -> Config:
    """``small`` with a light autoencoder and 1,000 denoiser steps: about 4x faster where bf16 is not native."""
    # The autoencoder's MLPs are most of a fit, and without native bf16 they run in fp32: 128-wide MLPs on 4,096
    # points for 1,000 steps. Geometry and variation hold; colour loses some detail (the step count, not the width
    # or the points). No rollout switch (a second denoiser would double the fit on such a CPU); its thin-part switch
    # snaps the samples instead of refitting at 96 voxels (about 5x the fit there; --thin-switch asks for it).
    # Textures of 512² (not 1,024²): its decoder's colour is blurrier than small's anyway, and baking a quarter of
    # the texels takes a sample from about 12 to 8 s on one AVX2 core. 1,000 denoiser steps (1,500 before): once
    # calibrated, the same figures within a few hundredths on five shapes, 26-80 s less. The colour loss on 2,048 of
    # a step's points in the band (of about 3,700): a step about a sixth faster, the colour as good (0.2 dB better on
    # average over four shapes), the geometry's half bit for bit the same. Measured in docs/presets.md.
    return _small().updated(
        **{
            "name": "quick",
            "autoencoder.mlp_hidden": 128,
            "autoencoder.points_per_step": 4096,
            "autoencoder.color_points": 2048,
            "autoencoder.steps": 1000,
            "diffusion.steps": 1000,
            "sampling.texture_size": 512,
            "thin_parts": dict(QUICK_THIN_CHANGES),
            "thin_walls": dict(QUICK_WALLS_CHANGES),
            "rollout_switch": {},
        }
    )


def _paper() -> Config:
    return Config(
        name="paper",
        grid=GridConfig(resolution=256, n_surface_points=2_000_000),
        autoencoder=AutoencoderConfig(),
        # on CUDA: bf16 autocast and a compiled training step (docs/performance.md)
        diffusion=DiffusionConfig(precision="auto", compile=True),
        sampling=SamplingConfig(steps=100, mesh_resolution=256, faces=50_000, texture_size=2048),
        checkpoint_every=2500,
    )


PRESETS = {"tiny": _tiny, "small": _small, "quick": _quick, "detail": _detail, "paper": _paper}


def get_preset(name: str) -> Config:
    """Return a fresh copy of a named preset (``tiny``, ``small``, ``quick``, ``detail`` or ``paper``)."""
    if name not in PRESETS:
        raise Sin3DMInputError(f"unknown preset '{name}'; choose one of: {', '.join(PRESETS)}")
    return PRESETS[name]()


def fast_mode() -> bool:
    """True when the ``SIN3DM_FAST`` environment variable asks for tiny settings (CI, tests)."""
    import os

    return os.environ.get("SIN3DM_FAST", "0") not in ("", "0", "false", "False")


def notebook_preset() -> Config:
    """The preset a notebook uses: ``tiny`` under ``SIN3DM_FAST=1``, else ``small``."""
    return get_preset("tiny" if fast_mode() else "small")

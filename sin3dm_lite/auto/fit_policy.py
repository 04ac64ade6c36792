"""What a fit decides about its input and settings, and what it says about them.

* :func:`thin_parts_switch`: finer settings for a shape that is mostly thin parts (:func:`thin_parts_hint`
  where the config has no such switch), and for one of thin walls only a wider denoiser field on trial
  (:func:`are_copies` on :func:`from_noise_distance`: the trial's verdict);
* :func:`keeps_goals_from_noise` / :func:`rollout_hint`: the cross-plane rollout for a shape whose layout
  varies little whatever the diversity knob;
* :func:`quick_hint`: the ``quick`` preset where the autoencoder would be slow (no native bf16);
* :func:`choose_pbr`, :func:`check_flips`: which variant to fit, and settings that do not go together;
* :func:`warn_if_poor`: a reconstruction too poor for useful samples, with the setting to fit again with;
* :func:`from_noise_distance` / :func:`copies_warning`: a fit whose samples from pure noise are the input.

:mod:`sin3dm_lite.app.fitting` runs the stages and asks these functions; each one is a plain function of the
config (and the grid or the calibration), so a test or a notebook can ask it too.
"""

from __future__ import annotations

import math
from shlex import quote

import torch

from ..app.device import bf16_is_fast, cpu_bf16_share
from ..data.config import Config
from ..data.grid import ShapeGrid
from ..data.mesh import TexturedMesh
from ..errors import Sin3DMInputError
from ..evaluate.calibration_record import COPIES_G_DIV
from ..model.diffusion import check_flips as check_flip_axes
from ..presets import DETAIL_CHANGES, PRESETS

#: a ``small`` fit switches to ``detail``'s settings when more of the solid than this is thin
#: (:meth:`ShapeGrid.thin_share`): on five test shapes, ``detail`` helped the three above it, not the two below.
THIN_SHARE_HINT = 0.2
MIN_IOU = 0.9  # fit warns below this reconstruction occupancy IoU ...
MIN_PSNR = 18.0  # ... or this colour PSNR (dB): an RMS colour error above 12.6 % (the colonnade example gets 20)

#: :func:`quick_hint` speaks up when an fp32 autoencoder would take longer than this (minutes, 2 cores)
QUICK_HINT_MINUTES = 8.0


#: above this share of thin parts a shape is almost all thin walls (the ruined tower 0.98, the square keep 1.0; the
#: colonnade 0.24): ``quick`` then tries a wider denoiser field too (:attr:`Config.thin_walls`)
THIN_WALLS_SHARE = 0.6
#: the wider field's trial looks at 4 samples from pure noise after this many denoiser steps (of 1,500):
#: :func:`are_copies`
WIDE_FIELD_CHECK_STEP = 150


# --------------------------------------------------------------------------- thin parts
def thin_parts_switch(cfg: Config, grid: ShapeGrid, thin: float | None = None) -> Config | None:
    """The settings :meth:`Sin3DM.fit` switches to when ``grid`` is mostly thin parts, else None.

    A preset with :attr:`Config.thin_parts` (``small``: the ``detail``
    settings, 96 voxels and a 17-texel denoiser field) swaps them in when
    more than :data:`THIN_SHARE_HINT` of the solid lies in parts under ~5
    voxels thick (:meth:`ShapeGrid.thin_share`): its 64-voxel grid and 9-texel
    field swell or break such parts (columns, small boxes, slats) in every
    sample, the finer grid keeps them in about the same fit time
    (docs/thin-parts.md). ``thin`` is the share, if already measured.

    ``quick``'s config also has :attr:`Config.thin_walls`, which it adds on a
    shape that is almost all thin walls (share above :data:`THIN_WALLS_SHARE`):
    a wider denoiser field, on trial (:func:`are_copies`).
    """
    if not cfg.thin_parts:
        return None
    thin = grid.thin_share() if thin is None else thin
    return cfg.for_thin_parts(walls=thin > THIN_WALLS_SHARE) if thin > THIN_SHARE_HINT else None


def _finer_settings() -> str:
    """The finer thin-part settings (``detail``'s) in words, as the switch message and the hint name them."""
    return (
        f"({DETAIL_CHANGES['grid.resolution']} voxels, a {DETAIL_CHANGES['diffusion.n_resblocks']}-ResBlock denoiser "
        "whose planes see each other)"
    )


#: how the fit's switch messages start each change on a line of its own, under the message's first line
ITEM = "\n    - "


def thin_parts_message(cfg: Config, new: Config, grid: ShapeGrid, thin: float) -> str:
    """What the fit says when it switches from ``cfg`` to ``new`` (:func:`thin_parts_switch`)."""
    if new.grid == cfg.grid:  # quick's switch: the same fit, snapped samples; one line per change, then the choices
        b0, b1 = cfg.diffusion.batch_size, new.diffusion.batch_size
        batch = (
            f"; its denoiser on batches of {b1} instead of {b0}, which snapped samples need no more" if b0 != b1 else ""
        )
        finer = (
            f"Its finer thin-part settings {_finer_settings()} copy a shape of thin walls and close its windows: "
            "CLI --thin-switch asks for them anyway."
            if cfg.walls_replace_thin_parts()  # small's: its thin-part settings are another grid's
            else f"The finer thin-part settings {_finer_settings()} keep them better at about 5x the fit time "
            "without native bf16: CLI --thin-switch."
        )
        walls = thin_walls_message(cfg, new)
        batch = batch if "batches of" not in walls else ""  # said there
        return (
            f"{thin:.0%} of '{grid.name}' lies in parts under ~5 voxels thick at {max(grid.shape)} voxels, which "
            f"the {cfg.name} preset's samples would thicken or break; the fit changes, no extra fit time (the run's "
            f"config is named '{new.name}'):"
            f"{ITEM}Its samples are snapped to the input's latent patches instead (sampling.snap={new.sampling.snap:g}, "
            f"and the calibration picks the diversity for that){batch}."
            + walls
            + f"{ITEM}To keep the plain sampler: CLI --no-thin-switch, Python preset=get_preset(...).updated(thin_parts={{}})."
            + ITEM
            + finer
        )
    return (
        f"{thin:.0%} of '{grid.name}' lies in parts under ~5 voxels thick at {max(grid.shape)} voxels, which "
        f"the {cfg.name} preset's samples would swell or break: fitting at {new.grid.resolution} voxels with a "
        f"{new.diffusion.n_resblocks}-ResBlock denoiser{' whose planes see each other' if new.diffusion.rollout else ''} "
        f"instead (its thin-part settings; small's are the 'detail' "
        f"preset's, about the same fit time; the run's config is named '{new.name}'). To keep {cfg.grid.resolution} voxels: CLI "
        "--no-thin-switch, Python preset=get_preset(...).updated(thin_parts={})."
    )


def field_width(n_resblocks: int) -> int:
    """Latent texels one output texel of the package's one-level denoiser sees: two 3×3 convolutions a ResBlock."""
    return 1 + 4 * n_resblocks


def thin_walls_message(cfg: Config, new: Config) -> str:
    """One more sentence for ``quick``'s switch (``cfg`` → ``new``) when it adds :attr:`Config.thin_walls`, else "".

    A 2-ResBlock denoiser sees 9 latent texels, less than a ruin's stepped top spans: its samples keep thin
    walls but round the staircase into a ragged, slanted rim. 4 ResBlocks (17 texels) keep the treads and
    risers at the same G-Div; 16 channels instead of 32, trained 1,500 steps instead of 1,000 on batches of 4
    instead of 6, keep most of that in about the narrower denoiser's time (a step 35.6 against 55.7 ms on one
    thread, 45.9 against 86.1 with AVX2 instructions) instead of 1.75x. But on a square keep of the same walls a
    17-texel field holds the whole plan and makes only copies, so the field is on trial:
    :func:`are_copies` (docs/thin-parts.md "`quick`'s thin-walls switch: the wider field, on trial").
    """
    if not cfg.thin_walls or not new.name.endswith("+walls"):
        return ""
    d0, d1 = cfg.diffusion, new.diffusion
    steps = f"for {d1.steps:,} steps " if d1.steps != d0.steps else ""
    steps += f"on batches of {d1.batch_size} " if d1.batch_size != d0.batch_size else ""
    k0, k1 = cfg.autoencoder.decoder_kernel, new.autoencoder.decoder_kernel
    extra = (  # what the switch changes beside the denoiser
        f"{ITEM}Its autoencoder's plane convolutions are {k1}x{k1} instead of {k0}x{k0} (about a fifth less of its "
        "time; a thin wall's windows close)."
        if k0 != k1
        else ""
    )
    if new.autoencoder.residual_planes and not cfg.autoencoder.residual_planes:
        extra += (
            f"{ITEM}Its autoencoder adds free planes to the encoder's, in which a window in a thin wall shows (the "
            "encoder's averages mix the wall with the one behind it)"
            + (
                ", and its snapped samples prefer the input's patch from the same place, which brings the windows back"
                if new.sampling.snap_place and not cfg.sampling.snap_place
                else ""
            )
            + "."
        )
    drop = f"CLI --set thin_walls={{}}, Python {preset_expr(cfg)}.updated(thin_walls={{}})"
    if not wide_field_undo(cfg):  # the user chose the denoiser: no wider field on trial, the rest stays
        return f"{ITEM}Almost all of it is thin walls.{extra}{ITEM}To fit without them: {drop}." if extra else ""
    return (
        f"{ITEM}Almost all of it is thin walls: its denoiser has {d1.n_resblocks} ResBlocks of {d1.base_channels} "
        f"channels {steps}instead of {d0.n_resblocks} of {d0.base_channels}, a field of "
        f"{field_width(d1.n_resblocks)} latent texels instead of {field_width(d0.n_resblocks)}, which keeps a stepped "
        "top that the narrower field rounds into a slanted rim (in about the narrower denoiser's time, 0.8-1.0x). A "
        f"field that wide can hold a small shape's whole plan: after {WIDE_FIELD_CHECK_STEP} steps the fit draws 4 "
        "samples from pure noise and, if they are copies, trains the narrower denoiser instead."
        + extra
        + f"{ITEM}To keep the narrower denoiser: {drop}"
        + (
            " (which drops the line above too; setting a denoiser setting yourself drops the wider field alone)."
            if extra
            else "."
        )
    )


def wide_field_undo(before: Config) -> dict:
    """The dotted settings that take the wider denoiser back to the narrower one of ``before``'s thin-part switch
    (what :attr:`Config.thin_walls` changes, as :meth:`Config.for_thin_parts` without ``walls`` sets them: for
    ``quick`` 2 ResBlocks of 32 channels, 1,000 steps, the snapped fits' batches of 6). The denoiser's alone: the
    autoencoder (whatever :attr:`Config.thin_walls` set in it) is trained by the time the trial looks."""
    # small's thin-part settings are another grid's (its thin-walls settings replace them): the preset's own denoiser
    old = (before if before.walls_replace_thin_parts() else before.for_thin_parts()).settings()
    return {k: old[k] for k in before.thin_walls if k.startswith("diffusion.")}


def wide_field_check_step(cfg: Config) -> int:
    """The denoiser step at which the wider field's trial looks at its samples (at most the last step)."""
    return min(WIDE_FIELD_CHECK_STEP, cfg.diffusion.steps)


def wide_field_message(cfg: Config, distance: float, undo: dict) -> str:
    """What the fit says when the wider field copies the shape and it trains the narrower denoiser instead."""
    changes = ", ".join(f"{k}={v}" for k, v in undo.items())
    return (
        f"after {WIDE_FIELD_CHECK_STEP} steps the wider denoiser's samples from pure noise are copies of the input "
        f"(their latents differ from the input's by {distance:.1%} of its variance): its "
        f"{field_width(cfg.diffusion.n_resblocks)}-texel field holds this shape's whole layout, so the denoiser is "
        f"trained again with the narrower field ({changes}), which varies it"
    )


def thin_parts_hint(cfg: Config, grid: ShapeGrid, thin: float) -> str | None:
    """What a fit says when ``grid`` is mostly thin parts but ``cfg`` has no thin-part switch (``quick``), else None.

    ``quick`` keeps its 64-voxel grid on such a shape because the finer
    settings cost about 5x its fit where the CPU has no native bf16: on the
    test ruin (walls 2-3 voxels thick, 98 % thin) ``quick`` took about 27 min
    with them instead of about 5, and its near copies scored LP-F 0.90 instead
    of 0.51 against the input at 128 voxels (docs/thin-parts.md). The hint
    names the switch, and snapped sampling (``sampling.snap``), which costs no fit
    time: calibrated with it (7×7 windows), the ruin's ``quick`` default went from
    0.15 to 0.45, G-Div from 0.07 to 0.20 and LP-IoU / LP-F from 0.27 / 0.43 to
    0.40 / 0.49 at 128 voxels (``quick`` switches to it by itself). Only configs between 64 and 96 voxels get it (``tiny``'s
    32 voxels are for tests, finer grids hold such parts already).
    """
    finer = DETAIL_CHANGES["grid.resolution"]
    if cfg.thin_parts or thin <= THIN_SHARE_HINT or not 64 <= cfg.grid.resolution < finer:
        return None
    python = preset_expr(cfg) if cfg.name.split("+")[0] in PRESETS else "preset=your_config"
    return (
        f"{thin:.0%} of '{grid.name}' lies in parts under ~5 voxels thick at {max(grid.shape)} voxels; the "
        f"{cfg.name} config keeps {cfg.grid.resolution} voxels, so its samples may thicken or break walls and "
        f"columns. The thin-part settings {_finer_settings()} keep them, at about 5x the fit time on a CPU without "
        "native bf16 "
        f"(about 25 minutes on 2 cores): CLI --thin-switch; Python {python}.updated(thin_parts="
        "get_preset('small').thin_parts). At no extra fit time, samples snapped to the input's latent patches keep "
        "more of them at more variation (the calibration then picks the diversity for that sampler): CLI --set "
        f"sampling.snap=1; Python {python}.updated(**{{'sampling.snap': 1.0}})."
    )


# --------------------------------------------------------------------------- time
def fp32_autoencoder_minutes(cfg: Config, one_color: bool = False) -> float:
    """About how long ``cfg``'s autoencoder trains in fp32 on 2 CPU cores (AVX2), in minutes.

    Fitted to two measured steps on a 2-core AMD EPYC without AVX512-BF16:
    ``small``'s (256-wide MLPs, 8,192 points, 64 voxels) 0.61 s, ``quick``'s
    (128 wide, 4,096 points) 0.18 s: a part that grows with the planes' area
    (their encoder and decoder) plus one that grows with points × width².
    ``detail``'s step (96 voxels) is 1.4x ``small``'s in fp32 here; the
    formula gives 1.25x. Half of each part is the colour's: its planes, and its
    head on ``color_points`` of the points (``quick``'s 2,048: 0.165 s, measured
    0.15-0.18); a shape of ``one_color`` trains none of it (``quick`` 0.09 s).
    """
    a = cfg.autoencoder
    planes = 0.119 * (cfg.grid.resolution / 64) ** 2
    mlps = 0.491 * (a.points_per_step / 8192) * (a.mlp_hidden / 256) ** 2
    colored = 0.0 if one_color else min(a.color_points or a.points_per_step, a.points_per_step) / a.points_per_step
    step_s = planes * (0.5 if one_color else 1.0) + mlps * (0.5 + 0.5 * colored)
    return a.steps * step_s / 60


def quick_hint(cfg: Config, device, one_color: bool = False) -> str | None:
    """What :meth:`Sin3DM.fit` says when its autoencoder would be slow on a CPU without native bf16, else None.

    ``small``'s paper-width autoencoder (its MLPs are most of a fit) runs in
    bf16 where the CPU has AVX512-BF16 or AMX and runs it faster (measured:
    :func:`~sin3dm_lite.app.device.bf16_is_fast`); elsewhere it runs in fp32, about
    20 minutes on 2 AVX2 cores (:func:`fp32_autoencoder_minutes`). The ``quick``
    preset's light autoencoder fits in about 5 minutes there, with blurrier
    texture (docs/presets.md). Any config whose autoencoder would take over
    :data:`QUICK_HINT_MINUTES` gets the hint, not only ``small``; a shape of
    ``one_color`` trains half an autoencoder (``ShapeGrid.single_color``).
    """
    dev = torch.device(device)
    if dev.type != "cpu" or bf16_is_fast(dev):
        return None
    minutes = fp32_autoencoder_minutes(cfg, one_color)
    if minutes <= QUICK_HINT_MINUTES:
        return None
    return (
        f"this CPU {_no_fast_bf16()}, so the {cfg.name} config's autoencoder ({cfg.autoencoder.steps:,} steps of "
        f"{cfg.autoencoder.points_per_step:,} points, {cfg.autoencoder.mlp_hidden}-wide MLPs) is slow here: about "
        f"{minutes:.0f} minutes on 2 cores in fp32. The 'quick' preset (a lighter "
        "autoencoder) fits in about 5 minutes, with the same shapes but blurrier texture: preset='quick' "
        "(CLI: --preset quick)."
    )


def _no_fast_bf16() -> str:
    """Why bf16 is not fast on this CPU, in words: no native bf16, or native bf16 that measured slow."""
    share = cpu_bf16_share()
    if share is None:
        return "has no native bf16 (emulated, it is slower still)"
    return f"runs bf16 no faster than fp32 (AVX512-BF16, but measured at {share:.1f}x fp32's time here)"


# --------------------------------------------------------------------------- advice
def preset_expr(cfg: Config) -> str:
    """How a user names the run's preset in Python: ``preset=get_preset('small')`` (or ``your Config``)."""
    base = cfg.name.split("+")[0]
    return f"preset=get_preset('{base}')" if base in PRESETS else "your Config"


def refit_advice(cfg: Config, setting: str, value, also: str = "") -> str:
    """ "fit again with SETTING=VALUE (CLI: --set ...; Python: ...)" for the run's ``cfg``."""
    python = f"{preset_expr(cfg)}.updated(**{{'{setting}': {value!r}}})"
    cli = str(value).lower() if isinstance(value, bool) else value
    return f"fit again with {setting}={cli}{also} (CLI: --set {setting}={cli}; Python: {python})"


def warn_if_poor(rec: dict, cfg: Config) -> None:
    """Warn when the autoencoder's reconstruction is too poor for useful samples, with the likely cause and the
    setting of the run's ``cfg`` to fit again with.

    Colour: more autoencoder steps, about 1.3 dB per doubling (docs/lab-notes.md; a finer grid is not the fix
    there). Occupancy: more steps or a finer grid.
    """
    import warnings

    iou, psnr, steps = rec.get("occupancy_iou"), rec.get("color_psnr"), cfg.autoencoder.steps
    if iou is not None and iou < MIN_IOU:
        finer = f" or grid.resolution={8 * round(1.5 * cfg.grid.resolution / 8)}"
        warnings.warn(
            f"low reconstruction quality: occupancy IoU {iou:.3f} < {MIN_IOU} (likely cause: too few "
            f"autoencoder steps or a grid too coarse for thin parts); "
            f"{refit_advice(cfg, 'autoencoder.steps', 2 * steps, finer)}",
            stacklevel=3,
        )
    if psnr is not None and psnr < MIN_PSNR:
        doublings = min(3, math.ceil((MIN_PSNR - psnr) / 1.3))  # about 1.3 dB per doubling of the steps
        warnings.warn(
            f"low reconstruction quality: colour PSNR {psnr:.2f} dB < {MIN_PSNR:.0f} dB (likely cause: too "
            "few autoencoder steps for this texture's detail: each doubling gave about 1.3 dB on a "
            f"two-texture mesh, and doubles the autoencoder's time); "
            f"{refit_advice(cfg, 'autoencoder.steps', steps * 2**doublings)}",
            stacklevel=3,
        )


# --------------------------------------------------------------------------- copies from pure noise
#: samples from pure noise whose latents lie closer to the input's than this (mean squared difference over the
#: input latent's variance, :func:`from_noise_distance`) may be copies. After 150 steps of ``quick``'s wider field
#: (its trial, which has nothing else to go by): the square keep 0.004 in one fit, 0.039 in another, tiles.obj 0.127,
#: the grey and the coloured ruin 0.32-0.40. After a fit the latents alone do not separate copies from samples
#: that vary: the keep's copies 0.037, but dunes.ply 0.032, rocks.stl 0.062 and tiles.obj 0.066 vary (G-Div at
#: diversity 1: 0.084, 0.197, 0.057), so there the calibration's samples decide too (:data:`COPIES_G_DIV`).
COPIES_DISTANCE = 0.07


def are_copies(distance: float) -> bool:
    """Whether samples at :func:`from_noise_distance` ``distance`` from the input are copies of it.

    The paper's ablation (its Fig. on receptive fields): too small a field loses the global structure, too large
    a one "overfits to the input example and is unable to produce variations". Which is too large depends on
    the shape: on the ruined tower (round, every stretch of wall like the next) a 17-texel field varies where
    the steps fall; on a square keep of the same walls, whose corners fix every texel's place, it makes only
    copies, even from pure noise, and from the first hundred training steps on, so the wider field's trial
    (after :data:`WIDE_FIELD_CHECK_STEP` steps) is cheap; the same test after a fit is :func:`copies_warning`'s.
    """
    return distance < COPIES_DISTANCE


def from_noise_distance(model, n: int = 4, seed: int = 0) -> float:
    """How far ``n`` samples from pure noise (diversity 1) lie from the input's latent: their mean squared
    difference over the input latent's variance, all channels (0: copies; a shape whose samples move its parts
    0.1 or more). Colour counts: a tiled slab whose samples keep its geometry but reshuffle the tiles' colours
    is no copy (geometry channels alone 0.005, all 0.108)."""
    planes = model.sample(n, seed=seed, diversity=1.0, progress=False).triplane.planes
    ref = model.latent.planes
    diff = sum(float(((p - r.to(p)) ** 2).mean()) for p, r in zip(planes, ref))
    spread = sum(float(((r - r.mean()) ** 2).mean()) for r in ref)
    return diff / max(spread, 1e-12)


def g_div_at_one(calibration: dict | None) -> float | None:
    """The mean G-Div of a calibration's samples at diversity 1 (on the grid it judged; None if it drew none)."""
    rows = [t["g_div"] for t in (calibration or {}).get("tried", []) if t.get("diversity") == 1.0 and "g_div" in t]
    return float(sum(rows) / len(rows)) if rows else None


def copies_warning(
    cfg: Config, distance: float, thin_parts: dict | None = None, g_div: float | None = None
) -> str | None:
    """What a fit warns when its samples from pure noise are copies of the input, else None: their latents near the
    input's (:data:`COPIES_DISTANCE`) and, where the calibration drew samples at diversity 1, their G-Div under
    :data:`COPIES_G_DIV`. The denoiser's field then holds the shape's whole layout, the paper's "too large a
    receptive field overfits"; no diversity setting varies it. The advice: the fit's thin-part switch off where
    it brought the wider field (``small`` on a square keep), else fewer ResBlocks."""
    if not are_copies(distance) or (g_div is not None and g_div >= COPIES_G_DIV):
        return None
    d = cfg.diffusion
    if thin_parts:
        fix = f"without the thin-part switch (CLI --no-thin-switch; Python {preset_expr(cfg)}.updated(thin_parts={{}}))"
    elif d.n_resblocks > 1:
        fix = refit_advice(cfg, "diffusion.n_resblocks", max(1, d.n_resblocks // 2))
    else:
        fix = "a smaller field, or another shape"
    among = "" if g_div is None else f"; G-Div {g_div:.3f} among the calibration's samples at diversity 1"
    return (
        f"even from pure noise this fit's samples are copies of the input (their latents differ from the input's by "
        f"{distance:.1%} of its variance{among}): its denoiser's {field_width(d.n_resblocks)}-texel field holds the whole "
        "layout of this shape, so no diversity setting varies it; a narrower field varies it, and may break its "
        f"structure (docs/thin-parts.md): fit again {fix}"
    )


# --------------------------------------------------------------------------- the rollout switch
def no_rollout_switch(cfg: Config) -> str:
    """How to keep the plain denoiser (CLI and Python)."""
    return f"--no-rollout-switch (Python: {preset_expr(cfg)}.updated(rollout_switch={{}}))"


def keeps_goals_from_noise(cfg: Config, calibration: dict | None) -> bool:
    """Whether a fit's denoiser has no cross-plane rollout and its calibration kept the input's patches even from
    pure noise (diversity 1): the case for the rollout (:attr:`Config.rollout_switch`, :func:`rollout_hint`).

    Such a shape's layout varies little whatever the knob (a wall's brick body, dunes), so the rollout
    costs it no variation and makes the three planes agree on the detail: on the wall a colour per brick
    and its vertical joints, which the plain denoiser smears; on the dunes smoother crests and better
    patches (docs/lab-notes.md, "The rollout switch"). The canyon, whose calibration stops below 1, copies
    its input with the rollout, so only a calibration that reaches 1 calls for it.
    """
    return bool(
        not cfg.diffusion.rollout
        and calibration
        and calibration.get("kept_goals")
        and calibration.get("diversity") == 1
        and not calibration.get("note")  # 1 because nearer settings were copies: not a layout that keeps its patches
    )


def rollout_message(cfg: Config) -> str:
    """What the fit says when it trains the denoiser again with the rollout (:attr:`Config.rollout_switch`)."""
    return (
        "this shape keeps the input's patches even from pure noise (calibrated to diversity 1): its layout "
        "varies little whatever the knob, so the denoiser is trained again with the cross-plane rollout, which "
        "makes the planes agree on fine detail at no cost in variation (on the wall: whole bricks instead of "
        f"smeared joints): {cfg.for_rollout().diffusion.steps:,} steps, each about 1.8x a plain one; to keep "
        "the plain denoiser: " + no_rollout_switch(cfg)
    )


def rollout_hint(cfg: Config, calibration: dict | None) -> str | None:
    """The hint a fit without :attr:`Config.rollout_switch` gives when :func:`keeps_goals_from_noise` holds
    (``None`` otherwise): fit again with the rollout."""
    if not keeps_goals_from_noise(cfg, calibration):
        return None
    return (
        "[fit] this shape keeps the input's patches even from pure noise (calibrated to diversity 1), so its "
        "layout varies little and the cross-plane rollout would cost it no variation, while making the planes "
        "agree on fine detail (on the wall: whole bricks instead of smeared joints); to try it, "
        + refit_advice(cfg, "diffusion.rollout", True)
    )


def calibration_grid_hint(thin_parts: dict | None, calibration: dict | None, run=None) -> str | None:
    """What a fit says after it switched to its thin-part settings and calibrated on a 64-voxel grid or coarser
    (``quick``'s; None otherwise): how to judge as the paper measures (128 voxels, any of 2³ sub-voxels inside,
    against the input mesh), where thin walls score higher and the choice is more varied (docs/calibration.md)."""
    resolution = (calibration or {}).get("resolution", 128)
    if thin_parts is None or resolution > 64:
        return None
    how = f"sin3dm-lite calibrate {quote(str(run))} --resolution 128" if run else "model.calibrate(resolution=128)"
    return (
        f"[fit] the calibration judged this thin-walled shape on its {resolution}-voxel training grid; judged as "
        "the paper measures (128 voxels against the input mesh), thin walls keep more of the input's patches and "
        "the choice is more varied (a ruined tower: 0.64 instead of 0.48, some samples with a flatter top; a "
        f"colonnade: 1 instead of 0.73), in about four times the time: {how}"
    )


# --------------------------------------------------------------------------- variants
def choose_pbr(mesh: TexturedMesh, pbr: bool | None, preset, say) -> bool:
    """Whether to fit the PBR variant: asked for, or (``pbr=None``) whenever the mesh has PBR maps."""
    already = isinstance(preset, Config) and preset.autoencoder.pbr
    if pbr is None:
        pbr = bool(already or mesh.has_pbr)
        if pbr and mesh.has_pbr:
            say(
                f"[fit] '{mesh.name}' has PBR maps: learning base colour, metallic, roughness and normals (pbr=False: colour only)"
            )
    elif pbr and not mesh.has_pbr:
        say(
            f"[fit] '{mesh.name}' has no PBR maps: learning its constant metallic / roughness and its geometric normals"
        )
    return bool(pbr)


def check_flips(cfg: Config) -> None:
    """``diffusion.flips`` needs a decoder that commutes with flips (autoencoder.mirror), and no PBR normals."""
    if not cfg.diffusion.flips:
        return
    check_flip_axes(cfg.diffusion.flips)
    if not cfg.autoencoder.mirror:
        raise Sin3DMInputError(
            f"diffusion.flips='{cfg.diffusion.flips}' needs autoencoder.mirror=true: only a decoder with mirror-symmetric "
            "kernels decodes a flipped latent to the mirrored shape (CLI: --set autoencoder.mirror=true)"
        )
    if cfg.autoencoder.pbr:
        raise Sin3DMInputError(
            "diffusion.flips does not work with the PBR variant: a mirrored shape's normals change direction, which a "
            "flipped latent does not say; fit with pbr=False (CLI: --no-pbr) or without flips"
        )

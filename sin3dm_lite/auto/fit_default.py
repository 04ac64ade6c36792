"""The preset a fit takes when none is named: the one this machine and this shape need, said first with why and
how long.

The machine: a CUDA GPU takes ``paper``; a CPU where bf16 measures faster than fp32 ``small`` (its autoencoder in
bf16); any other CPU ``quick`` (a light autoencoder in fp32). The shape: on a CPU, a shape mostly of thin parts
(more than :data:`MOSTLY_THIN` of its solid removed by an opening with a ball of :data:`THIN_RADIUS` voxels) takes
the finer grid, wider field and cross-plane rollout of :data:`FINER`'s preset. A preset named by the user wins.

The time is estimated from a few training steps of the chosen preset timed here on a synthetic shape
(:func:`estimate_fit`). A budget (``fit --minutes N``, :func:`within_minutes`) trains both networks for fewer steps
where the estimate is longer; without one, the default keeps to about :data:`DEFAULT_MINUTES` on a CPU
(:func:`default_budget`). Once the autoencoder has trained, a :class:`Budget` compares its time with the estimate
and shortens the denoiser's training where the fit has fallen behind (a slower machine, another job started).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from ..app.device import bf16_is_fast, cpu_bf16_share, get_device
from ..data.config import Config
from ..data.grid import is_flat
from ..errors import Sin3DMInputError
from ..presets import get_preset

#: the grid and the calibration, as a share of the two trainings' time
OTHER_SHARE = 0.2
#: the same where the calibration judges at 128 voxels by the paper's voxels (``detail``, ``fine``)
OTHER_SHARE_AT_128 = 0.35
#: the grid alone, for a fit that does not calibrate (``paper``): seconds against its training's minutes
OTHER_SHARE_GRID = 0.01
#: a compiled denoiser step (``DiffusionConfig.compile``) as a share of the eager one the estimate times, and the
#: compile's seconds, per device type (the ``paper`` denoiser on two GPUs and two CPUs: docs/performance.md)
COMPILED_SHARE = {"cuda": 0.63, "cpu": 0.9}
COMPILE_S = {"cuda": 90.0, "cpu": 150.0}
#: training steps timed per network (after untimed ones), their mean taken: a fit costs its steps' mean, and on a
#: shared machine the fastest of a few is its best case
TIMED_STEPS = 5
#: the finer preset of each CPU preset, for a shape that is mostly thin parts
FINER = {"small": "detail", "quick": "fine"}
#: the opening's ball radius, in voxels of the 64-voxel grid: it removes parts thinner than about 7 voxels (3.5
#: rather than 3, whose ball is thinner between the axes)
THIN_RADIUS = 3.5
#: more than this share of the solid in thin parts: the finer grid
MOSTLY_THIN = 0.5
#: the fewest training steps a time budget leaves, as a share of the preset's (a shorter budget asks for a lighter
#: preset)
LEAST_STEPS_SHARE = 0.5
#: the fit without a preset or a budget keeps to about this many minutes on a CPU (:func:`default_budget`) ...
DEFAULT_MINUTES = 11
#: ... but never trains fewer than this share of the preset's steps, and then says how long it takes
DEFAULT_LEAST_SHARE = 0.8
#: how far past its budget a fit may look, once the autoencoder has trained, before its denoiser trains fewer steps
#: (seconds: the grid and the estimate's own timing are not in the estimate)
LATE_S = 30.0


@dataclass
class Budget:
    """A fit's time budget, kept once more after the autoencoder: where that stage ran longer than estimated (a
    slower machine than the timed steps said, another job started), the rest is assumed as much slower, and the
    denoiser trains fewer steps so that the fit still ends within ``minutes`` of ``start`` (``time.monotonic()``),
    never fewer than ``least`` of the estimated steps. ``seconds``: :func:`estimate_fit`'s for ``steps`` (the
    autoencoder's and the denoiser's steps it was estimated for)."""

    minutes: float
    seconds: dict
    steps: tuple[int, int]
    least: float
    start: float
    strict: bool = False  # the user's own (``fit --minutes``): a fit adds no stage past it

    def allows(self, seconds: float) -> bool:
        """Whether ``seconds`` more keep the fit within its budget (:data:`LATE_S` late at most), or it is not strict."""
        return not self.strict or time.monotonic() - self.start + seconds <= self.minutes * 60 + LATE_S

    @classmethod
    def within(cls, cfg: Config, seconds: dict, minutes: float, start: float) -> Budget:
        """``fit --minutes``'s: ``cfg`` estimated at ``seconds``, at least :data:`LEAST_STEPS_SHARE` of its steps."""
        return cls(minutes, seconds, (cfg.autoencoder.steps, cfg.diffusion.steps), LEAST_STEPS_SHARE, start, True)

    @classmethod
    def by_default(cls, cfg: Config, seconds: dict | None, start: float) -> Budget | None:
        """The default's (:func:`default_budget`): about :data:`DEFAULT_MINUTES`, at least
        :data:`DEFAULT_LEAST_SHARE` of the steps; None where it keeps no budget."""
        if not _keeps_default_budget(cfg, seconds):
            return None
        return cls(DEFAULT_MINUTES, seconds, (cfg.autoencoder.steps, cfg.diffusion.steps), DEFAULT_LEAST_SHARE, start)

    def denoiser_steps(self, ae_steps: int, ae_seconds: float, planned: int) -> tuple[int, str | None]:
        """The denoiser's steps (at most ``planned``) once the autoencoder trained ``ae_steps`` in ``ae_seconds``,
        and the line that says why where they are fewer (None where ``planned`` keeps the budget)."""
        slow = ae_seconds / max(self.seconds["autoencoder"] * ae_steps / self.steps[0], 1e-9)
        per_step = slow * self.seconds["denoiser"] / self.steps[1]
        spent = time.monotonic() - self.start
        left = self.minutes * 60 - spent - slow * self.seconds["other"]  # the calibration's, as much slower
        if planned * per_step <= left + LATE_S:
            return planned, None
        least = max(50, int(np.ceil(self.least * self.steps[1] / 50)) * 50)
        steps = min(planned, max(least, int(left / per_step) // 50 * 50))
        if steps == planned:
            return planned, None
        end = (spent + steps * per_step + slow * self.seconds["other"]) / 60
        over = f", about {end:.0f} min in all (fewer steps would lose patches)" if end > self.minutes + 0.5 else ""
        return steps, (
            f"[fit] the autoencoder took {ae_seconds / 60:.1f} min, {slow:.1f}x its estimate: to keep within "
            f"{self.minutes:g} min the denoiser trains {steps:,} of its {planned:,} steps{over}"
        )


@dataclass
class DefaultPreset:
    """What :func:`choose_preset` picked for this machine and why, and the fit's estimated seconds per stage."""

    name: str
    why: str
    seconds: dict | None = None  # {"autoencoder", "denoiser", "other", "total"}
    thin_share: float | None = None  # the shape's share of thin parts (:func:`thin_share`) (None: not looked at)
    calibrates: bool | None = None  # whether the fit will calibrate (None: as its preset does)

    def lines(self) -> list[str]:
        """What ``fit`` says first: the preset and why, then how long."""
        said = [f"[fit] no preset named: '{self.name}' for {self.why}; name one to choose another (CLI --preset NAME)"]
        if self.seconds:
            from .calibration import calibrates

            s = {k: v / 60 for k, v in self.seconds.items()}
            will = calibrates(get_preset(self.name)) if self.calibrates is None else self.calibrates
            other = "grid and calibration" if will else "grid"
            said.append(
                f"[fit] it should take about {s['total']:.0f} min here (autoencoder {s['autoencoder']:.1f} + "
                f"denoiser {s['denoiser']:.1f} + {other} {s['other']:.1f} min, from "
                f"{TIMED_STEPS} steps of each timed just now)"
            )
        return said


def choose_preset(device=None) -> tuple[str, str]:
    """``(preset name, why in words)`` for ``device`` (default: CUDA if present, else the CPU)."""
    dev = get_device(device)
    if dev.type == "cuda":
        return "paper", f"this machine (a CUDA GPU, {torch.cuda.get_device_name(dev)}: the paper's settings)"
    share = cpu_bf16_share()
    if bf16_is_fast(dev):
        return "small", f"this machine (a CPU whose bf16 runs in {share:.1f}x fp32's time: the autoencoder in bf16)"
    why = "without native bf16" if share is None else f"whose native bf16 runs in {share:.1f}x fp32's time, no faster"
    return "quick", f"this machine (a CPU {why}: a light autoencoder in fp32)"


def thin_share(mesh, cfg: Config) -> float:
    """The share of ``mesh``'s solid in parts thinner than about 7 voxels, on ``cfg``'s grid (its warnings silenced:
    the fit's own grid says them again)."""
    from ..data.grid import mesh_to_grid

    g = cfg.grid
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        grid = mesh_to_grid(
            mesh, g.resolution, g.threshold_voxels, 20_000, seed=0, progress=False, margin_voxels=g.margin_voxels
        )
    return grid.thin_share(THIN_RADIUS * g.resolution / 64)


def one_colour(mesh, n_points: int = 4000) -> bool:
    """Whether ``mesh``'s surface has one colour, checked at ``n_points`` surface points as the grid checks it: its
    autoencoder then learns the geometry alone, which the estimate times so (a PBR mesh never counts)."""
    from ..data.grid import ONE_COLOUR_TOLERANCE

    if mesh is None or mesh.has_pbr:
        return False
    _, faces, bary = mesh.surface_points(n_points, np.random.default_rng(0))
    return float(np.ptp(mesh.colors_at(faces, bary), axis=0).max()) <= ONE_COLOUR_TOLERANCE


def proportions(mesh) -> tuple[float, float, float]:
    """``mesh``'s box, its sides over the longest (the grid, the latent and so the denoiser's work follow it)."""
    v = np.asarray(mesh.vertices, np.float64)
    size = np.maximum(v.max(0) - v.min(0), 1e-9) if len(v) else np.ones(3)
    return tuple(float(x) for x in size / size.max())


def for_shape(name: str, mesh) -> tuple[str, str, float | None]:
    """``(preset name, why in words, thin share)`` for ``mesh`` after the machine chose ``name``: the finer preset
    (:data:`FINER`) where the shape is mostly thin parts, else ``name`` (a flat mesh too: its slab is not a thin part
    of a shape); shapes on a GPU are not measured."""
    if mesh is None or name not in FINER:
        return name, "", None
    if is_flat(mesh.normalized(), get_preset(name).grid.resolution):
        return name, " and this shape (flat: one slab, whose colours and outline its samples vary)", None
    share = thin_share(mesh, get_preset(name))
    if share > MOSTLY_THIN:
        why = (
            f" and this shape ({share:.0%} of it in parts under 7 voxels thick at 64 voxels: the finer grid, the "
            "wider field and the cross-plane rollout keep them whole)"
        )
        return FINER[name], why, share
    return name, f" and this shape ({share:.0%} of it in thin parts: its 64-voxel grid holds it)", share


def default_preset(device=None, mesh=None, timed: bool = True, up=None, turn=None) -> DefaultPreset:
    """The preset a fit of ``mesh`` (None: not measured) without one takes on ``device``, and (``timed``) its estimated
    time (:func:`estimate_fit`), measured in the frame the fit will turn it to (``up``, ``turn``: :func:`as_fitted`)."""
    from .calibration import calibrates
    from .fit_policy import as_fitted

    mesh = as_fitted(mesh, up, turn) if mesh is not None else None

    name, why = choose_preset(device)
    name, shape, share = for_shape(name, mesh)
    box = proportions(mesh) if mesh is not None else None
    calibrated = calibrates(get_preset(name), mesh)
    seconds = estimate_fit(get_preset(name), device, box, one_colour(mesh), calibrated) if timed else None
    return DefaultPreset(name, why + shape, seconds, share, calibrated)


def within_minutes(cfg: Config, seconds: dict, minutes: float) -> tuple[dict, str]:
    """The settings that keep a fit of ``cfg`` (estimated ``seconds``, :func:`estimate_fit`) within ``minutes``, and
    the line that says so: both networks train for the same share of their steps. ``{}`` where the estimate already
    fits; a budget that would leave less than :data:`LEAST_STEPS_SHARE` of the steps is refused."""
    training = seconds["autoencoder"] + seconds["denoiser"]
    share = _share_within(seconds, minutes)
    if share < LEAST_STEPS_SHARE:
        least = np.ceil((seconds["other"] + LEAST_STEPS_SHARE * training) / 6) / 10  # minutes, up to a tenth
        lighter = "" if cfg.name in ("quick", "tiny") else ", or a lighter preset (--preset quick)"
        raise Sin3DMInputError(
            f"'{cfg.name}' cannot fit within {minutes:g} min here: at half of its training steps it needs about "
            f"{least:g} min; give --minutes {least:g} or more{lighter}"
        )
    changes, steps = _steps_at(cfg, share)
    if not changes:
        return {}, f"[fit] within {minutes:g} min: the preset's steps as they are"
    return changes, f"[fit] to keep within {minutes:g} min: {steps}"


def default_budget(cfg: Config, seconds: dict | None) -> tuple[dict, str | None]:
    """What the fit without a preset (``cfg``, estimated ``seconds``) changes to keep to about
    :data:`DEFAULT_MINUTES`, and the line that says so: like :func:`within_minutes`, but never below
    :data:`DEFAULT_LEAST_SHARE` of the steps and never refused. ``({}, None)`` where the estimate fits, without one,
    and for ``paper`` (its steps are the paper's)."""
    if not _keeps_default_budget(cfg, seconds):
        return {}, None
    share = max(DEFAULT_LEAST_SHARE, _share_within(seconds, DEFAULT_MINUTES))
    changes, steps = _steps_at(cfg, share)
    if not changes:  # the estimate fits, or within the rounding of the steps
        return {}, None
    total = (seconds["other"] + share * (seconds["autoencoder"] + seconds["denoiser"])) / 60
    here = f", about {total:.0f} min here (fewer would lose patches)" if total > DEFAULT_MINUTES + 0.5 else ""
    return changes, (
        f"[fit] the default keeps to about {DEFAULT_MINUTES} min on a CPU: {steps}{here}; --preset {cfg.name} "
        "trains all of them, --minutes N keeps to N"
    )


def _keeps_default_budget(cfg: Config, seconds: dict | None) -> bool:
    """Whether the default keeps a budget: where it has an estimate, and not for ``paper`` (the paper's steps)."""
    return bool(seconds) and cfg.name != "paper"


def _share_within(seconds: dict, minutes: float) -> float:
    """The share of both networks' steps that keeps a fit estimated at ``seconds`` within ``minutes`` (at most 1:
    the grid and the calibration stay as estimated)."""
    return min(1.0, (minutes * 60 - seconds["other"]) / (seconds["autoencoder"] + seconds["denoiser"]))


def _steps_at(cfg: Config, share: float) -> tuple[dict, str]:
    """Both networks' steps at ``share`` of the preset's (to 50 steps; ``{}`` where that changes neither), and how a
    line says them."""
    ae, dn = (max(50, int(round(share * n / 50)) * 50) for n in (cfg.autoencoder.steps, cfg.diffusion.steps))
    if (ae, dn) == (cfg.autoencoder.steps, cfg.diffusion.steps):
        return {}, ""
    steps = (
        f"{ae:,} autoencoder and {dn:,} denoiser steps ({share:.0%} of the preset's {cfg.autoencoder.steps:,} and "
        f"{cfg.diffusion.steps:,})"
    )
    return {"autoencoder.steps": ae, "diffusion.steps": dn}, steps


def timing_grid(
    resolution: int, n_points: int = 20_000, box=None, one_colour: bool = False, margin_voxels: float = 0.0
):
    """A synthetic shape for timing (a step's cost depends on the grid's size, the points and the colours, not on
    the shape): a ball in the training grid (:func:`~sin3dm_lite.data.box.training_dims`, with ``margin_voxels``) of
    a shape of sides ``box`` over the longest (default 1 × ½ × ½), coloured by position, or grey all over
    (``one_colour``)."""
    from ..data.box import training_dims
    from ..data.grid import ShapeGrid
    from ..data.mesh import Normalization

    box = (1.0, 0.5, 0.5) if box is None else box
    dims = training_dims(2.0 * np.asarray(box, np.float64), resolution, margin_voxels)[1]
    half = dims / dims.max()
    aabb = np.concatenate([-half, half]).astype(np.float32)
    thr = 6.0 / dims.max()
    g = ShapeGrid(
        np.zeros(tuple(dims), np.float32), np.zeros((*dims, 3), np.float32), aabb, thr, Normalization.identity()
    )
    c = g.voxel_centers()
    radius = 0.5 * half.min()
    g.sdf = np.clip(np.linalg.norm(c, axis=-1) - radius, -thr, thr).astype(np.float32)
    paint = (lambda x: np.full_like(x, 0.7)) if one_colour else (lambda x: (x + 1) / 2)
    g.color = np.where((np.abs(g.sdf) < thr)[..., None], paint(c), 0).astype(np.float32)
    p = np.random.default_rng(0).normal(size=(n_points, 3))
    g.points = (p / np.linalg.norm(p, axis=1, keepdims=True) * radius).astype(np.float32)
    g.point_sdf = np.zeros(n_points, np.float32)
    g.point_color = paint(g.points).astype(np.float32)
    return g


def _seconds_per_step(trainer) -> float:
    """The mean of :data:`TIMED_STEPS` steps of ``trainer`` after two untimed ones (the first ones allocate)."""
    for _ in range(2):
        trainer.step()
    t0 = time.perf_counter()
    for _ in range(TIMED_STEPS):
        trainer.step()
    return (time.perf_counter() - t0) / TIMED_STEPS


def other_share(cfg: Config, calibrated: bool = True) -> float:
    """The grid and the calibration as a share of the training's time: :data:`OTHER_SHARE_AT_128` where a fit of
    ``cfg`` calibrates at 128 voxels, :data:`OTHER_SHARE` where it calibrates on its training grid, and
    :data:`OTHER_SHARE_GRID` where it does not calibrate (``calibrated=False``: not this shape, a flat one)."""
    from .calibration import calibrates, judged_at

    if not (calibrated and calibrates(cfg)):
        return OTHER_SHARE_GRID
    return OTHER_SHARE_AT_128 if judged_at(cfg) else OTHER_SHARE


def estimate_fit(cfg: Config, device=None, box=None, one_colour: bool = False, calibrated: bool = True) -> dict:
    """About how long a fit of ``cfg`` takes on ``device``, in seconds (``autoencoder``, ``denoiser``, ``other``,
    ``total``): a few steps of each network timed on :func:`timing_grid` (the denoiser uncompiled), times their
    steps (a compiled denoiser at :data:`COMPILED_SHARE` of the eager step, plus :data:`COMPILE_S`), plus
    :func:`other_share` for the grid and the calibration. ``box``: the shape's proportions
    (:func:`proportions`); ``one_colour``: :func:`one_colour`; ``calibrated``: False where the fit will not calibrate
    this shape. The random state is left as it was."""
    from ..model.autoencoder import AutoencoderTrainer
    from ..model.diffusion import DiffusionTrainer

    dev = get_device(device)
    with torch.random.fork_rng(devices=[dev] if dev.type == "cuda" else []):
        grid = timing_grid(cfg.grid.resolution, box=box, one_colour=one_colour, margin_voxels=cfg.grid.margin_voxels)
        ae = AutoencoderTrainer(grid, cfg.updated(**{"autoencoder.pbr": False}).autoencoder, dev, 0)
        ae_s = _seconds_per_step(ae) * cfg.autoencoder.steps
        dm = DiffusionTrainer(ae.latent(), cfg.updated(**{"diffusion.compile": False}).diffusion, dev, 0)
        dn_s = _seconds_per_step(dm) * cfg.diffusion.steps
    if cfg.diffusion.compile:
        dn_s = dn_s * COMPILED_SHARE[dev.type] + COMPILE_S[dev.type]
    other = other_share(cfg, calibrated) * (ae_s + dn_s)
    return {"autoencoder": ae_s, "denoiser": dn_s, "other": other, "total": ae_s + dn_s + other}


__all__ = [
    "FINER",
    "MOSTLY_THIN",
    "OTHER_SHARE",
    "OTHER_SHARE_GRID",
    "THIN_RADIUS",
    "Budget",
    "DefaultPreset",
    "choose_preset",
    "default_preset",
    "estimate_fit",
    "one_colour",
    "for_shape",
    "other_share",
    "thin_share",
    "timing_grid",
    "within_minutes",
    "default_budget",
]

"""All settings in one place: the dataclasses of a run's configuration and what each setting may be.

:class:`Config` holds a whole run (grid, autoencoder, diffusion, sampling,
seed); :data:`LIMITS` says what every setting may be, checked whenever a
``Config`` is made or changed. The five named presets (``tiny``, ``small``,
``quick``, ``detail``, ``paper``) are in :mod:`sin3dm_lite.presets`.
"""

from __future__ import annotations

import ast
import json
import numbers
from dataclasses import MISSING, asdict, dataclass, field, fields, is_dataclass, replace
from typing import Any

import numpy as np

from ..errors import Sin3DMInputError


@dataclass
class GridConfig:
    """Mesh → truncated SDF + colour grid (docs/paper-notes.md "Input grid")."""

    resolution: int = 128  # voxels along the longest side (each axis rounded up to a multiple of 8)
    threshold_voxels: float = 3.0  # truncation band, in voxels
    n_surface_points: int = 500_000  # surface samples for the near-surface training points
    near_surface_sigma: float = 0.005  # Gaussian offset of near-surface points (normalised units; ≈0.64 voxel)
    margin_voxels: float = 0.0  # empty voxels kept between the shape and every box face (0: the paper's 1.03 only)
    up: str = "y"  # the input's up axis, turned to +y before the grid (data.mesh.UP_TURNS): "z" for a Z-up model
    turn: float = 0.0  # degrees the input is then turned about y (its walls along x and z); samples turned back


@dataclass
class AutoencoderConfig:
    """Triplane autoencoder (docs/paper-notes.md "Triplane autoencoder")."""

    geo_channels: int = 4  # latent channels 0..3 describe geometry
    tex_channels: int = 8  # latent channels 4..11 describe texture
    decoder_channels: int = 64  # width of the per-plane 2D ResNet block
    decoder_kernel: int = 5
    mlp_hidden: int = 256
    use_encoder: bool = True  # False = auto-decoder: the planes themselves are optimised
    steps: int = 25_000
    points_per_step: int = 65_536
    grid_fraction: float = 0.1  # share of grid points in a batch; the rest are near the surface
    color_points: int = 0  # the colour loss on at most this many of a batch's points in the band (0: all of them)
    lr_geo: float = 1e-3
    lr_tex: float = 5e-3
    lr_final_factor: float = 0.1  # exponential decay to this factor of the start lr over the run
    near_weight: float = 1.5  # SDF L1 weight where the error points towards / across the surface
    far_weight: float = 0.5  # ... and where it points away from it
    precision: str = "auto"  # "bf16" (mixed precision), "fp32", or "auto": bf16 where it measures faster
    pbr: bool = False  # PBR variant: 8 texture channels in, two more decoder heads (metallic-roughness, normal)

    @property
    def latent_channels(self) -> int:
        return self.geo_channels + self.tex_channels


@dataclass
class DiffusionConfig:
    """Triplane diffusion model (docs/paper-notes.md "Diffusion on triplanes")."""

    base_channels: int = 64
    n_resblocks: int = 4  # 2 / 4 / 6 as in the paper's receptive-field ablation
    downsample: bool = True  # the paper's one-level U-Net halves the resolution once
    rollout: bool = True  # cross-plane features in TriplaneConv
    time_embed_dim: int = 64
    timesteps: int = 1000
    beta_start: float = 1e-4
    beta_end: float = 0.02
    prediction: str = "x0"  # "x0" (the paper) or "eps" (the ablation)
    steps: int = 25_000
    batch_size: int = 32
    lr: float = 5e-4
    ema_decay: float = 0.9999  # use ~0.999 or 0 (raw weights) for short runs
    # latent diffusion's scale factor: the latent is multiplied by it for the diffusion and divided after sampling
    # (1: as it is, the paper; 0: to unit variance, the factor found at the fit recorded in its config)
    latent_scale: float = 1.0
    precision: str = "fp32"  # the training forward: "fp32", "bf16" (autocast) or "auto" (bf16 where it measures faster)
    compile: bool = False  # torch.compile the denoiser's training forward: minutes to compile, so for long fits


@dataclass
class SamplingConfig:
    """Defaults for drawing samples and turning them into meshes."""

    method: str = "ddim"  # "ddim" or "ddpm"
    steps: int = 50  # DDIM steps (DDPM always uses all timesteps)
    diversity: float = 1.0  # 1: from pure noise (the paper); lower: from the input's latent, noised (closer copies)
    mesh_resolution: int = 256  # decode grid along the longest side
    faces: int = 30_000  # face budget after simplification
    texture_size: int = 2048


@dataclass
class Config:
    """A whole run: data, both networks, sampling, seed."""

    name: str = "custom"
    seed: int = 0
    grid: GridConfig = field(default_factory=GridConfig)
    autoencoder: AutoencoderConfig = field(default_factory=AutoencoderConfig)
    diffusion: DiffusionConfig = field(default_factory=DiffusionConfig)
    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    checkpoint_every: int = 500  # training steps between checkpoints in a run folder

    def __post_init__(self) -> None:
        check_config(self)  # a setting out of range fails where it is made, before any work

    def check(self) -> Config:
        """Check every setting (:data:`LIMITS`; e.g. after changing one in place); returns ``self``."""
        check_config(self)
        return self

    def to_dict(self) -> dict:
        return asdict(self)

    def settings(self) -> dict:
        """Every setting by its dotted name: ``{"seed": 0, "grid.resolution": 32, ...}`` (the names ``--set`` takes)."""
        return _settings(self.to_dict())

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    @classmethod
    def from_dict(cls, d: dict) -> Config:
        for key, value in _settings(d).items():  # a saved config of a run that today's code would read wrongly
            if key in RETIRED and value != RETIRED[key]:
                raise Sin3DMInputError(
                    f"this run was fitted with {key}={value!r}, an experiment this version no longer has "
                    "(docs/lab-notes.md); fit it again without that setting"
                )
        return _from_dict(cls, d)

    def updated(self, **changes: Any) -> Config:
        """Copy with dotted-path changes, e.g. ``cfg.updated(**{"diffusion.steps": 100})``."""
        d = self.to_dict()
        for key, value in changes.items():
            if key not in LIMITS:
                raise unknown_setting(key)
            node = d
            *parents, leaf = key.split(".")
            for p in parents:
                node = node[p]
            _check_type(key, node[leaf], value)
            check_setting(key, value)
            if isinstance(node[leaf], float) and not isinstance(value, bool):
                value = float(value)  # a rate stays a float when given as a whole number (``--set x=0``)
            node[leaf] = value
        return Config.from_dict(d)


#: settings that earlier versions had, at the value today's code always assumes: mirror-symmetric decoder
#: convolutions and latents flipped or cropped in training (they varied the samples no better than the knob)
RETIRED = {"autoencoder.mirror": False, "diffusion.flips": "", "diffusion.crop": 0}

# --------------------------------------------------------------------------- what each setting may be
#: every setting's allowed values (:func:`check_setting`): ``(low, high)`` for a number (both ends allowed),
#: a list for a choice, ``bool``, ``str`` or ``dict`` for the rest
LIMITS: dict[str, Any] = {
    "name": str,
    "seed": (0, 2**32 - 1),
    "checkpoint_every": (1, 10**9),
    "grid.resolution": (16, 512),
    "grid.threshold_voxels": (0.5, 32.0),
    "grid.n_surface_points": (1_000, 50_000_000),
    "grid.near_surface_sigma": (0.0, 0.5),
    "grid.margin_voxels": (0.0, 64.0),
    "grid.up": ["y", "z", "x"],
    "grid.turn": (-180.0, 180.0),
    "autoencoder.geo_channels": (1, 256),
    "autoencoder.tex_channels": (1, 256),
    "autoencoder.decoder_channels": (1, 4096),
    "autoencoder.decoder_kernel": [1, 3, 5, 7, 9, 11, 13, 15],  # odd: the convolutions keep the plane's size
    "autoencoder.mlp_hidden": (1, 8192),
    "autoencoder.use_encoder": bool,
    "autoencoder.steps": (1, 10**8),
    "autoencoder.points_per_step": (1, 2**24),
    "autoencoder.grid_fraction": (0.0, 1.0),
    "autoencoder.color_points": (0, 2**24),
    "autoencoder.lr_geo": (1e-12, 1.0),
    "autoencoder.lr_tex": (1e-12, 1.0),
    "autoencoder.lr_final_factor": (1e-12, 1.0),
    "autoencoder.near_weight": (0.0, 1000.0),
    "autoencoder.far_weight": (0.0, 1000.0),
    "autoencoder.precision": ["auto", "fp32", "bf16"],
    "autoencoder.pbr": bool,
    "diffusion.base_channels": (1, 4096),
    "diffusion.n_resblocks": (1, 64),
    "diffusion.downsample": bool,
    "diffusion.rollout": bool,
    "diffusion.time_embed_dim": (2, 4096),
    "diffusion.timesteps": (2, 100_000),
    "diffusion.beta_start": (1e-12, 0.999),
    "diffusion.beta_end": (1e-12, 0.999),
    "diffusion.prediction": ["x0", "eps"],
    "diffusion.steps": (1, 10**8),
    "diffusion.batch_size": (1, 4096),
    "diffusion.lr": (1e-12, 1.0),
    "diffusion.ema_decay": (0.0, 0.999999),
    "diffusion.latent_scale": (0.0, 1000.0),
    "diffusion.precision": ["auto", "fp32", "bf16"],
    "diffusion.compile": bool,
    "sampling.method": ["ddim", "ddpm"],
    "sampling.steps": (1, 100_000),
    "sampling.diversity": (0.0, 1.0),
    "sampling.mesh_resolution": (16, 2048),
    "sampling.faces": (4, 100_000_000),
    "sampling.texture_size": (16, 16384),
}


def _number(x: float) -> str:
    """``10000`` → ``10,000``, ``0.5`` → ``0.5``, ``1e-12`` → ``1e-12``."""
    return f"{x:,}" if isinstance(x, int) else f"{x:g}"


def allowed(key: str) -> str:
    """What ``key`` may be, in words: ``a whole number from 1 to 100,000,000``, ``one of 'ddim', 'ddpm'``, ..."""
    rule = LIMITS[key]
    if rule is bool:
        return "true or false"
    if rule in (str, dict):
        return "a string" if rule is str else "a dict of dotted settings"
    if isinstance(rule, list):
        return "one of " + ", ".join(repr(c) for c in rule)
    low, high = rule
    kind = "a whole number" if isinstance(low, int) else "a number"
    return f"{kind} from {_number(low)} to {_number(high)}"


def check_setting(key: str, value: Any, option: str | None = None) -> None:
    """Refuse ``value`` for the dotted setting ``key`` unless :data:`LIMITS` allows it (one line: the valid range).

    ``option`` names the setting as the user gave it (a CLI flag such as ``--texture-size``); default the key.
    """
    rule = LIMITS[key]
    what = option or f"config setting '{key}'"
    if rule is bool:
        ok = isinstance(value, (bool, np.bool_))
    elif rule in (str, dict):
        ok = isinstance(value, rule)
    elif isinstance(rule, list):
        ok = type(value) is type(rule[0]) and value in rule
    else:
        low, high = rule
        whole = isinstance(low, int)
        kind_ok = (
            isinstance(value, numbers.Integral) if whole else isinstance(value, numbers.Real)
        ) and not isinstance(value, (bool, np.bool_))
        ok = kind_ok and low <= value <= high  # NaN fails both comparisons
    if not ok:
        raise Sin3DMInputError(f"{what} must be {allowed(key)}, not {value!r}")


def _settings(d: dict, prefix: str = "") -> dict:
    """A nested config dict as ``{dotted key: value}`` (the dict-valued settings kept whole)."""
    flat = {}
    for k, v in d.items():
        key = prefix + k
        if isinstance(v, dict) and key not in LIMITS:
            flat.update(_settings(v, key + "."))
        else:
            flat[key] = v
    return flat


def unknown_setting(key: str) -> Sin3DMInputError:
    """The error for a dotted name that is not a setting: the close match, or the settings of that section."""
    import difflib

    names = list(LIMITS)
    section, _, leaf = key.partition(".")
    sections = sorted({k.split(".")[0] for k in names if "." in k})
    if section in sections:
        leaves = [k.split(".", 1)[1] for k in names if k.startswith(section + ".")]
        close = difflib.get_close_matches(leaf, leaves, n=1, cutoff=0.7)
        hint = (
            (f"did you mean '{section}.{close[0]}'? " if close else "")
            + f"the {section} settings are: "
            + ", ".join(leaves)
        )
    else:
        close = difflib.get_close_matches(key, names, n=1, cutoff=0.7)
        hint = (f"did you mean '{close[0]}'? " if close else "") + (
            f"settings are SECTION.NAME with SECTION one of {', '.join(sections)}, or one of "
            + ", ".join(k for k in names if "." not in k)
        )
    return Sin3DMInputError(f"unknown config setting '{key}'; {hint} (names as in a run's config.json)")


def check_config(cfg: Config) -> None:
    """Every setting of ``cfg`` against :data:`LIMITS`, and the rules that tie two settings together."""
    flat = _settings(cfg.to_dict())
    for key, value in flat.items():
        if key not in LIMITS:
            raise unknown_setting(key)
        check_setting(key, value)
    d, s = cfg.diffusion, cfg.sampling
    if not d.beta_start < d.beta_end:
        raise Sin3DMInputError(
            f"diffusion.beta_start ({d.beta_start:g}) must be below diffusion.beta_end ({d.beta_end:g})"
        )
    if s.steps > d.timesteps:
        raise Sin3DMInputError(
            f"sampling.steps must be from 1 to diffusion.timesteps ({d.timesteps:,}), not {s.steps!r}"
        )


def _check_type(key: str, old: Any, value: Any) -> None:
    """A setting keeps its kind: a switch stays a bool, a count an integer, a rate a number, a name a string."""
    if old is None:
        return
    if isinstance(old, bool):
        ok, kind = isinstance(value, bool), "true or false"
    elif isinstance(old, numbers.Integral):
        ok, kind = isinstance(value, numbers.Integral) and not isinstance(value, bool), "a whole number"
    elif isinstance(old, numbers.Real):
        ok, kind = isinstance(value, numbers.Real) and not isinstance(value, bool), "a number"
    else:
        ok, kind = isinstance(value, type(old)), type(old).__name__
    if not ok:
        raise Sin3DMInputError(f"config setting '{key}' must be {kind} (it is {old!r} in this preset), not {value!r}")


def parse_settings(items) -> dict:
    """``["diffusion.rollout=true", "diffusion.steps=1500"]`` → ``{"diffusion.rollout": True, "diffusion.steps": 1500}``.

    ``true`` / ``false`` in any case, numbers, anything else as a string (what ``--set`` takes);
    :meth:`Config.updated` then checks the names and kinds.
    """
    changes = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise Sin3DMInputError(f"'{item}' is not SETTING=VALUE; e.g. --set diffusion.rollout=true")
        text = text.strip()
        if text.lower() in ("true", "false"):
            value: Any = text.lower() == "true"
        else:
            try:
                value = ast.literal_eval(text)
            except (ValueError, SyntaxError):
                value = text
        changes[key.strip()] = value
    return changes


def _from_dict(cls, d: dict):
    """``cls`` from its dictionary; a key that is no field (a setting an older version had) is left out."""
    kwargs = {}
    for f in fields(cls):
        if f.name not in d:
            continue
        value = d[f.name]
        sub = f.default_factory() if f.default_factory is not MISSING else None  # type: ignore[misc]
        if is_dataclass(sub):
            value = _from_dict(type(sub), value)
        kwargs[f.name] = value
    return cls(**kwargs)


__all__ = [
    "AutoencoderConfig",
    "Config",
    "LIMITS",
    "check_setting",
    "DiffusionConfig",
    "GridConfig",
    "SamplingConfig",
    "replace",
]

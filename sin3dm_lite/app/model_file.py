"""Every field of a ``model.pt`` checked before it is used: a file from a stranger builds nothing unbounded.

Each network is first laid out on torch's ``meta`` device (shapes, no memory) and compared with the memory there
is and with the file's weights, and only then built; whatever is wrong gives one
:class:`~sin3dm_lite.errors.Sin3DMInputError` naming the file and the field.
"""

from __future__ import annotations

import json
import math
import numbers
from pathlib import Path

import numpy as np
import torch

from ..data.config import Config
from ..data.mesh import MAX_COORDINATE, Normalization, is_rotation
from ..errors import Sin3DMInputError
from ..model.autoencoder import PBR_HEADS, TriplaneDecoder
from ..model.triplane import PLANES, Triplane
from ..model.unet import TriplaneUNet

#: the entries of a ``model.pt`` besides its format tag (:func:`~sin3dm_lite.app.checkpoints.model_bundle`)
FIELDS = ("config", "decoder", "latent", "denoiser", "aabb", "center", "scale", "color_channels", "report")
#: a plane of the latent has at most this many texels along a side (a 512-voxel grid's latent is 256)
MAX_LATENT_SIDE = 4096


def bad(path: Path, why: str) -> Sin3DMInputError:
    """The one-line error for a ``model.pt`` whose field is wrong: ``why`` says which and how."""
    return Sin3DMInputError(
        f"'{path}' is damaged or was not made by sin3dm-lite ({why}); fit the model again with "
        "`sin3dm-lite fit MESH --out DIR`, or get the run folder again from where it came"
    )


def model_parts(path: Path, b: dict) -> tuple:
    """``(config, decoder, latent, denoiser, aabb, normalization, report)`` from the checked fields of ``b``."""
    if missing := [k for k in FIELDS if k not in b]:
        raise bad(path, f"the entry '{missing[0]}' is missing")
    cfg = stored_config(path, b["config"])
    latent = stored_latent(path, b["latent"], cfg)
    aabb = stored_box(path, b["aabb"])
    norm = stored_normalization(path, b["center"], b["scale"], b.get("rotation"))
    report = json_dict(path, "report", b["report"])
    if (why := report_problem(report)) is not None:
        raise bad(path, why)
    color = b["color_channels"]
    want = sum(PBR_HEADS.values()) if cfg.autoencoder.pbr else 3
    if not isinstance(color, int) or isinstance(color, bool) or color != want:
        raise bad(path, f"color_channels is {color!r}, not the {want} its config's decoder predicts")
    weights = state_dict(path, "decoder", b["decoder"])
    threshold = weights.get("threshold")
    if not (isinstance(threshold, torch.Tensor) and threshold.numel() == 1 and 0 < float(threshold) <= 8):
        raise bad(path, "the decoder's threshold is not a number above 0 and at most 8")
    decoder = built(path, "decoder", lambda: TriplaneDecoder(cfg.autoencoder, float(threshold), color), weights, cfg)
    unet_weights = state_dict(path, "denoiser", b["denoiser"])
    denoiser = built(path, "denoiser", lambda: TriplaneUNet(latent.channels, cfg.diffusion), unet_weights, cfg)
    return cfg, decoder, latent, denoiser, aabb, norm, report


def json_dict(path: Path, field: str, text) -> dict:
    """The JSON object the string field ``field`` holds."""
    try:
        value = json.loads(text) if isinstance(text, (str, bytes)) else None
    except ValueError:
        value = None
    if not isinstance(value, dict):
        raise bad(path, f"its {field} is not a JSON object")
    return value


def report_problem(report: dict) -> str | None:
    """What is wrong with the fields of a model's report that sampling and evaluation read (None: nothing)."""
    shape = report.get("grid_shape")
    if shape is not None and not (
        isinstance(shape, list)
        and len(shape) == 3
        and all(isinstance(n, int) and not isinstance(n, bool) and 1 <= n <= 1024 for n in shape)
    ):
        return f"its report's grid_shape {shape!r} is not three whole numbers from 1 to 1024"
    for key in ("input", "input_path", "preset"):
        if report.get(key) is not None and not isinstance(report[key], str):
            return f"its report's {key} is not a string"
    for key in ("reconstruction", "calibration", "precision"):
        if report.get(key) is not None and not isinstance(report[key], dict):
            return f"its report's {key} is not a JSON object"
    diversity = (report.get("calibration") or {}).get("diversity")
    if diversity is not None and not (isinstance(diversity, (int, float)) and 0 <= diversity <= 1):
        return f"its report's calibrated diversity {diversity!r} is not a number from 0 to 1"
    return None


def stored_config(path: Path, text) -> Config:
    """The run's whole config (every section and setting present, each within LIMITS)."""
    d = json_dict(path, "config", text)
    if gaps := missing_settings(d):
        more = f" and {len(gaps) - 1} more" if len(gaps) > 1 else ""
        raise bad(path, f"its config lacks the setting '{gaps[0]}'{more}")
    try:
        return Config.from_dict(d)
    except Sin3DMInputError as e:
        raise bad(path, f"its config: {e}") from None
    except (TypeError, ValueError, AttributeError) as e:
        raise bad(path, f"its config is not a configuration ({type(e).__name__})") from None


def missing_settings(d) -> list[str]:
    """The :data:`REQUIRED` settings the config.json ``d`` lacks (``["(all)"]`` if it is no dictionary)."""
    if not isinstance(d, dict):
        return ["(all)"]
    gaps = []
    for key in Config().settings():
        node = d
        for part in key.split("."):
            node = node.get(part, _MISSING) if isinstance(node, dict) else _MISSING
        if node is _MISSING and key in REQUIRED:
            gaps.append(key)
    return gaps


_MISSING = object()
#: the settings every config.json and model.pt of a run holds; others (added later) take their defaults
REQUIRED = (
    "name",
    "seed",
    "grid.resolution",
    "autoencoder.geo_channels",
    "autoencoder.tex_channels",
    "autoencoder.decoder_channels",
    "autoencoder.decoder_kernel",
    "autoencoder.mlp_hidden",
    "autoencoder.steps",
    "diffusion.base_channels",
    "diffusion.n_resblocks",
    "diffusion.time_embed_dim",
    "diffusion.timesteps",
    "diffusion.steps",
    "sampling.steps",
    "sampling.mesh_resolution",
)


def stored_latent(path: Path, d, cfg: Config) -> Triplane:
    """The input's latent: three finite float planes of one batch, the config's channels, sides that agree."""
    if not isinstance(d, dict) or set(d) != set(PLANES):
        raise bad(path, f"its latent is not the three planes {', '.join(PLANES)}")
    planes = [d[name] for name in PLANES]
    if not all(isinstance(p, torch.Tensor) and p.dim() == 4 and p.is_floating_point() for p in planes):
        raise bad(path, "its latent planes are not 4-dimensional float tensors")
    (b, c, x, y), (_, _, x2, z), (_, _, y2, z2) = (p.shape for p in planes)
    if (
        {p.shape[0] for p in planes} != {1}
        or {p.shape[1] for p in planes} != {cfg.autoencoder.latent_channels}
        or (x, y, z) != (x2, y2, z2)
        or not 1 <= min(x, y, z) <= max(x, y, z) <= MAX_LATENT_SIDE
    ):
        raise bad(
            path,
            f"its latent planes {[tuple(p.shape) for p in planes]} are not one latent of "
            f"{cfg.autoencoder.latent_channels} channels (the config's) with sides from 1 to {MAX_LATENT_SIDE}",
        )
    if not all(bool(torch.isfinite(p).all()) for p in planes):
        raise bad(path, "its latent holds NaN or infinite values")
    return Triplane(*(p.float() for p in planes))


def stored_box(path: Path, aabb) -> np.ndarray:
    """The input's box: six finite numbers, each side longer than zero and within the [-1, 1] cube."""
    a = aabb.detach().cpu().double().numpy() if isinstance(aabb, torch.Tensor) else None
    if a is None or a.shape != (6,) or not np.isfinite(a).all():
        raise bad(path, "its box (aabb) is not six finite numbers")
    ext = a[3:] - a[:3]
    if not ((ext > 1e-3).all() and np.abs(a).max() <= 1.0 + 1e-4):
        shown = ", ".join(f"{v:.3g}" for v in a)
        raise bad(path, f"its box (aabb) [{shown}] is not a box inside [-1, 1] with sides longer than 0.001")
    return a.astype(np.float32)


def stored_normalization(path: Path, center, scale, rotation=None) -> Normalization:
    """The transform back to the input's coordinates: a finite centre within the meshes' limit, a finite scale > 0,
    a rotation (none in a model written before fits turned their input: the identity)."""
    r = rotation.detach().cpu().double().numpy() if isinstance(rotation, torch.Tensor) else rotation
    r = np.eye(3) if rotation is None else r
    if not isinstance(r, np.ndarray) or not is_rotation(r):
        raise bad(path, "its rotation is not a 3 × 3 rotation")
    c = center.detach().cpu().double().numpy() if isinstance(center, torch.Tensor) else None
    if c is None or c.shape != (3,) or not np.isfinite(c).all() or np.abs(c).max() > MAX_COORDINATE:
        raise bad(path, f"its centre is not three finite numbers within ±{MAX_COORDINATE:.0e}")
    s = float(scale) if isinstance(scale, numbers.Real) and not isinstance(scale, bool) else math.nan
    if not (math.isfinite(s) and s > 0 and math.isfinite(1 / s) and 1 / s <= 2 * MAX_COORDINATE):
        raise bad(path, f"its scale {scale!r} is not a finite number above 0")
    return Normalization(center=c, scale=s, rotation=r)


def state_dict(path: Path, name: str, d) -> dict:
    """A network's weights: a dictionary of tensors."""
    if not isinstance(d, dict) or not all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in d.items()):
        raise bad(path, f"its {name} is not a dictionary of tensors")
    return d


def built(path: Path, name: str, make, weights: dict, cfg: Config) -> torch.nn.Module:
    """The network ``make()`` builds, once its layout (on the meta device) fits in memory and matches ``weights``."""
    from .device import memory_available

    try:
        with torch.device("meta"):
            layout = make().state_dict()  # shapes only: nothing is allocated
    except (ValueError, RuntimeError, TypeError) as e:
        raise bad(path, f"its config makes no {name} ({e})") from None
    need = sum(t.numel() * t.element_size() for t in layout.values())
    have = memory_available("cpu")
    if need > have // 2:
        raise bad(
            path,
            f"its config asks for a {name} of {need / 2**30:,.1f} GiB ({size_settings(cfg, name)}), more than half "
            f"the {have / 2**30:,.1f} GiB of memory available",
        )
    for key, t in layout.items():
        if key not in weights:
            raise bad(path, f"its {name} weights lack '{key}', which its config asks for")
        if tuple(weights[key].shape) != tuple(t.shape):
            raise bad(
                path,
                f"its {name} weight '{key}' has shape {tuple(weights[key].shape)}, its config asks for {tuple(t.shape)}",
            )
    extra = sorted(set(weights) - set(layout))
    if extra:
        raise bad(path, f"its {name} weights hold '{extra[0]}', which its config has no place for")
    net = make()
    net.load_state_dict(weights)
    return net


def layout_bytes(make) -> int:
    """The bytes of the weights of the network ``make()`` builds, laid out on the meta device (nothing allocated)."""
    with torch.device("meta"):
        return sum(t.numel() * t.element_size() for t in make().state_dict().values())


#: a network in training holds its weights, their gradients, Adam's two moments and (the denoiser) an EMA copy
TRAINING_COPIES = 5


def check_network_sizes(cfg: Config) -> None:
    """Refuse a config whose networks would not fit in memory in training, before anything is built or written."""
    from .device import memory_available

    a = cfg.autoencoder
    color = sum(PBR_HEADS.values()) if a.pbr else 3
    nets = {
        "decoder": lambda: TriplaneDecoder(a, 1.0, color),
        "denoiser": lambda: TriplaneUNet(a.latent_channels, cfg.diffusion),
    }
    have = memory_available("cpu")
    for name, make in nets.items():
        need = TRAINING_COPIES * layout_bytes(make)
        if need > have // 2:
            raise Sin3DMInputError(
                f"the config's {name} ({size_settings(cfg, name)}) needs about {need / 2**30:,.1f} GiB to train, "
                f"more than half the {have / 2**30:,.1f} GiB of memory available; choose smaller settings"
            )


def size_settings(cfg: Config, name: str) -> str:
    """The settings that size the network ``name``, as ``key value`` pairs."""
    if name == "decoder":
        a = cfg.autoencoder
        return f"autoencoder.decoder_channels {a.decoder_channels}, mlp_hidden {a.mlp_hidden}, decoder_kernel {a.decoder_kernel}"
    d = cfg.diffusion
    return f"diffusion.base_channels {d.base_channels}, n_resblocks {d.n_resblocks}, time_embed_dim {d.time_embed_dim}"


__all__ = ["MAX_LATENT_SIDE", "REQUIRED", "missing_settings", "model_parts"]

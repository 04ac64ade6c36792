"""The files torch writes in a run folder: trainer checkpoints and ``model.pt``, written atomically, read safely.

``autoencoder.pt`` / ``diffusion.pt`` hold a trainer's state (:meth:`~sin3dm_lite.model.training.Trainer.state_dict`);
``model.pt`` holds what sampling needs (:func:`model_bundle`): decoder, the input's latent, denoiser, box,
normalisation, config and report, tagged :data:`MODEL_FORMAT`. Every file is read with ``weights_only=True``
(tensors and plain containers, never code); one that is damaged, foreign or of another version gives a one-line
:class:`Sin3DMInputError` that names it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from .data.config import Config
from .data.mesh import Normalization
from .errors import Sin3DMInputError
from .files import atomic_path, atomic_paths, save_torch, write_data
from .model.autoencoder import TriplaneDecoder
from .model.training import checkpoint_problem
from .model.triplane import Triplane

MODEL_FILE = "model.pt"
MODEL_FORMAT = "sin3dm-lite/1"


def atomic_torch_save(obj, path: Path) -> None:
    """Write ``obj`` with ``torch.save`` so that ``path`` is either the old or the new file, never half of one."""
    with atomic_path(path) as tmp:
        save_torch(obj, tmp)  # a full disk: OSError(ENOSPC), not torch's "unexpected pos" RuntimeError


def not_ours(path: Path, what: str, why: str) -> Sin3DMInputError:
    """The error for a file ``path`` (a ``what``: "model", a trainer's kind, "config") this version cannot read."""
    return Sin3DMInputError(
        f"'{path}' was not made by this version of sin3dm-lite ({why}); "
        + (
            "fit the model again with `sin3dm-lite fit MESH --out DIR`"
            if what == "model"
            else "delete it to restart that stage, or fit again into a new run folder"
        )
    )


def load_checkpoint(path: Path, what: str = "checkpoint") -> dict:
    """``torch.load`` with ``weights_only=True``: checkpoints hold tensors and plain containers only.

    A file that is truncated, not a checkpoint, holds code (a pickle of
    arbitrary objects) or is not a dictionary gives a :class:`Sin3DMInputError`
    naming the file; it is never unpickled with code.
    """
    import pickle
    import zipfile

    try:
        b = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:  # weights_only refused an object: the file holds more than tensors
        raise not_ours(path, what, "it holds Python objects other than tensors, which are not loaded") from None
    except (RuntimeError, EOFError, ValueError, zipfile.BadZipFile, OSError, UnicodeDecodeError, AttributeError) as e:
        raise not_ours(
            path,
            what,
            "it is truncated or not a PyTorch checkpoint"
            + (f": {e.strerror}" if isinstance(e, OSError) and e.strerror else ""),
        ) from None
    if not isinstance(b, dict):
        raise not_ours(path, what, f"it holds a {type(b).__name__}, not a dictionary")
    return b


def load_trainer_checkpoint(path: Path, kind: str) -> dict:
    """:func:`load_checkpoint` of a trainer checkpoint (``autoencoder.pt`` / ``diffusion.pt``) of this layout.

    One of an older version, or of the other trainer, gives the one-line "not made by this version" error.
    """
    b = load_checkpoint(path, kind)
    why = checkpoint_problem(b, kind)
    if why is not None:
        raise not_ours(path, kind, why)
    return b


def resume_trainer(trainer, path: Path) -> None:
    """Load the checkpoint ``path`` into ``trainer`` (one of its kind; a mismatch names the file)."""
    label = trainer.kind
    state = load_trainer_checkpoint(path, label)
    try:
        trainer.load_state_dict(state)
    except KeyError as e:
        raise not_ours(path, label, f"the entry {e} is missing") from None
    except (RuntimeError, ValueError, TypeError, AttributeError, IndexError) as e:
        raise not_ours(path, label, f"its contents do not match ({type(e).__name__})") from None


def save_trainer(trainer, path: Path) -> None:
    """Write ``trainer``'s checkpoint to ``path`` (atomically)."""
    atomic_torch_save(trainer.state_dict(), path)


def write_model(model, run: Path, also: dict[str, str] | None = None) -> Path:
    """Write ``model.pt`` (:func:`model_bundle`), ``config.json`` and the text files ``also`` (``{name: text}``)
    into the folder ``run``, all or none (:func:`files.atomic_paths`); returns ``model.pt``."""
    run.mkdir(parents=True, exist_ok=True)
    texts = {"config.json": model.config.to_json(), **(also or {})}
    with atomic_paths(run, [MODEL_FILE, *texts]) as tmp:
        save_torch(model_bundle(model), tmp[MODEL_FILE])
        for name, text in texts.items():
            write_data(tmp[name], text)
    return run / MODEL_FILE


def model_bundle(model) -> dict:
    """What ``model.pt`` holds for a fitted ``model`` (a :class:`~sin3dm_lite.pipeline.Sin3DM`): tensors on the CPU,
    config and report as JSON."""
    return {
        "format": MODEL_FORMAT,
        "config": model.config.to_json(),
        "decoder": {k: v.cpu() for k, v in model.decoder.state_dict().items()},
        "latent": model.latent.state_dict(),
        "denoiser": {k: v.cpu() for k, v in model.denoiser.state_dict().items()},
        "aabb": torch.from_numpy(model.aabb.copy()),
        "center": torch.from_numpy(np.asarray(model.normalization.center, np.float64)),
        "scale": float(model.normalization.scale),
        "color_channels": int(model.decoder.color_channels),
        "report": json.dumps(model.report),
    }


def read_model(path: Path) -> tuple:
    """The parts of the model ``model.pt`` at ``path`` holds, in the order ``Sin3DM(...)`` takes them:
    ``(config, decoder, latent, denoiser, aabb, normalization, report)``."""
    from .model.unet import TriplaneUNet

    b = load_checkpoint(path, "model")
    fmt = b.get("format")
    if fmt != MODEL_FORMAT:
        raise not_ours(path, "model", f"its format is {fmt!r}, not '{MODEL_FORMAT}'" if fmt else "it has no format tag")
    try:
        cfg = Config.from_dict(json.loads(b["config"]))
        latent = Triplane.from_state_dict(b["latent"])
        decoder = TriplaneDecoder(cfg.autoencoder, float(b["decoder"]["threshold"]), int(b["color_channels"]))
        decoder.load_state_dict(b["decoder"])
        denoiser = TriplaneUNet(latent.channels, cfg.diffusion)
        denoiser.load_state_dict(b["denoiser"])
        norm = Normalization(center=b["center"].numpy(), scale=float(b["scale"]))
        aabb, report = b["aabb"].numpy(), json.loads(b["report"])
    except KeyError as e:
        raise not_ours(path, "model", f"the entry {e} is missing") from None
    except Exception as e:  # noqa: BLE001 - wrong shapes, types or JSON: one clear message
        raise not_ours(path, "model", f"its contents do not match ({type(e).__name__})") from None
    return cfg, decoder, latent, denoiser, aabb, norm, report

"""The files torch writes in a run folder: trainer checkpoints and ``model.pt``, written atomically, read safely.

Every file is read with ``weights_only=True`` (tensors and plain containers, never code); one that is damaged,
foreign or of another version gives a one-line :class:`Sin3DMInputError` that names it.
"""

from __future__ import annotations

import json
import pickle
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from ..errors import Sin3DMInputError
from ..files import atomic_path, atomic_paths, save_torch, write_data
from ..files.inputs import check_regular, what_text_is
from ..model.training import checkpoint_problem
from .model_file import model_parts
from .pretrained import MODEL_FILE

MODEL_FORMAT = "sin3dm-lite/1"


def atomic_torch_save(obj, path: Path) -> None:
    """Write ``obj`` with ``torch.save`` so that ``path`` is either the old or the new file, never half of one."""
    with atomic_path(path) as tmp:
        save_torch(obj, tmp)  # a full disk: OSError(ENOSPC), not torch's "unexpected pos" RuntimeError


def not_ours(path: Path, what: str, why: str) -> Sin3DMInputError:
    """The error for a file ``path`` (a ``what``: "model" or a trainer's kind) this version cannot read."""
    fix = (
        "fit the model again with `sin3dm-lite fit MESH --out DIR`"
        if what == "model"
        else "delete it to restart that stage, or fit again into a new run folder"
    )
    return Sin3DMInputError(f"'{path}' was not made by this version of sin3dm-lite ({why}); {fix}")


def load_checkpoint(path: Path, what: str = "checkpoint") -> dict:
    """The dictionary the checkpoint ``path`` holds, loaded with ``weights_only=True``; anything else: one error."""
    check_regular(path, "a checkpoint")
    try:
        with open(path, "rb") as f:
            head = f.read(1024)
    except OSError as e:
        raise not_ours(path, what, f"it cannot be read: {e.strerror or e}") from None
    if (text := what_text_is(head)) is not None:
        raise Sin3DMInputError(f"'{path}' is {text}")
    if not head.startswith((b"PK\x03\x04", b"\x80")):  # torch's zip format, or its older pickle format
        why = "it is empty" if not head else "it is text" if _is_text(head) else "it is not a PyTorch checkpoint"
        raise not_ours(path, what, why)
    try:
        b = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:  # weights_only refused an object: the file holds more than tensors
        raise not_ours(path, what, "it holds Python objects other than tensors, which are not loaded") from None
    except MemoryError:
        raise not_ours(path, what, "it declares more data than fits in memory") from None
    except Exception as e:  # noqa: BLE001 - truncated, damaged or crafted: torch fails in many ways
        raise not_ours(
            path,
            what,
            "it is truncated or not a PyTorch checkpoint"
            + (f": {e.strerror}" if isinstance(e, OSError) and e.strerror else ""),
        ) from None
    if not isinstance(b, dict):
        raise not_ours(path, what, f"it holds a {type(b).__name__}, not a dictionary")
    return b


def _is_text(head: bytes) -> bool:
    """Whether ``head`` (a file's first bytes) looks like text: no control characters but tabs and line ends."""
    return not any(c < 32 and c not in b"\t\r\n" or c == 127 for c in head)


def load_trainer_checkpoint(path: Path, kind: str) -> dict:
    """:func:`load_checkpoint` of a ``kind`` trainer's checkpoint of this version's layout."""
    b = load_checkpoint(path, kind)
    if (why := checkpoint_problem(b, kind)) is not None:
        raise not_ours(path, kind, why)
    return b


def resume_trainer(trainer, path: Path) -> None:
    """Load the checkpoint ``path`` into ``trainer`` (one of its kind; a mismatch names the file)."""
    kind = trainer.kind
    state = load_trainer_checkpoint(path, kind)
    check_trainer_state(path, kind, trainer.cfg, state)
    try:
        trainer.load_state_dict(state)
    except KeyError as e:
        raise not_ours(path, kind, f"the entry {e} is missing") from None
    except (RuntimeError, ValueError, TypeError, AttributeError, IndexError) as e:
        raise not_ours(path, kind, f"its contents do not match ({type(e).__name__})") from None


def check_trainer_state(path: Path, label: str, cfg, state: dict) -> None:
    """Refuse a trainer checkpoint whose step is past ``cfg.steps`` or whose settings differ from ``cfg``'s."""
    steps = cfg.steps
    step = state.get("step")
    if not isinstance(step, int) or isinstance(step, bool) or not 0 <= step <= steps:
        raise not_ours(path, label, f"its step {step!r} is not a whole number from 0 to the config's {steps:,}")
    stored, now = state.get("config"), asdict(cfg)
    if not isinstance(stored, dict):
        raise not_ours(path, label, "it records no settings")
    differ = [k for k in now if k in stored and k not in ("precision", "compile") and stored[k] != now[k]]
    if differ:
        shown = "; ".join(f"{label}.{k} {stored[k]!r} there, {now[k]!r} in config.json" for k in differ[:3])
        raise Sin3DMInputError(
            f"cannot resume: '{path}' was trained with other settings than the run's config.json ({shown}); put "
            f"back the settings it was trained with, or delete it to train the {label} again from its first step"
        )


def save_trainer(trainer, path: Path) -> None:
    """Write ``trainer``'s checkpoint to ``path`` (atomically)."""
    atomic_torch_save(trainer.state_dict(), path)


def write_model(model, run: Path, also: dict[str, str] | None = None) -> Path:
    """Write ``model.pt``, ``config.json`` and the texts ``also`` (``{name: text}``) into ``run``, all or none."""
    run.mkdir(parents=True, exist_ok=True)
    texts = {"config.json": model.config.to_json(), **(also or {})}
    with atomic_paths(run, [MODEL_FILE, *texts]) as tmp:
        save_torch(model_bundle(model), tmp[MODEL_FILE])
        for name, text in texts.items():
            write_data(tmp[name], text)
    return run / MODEL_FILE


def model_bundle(model) -> dict:
    """What ``model.pt`` holds for a fitted ``model``: tensors on the CPU, config and report as JSON."""
    return {
        "format": MODEL_FORMAT,
        "config": model.config.to_json(),
        "decoder": {k: v.cpu() for k, v in model.decoder.state_dict().items()},
        "latent": model.latent.state_dict(),
        "denoiser": {k: v.cpu() for k, v in model.denoiser.state_dict().items()},
        "aabb": torch.from_numpy(model.aabb.copy()),
        "center": torch.from_numpy(np.asarray(model.normalization.center, np.float64)),
        "scale": float(model.normalization.scale),
        "rotation": torch.from_numpy(np.asarray(model.normalization.rotation, np.float64)),
        "color_channels": int(model.decoder.color_channels),
        "report": json.dumps(model.report),
    }


def read_model(path: Path) -> tuple:
    """The parts of the ``model.pt`` at ``path``, every field checked, in the order ``Sin3DM(...)`` takes them."""
    b = load_checkpoint(path, "model")
    fmt = b.get("format")
    if fmt != MODEL_FORMAT:
        raise not_ours(path, "model", f"its format is {fmt!r}, not '{MODEL_FORMAT}'" if fmt else "it has no format tag")
    return model_parts(path, b)

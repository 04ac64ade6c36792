"""Pick the compute device in one place (CPU by default, CUDA when present), and count parameters."""
from __future__ import annotations

import torch


def get_device(device: str | torch.device | None = None) -> torch.device:
    """Return ``device`` as a ``torch.device``; ``None`` or ``"auto"`` means CUDA if available, else CPU."""
    if device is None or device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    from .errors import Sin3DMInputError

    if isinstance(device, torch.device):
        dev = device
    else:
        try:
            dev = torch.device(str(device).strip().lower())
        except (RuntimeError, ValueError):
            raise Sin3DMInputError(f"unknown device '{device}'; use cpu or cuda (or cuda:N for the N-th GPU)") from None
    if dev.type not in ("cpu", "cuda"):
        raise Sin3DMInputError(f"device '{device}' is not supported; use cpu or cuda (or cuda:N for the N-th GPU)")
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise Sin3DMInputError("device 'cuda' was requested but no CUDA GPU is available; use --device cpu")
    if dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
        raise Sin3DMInputError(
            f"device '{device}' does not exist: this machine has {torch.cuda.device_count()} CUDA GPU(s); use cuda:0"
        )
    return dev


def count_parameters(module: torch.nn.Module, trainable_only: bool = False) -> int:
    """Number of scalar parameters in ``module`` (only those with ``requires_grad`` if ``trainable_only``)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad or not trainable_only)

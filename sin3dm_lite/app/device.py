"""Pick the compute device in one place (CPU by default, CUDA when present), its precision, and count parameters."""

from __future__ import annotations

import contextlib
import os
import time
from functools import cache
from pathlib import Path

import torch
from torch import nn

from ..errors import Sin3DMInputError

PRECISIONS = ("auto", "fp32", "bf16")


def get_device(device: str | torch.device | None = None) -> torch.device:
    """Return ``device`` as a ``torch.device``; ``None`` or ``"auto"`` means CUDA if available, else CPU."""
    if device is None or device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
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


#: bf16 counts as fast on a CPU when it does the autoencoder's kind of work in at most this share of fp32's time
BF16_FAST_SHARE = 0.8


@cache
def _cpu_has_bf16() -> bool:
    try:  # Linux; elsewhere stay in fp32
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return "avx512_bf16" in flags or "amx_bf16" in flags


@cache
def cpu_bf16_share() -> float | None:
    """bf16's time over fp32's for a training step of an MLP like the autoencoder's on this CPU, timed once a
    process (the CPU flag alone does not say whether bf16 is faster); None without AVX512-BF16 or AMX (emulated)."""
    if not _cpu_has_bf16():
        return None
    with torch.random.fork_rng(devices=[]):  # a seeded fit draws the same numbers whether or when this ran
        torch.manual_seed(0)
        x = torch.randn(4096, 64)
        mlp = nn.Sequential(nn.Linear(64, 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(), nn.Linear(256, 4))

    def step(bf16: bool) -> float:
        t0 = time.perf_counter()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            y = mlp(x).float().square().mean()
        y.backward()
        return time.perf_counter() - t0

    # the precisions take turns, so that another job slows both alike; two rounds warm up, the fastest counts
    rounds = [(step(True), step(False)) for _ in range(7)][2:]
    return min(b for b, _ in rounds) / min(f for _, f in rounds)


def bf16_is_fast(device: str | torch.device) -> bool:
    """Whether bfloat16 runs faster than float32 here: a CUDA GPU with bf16, or a CPU where it measures faster."""
    dev = torch.device(device)
    if dev.type == "cuda":
        return torch.cuda.is_bf16_supported()
    share = cpu_bf16_share() if dev.type == "cpu" else None
    return share is not None and share <= BF16_FAST_SHARE


def autocast(device: str | torch.device, precision: str = "auto"):
    """A context for a training step's forward pass in ``precision``: bf16 autocast (weights, optimiser and loss
    stay float32), or nothing for fp32; ``"auto"`` picks bf16 where :func:`bf16_is_fast`."""
    dev = torch.device(device)
    if resolved_precision(dev, precision) == "fp32":
        return contextlib.nullcontext()
    return torch.autocast(dev.type, dtype=torch.bfloat16)


def resolved_precision(device: str | torch.device, precision: str = "auto") -> str:
    """``"bf16"`` or ``"fp32"``: what a training step under ``precision`` runs in on ``device``."""
    if precision not in PRECISIONS:
        raise Sin3DMInputError(f"unknown precision '{precision}'; use one of {', '.join(PRECISIONS)}")
    if precision == "auto":
        return "bf16" if bf16_is_fast(torch.device(device)) else "fp32"
    return precision


def memory_available(device: str | torch.device) -> int:
    """Bytes free on ``device``: GPU memory for CUDA, available RAM otherwise (8 GiB when it cannot be read)."""
    dev = torch.device(device)
    if dev.type == "cuda":
        return int(torch.cuda.mem_get_info(dev)[0])
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 8 << 30

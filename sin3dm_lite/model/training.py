"""What the two trainers share: the step loop, the loss history, the random generator and the checkpoint.

:class:`~sin3dm_lite.model.autoencoder.AutoencoderTrainer` and
:class:`~sin3dm_lite.model.diffusion.DiffusionTrainer` are both a :class:`Trainer`:

* ``step()`` runs one optimisation step; ``run(until_step, progress, callback)``
  steps to ``until_step`` (at most ``cfg.steps``);
* ``history`` is a dict ``loss name -> list of floats``, one value per step
  (``"loss"``, the optimised total, always there);
* everything random in training comes from ``generator``, seeded with
  ``seed``; the initial weights come from ``torch.manual_seed(seed)`` inside
  ``torch.random.fork_rng``, the same on every device, the caller's global
  random state left as it was;
* ``state_dict()`` / ``load_state_dict()`` hold everything needed to resume
  exactly, as plain tensors and containers (``weights_only=True`` loads them)::

      format     TRAINER_FORMAT: checkpoints of other layouts are refused
      kind       "autoencoder" or "diffusion"
      model      the network's weights
      optimizer  scheduler  generator
      step       the number of finished steps
      history    {loss name: float64 tensor}
      config     the trainer's config as a dict
      seed

  plus each trainer's extras (the diffusion trainer's ``ema`` and ``h0``).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import torch
import torch.nn as nn
from tqdm.auto import tqdm

from ..app.device import get_device
from ..errors import Sin3DMInputError

TRAINER_FORMAT = "sin3dm-lite-trainer/2"


def cpu_copy(obj: Any) -> Any:
    """Copy of a nest of dicts / lists / tuples with every tensor detached and on the CPU."""
    if isinstance(obj, torch.Tensor):
        return obj.detach().to("cpu", copy=True)
    if isinstance(obj, dict):
        return {k: cpu_copy(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(cpu_copy(v) for v in obj)
    return obj


def checkpoint_problem(sd: dict, kind: str) -> str | None:
    """Why ``sd`` is not a ``kind`` trainer checkpoint of this layout (``None`` when it is one)."""
    fmt = sd.get("format")
    if fmt is None:
        return "it has no format tag: a checkpoint of an older version"
    if fmt != TRAINER_FORMAT:
        return f"its format is {fmt!r}, not '{TRAINER_FORMAT}'"
    if sd.get("kind") != kind:
        return f"it is a {sd.get('kind')!r} checkpoint, not a '{kind}' one"
    return None


#: PyTorch has a fused AdamW kernel for the CPU from 2.4 on: one loop over all parameters instead of a dozen small
#: ops per tensor
FUSED_CPU_ADAMW = torch.__version__ >= (2, 4)


class Trainer:
    """Base of the two trainers: subclasses set ``kind`` and ``loss_names``, build their parts and define
    :meth:`losses` (and, if they have any, :meth:`after_step`, :meth:`extra_state`, :meth:`load_extra_state`)."""

    kind: str = ""
    loss_names: tuple[str, ...] = ("loss",)

    model: nn.Module
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler

    def __init__(self, cfg, device, seed: int, generator_device: str | torch.device | None = None):
        """``generator_device``: where the training randomness is drawn (default: the training device)."""
        self.cfg, self.seed, self.device = cfg, seed, get_device(device)
        self.generator = torch.Generator(device=generator_device or self.device).manual_seed(seed)
        self.step_count = 0
        self.history: dict[str, list[float]] = {k: [] for k in self.loss_names}

    def init_model(self, build: Callable[[], nn.Module]) -> nn.Module:
        """``build()`` with the global RNG seeded from ``seed`` (restored afterwards), moved to the device."""
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.seed)
            model = build()
        return model.to(self.device)

    def adamw(self, params, **options) -> torch.optim.AdamW:
        """AdamW over ``params``, with PyTorch's fused kernel on a CPU where it has one (the same update, in one
        pass; the last bits of a fit differ from the per-tensor loop's)."""
        fused = True if self.device.type == "cpu" and FUSED_CPU_ADAMW else None
        return torch.optim.AdamW(params, fused=fused, **options)

    # ------------------------------------------------------------------ training
    def losses(self) -> dict[str, torch.Tensor]:
        """One batch's scalar losses, keyed as ``loss_names``; ``"loss"`` is the one minimised."""
        raise NotImplementedError

    def after_step(self) -> None:
        """Called after each optimiser step (the diffusion trainer updates its EMA here)."""

    def step(self) -> float:
        """One optimisation step; returns its loss."""
        self.model.train()
        losses = self.losses()
        self.optimizer.zero_grad(set_to_none=True)
        losses["loss"].backward()
        self.optimizer.step()
        self.scheduler.step()
        self.after_step()
        self.step_count += 1
        values = torch.stack([losses[k] for k in self.loss_names]).detach().tolist()  # one device sync
        for k, v in zip(self.loss_names, values):
            self.history[k].append(v)
        return self.history["loss"][-1]

    def run(
        self,
        until_step: int | None = None,
        progress: bool = True,
        callback: Callable[[Trainer], Any] | None = None,
    ) -> dict[str, list[float]]:
        """Train from ``step_count`` to ``until_step`` (default and at most ``cfg.steps``); returns ``history``.

        ``callback(self)`` runs after every step (the pipeline checkpoints there).
        """
        end = self.cfg.steps if until_step is None else min(until_step, self.cfg.steps)
        with tqdm(total=end, initial=self.step_count, desc=self.kind, disable=not progress, leave=False) as bar:
            while self.step_count < end:
                loss = self.step()
                bar.update(1)
                if self.step_count % 10 == 0 or self.step_count == end:
                    bar.set_postfix(loss=f"{loss:.4f}")
                if callback is not None:
                    callback(self)
        return self.history

    # ---------------------------------------------------------------- checkpoint
    def extra_state(self) -> dict:
        """The subclass's own top-level checkpoint entries."""
        return {}

    def load_extra_state(self, sd: dict) -> None:
        """Restore what :meth:`extra_state` saved."""

    def state_dict(self) -> dict:
        """A CPU copy of everything needed to resume exactly (plain tensors and containers only)."""
        return cpu_copy(
            {
                "format": TRAINER_FORMAT,
                "kind": self.kind,
                "model": self.model.state_dict(),
                "optimizer": self.optimizer.state_dict(),
                "scheduler": self.scheduler.state_dict(),
                "generator": self.generator.get_state(),
                "step": self.step_count,
                "history": {k: torch.tensor(v, dtype=torch.float64) for k, v in self.history.items()},
                "config": asdict(self.cfg),
                "seed": self.seed,
                **self.extra_state(),
            }
        )

    def load_state_dict(self, sd: dict) -> None:
        """Continue from a :meth:`state_dict` (of a trainer built with the same config)."""
        why = checkpoint_problem(sd, self.kind)
        if why is not None:
            raise Sin3DMInputError(f"not a {self.kind} checkpoint of this version of sin3dm-lite: {why}")
        self.model.load_state_dict(sd["model"])
        self.load_extra_state(sd)
        self.optimizer.load_state_dict(copy.deepcopy(sd["optimizer"]))  # it would alias (and then update) sd's tensors
        self.scheduler.load_state_dict(sd["scheduler"])
        self.generator.set_state(sd["generator"])
        self.step_count = int(sd["step"])
        self.history = {k: [float(x) for x in v.tolist()] for k, v in sd["history"].items()}


__all__ = ["FUSED_CPU_ADAMW", "TRAINER_FORMAT", "Trainer", "checkpoint_problem", "cpu_copy"]

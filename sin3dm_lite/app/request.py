"""What a sample run asks for, and the one place its defaults come from.

A setting left at ``None`` takes the model's (:class:`~sin3dm_lite.data.config.SamplingConfig`);
``Sin3DM.sample``, ``Sin3DM.to_mesh``, the mass sampler and the CLI all ask :meth:`SampleRequest.resolve`, so the
same request gets the same settings from any of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..data.config import SamplingConfig
from ..errors import Sin3DMInputError
from .threads import export_workers

DEFAULT_BATCH = 8  # latents per denoiser call in a mass run, fewer when memory is short


@dataclass(frozen=True)
class Resolved:
    """The settings a request gets on one model: its own where it has them, else the model's."""

    method: str
    steps: int
    diversity: float
    mesh_resolution: int
    faces: int
    texture_size: int


@dataclass
class SampleRequest:
    """What one sample run asks for: which indices and seeds, and the settings that override the model's (None: its own)."""

    n: int = 4
    start: int = 0
    seed: int = 0
    steps: int | None = None
    method: str | None = None  # "ddpm" or "ddim" (None: the model's; the CLI's --ddpm asks for "ddpm")
    diversity: float | None = None
    faces: int | None = None
    mesh_resolution: int | None = None
    texture_size: int | None = None
    no_pictures: bool = False
    overwrite: bool = False
    batch: int | None = None
    workers: int | None = None  # export processes (None: threads.export_workers(), one per core up to 4)
    control: dict = field(default_factory=lambda: {"resize": (1.0, 1.0, 1.0)})  # Sin3DM.plan's arguments

    def export_workers(self) -> int:
        """``workers``, or where it is None the machine's default."""
        return export_workers() if self.workers is None else self.workers

    def resolve(self, sampling: SamplingConfig, controlled: bool = False) -> Resolved:
        """The settings this request gets from a model with ``sampling``; ``controlled``: the plan keeps part of a
        known latent, so the default diversity is 1 (regenerated from pure noise, as in the paper)."""

        def own(value, default):  # None: the model's; 0 is a value (refused by the checks), not "the default"
            return default if value is None else value

        s = sampling
        return Resolved(
            method=own(self.method, s.method),
            steps=own(self.steps, s.steps),
            diversity=own(self.diversity, 1.0 if controlled else s.diversity),
            mesh_resolution=own(self.mesh_resolution, s.mesh_resolution),
            faces=own(self.faces, s.faces),
            texture_size=own(self.texture_size, s.texture_size),
        )

    def batch_size(self, limit: int) -> int:
        """Latents per denoiser call: ``batch`` (refused over ``limit``), or at most DEFAULT_BATCH, ``n`` and ``limit``."""
        if self.batch is not None and self.batch > limit:
            raise Sin3DMInputError(
                f"--batch {self.batch} is more samples than fit in memory at once here (at most "
                f"{limit} with this model and size); ask for a smaller --batch"
            )
        return self.batch if self.batch is not None else min(DEFAULT_BATCH, self.n, limit)

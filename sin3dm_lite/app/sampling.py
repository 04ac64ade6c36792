"""Sampling a fitted model: what to sample (a control plan), how many fit in memory, new triplanes, meshes.

The work behind ``Sin3DM.plan``, ``max_samples``, ``sample`` and ``to_mesh``; settings left at ``None`` take the
model's (:meth:`~sin3dm_lite.app.request.SampleRequest.resolve`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..data.box import grid_shape
from ..data.config import LIMITS, check_setting
from ..errors import Sin3DMInputError
from ..model.schedule import sampling_timesteps, start_step
from ..model.triplane import Triplane
from . import values
from .request import SampleRequest

MAX_SAMPLES = 10_000  # per call, whatever the memory
# what one mesh export holds at its peak (SDF grid, marching cubes, atlas, baked maps), per voxel and per texel
EXPORT_BYTES_PER_VOXEL = 96
EXPORT_BYTES_PER_TEXEL = 256


@dataclass
class Samples:
    """Generated triplanes and the box they live in (normalised coordinates; a retargeted sample's box is scaled
    like its latent, so voxels keep their size), with the denoising steps when they were asked for."""

    triplane: Triplane
    aabb: np.ndarray
    intermediates: list | None = None
    plan: Any = None  # the control.Plan that was sampled

    def __len__(self) -> int:
        return self.triplane.batch


def plan_for(
    model, resize=(1.0, 1.0, 1.0), outpaint=None, anchor: str = "center", regenerate=None, duplicate=None, plan=None
):
    """The :class:`control.Plan` that ``model.sample`` carries out for these arguments (checked: one clear error)."""
    from ..generate import control

    resized = np.any(np.array(values.factors(resize, "resize")) != 1.0)
    controls = dict(resize=resized or None, outpaint=outpaint, regenerate=regenerate, duplicate=duplicate, plan=plan)
    asked = [k for k, v in controls.items() if v is not None]
    if len(asked) > 1:
        raise Sin3DMInputError(f"one control at a time: got {' and '.join(asked)}")
    if plan is not None:
        return plan
    # the margin of empty voxels around the shape (half as many texels) and the shape's cut face: not kept where
    # the shape grows out of (outpaint) or is copied away from (duplicate) a face of the model's box
    trim = int(np.ceil(model.config.grid.margin_voxels / 2)) + 1
    if outpaint is not None:
        return control.outpaint(model.latent, model.aabb, outpaint, anchor, trim=trim)
    if regenerate is not None:
        return control.regenerate(model.latent, model.aabb, regenerate)
    if duplicate is not None:
        try:
            box, to = duplicate
        except (TypeError, ValueError):
            raise Sin3DMInputError("duplicate takes (box, to): ((x0, y0, z0), (x1, y1, z1)) and (tx, ty, tz)") from None
        return control.duplicate(model.latent, model.aabb, box, to, trim=trim)
    return control.retarget(model.latent, model.aabb, resize)


def max_samples(model, resize=(1.0, 1.0, 1.0)) -> int:
    """How many samples one ``model.sample`` call can hold: about 16 feature maps of the denoiser's widest layer
    per sample in half the device's free memory (at most :data:`MAX_SAMPLES`)."""
    from .device import memory_available

    factors = np.array(values.factors(resize, "resize"))
    x, y, z = np.maximum(4, np.round(np.array(model.latent.resolution) * factors))
    width = max(int(model.config.diffusion.base_channels), int(model.latent.channels)) * 2
    per_sample = 16 * (x * y + x * z + y * z) * width * 4
    return int(max(1, min(MAX_SAMPLES, 0.5 * memory_available(model.device) // per_sample)))


def draw(
    model,
    n: int,
    plan,
    steps=None,
    method=None,
    seed=0,
    return_intermediates=None,
    known=None,
    mask=None,
    progress: bool = True,
    diversity=None,
) -> Samples:
    """``model.sample``: ``n`` new triplanes for ``plan`` (:func:`plan_for`), at most :func:`max_samples`."""
    from ..model.diffusion import sample as diffusion_sample

    seed = check_sample_args(model, n, steps, method, seed, diversity)
    if plan.known is not None and known is not None:
        raise Sin3DMInputError(f"{plan.kind} chooses what to keep itself; do not pass known/mask with it")
    known, mask = (plan.known, plan.mask) if plan.known is not None else (known, mask)
    factors = np.array(plan.resolution) / np.array(model.latent.resolution)
    limit = max_samples(model, factors)
    if n > limit:
        raise Sin3DMInputError(
            f"{n} samples do not fit in memory at once here (at most {limit} with "
            "this model and size); draw them in several calls with other seeds"
        )
    r = SampleRequest(steps=steps, method=method, diversity=diversity).resolve(
        model.config.sampling, controlled=plan.known is not None
    )
    t0 = start_step(model.schedule, r.diversity)  # checks the value
    out = diffusion_sample(
        model.denoiser,
        model.schedule,
        plan.resolution,
        n=n,
        latent_channels=model.latent.channels,
        method=r.method,
        steps=r.steps,
        seed=seed,
        known=known,
        mask=mask,
        return_intermediates=return_intermediates,
        progress=progress,
        device=model.device,
        prediction=model.config.diffusion.prediction,
        start=plan.start if t0 < model.schedule.timesteps - 1 else None,
        diversity=r.diversity,
    )
    tp, inter = out if return_intermediates is not None else (out, None)
    return Samples(tp, plan.aabb, inter, plan)


def check_sample_args(model, n, steps, method, seed, diversity, names=None):
    """Refuse what ``model.sample`` cannot take; returns the seed (``names``: what the messages call the arguments)."""
    name = {k: k for k in ("n", "steps", "method", "seed", "diversity")} | (names or {})
    values.whole(n, name["n"])
    for key, value in (("steps", steps), ("method", method), ("diversity", diversity)):
        values.setting(f"sampling.{key}", value, name[key])
    r = SampleRequest(steps=steps, method=method).resolve(model.config.sampling)
    check_steps(model, r.method, r.steps, name["steps"])
    return values.seeds(seed, n, name["seed"])


def check_steps(model, method: str, steps: int, name: str = "steps") -> None:
    """DDIM takes 1 to the model's time steps (DDPM takes them all, whatever ``steps``)."""
    top = model.schedule.timesteps
    if method == "ddim" and not 1 <= steps <= top:
        raise Sin3DMInputError(
            f"{name} {steps} is more than this model's {top} time steps; ask for 1 to {top} DDIM steps"
        )
    sampling_timesteps(model.schedule, method, steps)


def export_bytes(resolution: int, texture_size: int, box) -> float:
    """What one export over ``box`` holds at its peak: its decode grid and its texture."""
    voxels = float(np.prod(grid_shape(np.asarray(box, np.float64), resolution)))
    return voxels * EXPORT_BYTES_PER_VOXEL + float(texture_size) ** 2 * EXPORT_BYTES_PER_TEXEL


def check_mesh_sizes(
    resolution: int,
    texture_size: int,
    box,
    parallel: int = 1,
    names: tuple[str, str] = ("mesh resolution", "texture size"),
) -> None:
    """Refuse a mesh resolution or texture size out of range or beyond memory (``parallel`` exports share half the
    free RAM) for an export over ``box``, naming the largest that fits."""
    from .device import memory_available

    keys = ("sampling.mesh_resolution", "sampling.texture_size")
    for key, value, name in zip(keys, (resolution, texture_size), names):  # a whole number, not too small
        check_setting(key, min(value, LIMITS[key][1]) if isinstance(value, int) else value, option=name)
    box = np.asarray(box, np.float64)
    ext = box[3:] - box[:3]
    share = float(np.prod(ext / ext.max()))  # voxels ≈ share · resolution³
    budget = 0.5 * memory_available("cpu") / max(1, parallel)  # the export's arrays live in RAM, whatever the device
    cap_res, cap_tex = LIMITS[keys[0]][1], LIMITS[keys[1]][1]

    def most_res(texels: float) -> int:  # the largest resolution that fits beside ``texels``
        return min(
            cap_res, int((max(budget - texels * EXPORT_BYTES_PER_TEXEL, 0) / EXPORT_BYTES_PER_VOXEL / share) ** (1 / 3))
        )

    def most_tex(voxels: float) -> int:  # the largest texture that fits beside ``voxels``
        return min(cap_tex, int((max(budget - voxels * EXPORT_BYTES_PER_VOXEL, 0) / EXPORT_BYTES_PER_TEXEL) ** 0.5))

    at_once = f", {parallel} exports at once (--workers)" if parallel > 1 else ""
    if resolution > most_res(0):  # too large even without a texture
        fits = texture_size <= most_tex(0)
        most = most_res(float(texture_size) ** 2) if fits else most_res(0)
        beside = f" and {names[1]} {texture_size}" if fits else ""
        raise Sin3DMInputError(
            f"{names[0]} {resolution} is too large: at most {most} here ({cap_res:,} anywhere; what fits in memory "
            f"with this box{beside}{at_once}); ask for a smaller one"
        )
    most = most_tex(float(np.prod(grid_shape(box, resolution))))
    if texture_size > most:
        raise Sin3DMInputError(
            f"{names[1]} {texture_size} is too large: at most {most} here ({cap_tex:,} anywhere; what fits in "
            f"memory with {names[0]} {resolution}{at_once}); ask for a smaller one"
        )


def decode(
    model,
    samples: Samples,
    index: int | None = None,
    resolution: int | None = None,
    faces: int | None = None,
    texture_size: int | None = None,
    vertex_colors: bool = False,
    original_coords: bool = True,
):
    """``model.to_mesh``: the samples (or the one at ``index``) as textured meshes."""
    from ..generate.extract import extract_mesh

    if not isinstance(samples, Samples):
        raise Sin3DMInputError(
            f"to_mesh takes the Samples that sample() returns (e.g. model.to_mesh(model.sample(2))), got {samples!r:.80}"
        )
    index = None if index is None else values.index(index, len(samples))
    for key, value, name in (
        ("mesh_resolution", resolution, "resolution"),
        ("faces", faces, "faces"),
        ("texture_size", texture_size, "texture_size"),
    ):
        values.setting(f"sampling.{key}", value, name, high=key == "faces")  # the sizes' top: check_mesh_sizes
    values.flag(vertex_colors, "vertex_colors")
    values.flag(original_coords, "original_coords")
    r = SampleRequest(mesh_resolution=resolution, faces=faces, texture_size=texture_size).resolve(model.config.sampling)
    check_mesh_sizes(r.mesh_resolution, r.texture_size, samples.aabb, names=("resolution", "texture_size"))
    items = range(len(samples)) if index is None else [index]
    meshes = []
    for i in items:
        m = extract_mesh(
            model.decoder,
            samples.triplane[i],
            samples.aabb,
            normalization=model.normalization,
            resolution=r.mesh_resolution,
            faces=r.faces,
            texture_size=r.texture_size,
            vertex_colors=vertex_colors,
            original_coords=original_coords,
        )
        m.name = f"sample_{i:03d}"
        meshes.append(m)
    return meshes if index is None else meshes[0]

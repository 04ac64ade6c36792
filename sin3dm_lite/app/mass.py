"""Many samples into one folder (``sin3dm-lite sample RUN -n N --out DIR``): written as they finish, resumable,
sharded over processes with torchrun.

This module checks the request and runs it (:func:`write_samples`); ``mass_folder`` keeps the folder and
``mass_workers`` the ranks and the export workers. The rules:

* sample ``i`` comes from the seed ``--seed + i`` alone: the same in any batch, on any number of processes;
* a sample counts as finished when its manifest line exists and all its files are there unchanged;
* the same command again continues a folder whose ``sampling.json`` holds the same settings; other settings are
  refused unless ``--overwrite``, which removes only the files ``sample`` wrote;
* every flag is checked before the folder is touched, and a run that fails before its first sample leaves nothing;
* memory is bounded by ``--batch`` and ``--workers``, not by ``-n``.
"""

from __future__ import annotations

import os
import shutil
import warnings
from pathlib import Path

from ..data.config import check_setting
from ..errors import Sin3DMInputError
from ..files import read_manifest, release_lock
from ..model.triplane import PLANE_AXES
from .mass_folder import (
    abandon,
    finish_folder,
    finished,
    folder_name,
    prepare_folder,
    read_settings,
    remove_if_empty,
    sample_output_names,
    sample_run_files,
    sample_settings,
)
from .mass_workers import Ranks, sample_many, worker_bytes, workers_memory_holds
from .request import SampleRequest
from .sampling import check_mesh_sizes, check_sample_args, export_bytes


def check_request(model, req: SampleRequest) -> None:
    """Refuse what sampling would refuse about the flags (``--steps`` out of range, ...) before the folder is touched."""
    names = {"n": "-n", "steps": "--steps", "method": "the method", "seed": "--seed", "diversity": "--diversity"}
    check_sample_args(model, req.n, req.steps, req.method, req.seed, req.diversity, names)


def check_sample_sizes(model, plan, req: SampleRequest) -> None:
    """Check ``--faces``, ``--mesh-resolution`` and ``--texture-size`` against their ranges and the memory; without
    ``--workers`` the default is lowered to what memory holds (at least one) and kept in ``req.workers``."""
    r = req.resolve(model.config.sampling)
    if req.faces is not None:
        check_setting("sampling.faces", req.faces, option="--faces")

    names = tuple(  # a value from the model's config is named as such
        f"--{flag}" if given is not None else f"sampling.{key} of the model's config (used without --{flag})"
        for flag, key, given in (
            ("mesh-resolution", "mesh_resolution", req.mesh_resolution),
            ("texture-size", "texture_size", req.texture_size),
        )
    )

    def check(parallel: int) -> None:
        check_mesh_sizes(r.mesh_resolution, r.texture_size, plan.aabb, parallel=parallel, names=names)

    workers = cap_workers(model, plan, req, r)
    if req.workers is None:  # the default: not a reason to refuse, so fewer workers where memory is short
        while workers > 1:
            try:
                check(workers)
                break
            except Sin3DMInputError:
                workers -= 1
        req.workers = workers
    check(max(1, workers))


def cap_workers(model, plan, req: SampleRequest, r) -> int:
    """The export workers asked for (``--workers``, ``SIN3DM_WORKERS`` or the default), at most as many as the
    memory holds (a warning where the user's number is lowered; where not even one fits, the exports' check refuses)."""
    workers = req.export_workers()
    one = export_bytes(r.mesh_resolution, r.texture_size, plan.aabb)
    held = workers_memory_holds(model, one)
    if workers <= 1 or workers <= held or held < 1:
        return workers
    if req.workers is not None or os.environ.get("SIN3DM_WORKERS"):
        asked = f"--workers {req.workers}" if req.workers is not None else f"SIN3DM_WORKERS={workers}"
        warnings.warn(
            f"{asked}: memory holds {held} export workers (each about {worker_bytes(model) / 2**20:.0f} MB of its "
            f"own and {one / 2**20:.0f} MB for its export); using {held}",
            UserWarning,
            stacklevel=2,
        )
    if req.workers is not None:
        req.workers = held
    return held


#: what a sample's files take on disk: per face (OBJ and GLB), per texel of each map (two PNGs), its preview
SAMPLE_BYTES_PER_FACE = 100
SAMPLE_BYTES_PER_TEXEL = 0.75
PREVIEW_BYTES = 100_000


def sample_bytes(model, plan, req: SampleRequest) -> float:
    """About how many bytes one sample folder takes: mesh, textures (PBR's grey maps at a third), latent, preview."""
    r = req.resolve(model.config.sampling)
    maps = 1 + (1 + 2 / 3) * bool(model.config.autoencoder.pbr)
    texels = 2 * maps * float(r.texture_size) ** 2
    latent = model.latent.planes[0].element_size() * sum(
        p.shape[1] * a * b for p, (a, b) in zip(model.latent.planes, plane_sizes(plan.resolution))
    )
    pictures = 0 if req.no_pictures else PREVIEW_BYTES
    return r.faces * SAMPLE_BYTES_PER_FACE + texels * SAMPLE_BYTES_PER_TEXEL + latent + pictures


def plane_sizes(resolution) -> list[tuple[int, int]]:
    """The (rows, columns) of the three planes of a latent of ``resolution`` (x, y, z) texels."""
    return [(resolution[a], resolution[b]) for a, b in PLANE_AXES.values()]


def shown_bytes(n: float) -> str:
    """``2.8 MB``, ``364 KB``, ``72 GB``."""
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("KB", 1e3)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n:.0f} bytes"


def replaced_bytes(out: Path, req: SampleRequest) -> int:
    """What ``--overwrite`` frees before sampling: the files an earlier ``sample`` wrote into ``out``, unchanged."""
    if not (req.overwrite and out.is_dir()):
        return 0
    gone, _ = sample_run_files(out, read_manifest(out))
    return sum((out / f).stat().st_size for f in gone)


def check_disk(model, out: Path, req: SampleRequest, plan, label: str = "sample") -> str:
    """Refuse ``-n`` samples that cannot fit on the disk of ``--out``, naming the largest ``-n`` that fits; else
    the line that says the estimate (samples already in a continued folder need no new space)."""
    base = out
    while not base.exists() and base.parent != base:
        base = base.parent
    free = shutil.disk_usage(base if base.is_dir() else base.parent).free + replaced_bytes(out, req)
    per = sample_bytes(model, plan, req)
    indices = range(req.start, req.start + req.n)
    continued = out.is_dir() and not req.overwrite and read_settings(out) is not None
    there = sum((out / folder_name(i)).is_dir() for i in indices) if continued else 0
    need = (req.n - there) * per
    if need > free:
        most = int(free // per) + there
        fix = f"at most -n {most} fits there" if most else "not one sample fits there"
        raise Sin3DMInputError(
            f"-n {req.n} needs about {shown_bytes(need)} on disk ({shown_bytes(per)} a sample with these "
            f"settings) but '{base}' has {shown_bytes(free)} free: {fix}; free space, ask for fewer, or choose "
            "another --out"
        )
    return (
        f"[{label}] about {shown_bytes(per)} a sample on disk, {shown_bytes(need)} for the {req.n - there} to "
        f"write ({shown_bytes(free)} free)"
    )


def write_samples(model, out: Path, req: SampleRequest, label: str = "sample", ranks=None, run: str = "") -> dict:
    """Sample ``req.n`` shapes from index ``req.start`` into ``out``, each written as it finishes; returns
    ``{"pending", "new", "total", "seconds"}``."""
    ranks = ranks or Ranks()
    out = Path(out)
    plan = model.plan(**req.control)  # a bad box fails here, before anything is written
    limit = model.max_samples(tuple(r / b for r, b in zip(plan.resolution, model.latent.resolution)))
    req.batch = req.batch_size(limit)
    check_request(model, req)  # every flag checked before the folder is touched
    check_sample_sizes(model, plan, req)
    settings = sample_settings(model, plan, req, req.control)
    why, pending, disk = None, None, None
    created = not out.exists()
    if ranks.rank == 0:
        try:
            disk = check_disk(model, out, req, plan, label)  # before the folder is touched
            pending = prepare_folder(out, req, settings, run, lambda o: sample_output_names(o, req))
        except Sin3DMInputError as e:
            why = str(e)
    why, pending = ranks.from_rank0((why, pending))
    if why is not None:
        if ranks.rank == 0:
            raise Sin3DMInputError(why)
        raise SystemExit(2)  # rank 0 says why
    try:
        if ranks.rank == 0:
            print(disk, flush=True)
        if ranks.rank == 0 and len(pending) < req.n:
            print(
                f"[{label}] {out}: {req.n - len(pending)} of the {req.n} samples are there already; "
                f"sampling the other {len(pending)}"
            )
        stats = sample_many(model, out, req, ranks, plan, pending, label)
        ranks.barrier()
        total = len(finish_folder(model, out, req, plan, label)) if ranks.rank == 0 else None
    except BaseException as e:
        if ranks.rank == 0 and ranks.world == 1 and abandon(out):  # nothing finished: leave nothing that blocks a rerun
            release_lock(out)
            remove_if_empty(out, created)  # files not ours, or temporaries of a killed worker: kept
        if isinstance(e, KeyboardInterrupt) and ranks.rank == 0:  # Ctrl-C or SIGTERM: say what stays, and how on
            raise type(e)(interrupted(out)) from None
        raise
    finally:
        if ranks.rank == 0:
            release_lock(out)
    return {"pending": len(pending), "total": total, **stats}


def interrupted(out: Path) -> str:
    """What an interrupted sample run leaves, in one line."""
    kept = len(finished(out)) if out.is_dir() else 0
    if not kept:
        return f"no sample was finished, nothing of this run is left in '{out}'"
    return f"the {kept} finished samples in '{out}' are kept; run the same command again to continue"


__all__ = ["SampleRequest", "write_samples", "check_request", "check_sample_sizes"]

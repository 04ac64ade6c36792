"""Many samples into one folder: written as they finish, resumable, sharded over processes with torchrun.

    sin3dm-lite sample RUN -n 1000 --out DIR                    one process; the same command again continues
    torchrun --nproc_per_node=2 -m sin3dm_lite.cli sample RUN -n 1000 --out DIR    two processes

This module holds the request (:class:`SampleRequest`) and the run (:func:`write_samples`);
``mass_folder`` the folder (prepared, continued, finished) and ``mass_workers`` the ranks and
the export workers.

The folder, as it fills::

    DIR/sampling.json     the settings all samples here share (model checksum, control, steps, seed base, sizes)
    DIR/NNN/              one folder per sample, appearing whole: mesh.obj/.mtl/.png, mesh.glb,
                          latent.pt (the triplane: decode or edit it again), preview.png
    DIR/.sin3dm-manifest-rank<r>.jsonl   while running: one line per finished sample of rank r (index, seed,
                          folder, files with size, time and SHA-256, faces, seconds, time), appended and flushed
    DIR/samples.jsonl     at the end: those lines of all ranks, sorted by index (rank 0 merges them)
    DIR/index.html        a 3D gallery of the first samples; contact_sheet.png: the input beside them

Rules:

* Sample ``i`` comes from the seed ``--seed + i`` alone (see :class:`diffusion.SampleNoise`),
  so ``--start i -n 1`` draws it again, in any batch, on any number of processes.
* A sample's line is appended before its folder is moved into place: a sample counts as
  finished when its line exists and all its files are there unchanged; anything else is redone.
* Rerunning into a folder whose ``sampling.json`` holds the same settings continues it
  (``-n`` and ``--start`` may differ: the folder grows); other settings are refused unless
  ``--overwrite``, which first removes every file ``sample`` wrote there (other files stay,
  those of other sin3dm-lite commands too), or unless no sample there finished yet.
* Every flag is checked before the folder is touched; a run that fails before its first
  sample finished removes what it wrote (:func:`mass_folder.abandon`), so the folder blocks nothing.
* Under torchrun (``RANK``/``WORLD_SIZE``/``LOCAL_RANK`` set) rank 0 checks and prepares the
  folder and lists the missing indices; rank ``r`` takes every ``world``-th of them; rank 0
  merges at the end. gloo on CPU, nccl on CUDA (``cuda:LOCAL_RANK``).
* Memory is bounded by ``--batch`` (latents per denoiser call) and ``--workers`` (processes
  decoding, texturing and exporting meshes while the next batch is sampled), not by ``-n``.
"""

from __future__ import annotations

from pathlib import Path

from .data.config import check_setting
from .errors import Sin3DMInputError
from .files import release_lock
from .mass_folder import abandon, finish_folder, prepare_folder, remove_if_empty, sample_output_names, sample_settings
from .mass_workers import Ranks, sample_many
from .request import SampleRequest  # what a run asks for, and its defaults


def check_request(model, req: SampleRequest) -> None:
    """Refuse what sampling would refuse about the flags (``--steps`` out of range, ...) before the folder is touched."""
    from .sampling import check_sample_args

    names = {"n": "-n", "steps": "--steps", "method": "the method", "seed": "--seed", "diversity": "--diversity"}
    check_sample_args(
        model, req.n, req.steps, req.method, req.seed, req.diversity, req.snap, names | {"snap": "--snap"}
    )


def check_sample_sizes(model, plan, req: SampleRequest) -> None:
    """``--faces``, ``--mesh-resolution`` and ``--texture-size`` against their ranges and the memory
    (``--workers`` exports at once), before any folder is made. Without ``--workers`` the default (one
    per core) is lowered to as many exports as memory holds, at least one, and kept in ``req.workers``."""
    r = req.resolve(model.config.sampling)  # --steps: mass.check_request
    if req.faces is not None:
        check_setting("sampling.faces", req.faces, option="--faces")

    def check(parallel: int) -> None:
        model.check_mesh_sizes(
            r.mesh_resolution,
            r.texture_size,
            plan.aabb,
            parallel=parallel,
            names=("--mesh-resolution", "--texture-size"),
        )

    workers = req.export_workers()
    if req.workers is None:  # the default: not a reason to refuse, so fewer workers where memory is short
        while workers > 1:
            try:
                check(workers)
                break
            except Sin3DMInputError:
                workers -= 1
        req.workers = workers
    check(max(1, workers))


def write_samples(model, out: Path, req: SampleRequest, label: str = "sample", ranks=None, run: str = "") -> dict:
    """Sample ``req.n`` shapes from index ``req.start`` into ``out``, each written as it finishes.

    Rank 0 checks and prepares the folder (continue, or start over with
    ``--overwrite``) and lists the missing indices; every rank samples its
    share in batches of ``--batch`` while ``--workers`` processes decode,
    texture and export; rank 0 then writes ``samples.jsonl``, ``index.html``,
    ``contact_sheet.png`` and the manifest. Returns ``{"pending", "new", "total", "seconds"}``.
    """
    ranks = ranks or Ranks()
    out = Path(out)
    plan = model.plan(**req.control)  # a bad box fails here, before anything is written
    limit = model.max_samples(tuple(r / b for r, b in zip(plan.resolution, model.latent.resolution)))
    req.batch = req.batch_size(limit)
    check_request(model, req)  # every flag checked before the folder is touched
    check_sample_sizes(model, plan, req)
    settings = sample_settings(model, plan, req, req.control)
    why, pending = None, None
    created = not out.exists()
    if ranks.rank == 0:
        try:
            pending = prepare_folder(out, req, settings, run, lambda o: sample_output_names(o, req))
        except Sin3DMInputError as e:
            why = str(e)
    why, pending = ranks.from_rank0((why, pending))
    if why is not None:
        if ranks.rank == 0:
            raise Sin3DMInputError(why)
        raise SystemExit(2)  # rank 0 says why
    try:
        if ranks.rank == 0 and len(pending) < req.n:
            print(
                f"[{label}] {out}: {req.n - len(pending)} of the {req.n} samples are there already; "
                f"sampling the other {len(pending)}"
            )
        stats = sample_many(model, out, req, ranks, plan, pending, label)
        ranks.barrier()
        total = len(finish_folder(model, out, req, plan, label)) if ranks.rank == 0 else None
    except BaseException:
        if ranks.rank == 0 and ranks.world == 1 and abandon(out):  # nothing finished: leave nothing that blocks a rerun
            release_lock(out)
            remove_if_empty(out, created)  # files not ours, or temporaries of a killed worker: kept
        raise
    finally:
        if ranks.rank == 0:
            release_lock(out)
    return {"pending": len(pending), "total": total, **stats}


__all__ = ["SampleRequest", "write_samples", "check_request", "check_sample_sizes"]

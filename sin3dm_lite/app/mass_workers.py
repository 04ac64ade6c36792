"""Who samples what, and who exports it: the torchrun ranks and the pool of export workers.

Each rank takes every ``world``-th of the missing indices and samples them in batches while ``--workers``
processes decode, texture and export the meshes; each finished sample is recorded, then moved into place.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import multiprocessing.process
import os
import re
import shutil
import sys
import tempfile
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from datetime import datetime
from multiprocessing import resource_sharer
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from tqdm.auto import tqdm

from ..errors import Sin3DMInputError
from ..files import (
    OWNER,
    append_manifest_part,
    confined,
    file_record,
    is_ours,
    make_temp_dir,
    owner_name,
    read_manifest,
    replacing,
    save_torch,
    writer_gone,
)
from ..formats.export import export_mesh
from ..model.triplane import Triplane
from .mass_folder import WRITER, finished, folder_name
from .sampling import Samples


# --------------------------------------------------------------------------- processes
@dataclass
class Ranks:
    """This process's place among the sampling processes (one process: rank 0 of 1)."""

    rank: int = 0
    world: int = 1
    local_rank: int = 0
    distributed: bool = False

    def barrier(self) -> None:
        if self.distributed:
            dist.barrier()

    def from_rank0(self, value):
        """``value`` of rank 0, on every rank."""
        if not self.distributed:
            return value
        box = [value]
        dist.broadcast_object_list(box, src=0)
        return box[0]


def start_ranks(device: str | None) -> tuple[Ranks, str | None]:
    """Join the torchrun group if launched by it (gloo on CPU, each rank its share of the cores; nccl on CUDA with
    ``cuda:LOCAL_RANK``); returns the ranks and this rank's device."""
    if not all(k in os.environ for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK")):  # not launched by torchrun
        return Ranks(), device
    local = int(os.environ["LOCAL_RANK"])
    cuda = torch.cuda.is_available() and (device is None or str(device).startswith("cuda"))
    if cuda:
        device = f"cuda:{local}"
        torch.cuda.set_device(local)
    else:
        device = "cpu"
        if "OMP_NUM_THREADS" not in os.environ:
            torch.set_num_threads(max(1, (os.cpu_count() or 1) // int(os.environ.get("LOCAL_WORLD_SIZE", 1))))
    if not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo")
    return Ranks(dist.get_rank(), dist.get_world_size(), local, True), device


def stop_ranks(ranks: Ranks) -> None:
    if ranks.distributed and dist.is_initialized():
        dist.destroy_process_group()


# --------------------------------------------------------------------------- one sample: decode, texture, export
_WORKER: dict = {}
#: what a started export worker holds of its own beside its model copy and its export's arrays (Python, torch, ...)
WORKER_BYTES = 384 << 20


def worker_bytes(model) -> int:
    """The memory one export worker takes before its export's arrays: :data:`WORKER_BYTES` and its model copy."""
    tensors = [*model.decoder.state_dict().values(), *model.denoiser.state_dict().values(), *model.latent.planes]
    return WORKER_BYTES + sum(t.numel() * t.element_size() for t in tensors)


def workers_memory_holds(model, one_export: float) -> int:
    """How many export workers half the free RAM holds, each its :func:`worker_bytes` and one export's bytes."""
    from .device import memory_available

    return int(0.5 * memory_available("cpu") // (worker_bytes(model) + one_export))


def exit_with_parent() -> None:
    """End this worker process as soon as the process that started it ends (a thread waits on the parent's
    sentinel): a worker waiting for its next job never learns otherwise that ``sample`` was killed."""
    parent = multiprocessing.parent_process()
    if parent is None:  # not started by multiprocessing
        return

    def wait_then_exit() -> None:
        multiprocessing.connection.wait([parent.sentinel])
        os._exit(1)

    threading.Thread(target=wait_then_exit, name="sin3dm-parent-watch", daemon=True).start()


def _worker_init(model_path: str, opts: dict) -> None:
    """A decode/export process: its own CPU copy of the model, one thread; it ends with its parent."""
    from ..pipeline import Sin3DM

    exit_with_parent()
    torch.set_num_threads(1)
    _WORKER.update(model=Sin3DM.load(model_path, device="cpu"), opts=opts)


def export_sample(tmp: str, latent: dict, aabb: np.ndarray, model=None, opts: dict | None = None) -> dict:
    """Decode one latent into a textured mesh in ``tmp`` (mesh.*, preview.png); returns ``{"faces", "no_pictures"}``."""
    model = model or _WORKER["model"]
    opts = opts or _WORKER["opts"]
    samples = Samples(Triplane.from_state_dict(latent).to(model.device), np.asarray(aabb))
    mesh = model.to_mesh(
        samples, 0, resolution=opts["mesh_resolution"], faces=opts["faces"], texture_size=opts["texture_size"]
    )
    export_mesh(mesh, Path(tmp), name="mesh")
    why = None
    if opts["pictures"] and not _WORKER.get("no_pictures"):
        from ..evaluate.render import render_hero
        from ..formats.images import png_bytes

        try:
            (Path(tmp) / "preview.png").write_bytes(png_bytes(render_hero(mesh, size=384, box=opts["box"])))
        except Sin3DMInputError as e:
            why = _WORKER["no_pictures"] = str(e)
    return {"faces": int(len(mesh.faces)), "no_pictures": why}


def install_sample(tmp: Path, dst: Path, out: Path, ours: dict | None) -> None:
    """Move the finished sample folder ``tmp`` to ``dst`` (never through a link); ``ours``: the manifest before."""
    confined(out, dst)
    if not dst.exists():
        os.rename(tmp, dst)
        return
    for item in sorted(tmp.iterdir(), key=lambda p: (p.suffix == ".obj", p.name)):  # an OBJ appears last
        rel = f"{dst.name}/{item.name}"
        if (dst / item.name).exists() and not is_ours(out, rel, ours, WRITER):
            raise Sin3DMInputError(
                f"'{dst / item.name}' was not written by `sin3dm-lite sample` and would be "
                "replaced; move it away and run again"
            )
        os.replace(item, confined(out, dst / item.name))
    shutil.rmtree(tmp, ignore_errors=True)


MP_PREFIX = "sin3dm-mp-"  # multiprocessing's temporaries of a sample run: sin3dm-mp-<pid>@<machine>-<random>


def own_mp_temps() -> Path:
    """A temporary folder for multiprocessing's sockets, named with this process's PID so that the next run removes
    one a killed run left (multiprocessing's own is removed only at a clean exit); set in its private ``_config``."""
    base = Path(tempfile.gettempdir())
    for old in base.glob(f"{MP_PREFIX}*"):
        m = re.match(f"^{MP_PREFIX}{OWNER}", old.name)
        if m and writer_gone(m) and old.is_dir() and not old.is_symlink():
            shutil.rmtree(old, ignore_errors=True)
    folder = Path(tempfile.mkdtemp(prefix=f"{MP_PREFIX}{owner_name()}-"))
    multiprocessing.process.current_process()._config["tempdir"] = str(folder)
    return folder


def drop_mp_temps(folder: Path | None) -> None:
    """After the pool is shut down: stop the sharer whose socket lies in ``folder`` and remove it."""
    if folder is None:
        return
    resource_sharer.stop()  # its socket: torch passes the latents' storage to the workers through it
    config = multiprocessing.process.current_process()._config
    if config.get("tempdir") == str(folder):
        config.pop("tempdir")
    shutil.rmtree(folder, ignore_errors=True)


# --------------------------------------------------------------------------- this rank's share of the run
def export_options(model, req, plan) -> dict:
    """What every export of the run shares: the mesh settings and one scale for every preview."""
    r = req.resolve(model.config.sampling)
    box_n = np.array([np.minimum(model.aabb[:3], plan.aabb[:3]), np.maximum(model.aabb[3:], plan.aabb[3:])])
    return {
        "mesh_resolution": r.mesh_resolution,
        "faces": r.faces,
        "texture_size": r.texture_size,
        "pictures": not req.no_pictures,
        "box": model.normalization.box_to_original(box_n),
    }


class RankExport:
    """This rank's samples on their way into ``out``, exported here or by a pool of worker processes; each lands
    (recorded, then moved into place) as it finishes."""

    def __init__(self, model, out: Path, req, ranks: Ranks, opts: dict, total: int, label: str):
        self.model, self.out, self.req, self.ranks, self.opts, self.total = model, out, req, ranks, opts, total
        self.tag = f"[{label}]" if ranks.world == 1 else f"[{label} rank {ranks.rank}]"
        self.pool, self.workers, self.mp_temps = None, 0, None
        self.temps: set[Path] = set()  # this run's temporary folders not moved into place: removed at the end
        self.futures: dict = {}  # export in a worker → (index, temporary folder, when its batch started)
        self.said: list[str] = []
        self.t0 = time.perf_counter()
        self.bar = tqdm(total=total, desc=f"{self.tag} decode, texture, export", unit="mesh", leave=False)

    def start_pool(self, workers: int) -> None:
        """Export in ``workers`` processes, each with its own CPU copy of the model (saved here once)."""
        model_tmp = make_temp_dir(self.out)
        self.temps.add(model_tmp)
        self.model.save(model_tmp)
        self.mp_temps = own_mp_temps()
        self.pool = ProcessPoolExecutor(
            workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_worker_init,
            initargs=(str(model_tmp / "model.pt"), self.opts),
        )
        self.workers = workers

    def sample_batch(self, plan, chunk: list[int]) -> None:
        """Sample the indices ``chunk`` in one denoiser call; each latent is saved, then exported."""
        req, started = self.req, time.perf_counter()
        samples = self.model.sample(
            len(chunk),
            plan=plan,
            steps=req.steps,
            method=req.method,
            seed=[req.seed + i for i in chunk],
            diversity=req.diversity,
            progress=False,
        )
        for j, i in enumerate(chunk):
            tmp = make_temp_dir(self.out)
            self.temps.add(tmp)
            latent = samples.triplane[j].clone().state_dict()  # its own storage, not the whole batch's
            aabb = torch.from_numpy(np.asarray(samples.aabb, np.float64))
            save_torch({"triplane": latent, "aabb": aabb, "index": i, "seed": req.seed + i}, tmp / "latent.pt")
            if self.pool is None:
                self.land(i, tmp, started, export_sample(str(tmp), latent, samples.aabb, self.model, self.opts))
                continue
            try:
                self.futures[self.pool.submit(export_sample, str(tmp), latent, samples.aabb)] = (i, tmp, started)
            except BrokenProcessPool:  # the worker died before this sample was handed over: the same one line
                first = min([i, *(k for k, _, _ in self.futures.values())])
                raise Sin3DMInputError(worker_died(self.out, first)) from None
            while len(self.futures) >= 2 * self.workers:  # bounded: at most 2 meshes per worker wait
                self.collect(block=True)
        if self.pool is not None:
            self.collect(block=False)

    def land(self, i: int, tmp: Path, started: float, info: dict) -> None:
        """Record sample ``i`` (its manifest part's line), then move its folder ``tmp`` into place."""
        out, name = self.out, folder_name(i)
        confined(out, out / name)  # before its record: a folder linked elsewhere meanwhile is refused
        ours = read_manifest(out) if (out / name).exists() else None  # before this record joins it
        files = {f"{name}/{k}": v for k, v in file_record(tmp, sorted(p.name for p in tmp.iterdir()), WRITER).items()}
        if ours is not None:  # files of an earlier, killed try stay ours until this one replaces them
            files = replacing(out, ours, files)
        append_manifest_part(
            out,
            f"rank{self.ranks.rank}",
            {
                "index": i,
                "seed": self.req.seed + i,
                "folder": name,
                "files": files,
                "faces": info["faces"],
                "seconds": round(time.perf_counter() - started, 3),
                "time": datetime.now().isoformat(timespec="milliseconds"),
                "rank": self.ranks.rank,
            },
        )
        install_sample(tmp, out / name, out, ours)
        self.temps.discard(tmp)
        if info["no_pictures"] and not self.said:
            self.said.append(info["no_pictures"])
            print(f"{self.tag} no pictures: {info['no_pictures']}")
        self.bar.update(1)
        tqdm.write(
            f"{self.tag} {self.bar.n}/{self.total}: {folder_name(i)} {info['faces']:,} faces  "
            f"({time.perf_counter() - self.t0:.0f} s)",
            file=sys.stdout,
        )

    def collect(self, block: bool) -> None:
        """Land the exports the workers finished (waiting for one if ``block``), in index order."""
        futures = self.futures
        done = wait(list(futures), return_when=FIRST_COMPLETED).done if block else [f for f in futures if f.done()]
        for f in sorted(done, key=lambda f: futures[f][0]):
            try:
                info = f.result()
            except BrokenProcessPool:  # the OOM killer, a kill -9: every waiting sample fails with it
                raise Sin3DMInputError(worker_died(self.out, min(i for i, _, _ in futures.values()))) from None
            self.land(*futures.pop(f), info)

    def close(self) -> None:
        """Stop the workers; remove the model copy, and unfinished samples after an error (finished ones were moved)."""
        self.bar.close()
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            drop_mp_temps(self.mp_temps)
        for tmp in self.temps:
            shutil.rmtree(tmp, ignore_errors=True)


def sample_many(model, out: Path, req, ranks: Ranks, plan, pending: list[int], label: str = "sample") -> dict:
    """Sample this rank's share of ``pending`` into ``out``; returns ``{"new", "seconds"}``."""
    mine = pending[ranks.rank :: ranks.world]
    run = RankExport(model, out, req, ranks, export_options(model, req, plan), len(mine), label)
    try:
        workers = req.export_workers()
        if workers > 0 and len(mine) > 1:
            run.start_pool(min(workers, len(mine)))
        batch = max(1, req.batch)
        for k in range(0, len(mine), batch):
            run.sample_batch(plan, mine[k : k + batch])
        while run.futures:
            run.collect(block=True)
    finally:
        run.close()
    return {"new": len(mine), "seconds": time.perf_counter() - run.t0}


def worker_died(out: Path, index: int) -> str:
    """The one-line message for an export worker that died (killed, out of memory) while exporting ``index``."""
    kept = len(finished(out))
    kept = {0: "no sample was finished yet", 1: "the finished sample is kept"}.get(
        kept, f"the {kept} finished samples are kept"
    )
    return (
        f"the export worker process died while exporting sample {folder_name(index)} to '{out}' (killed, perhaps "
        f"for lack of memory); {kept}: run the same command again to continue (it resumes), with --workers 0 "
        "to export in the sampling process if memory is short"
    )

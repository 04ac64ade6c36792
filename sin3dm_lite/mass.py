"""Many samples into one folder: written as they finish, resumable, sharded over processes with torchrun.

    sin3dm-lite sample RUN -n 1000 --out DIR                    one process; the same command again continues
    torchrun --nproc_per_node=2 -m sin3dm_lite.cli sample RUN -n 1000 --out DIR    two processes

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
  sample finished removes what it wrote (:func:`abandon`), so the folder blocks nothing.
* Under torchrun (``RANK``/``WORLD_SIZE``/``LOCAL_RANK`` set) rank 0 checks and prepares the
  folder and lists the missing indices; rank ``r`` takes every ``world``-th of them; rank 0
  merges at the end. gloo on CPU, nccl on CUDA (``cuda:LOCAL_RANK``).
* Memory is bounded by ``--batch`` (latents per denoiser call) and ``--workers`` (processes
  decoding, texturing and exporting meshes while the next batch is sampled), not by ``-n``.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np
import torch

from .data.config import check_setting
from .errors import Sin3DMInputError
from .files import (
    MANIFEST,
    acquire_lock,
    append_manifest_part,
    file_record,
    foreign_files,
    is_ours,
    make_temp_dir,
    manifest_parts,
    read_manifest,
    read_manifest_parts,
    release_lock,
    replacing,
    save_torch,
    write_manifest,
)
from .request import SampleRequest  # what a run asks for (defined beside its defaults; named here too)

SETTINGS = "sampling.json"
SAMPLES = "samples.jsonl"
MAX_RUN_SAMPLES = 1_000_000  # per run folder
GALLERY_MAX = 16  # samples shown in index.html and contact_sheet.png
SAMPLE_FILES = ("mesh", "preview.png", "latent.pt")  # names (prefixes) written into NNN/
WRITER = "sample"  # the command that owns these files in the manifest: --overwrite replaces only them



def folder_name(i: int) -> str:
    return f"{i:03d}"


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
            torch.distributed.barrier()

    def from_rank0(self, value):
        """``value`` of rank 0, on every rank."""
        if not self.distributed:
            return value
        box = [value]
        torch.distributed.broadcast_object_list(box, src=0)
        return box[0]


def launched_by_torchrun() -> bool:
    return all(k in os.environ for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK"))


def start_ranks(device: str | None) -> tuple[Ranks, str | None]:
    """Join the torchrun group if launched by it; returns the ranks and this rank's device.

    gloo on CPU, nccl on CUDA with ``cuda:LOCAL_RANK``; on CPU each rank gets its
    share of the cores unless ``OMP_NUM_THREADS`` says otherwise.
    """
    if not launched_by_torchrun():
        return Ranks(), device
    import torch.distributed as dist

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
    if ranks.distributed and torch.distributed.is_initialized():
        torch.distributed.destroy_process_group()


# --------------------------------------------------------------------------- settings and progress
def model_checksum(model) -> str:
    """SHA-256 of what a sample depends on in the model: the denoiser, the decoder and the input's latent."""
    h = hashlib.sha256()
    for part in (model.denoiser.state_dict(), model.decoder.state_dict(), model.latent.state_dict()):
        for k in sorted(part):
            h.update(k.encode())
            h.update(part[k].detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()[:16]


def sample_settings(model, plan, req: SampleRequest, control: dict) -> dict:
    """Everything a sample's content depends on besides its index (what a continued run must share)."""
    r = req.resolve(model.config.sampling, controlled=plan.known is not None)
    return json.loads(json.dumps({  # JSON types: tuples become lists, as when read back
        "model": model_checksum(model), "control": control, "method": r.method,
        "steps": r.steps, "diversity": r.diversity, "seed": req.seed,
        "mesh_resolution": r.mesh_resolution, "faces": r.faces,
        "texture_size": r.texture_size, "pictures": not req.no_pictures,
    }))


def read_settings(out: Path) -> dict | None:
    """The settings of the sample run in ``out`` (None without a ``sampling.json`` of ours)."""
    try:
        if not is_ours(out, SETTINGS, by=WRITER):
            return None
        data = json.loads((out / SETTINGS).read_text(encoding="utf-8"))
        return data["settings"] if data.get("tool") == "sin3dm-lite" else None
    except (OSError, ValueError, KeyError, AttributeError, TypeError):
        return None


def finished(out: Path) -> dict[int, dict]:
    """``{index: record}`` of the samples in ``out`` that are complete: a record and all its files, unchanged."""
    records = []
    try:
        for line in (out / SAMPLES).read_text(encoding="utf-8").splitlines() if is_ours(out, SAMPLES) else []:
            records.append(json.loads(line))
    except (OSError, ValueError):
        records = []
    records += read_manifest_parts(out)
    ours = read_manifest(out)
    done = {}
    for r in records:
        try:
            i, files = int(r["index"]), r["files"]
        except (KeyError, TypeError, ValueError):
            continue
        if files and all(is_ours(out, f, ours, WRITER) for f in files):
            done[i] = r
    return done


def check_folder(out: Path, req: SampleRequest, settings: dict, names_for) -> bool:
    """Whether ``out`` continues a sample run (True) or starts a new one; refuses what must not be touched.

    Same settings in ``sampling.json``: continue. Other settings: refused unless
    ``--overwrite``. A non-empty folder without them: refused unless ``--overwrite``.
    ``names_for(out)`` lists the files the run will write (checked for foreign ones).
    """
    from .files import check_output_folder, clash_error, present

    if out.exists() and not out.is_dir():
        raise Sin3DMInputError(f"--out '{out}' is a file; give a folder to write into")
    old = read_settings(out) if out.is_dir() else None
    if old is not None and not req.overwrite:
        content = [p.name for p in present(out) if p.name != MANIFEST and p not in manifest_parts(out)]
        if old != settings and not finished(out) and not foreign_files(out, content, WRITER):
            return False  # a run stopped before its first sample (killed): nothing there to keep, start over
        if old != settings:
            key = next(k for k in sorted(set(old) | set(settings)) if old.get(k) != settings.get(k))
            raise Sin3DMInputError(f"'{out}' holds samples with other settings ({key}: {old.get(key)} there, "
                                   f"{settings.get(key)} now); choose another --out, or pass --overwrite to replace "
                                   "them (files sin3dm-lite did not write are kept)")
        clash = foreign_files(out, names_for(out), WRITER)
        if clash:
            raise clash_error(out, clash[0], WRITER)
        return True
    check_output_folder(out, req.overwrite, names_for(out), by=WRITER)
    return False


def sample_file(rel: str) -> bool:
    """Whether ``rel`` is a name a sample run writes (how files of older versions, which did not say, are told apart)."""
    parts = Path(rel).parts
    if len(parts) == 1:
        return rel in (SETTINGS, SAMPLES, "index.html", "contact_sheet.png")
    return len(parts) == 2 and parts[0].isdigit() and parts[1].startswith(SAMPLE_FILES)


def remove_ours(out: Path) -> None:
    """Remove every file of a sample run the manifest (and its parts) lists as ours and unchanged, and folders
    left empty; files other commands wrote there (a ``render``'s pictures, an ``evaluate`` report) stay."""
    from .files import writer

    m = read_manifest(out)
    kept = {}
    for f in sorted(m, key=lambda f: -len(Path(f).parts)):
        w = writer(out, f, m)
        if w == WRITER or w == "" and sample_file(f):
            (out / f).unlink(missing_ok=True)
            for d in list(Path(f).parents)[:-1]:
                try:
                    (out / d).rmdir()
                except OSError:
                    break
        elif w is not None:
            kept[f] = m[f]
    write_manifest(out, kept)
    for part in manifest_parts(out):
        part.unlink(missing_ok=True)


def check_request(model, req: SampleRequest) -> None:
    """Refuse what sampling would refuse about the flags (``--steps`` out of range, ...) before the folder is touched."""
    from .model.diffusion import sampling_timesteps

    r = req.resolve(model.config.sampling)
    steps, top = r.steps, model.schedule.timesteps
    if r.method == "ddim" and not 1 <= steps <= top:
        raise Sin3DMInputError(f"--steps {steps} is more than this model's {top} time steps; ask for 1 to {top} "
                               "DDIM steps")
    sampling_timesteps(model.schedule, r.method, steps)


def abandon(out: Path) -> bool:
    """After a run failed before any sample finished: remove what it wrote, so that the folder blocks no
    corrected command (its ``sampling.json`` would refuse other settings). Returns whether it did."""
    if finished(out):
        return False
    remove_ours(out)
    if not read_manifest(out):
        (out / MANIFEST).unlink(missing_ok=True)
    return True


def prepare_folder(out: Path, req: SampleRequest, settings: dict, run: str, names_for) -> list[int]:
    """Rank 0: lock, check and set up ``out``; returns the indices still to sample.

    The lock comes before the checks: a check made before another writer
    filled the folder would be out of date (and remove its samples as ours).
    """
    from .files import check_writable, write_recorded

    if out.exists() and not out.is_dir():
        raise Sin3DMInputError(f"--out '{out}' is a file; give a folder to write into")
    check_writable(out)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        acquire_lock(out, "output folder")  # one writer per folder; removes temporaries a killed run left
    except BaseException:
        _remove_if_empty(out, created)
        raise
    try:
        continuing = check_folder(out, req, settings, names_for)
        if not continuing:
            remove_ours(out)
            write_recorded(out / SETTINGS, json.dumps({"tool": "sin3dm-lite", "kind": "samples", "run": run,
                                                       "settings": settings}, indent=1), by=WRITER)
        done = finished(out)
    except BaseException:
        release_lock(out)
        _remove_if_empty(out, created)
        raise
    return [i for i in range(req.start, req.start + req.n) if i not in done]


def _remove_if_empty(out: Path, created: bool) -> None:
    if created:
        try:
            out.rmdir()
        except OSError:
            pass  # something is there


# --------------------------------------------------------------------------- one sample: decode, texture, export
_WORKER: dict = {}


def _worker_init(model_path: str, opts: dict) -> None:
    """A decode/export process: its own CPU copy of the model, one thread."""
    from .pipeline import Sin3DM

    torch.set_num_threads(1)
    _WORKER.update(model=Sin3DM.load(model_path, device="cpu"), opts=opts)


def export_sample(tmp: str, latent: dict, aabb: np.ndarray, model=None, opts: dict | None = None) -> dict:
    """Decode one latent into a textured mesh in ``tmp`` (mesh.*, preview.png); returns ``{"faces", "no_pictures"}``."""
    from .data.export import export_mesh
    from .model.triplane import Triplane
    from .pipeline import Samples

    model = model or _WORKER["model"]
    opts = opts or _WORKER["opts"]
    samples = Samples(Triplane.from_state_dict(latent).to(model.device), np.asarray(aabb))
    mesh = model.to_mesh(samples, 0, resolution=opts["mesh_resolution"], faces=opts["faces"],
                         texture_size=opts["texture_size"])
    export_mesh(mesh, Path(tmp), name="mesh")
    why = None
    if opts["pictures"] and not _WORKER.get("no_pictures"):
        from .evaluate.render import render_hero
        from .show.viewer import png_bytes

        try:
            (Path(tmp) / "preview.png").write_bytes(png_bytes(render_hero(mesh, size=384, box=opts["box"])))
        except Sin3DMInputError as e:
            why = _WORKER["no_pictures"] = str(e)
    return {"faces": int(len(mesh.faces)), "no_pictures": why}


def install_sample(tmp: Path, dst: Path, out: Path, ours: dict | None) -> None:
    """Move the finished sample folder ``tmp`` to ``dst``: one rename, or file by file into an existing one.

    ``ours``: ``out``'s manifest as it was before this sample's record was
    appended (what an existing ``dst`` holds of ours, e.g. a half-written earlier try).
    """
    if not dst.exists():
        os.rename(tmp, dst)
        return
    for item in sorted(tmp.iterdir(), key=lambda p: (p.suffix == ".obj", p.name)):  # an OBJ appears last
        rel = f"{dst.name}/{item.name}"
        if (dst / item.name).exists() and not is_ours(out, rel, ours, WRITER):
            raise Sin3DMInputError(f"'{dst / item.name}' was not written by `sin3dm-lite sample` and would be "
                                   "replaced; move it away and run again")
        os.replace(item, dst / item.name)
    shutil.rmtree(tmp, ignore_errors=True)


# --------------------------------------------------------------------------- the whole run
def sample_many(model, out: Path, req: SampleRequest, ranks: Ranks, plan, pending: list[int], label: str = "sample") -> dict:
    """Sample this rank's share of ``pending`` into ``out``; returns ``{"new", "seconds"}``."""
    from tqdm.auto import tqdm

    mine = pending[ranks.rank::ranks.world]
    r = req.resolve(model.config.sampling)
    box_n = np.array([np.minimum(model.aabb[:3], plan.aabb[:3]), np.maximum(model.aabb[3:], plan.aabb[3:])])
    opts = {"mesh_resolution": r.mesh_resolution, "faces": r.faces,
            "texture_size": r.texture_size, "pictures": not req.no_pictures,
            "box": model.normalization.to_original(box_n)}  # one scale for every preview
    tag = f"[{label}]" if ranks.world == 1 else f"[{label} rank {ranks.rank}]"
    pool = None
    temps: set[Path] = set()  # this run's temporary folders not moved into place: removed at the end
    workers = req.workers if len(mine) > 1 else 0
    futures: dict = {}
    t0 = time.perf_counter()
    bar = tqdm(total=len(mine), desc=f"{tag} decode, texture, export", unit="mesh", leave=False)
    said: list[str] = []

    def land(i: int, tmp: Path, started: float, info: dict) -> None:
        name = folder_name(i)
        ours = read_manifest(out) if (out / name).exists() else None  # before this record joins it
        files = {f"{name}/{k}": v for k, v in file_record(tmp, sorted(p.name for p in tmp.iterdir()), WRITER).items()}
        if ours is not None:  # files of an earlier, killed try stay ours until this one replaces them
            files = replacing(out, ours, files)
        append_manifest_part(out, f"rank{ranks.rank}", {
            "index": i, "seed": req.seed + i, "folder": name, "files": files, "faces": info["faces"],
            "seconds": round(time.perf_counter() - started, 3), "time": datetime.now().isoformat(timespec="milliseconds"),
            "rank": ranks.rank})
        install_sample(tmp, out / name, out, ours)
        temps.discard(tmp)
        if info["no_pictures"] and not said:
            said.append(info["no_pictures"])
            print(f"{tag} no pictures: {info['no_pictures']}")
        bar.update(1)
        tqdm.write(f"{tag} {bar.n}/{len(mine)}: {folder_name(i)} {info['faces']:,} faces  "
                   f"({time.perf_counter() - t0:.0f} s)", file=sys.stdout)

    def collect(block: bool) -> None:
        done, _ = wait(list(futures), return_when=FIRST_COMPLETED) if block else (
            [f for f in futures if f.done()], None)
        for f in sorted(done, key=lambda f: futures[f][0]):
            try:
                info = f.result()
            except BrokenProcessPool:  # the OOM killer, a kill -9: every waiting sample fails with it
                raise Sin3DMInputError(worker_died(out, min(i for i, _, _ in futures.values()))) from None
            land(*futures.pop(f), info)

    try:
        if workers > 0:
            import multiprocessing

            model_tmp = make_temp_dir(out)
            temps.add(model_tmp)
            model.save(model_tmp)
            pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                       initializer=_worker_init, initargs=(str(model_tmp / "model.pt"), opts))
        batch = max(1, req.batch)
        for k in range(0, len(mine), batch):
            chunk = mine[k:k + batch]
            started = time.perf_counter()
            samples = model.sample(len(chunk), plan=plan, steps=req.steps, method=req.method,
                                   seed=[req.seed + i for i in chunk], diversity=req.diversity, progress=False)
            for j, i in enumerate(chunk):
                tmp = make_temp_dir(out)
                temps.add(tmp)
                latent = samples.triplane[j].clone().state_dict()  # its own storage, not the whole batch's
                save_torch({"triplane": latent, "aabb": torch.from_numpy(np.asarray(samples.aabb, np.float64)),
                            "index": i, "seed": req.seed + i}, tmp / "latent.pt")
                if pool is None:
                    land(i, tmp, started, export_sample(str(tmp), latent, samples.aabb, model, opts))
                    continue
                futures[pool.submit(export_sample, str(tmp), latent, samples.aabb)] = (i, tmp, started)
                while len(futures) >= 2 * workers:  # bounded: at most 2 meshes per worker wait
                    collect(block=True)
            if pool is not None:
                collect(block=False)
        while futures:
            collect(block=True)
    finally:
        bar.close()
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        for tmp in temps:  # the model copy, and unfinished samples after an error (finished ones were moved)
            shutil.rmtree(tmp, ignore_errors=True)
    return {"new": len(mine), "seconds": time.perf_counter() - t0}


def worker_died(out: Path, index: int) -> str:
    """The one-line message for an export worker that died (killed, out of memory) while exporting ``index``."""
    kept = len(finished(out))
    kept = {0: "no sample was finished yet", 1: "the finished sample is kept"}.get(kept, f"the {kept} finished samples are kept")
    return (f"the export worker process died while exporting sample {folder_name(index)} to '{out}' (killed, perhaps "
            f"for lack of memory); {kept}: run the same command again to continue (it resumes), with --workers 0 "
            "to export in the sampling process if memory is short")


def finish_folder(model, out: Path, req: SampleRequest, plan, label: str = "sample") -> dict[int, dict]:
    """Rank 0, after every rank is done: samples.jsonl, index.html, contact_sheet.png and the manifest."""
    from .data.mesh_io import load_any
    from .show.viewer import gallery, save_html

    done = finished(out)
    tmp = make_temp_dir(out)
    try:
        (tmp / SAMPLES).write_text("".join(json.dumps(done[i]) + "\n" for i in sorted(done)), encoding="utf-8")
        first = sorted(done)[:GALLERY_MAX]
        meshes = [load_any(out / folder_name(i) / "mesh.obj") for i in first]
        if meshes:
            save_html(gallery(meshes, labels=[folder_name(i) for i in first]), tmp / "index.html")
        previews = [out / folder_name(i) / "preview.png" for i in first]
        if not req.no_pictures and previews and all(p.is_file() for p in previews):
            write_contact_sheet(model, req, plan, previews, [folder_name(i) for i in first], tmp / "contact_sheet.png",
                                label)
        names = sorted(p.name for p in tmp.iterdir())
        new = file_record(tmp, names, WRITER)
        m = read_manifest(out)
        m = {f: st for f, st in m.items() if is_ours(out, f, m)}
        write_manifest(out, {**m, **replacing(out, m, new)})  # first: nothing of ours unrecorded, old or new
        for n in names:
            os.replace(tmp / n, out / n)
        write_manifest(out, {**m, **new})
        for part in manifest_parts(out):  # merged into samples.jsonl and the manifest
            part.unlink(missing_ok=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return done


def write_contact_sheet(model, req: SampleRequest, plan, previews: list[Path], labels: list[str], path: Path, label: str) -> None:
    """The input's reconstruction (rendered at the previews' scale) beside the samples' previews."""
    from PIL import Image

    from .evaluate.render import contact_sheet, render_hero
    from .show.viewer import png_bytes

    box_n = np.array([np.minimum(model.aabb[:3], plan.aabb[:3]), np.maximum(model.aabb[3:], plan.aabb[3:])])
    try:
        reference = model.to_mesh(model.input_sample(), 0, resolution=req.mesh_resolution, faces=req.faces,
                                  texture_size=req.texture_size)
        ref = render_hero(reference, size=384, box=model.normalization.to_original(box_n))
    except Sin3DMInputError as e:
        print(f"[{label}] no contact sheet: {e}")
        return
    images = [ref] + [np.asarray(Image.open(p).convert("RGB")) for p in previews]
    path.write_bytes(png_bytes(contact_sheet(images, ["input (reconstruction)"] + labels)))


__all__ = ["sample_many", "finish_folder", "prepare_folder", "start_ranks", "stop_ranks", "Ranks", "finished",
           "read_settings", "sample_settings", "model_checksum", "launched_by_torchrun"]


def check_sample_sizes(model, plan, req: SampleRequest) -> None:
    """``--faces``, ``--mesh-resolution`` and ``--texture-size`` against their ranges and the memory
    (``--workers`` exports at once), before any folder is made."""
    r = req.resolve(model.config.sampling)  # --steps: mass.check_request
    if req.faces is not None:
        check_setting("sampling.faces", req.faces, option="--faces")
    model.check_mesh_sizes(r.mesh_resolution, r.texture_size, plan.aabb,
                           parallel=max(1, req.workers), names=("--mesh-resolution", "--texture-size"))


def sample_output_names(out: Path, req: SampleRequest) -> list[str]:
    """The files a sample run into ``out`` writes where something may already be (checked for foreign files)."""
    names = ["index.html", SETTINGS, SAMPLES] + ([] if req.no_pictures else ["contact_sheet.png"])
    for d in (out.iterdir() if out.is_dir() else []):
        if d.name.isdigit() and req.start <= int(d.name) < req.start + req.n:
            names += ([f"{d.name}/{f.name}" for f in d.iterdir() if f.name.startswith(SAMPLE_FILES)]
                      if d.is_dir() else [d.name])
    return names


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
            print(f"[{label}] {out}: {req.n - len(pending)} of the {req.n} samples are there already; "
                  f"sampling the other {len(pending)}")
        stats = sample_many(model, out, req, ranks, plan, pending, label)
        ranks.barrier()
        total = len(finish_folder(model, out, req, plan, label)) if ranks.rank == 0 else None
    except BaseException:
        if ranks.rank == 0 and ranks.world == 1 and abandon(out):  # nothing finished: leave nothing that blocks a rerun
            release_lock(out)
            if created:
                try:
                    out.rmdir()
                except OSError:
                    pass  # files not ours, or temporaries of a killed worker: keep the folder
        raise
    finally:
        if ranks.rank == 0:
            release_lock(out)
    return {"pending": len(pending), "total": total, **stats}

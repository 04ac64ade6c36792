"""The folder of a sample run (``sin3dm-lite sample``): its names, its settings, which samples are finished.

Rank 0 prepares it (:func:`prepare_folder`) and finishes it (:func:`finish_folder`); a run that fails before its
first sample leaves nothing behind (:func:`abandon`). ``req`` is the run's :class:`~.request.SampleRequest`.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from contextlib import suppress
from pathlib import Path

import numpy as np

from ..errors import Sin3DMInputError
from ..files import (
    MANIFEST,
    acquire_lock,
    check_output_folder,
    check_writable,
    clash_error,
    confined,
    file_record,
    foreign_files,
    is_ours,
    make_temp_dir,
    manifest_parts,
    present,
    read_manifest,
    read_manifest_parts,
    refuse_links,
    release_lock,
    remove_files,
    replacing,
    write_manifest,
    write_recorded,
    writer,
)

SETTINGS = "sampling.json"
SAMPLES = "samples.jsonl"
MAX_RUN_SAMPLES = 1_000_000  # per run folder
GALLERY_MAX = 16  # samples shown in index.html and contact_sheet.png
SAMPLE_FILES = ("mesh", "preview.png", "latent.pt")  # names (prefixes) written into NNN/
WRITER = "sample"  # the command that owns these files in the manifest: --overwrite replaces only them


def folder_name(i: int) -> str:
    return f"{i:03d}"


def model_checksum(model) -> str:
    """SHA-256 of what a sample depends on in the model: the denoiser, the decoder and the input's latent."""
    h = hashlib.sha256()
    for part in (model.denoiser.state_dict(), model.decoder.state_dict(), model.latent.state_dict()):
        for k in sorted(part):
            h.update(k.encode())
            h.update(part[k].detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()[:16]


def sample_settings(model, plan, req, control: dict) -> dict:
    """Everything a sample's content depends on besides its index (what a continued run must share)."""
    r = req.resolve(model.config.sampling, controlled=plan.known is not None)
    settings = {
        "model": model_checksum(model),
        "control": control,
        "method": r.method,
        "steps": r.steps,
        "diversity": r.diversity,
        "seed": req.seed,
        "mesh_resolution": r.mesh_resolution,
        "faces": r.faces,
        "texture_size": r.texture_size,
        "pictures": not req.no_pictures,
    }
    return json.loads(json.dumps(settings))  # JSON types: tuples become lists, as when read back


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
    try:
        lines = (out / SAMPLES).read_text(encoding="utf-8").splitlines() if is_ours(out, SAMPLES) else []
        records = [json.loads(line) for line in lines]
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


def check_folder(out: Path, req, settings: dict, names_for) -> bool:
    """Whether ``out`` continues a sample run (the same settings) or starts a new one; refuses what must not be
    touched. ``names_for(out)`` lists the files the run will write (checked for foreign ones)."""
    if out.exists() and not out.is_dir():
        raise Sin3DMInputError(f"--out '{out}' is a file; give a folder to write into")
    refuse_links(out)  # a sample folder linked elsewhere is never written, replaced or emptied
    old = read_settings(out) if out.is_dir() else None
    if old is not None and not req.overwrite:
        content = [p.name for p in present(out) if p.name != MANIFEST and p not in manifest_parts(out)]
        if old != settings and not finished(out) and not foreign_files(out, content, WRITER):
            return False  # a run stopped before its first sample (killed): nothing there to keep, start over
        if old != settings:
            key = next(k for k in sorted(set(old) | set(settings)) if old.get(k) != settings.get(k))
            raise Sin3DMInputError(
                f"'{out}' holds samples with other settings ({key}: {old.get(key)} there, "
                f"{settings.get(key)} now); choose another --out, or pass --overwrite to replace "
                "them (files sin3dm-lite did not write are kept)"
            )
        if clash := foreign_files(out, names_for(out), WRITER):
            raise clash_error(out, clash[0], WRITER)
        return True
    check_output_folder(out, req.overwrite, names_for(out), by=WRITER)
    return False


def sample_file(rel: str) -> bool:
    """Whether ``rel`` is a name a sample run writes (for files of older versions, which did not record it)."""
    parts = Path(rel).parts
    if len(parts) == 1:
        return rel in (SETTINGS, SAMPLES, "index.html", "contact_sheet.png")
    return len(parts) == 2 and parts[0].isdigit() and parts[1].startswith(SAMPLE_FILES)


def sample_run_files(out: Path, m: dict) -> tuple[list[str], dict]:
    """Of ``out``'s manifest ``m``: the files a sample run wrote there, unchanged (what ``--overwrite`` removes),
    and the entries of other commands' files, unchanged (what stays)."""
    gone, kept = [], {}
    for f in m:
        w = writer(out, f, m)
        if w == WRITER or w == "" and sample_file(f):
            gone.append(f)
        elif w is not None:
            kept[f] = m[f]
    return gone, kept


def remove_ours(out: Path) -> None:
    """Remove every unchanged file of a sample run the manifest lists, and folders left empty; others' files stay."""
    gone, kept = sample_run_files(out, read_manifest(out))
    remove_files(out, gone)
    write_manifest(out, kept)
    for part in manifest_parts(out):
        part.unlink(missing_ok=True)


def sample_output_names(out: Path, req) -> list[str]:
    """The files a sample run into ``out`` writes where something may already be (checked for foreign files)."""
    names = ["index.html", SETTINGS, SAMPLES] + ([] if req.no_pictures else ["contact_sheet.png"])
    for d in out.iterdir() if out.is_dir() else []:
        if d.name.isdigit() and req.start <= int(d.name) < req.start + req.n:
            names += (
                [f"{d.name}/{f.name}" for f in d.iterdir() if f.name.startswith(SAMPLE_FILES)]
                if d.is_dir()
                else [d.name]
            )
    return names


def abandon(out: Path) -> bool:
    """Remove what a run wrote if no sample finished, so the folder blocks no corrected command; whether it did."""
    if finished(out):
        return False
    remove_ours(out)
    if not read_manifest(out):
        (out / MANIFEST).unlink(missing_ok=True)
    return True


def prepare_folder(out: Path, req, settings: dict, run: str, names_for) -> list[int]:
    """Rank 0: lock (first: a check before another writer filled it would be stale), check and set up ``out``;
    returns the indices still to sample."""
    if out.exists() and not out.is_dir():
        raise Sin3DMInputError(f"--out '{out}' is a file; give a folder to write into")
    check_writable(out)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        acquire_lock(out, "output folder")  # one writer per folder; removes temporaries a killed run left
    except BaseException:
        remove_if_empty(out, created)
        raise
    try:
        continuing = check_folder(out, req, settings, names_for)
        if not continuing:
            remove_ours(out)
            write_recorded(
                out / SETTINGS,
                json.dumps({"tool": "sin3dm-lite", "kind": "samples", "run": run, "settings": settings}, indent=1),
                by=WRITER,
            )
        done = finished(out)
    except BaseException:
        release_lock(out)
        remove_if_empty(out, created)
        raise
    return [i for i in range(req.start, req.start + req.n) if i not in done]


def remove_if_empty(out: Path, created: bool) -> None:
    """Remove ``out`` if this run created it and it holds nothing (files not ours, or temporaries of a killed worker: kept)."""
    if created:
        with suppress(OSError):  # something is there
            out.rmdir()


def finish_folder(model, out: Path, req, plan, label: str = "sample") -> dict[int, dict]:
    """Rank 0, after every rank is done: samples.jsonl, index.html, contact_sheet.png and the manifest."""
    from ..formats.load import load_any
    from ..show.viewer import gallery, save_html

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
            write_contact_sheet(
                model, req, plan, previews, [folder_name(i) for i in first], tmp / "contact_sheet.png", label
            )
        names = sorted(p.name for p in tmp.iterdir())
        new = file_record(tmp, names, WRITER)
        m = read_manifest(out)
        m = {f: st for f, st in m.items() if is_ours(out, f, m)}
        write_manifest(out, {**m, **replacing(out, m, new)})  # first: nothing of ours unrecorded, old or new
        for n in names:
            os.replace(tmp / n, confined(out, out / n))
        write_manifest(out, {**m, **new})
        for part in manifest_parts(out):  # merged into samples.jsonl and the manifest
            part.unlink(missing_ok=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return done


def write_contact_sheet(model, req, plan, previews: list[Path], labels: list[str], path: Path, label: str) -> None:
    """The input's reconstruction (rendered at the previews' scale) beside the samples' previews."""
    from PIL import Image

    from ..evaluate.render import contact_sheet, render_hero
    from ..formats.images import png_bytes

    box_n = np.array([np.minimum(model.aabb[:3], plan.aabb[:3]), np.maximum(model.aabb[3:], plan.aabb[3:])])
    try:
        reference = model.to_mesh(
            model.input_sample(), 0, resolution=req.mesh_resolution, faces=req.faces, texture_size=req.texture_size
        )
        ref = render_hero(reference, size=384, box=model.normalization.box_to_original(box_n))
    except Sin3DMInputError as e:
        print(f"[{label}] no contact sheet: {e}")
        return
    images = [ref] + [np.asarray(Image.open(p).convert("RGB")) for p in previews]
    path.write_bytes(png_bytes(contact_sheet(images, ["input (reconstruction)"] + labels, crop=True)))

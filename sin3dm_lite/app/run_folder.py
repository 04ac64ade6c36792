"""A fit's run folder: made in one rename, checked before a resume, cleaned up after a failed fresh fit.

It holds ``config.json``, ``input.json`` (what the fit was asked for: the input's digest and settings), the
stages' ``grid.npz``, ``autoencoder.pt`` and ``diffusion.pt`` (checkpoints), then ``model.pt``, ``losses.json`` and
``report.json``. A resume refuses another input or settings that differ from what the grid and checkpoints were
made with.
"""

from __future__ import annotations

import json
import re
from contextlib import suppress
from dataclasses import replace
from pathlib import Path

from ..data.box import grid_shape
from ..data.config import Config
from ..data.grid import load_grid
from ..errors import Sin3DMInputError
from ..files import acquire_lock, atomic_write, create_locked_folder, release_lock
from ..files.inputs import json_or_why, read_json
from ..presets import get_preset
from .checkpoints import MODEL_FILE, check_trainer_state, load_trainer_checkpoint
from .model_file import check_network_sizes, missing_settings

INPUT_FILE = "input.json"
RUN_FILES = (
    "config.json",
    INPUT_FILE,
    "grid.npz",
    "autoencoder.pt",
    "diffusion.pt",
    "diffusion_narrower.pt",
    MODEL_FILE,
    "losses.json",
    "report.json",
)


def check_run_folder(run: Path, source, resume: bool) -> None:
    """Before any stage writes: refuse a run folder the fit cannot write or, for a resume, damaged checkpoints."""
    from ..files import check_not_overlapping, check_writable, refuse_links

    if isinstance(source, (str, Path)) and Path(source).exists():
        check_not_overlapping(run, {"input mesh": Path(source)})
    if run.exists() and not run.is_dir():
        raise Sin3DMInputError(f"run folder '{run}' is a file; give a folder's name (CLI: --out DIR; Python: out=DIR)")
    check_writable(run)
    refuse_links(run)  # a fit writes and (when it fails) removes files in it: never through a link
    if resume:
        for name, kind in (
            ("autoencoder", "autoencoder"),
            ("diffusion", "diffusion"),
            ("diffusion_narrower", "diffusion"),
        ):
            if (run / f"{name}.pt").exists():
                load_trainer_checkpoint(run / f"{name}.pt", kind)
        if (run / "grid.npz").exists() or (run / "grid.npz").is_symlink():
            load_grid(run / "grid.npz", fix="delete it: the resumed fit makes it again from the mesh")


def prepare_run(
    run: Path | None, preset, resume: bool, seed: int | None, asked: dict | None = None, pbr: bool | None = None
) -> Config:
    """Resolve the config and check the run folder (new, or resumable with the same input and settings)."""
    cfg = None
    if preset is not None:
        cfg = preset if isinstance(preset, Config) else get_preset(preset)
        if seed is not None:
            cfg = cfg.updated(seed=seed)
        check_network_sizes(cfg)  # before any folder is made
    if run is None:
        if resume:
            raise Sin3DMInputError("resume needs a run folder; pass out=RUN_DIR (CLI: --out RUN_DIR)")
        return cfg
    if resume:
        return _resumed_config(run, cfg, seed, asked, pbr)
    if run.exists() and any(run.iterdir()):
        if (run / "config.json").is_file():
            raise Sin3DMInputError(
                f"run folder '{run}' is not empty: it holds a fit; continue it with --resume, or "
                "choose a new or empty --out"
            )
        raise Sin3DMInputError(
            f"--out '{run}' is not empty and holds no fit of sin3dm-lite; choose a new or empty "
            "folder for --out (nothing in it is touched)"
        )
    # the folder appears with its config and lock in one rename: a kill never leaves one that blocks the next try
    files = {"config.json": cfg.to_json()}
    if asked is not None:
        files[INPUT_FILE] = json.dumps({**asked, "config": cfg.to_dict()}, indent=2)
    create_locked_folder(run, files, option="--out")
    return cfg


def _resumed_config(
    run: Path, asked_cfg: Config | None, seed: int | None, asked: dict | None, pbr: bool | None
) -> Config:
    """The config of the run folder ``run`` to resume (checked against what is asked now), with its lock taken."""
    cfg_file = run / "config.json"
    if not cfg_file.exists():
        raise Sin3DMInputError(
            f"cannot resume: '{run}' is not a fit's run folder (it has no config.json, which a "
            "fit writes first); start a new fit into a new or empty folder (CLI: --out)"
        )
    cfg = read_run_config(cfg_file)
    check_config_matches_run(run, cfg)
    check_network_sizes(cfg)
    if asked is not None:  # another mesh or other settings would train on top of this run's checkpoints
        if asked_cfg is None and (seed is not None or pbr is not None):  # the run's own, with these changed
            asked_cfg = recorded_config(run, cfg).updated(**({} if seed is None else {"seed": seed}))
        check_same_request(run, asked, asked_cfg, pbr, cfg)
    acquire_lock(run)
    return cfg


def record_config(run: Path, cfg: Config) -> None:
    """Write ``cfg`` as the run's config.json and as the settings its input.json records (a fit that changed its own
    steps on the way, :class:`~sin3dm_lite.auto.fit_default.Budget`): a resume then checks and trains to them."""
    rec = read_input(run)
    if rec is not None:
        atomic_write(run / INPUT_FILE, json.dumps({**rec, "config": cfg.to_dict()}, indent=2))
    atomic_write(run / "config.json", cfg.to_json())


def read_input(run: Path) -> dict | None:
    """The run folder's input.json (what it was fitted to), None without one (an older run); a damaged one is refused."""
    path = run / INPUT_FILE
    if not path.exists() and not path.is_symlink():
        return None
    rec, why = json_or_why(path, "a run's record")
    if why is None and not (isinstance(rec, dict) and isinstance(rec.get("digest"), str)):
        why = "it is not a JSON object with the input's digest"
    elif why is None and "config" in rec and (gaps := missing_settings(rec["config"])):
        why = f"its config lacks the setting '{gaps[0]}'"
    if why is not None:
        raise Sin3DMInputError(
            f"cannot resume: '{path}' is damaged ({why}); it records what the fit was asked for, which a resume "
            "checks: put back the original, or fit again into a new --out"
        )
    return rec


def recorded_config(run: Path, cfg: Config) -> Config:
    """The settings a run was asked for (its input.json), else its config.json's ``cfg``."""
    rec = read_input(run)
    if not (rec and isinstance(rec.get("config"), dict)):
        return cfg
    try:
        return Config.from_dict(rec["config"])
    except (Sin3DMInputError, TypeError, ValueError, AttributeError) as e:
        raise Sin3DMInputError(
            f"cannot resume: '{run / INPUT_FILE}' records settings that are not a configuration ({e}); put back the "
            "original, or fit again into a new --out"
        ) from None


def read_run_config(cfg_file: Path) -> Config:
    """A run's config.json, whole (an emptied file would otherwise resume with the defaults) and within LIMITS."""
    d, why = json_or_why(cfg_file, "a run's config")
    if why is None and (gaps := missing_settings(d)):
        why = (
            "it is not a JSON object"
            if gaps == ["(all)"]
            else "it is an empty JSON object"
            if d == {}
            else f"it lacks the setting '{gaps[0]}'" + (f" and {len(gaps) - 1} more" if len(gaps) > 1 else "")
        )
    if why is None:
        try:
            return Config.from_dict(d)
        except Sin3DMInputError as e:  # a setting out of range
            raise Sin3DMInputError(f"cannot resume: '{cfg_file}': {e}") from None
        except (TypeError, ValueError, AttributeError) as e:
            why = f"it is not a configuration ({type(e).__name__})"
    raise Sin3DMInputError(
        f"cannot resume: '{cfg_file}' is damaged ({why}); it holds the settings this run's grid and checkpoints were "
        f"made with: put back the original ({INPUT_FILE} beside it records what the fit was asked for), or fit "
        "again into a new --out"
    )


#: the sections of a config that the grid and the trainers' checkpoints were made with
TRAINED = ("seed", "grid.", "autoencoder.", "diffusion.")


def trained_settings(cfg: Config) -> dict:
    return {k: v for k, v in cfg.settings().items() if k.startswith(TRAINED)}


def _as_trained(section, state: dict):
    """A config section as its checkpoint ``state`` can be compared with before the latent exists: a diffusion
    asked for unit variance (``latent_scale`` 0) records the number it found, compared again when it loads."""
    stored = state.get("config")
    found = stored.get("latent_scale") if isinstance(stored, dict) else None
    if getattr(section, "latent_scale", None) == 0 and isinstance(found, float) and found > 0:
        return replace(section, latent_scale=found)
    return section


def check_config_matches_run(run: Path, cfg: Config) -> None:
    """Refuse to resume ``run`` when ``cfg`` is not what input.json, the checkpoints or grid.npz were made with."""
    rec = read_input(run)
    if rec is not None and isinstance(rec.get("config"), dict):
        have, near = trained_settings(cfg), trained_settings(recorded_config(run, cfg))
        differ = [k for k in near if near[k] != have.get(k)]
        if differ:
            shown = "; ".join(f"{k} {have.get(k)!r} there, {near[k]!r} recorded" for k in differ[:3])
            more = f" and {len(differ) - 3} more" if len(differ) > 3 else ""
            raise Sin3DMInputError(
                f"cannot resume: '{run / 'config.json'}' no longer holds the settings the fit recorded in {INPUT_FILE} "
                f"({shown}{more}); its grid and checkpoints were made with those: put them back, or fit with the new "
                "settings into a new --out"
            )
    for kind in ("autoencoder", "diffusion"):  # before the autoencoder stage trains on or writes
        if (run / f"{kind}.pt").exists():
            state = load_trainer_checkpoint(run / f"{kind}.pt", kind)
            check_trainer_state(run / f"{kind}.pt", kind, _as_trained(getattr(cfg, kind), state), state)
    grid = run / "grid.npz"
    if grid.is_file():
        shape = load_grid(grid).shape
        want = max(grid_shape((2.0, 2.0, 2.0), cfg.grid.resolution, multiple=8))
        if max(shape) != want:
            raise Sin3DMInputError(
                f"cannot resume: '{run / 'config.json'}' asks for grid.resolution {cfg.grid.resolution}, but the run's "
                f"grid.npz has {max(shape)} voxels along its longest side; put back the resolution it was made with, "
                "or fit into a new --out"
            )


def check_same_request(run: Path, asked: dict, asked_cfg: Config | None, pbr: bool | None, cfg: Config) -> None:
    """Refuse to resume ``run`` with another input than it was fitted to, or other settings (one line: what differs)."""
    rec = read_input(run)
    if rec is not None:
        other_input = rec["digest"] != asked["digest"]
        was = rec.get("input", "another mesh")
    else:  # a run of an older version: its report names the input, if it got that far
        name = read_report(run).get("input")
        other_input = isinstance(name, str) and name != asked["name"]
        was = f"'{name}'"
    if other_input:
        raise Sin3DMInputError(
            f"cannot resume: '{run}' was fitted to {was}, not {asked['input']}; resume it with that input, or fit "
            f"{asked['input']} into a new --out"
        )
    if asked_cfg is None:
        return
    want, have = asked_cfg.to_dict(), recorded_config(run, cfg).to_dict()
    if pbr is not None:
        want["autoencoder"]["pbr"] = bool(pbr)
    elif not want["autoencoder"]["pbr"]:  # chosen from the mesh, which is the same
        want["autoencoder"]["pbr"] = have["autoencoder"]["pbr"]
    want, have = Config.from_dict(want).settings(), Config.from_dict(have).settings()
    if rec is None:  # an older run records only its config.json, which its switches and calibration changed
        have.update(name=have["name"].split("+")[0])
        differ = [k for k in ("name",) if want[k] != have[k]]
    else:
        differ = [k for k in want if want[k] != have.get(k)]
    if differ:
        shown = [f"{'preset' if k == 'name' else k} {have.get(k)!r} there, {want[k]!r} now" for k in differ[:3]]
        more = f" and {len(differ) - 3} more" if len(differ) > 3 else ""
        raise Sin3DMInputError(
            f"cannot resume: '{run}' was fitted with other settings ({'; '.join(shown)}{more}); resume it with its "
            "own (leave out --preset, --set, --seed and --pbr; Python: preset=None), or fit into a new --out"
        )


def read_report(run: Path) -> dict:
    """The run folder's report.json, or {} when it is missing or unreadable (it is only a record)."""
    try:
        report = read_json(run / "report.json", "a run's report")
    except (OSError, ValueError):  # a FIFO or a device is refused (Sin3DMInputError is a ValueError) unread
        return {}
    return report if isinstance(report, dict) else {}


def remove_failed_run(run: Path, existed: bool) -> None:
    """Remove what a failed fresh fit wrote into ``run`` (and the folder, if it made it); what cannot be removed
    stays, so that the user reads the fit's own error."""
    names = [run / name for name in RUN_FILES]
    with suppress(OSError):  # temporaries of atomic writes
        names += [p for p in run.iterdir() if re.match(r"^\..*\.sin3dm-\d+-[^.]*\.tmp", p.name)]
    for p in names:
        with suppress(OSError):
            p.unlink(missing_ok=True)
    release_lock(run)
    if not existed:
        with suppress(OSError):  # someone put a file there meanwhile: leave it
            run.rmdir()

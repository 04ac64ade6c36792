"""Write files safely; every name is importable from here (``from sin3dm_lite.files import atomic_write``).

* Atomically: a reader (or a crash) sees the old file or the new one, never half of one (``atomic``).
* Never over another's files: an output folder records what this tool wrote
  in a manifest (``.sin3dm-manifest.json``); only those files are ever replaced.
  A file is recorded *before* it appears, and a file of ours it replaces stays
  recorded until the move is done (:func:`recorded_path`, :func:`replacing`),
  so no kill makes our own file look foreign to the next run (``manifest``).
* Temporary files and folders carry the writer's PID in their name, so that a
  later run removes the ones a killed process left behind
  (:func:`atomic_path` for one file, :func:`atomic_folder` for several; ``atomic``).
* A long writer (``sample`` of many shapes) records as it goes in manifest
  parts (``.sin3dm-manifest-<name>.jsonl``, one JSON object with a ``files``
  entry per line, appended and flushed per item); they count as the manifest
  until the writer merges them into it at the end (:func:`append_manifest_part`).
* A folder is locked while one process writes it: an OS lock held on ``.sin3dm-lock`` (which
  names the PID) for the writer's life, see :func:`acquire_lock` (``locks``).
* Nothing is written, replaced or deleted through a symbolic link or outside the output folder
  (:func:`refuse_links` before the work, :func:`confined` at each write; ``confined``).
* Output folders are checked before the long work and filled without touching
  what is not ours (:func:`check_output_folder`, :func:`install_output`; ``outputs``).
"""

from __future__ import annotations

from .atomic import (
    NEARLY_FULL,
    OWNER,
    TEMP_PREFIX,
    atomic_folder,
    atomic_path,
    atomic_paths,
    atomic_write,
    is_temporary,
    machine_tag,
    make_temp_dir,
    named,
    owner_name,
    pid_alive,
    remove_stale_temps,
    resolved_path,
    save_torch,
    shown_path,
    write_data,
    write_failed,
    writer_gone,
)
from .confined import confined, link_error, refuse_links
from .locks import LOCK, acquire_lock, create_locked_folder, holds_lock, locked, release_lock
from .manifest import (
    MANIFEST,
    MANIFEST_PART,
    append_manifest_part,
    file_entry,
    file_record,
    is_ours,
    manifest_parts,
    read_manifest,
    read_manifest_parts,
    record_written,
    recorded_path,
    replacing,
    write_manifest,
    write_recorded,
    writer,
)
from .outputs import (
    check_not_overlapping,
    check_output_folder,
    check_writable,
    clash_error,
    foreign_files,
    install_output,
    merge_output,
    present,
    remove_files,
)

__all__ = [
    "NEARLY_FULL",
    "OWNER",
    "TEMP_PREFIX",
    "atomic_folder",
    "atomic_path",
    "atomic_paths",
    "atomic_write",
    "confined",
    "link_error",
    "refuse_links",
    "is_temporary",
    "machine_tag",
    "make_temp_dir",
    "named",
    "owner_name",
    "pid_alive",
    "remove_stale_temps",
    "resolved_path",
    "save_torch",
    "shown_path",
    "write_data",
    "write_failed",
    "writer_gone",
    "LOCK",
    "acquire_lock",
    "create_locked_folder",
    "holds_lock",
    "locked",
    "release_lock",
    "MANIFEST",
    "MANIFEST_PART",
    "append_manifest_part",
    "file_entry",
    "file_record",
    "is_ours",
    "manifest_parts",
    "read_manifest",
    "read_manifest_parts",
    "record_written",
    "recorded_path",
    "replacing",
    "write_manifest",
    "write_recorded",
    "writer",
    "check_not_overlapping",
    "check_output_folder",
    "check_writable",
    "clash_error",
    "foreign_files",
    "install_output",
    "merge_output",
    "present",
    "remove_files",
]

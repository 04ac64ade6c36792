"""Write files safely; every name is importable from here (``from sin3dm_lite.files import atomic_write``).

* ``atomic``: a reader (or a crash) sees the old file or the new one, never half of one; temporaries carry the
  writer's PID, so a later run removes those a killed process left behind.
* ``manifest``: an output folder records what this tool wrote, and only those files are ever replaced.
* ``locks``: one writer per folder, an OS lock held on ``.sin3dm-lock`` for the writer's life.
* ``confined``: nothing is written, replaced or deleted through a symbolic link or outside the output folder.
* ``outputs``: output folders checked before the long work and filled without touching what is not ours.
* ``inputs`` (import from there): the files a user hands over, checked to be regular files before they are opened.
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

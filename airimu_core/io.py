"""Atomic file output: write to a temporary file beside the target, then rename, so that nothing already
written is ever left half-written or lost."""

from __future__ import annotations

import csv
import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

TEMP_SUFFIX = ".tmp"  # temporary files are ".<target name>.<pid>.<random>.tmp" beside the target
LOCK_NAME = ".lock"  # a folder's writer lock (folder_lock)


def output_folder(folder: str | Path) -> Path:
    """Create ``folder`` (and its parents) for output; a path that is a file is an ``InputError`` naming it."""
    from airimu_core.errors import InputError

    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(f"{folder}: is a file (or lies under one); expected a folder for the output") from None
    except PermissionError:
        raise InputError(f"{folder}: no permission to create the output folder") from None
    return folder


@contextmanager
def folder_lock(folder: str | Path) -> Iterator[None]:
    """Hold ``folder``'s writer lock: ``flock`` on ``folder/.lock``, released by the OS however the holder ends (a
    killed run leaves no stale lock). A second writer gets a ``FolderBusyError`` naming the folder and the process
    that holds it. POSIX only; elsewhere nothing is locked."""
    from airimu_core.errors import FolderBusyError

    try:
        import fcntl
    except ImportError:  # not POSIX
        yield
        return
    import socket

    folder = output_folder(folder)
    fd = os.open(folder / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o666 & ~_umask())
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.read(fd, 200).decode(errors="replace").strip() or "another process"
        os.close(fd)
        raise FolderBusyError(
            f"{folder}: another writer holds it ({holder}); wait for it to finish or choose another folder"
        ) from None
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"process {os.getpid()} on {socket.gethostname()}".encode())
        yield
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


@contextmanager
def atomic_file(path: str | Path, mode: str = "w") -> Iterator:
    """Open a temporary file beside ``path``; on success it is flushed to disk (fsync) and replaces ``path``, on
    error it is removed. The result has the usual permissions (0666 minus the umask; ``mkstemp`` makes 0600).
    Temporaries of a killed writer of the same target (its process gone) are removed first; a target that is a
    folder, or whose parent is a file, is an ``InputError`` naming it."""
    from airimu_core.errors import InputError

    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder; expected the path of a file to write")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(f"{path}: cannot write it: a part of {path.parent} is a file, not a folder") from None
    except PermissionError:
        raise InputError(f"{path}: cannot write it: no permission to create {path.parent}") from None
    _remove_orphans(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=TEMP_SUFFIX, dir=path.parent)
    except PermissionError:
        raise InputError(f"{path}: cannot write it: no permission to write in {path.parent}") from None
    try:
        with os.fdopen(fd, mode) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _remove_orphans(path: Path) -> None:
    """Delete ``atomic_file`` temporaries of ``path`` whose writing process no longer runs (killed mid-write)."""
    for tmp in path.parent.glob(f".{path.name}.*{TEMP_SUFFIX}"):
        pid = tmp.name[len(path.name) + 2 :].split(".", 1)[0]
        if pid.isdigit() and not _running(int(pid)):
            tmp.unlink(missing_ok=True)


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def remove_temporaries(folder: str | Path, names) -> list[Path]:
    """Delete the temporary files ``atomic_file`` left beside ``folder/name`` for each of ``names`` when its process
    was killed mid-write (SIGKILL skips the clean-up; the targets themselves are intact). Only for a folder with a
    single writer, such as a run folder being resumed: another writer's file in progress would be deleted too.
    Returns the deleted files."""
    stale = [p for name in names for p in Path(folder).glob(f".{name}.*{TEMP_SUFFIX}") if p.is_file()]
    for path in stale:
        path.unlink(missing_ok=True)
    return stale


def write_json_atomic(path: str | Path, data) -> Path:
    """Write ``data`` as indented JSON to ``path`` atomically; returns the path."""
    with atomic_file(path) as f:
        json.dump(data, f, indent=2)
        f.write("\n")
    return Path(path)


def write_csv_atomic(path: str | Path, records: list[dict]) -> Path:
    """Write dicts with the same keys as CSV (one header line) to ``path`` atomically; returns the path."""
    with atomic_file(path) as f:
        writer = csv.DictWriter(f, fieldnames=list(records[0]))
        writer.writeheader()
        writer.writerows(records)
    return Path(path)

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

TEMP_SUFFIX = ".tmp"  # temporary files are ".<target name>.<random>.tmp" beside the target
LOCK_NAME = ".lock"  # a folder's writer lock (folder_lock)


@contextmanager
def folder_lock(folder: str | Path) -> Iterator[None]:
    """Hold ``folder``'s writer lock: ``flock`` on ``folder/.lock``, released by the OS however the holder ends (a
    killed run leaves no stale lock). A second writer gets a ``FolderBusyError`` naming the folder and the process
    that holds it. POSIX only; elsewhere nothing is locked."""
    from learned_imu.errors import FolderBusyError

    try:
        import fcntl
    except ImportError:  # not POSIX
        yield
        return
    import socket

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
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
    error it is removed. The result has the usual permissions (0666 minus the umask; ``mkstemp`` makes 0600)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
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

"""Atomic file writes: a temporary file in the destination directory, flushed, fsynced, then ``os.replace``-d over
the destination (atomic on POSIX and Windows). A failure at any point leaves the previous file untouched and
removes the temporary file. A writer killed outright (SIGKILL, power loss) cannot remove its temporary file; the
temporary names carry the writer's process id, and the next successful write of the same destination removes the
temporaries of writers that no longer run on this machine."""

import contextlib
import glob
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO


def _fsync_directory(directory: Path) -> None:
    """Makes the rename durable (POSIX); a no-op where directories cannot be opened (Windows)."""
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # Exists, owned by someone else.
        return True
    return True


def _remove_stale_temporaries(path: Path) -> None:
    """Removes ``path``'s temporary files whose writer process is gone (a live writer's file is left alone)."""
    prefix = f".{path.name}."
    for candidate in path.parent.glob(f"{glob.escape(prefix)}*.tmp"):
        pid = candidate.name[len(prefix):].split(".", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not _process_alive(int(pid)):
            with contextlib.suppress(FileNotFoundError):
                candidate.unlink()


def atomic_write(path: str | os.PathLike, write: Callable[[BinaryIO], None]) -> Path:
    """Calls ``write(file)`` on a temporary binary file next to ``path`` and renames it over ``path``.

    The parent directory is created if needed. Returns ``path`` as a :class:`~pathlib.Path`.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temporary = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as file:
            write(file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise
    _fsync_directory(path.parent)
    _remove_stale_temporaries(path)
    return path

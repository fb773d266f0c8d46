"""One training per run directory: an exclusive ``flock`` on ``<run_dir>/.lock`` held for the run's life.

Two ``seqdex train`` processes on one run directory (two fresh starts, or two ``--resume``) would both run to the
end and overwrite each other's ``last.pt`` and ``config.json``. :class:`RunLock` takes the lock without waiting;
the second process is refused with a :class:`~seqdex_drake.cli.CliError` naming the first (its pid, host, command
and start time, which the holder writes into the lock file). The kernel releases a ``flock`` when its holder
exits in any way (a crash, SIGKILL), so a lock is never stale; the file itself stays in the run directory (removing
it on release would let a third process lock a new file while a second holds the old one).

The lock file is opened close-on-exec and the env workers start from a fork server, not from the trainer, so no
worker holds the lock after the trainer is gone.
"""

import datetime
import fcntl
import json
import os
import shlex
import socket
import sys
from pathlib import Path

from seqdex_drake.cli import CliError

#: The lock file's name inside the run directory.
LOCK_NAME = ".lock"


class RunLock:
    """The exclusive lock of ``run_dir`` as a context manager (``with RunLock(run_dir):``).

    Args:
        run_dir: the run directory.
        create: create ``run_dir`` (and its parents) if it does not exist.

    If the ``with`` block ends with an exception (a refused command), what the lock created is removed again: the
    lock file, and the directories if they hold nothing else, so that a refused command leaves nothing behind.
    """

    def __init__(self, run_dir: str | os.PathLike, create: bool = False):
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / LOCK_NAME
        self.create = create
        self._fd: int | None = None
        self._created: list[Path] = []  # Directories this lock made, deepest first.
        self._created_file = False

    def acquire(self) -> None:
        """Takes the lock; :class:`CliError` if another process holds it or the directory cannot be used."""
        if self.create:
            self._make_directories()
        try:
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
                self._created_file = True
            except FileExistsError:
                fd = os.open(self.path, os.O_RDWR | os.O_CLOEXEC)
        except OSError as error:
            self._remove_created()
            raise CliError(f"cannot create the lock file {self.path} ({error.strerror or error}); pick a writable "
                           f"--run-dir") from error
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _describe_holder(fd)
            os.close(fd)
            self._created_file = False  # Created an instant ago but locked by the other process: it is theirs.
            self._remove_created()
            raise CliError(f"{self.run_dir} is in use by {holder}; wait for it to end, stop it (Ctrl-C or kill -TERM "
                           f"saves its last.pt), or pick another --run-dir") from None
        except OSError as error:  # A file system without flock: go on, but say that nothing guards the directory.
            print(f"seqdex: warning: cannot lock {self.path} ({error.strerror or error}); make sure no other "
                  f"training uses {self.run_dir}", file=sys.stderr)
        holder = {"pid": os.getpid(), "host": socket.gethostname(), "command": shlex.join(["seqdex", *sys.argv[1:]]),
                  "started": datetime.datetime.now().isoformat(timespec="seconds")}
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(holder) + "\n").encode(), 0)
        except OSError:  # A full disk: the lock holds all the same, a refused process just cannot name us.
            pass
        self._fd = fd

    def release(self) -> None:
        """Releases the lock (the lock file stays, emptied)."""
        if self._fd is not None:
            try:
                os.ftruncate(self._fd, 0)
            except OSError:
                pass
            os.close(self._fd)  # Closing the descriptor releases the flock.
            self._fd = None

    def __enter__(self) -> "RunLock":
        self.acquire()
        return self

    def __exit__(self, exc_type, exc, traceback) -> bool:
        self.release()
        if exc_type is not None:
            self._remove_created()
        return False

    def _make_directories(self) -> None:
        missing = []
        directory = self.run_dir
        while not directory.exists() and directory != directory.parent:
            missing.append(directory)
            directory = directory.parent
        for directory in reversed(missing):
            try:
                directory.mkdir()
            except FileExistsError:  # Another process made it meanwhile: not ours to remove.
                continue
            except OSError as error:
                self._remove_created()
                raise CliError(f"cannot create the run directory {self.run_dir}: {directory} "
                               f"({error.strerror or error}); pick a writable --run-dir") from error
            self._created.insert(0, directory)

    def _remove_created(self) -> None:
        """Removes the lock file if this lock created it, and the directories it created if they are empty."""
        if self._created_file:
            self.path.unlink(missing_ok=True)
            self._created_file = False
        for directory in self._created:
            try:
                directory.rmdir()  # Only an empty directory goes.
            except OSError:
                break  # Not empty (the run wrote into it, or another process did): keep it and its parents.
        self._created = []


def _describe_holder(fd: int) -> str:
    """'process 123 on host h (seqdex train ..., started ...)' from the lock file, or 'another process'."""
    try:
        holder = json.loads(os.pread(fd, 4096, 0).decode())
        return (f"process {int(holder['pid'])} on host {holder['host']} ({holder['command']}, started "
                f"{holder['started']})")
    except (OSError, ValueError, KeyError, TypeError):
        return "another process"

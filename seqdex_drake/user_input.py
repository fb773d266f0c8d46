"""Checks of what a user typed (seeds, output paths), shared by the command line and the scripts.

:class:`InputError` is a failure the user can fix: front ends print its message without a traceback and exit
with its ``code`` (2, bad input). The checks run before any work starts and create nothing.
"""

import os
import tempfile
from pathlib import Path


class InputError(Exception):
    """A failure the user can fix: printed as ``<program>: error: <message>``, exit ``code``."""

    def __init__(self, message: str, code: int = 2):
        super().__init__(message)
        self.code = code


#: Seeds are used as numpy seeds (``seed + env index``, ``seed + step``): non-negative, within 32 bits.
MAX_SEED = 2**32 - 1


def check_seed(seed: int, flag: str = "--seed") -> None:
    """Raises :class:`InputError` unless ``0 <= seed <= MAX_SEED``."""
    if not 0 <= seed <= MAX_SEED:
        raise InputError(f"{flag} must be in 0 .. {MAX_SEED}, got {seed}")


def check_creatable(path: str | os.PathLike, flag: str, directory: bool = False) -> None:
    """Raises :class:`InputError` unless a file (``directory``: a directory) can be written at ``path``.

    Checked up front and creating nothing: an existing ``path`` must be of the right kind, the nearest existing
    ancestor must be a directory (not a file), and a temporary file must be creatable in it (a real test, so
    read-only file systems and permissions count, also for root). Files are written atomically (a temporary file
    next to them, then a rename), so a file's directory must be writable, not the file itself.
    """
    path = nearest = Path(path)
    try:
        if path.is_dir() and not directory:
            raise InputError(f"{flag} {path} is a directory; name a file")
        if path.exists() and directory and not path.is_dir():
            raise InputError(f"{flag} {path} is a file, not a directory; pick another {flag}")
        nearest = path if directory and path.is_dir() else path.parent
        while not nearest.exists() and nearest != nearest.parent:
            nearest = nearest.parent
        if not nearest.is_dir():
            raise InputError(f"{flag} {path}: {nearest} is a file, not a directory; pick another {flag}")
        with tempfile.TemporaryFile(dir=nearest):
            pass
    except OSError as error:
        raise InputError(f"{flag} {path}: cannot write in {nearest} ({error.strerror or error}); pick a writable "
                         f"{flag}") from error

"""Exclusive locks on output folders: two moseg commands writing one folder would undo each other's work
(both build it under the same temporary name, and the second removes the first's).

`exclusive_lock` holds a POSIX advisory lock (`fcntl.flock`) on a lock file; the kernel drops it when the
process ends, however it ends, so a killed command never leaves a folder locked. `output_lock` locks the
output folder of one run (`.NAME.lock` beside it: the folder itself is renamed into place only at the end);
a batch locks the folder it writes into (mosegpipe.apps.batch.run).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from mosegpipe.errors import InputError


def _open_locked(lock: Path, busy: str) -> IO[Any]:
    """The lock file, open and locked: a file its last holder removed between our open and our lock
    locks nothing (a third command would create and lock a new one), so it is opened again."""
    import fcntl

    while True:
        fh = open(lock, "a+")  # noqa: SIM115 - held until the lock is released
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.close()
            raise InputError(busy) from None
        except BaseException:
            fh.close()
            raise
        try:
            same = os.stat(lock).st_ino == os.fstat(fh.fileno()).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fh
        fh.close()


@contextlib.contextmanager
def exclusive_lock(lock: Path, busy: str) -> Iterator[None]:
    """Holds an exclusive lock on the file `lock` (created if missing, removed on release).

    Args:
        lock: the lock file; its folder must exist.
        busy: the message of the error raised when another process holds the lock.

    Raises:
        InputError: another process holds it (`busy`); never waits.
    """
    try:
        import fcntl  # noqa: F401
    except ImportError:  # not POSIX: no lock
        yield
        return
    fh = _open_locked(lock, busy)
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()
        fh.close()  # closing the last descriptor releases the lock


def output_lock_path(out: str | os.PathLike[str]) -> Path:
    """The lock file of output folder `out`: `.NAME.lock` beside it."""
    final = Path(out).absolute()
    return final.with_name(f".{final.name}.lock")


@contextlib.contextmanager
def output_lock(out: str | os.PathLike[str]) -> Iterator[None]:
    """Holds the lock of output folder `out` while a command writes it (`moseg run`, `pair`, `tracks`, `live`).

    The folders above `out` that are missing are created for the lock file (the outputs would create them);
    those still empty when the lock is released are removed again, so a run that fails leaves nothing.

    Raises:
        InputError: another moseg command holds it ("OUT: another moseg command is writing there").
    """
    lock = output_lock_path(out)
    created: list[Path] = []
    parent = lock.parent
    while not parent.exists():
        created.append(parent)
        parent = parent.parent
    try:
        for folder in reversed(created):
            folder.mkdir(exist_ok=True)
        with exclusive_lock(lock, f"{out}: another moseg command is writing there"):
            yield
    finally:
        for folder in created:  # deepest first
            with contextlib.suppress(OSError):  # not empty: the outputs are in it
                folder.rmdir()

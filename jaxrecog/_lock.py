"""One campaign per folder: an exclusive lock on an ``experiment`` run's
``--out`` and work folders.

Two ``experiment`` runs into one ``--out`` (or one work folder) each ran
every trial and stored each twice.  :func:`folder_lock` holds a
``flock`` on ``FOLDER/.jaxrecog.lock`` for the whole run; the file names the
holder (PID, host, start time), so a second run is refused with one line
naming the first.  The kernel drops the lock when its holder dies, however it
dies: the lock file of a killed run (a dead PID) is simply taken over by the
next run.  The file is removed when the run ends.

One output file per writer: :func:`file_lock` is the same lock on one file
(``FOLDER/.NAME.lock`` beside it), held by ``jaxrecog train`` from its
writability check until the model is saved; a second writer of the same file
is refused at once (no waiting), with one line naming the first.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
import time
from pathlib import Path
from typing import Iterator

__all__ = ["LOCK_NAME", "FolderLockedError", "FileLockedError", "folder_lock", "file_lock"]

LOCK_NAME = ".jaxrecog.lock"


class FolderLockedError(OSError):
    """Another run holds the folder (one line naming it)."""


class FileLockedError(FolderLockedError):
    """Another run is writing the same output file (one line naming it)."""


def _holder(fd: int) -> str:
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        text = os.read(fd, 512).decode("utf-8", "replace").split()
    except OSError:
        text = []
    if len(text) >= 2 and text[0].isdigit():
        since = f", started {' '.join(text[2:5])}" if len(text) >= 4 else ""
        return f"PID {text[0]} on {text[1]}{since}"
    return "a process that has not written its PID yet"


def _acquire(folder: Path, what: str, target: Path | None = None) -> tuple[int, Path]:
    """Lock ``folder`` (``target``: the one file ``target`` of ``folder``, by
    ``FOLDER/.NAME.lock``; the folder then must exist)."""
    if target is None:
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / LOCK_NAME
    else:
        path = folder / f".{target.name}.lock"
    flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    for _ in range(20):
        try:
            fd = os.open(path, flags, 0o644)
        except OSError as e:  # e.g. a symbolic link there: never followed
            raise OSError(e.errno, f"cannot take the lock {path} ({e.strerror})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            if target is not None:
                raise FileLockedError(f"{target} is being written by another {what} ({holder}); wait for it to "
                                      f"end or choose another file") from None
            raise FolderLockedError(f"{folder} is in use by another {what} ({holder}); wait for it to end "
                                    f"or choose another folder") from None
        try:  # the file we locked is still the one at the path (not one a finishing run just removed)
            same = os.fstat(fd).st_ino == os.stat(path, follow_symlinks=False).st_ino
        except FileNotFoundError:
            same = False
        if not same:
            os.close(fd)
            continue
        stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, f"{os.getpid()} {socket.gethostname() or 'host'} {stamp} UTC\n".encode())
        return fd, path
    raise FolderLockedError(f"{folder}: could not take {path} (it keeps being replaced)")


def _release(fd: int, path: Path) -> None:
    try:
        os.unlink(path)  # while still holding it: a newcomer then locks a fresh file
    except OSError:
        pass
    os.close(fd)


@contextlib.contextmanager
def folder_lock(*folders: str | os.PathLike, what: str = "jaxrecog experiment run") -> Iterator[None]:
    """Hold an exclusive lock on each of ``folders`` (created if missing; one
    folder given twice is locked once) for the ``with`` block.

    Raises:
        FolderLockedError: a live process holds one of them; the message
            names the folder and that process's PID.  Nothing is held then.
    """
    seen: dict[str, Path] = {}
    for f in folders:
        p = Path(f)
        seen.setdefault(os.path.realpath(p), p)
    held: list[tuple[int, Path]] = []
    try:
        for real in sorted(seen):
            held.append(_acquire(seen[real], what))
        yield
    finally:
        for fd, path in reversed(held):
            _release(fd, path)


@contextlib.contextmanager
def file_lock(path: str | os.PathLike, what: str = "jaxrecog run") -> Iterator[None]:
    """Hold an exclusive lock on writing the one file ``path`` (by
    ``FOLDER/.NAME.lock`` beside it; its folder must exist) for the ``with``
    block: two ``jaxrecog train --out m.npz`` at once both trained and both
    exited 0, and one model was lost; now the second is refused at once.

    Raises:
        FileLockedError: a live process is writing ``path``; the message
            names the file and that process's PID.  Nothing is held then.
    """
    p = Path(path)
    folder = p.parent if str(p.parent) else Path(".")
    held = _acquire(folder, what, target=p)
    try:
        yield
    finally:
        _release(*held)

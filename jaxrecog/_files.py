"""One rule for every file jaxrecog reads as text or writes as output.

Outputs (model files, rendered databases, reports, plots, ``--problems-out``,
JSON and TOML written beside results) are written only as *regular files* into
*existing* folders: :func:`check_output_file` refuses a target that exists and
is not a regular file (a folder, ``/dev/null``, ``/dev/full``, a FIFO, a
socket) and a target whose folder does not exist (no folder chain is created
behind the user's back: ``--out /nonexistent/m.npz`` is a typo more often than
a wish).  :func:`check_output_folder` does the same for a command's output
*folder* (``render --out DB``, ``experiment --out OUT``): named as a folder,
it is created with any missing parents (``--out out/iii``), but never through
a path of which a part is a file, and it must take files.  :func:`write_text` writes one text
output atomically (a temporary file in the same folder, then a rename) after
those checks.

Inputs read as text (settings files, experiment files, rig files) go through
:func:`read_text`: a regular file only (``/dev/zero``, a FIFO or a terminal is
refused before a byte is read), at most :data:`MAX_TEXT_BYTES` (the size is
checked before reading and the read itself is capped, so a file that grows
while read cannot run away either), UTF-8 (a bad byte is one line naming the
file and the byte's offset).  :func:`read_bytes` is the same bounded read
without the decoding (a database's ``manifest.csv``, up to 1 GiB).

Every failure is one :class:`OSError` line naming what was being read or
written and the path.  A leaf module of the core (standard library only).
"""

from __future__ import annotations

import os
import secrets
import stat
from pathlib import Path

from .problems import one_line

__all__ = ["MAX_TEXT_BYTES", "OutputPathError", "OutputIsFolderError", "OutputFolderError", "OutputFolderMissingError",
           "TextFileError", "check_output_file", "check_output_folder",
           "read_bytes", "read_text", "replace_from_temp", "write_text"]

#: The largest settings / experiment / rig text file read (1 MiB: such files
#: are a few hundred bytes; anything larger is not one).
MAX_TEXT_BYTES = 1 << 20


class OutputPathError(OSError):
    """An output path that jaxrecog will not write (one line naming it)."""


class OutputIsFolderError(OutputPathError, IsADirectoryError):
    """The output file's path is a folder."""


class OutputFolderError(OutputPathError, NotADirectoryError):
    """The output file's folder is a file (or a part of its path is)."""


class OutputFolderMissingError(OutputPathError, FileNotFoundError):
    """The output file's folder does not exist (it is not created)."""


class TextFileError(OSError):
    """A text input that cannot be read as one (one line naming it)."""


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _folder_of(p: Path) -> Path:
    return p.parent if str(p.parent) else Path(".")


def check_output_file(path: str | os.PathLike, what: str = "output file") -> Path:
    """``path`` as a :class:`~pathlib.Path` when it may be written as ``what``:
    its folder exists, and ``path`` is absent or a regular file (a symbolic
    link counts as what it points to).

    Raises:
        OutputPathError: one line, e.g. ``cannot write model file /dev/null:
            it is a character device, not a regular file``.
    """
    p = Path(path)
    folder = _folder_of(p)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        st = None
    except OSError as e:
        if e.errno == 20:  # ENOTDIR: a part of the folder is a file
            raise OutputFolderError(f"cannot write {what} {p}: {folder} is not a folder") from None
        raise OutputPathError(f"cannot write {what} {p}: {e.strerror}") from None
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise OutputIsFolderError(f"cannot write {what} {p}: it is a folder")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise OutputPathError(f"cannot write {what} {p}: it is {_kind(st.st_mode)}, not a regular file")
    if st is None:
        if not folder.exists():
            raise OutputFolderMissingError(f"cannot write {what} {p}: folder {folder} does not exist "
                                           f"(create it first)")
        if not folder.is_dir():
            raise OutputFolderError(f"cannot write {what} {p}: {folder} is not a folder")
    return p


def check_output_folder(path: str | os.PathLike, what: str = "output folder", *, create: bool = True) -> Path:
    """``path`` as a folder outputs may be written into: an existing folder,
    or (``create``) a new one, made with its missing parents; then checked
    writable by creating and removing a temporary file in it.

    Raises:
        OutputPathError: one line (``path`` or a folder above it exists and
            is not a folder, ``path`` is missing and not ``create``, or it
            does not take files).
    """
    p = Path(path)
    for above in (p, *p.parents):
        if above.exists():
            if not above.is_dir():
                raise OutputPathError(f"cannot write {what} {p}: {above} exists and is not a folder")
            break
    if not p.exists():
        if not create:
            raise OutputPathError(f"{what} {p} does not exist")
        try:
            p.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise OutputPathError(f"cannot create {what} {p}: {e.strerror}") from None
    probe = p / f".jaxrecog-probe.{os.getpid()}.{secrets.token_hex(4)}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o600)
    except OSError as e:
        raise OutputPathError(f"cannot write into {what} {p}: {e.strerror}") from None
    os.close(fd)
    os.unlink(probe)
    return p


def write_text(path: str | os.PathLike, text: str, what: str = "output file") -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically, after :func:`check_output_file`:
    a temporary file beside it, then renamed over it (an existing file keeps its mode)."""
    p = check_output_file(path, what)
    folder = _folder_of(p)
    tmp = folder / f".{p.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(tmp, flags, 0o666)
    except OSError as e:
        raise OutputPathError(f"cannot write {what} {p}: {e.strerror}") from None
    replace_from_temp(fd, tmp, p, lambda f: f.write(text.encode("utf-8")))
    return p


def replace_from_temp(fd: int, tmp: str | os.PathLike, path: str | os.PathLike, write, *,
                      durable: bool = False) -> None:
    """Finish an atomic write: ``write(f)`` into the new temporary file open
    as ``fd`` (binary), give it the mode of the regular file it replaces, and
    rename it over ``path`` (``durable``: flushed to disk first).  On any
    failure the temporary file is removed and ``path`` is untouched."""
    try:
        try:  # written over an existing file: keep its mode (as open(path, "w") would)
            st = os.stat(path)
            if stat.S_ISREG(st.st_mode):
                os.fchmod(fd, stat.S_IMODE(st.st_mode))
        except FileNotFoundError:
            pass
        with os.fdopen(fd, "wb") as f:
            write(f)
            if durable:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def read_bytes(path: str | os.PathLike, what: str, limit: int) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them.

    The file is opened without blocking (a FIFO with no writer does not hang
    the reader), checked to be a regular file of at most ``limit`` bytes, and
    read with a cap of ``limit + 1`` bytes (a file that grows while read).

    Raises:
        FileNotFoundError: no such file (the message names ``what`` and the path).
        TextFileError: not a regular file, too large, or unreadable.
    """
    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} {p} not found") from None
    except OSError as e:
        raise TextFileError(f"{what} {p} cannot be read: {e.strerror}") from None
    chunks, n = [], 0
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise TextFileError(f"{what} {p} is {_kind(st.st_mode)}, not a regular file")
        if st.st_size > limit:
            raise TextFileError(f"{what} {p} is {st.st_size} bytes, more than the {limit} a {what} may have")
        while n <= limit:
            b = os.read(fd, limit + 1 - n)
            if not b:
                break
            chunks.append(b)
            n += len(b)
    except TextFileError:
        raise
    except OSError as e:
        raise TextFileError(f"{what} {p} cannot be read: {e.strerror}") from None
    finally:
        os.close(fd)
    if n > limit:
        raise TextFileError(f"{what} {p} grew past {limit} bytes while it was read")
    return b"".join(chunks)


def read_text(path: str | os.PathLike, what: str = "settings file", limit: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of the regular file ``path``, at most ``limit`` bytes
    (:func:`read_bytes`).

    Raises:
        FileNotFoundError: no such file (the message names ``what`` and the path).
        TextFileError: not a regular file, too large, not UTF-8, or unreadable.
    """
    raw = read_bytes(path, what, limit)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise TextFileError(f"{what} {one_line(path)} is not UTF-8 text (byte 0x{raw[e.start]:02x} at offset "
                            f"{e.start})") from None

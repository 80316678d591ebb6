"""Atomic file writes: readers see either the old file or the whole new one."""

from __future__ import annotations

import contextlib
import os
import secrets

from .paths import keep_mode, output_target


def atomic_write_text(path, text: str, *, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_write_bytes`).

    Raises:
        OSError: the directory is missing or not writable, or the disk is full.
        UnicodeEncodeError: ``text`` cannot be encoded (nothing is created then).
    """
    # Encode before creating anything: an encoding error leaves no file.
    atomic_write_bytes(path, text.encode(encoding))


def atomic_write_bytes(path, data: bytes | memoryview) -> None:
    """Write ``data`` to ``path`` so that readers see either the old file or the whole new one.

    The data goes to a temporary file in the same directory (so the final rename stays on one
    file system), is flushed and fsynced, then renamed over ``path`` with :func:`os.replace`.
    On any exception the temporary file is removed and ``path`` is left as it was. Where
    ``path`` is a symbolic link, the file it leads to is written (in that file's directory)
    and the link is kept; a file replaced keeps its permission bits.

    Arguments:
        path: the destination file.
        data: the complete content.

    Raises:
        OSError: the directory is missing or not writable, or the disk is full.
        FileProblem: (a ``ValueError``) ``path`` is, or links to, something other than a
            regular file or a new path (a directory, a device, a pipe, a socket).
    """
    path = output_target(path)  # through a symbolic link; never over a device or a pipe
    temp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    # O_EXCL: never reuse someone else's file; mode 0o666 lets the umask decide permissions,
    # as for any ordinarily created file (tempfile.mkstemp would force 0o600).
    fd = os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        keep_mode(path, temp)
        os.replace(temp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temp)
        raise
    # Persist the rename itself; best effort, since not every platform can fsync a directory.
    with contextlib.suppress(OSError):
        dir_fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)

"""Files a user names on the command line: checked before any computing.

A missing input, or an output that cannot be written, must be reported at once (exit 2, one
line naming the user's path and the reason), not after minutes of simulation, and never by the
name of a hidden temporary file.
"""

import os
import secrets
from pathlib import Path


class FileProblem(ValueError):
    """A file the user named cannot be read or written. The message starts with the path."""

    def __init__(self, path, reason: str):
        super().__init__(f"{path}: {reason}")
        self.path = str(path)


def _reason(err: OSError) -> str:
    return (err.strerror or str(err)).lower() if isinstance(err, OSError) else str(err)


def check_readable(path, what: str = "file") -> Path:
    """``path`` exists, is a regular file and can be opened for reading."""
    p = Path(path)
    if not p.exists():
        raise FileProblem(path, f"{what} not found")
    if p.is_dir():
        raise FileProblem(path, f"is a directory, not a {what}")
    try:
        with open(p, "rb"):
            pass
    except OSError as err:
        raise FileProblem(path, f"cannot read the {what}: {_reason(err)}") from None
    return p


def prepare_output(path, what: str = "output file") -> Path:
    """Make sure ``path`` can be written, before computing what goes in it.

    Missing parent directories are created (as ``jaximpact sweep`` does for its directory).
    Refused with :class:`FileProblem`: a path that is a directory, a parent that is a file, and
    a directory where no file can be created (probed with a temporary file, removed at once).
    """
    p = Path(path)
    if p.is_dir():
        raise FileProblem(path, f"is a directory; give a file name for the {what}")
    parent = p.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise FileProblem(path, "a parent of this path is a file, not a directory") from None
    except OSError as err:
        raise FileProblem(path, f"cannot create its directory: {_reason(err)}") from None
    if not parent.is_dir():
        raise FileProblem(path, "a parent of this path is a file, not a directory")
    probe = parent / f".{p.name}.{secrets.token_hex(4)}.probe"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as err:
        raise FileProblem(path, f"cannot write the {what}: {_reason(err)}") from None
    os.close(fd)
    os.unlink(probe)
    return p


def write_failed(path, err: OSError) -> FileProblem:
    """The error to raise when writing ``path`` failed after all (disk full, ...)."""
    return FileProblem(path, f"could not be written: {_reason(err)}")

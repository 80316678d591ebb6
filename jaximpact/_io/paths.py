"""Files a user names on the command line: checked before any computing.

A missing input, or an output that cannot be written, must be reported at once (exit 2, one
line naming the user's path and the reason), not after minutes of simulation, and never by the
name of a hidden temporary file.
"""

import contextlib
import errno
import os
import secrets
import stat
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


def output_target(path, what: str = "output file") -> Path:
    """The file that an output named ``path`` is written to.

    ``path`` itself, or, where it is a symbolic link (or a chain of them, even one that ends at
    a file not yet created), the file the link leads to: an output is written through a link to
    its target, and the link stays a link. The target must be a regular file or a new path.

    Raises:
        FileProblem: naming ``path``: it (or what it links to) is a directory, a device, a pipe,
            a socket, or a chain of links that never ends.
    """
    p = Path(path)
    target = Path(os.path.realpath(p))
    try:
        mode = os.stat(target).st_mode
    except NotADirectoryError:
        raise FileProblem(path, "a parent of this path is a file, not a directory") from None
    except FileNotFoundError:
        if os.path.islink(target):  # realpath stops inside a loop of links
            raise FileProblem(path, "is a symbolic link that never ends (a loop)") from None
        return target  # a new file
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise FileProblem(path, "is a symbolic link that never ends (a loop)") from None
        raise FileProblem(path, f"cannot use it for the {what}: {_reason(err)}") from None
    if stat.S_ISDIR(mode):
        raise FileProblem(path, f"is a directory; give a file name for the {what}")
    if not stat.S_ISREG(mode):
        kind = (
            "a device"
            if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a pipe"
            if stat.S_ISFIFO(mode)
            else "a socket"
            if stat.S_ISSOCK(mode)
            else "not a regular file"
        )
        link = f" (a link to {target})" if target != Path(os.path.abspath(p)) else ""
        raise FileProblem(path, f"is {kind}{link}; the {what} must be a regular file or a new path")
    return target


def keep_mode(target: Path, temp: Path) -> None:
    """Give ``temp`` the permission bits of the file it is about to replace (if any)."""
    with contextlib.suppress(FileNotFoundError):
        os.chmod(temp, stat.S_IMODE(os.stat(target).st_mode))


@contextlib.contextmanager
def atomic_output(path, what: str = "output file"):
    """Write an output atomically with a writer that wants a file name (``savefig``,
    ``to_netcdf``): yields a temporary path in the directory of the target (see
    :func:`output_target`) with the same suffix, renamed over the target when the block ends
    without an exception, removed otherwise."""
    target = output_target(path, what)
    temp = target.with_name(f".{target.stem}.{secrets.token_hex(6)}.tmp{target.suffix}")
    try:
        yield temp
        keep_mode(target, temp)
        os.replace(temp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temp)
        raise


def prepare_output(path, what: str = "output file") -> Path:
    """Make sure ``path`` can be written, before computing what goes in it.

    Missing parent directories are created (as ``jaximpact sweep`` does for its directory).
    A symbolic link is followed: the output goes to the file it leads to (see
    :func:`output_target`). Refused with :class:`FileProblem`: a path that is (or leads to) a
    directory, a device, a pipe or a socket, a parent that is a file, and a directory where no
    file can be created (probed with a temporary file, removed at once).
    """
    if not str(path).strip():  # e.g. `-o "$OUT"` with OUT unset
        raise FileProblem("''", f"is an empty path; give a file name for the {what}")
    p = Path(path)
    if p.is_dir():
        raise FileProblem(path, f"is a directory; give a file name for the {what}")
    target = output_target(path, what)
    parent = target.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise FileProblem(path, "a parent of this path is a file, not a directory") from None
    except OSError as err:
        raise FileProblem(path, f"cannot create its directory: {_reason(err)}") from None
    if not parent.is_dir():
        raise FileProblem(path, "a parent of this path is a file, not a directory")
    probe = parent / f".{target.name}.{secrets.token_hex(4)}.probe"
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

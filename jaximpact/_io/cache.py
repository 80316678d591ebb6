"""JAX's persistent compilation cache: compiled programs kept on disk between processes.

Every ``jaximpact`` command compiles its solve (seconds to tens of seconds); with the cache on,
a later process with the same program (same shapes, settings and JAX version) loads it from
disk instead. It is on by default, for the CLI and the API alike: ``import jaximpact`` turns
it on (:func:`enable_default_cache`) unless JAX already has a cache directory (the user's own
choice is kept) or ``JAXIMPACT_CACHE_DIR=off``; :func:`enable_compilation_cache` moves it.

Where: ``$JAXIMPACT_CACHE_DIR`` if set (``off`` disables the cache), else
``<user cache dir>/jaximpact/jax-compilation-cache`` (platformdirs: ``~/.cache/...`` on Linux,
``~/Library/Caches/...`` on macOS, ``%LOCALAPPDATA%\\...`` on Windows).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

__all__ = [
    "CACHE_ENV",
    "cache_dir",
    "cached_program",
    "compiled_program",
    "code_fingerprint",
    "enable_compilation_cache",
    "enable_default_cache",
    "lowered_program",
    "runtime_checks_as_nan",
]

#: Environment variable that moves (a path) or disables (``off``) the cache.
CACHE_ENV = "JAXIMPACT_CACHE_DIR"

_OFF = ("off", "0", "false", "no", "none", "disable", "disabled")

# Cache every program that takes at least this long to compile (s). The solves take seconds;
# the tiny helper programs (a few ms) are as quick to compile as to load.
MIN_COMPILE_TIME_S = 0.05


def cache_dir(path=None) -> Path | None:
    """The cache directory that :func:`enable_compilation_cache` would use.

    **Arguments:** `path`: an explicit directory, or ``None`` for ``$JAXIMPACT_CACHE_DIR``,
    else the user cache directory.

    **Returns:** the directory, or ``None`` when the environment variable says ``off``.
    """
    if path is None:
        env = os.environ.get(CACHE_ENV, "").strip()
        if env.lower() in _OFF:
            return None
        if env:
            return Path(env).expanduser()
        import platformdirs

        return platformdirs.user_cache_path("jaximpact") / "jax-compilation-cache"
    return Path(path).expanduser()


def enable_compilation_cache(path=None) -> Path | None:
    """Keep compiled JAX programs on disk, so later processes skip compiling them.

    **Arguments:** `path`: the cache directory (created if missing). Default:
    ``$JAXIMPACT_CACHE_DIR``, else ``<user cache dir>/jaximpact/jax-compilation-cache``;
    ``JAXIMPACT_CACHE_DIR=off`` leaves the cache off (an explicit `path` is always used).

    **Returns:** the directory in use, or ``None`` if the cache stays off (or the directory
    cannot be created: then programs are compiled as usual).

    Programs that take at least ``MIN_COMPILE_TIME_S`` (0.05 s) to compile are stored, whatever
    their size. Call it before the first computation; calling it again with another
    directory switches to that one. The cache is trusted code: do not point it at a directory
    that others can write.
    """
    import jax

    directory = cache_dir(path)
    if directory is None:
        return None
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    from jax.experimental.compilation_cache import compilation_cache

    if jax.config.jax_compilation_cache_dir not in (None, str(directory)):
        compilation_cache.reset_cache()  # drop the handle on the previous directory
    jax.config.update("jax_compilation_cache_dir", str(directory))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
    # -1: no size threshold (0 would let JAX pick its own default minimum).
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    return directory


def enable_default_cache() -> Path | None:
    """The cache on, where nobody chose otherwise (called by ``import jaximpact``): a
    notebook's second kernel and a script's second run then load their programs instead of
    compiling them (BENCHMARKS.md, "First result"). Left alone where JAX already has a cache
    directory or ``$JAXIMPACT_CACHE_DIR`` is ``off``; any failure leaves it off, silently."""
    try:
        import jax

        if jax.config.jax_compilation_cache_dir:
            return None
        return enable_compilation_cache()
    except Exception:  # never let the cache stop an import
        return None


# --- traced programs -------------------------------------------------------------------------
#
# The compilation cache keys on the lowered program, so a new process still traces and lowers
# before it can look anything up: for a vmapped diffrax solve with its Jacobian that is most of
# a warm run (seconds). Programs that jaximpact builds itself (the fit's residual-and-Jacobian
# program) are therefore also kept traced, as serialized `jax.export` modules beside the
# compiled ones, under a key made of the code (the source of jaximpact and fitting, the versions
# of JAX and its libraries), the precision and backend, the argument shapes and the caller's
# digest of everything the function closes over.

_EXPORT_SUBDIR = "traced"
_LIBRARIES = ("jax", "jaxlib", "diffrax", "equinox", "optimistix", "lineax", "optax", "numpy")
_code_digest: str | None = None


def code_fingerprint() -> str:
    """Digest of the code a traced program depends on: the source files of ``jaximpact`` and
    ``fitting`` and the versions of JAX and the libraries it traces through."""
    global _code_digest
    if _code_digest is None:
        import hashlib
        import importlib.metadata
        import importlib.util

        h = hashlib.sha256()
        for lib in _LIBRARIES:
            try:
                h.update(f"{lib}={importlib.metadata.version(lib)};".encode())
            except importlib.metadata.PackageNotFoundError:
                h.update(f"{lib}=?;".encode())
        for package in ("jaximpact", "fitting"):
            spec = importlib.util.find_spec(package)
            if spec is None or not spec.submodule_search_locations:
                continue
            root = Path(next(iter(spec.submodule_search_locations)))
            for file in sorted(root.rglob("*.py")):
                h.update(str(file.relative_to(root)).encode())
                h.update(file.read_bytes())
        _code_digest = h.hexdigest()
    return _code_digest


def cached_program(name: str, fn, args, key: str):
    """A jittable stand-in for ``fn`` at the shapes of ``args``, traced at most once per cache.

    With the compilation cache on (:func:`enable_compilation_cache`), the traced program is
    loaded from ``<cache>/traced/`` when there, else traced, exported and stored there; its
    compilation then goes through the compilation cache as usual. With the cache off, or if
    the program cannot be exported or stored, this is ``jax.jit(fn)``.

    **Arguments:**
    - `name`: a label for the file name.
    - `fn`: the function (of arrays; returns a tuple of arrays).
    - `args`: example arguments (arrays or ``jax.ShapeDtypeStruct``), fixing shapes and dtypes.
    - `key`: the caller's digest of everything ``fn`` depends on besides its arguments and the
      code (closed-over data, settings).

    **Returns:** ``(program, source)``: ``program`` has ``.lower(*args).compile()``; ``source``
    is ``"traced"`` (traced now) or ``"cache"`` (loaded, not traced).
    """
    import jax

    directory = jax.config.jax_compilation_cache_dir
    if not directory:
        return jax.jit(fn), "traced"
    path = Path(directory) / _EXPORT_SUBDIR / f"{name}-{_digest(args, key)}.jaxexport"
    try:
        exported = jax.export.deserialize(bytearray(path.read_bytes()))
        return jax.jit(exported.call), "cache"
    except FileNotFoundError:
        pass
    except Exception:  # an unreadable or incompatible file: trace again and replace it
        pass
    try:
        exported = jax.export.export(jax.jit(fn))(*args)
        data = exported.serialize()
    except Exception:  # not exportable (e.g. a host callback) or no flatbuffers: plain jit
        return jax.jit(fn), "traced"
    try:
        from .atomic import atomic_write_bytes

        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, bytes(data))
    except OSError:
        pass
    return jax.jit(exported.call), "traced"


def _digest(args, *parts) -> str:
    """Digest of the code, the argument shapes, the precision, the backend and ``parts``."""
    import hashlib

    import jax

    avals = [(tuple(a.shape), str(a.dtype)) for a in jax.tree_util.tree_leaves(args)]
    h = hashlib.sha256()
    for part in (
        code_fingerprint(),
        *parts,
        repr(avals),
        repr(jax.tree_util.tree_structure(args)),
        str(jax.config.jax_enable_x64),
        jax.default_backend(),
    ):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()[:40]


# --- compiled programs ------------------------------------------------------------------------
#
# A program loaded from the traced cache is lowered again (0.2 s for the fit's) and found in
# JAX's compilation cache (0.35 s) by each process. Its compiled executable was once kept too
# (`jax.experimental.serialize_executable`, 0.35 s faster per warm fit), but that loads it
# without its XLA compile options, and on a CPU such an executable failed at its first run in
# a process that had compiled other programs before ("NOT_FOUND: Function
# slice_exponential_fusion.2 not found", 2026-11-26, jax 0.10.2); JAX's own cache passes the
# options and has not failed so.


def compiled_program(name: str, fn, args, key: str, options: dict | None = None):
    """``fn`` compiled at the shapes of ``args`` with XLA ``options``: its traced program from
    :func:`cached_program`, compiled through JAX's compilation cache (a warm process loads the
    executable from there).

    **Returns:** ``(compiled, source)``: ``source`` is ``"cache"`` (loaded traced) or
    ``"traced"``.
    """
    lowered, source = lowered_program(name, fn, args, key)
    return lowered.compile(options), source


def lowered_program(name: str, fn, args, key: str):
    """``fn`` lowered at the shapes of ``args`` (:func:`cached_program`), ready for
    ``.compile(options)``; the compile, which releases Python's GIL, may then run in another
    thread. **Returns:** ``(lowered, source)`` as :func:`compiled_program`."""
    program, source = cached_program(name, fn, args, key)
    return program.lower(*args), source


@contextlib.contextmanager
def runtime_checks_as_nan():
    """Trace with Equinox's run-time checks returning NaN instead of raising.

    A raising check (``eqx.error_if``, e.g. lineax's check for a singular matrix in the
    implicit derivative of the event's root find, reached by forward-mode derivatives of
    ``simulate``) is a host callback, and a program with a host callback can be neither
    exported nor kept in the compilation cache. Traced under this context, a failed check makes
    the affected outputs NaN, which callers must treat as a failure (the fit does: a non-finite
    Jacobian is a rejected point). Equinox reads its ``EQX_ON_ERROR`` setting when a check is
    traced; this sets it for the duration of the block only (no effect if Equinox's internals
    differ from the version this was written for: then programs with checks are simply not
    cached).
    """
    try:
        from equinox import _errors
    except ImportError:  # pragma: no cover
        yield
        return
    old = getattr(_errors, "EQX_ON_ERROR", None)
    if old is None:
        yield
        return
    _errors.EQX_ON_ERROR = "nan"
    try:
        yield
    finally:
        _errors.EQX_ON_ERROR = old

"""The on-disk sweep: a Parquet dataset directory of part files and per-process manifests,
its checks before writing, and its readers (docs/sweeps.md has the layout)."""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .._io.tables import (
    COLUMN_UNITS,
    FAILURE_REASONS,
    RESULT_COLUMNS,
    TEXT_RESULT_COLUMNS,
    atomic_write_bytes,
)
from ._sources import SweepError

#: The format identifier a sweep's manifests carry (``"format"``); others are refused.
FORMAT = "jaximpact-sweep/1"


_PART = re.compile(r"^part-(\d{6,})\.parquet$")


# "_manifest-": since failure_reason; "manifest-": sweeps written before (still read, renamed).
_MANIFEST = re.compile(r"^_?manifest-(\d{5,})\.json$")


# Temporaries: tables.atomic_write_bytes's ".NAME.HEX.tmp" and the write test's.
_TEMP = re.compile(r"^\.(part-|_?manifest-|_write-test-).*\.tmp$")


def _part_name(chunk: int) -> str:
    return f"part-{chunk:06d}.parquet"


def _manifest_name(process: int) -> str:
    return f"_manifest-{process:05d}.json"


def _legacy_manifest_name(process: int) -> str:
    return f"manifest-{process:05d}.json"


def _is_ours(name: str) -> bool:
    """A file this module writes: a part, a manifest (either name) or a temporary."""
    return bool(_PART.match(name) or _MANIFEST.match(name) or _TEMP.match(name))


def _atomic_write_table(path: Path, table, **options) -> None:
    """Write a Parquet file so that readers see either nothing/the old file or the whole file
    (``options``: of ``pyarrow.parquet.write_table``)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    buffer = pa.BufferOutputStream()  # one chunk's file: tens of MB at most
    pq.write_table(table, buffer, **options)
    atomic_write_bytes(path, memoryview(buffer.getvalue()))  # no copy into Python bytes


def _load_manifests(directory: Path) -> dict[int, tuple[Path, dict]]:
    """``{process index: (file, manifest)}`` of every manifest in the directory.

    ``_manifest-P.json`` wins over an old-style ``manifest-P.json`` of the same process (both
    exist only for a moment, while a resume renames the old one).
    """
    for _attempt in range(10):
        out: dict[int, tuple[Path, dict]] = {}
        if not directory.is_dir():
            return out
        entry = directory
        try:
            for entry in sorted(directory.iterdir(), key=lambda e: e.name.startswith("_")):
                match = _MANIFEST.match(entry.name)
                if not match:
                    continue
                manifest = json.loads(entry.read_text(encoding="utf-8"))
                if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
                    raise SweepError(f"{entry}: not a {FORMAT} manifest")
                out[int(match.group(1))] = (entry, manifest)  # "_manifest" sorts last: wins
        except FileNotFoundError:
            continue  # renamed by another process of a distributed resume: list again
        except (OSError, json.JSONDecodeError) as err:
            # Written atomically, so this is damage from outside the sweep: say so, do not guess.
            raise SweepError(f"{entry}: unreadable sweep manifest ({err})") from None
        return out
    raise SweepError(f"{directory}: its manifests keep changing while being read")


def _result_columns(manifests: dict) -> tuple[str, ...]:
    """The result columns of the sweep's part files (a sweep keeps one schema for its life).

    Manifests written before ``failure_reason`` existed do not list them: such a sweep keeps
    the columns it was begun with when resumed, so every part file of the directory has the same
    schema (any reader can read it whole; :func:`read_sweep` fills ``failure_reason``).
    """
    legacy = RESULT_COLUMNS[:-1]
    for _, manifest in manifests.values():
        if tuple(manifest.get("result_columns", legacy)) != RESULT_COLUMNS:
            return legacy
    return RESULT_COLUMNS


def _manifest_failures(directory: Path, manifest: dict) -> dict[str, int]:
    """``{reason: count}`` over the chunks a manifest lists (``unrecorded``: an old sweep)."""
    if "failures" in manifest:
        return {str(k): int(v) for k, v in manifest["failures"].items()}
    import pyarrow.parquet as pq

    # A manifest written before failure counts were kept: count from its part files.
    counts: dict[str, int] = {}
    for chunk in manifest["completed"]:
        file = directory / _part_name(int(chunk))
        try:
            names = pq.read_schema(file).names
            table = pq.read_table(file, columns=[n for n in TEXT_RESULT_COLUMNS if n in names])
        except Exception as err:  # pyarrow raises its own types
            raise SweepError(f"{file}: listed as done but unreadable ({err})") from None
        status = table.column("status").to_pylist()
        reasons = (
            table.column("failure_reason").to_pylist()
            if "failure_reason" in table.column_names
            else [None] * len(status)
        )
        _count_failures(counts, status, reasons)
    return counts


def _count_failures(counts: dict[str, int], status, reasons) -> None:
    for s, r in zip(status, reasons, strict=True):
        if s == "failed":
            key = r or "unrecorded"
            counts[key] = counts.get(key, 0) + 1


def describe_failures(counts: dict[str, int]) -> str:
    """``"2 max_steps (the solver's step limit was reached), 1 nonfinite (...)"``, most first."""
    explain = {**FAILURE_REASONS, "unrecorded": "written before failure_reason was recorded"}
    items = sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))
    return ", ".join(f"{n} {r} ({explain.get(r, 'unknown reason')})" for r, n in items if n)


def _clear(directory: Path, keep=lambda name: False) -> None:
    """Delete this module's files (parts, manifests, temporaries) unless ``keep(name)``."""
    for entry in directory.iterdir():
        if _is_ours(entry.name) and not keep(entry.name):
            with contextlib.suppress(FileNotFoundError):
                entry.unlink()


def _prepare_output(directory: Path) -> None:
    """Create the output directory (and parents) and check that it can be written.

    Raises:
        SweepError: naming the path: it is a file, a parent is a file, it cannot be created or
            is not writable, or it is a non-empty directory that is not a sweep.
    """
    if directory.exists() and not directory.is_dir():
        raise SweepError(
            f"{directory}: exists and is not a directory (a sweep writes a directory); "
            "choose another -o"
        )
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        blocker = next((p for p in directory.parents if p.exists()), None)
        if blocker is not None and not blocker.is_dir():
            reason = f"{blocker} is not a directory"
        else:
            reason = err.strerror or str(err)
        raise SweepError(f"{directory}: cannot create the output directory ({reason})") from None
    try:
        names = [entry.name for entry in directory.iterdir()]
    except OSError as err:
        reason = err.strerror or err
        raise SweepError(f"{directory}: cannot list the output directory ({reason})") from None
    if not any(_MANIFEST.match(n) for n in names):
        foreign = sorted(n for n in names if not _is_ours(n))
        if foreign:
            more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
            raise SweepError(
                f"{directory}: not empty and not a sweep output (no _manifest-*.json; it holds "
                f"{foreign[0]!r}{more}); choose a new or empty directory for -o"
            )
    probe = directory / f"._write-test-{secrets.token_hex(6)}.tmp"
    try:
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        os.unlink(probe)
    except OSError as err:
        raise SweepError(
            f"{directory}: cannot write in the output directory ({err.strerror or err})"
        ) from None


def _setting_differences(old: dict, new: dict) -> list[str]:
    """The settings that differ between a sweep's manifest and this run, one phrase each."""

    def both(a, b) -> str:
        return f"{a} in the sweep, {b} now"

    out = []
    if old.get("jaximpact") != new["jaximpact"]:
        out.append(f"jaximpact version: {both(old.get('jaximpact'), new['jaximpact'])}")
    if old.get("scene_sha256") != new["scene_sha256"]:
        out.append(f"scene: other content, {both(old.get('scene'), new['scene'])}")
    if old.get("impacts") != new["impacts"]:
        out.extend(_impacts_differences(old.get("impacts") or {}, new["impacts"]))
    for key in ("precision", "chunk_size"):
        if old.get(key) != new[key]:
            out.append(f"{key}: {both(old.get(key), new[key])}")
    # Every other setting that differs (stored columns and precision, say) is named too; the
    # counts derived from the impacts and the chunk size only where nothing above differs.
    covered = {"jaximpact", "scene", "scene_sha256", "impacts", "precision", "chunk_size"}
    derived = set() if not out else {"n_impacts", "n_chunks", "columns"}
    for key in sorted(set(old) | set(new)):
        if key not in covered | derived and old.get(key) != new.get(key):
            out.append(f"{key}: {both(old.get(key), new.get(key))}")
    return out or ["the settings hash differs"]


def _impacts_differences(old: dict, new: dict) -> list[str]:
    def kind(f: dict) -> str:
        return "an impacts file" if "impacts_sha256" in f else "a grid"

    if kind(old) != kind(new):
        return [f"impacts: {kind(old)} in the sweep, {kind(new)} now"]
    if "impacts_sha256" in new:
        return [
            f"impacts file: other content, sha256 {old['impacts_sha256'][:12]}... in the sweep, "
            f"{new['impacts_sha256'][:12]}... now"
        ]
    old_axes, new_axes = dict(old.get("grid", [])), dict(new["grid"])
    if list(old_axes) != list(new_axes):
        return [f"grid axes: {', '.join(old_axes)} in the sweep, {', '.join(new_axes)} now"]

    def values(v: list) -> str:
        if len(v) <= 4:
            return ",".join(v)
        return f"{len(v)} values {v[0]}..{v[-1]}"

    out = [
        f"grid {k}: {values(v)} in the sweep, {values(new_axes[k])} now"
        for k, v in old_axes.items()
        if v != new_axes[k]
    ]
    old_defaults = old.get("defaults", {})
    for k, v in new.get("defaults", {}).items():
        if k not in new_axes and old_defaults.get(k) != v:
            old_value = old_defaults.get(k)
            out.append(f"{k} (the scene's [impact]): {old_value} in the sweep, {v} now")
    return out


def _merged(path) -> tuple[dict, list[int]]:
    directory = Path(path)
    manifests = _load_manifests(directory)
    if not manifests:
        raise SweepError(f"{directory}: no sweep manifest (not a sweep output, or nothing done)")
    hashes = {m["settings_hash"] for _, m in manifests.values()}
    if len(hashes) != 1:
        raise SweepError(f"{directory}: manifests from different settings: {sorted(hashes)}")
    settings = next(iter(manifests.values()))[1]["settings"]
    done = sorted({int(c) for _, m in manifests.values() for c in m["completed"]})
    return {**settings, "settings_hash": hashes.pop()}, done


def _schema(input_columns, result_columns=RESULT_COLUMNS, stored="float64"):
    """The part files' schema: float64 inputs, results as ``stored`` (float64, or float32
    where the sweep asked for it), text columns as strings; each column's SI unit as field
    metadata ``{"unit": ...}`` (none for text columns)."""
    import pyarrow as pa

    number = pa.float32() if stored == "float32" else pa.float64()

    def make_field(name: str):
        unit = COLUMN_UNITS.get(name, "")
        if name in TEXT_RESULT_COLUMNS:
            kind = pa.string()
        else:
            kind = number if name in result_columns else pa.float64()
        return pa.field(name, kind, metadata={"unit": unit} if unit else None)

    return pa.schema([make_field(n) for n in (*input_columns, *result_columns)])


def _normalized(table, file: Path, target):
    """A part file's table in the full schema: ``failure_reason`` added (null) to parts of a
    sweep begun before it existed, units attached, file metadata dropped."""
    import pyarrow as pa

    if "failure_reason" in target.names and "failure_reason" not in table.column_names:
        table = table.append_column("failure_reason", pa.nulls(table.num_rows, pa.string()))
    try:
        return pa.Table.from_arrays([table.column(n) for n in target.names], schema=target)
    except (KeyError, pa.ArrowException) as err:
        raise SweepError(f"{file}: columns differ from the sweep's ({err})") from None


def read_sweep(path, *, allow_partial: bool = False):
    """Read a sweep output directory into one ``pyarrow.Table``, rows in impact order.

    Arguments:
        path: the directory written by :func:`run_sweep` / ``jaximpact sweep``.
        allow_partial: return the completed chunks of an unfinished sweep (rows of missing
            chunks are absent) instead of raising.

    Returns:
        pyarrow.Table: the input columns, then :data:`~jaximpact.tables.RESULT_COLUMNS` (or
        the sweep's chosen ones: ``run_sweep(columns=...)``), units
        as field metadata; ``failure_reason`` is null unless ``status`` is ``failed`` (and for
        every row of a sweep begun before the column existed).

    Raises:
        SweepError: not a sweep directory, manifests that disagree, a listed part file missing
            or from other settings, or (unless ``allow_partial``) chunks not yet done.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    settings, done = _merged(path)
    missing = sorted(set(range(settings["n_chunks"])) - set(done))
    if missing and not allow_partial:
        raise SweepError(
            f"{path}: sweep incomplete: {len(missing)} of {settings['n_chunks']} chunks not done "
            f"(first: {missing[0]}); run the same command again to finish it"
        )
    target = _schema(
        settings["columns"],
        settings.get("result_columns", RESULT_COLUMNS),
        settings.get("stored_precision", "float64"),
    )
    tables = []
    for chunk in done:
        file = Path(path) / _part_name(chunk)
        try:
            table = pq.read_table(file)
        except (OSError, pa.ArrowException) as err:
            raise SweepError(f"{file}: listed as done but unreadable ({err})") from None
        meta = table.schema.metadata or {}
        if meta.get(b"jaximpact.settings_hash", b"").decode() != settings["settings_hash"]:
            raise SweepError(f"{file}: written with other settings than the manifest")
        tables.append(_normalized(table, file, target))
    if not tables:
        return target.empty_table()
    return pa.concat_tables(tables)


def read_sweep_columns(path, *, allow_partial: bool = False) -> dict[str, np.ndarray]:
    """Read a sweep output as ``{column: numpy array}`` (like ``tables.read_results``).

    Numeric columns are float64 (NaN for "not applicable"), ``status`` and ``failure_reason``
    arrays of str (``failure_reason`` ``""`` where null). Arguments and exceptions as
    :func:`read_sweep`.
    """
    table = read_sweep(path, allow_partial=allow_partial)
    out = {}
    for name in table.column_names:
        column = table.column(name)
        if name in TEXT_RESULT_COLUMNS:
            out[name] = np.array(["" if v is None else v for v in column.to_pylist()], dtype=str)
        else:
            out[name] = np.asarray(column.to_numpy(), dtype=np.float64)
    return out


def iter_chunks(path) -> Iterator:
    """Yield the completed part files of a sweep as ``pyarrow.Table``, in chunk order.

    For sweeps too large to read at once. Tables as :func:`read_sweep`'s rows (same schema);
    raises as :func:`read_sweep` (partial allowed).
    """
    import pyarrow.parquet as pq

    settings, done = _merged(path)
    target = _schema(
        settings["columns"],
        settings.get("result_columns", RESULT_COLUMNS),
        settings.get("stored_precision", "float64"),
    )
    for chunk in done:
        file = Path(path) / _part_name(chunk)
        yield _normalized(pq.read_table(file), file, target)

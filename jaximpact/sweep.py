"""Large sweeps: millions of impacts in fixed-size chunks, streamed to Parquet, resumable, sharded.

``jaximpact sweep`` (and :func:`run_sweep`) simulates an impacts table (CSV or Parquet) or a
cartesian grid of impact inputs and scene parameters, ``chunk_size`` impacts at a time:

* **One compilation.** Every chunk has the same size (the last one is padded by repeating its
  final row; padded rows are dropped on output) and the model terms and solver are chosen once
  for the whole sweep, from all its values, exactly as :func:`jaximpact.simulate` would choose
  them for the whole batch. Inside, a chunk is solved as ``simulate`` solves a batch (the same
  lanes per device at a time), and every operation is per impact, so a sweep gives
  ``simulate``'s bits on the same impacts (tested).
* **Pipelined.** Chunk ``k+1`` is dispatched (from a thread of its own, since JAX's call of a
  program sharded over several CPU devices returns only when it is done) before chunk ``k`` is
  awaited; chunk ``k``'s status codes and numeric results then come back in one transfer, are
  converted to Arrow column-wise, and a writer thread writes the part file and the manifest
  while the devices compute. So the devices always have work queued, and the host's work
  costs the sweep's rate only the CPU time it takes from the computation (BENCHMARKS.md,
  "Sweep pipeline (issue 12)").
* **Streamed output.** The output path is a directory (a Parquet dataset)::

      RESULTS.parquet/
          part-000000.parquet     # chunk 0: rows 0 .. chunk_size-1
          part-000001.parquet
          ...
          _manifest-00000.json    # process 0: settings, the chunks it completed, failure counts
          _manifest-00001.json    # (one manifest per process with --distributed)

  Each part file has the results-CSV columns: the input columns, then
  :data:`jaximpact.tables.RESULT_COLUMNS` (NaN for "not applicable"); ``status`` is a string
  and ``failure_reason`` a string that is null unless ``status`` is ``failed`` (then one of
  :data:`jaximpact.tables.FAILURE_REASONS`). Every numeric column carries its SI unit as
  Parquet field metadata (``{"unit": "m/s"}``, from :data:`jaximpact.tables.COLUMN_UNITS`).
  :func:`read_sweep` (``pyarrow.Table``) and :func:`read_sweep_columns` (``{name: numpy array}``,
  ``failure_reason`` ``""`` when null, as ``tables.read_results``) assemble the rows in order.
  Bookkeeping files start with ``_`` and temporaries with ``.`` (and end in ``.tmp``), which
  ``pyarrow.parquet.read_table(dir)``, ``pyarrow.dataset`` and pandas skip; polars and DuckDB
  read the glob ``RESULTS.parquet/*.parquet``. Sweeps written before this layout
  (``manifest-*.json``, parts without ``failure_reason``) stay readable and resumable: a resume
  renames the manifest and keeps writing the sweep's own columns, so every part of a directory
  has one schema (its ``failure_reason`` reads as null/``""``; ``--restart`` to get reasons).
* **Resumable.** A part file and then the manifest are written atomically (temporary file,
  fsync, ``os.replace``). A chunk counts as done only once a manifest lists it, so after a kill
  at any point the same command continues with the first chunk not listed: listed chunks are
  never recomputed nor rewritten, and a part file written but not yet listed is simply written
  again (same content). The manifest records the settings (scene file, impacts file or grid,
  chunk size, precision, jaximpact version) and their hash; a sweep refuses to continue into a
  directory made with other settings, naming each setting that differs, unless
  ``restart=True`` (``--restart``), which deletes the old parts. It also refuses a non-empty
  directory that is not a sweep (no manifest, files of its own), and checks that the directory
  can be created and written before computing anything.
* **Sharded.** Each chunk is split across all local JAX devices: a ``jit`` with the inputs
  sharded along the batch over a 1-D mesh (``NamedSharding(mesh, P("batch"))``), so each device
  integrates its slice; they exchange only one boolean per solver step (see ``_runner``). The
  chunk size
  must be a multiple of the local device count. Across hosts (``jax.distributed``), process
  ``p`` of ``P`` takes the chunks ``i`` with ``i % P == p`` and writes its own part files and
  its own manifest (``_manifest-<p>.json``), so processes never write the same file; readers
  merge the manifests.
* **Bounded memory.** Results are never accumulated: at most three chunks (the one computing,
  the one being converted, the one being written) are held. Inputs from a file are held as
  float64 columns (8 bytes per value; results take 16 columns); a grid is generated chunk by
  chunk.

Grid syntax (one ``--grid`` per axis, cartesian product, the last axis varying fastest)::

    NAME=VALUE                 one value            omega0=0
    NAME=V1,V2,...             a list               angle_deg=-40,0,40
    NAME=START:STOP:NUM        NUM values, linear   angle_deg=-60:60:25   (both ends included)
    NAME=START:STOP:NUM:log    NUM values, geometric speed=0.1:5:50:log

``NAME`` is ``speed``, ``angle_deg``, ``omega0`` or a scene parameter (``radius, density, K, f0,
C_A, C_H, friction, lambda``). ``speed``, ``angle_deg`` and ``omega0`` not given come from the
scene's ``[impact]``. Output input-columns: ``speed, angle_deg, omega0``, then the parameter
axes in the order given.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import re
import secrets
import signal
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .tables import (
    COLUMN_UNITS,
    FAILURE_REASONS,
    IMPACT_COLUMNS,
    IMPACT_PARAMETER_COLUMNS,
    RESULT_COLUMNS,
    TEXT_RESULT_COLUMNS,
    ImpactTable,
    TableError,
    allowed_range,
    atomic_write_bytes,
    atomic_write_text,
    check_impact_value,
    read_impacts,
)

__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "GridSource",
    "SweepError",
    "SweepSummary",
    "TableSource",
    "describe_failures",
    "parse_grid",
    "read_impacts_file",
    "read_sweep",
    "read_sweep_columns",
    "iter_chunks",
    "run_sweep",
]

FORMAT = "jaximpact-sweep/1"
DEFAULT_CHUNK_SIZE = 8192
GRID_NAMES = IMPACT_COLUMNS + IMPACT_PARAMETER_COLUMNS
_PART = re.compile(r"^part-(\d{6,})\.parquet$")
# "_manifest-": since failure_reason; "manifest-": sweeps written before (still read, renamed).
_MANIFEST = re.compile(r"^_?manifest-(\d{5,})\.json$")
# Temporaries: tables.atomic_write_bytes's ".NAME.HEX.tmp" and the write test's.
_TEMP = re.compile(r"^\.(part-|_?manifest-|_write-test-).*\.tmp$")
# Test hook only: after this many chunks are committed in one run, write the next part file and
# then SIGKILL the process before its manifest entry is written (the most delicate moment).
_KILL_ENV = "JAXIMPACT_SWEEP_KILL_AFTER"


class SweepError(ValueError):
    """Bad sweep settings: grid syntax, chunk size, or an output made with other settings."""


# ---------------------------------------------------------------------------------------------
# Impact sources


class TableSource:
    """Impacts from a table held in memory (an impacts CSV or Parquet file).

    Arguments:
        table: the validated :class:`~jaximpact.tables.ImpactTable`.
        fingerprint: what identifies the input for the settings hash (e.g. the file's sha256).
    """

    def __init__(self, table: ImpactTable, fingerprint: dict):
        self.table = table
        self.columns = tuple(table.columns)
        self.n = len(table)
        self.fingerprint = fingerprint
        self._all = {"speed": table.speed, "angle_deg": table.angle_deg, "omega0": table.omega0}
        self._all.update(table.overrides)

    def rows(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Rows ``start:stop``: every impact input present (``omega0`` always), float64."""
        return {k: v[start:stop] for k, v in self._all.items()}

    def value_sets(self) -> dict[str, np.ndarray]:
        """All values each input takes (for the model-term and solver choice)."""
        return dict(self._all)


class GridSource:
    """Impacts on a cartesian grid, generated chunk by chunk (never held in full).

    Arguments:
        axes: ``{name: 1-D float64 values}`` in product order (the last varies fastest).
        impact_defaults: ``speed``, ``angle_deg``, ``omega0`` used where no axis is given.

    Raises:
        SweepError: an unknown name, an empty axis, or a value out of range.
    """

    def __init__(self, axes: dict[str, np.ndarray], impact_defaults: dict[str, float]):
        if not axes:
            raise SweepError("the grid has no axes")
        for name, values in axes.items():
            if name not in GRID_NAMES:
                raise SweepError(f"grid: unknown name {name!r}; allowed: {', '.join(GRID_NAMES)}")
            for v in np.asarray(values, float).tolist():
                try:
                    check_impact_value(name, v)
                except TableError:
                    raise SweepError(
                        f"grid {name}: value {v!r} out of range: {allowed_range(name)}"
                    ) from None
        self.axes = {k: np.asarray(v, np.float64) for k, v in axes.items()}
        self.defaults = {k: float(impact_defaults[k]) for k in IMPACT_COLUMNS}
        self.shape = tuple(v.size for v in self.axes.values())
        self.n = math.prod(self.shape)
        self.columns = IMPACT_COLUMNS + tuple(k for k in self.axes if k not in IMPACT_COLUMNS)
        self.fingerprint = {
            "grid": [[k, [repr(float(x)) for x in v]] for k, v in self.axes.items()],
            "defaults": {k: repr(v) for k, v in self.defaults.items()},
        }

    def rows(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Rows ``start:stop`` of the product, float64."""
        index = np.unravel_index(np.arange(start, stop), self.shape)
        out = {k: np.full(stop - start, v) for k, v in self.defaults.items()}
        for (name, values), idx in zip(self.axes.items(), index, strict=True):
            out[name] = values[idx]
        return out

    def value_sets(self) -> dict[str, np.ndarray]:
        """The values each input takes (axis values; defaults as one value)."""
        out = {k: np.array([v]) for k, v in self.defaults.items()}
        out.update(self.axes)
        return out


def parse_grid(specs: Sequence[str]) -> dict[str, np.ndarray]:
    """Parse ``--grid`` specifications (see the module docstring for the syntax).

    Arguments:
        specs: strings like ``"speed=0.1:5:50:log"``, ``"angle_deg=-40,0,40"``, ``"f0=325"``.

    Returns:
        dict: ``{name: float64 values}`` in the order given.

    Raises:
        SweepError: bad syntax, an unknown or repeated name, a non-finite number, ``NUM < 1``,
            or a log range that does not have both ends > 0.
    """
    axes: dict[str, np.ndarray] = {}
    for spec in specs:
        name, sep, body = spec.partition("=")
        name, body = name.strip(), body.strip()
        hint = (
            f"grid {spec!r}: expected NAME=VALUE, NAME=V1,V2,..., NAME=START:STOP:NUM "
            "or NAME=START:STOP:NUM:log"
        )
        if not sep or not name or not body:
            raise SweepError(hint)
        if name not in GRID_NAMES:
            raise SweepError(
                f"grid {spec!r}: unknown name {name!r}; allowed: {', '.join(GRID_NAMES)}"
            )
        if name in axes:
            raise SweepError(f"grid {spec!r}: {name} given twice")

        number = lambda text, hint=hint: _grid_number(text, hint)  # noqa: E731

        if ":" in body:
            parts = body.split(":")
            log = len(parts) == 4 and parts[3].strip() == "log"
            if len(parts) not in (3, 4) or (len(parts) == 4 and not log):
                raise SweepError(hint)
            start, stop = number(parts[0]), number(parts[1])
            try:
                num = int(parts[2])
            except ValueError:
                raise SweepError(f"{hint}; NUM {parts[2].strip()!r} is not an integer") from None
            if num < 1:
                raise SweepError(f"grid {spec!r}: NUM must be >= 1")
            if log:
                if start <= 0 or stop <= 0:
                    raise SweepError(f"grid {spec!r}: a log range needs START > 0 and STOP > 0")
                values = np.geomspace(start, stop, num)
            else:
                values = np.linspace(start, stop, num)
        else:
            values = np.array([number(t) for t in body.split(",")])
        axes[name] = values
    return axes


def _grid_number(text: str, hint: str) -> float:
    """One finite number of a grid specification."""
    try:
        value = float(text)
    except ValueError:
        raise SweepError(f"{hint}; {text.strip()!r} is not a number") from None
    if not math.isfinite(value):
        raise SweepError(f"{hint}; {text.strip()!r} is not finite")
    return value


def read_impacts_file(path) -> TableSource:
    """Read an impacts table from CSV (``.csv``) or Parquet (any other suffix).

    The Parquet file has the columns of the impacts CSV (numbers, no nulls).

    Raises:
        TableError: as :func:`jaximpact.tables.read_impacts`: missing, unknown or invalid
            columns and values, named by file and column (and line for CSV).
        OSError: the file cannot be read.
    """
    path = Path(path)
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    fingerprint = {"impacts_sha256": digest.hexdigest()}
    if path.suffix.lower() == ".csv":
        return TableSource(read_impacts(path), fingerprint)
    import pyarrow.parquet as pq

    try:
        data = pq.read_table(path)
    except Exception as err:  # pyarrow raises its own types for a corrupt or non-Parquet file
        raise TableError(f"{path}: not a readable Parquet file ({err})", path=path) from None
    allowed = IMPACT_COLUMNS + IMPACT_PARAMETER_COLUMNS
    for name in data.column_names:
        if name not in allowed:
            raise TableError(
                f"{path}, column '{name}': unknown column; allowed columns: {', '.join(allowed)}",
                path=path,
                column=name,
            )
    for name in ("speed", "angle_deg"):
        if name not in data.column_names:
            raise TableError(f"{path}, column '{name}': required column missing", path=path)
    values = {}
    for name in data.column_names:
        column = data.column(name)
        if column.null_count:
            raise TableError(f"{path}, column '{name}': null values", path=path, column=name)
        try:
            values[name] = np.asarray(column.to_numpy(), dtype=np.float64)
        except (TypeError, ValueError):
            raise TableError(f"{path}, column '{name}': not numbers", path=path) from None
    table = ImpactTable(
        speed=values["speed"],
        angle_deg=values["angle_deg"],
        omega0=values.get("omega0"),
        overrides={k: v for k, v in values.items() if k in IMPACT_PARAMETER_COLUMNS},
        columns=tuple(data.column_names),
        source=str(path),
    )
    return TableSource(table, fingerprint)


# ---------------------------------------------------------------------------------------------
# Output directory: part files and manifests
#
# Bookkeeping files start with "_" and temporaries with "." (and end in ".tmp"), so that Parquet
# readers that open the directory (pyarrow.parquet.read_table, pyarrow.dataset, pandas) skip
# them. Sweeps written before this rule named their manifests "manifest-PPPPP.json": they are
# read too, and a resume renames them.


def _part_name(chunk: int) -> str:
    return f"part-{chunk:06d}.parquet"


def _manifest_name(process: int) -> str:
    return f"_manifest-{process:05d}.json"


def _legacy_manifest_name(process: int) -> str:
    return f"manifest-{process:05d}.json"


def _is_ours(name: str) -> bool:
    """A file this module writes: a part, a manifest (either name) or a temporary."""
    return bool(_PART.match(name) or _MANIFEST.match(name) or _TEMP.match(name))


def _atomic_write_table(path: Path, table) -> None:
    """Write a Parquet file so that readers see either nothing/the old file or the whole file."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    buffer = pa.BufferOutputStream()  # one chunk's file: a few MB at most
    pq.write_table(table, buffer)
    atomic_write_bytes(path, buffer.getvalue().to_pybytes())


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
    if not out:  # what remains is derived from the above; say it anyway
        for key in sorted(set(old) | set(new)):
            if key != "scene" and old.get(key) != new.get(key):
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


# ---------------------------------------------------------------------------------------------
# Reading


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


def _schema(input_columns, result_columns=RESULT_COLUMNS):
    """The part files' schema: float64 inputs and results, text columns as strings; each
    column's SI unit as field metadata ``{"unit": ...}`` (none for text columns)."""
    import pyarrow as pa

    def make_field(name: str):
        unit = COLUMN_UNITS.get(name, "")
        kind = pa.string() if name in TEXT_RESULT_COLUMNS else pa.float64()
        return pa.field(name, kind, metadata={"unit": unit} if unit else None)

    return pa.schema([make_field(n) for n in (*input_columns, *result_columns)])


def _normalized(table, file: Path, target):
    """A part file's table in the full schema: ``failure_reason`` added (null) to parts of a
    sweep begun before it existed, units attached, file metadata dropped."""
    import pyarrow as pa

    if "failure_reason" not in table.column_names:
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
        pyarrow.Table: the input columns, then :data:`~jaximpact.tables.RESULT_COLUMNS`, units
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
    target = _schema(settings["columns"])
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


# ---------------------------------------------------------------------------------------------
# Running


@dataclass(frozen=True)
class SweepSummary:
    """What one :func:`run_sweep` call did (for this process).

    Attributes:
        output: the output directory.
        n_impacts, n_chunks, chunk_size: the whole sweep.
        chunks_run: chunks computed by this call; ``chunks_skipped``: this process's chunks
            already done before it started.
        impacts_run: impacts (without padding) computed by this call.
        failed: impacts with status ``failed`` among those computed by this call.
        seconds: wall time of the call; ``devices``: local devices used.
        complete: every chunk of the sweep is listed in the manifests as seen at the end.
        impacts_done: impacts in the chunks the manifests list at the end (every process, every
            call; ``n_impacts`` once complete).
        failures: ``{failure_reason: count}`` over those impacts (``unrecorded``: failed in a
            sweep begun before reasons were recorded); empty when none failed.
        legacy_columns: the sweep was begun before ``failure_reason`` existed; its part files
            keep the older columns (one schema per directory), so reasons are not stored.
    """

    output: str
    n_impacts: int
    n_chunks: int
    chunk_size: int
    chunks_run: int
    chunks_skipped: int
    impacts_run: int
    failed: int
    seconds: float
    devices: int
    complete: bool
    impacts_done: int = 0
    failures: dict = field(default_factory=dict)
    legacy_columns: bool = False


_RUNNERS: dict = {}
_STIFFNESS: list = []  # the jitted stiffness estimate, made on first use (jax imports lazily)

# How the sweep's program solves a chunk: the batch path of ``jaximpact.simulate`` (its
# ``_simulate``), so that a sweep gives simulate's bits. ``loop``: simulate's choice for
# concrete inputs (a sweep never differentiates).
_LOOP = "pool"


def _runner(terms, cfg, devices):
    """The jitted, sharded program that solves one chunk (cached per model, solver, devices).

    A ``jit`` of the simulator's batch function with its inputs sharded along the batch over a
    1-D mesh of the local devices: XLA's SPMD partitioner gives each device its slice of the
    chunk. The compiled program exchanges no data between devices, only one boolean per solver
    step (the batched while-loop's "any impact still running", an all-reduce), so the devices
    step in lockstep as a single-device ``vmap`` does for its whole batch. (``jax.shard_map``,
    which would let each device stop on its own, does not work here: under it lineax, used by
    the event root finder, rejects the manual-mesh shardings of its own traced values -
    "pytree does not match out_structure" - with jax 0.10.)

    Inside, the chunk is solved as ``simulate`` solves a batch of that size on these devices:
    the same lanes per device at a time (``chunk``, ``shards``; ``lax.map`` over sub-chunks on
    a CPU). Returns ``(fn, sharding)``: ``fn(params, speed, angle_deg, omega0)`` gives the
    status codes and the numeric result columns stacked as one ``(len(OUTPUT_FIELDS), size)``
    array, so that fetching a chunk is one transfer of what its part file holds (not the step
    counts).
    """
    import jax
    import jax.numpy as jnp
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as P

    from ._results import OUTPUT_FIELDS
    from ._simulate import _default_chunk, _simulate_flat
    from ._tsit5 import lane_group

    shards = len(devices)
    chunk = _default_chunk(shards)
    key = (terms, cfg, tuple(d.id for d in devices), chunk, _LOOP)
    if key not in _RUNNERS:
        mesh = Mesh(np.array(devices), ("batch",))
        sharding = NamedSharding(mesh, P("batch"))

        def sweep_chunk(params, speed, angle_deg, omega0):
            inputs = (params, speed, angle_deg, omega0)
            size = speed.shape[0]
            # as simulate: at least 2 lanes, whole lane groups per device (per_state form)
            pad = -size % (shards * max(2, lane_group(speed.dtype, cfg.stages)))
            inputs = jax.tree_util.tree_map(lambda x: jnp.pad(x, (0, pad), mode="edge"), inputs)
            result = _simulate_flat(terms, cfg, *inputs, chunk=chunk, shards=shards, loop=_LOOP)
            values = jnp.stack([getattr(result, k)[:size] for k in OUTPUT_FIELDS])
            return result.status[:size], values

        fn = jax.jit(
            sweep_chunk,
            in_shardings=sharding,
            out_shardings=(sharding, NamedSharding(mesh, P(None, "batch"))),
        )
        _RUNNERS[key] = (fn, sharding)
    return _RUNNERS[key]


def _params(base: dict, rows: dict, size: int, dtype) -> dict:
    """Per-impact parameter arrays: the row's override, else the scene's value."""
    return {k: np.asarray(rows[k] if k in rows else np.full(size, base[k]), dtype) for k in base}


def _padded_rows(source, start: int, chunk_size: int) -> tuple[dict, int]:
    """Rows ``start:start+chunk_size`` of ``source`` and how many are real.

    A short last chunk is padded by repeating its last row: a valid impact, so padding cannot
    fail or slow down the solver, and the shape (hence the compilation) stays the same.
    """
    stop = min(start + chunk_size, source.n)
    rows = source.rows(start, stop)
    valid = stop - start
    if valid == chunk_size:
        return rows, valid
    pad = np.concatenate([np.arange(valid), np.full(chunk_size - valid, valid - 1)])
    return {k: v[pad] for k, v in rows.items()}, valid


def _chunk_inputs(source, base: dict, chunk: int, chunk_size: int, dtype):
    """Chunk ``chunk``'s rows (unpadded, for its part file), its number of real rows, and the
    padded program inputs ``[params, speed, angle_deg, omega0]`` as host arrays."""
    padded, valid = _padded_rows(source, chunk * chunk_size, chunk_size)
    rows = {k: v[:valid] for k, v in padded.items()}
    prm = _params(base, padded, chunk_size, dtype)
    return rows, valid, [prm] + [np.asarray(padded[k], dtype) for k in IMPACT_COLUMNS]


def _dispatch(fn, sharding, args):
    """Put a chunk's inputs on the devices and run its program (asynchronously where JAX can);
    the copy of its results to the host starts as soon as they are computed (on a GPU)."""
    import jax

    result = fn(*jax.device_put(args, sharding))
    for array in result:
        array.copy_to_host_async()
    return result


def _fetch(result, valid: int) -> tuple[np.ndarray, np.ndarray]:
    """Wait for a chunk's program and copy its status codes and result columns to the host."""
    import jax

    status, values = jax.device_get(result)
    return np.asarray(status[:valid]), np.asarray(values[:, :valid])


def _model_config(scene, source, chunk_size: int, dtype):
    """Model terms and solver settings for the whole sweep (static: one compilation).

    The same choice :func:`jaximpact.simulate` makes for one batch holding every impact: the
    terms from all values each input takes; with ``method = "auto"``, Kvaerno5 if the stiffness
    estimate of any impact exceeds the limit (computed chunk by chunk to bound memory, in one
    compiled function of the padded chunk, read back once at the end).
    """
    import jax
    import jax.numpy as jnp

    from ._simulate import (
        integration_settings,
        required_terms,
        scene_parameters,
        stiffness_estimate,
    )

    base = {k: float(v) for k, v in scene_parameters(scene).items()}
    sets = source.value_sets()
    params = {k: np.asarray(sets.get(k, base[k]), np.float64) for k in base}
    terms = required_terms(scene, params, sets["angle_deg"], sets["omega0"])
    method = scene.solver.method
    if method == "auto":
        if not _STIFFNESS:
            _STIFFNESS.append(jax.jit(stiffness_estimate))
        stiffness = None
        for start in range(0, source.n, chunk_size):
            rows, _ = _padded_rows(source, start, chunk_size)  # the copies: the same maximum
            prm = _params(base, rows, chunk_size, dtype)
            estimate = _STIFFNESS[0](prm, rows["speed"].astype(dtype), rows["angle_deg"])
            stiffness = estimate if stiffness is None else jnp.maximum(stiffness, estimate)
        method = "kvaerno5" if float(stiffness) > scene.solver.stiffness_limit else "tsit5"
    one = {k: np.ones(1) for k in base}
    cfg = integration_settings(scene, one, np.ones(1), np.zeros(1), dtype, method)
    return base, terms, cfg


def _settings(scene_path, source, chunk_size: int, dtype) -> tuple[dict, str]:
    from . import __version__
    from ._scene_io import describe_scene_source
    from ._scene_io import scene_path as resolve_scene

    scene_file = resolve_scene(scene_path)  # an embedded scene's name, or a path
    settings = {
        "format": FORMAT,
        "jaximpact": __version__,
        "scene": describe_scene_source(scene_path),
        "scene_sha256": hashlib.sha256(scene_file.read_bytes()).hexdigest(),
        "impacts": source.fingerprint,
        "precision": np.dtype(dtype).name,
        "chunk_size": chunk_size,
        "n_impacts": source.n,
        "n_chunks": -(-source.n // chunk_size),
        "columns": list(source.columns),
    }
    # The hash covers what determines the numbers; not the scene's path (moving a file is fine).
    hashed = {k: v for k, v in settings.items() if k != "scene"}
    digest = hashlib.sha256(json.dumps(hashed, sort_keys=True).encode()).hexdigest()
    return settings, digest


def _status_texts():
    """Arrow string arrays indexed by status code: the ``status`` column's text
    (rebound/captured/failed) and ``failure_reason``'s (null unless failed)."""
    import pyarrow as pa

    from ._results import Status

    codes = range(max(Status.NAMES) + 1)
    status = pa.array([Status.csv_name(c) for c in codes], pa.string())
    reason = [Status.NAMES[c] if c >= Status.MAX_STEPS else None for c in codes]
    return status, pa.array(reason, pa.string())


def _failure_counts(status: np.ndarray) -> dict[str, int]:
    """``{failure_reason: count}`` of a chunk's status codes (failed impacts only)."""
    from ._results import Status

    counts = np.bincount(status, minlength=max(Status.NAMES) + 1)
    return {Status.NAMES[c]: int(n) for c, n in enumerate(counts) if c >= Status.MAX_STEPS and n}


def _chunk_table(inputs: dict, columns, status, values, settings_hash: str, result_columns):
    """One chunk's part file: inputs, then ``result_columns`` (``failure_reason`` null unless
    failed), units as field metadata, the settings hash as file metadata. ``status``: codes;
    ``values``: the numeric result columns in ``OUTPUT_FIELDS`` order (``_fetch``)."""
    import pyarrow as pa

    from ._results import OUTPUT_FIELDS

    arrays = [pa.array(np.asarray(inputs[k], np.float64)) for k in columns]
    numbers = dict(zip(OUTPUT_FIELDS, values, strict=True))
    codes = pa.array(np.asarray(status, np.int32))
    status_text, reason_text = _status_texts()
    for name in result_columns:
        if name == "status":
            arrays.append(status_text.take(codes))
        elif name == "failure_reason":
            arrays.append(reason_text.take(codes))
        else:
            arrays.append(pa.array(np.asarray(numbers[name], np.float64)))
    table = pa.Table.from_arrays(arrays, schema=_schema(columns, result_columns))
    return table.replace_schema_metadata({"jaximpact.settings_hash": settings_hash})


class _Writer:
    """Writes finished chunks in a thread of its own, one at a time and in order.

    ``write(*item)`` runs in the thread (part file, then manifest). ``submit`` first waits for
    the previous item, so at most one chunk is being written while the next is fetched and
    converted; an error in the thread is raised by the next ``submit`` or by ``finish``.
    """

    def __init__(self, write):
        import queue
        import threading

        self._write = write
        self._queue: queue.Queue = queue.Queue()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="sweep-writer", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            try:
                if item is None:
                    return
                if self._error is None:
                    self._write(*item)
            except BaseException as err:  # handed to the main thread
                self._error = err
            finally:
                self._queue.task_done()

    def _check(self) -> None:
        if self._error is not None:
            raise self._error

    def submit(self, *item) -> None:
        self._queue.join()
        self._check()
        self._queue.put(item)

    def finish(self) -> None:
        """Wait until everything submitted is written; raise the thread's error, if any."""
        self._queue.join()
        self._check()

    def close(self) -> None:
        """Stop the thread after what it holds (also after an error in the main thread)."""
        self._queue.put(None)
        self._thread.join()


def run_sweep(
    source: TableSource | GridSource,
    output,
    *,
    scene_path=None,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    restart: bool = False,
    progress: bool = True,
    process_index: int | None = None,
    process_count: int | None = None,
) -> SweepSummary:
    """Run (or continue) a sweep, writing each finished chunk to ``output``.

    Set the precision first (``jax.config.update("jax_enable_x64", True)`` for float64); it is
    part of the settings.

    Arguments:
        source: the impacts (:func:`read_impacts_file`, or :class:`GridSource`).
        output: the output directory (created if missing).
        scene_path: an embedded scene's name or a scene file; ``None``: the embedded Table 1
            scene.
        chunk_size: impacts per chunk; a multiple of the number of local JAX devices.
        restart: delete results made with other settings (or any results) and start over.
        progress: show a tqdm progress bar on stderr (impacts/s, ETA).
        process_index, process_count: this process's share (chunks ``i`` with
            ``i % process_count == process_index``); default ``jax.process_index()`` and
            ``jax.process_count()`` (0 and 1 without ``jax.distributed``).

    Returns:
        SweepSummary: what this call computed.

    Raises:
        SweepError: chunk size not a positive multiple of the device count, bad process share,
            ``output`` a file, not creatable or not writable, a non-empty directory that is
            not a sweep, or results there made with other settings (without ``restart``; the
            message names each setting that differs). All raised before any computing.
        SceneError: the scene file is invalid. OSError: files cannot be read or written.
    """
    import jax
    import jax.numpy as jnp
    from tqdm import tqdm

    from . import load_scene

    t_start = time.perf_counter()
    devices = jax.local_devices()
    if chunk_size < 1 or chunk_size % len(devices):
        raise SweepError(
            f"--chunk-size {chunk_size} must be a positive multiple of the number of local "
            f"devices ({len(devices)}: {', '.join(str(d) for d in devices)})"
        )
    index = jax.process_index() if process_index is None else process_index
    count = jax.process_count() if process_count is None else process_count
    if not 0 <= index < count:
        raise SweepError(f"process index {index} is not in [0, {count})")
    dtype = jnp.result_type(float)
    scene = load_scene(scene_path)
    settings, digest = _settings(scene_path, source, chunk_size, dtype)
    n_chunks = settings["n_chunks"]

    directory = Path(output)
    _prepare_output(directory)  # before any computing: every file problem first
    mine = [c for c in range(n_chunks) if c % count == index]
    if restart:
        # Each process deletes only what it will rewrite, so concurrent processes of a
        # distributed restart never delete each other's new files; process 0 also deletes what
        # no process of this run owns (parts past the end, manifests of a larger old run).
        own = {_part_name(c) for c in mine}
        own |= {_manifest_name(index), _legacy_manifest_name(index)}

        def keep(name: str) -> bool:
            if name in own:
                return False
            if index != 0:
                return True
            part, manifest = _PART.match(name), _MANIFEST.match(name)
            if part:
                return int(part.group(1)) < n_chunks
            if manifest:
                return int(manifest.group(1)) < count
            return True  # others' temporaries may be in flight

        _clear(directory, keep)
        manifests = {}
    else:
        manifests = _load_manifests(directory)
        for _, m in manifests.values():
            if m.get("settings_hash") != digest:
                differences = _setting_differences(m.get("settings") or {}, settings)
                raise SweepError(
                    f"{directory}: a sweep made with other settings: {'; '.join(differences)}. "
                    "Use --restart to discard its results, or another -o"
                )
        # Old-style manifest names (before "_manifest-"): this process renames its own (process
        # 0 also those no process of this run owns), so Parquet readers skip them from now on.
        for p, (file, m) in list(manifests.items()):
            if (p == index or (index == 0 and p >= count)) and file.name != _manifest_name(p):
                os.replace(file, directory / _manifest_name(p))
                manifests[p] = (directory / _manifest_name(p), m)
    result_columns = _result_columns(manifests)
    done = {int(c) for _, m in manifests.values() for c in m["completed"]}
    own_manifest = manifests[index][1] if index in manifests else {"completed": []}
    own_completed = sorted(int(c) for c in own_manifest["completed"])
    own_failures = _manifest_failures(directory, own_manifest) if own_completed else {}
    todo = [c for c in mine if c not in done]

    base, terms, cfg = _model_config(scene, source, chunk_size, dtype)
    fn, sharding = _runner(terms, cfg, devices)
    kill_after = os.environ.get(_KILL_ENV)
    kill_after = None if kill_after is None else int(kill_after)

    def launch(chunk: int):
        """Build chunk ``chunk``'s inputs and dispatch it (in the dispatcher thread)."""
        rows, valid, args = _chunk_inputs(source, base, chunk, chunk_size, dtype)
        return chunk, valid, rows, dispatcher.submit(_dispatch, fn, sharding, args)

    def write(chunk: int, valid: int, table, counts: dict) -> None:
        """In the writer thread: the part file, then the manifest that lists it."""
        nonlocal failed, impacts_run
        _atomic_write_table(directory / _part_name(chunk), table)
        if kill_after is not None and len(own_completed) - skipped_own >= kill_after:
            os.kill(os.getpid(), signal.SIGKILL)  # test hook: die before the manifest update
        own_completed.append(chunk)
        # Counted in memory (reasons are known even where the sweep's columns lack them), and
        # stored with the completed list in one atomic write.
        for reason, n in counts.items():
            own_failures[reason] = own_failures.get(reason, 0) + n
        manifest = {
            "format": FORMAT,
            "settings_hash": digest,
            "settings": settings,
            "process_index": index,
            "process_count": count,
            "result_columns": list(result_columns),
            "completed": sorted(own_completed),
            "failures": dict(sorted(own_failures.items())),
        }
        atomic_write_text(directory / _manifest_name(index), json.dumps(manifest, indent=1) + "\n")
        failed += sum(counts.values())
        impacts_run += valid
        bar.update(valid)

    def hand_over(chunk: int, valid: int, rows: dict, result) -> None:
        """Wait for the chunk, convert it and give it to the writer."""
        status, values = _fetch(result.result(), valid)
        table = _chunk_table(rows, source.columns, status, values, digest, result_columns)
        writer.submit(chunk, valid, table, _failure_counts(status))

    skipped_own = len(own_completed)
    total = sum(min(chunk_size, source.n - c * chunk_size) for c in mine)
    bar = tqdm(
        total=total,
        initial=total - sum(min(chunk_size, source.n - c * chunk_size) for c in todo),
        unit="impact",
        unit_scale=True,
        smoothing=0.1,
        # No bar for a single chunk (it would jump from 0 to 100 %) nor for work under a second.
        disable=not progress or len(todo) < 2,
        delay=1.0,
        desc=f"sweep {directory.name}" + (f" [process {index}/{count}]" if count > 1 else ""),
    )
    failed = impacts_run = 0
    pending = None
    writer = _Writer(write)
    # JAX runs a program on one CPU device asynchronously, but the call of a program sharded
    # over several CPU devices returns only when the chunk is done (measured): calls from a
    # thread of their own keep this thread free to fetch and convert the chunk before.
    dispatcher = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sweep-dispatch")
    try:
        # Dispatch chunk k+1 before waiting for chunk k: the devices always have the next chunk
        # while the host fetches, converts and (in the writer thread) writes the last one.
        for chunk in todo:
            launched = launch(chunk)
            if pending is not None:
                hand_over(*pending)
            pending = launched
        if pending is not None:
            hand_over(*pending)
        writer.finish()
    finally:
        dispatcher.shutdown(wait=True, cancel_futures=True)
        writer.close()
        bar.close()
    final = _load_manifests(directory)
    finished = {int(c) for _, m in final.values() for c in m["completed"]}
    failures: dict[str, int] = {}
    for _, m in final.values():
        for reason, n in _manifest_failures(directory, m).items():
            failures[reason] = failures.get(reason, 0) + n
    return SweepSummary(
        output=str(directory),
        n_impacts=source.n,
        n_chunks=n_chunks,
        chunk_size=chunk_size,
        chunks_run=len(todo),
        chunks_skipped=len(mine) - len(todo),
        impacts_run=impacts_run,
        failed=failed,
        seconds=time.perf_counter() - t_start,
        devices=len(devices),
        complete=finished >= set(range(n_chunks)),
        impacts_done=sum(min(chunk_size, source.n - c * chunk_size) for c in finished),
        failures=failures,
        legacy_columns=result_columns != RESULT_COLUMNS,
    )


def iter_chunks(path) -> Iterator:
    """Yield the completed part files of a sweep as ``pyarrow.Table``, in chunk order.

    For sweeps too large to read at once. Tables as :func:`read_sweep`'s rows (same schema);
    raises as :func:`read_sweep` (partial allowed).
    """
    import pyarrow.parquet as pq

    settings, done = _merged(path)
    target = _schema(settings["columns"])
    for chunk in done:
        file = Path(path) / _part_name(chunk)
        yield _normalized(pq.read_table(file), file, target)

"""Impact tables (CSV input) and results files (CSV output), numpy only.

File formats are those of the project conventions:

* impacts CSV: a header row with ``speed`` (m/s, > 0) and ``angle_deg`` (from the surface
  normal, in (-90, 90)), optionally ``omega0`` (rad/s, default 0) and any of
  :data:`IMPACT_PARAMETER_COLUMNS`, which override the scene for that row;
* results CSV: the input columns, then :data:`RESULT_COLUMNS`.

In both, lines starting with ``#`` are comments, blank lines are ignored and whitespace around
fields is ignored. Every problem in an input file is a :class:`TableError` (a ``ValueError``)
naming the file, the 1-based line number (as an editor shows it, comment lines included), the
column and the allowed values: a row is never dropped silently.

This module deliberately imports no JAX so that readers, writers and their tests stay light; the
small parsing helpers (:func:`read_csv_rows`, :func:`parse_number`, :func:`check_impact_value`)
are shared with ``fitting._data``.
"""

from __future__ import annotations

import contextlib
import csv
import io
import math
import os
import secrets
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "IMPACT_COLUMNS",
    "IMPACT_PARAMETER_COLUMNS",
    "RESULT_COLUMNS",
    "RESULT_STATUSES",
    "COLUMN_UNITS",
    "FAILURE_REASONS",
    "TEXT_RESULT_COLUMNS",
    "CsvRows",
    "ImpactTable",
    "TableError",
    "allowed_range",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_impact_value",
    "located_error",
    "parse_number",
    "read_csv_rows",
    "read_impacts",
    "read_results",
    "readonly_array",
    "write_results",
]

#: Columns that describe the impact itself; ``speed`` and ``angle_deg`` are required.
IMPACT_COLUMNS = ("speed", "angle_deg", "omega0")

#: Scene parameters that an impacts CSV may override per row.
IMPACT_PARAMETER_COLUMNS = ("radius", "density", "K", "f0", "C_A", "C_H", "friction", "lambda")

#: Columns a results CSV holds after the input columns, in this order.
RESULT_COLUMNS = (
    "status",
    "vn_out",
    "vt_out",
    "omega_out",
    "cor_n",
    "cor_t",
    "rebound_angle_deg",
    "contact_time",
    "roll_time",
    "max_overlap",
    "energy_in",
    "energy_out",
    "loss_hertz_damping",
    "loss_adhesion_damping",
    "loss_friction",
    "loss_rolling",
    "failure_reason",
)

#: Result columns that hold text; the others are numbers (NaN, an empty field, where they do
#: not apply). ``failure_reason`` is empty unless ``status`` is ``failed``, then one of
#: :data:`FAILURE_REASONS`.
TEXT_RESULT_COLUMNS = ("status", "failure_reason")

#: Why an impact failed (the ``failure_reason`` column; ``jaximpact.Status`` names them too).
FAILURE_REASONS = {
    "max_steps": "the solver's step limit was reached",
    "nonfinite": "the state became NaN or infinite",
    "solver_error": "the solver failed",
}

#: SI units of every impacts- and results-file column (CSV headers keep the bare names).
COLUMN_UNITS = {
    "speed": "m/s",
    "angle_deg": "deg",
    "omega0": "rad/s",
    "radius": "m",
    "density": "kg/m^3",
    "K": "N/m^2",
    "f0": "N/m",
    "C_A": "s/m",
    "C_H": "s/m",
    "friction": "1",
    "lambda": "N m",
    "status": "",
    "vn_out": "m/s",
    "vt_out": "m/s",
    "omega_out": "rad/s",
    "cor_n": "1",
    "cor_t": "1",
    "rebound_angle_deg": "deg",
    "contact_time": "s",
    "roll_time": "s",
    "max_overlap": "m",
    "energy_in": "J",
    "energy_out": "J",
    "loss_hertz_damping": "J",
    "loss_adhesion_damping": "J",
    "loss_friction": "J",
    "loss_rolling": "J",
    "failure_reason": "",
}

#: The statuses the conventions define for a simulated impact.
RESULT_STATUSES = ("rebound", "captured", "failed")

_POSITIVE = ("radius", "density", "K")
_NON_NEGATIVE = ("f0", "C_A", "C_H", "friction", "lambda")


class TableError(ValueError):
    """A problem in a table file (or in arrays meant for one).

    The message names the file, line and column; they are also kept as attributes (``None``
    where they do not apply) so that a command-line tool can report them its own way.
    """

    def __init__(self, message: str, *, path=None, line=None, column=None):
        super().__init__(message)
        self.path = None if path is None else str(path)
        self.line = line
        self.column = column


def located_error(error: type[TableError], path, line, column, problem: str) -> TableError:
    """Build ``error`` with the standard "file, line N, column 'c': problem" message."""
    where = [str(path) if path is not None else "<table>"]
    if line is not None:
        where.append(f"line {line}")
    if column is not None:
        where.append(f"column '{column}'")
    return error(f"{', '.join(where)}: {problem}", path=path, line=line, column=column)


# ---------------------------------------------------------------------------------------------
# Value ranges


def allowed_range(name: str) -> str:
    """Describe the allowed values of impact column ``name`` (for error messages).

    Raises:
        KeyError: ``name`` is not an impact or parameter column.
    """
    if name == "speed" or name in _POSITIVE:
        return f"{name} must be finite and > 0"
    if name == "angle_deg":
        return "angle_deg must be finite, with -90 < angle_deg < 90"
    if name == "omega0":
        return "omega0 must be finite"
    if name in _NON_NEGATIVE:
        return f"{name} must be finite and >= 0"
    raise KeyError(name)


def _in_range(name: str, value: float) -> bool:
    if not math.isfinite(value):
        return False
    if name == "speed" or name in _POSITIVE:
        return value > 0
    if name == "angle_deg":
        return abs(value) < 90
    if name in _NON_NEGATIVE:
        return value >= 0
    return True  # omega0: any finite spin


def check_impact_value(
    name: str, value: float, *, path=None, line=None, error: type[TableError] = TableError
) -> None:
    """Check one impact or parameter value against its allowed range.

    Arguments:
        name: column name (one of :data:`IMPACT_COLUMNS` or :data:`IMPACT_PARAMETER_COLUMNS`).
        value: the value.
        path, line: where it came from, for the message.
        error: the exception class to raise (a :class:`TableError` subclass).

    Raises:
        TableError: (or ``error``) the value is out of range or not finite.
    """
    if not _in_range(name, value):
        raise located_error(
            error, path, line, name, f"value {value!r} out of range: {allowed_range(name)}"
        )


# ---------------------------------------------------------------------------------------------
# Generic CSV reading


@dataclass(frozen=True)
class CsvRows:
    """The raw content of a commented CSV file.

    Attributes:
        path: the file, as given.
        preamble: the ``#`` comment lines before the header, without the leading ``#`` and one
            following space (blank lines among them kept as empty strings).
        header: the column names, stripped.
        header_line: line number of the header.
        rows: ``(line number, fields)`` for every data line, fields stripped.
    """

    path: str
    preamble: tuple[str, ...]
    header: tuple[str, ...]
    header_line: int
    rows: tuple[tuple[int, tuple[str, ...]], ...]


def _split(line: str) -> tuple[str, ...]:
    # The csv module handles quoted fields (e.g. a status text with a comma) correctly.
    return tuple(f.strip() for f in next(csv.reader([line])))


def read_csv_rows(path, *, error: type[TableError] = TableError) -> CsvRows:
    """Read a CSV file with ``#`` comments into a header and numbered rows.

    Checks only the structure: a header exists, its names are non-empty and distinct, and every
    data row has as many fields as the header.

    Arguments:
        path: the file.
        error: the exception class to raise.

    Returns:
        CsvRows: the header, the rows with their line numbers, and the leading comments.

    Raises:
        TableError: (or ``error``) no header, an empty or repeated column name, or a row with
            the wrong number of fields.
        OSError: the file cannot be read.
    """
    preamble: list[str] = []
    header: tuple[str, ...] | None = None
    header_line = 0
    rows: list[tuple[int, tuple[str, ...]]] = []
    # utf-8-sig: spreadsheet programs often put a byte-order mark in front of the header.
    # newline=None: \r\n and \r count as one line end, so line numbers match an editor's.
    with open(path, encoding="utf-8-sig", newline=None) as f:
        for number, raw in enumerate(f, start=1):
            text = raw.strip()
            if text.startswith("#"):
                if header is None:
                    preamble.append(text[1:].removeprefix(" "))
                continue
            if not text:
                if header is None and preamble:
                    preamble.append("")
                continue
            fields = _split(text)
            if header is None:
                header, header_line = fields, number
                for name in header:
                    if not name:
                        raise located_error(
                            error, path, number, None, "empty column name in the header"
                        )
                    if header.count(name) > 1:
                        raise located_error(
                            error, path, number, name, "column named twice in the header"
                        )
                continue
            if len(fields) != len(header):
                raise located_error(
                    error,
                    path,
                    number,
                    None,
                    f"expected {len(header)} fields ({', '.join(header)}), found {len(fields)}",
                )
            rows.append((number, fields))
    if header is None:
        raise located_error(
            error, path, None, None, "no header row (the file is empty or all comments)"
        )
    while preamble and not preamble[-1]:
        preamble.pop()
    return CsvRows(str(path), tuple(preamble), header, header_line, tuple(rows))


def parse_number(
    text: str, *, path=None, line=None, column=None, error: type[TableError] = TableError
) -> float:
    """Parse one field as a finite float.

    Raises:
        TableError: (or ``error``) the field is empty, not a number, NaN or infinite.
    """
    if not text:
        raise located_error(error, path, line, column, "empty value (a number is required)")
    try:
        value = float(text)
    except ValueError:
        raise located_error(error, path, line, column, f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise located_error(error, path, line, column, f"value must be finite, got {text!r}")
    return value


# ---------------------------------------------------------------------------------------------
# Impact tables


def readonly_array(values, dtype=np.float64) -> np.ndarray:
    """A read-only 1-D copy, so a frozen table cannot be changed through its arrays."""
    array = np.array(values, dtype=dtype, ndmin=1)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class ImpactTable:
    """A batch of impacts, one row each; validated on construction.

    Attributes:
        speed: impact speeds, m/s (float64, > 0).
        angle_deg: incidence angles from the normal, degrees (float64, in (-90, 90)).
        omega0: initial spins, rad/s (float64; zeros when not given).
        overrides: per-row scene parameters, ``{name: float64 array}``, names from
            :data:`IMPACT_PARAMETER_COLUMNS`.
        columns: the input column names in file order, so a results file can repeat exactly
            them; when not given: ``speed, angle_deg``, ``omega0`` if given, the overrides.
        lines: source line number of each row (int64), or ``None`` for tables built in code.
        source: the file it was read from, or ``""``.

    The arrays are read-only copies.

    Raises:
        TableError: lengths differ, the table is empty, a column name is unknown, or a value is
            out of range (the message gives the line when known, else the 0-based row).
    """

    speed: np.ndarray
    angle_deg: np.ndarray
    omega0: np.ndarray | None = None
    overrides: dict[str, np.ndarray] = field(default_factory=dict)
    columns: tuple[str, ...] = ()
    lines: np.ndarray | None = None
    source: str = ""

    def __post_init__(self):
        # Frozen dataclass: normalize fields through object.__setattr__.
        put = object.__setattr__
        speed = readonly_array(self.speed)
        n = speed.size
        omega0 = np.zeros(n) if self.omega0 is None else self.omega0
        values = {
            "speed": speed,
            "angle_deg": readonly_array(self.angle_deg),
            "omega0": readonly_array(omega0),
        }
        overrides = {}
        for name, column in self.overrides.items():
            if name not in IMPACT_PARAMETER_COLUMNS:
                raise located_error(
                    TableError,
                    self.source or None,
                    None,
                    name,
                    f"unknown parameter; allowed: {', '.join(IMPACT_PARAMETER_COLUMNS)}",
                )
            overrides[name] = values[name] = readonly_array(column)
        lines = None if self.lines is None else readonly_array(self.lines, np.int64)
        for name, column in values.items():
            if column.ndim != 1 or column.size != n:
                raise located_error(TableError, self.source or None, None, name, "length differs")
        if lines is not None and lines.size != n:
            raise TableError(f"ImpactTable: {lines.size} line numbers for {n} rows")
        if n == 0:
            raise located_error(
                TableError, self.source or None, None, None, "the table has no rows"
            )
        columns = tuple(self.columns)
        if not columns:
            given_spin = () if self.omega0 is None else ("omega0",)
            columns = ("speed", "angle_deg", *given_spin, *overrides)
        # omega0 may be listed or not (it defaults to 0); every other column must be listed once.
        expected = {"speed", "angle_deg", *overrides}
        if set(columns) - {"omega0"} != expected or len(set(columns)) != len(columns):
            raise TableError(
                f"ImpactTable: columns {columns} must list speed, angle_deg, optionally omega0, "
                f"and the overrides {tuple(overrides)}, each once"
            )
        for name, column in values.items():
            for i, value in enumerate(column.tolist()):
                if not _in_range(name, value):
                    line = None if lines is None else int(lines[i])
                    where = "" if lines is not None else f"row {i}: "
                    raise located_error(
                        TableError,
                        self.source or None,
                        line,
                        name,
                        f"{where}value {value!r} out of range: {allowed_range(name)}",
                    )
        put(self, "speed", speed)
        put(self, "angle_deg", values["angle_deg"])
        put(self, "omega0", values["omega0"])
        put(self, "overrides", overrides)
        put(self, "columns", columns)
        put(self, "lines", lines)
        put(self, "source", str(self.source))

    def __len__(self) -> int:
        return self.speed.size

    def as_columns(self) -> dict[str, np.ndarray]:
        """The input columns, in :attr:`columns` order, as ``{name: array}``."""
        every = {"speed": self.speed, "angle_deg": self.angle_deg, "omega0": self.omega0}
        every.update(self.overrides)
        return {name: every[name] for name in self.columns}

    def overrides_at(self, i: int) -> dict[str, float]:
        """The scene parameters row ``i`` overrides, as ``{name: float}``."""
        return {name: float(column[i]) for name, column in self.overrides.items()}


def read_impacts(path) -> ImpactTable:
    """Read an impacts CSV.

    Arguments:
        path: the file (``speed, angle_deg[, omega0][, parameter columns]``).

    Returns:
        ImpactTable: the rows, in file order.

    Raises:
        TableError: a missing or unknown column, a row with the wrong number of fields, a value
            that is not a finite number or is out of range, or no data rows; the message names
            the file, line and column.
        OSError: the file cannot be read.
    """
    table = read_csv_rows(path)
    allowed = IMPACT_COLUMNS + IMPACT_PARAMETER_COLUMNS
    for name in table.header:
        if name not in allowed:
            raise located_error(
                TableError,
                path,
                table.header_line,
                name,
                f"unknown column; allowed columns: {', '.join(allowed)}",
            )
    for name in ("speed", "angle_deg"):
        if name not in table.header:
            raise located_error(
                TableError, path, table.header_line, name, "required column missing from the header"
            )
    if not table.rows:
        raise located_error(
            TableError, path, table.header_line, None, "no data rows after the header"
        )
    values: dict[str, list[float]] = {name: [] for name in table.header}
    for line, fields in table.rows:
        for name, text in zip(table.header, fields, strict=True):
            value = parse_number(text, path=path, line=line, column=name)
            check_impact_value(name, value, path=path, line=line)
            values[name].append(value)
    return ImpactTable(
        speed=values["speed"],
        angle_deg=values["angle_deg"],
        omega0=values.get("omega0"),
        overrides={k: v for k, v in values.items() if k in IMPACT_PARAMETER_COLUMNS},
        columns=table.header,
        lines=[line for line, _ in table.rows],
        source=str(path),
    )


# ---------------------------------------------------------------------------------------------
# Writing


def atomic_write_text(path, text: str, *, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_write_bytes`).

    Raises:
        OSError: the directory is missing or not writable, or the disk is full.
        UnicodeEncodeError: ``text`` cannot be encoded (nothing is created then).
    """
    # Encode before creating anything: an encoding error leaves no file.
    atomic_write_bytes(path, text.encode(encoding))


def atomic_write_bytes(path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers see either the old file or the whole new one.

    The data goes to a temporary file in the same directory (so the final rename stays on one
    file system), is flushed and fsynced, then renamed over ``path`` with :func:`os.replace`.
    On any exception the temporary file is removed and ``path`` is left as it was.

    Arguments:
        path: the destination file.
        data: the complete content.

    Raises:
        OSError: the directory is missing or not writable, or the disk is full.
    """
    path = Path(path)
    temp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    # O_EXCL: never reuse someone else's file; mode 0o666 lets the umask decide permissions,
    # as for any ordinarily created file (tempfile.mkstemp would force 0o600).
    fd = os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(temp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temp)
        raise
    # Persist the rename itself; best effort, since not every platform can fsync a directory.
    try:
        dir_fd = os.open(path.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dir_fd)
    except OSError:
        pass
    finally:
        os.close(dir_fd)


def _format_float(value: float) -> str:
    # repr gives the shortest text that reads back to exactly the same float64, so results
    # files round-trip bit for bit (regression tests, re-fitting) at no cost in length for
    # short values; a fixed '.10g' would lose digits. NaN (not applicable) is an empty field.
    if math.isnan(value):
        return ""
    return repr(float(value))


def _numeric_column(name: str, values, path) -> list[float]:
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise located_error(
            TableError, path, None, name, f"values are not numbers ({exc})"
        ) from None
    if array.ndim != 1:
        raise located_error(
            TableError, path, None, name, f"expected a 1-D array, got shape {array.shape}"
        )
    return array.tolist()


def write_results(
    path,
    inputs: ImpactTable | Mapping[str, Sequence[float]],
    results: Mapping[str, Sequence],
    *,
    comments: Sequence[str] = (),
) -> None:
    """Write a results CSV atomically (see :func:`atomic_write_text`).

    Arguments:
        path: the destination file.
        inputs: the impact table that was simulated (its :attr:`ImpactTable.columns` are
            repeated), or an ordered mapping ``{input column: values}``.
        results: ``{name: values}`` with exactly the keys of :data:`RESULT_COLUMNS`: ``status``
            holds strings, the others numbers (NaN for "not applicable", written empty).
        comments: lines written first, each prefixed with ``# `` (e.g. the scene used).

    Raises:
        TableError: a result column missing or unknown, an input column named like a result
            column, lengths that differ, non-numeric values, or an empty or multi-line status.
            Nothing is written then: the whole text is built before the file is touched.
        OSError: the file cannot be written (no partial file is left).
    """
    columns = inputs.as_columns() if isinstance(inputs, ImpactTable) else dict(inputs)
    missing = [name for name in RESULT_COLUMNS if name not in results]
    unknown = [name for name in results if name not in RESULT_COLUMNS]
    if missing or unknown:
        raise located_error(
            TableError,
            path,
            None,
            None,
            f"result columns missing: {missing or 'none'}; unknown: {unknown or 'none'}; "
            f"expected: {', '.join(RESULT_COLUMNS)}",
        )
    clash = [name for name in columns if name in RESULT_COLUMNS]
    if clash:
        raise located_error(
            TableError, path, None, clash[0], "input column named like a result column"
        )

    table: dict[str, list] = {name: _numeric_column(name, v, path) for name, v in columns.items()}
    status = [str(s) for s in np.asarray(results["status"], dtype=object).ravel()]
    for i, s in enumerate(status):
        # A status must read back as one field of one line, and not as a comment.
        if not s or s != s.strip() or s.startswith("#") or not s.isprintable():
            raise located_error(TableError, path, None, "status", f"row {i}: invalid status {s!r}")
    table["status"] = status
    reasons = [str(s) for s in np.asarray(results["failure_reason"], dtype=object).ravel()]
    for i, s in enumerate(reasons):
        if s and s not in FAILURE_REASONS:
            raise located_error(
                TableError, path, None, "failure_reason", f"row {i}: invalid reason {s!r}"
            )
    for name in RESULT_COLUMNS[1:]:
        if name not in TEXT_RESULT_COLUMNS:
            table[name] = _numeric_column(name, results[name], path)
    table["failure_reason"] = reasons
    lengths = {name: len(v) for name, v in table.items()}
    if len(set(lengths.values())) != 1:
        raise located_error(TableError, path, None, None, f"columns differ in length: {lengths}")

    buffer = io.StringIO()
    for comment in comments:
        for part in str(comment).splitlines() or [""]:
            buffer.write(f"# {part}".rstrip() + "\n")
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(table)
    for row in zip(*table.values(), strict=True):
        writer.writerow(v if isinstance(v, str) else _format_float(v) for v in row)
    atomic_write_text(path, buffer.getvalue())


def read_results(path) -> dict[str, np.ndarray]:
    """Read a results CSV written by :func:`write_results`.

    Arguments:
        path: the file.

    Returns:
        dict: ``{column: array}`` in file order: the input columns and the numeric result
        columns as float64 (empty fields as NaN), ``status`` as an array of str.

    Raises:
        TableError: the header does not end with :data:`RESULT_COLUMNS`, or a numeric field is
            not a number.
        OSError: the file cannot be read.
    """
    table = read_csv_rows(path)
    # Files written before failure_reason existed end with loss_rolling: still readable.
    expected = RESULT_COLUMNS if table.header[-1:] == ("failure_reason",) else RESULT_COLUMNS[:-1]
    n_inputs = len(table.header) - len(expected)
    if n_inputs < 0 or table.header[n_inputs:] != expected:
        raise located_error(
            TableError,
            path,
            table.header_line,
            None,
            f"the header must end with the result columns {', '.join(RESULT_COLUMNS)}",
        )
    columns: dict[str, np.ndarray] = {}
    for j, name in enumerate(table.header):
        texts = [fields[j] for _, fields in table.rows]
        if name in TEXT_RESULT_COLUMNS:
            columns[name] = np.array(texts, dtype=str)
            continue
        values = []
        for (line, _), text in zip(table.rows, texts, strict=True):
            if not text:
                values.append(math.nan)
                continue
            try:
                values.append(float(text))
            except ValueError:
                raise located_error(
                    TableError, path, line, name, f"not a number: {text!r}"
                ) from None
        columns[name] = np.array(values, dtype=np.float64)
    return columns

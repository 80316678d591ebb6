"""Impact tables (CSV input) and results files (CSV output), on numpy and pyarrow.

File formats are those of the project conventions:

* impacts CSV: a header row with ``speed`` (m/s, > 0) and ``angle_deg`` (from the surface
  normal, in (-90, 90)), optionally ``omega0`` (rad/s, default 0) and any of
  :data:`IMPACT_PARAMETER_COLUMNS`, which override the scene for that row;
* results CSV: the input columns, then :data:`RESULT_COLUMNS`.

In both, lines starting with ``#`` are comments, blank lines are ignored and whitespace around
fields is ignored. Every problem in an input file is a :class:`TableError` (a ``ValueError``)
naming the file, the 1-based line number (as an editor shows it, comment lines included), the
column and the allowed values: a row is never dropped silently.

pyarrow parses the CSV (quoting, conversion to numbers); this module sorts out comments and line
numbers around it. It deliberately imports no JAX so that readers, writers and their tests stay
light; the small parsing helpers (:func:`read_csv_rows`, :func:`parse_number`,
:func:`check_impact_value`) are shared with ``fitting._data``.

The columns are defined in :mod:`.columns`, the generic CSV reading in :mod:`.csv_rows` and
the atomic writes in :mod:`.atomic`; this module holds the impact tables and the results
files and keeps every name of :data:`__all__` importable from here (and from
``jaximpact.tables``).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .._model.ranges import IMPLAUSIBLE
from .atomic import atomic_write_bytes, atomic_write_text
from .columns import (
    COLUMN_UNITS,
    FAILURE_REASONS,
    IMPACT_COLUMNS,
    IMPACT_PARAMETER_COLUMNS,
    OPTIONAL_RESULT_COLUMNS,
    RESULT_COLUMNS,
    RESULT_STATUSES,
    TEXT_RESULT_COLUMNS,
)
from .csv_rows import (
    CsvRows,
    TableError,
    _in_range,
    allowed_range,
    check_impact_value,
    located_error,
    number_text,
    parse_number,
    read_csv_rows,
    readonly_array,
)

__all__ = [
    "IMPACT_COLUMNS",
    "IMPACT_PARAMETER_COLUMNS",
    "RESULT_COLUMNS",
    "RESULT_STATUSES",
    "OPTIONAL_RESULT_COLUMNS",
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
    "number_text",
    "parse_number",
    "read_csv_rows",
    "read_impacts",
    "read_results",
    "readonly_array",
    "write_results",
]


# ---------------------------------------------------------------------------------------------
# Impact tables


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

        def fail(line, column, problem: str) -> TableError:
            return located_error(TableError, self.source or None, line, column, problem)

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
                allowed = ", ".join(IMPACT_PARAMETER_COLUMNS)
                raise fail(None, name, f"unknown parameter; allowed: {allowed}")
            overrides[name] = values[name] = readonly_array(column)
        lines = None if self.lines is None else readonly_array(self.lines, np.int64)
        for name, column in values.items():
            if column.ndim != 1 or column.size != n:
                raise fail(None, name, "length differs")
        if lines is not None and lines.size != n:
            raise TableError(f"ImpactTable: {lines.size} line numbers for {n} rows")
        if n == 0:
            raise fail(None, None, "the table has no rows")
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
            bad = np.flatnonzero(~_in_range(name, column))
            if bad.size:
                i = int(bad[0])
                line, where = (None, f"row {i}: ") if lines is None else (int(lines[i]), "")
                problem = f"value {float(column[i])!r} out of range: {allowed_range(name)}"
                raise fail(line, name, where + problem)
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
    table.check_header(IMPACT_COLUMNS + IMPACT_PARAMETER_COLUMNS, ("speed", "angle_deg"))
    if not len(table):
        raise located_error(
            TableError, path, table.header_line, None, "no data rows after the header"
        )
    values = {name: table.numbers(name) for name in table.header}
    return ImpactTable(
        speed=values["speed"],
        angle_deg=values["angle_deg"],
        omega0=values.get("omega0"),
        overrides={k: v for k, v in values.items() if k in IMPACT_PARAMETER_COLUMNS},
        columns=table.header,
        lines=table.lines,
        source=str(path),
    )


# ---------------------------------------------------------------------------------------------
# Results files


def _bad_reason(reason: str) -> str:
    return f"invalid failure reason {reason!r}; allowed: empty, {', '.join(FAILURE_REASONS)}"


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
        results: ``{name: values}`` with the keys of :data:`RESULT_COLUMNS` (and optionally
            those of :data:`OPTIONAL_RESULT_COLUMNS`, written last): ``status``
            holds strings, ``failure_reason`` empty strings or keys of :data:`FAILURE_REASONS`,
            the others numbers (NaN for "not applicable", written empty).
        comments: lines written first, each prefixed with ``# `` (e.g. the scene used).

    Raises:
        TableError: a result column missing or unknown, an input column named like a result
            column, lengths that differ, non-numeric values, an empty or multi-line status, or
            an unknown failure reason.
            Nothing is written then: the whole text is built before the file is touched.
        OSError: the file cannot be written (no partial file is left).
    """

    def fail(column, problem: str) -> TableError:
        return located_error(TableError, path, None, column, problem)

    columns = inputs.as_columns() if isinstance(inputs, ImpactTable) else dict(inputs)
    missing = [name for name in RESULT_COLUMNS if name not in results]
    unknown = [name for name in results if name not in RESULT_COLUMNS + OPTIONAL_RESULT_COLUMNS]
    if missing or unknown:
        raise fail(
            None,
            f"result columns missing: {missing or 'none'}; unknown: {unknown or 'none'}; "
            f"expected: {', '.join(RESULT_COLUMNS)}",
        )
    clash = [name for name in columns if name in RESULT_COLUMNS + OPTIONAL_RESULT_COLUMNS]
    if clash:
        raise fail(clash[0], "input column named like a result column")

    table: dict[str, list] = {name: _numeric_column(name, v, path) for name, v in columns.items()}
    written = RESULT_COLUMNS + tuple(n for n in OPTIONAL_RESULT_COLUMNS if n in results)
    for name in written:
        table[name] = (
            [str(s) for s in np.asarray(results[name], dtype=object).ravel()]
            if name in TEXT_RESULT_COLUMNS
            else _numeric_column(name, results[name], path)
        )
    lengths = {name: len(v) for name, v in table.items()}
    if len(set(lengths.values())) != 1:
        raise fail(None, f"columns differ in length: {lengths}")
    for i, (s, reason) in enumerate(zip(table["status"], table["failure_reason"], strict=True)):
        # A status must read back as one field of one line, and not as a comment.
        if not s or s != s.strip() or s.startswith("#") or not s.isprintable():
            raise fail("status", f"row {i}: invalid status {s!r}")
        if reason and reason not in FAILURE_REASONS:
            raise fail("failure_reason", f"row {i}: {_bad_reason(reason)}")
    for i, flag in enumerate(table.get("implausible", ())):
        if flag and flag not in IMPLAUSIBLE:
            allowed = ", ".join(IMPLAUSIBLE)
            raise fail("implausible", f"row {i}: invalid flag {flag!r}; allowed: empty, {allowed}")

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
        columns as float64 (empty fields as NaN), ``status``, ``failure_reason`` and
        ``implausible`` (where the file has it) as arrays of str. Files written before
        ``failure_reason`` existed have no such key.

    Raises:
        TableError: the header does not end with :data:`RESULT_COLUMNS` (with or without
            ``failure_reason``; optionally then ``implausible``), a numeric field is not a
            number, a failure reason is unknown, or the file is not well-formed (see
            :func:`read_csv_rows`).
        OSError: the file cannot be read.
    """
    table = read_csv_rows(path)
    # Files written before failure_reason existed end with loss_rolling: still readable.
    last = table.header[-1:]
    expected = (
        RESULT_COLUMNS + OPTIONAL_RESULT_COLUMNS
        if last == OPTIONAL_RESULT_COLUMNS[-1:]
        else RESULT_COLUMNS
        if last == ("failure_reason",)
        else RESULT_COLUMNS[:-1]
    )
    n_inputs = len(table.header) - len(expected)
    if n_inputs < 0 or table.header[n_inputs:] != expected:
        problem = f"the header must end with the result columns {', '.join(RESULT_COLUMNS)}"
        raise located_error(TableError, path, table.header_line, None, problem)
    columns = {
        name: np.array(table.fields[name].to_pylist(), dtype=str)
        if name in TEXT_RESULT_COLUMNS
        else table.numbers(name, empty_as_nan=True)
        for name in table.header
    }
    bad = np.flatnonzero(~np.isin(columns.get("failure_reason", []), ["", *FAILURE_REASONS]))
    if bad.size:
        problem = _bad_reason(columns["failure_reason"][bad[0]])
        raise located_error(TableError, path, int(table.lines[bad[0]]), "failure_reason", problem)
    return columns

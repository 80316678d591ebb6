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
"""

from __future__ import annotations

import contextlib
import csv
import functools
import io
import math
import os
import re
import secrets
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pv

from .._model.ranges import IMPLAUSIBLE, RANGES, range_text
from .paths import keep_mode, output_target

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
TEXT_RESULT_COLUMNS = ("status", "failure_reason", "implausible")

#: Result columns a results CSV may add after :data:`RESULT_COLUMNS`: ``implausible``, the
#: plausibility flag of each impact (``jaximpact simulate`` writes it): empty, or a key of
#: :data:`IMPLAUSIBLE` (``large_overlap``: the maximum overlap is beyond the small-strain range
#: of Hertz contact; docs/input_ranges.md).
OPTIONAL_RESULT_COLUMNS = ("implausible",)

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
    "implausible": "",
}

#: The statuses the conventions define for a simulated impact.
RESULT_STATUSES = ("rebound", "captured", "failed")


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


def number_text(value) -> str:
    """A value as a message shows it: ``2.0``, never ``np.float64(2.0)`` (numpy 2's repr)."""
    if isinstance(value, (bool, np.bool_)):
        return repr(bool(value))
    if isinstance(value, (int, float, np.integer, np.floating)):
        return repr(int(value)) if isinstance(value, (int, np.integer)) else repr(float(value))
    return repr(value)


def located_error(error: type[TableError], path, line, column, problem: str) -> TableError:
    """Build ``error`` with the standard "file, line N, column 'c': problem" message."""
    where = [] if path is None else [str(path)]
    if line is not None:
        where.append(f"line {line}")
    if column is not None:
        where.append(f"column '{column}'")
    text = f"{', '.join(where)}: {problem}" if where else problem
    return error(text, path=path, line=line, column=column)


# ---------------------------------------------------------------------------------------------
# Value ranges


def allowed_range(name: str) -> str:
    """Describe the allowed values of impact column ``name`` (for error messages): its
    documented range (``jaximpact._ranges.RANGES``, docs/input_ranges.md).

    Raises:
        KeyError: ``name`` is not an impact or parameter column.
    """
    if name not in IMPACT_COLUMNS + IMPACT_PARAMETER_COLUMNS:
        raise KeyError(name)
    return range_text(name)


def _in_range(name: str, value) -> np.ndarray:
    """Whether each of ``value`` (a float or an array) is allowed in column ``name``."""
    return RANGES[name].contains(value)


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
            error,
            path,
            line,
            name,
            f"value {number_text(value)} out of range: {allowed_range(name)}",
        )


# ---------------------------------------------------------------------------------------------
# Generic CSV reading

# A number as the readers accept it: Python's float syntax less its rarities (underscores,
# non-ASCII digits). pyarrow converts exactly these (correctly rounded, as float() does), so
# one pattern tells which field is wrong before any conversion.
_NUMBER = r"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|(?i:nan|inf|infinity))"
_NUMBER_RE = re.compile(_NUMBER)


def _number_problem(text: str, *, finite: bool = True) -> str | None:
    """What is wrong with ``text`` as a (finite) number, or ``None``."""
    if not text:
        return "empty value (a number is required)"
    if not _NUMBER_RE.fullmatch(text):
        return f"not a number: {text!r}"
    if finite and not math.isfinite(float(text)):
        return f"value must be finite, got {text!r}"
    return None


def parse_number(
    text: str, *, path=None, line=None, column=None, error: type[TableError] = TableError
) -> float:
    """Parse one field (surrounding whitespace ignored) as a finite float.

    Raises:
        TableError: (or ``error``) the field is empty, not a number, NaN or infinite.
    """
    text = text.strip()
    problem = _number_problem(text)
    if problem:
        raise located_error(error, path, line, column, problem)
    return float(text)


@dataclass(frozen=True, eq=False)
class CsvRows:
    """The content of a commented CSV file, every field as text.

    Attributes:
        path: the file, as given.
        preamble: the ``#`` comment lines before the header, without the leading ``#`` and one
            following space (blank lines among them kept as empty strings).
        header: the column names, stripped.
        header_line: line number of the header.
        lines: line number of each data row (int64).
        fields: ``{column: pyarrow string array}``, one stripped field per data row.
        error: the exception class that :meth:`numbers` raises.
    """

    path: str
    preamble: tuple[str, ...]
    header: tuple[str, ...]
    header_line: int
    lines: np.ndarray
    fields: dict[str, pa.Array]
    error: type[TableError] = TableError

    def __len__(self) -> int:
        return self.lines.size

    def check_header(self, allowed: Sequence[str], required: Sequence[str]) -> None:
        """Refuse a header column not in ``allowed`` and a ``required`` one that is missing."""
        for name in self.header:
            if name not in allowed:
                problem = f"unknown column; allowed columns: {', '.join(allowed)}"
                raise located_error(self.error, self.path, self.header_line, name, problem)
        for name in required:
            if name not in self.header:
                problem = "required column missing from the header"
                raise located_error(self.error, self.path, self.header_line, name, problem)

    def records(self) -> Iterator[tuple[int, dict[str, str]]]:
        """``(line number, {column: field})`` for every data row, in file order."""
        columns = zip(*(self.fields[name].to_pylist() for name in self.header), strict=True)
        for line, values in zip(self.lines.tolist(), columns, strict=True):
            yield line, dict(zip(self.header, values, strict=True))

    def numbers(self, name: str, *, empty_as_nan: bool = False) -> np.ndarray:
        """Column ``name`` as float64, converted by pyarrow.

        By default every field must be a finite number; with ``empty_as_nan`` an empty field
        reads as NaN, and ``nan`` and ``inf`` are accepted.

        Raises:
            TableError: (or :attr:`error`) at the first field that does not qualify.
        """
        texts = self.fields[name]
        if empty_as_nan:
            texts = pc.if_else(pc.equal(texts, ""), "nan", texts)
        ok = pc.match_substring_regex(texts, f"^(?:{_NUMBER})$")
        values = np.array(pc.cast(pc.if_else(ok, texts, "nan"), pa.float64()))  # writable
        ok = np.asarray(ok) & (empty_as_nan | np.isfinite(values))
        if not ok.all():
            i = int(np.argmin(ok))
            problem = _number_problem(texts[i].as_py(), finite=not empty_as_nan)
            raise located_error(self.error, self.path, int(self.lines[i]), name, problem)
        return values


def read_csv_rows(path, *, error: type[TableError] = TableError) -> CsvRows:
    """Read a CSV file with ``#`` comments into a header and numbered rows of text.

    The lines are first sorted into comments, blank lines and records (the header and data
    rows), so that each row keeps the line number an editor shows; pyarrow parses the records.
    Checks only the structure: UTF-8 text (a byte-order mark is allowed), a header with
    non-empty distinct names, as many fields in every row as in the header, and no quoted field
    left open at the end of its line.

    Raises:
        TableError: (or ``error``) one of these problems, with its line.
        OSError: the file cannot be read.
    """
    data = Path(path).read_bytes()
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise located_error(error, path, line, None, "not UTF-8 text") from None
    # \r\n and \r end a line too, as in an editor.
    lines = [line.strip() for line in text.replace("\r\n", "\n").replace("\r", "\n").split("\n")]
    # The records (the header and the data rows), by index in lines: what pyarrow reads.
    records = [i for i, line in enumerate(lines) if line and not line.startswith("#")]
    if not records:
        problem = "no header row (the file is empty or all comments)"
        raise located_error(error, path, None, None, problem)
    start = next(i for i, line in enumerate(lines) if line)  # blank lines before are no preamble
    preamble = [line[1:].removeprefix(" ") for line in lines[start : records[0]]]
    while preamble and not preamble[-1]:
        preamble.pop()

    def fail(record: int, column, problem: str) -> TableError:
        return located_error(error, path, records[record - 1] + 1, column, problem)

    ragged = []  # (record, fields found, holds a line end) of the rows pyarrow skips

    def skip(row) -> str:
        ragged.append((row.number, row.actual_columns, "\n" in row.text))
        return "skip"

    try:
        table = pv.read_csv(
            io.BytesIO("\n".join([lines[i] for i in records] + [""]).encode()),
            # One thread, so that pyarrow numbers the rows it skips (from 1, as records are).
            read_options=pv.ReadOptions(autogenerate_column_names=True, use_threads=False),
            parse_options=pv.ParseOptions(invalid_row_handler=skip),
            # Every field as text (a line of n characters holds at most n + 1 fields).
            convert_options=pv.ConvertOptions(
                column_types={f"f{i}": pa.string() for i in range(len(lines[records[0]]) + 1)}
            ),
        )
    except pa.ArrowInvalid as exc:  # pyarrow finds no end to the first record
        raise fail(1, None, f"the header is not a complete CSV line (pyarrow: {exc})") from None
    columns = [column.combine_chunks() for column in table.columns]
    names = [column[0].as_py() for column in columns]
    header = tuple(name.strip() for name in names)
    for name, raw in zip(header, names, strict=True):
        if not name or "\n" in raw:
            raise fail(1, None, f"empty or unclosed column name in the header: {raw!r}")
        if header.count(name) > 1:
            raise fail(1, name, "column named twice in the header")
    # A quote left open swallows line ends. Up to the first field holding one and the first
    # skipped row, rows and records match one to one: report whichever comes first.
    unclosed = "a quoted field is not closed on its line"
    expected = f"expected {len(header)} fields ({', '.join(header)})"
    problems = [
        (record, unclosed if open_quote else f"{expected}, found {found}")
        for record, found, open_quote in ragged[:1]
    ]
    # (in pyarrow: converting its boolean arrays to numpy imports pandas, 0.2 s a command)
    newline = functools.reduce(pc.or_, [pc.match_substring(c, "\n") for c in columns])
    spans = pc.indices_nonzero(newline).to_pylist()
    problems += [(int(i) + 1, unclosed) for i in spans[:1]]
    if problems:
        record, problem = min(problems, key=lambda p: p[0])  # a skipped row first on a tie
        raise fail(record, None, problem)
    fields = {n: pc.utf8_trim_whitespace(c[1:]) for n, c in zip(header, columns, strict=True)}
    numbers = readonly_array(np.add(records[1:], 1), np.int64)  # the line of each data row
    return CsvRows(str(path), tuple(preamble), header, records[0] + 1, numbers, fields, error)


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
# Writing


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

"""Reading a table file: a CSV with ``#`` comments into numbered rows of text
(:func:`read_csv_rows`, pyarrow parsing the records), numbers as the readers accept them
(:func:`parse_number`), the impact columns' value ranges, and :class:`TableError`, whose
message names the file, the 1-based line and the column."""

from __future__ import annotations

import functools
import io
import math
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pv

from .._model.ranges import RANGES, range_text
from .columns import IMPACT_COLUMNS, IMPACT_PARAMETER_COLUMNS


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


def readonly_array(values, dtype=np.float64) -> np.ndarray:
    """A read-only 1-D copy, so a frozen table cannot be changed through its arrays."""
    array = np.array(values, dtype=dtype, ndmin=1)
    array.setflags(write=False)
    return array

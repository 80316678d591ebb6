"""Observation data for fitting: loading, validation, and the bundled Kharaz (2001) data set.

Two layouts are accepted (the project conventions), told apart by the header:

* long, when the header has an ``observable`` column:
  ``speed, angle_deg[, omega0][, parameter columns], observable, value[, sigma]``,
  one observation per row;
* wide, otherwise: impact columns, then observed result columns named from
  :data:`OBSERVABLES`, each with an optional ``sigma_<name>`` column. An empty cell means "not
  observed" and is skipped. A ``status`` column (``rebound`` | ``captured``) is read as the
  observable ``captured`` (0.0 or 1.0).

Either way the result is one :class:`Observations` in long form, with the distinct impacts
gathered once in an :class:`~jaximpact.tables.ImpactTable` so that a simulator can run each
impact a single time. Numpy only: this module must not import JAX.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from jaximpact.tables import (
    IMPACT_COLUMNS,
    IMPACT_PARAMETER_COLUMNS,
    ImpactTable,
    TableError,
    check_impact_value,
    located_error,
    parse_number,
    read_csv_rows,
    readonly_array,
)

__all__ = [
    "CAPTURE_STATUSES",
    "KHARAZ2001_FILE",
    "OBSERVABLES",
    "DataError",
    "Observations",
    "kharaz2001_path",
    "load_kharaz2001",
    "load_observations",
]

#: Quantities an observation may give; the first five are results-CSV columns, ``captured`` is
#: 1.0 for a captured sphere and 0.0 for a rebound.
OBSERVABLES = ("cor_n", "cor_t", "vt_out", "omega_out", "rebound_angle_deg", "captured")

#: Values of a wide file's ``status`` column and the ``captured`` value each stands for.
CAPTURE_STATUSES = {"rebound": 0.0, "captured": 1.0}

#: File name of the bundled Kharaz, Gorham & Salman (2001) oblique-impact data.
KHARAZ2001_FILE = "kharaz2001_oblique_impact.csv"

_IMPACT_NAMES = IMPACT_COLUMNS + IMPACT_PARAMETER_COLUMNS
_LONG_EXTRA = ("observable", "value", "sigma")


class DataError(TableError):
    """A problem in an observation file; the message names the file, line and column."""


def _fail(path, line, column, problem: str) -> DataError:
    return located_error(DataError, path, line, column, problem)


@dataclass(frozen=True, eq=False)
class Observations:
    """Observations in long form, one entry per observed value, in file order.

    Attributes:
        speed, angle_deg, omega0: the impact of each observation (float64).
        observable: the observable's name (array of str, from :data:`OBSERVABLES`).
        value: the observed value (float64; ``captured`` is 0.0 or 1.0).
        sigma: its standard uncertainty (float64, > 0), NaN where the file gives none.
        line: the source line of each observation (int64).
        impact_index: index of each observation's impact in :attr:`impacts` (int64).
        impacts: the distinct impacts, in order of first appearance, with any parameter
            overrides; ``impacts.lines`` holds the line where each first appears.
        source: the file read.
        provenance: the ``#`` comment lines at the top of the file, without the ``#``,
            joined with newlines (``""`` if none), so reports can cite the data.
        layout: ``"wide"`` or ``"long"``, as detected from the header.
    """

    speed: np.ndarray
    angle_deg: np.ndarray
    omega0: np.ndarray
    observable: np.ndarray
    value: np.ndarray
    sigma: np.ndarray
    line: np.ndarray
    impact_index: np.ndarray
    impacts: ImpactTable
    source: str
    provenance: str
    layout: str

    def __len__(self) -> int:
        return self.value.size

    def counts(self) -> dict[str, int]:
        """Number of observations of each observable present, in :data:`OBSERVABLES` order."""
        return {
            name: int(np.count_nonzero(self.observable == name))
            for name in OBSERVABLES
            if np.any(self.observable == name)
        }


class _Builder:
    """Collects observations and assigns each distinct impact one index."""

    def __init__(self, path, impact_names: tuple[str, ...]):
        self.path = path
        self.impact_names = impact_names
        self.index: dict[tuple[float, ...], int] = {}
        self.impact_rows: list[tuple[float, ...]] = []
        self.impact_lines: list[int] = []
        self.observations: list[tuple[int, str, float, float, int]] = []

    def impact(self, line: int, fields: dict[str, str]) -> tuple[float, ...]:
        """Parse and check the impact columns of one row (even if it observes nothing)."""
        values = []
        for name in self.impact_names:
            value = parse_number(
                fields[name], path=self.path, line=line, column=name, error=DataError
            )
            check_impact_value(name, value, path=self.path, line=line, error=DataError)
            values.append(value)
        return tuple(values)

    def add(self, line: int, impact, name: str, value_text: str, sigma_text: str, columns):
        """Validate and record one observation of ``impact`` (from :meth:`impact`).

        ``columns`` names the value and sigma columns for error messages. The impact is
        registered here, so that a wide row observing nothing adds no impact to simulate.
        """
        value_column, sigma_column = columns
        value = parse_number(
            value_text, path=self.path, line=line, column=value_column, error=DataError
        )
        if name == "captured" and value not in (0.0, 1.0):
            raise _fail(
                self.path, line, value_column, f"captured must be 0 or 1, got {value_text!r}"
            )
        sigma = np.nan
        if sigma_text:
            sigma = parse_number(
                sigma_text, path=self.path, line=line, column=sigma_column, error=DataError
            )
            if sigma <= 0:
                raise _fail(
                    self.path,
                    line,
                    sigma_column,
                    f"sigma must be finite and > 0, got {sigma_text!r}",
                )
        if impact not in self.index:
            self.index[impact] = len(self.impact_rows)
            self.impact_rows.append(impact)
            self.impact_lines.append(line)
        self.observations.append((line, name, value, sigma, self.index[impact]))

    def build(self, provenance: str, layout: str, header_line: int) -> Observations:
        if not self.observations:
            raise _fail(self.path, header_line, None, "no usable observations in the file")
        lines, names, values, sigmas, index = zip(*self.observations, strict=True)
        table = np.array(self.impact_rows, dtype=np.float64)
        by_name = {name: table[:, j] for j, name in enumerate(self.impact_names)}
        impacts = ImpactTable(
            speed=by_name["speed"],
            angle_deg=by_name["angle_deg"],
            omega0=by_name.get("omega0"),
            overrides={k: v for k, v in by_name.items() if k in IMPACT_PARAMETER_COLUMNS},
            columns=self.impact_names,
            lines=self.impact_lines,
            source=str(self.path),
        )
        index = readonly_array(index, np.int64)
        return Observations(
            speed=readonly_array(impacts.speed[index], np.float64),
            angle_deg=readonly_array(impacts.angle_deg[index], np.float64),
            omega0=readonly_array(impacts.omega0[index], np.float64),
            observable=readonly_array(names, str),
            value=readonly_array(values, np.float64),
            sigma=readonly_array(sigmas, np.float64),
            line=readonly_array(lines, np.int64),
            impact_index=index,
            impacts=impacts,
            source=str(self.path),
            provenance="\n".join(provenance),
            layout=layout,
        )


def load_observations(path) -> Observations:
    """Read an observation file in wide or long layout (detected from the header).

    Arguments:
        path: the CSV file.

    Returns:
        Observations: every observation, in file order (wide rows: left to right).

    Raises:
        DataError: a missing or unknown column (including an unknown observable name), a row
            with the wrong number of fields, a value that is not a finite number, an impact
            value out of range, a sigma <= 0, a sigma without a value, a ``captured`` value
            other than 0 or 1, an unknown status, or no observation at all. The message names
            the file, line and column.
        OSError: the file cannot be read.
    """
    rows = read_csv_rows(path, error=DataError)
    header = rows.header
    impact_names = tuple(name for name in header if name in _IMPACT_NAMES)
    builder = _Builder(path, impact_names)

    if "observable" in header:
        layout = "long"
        rows.check_header(
            _IMPACT_NAMES + _LONG_EXTRA, ("speed", "angle_deg", "observable", "value")
        )
        for line, fields in rows.records():
            name = fields["observable"]
            if name not in OBSERVABLES:
                raise _fail(
                    path,
                    line,
                    "observable",
                    f"unknown observable {name!r}; allowed: {', '.join(OBSERVABLES)}",
                )
            impact = builder.impact(line, fields)
            builder.add(
                line, impact, name, fields["value"], fields.get("sigma", ""), _LONG_EXTRA[1:]
            )
    else:
        layout = "wide"
        observed = tuple(name for name in OBSERVABLES if name in header)
        allowed = (
            _IMPACT_NAMES + OBSERVABLES + tuple(f"sigma_{n}" for n in OBSERVABLES) + ("status",)
        )
        rows.check_header(allowed, ("speed", "angle_deg"))
        _check_wide_header(path, header, rows.header_line, observed)
        for line, fields in rows.records():
            impact = builder.impact(line, fields)
            for name in header:
                if name == "status":
                    _add_status(builder, path, line, impact, fields["status"])
                    continue
                if name not in observed:
                    continue
                sigma_column = f"sigma_{name}"
                sigma_text = fields.get(sigma_column, "")
                if not fields[name]:
                    if sigma_text:
                        raise _fail(path, line, sigma_column, f"sigma given but {name} is empty")
                    continue  # not observed on this row
                builder.add(line, impact, name, fields[name], sigma_text, (name, sigma_column))
    return builder.build(rows.preamble, layout, rows.header_line)


def _check_wide_header(path, header, header_line: int, observed) -> None:
    """A wide file's header beyond its known names: each ``sigma_X`` has its ``X``, capture is
    given one way, and something is observed (``DataError`` naming the column)."""
    for name in header:
        if name.startswith("sigma_") and name.removeprefix("sigma_") not in header:
            raise _fail(
                path,
                header_line,
                name,
                f"no column {name.removeprefix('sigma_')!r} for it",
            )
    if "status" in header and "captured" in header:
        raise _fail(path, header_line, "status", "give capture as 'status' or 'captured', not both")
    if not observed and "status" not in header:
        raise _fail(
            path,
            header_line,
            None,
            f"no observed columns; expected some of {', '.join(OBSERVABLES)} or status "
            "(or, for the long layout, an 'observable' column)",
        )


def _add_status(builder: _Builder, path, line: int, impact, text: str) -> None:
    """Record a wide file's ``status`` cell as a ``captured`` observation (empty: none)."""
    if not text:
        return
    if text not in CAPTURE_STATUSES:
        raise _fail(
            path,
            line,
            "status",
            f"status {text!r} is not an observation; allowed: "
            f"{', '.join(CAPTURE_STATUSES)} or empty",
        )
    builder.add(line, impact, "captured", repr(CAPTURE_STATUSES[text]), "", ("status", None))


def kharaz2001_path() -> Path:
    """Path of the bundled Kharaz, Gorham & Salman (2001) observation file.

    Returns:
        Path: the CSV shipped as package data in ``fitting/data``.

    Raises:
        FileNotFoundError: the package is installed in a form (e.g. a zip) that has no real
            file; use :func:`load_kharaz2001`, which works in any case.
    """
    resource = resources.files(__package__) / "data" / KHARAZ2001_FILE
    if not isinstance(resource, Path) or not resource.is_file():
        raise FileNotFoundError(f"no file for the package resource {resource}")
    return resource


def load_kharaz2001() -> Observations:
    """Load the bundled Kharaz (2001) data (24 observations of cor_t, omega_out and
    rebound_angle_deg at 3.9 m/s, no spin), wherever the package is installed."""
    resource = resources.files(__package__) / "data" / KHARAZ2001_FILE
    with resources.as_file(resource) as path:  # a temporary copy only if installed zipped
        return load_observations(path)

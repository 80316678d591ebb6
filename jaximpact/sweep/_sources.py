"""What a sweep simulates: an impacts table (CSV or Parquet) or a cartesian grid of impact
inputs and scene parameters, read or generated chunk by chunk."""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .._io.tables import (
    IMPACT_COLUMNS,
    IMPACT_PARAMETER_COLUMNS,
    ImpactTable,
    TableError,
    allowed_range,
    check_impact_value,
    read_impacts,
)

#: The names a ``--grid`` axis may have: the impact columns and the scene parameter columns.
GRID_NAMES = IMPACT_COLUMNS + IMPACT_PARAMETER_COLUMNS


class SweepError(ValueError):
    """Bad sweep settings: grid syntax, chunk size, or an output made with other settings."""


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
    """Parse ``--grid`` specifications (syntax: docs/sweeps.md).

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

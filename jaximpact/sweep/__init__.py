"""Large sweeps: millions of impacts in fixed-size chunks, streamed to Parquet, resumable.

The design and the on-disk layout: docs/sweeps.md."""

from ._run import DEFAULT_CHUNK_SIZE as DEFAULT_CHUNK_SIZE
from ._run import DEFAULT_CHUNK_SIZE_FLOAT32 as DEFAULT_CHUNK_SIZE_FLOAT32
from ._run import SweepSummary as SweepSummary
from ._run import default_chunk_size as default_chunk_size
from ._run import run_sweep as run_sweep
from ._sources import GRID_NAMES as GRID_NAMES
from ._sources import GridSource as GridSource
from ._sources import SweepError as SweepError
from ._sources import TableSource as TableSource
from ._sources import parse_grid as parse_grid
from ._sources import read_impacts_file as read_impacts_file
from ._store import FORMAT as FORMAT
from ._store import describe_failures as describe_failures
from ._store import iter_chunks as iter_chunks
from ._store import read_sweep as read_sweep
from ._store import read_sweep_columns as read_sweep_columns

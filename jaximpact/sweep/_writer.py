"""Writing solved chunks: each chunk's Arrow table and Parquet part file on a pool of threads,
then, in chunk order, the manifest that lists it."""

from __future__ import annotations

import os
from collections import deque

import numpy as np

from .._io.columns import TEXT_RESULT_COLUMNS
from ._chunks import _status_texts
from ._store import _schema

#: Parquet settings of the part files: dictionary encoding for the input columns (a grid's
#: axes repeat a few values; a table's inputs fall back to plain encoding) and the text
#: columns (status, failure_reason: a handful of values), not for the result columns. pyarrow's
#: default tries a dictionary for every column and gives it up for float columns only after
#: filling a page: a 1,048,576-row chunk of the default columns encoded 2.2x faster without
#: that attempt (BENCHMARKS.md, "Sweep host side"). No compression by default: on 2 cores the
#: pipeline handled 3.7-4.0 million rows/s of real results against 2.9-3.0 with Snappy
#: (files 18 % larger; lz4 as slow as Snappy, zstd slower); ``--compression`` picks another.
COMPRESSION = "none"
COMPRESSIONS = ("none", "snappy", "lz4", "zstd")


def parquet_options(input_columns, result_columns, compression=None) -> dict:
    """Keyword arguments of ``pyarrow.parquet.write_table`` for a part file (``compression``:
    one of :data:`COMPRESSIONS`; default :data:`COMPRESSION`)."""
    text = [c for c in TEXT_RESULT_COLUMNS if c in result_columns]
    # statistics (min/max per page) for the inputs alone: what readers filter on (16 % of the
    # encoding's time for the result columns)
    return {
        "compression": compression or COMPRESSION,
        "use_dictionary": [*input_columns, *text],
        "write_statistics": list(input_columns),
    }


def writer_threads() -> int:
    """Threads that encode and write part files at once (pyarrow releases the GIL while
    encoding): one per core this process may use, at least 4 (writing waits on the disk too:
    on 2 cores 4 threads handled 1.05-1.26x the rows/s of 2 with chunks of 131,072 rows and
    more) and at most 8 (each holds a chunk: memory)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(4, min(cores, 8))


def _chunk_table(
    inputs: dict, columns, status, values, settings_hash: str, result_columns, stored="float64"
):
    """One chunk's part file: inputs, then ``result_columns`` (``failure_reason`` null unless
    failed; numbers as ``stored``), units as field metadata, the settings hash as file
    metadata. ``status``: codes; ``values``: the numeric result columns in ``OUTPUT_FIELDS``
    order (``_fetch``)."""
    import pyarrow as pa

    from .._engine.results import OUTPUT_FIELDS

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
            arrays.append(pa.array(np.asarray(numbers[name], stored)))
    table = pa.Table.from_arrays(arrays, schema=_schema(columns, result_columns, stored))
    return table.replace_schema_metadata({"jaximpact.settings_hash": settings_hash})


class _Writer:
    """Part files written on ``threads`` threads at once, committed in submission order.

    ``write(*item)`` (on a pool thread) builds and writes a chunk's part file; ``commit(*item)``
    (on the caller's thread, in the order the items were submitted) records it in the
    manifest. At most ``threads`` chunks are held: ``submit`` first commits the oldest once
    that many are in flight, so memory stays bounded by a few chunks. An error of a write is
    raised by the ``submit`` or ``finish`` that commits its chunk; a chunk whose part file was
    written but not committed (an interruption) is computed again on resumption.
    """

    def __init__(self, write, commit, threads: int):
        from concurrent.futures import ThreadPoolExecutor

        self._write, self._commit = write, commit
        self._threads = max(1, int(threads))
        self._pool = ThreadPoolExecutor(self._threads, thread_name_prefix="sweep-writer")
        self._pending: deque = deque()

    def _commit_oldest(self) -> None:
        future, item = self._pending.popleft()
        future.result()  # the write's error, if any
        self._commit(*item)

    def submit(self, *item) -> None:
        while len(self._pending) >= self._threads:
            self._commit_oldest()
        self._pending.append((self._pool.submit(self._write, *item), item))

    def finish(self) -> None:
        """Wait until everything submitted is written and committed; raise the first error."""
        while self._pending:
            self._commit_oldest()

    def close(self) -> None:
        """Stop the pool after the writes under way (also after an error in the caller);
        queued writes are dropped, uncommitted."""
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._pending.clear()

"""Writing one solved chunk: its Arrow table, then its part file and the manifest, on a thread
of their own."""

from __future__ import annotations

import numpy as np

from ._chunks import _status_texts
from ._store import _schema


def _chunk_table(inputs: dict, columns, status, values, settings_hash: str, result_columns):
    """One chunk's part file: inputs, then ``result_columns`` (``failure_reason`` null unless
    failed), units as field metadata, the settings hash as file metadata. ``status``: codes;
    ``values``: the numeric result columns in ``OUTPUT_FIELDS`` order (``_fetch``)."""
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

"""The host side of `jaximpact sweep` alone: rows/s of its pipeline fed with precomputed results.

Run: ``python benchmarks/sweep_host.py [--rows N] [--chunks 32768 131072 1048576]
[--threads 1 2 4]`` (about 2 minutes on 2 cores).

No impact is solved. The results of 65,536 real float64 impacts of the Table 1 scene (a grid
of speed, angle, spin and f0) are computed once and tiled to each chunk's size (each copy
scaled by its own factor 1 + k 1e-9, so that no row repeats another); the program
that "solves" a chunk returns them from the device as the sweep's program would. Measured:

- each stage alone, on one thread, one chunk of each size: *inputs* (the chunk's grid rows
  and parameter arrays), *fetch* (device to host), *table* (the Arrow table), *encode* (the
  Parquet bytes, in memory) and *write* (the atomic file write of those bytes);
- the pipeline as the sweep runs it (``jaximpact.sweep._run._Pipeline``: dispatch, fetch,
  part files on ``threads`` writer threads, manifests in chunk order) over ``--rows`` rows, by
  compression, chunk size and writer-thread count;
- the Parquet settings: pyarrow's defaults against the sweep's (dictionary only for the input
  and text columns, statistics only for the inputs), by compression (the sweep's default:
  none); bytes per row by ``--columns``.

The sweep's default columns: the impact inputs (speed, angle_deg, omega0, f0) and every
result column (``jaximpact._io.tables.RESULT_COLUMNS``).
"""

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import jaximpact

jaximpact.use_all_cpu_cores()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import load_average, machine, measured_line, table, write_result  # noqa: E402

from jaximpact._engine.results import OUTPUT_FIELDS  # noqa: E402
from jaximpact._io.tables import RESULT_COLUMNS  # noqa: E402
from jaximpact.sweep import _chunks, _run, _store, _writer  # noqa: E402
from jaximpact.sweep._sources import GridSource  # noqa: E402

COMMAND = "python benchmarks/sweep_host.py"
REAL = 65_536


def _grid(rows: int) -> GridSource:
    """A grid of at least ``rows`` impacts (speed x angle x spin x f0)."""
    speeds = max(1, rows // (64 * 8 * 4))
    axes = {
        "speed": np.geomspace(0.05, 10.0, speeds),
        "angle_deg": np.linspace(-80.0, 80.0, 64),
        "omega0": np.linspace(-2e4, 2e4, 8),
        "f0": np.linspace(100.0, 400.0, 4),
    }
    return GridSource(axes, {"speed": 1.0, "angle_deg": 0.0, "omega0": 0.0})


def real_results():
    """Status codes and result columns of REAL solved impacts (float64, Table 1 scene)."""
    source = _grid(REAL)
    rows = source.rows(0, REAL)
    scene = jaximpact.table1_scene()
    result = jaximpact.simulate(
        scene.replace(contact={"f0": rows["f0"]}), rows["speed"], rows["angle_deg"], rows["omega0"]
    )
    status = np.asarray(result.status, np.int32)
    values = np.stack([np.asarray(getattr(result, k), np.float64) for k in OUTPUT_FIELDS])
    return status, values


def _tiled(status, values, size):
    """``size`` rows of the REAL results, each copy scaled by its own factor 1 + k 1e-9 (a
    sweep's impacts differ: exact copies would flatter dictionary encoding)."""
    reps = -(-size // status.size)
    scale = np.repeat(1.0 + 1e-9 * np.arange(reps), status.size)
    return np.tile(status, reps)[:size], (np.tile(values, (1, reps)) * scale)[:, :size]


def _rate(seconds, rows):
    return rows / seconds / 1e6


def stage_rates(status, values, size, repeats=3):
    """Million rows/s of each stage alone, one thread, a chunk of ``size`` rows."""
    source = _grid(size)
    scene = jaximpact.table1_scene()
    base, _, _ = _chunks._model_config(scene, source, size, np.float64)
    st, vals = _tiled(status, values, size)
    device = (jax.device_put(st), jax.device_put(vals))
    times = {k: [] for k in ("inputs", "fetch", "table", "encode", "write")}
    work = Path(tempfile.mkdtemp(prefix="sweep_host-"))
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        for _ in range(repeats):
            t = time.perf_counter()
            rows, valid, _ = _chunks._chunk_inputs(source, base, 0, size, np.float64)
            times["inputs"].append(time.perf_counter() - t)
            t = time.perf_counter()
            s, v = _chunks._fetch(device, valid)
            times["fetch"].append(time.perf_counter() - t)
            t = time.perf_counter()
            tab = _writer._chunk_table(rows, source.columns, s, v, "x", RESULT_COLUMNS)
            times["table"].append(time.perf_counter() - t)
            t = time.perf_counter()
            buffer = pa.BufferOutputStream()
            pq.write_table(tab, buffer, **_writer.parquet_options(source.columns, RESULT_COLUMNS))
            data = buffer.getvalue().to_pybytes()
            times["encode"].append(time.perf_counter() - t)
            t = time.perf_counter()
            _store.atomic_write_bytes(work / "part.parquet", data)
            times["write"].append(time.perf_counter() - t)
        size_per_row = len(data) / size
    finally:
        shutil.rmtree(work, ignore_errors=True)
    rates = {k: _rate(statistics.median(v), size) for k, v in times.items()}
    serial = size / sum(statistics.median(v) for v in times.values()) / 1e6
    return rates, serial, size_per_row


def encoding_rates(status, values, size):
    """Million rows/s and bytes/row of the encoding with pyarrow's defaults and the sweep's
    settings, by compression (one thread)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    source = _grid(size)
    rows = source.rows(0, size)
    st, vals = _tiled(status, values, size)
    tab = _writer._chunk_table(rows, source.columns, st, vals, "x", RESULT_COLUMNS)
    out = []
    for label, options in (
        ("pyarrow defaults (snappy, dictionary for every column)", {}),
        ("dictionary for the text columns only, snappy",
         {"compression": "snappy", "use_dictionary": ["status", "failure_reason"]}),
        *(
            (f"sweep's: dictionary for inputs and text columns, {c}",
             {**_writer.parquet_options(source.columns, RESULT_COLUMNS), "compression": c})
            for c in ("snappy", "lz4", "zstd", "none")
        ),
    ):  # fmt: skip
        seconds = []
        for _ in range(3):
            buffer = pa.BufferOutputStream()
            t = time.perf_counter()
            pq.write_table(tab, buffer, **options)
            seconds.append(time.perf_counter() - t)
        out.append((label, _rate(statistics.median(seconds), size), len(buffer.getvalue()) / size))
    return out


COLUMN_SETS = {
    "all (default)": RESULT_COLUMNS,
    "cor_n,cor_t,omega_out,contact_time": ("status", "cor_n", "cor_t", "omega_out",
                                            "contact_time"),
    "cor_n": ("status", "cor_n"),
}  # fmt: skip


def column_set_sizes(status, values, size):
    """Bytes per row of a part file by the result columns kept (``--columns``)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    source = _grid(size)
    rows = source.rows(0, size)
    st, vals = _tiled(status, values, size)
    out = []
    for label, columns in COLUMN_SETS.items():
        tab = _writer._chunk_table(rows, source.columns, st, vals, "x", columns)
        buffer = pa.BufferOutputStream()
        pq.write_table(tab, buffer, **_writer.parquet_options(source.columns, columns))
        out.append((label, len(columns), len(buffer.getvalue()) / size))
    return out


def pipeline_rate(status, values, rows, size, threads, compression=None):
    """Million rows/s of the sweep's pipeline (no solving) over ``rows`` rows."""
    source = _grid(rows)
    n = (source.n // size) * size or size
    scene = jaximpact.table1_scene()
    base, _, _ = _chunks._model_config(scene, source, size, np.float64)
    st, vals = _tiled(status, values, size)
    device = (jax.device_put(st), jax.device_put(vals))
    sharding = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
    work = Path(tempfile.mkdtemp(prefix="sweep_host-"))
    try:
        manifest = {"format": _store.FORMAT, "settings_hash": "x", "settings": {},
                    "process_index": 0, "process_count": 1,
                    "result_columns": list(RESULT_COLUMNS)}  # fmt: skip
        pipeline = _run._Pipeline(
            source, base, size, np.float64, lambda *args: device, sharding, work, manifest,
            RESULT_COLUMNS, [], {},
        )  # fmt: skip
        pipeline.threads = threads
        pipeline.compression = compression
        todo = list(range(n // size))

        class _Bar:  # the progress bar's interface, silent
            def update(self, n):
                pass

            def close(self):
                pass

        t = time.perf_counter()
        pipeline.run(todo, _Bar())
        seconds = time.perf_counter() - t
        written = sum(f.stat().st_size for f in work.glob("part-*.parquet"))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return _rate(seconds, len(todo) * size), written / (len(todo) * size)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1 << 23, help="rows per pipeline run (8.4M)")
    ap.add_argument("--chunks", type=int, nargs="+", default=[32768, 131072, 1048576])
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2, 4])
    args = ap.parse_args()
    info = machine()
    status, values = real_results()
    lines = ["### Sweep host side\n", measured_line(info, COMMAND)]
    lines.append(
        f"\nCPU devices: {len(jax.local_devices())}; writer threads by default: "
        f"{_writer.writer_threads()}. Million rows/s (medians of 3), default columns "
        f"({4 + len(RESULT_COLUMNS)}: 4 inputs, {len(RESULT_COLUMNS)} results).\n"
    )
    rows = []
    for size in args.chunks:
        rates, serial, per_row = stage_rates(status, values, size)
        rows.append([f"{size:,}"] + [f"{rates[k]:.1f}" for k in rates]
                    + [f"{serial:.2f}", f"{per_row:.0f}"])  # fmt: skip
        print(rows[-1], file=sys.stderr, flush=True)
    lines.append("Each stage alone (one thread):\n")
    lines.append(table(["chunk", "inputs", "fetch", "table", "encode", "write",
                        "all stages in series", "bytes/row"], rows))  # fmt: skip
    rows = []
    for label, rate, per_row in encoding_rates(status, values, max(args.chunks)):
        rows.append([label, f"{rate:.2f}", f"{per_row:.0f}"])
    lines.append(f"\nParquet encoding of a {max(args.chunks):,}-row chunk (one thread):\n")
    lines.append(table(["settings", "M rows/s", "bytes/row"], rows))
    rows = [[label, str(n), f"{b:.0f}"] for label, n, b in
            column_set_sizes(status, values, max(args.chunks))]  # fmt: skip
    lines.append(f"\nBytes per row of a {max(args.chunks):,}-row part file by `--columns`:\n")
    lines.append(table(["--columns", "result columns (status included)", "bytes/row"], rows))
    rows = []
    for compression in ("none", "snappy"):
        for size in args.chunks:
            for threads in args.threads:
                rate, per_row = pipeline_rate(status, values, args.rows, size, threads,
                                              compression)  # fmt: skip
                rows.append([compression, f"{size:,}", str(threads), f"{rate:.2f}",
                             f"{per_row:.0f}"])  # fmt: skip
                print(rows[-1], file=sys.stderr, flush=True)
    lines.append(
        f"\nThe pipeline (no solving) over {args.rows:,} rows (default: no compression, "
        f"{_writer.writer_threads()} writer threads here):\n"
    )
    lines.append(table(["compression", "chunk", "writer threads", "M rows/s",
                        "bytes/row on disk"], rows))  # fmt: skip
    print("\n".join(lines))
    print(f"load average at the end: {load_average()}")
    write_result("sweep_host", {"markdown": "\n".join(lines)}, info, COMMAND)


if __name__ == "__main__":
    main()

"""``jaximpact sweep``: its options, help text and command (the engine: this package)."""

import argparse
import sys

SWEEP_EPILOG = """\
impacts: --impacts FILE (.csv, or Parquet with the same columns), or a grid:
  one --grid per axis; the cartesian product, the last axis varying fastest:
    NAME=VALUE               one value              omega0=0
    NAME=V1,V2,...           a list                 angle_deg=-40,0,40
    NAME=START:STOP:NUM      NUM values, linear     angle_deg=-60:60:25  (ends included)
    NAME=START:STOP:NUM:log  NUM values, geometric  speed=0.1:5:50:log
  NAME: speed, angle_deg, omega0 (default: the scene's [impact]) or a scene parameter
  (radius, density, K, f0, C_A, C_H, friction, lambda).

output: a directory RESULTS.parquet/ of part-NNNNNN.parquet files (the results-CSV columns;
  status and failure_reason as text, failure_reason null unless failed; each column's SI unit
  as Parquet field metadata {"unit": "m/s"}) and _manifest-PPPPP.json files (settings,
  completed chunks, failure counts). Read it with jaximpact.sweep.read_sweep(path),
  pyarrow.parquet.read_table(path), pandas.read_parquet(path), or with polars and DuckDB
  through the glob RESULTS.parquet/*.parquet. -o must be new, empty, or a sweep; missing parent
  directories are created. Sweeps with the older manifest-PPPPP.json names stay readable and
  resumable (a resume renames them).

resume: run the same command again; finished chunks are kept. Other settings (scene, impacts,
  chunk size, precision, version) are refused, naming each that differs, unless --restart.

exit status: 0 done (a warning counts the failed impacts per reason); 1 every impact of the
  sweep (done so far) failed, or the computation failed; 2 bad input or a file problem (one
  line naming the path or field; checked before any computing).

devices: each chunk is split over all local JAX devices (GPUs; on CPU force several with
  XLA_FLAGS=--xla_force_host_platform_device_count=N). --distributed: one process per host,
  each taking chunks i with i % process_count == process_index.

example:
  jaximpact sweep --grid speed=0.1:5:50:log --grid angle_deg=-60:60:25 --grid f0=100:400:4 \\
      -o sweep.parquet
"""


def cmd_sweep(args) -> int:
    import os

    import jax

    if args.precision == "float64":
        jax.config.update("jax_enable_x64", True)
    from .. import load_scene
    from . import GridSource, describe_failures, parse_grid, read_impacts_file, run_sweep

    # Inputs first (numpy only): a typo should fail before any distributed rendezvous.
    source = read_impacts_file(args.impacts) if args.impacts else None
    axes = None if args.impacts else parse_grid(args.grid)
    if args.distributed and not jax.distributed.is_initialized():
        # jax.distributed.initialize must run before a JAX backend starts, and importing
        # jaximpact already starts one (the scene defaults are arrays). So start this command
        # again in a fresh interpreter that initializes first, then imports jaximpact; None
        # values let JAX detect the cluster (SLURM, Open MPI, Kubernetes, ...).
        init = {
            "coordinator_address": args.coordinator,
            "num_processes": args.num_processes,
            "process_id": args.process_id,
        }
        boot = (
            f"import sys, jax; jax.distributed.initialize(**{init!r}); "
            "from jaximpact.cli import main; sys.exit(main(sys.argv[1:]))"
        )
        sys.stdout.flush()
        os.execv(sys.executable, [sys.executable, "-c", boot, *sys.argv[1:]])
    if source is None:
        impact = load_scene(args.scene).impact
        defaults = {k: float(getattr(impact, k)) for k in ("speed", "angle_deg", "omega0")}
        source = GridSource(axes, defaults)
    summary = run_sweep(
        source,
        args.output,
        scene_path=args.scene,
        chunk_size=args.chunk_size,
        restart=args.restart,
        progress=not args.no_progress,
        columns=args.columns,
        compression=args.compression,
        stored_precision=args.stored_precision,
    )
    print(summary_line(summary))
    if summary.legacy_columns:
        print(
            "note: this sweep was begun before failure_reason existed; it keeps its columns "
            "(reasons are not stored; --restart to get them)",
            file=sys.stderr,
        )
    if summary.failures:
        n_failed = sum(summary.failures.values())
        counts = describe_failures(summary.failures)
        if n_failed == summary.impacts_done:
            print(
                f"error: all {n_failed} impacts of the sweep failed: {counts}; see the "
                "failure_reason column",
                file=sys.stderr,
            )
            return 1
        print(
            f"warning: {n_failed} of {summary.impacts_done} impacts failed: {counts}; see the "
            "status and failure_reason columns",
            file=sys.stderr,
        )
    return 0


def summary_line(summary) -> str:
    """The line a finished ``jaximpact sweep`` prints (a `SweepSummary`)."""
    rate = (
        f" ({summary.impacts_run / summary.seconds:.0f} impacts/s)"
        if summary.impacts_run and summary.seconds
        else ""
    )
    return (
        f"sweep {summary.output}: {_count(summary.n_impacts, 'impact')} in "
        f"{_count(summary.n_chunks, 'chunk')} of {summary.chunk_size} on "
        f"{_count(summary.devices, 'device')}; this run: {_count(summary.chunks_run, 'chunk')}, "
        f"{_count(summary.impacts_run, 'impact')} in {summary.seconds:.1f} s{rate}, "
        f"{summary.chunks_skipped} already done; "
        + ("complete" if summary.complete else "incomplete (other processes' chunks pending)")
    )


def _count(n: int, noun: str) -> str:
    """``1 chunk``, ``2 chunks``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def add_sweep_command(sub) -> None:
    """Register ``jaximpact sweep`` on the subcommand parsers ``sub``."""
    import os

    from . import DEFAULT_CHUNK_SIZE, DEFAULT_CHUNK_SIZE_FLOAT32

    env_int = lambda name: int(os.environ[name]) if os.environ.get(name) else None  # noqa: E731
    sw = sub.add_parser(
        "sweep",
        help="large sweeps: chunked, streamed to Parquet, resumable, multi-device",
        description="Simulate many impacts (a file or a grid) in fixed-size chunks, writing "
        "each finished chunk to a Parquet dataset; resumable and sharded over devices.",
        epilog=SWEEP_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sw.add_argument(
        "scene", nargs="?", help="scene: an embedded name (`jaximpact scenes`) or a TOML file"
    )
    what = sw.add_mutually_exclusive_group(required=True)
    what.add_argument("--impacts", help="impacts file: CSV or Parquet (columns as the CSV)")
    what.add_argument(
        "--grid", action="append", metavar="NAME=SPEC", help="a grid axis (repeat; see below)"
    )
    sw.add_argument("-o", "--output", required=True, help="output directory (RESULTS.parquet)")
    sw.add_argument(
        "--chunk-size",
        type=int,
        default=None,
        help=f"impacts per chunk, a multiple of the local device count (default: the sweep's "
        f"own when continuing one, else {DEFAULT_CHUNK_SIZE}, or "
        f"{DEFAULT_CHUNK_SIZE_FLOAT32} in float32); memory grows with it",
    )
    sw.add_argument("--precision", choices=("float64", "float32"), default="float64")
    sw.add_argument(
        "--columns",
        metavar="LIST",
        help="result columns to store, comma-separated (status is always kept; default: all "
        "of them, about 120 bytes a row; cor_n,cor_t,omega_out,contact_time about 35)",
    )
    sw.add_argument(
        "--stored-precision",
        choices=("float64", "float32"),
        default=None,
        help="of the numeric result columns (float32: half the bytes, for float32 runs; "
        "default: the sweep's own when continuing one, else float64)",
    )
    sw.add_argument(
        "--compression",
        choices=("none", "snappy", "lz4", "zstd"),
        default=None,
        help="of the Parquet files (default none: the fastest to write; snappy about 15 %% "
        "smaller, zstd 25 %%, each slower)",
    )
    sw.add_argument("--restart", action="store_true", help="discard existing results in the output")
    sw.add_argument("--no-progress", action="store_true", help="no progress bar")
    sw.add_argument(
        "--distributed",
        action="store_true",
        help="initialize jax.distributed; each process takes every process_count-th chunk",
    )
    sw.add_argument(
        "--coordinator",
        default=os.environ.get("JAX_COORDINATOR_ADDRESS"),
        help="host:port of process 0 (default $JAX_COORDINATOR_ADDRESS, else auto-detected)",
    )
    sw.add_argument(
        "--num-processes",
        type=int,
        default=env_int("JAX_NUM_PROCESSES"),
        help="(default $JAX_NUM_PROCESSES, else auto-detected)",
    )
    sw.add_argument(
        "--process-id",
        type=int,
        default=env_int("JAX_PROCESS_ID"),
        help="(default $JAX_PROCESS_ID, else auto-detected)",
    )
    sw.set_defaults(func=cmd_sweep)

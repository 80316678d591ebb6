"""Large-sweep benchmark: a 1,000,000-impact sweep end to end, and scaling over host devices.

Run: ``python benchmarks/sweep_benchmark.py [--n 1000000] [--scaling-n 65536] [--repeats 3]``
(about 5 minutes on 2 cores for the defaults). Prints Markdown; ``--pipeline`` prints
BENCHMARKS.md's "Large sweeps" section.

* The big sweep runs the command line exactly as a user would (``jaximpact sweep`` on a Parquet
  impacts file, the embedded Table 1 scene, oblique spinning impacts, float64, chunks of 8192),
  under ``/usr/bin/time -v`` for the peak resident memory (``resource.getrusage`` of the
  children where that program is missing). Wall time includes start-up and compilation.
* Scaling: one worker process per forced host-device count
  (``XLA_FLAGS=--xla_force_host_platform_device_count=D``) compiles on a one-chunk warm-up sweep,
  then times ``run_sweep`` on ``--scaling-n`` impacts ``--repeats`` times (median), so the rate
  is the steady state without compilation. Forced host devices share the machine's cores, so
  little gain is expected beyond the core count.
* ``--pipeline``: the sweep's marginal rate against ``simulate``'s on the same
  impacts, in one worker process per precision and device count: ``run_sweep`` on ``N`` and on
  ``2N`` impacts (``N`` = ``--pipeline-chunks`` chunks, so compilation and the first chunk's
  latency cancel in the difference) and ``simulate`` on the same ``N`` and ``2N`` impacts in
  one call each (its own chunking inside; results left on the device), interleaved, medians of
  ``--repeats``; marginal rate = ``N / (t(2N) - t(N))``, the ratio taken within each repeat.
  Then one more sweep of ``2N`` with every phase of the sweep timed (exclusive times, by
  wrapping the sweep module's functions), and a bitwise comparison of its results with
  ``simulate``'s.
"""

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def make_impacts(path: Path, n: int, seed: int = 0) -> None:
    """Oblique spinning impacts: 0.5-5 m/s, -60..60 deg, |omega0| <= 2e4 rad/s (Parquet)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    rng = np.random.default_rng(seed)
    table = pa.table(
        {
            "speed": rng.uniform(0.5, 5.0, n),
            "angle_deg": rng.uniform(-60.0, 60.0, n),
            "omega0": rng.uniform(-2e4, 2e4, n),
        }
    )
    pq.write_table(table, path)


def dir_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.iterdir() if p.is_file())


def big_sweep(work: Path, n: int, chunk: int) -> dict:
    impacts = work / f"impacts-{n}.parquet"
    make_impacts(impacts, n)
    out = work / "big.parquet"
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "jaximpact.cli", "sweep", "--impacts", str(impacts)]
    cmd += ["-o", str(out), "--chunk-size", str(chunk), "--no-progress"]
    timer = shutil.which("time") or ("/usr/bin/time" if Path("/usr/bin/time").exists() else None)
    if timer:
        cmd = [timer, "-v", *cmd]
    t = time.perf_counter()
    run = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if run.returncode:
        raise SystemExit(f"sweep failed ({run.returncode}):\n{run.stderr[-3000:]}")
    match = re.search(r"Maximum resident set size \(kbytes\): (\d+)", run.stderr)
    if match:
        peak_mib = int(match.group(1)) / 1024
    else:  # ru_maxrss is in KiB on Linux
        peak_mib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    from jaximpact.sweep import read_sweep_columns

    status = read_sweep_columns(out)["status"]
    return {
        "n": n,
        "chunk": chunk,
        "wall_s": wall,
        "rate": n / wall,
        "peak_mib": peak_mib,
        "output_mib": dir_size(out) / 2**20,
        "input_mib": impacts.stat().st_size / 2**20,
        "statuses": {str(s): int(np.sum(status == s)) for s in np.unique(status)},
        "stdout": run.stdout.strip(),
    }


def worker(args) -> None:
    """Inside a process with forced host devices: warm up, then time steady-state sweeps."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from jaximpact.sweep import read_impacts_file, run_sweep

    work = Path(args.workdir)
    source = read_impacts_file(work / f"impacts-{args.scaling_n}.parquet")
    warm = read_impacts_file(work / "impacts-warmup.parquet")
    run_sweep(warm, work / "warm", chunk_size=args.chunk_size, progress=False, restart=True)
    times = []
    for _ in range(args.repeats):
        t = time.perf_counter()
        run_sweep(
            source, work / "scaling", chunk_size=args.chunk_size, progress=False, restart=True
        )
        times.append(time.perf_counter() - t)
    print(json.dumps({"devices": len(jax.local_devices()), "times": times}))


def scaling(work: Path, n: int, chunk: int, repeats: int) -> list[dict]:
    make_impacts(work / f"impacts-{n}.parquet", n, seed=1)
    make_impacts(work / "impacts-warmup.parquet", chunk, seed=2)
    rows = []
    for devices in (1, 2, 4):
        env = dict(os.environ, JAX_PLATFORMS="cpu")
        env["XLA_FLAGS"] = (
            env.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={devices}"
        ).strip()
        cmd = [sys.executable, __file__, "--worker", "--workdir", str(work)]
        cmd += ["--scaling-n", str(n), "--chunk-size", str(chunk), "--repeats", str(repeats)]
        run = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if run.returncode:
            raise SystemExit(f"worker failed:\n{run.stderr[-3000:]}")
        result = json.loads(run.stdout.strip().splitlines()[-1])
        median = float(np.median(result["times"]))
        rows.append({**result, "median_s": median, "rate": n / median})
    return rows


# ---------------------------------------------------------------------------------------------
# --pipeline: the sweep's marginal rate against simulate's, and where its time goes

PIPELINE_CONFIGS = "float64:1,float64:2,float32:1,float32:2"

# Functions of jaximpact.sweep's modules timed by the phase profile (those in the version run).
PHASES = {
    "_model_config": "setup: model terms, solver choice (stiffness scan of all impacts)",
    "_chunk_inputs": "inputs: rows, padding, parameters (host)",
    "_params": "inputs: parameters (host)",
    "dispatch": "dispatch the chunk (device_put, call; asynchronous)",
    "_fetch": "wait for the chunk, copy its results to the host",
    "_chunk_table": "convert the results to an Arrow table",
    "_atomic_write_table": "Parquet: encode the part file",
    "atomic_write_bytes": "part file: write, fsync, rename",
    "atomic_write_text": "manifest: write, fsync, rename",
    "_Writer.submit": "wait for the writer thread (the chunk before)",
    "_Writer.finish": "wait for the writer thread (the last chunk)",
}


class PhaseTimer:
    """Exclusive wall time per phase and thread: a wrapped call's time less its callees'."""

    def __init__(self):
        import threading

        self.local = threading.local()
        self.totals: dict[tuple[str, str], list] = {}

    def wrap(self, name, fn):
        import functools
        import threading

        @functools.wraps(fn)
        def timed(*args, **kwargs):
            stack = self.local.__dict__.setdefault("stack", [])
            stack.append(0.0)  # time spent in wrapped callees
            t = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                elapsed = time.perf_counter() - t
                inner = stack.pop()
                if stack:
                    stack[-1] += elapsed
                key = (threading.current_thread().name, name)
                total = self.totals.setdefault(key, [0.0, 0])
                total[0] += elapsed - inner
                total[1] += 1

        return timed

    def install(self, *modules):
        """Wrap the functions named in PHASES in each of ``modules`` (where the sweep calls
        them; a class's method once), and the runner's compiled function (the first module's)."""
        done = set()
        for module in modules:
            for name in PHASES:
                owner, _, attribute = name.rpartition(".")
                owner = getattr(module, owner, None) if owner else module
                if (id(owner), attribute) in done:
                    continue
                if callable(getattr(owner, attribute, None)) and name != "dispatch":
                    setattr(owner, attribute, self.wrap(name, getattr(owner, attribute)))
                    done.add((id(owner), attribute))
        module = modules[0]
        runner = module._runner

        def wrapped_runner(*args, **kwargs):
            fn, *rest = runner(*args, **kwargs)
            return (self.wrap("dispatch", fn), *rest)

        module._runner = wrapped_runner


def split_impacts(work: Path, n: int, seed: int) -> tuple[Path, Path]:
    """Files of the first ``n`` and all ``2n`` impacts of one random set."""
    import pyarrow.parquet as pq

    both = work / f"pipeline-{2 * n}.parquet"
    make_impacts(both, 2 * n, seed)
    half = work / f"pipeline-{n}.parquet"
    pq.write_table(pq.read_table(both).slice(0, n), half)
    return half, both


def pipeline_worker(args) -> None:
    """Inside one process (precision and forced device count set): see the module docstring."""
    import jax

    jax.config.update("jax_enable_x64", args.precision == "float64")
    import jaximpact as ji
    from jaximpact import sweep
    from jaximpact.tables import RESULT_COLUMNS

    work = Path(args.workdir)
    chunk, n = args.chunk_size, args.chunk_size * args.pipeline_chunks
    warm_file = work / "pipeline-warm.parquet"
    make_impacts(warm_file, chunk, seed=5)
    half, both = split_impacts(work, n, seed=4)
    sources = {"n": sweep.read_impacts_file(half), "2n": sweep.read_impacts_file(both)}
    scene = ji.load_scene()

    def run_sweep(source, tag):
        out = work / f"pipeline-out-{tag}"
        shutil.rmtree(out, ignore_errors=True)
        t, c = time.perf_counter(), time.process_time()
        sweep.run_sweep(source, out, chunk_size=chunk, progress=False)
        return time.perf_counter() - t, time.process_time() - c

    def run_simulate(source):
        table = source.table
        t, c = time.perf_counter(), time.process_time()
        result = ji.simulate(scene, table.speed, table.angle_deg, table.omega0)
        jax.block_until_ready(result)
        return time.perf_counter() - t, time.process_time() - c

    t = time.perf_counter()
    run_sweep(sweep.read_impacts_file(warm_file), "warm")  # compiles the sweep's program
    compile_sweep = time.perf_counter() - t
    t = time.perf_counter()
    for source in sources.values():
        run_simulate(source)  # compiles simulate's program for each batch size
    compile_simulate = time.perf_counter() - t

    runs = {
        "sweep n": lambda: run_sweep(sources["n"], "n"),
        "sweep 2n": lambda: run_sweep(sources["2n"], "2n"),
        "simulate n": lambda: run_simulate(sources["n"]),
        "simulate 2n": lambda: run_simulate(sources["2n"]),
    }
    names = list(runs)
    wall: dict[str, list] = {k: [] for k in names}
    cpu: dict[str, list] = {k: [] for k in names}
    for repeat in range(args.repeats):
        # Rotate the order so that a slow spell of the shared machine hits each kind alike.
        for name in names[repeat % 2 * 2 :] + names[: repeat % 2 * 2]:
            w, c = runs[name]()
            wall[name].append(w)
            cpu[name].append(c)

    timer = PhaseTimer()
    timer.install(sweep._run, sweep._chunks, sweep._writer, sweep._store)
    profiled = run_sweep(sources["2n"], "profile")[0]
    got = sweep.read_sweep_columns(work / "pipeline-out-profile")
    table = sources["2n"].table
    want = ji.simulate(scene, table.speed, table.angle_deg, table.omega0).columns()
    bitwise = all(
        np.array_equal(np.asarray(got[k]), np.asarray(want[k]).astype(got[k].dtype), equal_nan=True)
        if got[k].dtype.kind == "f"
        else np.array_equal(got[k], np.asarray(want[k], str))
        for k in RESULT_COLUMNS
    )
    print(
        json.dumps(
            {
                "precision": args.precision,
                "devices": len(jax.local_devices()),
                "chunk": chunk,
                "n": n,
                "wall": wall,
                "cpu": cpu,
                "compile_sweep_s": compile_sweep,
                "compile_simulate_s": compile_simulate,
                "profile_wall_s": profiled,
                "profile": [[t, k, v[0], v[1]] for (t, k), v in sorted(timer.totals.items())],
                "bitwise": bool(bitwise),
            }
        )
    )


def pipeline(work: Path, chunk: int, chunks: int, repeats: int, configs) -> list[dict]:
    from jaximpact._engine.devices import _with_loop_kernels
    from jaximpact.sweep import default_chunk_size

    rows = []
    for precision, devices in configs:
        env = dict(os.environ, JAX_PLATFORMS="cpu")
        # XLA's settings as the command line makes them (``use_all_cpu_cores``: loop kernels)
        env["XLA_FLAGS"] = _with_loop_kernels(
            env.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={devices}"
        ).strip()
        cmd = [sys.executable, __file__, "--pipeline-worker", "--workdir", str(work)]
        size = chunk or default_chunk_size(np.dtype(precision), devices)
        cmd += ["--precision", precision, "--chunk-size", str(size)]
        cmd += ["--pipeline-chunks", str(chunks), "--repeats", str(repeats)]
        run = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if run.returncode:
            raise SystemExit(f"pipeline worker failed:\n{run.stderr[-3000:]}")
        rows.append(json.loads(run.stdout.strip().splitlines()[-1]))
        print(f"<!-- {json.dumps(rows[-1])} -->", flush=True)
    return rows


def marginal(row: dict, kind: str, clock: str = "wall") -> tuple[float, float, float]:
    """Median times (``clock``: wall or CPU seconds) of ``N`` and ``2N`` impacts and the
    marginal rate ``N / (t(2N) - t(N))``."""
    t1 = float(np.median(row[clock][f"{kind} n"]))
    t2 = float(np.median(row[clock][f"{kind} 2n"]))
    return t1, t2, row["n"] / (t2 - t1)


def per_repeat(row: dict, clock: str) -> list[float]:
    """The ratio of marginal rates (sweep / simulate) within each repeat."""
    t = row[clock]
    return [
        (b2 - b1) / (a2 - a1)
        for a1, a2, b1, b2 in zip(
            t["sweep n"], t["sweep 2n"], t["simulate n"], t["simulate 2n"], strict=True
        )
    ]


def report_pipeline(rows: list[dict], repeats: int) -> None:
    print(
        "| precision | devices | clock | sweep N / 2N (s) | sweep marginal (impacts/s) | "
        "simulate N / 2N (s) | simulate marginal (impacts/s) | ratio | ratio per repeat | "
        "bitwise |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        for clock in ("wall", "cpu"):
            s1, s2, sweep_rate = marginal(row, "sweep", clock)
            m1, m2, sim_rate = marginal(row, "simulate", clock)
            print(
                f"| {row['precision']} | {row['devices']} | {clock} | {s1:.2f} / {s2:.2f} | "
                f"{sweep_rate:,.0f} | {m1:.2f} / {m2:.2f} | {sim_rate:,.0f} | "
                f"**{sweep_rate / sim_rate:.2f}** | "
                f"{', '.join(f'{r:.2f}' for r in per_repeat(row, clock))} | "
                f"{'yes' if row['bitwise'] else 'no'} |"
            )
    print(
        f"\nN = {rows[0]['n']:,} impacts ({rows[0]['n'] // rows[0]['chunk']} chunks of "
        f"{rows[0]['chunk']}); medians of {repeats} interleaved repeats; *wall*: wall-clock "
        "seconds, *cpu*: CPU-seconds of the process (all threads; rates per CPU-second); "
        "ratio = sweep's marginal rate / simulate's from the median times; per repeat: the "
        "same within each repeat. *bitwise*: every result column of the sweep equal to "
        "simulate's on the 2N impacts.\n"
    )
    print("Where a sweep of 2N spends its time (exclusive wall time per phase, one run):\n")
    print("| precision | devices | thread | phase | ms per chunk | share of the sweep |")
    print("|---|---|---|---|---|---|")
    for row in rows:
        n_chunks = 2 * row["n"] // row["chunk"]
        accounted = 0.0
        order = list(PHASES)  # main thread first, then the writer's; phases in PHASES order
        phases = sorted(row["profile"], key=lambda r: (r[0] != "MainThread", order.index(r[1])))
        for thread, name, seconds, _calls in phases:
            if thread == "MainThread":
                accounted += seconds
            print(
                f"| {row['precision']} | {row['devices']} | {thread} | {PHASES[name]} | "
                f"{1e3 * seconds / n_chunks:.1f} | {seconds / row['profile_wall_s']:.1%} |"
            )
        rest = row["profile_wall_s"] - accounted
        print(
            f"| {row['precision']} | {row['devices']} | MainThread | the rest (waiting for "
            f"results where not timed above, Python, manifests read) | "
            f"{1e3 * rest / n_chunks:.1f} | {rest / row['profile_wall_s']:.1%} |"
        )


def report_from_output(path: str, repeats: int) -> None:
    """Print the tables again from the JSON lines (``<!-- ... -->``) of earlier runs."""
    rows = []
    for file in path.split(","):
        for line in Path(file).read_text().splitlines():
            if line.startswith("<!-- "):
                rows.append(json.loads(line[5:-4]))
    report_pipeline(rows, repeats)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=1_000_000)
    parser.add_argument(
        "--chunk-size", type=int, default=None, help="default: the sweep's, by precision"
    )
    parser.add_argument("--scaling-n", type=int, default=65536)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-big", action="store_true")
    parser.add_argument("--workdir", help="keep files here (default: a temporary directory)")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument(
        "--pipeline", action="store_true", help="only the sweep-against-simulate comparison"
    )
    parser.add_argument("--pipeline-chunks", type=int, default=4, help="N in chunks")
    parser.add_argument(
        "--pipeline-configs",
        default=PIPELINE_CONFIGS,
        help="precision:devices, comma-separated",
    )
    parser.add_argument("--pipeline-worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument(
        "--pipeline-report", metavar="FILES", help="re-print the tables from earlier outputs"
    )
    parser.add_argument("--precision", default="float64", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args)
        return
    if args.pipeline_worker:
        pipeline_worker(args)
        return
    if args.pipeline_report:
        report_from_output(args.pipeline_report, args.repeats)
        return
    from _common import default_settings, machine, measured_line, write_result

    work = Path(args.workdir or tempfile.mkdtemp(prefix="sweep-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    if args.pipeline:
        configs = [
            (c.split(":")[0], int(c.split(":")[1])) for c in args.pipeline_configs.split(",")
        ]
        command = "python benchmarks/sweep_benchmark.py --pipeline"
        if args.pipeline_configs != PIPELINE_CONFIGS:
            command += f" --pipeline-configs {args.pipeline_configs}"
        if args.chunk_size:
            command += f" --chunk-size {args.chunk_size}"
        if args.pipeline_chunks != 4:
            command += f" --pipeline-chunks {args.pipeline_chunks}"
        if args.repeats != 3:
            command += f" --repeats {args.repeats}"
        print("## Large sweeps\n")
        info = machine()
        print(measured_line(info, command, settings=default_settings()))
        print(
            "Embedded Table 1 scene, oblique spinning impacts (0.5-5 m/s, -60..60 deg, "
            "|omega0| <= 2e4 rad/s): the sweep's marginal rate against `simulate`'s on the "
            "same impacts.\n"
        )
        rows = pipeline(work, args.chunk_size, args.pipeline_chunks, args.repeats, configs)
        report_pipeline(rows, args.repeats)
        write_result("sweep_benchmark_pipeline", rows, info, command)
        if not args.workdir:
            shutil.rmtree(work, ignore_errors=True)
        return
    args.chunk_size = args.chunk_size or 8192  # float64 below
    print("### A sweep end to end, and over host devices\n")
    info = machine()
    command = (
        "python benchmarks/sweep_benchmark.py"
        + (f" --n {args.n}" if args.n != 1_000_000 else "")
        + (f" --scaling-n {args.scaling_n}" if args.scaling_n != 65536 else "")
    )
    print(measured_line(info, command, settings=default_settings()))
    print(
        "`jaximpact sweep` on the embedded Table 1 scene, oblique spinning impacts "
        "(0.5-5 m/s, -60..60 deg, |omega0| <= 2e4 rad/s), float64.\n"
    )
    big = None
    if not args.skip_big:
        big = big_sweep(work, args.n, args.chunk_size)
        print(
            "| impacts | chunk | wall (s) | impacts/s | peak RSS (MiB) | output (MiB) | "
            "input (MiB) |"
        )
        print("|---|---|---|---|---|---|---|")
        print(
            f"| {big['n']:,} | {big['chunk']} | {big['wall_s']:.0f} | {big['rate']:.0f} | "
            f"{big['peak_mib']:.0f} | {big['output_mib']:.1f} | {big['input_mib']:.1f} |"
        )
        print(f"\nStatuses: {big['statuses']}. CLI summary: {big['stdout']}\n")
    rows = scaling(work, args.scaling_n, args.chunk_size, args.repeats)
    print(
        f"Scaling over forced host devices ({args.scaling_n:,} impacts, chunks of "
        f"{args.chunk_size}, median of {args.repeats} after compilation):\n"
    )
    print("| devices | median (s) | impacts/s | speed-up |")
    print("|---|---|---|---|")
    for row in rows:
        print(
            f"| {row['devices']} | {row['median_s']:.2f} | {row['rate']:.0f} | "
            f"{row['rate'] / rows[0]['rate']:.2f} |"
        )
    write_result("sweep_benchmark", {"big": big, "scaling": rows}, info, command)
    if not args.workdir:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()

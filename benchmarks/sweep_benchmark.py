"""Large-sweep benchmark: a 1,000,000-impact sweep end to end, and scaling over host devices.

Run: ``python benchmarks/sweep_benchmark.py [--n 1000000] [--scaling-n 65536] [--repeats 3]``
(about 5 minutes on 2 cores for the defaults). Prints a Markdown section for BENCHMARKS.md.

* The big sweep runs the command line exactly as a user would (``jaximpact sweep`` on a Parquet
  impacts file, the embedded Table 1 scene, oblique spinning impacts, float64, chunks of 8192),
  under ``/usr/bin/time -v`` for the peak resident memory (``resource.getrusage`` of the
  children where that program is missing). Wall time includes start-up and compilation.
* Scaling: one worker process per forced host-device count
  (``XLA_FLAGS=--xla_force_host_platform_device_count=D``) compiles on a one-chunk warm-up sweep,
  then times ``run_sweep`` on ``--scaling-n`` impacts ``--repeats`` times (median), so the rate
  is the steady state without compilation. Forced host devices share the machine's cores, so
  little gain is expected beyond the core count.
"""

import argparse
import json
import os
import platform
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=1_000_000)
    parser.add_argument("--chunk-size", type=int, default=8192)
    parser.add_argument("--scaling-n", type=int, default=65536)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-big", action="store_true")
    parser.add_argument("--workdir", help="keep files here (default: a temporary directory)")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args)
        return
    import jax

    work = Path(args.workdir or tempfile.mkdtemp(prefix="sweep-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    print("## Large sweeps (`jaximpact sweep`)\n")
    print(
        f"Machine: {platform.machine()}, {os.cpu_count()} CPU cores, jax {jax.__version__}; "
        "embedded Table 1 scene, oblique spinning impacts (0.5-5 m/s, -60..60 deg, "
        "|omega0| <= 2e4 rad/s), float64.\n"
    )
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
    if not args.workdir:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()

"""Throughput by instruction set: the same CPU with XLA limited to AVX2 or AVX (issue 32).

BENCHMARKS' rates come from CPUs with AVX-512; users also run on CPUs without it (AVX2 only,
e.g. many AMD EPYC). XLA's ``--xla_cpu_max_isa`` limits the instructions it emits, so one
machine can measure what a narrower CPU's vector units give (the same cores, caches and clock:
only the instruction set differs, which isolates what the AVX-512 gain rests on).

Each case runs in a fresh process: ``jaximpact.simulate`` of N oblique spinning Table 1 impacts
(0.5-5 m/s, -60..60 deg, |omega0| <= 2e4 rad/s; ``use_all_cpu_cores()``), the first call
(compile) timed, then the median of ``--repeats`` warm calls. The cases alternate (default,
AVX2, AVX, default, ...) so that load drifts hit each alike; each row gives its ratio to the
default's median in the same run.

Run: ``python benchmarks/isa_comparison.py [--n 20000] [--repeats 3] [--rounds 2]``.

Duration: about 4 minutes on 2 cores with ``--rounds 2``.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import load_average, machine, write_result  # noqa: E402

WORKER = """
import json, sys, time
import jaximpact as ji
ji.use_all_cpu_cores()
import jax
import numpy as np
n, repeats, x64 = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3] == "float64"
jax.config.update("jax_enable_x64", x64)
rng = np.random.default_rng(0)
s, a, w = rng.uniform(0.5, 5, n), rng.uniform(-60, 60, n), rng.uniform(-2e4, 2e4, n)
scene = ji.table1_scene()
t0 = time.perf_counter()
np.asarray(ji.simulate(scene, s, a, w).cor_n)
first = time.perf_counter() - t0
times = []
for _ in range(repeats):
    t0 = time.perf_counter()
    r = ji.simulate(scene, s, a, w)
    np.asarray(r.cor_n)
    times.append(time.perf_counter() - t0)
ok = int(np.sum(np.asarray(r.status) <= 1))
print("RESULT " + json.dumps({"first": first, "times": times, "ok": ok}))
"""

ISAS = {"default": None, "AVX2": "AVX2", "AVX": "AVX"}


def run_case(isa, n, repeats, precision):
    env = dict(os.environ, JAXIMPACT_CACHE_DIR="off")
    flags = [f for f in env.get("XLA_FLAGS", "").split() if "max_isa" not in f]
    if ISAS[isa]:
        flags.append(f"--xla_cpu_max_isa={ISAS[isa]}")
    env["XLA_FLAGS"] = " ".join(flags)
    out = subprocess.run(
        [sys.executable, "-c", WORKER, str(n), str(repeats), precision],
        capture_output=True, text=True, env=env, timeout=1800,
    )  # fmt: skip
    if out.returncode != 0:
        raise RuntimeError(f"{isa} {precision}: {out.stderr[-2000:]}")
    line = next(x for x in out.stdout.splitlines() if x.startswith("RESULT "))
    return json.loads(line[len("RESULT ") :])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=2, help="alternating rounds of every case")
    ap.add_argument("--precisions", nargs="+", default=["float64", "float32"])
    args = ap.parse_args(argv)
    info = machine()
    print(info)
    print(f"load average at the start: {load_average()}")
    runs = {}
    for _ in range(args.rounds):
        for precision in args.precisions:
            for isa in ISAS:
                r = run_case(isa, args.n, args.repeats, precision)
                runs.setdefault((precision, isa), []).append(r)
                print(precision, isa, json.dumps(r), flush=True)
    print(f"load average at the end: {load_average()}")
    print()
    print("| precision | instruction set | impacts/s (median) | ratio to default | first call s |")
    print("|---|---|---|---|---|")
    rows = []
    for precision in args.precisions:
        base = None
        for isa in ISAS:
            rs = runs[(precision, isa)]
            rate = statistics.median(args.n / t for r in rs for t in r["times"])
            first = statistics.median(r["first"] for r in rs)
            base = base or rate
            print(f"| {precision} | {isa} | {rate:,.0f} | {rate / base:.2f} | {first:.1f} |")
            rows.append(dict(precision=precision, isa=isa, rate=rate, ratio=rate / base,
                             first=first, runs=rs))  # fmt: skip
    command = f"python benchmarks/isa_comparison.py --n {args.n} --rounds {args.rounds}"
    write_result("isa_comparison", {"n": args.n, "repeats": args.repeats, "rows": rows}, info,
                 command)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Loop kernels: impacts/s of the CPU settings side by side, with the error of each.

Run: ``python benchmarks/loop_kernels.py [--n 20000] [--repeats 5] [--update BENCHMARKS.md]``
(about 5 minutes on 2 cores); prints the Markdown of BENCHMARKS.md, "Loop kernels" (written
there with ``--update``).

Workload: ``n`` random oblique spinning impacts on the Table 1 contact without rolling moments
(0.3-10 m/s, -70..70 deg, |omega0| <= 2e4 rad/s), full outputs, default settings, float64 and
float32. Each configuration runs in a fresh process (XLA's settings are fixed when JAX starts):

- *one device*: the Python API as imported (XLA splits a large batch's operations over the
  cores);
- *device per core*: ``ji.use_all_cpu_cores(loop_kernels=False)``;
- *device per core, loop kernels*: ``ji.use_all_cpu_cores()``, as the command line runs: each
  device's step loop compiled into one kernel, the throughput program without XLA's fusion.

In the one-device process the plain peer, diffrax's ``diffeqsolve`` vmapped over the whole
batch, is timed too (interleaved with the default). Rate: median of ``repeats`` calls after the
first; compile: the first call minus that median. Error: the largest ``|cor_n - exact|`` over the
first 100 impacts (all rebounds), ``exact`` from ``jaximpact.reference`` (rtol 1e-12).
"""

import argparse
import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

TITLE = "Loop kernels"
CHECKED = 100  # impacts compared with the reference
MODES = {
    "one": "one device",
    "cores": "device per core",
    "kernels": "device per core, loop kernels (**CLI**)",
}


def impacts(n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.3, 10.0, n), rng.uniform(-70.0, 70.0, n), rng.uniform(-2e4, 2e4, n)


def scene_of(ji):
    return ji.table1_scene().replace(model={"rolling_moments": "none"})


def worker(cfg):
    """In the subprocess: time ``simulate`` (and the plain peer), print one JSON line."""
    from _common import interleaved_timings

    import jaximpact as ji

    if cfg["mode"] != "one":
        ji.use_all_cpu_cores(loop_kernels=cfg["mode"] == "kernels")
    import jax

    jax.config.update("jax_enable_x64", cfg["x64"])
    from jaximpact._engine.simulate import _simulate

    scene = scene_of(ji)
    speed, angle, omega0 = impacts(cfg["n"])
    calls = {"default": {}}
    if cfg["mode"] == "one":
        calls["plain"] = dict(chunk=0, loop="diffrax")
    fns = {
        name: (lambda kw=kw: jax.block_until_ready(_simulate(scene, speed, angle, omega0, **kw)))
        for name, kw in calls.items()
    }
    runs = interleaved_timings(fns, cfg["repeats"])  # first calls, then repeats in turn
    kernels = None
    if cfg["mode"] == "kernels":  # is the step loop one kernel in the compiled program?
        from jaximpact._engine.devices import compiler_options

        program = jax.jit(
            lambda s, a, w: _simulate(scene, s, a, w).cor_n,
            compiler_options=compiler_options(throughput=True),
        )
        text = program.lower(speed, angle, omega0).compile().as_text()
        kernels = text.count('xla_cpu_small_call="true"')
    for name, r in runs.items():
        run = r["median"]
        res = r["result"]
        out = dict(
            mode=cfg["mode"],
            x64=cfg["x64"],
            path=name,
            devices=len(jax.devices()),
            rate=cfg["n"] / run,
            run=run,
            compile=r["first"] - run,
            steps_median=float(np.median(np.asarray(res.steps))),
            # CPU-ns per step an impact needed (the devices' time over the steps of all impacts)
            ns_per_step=1e9 * run * len(jax.devices()) / float(np.sum(np.asarray(res.steps))),
            kernels=kernels if name == "default" else None,
            failed=int(np.sum(np.asarray(res.status) >= 2)),
            status=np.asarray(res.status)[:CHECKED].tolist(),
            cor_n=np.asarray(res.cor_n, float)[:CHECKED].tolist(),
        )
        print("RESULT " + json.dumps(out), flush=True)


def spawn(cfg, timeout=1800):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", json.dumps(cfg)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-3000:])
    return [json.loads(x[7:]) for x in proc.stdout.splitlines() if x.startswith("RESULT ")]


def measure(n=20000, repeats=5):
    from _common import reference_rows

    from jaximpact import reference

    results = []
    for x64 in (True, False):
        for mode in MODES:
            results += spawn(dict(mode=mode, x64=x64, n=n, repeats=repeats))
    speed, angle, omega0 = (x[:CHECKED] for x in impacts(n))
    params = dataclasses.replace(reference.table1_params(), rolling_moments="none")
    exact = reference_rows(params, speed, angle, omega0)
    for r in results:
        rebound = (np.asarray(r["status"]) == 0) & (exact["status"] == "rebound")
        r["checked"] = int(np.sum(rebound))
        r["error"] = float(np.max(np.abs(np.asarray(r["cor_n"]) - exact["cor_n"])[rebound]))
        r["status_mismatch"] = int(
            np.sum((np.asarray(r["status"]) == 0) != (exact["status"] == "rebound"))
        )
    return results


def report(results, n, repeats, info):
    from _common import default_settings, measured_line, table

    rows = []
    for x64 in (True, False):
        group = [r for r in results if r["x64"] == x64]
        base = next(r for r in group if r["mode"] == "one" and r["path"] == "default")
        plain = next(r for r in group if r["path"] == "plain")
        for r in group:
            name = (
                "`diffeqsolve` vmapped (plain peer)" if r["path"] == "plain" else MODES[r["mode"]]
            )
            rows.append(
                [
                    "float64" if x64 else "float32",
                    name,
                    r["devices"],
                    f"{r['rate']:,.0f}",
                    f"{r['rate'] / base['rate']:.2f}",
                    f"{r['rate'] / plain['rate']:.2f}",
                    f"{r['compile']:.1f}",
                    f"{r['steps_median']:.0f}",
                    f"{r['ns_per_step']:.0f}",
                    f"{r['error']:.1e} ({r['checked']})",
                    r["status_mismatch"] + r["failed"],
                ]
            )
    command = "python benchmarks/loop_kernels.py" + (f" --n {n}" if n != 20000 else "")
    command += f" --repeats {repeats}" if repeats != 5 else ""
    return "\n".join(
        [
            f"## {TITLE}\n",
            measured_line(info, command, settings=default_settings()),
            f"{n:,} random oblique spinning impacts on the Table 1 contact without rolling "
            "moments (0.3-10 m/s, -70..70 deg, |omega0| <= 2e4 rad/s), full outputs. One "
            "process per row group (XLA's settings are fixed when JAX starts): the Python API "
            "as imported (one device), `ji.use_all_cpu_cores(loop_kernels=False)` (one XLA "
            "device per core) and `ji.use_all_cpu_cores()` (as the command line runs: each "
            "device's step loop compiled into one kernel, the throughput program without "
            "XLA's operation fusion). Rates are medians of "
            f"{repeats} calls after the first; *vs one device* and *vs plain* are ratios to "
            "rows of the same precision (the plain peer, `diffeqsolve` vmapped over the whole "
            "batch, timed in the one-device process); *error*: the largest |cor_n - exact| "
            f"over the first {CHECKED} impacts that both call rebounds (their number in "
            "brackets), against `jaximpact.reference` at rtol 1e-12; *mismatches*: statuses "
            "that differ from the reference's, and failed impacts; *ns per step*: the devices' "
            "time (run time x devices) over the steps of all impacts (each lane's own, not "
            "its chunk's slowest). Every program prefers 512-bit vectors (XLA:CPU's default is "
            "256 bits where the CPU has 512). With loop kernels the compiled program holds "
            f"{kernels_text(results)} loops compiled as single kernels "
            "(`xla_cpu_small_call`; among them the step loop, the event's root find and, in "
            "float32, the pool's tail loop, where lanes are refilled as impacts finish); the "
            "rest of the program (chunks, refills, outputs) runs as XLA's usual kernels.\n",
            table(
                [
                    "precision",
                    "configuration",
                    "devices",
                    "impacts/s",
                    "vs one device",
                    "vs plain",
                    "compile (s)",
                    "steps (median)",
                    "ns per step",
                    "error (checked)",
                    "mismatches",
                ],
                rows,
            ),
            "",
        ]
    )


def kernels_text(results):
    """How many loops the loop-kernel programs compiled as single kernels, per precision."""
    found = [
        f"{r['kernels']} ({'float64' if r['x64'] else 'float32'})"
        for r in results
        if r.get("kernels") is not None
    ]
    return " and ".join(found) or "no"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--update", metavar="BENCHMARKS.md")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return worker(json.loads(args.worker))
    from _common import machine, replace_section, write_result

    info = machine()
    results = measure(args.n, args.repeats)
    md = report(results, args.n, args.repeats, info)
    print(md)
    figures = {"n": args.n, "repeats": args.repeats, "configurations": results}
    write_result("loop_kernels", figures, info, f"python benchmarks/loop_kernels.py --n {args.n}")
    if args.update:
        replace_section(args.update, md)
        print(f"replaced the section {TITLE!r} of {args.update}")


if __name__ == "__main__":
    main()

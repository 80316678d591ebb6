"""Throughput: impacts/s by batch size, batch paths, lane-step cost, against a scipy loop.

Impacts per second against batch size, compile time and peak memory; the batch paths side by
side; where a lane-step's time goes; jaximpact against a scipy ``solve_ivp`` loop.

Run (each prints the Markdown of its part of BENCHMARKS.md, "Throughput"):

- ``python benchmarks/run_all.py --only throughput`` (``run``): "By batch size and scene
  options", written into BENCHMARKS.md;
- ``python benchmarks/throughput.py --defaults [--compare-with CHECKOUT ...]``: "As a notebook
  runs it and as the command line runs it" (JAX's defaults against ``use_all_cpu_cores()``);
- ``python benchmarks/throughput.py --paths``: "Default path and alternatives";
- ``python benchmarks/throughput.py --profile``: "Where a lane-step's time goes";
- ``python benchmarks/throughput.py --scipy-ratio``: "Compared with a scipy `solve_ivp` loop".

Each configuration runs in a fresh subprocess (``python benchmarks/throughput.py --worker
JSON``) so that its peak resident memory (``VmHWM`` in ``/proc/self/status``, which includes
XLA's buffers) and its compile time are its own. Small batches (<= 1000) share one process per
scene and precision, run in increasing size (their VmHWM is the peak up to that size).

Impacts: the full oblique spinning Table 1 scene (0.5-5 m/s, -60..60 deg, |omega0| <= 2e4
rad/s) and normal impacts without spin (same speeds), which ``required_terms`` integrates
with the normal states only. Timings are medians of repeated calls after the first (compiling)
call; compile time = first call minus the median.

Duration: not recorded for each part; ``run`` is part of ``run_all.py``'s 20 minutes.
"""

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

KINDS = {
    "full": "oblique spinning (full model)",
    "normal": "normal, no spin (normal-only model)",
    "normal-forced-full": "same normal impacts at angle 1e-12 (full model compiled)",
    "normal-no-adhesion": "normal, no spin, f0 = 0 (no adhesion terms)",
    "full-cores": "oblique spinning, all CPU cores (`use_all_cpu_cores()`, as the CLI does)",
    "full-rebound": 'oblique spinning, `outputs = "rebound"` (motion only, no ledger)',
    "full-rebound-cores": 'oblique spinning, `outputs = "rebound"`, all CPU cores',
}


def impacts(kind, n, seed=0):
    rng = np.random.default_rng(seed)
    speed = rng.uniform(0.5, 5.0, n)
    if kind.startswith("full"):
        return speed, rng.uniform(-60.0, 60.0, n), rng.uniform(-2e4, 2e4, n)
    angle = np.full(n, 1e-12 if kind == "normal-forced-full" else 0.0)
    return speed, angle, np.zeros(n)


def vm_hwm_mb():
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def worker(cfg):
    """Runs in the subprocess: time the configured batches, print one JSON line each."""
    import jax

    jax.config.update("jax_enable_x64", cfg["x64"])
    import jaximpact as ji

    if cfg["kind"].endswith("-cores"):
        ji.use_all_cpu_cores()  # a device per core and loop kernels, as the command line runs
    scene = ji.table1_scene()
    if cfg["kind"] == "normal-no-adhesion":
        scene = scene.replace(contact={"f0": 0.0})
    if "rebound" in cfg["kind"]:
        scene = scene.replace(solver={"outputs": "rebound"})
    for n in cfg["sizes"]:
        speed, angle, omega0 = impacts(cfg["kind"], n)

        def call(speed=speed, angle=angle, omega0=omega0):
            return jax.block_until_ready(ji.simulate(scene, speed, angle, omega0))

        t = time.perf_counter()
        res = call()
        first = time.perf_counter() - t
        repeats = 5 if n <= 1000 else (3 if n <= 20000 else 2)
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            call()
            times.append(time.perf_counter() - t)
        run = float(np.median(times))
        steps = np.asarray(res.steps)
        out = dict(
            kind=cfg["kind"],
            x64=cfg["x64"],
            n=n,
            first=first,
            run=run,
            compile=first - run,
            rate=n / run,
            hwm_mb=vm_hwm_mb(),
            steps_median=float(np.median(steps)),
            steps_max=int(steps.max()),
            failed=int(np.sum(np.asarray(res.status) >= 2)),
        )
        if cfg.get("rhs") and n == cfg["sizes"][-1]:
            out["rhs"] = rhs_cost(scene, speed, angle, omega0, int(steps.max()))
        print("RESULT " + json.dumps(out), flush=True)


def rhs_cost(scene, speed, angle, omega0, steps):
    """Time of the bare vmapped right-hand side, evaluated as often as Tsit5 does (6 stages per
    step over every lane) for ``steps`` steps. Every state moves by a small multiple of its
    derivative each time, so every output of the field is computed and nothing is hoisted out
    of the loop (summing two outputs, as this did before, let XLA drop the others and measured
    a third of the field's cost)."""
    import jax
    import jax.numpy as jnp

    from jaximpact._engine.simulate import (
        _problem,
        integration_settings,
        required_terms,
        scene_parameters,
    )

    dtype = jnp.result_type(float)
    params = {k: jnp.full(speed.shape, v, dtype) for k, v in scene_parameters(scene).items()}
    terms = required_terms(scene, params, angle, omega0)
    cfg = integration_settings(scene, params, speed, angle, dtype)

    def one(prm, s, a, w):
        prob = _problem(terms, cfg, prm, s, a, w)
        y = dict(prob.y0, n=prob.y0["n"] + 0.3)  # well inside the contact

        def body(i, y):
            dy = prob.term.vf(0.0, y, prob.p)
            return {k: y[k] + 1e-9 * dy[k] for k in y}

        return jax.lax.fori_loop(0, 6 * steps, body, y)

    f = jax.jit(jax.vmap(one))
    args = (
        params,
        jnp.asarray(speed, dtype),
        jnp.asarray(angle, dtype),
        jnp.asarray(omega0, dtype),
    )
    jax.block_until_ready(f(*args))
    times = []
    for _ in range(3):
        t = time.perf_counter()
        jax.block_until_ready(f(*args))
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def spawn(cfg, timeout=900, tree=None):
    """Run ``worker(cfg)`` in a fresh process; ``tree``: a checkout whose ``jaximpact`` it
    imports (default: the installed one), at JAX's defaults (no ``XLA_FLAGS``)."""
    cmd = [sys.executable, str(HERE / "throughput.py"), "--worker", json.dumps(cfg)]
    env = None
    if tree:
        env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "PYTHONPATH")}
        env["PYTHONPATH"] = str(tree)
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    rows = [json.loads(line[7:]) for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    if proc.returncode != 0:
        print(proc.stderr[-2000:], file=sys.stderr)
    return rows


TITLE = "By batch size and scene options"
SAVINGS = ("normal", "normal-forced-full", "normal-no-adhesion")


def run(
    quick=False, info=None, note=None, command="python benchmarks/run_all.py --only throughput"
):
    """The subsection "By batch size and scene options" of BENCHMARKS.md's "Throughput" (from
    its heading), and the measurements (``results``; ``savings_n``: the batch of the
    scene-option rows that ``term_contributions`` reports)."""
    from _common import machine

    info = info or machine()
    if quick:
        plan = [dict(kind=k, x64=True, sizes=[1, 100, 1000]) for k in ("full", "normal")]
        plan += [dict(kind="full", x64=False, sizes=[1, 1000])]
        plan += [dict(kind="full", x64=True, sizes=[10000])]
        savings_n = 1000
    else:
        plan = []
        for x64 in (True, False):
            for kind in ("full", "normal"):
                plan.append(dict(kind=kind, x64=x64, sizes=[1, 10, 100, 1000]))
                for n in (10000, 20000, 100000):
                    plan.append(dict(kind=kind, x64=x64, sizes=[n]))
        savings_n = 10000
    plan += [dict(kind=k, x64=True, sizes=[savings_n]) for k in SAVINGS[1:]]
    big = 10000 if quick else 20000
    plan += [
        dict(kind=k, x64=x64, sizes=[big])
        for k in ("full-cores", "full-rebound", "full-rebound-cores")
        for x64 in (True, False)
    ]
    results = []
    for cfg in plan:
        results += spawn(cfg)
    text = report(results, info, command, note)
    return text, dict(results=results, savings_n=savings_n)


def report(results, info=None, command=None, note=None):
    from _common import default_settings, measured_line, save_figure, table

    prec = lambda r: "float64" if r["x64"] else "float32"  # noqa: E731
    rows = [
        [
            KINDS[r["kind"]],
            prec(r),
            r["n"],
            f"{r['rate']:,.0f}",
            f"{r['run']:.3f}",
            f"{r['compile']:.1f}",
            f"{r['hwm_mb']:.0f}",
            f"{r['steps_median']:.0f}",
            r["steps_max"],
            r["failed"],
        ]
        for r in results
    ]
    comp = [r["compile"] for r in results]
    md = [f"### {TITLE}\n"]
    if info:
        md.append(measured_line(info, command, settings=default_settings(), note=note))
    md.append(
        "Impacts: "
        + "; ".join(f"*{v}*" for v in KINDS.values())
        + ". Full scene: 0.5-5 m/s, -60..60 deg, |omega0| <= 2e4 rad/s. One process per "
        "configuration (batches <= 1000 share one, in increasing size); *peak MB*: VmHWM of "
        "that process (includes the Python/JAX runtime, ~300 MB). Median of repeated calls "
        "after compilation."
        + (
            " Compile time of `simulate` (first call minus a second): median "
            f"{np.median(comp):.1f} s, range {min(comp):.1f}-{max(comp):.1f} s over these "
            "configurations.\n"
            if comp
            else "\n"
        )
    )
    fig = plot(results)
    md.append(f"![throughput]({save_figure(fig, 'throughput')})\n")
    md.append(
        table(
            [
                "impacts",
                "precision",
                "batch",
                "impacts/s",
                "run (s)",
                "compile (s)",
                "peak MB",
                "median steps",
                "max steps",
                "failed",
            ],
            rows,
        )
    )
    return "\n".join(md) + "\n"


def plot(results):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for kind in ("full", "normal"):
        for x64 in (True, False):
            pts = sorted(
                (r["n"], r["rate"]) for r in results if r["kind"] == kind and r["x64"] == x64
            )
            if pts:
                x, y = zip(*pts, strict=True)
                ax.loglog(
                    x, y, "-o" if x64 else "--s", label=f"{kind}, {'float64' if x64 else 'float32'}"
                )
    ax.set_xlabel("batch size (impacts per call)")
    ax.set_ylabel("impacts per second")
    ax.set_title("jaximpact throughput (2-core CPU)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


# The batch paths of one configuration, timed in the same process with interleaved repeats
# (the machine is shared: ratios are measured side by side, not across runs). ``loop``: the
# private step-loop setting of ``jaximpact._engine.simulate._simulate``.
PATHS = {
    "plain": (
        "`diffeqsolve` vmapped over the whole batch (plain)",
        dict(chunk=0, loop="diffrax"),
    ),
    "chunked": ("`diffeqsolve`, a fixed number of lanes at a time", dict(loop="diffrax")),
    "lean": ("jaximpact's step loop, a fixed number of lanes at a time", dict(loop="lean")),
    "default": ("**default** (`simulate`)", {}),
}


def paths_worker(cfg):
    """Runs in the subprocess: each path (or chunk size) once to compile, then the repeats
    interleaved; prints one JSON line per path."""
    import jax

    jax.config.update("jax_enable_x64", cfg["x64"])
    import jaximpact as ji
    from jaximpact._engine import simulate as sim

    scene = ji.table1_scene()
    speed, angle, omega0 = impacts("full", cfg["n"])
    runs = {}
    for name in cfg["paths"]:
        kw = dict(PATHS[name][1]) if name in PATHS else dict(chunk=int(name))
        call = lambda kw=kw: jax.block_until_ready(  # noqa: E731
            sim._simulate(scene, speed, angle, omega0, **kw)
        )
        t = time.perf_counter()
        res = call()
        runs[name] = dict(call=call, first=time.perf_counter() - t, times=[], res=res)
    base = runs[cfg["paths"][0]]["res"]
    for _ in range(cfg["repeats"]):
        for r in runs.values():
            t, c = time.perf_counter(), time.process_time()
            r["call"]()
            r["times"].append(time.perf_counter() - t)
            r.setdefault("cpu", []).append(time.process_time() - c)
    for name, r in runs.items():
        same = all(
            np.array_equal(np.asarray(getattr(r["res"], k)), np.asarray(getattr(base, k)), True)
            for k in ("status", "steps", "cor_n", "vt_out", "omega_out", "contact_time")
        )
        run = float(np.median(r["times"]))
        out = dict(
            path=name,
            x64=cfg["x64"],
            devices=len(jax.local_devices()),
            n=cfg["n"],
            run=run,
            rate=cfg["n"] / run,
            # CPU seconds of the process (all its threads: XLA splits large fusions over cores)
            cpu=float(np.median(r["cpu"])),
            cpu_rate=cfg["n"] / float(np.median(r["cpu"])),
            times=r["times"],
            compile=r["first"] - run,
            bitwise=same,
            steps_max=int(np.asarray(r["res"].steps).max()),
            steps_median=float(np.median(np.asarray(r["res"].steps))),
        )
        print("RESULT " + json.dumps(out), flush=True)


def paths_spawn(cfg, devices=1, timeout=1800):
    cmd = [sys.executable, str(HERE / "throughput.py"), "--paths-worker", json.dumps(cfg)]
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    if proc.returncode != 0:
        print(proc.stderr[-2000:], file=sys.stderr)
    return [json.loads(x[7:]) for x in proc.stdout.splitlines() if x.startswith("RESULT ")]


def paths(n=20000, repeats=3, scan=(0, 512, 1024, 2048, 4096, 8192)):
    """Markdown of "Default path and alternatives": the batch paths per precision and device
    count, and the scan of lanes per device at a time (float64, one device)."""
    from _common import default_settings, machine, measured_line, table

    rows = []
    for x64 in (True, False):
        for devices in (1, len(os.sched_getaffinity(0))):
            cfg = dict(x64=x64, n=n, repeats=repeats, paths=list(PATHS))
            res = paths_spawn(cfg, devices)
            plain = next((r for r in res if r["path"] == "plain"), None)
            for r in res:
                rows.append(
                    [
                        "float64" if x64 else "float32",
                        r["devices"],
                        PATHS[r["path"]][0],
                        f"{r['rate']:,.0f}",
                        f"{r['run']:.2f}",
                        f"{plain['run'] / r['run']:.2f}" if plain else "–",
                        f"{r['cpu_rate']:,.0f}",
                        f"{r['steps_median']:.0f} / {r['steps_max']}",
                        f"{r['compile']:.0f}",
                        "yes" if r["bitwise"] else "**no**",
                    ]
                )
    scan_res = paths_spawn(dict(x64=True, n=n, repeats=repeats, paths=[str(c) for c in scan]))
    base = next((r for r in scan_res if r["path"] == "0"), None)
    scan_rows = [
        [
            "whole batch" if r["path"] == "0" else r["path"],
            f"{r['rate']:,.0f}",
            f"{r['run']:.2f}",
            f"{base['run'] / r['run']:.2f}" if base else "–",
            f"{r['cpu_rate']:,.0f}",
            "yes" if r["bitwise"] else "**no**",
        ]
        for r in scan_res
    ]
    md = [
        "### Default path and alternatives\n",
        measured_line(
            machine(),
            "python benchmarks/throughput.py --paths"
            + (f" --n {n}" if n != 20000 else "")
            + (f" --repeats {repeats}" if repeats != 3 else ""),
            settings=default_settings(),
        ),
        f"Batch of {n:,} oblique spinning impacts on the Table 1 scene (0.5-5 m/s, -60..60 deg, "
        f"|omega0| <= 2e4 rad/s), full outputs. Medians of {repeats} interleaved repeats per "
        "configuration, one process per precision and device count (several devices: one XLA "
        "host device per core, as `ji.use_all_cpu_cores()` and the CLI do). *vs plain*: "
        "against diffrax's `diffeqsolve` vmapped over the whole batch, timed in the same "
        "process; *bitwise*: status, steps and outputs identical to the first row of the "
        "process. The rows other than **default** are for comparison; `simulate` always takes "
        "the default path for concrete inputs.\n",
        table(
            [
                "precision",
                "devices",
                "path",
                "impacts/s",
                "run (s)",
                "vs plain",
                "impacts per CPU-s",
                "steps median / max",
                "compile (s)",
                "bitwise",
            ],
            rows,
        ),
        "\nLanes per device at a time (an internal setting, not an option of `simulate`; "
        "default path, float64, one device):\n",
        table(
            ["chunk", "impacts/s", "run (s)", "vs whole batch", "impacts per CPU-s", "bitwise"],
            scan_rows,
        ),
    ]
    return "\n".join(md) + "\n", dict(paths=rows, scan=scan_res)


DEFAULTS_TITLE = "As a notebook runs it and as the command line runs it"


def defaults(n=20000, rounds=2, trees=()):
    """Markdown of "As a notebook runs it and as the command line runs it": ``simulate`` of
    ``n`` oblique spinning impacts at JAX's defaults (``import jaximpact`` and call, as a
    notebook does) and with ``use_all_cpu_cores()`` (as the command line does), each in a fresh
    process, the two back to back in every round; ``trees``: other checkouts measured in the
    same rounds (before/after a change)."""
    from _common import machine, measured_line, table

    info = machine()
    trees = [str(HERE.parent), *map(str, trees)]

    def label(tree):
        commit = subprocess.run(
            ["git", "-C", tree, "rev-parse", "--short", "HEAD"], capture_output=True, text=True
        ).stdout.strip()
        return "this checkout" if tree == trees[0] else f"{commit} ({tree})"

    runs = {}
    for _ in range(rounds):
        for x64 in (True, False):
            for tree in trees:
                for kind in ("full", "full-cores"):
                    load = os.getloadavg()[0]
                    for r in spawn(dict(kind=kind, x64=x64, sizes=[n]), tree=tree):
                        runs.setdefault((tree, x64, kind), []).append((r["rate"], load))
    rows = []
    for tree in trees:
        for x64 in (True, False):
            nb, cli = runs.get((tree, x64, "full"), []), runs.get((tree, x64, "full-cores"), [])
            if not nb or not cli:
                continue
            ratios = [a[0] / b[0] for a, b in zip(nb, cli, strict=False)]
            rows.append([
                label(tree), "float64" if x64 else "float32",
                f"{np.median([r for r, _ in nb]):,.0f}", f"{np.median([r for r, _ in cli]):,.0f}",
                f"{np.median(ratios):.2f}",
                ", ".join(f"{a[0]:,.0f} / {b[0]:,.0f}" for a, b in zip(nb, cli, strict=False)),
                ", ".join(f"{a[1]:.1f} / {b[1]:.1f}" for a, b in zip(nb, cli, strict=False)),
            ])  # fmt: skip
    command = "python benchmarks/throughput.py --defaults" + (f" --n {n}" if n != 20000 else "")
    command += f" --rounds {rounds}" if rounds != 2 else ""
    md = [
        f"### {DEFAULTS_TITLE}\n",
        measured_line(info, command + "".join(f" --compare-with {t}" for t in trees[1:])),
        f"`simulate` of {n:,} oblique spinning Table 1 impacts (0.5-5 m/s, -60..60 deg, |omega0| "
        "<= 2e4 rad/s), each configuration in a fresh process, median of 3 warm calls. *notebook*: "
        "`import jaximpact` and call, at JAX's defaults (one XLA CPU device, with what the "
        "import sets where nothing else did); *CLI*: "
        "`ji.use_all_cpu_cores()` first (a device per core, loop kernels), as the command line "
        f"does. The two back to back in each of {rounds} rounds; *ratio*: the median of the "
        "rounds' notebook / CLI ratios; load averages (1 min) at the start of each process.\n",
        f"**{info['cpu']}, {info['cores']} cores**\n",
        table(
            [
                "code",
                "precision",
                "notebook impacts/s",
                "CLI impacts/s",
                "ratio",
                "rounds: notebook / CLI impacts/s",
                "load: notebook / CLI",
            ],
            rows,
        ),  # fmt: skip
    ]
    return "\n".join(md) + "\n", {"rows": rows, "trees": trees}


SCIPY_SETTINGS = [("LSODA", r) for r in (1e-8, 1e-9, 1e-10)]
SCIPY_SETTINGS += [("RK45", r) for r in (1e-8, 1e-9, 1e-10)]
SCIPY_SETTINGS += [("DOP853", r) for r in (1e-8, 1e-9, 1e-10, 1e-11)]


def scipy_ratio_worker(cfg):
    """Runs in the subprocess (one host device per core): jaximpact's default float64 batch
    and the scipy loops, in one process, interleaved; prints one JSON line."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import scipy_peer as peer
    from _common import as_dict, max_error, output_errors, reference_rows

    import jaximpact as ji
    from jaximpact import reference as ref

    n = cfg["n_scipy"]
    speed, angle, omega0 = impacts("full", n, seed=5)
    params = ref.table1_params()
    exact = reference_rows(params, speed, angle, omega0)
    scene = ji.table1_scene()
    res = as_dict(ji.simulate(scene, speed, angle, omega0))
    jax_error = max_error(output_errors(res, exact, speed, 35e-6)[0])
    sp, an, om = impacts("full", cfg["n"])

    def jax_once():
        t, c = time.perf_counter(), time.process_time()
        jax.block_until_ready(ji.simulate(scene, sp, an, om))
        return time.perf_counter() - t, time.process_time() - c

    jax_once()  # compile
    jax_runs = []
    rows = []
    for method, rtol in SCIPY_SETTINGS:
        jax_runs.append(jax_once())
        t, c = time.perf_counter(), time.process_time()
        out = peer.simulate_loop(
            params,
            speed,
            angle,
            omega0,
            method=method,
            rtol=rtol,
            atol=rtol * 1e-2,
            ring_width=scene.solver.ring_width,
        )
        wall, cpu = (time.perf_counter() - t) / n, (time.process_time() - c) / n
        err, bad = output_errors(out, exact, speed, 35e-6)
        rows.append(
            dict(method=method, rtol=rtol, wall=wall, cpu=cpu, error=max_error(err), mismatches=bad)
        )
    jax_runs.append(jax_once())
    wall = float(np.median([w for w, _ in jax_runs]))
    cpu = float(np.median([c for _, c in jax_runs]))
    out = dict(
        devices=len(jax.local_devices()),
        n=cfg["n"],
        jax_wall=wall / cfg["n"],
        jax_cpu=cpu / cfg["n"],
        jax_error=jax_error,
        scipy=rows,
    )
    print("RESULT " + json.dumps(out), flush=True)


def scipy_ratio(n=20000, n_scipy=30):
    """Markdown of "Compared with a scipy `solve_ivp` loop": jaximpact (all cores) against
    scipy loops, at equal accuracy, one process."""
    from _common import default_settings, machine, measured_line, table

    info = machine()

    cmd = [sys.executable, str(HERE / "throughput.py"), "--scipy-ratio-worker"]
    cmd.append(json.dumps(dict(n=n, n_scipy=n_scipy)))
    env = dict(os.environ)
    cores = len(os.sched_getaffinity(0))
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={cores}"
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=3600, env=env)
    lines = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
    if not lines:
        raise SystemExit(proc.stderr[-3000:])
    r = json.loads(lines[0][7:])
    rows = [
        [
            f"scipy `solve_ivp` {s['method']} rtol {s['rtol']:g} (loop, 1 process)",
            f"{s['error']:.1e}",
            f"{s['wall'] * 1e3:.2f}",
            f"{s['wall'] / r['jax_wall']:,.0f}",
            f"{s['cpu'] / r['jax_cpu']:,.0f}",
        ]
        for s in r["scipy"]
    ]
    rows.insert(
        0,
        [
            f"jaximpact `simulate`, default float64, {r['devices']} devices, batch {r['n']:,}",
            f"{r['jax_error']:.1e}",
            f"{r['jax_wall'] * 1e3:.4f}",
            "1",
            "1",
        ],
    )
    equal = [s for s in r["scipy"] if s["error"] <= r["jax_error"]]
    best = (
        min(equal, key=lambda s: s["wall"]) if equal else min(r["scipy"], key=lambda s: s["error"])
    )
    verdict = (
        f"At equal accuracy (the fastest scipy setting with an error at most jaximpact's "
        f"{r['jax_error']:.1e}: {best['method']} rtol {best['rtol']:g}, error "
        f"{best['error']:.1e}): **{best['wall'] / r['jax_wall']:,.0f}x** in wall time, "
        f"{best['cpu'] / r['jax_cpu']:,.0f}x per CPU-second."
        if equal
        else f"No scipy setting reached jaximpact's error {r['jax_error']:.1e}; the most "
        f"accurate ({best['method']} rtol {best['rtol']:g}, {best['error']:.1e}) is "
        f"{best['wall'] / r['jax_wall']:,.0f}x slower in wall time."
    )
    md = [
        "### Compared with a scipy `solve_ivp` loop\n",
        measured_line(
            info,
            "python benchmarks/throughput.py --scipy-ratio" + (f" --n {n}" if n != 20000 else ""),
            settings=default_settings(),
        ),
        f"Errors: largest of `cor_n`, `vt_out`/speed, `omega_out` r/speed against the exact "
        f"reference on {n_scipy} oblique spinning Table 1 impacts (seed 5); the peer integrates "
        "the same smooth model (same slip and ring widths). Times per impact; jaximpact timed "
        "between the scipy settings (median of all). *x wall*: the scipy loop's wall time over "
        "jaximpact's; *x CPU*: the same per CPU-second (the scipy loop uses one core, "
        "jaximpact all).\n",
        table(["solver", "max error", "ms per impact", "x wall", "x CPU"], rows),
        "\n" + verdict + "\n",
    ]
    return "\n".join(md), r


def profile_worker(cfg):
    """Runs in the subprocess: where a lane-step's time goes, one chunk on one device."""
    import jax
    from _common import median_time

    jax.config.update("jax_enable_x64", cfg["x64"])
    import jaximpact as ji
    from jaximpact._engine import simulate as sim

    scene = ji.table1_scene()
    sp, an, om = impacts("full", cfg["lanes"])
    out = dict(x64=cfg["x64"], lanes=cfg["lanes"])
    for loop in ("lean", "diffrax"):
        call = lambda loop=loop: jax.block_until_ready(  # noqa: E731
            sim._simulate(scene, sp, an, om, chunk=0, loop=loop)
        )
        res = call()
        out[loop] = median_time(call, cfg["repeats"])
    steps = np.asarray(res.steps)
    out["steps_max"], out["steps_sum"] = int(steps.max()), int(steps.sum())
    out["field"] = rhs_cost(scene, sp, an, om, out["steps_max"])
    print("RESULT " + json.dumps(out), flush=True)


def profile(lanes=8192, repeats=5):
    """Markdown of "Where a lane-step's time goes": ns per lane-step of jaximpact's step loop,
    of ``diffeqsolve`` and of the bare vector field."""
    from _common import default_settings, machine, measured_line, table

    info = machine()

    rows = []
    for x64 in (True, False):
        cmd = [sys.executable, str(HERE / "throughput.py"), "--profile-worker"]
        cmd.append(json.dumps(dict(x64=x64, lanes=lanes, repeats=repeats)))
        env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=1")
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800, env=env)
        lines = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
        if not lines:
            raise SystemExit(proc.stderr[-3000:])
        r = json.loads(lines[0][7:])
        lane_steps = r["lanes"] * r["steps_max"]
        ns = {k: r[k] / lane_steps * 1e9 for k in ("lean", "diffrax", "field")}
        rows.append(
            [
                "float64" if x64 else "float32",
                f"{ns['diffrax']:.0f}",
                f"{ns['lean']:.0f}",
                f"{ns['field']:.0f} ({ns['field'] / ns['lean']:.0%})",
                f"{ns['lean'] - ns['field']:.0f}",
                f"{r['steps_max']} / {r['steps_sum'] / r['lanes']:.0f}",
                f"{lanes * r['steps_max'] / r['steps_sum']:.2f}",
            ]
        )
    md = [
        "### Where a lane-step's time goes\n",
        measured_line(info, "python benchmarks/throughput.py --profile", default_settings()),
        f"One chunk of {lanes} oblique spinning Table 1 impacts on one device (default "
        "settings), medians of "
        f"{repeats}; ns per lane-step = time / (lanes x the chunk's largest step count). "
        "*vector field*: the bare vmapped vector field with every output used, evaluated 6 "
        "times per lane-step as Tsit5 does; *rest*: jaximpact's step loop less that (stage "
        "sums, error norm, controller, event function and test, masked updates); "
        "*slowest-lane factor*: lane-steps run over "
        "lane-steps needed "
        "(what refilling finished lanes could save at most).\n",
        table(
            [
                "precision",
                "`diffeqsolve` ns/lane-step",
                "jaximpact step loop ns/lane-step",
                "vector field (6 evaluations)",
                "rest",
                "steps max / mean",
                "slowest-lane factor",
            ],
            rows,
        ),
    ]
    return "\n".join(md)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--paths-worker", help=argparse.SUPPRESS)
    ap.add_argument(
        "--paths",
        action="store_true",
        help='the default batch path against the alternatives ("Default path and alternatives")',
    )
    ap.add_argument("--scipy-ratio", action="store_true", help="jaximpact vs scipy loops")
    ap.add_argument("--scipy-ratio-worker", help=argparse.SUPPRESS)
    ap.add_argument("--profile", action="store_true", help="where a lane-step's time goes")
    ap.add_argument("--profile-worker", help=argparse.SUPPRESS)
    ap.add_argument(
        "--defaults",
        action="store_true",
        help="as a notebook runs it (JAX's defaults) against the command line's settings",
    )
    ap.add_argument(
        "--compare-with", nargs="*", default=[], help="--defaults: other checkouts, same rounds"
    )
    ap.add_argument("--rounds", type=int, default=2, help="--defaults: rounds")
    ap.add_argument("--n", type=int, default=20000, help="batch size")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    from _common import machine, write_result

    if args.worker:
        worker(json.loads(args.worker))
    elif args.paths_worker:
        paths_worker(json.loads(args.paths_worker))
    elif args.profile_worker:
        profile_worker(json.loads(args.profile_worker))
    elif args.profile:
        info = machine()
        text = profile()
        print(text)
        command = "python benchmarks/throughput.py --profile"
        write_result("throughput_profile", {"markdown": text}, info, command)
    elif args.scipy_ratio_worker:
        scipy_ratio_worker(json.loads(args.scipy_ratio_worker))
    elif args.scipy_ratio:
        info = machine()
        text, data = scipy_ratio(args.n)
        print(text)
        command = f"python benchmarks/throughput.py --scipy-ratio --n {args.n}"
        write_result("throughput_scipy_ratio", data, info, command)
    elif args.defaults:
        info = machine()
        text, data = defaults(args.n, args.rounds, args.compare_with)
        print(text)
        command = f"python benchmarks/throughput.py --defaults --n {args.n}"
        write_result("throughput_defaults", data, info, command)
    elif args.paths:
        info = machine()
        text, data = paths(args.n, args.repeats)
        print(text)
        command = f"python benchmarks/throughput.py --paths --n {args.n}"
        write_result("throughput_paths", data, info, command)
    else:
        ap.error("give --defaults, --paths, --profile or --scipy-ratio")

"""First result: each entry point in a fresh process, cold and warm compilation cache (issue 32).

Run: ``python benchmarks/first_result.py [--only NAME ...] [--skip-long]`` (about 15 minutes
on 2 cores; ``--skip-long`` leaves out the wall law and the posterior).

Each case runs twice in a fresh Python process: *cold* with an empty ``JAXIMPACT_CACHE_DIR``,
*warm* with that cache again (as a notebook's second kernel or a script's second run).
Reported: the wall time of the whole process (imports included), the time to the first
result inside it, and JAX's own account of it (``JAX_LOG_COMPILES=1``): seconds spent
tracing, lowering to MLIR and in XLA's compiler, summed over every program the process built
(compilations served by the cache count as none), and the number of programs compiled.
"""

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import machine, measured_line, table, write_result  # noqa: E402

COMMAND = "python benchmarks/first_result.py"

_PRELUDE = """
import time, sys
t0 = time.perf_counter()
import jax
jax.config.update("jax_enable_x64", True)
import numpy as np
import jaximpact as ji
t_import = time.perf_counter() - t0
"""
_REPORT = """
print(f"FIRST_RESULT {time.perf_counter() - t1:.3f} IMPORT {t_import:.3f}")
"""

CASES = {
    "simulate 3": (
        "README's simulate of 3 impacts",
        """
t1 = time.perf_counter()
r = ji.simulate(ji.table1_scene(), np.array([0.5, 1.0, 2.0]), np.array([0.0, 30.0, 45.0]), 0.0)
np.asarray(r.cor_n)
""",
    ),
    "simulate 20000": (
        "simulate of 20,000 oblique spinning impacts",
        """
rng = np.random.default_rng(0)
s, a, w = rng.uniform(0.5, 5, 20000), rng.uniform(-60, 60, 20000), rng.uniform(-2e4, 2e4, 20000)
t1 = time.perf_counter()
np.asarray(ji.simulate(ji.table1_scene(), s, a, w).cor_n)
""",
    ),
    "grad": (
        "jax.grad of sum(cor_n) of 3 impacts in f0",
        """
speed, angle = np.array([0.5, 1.0, 2.0]), np.array([0.0, 30.0, 45.0])
def loss(f0):
    scene = ji.table1_scene().replace(contact={"f0": f0})
    return ji.simulate(scene, speed, angle, 0.0).cor_n.sum()
t1 = time.perf_counter()
float(jax.grad(loss)(300.0))
""",
    ),
    "jacfwd": (
        "jax.jacfwd of cor_n of 3 impacts in C_A, C_H, f0",
        """
speed, angle = np.array([0.5, 1.0, 2.0]), np.array([0.0, 30.0, 45.0])
def out(p):
    scene = ji.table1_scene().replace(contact={"C_A": p[0], "C_H": p[1], "f0": p[2]})
    return ji.simulate(scene, speed, angle, 0.0).cor_n
t1 = time.perf_counter()
np.asarray(jax.jacfwd(out)(jax.numpy.array([0.75, 0.25, 300.0])))
""",
    ),
    "capture speed": (
        "capture_speed at 30 deg and its jax.grad in f0",
        """
def vc(f0):
    return ji.capture_speed(ji.table1_scene().replace(contact={"f0": f0}), angle_deg=30.0).speed
t1 = time.perf_counter()
float(vc(300.0))
print(f"VALUE {time.perf_counter() - t1:.3f}")
float(jax.grad(vc)(300.0))
""",
    ),
    "kvaerno5": (
        "simulate of 3 impacts with Kvaerno5",
        """
scene = ji.table1_scene().replace(solver={"method": "kvaerno5"})
t1 = time.perf_counter()
np.asarray(ji.simulate(scene, np.array([0.5, 1.0, 2.0]), np.array([0.0, 30.0, 45.0]), 0.0).cor_n)
""",
    ),
}
CLI_CASES = {
    "cli simulate": ("`jaximpact simulate` (the paper's 3 impacts)", ["simulate"]),
    "cli fit": (
        "`jaximpact fit` of C_A, C_H, f0 on 25 impacts",
        ["fit", "{data}", "--params", "C_A", "C_H", "f0", "--no-progress"],
    ),  # fmt: skip
    "cli fit --plot": (
        "... with `--plot`",
        [
            "fit",
            "{data}",
            "--params",
            "C_A",
            "C_H",
            "f0",
            "--no-progress",
            "--plot",
            "{work}/fit.png",
        ],
    ),  # fmt: skip
    "cli posterior": (
        "... with `--posterior`",
        ["fit", "{data}", "--params", "C_A", "C_H", "f0", "--no-progress", "--posterior"],
    ),  # fmt: skip
    "cli wall-law": (
        "`jaximpact wall-law table1` (default grid)",
        ["wall-law", "table1", "-o", "{work}/wall"],
    ),  # fmt: skip
}
LONG = ("cli posterior", "cli wall-law")
TARGETS = {"simulate 3": 5, "grad": 10, "jacfwd": 10, "capture speed": 15, "kvaerno5": 15,
           "cli wall-law": 60}  # fmt: skip

_LOG = {
    "trace": re.compile(r"Finished tracing .* in ([0-9.e-]+) sec"),
    "lower": re.compile(r"Finished jaxpr to MLIR module conversion .* in ([0-9.e-]+) sec"),
    "compile": re.compile(r"Finished XLA compilation of .* in ([0-9.e-]+) sec"),
}


def _jax_account(stderr: str) -> dict:
    out = {k: sum(float(x) for x in p.findall(stderr)) for k, p in _LOG.items()}
    out["programs"] = len(_LOG["compile"].findall(stderr))
    return out


def _data(work: Path) -> Path:
    """25 cor_n observations of the Table 1 sphere (0.3 % noise), as the fit benchmark's."""
    sys.path.insert(0, str(HERE))
    from fit_benchmark import _MAKE_DATA

    path = work / "micro25.csv"
    subprocess.run([sys.executable, "-c", _MAKE_DATA, str(path)], check=True)
    return path


def _run(args, cache, env_extra=None):
    env = {**os.environ, "JAXIMPACT_CACHE_DIR": str(cache), "JAX_LOG_COMPILES": "1"}
    env.pop("XLA_FLAGS", None)
    env.update(env_extra or {})
    t = time.perf_counter()
    proc = subprocess.run(args, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t
    if proc.returncode not in (0, 3):
        raise RuntimeError(f"{args[:4]} exited {proc.returncode}: {proc.stderr[-1500:]}")
    first = re.search(r"FIRST_RESULT ([0-9.]+)", proc.stdout)
    value = re.search(r"VALUE ([0-9.]+)", proc.stdout)
    return {
        "wall": wall,
        "first": float(first.group(1)) if first else None,
        "value": float(value.group(1)) if value else None,
        **_jax_account(proc.stderr),
    }


def measure(names, work: Path) -> dict:
    data = _data(work)
    results = {}
    for name in names:
        cache = work / f"cache-{re.sub(r'[^a-z0-9]+', '-', name)}"
        for phase in ("cold", "warm"):
            if name in CASES:
                code = _PRELUDE + CASES[name][1] + _REPORT
                args = [sys.executable, "-c", code]
            else:
                exe = shutil.which("jaximpact", path=os.path.dirname(sys.executable))
                cmd = [exe] if exe else [sys.executable, "-m", "jaximpact.cli"]
                args = cmd + [a.format(data=data, work=work) for a in CLI_CASES[name][1]]
                shutil.rmtree(work / "wall", ignore_errors=True)
            results[(name, phase)] = _run(args, cache)
            r = results[(name, phase)]
            print(f"{name} {phase}: {r['wall']:.1f} s", file=sys.stderr, flush=True)
    return results


def report(results, info, command) -> str:
    rows = []
    for (name, phase), r in results.items():
        about = (CASES.get(name) or CLI_CASES[name])[0]
        first = "" if r["first"] is None else f"{r['first']:.1f}"
        if r["value"] is not None:
            first = f"{r['value']:.1f} (value), {first} (value + gradient)"
        target = TARGETS.get(name, "")
        rows.append([
            about if phase == "cold" else "", phase, f"{r['wall']:.1f}", first,
            f"{r['trace']:.1f}", f"{r['lower']:.1f}", f"{r['compile']:.1f}", str(r["programs"]),
            str(target) if phase == "cold" else "",
        ])  # fmt: skip
    header = ["entry point", "cache", "process wall s", "first result s", "tracing s",
              "lowering s", "XLA compile s", "programs (compiled or loaded)",
              "target s"]  # fmt: skip
    return (
        "## First result\n\n"
        + measured_line(info, command)
        + "\nEach command in a fresh process, cold (empty cache) then warm (the same cache "
        "again). *first result*: from the call to its result inside the process (imports "
        "excluded); tracing, lowering and XLA compile: JAX's own log of every program the "
        "process built (`JAX_LOG_COMPILES=1`), summed (a program traced inside another counts "
        "in both; XLA compile includes loading from the cache).\n\n" + table(header, rows) + "\n"
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=[*CASES, *CLI_CASES])
    ap.add_argument("--skip-long", action="store_true")
    args = ap.parse_args()
    names = args.only or [n for n in (*CASES, *CLI_CASES) if not (args.skip_long and n in LONG)]
    info = machine()
    work = Path(tempfile.mkdtemp(prefix="first_result-"))
    try:
        results = measure(names, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(report(results, info, COMMAND))
    rows = [{"entry point": name, "cache": phase, "target s": TARGETS.get(name), **r}
            for (name, phase), r in results.items()]  # fmt: skip
    write_result("first_result", rows, info, COMMAND)


if __name__ == "__main__":
    main()

"""Posterior time end to end: `jaximpact fit DATA --params ... --posterior` in fresh
processes, cold and warm cache (issue 52's time targets on 2 cores from a cold cache: 15 s
for the nearly Gaussian case, 30 s for the weakly determined one, 20 s for four parameters
from cor_n and cor_t, 120 s for Kharaz with the Mindlin model; issue 34's were 30 and 60 s).

Run: ``python benchmarks/posterior_end_to_end.py [--repeats N] [--cases gaussian weak]``
(about 5 minutes on 2 cores with one repeat).

The data (synthetic, Table 1 sphere with C_A = 0.75, C_H = 0.25, f0 = 300; cor_n with
additive noise of sigma 0.003, numpy seed 0, the sigma given in the file):

- ``gaussian``: 25 impacts, 0.3-5 m/s, 0-60 degrees (the posterior is nearly Gaussian);
- ``weak``: 6 normal impacts, 0.6-8 m/s (C_A and f0 weakly determined: SMC starts from the
  prior);
- ``four``: C_A, C_H, f0 and friction (0.3, the Table 1 scene's) from 10 oblique impacts,
  0.5-5 m/s at 15-60 degrees, cor_n and cor_t (sigma 0.003 each);
- ``kharaz_mindlin``: `jaximpact fit kharaz2001_mindlin --params friction G_star --posterior`
  (the embedded measurements; no sigmas: three noise factors, integrated out).

Cold: an empty ``JAXIMPACT_CACHE_DIR``; warm: the same command again with that cache. Wall
time of the whole command (Python start-up and imports included); the fit's and the
sampler's own seconds from the JSON.
"""

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import machine, measured_line, table, write_result  # noqa: E402

COMMAND = "python benchmarks/posterior_end_to_end.py"

_MAKE_DATA = """
import sys, numpy as np, jax
jax.config.update("jax_enable_x64", True)
import jaximpact
case, path = sys.argv[1], sys.argv[2]
if case == "gaussian":
    speed = np.geomspace(0.3, 5.0, 25)
    angle = np.tile([0.0, 0.0, 30.0, 45.0, 60.0], 5)
elif case == "four":
    speed = np.geomspace(0.5, 5.0, 10)
    angle = np.tile([15.0, 30.0, 45.0, 60.0, 30.0], 2)
else:
    speed = np.geomspace(0.6, 8.0, 6)
    angle = np.zeros(6)
scene = jaximpact.table1_scene().replace(contact=dict(C_A=0.75, C_H=0.25, f0=300.0))
r = jaximpact.simulate(scene, speed, angle, 0.0)
assert np.all(np.asarray(r.status) == 0)
rng = np.random.default_rng(0)
observed = ("cor_n", "cor_t") if case == "four" else ("cor_n",)
rows = []
for name in observed:
    value = np.asarray(getattr(r, name)) + 0.003 * rng.standard_normal(speed.size)
    rows += [f"{float(s)!r},{float(a)!r},{name},{float(v)!r},0.003"
             for s, a, v in zip(speed, angle, value)]
open(path, "w").write("speed,angle_deg,observable,value,sigma\\n" + "\\n".join(rows) + "\\n")
"""
CASES = {
    "gaussian": "25 impacts, 0.3-5 m/s, 0-60 deg (nearly Gaussian)",
    "weak": "6 normal impacts, 0.6-8 m/s (C_A, f0 weakly determined)",
    "four": "C_A, C_H, f0, friction from 10 oblique impacts (cor_n, cor_t)",
    "kharaz_mindlin": "Kharaz (2001), Mindlin model: friction, G_star (noise integrated)",
}
PARAMS = {
    "gaussian": ["C_A", "C_H", "f0"],
    "weak": ["C_A", "C_H", "f0"],
    "four": ["C_A", "C_H", "f0", "friction"],
    "kharaz_mindlin": ["friction", "G_star"],
}
TARGETS = {"gaussian": 15.0, "weak": 30.0, "four": 20.0, "kharaz_mindlin": 120.0}


def _command():
    exe = shutil.which("jaximpact", path=os.path.dirname(sys.executable))
    return [exe] if exe else [sys.executable, "-m", "jaximpact.cli"]


def _posterior(case, data, cache, out):
    """One ``fit --posterior`` in a fresh process: (wall seconds, its JSON)."""
    env = {**os.environ, "JAXIMPACT_CACHE_DIR": str(cache)}
    args = ["fit", str(data), "--params", *PARAMS[case], "--posterior", "--no-progress"]
    t = time.perf_counter()
    proc = subprocess.run([*_command(), *args, "-o", str(out)], capture_output=True, text=True,
                          env=env)  # fmt: skip
    wall = time.perf_counter() - t
    if proc.returncode != 0:
        raise RuntimeError(f"exit {proc.returncode}: {proc.stderr[-2000:]}")
    return wall, json.loads(Path(out).read_text())


def measure(cases, repeats):
    work = Path(tempfile.mkdtemp(prefix="posterior_e2e-"))
    rows = {}
    try:
        for case in cases:
            data = work / f"{case}.csv"
            if case == "kharaz_mindlin":
                data = "kharaz2001_mindlin"  # the embedded data set, with its scene
            else:
                subprocess.run([sys.executable, "-c", _MAKE_DATA, case, str(data)], check=True)
            for i in range(repeats):
                cache = work / f"cache-{case}-{i}"
                for phase in ("cold", "warm"):
                    wall, out = _posterior(case, data, cache, work / "out.json")
                    rows.setdefault((case, phase), []).append((wall, out))
                    print(f"{case} {phase} {wall:.1f} s", file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return rows


def report(rows, info, command):
    out = []
    for (case, phase), runs in rows.items():
        wall = statistics.median(w for w, _ in runs)
        post = runs[0][1]["posterior"]
        t = post["timings"]
        ess = min(p["posterior"]["ess"] for p in runs[0][1]["params"].values())
        out.append([
            CASES[case], phase, f"{wall:.1f}", f"{t.get('fit', float('nan')):.1f}",
            f"{t.get('sampling', float('nan')):.1f}", f"{post['evaluations']:,}",
            f"{ess:.0f}", "yes" if post["converged"] else "no",
            f"{TARGETS[case]:.0f}" if phase == "cold" else "",
        ])  # fmt: skip
    header = ["data", "cache", "wall s", "fit s", "sampling s", "evaluations", "ESS (min)",
              "converged", "target s"]  # fmt: skip
    n = max(len(r) for r in rows.values())
    return (
        "### Posterior time end to end\n\n"
        + measured_line(info, command)
        + f"\nMedians of {n} repeat(s) of each command in a fresh process.\n\n"
        + table(header, out)
        + "\n"
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--cases", nargs="+", choices=sorted(CASES), default=list(CASES))
    args = ap.parse_args()
    info = machine()
    rows = measure(args.cases, args.repeats)
    command = COMMAND + (f" --repeats {args.repeats}" if args.repeats > 1 else "")
    print(report(rows, info, command))
    write_result("posterior_end_to_end", figures(rows), info, command)


def figures(rows) -> list[dict]:
    """One row per case and cache: the median wall seconds and the first run's figures."""
    out = []
    for (case, phase), runs in rows.items():
        post = runs[0][1]["posterior"]
        t = post["timings"]
        out.append({
            "case": case, "cache": phase, "wall": statistics.median(w for w, _ in runs),
            "walls": [w for w, _ in runs], "fit": t.get("fit"), "sampling": t.get("sampling"),
            "evaluations": post["evaluations"], "converged": post["converged"],
            "ess_min": min(p["posterior"]["ess"] for p in runs[0][1]["params"].values()),
            "target": TARGETS[case] if phase == "cold" else None,
        })  # fmt: skip
    return out


if __name__ == "__main__":
    main()

"""capture_speed's statuses over random scenes of each normal law: no ``failed`` (and no
impact of its search left at ``max_steps``) where the exact reference decides the impacts.

Run: ``python benchmarks/capture_speed_statuses.py [--scenes N] [--laws a,b] [--ranges R]
[--seed S] [--json FILE]`` (default 200 scenes per law: about 6 minutes on 2 shared cores,
Thornton-Ning half of it). Prints BENCHMARKS.md's "capture_speed on random scenes" table;
exit status 1 if a search failed where the reference decides every impact of its scan.

Scenes (seeded, log-uniform): ``--ranges prior`` (default) draws every parameter over its
default prior (``jaximpact.parameters``; docs/posterior.md: physically typical values, inside
the hard limits of docs/input_ranges.md): radius 1e-7-0.1 m, density 100-3e4 kg/m^3, K
1e8-1e13 Pa, f0 0.1-1e5 N/m (Brach-Dunn), w 1e-4-100 J/m^2 (DMT, JKR, Thornton-Ning), C_A
and C_H 1e-3-100 s/m, p_y from 1.02 to 100 times its lower bound (the JKR centre pressure
at first touch). ``--ranges input`` draws over the hard limits themselves (radius 1e-9-1 m,
density 1-1e5, K 1e6-1e13, f0 1e-3-1e6, w 1e-6-1e4, C_A, C_H 1e-4-1e4; the open or zero ends
cut where stated). Each scene's ``capture_speed`` at normal incidence without spin, the
scenes of a law as one batch (``method = "auto"``).

For each scene whose search ends ``failed``, the exact reference (``jaximpact.reference``;
Thornton-Ning: ``reference.thornton_ning``) simulates the scan's 19 speeds: the scene counts
as "failed where decided" if the reference gives every one a status (rebound or captured).
The search's own ``max_steps`` impacts are counted by wrapping ``simulate`` (an impact that
reached ``max_steps`` on the explicit solver and was run again on the implicit one is
counted apart, as ``retried``).
"""

import argparse
import collections
import json
import math
import sys
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import jaximpact as ji  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import machine, write_result  # noqa: E402

import jaximpact._engine.api as api  # noqa: E402
from jaximpact import reference as ref  # noqa: E402
from jaximpact.parameters import PARAMETERS  # noqa: E402
from jaximpact.reference import thornton_ning  # noqa: E402
from jaximpact.wall_law import CaptureStatus  # noqa: E402
from jaximpact.wall_law._capture import scan_speeds, scene_with  # noqa: E402

LAWS = ("brach_dunn", "dmt", "jkr", "thornton_ning")
# --ranges input: the hard limits of docs/input_ranges.md, with these ends where a limit is
# 0 or open (log-uniform needs a positive end)
INPUT_RANGES = {
    "radius": (1e-9, 1.0),
    "density": (1.0, 1e5),
    "K": (1e6, 1e13),
    "f0": (1e-3, 1e6),
    "w": (1e-6, 1e4),
    "C_A": (1e-4, 1e4),
    "C_H": (1e-4, 1e4),
}
NAMES = {
    "brach_dunn": ("radius", "density", "K", "f0", "C_A", "C_H"),
    "dmt": ("radius", "density", "K", "w", "C_H"),
    "jkr": ("radius", "density", "K", "w", "C_H"),
    "thornton_ning": ("radius", "density", "K", "w", "C_H"),
}


def draw(law, n, rng, ranges):
    """``n`` scenes of ``law`` as a dict of parameter arrays."""
    values = {}
    for name in NAMES[law]:
        lo, hi = PARAMETERS[name].default_prior if ranges == "prior" else INPUT_RANGES[name]
        values[name] = np.exp(rng.uniform(math.log(lo), math.log(hi), n))
    if law != "brach_dunn":
        values["f0"] = np.zeros(n)
    if law == "thornton_ning":
        E = 0.75 * values["K"]
        floor = 0.5875 * (E**2 * values["w"] / values["radius"]) ** (1.0 / 3.0)
        p_y = floor * 10.0 ** rng.uniform(math.log10(1.02), 2.0, n)
        values["p_y"] = np.minimum(p_y, 1e13)
    return values


def base_scene(law):
    scene = ji.table1_scene().replace(contact={"friction": 0.3}, model={"normal": law})
    return scene


class Recorder:
    """Counts the statuses of every impact ``capture_speed`` simulates (by the solver it
    ran)."""

    def __init__(self):
        self.counts = collections.Counter()
        self.original = api.simulate

    def __enter__(self):
        def wrapped(scene, *args, **kwargs):
            res = self.original(scene, *args, **kwargs)
            method = kwargs.get("method") or scene.solver.method
            for code in np.asarray(res.status).ravel():
                self.counts[(method, ji.Status.NAMES[int(code)])] += 1
            return res

        api.simulate = wrapped
        return self

    def __exit__(self, *exc):
        api.simulate = self.original


def reference_decides(law, values, i, speeds):
    """Whether the exact reference gives every impact of the scan a status."""
    v = {k: float(x[i]) for k, x in values.items()}
    try:
        for speed in speeds:
            if law == "thornton_ning":
                m = v["density"] * 4.0 / 3.0 * math.pi * v["radius"] ** 3
                res = thornton_ning.simulate_normal_impact(
                    speed, v["radius"], 0.75 * v["K"], v["w"], m, v["p_y"], v["C_H"]
                )
            else:
                p = ref.Params(
                    radius=v["radius"],
                    density=v["density"],
                    K=v["K"],
                    f0=v.get("f0", 0.0),
                    C_A=v.get("C_A", 0.0),
                    C_H=v["C_H"],
                    friction=0.3,
                    normal=law,
                    w=v.get("w", 0.0),
                )
                res = ref.simulate_impact(p, speed, 0.0, 0.0)
            if res.status not in ("rebound", "captured"):
                return False
    except Exception:  # the reference itself cannot run it: undecided
        return False
    return True


def run_law(law, n, seed, ranges):
    rng = np.random.default_rng([seed, LAWS.index(law)])
    values = draw(law, n, rng, ranges)
    scene = scene_with(base_scene(law), values)
    start = time.perf_counter()
    with Recorder() as rec:
        got = ji.capture_speed(scene, 0.0, 0.0)
    seconds = time.perf_counter() - start
    names = got.status_names
    failed = np.flatnonzero(np.asarray(got.status) == CaptureStatus.FAILED)
    grid = scan_speeds(values, law=law)
    decided = [int(i) for i in failed if reference_decides(law, values, i, grid[i])]
    max_steps = {m: c for (m, s), c in rec.counts.items() if s == "max_steps"}
    explicit_max = sum(c for m, c in max_steps.items() if m != "kvaerno5")
    return {
        "law": law,
        "scenes": n,
        "statuses": dict(collections.Counter(names.tolist())),
        "failed": int(failed.size),
        "failed_where_decided": len(decided),
        "failed_lanes": decided,
        "max_steps_implicit": max_steps.get("kvaerno5", 0),
        "max_steps_explicit_retried": explicit_max,
        "implicit_lanes": getattr(got, "implicit", "-"),  # (before the per-lane solvers: -)
        "retried_lanes": getattr(got, "retried", "-"),
        "evaluations": got.evaluations,
        "seconds": seconds,
    }


def table(rows):
    head = (
        "| law | scenes | threshold | all_captured | none_in_range | multiple | not_converged "
        "| failed | failed where the reference decides | implicit lanes (retried) | s |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|"
    )
    lines = [head]
    for r in rows:
        s = r["statuses"]
        lines.append(
            f"| {r['law']} | {r['scenes']} | {s.get('threshold', 0)} | "
            f"{s.get('all_captured', 0)} | {s.get('none_in_range', 0)} | "
            f"{s.get('multiple', 0)} | {s.get('not_converged', 0)} | {r['failed']} | "
            f"{r['failed_where_decided']} | {r['implicit_lanes']} ({r['retried_lanes']}) | "
            f"{r['seconds']:.0f} |"
        )
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=200)
    ap.add_argument("--laws", default=",".join(LAWS))
    ap.add_argument("--ranges", choices=("prior", "input"), default="prior")
    ap.add_argument("--seed", type=int, default=57)
    ap.add_argument("--json", default=None, help="write the rows here too")
    args = ap.parse_args(argv)
    info = machine()
    rows = []
    for law in args.laws.split(","):
        row = run_law(law, args.scenes, args.seed, args.ranges)
        print(json.dumps(row), file=sys.stderr, flush=True)
        rows.append(row)
    print(f"{args.scenes} scenes per law, --ranges {args.ranges}, seed {args.seed}")
    print(table(rows))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    command = "python benchmarks/capture_speed_statuses.py " + " ".join(argv or sys.argv[1:])
    write_result(
        "capture_speed_statuses",
        {"scenes": args.scenes, "ranges": args.ranges, "seed": args.seed, "laws": rows},
        info, command.strip(),
    )  # fmt: skip
    bad = sum(r["failed_where_decided"] for r in rows)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

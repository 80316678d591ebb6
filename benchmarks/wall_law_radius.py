"""The wall law across a radius range: its radius nodes, build cost and error between nodes.

Run: ``python benchmarks/wall_law_radius.py [--radius LO HI] [--points N] [--angles SPEC]
[--layout aligned|grid]`` (Table 1 scene, default 1-100 um and the default angle grid: about 5
minutes on 2 cores with the kink-aligned layout, 15-30 with ``--layout grid``).
Runs as ``jaximpact wall-law`` does (``ji.use_all_cpu_cores()``: one XLA device per core, loop
kernels). Prints the figures of BENCHMARKS.md's "Wall law across radius" and writes them to
``benchmarks/results/wall_law_radius.json``.

1. ``wall_law(scene, radius=(LO, HI))``: radius nodes bisected until the capture speed at every
   interval's midpoint is within ``capture_tol`` (1e-3) of the table's, then split where the
   results bend (``refine_tol``), then the angle pass; stick rows below the radius that sticks
   at every speed.
2. The interpolated capture speed against ``capture_speed`` itself at random (radius, angle):
   radius log-uniform over the range, angle uniform 0-85 deg (points inside the intervals the
   build reports as unresolved are counted apart).
3. The table against ``simulate`` at random points (radius log-uniform, angle 0-85 deg, speed
   ratio log-uniform 0.5-200, capped at 1000 m/s): stick/rebound disagreements outside 0.1 %
   of the capture speed and outside the unresolved intervals (of the capture speed, and of the
   aligned layout's results check), and the largest errors of the rebounds the table does not
   flag as clamped, beyond 0.5 % of the capture speed (as ``jaximpact wall-law --check``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("JAXIMPACT_CACHE_DIR", "off")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import machine, measured_line, results_dir, write_atomic  # noqa: E402

import jaximpact as ji  # noqa: E402

ji.use_all_cpu_cores()  # as the command line does: one XLA device per core, loop kernels
from jaximpact.wall_law import compare_with_simulate, random_points, wall_law  # noqa: E402
from jaximpact.wall_law._capture import scene_with  # noqa: E402
from jaximpact.wall_law._table import _cell  # noqa: E402

COMMAND = "python benchmarks/wall_law_radius.py"


def lanes(scene, radius):
    values = {k: np.full(radius.size, float(v)) for k, v in ji.scene_parameters(scene).items()}
    values["radius"] = radius
    return scene_with(scene, values)


def in_bands(r, bands):
    return np.array([any(lo <= x <= hi for lo, hi, _ in bands) for x in r], bool)


def capture_errors(law, scene, n, seed=4):
    """The table's capture speed against capture_speed at n random (radius, angle)."""
    rng = np.random.default_rng(seed)
    r = np.exp(rng.uniform(np.log(law.radius[0]), np.log(law.radius[-1]), n))
    a = rng.uniform(0.0, 85.0, n)
    w = np.zeros(n)
    cap = ji.capture_speed(lanes(scene, r), a, w)
    true = np.asarray(cap.speed, float)
    status = np.asarray(cap.status)
    idx = [_cell(np.log(law.radius), np.log(r)), _cell(law.angle_deg, a), _cell(law.omega0, w)]
    table = law.reference_at(tuple(i for i, _, _ in idx), tuple(x for _, x, _ in idx), a)
    band = in_bands(r, law.radius_report.get("unresolved", []))
    stick_true, stick_table = ~np.isfinite(true), ~np.isfinite(table)
    both = ~stick_true & ~stick_table & ~band
    with np.errstate(invalid="ignore"):
        err = np.abs(table / true - 1.0)
    return {
        "points": n,
        "in_unresolved_bands": int(band.sum()),
        "stick_disagree_outside_bands": int(np.sum((stick_true != stick_table) & ~band)),
        "stick_both": int(np.sum(stick_true & stick_table)),
        "max_rel_error": float(np.max(err[both])),
        "p99_rel_error": float(np.percentile(err[both], 99)),
        "worst_at": {
            "radius": float(r[both][np.argmax(err[both])]),
            "angle_deg": float(a[both][np.argmax(err[both])]),
        },
        "statuses": dict(
            zip(*(v.tolist() for v in np.unique(status, return_counts=True)), strict=True)
        ),
    }


def simulate_errors(law, scene, n, seed=5):
    pts = random_points(law, n, seed=seed)
    c = compare_with_simulate(law, scene, pts)
    bands = [(lo, hi, None) for lo, hi in law.unresolved_radii]
    band = in_bands(pts["radius"], bands)
    clamped = (c["code"] & 2) == 2
    agree = c["status_agree"] | c["near_capture"] | band
    out = {
        "points": n,
        "failed": int(c["failed"].sum()),
        "in_unresolved_bands": int(band.sum()),
        "clamped": int(clamped.sum()),
        "captured_by_table": int(c["captured_table"].sum()),
        "status_disagree": int((~agree).sum()),
        "status_disagree_unclamped": int((~agree & ~clamped).sum()),
    }
    near = np.abs(pts["speed_ratio"] - 1.0) <= 5e-3  # the capture speed's tolerance there
    out["within_0.5%_of_capture"] = int(near.sum())
    for k, e in c["error"].items():
        e = np.where(clamped | band | near, np.nan, e)
        worst = int(np.nanargmax(e))
        out[f"max_{k}"] = float(e[worst])
        out[f"p99_{k}"] = float(np.nanpercentile(e, 99))
        out[f"worst_{k}_at"] = {
            "radius": float(pts["radius"][worst]),
            "angle_deg": float(pts["angle_deg"][worst]),
            "speed_ratio": float(pts["speed_ratio"][worst]),
            "speed": float(c["speed"][worst]),
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--radius", nargs=2, type=float, default=(1e-6, 100e-6), metavar=("LO", "HI"))
    ap.add_argument("--angles", default=None, help="angles, e.g. 0:85:18 (default the grid's)")
    ap.add_argument("--points", type=int, default=2000)
    ap.add_argument("--layout", choices=("aligned", "grid"), default="aligned")
    ap.add_argument("--out", default=None, help="default results/wall_law_radius[_aligned].json")
    args = ap.parse_args()
    name = "wall_law_radius.json" if args.layout == "grid" else "wall_law_radius_aligned.json"
    args.out = args.out or str(results_dir() / name)
    info = machine()
    scene = ji.table1_scene()
    angles = None
    if args.angles:
        lo, hi, num = args.angles.split(":")
        angles = np.linspace(float(lo), float(hi), int(num))
    start = time.perf_counter()
    law = wall_law(
        scene, radius=args.radius, angle_deg=angles, layout=args.layout,
        progress=lambda m: print(f"  [{time.perf_counter() - start:7.1f} s] {m}", flush=True),
    )  # fmt: skip
    build = time.perf_counter() - start
    from jaximpact.wall_law import c_header

    header_bytes = len(c_header(law, "table1").encode())
    R, A, W, X = law.shape
    report = law.radius_report
    t = time.perf_counter()
    cap = capture_errors(law, scene, args.points)
    sim = simulate_errors(law, scene, args.points)
    check = time.perf_counter() - t
    result = {
        "measured": measured_line(info, COMMAND),
        "radius_range": list(args.radius),
        "layout": args.layout,
        "shape": [R, A, W, X],
        "capture_angles": int(law.angle_deg.size),
        "c_header_bytes": header_bytes,
        "build_seconds": build,
        "impacts": int(law.impacts),
        "stick_radii": int(law.stick.all(axis=(1, 2)).sum()),
        "rows_with_a_top": int(np.sum(law.top_ratio < law.speed_ratio[-1])),
        "rows_captured_above_top": int(np.sum(law.captured_above_top == 1)),
        "radius_report": report,
        "capture_speed": cap,
        "against_simulate": sim,
        "check_seconds": check,
    }
    write_atomic(Path(args.out), json.dumps(result, indent=1, default=float))
    print(json.dumps(result, indent=1, default=float))


if __name__ == "__main__":
    main()

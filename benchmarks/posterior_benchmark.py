"""Posterior and design: sampling time, calibration coverage, design ratio.

Run: ``python benchmarks/posterior_benchmark.py [--time] [--coverage N] [--design]
[--warmup W] [--draws D] [--cache DIR]``; the full run is ``--time --coverage 20
--design`` with the defaults W = D = 1000 (hours on 2 cores; see BENCHMARKS.md for what was
actually run).

- data: the Table 1 microsphere, 25 impacts (0.3-5 m/s, 0/0/30/45/60 degrees), cor_n with
  sigma 0.003, at C_A = 0.75, C_H = 0.25, f0 = 300, noise drawn anew for each replication;
- ``--time``: one fit + posterior (4 chains x D draws after W warm-up steps), from a cold
  compilation cache (a new temporary directory): wall time of each phase;
- ``--coverage N``: N replications; the fraction of the 90 % intervals (q05..q95) that contain
  the true value, per parameter (target 80-97 % at N = 20), R-hat and divergences of each;
- ``--design``: 12 impacts chosen by `fitting.design` from a grid of candidates (speed
  0.05-5 m/s x angle 0-60 degrees) against 50 random 12-subsets of the usable candidates:
  ratio of det(J^T S^-1 J) to the median random one (target >= 5).

Duration: hours on 2 cores for the full run; ``--design`` alone minutes.
"""

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import fitting  # noqa: E402
import jaximpact  # noqa: E402

NAMES = ["C_A", "C_H", "f0"]
TRUTH = {"C_A": 0.75, "C_H": 0.25, "f0": 300.0}
SIGMA = 0.003
SPEED = np.geomspace(0.3, 5.0, 25)
ANGLE = np.tile([0.0, 0.0, 30.0, 45.0, 60.0], 5)


def write_data(path, values):
    rows = ["speed,angle_deg,observable,value,sigma"]
    rows += [
        f"{float(s)!r},{float(a)!r},cor_n,{float(v)!r},{SIGMA}"
        for s, a, v in zip(SPEED, ANGLE, values, strict=True)
    ]
    Path(path).write_text("\n".join(rows) + "\n")
    return path


def truth_scene(folder):
    placeholder = write_data(folder / "placeholder.csv", np.full(SPEED.size, 0.5))
    return fitting.Objective(jaximpact.table1_scene(), placeholder, NAMES).scene_at(TRUTH)


def clean_values(scene):
    return np.asarray(jaximpact.simulate(scene, SPEED, ANGLE, 0.0).cor_n)


def run_once(folder, clean, seed, warmup, draws, progress):
    rng = np.random.default_rng(seed)
    data = write_data(folder / f"data{seed}.csv", clean + SIGMA * rng.standard_normal(clean.size))
    t0 = time.perf_counter()
    post = fitting.sample_posterior(
        jaximpact.table1_scene(),
        data,
        NAMES,
        initial={"C_A": 1.5, "C_H": 0.15, "f0": 500.0},
        starts=1,
        warmup=warmup,
        draws=draws,
        seed=seed,
        progress=progress,
    )
    return post, time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--time", action="store_true")
    ap.add_argument("--coverage", type=int, default=0)
    ap.add_argument("--design", action="store_true")
    ap.add_argument("--seeds", help="with --coverage: only these replications (comma list)")
    ap.add_argument("--warmup", type=int, default=300)
    ap.add_argument("--draws", type=int, default=1000)
    ap.add_argument("--cache", help="compilation cache (default: a new temporary directory)")
    ap.add_argument("--json", help="write the numbers here")
    args = ap.parse_args(argv)
    out = {"warmup": args.warmup, "draws": args.draws}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        jaximpact.enable_compilation_cache(args.cache or folder / "cache")
        scene = truth_scene(folder)
        clean = clean_values(scene)
        if args.time:
            post, wall = run_once(folder, clean, 0, args.warmup, args.draws, True)
            out["time"] = {
                "wall_s": wall,
                **post.timings,
                "evaluations": post.evaluations,
                "status": post.status,
                "divergences": post.divergences,
                "rhat": {n: post.summary[n]["rhat"] for n in NAMES},
                "ess": {n: post.summary[n]["ess"] for n in NAMES},
            }
            print(json.dumps(out["time"], indent=1), flush=True)
        if args.coverage:
            hits = {n: 0 for n in NAMES}
            reps = []
            seeds = [int(x) for x in args.seeds.split(",")] if args.seeds else None
            for seed in seeds or range(1, args.coverage + 1):
                post, wall = run_once(folder, clean, seed, args.warmup, args.draws, False)
                rep = {
                    "seed": seed,
                    "wall_s": wall,
                    "status": post.status,
                    "divergences": post.divergences,
                    "sampler": post.sampler,
                    "khat": post.khat,
                }
                for n in NAMES:
                    s = post.summary[n]
                    inside = s["q05"] <= TRUTH[n] <= s["q95"]
                    hits[n] += inside
                    rep[n] = {"q05": s["q05"], "q95": s["q95"], "rhat": s["rhat"], "inside": inside}
                reps.append(rep)
                print(json.dumps(rep), flush=True)
            out["coverage"] = {n: hits[n] / args.coverage for n in NAMES}
            out["replications"] = reps
            print("coverage of the 90 % intervals:", out["coverage"], flush=True)
        if args.design:
            speed = np.geomspace(0.05, 5.0, 30)
            angle = np.array([0.0, 15.0, 30.0, 45.0, 60.0])
            s, a = np.meshgrid(speed, angle)
            cand = folder / "cand.csv"
            cand.write_text(
                "speed,angle_deg\n"
                + "\n".join(
                    f"{x!r},{y!r}"
                    for x, y in zip(s.ravel().tolist(), a.ravel().tolist(), strict=True)
                )
                + "\n"
            )
            t0 = time.perf_counter()
            d = fitting.design(scene, cand, NAMES, 12, sigma={"cor_n": SIGMA})
            t_design = time.perf_counter() - t0
            rng = np.random.default_rng(0)
            designed = fitting.log_det_information(d.information, d.chosen)
            random = [
                fitting.log_det_information(d.information, rng.choice(d.usable, 12, replace=False))
                for _ in range(50)
            ]
            out["design"] = {
                "candidates": len(d.candidates),
                "usable": len(d.usable),
                "dropped_captured": len(d.dropped_captured),
                "dropped_near_capture": len(d.dropped_near_capture),
                "ratio_to_median_random": math.exp(designed - float(np.median(random))),
                "seconds": t_design,
                "chosen": [
                    [float(d.candidates.speed[i]), float(d.candidates.angle_deg[i])]
                    for i in d.chosen
                ],
            }
            print(json.dumps(out["design"], indent=1), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Capture speed and wall law: accuracy against the exact reference and simulate, and cost.

Run: ``python benchmarks/wall_law_benchmark.py [--scenes N] [--points N] [--skip-derivatives]``
(about 8 minutes on 2 cores: the default wall law about a minute, the reference's bisections
and the derivative program the rest). Prints the figures of BENCHMARKS.md's "Wall law".

1. ``capture_speed`` on N random adhesive scenes at 0 and 45 degrees against the exact
   reference's threshold found by bisection (bracket 1e-4 around jaximpact's value, to 1e-10).
2. Its derivatives (``jax.jacfwd``, implicit-function theorem) against central differences
   (step 1e-3 of the value) of the reference's threshold, on two of those scenes.
3. The default wall law of the Table 1 scene (one radius): build time in a fresh process
   state (compiling included, no compilation cache), then its interpolation against
   ``simulate`` at random points (speed ratio log-uniform 0.5-200, angle 0-85 deg).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

os.environ.setdefault("JAXIMPACT_CACHE_DIR", "off")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from _common import machine, write_result  # noqa: E402

import jaximpact as ji  # noqa: E402
from jaximpact import reference  # noqa: E402
from jaximpact.wall_law import compare_with_simulate, random_points, wall_law  # noqa: E402
from jaximpact.wall_law._capture import scene_with  # noqa: E402

NAMES = ("radius", "density", "K", "f0", "C_A", "C_H", "friction")
DERIVATIVE_NAMES = ("radius", "density", "K", "f0", "C_A", "C_H")


def random_scenes(n: int, seed: int = 2026) -> dict:
    rng = np.random.default_rng(seed)
    return {
        "radius": np.exp(rng.uniform(np.log(5e-6), np.log(50e-6), n)),
        "density": rng.uniform(2000.0, 9000.0, n),
        "K": np.exp(rng.uniform(np.log(2e10), np.log(2e11), n)),
        "f0": rng.uniform(50.0, 500.0, n),
        "C_A": rng.uniform(0.2, 2.0, n),
        "C_H": rng.uniform(0.05, 0.5, n),
        "friction": rng.uniform(0.1, 0.5, n),
    }


def ref_params(values: dict, i: int) -> reference.Params:
    return reference.Params(**{k: float(values[k][i]) for k in NAMES})


def ref_threshold(p, angle, guess, width=1e-4, rel_tol=1e-10):
    return reference.capture_speed(
        p, angle, 0.0, lo=(1 - width) * guess, hi=(1 + width) * guess, rel_tol=rel_tol
    )


def capture_accuracy(n: int) -> dict:
    """``n`` random scenes with one capture threshold at 0 and 45 degrees (scenes drawn until
    there are ``n``; the others, small spheres that stick at every speed or stick again at
    high speed, are counted by status)."""
    drawn = random_scenes(4 * n)
    scene = scene_with(ji.table1_scene(), {k: v[:, None] for k, v in drawn.items()})
    angles = np.array([0.0, 45.0])
    t = time.perf_counter()
    got = ji.capture_speed(scene, angles)
    seconds = time.perf_counter() - t
    names, counts = np.unique(got.status_names, return_counts=True)
    keep = np.flatnonzero(np.all(np.asarray(got.status) == 0, axis=1))[:n]
    n = keep.size
    values = {k: v[keep] for k, v in drawn.items()}
    speed = np.asarray(got.speed)[keep]
    errors = np.zeros((n, 2))
    for i in range(n):
        for j, a in enumerate(angles):
            want = ref_threshold(ref_params(values, i), a, speed[i, j])
            errors[i, j] = abs(speed[i, j] / want - 1)
    return {
        "n": n,
        "drawn": len(drawn["f0"]),
        "statuses": dict(zip(names.tolist(), counts.tolist(), strict=True)),
        "status": np.asarray(got.status)[keep],
        "errors": errors,
        "seconds": seconds,
        "evaluations": got.evaluations,
        "range": (speed.min(), speed.max()),
        "values": values,
    }


def derivative_accuracy(values: dict) -> dict:
    """On the first two scenes of ``values`` (scenes with one threshold)."""
    out = {}
    t_first = None
    for i in range(2):
        vals = {k: float(values[k][i]) for k in NAMES}
        base = scene_with(ji.table1_scene(), vals)
        for angle in (0.0, 45.0):
            t = time.perf_counter()
            jac = jax.jacfwd(
                lambda v, a=angle, s=base: ji.capture_speed(scene_with(s, v), a).speed
            )(vals)
            if t_first is None:
                t_first = time.perf_counter() - t
            v0 = float(ji.capture_speed(base, angle).speed)
            p = ref_params(values, i)
            for name in DERIVATIVE_NAMES:
                h = 1e-3 * getattr(p, name)
                up = ref_threshold(
                    dataclasses.replace(p, **{name: getattr(p, name) + h}), angle, v0, 0.1
                )
                down = ref_threshold(
                    dataclasses.replace(p, **{name: getattr(p, name) - h}), angle, v0, 0.1
                )
                fd = (up - down) / (2 * h)
                out[(i, angle, name)] = abs(float(jac[name]) / fd - 1)
    return {"errors": out, "first_jacfwd_seconds": t_first}


def wall_law_figures(points: int) -> dict:
    scene = ji.table1_scene()
    t = time.perf_counter()
    law = wall_law(scene)
    build = time.perf_counter() - t
    t = time.perf_counter()
    c = compare_with_simulate(law, scene, random_points(law, points, seed=1))
    check = time.perf_counter() - t
    agree = c["status_agree"] | c["near_capture"]
    return {
        "shape": law.shape,
        "build": build,
        "impacts": law.impacts,
        "check": check,
        "points": points,
        "failed": int(c["failed"].sum()),
        "disagree": int((~agree).sum()),
        "near": int(c["near_capture"].sum()),
        "captured": int(c["captured_table"].sum()),
        "errors": {k: float(np.nanmax(v)) for k, v in c["error"].items()},
        "p99": {k: float(np.nanpercentile(v, 99)) for k, v in c["error"].items()},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=int, default=8, help="random scenes for capture_speed")
    ap.add_argument("--points", type=int, default=2000, help="random points for the table")
    ap.add_argument("--skip-derivatives", action="store_true")
    args = ap.parse_args()
    info = machine()
    load = os.getloadavg()[0]
    w = wall_law_figures(args.points)
    R, A, W, X = w["shape"]
    print(f"1-minute load average at the start: {load:.1f}")
    print(
        f"default wall law (Table 1, one radius): {R} x {A} x {W} x {X} nodes, "
        f"{w['impacts']} impacts, {w['build']:.1f} s (compiling included, no cache)"
    )
    print(
        f"against simulate at {w['points']} random points ({w['captured']} captured by the "
        f"table, {w['near']} within 0.1 % of the capture speed): status disagreements outside "
        f"that band {w['disagree']}, failures {w['failed']}; largest errors "
        + ", ".join(
            f"{k} {v:.2e} (99th percentile {w['p99'][k]:.1e})" for k, v in w["errors"].items()
        )
        + f"; check {w['check']:.1f} s"
    )
    figures = {"wall_law": w}
    c = capture_accuracy(args.scenes)
    figures["capture_speed"] = c
    e = c["errors"]
    print(
        f"capture_speed: statuses of {c['drawn']} random scenes x (0, 45 deg): {c['statuses']}; "
        f"on {c['n']} with one threshold: "
        f"speeds {c['range'][0]:.4g}-{c['range'][1]:.4g} m/s, largest relative error against "
        f"the reference's bisection {e.max():.2e} (0 deg {e[:, 0].max():.2e}, 45 deg "
        f"{e[:, 1].max():.2e}); {c['evaluations']} simulate calls per lane, {c['seconds']:.1f} s"
    )
    if not args.skip_derivatives:
        d = derivative_accuracy(c["values"])
        errs = d["errors"]
        by_name = {n: max(v for (i, a, m), v in errs.items() if m == n) for n in DERIVATIVE_NAMES}
        print(
            "derivatives (2 scenes x 0, 45 deg), largest relative error against central "
            "differences of the reference: "
            + ", ".join(f"{k} {v:.1e}" for k, v in by_name.items())
            + f"; first jax.jacfwd {d['first_jacfwd_seconds']:.0f} s (compiling included)"
        )
        figures["derivatives"] = {"largest_relative_error": by_name,
                                  "first_jacfwd_seconds": d["first_jacfwd_seconds"]}  # fmt: skip
    command = (
        f"python benchmarks/wall_law_benchmark.py --scenes {args.scenes} --points {args.points}"
    )
    write_result("wall_law_benchmark", figures, info, command)


if __name__ == "__main__":
    main()

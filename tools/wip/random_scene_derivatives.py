"""Derivatives on random scenes and impacts up to 25 m/s and grazing angles against the exact
reference (issue 52: every entry within 1e-3).

Scenes (seed 52): adhesive, rolling moments alternately analytical and constant-lambda, drawn
as in tests/test_derivatives.py (radius 9-45 um, density 2000-9000, K 2e10-1.6e11 Pa, f0
20-300 N/m, C_A 0.2-1.5, C_H 0.05-0.5, friction 0.1-0.6, lambda 0.5-2 nm); impacts log-uniform
0.5-25 m/s, -70..70 deg, every other with spin up to 0.3 speed/radius. Derivatives
(``output_jacobian``, compact program) of ``cor_n``, ``vt_out``, ``omega_out`` with respect to
f0, C_A, C_H, friction, (lambda,) speed, angle and spin of every rebound, against central
differences of the reference (rtol 1e-12, Richardson), scaled to order one (``x d/dx``; vt by
the speed, omega by speed/radius), each relative to its own magnitude floored at 1e-2 of its
row's largest. Entries whose finite difference is itself uncertain (Richardson estimate above
1e-4 of that scale: a regime switch inside the step) are not judged, and counted.

    python benchmarks/random_scene_derivatives.py [--scenes 6] [--impacts 6] [--rtol R]
        [--cache FILE.pkl]

Duration: about 5 minutes on 2 cores (the reference's finite differences, about 2 minutes,
are most of it; ``--cache`` keeps them).
"""

import argparse
import math
import pickle
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

import jaximpact as ji  # noqa: E402
from jaximpact import reference as ref  # noqa: E402

OUTPUTS = ("cor_n", "vt_out", "omega_out")
FD_TOL = 1e-4  # as tests/test_derivatives.py: 0.1 of the 1e-3 target


def _scene(rng, moments):
    radius = rng.uniform(9e-6, 45e-6)
    v = dict(radius=radius, density=rng.uniform(2000.0, 9000.0), K=10 ** rng.uniform(10.3, 11.2),
             f0=rng.uniform(20.0, 300.0), C_A=rng.uniform(0.2, 1.5), C_H=rng.uniform(0.05, 0.5),
             friction=rng.uniform(0.1, 0.6),
             lam=rng.uniform(0.5e-9, 2e-9) if moments == "lambda" else 0.0)  # fmt: skip
    scene = ji.Scene(
        particle=ji.Particle(radius=radius, density=v["density"]),
        contact=ji.Contact(**{k: v[k] for k in ("K", "f0", "C_A", "C_H", "friction")}),
        model=ji.Model(adhesion=True, rolling_moments=moments, lambda_=v["lam"]),
    )
    return scene, ref.Params(**v, adhesion=True, rolling_moments=moments)


def cases(seed=52, n_scenes=6, n_impacts=6, v_max=25.0):
    """``[(scene, params, speed, angle, omega0, inputs)]``."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n_scenes):
        moments = ("analytical", "lambda")[k % 2]
        scene, p = _scene(rng, moments)
        speed = 10 ** rng.uniform(math.log10(0.5), math.log10(v_max), n_impacts)
        angle = rng.uniform(-70.0, 70.0, n_impacts)
        omega0 = rng.uniform(-0.3, 0.3, n_impacts) * speed / p.radius
        omega0[1::2] = 0.0
        inputs = ("f0", "C_A", "C_H", "friction", *(("lambda",) if moments == "lambda" else ()),
                  "speed", "angle_deg", "omega0")  # fmt: skip
        out.append((scene, p, speed, angle, omega0, inputs))
    return out


def exact_results(cs):
    table = []
    for _, p, speed, angle, omega0, inputs in cs:
        rows = []
        for v, a, w in zip(speed, angle, omega0, strict=True):
            status = ref.simulate_impact(p, v, a, w, rtol=1e-12).status
            d = ref.output_derivatives(p, v, a, w, inputs=inputs) if status == "rebound" else None
            rows.append((status, d))
        table.append(rows)
    return table


def _scale(p, speed, c, out):
    x = {"angle_deg": 180 / math.pi, "omega0": speed / p.radius, "speed": speed}.get(c)
    x = abs(p.lam if c == "lambda" else getattr(p, c)) if x is None else x
    return x / {"cor_n": 1.0, "vt_out": speed, "omega_out": speed / p.radius}[out]


def errors(cs, exact, rtol=None):
    """``(judged, skipped)``: judged entries as ``(error, speed, angle, omega0, out, input)``."""
    judged, skipped = [], 0
    for (scene, p, speed, angle, omega0, inputs), rows in zip(cs, exact, strict=True):
        if rtol:
            scene = scene.replace(solver={"rtol": rtol, "atol": rtol / 100})
        jac = ji.output_jacobian(scene, speed, angle, omega0, inputs=inputs, program="compact")
        for i, (status, d) in enumerate(rows):
            if status != "rebound":
                continue
            want, fd_error = d
            for out in OUTPUTS:
                s = {c: _scale(p, speed[i], c, out) for c in inputs}
                row = {c: want[out][c] * s[c] for c in inputs}
                typical = max(abs(x) for x in row.values())
                for j, c in enumerate(inputs):
                    floor = max(abs(row[c]), 1e-2 * typical)
                    if fd_error[out][c] * s[c] > FD_TOL * floor:
                        skipped += 1
                        continue
                    got = float(np.asarray(jac[out])[i, j]) * s[c]
                    error = abs(got - row[c]) / floor
                    judged.append((error, speed[i], angle[i], omega0[i], out, c))
    return judged, skipped


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=52)
    ap.add_argument("--scenes", type=int, default=6)
    ap.add_argument("--impacts", type=int, default=6)
    ap.add_argument("--rtol", type=float, help="solver rtol (atol rtol/100); default: defaults")
    ap.add_argument("--cache", help="pickle the reference results here and reuse them")
    args = ap.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import machine, measured_line

    cs = cases(args.seed, args.scenes, args.impacts)
    if args.cache and Path(args.cache).exists():
        exact = pickle.loads(Path(args.cache).read_bytes())
    else:
        exact = exact_results(cs)
        if args.cache:
            Path(args.cache).write_bytes(pickle.dumps(exact))
    start = time.perf_counter()
    judged, skipped = errors(cs, exact, args.rtol)
    seconds = time.perf_counter() - start
    e = np.array([x[0] for x in judged])
    print(measured_line(machine(), "python benchmarks/random_scene_derivatives.py"))
    print(f"{e.size} derivatives judged ({skipped} skipped: finite difference uncertain): "
          f"max {e.max():.2e}, median {np.median(e):.1e}, {(e > 1e-3).sum()} above 1e-3 "
          f"(output_jacobian {seconds:.0f} s including compilation)")  # fmt: skip
    for err, v, a, w, out, c in sorted(judged, key=lambda x: -x[0])[:5]:
        print(f"  {err:.2e}: d {out}/d {c} at {v:.2f} m/s, {a:.1f} deg, {w:.3g} rad/s")


if __name__ == "__main__":
    main()

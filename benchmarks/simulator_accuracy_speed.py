"""Default-setting accuracy against the exact reference, capture speed, and batch throughput.

Run: ``python benchmarks/simulator_accuracy_speed.py`` (about 3 minutes on 2 cores). Prints a
Markdown section for BENCHMARKS.md. Timings are medians of repeated runs after compilation.
"""

import platform
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import jaximpact as ji  # noqa: E402
from jaximpact import reference as ref  # noqa: E402


def held_out(n, seed=1):
    rng = np.random.default_rng(seed)
    speed = 10 ** rng.uniform(-1.2, 1.0, n)
    angle = rng.uniform(-70, 70, n)
    omega0 = rng.uniform(-3e4, 3e4, n)
    angle[:10] = 0.0
    omega0[:5] = 0.0
    return speed, angle, omega0


def scaled_error(res, exact, speed, angle, radius):
    ok = np.array([e.status == "rebound" for e in exact])
    v_n = speed * np.cos(np.radians(angle))
    cols = {k: np.array([getattr(e, k) for e in exact], float)
            for k in ("vn_out", "vt_out", "omega_out")}
    err = np.stack([
        np.abs(np.asarray(res.cor_n) - cols["vn_out"] / v_n),
        np.abs(np.asarray(res.vt_out) - cols["vt_out"]) / speed,
        np.abs(np.asarray(res.omega_out) - cols["omega_out"]) * radius / speed,
    ])[:, ok]
    mismatches = int(np.sum(res.columns()["status"] != np.array([e.status for e in exact])))
    return float(err.max()), mismatches


def median_time(fn, repeats=3):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main():
    scene = ji.table1_scene()
    radius = float(scene.particle.radius)
    speed, angle, omega0 = held_out(60)
    params = ref.table1_params()
    exact = [ref.simulate_impact(params, *x) for x in zip(speed, angle, omega0, strict=True)]
    print("## Simulator: default settings against the exact reference\n")
    print(f"Machine: {platform.processor() or platform.machine()}, jax {jax.__version__}, "
          f"devices {jax.devices()}\n")
    print("60 held-out Table 1 impacts (0.06-10 m/s, -70..70 deg, |omega0| <= 3e4 rad/s, "
          "including captures). Error = max over rebounds of |d cor_n|, |d vt_out|/speed, "
          "|d omega_out| r/speed.\n")
    print("| method | rtol | slip_width | max error | status mismatches | median steps |")
    print("|---|---|---|---|---|---|")
    for method, rtol, width in [("tsit5", 1e-8, 1e-3), ("tsit5", 1e-8, 1e-5),
                                ("tsit5", 1e-11, 1e-3), ("tsit5", 1e-11, 1e-6),
                                ("tsit5", 1e-6, 1e-3), ("dopri8", 1e-7, 1e-3)]:
        s = scene.replace(solver={"method": method, "rtol": rtol, "atol": rtol * 1e-2,
                                  "slip_width": width, "max_steps": 100000})
        res = ji.simulate(s, speed, angle, omega0)
        err, bad = scaled_error(res, exact, speed, angle, radius)
        print(f"| {method} | {rtol:g} | {width:g} | {err:.1e} | {bad} | "
              f"{np.median(np.asarray(res.steps)):.0f} |")
    v_c = ref.capture_speed(params)
    lo, hi = 0.05, 0.2
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        captured = int(ji.simulate(scene, mid, 0.0, 0.0).status) == ji.Status.CAPTURED
        lo, hi = (mid, hi) if captured else (lo, mid)
    print(f"\nCapture speed of the Table 1 scene (normal, no spin): jaximpact {0.5 * (lo + hi):.7f}"
          f" m/s, exact reference {v_c:.7f} m/s.\n")
    print("## Simulator: batch throughput (full oblique spinning Table 1 scene)\n")
    print("| precision | batch | compile + first run (s) | median run (s) | impacts/s | max steps |")
    print("|---|---|---|---|---|---|")
    rng = np.random.default_rng(0)
    for x64 in (True, False):
        with jax.enable_x64(x64):
            sc = ji.table1_scene()
            for n in (1000, 10000):
                sp = rng.uniform(0.5, 5, n)
                an = rng.uniform(-60, 60, n)
                om = rng.uniform(-2e4, 2e4, n)
                t = time.perf_counter()
                res = ji.simulate(sc, sp, an, om)
                jax.block_until_ready(res)
                first = time.perf_counter() - t
                run = median_time(lambda sc=sc, sp=sp, an=an, om=om: ji.simulate(sc, sp, an, om))
                print(f"| {'float64' if x64 else 'float32'} | {n} | {first:.1f} | {run:.2f} | "
                      f"{n / run:.0f} | {int(np.max(res.steps))} |")
    t = time.perf_counter()
    for x in zip(speed[:20], angle[:20], omega0[:20], strict=True):
        ref.simulate_impact(params, *x)
    print(f"\nExact scipy reference (DOP853, rtol 1e-12, switched): "
          f"{(time.perf_counter() - t) / 20 * 1e3:.0f} ms per impact.")


if __name__ == "__main__":
    main()

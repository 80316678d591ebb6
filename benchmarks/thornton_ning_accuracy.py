"""Thornton-Ning in the engine against its exact reference, and its cost against JKR.

    python benchmarks/thornton_ning_accuracy.py [--impacts 2000]

Prints (BENCHMARKS.md, "Thornton-Ning"): for the oracle set of docs/thornton_ning.md (a 5 um
sphere, E* = 10 GPa, rho = 2500 kg/m^3, w = 0.1 J/m^2) at four limiting pressures, the
largest error of ``cor_n``, the largest overlap and the contact time against
``jaximpact.reference.thornton_ning`` over log-spaced speeds (statuses compared), and the
ledger's largest residual; then the warm run time of a batch of oblique spinning impacts with
the Thornton-Ning law against the same batch with JKR (medians of 5, one process, the API's
default program), with the mean steps per impact; then ``w`` and ``p_y`` fitted to synthetic
rebounds with known answers.

Duration: not recorded (four limiting pressures, a timed batch, two small fits).
"""

from __future__ import annotations

import argparse
import math
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _common import interleaved_timings, machine, write_result  # noqa: E402

import jaximpact as ji  # noqa: E402
from jaximpact.reference import thornton_ning as tn  # noqa: E402

R, E, RHO, W = 5e-6, 1e10, 2500.0, 0.1
MASS = RHO * 4.0 / 3.0 * math.pi * R**3


def scene(normal="thornton_ning", p_y=3e8, C_H=0.0, friction=0.3):
    contact = dict(K=4 * E / 3, f0=0.0, C_A=0.0, C_H=C_H, friction=friction, w=W)
    if normal == "thornton_ning":
        contact["p_y"] = p_y
    return ji.Scene(
        particle=ji.Particle(radius=R, density=RHO),
        contact=ji.Contact(**contact),
        model=ji.Model(normal=normal),
    )


def accuracy(speeds):
    rows = []
    for p_y in (8e7, 1e8, 3e8, 1e9):
        res = ji.simulate(scene(p_y=p_y), speeds, np.zeros_like(speeds), 0.0)
        err = {"cor_n": 0.0, "max_overlap": 0.0, "contact_time": 0.0}
        mismatched, captured = 0, 0
        for i, v in enumerate(speeds):
            q = tn.simulate_normal_impact(float(v), R, E, W, MASS, p_y)
            code = ji.Status.REBOUND if q.status == "rebound" else ji.Status.CAPTURED
            mismatched += int(res.status[i]) != code
            captured += q.status == "captured"
            err["cor_n"] = max(err["cor_n"], abs(float(res.cor_n[i]) - q.v_out / v))
            if q.status == "rebound":
                for k, exact in (("max_overlap", q.max_overlap), ("contact_time", q.contact_time)):
                    err[k] = max(err[k], abs(float(getattr(res, k)[i]) / exact - 1))
        losses = res.loss_hertz_damping + res.loss_adhesion_damping + res.loss_plastic
        ledger = float(jnp.max(jnp.abs(res.energy_in - res.energy_out - losses) / res.energy_in))
        rows.append((p_y, len(speeds), captured, mismatched, err, ledger))
    return rows


def timing(n, repeats=5):
    rng = np.random.default_rng(0)
    speeds = rng.uniform(0.2, 20.0, n)
    angles = rng.uniform(-70, 70, n)
    omega0 = rng.uniform(-0.3, 0.3, n) * speeds / R
    out = {}
    for law in ("jkr", "thornton_ning"):
        s = scene(law, C_H=0.1)

        def call(s=s):
            res = ji.simulate(s, speeds, angles, omega0)
            res.cor_n.block_until_ready()
            return res

        r = interleaved_timings({law: call}, repeats)[law]  # a first call, then the repeats
        out[law] = (r["first"], r["median"], float(np.mean(np.asarray(r["result"].steps))))
    return out


def synthetic_fit():
    """``w`` and ``p_y`` fitted to 20 normal ``cor_n`` (0.1-30 m/s, 0.3 % noise) of the
    sphere at w = 0.1 J/m^2, p_y = 0.3 GPa, from a start 2x and 0.5x off."""
    import tempfile
    from pathlib import Path

    import fitting

    speeds = np.geomspace(0.1, 30.0, 20)
    clean = np.asarray(ji.simulate(scene(friction=0.0), speeds, np.zeros(20), 0.0).cor_n)
    noisy = clean * (1 + 0.003 * np.random.default_rng(3).standard_normal(clean.size))
    lines = ["speed,angle_deg,observable,value"]
    lines += [f"{float(s)!r},0.0,cor_n,{float(v)!r}" for s, v in zip(speeds, noisy, strict=True)]
    with tempfile.TemporaryDirectory() as work:
        data = Path(work) / "tn.csv"
        data.write_text("\n".join(lines) + "\n")
        t0 = time.perf_counter()
        result = fitting.fit(
            scene(friction=0.0),
            data,
            ["w", "p_y"],
            initial={"w": 2 * W, "p_y": 1.5e8},
            progress=False,
        )
        wall = time.perf_counter() - t0
    return result, wall


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--impacts", type=int, default=2000, help="impacts in the timed batch")
    args = parser.parse_args()
    info = machine()
    print(f"{info['date']}, {info['cpu']}, {info['cores']} cores, load average {info['load']}")
    speeds = np.geomspace(0.05, 100.0, 25)
    print("| p_y (Pa) | impacts (captured) | status differences | cor_n | max_overlap (rel) |"
          " contact_time (rel) | ledger (of energy in) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    figures = {"accuracy": []}
    for p_y, n, captured, mismatched, err, ledger in accuracy(speeds):
        figures["accuracy"].append(dict(p_y=p_y, impacts=n, captured=captured,
                                        status_differences=mismatched, errors=err,
                                        ledger=ledger))  # fmt: skip
        print(
            f"| {p_y:.0e} | {n} ({captured}) | {mismatched} | {err['cor_n']:.1e} | "
            f"{err['max_overlap']:.1e} | {err['contact_time']:.1e} | {ledger:.1e} |"
        )
    t = timing(args.impacts)
    print(f"\n{args.impacts} oblique spinning impacts, 0.2-20 m/s, C_H = 0.1 s/m, friction 0.3:")
    print("| law | first call s (compile + run) | warm s (median of 5) | impacts/s | mean steps |")
    print("|---|---|---|---|---|")
    for law, (first, warm, steps) in t.items():
        print(f"| {law} | {first:.1f} | {warm:.3f} | {args.impacts / warm:,.0f} | {steps:.0f} |")
    ratio = t["thornton_ning"][1] / t["jkr"][1]
    print(f"Thornton-Ning / JKR warm time: {ratio:.2f}")
    result, wall = synthetic_fit()
    print(
        f"\nsynthetic fit of w, p_y (truth 0.1 J/m^2, 3e8 Pa; start 0.2, 1.5e8): "
        f"{'converged' if result.converged else 'NOT converged'} in {wall:.1f} s; "
        + ", ".join(f"{k} = {result.values[k]:.5g} +- {result.stderr[k]:.2g}" for k in ("w", "p_y"))
    )
    figures["timing"] = {
        "impacts": args.impacts,
        **{law: dict(first=f, warm=w, rate=args.impacts / w, mean_steps=s)
           for law, (f, w, s) in t.items()},
        "thornton_ning_over_jkr": ratio,
    }  # fmt: skip
    figures["synthetic_fit"] = {
        "converged": bool(result.converged),
        "seconds": wall,
        "values": {k: result.values[k] for k in ("w", "p_y")},
        "stderr": {k: result.stderr[k] for k in ("w", "p_y")},
    }
    command = f"python benchmarks/thornton_ning_accuracy.py --impacts {args.impacts}"
    write_result("thornton_ning_accuracy", figures, info, command)


if __name__ == "__main__":
    main()

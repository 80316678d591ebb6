"""Tangential compliance: both models fitted to all the Kharaz data, side by side.

Run: ``python benchmarks/tangential_compliance.py`` (about 3 minutes on 2 cores).

- The rigid model (embedded scene ``kharaz2001``) fitted in ``friction``, and the Mindlin model
  (``kharaz2001_mindlin``) in ``friction`` and ``G_star``, each to all 24 observations (every
  angle 1.8-60 degrees; cor_t, rebound angle, omega_out) with ``fitting.fit`` (3 starts, the
  CLI's defaults), then the root-mean-square of model minus data per observable, computed the
  same way for both (``jaximpact.simulate`` at the fitted values, at the data's impacts).
- The cost of the option: a warm ``simulate`` of 200 impacts (3.9 m/s, 0.5-65 degrees) of each
  scene at the physical G*, median of 7 runs, and the mean step count.
- The rigid model unchanged by the option: the outputs and step counts of 15 impacts of each
  embedded rigid scene, against the same run of a version without the option when its source
  is given (``--before DIR``, a checkout of ``jaximpact/`` from that version): bitwise
  equality.
"""

import argparse
import json
import subprocess
import sys

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import fitting  # noqa: E402
import jaximpact as ji  # noqa: E402

OBSERVABLES = ("cor_t", "rebound_angle_deg", "omega_out")


def rms_by_observable(scene, obs):
    impacts = obs.impacts
    res = ji.simulate(scene, impacts.speed, impacts.angle_deg, impacts.omega0)
    out = {}
    for name in OBSERVABLES:
        sel = obs.observable == name
        model = np.asarray(getattr(res, name))[obs.impact_index[sel]]
        out[name] = float(np.sqrt(np.mean((model - obs.value[sel]) ** 2)))
    return out


PROBE = """
import sys, json
sys.path.insert(0, sys.argv[1]) if sys.argv[1] else None
import jax; jax.config.update("jax_enable_x64", True)
import numpy as np, jaximpact as ji
out = {}
for name in ("kharaz2001", "table1"):
    r = ji.simulate(ji.load_scene(name), np.linspace(0.5, 4, 15), np.linspace(0, 70, 15),
                    np.linspace(-300, 300, 15))
    for f in ("vn_out", "vt_out", "omega_out", "contact_time", "energy_out", "loss_friction",
              "steps"):
        out[f"{name}.{f}"] = np.asarray(getattr(r, f)).tolist()
print(json.dumps(out))
"""


def rigid_unchanged(before):
    runs = [
        json.loads(subprocess.check_output([sys.executable, "-c", PROBE, path], text=True))
        for path in (before, "")
    ]
    same = all(runs[0][k] == runs[1][k] for k in runs[0])  # float lists: exact equality
    steps = {k: sum(v) for k, v in runs[1].items() if k.endswith(".steps")}
    return same, steps


def cost():
    import statistics
    import time

    angles = np.linspace(0.5, 65.0, 200)
    out = {}
    for name in ("kharaz2001", "kharaz2001_mindlin"):
        scene = ji.load_scene(name)
        jax.block_until_ready(ji.simulate(scene, 3.9, angles).vt_out)  # compile
        times = []
        for _ in range(7):
            start = time.perf_counter()
            res = ji.simulate(scene, 3.9, angles)
            jax.block_until_ready(res.vt_out)
            times.append(time.perf_counter() - start)
        out[name] = (statistics.median(times), float(np.mean(np.asarray(res.steps))))
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", help="directory holding jaximpact/ of the commit before")
    args = parser.parse_args()
    from _common import machine, write_result

    info = machine()
    obs = fitting.load_kharaz2001()
    rows = []
    for scene_name, params in (("kharaz2001", ["friction"]), ("kharaz2001_mindlin",
                                                             ["friction", "G_star"])):  # fmt: skip
        result = fitting.fit(ji.load_scene(scene_name), obs, params, starts=3, progress=False)
        rms = rms_by_observable(result.scene, obs)
        values = {k: (result.values[k], result.stderr[k]) for k in params}
        rows.append((scene_name, result.status, values, rms))
    print("| model | fitted | rms cor_t | rms rebound angle (deg) | rms omega_out (rad/s) |")
    print("|---|---|---|---|---|")
    for name, status, values, rms in rows:
        fitted = ", ".join(f"{k} = {v:.4g} +- {e:.2g}" for k, (v, e) in values.items())
        print(
            f"| {name} ({status}) | {fitted} | {rms['cor_t']:.4f} | "
            f"{rms['rebound_angle_deg']:.3f} | {rms['omega_out']:.1f} |"
        )
    costs = cost()
    for name, (seconds, steps) in costs.items():
        print(f"{name}: 200 impacts warm, median of 7: {seconds:.3f} s; mean steps {steps:.0f}")
    figures = {
        "fits": [dict(scene=n, status=s, values=v, rms=r) for n, s, v, r in rows],
        "cost": {n: {"seconds": s, "mean_steps": st} for n, (s, st) in costs.items()},
    }
    if args.before:
        same, steps = rigid_unchanged(args.before)
        print(f"rigid scenes bitwise unchanged against {args.before}: {same}; steps {steps}")
        figures["rigid_unchanged"] = {"same": same, "steps": steps}
    write_result(
        "tangential_compliance", figures, info, "python benchmarks/tangential_compliance.py"
    )


if __name__ == "__main__":
    main()

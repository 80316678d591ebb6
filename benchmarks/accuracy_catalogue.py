"""Accuracy of the default engine against the exact reference on a seeded catalogue of scenes.

Run: ``python benchmarks/accuracy_catalogue.py [--quick] [--seed N] [-o TABLE.md]``
(full: about 5 minutes on 2 cores; ``--quick``: about 2). Prints the measurements of
BENCHMARKS.md's "Accuracy" section (its heading, the measured line and the table).

Catalogue (seeded): random scenes (radius 5-50 um, density 1000-20000 kg/m^3, K 3e9-2e11 Pa,
f0 0 or 10-1000 N/m, C_A, C_H, friction over the ranges the tests use, rolling moments
analytical / lambda / none), each with

* general impacts: 0.02-5 m/s (log-uniform), -80..80 deg, |omega0| up to 1e5 rad/s (some
  normal, some without spin), rebounding or captured;
* a band near the capture speed (adhesive scenes): for a few (angle, spin) pairs the reference's
  capture speed ``v_c`` by bisection, then impacts at ``v_c (1 + delta)``, delta from -0.3 to
  +0.3 (down to 3e-3 above it);
* a slow spinning impact just above capture (0.0232 m/s, -24 deg, 74,925 rad/s) on a Table 1
  scene whose f0 (154.89 N/m) puts its capture speed at 0.0230 m/s, with a band around it.

Errors: ``|d cor_n|``, ``|d vt_out|/speed``,
``|d omega_out| r/speed``. Rebounds are split into "rebound" (far from capture) and "near
capture" (``v < 1.5 v_c`` for the impact's angle and spin, where ``v_c`` is known), captures
compare ``vt_out`` and ``omega_out`` at the moment the capture is declared. The reference is
``reference.simulate_impact`` (switched, event-located, DOP853) at rtol 1e-13, atol 1e-17,
checked against its default rtol 1e-12 (their largest difference is reported: at the default
tolerances one captured spinning impact came out 2.5e-6 off in the spin). float64 runs in
this process, float32 in a subprocess (JAX's x64 switch is global).

``--setting KEY=VALUE`` runs the engine with solver settings changed (``slip_width``,
``ring_width``, ``rtol``, ``atol``, ``method``), for finding where the error comes from.
"""

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SLOW_SPIN_POINT = (0.0232, -24.0, 74925.0)
# N/m: the Table 1 scene's capture speed at -24 deg, 74,925 rad/s is then 0.0230 m/s
SLOW_SPIN_F0 = 154.89
KEYS = ("cor_n", "vt", "omega")
NEAR = 1.5  # rebounds below NEAR * v_c count as "near capture"


def random_scene(rng, index):
    """One scene as a dict of parameters (SI) and switches."""
    moments = ("analytical", "lambda", "none")[index % 3]
    adhesive = index % 4 != 3  # every fourth scene has no adhesion
    return dict(
        radius=float(10 ** rng.uniform(math.log10(5e-6), math.log10(50e-6))),
        density=float(10 ** rng.uniform(3.0, math.log10(2e4))),
        K=float(10 ** rng.uniform(9.5, 11.3)),
        f0=float(10 ** rng.uniform(1.0, 3.0)) if adhesive else 0.0,
        C_A=float(10 ** rng.uniform(-1.5, 0.3)),
        C_H=float(10 ** rng.uniform(-1.5, -0.3)),
        friction=float(rng.uniform(0.05, 0.8)),
        lam=float(10 ** rng.uniform(-10.0, -8.0)) if moments == "lambda" else 0.0,
        moments=moments,
    )


def slow_spin_scene():
    from jaximpact import reference as ref

    p = ref.table1_params(f0=SLOW_SPIN_F0)
    return dict(
        radius=p.radius,
        density=p.density,
        K=p.K,
        f0=p.f0,
        C_A=p.C_A,
        C_H=p.C_H,
        friction=p.friction,
        lam=0.0,
        moments="analytical",
    )


def ref_params(s):
    from jaximpact import reference as ref

    return ref.Params(
        radius=s["radius"],
        density=s["density"],
        K=s["K"],
        f0=s["f0"],
        C_A=s["C_A"],
        C_H=s["C_H"],
        friction=s["friction"],
        lam=s["lam"],
        adhesion=s["f0"] > 0,
        rolling_moments=s["moments"],
    )


def engine_scene(s, settings=None):
    import jaximpact as ji

    return ji.Scene(
        particle=ji.Particle(radius=s["radius"], density=s["density"]),
        contact=ji.Contact(
            K=s["K"], f0=s["f0"], C_A=s["C_A"], C_H=s["C_H"], friction=s["friction"]
        ),
        model=ji.Model(adhesion=s["f0"] > 0, rolling_moments=s["moments"], lambda_=s["lam"]),
        solver=ji.Solver(**(settings or {})),
    )


def capture_speed(params, angle, omega0):
    """The reference's capture speed for this angle and spin, or None outside 1e-4..20 m/s."""
    from jaximpact import reference as ref

    try:
        return ref.capture_speed(params, angle, omega0, lo=1e-4, hi=20.0, rel_tol=1e-6)
    except (ValueError, RuntimeError):
        return None


def build(seed, quick):
    """Scenes and impacts: a list of (scene dict, impacts dict of arrays)."""
    rng = np.random.default_rng(seed)
    n_scenes, n_general, n_pairs = (6, 12, 2) if quick else (15, 24, 3)
    deltas = np.array([-0.3, -0.03, 0.003, 0.01, 0.03, 0.1, 0.3])
    out = []
    scenes = [random_scene(rng, i) for i in range(n_scenes)] + [slow_spin_scene()]
    for i, s in enumerate(scenes):
        params = ref_params(s)
        last = i == len(scenes) - 1
        n = 0 if last else n_general
        speed = 10 ** rng.uniform(math.log10(0.02), math.log10(5.0), n)
        angle = rng.uniform(-80.0, 80.0, n)
        omega0 = rng.choice([-1.0, 1.0], n) * 10 ** rng.uniform(2.0, 5.0, n)
        if n:
            angle[0], omega0[:2] = 0.0, 0.0
        v_c = np.full(n, np.nan)
        pairs = [(SLOW_SPIN_POINT[1], SLOW_SPIN_POINT[2])] if last else []
        if s["f0"] > 0 and not last:
            pairs += [(0.0, 0.0)] + [
                (float(rng.uniform(-80, 80)), float(rng.choice([-1, 1]) * 10 ** rng.uniform(3, 5)))
                for _ in range(n_pairs - 1)
            ]
        extra = [[], [], [], []]
        for a, w in pairs:
            vc = capture_speed(params, a, w)
            if vc is None:
                continue
            vs = vc * (1 + deltas)
            if last:
                vs = np.append(vs, SLOW_SPIN_POINT[0])
            extra[0] += list(vs)
            extra[1] += [a] * len(vs)
            extra[2] += [w] * len(vs)
            extra[3] += [vc] * len(vs)
        speed = np.concatenate([speed, extra[0]])
        angle = np.concatenate([angle, extra[1]])
        omega0 = np.concatenate([omega0, extra[2]])
        v_c = np.concatenate([v_c, extra[3]])
        out.append((s, dict(speed=speed, angle=angle, omega0=omega0, v_c=v_c)))
    return out


def reference(s, imp):
    """The exact reference at two tolerances: the tighter one is the yardstick, their
    difference (``ref_spread``, scaled like the errors) says how well it is known."""
    from jaximpact import reference as ref

    params = ref_params(s)
    v_n = imp["speed"] * np.cos(np.radians(imp["angle"]))
    out = {}
    for tag, tol in (("", dict(rtol=1e-13, atol=1e-17)), ("loose_", dict(rtol=1e-12))):
        rows = [
            ref.simulate_impact(params, float(v), float(a), float(w), **tol)
            for v, a, w in zip(imp["speed"], imp["angle"], imp["omega0"], strict=True)
        ]
        out[tag + "status"] = np.array([r.status for r in rows])
        out[tag + "cor_n"] = np.array([r.vn_out for r in rows]) / v_n
        out[tag + "vt_out"] = np.array([r.vt_out for r in rows])
        out[tag + "omega_out"] = np.array([r.omega_out for r in rows])
    return out


def engine(catalogue, settings=None):
    """Default engine on every scene (this process's precision): per scene a dict of arrays."""
    import jax

    import jaximpact as ji

    # Every scene's batch padded to one length (copies of its last impact; a lane's result
    # does not depend on its batch), so that scenes with the same switches share one program.
    size = max(len(imp["speed"]) for _, imp in catalogue)
    out = []
    for s, imp in catalogue:
        n = len(imp["speed"])
        pad = lambda x, n=n: np.concatenate([x, np.full(size - n, x[-1])])  # noqa: E731
        t = time.perf_counter()
        res = ji.simulate(
            engine_scene(s, settings), pad(imp["speed"]), pad(imp["angle"]), pad(imp["omega0"])
        )
        jax.block_until_ready(res.cor_n)
        out.append(
            dict(
                status=np.array([ji.Status.NAMES[int(c)] for c in np.asarray(res.status)[:n]]),
                cor_n=np.asarray(res.cor_n, float)[:n],
                vt_out=np.asarray(res.vt_out, float)[:n],
                omega_out=np.asarray(res.omega_out, float)[:n],
                steps=np.asarray(res.steps, float)[:n],
                seconds=np.full(n, time.perf_counter() - t),
            )
        )
    return out


def errors(s, imp, exact, got):
    """Per-impact scaled errors (NaN where not comparable) and regime labels."""
    speed = imp["speed"]
    same = got["status"] == exact["status"]
    rebound = same & (exact["status"] == "rebound")
    captured = same & (exact["status"] == "captured")
    near = rebound & (speed < NEAR * np.nan_to_num(imp["v_c"], nan=0.0))
    regime = np.where(captured, "captured", np.where(near, "near capture", "rebound"))
    regime = np.where(same, regime, "mismatch")
    err = {
        "cor_n": np.where(rebound, np.abs(got["cor_n"] - exact["cor_n"]), np.nan),
        "vt": np.where(same, np.abs(got["vt_out"] - exact["vt_out"]) / speed, np.nan),
        "omega": np.where(
            same, np.abs(got["omega_out"] - exact["omega_out"]) * s["radius"] / speed, np.nan
        ),
    }
    return err, regime


def summarize(catalogue, exacts, gots):
    """Worst error per regime and output, with where it occurs; status mismatches."""
    worst, mismatches, count = {}, [], {}
    for k, ((s, imp), exact, got) in enumerate(zip(catalogue, exacts, gots, strict=True)):
        err, regime = errors(s, imp, exact, got)
        for i, reg in enumerate(regime):
            if reg == "mismatch":
                vc = imp["v_c"][i]
                mismatches.append(
                    dict(
                        scene=k,
                        speed=float(imp["speed"][i]),
                        angle=float(imp["angle"][i]),
                        omega0=float(imp["omega0"][i]),
                        delta=float(imp["speed"][i] / vc - 1) if np.isfinite(vc) else None,
                        exact=str(exact["status"][i]),
                        got=str(got["status"][i]),
                    )
                )
                continue
            count[reg] = count.get(reg, 0) + 1
            for key in KEYS:
                e = err[key][i]
                if np.isfinite(e) and e > worst.get((reg, key), {"error": -1.0})["error"]:
                    vc = imp["v_c"][i]
                    worst[(reg, key)] = dict(
                        error=float(e),
                        scene=k,
                        moments=s["moments"],
                        adhesive=s["f0"] > 0,
                        speed=float(imp["speed"][i]),
                        angle=float(imp["angle"][i]),
                        omega0=float(imp["omega0"][i]),
                        delta=float(imp["speed"][i] / vc - 1) if np.isfinite(vc) else None,
                    )
    return worst, mismatches, count


def where(w):
    text = f"{w['speed']:.4g} m/s, {w['angle']:.0f} deg, {w['omega0']:.3g} rad/s"
    if w["delta"] is not None:
        text += f" (v_c {'+' if w['delta'] >= 0 else ''}{100 * w['delta']:.2g} %)"
    return text + f"; scene {w['scene']} ({w['moments']}{', adhesive' if w['adhesive'] else ''})"


def report(results, counts):
    """Markdown table: per precision and regime, the worst error of each output and where."""
    lines = [
        "| precision | regime | impacts | cor_n | vt/speed | omega r/speed | worst case at |",
        "|---|---|---|---|---|---|---|",
    ]
    for prec, (worst, _, count) in results.items():
        for reg in ("rebound", "near capture", "captured"):
            vals = [worst.get((reg, k)) for k in KEYS]
            if not any(vals):
                continue
            big = max((v for v in vals if v), key=lambda v: v["error"])
            cells = [f"{v['error']:.1e}" if v else "–" for v in vals]
            cells = " | ".join(cells)
            lines.append(f"| {prec} | {reg} | {count.get(reg, 0)} | {cells} | {where(big)} |")
    for prec, (_, mism, _) in results.items():
        for m in mism:
            d = f"v_c {100 * m['delta']:+.2g} %" if m["delta"] is not None else "far from v_c"
            lines.append(
                f"\n{prec}: status {m['got']} instead of {m['exact']} at {m['speed']:.4g} m/s, "
                f"{m['angle']:.0f} deg, {m['omega0']:.3g} rad/s ({d}), scene {m['scene']}"
            )
    return "\n".join(lines)


def float32_in_subprocess(catalogue, settings):
    """The same engine runs in float32 in a fresh process (x64 off); results via npz."""
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "in.json"
        dst = Path(tmp) / "out.npz"
        src.write_text(
            json.dumps(
                dict(
                    catalogue=[
                        (s, {k: v.tolist() for k, v in imp.items()}) for s, imp in catalogue
                    ],
                    settings=settings,
                )
            )
        )
        subprocess.run(
            [sys.executable, __file__, "--float32-worker", str(src), str(dst)], check=True
        )
        data = np.load(dst)
        return [
            {k: data[f"{i}_{k}"] for k in ("status", "cor_n", "vt_out", "omega_out", "steps")}
            for i in range(len(catalogue))
        ]


def float32_worker(src, dst):
    spec = json.loads(Path(src).read_text())
    catalogue = [(s, {k: np.array(v) for k, v in imp.items()}) for s, imp in spec["catalogue"]]
    gots = engine(catalogue, spec["settings"])
    np.savez(dst, **{f"{i}_{k}": v for i, g in enumerate(gots) for k, v in g.items()})


def parse_settings(items):
    settings = {}
    for item in items or []:
        key, value = item.split("=", 1)
        settings[key] = value if key == "method" else float(value)
    return settings


def run(quick=False, seed=2013, settings=None, float32=True, cache=None):
    """Returns (markdown, results by precision, catalogue, exacts, engine outputs)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    t0 = time.perf_counter()
    if cache and Path(cache).exists():
        import pickle

        catalogue, exacts = pickle.loads(Path(cache).read_bytes())
    else:
        catalogue = build(seed, quick)
        exacts = [reference(s, imp) for s, imp in catalogue]
        if cache:
            import pickle

            Path(cache).write_bytes(pickle.dumps((catalogue, exacts)))
    t_ref = time.perf_counter() - t0
    results, gots = {}, {}
    gots["float64"] = engine(catalogue, settings)
    if float32:
        gots["float32"] = float32_in_subprocess(catalogue, settings)
    for prec, g in gots.items():
        results[prec] = summarize(catalogue, exacts, g)
    loose = [
        {k: e["loose_" + k] for k in ("status", "cor_n", "vt_out", "omega_out")} for e in exacts
    ]
    spread, _, _ = summarize(catalogue, exacts, loose)
    spread = max((w for w in spread.values()), key=lambda w: w["error"])
    n = sum(len(imp["speed"]) for _, imp in catalogue)
    steps = {p: float(np.median(np.concatenate([x["steps"] for x in g]))) for p, g in gots.items()}
    text = report(results, None)
    head = (
        f"{len(catalogue)} scenes, {n} impacts (seed {seed}{', quick' if quick else ''}); "
        f"reference and catalogue {t_ref:.0f} s, total {time.perf_counter() - t0:.0f} s; "
        "median steps "
        + ", ".join(f"{p} {v:.0f}" for p, v in steps.items())
        + f". Reference at rtol 1e-12 against 1e-13: largest difference {spread['error']:.1e}"
        f" at {where(spread)}."
    )
    return head + "\n\n" + text, results, catalogue, exacts, gots


def main():
    if len(sys.argv) == 4 and sys.argv[1] == "--float32-worker":
        os.environ.pop("JAX_ENABLE_X64", None)
        float32_worker(sys.argv[2], sys.argv[3])
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer scenes and impacts")
    ap.add_argument("--seed", type=int, default=2013)
    ap.add_argument("--setting", action="append", help="solver setting KEY=VALUE (repeatable)")
    ap.add_argument("--no-float32", action="store_true")
    ap.add_argument("--cache", help="pickle the catalogue and reference here and reuse it")
    ap.add_argument("-o", "--output", help="also write the Markdown table here")
    args = ap.parse_args()
    text, results, *_ = run(
        args.quick, args.seed, parse_settings(args.setting), not args.no_float32, args.cache
    )
    if not args.setting:
        from _common import default_settings, machine, measured_line, write_result

        command = "python benchmarks/accuracy_catalogue.py" + (" --quick" if args.quick else "")
        command += f" --seed {args.seed}" if args.seed != 2013 else ""
        command += " --no-float32" if args.no_float32 else ""
        info = machine()
        text = (
            "## Accuracy\n\n"
            + measured_line(info, command, settings=default_settings())
            + "\n"
            + text
        )
    print(text)
    if args.output:
        Path(args.output).write_text(text + "\n")
    if not args.setting:  # the published settings: a result file
        name = "accuracy_catalogue" + ("_quick" if args.quick else "")
        write_result(name, {"summary": results, "markdown": text}, info, command)


if __name__ == "__main__":
    main()

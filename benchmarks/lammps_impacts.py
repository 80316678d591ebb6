"""LAMMPS as an external reference for normal sphere-wall impacts (issue 54): LAMMPS's
rebound against closed forms, then against ``jaximpact.simulate`` per normal law and damping.

Run: ``python benchmarks/lammps_impacts.py [--quick] [--cases N] [--divisors 200,400,800]``
(needs ``lmp``, LAMMPS 29 Sep 2021 with GRANULAR). Duration: about 5 minutes on 2 cores
(``--quick``: about 1 minute).

Each impact is one LAMMPS process (``jaximpact._io.lammps.impact_script``: ``units si``, one
sphere, ``fix nve/sphere``, the wall at z = 0, no gravity; JKR on a frozen sphere of 100
radii instead, since this version's JKR wall gives NaN on leaving) run at the time steps
``t_c / N`` for each divisor ``N`` (``t_c``: Hertz's contact time at the impact speed), at most
2 processes at a time. The rebound velocity is extrapolated to ``dt -> 0`` (Richardson from
the three steps, with the order they show; the finest step's value where the differences do
not shrink). A sphere still in contact after ``40 t_c`` is captured.

Part 1, closed forms (LAMMPS alone): undamped Hertz and DMT ``e = 1``; undamped JKR (pair)
``e = sqrt(1 - 2 W' / (m v^2))`` with ``W'`` the JKR loop from zero overlap to LAMMPS's
pull-off point (the force minimum); small damping ``eta = c n^q`` (velocity, mass_velocity:
``q = 0``; viscoelastic ``q = 1/2``): ``1 - e = 2 c n_max^(1+q) J_q / (m v)`` with ``J_q =
(2/5) B(2 (q+1) / 5, 3/2)`` (so ``v^(-1/5)`` for ``q = 0``, ``v^(1/5)`` for ``q = 1/2``); Tsuji's
restitution independent of the speed. Part 2: per normal law (hertz, dmt, jkr) and damping
(none, velocity, mass_velocity, viscoelastic, tsuji), impacts at speeds 0.05-10 m/s and radii
5-50 um against ``jaximpact.simulate(scene, speed, 0.0, 0.0)``; a damped combination is
skipped, with a message, while jaximpact's ``Model`` has no ``damping`` field.
"""

import argparse
import concurrent.futures
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from jaximpact._io import lammps  # noqa: E402

DENSITY = 2500.0
K = 1.0e11  # Pa: E* = 75 GPa (glass-like)
W = 0.5  # J/m^2: JKR sticks below about 0.03-0.2 m/s over 50-5 um
PARTNER = 100.0  # JKR's frozen partner, in sphere radii
TIME_LIMIT = 40.0  # in Hertz contact times
DAMPINGS = ("none", *lammps.DAMPINGS)
Q = {"velocity": 0.0, "mass_velocity": 0.0, "viscoelastic": 0.5, "tsuji": 0.25}


def run_scripts(scripts):
    """Run LAMMPS input scripts in one process (joined by ``clear``); each script's final
    ``JAXIMPACT`` line as ``{"step", "z", "vz"}``, or None where LAMMPS stopped with an error
    (the scripts after it are run again one by one)."""
    out = subprocess.run(
        ["lmp", "-nocite", "-log", "none"],
        input="clear\n".join(scripts),
        text=True,
        capture_output=True,
    )
    rows = []
    for line in out.stdout.splitlines():
        if line.startswith("JAXIMPACT "):
            rows.append({k: float(v) for k, v in (p.split("=") for p in line.split()[1:])})
    if len(rows) < len(scripts):
        rows.append(None)  # the one that failed
        if len(scripts) > len(rows):
            rows += [run_scripts([s])[0] for s in scripts[len(rows) :]]
    return rows


def richardson(values):
    """``(extrapolated, order)`` from values at steps ``h, h/2, h/4``; the finest value and
    NaN where the differences do not shrink (order <= 0.5)."""
    e1, e2, e3 = values
    d1, d2 = e1 - e2, e2 - e3
    if not (np.isfinite(d1) and np.isfinite(d2)) or d2 == 0 or d1 / d2 <= 2**0.5:
        return e3, float("nan")
    p = math.log2(d1 / d2)
    return e3 - d2 / (2**p - 1), p


def exit_force(law, reff, mass, v_out):
    """The contact force (N, toward the wall negative) just before the contact ends, leaving
    at ``v_out``: DMT's ``-2 pi w R`` or JKR's pull-off force ``-1.5 pi w R`` (pair: it ends at
    the force minimum), plus the damping at the exit's contact radius (0 for Hertz and DMT)."""
    force, a = 0.0, 0.0
    if law.normal == "dmt":
        force = -2.0 * math.pi * law.w * reff
    elif law.normal == "jkr" and law.w > 0:
        force = -1.5 * math.pi * law.w * reff
        a = (9.0 * math.pi * law.w * reff**2 / (8.0 * 0.75 * law.K)) ** (1.0 / 3.0)
    eta = {
        "none": 0.0,
        "velocity": law.eta_n,
        "mass_velocity": law.eta_n * mass,
        "viscoelastic": law.eta_n * a * mass,
        "tsuji": lammps.tsuji_alpha(law.eta_n) * math.sqrt(mass * law.K * a),
    }[law.damping]
    return force - eta * v_out


def _rebound(row, law, radius, density, speed, dt, partner):
    """``cor`` of a rebound, its exit corrected to second order: the Verlet kick of the last
    step in contact applies the exit force ``F`` over a whole step, the contact ends a
    fraction ``s`` of it later (linear in the last two positions): ``v += F dt (s - 1/2) / m``.
    The entry needs none: the sphere starts 1.5 steps of flight above contact."""
    mass = density * 4.0 / 3.0 * math.pi * radius**3
    reff = radius if partner is None else radius * partner / (radius + partner)
    if partner is None:
        leave = radius + max(lammps.wall_pulloff_distance(law, radius), 0.0)
    else:
        leave = radius - min(lammps.pair_pulloff_overlap(law, reff), 0.0)
    vz = row["vz"]
    s = (leave - (row["z"] - vz * dt)) / (vz * dt)
    return (vz + exit_force(law, reff, mass, vz) * dt * (s - 0.5) / mass) / speed


def lammps_impact(law, radius, density, speed, divisors=(200, 400, 800)):
    """One normal impact in LAMMPS at ``t_c / N`` for each divisor ``N``: a dict with
    ``cor`` (per step, NaN unless a rebound), ``status`` (per step: rebound, captured,
    failed), ``cor_x`` (extrapolated), ``order``, ``conv`` (|difference of the two finest|)."""
    tc = lammps.contact_time_estimate(radius, density, law.K, speed)
    partner = PARTNER * radius if law.normal == "jkr" else None
    scripts, limits = [], []
    for n in divisors:
        limits.append(int(TIME_LIMIT * n) + 2)
        scripts.append(
            lammps.impact_script(
                law, speed, radius=radius, density=density, dt=tc / n, max_steps=limits[-1],
                partner_radius=partner,
            )
        )  # fmt: skip
    cors, statuses = [], []
    for row, limit, n in zip(run_scripts(scripts), limits, divisors, strict=True):
        if row is None or not np.isfinite(row["vz"]):
            cors.append(float("nan"))
            statuses.append("failed")
        elif row["step"] < limit:
            cors.append(_rebound(row, law, radius, density, speed, tc / n, partner))
            statuses.append("rebound")
        else:
            cors.append(float("nan"))
            statuses.append("captured" if row["z"] < 1.01 * radius else "failed")
    cor_x, order = richardson(cors) if len(cors) == 3 else (cors[-1], float("nan"))
    return {
        "cor": cors,
        "status": statuses,
        "cor_x": cor_x,
        "order": order,
        "conv": abs(cors[-1] - cors[-2]),
    }


def map_parallel(fn, jobs, workers=2):
    """``[fn(*job) for job in jobs]``, at most ``workers`` LAMMPS processes at a time."""
    with concurrent.futures.ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(lambda job: fn(*job), jobs))


def n_max(radius, density, K, speed):
    """Hertz's largest overlap ``(5 m v^2 / (4 K sqrt(R)))^(2/5)``."""
    m = density * 4.0 / 3.0 * math.pi * radius**3
    return (5.0 * m * speed**2 / (4.0 * K * math.sqrt(radius))) ** 0.4


def small_damping_loss(damping, eta_n, radius, density, K, speed):
    """``1 - e`` to first order in the damping, ``2 c n_max^(1+q) J_q / (m v)`` for the
    damping ``eta = c n^q`` integrated along the undamped Hertz impact (see the docstring)."""
    m = density * 4.0 / 3.0 * math.pi * radius**3
    c = {
        "velocity": eta_n,
        "mass_velocity": eta_n * m,
        "viscoelastic": eta_n * m * math.sqrt(radius),
        "tsuji": lammps.tsuji_alpha(eta_n) * math.sqrt(m * K * math.sqrt(radius)),
    }[damping]
    q = Q[damping]
    J = 0.4 * math.gamma(0.4 * (q + 1)) * math.gamma(1.5) / math.gamma(0.4 * (q + 1) + 1.5)
    return 2.0 * c * n_max(radius, density, K, speed) ** (1 + q) * J / (m * speed)


def eta_for_loss(damping, loss, radius, density, K, speed):
    """The coefficient whose first-order ``1 - e`` at ``speed`` is ``loss``."""
    return loss / small_damping_loss(damping, 1.0, radius, density, K, speed)


def jkr_pair_cor(radius, density, K, w, speed):
    """Undamped JKR restitution of LAMMPS's pair rule: snap in at zero overlap, release at
    the force minimum (load-controlled pull-off, ``x^(3/2) = 3 sqrt(2 pi) / 4`` in ``a = x
    (w R^2 / E)^(1/3)``): the loop ``W' = (w^5 R^4 / E^2)^(1/3) (H(x0) - H(xp))`` with ``H(x)
    = (4/3) sqrt(2 pi) x^(7/2) - pi x^2 - (8/15) x^5`` (docs/physics.md, "JKR closed forms")."""
    E = 0.75 * K
    m = density * 4.0 / 3.0 * math.pi * radius**3

    def H(x):
        return 4.0 / 3.0 * math.sqrt(2 * math.pi) * x**3.5 - math.pi * x * x - 8.0 / 15.0 * x**5

    x0 = (2 * math.pi) ** (1 / 3)
    xp = (3 * math.sqrt(2 * math.pi) / 4) ** (2 / 3)
    loop = (w**5 * radius**4 / E**2) ** (1 / 3) * (H(x0) - H(xp))
    ratio = 2 * loop / (m * speed**2)
    return math.sqrt(1 - ratio) if ratio < 1 else float("nan")


def _hertz_cases(quick):
    speeds = (0.05, 1.0, 10.0)
    radii = (1e-5,) if quick else (5e-6, 5e-5)
    return [(r, v) for r in radii for v in speeds]


def closed_forms(divisors, quick=False):
    """Part 1: LAMMPS against closed forms. Rows ``{"check", "case", "lammps", "closed",
    "diff", "conv", "order"}`` (``diff``: LAMMPS extrapolated less closed form) and the fitted
    speed exponents of ``1 - e`` for the small dampings."""
    jobs, meta = [], []
    for r, v in _hertz_cases(quick):
        jobs.append((lammps.ContactLaw("hertz", K), r, DENSITY, v, divisors))
        meta.append(("undamped Hertz: e = 1", f"r {r * 1e6:g} um, v {v:g}", 1.0))
        jobs.append((lammps.ContactLaw("dmt", K, W), r, DENSITY, v, divisors))
        meta.append(("undamped DMT: e = 1", f"r {r * 1e6:g} um, v {v:g}", 1.0))
    reff = 1e-5 * PARTNER / (PARTNER + 1)
    for v in (0.1, 1.0) if quick else (0.07, 0.1, 0.3, 1.0, 3.0):
        jobs.append((lammps.ContactLaw("jkr", K, W), 1e-5, DENSITY, v, divisors))
        closed = jkr_pair_cor(reff, DENSITY * (1e-5 / reff) ** 3, K, W, v)
        meta.append(("undamped JKR pair: e = sqrt(1 - 2W'/(m v^2))", f"r 10 um, v {v:g}", closed))
    speeds = (0.05, 1.0, 10.0) if quick else (0.05, 0.2, 1.0, 3.0, 10.0)
    for d in ("velocity", "mass_velocity", "viscoelastic"):
        eta = eta_for_loss(d, 1e-3, 1e-5, DENSITY, K, 1.0)
        for v in speeds:
            jobs.append((lammps.ContactLaw("hertz", K, 0.0, d, eta), 1e-5, DENSITY, v, divisors))
            loss = small_damping_loss(d, eta, 1e-5, DENSITY, K, v)
            meta.append((f"small {d} damping: 1 - e", f"eta_n {eta:.4g}, v {v:g}", loss))
    for e in (0.5, 0.9) if quick else (0.3, 0.5, 0.7, 0.9):
        for v in speeds:
            jobs.append(
                (lammps.ContactLaw("hertz", K, 0.0, "tsuji", e), 1e-5, DENSITY, v, divisors)
            )
            meta.append((f"tsuji e = {e:g}: e independent of v", f"v {v:g}", float("nan")))
    results = map_parallel(lammps_impact, jobs)
    rows = []
    for (check, case, closed), res in zip(meta, results, strict=True):
        value = 1.0 - res["cor_x"] if check.startswith("small") else res["cor_x"]
        rows.append({"check": check, "case": case, "lammps": value, "closed": closed,
                     "diff": value - closed, "conv": res["conv"], "order": res["order"],
                     "status": res["status"][-1]})  # fmt: skip
    for check in {r["check"] for r in rows if r["check"].startswith("tsuji")}:
        group = [r for r in rows if r["check"] == check]
        mean = float(np.mean([r["lammps"] for r in group]))
        for r in group:
            r["closed"], r["diff"] = mean, r["lammps"] - mean
    return rows, _exponents(rows)


def _exponents(rows):
    """The fitted exponent ``p`` of ``1 - e ~ v^p`` per small damping (LAMMPS)."""
    out = {}
    for d in ("velocity", "mass_velocity", "viscoelastic"):
        group = [r for r in rows if r["check"] == f"small {d} damping: 1 - e"]
        v = [float(r["case"].split("v ")[1]) for r in group]
        out[d] = float(np.polyfit(np.log(v), np.log([r["lammps"] for r in group]), 1)[0])
    return out


def cases(normal, damping, n):
    """``n`` impacts of one combination: ``(radius, speed, eta_n)``, speeds log-spaced over
    0.05-10 m/s, radii over 5-50 um in another order, damping strengths varied (first-order
    ``1 - e`` of 0.05-0.3 at 1 m/s; tsuji's e 0.5-0.9)."""
    speeds = np.geomspace(0.05, 10.0, n)
    radii = np.geomspace(5e-6, 5e-5, n)[(np.arange(n) * 7) % n]
    out = []
    for k in range(n):
        eta = 0.0
        if damping == "tsuji":
            eta = (0.5, 0.7, 0.9)[k % 3]
        elif damping != "none":
            loss = (0.05, 0.15, 0.3)[k % 3]
            eta = eta_for_loss(damping, loss, radii[k], DENSITY, K, 1.0)
        out.append((float(radii[k]), float(speeds[k]), eta))
    return out


def jaximpact_rows(normal, damping, impacts):
    """``jaximpact.simulate`` of the impacts (JKR: the sphere of the frozen partner's
    reduced radius with the same mass), or a message why not."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jaximpact as ji

    has_damping = "damping" in getattr(ji.Model, "__dataclass_fields__", {})
    if damping != "none" and not has_damping:
        return None, "jaximpact's Model has no damping field yet: skipped"
    r = np.array([c[0] for c in impacts])
    v = np.array([c[1] for c in impacts])
    scale = PARTNER / (PARTNER + 1.0) if normal == "jkr" else 1.0
    model = {"normal": "brach_dunn" if normal == "hertz" else normal, "rotation": False,
             "adhesion": normal != "hertz", "rolling_moments": "none"}  # fmt: skip
    contact = {"K": K, "f0": 0.0, "C_A": 0.0, "C_H": 0.0, "friction": 0.0,
               "w": W if normal != "hertz" else 0.0}  # fmt: skip
    if normal == "jkr" and "jkr_release" in getattr(ji.Model, "__dataclass_fields__", {}):
        model["jkr_release"] = "pull_off"  # LAMMPS's JKR contact ends at the force minimum
    if has_damping:
        model["damping"] = "hertzian" if damping == "none" else damping
        if damping != "none":
            contact["eta_n"] = np.array([c[2] for c in impacts])
    scene = ji.table1_scene().replace(
        particle={"radius": r * scale, "density": DENSITY / scale**3},
        contact=contact,
        model=model,
    )
    res = ji.simulate(scene, v, angle_deg=0.0, omega0=0.0)
    return {"cor_n": np.asarray(res.cor_n, float), "status": list(res.status_names)}, None


def compare(normal, damping, n, divisors):
    """Part 2 for one combination: LAMMPS against jaximpact over ``cases``."""
    impacts = cases(normal, damping, n)
    jobs = [(lammps.ContactLaw(normal, K, W if normal != "hertz" else 0.0, damping, eta),
             r, DENSITY, v, divisors) for r, v, eta in impacts]  # fmt: skip
    lmp_rows = map_parallel(lammps_impact, jobs)
    jax_rows, skipped = jaximpact_rows(normal, damping, impacts)
    out = {"combination": f"{normal} / {damping}", "cases": n, "skipped": skipped,
           "max_conv": float(np.nanmax([x["conv"] for x in lmp_rows] + [0.0])),
           "orders": [x["order"] for x in lmp_rows],
           "lammps": [dict(x, radius=c[0], speed=c[1], eta_n=c[2])
                      for x, c in zip(lmp_rows, impacts, strict=True)]}  # fmt: skip
    out["captured"] = sum(x["status"][-1] == "captured" for x in lmp_rows)
    out["failed"] = sum(x["status"][-1] == "failed" for x in lmp_rows)
    out["dt_status_changes"] = sum(len(set(x["status"])) > 1 for x in lmp_rows)
    if jax_rows is None:
        return out
    diffs, disagree = [], 0
    for k, x in enumerate(lmp_rows):
        js = jax_rows["status"][k]
        if js != x["status"][-1]:
            disagree += 1
        elif js == "rebound":
            diffs.append(abs(jax_rows["cor_n"][k] - x["cor_x"]))
    out.update(max_diff=float(max(diffs, default=float("nan"))), status_disagreements=disagree,
               jaximpact=jax_rows)  # fmt: skip
    return out


def _fmt(x, spec=".1e"):
    return "–" if x is None or not np.isfinite(x) else format(x, spec)


def _print_closed(rows, exponents):
    from _common import table

    print("### LAMMPS against closed forms\n")
    body = [(r["check"], r["case"], r["status"], _fmt(r["lammps"], ".10g"),
             _fmt(r["closed"], ".10g"), _fmt(r["diff"]), _fmt(r["conv"]),
             _fmt(r["order"], ".2f")) for r in rows]  # fmt: skip
    print(table(["check", "case", "status", "LAMMPS (dt -> 0)", "closed form", "difference",
                 "dt convergence", "order"], body))  # fmt: skip
    print("\nFitted exponent p of 1 - e ~ v^p (small damping; closed form -0.2, -0.2, +0.2): "
          + ", ".join(f"{d} {p:.4f}" for d, p in exponents.items()) + "\n")  # fmt: skip


def _print_comparison(results):
    from _common import table

    print("### LAMMPS against jaximpact.simulate\n")
    body = []
    for o in results:
        orders = [p for p in o["orders"] if np.isfinite(p)]
        body.append((o["combination"], o["cases"], o["captured"], o["failed"],
                     o["skipped"] or _fmt(o.get("max_diff")), _fmt(o["max_conv"]),
                     f"{np.median(orders):.2f} ({len(orders)})" if orders else "–",
                     o.get("status_disagreements", "–"), o["dt_status_changes"]))  # fmt: skip
    print(table(["normal / damping", "cases", "LAMMPS captured", "LAMMPS failed",
                 "max abs(d cor_n)", "LAMMPS dt convergence", "median order (cases)",
                 "status disagreements", "status changes over dt"], body))  # fmt: skip


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="a few cases of a few combinations")
    ap.add_argument("--cases", type=int, default=20, help="impacts per combination")
    ap.add_argument("--divisors", default="200,400,800", help="t_c / N for each N (three)")
    args = ap.parse_args(argv)
    if shutil.which("lmp") is None:
        print("lmp (LAMMPS) not found: nothing measured", file=sys.stderr)
        return 1
    from _common import machine, write_result

    info = machine()
    divisors = tuple(int(x) for x in args.divisors.split(","))
    rows, exponents = closed_forms(divisors, quick=args.quick)
    _print_closed(rows, exponents)
    combos = [(n, d) for n in lammps.LAWS for d in DAMPINGS]
    if args.quick:
        combos = [("hertz", "none"), ("dmt", "velocity"), ("jkr", "tsuji")]
    n = 4 if args.quick else args.cases
    results = [compare(normal, damping, n, divisors) for normal, damping in combos]
    _print_comparison(results)
    command = "python benchmarks/lammps_impacts.py" + (" --quick" if args.quick else "")
    write_result("lammps_impacts", {"divisors": divisors, "closed_forms": rows,
                 "exponents": exponents, "comparison": results}, info, command)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

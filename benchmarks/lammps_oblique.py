"""LAMMPS as an external reference for oblique, spinning sphere-wall impacts with its
tangential models (issue 54): linear_history and mindlin against closed forms, then against
``jaximpact.simulate`` per normal law, damping and tangential model.

Run: ``python benchmarks/lammps_oblique.py [--quick] [--cases N] [--divisors 200,400,800]``
(needs ``lmp``, LAMMPS 29 Sep 2021 with GRANULAR). Duration: about 10 minutes on 2 cores
(``--quick``: about 1 minute).

Each impact is one LAMMPS script (``jaximpact._io.lammps.oblique_script``: ``units si``, one
sphere, ``fix nve/sphere``, the wall at z = 0, no gravity; JKR on a frozen sphere of 1e4
radii, since this version's JKR wall gives NaN on leaving) run at the time steps ``t_c / N``
for each divisor ``N`` (``t_c``: Hertz's contact time at the normal speed), at most 2
processes at a time. The script stops at the last step in contact and prints that step's
state, force and torque; the exit state is that step's ``v + s dt F / m``, ``omega + s dt
T / I`` with ``s`` the fraction of the next step to the contact's end (linear in the
positions). ``vn_out/speed``, ``vt_out/speed`` and ``omega_out r/speed`` are each
extrapolated to ``dt -> 0`` (Richardson from the three steps, with the order they show; the
finest step's value where the differences do not shrink). A sphere still in contact after
``40 t_c`` is captured.

Part 1, closed forms (LAMMPS alone, undamped, ``e = 1``): sliding throughout (Hertz, both
models, any stiff enough spring) ``vt_out = vt - mu (1 + e) v_n``, ``omega_out = omega_0 +
(5/2) mu (1 + e) v_n / r``; sliding throughout on DMT: ``dvt = mu int Fncrit dt / m`` by
quadrature along the DMT impact, with the documented load ``|F_ne + 2 F_pulloff|`` (the Hertz
force plus ``4 pi coh R``) and with ``|F_ne|``, what this build does (fix_wall_gran.cpp and
pair_granular.cpp compute ``F_pulloff = 4 pi coh R`` from a ``coh`` that only the JKR branch
sets: uninitialised for DMT, in practice 0); sticking (``mu = 1e6``, linear_history: the slip
``s`` oscillates as ``s0 cos(w_t t)``, ``w_t = sqrt(7 k_t / (2 m))``) ``vt_out = vt - (2/7) s0
(1 - cos(w_t t_c))``, ``omega_out = omega_0 + (5/7) s0 (1 - cos(w_t t_c)) / r``. Part 2: per
normal law (hertz, dmt, jkr pair) x damping (none, velocity, tsuji) x tangential model
(lammps_linear_history, lammps_mindlin), impacts at speeds 0.1-5 m/s, angles 10-75 deg, spins
-1e5..1e5 rad/s, radii 5-50 um, mu 0.1-0.5, k_t 1e5-1e6 N/m or G* 3e9-3e10 Pa, against
``jaximpact.simulate(scene, speed, angle_deg, omega0)``; skipped, with a message, while
``jaximpact._model.scene.TANGENTIAL_MODELS`` lacks the model or simulate refuses it.
"""

import argparse
import math
import shutil
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from lammps_impacts import eta_for_loss, map_parallel, n_max, richardson, run_scripts  # noqa: E402

from jaximpact._io import lammps  # noqa: E402

DENSITY = 2500.0
K = 1.0e11  # Pa: E* = 75 GPa (glass-like)
W = 0.5  # J/m^2 (coh = 0.25)
PARTNER = 1.0e4  # JKR's frozen partner, in sphere radii (its curvature: < 2e-6 rad a contact)
TIME_LIMIT = 40.0  # in Hertz contact times
DAMPINGS = ("none", "velocity", "tsuji")
TANGENTIALS = ("lammps_linear_history", "lammps_mindlin")
OUTPUTS = ("vn", "vt", "w")  # vn_out/speed, vt_out/speed, omega_out r/speed


def exit_state(row, law, radius, dt, partner):
    """``(vn_out, vt_out, omega_out)`` (m/s, m/s, rad/s) at the contact's end from the last
    step in contact: ``v + s dt F / m``, ``omega + s dt T / I``, the velocity split along the
    normal at the exit (the wall's z; the partner's radius through the sphere)."""
    m = row["mass"]
    inertia = 0.4 * m * radius**2
    pos = np.array([row["x"], row["z"]])
    vel = np.array([row["vx"], row["vz"]])
    force = np.array([row["fx"], row["fz"]])
    half = vel + 0.5 * dt * force / m
    nxt = pos + dt * half
    if partner is None:
        centre = None
        leave = radius + max(lammps.wall_pulloff_distance(law, radius), 0.0)
        d0, d1 = pos[1], nxt[1]
    else:
        centre = np.array([0.0, -partner])
        reff = radius * partner / (radius + partner)
        leave = partner + radius - min(lammps.pair_pulloff_overlap(law, reff), 0.0)
        d0, d1 = np.linalg.norm(pos - centre), np.linalg.norm(nxt - centre)
    s = float(np.clip((leave - d0) / (d1 - d0), 0.0, 1.0)) if d1 != d0 else 0.0
    v = vel + s * dt * force / m
    w = row["wy"] + s * dt * row["ty"] / inertia
    if centre is None:
        n = np.array([0.0, 1.0])
    else:
        n = pos + s * dt * half - centre
        n = n / np.linalg.norm(n)
    t = np.array([n[1], -n[0]])
    return float(v @ n), float(v @ t), float(w)


def lammps_oblique(law, radius, density, speed, angle, omega0, divisors=(200, 400, 800)):
    """One oblique impact in LAMMPS at ``t_c / N`` for each divisor ``N``: a dict with, per
    output ``k`` of ``vn, vt, w`` (``vn_out/speed``, ``vt_out/speed``, ``omega_out r/speed``),
    ``k`` (per step), ``k_x`` (extrapolated), ``k_order``, ``k_conv`` (|difference of the two
    finest|), and ``status`` (per step: rebound, captured, failed)."""
    vn_in = speed * math.cos(math.radians(angle))
    tc = lammps.contact_time_estimate(radius, density, law.K, vn_in)
    partner = PARTNER * radius if law.normal == "jkr" else None
    scripts, limits = [], []
    for n in divisors:
        limits.append(int(TIME_LIMIT * n) + 2)
        scripts.append(
            lammps.oblique_script(
                law, speed, angle, omega0, radius=radius, density=density, dt=tc / n,
                max_steps=limits[-1], partner_radius=partner,
            )
        )  # fmt: skip
    out = {k: [] for k in OUTPUTS}
    out["status"] = []
    for row, limit, n in zip(run_scripts(scripts), limits, divisors, strict=True):
        values = (float("nan"),) * 3
        if row is None or not all(np.isfinite(v) for v in row.values()):
            status = "failed"
        elif row["step"] < limit:
            status = "rebound"
            vn, vt, w = exit_state(row, law, radius, tc / n, partner)
            values = (vn / speed, vt / speed, w * radius / speed)
        else:
            near = row["z"] < 1.01 * radius if partner is None else row["z"] > -0.01 * radius
            status = "captured" if near else "failed"
        out["status"].append(status)
        for k, v in zip(OUTPUTS, values, strict=True):
            out[k].append(v)
    for k in OUTPUTS:
        x, p = richardson(out[k]) if len(divisors) == 3 else (out[k][-1], float("nan"))
        out[f"{k}_x"], out[f"{k}_order"] = x, p
        out[f"{k}_conv"] = abs(out[k][-1] - out[k][-2])
    return out


# --- closed forms -------------------------------------------------------------------------


def hertz_contact_time(radius, density, K_, vn):
    """The undamped Hertz contact time ``2 (n_max / v) int_0^1 du / sqrt(1 - u^(5/2))``."""
    from scipy.integrate import quad

    # u = 1 - x^2 removes the endpoint singularity
    integral = quad(lambda x: 2 * x / math.sqrt(1 - (1 - x * x) ** 2.5), 0, 1, epsabs=1e-14)[0]
    return 2.0 * n_max(radius, density, K_, vn) / vn * integral


def dmt_impulse(radius, density, K_, w, vn, load):
    """``int load(n) dt`` over an undamped DMT impact (``2 int_0^n_max load / ndot dn``, ``m
    ndot^2 / 2 = m v^2 / 2 - (2/5) K sqrt(R) n^(5/2) + 2 pi w R n``), and the mass."""
    from scipy.integrate import quad
    from scipy.optimize import brentq

    m = density * 4.0 / 3.0 * math.pi * radius**3
    a, b = 0.4 * K_ * math.sqrt(radius), 2.0 * math.pi * w * radius

    def energy(n):
        return 0.5 * m * vn**2 - a * n**2.5 + b * n

    big = 1e3 * n_max(radius, density, K_, vn)
    top = brentq(energy, 1e-6 * big, big, xtol=1e-30, rtol=1e-15)
    slope = 2.5 * a * top**1.5 - b  # -dE/dn at the turning point

    def f(x):  # n = top (1 - x^2) removes the turning point's 1/sqrt singularity
        n = top * (1 - x * x)
        e = energy(n)
        if x < 1e-6 or e <= 0:
            return 2 * top / math.sqrt(2 * slope * top / m) * load(n)
        return 2 * top * x / math.sqrt(2 * e / m) * load(n)

    return 2.0 * quad(f, 0, 1, epsabs=0, epsrel=1e-12, limit=200)[0], m


def sliding_closed(vn, vt, omega0, mu, radius, extra=0.0):
    """Sliding throughout, the slip positive: ``vt - mu (2 v_n + extra)``, ``omega_0 + (5/2)
    mu (2 v_n + extra) / r`` (``extra``: DMT's ``4 pi w R t_c / m``), normalised later."""
    dv = mu * (2.0 * vn + extra)
    return vt - dv, omega0 + 2.5 * dv / radius


def sticking_closed(vn, vt, omega0, k_t, radius, density):
    """Sticking throughout (linear_history): ``vt - (2/7) s0 (1 - cos(w_t t_c))``, ``omega0 +
    (5/7) s0 (1 - cos(w_t t_c)) / r``, ``w_t = sqrt(7 k_t / (2 m))``, ``s0 = vt - r omega0``."""
    m = density * 4.0 / 3.0 * math.pi * radius**3
    tc = hertz_contact_time(radius, density, K, vn)
    s0 = vt - radius * omega0
    c = 1.0 - math.cos(math.sqrt(3.5 * k_t / m) * tc)
    return vt - s0 * c / 3.5, omega0 + 2.5 * s0 * c / (3.5 * radius)


def closed_form_cases(quick=False):
    """``(label, law, radius, speed, angle, omega0, (vn, vt, w) closed, normalised)``."""
    out = []
    slide = [(1e-5, 1.0, 70.0, 0.0, 0.1), (2e-5, 3.0, 60.0, -2e4, 0.1), (5e-6, 0.3, 75.0, 1e4, 0.2)]
    if quick:
        slide = slide[:1]
    for r, v, ang, w0, mu in slide:
        vn, vt = v * math.cos(math.radians(ang)), v * math.sin(math.radians(ang))
        vt_o, w_o = sliding_closed(vn, vt, w0, mu, r)
        closed = (vn / v, vt_o / v, w_o * r / v)
        case = f"r {r * 1e6:g} um, v {v:g}, {ang:g} deg, omega0 {w0:g}, mu {mu:g}"
        for kt in (1e6, 1e7) if not quick else (1e6,):
            law = lammps.ContactLaw("hertz", K, tangential="linear_history", k_t=kt, mu=mu)
            out.append(
                (f"sliding, Hertz, linear_history k_t {kt:g}", law, r, v, ang, w0, closed, case)
            )
        for g in (3e9, 3e10) if not quick else (3e10,):
            law = lammps.ContactLaw("hertz", K, tangential="mindlin", k_t=8 * g, mu=mu)
            out.append((f"sliding, Hertz, mindlin G* {g:g}", law, r, v, ang, w0, closed, case))
    dmt_slide = [(1e-5, 1.0, 70.0, 0.0, 0.1), (2e-5, 3.0, 60.0, -2e4, 0.1)]
    for r, v, ang, w0, mu in dmt_slide[:1] if quick else dmt_slide:
        vn, vt = v * math.cos(math.radians(ang)), v * math.sin(math.radians(ang))
        pulloff = 2.0 * math.pi * W * r  # 4 pi coh R

        def hertz(n, r=r):
            return K * math.sqrt(r) * n**1.5

        case = f"r {r * 1e6:g} um, v {v:g}, {ang:g} deg, omega0 {w0:g}, mu {mu:g}"
        law = lammps.ContactLaw("dmt", K, W, tangential="linear_history", k_t=1e7, mu=mu)
        for label, load in (
            ("documented load |F_ne + 2 F_pulloff|", lambda n, h=hertz, p=pulloff: h(n) + p),
            ("as built: load |F_ne|", lambda n, h=hertz, p=pulloff: abs(h(n) - p)),
        ):
            impulse, m = dmt_impulse(r, DENSITY, K, W, vn, load)
            vt_o, w_o = sliding_closed(vn, vt, w0, mu, r, impulse / m - 2.0 * vn)
            out.append((f"sliding, DMT, linear_history k_t 1e7, {label}", law, r, v, ang, w0,
                        (vn / v, vt_o / v, w_o * r / v), case))  # fmt: skip
    stick = [(1e-5, 1.0, 30.0, 0.0, 1e5), (1e-5, 1.0, 30.0, 0.0, 1e6), (2e-5, 2.0, 45.0, 3e4, 3e6)]
    if quick:
        stick = stick[1:2]
    for r, v, ang, w0, kt in stick:
        vn, vt = v * math.cos(math.radians(ang)), v * math.sin(math.radians(ang))
        vt_o, w_o = sticking_closed(vn, vt, w0, kt, r, DENSITY)
        law = lammps.ContactLaw("hertz", K, tangential="linear_history", k_t=kt, mu=1e6)
        case = f"r {r * 1e6:g} um, v {v:g}, {ang:g} deg, omega0 {w0:g}, k_t {kt:g}"
        out.append(("sticking (mu 1e6), Hertz, linear_history", law, r, v, ang, w0,
                    (vn / v, vt_o / v, w_o * r / v), case))  # fmt: skip
    return out


def closed_forms(divisors, quick=False):
    """Part 1: rows ``{"check", "case", "status", per output: lammps, closed, diff, conv,
    order}`` (LAMMPS extrapolated less closed form, all relative to the speed)."""
    cases_ = closed_form_cases(quick)
    jobs = [(law, r, DENSITY, v, ang, w0, divisors) for _, law, r, v, ang, w0, _, _ in cases_]
    results = map_parallel(lammps_oblique, jobs)
    rows = []
    for (check, _, _, _, _, _, closed, case), res in zip(cases_, results, strict=True):
        row = {"check": check, "case": case, "status": res["status"][-1]}
        for k, c in zip(OUTPUTS, closed, strict=True):
            row[k] = {"lammps": res[f"{k}_x"], "closed": c, "diff": res[f"{k}_x"] - c,
                      "conv": res[f"{k}_conv"], "order": res[f"{k}_order"],
                      "per_dt": res[k]}  # fmt: skip
        rows.append(row)
    return rows


# --- against jaximpact --------------------------------------------------------------------


def cases(normal, damping, tangential, n):
    """``n`` impacts of one combination: dicts of radius, speed, angle, omega0, mu, k
    (``k_t`` N/m or ``G*`` Pa), eta_n; each input spread over its range in its own order."""
    idx = np.arange(n)
    speeds = np.geomspace(0.1, 5.0, n)
    radii = np.geomspace(5e-6, 5e-5, n)[(idx * 7) % n]
    angles = np.linspace(10.0, 75.0, n)[(idx * 3 + 1) % n]
    spins = np.linspace(-1e5, 1e5, n)[(idx * 11 + 5) % n]
    mus = np.linspace(0.1, 0.5, n)[(idx * 13 + 2) % n]
    ks = (
        np.geomspace(1e5, 1e6, n)
        if tangential == "lammps_linear_history"
        else np.geomspace(3e9, 3e10, n)
    )
    ks = ks[(idx * 9 + 3) % n]
    out = []
    for k in range(n):
        eta = 0.0
        if damping == "tsuji":
            eta = (0.5, 0.7, 0.9)[k % 3]
        elif damping != "none":
            eta = eta_for_loss(damping, (0.05, 0.15, 0.3)[k % 3], radii[k], DENSITY, K, 1.0)
        out.append({"radius": float(radii[k]), "speed": float(speeds[k]),
                    "angle": float(angles[k]), "omega0": float(spins[k]), "mu": float(mus[k]),
                    "k": float(ks[k]), "eta_n": eta})  # fmt: skip
    return out


def contact_law(normal, damping, tangential, c):
    name = lammps.SCENE_TANGENTIALS[tangential]
    k_t = c["k"] if name == "linear_history" else 8.0 * c["k"]
    return lammps.ContactLaw(normal, K, W if normal != "hertz" else 0.0, damping, c["eta_n"], name,
                             k_t, c["mu"])  # fmt: skip


def jaximpact_rows(normal, damping, tangential, impacts):
    """``jaximpact.simulate`` of the impacts (JKR: the sphere of the frozen partner's reduced
    radius ``R``, the same mass, the spin scaled by ``r / R`` so that ``R omega`` is LAMMPS's
    ``r omega``), or a message why not."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jaximpact as ji
    from jaximpact._model import scene as scene_module

    if tangential not in getattr(scene_module, "TANGENTIAL_MODELS", ()):
        return None, f"jaximpact's TANGENTIAL_MODELS lacks {tangential!r}: skipped"
    col = {k: np.array([c[k] for c in impacts]) for k in impacts[0]}
    scale = PARTNER / (PARTNER + 1.0) if normal == "jkr" else 1.0
    model = {"normal": "brach_dunn" if normal == "hertz" else normal, "rotation": True,
             "adhesion": normal != "hertz", "rolling_moments": "none", "tangential": tangential,
             "damping": "hertzian" if damping == "none" else damping}  # fmt: skip
    if normal == "jkr":
        model["jkr_release"] = "pull_off"  # LAMMPS's JKR contact ends at the force minimum
    contact = {"K": K, "f0": 0.0, "C_A": 0.0, "C_H": 0.0, "friction": col["mu"],
               "w": W if normal != "hertz" else 0.0}  # fmt: skip
    contact["k_t" if tangential == "lammps_linear_history" else "G_star"] = col["k"]
    if damping != "none":
        contact["eta_n"] = col["eta_n"]
    try:
        scene = ji.table1_scene().replace(
            particle={"radius": col["radius"] * scale, "density": DENSITY / scale**3},
            contact=contact,
            model=model,
        )
        res = ji.simulate(scene, col["speed"], angle_deg=col["angle"], omega0=col["omega0"] / scale)
    except Exception as err:  # the engine may not take the model yet
        return None, f"jaximpact.simulate refused it ({type(err).__name__}: {err}): skipped"
    v = col["speed"]
    return {
        "vn": np.asarray(res.vn_out, float) / v,
        "vt": np.asarray(res.vt_out, float) / v,
        "w": np.asarray(res.omega_out, float) * col["radius"] * scale / v,
        "status": list(res.status_names),
    }, None


def compare(normal, damping, tangential, n, divisors):
    """Part 2 for one combination: LAMMPS against jaximpact over ``cases``."""
    impacts = cases(normal, damping, tangential, n)
    jobs = [(contact_law(normal, damping, tangential, c), c["radius"], DENSITY, c["speed"],
             c["angle"], c["omega0"], divisors) for c in impacts]  # fmt: skip
    lmp_rows = map_parallel(lammps_oblique, jobs)
    jax_rows, skipped = jaximpact_rows(normal, damping, tangential, impacts)
    out = {"combination": f"{normal} / {damping} / {tangential}", "cases": n, "skipped": skipped,
           "lammps": [dict(x, **c) for x, c in zip(lmp_rows, impacts, strict=True)]}  # fmt: skip
    for k in OUTPUTS:
        out[f"max_conv_{k}"] = float(np.nanmax([x[f"{k}_conv"] for x in lmp_rows] + [0.0]))
        out[f"orders_{k}"] = [x[f"{k}_order"] for x in lmp_rows]
    out["captured"] = sum(x["status"][-1] == "captured" for x in lmp_rows)
    out["failed"] = sum(x["status"][-1] == "failed" for x in lmp_rows)
    out["dt_status_changes"] = sum(len(set(x["status"])) > 1 for x in lmp_rows)
    if jax_rows is None:
        return out
    disagree = 0
    diffs = {k: [] for k in OUTPUTS}
    for i, x in enumerate(lmp_rows):
        js = jax_rows["status"][i]
        if js != x["status"][-1]:
            disagree += 1
        elif js == "rebound":
            for k in OUTPUTS:
                diffs[k].append(abs(jax_rows[k][i] - x[f"{k}_x"]))
    for k in OUTPUTS:
        out[f"max_diff_{k}"] = float(max(diffs[k], default=float("nan")))
    out["status_disagreements"] = disagree
    out["jaximpact"] = {k: [float(v) for v in jax_rows[k]] for k in OUTPUTS}
    out["jaximpact"]["status"] = jax_rows["status"]
    return out


def _fmt(x, spec=".1e"):
    return "–" if x is None or not np.isfinite(x) else format(x, spec)


def _median_order(orders):
    orders = [p for p in orders if np.isfinite(p)]
    return f"{np.median(orders):.2f} ({len(orders)})" if orders else "–"


def _print_closed(rows):
    from _common import table

    print("### LAMMPS against closed forms (outputs / speed: vn_out, vt_out, omega_out r)\n")
    body = []
    for r in rows:
        for k in ("vt", "w", "vn"):
            o = r[k]
            body.append((r["check"], r["case"], k, r["status"], _fmt(o["lammps"], ".10g"),
                         _fmt(o["closed"], ".10g"), _fmt(o["diff"]), _fmt(o["conv"]),
                         _fmt(o["order"], ".2f")))  # fmt: skip
    print(table(["check", "case", "output", "status", "LAMMPS (dt -> 0)", "closed form",
                 "difference", "dt convergence", "order"], body))  # fmt: skip
    print()


def _print_comparison(results):
    from _common import table

    print("### LAMMPS against jaximpact.simulate (differences relative to the speed)\n")
    body = []
    for o in results:
        body.append((o["combination"], o["cases"], o["captured"], o["failed"],
                     o["skipped"] or " / ".join(_fmt(o.get(f"max_diff_{k}")) for k in OUTPUTS),
                     " / ".join(_fmt(o[f"max_conv_{k}"]) for k in OUTPUTS),
                     " / ".join(_median_order(o[f"orders_{k}"]) for k in OUTPUTS),
                     o.get("status_disagreements", "–"), o["dt_status_changes"]))  # fmt: skip
    print(table(["normal / damping / tangential", "cases", "LAMMPS captured", "LAMMPS failed",
                 "max abs diff vn / vt / omega r", "LAMMPS dt convergence vn / vt / omega r",
                 "median order (cases) vn / vt / omega r", "status disagreements",
                 "status changes over dt"], body))  # fmt: skip


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="a few cases of a few combinations")
    ap.add_argument("--cases", type=int, default=20, help="impacts per combination")
    ap.add_argument("--divisors", default="200,400,800", help="t_c / N for each N (three)")
    ap.add_argument("--skip-closed", action="store_true", help="part 2 only")
    args = ap.parse_args(argv)
    if shutil.which("lmp") is None:
        print("lmp (LAMMPS) not found: nothing measured", file=sys.stderr)
        return 1
    from _common import machine, write_result

    info = machine()
    divisors = tuple(int(x) for x in args.divisors.split(","))
    rows = [] if args.skip_closed else closed_forms(divisors, quick=args.quick)
    if rows:
        _print_closed(rows)
    combos = [(n, d, t) for n in lammps.LAWS for d in DAMPINGS for t in TANGENTIALS]
    if args.quick:
        combos = [("hertz", "none", TANGENTIALS[0]), ("dmt", "velocity", TANGENTIALS[1]),
                  ("jkr", "tsuji", TANGENTIALS[0])]  # fmt: skip
    n = 4 if args.quick else args.cases
    results = [compare(normal, d, t, n, divisors) for normal, d, t in combos]
    _print_comparison(results)
    command = "python benchmarks/lammps_oblique.py" + (" --quick" if args.quick else "")
    write_result("lammps_oblique", {"divisors": divisors, "closed_forms": rows,
                 "comparison": results}, info, command)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

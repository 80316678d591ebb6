"""The rolling kink of the wall law in kink-aligned coordinates: a feasibility measurement.

Run: ``python benchmarks/wall_law_kink.py [--points N] [--per-side N ...]`` (about 5 minutes
on 2 cores). Prints the figures of BENCHMARKS.md's "Wall law: kink-aligned angles".

At one radius (the Table 1 scene, spin 0) the default table needs about 570 angle nodes and
240 speed nodes, most of them where the onset of rolling puts a kink into the tangential
results. The idea measured here: tabulate the angle ``theta*(x)`` at which the sphere stops
reaching rolling before it leaves the wall (per speed-ratio node ``x``), and the results
against a coordinate in which that angle is a fixed node (``u = theta / theta*`` below it,
``1 + (theta - theta*) / (85 - theta*)`` above), so that no interval straddles the kink.

1. Where the sphere rolls: ``roll_time`` finite (the slip fell to zero during the contact) on
   the grid of 64 speed ratios x 171 angles; per speed ratio the number of changes along the
   angle.
2. ``theta*(x)`` by bisection (40 steps) for the speed ratios with exactly one change.
3. Aligned grids with N nodes per side, interpolated bilinearly in ``(asinh sqrt(x - 1), u)``
   with ``theta*`` interpolated linearly in the same speed coordinate, against ``simulate``
   at random points (angle 0.5-85 deg, speed coordinate uniform) inside the band of speed
   ratios with one change; the default table (``wall_law(scene)``) at the same points.

The capture speed at an angle is the base table's (the first pass, ``g`` interpolated in
angle, as the C function does): the points' speeds are ``x v_c``, so both tables are checked
on the speed ratio they interpolate in.
"""

from __future__ import annotations

import argparse
import json
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from _common import machine, results_dir  # noqa: E402

import jaximpact as ji  # noqa: E402
from jaximpact.wall_law import wall_law  # noqa: E402
from jaximpact.wall_law._table import DEFAULT_SPEED_RATIOS  # noqa: E402

TOP_ANGLE = 85.0
OUTPUTS = ("cor_n", "cor_t", "spin_ratio")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=4000)
    ap.add_argument("--per-side", type=int, nargs="+", default=[8, 16, 32])
    ap.add_argument(
        "--radii",
        type=float,
        nargs="*",
        default=[10e-6, 12e-6, 15e-6, 20e-6, 50e-6, 100e-6],
        help="radii (m) at which to map where the sphere rolls (step 1 only)",
    )
    args = ap.parse_args()
    ji.use_all_cpu_cores()
    t0 = time.perf_counter()
    scene = ji.table1_scene()
    radius = float(scene.particle.radius)
    base = wall_law(scene, refine=False, speed_tol=False)
    angles, g = base.angle_deg, base.reference_table[0, :, 0]

    def capture(theta):
        return np.interp(theta, angles, g) ** -4 / np.cos(np.radians(theta))

    def sim(x, theta):
        x, theta = np.broadcast_arrays(np.asarray(x, float), np.asarray(theta, float))
        v = x * capture(theta)
        r = ji.simulate(scene, v.ravel(), theta.ravel(), 0.0)
        get = lambda k: np.asarray(getattr(r, k)).reshape(x.shape)  # noqa: E731
        sin = np.sin(np.radians(theta))
        with np.errstate(invalid="ignore", divide="ignore"):
            return {
                "cor_n": get("cor_n"),
                "vt_ratio": get("vt_out") / v,
                "cor_t": np.where(sin > 0, get("vt_out") / (v * sin), np.nan),
                "spin_ratio": get("omega_out") * radius / v,
                "rolled": np.isfinite(get("roll_time")),
                "rebound": get("status") == 0,
            }

    coord = lambda x: np.arcsinh(np.sqrt(np.maximum(x - 1.0, 0.0)))  # noqa: E731
    xs = np.where(DEFAULT_SPEED_RATIOS == 1.0, 1.0 + 1e-6, DEFAULT_SPEED_RATIOS)
    sx = coord(xs)

    # 1. where the sphere rolls
    grid = np.linspace(0.0, TOP_ANGLE, 171)
    rolled = sim(xs[:, None], grid[None, :])["rolled"]
    changes = np.abs(np.diff(rolled.astype(int), axis=1)).sum(axis=1)
    one = (changes == 1) & rolled[:, 0] & ~rolled[:, -1]
    band = np.flatnonzero(one)
    lo_j, hi_j = int(band.min()), int(band.max())
    assert np.all(one[lo_j : hi_j + 1]), "the band of one change is not contiguous"
    print(
        f"rolling map: changes along the angle per speed ratio {np.bincount(changes).tolist()}; "
        f"one change (rolls below, slides above) for x = {xs[lo_j]:.3f} .. {xs[hi_j]:.2f}"
    )
    for j in range(len(xs)):
        if not one[j] and changes[j]:
            where = grid[np.flatnonzero(np.diff(rolled[j].astype(int))) + 1]
            print(f"  x = {xs[j]:.3f}: rolled at 0 deg {rolled[j, 0]}, changes at {where}")

    # 2. theta*(x) on the band
    xb = xs[lo_j : hi_j + 1]
    k = np.argmax(~rolled[lo_j : hi_j + 1], axis=1)
    lo, hi = grid[k - 1], grid[k]
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        r = sim(xb, mid)["rolled"]
        lo, hi = np.where(r, mid, lo), np.where(r, hi, mid)
    tstar = 0.5 * (lo + hi)
    print(
        f"theta*: {tstar[0]:.2f} deg at x = {xb[0]:.3f} to {tstar[-1]:.2f} deg at x = {xb[-1]:.2f}"
    )

    # 3. random points in the band, against simulate
    rng = np.random.default_rng(2026)
    sq = rng.uniform(sx[lo_j], sx[hi_j], args.points)
    xq, tq = 1.0 + np.sinh(sq) ** 2, rng.uniform(0.5, TOP_ANGLE, args.points)
    truth = sim(xq, tq)
    ok = truth["rebound"]
    j = np.clip(np.searchsorted(sx[lo_j : hi_j + 1], sq) - 1, 0, len(xb) - 2)
    w = (sq - sx[lo_j:][j]) / (sx[lo_j:][j + 1] - sx[lo_j:][j])
    tstar_q = (1 - w) * tstar[j] + w * tstar[j + 1]

    def u_of(theta, ts):
        return np.where(theta < ts, theta / ts, 1.0 + (theta - ts) / (TOP_ANGLE - ts))

    def theta_of(u, ts):
        return np.where(u < 1.0, u * ts, ts + (u - 1.0) * (TOP_ANGLE - ts))

    def errors(values):
        out = {}
        for name in OUTPUTS:
            e = np.abs(values[name] - truth[name])
            e = e[ok & np.isfinite(truth[name]) & (tq > (5.0 if name == "cor_t" else 0.0))]
            out[name] = {"max": float(e.max()), "p99": float(np.percentile(e, 99))}
        return out

    rows = []
    for n in args.per_side:
        us = np.concatenate([np.linspace(0.0, 1.0, n + 1), 1.0 + np.linspace(0.0, 1.0, n + 1)[1:]])
        cells = sim(xb[:, None], theta_of(us[None, :], tstar[:, None]))
        uq = u_of(tq, tstar_q)
        i = np.clip(np.searchsorted(us, uq) - 1, 0, len(us) - 2)
        z = (uq - us[i]) / (us[i + 1] - us[i])
        values = {}
        for name in ("cor_n", "vt_ratio", "spin_ratio"):
            c = cells[name]
            values[name] = (1 - w) * ((1 - z) * c[j, i] + z * c[j, i + 1]) + w * (
                (1 - z) * c[j + 1, i] + z * c[j + 1, i + 1]
            )
        with np.errstate(invalid="ignore", divide="ignore"):
            values["cor_t"] = values["vt_ratio"] / np.sin(np.radians(tq))
        rows.append({"table": f"aligned, {n} per side", "angles": len(us), "speeds": len(xb),
                     "errors": errors(values)})  # fmt: skip

    t1 = time.perf_counter()
    default = wall_law(scene)
    build = time.perf_counter() - t1
    speed = xq * capture(tq)
    theta = np.radians(tq)
    code, vn_out, vt_out, om_out = default.evaluate(
        radius, speed * np.cos(theta), speed * np.sin(theta)
    )
    ok &= code == 0
    with np.errstate(invalid="ignore", divide="ignore"):
        values = {
            "cor_n": vn_out / (speed * np.cos(theta)),
            "cor_t": vt_out / (speed * np.sin(theta)),
            "spin_ratio": om_out * radius / speed,
        }
    rows.append({"table": f"default (`wall_law(scene)`, {build:.0f} s)",
                 "angles": len(default.angle_deg), "speeds": len(default.speed_ratio),
                 "errors": errors(values)})  # fmt: skip

    survey = [_rolling_survey(scene, r) for r in args.radii]
    info = machine()
    print(
        f"\n{info}; {int(ok.sum())} rebounding points in the band; {time.perf_counter() - t0:.0f} s"
    )
    print(
        "\n| table | angles | speed ratios | "
        + " | ".join(f"{o} max (p99)" for o in OUTPUTS)
        + " |"
    )
    print("|---|---|---|" + "---|" * len(OUTPUTS))
    for r in rows:
        e = r["errors"]
        cols = " | ".join(f"{e[o]['max']:.1e} ({e[o]['p99']:.1e})" for o in OUTPUTS)
        print(f"| {r['table']} | {r['angles']} | {r['speeds']} | {cols} |")
    out = results_dir() / "wall_law_kink.json"
    print(
        "\n| radius um | rebounding cells | speed ratios with 0 / 1 / 2+ changes | theta* (deg) "
        "| 0 changes, rolls at every angle |"
    )
    print("|---|---|---|---|---|")
    for r in survey:
        counted = f"{r['zero']} / {r['one']} / {r['more']}"
        rolls = r["zero_rolling_at_every_angle"]
        print(
            f"| {r['radius'] * 1e6:g} | {r['rebounding']} | {counted} "
            f"| {r['theta_star']} | {rolls} |"
        )
    out.write_text(json.dumps({"machine": info, "theta_star": [xb.tolist(), tstar.tolist()],
                               "changes": changes.tolist(), "rows": rows, "survey": survey},
                              indent=1))  # fmt: skip


def _rolling_survey(scene, radius: float) -> dict:
    """Where the sphere of ``radius`` rolls on the first-pass grid (rebounding cells only):
    per speed ratio, the number of changes along the angle, and the range of the angle of the
    change where there is one (to the grid's 0.5 deg)."""
    scene = scene.replace(particle={"radius": radius})
    law = wall_law(scene, refine=False, speed_tol=False)
    speed = law.speed[0, :, 0, :].T  # (speed ratio, angle)
    ok = law.status[0, :, 0, :].T == 0
    angle = np.broadcast_to(law.angle_deg[None, :], speed.shape)
    res = ji.simulate(scene, np.where(ok, speed, 1.0).ravel(), angle.ravel(), 0.0)
    rolled = np.isfinite(np.asarray(res.roll_time)).reshape(speed.shape)
    counts, where, rolls_only = [], [], 0
    for j in range(speed.shape[0]):
        r = rolled[j][ok[j]]
        if r.size < 2:
            continue
        flips = np.flatnonzero(np.diff(r.astype(int)))
        counts.append(len(flips))
        rolls_only += int(len(flips) == 0 and r.all())
        if len(flips) == 1:
            where.append(float(law.angle_deg[ok[j]][flips[0] + 1]))
    counts = np.asarray(counts)
    span = f"{min(where):.1f} - {max(where):.1f}" if where else "-"
    return {
        "radius": radius, "rebounding": int(ok.sum()), "zero": int(np.sum(counts == 0)),
        "one": int(np.sum(counts == 1)), "more": int(np.sum(counts > 1)), "theta_star": span,
        "zero_rolling_at_every_angle": rolls_only,
    }  # fmt: skip


if __name__ == "__main__":
    main()

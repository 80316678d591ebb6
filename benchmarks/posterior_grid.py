"""The posterior samplers against exact grid posteriors of the same likelihood and priors.

Synthetic Table 1 data (truth C_A = 0.75 s/m, C_H = 0.25 s/m, f0 = 300 N/m; cor_n with sigma
0.003, observed captures as ``captured``), one noise draw per case. For each case: the exact
posterior by `fitting._bayesian.grid_reference.grid_reference` at two resolutions (their
difference is the grid's own error), then `fitting.sample_posterior` with the default sampler
(SMC) and with the independence sampler (the default before), each from a cold start of its
program in this process. Errors are in units of the grid's sd: mean and 5/50/95 % quantiles
(worst over parameters), and the sd ratio.

Cases (the kinds of issue 34):
- ``gaussian``: 25 impacts 0.3-5 m/s at 0-60 degrees, C_A, C_H, f0 (grid in the fit's
  whitened axes);
- ``near_capture``: 8 normal impacts from 1.05 to 4 times the capture speed, C_A and f0;
- ``captured``: 11 normal impacts from half the capture speed to 5 m/s (the slowest captured,
  observed as ``captured``), C_A and f0;
- ``ridge``: 8 normal impacts 0.2-8 m/s, C_A and f0 (a curved C_A-f0 ridge);
- ``weak``: 6 normal impacts 0.6-8 m/s, C_A and f0 (C_A weakly determined, mass toward 0);
- ``bound``: the weak design with C_A's prior log-uniform on 0.3-3 s/m;
- ``weak3``, ``bound3``: the same two with C_A, C_H and f0 (with C_H known the weak design
  determines C_A and f0 well; with all three C_A is weakly determined, with mass toward 0).
Grids: ``gaussian``, ``near_capture`` and ``captured`` (narrow, thin, nearly straight ridges:
an axis-aligned grid over the prior box aliases them) in the fit's whitened axes; the others
along ``ln p`` over the whole prior box (robust to curvature and to mass far from the fit),
and for ``weak3`` and ``bound3`` a grid that follows the curved C_A-f0 ridge
(:func:`sliced_grid`: 40 or 60 slices along ln C_A, 30^2 or 40^2 cells in each; an axis-
aligned 48^3 grid disagreed with a 36^3 one by 0.64 sd there). C_H is held at its true value
where it is not fitted.
The grid's self-error (its two resolutions against each other) says whether it can judge.

Run: ``python benchmarks/posterior_grid.py [--cases a,b] [--json out.json]`` (about 3 minutes
a case on 2 cores).
"""

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import jaximpact

jaximpact.use_all_cpu_cores()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import fitting  # noqa: E402
from fitting._bayesian.grid_reference import grid_reference  # noqa: E402

TRUTH = {"C_A": 0.75, "C_H": 0.25, "f0": 300.0}
SIGMA = 0.003
INITIAL = {"C_A": 1.5, "C_H": 0.15, "f0": 500.0}


def capture_speed(scene):
    """Normal capture speed of the truth scene (bisection on the status)."""
    lo, hi = 1e-3, 5.0
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        captured = int(jaximpact.simulate(scene, mid, 0.0, 0.0).status) == 1
        lo, hi = (mid, hi) if captured else (lo, mid)
    return hi


def compare(summary, grid, names):
    """Errors of ``summary`` against ``grid`` in units of the grid's sd: ``{name: {mean, q05,
    median, q95, sd_ratio}, "worst": ...}``."""
    out, worst = {}, 0.0
    for n in names:
        sd = grid[n]["sd"]
        e = {k: abs(summary[n][k] - grid[n][k]) / sd for k in ("mean", "q05", "median", "q95")}
        worst = max(worst, *e.values())
        out[n] = {**e, "sd_ratio": summary[n]["sd"] / sd}
    out["worst"] = worst
    return out


def cases(v_c):
    three, two = ("C_A", "C_H", "f0"), ("C_A", "f0")
    normal = lambda n: np.zeros(n)  # noqa: E731
    return {
        "gaussian": (np.geomspace(0.3, 5.0, 25), np.tile([0.0, 0.0, 30.0, 45.0, 60.0], 5),
                     three, None, dict(axes="whitened", points=(30, 40))),
        "near_capture": (np.geomspace(1.05 * v_c, 4 * v_c, 8), normal(8), two, None,
                         dict(axes="whitened", points=(60, 90))),
        "captured": (np.geomspace(0.5 * v_c, 5.0, 11), normal(11), two, None,
                     dict(axes="whitened", points=(60, 90))),
        "ridge": (np.geomspace(0.2, 8.0, 8), normal(8), two, None,
                  dict(axes="parameters", points=(100, 140))),
        "weak": (np.geomspace(0.6, 8.0, 6), normal(6), two, None,
                 dict(axes="parameters", points=(100, 140))),
        "bound": (np.geomspace(0.6, 8.0, 6), normal(6), two, {"C_A": "loguniform:0.3:3"},
                  dict(axes="parameters", points=(100, 140))),
        "weak3": (np.geomspace(0.6, 8.0, 6), normal(6), three, None,
                  dict(axes="sliced", points=((40, 30), (60, 40)))),
        "bound3": (np.geomspace(0.6, 8.0, 6), normal(6), three, {"C_A": "loguniform:0.3:3"},
                   dict(axes="sliced", points=((40, 30), (60, 40)))),
    }  # fmt: skip


def write_data(path, scene, names, speed, angle, rng):
    """Noisy cor_n of the truth (``captured`` rows where the truth captures)."""
    placeholder = Path(path)
    rows = ["speed,angle_deg,observable,value,sigma"]
    rows += [
        f"{float(s)!r},{float(a)!r},cor_n,0.5,{SIGMA}" for s, a in zip(speed, angle, strict=True)
    ]
    placeholder.write_text("\n".join(rows) + "\n")
    result = jaximpact.simulate(scene, speed, angle, 0.0)
    status, cor_n = np.asarray(result.status), np.asarray(result.cor_n)
    rows = ["speed,angle_deg,observable,value,sigma"]
    for s, a, st, c in zip(speed, angle, status, cor_n, strict=True):
        if st == 1:
            rows.append(f"{float(s)!r},{float(a)!r},captured,1.0,0.01")
        else:
            rows.append(
                f"{float(s)!r},{float(a)!r},cor_n,{float(c + SIGMA * rng.normal())!r},{SIGMA}"
            )
    placeholder.write_text("\n".join(rows) + "\n")
    return placeholder, int(np.sum(status == 1))


def run_case(name, spec, folder, truth_scene, recorded=None, samplers=("auto", "independence")):
    """One case; ``recorded``: a row of an earlier run whose grid (the same data: its noise
    draw is seeded) is reused instead of computed again."""
    speed, angle, names, priors, grid_options = spec
    rng = np.random.default_rng(7)
    data, captured = write_data(folder / f"{name}.csv", truth_scene, names, speed, angle, rng)
    scene = truth_scene  # C_H at its true value where it is not fitted
    t0 = time.perf_counter()
    fit = fitting.fit(scene, data, names, initial={n: INITIAL[n] for n in names}, starts=1,
                      progress=False)  # fmt: skip
    t_fit = time.perf_counter() - t0
    posts = {}
    for sampler in samplers:
        t0 = time.perf_counter()
        try:
            post = fitting.sample_posterior(scene, data, names, priors=priors, fit_result=fit,
                                            sampler=sampler, progress=False)  # fmt: skip
            posts[sampler] = (post, time.perf_counter() - t0)
        except fitting.FitError as error:
            posts[sampler] = (str(error), 0.0)
    grids = []
    for points in () if recorded else grid_options["points"]:
        t0 = time.perf_counter()
        if grid_options["axes"] == "sliced":  # 3 parameters: slices x points^2
            draws = posts["auto"][0].draws.reshape(-1, len(names))
            g = sliced_grid(fit, priors, draws, slices=points[0], points=points[1])
        else:
            g = grid_reference(fit, priors, points=points, axes=grid_options["axes"])
        grids.append((points, g, time.perf_counter() - t0))
    out = {
        "case": name,
        "params": list(names),
        "impacts": int(speed.size),
        "captured": captured,
        "fit_status": fit.status,
        "fit_s": t_fit,
    }
    if recorded:
        keys = ("grid", "grid_points", "grid_s", "grid_face_mass", "grid_self_error")
        out.update({k: recorded[k] for k in keys}, grid_reused=True)
        grid = recorded["grid"]
    else:
        grid = grids[-1][1]
        out.update(
            grid={n: grid[n] for n in names},
            grid_points=[p for p, _, _ in grids],
            grid_s=[t for _, _, t in grids],
            grid_face_mass=grid["_face_mass"],
            grid_self_error=compare(grids[0][1], grid, names)["worst"],
        )
    for sampler, (post, wall) in posts.items():
        if isinstance(post, str):
            out[sampler] = {"error": post}
            continue
        errors = compare(post.summary, grid, names)
        out[sampler] = {
            "sampler": post.sampler,
            "reason": post.reason,
            "converged": bool(post.converged),
            "problems": post.problems,
            "worst": errors["worst"],
            "errors": {n: errors[n] for n in names},
            "summary": {
                n: {
                    k: post.summary[n][k]
                    for k in ("mean", "sd", "q05", "median", "q95", "rhat", "ess", "ess_tail")
                }
                for n in names
            },  # fmt: skip
            "ess_min": min(
                min(post.summary[n]["ess"], post.summary[n]["ess_tail"]) for n in names
            ),  # fmt: skip
            "evaluations": post.evaluations,
            "seconds": wall,
        }
    return out


def sliced_grid(fit, priors, draws, *, slices=60, points=40, half_width=8.0):
    """The exact posterior on a grid that follows a curved ridge: slices along ``ln C_A`` (the
    first parameter) over its whole prior range, and in each slice a square grid of
    ``points^2`` cells over ``|g| <= half_width`` in coordinates
    ``ln(C_H, f0) = m(t) + L(t) g``, where ``m`` and ``L L^T`` are the local
    (kernel-weighted) mean and covariance of the other two given ``ln C_A = t`` among
    ``draws`` (physical, ``(n, 3)``). The draws only place the cells: the density is
    evaluated exactly on them, and the mass on each slice's faces (``face_mass``) says whether
    a slice missed part of the posterior. Summaries as
    `grid_reference` (cells as weighted points, each spread over 2^3 points)."""
    from fitting._bayesian.grid_reference import _weighted_summary, posterior_setup
    from fitting._bayesian.programs import BLOCK, _blocks

    space, batch, _, _ = posterior_setup(fit, priors)
    evaluate = _blocks(batch, BLOCK)
    ends = np.array([space._box(i) for i in range(3)])
    U = np.log(np.asarray(draws, float))
    lo, hi = ends[0]  # the whole prior range of ln C_A: a tail the draws miss is still here
    h_t = (hi - lo) / slices
    t = lo + (np.arange(slices) + 0.5) * h_t
    offsets = (np.arange(points) + 0.5) / points * 2 * half_width - half_width
    h_g = offsets[1] - offsets[0]
    G = np.stack(np.meshgrid(offsets, offsets, indexing="ij"), -1).reshape(-1, 2)
    width = 0.1 * np.std(U[:, 0]) + 1e-3  # kernel width along t for the local moments
    log_mass, cells, faces = [], [], []
    for ti in t:
        # local moments (beyond the draws' range: those of the nearest draws)
        log_w = -0.5 * ((U[:, 0] - ti) / width) ** 2
        w = np.exp(log_w - log_w.max())
        w = w / w.sum()
        mean = w @ U[:, 1:]
        dev = U[:, 1:] - mean
        cov = (w[:, None] * dev).T @ dev + 1e-10 * np.eye(2)
        L = np.linalg.cholesky(cov)
        rest = mean + G @ L.T
        points_u = np.column_stack([np.full(len(G), ti), rest])
        s = np.clip((points_u - ends[:, 0]) / (ends[:, 1] - ends[:, 0]), 1e-300, 1 - 1e-16)
        inside = np.all((points_u > ends[:, 0]) & (points_u < ends[:, 1]), axis=1)
        X = np.log(s) - np.log1p(-s)
        lp = evaluate(X) - np.sum(np.log((ends[:, 1] - ends[:, 0]) * s * (1 - s)), axis=1)
        lp = np.where(inside, lp, -np.inf)
        log_mass.append(lp + np.log(np.linalg.det(L)))
        cells.append((points_u, L))
        edge = (np.abs(G[:, 0]) > half_width - h_g) | (np.abs(G[:, 1]) > half_width - h_g)
        faces.append(edge)
    log_mass = np.concatenate(log_mass)
    mass = np.exp(log_mass - np.max(log_mass))
    mass /= mass.sum()
    face = float(mass[np.concatenate(faces)].sum())
    # each cell's mass over 2^3 points inside it (its parallelogram in ln p)
    sub_t = np.array([-0.25, 0.25]) * h_t
    sub_g = np.stack(np.meshgrid([-0.25, 0.25], [-0.25, 0.25], indexing="ij"), -1).reshape(-1, 2)
    pts, wts = [], []
    for (points_u, L), m in zip(cells, np.split(mass, slices), strict=True):
        for dt in sub_t:
            for dg in sub_g:
                shift = np.concatenate([[dt], L @ (dg * h_g)])
                pts.append(np.exp(points_u + shift))
                wts.append(m / 8)
    values, weight = np.concatenate(pts), np.concatenate(wts)
    keep = weight > 1e-14 * weight.max()
    out = _weighted_summary(fit.params, values[keep], weight[keep] / weight[keep].sum(), None,
                            face)  # fmt: skip
    return out


def table(rows):
    print("| case | params | sampler | converged | worst error (grid sd) | sd ratio | ESS min "
          "| s | grid self-error |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        for key in ("auto", "independence"):
            if key not in r:
                continue
            s = r[key]
            if "error" in s:
                print(f"| {r['case']} | {len(r['params'])} | {key} | refused: {s['error']} |")
                continue
            ratio = [s["errors"][n]["sd_ratio"] for n in r["params"]]
            print(
                f"| {r['case']} | {len(r['params'])} | {s['sampler']} | "
                f"{'yes' if s['converged'] else 'no'} | {s['worst']:.2f} | "
                f"{min(ratio):.2f}-{max(ratio):.2f} | {s['ess_min']:.0f} | {s['seconds']:.1f} | "
                f"{r['grid_self_error']:.3f} |"
            )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", help="comma list (default: all)")
    ap.add_argument("--json", help="write the numbers here")
    ap.add_argument("--table", help="print the table of a JSON written before")
    ap.add_argument(
        "--grids", help="a JSON written before: reuse its grids (same cases, same data) and "
        "run the samplers only",
    )  # fmt: skip
    ap.add_argument("--samplers", default="auto,independence", help="comma list")
    args = ap.parse_args(argv)
    if args.table:
        table(json.loads(Path(args.table).read_text()))
        return 0
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        placeholder = folder / "p.csv"
        placeholder.write_text("speed,angle_deg,observable,value,sigma\n1.0,0.0,cor_n,0.5,0.01\n")
        truth_scene = fitting.Objective(
            jaximpact.table1_scene(), placeholder, list(TRUTH)
        ).scene_at(TRUTH)
        v_c = capture_speed(truth_scene)
        print(f"capture speed at the truth: {v_c:.4f} m/s", flush=True)
        specs = cases(v_c)
        recorded = {}
        if args.grids:
            recorded = {r["case"]: r for r in json.loads(Path(args.grids).read_text())}
        for name in args.cases.split(",") if args.cases else specs:
            row = run_case(name, specs[name], folder, truth_scene, recorded.get(name),
                           tuple(args.samplers.split(",")))  # fmt: skip
            for key in ("auto", "independence"):  # samplers not run: their recorded rows
                if key not in row and key in recorded.get(name, {}):
                    row[key] = dict(recorded[name][key], reused=True)
            rows.append(row)
            print(json.dumps(row), flush=True)
            if args.json:
                Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    table(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())

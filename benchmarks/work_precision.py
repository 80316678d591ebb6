"""Work-precision: error against run time, regularization error separated from solver error.

* Regularization error: the smooth model's widths varied at a very tight tolerance (Tsit5,
  rtol 1e-12, atol 1e-14), against the exact switched reference.
* Solver error: each method and tolerance (step ``dt`` for the fixed-step Runge-Kutta-Gill) at
  a fixed width, against the tight solve at the same width.
* Total error: against the exact reference, for every setting.

Errors: ``|d cor_n|``, ``|d vt_out|/speed``, ``|d omega_out| r/speed`` (rebounds) and the
relative contact time; "max" is the largest over the four outputs and the held-out impacts.
Run time: median of repeated runs of the whole held-out batch (one vmapped call, after
compilation), divided by the number of impacts.

Duration: part of ``run_all.py``'s 20 minutes on 2 cores (``run_all.py --only work_precision``).
"""

import time

import jax
import numpy as np
from _common import (
    as_dict,
    fmt,
    held_out,
    max_error,
    median_time,
    output_errors,
    reference_rows,
    save_figure,
    table,
)

import jaximpact as ji
from jaximpact import reference as ref

TIGHT = dict(method="tsit5", rtol=1e-12, atol=1e-14)
# The widths of the solver-error table (and of the regularization rows that vary the other)
DEFAULT_WIDTH, DEFAULT_RING = 1e-3, 1e-8
TITLE = "Accuracy against cost"
WHY = (
    "\n**Why these methods and widths.** Tsit5 at rtol 1e-8 / atol 1e-10 already brings the "
    "solver error down to the regularization floor of slip_width 1e-3 (total error about "
    "1e-5, mostly in vt/omega) at the lowest cost per impact of the adaptive methods here; "
    "Dopri8 is no cheaper at this accuracy, the fixed-step Runge-Kutta-Gill needs dt <= 0.003 "
    "Hertz times (three times the cost) for the same error, and the implicit Kvaerno methods "
    "cost 25x or more per impact, so `auto` uses them only where the stiffness estimate or a "
    "slip width below the solver noise calls for them. slip_width 1e-3 keeps the "
    "regularization error near 1e-5 (it grows about as the square of the width) while "
    "staying far above the solver noise: with a narrow width and a loose tolerance some "
    "impacts chatter across the friction switch for thousands of steps (Tsit5 rtol 1e-6 at "
    "width 1e-5 in the table). The ring's regularization error is about 0.25 ring_width in "
    "cor_n. The float64 default rtol is 1e-10, tighter than the values need, because "
    "derivatives converge more slowly than values ([Derivatives](#derivatives)).\n"
)


def scenes():
    """(name, jaximpact scene, reference params)."""
    t1 = ji.table1_scene()
    dry = t1.replace(model={"adhesion": False}, contact={"f0": 0.0, "C_A": 0.0})
    return [
        ("Table 1", t1, ref.table1_params()),
        ("non-adhesive", dry, ref.table1_params(adhesion=False, f0=0.0, C_A=0.0)),
    ]


def solve(scene, speed, angle, omega0, repeats, **solver):
    settings = dict(max_steps=200_000, slip_width=DEFAULT_WIDTH, ring_width=DEFAULT_RING)
    settings.update(solver)
    s = scene.replace(solver=settings)
    t = time.perf_counter()
    res = jax.block_until_ready(ji.simulate(s, speed, angle, omega0))
    first = time.perf_counter() - t
    run = median_time(lambda: jax.block_until_ready(ji.simulate(s, speed, angle, omega0)), repeats)
    return as_dict(res), dict(
        time=run / len(speed),
        compile=first - run,
        steps=float(np.median(res.steps)),
        max_steps=int(np.max(res.steps)),
    )


def run(
    quick=False, info=None, note=None, command="python benchmarks/run_all.py --only work_precision"
):
    """The section "Accuracy against cost" of BENCHMARKS.md (from its heading), and the data."""
    from _common import machine, measured_line

    info = info or machine()
    n = 12 if quick else 40
    repeats = 2 if quick else 3
    speed, angle, omega0 = held_out(n)
    if quick:
        widths = [1e-2, 1e-3, 1e-5]
        rings = []
        solvers = [
            ("tsit5", [1e-5, 1e-8]),
            ("dopri8", [1e-8]),
            ("rk4", [0.01]),
            ("kvaerno5", [1e-8]),
        ]
        extra_width = []
    else:
        widths = [1e-2, 1e-3, 1e-4, 1e-5, 1e-6]
        rings = [1e-4, 1e-6]
        tols = [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10]
        solvers = [
            ("tsit5", tols),
            ("dopri5", tols[::2]),
            ("dopri8", [1e-4, 1e-6, 1e-8, 1e-10]),
            ("rk4", [0.1, 0.03, 0.01, 0.003]),
            ("kvaerno5", [1e-5, 1e-8]),
            ("kvaerno3", [1e-6]),
        ]
        extra_width = [("tsit5", 1e-5, [1e-6, 1e-8, 1e-10])]
    rows_reg, rows_sol, data = [], [], {"reg": {}, "sol": {}}
    radius = 35e-6
    for name, scene, params in scenes():
        if quick and name != "Table 1":
            continue
        exact = reference_rows(params, speed, angle, omega0)
        tight = {}
        for width in widths:
            res, info = solve(scene, speed, angle, omega0, 1, slip_width=width, **TIGHT)
            tight[width] = res
            err, bad = output_errors(res, exact, speed, radius)
            data["reg"][(name, width)] = err
            rows_reg.append(
                [name, f"{width:g}", f"{DEFAULT_RING:g}"]
                + [fmt(np.nanmax(err[k])) for k in err]
                + [bad]
            )
        for ring in rings:
            res, info = solve(scene, speed, angle, omega0, 1, ring_width=ring, **TIGHT)
            err, bad = output_errors(res, exact, speed, radius)
            rows_reg.append(
                [name, f"{DEFAULT_WIDTH:g}", f"{ring:g}"]
                + [fmt(np.nanmax(err[k])) for k in err]
                + [bad]
            )
        configs = [(m, t, DEFAULT_WIDTH) for m, ts in solvers for t in ts]
        configs += [(m, t, w) for m, w, ts in extra_width for t in ts]
        for method, tol, width in configs:
            if name != "Table 1" and method in ("kvaerno3", "dopri5") and not quick:
                continue
            opts = dict(dt=tol) if method == "rk4" else dict(rtol=tol, atol=tol * 1e-2)
            res, info = solve(
                scene, speed, angle, omega0, repeats, method=method, slip_width=width, **opts
            )
            err_s, bad_s = output_errors(res, tight[width], speed, radius)
            err_t, bad_t = output_errors(res, exact, speed, radius)
            data["sol"][(name, method, tol, width)] = (max_error(err_s), info["time"])
            rows_sol.append(
                [
                    name,
                    method,
                    ("dt " if method == "rk4" else "") + f"{tol:g}",
                    f"{width:g}",
                    f"{info['time'] * 1e6:.0f}",
                    f"{info['steps']:.0f} / {info['max_steps']}",
                    f"{info['compile']:.1f}",
                    fmt(max_error(err_s)),
                    fmt(max_error(err_t)),
                    fmt(np.nanmax(err_t["cor_n"])),
                    bad_t,
                ]
            )
    fig = plot(data, widths)
    path = save_figure(fig, "work_precision")
    md = [
        f"## {TITLE}\n",
        measured_line(
            info,
            command,
            settings=f"slip_width {DEFAULT_WIDTH:g} and ring_width {DEFAULT_RING:g} unless "
            "a column says otherwise; method and tolerances as in the tables",
            note=note,
        ),
        f"{n} held-out impacts per scene (speeds 0.1-10 m/s log-uniform, angles -70..70 deg, "
        "|omega0| <= 3e4 rad/s, a tenth normal, some captured). Errors scaled as in the "
        "accuracy catalogue: |d cor_n|, |d vt_out|/speed, |d omega_out| r/speed (rebounds) and "
        "the relative contact time; *max* is over the four outputs and all impacts. The exact "
        "reference is `reference.simulate_impact` (switched model, DOP853, rtol 1e-12).\n",
        f"![work-precision]({path})\n",
        "### Regularization error (Tsit5 at rtol 1e-12, atol 1e-14, against the exact reference)\n",
        table(
            [
                "scene",
                "slip_width",
                "ring_width",
                "cor_n",
                "vt/speed",
                "omega r/speed",
                "contact_time (rel.)",
                "status mismatches",
            ],
            rows_reg,
        ),
        WHY,
        "\n### Solver error (against the tight solve at the same widths) and total error "
        "(against the exact reference)\n",
        "Time: per impact, batch of held-out impacts in one vmapped call (the slowest lane "
        "sets the batch's cost), median of repeats after compilation. atol = rtol/100.\n",
        table(
            [
                "scene",
                "method",
                "rtol / dt",
                "slip_width",
                "us/impact",
                "steps median / max",
                "compile (s)",
                "solver error (max)",
                "total error (max)",
                "total cor_n",
                "status mismatches",
            ],
            rows_sol,
        ),
    ]
    return "\n".join(md) + "\n", data


def plot(data, widths):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for name, style in (("Table 1", "-"), ("non-adhesive", "--")):
        ws = [w for w in widths if (name, w) in data["reg"]]
        if not ws:
            continue
        for key, label in (
            ("cor_n", "cor_n"),
            ("vt", "vt/speed"),
            ("omega", "omega r/speed"),
            ("contact_time", "contact time"),
        ):
            ys = [np.nanmax(data["reg"][(name, w)][key]) for w in ws]
            ax1.loglog(ws, np.maximum(ys, 1e-16), style, marker="o", label=f"{label} ({name})")
    ax1.set_xlabel("slip_width (fraction of the normal speed)")
    ax1.set_ylabel("max error against the exact reference")
    ax1.set_title("Regularization error (rtol 1e-12)")
    ax1.axvline(DEFAULT_WIDTH, color="grey", lw=0.8)
    ax1.legend(fontsize=6)
    methods = sorted({k[1] for k in data["sol"]})
    colors = dict(zip(methods, plt.rcParams["axes.prop_cycle"].by_key()["color"], strict=False))
    for method in methods:
        for name, style in (("Table 1", "-"), ("non-adhesive", "--")):
            # connected in tolerance (step) order: run times are noisy on a shared machine
            pts = sorted(
                (k[2], v[1], v[0])
                for k, v in data["sol"].items()
                if k[0] == name and k[1] == method and k[3] == DEFAULT_WIDTH
            )
            if pts:
                _, x, y = zip(*pts, strict=True)
                ax2.loglog(
                    np.array(x) * 1e6,
                    np.maximum(y, 1e-16),
                    style,
                    marker="o",
                    color=colors[method],
                    label=f"{method} ({name})",
                )
    ax2.set_xlabel("run time per impact (us, batch of held-out impacts)")
    ax2.set_ylabel("max solver error (vs tight solve, same width)")
    ax2.set_title(f"Solver error at slip_width {DEFAULT_WIDTH:g}")
    ax2.legend(fontsize=6)
    fig.tight_layout()
    return fig

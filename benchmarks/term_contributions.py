"""What can this scene leave out? The size of each term's contribution to given impacts.

``term_contributions(params, scene, speed, angle_deg, omega0)`` integrates each impact with the
exact reference's time history (``reference.impact_history``, dense output) and reports

* impulses (time integrals of magnitudes) of the normal forces ``F_H, F_HD, F_A, F_AD`` and the
  moments ``M_A, M_H`` against the friction moment ``r F_t`` (the paper's conclusion is that
  ``|M_A + M_H|`` is negligible against ``|r F_t|``);
* the energy ledger of ``jaximpact.simulate``: the share of the incoming energy lost to Hertz
  damping, adhesion damping, friction and the rolling moments.

A term whose impulse or energy share is far below the accuracy you need can be switched off
(``model.rolling_moments = "none"``, ``model.adhesion = false``, ...). Run this file for the
Table 1 scene's three paper impacts (1.66 m/s, 0 and +-40 deg, 1e6 deg/s) and what leaving
terms out buys in impacts/s (``throughput.py``'s normal-impact configurations):
``python benchmarks/term_contributions.py [--update BENCHMARKS.md]`` (``--update`` replaces
only the "What a scene can leave out" section of that file). Also a section of ``run_all.py``
(``terms``), which takes the impacts/s from its ``throughput`` section when both run.

Duration: not recorded; part of ``run_all.py``'s 20 minutes with ``--only terms``.
"""

import math
import sys

import numpy as np

from jaximpact import reference as ref

FORCES = ("F_H", "F_HD", "F_A", "F_AD")
LOSSES = ("loss_hertz_damping", "loss_adhesion_damping", "loss_friction", "loss_rolling")


def _impulses(params, speed, angle, omega0, samples=4000):
    hist, res = ref.impact_history(params, speed, angle, omega0, n_samples=samples)
    t = hist["t"]
    parts = [
        ref.contact_forces(params, n, nd, w)
        for n, nd, w in zip(hist["n"], hist["ndot"], hist["w"], strict=True)
    ]
    series = {k: np.array([p[k] for p in parts]) for k in FORCES + ("M_A", "M_H", "M")}
    series["r F_t"] = params.radius * hist["F_t"]
    return {k: float(np.trapezoid(np.abs(v), t)) for k, v in series.items()}, res


def term_contributions(params, scene, speed, angle_deg, omega0):
    """One dict per impact: impulses (N s, N m s), their ratios, and the energy shares."""
    import jax

    import jaximpact as ji

    speed, angle_deg, omega0 = np.broadcast_arrays(
        *(np.atleast_1d(np.asarray(x, float)) for x in (speed, angle_deg, omega0))
    )
    with jax.enable_x64(True):
        sim = ji.simulate(scene, speed, angle_deg, omega0)
    rows = []
    for i, (v, a, w) in enumerate(zip(speed, angle_deg, omega0, strict=True)):
        imp, res = _impulses(params, v, a, w)
        e_in = float(sim.energy_in[i])
        rows.append(
            dict(
                speed=v,
                angle=a,
                omega0=w,
                status=res.status,
                impulses=imp,
                moment_ratio=imp["M"] / imp["r F_t"] if imp["r F_t"] > 0 else float("nan"),
                energy={k: float(getattr(sim, k)[i]) / e_in for k in LOSSES},
                energy_ref={k: getattr(res, k) / res.energy_in for k in LOSSES},
            )
        )
    return rows


def _label(r):
    return f"{r['speed']:g} m/s, {r['angle']:+g} deg, {math.degrees(r['omega0']):.0e} deg/s"


def _pct(x, y):
    return f"{100 * x:.3g}% ({100 * y:.3g}%)"


def markdown(rows):
    from _common import table

    head = [
        "impact",
        "status",
        *(f"∫\\|{k}\\|" for k in FORCES + ("M_A", "M_H")),
        "∫\\|M_A+M_H\\| / ∫\\|r F_t\\|",
    ]
    out = [
        table(
            head,
            [
                [
                    _label(r),
                    r["status"],
                    *(f"{r['impulses'][k]:.2e}" for k in FORCES + ("M_A", "M_H")),
                    f"{r['moment_ratio']:.1e}",
                ]
                for r in rows
            ],
        )
    ]
    out.append(
        "\nShare of the incoming energy lost to each term (jaximpact ledger; exact "
        "reference in brackets):\n"
    )
    out.append(
        table(
            ["impact", "Hertz damping", "adhesion damping", "friction", "rolling moments"],
            [
                [
                    f"{r['speed']:g} m/s, {r['angle']:+g} deg",
                    *(_pct(r["energy"][k], r["energy_ref"][k]) for k in LOSSES),
                ]
                for r in rows
            ],
        )
    )
    return "\n".join(out)


TITLE = "What a scene can leave out"
COMMAND = "python benchmarks/term_contributions.py"


def savings(results, n):
    """Markdown table: impacts/s of the normal-impact configurations at batch ``n`` (float64)
    from ``throughput`` results, against the normal-only model."""
    from _common import table
    from throughput import KINDS, SAVINGS

    pick = {r["kind"]: r for r in results if r["x64"] and r["n"] == n and r["kind"] in SAVINGS}
    base = pick.get("normal")
    rows = [
        [
            KINDS[k],
            f"{pick[k]['rate']:,.0f}",
            f"{pick[k]['run']:.3f}",
            f"{pick[k]['steps_max']}",
            f"{base['run'] / pick[k]['run']:.2f}" if base else "–",
        ]
        for k in SAVINGS
        if k in pick
    ]
    return table(
        ["impacts", "impacts/s", "run (s)", "max steps", "speed relative to the normal-only model"],
        rows,
    )


def run(quick=False, info=None, note=None, command=COMMAND, throughput=None):
    """The section "What a scene can leave out" of BENCHMARKS.md (from its heading), and the
    impulses. ``throughput``: the data of ``throughput.run`` when it ran in the same process
    (its normal-impact rows are reused); else those configurations are measured here."""
    from _common import default_settings, machine, measured_line

    import jaximpact as ji

    info = info or machine()
    rows = term_contributions(
        ref.table1_params(),
        ji.table1_scene(),
        1.66,
        np.array([0.0, 40.0, -40.0]),
        math.radians(1e6),
    )
    if throughput is None:
        from throughput import SAVINGS, spawn

        n = 1000 if quick else 10000
        results = [r for k in SAVINGS for r in spawn(dict(kind=k, x64=True, sizes=[n]))]
        where = "measured in the same run"
    else:
        results, n = throughput["results"], throughput["savings_n"]
        where = 'from the same run as "By batch size and scene options"'
    md = [
        f"## {TITLE}\n",
        measured_line(info, command, note=note),
        "Impulses (time integrals of magnitudes, N s and N m s) over the contact from the exact "
        "reference's dense history, for the Table 1 scene's three paper impacts (function "
        "`term_contributions`).\n",
        markdown(rows),
        "",
        f"What leaving terms out buys (batch {n:,}, float64, {where}; default settings: "
        f"{default_settings()}): a normal impact without spin compiles only the normal "
        "states, and a scene without adhesion never evaluates the ring.\n",
        savings(results, n),
        "",
    ]
    return "\n".join(md) + "\n", rows


if __name__ == "__main__":
    import argparse
    from pathlib import Path

    import jax

    jax.config.update("jax_enable_x64", True)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import machine, replace_section, write_result

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--update",
        metavar="BENCHMARKS.md",
        help=f"replace the {TITLE!r} section of this file",
    )
    ap.add_argument("--note", help="a sentence about the run for the measured line")
    args = ap.parse_args()
    info = machine()
    text, rows = run(info=info, note=args.note)
    print(text)
    write_result("term_contributions", rows, info, COMMAND)
    if args.update:
        replace_section(Path(args.update), text)
        print(f"replaced the section {TITLE!r} of {args.update}", file=sys.stderr)

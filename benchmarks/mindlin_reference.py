"""The Mindlin scene against its exact reference at the default settings.

40 random rebounds of the Kharaz sphere (5 mm alumina, no adhesion): speed 0.5-5 m/s, angle
1-85 deg, friction 0.05-0.5, G* 0.3-1.5 of alumina's (seed 2027), simulated in one batch
with `jaximpact.simulate` at the scene's defaults and one by one by `jaximpact.reference`
(the switched stick/slip model with events, rtol 1e-12). Errors of the rebound velocities
(`vn_out`, `vt_out`, `omega_out * r`) in units of the impact speed; issue 35's target: every
one within 1e-5.

With ``--target R2 RHO2 OMEGA2`` the same impacts strike a second sphere (radius m, density
kg/m^3, spin rad/s) instead of the anvil, and its spin after the impact (`omega2_out * r2`) is
compared too.

Run: ``python benchmarks/mindlin_reference.py [--slip-width W] [--target R2 RHO2 OMEGA2]``
(about 1 minute).
"""

import argparse
import sys
from pathlib import Path

import equinox as eqx
import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import jaximpact as ji  # noqa: E402
from jaximpact import reference as ref  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import machine, measured_line, table, write_result  # noqa: E402

#: Kharaz et al. (2001): alumina, E = 380 GPa, nu = 0.23, on a rigid anvil.
G_ALUMINA = 380e9 / (2 * 1.23) / (2 - 0.23)
RANGES = {"speed": (0.5, 5.0), "angle": (1.0, 85.0), "friction": (0.05, 0.5), "G": (0.3, 1.5)}


def points(n=40, seed=2027):
    rng = np.random.default_rng(seed)
    return {k: rng.uniform(lo, hi, n) for k, (lo, hi) in RANGES.items()}


def errors(pts, solver=None, target=None):
    """``{output: |engine - reference| / speed}`` per impact, and the engine's step counts;
    ``target``: ``(radius, density, spin)`` of a second sphere, or None (the anvil)."""
    base = ji.load_scene("kharaz2001")
    scene = base.replace(
        model={"tangential": "mindlin"},
        contact={"friction": pts["friction"], "G_star": G_ALUMINA * pts["G"]},
        solver=solver or {},
    )
    pair = {}
    if target is not None:
        r2, rho2, w2 = target
        second = ji.Target(radius=r2, density=rho2, omega0=w2)
        scene = eqx.tree_at(lambda s: s.target, scene, second, is_leaf=lambda x: x is None)
        pair = {"radius2": r2, "density2": rho2, "omega2": w2}
    res = ji.simulate(scene, pts["speed"], pts["angle"])
    r = float(base.particle.radius)
    out = {"vn_out": [], "vt_out": [], "omega_out r": []}
    if target is not None:
        out["omega2_out r2"] = []
    for i, (v, a, f, g) in enumerate(zip(*pts.values(), strict=True)):
        params = ref.Params(
            radius=r, density=float(base.particle.density), K=float(base.contact.K),
            C_H=float(base.contact.C_H), friction=float(f), adhesion=False,
            rolling_moments="none", tangential="mindlin", G_star=G_ALUMINA * float(g), **pair,
        )  # fmt: skip
        exact = ref.simulate_impact(params, float(v), float(a), rtol=1e-12, atol=1e-15)
        assert exact.status == "rebound", (i, exact.status)
        out["vn_out"].append(abs(float(res.vn_out[i]) - exact.vn_out) / v)
        out["vt_out"].append(abs(float(res.vt_out[i]) - exact.vt_out) / v)
        out["omega_out r"].append(abs(float(res.omega_out[i]) - exact.omega_out) * r / v)
        if target is not None:
            miss = abs(float(res.omega2_out[i]) - exact.omega2_out) * target[0] / v
            out["omega2_out r2"].append(miss)
    return {k: np.array(e) for k, e in out.items()}, np.asarray(res.steps)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--slip-width", type=float, help="solver.slip_width (default: the scene's)")
    ap.add_argument("--target", type=float, nargs=3, metavar=("R2", "RHO2", "OMEGA2"))
    args = ap.parse_args()
    solver = {"slip_width": args.slip_width} if args.slip_width else {}
    info = machine()
    pts = points()
    err, steps = errors(pts, solver, args.target)
    worst = max(range(len(steps)), key=lambda i: max(e[i] for e in err.values()))
    rows = [[k, f"{np.median(e):.1e}", f"{np.max(e):.1e}"] for k, e in err.items()]
    settings = {**solver, **({"target": args.target} if args.target else {})}
    print(measured_line(info, "python benchmarks/mindlin_reference.py", settings or None))
    print(table(["output / speed", "median error", "largest error"], rows))
    print(f"\nsteps: mean {steps.mean():.0f}, largest {steps.max()}; worst impact: "
          + ", ".join(f"{k} {v[worst]:.3g}" for k, v in pts.items()))  # fmt: skip
    figures = {
        "settings": settings,
        "median_error": {k: float(np.median(e)) for k, e in err.items()},
        "largest_error": {k: float(np.max(e)) for k, e in err.items()},
        "steps_mean": float(steps.mean()),
        "steps_max": int(steps.max()),
        "worst_impact": {k: float(v[worst]) for k, v in pts.items()},
    }
    name = "mindlin_reference" + ("_target" if args.target else "")
    write_result(name, figures, info, "python benchmarks/mindlin_reference.py")


if __name__ == "__main__":
    main()

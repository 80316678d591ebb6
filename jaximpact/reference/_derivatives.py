"""Quantities derived from many reference impacts: the capture speed (bisection) and
finite-difference derivatives of the outputs."""

from __future__ import annotations

import math
from dataclasses import replace

from ._impact import simulate_impact
from ._params import ImpactResult, Params


def capture_speed(
    p: Params,
    angle_deg: float = 0.0,
    omega0: float = 0.0,
    lo: float = 1e-3,
    hi: float = 10.0,
    rel_tol: float = 1e-6,
    **options,
) -> float:
    """Bisection for the speed below which the impact is captured (``lo`` must capture, ``hi``
    rebound)."""

    def captured(v):
        st = simulate_impact(p, v, angle_deg, omega0, **options).status
        if st == "failed":
            raise RuntimeError(f"impact at {v} m/s failed")
        return st == "captured"

    if not captured(lo) or captured(hi):
        raise ValueError("the bracket [lo, hi] does not straddle the capture speed")
    while hi - lo > rel_tol * hi:
        mid = 0.5 * (lo + hi)
        if captured(mid):
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


#: Outputs and inputs of :func:`output_derivatives` (names as in ``jaximpact.ImpactResult`` and
#: the impacts CSV; ``lambda`` is ``Params.lam``).
DERIVATIVE_OUTPUTS = ("cor_n", "vt_out", "omega_out", "rebound_angle_deg", "contact_time")


#: Inputs of :func:`output_derivatives` (impacts-CSV names; ``lambda`` is ``Params.lam``).
DERIVATIVE_INPUTS = (
    "f0", "C_A", "C_H", "friction", "K", "radius", "density", "lambda",
    "speed", "angle_deg", "omega0",
)  # fmt: skip


def _outputs(res: ImpactResult, speed: float, angle_deg: float) -> dict:
    v_n = speed * math.cos(math.radians(angle_deg))
    return {
        "cor_n": res.vn_out / v_n,
        "vt_out": res.vt_out,
        "omega_out": res.omega_out,
        "rebound_angle_deg": math.degrees(math.atan2(res.vt_out, res.vn_out)),
        "contact_time": res.contact_time,
    }


def output_derivatives(
    p: Params,
    speed: float,
    angle_deg: float = 0.0,
    omega0: float = 0.0,
    inputs=DERIVATIVE_INPUTS,
    rel_step: float = 1e-4,
    **options,
) -> tuple[dict, dict]:
    """Derivatives of the outputs by central differences of the exact model, Richardson-checked.

    For each input ``x`` the central difference ``D(h)`` is taken at ``h`` and ``h/2`` (``h =
    rel_step * |x|``; for ``angle_deg`` ``rel_step * 180/pi`` degrees, for ``omega0``
    ``rel_step * speed / radius``); the Richardson value ``(4 D(h/2) - D(h)) / 3`` is returned
    with ``|Richardson - D(h/2)|`` as its error estimate (large where a regime switch lies
    within the step, or the reference's own noise, ~rtol / h, dominates).

    Returns ``(jac, err)``: dicts ``output -> input -> value``. Inputs whose value is 0 (a
    central difference would leave the allowed range) are skipped. ``options`` go to
    :func:`simulate_impact` (default ``rtol=1e-12``).
    """
    x0 = {
        "f0": p.f0, "C_A": p.C_A, "C_H": p.C_H, "friction": p.friction, "K": p.K,
        "radius": p.radius, "density": p.density, "lambda": p.lam,
        "speed": speed, "angle_deg": angle_deg, "omega0": omega0,
    }  # fmt: skip
    if p.tangential in ("mindlin", "lammps_mindlin"):
        x0["G_star"] = p.G_star
    if p.tangential == "lammps_linear_history":
        x0["k_t"] = p.k_t
    if p.damping != "hertzian":
        x0["eta_n"] = p.eta_n
    if p.normal in ("dmt", "jkr"):
        x0["w"] = p.w
    if p.target:
        x0.update(radius2=p.radius2, density2=p.density2, omega2=p.omega2)

    def run(name, value):
        x = dict(x0, **{name: value})
        q = replace(
            p,
            **{
                ("lam" if k == "lambda" else k): x[k]
                for k in x0
                if k not in ("speed", "angle_deg", "omega0")
            },
        )
        res = simulate_impact(q, x["speed"], x["angle_deg"], x["omega0"], **options)
        if res.status == "failed":  # a rare stall at a switch: a second try at another rtol
            retry = dict(options, rtol=0.5 * options.get("rtol", 1e-12))
            res = simulate_impact(q, x["speed"], x["angle_deg"], x["omega0"], **retry)
        if res.status != "rebound":
            raise RuntimeError(
                f"{name} = {value!r}: the reference did not rebound ({res.status}: {res.message})"
            )
        return _outputs(res, x["speed"], x["angle_deg"])

    steps = {"angle_deg": rel_step * 180.0 / math.pi, "omega0": rel_step * speed / p.radius}
    if p.target:
        steps["omega2"] = rel_step * speed / p.radius2
    jac = {k: {} for k in DERIVATIVE_OUTPUTS}
    err = {k: {} for k in DERIVATIVE_OUTPUTS}
    for name in inputs:
        h = steps.get(name, rel_step * abs(x0[name]))
        if h == 0:
            continue
        d = []
        for hh in (h, h / 2):
            up, down = run(name, x0[name] + hh), run(name, x0[name] - hh)
            d.append({k: (up[k] - down[k]) / (2 * hh) for k in DERIVATIVE_OUTPUTS})
        for k in DERIVATIVE_OUTPUTS:
            jac[k][name] = (4 * d[1][k] - d[0][k]) / 3
            err[k][name] = abs(jac[k][name] - d[1][k])
    return jac, err

"""The exact contact forces and moments: Hertz scales, the adhesion ring integrals, the
forces at a state, and the normal potential."""

from __future__ import annotations

import math

from . import jkr
from ._params import Params


def hertz_scales(p: Params, v_n: float) -> tuple[float, float]:
    """Peak overlap n* of an undamped, non-adhesive Hertz impact at normal speed v_n, and n*/v_n."""
    m, r = p.reduced_mass, p.reduced_radius
    n_star = (5.0 * m * v_n**2 / (4.0 * p.K * math.sqrt(r))) ** 0.4
    return n_star, n_star / v_n


def ring_integrals(ndot: float, b: float) -> tuple[float, float]:
    """I0 = int max(-u,0) da and I1 = int max(-u,0) cos(a) da over [0, 2pi], u = ndot + b cos(a)."""
    ab = abs(b)
    if ndot >= ab:  # the whole ring approaches (or is at rest): no damping
        return 0.0, 0.0
    if ndot <= -ab:  # the whole ring separates
        return -2.0 * math.pi * ndot, -math.pi * b
    # partial ring: u < 0 for beta < alpha < 2 pi - beta, cos(beta) = -ndot/|b|
    c = -ndot / ab
    beta = math.acos(c)
    sb = math.sqrt(max(1.0 - c * c, 0.0))
    i0 = -2.0 * ndot * (math.pi - beta) + 2.0 * ab * sb
    i1 = 2.0 * ndot * sb - ab * (math.pi - beta) + ab * sb * c  # (b/2) sin(2 beta) = b sb c
    return i0, (i1 if b > 0 else -i1)


# LAMMPS's Tsuji polynomial alpha(e) (coefficients of e^0 .. e^6; LAMMPS 29 Sep 2021).
_TSUJI = (1.2728, -4.2783, 11.087, -22.348, 27.467, -18.022, 4.8218)


def damping_force(p: Params, hertz: float, a: float, ndot: float) -> float:
    """The normal damping force at Hertz force ``hertz`` and contact radius ``a``: Brach-Dunn's
    ``-C_H hertz ndot``, or LAMMPS's ``-eta_n ndot`` (``eta_n``: ``eta``, ``eta m``, ``eta a
    m`` or ``alpha(e) sqrt(m K a)``, with ``m`` the reduced mass)."""
    if p.damping == "hertzian":
        return -hertz * p.C_H * ndot
    m = p.reduced_mass
    if p.damping == "velocity":
        eta = p.eta_n
    elif p.damping == "mass_velocity":
        eta = p.eta_n * m
    elif p.damping == "viscoelastic":
        eta = p.eta_n * a * m
    else:  # tsuji
        alpha = sum(c * p.eta_n**i for i, c in enumerate(_TSUJI))
        eta = alpha * math.sqrt(m * p.K * a)
    return -eta * ndot


def contact_forces(p: Params, n: float, ndot: float, w: float) -> dict:
    """Normal force parts, rolling moments and friction load at a state (SI).

    Returns a dict with F_H, F_HD, F_A, F_AD, F_n, M_A, M_H, M and N.
    """
    out = dict(F_H=0.0, F_HD=0.0, F_A=0.0, F_AD=0.0, F_n=0.0, M_A=0.0, M_H=0.0, M=0.0, N=0.0)
    if p.jkr:
        return _jkr_forces(p, n, ndot, w, out)
    if not n > 0:
        return out
    r = p.reduced_radius
    a = math.sqrt(r * n)
    hertz = p.K * math.sqrt(r) * n**1.5
    out["F_H"] = -hertz
    out["F_HD"] = damping_force(p, hertz, a, ndot)
    analytical = p.rolling_moments == "analytical"
    if p.adhesion and p.normal == "dmt":
        out["F_A"] = 2.0 * math.pi * p.w * r
    elif p.adhesion:
        out["F_A"] = 2.0 * math.pi * a * p.f0
        i0, i1 = ring_integrals(ndot, w * a if analytical else 0.0)
        out["F_AD"] = p.f0 * p.C_A * a * i0
        if analytical:
            out["M_A"] = p.f0 * p.C_A * a * a * i1
    if analytical:
        out["M_H"] = -(p.K / 5.0) * math.sqrt(n / r) * p.C_H * a**4 * w
        out["M"] = out["M_A"] + out["M_H"]
    elif p.rolling_moments == "lambda":
        out["M"] = -p.lam * p.C_A * a * w
    out["F_n"] = out["F_H"] + out["F_HD"] + out["F_A"] + out["F_AD"]
    out["N"] = abs(out["F_n"]) if p.friction_load == "net" else hertz
    if p.tangential.startswith("lammps_"):
        out["N"] = _lammps_critical_load(p, out)
    return out


def _lammps_critical_load(p: Params, out: dict) -> float:
    """LAMMPS's critical normal force (29 Sep 2021, as built): ``|F_ne + 2 F_pulloff|`` for
    JKR (``F_pulloff = 1.5 pi w r``), ``|F_ne|`` for DMT (its cohesion is not set there),
    without the damping; else ``|F_ne + F_damp|``."""
    if p.normal == "jkr":
        return abs(-out["F_H"] - out["F_A"] + 3.0 * math.pi * p.w * p.reduced_radius)
    if p.normal == "dmt":
        return abs(-out["F_H"] - out["F_A"])
    return abs(out["F_n"])


def _jkr_forces(p: Params, n: float, ndot: float, w: float, out: dict) -> dict:
    """The JKR law (from the contact radius of the stable branch, found by root finding):
    Hertzian part ``K a^3 / r`` damped by ``C_H``, adhesive part ``sqrt(6 pi w K a^3)``."""
    if not n > p.separation_overlap:
        return out
    r, E = p.reduced_radius, 0.75 * p.K
    a = jkr.contact_radius(n, r, E, p.w)
    hertz = p.K * a**3 / r
    out["F_H"] = -hertz
    out["F_HD"] = damping_force(p, hertz, a, ndot)
    out["F_A"] = math.sqrt(6.0 * math.pi * p.w * p.K * a**3)
    if p.rolling_moments == "analytical":
        out["M_H"] = -(p.K / 5.0) * p.C_H * a**5 / r * w
        out["M"] = out["M_H"]
    elif p.rolling_moments == "lambda":
        out["M"] = -p.lam * p.C_A * a * w
    out["F_n"] = out["F_H"] + out["F_HD"] + out["F_A"]
    out["N"] = abs(out["F_n"]) if p.friction_load == "net" else hertz
    if p.tangential.startswith("lammps_"):
        out["N"] = _lammps_critical_load(p, out)
    return out


def _jkr_energy(p: Params, a: float) -> float:
    """An antiderivative in ``a`` of ``P(a) dn/da`` (docs/physics.md, "Normal laws")."""
    r, K, w = p.reduced_radius, p.K, p.w
    return (
        0.4 * K * a**5 / r**2
        - 8.0 / (3.0 * r) * math.sqrt(3.0 * math.pi * w * K / 8.0) * a**3.5
        + math.pi * w * a * a
    )


def normal_potential(p: Params, n: float) -> float:
    """V(n), the potential of F_H + F_A (zero out of contact; continuous at 0 for DMT too; for
    JKR zero at first touch, ``n = 0``)."""
    if p.jkr:
        r, E = p.reduced_radius, 0.75 * p.K
        a = jkr.contact_radius(max(n, p.separation_overlap), r, E, p.w)
        lam = (p.w * r * r / E) ** (1.0 / 3.0)
        return _jkr_energy(p, a) - _jkr_energy(p, (2.0 * math.pi) ** (1.0 / 3.0) * lam)
    if not n > 0:
        return 0.0
    r = p.reduced_radius
    v = 0.4 * p.K * math.sqrt(r) * n**2.5
    if p.adhesion and p.normal == "dmt":
        v -= 2.0 * math.pi * p.w * r * n
    elif p.adhesion:
        v -= 4.0 / 3.0 * math.pi * p.f0 * math.sqrt(r) * n**1.5
    return v

"""The Thornton & Ning (1998) adhesive elastic-plastic normal contact, as reconstructed in
docs/thornton_ning.md (the paper itself was not available), and an exact normal impact with
it: the oracle of the engine's ``[model] normal = "thornton_ning"``.

Same conventions as :mod:`jaximpact.reference.jkr`: ``w`` is the work of adhesion (TN's
``Gamma``), ``E``, ``R`` and ``m`` the effective modulus, radius and mass, the force ``P``
repulsive positive, the overlap ``delta`` positive in compression. The law:

- elastic JKR (``jkr.force``, ``jkr.overlap``) until the pressure at the contact's centre
  reaches the limiting pressure ``p_y`` (TN eq. 65), at the yield radius ``a_y``:
  ``p_y = 2 E a_y / (pi R) - sqrt(2 w E / (pi a_y))``;
- plastic loading beyond it, along the JKR geometry ``delta(a)`` of ``R``:
  ``P = P_y + pi p_y (a^2 - a_y^2) - sqrt(8 pi w E) a_y (sqrt(a) - sqrt(a_y))``;
- unloading from the largest overlap ``delta_m`` (contact radius ``a_m``, force ``P_m``)
  elastically along the JKR curve of the radius ``R_p = 4 E a_m^3 / (3 (P_m + sqrt(8 pi w E
  a_m^3)))`` shifted to pass through ``(delta_m, P_m)``, down to its snap-off.

With ``w = 0`` this is Thornton's (1997) elastic-plastic law (``a^2 = R delta``, ``a_y = pi p_y
R / (2 E)``), whose restitution is :func:`restitution_without_adhesion` (TN eq. 44).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from . import jkr

__all__ = [
    "TNImpact",
    "loading_force",
    "restitution_without_adhesion",
    "simulate_normal_impact",
    "unloading_curve",
    "yield_radius",
    "yield_velocity_without_adhesion",
]


def yield_radius(R, E, w, p_y) -> float:
    """The contact radius at which the JKR centre pressure reaches ``p_y`` (TN eq. 65)."""
    if w == 0:
        return math.pi * p_y * R / (2.0 * E)

    def excess(a):
        return 2.0 * E * a / (math.pi * R) - math.sqrt(2.0 * w * E / (math.pi * a)) - p_y

    hi = math.pi * R * p_y / (2.0 * E) + (w * R * R / E) ** (1.0 / 3.0)
    while excess(hi) < 0:
        hi *= 2.0
    lo = hi
    while excess(lo) > 0:
        lo *= 0.5
    return brentq(excess, lo, hi, xtol=1e-18, rtol=4 * np.finfo(float).eps, maxiter=300)


def _radius(delta, R, E, w) -> float:
    """The contact radius of the (stable) curve of radius ``R`` at overlap ``delta``."""
    if w == 0:
        return math.sqrt(R * max(delta, 0.0))
    return jkr.contact_radius(delta, R, E, w)


def _elastic_force(a, R, E, w) -> float:
    return float(jkr.force(a, R, E, w))


def _overlap(a, R, E, w) -> float:
    return float(jkr.overlap(a, R, E, w)) if w > 0 else a * a / R


def loading_force(a, R, E, w, a_y, p_y) -> float:
    """The loading force at contact radius ``a``: elastic JKR below ``a_y``, plastic above."""
    if a <= a_y:
        return _elastic_force(a, R, E, w)
    c = math.sqrt(8.0 * math.pi * w * E)
    return (
        _elastic_force(a_y, R, E, w)
        + math.pi * p_y * (a * a - a_y * a_y)
        - c * a_y * (math.sqrt(a) - math.sqrt(a_y))
    )


def unloading_curve(delta_m, R, E, w, a_y, p_y) -> tuple[float, float]:
    """``(R_p, shift)`` of the elastic curve through the largest overlap ``delta_m``: the
    contact radius there is ``a(delta - shift)`` of the JKR curve of ``R_p``."""
    a_m = _radius(delta_m, R, E, w)
    if a_m <= a_y:
        return R, 0.0
    P_m = loading_force(a_m, R, E, w, a_y, p_y)
    R_p = 4.0 * E * a_m**3 / (3.0 * (P_m + math.sqrt(8.0 * math.pi * w * E * a_m**3)))
    return R_p, delta_m - _overlap(a_m, R_p, E, w)


def yield_velocity_without_adhesion(R, E, m, p_y) -> float:
    """Thornton's yield velocity (TN eq. 10, ``w = 0``): ``m V_y^2 / 2 = 8 E a_y^5 /
    (15 R^2)``."""
    a_y = math.pi * p_y * R / (2.0 * E)
    return math.sqrt(16.0 * E * a_y**5 / (15.0 * R * R * m))


def restitution_without_adhesion(speed, R, E, m, p_y) -> float:
    """Thornton's restitution of the law without adhesion (TN eq. 44), 1 below yield."""
    x = yield_velocity_without_adhesion(R, E, m, p_y) / speed
    if x >= 1.0:
        return 1.0
    return (
        math.sqrt(6.0 * math.sqrt(3.0) / 5.0)
        * math.sqrt(1.0 - x * x / 6.0)
        * (x / (x + 2.0 * math.sqrt(6.0 / 5.0 - x * x / 5.0))) ** 0.25
    )


@dataclass
class TNImpact:
    """A Thornton-Ning normal impact: ``status`` (``"rebound"`` or ``"captured"``), the
    rebound speed ``v_out`` (0 when captured), ``contact_time`` (to the snap-off, or to the
    first turn back toward the wall after unloading began), ``max_overlap``, the unloading
    curve's ``R_p`` and the energy lost to damping (``loss_damping``)."""

    status: str
    v_out: float
    contact_time: float
    max_overlap: float
    R_p: float
    loss_damping: float


def simulate_normal_impact(speed, R, E, w, m, p_y, C_H=0.0, rtol=1e-12) -> TNImpact:
    """An impact at ``speed`` (m/s) integrated in three phases (scipy's ``solve_ivp``, events
    located to the tolerance), independently of the engine's closed forms: elastic loading
    to the yield overlap (if reached), plastic loading to the largest overlap (the turning
    point), elastic unloading on the curve of that overlap to its snap-off (rebound) or to a
    turn back toward the wall (captured). ``C_H``: the Hertzian damping of the force's
    Hertzian part ``4 E a^3 / (3 R_p)`` (the curve the state is on), as the engine damps it;
    Thornton and Ning's law has none (0)."""
    if not (speed > 0 and R > 0 and E > 0 and w >= 0 and m > 0 and p_y > 0):
        raise ValueError("speed, R, E, m and p_y must be > 0 and w >= 0")
    a_y = yield_radius(R, E, w, p_y)
    delta_y = _overlap(a_y, R, E, w)
    hertz = (15.0 * m * speed * speed / (16.0 * E * math.sqrt(R))) ** 0.4
    scale = hertz
    if w > 0:
        scale = max(scale, (w * w * R / (E * E)) ** (1.0 / 3.0))
    T = scale / speed
    adhesion = math.sqrt(8.0 * math.pi * w * E)
    options = dict(
        method="DOP853", rtol=rtol, atol=[1e-3 * rtol * scale, 1e-3 * rtol * speed, 1e-30]
    )

    def damped(P, a, v):  # the force less its Hertzian damping (the third state: its work)
        hertz_part = P + adhesion * a**1.5
        return -(P + C_H * hertz_part * v) / m, C_H * hertz_part * v * v

    t, y = _loaded(speed, R, E, w, p_y, a_y, delta_y, T, damped, options)
    return _unloaded(t, y, R, E, w, p_y, a_y, T, damped, options)


def _loaded(speed, R, E, w, p_y, a_y, delta_y, T, damped, options):
    """The loading phases of :func:`simulate_normal_impact` from first touch: elastic to the
    yield overlap (if reached), then plastic to the turning point. Returns the time and state
    ``(overlap, its rate, damping work)`` there."""

    def loading(plastic):
        def rhs(t, y):
            a = _radius(y[0], R, E, w)
            P = loading_force(a, R, E, w, a_y, p_y) if plastic else _elastic_force(a, R, E, w)
            dv, loss = damped(P, a, y[1])
            return [y[1], dv, loss]

        return rhs

    def turned(t, y):
        return y[1]

    turned.terminal, turned.direction = True, -1.0

    def yielded(t, y):
        return y[0] - delta_y

    yielded.terminal, yielded.direction = True, 1.0

    t, y = 0.0, np.array([0.0, float(speed), 0.0])
    if delta_y > 0:  # elastic loading (JKR's snap-in at zero overlap) until yield or turning
        sol = solve_ivp(
            loading(False), (t, 1e4 * T), y, events=(turned, yielded), max_step=0.05 * T, **options
        )
        t, y = float(sol.t[-1]), sol.y[:, -1].copy()
        if sol.status != 1:
            raise RuntimeError(f"the loading did not end: {sol.message}")
        plastic = sol.t_events[1].size > 0
    else:
        plastic = True
    if plastic:
        sol = solve_ivp(
            loading(True), (t, 1e4 * T), y, events=(turned,), max_step=0.05 * T, **options
        )
        if sol.status != 1:
            raise RuntimeError(f"the plastic loading did not end: {sol.message}")
        t, y = float(sol.t[-1]), sol.y[:, -1].copy()
    return t, y


def _unloaded(t, y, R, E, w, p_y, a_y, T, damped, options) -> TNImpact:
    """The elastic unloading of :func:`simulate_normal_impact` from the turning point ``(t,
    y)``, on the curve of the largest overlap, to its snap-off (rebound) or to a turn back
    toward the wall (captured)."""
    delta_m = float(y[0])
    R_p, shift = unloading_curve(delta_m, R, E, w, a_y, p_y)
    delta_c = shift + (jkr.snap_off(R_p, E, w)[1] if w > 0 else 0.0)

    def unloading(t, y):
        a = _radius(y[0] - shift, R_p, E, w)
        dv, loss = damped(_elastic_force(a, R_p, E, w), a, y[1])
        return [y[1], dv, loss]

    def snapped(t, y):
        return y[0] - delta_c

    snapped.terminal, snapped.direction = True, -1.0

    def back(t, y):
        return y[1]

    back.terminal, back.direction = True, 1.0
    y[1] = min(y[1], 0.0)
    sol = solve_ivp(
        unloading, (t, t + 1e4 * T), y, events=(snapped, back), max_step=0.05 * T, **options
    )
    if sol.t_events[0].size:
        end = sol.y_events[0][0]
        return TNImpact(
            "rebound", -float(end[1]), float(sol.t_events[0][0]), delta_m, R_p, float(end[2])
        )
    if sol.t_events[1].size:
        end = sol.y_events[1][0]
        return TNImpact("captured", 0.0, float(sol.t_events[1][0]), delta_m, R_p, float(end[2]))
    raise RuntimeError(f"the unloading did not end: {sol.message}")

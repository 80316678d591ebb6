"""The JKR adhesive normal contact (Johnson, Kendall & Roberts 1971) in closed form, and an exact
elastic JKR normal impact: the oracles of the engine's JKR normal law (``[model] normal =
"jkr"``, docs/physics.md "Normal laws").

Convention: ``w`` is the **work of adhesion** (Dupre, J/m^2), the energy per unit area needed
to separate the two surfaces; for two surfaces of one material ``w = 2 gamma`` with ``gamma``
its surface energy. A code whose pull-off force reads ``3 pi gamma R`` means this ``gamma``.
``R`` and ``E`` are the effective radius and modulus (``E = E*``: ``1/E* = (1 - nu1^2)/E1 +
(1 - nu2^2)/E2``), ``m`` the effective mass; for a sphere on a flat rigid wall ``R`` and ``m``
are the sphere's own.

The contact in terms of the contact radius ``a`` (force ``P`` repulsive positive, overlap
``delta`` positive in compression):

    P(a) = 4 E a^3 / (3 R) - sqrt(8 pi w E a^3),     delta(a) = a^2 / R - sqrt(2 pi w a / E).

In the scales ``a = x lam``, ``lam = (w R^2 / E)^(1/3)``: ``P = w R (4/3 x^3 - sqrt(8 pi)
x^(3/2))`` and ``delta = mu (x^2 - sqrt(2 pi) x^(1/2))``, ``mu = (w^2 R / E^2)^(1/3)``. Hence
(derivations in docs/physics.md, "JKR closed forms"):

- pull-off force under load control ``F_c = 1.5 pi w R``: ``-P`` at its largest, where
  ``dP / da = 0`` (``x^(3/2) = 3 sqrt(2 pi) / 4``);
- at zero overlap (``x0 = (2 pi)^(1/3)``): ``P = -4 pi w R / 3 = -8/9 F_c``; an approaching
  sphere snaps into contact there;
- under displacement control the contact is stable down to the least overlap ``delta_c``
  (``d delta / d a = 0``: ``xc = (pi / 8)^(1/3)``), where ``P = -5 pi w R / 6 = -5/9 F_c`` and
  the sphere snaps off;
- the energy an elastic JKR impact loses (the work of the tensile force between ``delta = 0``
  and ``delta_c``, not given back): ``W = c_W (w^5 R^4 / E^2)^(1/3)`` with
  ``c_W = (1 + 3 2^(5/3)) pi^(5/3) / 10 = 7.0922...``;
- so an elastic JKR sphere sticks below ``V_s = sqrt(2 W / m) = c_s (F_c^5 / (m^3 R E^2))^(1/6)``
  with ``c_s = sqrt(2 c_W) / (3 pi / 2)^(5/6) = 1.0348...``, and rebounds above it with
  ``e = sqrt(1 - (V_s / V)^2)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

__all__ = [
    "C_S",
    "C_W",
    "JKRImpact",
    "energy_loss",
    "force",
    "overlap",
    "pull_off_force",
    "restitution",
    "simulate_normal_impact",
    "snap_off",
    "pull_off",
    "potential",
    "contact_radius",
    "sticking_velocity",
]

#: Energy lost in an elastic JKR impact, in units of (w^5 R^4 / E^2)^(1/3) (docstring).
C_W = (1.0 + 3.0 * 2.0 ** (5.0 / 3.0)) * math.pi ** (5.0 / 3.0) / 10.0
#: Sticking velocity of an elastic JKR impact, in units of (F_c^5 / (m^3 R E^2))^(1/6).
C_S = math.sqrt(2.0 * C_W) / (1.5 * math.pi) ** (5.0 / 6.0)

_SQRT_2PI = math.sqrt(2.0 * math.pi)
#: Contact radius (in ``lam``) at zero overlap and at the least overlap (snap-off).
_X0 = (2.0 * math.pi) ** (1.0 / 3.0)
_XC = (math.pi / 8.0) ** (1.0 / 3.0)


def _scales(R, E, w):
    lam = (w * R * R / E) ** (1.0 / 3.0)
    mu = (w * w * R / (E * E)) ** (1.0 / 3.0)
    return lam, mu


def force(a, R, E, w):
    """JKR force (N, repulsive positive) at contact radius ``a`` (m)."""
    a = np.asarray(a, float)
    return 4.0 * E * a**3 / (3.0 * R) - np.sqrt(8.0 * math.pi * w * E * a**3)


def overlap(a, R, E, w):
    """JKR overlap (m, positive in compression) at contact radius ``a`` (m)."""
    a = np.asarray(a, float)
    return a * a / R - np.sqrt(2.0 * math.pi * w * a / E)


def pull_off_force(R, w):
    """``F_c = 1.5 pi w R``: the largest tensile force under load control (N, positive)."""
    return 1.5 * math.pi * w * R


def snap_off(R, E, w) -> tuple[float, float, float]:
    """The least overlap of the stable branch, where a receding sphere snaps off: ``(a_c,
    delta_c, P_c)`` (``P_c = -5/9 F_c``)."""
    lam, _ = _scales(R, E, w)
    a = _XC * lam
    return a, float(overlap(a, R, E, w)), float(force(a, R, E, w))


#: Contact radius (in ``lam``) at the load-controlled pull-off, where the force is least.
_XP = (9.0 * math.pi / 8.0) ** (1.0 / 3.0)


def pull_off(R, E, w) -> tuple[float, float, float]:
    """The load-controlled pull-off, where the force is least (``-F_c``): ``(a_p, delta_p,
    P_p)``; a contact that ends there (LAMMPS's rule) ends before the snap-off."""
    lam, _ = _scales(R, E, w)
    a = _XP * lam
    return a, float(overlap(a, R, E, w)), float(force(a, R, E, w))


def potential(a, R, E, w) -> float:
    """The JKR potential (J) at contact radius ``a`` on the stable branch, zero at first touch
    (``a0 = (2 pi)^(1/3) lam``): ``G(a) - G(a0)`` with ``G' = P dn/da``; at the snap-off it is
    :func:`energy_loss`."""

    def G(x):
        K = 4.0 * E / 3.0
        return (
            0.4 * K * x**5 / R**2
            - 8.0 / (3.0 * R) * math.sqrt(3.0 * math.pi * w * K / 8.0) * x**3.5
            + math.pi * w * x * x
        )

    lam, _ = _scales(R, E, w)
    return G(a) - G(_X0 * lam)


def contact_radius(delta, R, E, w) -> float:
    """Contact radius on the stable branch (``a >= a_c``) at overlap ``delta >= delta_c``."""
    lam, mu = _scales(R, E, w)
    d = delta / mu  # x^2 - sqrt(2 pi) x^(1/2) = d, increasing in x above _XC
    g = lambda y: y**4 - _SQRT_2PI * y - d  # noqa: E731  (y = sqrt(x))
    lo = math.sqrt(_XC)
    if g(lo) >= 0.0:
        return _XC * lam
    hi = max(2.0 * lo, (abs(d) + _SQRT_2PI) ** 0.25 + 1.0)
    y = brentq(g, lo, hi, xtol=1e-15, rtol=4 * np.finfo(float).eps, maxiter=200)
    return y * y * lam


def energy_loss(R, E, w) -> float:
    """``W = C_W (w^5 R^4 / E^2)^(1/3)``: the energy an elastic JKR impact loses (J)."""
    return C_W * (w**5 * R**4 / E**2) ** (1.0 / 3.0)


def sticking_velocity(R, E, w, m) -> float:
    """``V_s = C_S (F_c^5 / (m^3 R E^2))^(1/6) = sqrt(2 W / m)`` (m/s)."""
    return C_S * (pull_off_force(R, w) ** 5 / (m**3 * R * E * E)) ** (1.0 / 6.0)


def restitution(speed, R, E, w, m) -> float:
    """``e = sqrt(1 - (V_s / V)^2)`` above the sticking velocity, else 0 (captured)."""
    ratio = sticking_velocity(R, E, w, m) / speed
    return math.sqrt(1.0 - ratio * ratio) if ratio < 1.0 else 0.0


@dataclass
class JKRImpact:
    """An elastic JKR normal impact: ``status`` ``"rebound"`` or ``"captured"``, the rebound
    speed ``v_out`` (m/s, 0 when captured), ``contact_time`` (s, to the snap-off, or to the
    first turn back toward the wall of a captured sphere), ``max_overlap`` (m)."""

    status: str
    v_out: float
    contact_time: float
    max_overlap: float


def simulate_normal_impact(speed, R, E, w, m, rtol=1e-12) -> JKRImpact:
    """The impact of a sphere arriving at ``speed`` (m/s) integrated exactly (scipy's
    ``solve_ivp``, events located to the tolerance), independent of the closed forms above:
    it snaps into contact at zero overlap (``a`` jumps to its zero-overlap value), follows the
    stable branch ``m delta'' = -P(delta)`` in and out, and snaps off at ``delta_c`` moving
    out (rebound); a sphere that turns back toward the wall before reaching ``delta_c`` is
    captured (it oscillates in the contact for ever: no damping)."""
    if not (speed > 0 and R > 0 and E > 0 and w > 0 and m > 0):
        raise ValueError("speed, R, E, w and m must be > 0")
    _, delta_c, _ = snap_off(R, E, w)
    _, mu = _scales(R, E, w)
    # Time scale of the contact: its overlap scale (Hertz's largest overlap at this speed, or
    # the adhesion's own) over the speed.
    hertz = (15.0 * m * speed * speed / (16.0 * E * math.sqrt(R))) ** 0.4
    T = max(hertz, mu) / speed

    def rhs(t, y):
        a = contact_radius(y[0], R, E, w)
        return [y[1], -float(force(a, R, E, w)) / m]

    def snapped(t, y):  # reaches the least overlap moving out
        return y[0] - delta_c

    snapped.terminal, snapped.direction = True, -1.0

    def turned(t, y):  # velocity back toward the wall after moving out
        return y[1]

    turned.terminal, turned.direction = True, 1.0

    sol = solve_ivp(
        rhs, (0.0, 1e4 * T), [0.0, float(speed)], method="DOP853", rtol=rtol,
        atol=[1e-3 * rtol * max(hertz, mu), 1e-3 * rtol * speed],
        events=(snapped, turned), max_step=0.05 * T,
    )  # fmt: skip
    max_overlap = float(np.max(sol.y[0]))
    if sol.t_events[0].size:
        v_out = -float(sol.y_events[0][0][1])
        return JKRImpact("rebound", v_out, float(sol.t_events[0][0]), max_overlap)
    if sol.t_events[1].size:
        return JKRImpact("captured", 0.0, float(sol.t_events[1][0]), max_overlap)
    raise RuntimeError(f"the JKR impact did not end: {sol.message}")

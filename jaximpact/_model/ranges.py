"""The range of every scene and impact input, and the plausibility of results.

One table, :data:`RANGES`, serves every way in: ``simulate`` (scene, arguments), the scene
file, the impacts CSV, the sweep grid, and ``fitting`` (starting values, fitted values,
priors, data columns, design candidates). A value outside its range is an error naming the
field and the range. The ranges are wide: they exclude what the model cannot mean (a negative
radius, an impact at or beyond 90 degrees) and values that are certainly a slip of units or a
regime the model does not describe (a speed of 1e6 m/s, a friction coefficient of 60); the
reasons are in docs/input_ranges.md.

A result inside the ranges can still lie outside what the model describes. Hertz contact is
a small-strain theory: where the maximum overlap exceeds :data:`MAX_OVERLAP_RATIO` of the
radius (contact radius ``a = sqrt(r n)`` above about a third of the radius), the impact is
flagged ``large_overlap`` (:func:`implausible`): a warning and a flag column, not an error.
Numpy only (no JAX), so that the table readers can use it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "IMPLAUSIBLE",
    "MAX_OVERLAP_RATIO",
    "RANGES",
    "Range",
    "hertz_overlap_ratio",
    "implausible",
]


@dataclass(frozen=True)
class Range:
    """An allowed interval: ``lo`` and ``hi`` with whether each end is allowed, and the unit
    (``"1"``: dimensionless)."""

    lo: float
    hi: float
    unit: str
    lo_closed: bool = True
    hi_closed: bool = True

    def contains(self, value) -> np.ndarray:
        """Whether each value (a float or an array) is finite and inside the range."""
        v = np.asarray(value, dtype=np.float64)
        above = v >= self.lo if self.lo_closed else v > self.lo
        below = v <= self.hi if self.hi_closed else v < self.hi
        return np.isfinite(v) & above & below

    def interval(self) -> str:
        """``(0, 1000] m/s``."""
        left = "[" if self.lo_closed else "("
        right = "]" if self.hi_closed else ")"
        unit = "" if self.unit == "1" else f" {self.unit}"
        return f"{left}{_g(self.lo)}, {_g(self.hi)}{right}{unit}"

    def inner(self) -> str:
        """The range without its ends, ``(0, 10)``: where a fit on a logit scale may start."""
        unit = "" if self.unit == "1" else f" {self.unit}"
        return f"({_g(self.lo)}, {_g(self.hi)}){unit}"


def _g(x: float) -> str:
    """``1000``, ``1e6``, ``1e-9``: short, without ``e+06``."""
    if math.isinf(x):
        return "inf"
    if x != 0 and not 1e-3 <= abs(x) < 1e4:
        mantissa, exponent = f"{x:e}".split("e")
        return f"{mantissa.rstrip('0').rstrip('.')}e{int(exponent)}"
    return f"{x:g}"


#: The documented range of every input (docs/input_ranges.md), by impacts-CSV column name
#: (``lambda`` is ``model.lambda``); ``E``, ``nu``, ``zeta`` stand for ``E1``/``E2``,
#: ``nu1``/``nu2`` and ``zeta_A``/``zeta_H`` of a scene file.
RANGES = {
    "speed": Range(0.0, 1e3, "m/s", lo_closed=False),
    "angle_deg": Range(-90.0, 90.0, "deg", lo_closed=False, hi_closed=False),
    "omega0": Range(-1e9, 1e9, "rad/s"),
    "radius": Range(1e-9, 1.0, "m"),
    "density": Range(0.0, 1e5, "kg/m^3", lo_closed=False),
    "K": Range(0.0, 1e13, "Pa", lo_closed=False),
    "f0": Range(0.0, 1e6, "N/m"),
    "C_A": Range(0.0, 1e4, "s/m"),
    "C_H": Range(0.0, 1e4, "s/m"),
    "friction": Range(0.0, 10.0, "1"),
    "lambda": Range(0.0, 100.0, "N m"),
    "G_star": Range(0.0, 1e13, "Pa"),  # 0: not given (needed > 0 by tangential = "mindlin")
    "w": Range(0.0, 1e4, "J/m^2"),  # work of adhesion of model.normal = "dmt" or "jkr"
    "p_y": Range(0.0, 1e13, "Pa"),  # limiting contact pressure of "thornton_ning" (0: not given)
    "k_t": Range(0.0, 1e12, "N/m"),  # LAMMPS's linear_history stiffness (0: not given)
    # a LAMMPS normal damping's coefficient (model.damping); its unit is the model's
    "eta_n": Range(0.0, 1e18, "kg/s, 1/s, 1/(m s) or 1 (model.damping)"),
    # the second sphere of a sphere-sphere impact ([target])
    "radius2": Range(1e-9, 1e12, "m"),
    "density2": Range(0.0, 1e30, "kg/m^3", lo_closed=False),
    "omega2": Range(-1e9, 1e9, "rad/s"),
    "E": Range(0.0, 1e13, "Pa", lo_closed=False),
    "nu": Range(-1.0, 0.5, "1", lo_closed=False),
    "zeta": Range(0.0, 1e6, "1"),
    "reference_speed": Range(0.0, 1e3, "m/s", lo_closed=False),
}


def range_text(name: str, field: str | None = None) -> str:
    """``speed must be finite and in (0, 1000] m/s``: the rule, naming ``field`` (default
    ``name``)."""
    return f"{field or name} must be finite and in {RANGES[name].interval()}"


# ---------------------------------------------------------------------------------------------
# Plausibility of results

#: A maximum overlap beyond this fraction of the radius is outside the small-strain range of
#: Hertz contact (the contact radius ``sqrt(r n)`` is then above 0.32 of the sphere's radius).
MAX_OVERLAP_RATIO = 0.1

#: Flags of physically implausible results (the ``implausible`` column), with their meaning.
IMPLAUSIBLE = {
    "large_overlap": f"maximum overlap above {MAX_OVERLAP_RATIO:g} of the radius, beyond the "
    "small-strain range of Hertz contact",
}


def hertz_overlap_ratio(density, K, speed, angle_deg) -> np.ndarray:
    """The maximum overlap of an elastic Hertz impact over the radius (no damping, no
    adhesion): ``n*/r = (5 pi rho v_n^2 / (3 K))^(2/5)``, whatever the radius."""
    v_n = np.asarray(speed, float) * np.cos(np.deg2rad(np.asarray(angle_deg, float)))
    rho, K = np.asarray(density, float), np.asarray(K, float)
    return (5.0 * math.pi * rho * v_n**2 / (3.0 * K)) ** 0.4


def implausible(radius, max_overlap, density, K, speed, angle_deg) -> np.ndarray:
    """The ``implausible`` flag of each impact: ``"large_overlap"`` or ``""``.

    The ratio is the simulated ``max_overlap / radius`` where it is known, else (an impact
    that failed, or ``solver.outputs = "rebound"``, which does not record it) the elastic
    Hertz estimate :func:`hertz_overlap_ratio`. Arguments broadcast together.
    """
    radius, max_overlap = np.asarray(radius, float), np.asarray(max_overlap, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(
            np.isfinite(max_overlap),
            max_overlap / radius,
            hertz_overlap_ratio(density, K, speed, angle_deg),
        )
    return np.where(ratio > MAX_OVERLAP_RATIO, "large_overlap", "").astype(object)

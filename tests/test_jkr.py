"""JKR oracles (jaximpact.reference.jkr) against their definitions, computed independently:
the force-overlap curve's extremes by numerical minimization, the energy lost by quadrature,
and the sticking velocity and restitution by integrating the impact itself."""

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import minimize_scalar

from jaximpact.reference import jkr

# A 20 um glass-like sphere on a stiff wall; and a softer, stickier pair.
CASES = [
    dict(R=20e-6, E=5e10, w=0.1, rho=2500.0),
    dict(R=3e-6, E=2e9, w=0.5, rho=1000.0),
]


def _mass(c):
    return 4.0 / 3.0 * math.pi * c["R"] ** 3 * c["rho"]


@pytest.mark.parametrize("c", CASES)
def test_force_at_zero_overlap_and_pull_off(c):
    """At zero overlap ``P = -8/9 F_c``; the largest tension on the curve (load control) is
    ``F_c = 1.5 pi w R``."""
    R, E, w = c["R"], c["E"], c["w"]
    F_c = jkr.pull_off_force(R, w)
    assert F_c == pytest.approx(1.5 * math.pi * w * R, rel=1e-15)
    a0 = jkr.contact_radius(0.0, R, E, w)
    assert abs(float(jkr.overlap(a0, R, E, w))) < 1e-12 * a0 * a0 / R
    assert float(jkr.force(a0, R, E, w)) == pytest.approx(-8.0 / 9.0 * F_c, rel=1e-9)
    best = minimize_scalar(lambda a: float(jkr.force(a, R, E, w)), bounds=(1e-3 * a0, a0),
                           method="bounded", options={"xatol": 1e-12 * a0})  # fmt: skip
    assert best.fun == pytest.approx(-F_c, rel=1e-9)


@pytest.mark.parametrize("c", CASES)
def test_snap_off_under_displacement_control(c):
    """The stable branch ends at the least overlap (``d delta / d a = 0``), where the force is
    ``-5/9 F_c``."""
    R, E, w = c["R"], c["E"], c["w"]
    a_c, delta_c, P_c = jkr.snap_off(R, E, w)
    a0 = jkr.contact_radius(0.0, R, E, w)
    least = minimize_scalar(lambda a: float(jkr.overlap(a, R, E, w)), bounds=(1e-3 * a0, a0),
                            method="bounded", options={"xatol": 1e-12 * a0})  # fmt: skip
    assert least.x == pytest.approx(a_c, rel=1e-5)  # a flat minimum: its place to sqrt(eps)
    assert least.fun == pytest.approx(delta_c, rel=1e-10)
    assert P_c == pytest.approx(-5.0 / 9.0 * jkr.pull_off_force(R, w), rel=1e-12)
    # the stable branch's inverse: overlap -> contact radius -> the same overlap
    for delta in np.linspace(delta_c, 5 * abs(delta_c), 7):
        a = jkr.contact_radius(delta, R, E, w)
        assert a >= a_c * (1 - 1e-12)
        assert float(jkr.overlap(a, R, E, w)) == pytest.approx(delta, abs=1e-12 * abs(delta_c))


@pytest.mark.parametrize("c", CASES)
def test_energy_lost_is_the_tensile_work_between_zero_overlap_and_snap_off(c):
    """``W = c_W (w^5 R^4 / E^2)^(1/3)`` against the quadrature of ``-P d delta`` along the
    stable branch from the snap-off to zero overlap; c_W about 7.09 (the issue's numerical
    check)."""
    R, E, w = c["R"], c["E"], c["w"]
    a_c, _, _ = jkr.snap_off(R, E, w)
    a0 = jkr.contact_radius(0.0, R, E, w)

    def integrand(a):  # -P(a) d delta / d a, the slope by a central difference
        h = 1e-6 * a
        slope = float(jkr.overlap(a + h, R, E, w) - jkr.overlap(a - h, R, E, w)) / (2 * h)
        return -float(jkr.force(a, R, E, w)) * slope

    work, _ = quad(integrand, a_c, a0, epsabs=0.0, epsrel=1e-12, limit=200)
    assert jkr.energy_loss(R, E, w) == pytest.approx(work, rel=1e-8)
    assert jkr.C_W == pytest.approx(7.09, abs=0.005)


@pytest.mark.parametrize("c", CASES)
def test_impact_sticks_below_and_rebounds_above_the_sticking_velocity(c):
    """The exact impact (integrated, no closed form used) against ``V_s = c_s (F_c^5 /
    (m^3 R E^2))^(1/6)`` and ``e = sqrt(1 - (V_s / V)^2)`` (``e^2`` to 1e-8); c_s about
    1.035 with the work of adhesion ``w`` (the issue's numerical check)."""
    R, E, w = c["R"], c["E"], c["w"]
    m = _mass(c)
    V_s = jkr.sticking_velocity(R, E, w, m)
    assert V_s == pytest.approx(math.sqrt(2 * jkr.energy_loss(R, E, w) / m), rel=1e-12)
    assert jkr.C_S == pytest.approx(1.035, abs=5e-4)
    for ratio in (0.5, 0.995):
        assert jkr.simulate_normal_impact(ratio * V_s, R, E, w, m).status == "captured"
    for ratio in (1.005, 1.5, 4.0, 40.0):
        V = ratio * V_s
        hit = jkr.simulate_normal_impact(V, R, E, w, m)
        assert hit.status == "rebound" and hit.max_overlap > 0
        # the kinetic energy left, to 1e-8 of the incoming (e itself near V_s is 1 / e more
        # sensitive)
        e = jkr.restitution(V, R, E, w, m)
        assert abs((hit.v_out / V) ** 2 - e * e) < 1e-8, (ratio, hit.v_out / V, e)


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="must be > 0"):
        jkr.simulate_normal_impact(1.0, 20e-6, 5e10, 0.0, 1e-12)

"""Tests of the exact switched reference model (jaximpact.reference) against known physics.

Each check is an independent property (quadrature, closed-form Hertz, rigid-body impulse
relations, symmetry, energy ledger), not a stored output of the reference itself.
"""

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import dblquad, quad

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from jaximpact.reference import (  # noqa: E402
    TABLE1_OMEGA0,
    TABLE1_SPEED,
    Params,
    contact_forces,
    hertz_scales,
    impact_history,
    ring_integrals,
    simulate_impact,
    table1_params,
    zeta_to_c,
)

R, RHO, K = 35e-6, 8000.0, 11.4e10


def hertz_only(**kw):
    """Non-adhesive, undamped scene unless overridden."""
    base = dict(radius=R, density=RHO, K=K, adhesion=False, rolling_moments="none")
    base.update(kw)
    return Params(**base)


def hertz_time_integral():
    """int_0^1 dx / sqrt(1 - x^2.5), with the (1-x)^-1/2 end singularity as a quad weight."""

    def f(x):
        return math.sqrt((1 - x) / (1 - x**2.5)) if x < 1 else 1 / math.sqrt(2.5)

    return quad(f, 0, 1, weight="alg", wvar=(0, -0.5), epsabs=0, epsrel=1e-13)[0]


# ---------------------------------------------------------------- contact laws


def test_ring_integrals_match_quadrature():
    rng = np.random.default_rng(0)
    samples = [(rng.normal(), rng.normal()) for _ in range(300)]
    samples += [(0.3, 0.0), (-0.3, 0.0), (0.0, 0.0), (0.5, 0.5), (-0.5, 0.5), (0.5, -0.5)]
    for ndot, b in samples:
        i0, i1 = ring_integrals(ndot, b)

        def neg(al, ndot=ndot, b=b):
            return max(-(ndot + b * math.cos(al)), 0.0)

        # break the range where u changes sign so that quad sees smooth pieces
        pts = []
        if b != 0 and abs(ndot) < abs(b):
            beta = math.acos(-ndot / b)
            pts = [beta, 2 * math.pi - beta]
        q0 = quad(neg, 0, 2 * math.pi, points=pts or None, epsabs=1e-13, limit=200)[0]
        q1 = quad(
            lambda al, g=neg: g(al) * math.cos(al),
            0,
            2 * math.pi,
            points=pts or None,
            epsabs=1e-13,
            limit=200,
        )[0]
        assert i0 == pytest.approx(q0, abs=1e-10)
        assert i1 == pytest.approx(q1, abs=1e-10)
        assert i0 >= 0
        assert i1 * b <= 1e-15  # the peeling moment opposes the spin


def test_adhesion_damping_limits():
    p = table1_params()
    n, w = 5e-8, 2e4
    a = math.sqrt(p.radius * n)
    cd = p.f0 * p.C_A
    # whole ring separating: F_AD = 2 pi a f0 C_A (-ndot), M_A = -pi f0 C_A a^3 w
    fc = contact_forces(p, n, -1.0, w)
    assert -1.0 < -a * w
    assert fc["F_AD"] == pytest.approx(2 * math.pi * a * cd * 1.0, rel=1e-14)
    assert fc["M_A"] == pytest.approx(-math.pi * cd * a**3 * w, rel=1e-14)
    # whole ring approaching: nothing
    fc = contact_forces(p, n, 1.0, w)
    assert fc["F_AD"] == 0 and fc["M_A"] == 0
    # no spin: the plain separating-only damping
    fc = contact_forces(p, n, -0.2, 0.0)
    assert fc["F_AD"] == pytest.approx(2 * math.pi * a * cd * 0.2, rel=1e-14)
    # "none"/"lambda": the spin does not enter the ring
    for mode in ("none", "lambda"):
        q = table1_params(rolling_moments=mode, lam=1e-4)
        fc = contact_forces(q, n, 0.1 * a * w, w)
        assert fc["F_AD"] == 0 and fc["M_A"] == 0
        fc = contact_forces(q, n, -0.2, w)
        assert fc["F_AD"] == pytest.approx(2 * math.pi * a * cd * 0.2, rel=1e-14)
    assert contact_forces(table1_params(rolling_moments="lambda", lam=1e-4), n, 0.0, w)[
        "M"
    ] == pytest.approx(-1e-4 * p.C_A * a * w, rel=1e-14)
    # out of contact: nothing at all
    assert all(v == 0 for v in contact_forces(p, -1e-9, -1.0, w).values())


def test_hertz_rolling_moment_is_the_pressure_integral():
    # eq. (15)-(16): M_H = -(3K/2pi) sqrt(n/r) C_H w int_0^a int_0^2pi rho^3 sqrt(1 - rho^2/a^2)
    # cos^2 dalpha drho (sign: opposing the spin), which must equal -(K/5) sqrt(n/r) C_H a^4 w
    p = table1_params()
    n, w = 8e-8, 3e4
    a = math.sqrt(p.radius * n)
    val = dblquad(
        lambda al, rho: rho**3 * math.sqrt(max(1 - (rho / a) ** 2, 0.0)) * math.cos(al) ** 2,
        0,
        a,
        0,
        2 * math.pi,
        epsabs=0,
        epsrel=1e-10,
    )[0]
    expected = -(3 * p.K / (2 * math.pi)) * math.sqrt(n / p.radius) * p.C_H * w * val
    assert contact_forces(p, n, 0.5, w)["M_H"] == pytest.approx(expected, rel=1e-8)


def test_table1_damping_constants():
    assert zeta_to_c(400, R, RHO, K, 1.66) == pytest.approx(0.882, abs=1e-3)
    assert zeta_to_c(100, R, RHO, K, 1.66) == pytest.approx(0.220, abs=1e-3)
    p = table1_params()
    assert (p.radius, p.density, p.K, p.f0, p.friction, p.lam) == (R, RHO, K, 325.0, 0.3, 0.0)


# ---------------------------------------------------------------- normal impact


@pytest.mark.parametrize("speed", [0.05, 1.66, 40.0])
def test_undamped_hertz_closed_form(speed):
    p = hertz_only()
    res = simulate_impact(p, speed)
    n_star, t_star = hertz_scales(p, speed)
    assert n_star == pytest.approx(
        (5 * p.mass * speed**2 / (4 * K * math.sqrt(R))) ** 0.4, rel=1e-15
    )
    assert res.status == "rebound"
    assert res.vn_out / speed == pytest.approx(1.0, abs=1e-9)
    assert res.contact_time == pytest.approx(2 * t_star * hertz_time_integral(), rel=1e-9)
    assert res.max_overlap == pytest.approx(n_star, rel=1e-9)
    assert res.vt_out == 0 and res.omega_out == 0
    assert abs(res.ledger_residual) < 1e-9


def test_hertz_contact_time_constant():
    # the brief's 2.94351 is the same constant to about 1e-4
    assert 2 * hertz_time_integral() == pytest.approx(2.94351, rel=1e-4)


def test_capture_and_rebound():
    p = table1_params()
    low = simulate_impact(p, 0.03)
    high = simulate_impact(p, 1.0)
    assert low.status == "captured" and low.n_out > 0
    assert high.status == "rebound" and 0 < high.vn_out < 1.0
    for res in (low, high):
        assert abs(res.ledger_residual) < 1e-9
    # a declared capture stays captured when integrated on (no capture event, time limit)
    on = simulate_impact(p, 0.03, detect_capture=False, t_max=30 * low.contact_time)
    assert on.status == "failed" and "time limit" in on.message
    # the same with spin, where the partial ring couples rotation into the normal motion
    spin = simulate_impact(p, 0.03, 0.0, TABLE1_OMEGA0)
    assert spin.status == "captured"
    on = simulate_impact(
        p, 0.03, 0.0, TABLE1_OMEGA0, detect_capture=False, t_max=30 * spin.contact_time
    )
    assert on.status == "failed" and "time limit" in on.message


def test_restitution_falls_with_damping():
    e = [simulate_impact(hertz_only(C_H=c), 1.66).vn_out / 1.66 for c in (0.0, 0.1, 0.3)]
    assert e[0] > e[1] > e[2] > 0


# ---------------------------------------------------------------- tangential, rigid-body limits


def test_full_sliding_impulse_ratio():
    # sliding throughout, no adhesion: int |F_n| dt = m (1 + e) v_n, so
    # dvt = -f (1 + e) v_n and d(omega) = -r dvt / k^2
    p = hertz_only(K=1e13, C_H=0.2, friction=0.3, rotation=True)
    speed, ang = 2.0, 75.0
    v_n, v_t = speed * math.cos(math.radians(ang)), speed * math.sin(math.radians(ang))
    res = simulate_impact(p, speed, ang, 0.0)
    e = res.vn_out / v_n
    assert e < 0.99 and math.isnan(res.roll_time)
    dvt = -p.friction * (1 + e) * v_n
    assert res.vt_out - v_t == pytest.approx(dvt, rel=1e-9)
    assert res.omega_out == pytest.approx(-p.radius * dvt / p.k2, rel=1e-9)
    # without rotation the same impulse, and no spin
    q = hertz_only(K=1e13, C_H=0.2, friction=0.3, rotation=False)
    res = simulate_impact(q, speed, ang, 0.0)
    assert res.vt_out - v_t == pytest.approx(-q.friction * (1 + res.vn_out / v_n) * v_n, rel=1e-9)
    assert res.omega_out == 0


@pytest.mark.parametrize("omega0", [0.0, 3e4, -3e4])
def test_rolling_exit_conserves_contact_angular_momentum(omega0):
    # slip reaches zero, no rolling moments: the sphere leaves rolling with
    # vt = r w = (5 vt0 + 2 r w0) / 7 (kappa = 2/5)
    p = hertz_only(K=1e13, C_H=0.1, friction=0.5)
    speed, ang = 1.0, 8.0
    v_t = speed * math.sin(math.radians(ang))
    res = simulate_impact(p, speed, ang, omega0)
    assert 0 < res.roll_time < res.contact_time
    target = (5 * v_t + 2 * p.radius * omega0) / 7
    assert res.vt_out == pytest.approx(target, rel=1e-9, abs=1e-12)
    assert p.radius * res.omega_out == pytest.approx(target, rel=1e-9, abs=1e-12)


def test_sticking_without_rotation():
    p = hertz_only(friction=0.5, C_H=0.1, rotation=False)
    res = simulate_impact(p, 1.0, 10.0, 5e4)  # omega0 is ignored without rotation
    assert res.vt_out == 0 and res.omega_out == 0 and 0 < res.roll_time < res.contact_time
    assert abs(res.ledger_residual) < 1e-9


@pytest.mark.parametrize("moments", ["none", "analytical", "lambda"])
def test_mirror_symmetry(moments):
    p = table1_params(rolling_moments=moments, lam=1e-5)
    a = simulate_impact(p, 1.2, 30.0, 0.5 * TABLE1_OMEGA0)
    b = simulate_impact(p, 1.2, -30.0, -0.5 * TABLE1_OMEGA0)
    assert b.vn_out == pytest.approx(a.vn_out, rel=1e-9)
    assert b.vt_out == pytest.approx(-a.vt_out, rel=1e-9)
    assert b.omega_out == pytest.approx(-a.omega_out, rel=1e-9)
    assert b.contact_time == pytest.approx(a.contact_time, rel=1e-9)


# ---------------------------------------------------------------- energy ledger


@pytest.mark.parametrize("moments", ["none", "analytical", "lambda"])
@pytest.mark.parametrize("angle", [-40.0, 40.0, 70.0])
@pytest.mark.parametrize("load", ["net", "hertz"])
def test_ledger_closes_and_losses_are_dissipative(moments, angle, load):
    p = table1_params(rolling_moments=moments, lam=1e-5, friction_load=load)
    res = simulate_impact(p, TABLE1_SPEED, angle, TABLE1_OMEGA0)
    assert res.status == "rebound"
    assert abs(res.ledger_residual) < 1e-9
    tol = 1e-12 * res.energy_in
    assert res.loss_hertz_damping > 0
    assert res.loss_friction > 0
    if moments == "analytical":
        # F_AD ndot alone can be positive (partial ring), F_AD ndot + M_A w cannot
        assert res.loss_adhesion_damping + res.loss_rolling >= -tol
    else:
        assert res.loss_adhesion_damping > 0
        assert res.loss_rolling >= -tol
    assert res.energy_out < res.energy_in


def test_random_scenes_ledger_and_friction_cone():
    rng = np.random.default_rng(7)
    for _ in range(12):
        moments = str(rng.choice(["none", "analytical", "lambda"]))
        p = table1_params(
            rolling_moments=moments,
            lam=float(10 ** rng.uniform(-8, -3)),
            friction=float(rng.choice([0.0, 0.1, 0.5])),
            friction_load=str(rng.choice(["net", "hertz"])),
            f0=float(325 * 10 ** rng.uniform(-1, 1)),
            C_A=float(10 ** rng.uniform(-1.5, 0.5)),
            C_H=float(10 ** rng.uniform(-1.5, 0.3)),
        )
        speed = float(10 ** rng.uniform(-0.5, 1.2))
        angle = float(rng.uniform(-85, 85))
        omega0 = float(rng.normal() * 2 * TABLE1_OMEGA0)
        h, res = impact_history(p, speed, angle, omega0)
        assert res.status in ("rebound", "captured")
        assert abs(res.ledger_residual) < 1e-9
        rolling = h["mode"] == 0
        sliding = np.abs(h["mode"]) == 1
        scale = max(speed, abs(omega0) * p.radius)
        assert np.all(h["slip"][rolling] == 0)
        assert np.all(h["slip"][sliding] * h["mode"][sliding] >= -1e-12 * scale)
        cone = p.friction * h["N"][rolling] * (1 + 1e-6) + 1e-12 * np.max(h["N"])
        assert np.all(np.abs(h["F_t"][rolling]) <= cone)
        assert np.all(h["n"] >= 0) and np.all(np.diff(h["t"]) >= 0)


# ---------------------------------------------------------------- the paper's scene


def test_table1_spinning_normal_impact():
    omega0 = TABLE1_OMEGA0
    res = {
        m: simulate_impact(table1_params(rolling_moments=m), TABLE1_SPEED, 0.0, omega0)
        for m in ("none", "analytical")
    }
    for r in res.values():
        assert r.status == "rebound" and 0 < r.roll_time < r.contact_time
    # friction brings the contact point to rest: the spin drops to 2/7 of omega0 (angular
    # momentum about the contact point); the analytical rolling moments change that very little
    assert res["none"].omega_out == pytest.approx(2 / 7 * omega0, rel=1e-9)
    assert res["analytical"].omega_out == pytest.approx(res["none"].omega_out, rel=1e-3)
    # and after rolling starts the spin stays nearly constant with the analytical moments
    h, r = impact_history(table1_params(), TABLE1_SPEED, 0.0, omega0)
    after = h["w"][h["t"] >= r.roll_time]
    assert np.ptp(after) < 1e-3 * abs(after[0])
    # a huge constant lambda stops the spin during contact
    big = simulate_impact(
        table1_params(rolling_moments="lambda", lam=1e-3), TABLE1_SPEED, 0, omega0
    )
    assert big.status == "rebound" and abs(big.omega_out) < 1e-6 * omega0


def test_table1_oblique_spin_direction():
    # paper, Fig. 5: with the analytical model the spin keeps its sign at +40 degrees
    # and reverses at -40 degrees
    p = table1_params()
    plus = simulate_impact(p, TABLE1_SPEED, 40.0, TABLE1_OMEGA0)
    minus = simulate_impact(p, TABLE1_SPEED, -40.0, TABLE1_OMEGA0)
    assert plus.omega_out > 0 > minus.omega_out


def test_history_dense_sampling_matches_result():
    p = table1_params()
    h, res = impact_history(p, TABLE1_SPEED, 40.0, TABLE1_OMEGA0, n_samples=300)
    assert len(h["t"]) == 300 and h["t"][0] == 0 and h["t"][-1] == res.contact_time
    assert h["n"][0] == 0 and h["n"][-1] < 1e-20
    assert np.max(h["n"]) <= res.max_overlap * (1 + 1e-12)
    assert h["tdot"][-1] == pytest.approx(res.vt_out, rel=1e-12)
    assert h["w"][-1] == pytest.approx(res.omega_out, rel=1e-12)
    # the dense grid resolves the peak overlap and respects the friction cone
    assert np.max(h["n"]) == pytest.approx(res.max_overlap, rel=1e-3)
    rolling = h["mode"] == 0
    assert np.all(np.abs(h["F_t"][rolling]) <= p.friction * h["N"][rolling] * (1 + 1e-6) + 1e-15)


def test_invalid_input():
    with pytest.raises(ValueError):
        Params(radius=R, density=RHO, K=K, rolling_moments="bogus")
    with pytest.raises(ValueError):
        simulate_impact(table1_params(), 1.0, 90.0)
    with pytest.raises(ValueError):
        simulate_impact(table1_params(), -1.0)

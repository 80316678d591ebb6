"""Tests of the safe helpers, the force and moment laws, and the energy ledger of the ODE.

Every law is checked against an independent closed form (written out here in numpy, from the
model's equations) or a numerical quadrature (scipy), in SI units with realistic values; the
assembled vector field is checked in Hertz units with O(1) parameters.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy import integrate

from jaximpact._model import dynamics as _dynamics
from jaximpact._model import laws as _laws
from jaximpact._model import safe as _safe
from jaximpact._model.units import ScaledParameters

jax.config.update("jax_enable_x64", True)

# Realistic SI values (Table 1 of Brach, Dunn & Cheng 1999, CONVENTIONS).
R = 35e-6  # radius, m
K = 1.14e11  # Pa
F0 = 325.0  # N/m
C_A = 0.88  # s/m
C_H = 0.22  # s/m
LAM = 1e-7  # N m
N_TYPICAL = 1e-8  # overlap, m (a ~ 0.6 um)
W_TYPICAL = 1e5  # spin, rad/s (a w ~ 0.06 m/s)
RING_WIDTH = 1e-3  # m/s


def finite(tree):
    return all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree_util.tree_leaves(tree))


def rng(seed=0):
    return np.random.default_rng(seed)


# ---------------------------------------------------------------------------------------------
# 1. Safe helpers
# ---------------------------------------------------------------------------------------------

SAFE_FUNCTIONS = {
    "sqrt": (_safe.safe_sqrt, 0.5),
    "pow1.5": (lambda x: _safe.safe_pow(x, 1.5), 1.5),
    "pow2.5": (lambda x: _safe.safe_pow(x, 2.5), 2.5),
    "pow0.5": (lambda x: _safe.safe_pow(x, 0.5), 0.5),
}


@pytest.mark.parametrize("name", SAFE_FUNCTIONS)
@pytest.mark.parametrize("x", [0.0, -1e-300, -1e-12, -3.0])
def test_safe_function_is_zero_with_finite_derivatives_at_and_below_zero(name, x):
    f, _ = SAFE_FUNCTIONS[name]
    x = jnp.float64(x)
    assert f(x) == 0.0
    assert jax.grad(f)(x) == 0.0
    assert jax.hessian(f)(x) == 0.0


@pytest.mark.parametrize("name", SAFE_FUNCTIONS)
def test_safe_function_matches_power_and_its_derivatives_for_positive_input(name):
    f, p = SAFE_FUNCTIONS[name]
    x = np.array([1e-30, 1e-12, 1e-8, 0.37, 1.0, 2.5, 1e6])
    np.testing.assert_allclose(jax.vmap(f)(x), x**p, rtol=1e-14)
    np.testing.assert_allclose(jax.vmap(jax.grad(f))(x), p * x ** (p - 1), rtol=1e-14)
    np.testing.assert_allclose(jax.vmap(jax.hessian(f))(x), p * (p - 1) * x ** (p - 2), rtol=1e-13)
    if name == "sqrt":
        np.testing.assert_array_equal(jax.vmap(f)(x), jnp.sqrt(x))


@pytest.mark.parametrize("name", SAFE_FUNCTIONS)
@pytest.mark.parametrize("x", [0.05, 0.7, 3.0])
def test_safe_function_check_grads_at_positive_points(name, x):
    f, _ = SAFE_FUNCTIONS[name]
    check_grads(f, (jnp.float64(x),), order=2, modes=["fwd", "rev"], eps=1e-4)


def test_smooth_sign_flat_is_odd():
    z = jnp.asarray(rng().normal(scale=3.0, size=200))
    np.testing.assert_array_equal(_safe.smooth_sign_flat(-z), -_safe.smooth_sign_flat(z))


def test_smooth_sign_flat_equals_sign_beyond_three():
    z = jnp.concatenate([jnp.linspace(3.0 + 1e-12, 50.0, 500), jnp.array([1e3, 1e30])])
    z = jnp.concatenate([z, -z])
    assert float(jnp.max(jnp.abs(_safe.smooth_sign_flat(z) - jnp.sign(z)))) < 1e-7


def test_smooth_sign_flat_has_zero_slope_and_finite_hessian_at_zero():
    zero = jnp.float64(0.0)
    assert _safe.smooth_sign_flat(zero) == 0.0
    assert jax.grad(_safe.smooth_sign_flat)(zero) == 0.0
    assert finite(jax.hessian(_safe.smooth_sign_flat)(zero))
    # Behaves as z|z| near 0.
    z = jnp.array([-1e-3, -1e-5, 1e-5, 1e-3])
    np.testing.assert_allclose(_safe.smooth_sign_flat(z), z * jnp.abs(z), rtol=1e-6)


# ---------------------------------------------------------------------------------------------
# 2. Laws vs closed forms (SI)
# ---------------------------------------------------------------------------------------------

OVERLAPS = np.array([1e-12, 3e-10, 1e-9, 1e-8, 5e-8])


def test_contact_radius_is_hertz_geometry():
    np.testing.assert_allclose(_laws.contact_radius(OVERLAPS, R), np.sqrt(R * OVERLAPS), rtol=1e-14)


def test_hertz_force_closed_form():
    expected = -K * np.sqrt(R) * OVERLAPS**1.5
    np.testing.assert_allclose(_laws.hertz_force(OVERLAPS, R, K), expected, rtol=1e-13)


@pytest.mark.parametrize("ndot", [-1.3, -0.2, 0.0, 0.4, 2.0])
def test_hertz_damping_force_closed_form_and_dissipative(ndot):
    got = _laws.hertz_damping_force(OVERLAPS, ndot, R, K, C_H)
    expected = -K * np.sqrt(R) * OVERLAPS**1.5 * C_H * ndot
    np.testing.assert_allclose(got, expected, rtol=1e-13, atol=0)
    assert np.all(np.asarray(got) * ndot <= 0)


def test_adhesion_force_closed_form():
    expected = 2 * np.pi * np.sqrt(R * OVERLAPS) * F0
    np.testing.assert_allclose(_laws.adhesion_force(OVERLAPS, R, F0), expected, rtol=1e-13)


def test_minus_hertz_potential_slope_is_hertz_force():
    slope = jax.vmap(jax.grad(_laws.hertz_potential), (0, None, None))(OVERLAPS, R, K)
    np.testing.assert_allclose(-slope, _laws.hertz_force(OVERLAPS, R, K), rtol=1e-13)


def test_minus_adhesion_potential_slope_is_adhesion_force():
    slope = jax.vmap(jax.grad(_laws.adhesion_potential), (0, None, None))(OVERLAPS, R, F0)
    np.testing.assert_allclose(-slope, _laws.adhesion_force(OVERLAPS, R, F0), rtol=1e-13)


@pytest.mark.parametrize("w", [-3e5, -1.0, 2e4, 1e6])
def test_hertz_rolling_moment_closed_form(w):
    a = np.sqrt(R * OVERLAPS)
    expected = -(K / 5) * np.sqrt(OVERLAPS / R) * C_H * a**4 * w
    got = _laws.hertz_rolling_moment(OVERLAPS, w, R, K, C_H)
    np.testing.assert_allclose(got, expected, rtol=1e-13)
    assert np.all(np.asarray(got) * w < 0)  # opposes the spin


@pytest.mark.parametrize("n, w", [(1e-8, 1e5), (3e-9, -2e6)])
def test_hertz_rolling_moment_is_the_moment_of_the_damped_hertz_pressure(n, w):
    """Integrate the damping pressure ``p(rho) C_H w rho cos(alpha)`` times the lever."""
    a = np.sqrt(R * n)
    force = K * np.sqrt(R) * n**1.5
    p0 = 3 * force / (2 * np.pi * a**2)

    def integrand(rho, alpha):  # dblquad: inner variable first
        pressure = p0 * np.sqrt(max(1 - (rho / a) ** 2, 0.0))
        lever = rho * np.cos(alpha)
        return pressure * C_H * w * lever * lever * rho

    moment, _ = integrate.dblquad(integrand, 0, 2 * np.pi, 0, a, epsabs=0, epsrel=1e-11)
    got = float(_laws.hertz_rolling_moment(n, w, R, K, C_H))
    np.testing.assert_allclose(got, -moment, rtol=1e-8)


@pytest.mark.parametrize("w", [-3e5, 2e4, 1e6])
def test_lambda_moment_closed_form(w):
    expected = -LAM * C_A * np.sqrt(R * OVERLAPS) * w
    got = _laws.lambda_moment(OVERLAPS, w, R, C_A, LAM)
    np.testing.assert_allclose(got, expected, rtol=1e-13)
    assert np.all(np.asarray(got) * w < 0)


LAWS_OF_N = {
    "contact_radius": lambda n: _laws.contact_radius(n, R),
    "hertz_force": lambda n: _laws.hertz_force(n, R, K),
    "hertz_damping_force": lambda n: _laws.hertz_damping_force(n, 0.7, R, K, C_H),
    "adhesion_force": lambda n: _laws.adhesion_force(n, R, F0),
    "hertz_potential": lambda n: _laws.hertz_potential(n, R, K),
    "adhesion_potential": lambda n: _laws.adhesion_potential(n, R, F0),
    "hertz_rolling_moment": lambda n: _laws.hertz_rolling_moment(n, W_TYPICAL, R, K, C_H),
    "lambda_moment": lambda n: _laws.lambda_moment(n, W_TYPICAL, R, C_A, LAM),
    "adhesion_damping_force": lambda n: _laws.adhesion_damping(n, -0.5, W_TYPICAL, R, F0, C_A)[0],
    "adhesion_damping_moment": lambda n: _laws.adhesion_damping(n, -0.5, W_TYPICAL, R, F0, C_A)[1],
    "adhesion_damping_force_w": (
        lambda n: _laws.adhesion_damping(n, -0.5, W_TYPICAL, R, F0, C_A, RING_WIDTH)[0]
    ),
    "adhesion_damping_moment_w": (
        lambda n: _laws.adhesion_damping(n, -0.5, W_TYPICAL, R, F0, C_A, RING_WIDTH)[1]
    ),
}


@pytest.mark.parametrize("name", LAWS_OF_N)
def test_law_is_zero_out_of_contact_and_continuous_at_first_touch(name):
    law = LAWS_OF_N[name]
    for n in (0.0, -1e-300, -1e-9, -1.0):
        assert law(jnp.float64(n)) == 0.0
    scale = abs(float(law(jnp.float64(N_TYPICAL))))
    assert scale > 0
    # Approaching n = 0 from above, the law goes to 0 (the slowest, a ~ sqrt(n), by 1e-12 here).
    values = np.abs([float(law(jnp.float64(N_TYPICAL * 10.0**-k))) for k in range(0, 25, 4)])
    assert np.all(np.diff(values) <= 0)
    assert values[-1] <= 1e-11 * scale


# ---------------------------------------------------------------------------------------------
# 3. The adhesion ring
# ---------------------------------------------------------------------------------------------


def ring_quadrature(ndot, b):
    """``int max(-(ndot + b cos), 0) [1, cos] dalpha`` over a period, with the kinks as points."""
    kinks = []
    if b != 0 and abs(ndot / b) < 1:
        beta = np.arccos(-ndot / b)
        kinks = [beta, 2 * np.pi - beta]

    def quad(weight):
        def f(alpha):
            return max(-(ndot + b * np.cos(alpha)), 0.0) * weight(alpha)

        value, _ = integrate.quad(
            f, 0, 2 * np.pi, points=kinks or None, epsabs=1e-13, epsrel=1e-12, limit=200
        )
        return value

    return quad(lambda alpha: 1.0), quad(np.cos)


def ring_samples(regime, count=12, seed=1):
    g = rng(seed)
    b = g.uniform(0.05, 3.0, count) * g.choice([-1.0, 1.0], count)
    if regime == "partial":
        ndot = np.abs(b) * g.uniform(-0.98, 0.98, count)
    elif regime == "approaching":
        ndot = np.abs(b) * g.uniform(1.02, 4.0, count)
    elif regime == "separating":
        ndot = -np.abs(b) * g.uniform(1.02, 4.0, count)
    else:  # "edges": spin-free ring, turning point, exactly on the regime boundaries
        ndot = np.array([-1.3, 0.0, 0.8, 0.0, 0.7, -0.7, 0.7, -0.7, -2.0, 1e-3])
        b = np.array([0.0, 0.0, 0.0, 1.1, 0.7, 0.7, -0.7, -0.7, 1e-9, -1e-3])
    return ndot, b


REGIMES = ["partial", "approaching", "separating", "edges"]


@pytest.mark.parametrize("regime", REGIMES)
def test_ring_integrals_match_quadrature(regime):
    ndot, b = ring_samples(regime)
    i0, i1 = jax.vmap(_laws.ring_integrals)(jnp.asarray(ndot), jnp.asarray(b))
    expected = np.array([ring_quadrature(x, y) for x, y in zip(ndot, b, strict=True)])
    scale = 1.0 + np.abs(ndot) + np.abs(b)
    np.testing.assert_allclose(i0 / scale, expected[:, 0] / scale, rtol=0, atol=1e-11)
    np.testing.assert_allclose(i1 / scale, expected[:, 1] / scale, rtol=0, atol=1e-11)


@pytest.mark.parametrize("width", [0.0, 0.1])
@pytest.mark.parametrize("regime", REGIMES)
def test_ring_moment_integral_opposes_b(regime, width):
    ndot, b = ring_samples(regime)
    i0, i1 = jax.vmap(_laws.ring_integrals, (0, 0, None))(jnp.asarray(ndot), jnp.asarray(b), width)
    i0, i1 = np.asarray(i0), np.asarray(i1)
    assert np.all(i0 >= 0)
    assert np.all(i1 * b <= 0)
    assert np.all(i1[b == 0] == 0)
    if regime in ("partial", "separating"):
        assert np.all(i1 * b < 0)


@pytest.mark.parametrize("width", [0.0, RING_WIDTH, 0.1])
@pytest.mark.parametrize("regime", REGIMES)
def test_spin_free_ring_is_the_ring_at_zero_spin(regime, width):
    """``b = None`` (the models without the analytical moments) is the ring at ``b = 0``."""
    ndot = jnp.asarray(ring_samples(regime)[0])
    general = jax.vmap(_laws.ring_integrals, (0, None, None))(ndot, 0.0, width)
    spin_free = _laws.ring_integrals(ndot, None, width)
    np.testing.assert_allclose(spin_free[0], general[0], rtol=1e-14, atol=1e-14)
    assert np.all(np.asarray(spin_free[1]) == 0.0)
    force, moment = _laws.adhesion_damping(OVERLAPS[:, None], ndot, None, R, F0, C_A, width)
    expected = _laws.adhesion_damping(OVERLAPS[:, None], ndot, 0.0, R, F0, C_A, width)[0]
    np.testing.assert_allclose(force, expected, rtol=1e-14, atol=1e-14 * np.max(np.abs(expected)))
    assert np.all(np.asarray(moment) == 0.0)


@pytest.mark.parametrize("width", [0.0, 0.1])
@pytest.mark.parametrize("regime", REGIMES)
def test_ring_integrals_parity_in_b(regime, width):
    ndot, b = (jnp.asarray(x) for x in ring_samples(regime))
    ring = jax.vmap(_laws.ring_integrals, (0, 0, None))
    i0, i1 = ring(ndot, b, width)
    j0, j1 = ring(ndot, -b, width)
    np.testing.assert_allclose(j0, i0, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(j1, -i1, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("regime", REGIMES)
def test_regularized_ring_converges_as_width_shrinks(regime):
    ndot, b = (jnp.asarray(x) for x in ring_samples(regime))
    ring = jax.vmap(_laws.ring_integrals, (0, 0, None))
    exact = np.stack(ring(ndot, b, 0.0))
    widths = [1e-2, 1e-3, 1e-4, 1e-5]
    errors = [float(np.max(np.abs(np.stack(ring(ndot, b, h)) - exact))) for h in widths]
    for h, err in zip(widths, errors, strict=True):
        assert err <= 10 * h  # at least linear
    assert errors[-1] <= max(1e-3 * errors[0], 1e-13)  # shrinking with the width


@pytest.mark.parametrize("width", [0.0, RING_WIDTH, 0.05])
def test_adhesion_damping_is_dissipative(width):
    g = rng(2)
    count = 400
    n = 10.0 ** g.uniform(-11, -7, count)
    a = np.sqrt(R * n)
    w = g.uniform(-1, 1, count) * 10.0 ** g.uniform(3, 7, count)
    # ndot of the order of a|w| (the partial ring), and sometimes far from it.
    ndot = a * np.abs(w) * g.uniform(-2, 2, count) + g.choice([0.0, 0.0, 1.0], count) * g.normal(
        scale=0.5, size=count
    )
    ndot[:20] = 0.0
    ndot[20:40] = a[20:40] * np.abs(w[20:40])
    ndot[40:60] = -a[40:60] * np.abs(w[40:60])
    force, moment = jax.vmap(_laws.adhesion_damping, (0, 0, 0, None, None, None, None))(
        n, ndot, w, R, F0, C_A, width
    )
    power = ndot * np.asarray(force) + w * np.asarray(moment)
    scale = np.abs(ndot * force) + np.abs(w * moment)
    assert np.all(power <= 1e-12 * scale)
    assert np.all(np.asarray(force) >= 0)  # attractive


@pytest.mark.parametrize("ndot", [-2.0, -0.3, -1e-6, 0.0, 1e-6, 0.5])
def test_adhesion_damping_without_spin(ndot):
    a = np.sqrt(R * OVERLAPS)
    force, moment = _laws.adhesion_damping(OVERLAPS, ndot, 0.0, R, F0, C_A)
    np.testing.assert_allclose(force, 2 * np.pi * a * F0 * C_A * max(-ndot, 0.0), rtol=1e-13)
    np.testing.assert_array_equal(moment, 0.0)


@pytest.mark.parametrize("w", [-4e6, -1e5, 3e4, 2e6])
def test_adhesion_damping_whole_ring_separating(w):
    a = np.sqrt(R * OVERLAPS)
    for factor in (1.0 + 1e-9, 1.5, 10.0):
        ndot = -factor * a * abs(w)
        force, moment = _laws.adhesion_damping(OVERLAPS, ndot, w, R, F0, C_A)
        np.testing.assert_allclose(moment, -np.pi * F0 * C_A * a**3 * w, rtol=1e-12)
        np.testing.assert_allclose(force, -2 * np.pi * a * F0 * C_A * ndot, rtol=1e-12)


@pytest.mark.parametrize("w", [-4e6, -1e5, 0.0, 3e4, 2e6])
def test_adhesion_damping_whole_ring_approaching(w):
    a = np.sqrt(R * OVERLAPS)
    for ndot in (a * abs(w), 1.5 * a * abs(w) + 1e-9, 3.0 + a * abs(w)):
        force, moment = _laws.adhesion_damping(OVERLAPS, ndot, w, R, F0, C_A)
        np.testing.assert_array_equal(force, 0.0)
        np.testing.assert_array_equal(moment, 0.0)


# ---------------------------------------------------------------------------------------------
# 4. Finite derivatives at the switch points
# ---------------------------------------------------------------------------------------------

_A = float(np.sqrt(R * N_TYPICAL))
ADHESION_SWITCHES = {
    # name: (n, ndot, w); b = w a == 0 in the first three
    "ndot=0,w=0": (N_TYPICAL, 0.0, 0.0),
    "ndot<0,w=0": (N_TYPICAL, -0.4, 0.0),
    "n=0": (0.0, -0.4, W_TYPICAL),
    "n=0,ndot=0,w=0": (0.0, 0.0, 0.0),
    "ndot=+a|w|": (N_TYPICAL, _A * W_TYPICAL, W_TYPICAL),
    "ndot=-a|w|": (N_TYPICAL, -_A * W_TYPICAL, W_TYPICAL),
    "ndot=+a|w|,w<0": (N_TYPICAL, _A * W_TYPICAL, -W_TYPICAL),
    "ndot=-a|w|,w<0": (N_TYPICAL, -_A * W_TYPICAL, -W_TYPICAL),
    "ndot=0,partial": (N_TYPICAL, 0.0, W_TYPICAL),
}


def adhesion_switch_cases():
    # width = 0 with b = w a = 0 (w = 0 or n = 0) once gave NaN derivatives through
    # sqrt(b^2 + 0); these cases guard the safe square root that fixed it.
    for (name, point), width in itertools.product(ADHESION_SWITCHES.items(), [0.0, RING_WIDTH]):
        yield pytest.param(point, width, id=f"{name}-width={width}")


def value_and_derivatives(f):
    """Value, reverse and forward Jacobians and Hessian of ``f`` at ``x``, compiled once."""
    return jax.jit(lambda x: (f(x), jax.jacrev(f)(x), jax.jacfwd(f)(x), jax.hessian(f)(x)))


ADHESION_DERIVATIVES = {
    # every input: n, ndot, w, radius, f0, C_A
    width: value_and_derivatives(
        lambda x, width=width: jnp.stack(_laws.adhesion_damping(*x, width))
    )
    for width in (0.0, RING_WIDTH)
}


@pytest.mark.parametrize("point, width", list(adhesion_switch_cases()))
def test_adhesion_damping_derivatives_finite_at_switch_points(point, width):
    x = jnp.array([*point, R, F0, C_A])
    assert finite(ADHESION_DERIVATIVES[width](x))


# every input: slip, load, friction, hold
FRICTION_DERIVATIVES = value_and_derivatives(
    lambda x: _laws.friction_force(x[0], x[1], x[2], x[3], 1e-3)
)


@pytest.mark.parametrize(
    "slip, load, hold",
    [
        (0.0, 1.0, 0.0),
        (0.0, 1.0, 0.2),
        (0.0, 1.0, 0.3),  # hold exactly at the bound f N
        (0.0, 1.0, -0.3),
        (0.0, 0.0, 0.0),  # no load (first touch)
        (1e-3, 1.0, 0.1),  # slip = width
        (-3e-3, 2.0, -5.0),
    ],
)
def test_friction_derivatives_finite_at_switch_points(slip, load, hold):
    x = jnp.array([slip, load, 0.3, hold])
    assert finite(FRICTION_DERIVATIVES(x))


# ---------------------------------------------------------------------------------------------
# 5. Friction
# ---------------------------------------------------------------------------------------------

friction_vmapped = jax.vmap(_laws.friction_force, (0, 0, None, 0, None))


def friction_samples(width, count=2000, seed=3):
    g = rng(seed)
    slip = g.normal(size=count) * width * 10.0 ** g.uniform(-3, 2, count)
    slip[:10] = 0.0
    load = 10.0 ** g.uniform(-6, -2, count)  # N
    hold = g.normal(size=count) * load * 0.5
    return slip, load, hold


@pytest.mark.parametrize("width", [1e-3, 0.2])
def test_friction_bounded_by_coulomb_limit(width):
    slip, load, hold = friction_samples(width)
    force = np.asarray(friction_vmapped(slip, load, 0.3, hold, width))
    assert np.all(np.abs(force) <= 0.3 * load * (1 + 1e-15))


@pytest.mark.parametrize("width", [1e-3, 0.2])
def test_friction_is_coulomb_when_sliding(width):
    slip, load, hold = friction_samples(width)
    sliding = np.abs(slip) > 3 * width
    assert sliding.sum() > 100
    force = np.asarray(friction_vmapped(slip, load, 0.3, hold, width))
    coulomb = -0.3 * load * np.sign(slip)
    np.testing.assert_allclose(force[sliding], coulomb[sliding], rtol=1e-7, atol=0)


def test_friction_in_pure_rolling_is_the_clipped_holding_force():
    load = np.array([1e-4, 1e-4, 1e-4, 1e-4, 2.0, 0.0])
    hold = np.array([0.0, 1e-5, -2.9e-5, 7e-5, -3.0, 1.0])
    force = friction_vmapped(np.zeros_like(load), load, 0.3, hold, 1e-3)
    np.testing.assert_array_equal(force, np.clip(hold, -0.3 * load, 0.3 * load))


@pytest.mark.parametrize("width", [1e-3, 0.2])
def test_friction_without_holding_force_is_dissipative(width):
    slip, load, _ = friction_samples(width)
    force = np.asarray(friction_vmapped(slip, load, 0.3, np.zeros_like(load), width))
    assert np.all(force * slip <= 0)
    assert np.all(force[slip != 0] * slip[slip != 0] < 0)


def test_friction_converges_to_coulomb_as_width_shrinks():
    g = rng(4)
    slip = g.normal(size=200) * 10.0 ** g.uniform(-4, 0, 200)
    load = np.ones_like(slip)
    hold = g.uniform(-0.3, 0.3, 200)
    coulomb = -0.3 * np.sign(slip)
    widths = 10.0 ** -np.arange(0, 8)
    errors = np.array(
        [np.abs(np.asarray(friction_vmapped(slip, load, 0.3, hold, h)) - coulomb) for h in widths]
    )
    assert np.all(np.diff(errors, axis=0) <= 1e-15)  # pointwise non-increasing
    assert np.max(errors[-1]) <= 1e-7  # all |s| > 3e-7 here: Coulomb


# ---------------------------------------------------------------------------------------------
# 6. The energy ledger of the assembled vector field (Hertz units)
# ---------------------------------------------------------------------------------------------

SCALED_RADIUS = 100.0
SCALED = ScaledParameters(
    radius=jnp.float64(SCALED_RADIUS),
    K=jnp.float64(1.25 / np.sqrt(SCALED_RADIUS)),  # Hertz force 1.25 at unit overlap
    f0=jnp.float64(0.01),  # adhesion force ~0.6 at unit overlap
    C_A=jnp.float64(0.8),
    C_H=jnp.float64(0.1),
    friction=jnp.float64(0.3),
    lam=jnp.float64(0.05),
    inertia=jnp.float64(0.4 * SCALED_RADIUS**2),
)
LOSS_KEYS = ["loss_hertz_damping", "loss_adhesion_damping", "loss_friction", "loss_rolling"]


def random_states(terms, count=300, seed=5):
    g = rng(seed)
    n = g.uniform(1e-4, 1.3, count)
    a = np.sqrt(SCALED_RADIUS * n)
    w = g.uniform(-1, 1, count) * 3.0 / SCALED_RADIUS
    ndot = g.uniform(-1.5, 1.5, count)
    ndot[: count // 3] *= a[: count // 3] * np.abs(w[: count // 3])  # partial ring
    vt = g.uniform(-1, 1, count)
    vt[: count // 5] = SCALED_RADIUS * w[: count // 5]  # pure rolling
    vt[count // 5 : count // 4] += 5e-4  # within the slip width
    y0 = _dynamics.initial_state(terms, 0.0, 0.0, jnp.float64)
    y = {k: jnp.broadcast_to(v, (count,)) for k, v in y0.items()}
    y.update(n=jnp.asarray(n), ndot=jnp.asarray(ndot), vt=jnp.asarray(vt), w=jnp.asarray(w))
    return y


@pytest.mark.parametrize("friction_load", ["net", "hertz"])
@pytest.mark.parametrize("rolling_moments", ["none", "analytical", "lambda"])
def test_energy_ledger_closes_and_losses_are_dissipative(rolling_moments, friction_load):
    terms = _dynamics.Terms(
        tangential=True,
        rotation=True,
        adhesion=True,
        rolling_moments=rolling_moments,
        friction_load=friction_load,
        slip_width=1e-3,
        ring_width=1e-6,
    )
    field = _dynamics.ImpactField(terms)

    def rates(y):
        dy = field(0.0, y, SCALED)
        _, e_dot = jax.jvp(lambda z: _dynamics.mechanical_energy(terms, SCALED, z), (y,), (dy,))
        return e_dot, dy

    ys = random_states(terms)
    e_dot, dy = jax.jit(jax.vmap(rates))(ys)
    losses = {k: np.asarray(dy.get(k, jnp.zeros_like(e_dot))) for k in LOSS_KEYS}
    total = sum(losses.values())
    # Round-off scale: every power term that enters dE/dt, the conservative ones included.
    powers = [ys["ndot"] * dy["ndot"], ys["vt"] * dy["vt"], SCALED.inertia * ys["w"] * dy["w"]]
    scale = sum(np.abs(v) for v in losses.values()) + sum(np.abs(np.asarray(v)) for v in powers)
    assert np.max(np.abs(np.asarray(e_dot) + total) / scale) < 1e-12

    assert np.all(losses["loss_hertz_damping"] >= 0)
    assert np.all(losses["loss_rolling"] >= 0)
    assert np.all(losses["loss_adhesion_damping"] + losses["loss_rolling"] >= -1e-14)
    if rolling_moments == "none":
        assert np.all(losses["loss_friction"] >= 0)
        assert np.all(losses["loss_adhesion_damping"] >= 0)
    else:
        assert np.any(losses["loss_rolling"] > 0)
    if rolling_moments == "analytical":
        # The partial ring passes energy from the spin to the normal motion at some states.
        assert np.any(losses["loss_adhesion_damping"] < 0)


@pytest.mark.parametrize("rotation", [True, False])
def test_shell_friction_opposes_slip_stops_at_rolling_and_closes_the_ledger(rotation):
    # The closed-form friction of the contact shell (jaximpact._simulate._shell_friction).
    from jaximpact._engine.simulate import _shell_friction

    terms = _dynamics.Terms(
        tangential=True,
        rotation=rotation,
        adhesion=True,
        rolling_moments="analytical",
        friction_load="net",
        slip_width=1e-5,
        ring_width=1e-8,
        contact_floor=1e-4,
    )
    g = rng(11)
    count = 400
    w = g.uniform(-1, 1, count) * 3.0 / SCALED_RADIUS if rotation else np.zeros(count)
    slip = g.normal(size=count) * 10.0 ** g.uniform(-9, 0, count)
    y = {"vt": jnp.asarray(SCALED_RADIUS * w + slip), "w": jnp.asarray(w)}
    if not rotation:
        del y["w"]
    shell = {"time": jnp.asarray(10.0 ** g.uniform(-5, 0, count))}  # up to slow separations
    ndot = jnp.asarray(g.choice([-1.0, 1.0], count) * 1e-4 / shell["time"])
    out = jax.vmap(lambda yy, s, nd: _shell_friction(terms, SCALED, yy, s, nd))(y, shell, ndot)
    w1 = np.asarray(out["w"]) if rotation else np.zeros(count)
    new_slip = np.asarray(out["vt"]) - SCALED_RADIUS * w1
    # The slip shrinks toward zero and never changes sign (the impulse stops at rolling).
    rounding = 1e-14 * (1.0 + np.abs(np.asarray(y["vt"])))  # slip = vt - r w, rounded
    assert np.all(np.abs(new_slip) <= np.abs(slip) + rounding)
    assert np.all(new_slip * slip >= -rounding * np.abs(slip))
    stopped = np.abs(new_slip) < rounding
    assert 0 < np.sum(stopped) < count  # both regimes occur
    # The friction loss is the kinetic energy taken, and it is never negative.
    inertia = float(SCALED.inertia) if rotation else 0.0
    vt0 = np.asarray(y["vt"])
    ke = lambda vt, ww: 0.5 * vt**2 + 0.5 * inertia * ww**2  # noqa: E731
    change = ke(np.asarray(out["vt"]), w1) - ke(vt0, w)
    loss = np.asarray(out["loss_friction"])
    assert np.all(loss >= -1e-18)
    assert np.all(np.abs(loss + change) <= 1e-14 * ke(vt0, w) + 1e-9 * loss)
    # Sliding far from rolling: the impulse is f times the load integral over the shell time.
    far = (np.abs(slip) > 1e-4) & ~stopped
    assert np.any(far)
    sr, eps, nd = np.sqrt(SCALED_RADIUS), 1e-4, np.asarray(ndot)
    load = np.abs(
        -0.4 * float(SCALED.K) * sr * eps**2.5 * (1 + float(SCALED.C_H) * nd)
        + (4 / 3)
        * np.pi
        * float(SCALED.f0)
        * sr
        * eps**1.5
        * (1 + float(SCALED.C_A) * np.maximum(-nd, 0))
    )
    impulse = float(SCALED.friction) * load * np.asarray(shell["time"]) / eps
    dv = np.asarray(out["vt"]) - vt0
    np.testing.assert_allclose(dv[far], -np.sign(slip[far]) * impulse[far], rtol=1e-9, atol=1e-14)

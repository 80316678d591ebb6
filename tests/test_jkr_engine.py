"""The JKR normal law in the engine (``model.normal = "jkr"``): its closed-form contact radius,
force and potential against ``jaximpact.reference.jkr``; elastic impacts against the
restitution ``e = sqrt(1 - (V_s/V)^2)``; damped, oblique, spinning impacts against the exact
switched reference (which finds the contact radius by root finding); derivatives against the
reference's central differences; batches, float32 and the Hertz limit."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference_checks import (
    check_batch_exact,
    check_derivatives,
    check_impacts,
    random_impacts,
)

import jaximpact as ji
from jaximpact import reference as ref
from jaximpact._model import laws
from jaximpact.reference import jkr

R, RHO, K = 20e-6, 2500.0, 6.6e10  # a 20 um glass-like sphere on a stiff wall
E = 0.75 * K  # K = 4 E*/3
MASS = RHO * 4 / 3 * math.pi * R**3


def jkr_scene(w=0.1, C_H=0.2, friction=0.3, moments="analytical", lam=0.0, C_A=0.5):
    return ji.Scene(
        particle=ji.Particle(radius=R, density=RHO),
        contact=ji.Contact(K=K, f0=0.0, C_A=C_A, C_H=C_H, friction=friction, w=w),
        model=ji.Model(normal="jkr", rolling_moments=moments, lambda_=lam),
    )


def jkr_params(w=0.1, C_H=0.2, friction=0.3, moments="analytical", lam=0.0, C_A=0.5):
    return ref.Params(
        radius=R, density=RHO, K=K, C_A=C_A, C_H=C_H, friction=friction, w=w, lam=lam,
        normal="jkr", rolling_moments=moments,
    )  # fmt: skip


def jkr_mindlin(case, G_star=2.6e10):
    """The JKR scene of ``case`` with the Mindlin spring, and its reference twin."""
    scene = jkr_scene(**case).replace(contact={"G_star": G_star}, model={"tangential": "mindlin"})
    twin = {**jkr_params(**case).__dict__, "tangential": "mindlin", "G_star": G_star}
    return scene, ref.Params(**twin)


@pytest.mark.parametrize("w", [0.01, 0.1, 2.0])
def test_contact_radius_force_and_potential_closed_forms(w):
    """The closed-form contact radius equals the reference's root (1e-13) from the snap-off to
    1e7 overlap scales; the force is ``-8/9 F_c`` at zero overlap and ``-5/9 F_c`` at the
    snap-off (repulsive positive); the potential's barrier is the elastic JKR loss
    ``c_W (w^5 R^4 / E^2)^(1/3)`` and its derivative is the force."""
    lam, mu = laws.jkr_scales(R, E, w)
    _, n_c, _ = jkr.snap_off(R, E, w)
    assert laws.JKR_SNAP_OFF * mu == pytest.approx(n_c, rel=1e-14)
    for d in (-1.6, -1.0, -0.3, 0.0, 1e-3, 1.0, 50.0, 1e4, 1e7):
        n = max(d * mu, n_c)
        got = float(laws.jkr_contact_radius(jnp.float64(n), R, E, w))
        assert got == pytest.approx(jkr.contact_radius(n, R, E, w), rel=1e-13), d
    F_c = jkr.pull_off_force(R, w)

    def force(n):  # toward the surface positive (attractive), as in the engine
        a = laws.jkr_contact_radius(n, R, E, w)
        return laws.jkr_hertz_force(a, R, K) + laws.jkr_adhesion_force(a, K, w)

    assert float(force(jnp.float64(0.0))) == pytest.approx(8 / 9 * F_c, rel=1e-13)
    a_c = laws.jkr_contact_radius(jnp.float64(n_c), R, E, w)
    assert float(a_c) == pytest.approx(lam * (math.pi / 8) ** (1 / 3), rel=1e-7)
    assert float(force(jnp.float64(n_c))) == pytest.approx(5 / 9 * F_c, rel=1e-7)
    barrier = laws.jkr_potential(lam * (math.pi / 8) ** (1 / 3), R, K, w)
    assert float(barrier) == pytest.approx(jkr.energy_loss(R, E, w), rel=1e-13)
    slope = jax.grad(lambda n: laws.jkr_potential(laws.jkr_contact_radius(n, R, E, w), R, K, w))
    for d in (-1.2, 0.5, 30.0):
        assert float(slope(jnp.float64(d * mu))) == pytest.approx(
            -float(force(jnp.float64(d * mu))), rel=1e-12
        )


def test_floor_continuation_is_smooth_and_exact_above_it():
    """Above ``d_c + floor`` the continued radius is the closed form; below it, continuous and
    finite past the snap-off (where the closed form is a square root's NaN)."""
    w = 0.1
    lam, mu = laws.jkr_scales(R, E, w)
    floor = 1e-4
    d = jnp.array([laws.JKR_SNAP_OFF + 2 * floor, laws.JKR_SNAP_OFF + floor])
    np.testing.assert_allclose(
        np.asarray(laws.jkr_contact_radius(d * mu, R, E, w, floor)),
        np.asarray(laws.jkr_contact_radius(d * mu, R, E, w)),
        rtol=1e-14,
    )
    below = laws.jkr_contact_radius((laws.JKR_SNAP_OFF - 1e-2) * mu, R, E, w, floor)
    assert np.isfinite(float(below)) and 0 < float(below) / lam < 1.0


def test_elastic_impacts_follow_the_closed_form_restitution():
    """No damping, no friction: captured below the sticking speed ``V_s``, rebound above it
    with ``e = sqrt(1 - (V_s/V)^2)`` (Thornton & Ning's elastic-adhesive restitution with
    this project's constant ``c_s = 1.0348``) to 1e-8; the ledger's adhesion loss is ``W``."""
    w = 0.1
    scene = jkr_scene(w=w, C_H=0.0, friction=0.0, moments="none")
    V_s = jkr.sticking_velocity(R, E, w, MASS)
    ratios = np.array([0.5, 0.99, 1.001, 1.01, 1.1, 2.0, 10.0, 1000.0])
    res = ji.simulate(scene, ratios * V_s, 0.0, 0.0)
    for i, ratio in enumerate(ratios):
        want = jkr.restitution(ratio * V_s, R, E, w, MASS)
        if ratio < 1:
            assert int(res.status[i]) == ji.Status.CAPTURED
            continue
        assert int(res.status[i]) == ji.Status.REBOUND
        assert float(res.cor_n[i]) == pytest.approx(want, abs=1e-8), ratio
        W = float(res.loss_adhesion_damping[i])
        assert W == pytest.approx(jkr.energy_loss(R, E, w), rel=1e-10)
        assert abs(float(res.energy_in[i] - res.energy_out[i]) - W) < 1e-8 * float(res.energy_in[i])


# Damped, oblique, spinning impacts: analytical (Hertzian) and lambda rolling moments.
CASES = [
    pytest.param(dict(w=0.1, C_H=0.2, moments="analytical"), marks=pytest.mark.slow),
    dict(w=1.0, C_H=0.5, moments="none"),
    pytest.param(dict(w=0.3, C_H=1.0, moments="lambda", lam=1e-10), marks=pytest.mark.slow),
]


@pytest.mark.parametrize("case", CASES)
def test_impacts_match_the_exact_reference(case):
    """Statuses equal and velocities and spin within 1e-7 of the speed (measured 5e-9) across
    captures at first touch, captures during the contact and rebounds; the ledger closed."""
    speeds = np.geomspace(3e-3, 5.0, 10)
    angles, omega0 = random_impacts(3, speeds, R)
    seen = check_impacts(jkr_scene(**case), jkr_params(**case), speeds, angles, omega0)
    assert seen == {"rebound", "captured"}


@pytest.mark.slow  # a Mindlin program (~15 s to compile) and 20 reference runs
@pytest.mark.parametrize("case", [dict(w=1.0, C_H=0.5, moments="none"), dict(w=0.1)])
def test_mindlin_spring_matches_the_exact_reference(case):
    """JKR with the Mindlin spring against the reference's Mindlin model (JKR's contact
    radius in ``k_t = 8 G* a``): statuses equal, velocities and spin within 1e-5 of the speed
    (measured 2.3e-6; the Mindlin scene's own accuracy), the ledger closed with the spring's
    energy at the snap-off counted as lost (docs/physics.md, "Tangential compliance")."""
    scene, params = jkr_mindlin(case)
    speeds = np.geomspace(3e-3, 5.0, 10)
    angles, omega0 = random_impacts(3, speeds, R)
    seen = check_impacts(scene, params, speeds, angles, omega0, tol=1e-5)
    assert seen == {"rebound", "captured"}


@pytest.mark.slow  # a Mindlin forward-mode program and 6 x 4 reference runs
def test_mindlin_spring_derivatives_match_the_reference():
    """JKR with the Mindlin spring, a spinning oblique rebound: d(output)/d(w, G*, friction,
    C_H, speed, angle) against the reference's central differences, scaled to order one,
    within 1.5e-3 (measured 7.1e-4, in omega_out by the speed; the project's level for
    derivatives at rtol 1e-10, BENCHMARKS.md "Derivatives")."""
    scene, params = jkr_mindlin(dict(w=0.1))
    inputs = ("w", "G_star", "friction", "C_H", "speed", "angle_deg")
    check_derivatives(scene, params, 0.4, 25.0, 3e3, inputs, tol=1.5e-3)


def test_stiff_mindlin_spring_approaches_rigid_jkr():
    """The reference's JKR Mindlin model: a spring 40 times stiffer than a glass contact's
    (G* = 1e12 Pa) rebounds as the rigid Coulomb JKR model within 2e-3 of the speed (measured
    1.0e-3 at 8 deg, where it sticks, 1.8e-4 at 30 deg, where it slides), with the ledger
    closed (the spring's energy left at the snap-off booked as lost), and the soft spring
    (G* = 1e9) is farther off."""
    speed = 0.5
    for angle in (8.0, 30.0):
        rigid = ref.simulate_impact(jkr_params(w=0.1), speed, angle)
        off = []
        for G in (1e9, 1e12):
            out = ref.simulate_impact(jkr_mindlin(dict(w=0.1), G)[1], speed, angle)
            assert out.status == "rebound" and abs(out.ledger_residual) < 1e-9
            off.append(max(abs(out.vt_out - rigid.vt_out), abs(out.vn_out - rigid.vn_out)))
        assert off[1] < 2e-3 * speed < off[0], (angle, off)


def test_capture_speed_agrees_with_the_reference():
    """Around the reference's capture speed (bisection to 1e-6, a damped oblique spinning
    impact): captured 0.1 % below it and rebounding 0.1 % above it, as the reference."""
    case = dict(w=0.3, C_H=1.0, moments="analytical")
    scene, p = jkr_scene(**case), jkr_params(**case)
    angle, omega0 = 30.0, 2e3
    v_c = ref.capture_speed(p, angle, omega0, lo=1e-3, hi=1.0)
    res = ji.simulate(scene, np.array([0.999, 1.001]) * v_c, angle, omega0)
    assert list(np.asarray(res.status)) == [ji.Status.CAPTURED, ji.Status.REBOUND]
    q = ref.simulate_impact(p, 1.001 * v_c, angle, omega0)
    assert float(res.vn_out[1]) == pytest.approx(q.vn_out, abs=1e-6 * v_c)


@pytest.mark.slow  # a Jacobian program of the JKR law (23 s): CI's second step
def test_derivatives_match_central_differences_of_the_reference():
    """``d/dw``, ``d/dC_H`` and the impact's inputs of an oblique spinning rebound, from
    ``output_jacobian``, against the reference's Richardson-checked central differences."""
    inputs = ("w", "C_H", "friction", "speed", "angle_deg")
    check_derivatives(jkr_scene(w=0.3), jkr_params(w=0.3), 0.2, 35.0, 0.1 * 0.2 / R, inputs)


def test_batch_does_not_change_a_lane_and_zero_w_is_hertz():
    """An impact is bitwise the same alone and in a batch (including one stuck at first
    touch); ``w = 0`` is the Hertz law of the Brach-Dunn scene without adhesion, bitwise."""
    scene = jkr_scene(w=0.3)
    speeds = np.array([0.004, 0.05, 0.3, 2.0])
    angles = np.array([0.0, 40.0, -20.0, 60.0])
    omega0 = np.array([0.0, 2e4, -1e4, 0.0])
    keys = ("status", "cor_n", "vt_out", "omega_out", "contact_time")
    check_batch_exact(scene, speeds, angles, omega0, keys=keys)
    hertz = ji.Scene(
        particle=ji.Particle(radius=R, density=RHO),
        contact=ji.Contact(K=K, f0=0.0, C_A=0.5, C_H=0.2, friction=0.3),
        model=ji.Model(adhesion=False),
    )
    a, b = (
        ji.simulate(jkr_scene(w=0.0), speeds, angles, omega0),
        ji.simulate(hertz, speeds, angles, omega0),
    )
    for k in ("cor_n", "vt_out", "omega_out", "contact_time"):
        np.testing.assert_array_equal(np.asarray(getattr(a, k)), np.asarray(getattr(b, k)), k)


@pytest.mark.slow  # a float32 program of its own (16 s): CI's second step
def test_float32_runs_and_agrees_to_its_precision():
    """In float32 no impact fails and rebounds agree with float64 to 1e-3 of the speed."""
    scene = jkr_scene(w=0.3)
    speeds = np.geomspace(3e-3, 5.0, 12)
    angles = np.linspace(-70, 70, speeds.size)
    r64 = ji.simulate(scene, speeds, angles, 0.0)
    with jax.enable_x64(False):  # (the tests run with x64 on: float32 only inside this)
        r32 = ji.simulate(scene, speeds.astype(np.float32), angles.astype(np.float32), 0.0)
        assert r32.vn_out.dtype == jnp.float32
    assert np.all(np.asarray(r32.status) <= ji.Status.CAPTURED)
    same = np.asarray(r32.status) == np.asarray(r64.status)
    assert same.sum() >= speeds.size - 1  # one may flip right at the capture speed
    rebound = same & (np.asarray(r64.status) == ji.Status.REBOUND)
    err = np.abs(np.asarray(r32.vn_out, float) - np.asarray(r64.vn_out)) / speeds
    assert np.max(err[rebound]) < 1e-3


@pytest.mark.slow  # two Jacobian programs
def test_derivatives_are_batch_exact():
    """A lane's derivatives in ``w`` and ``C_H`` are bitwise the same alone and in a batch."""
    scene = jkr_scene(w=0.3)
    speeds = np.array([0.05, 0.3, 2.0])
    angles = np.array([40.0, -20.0, 60.0])
    omega0 = np.array([2e4, -1e4, 0.0])
    inputs = ("w", "C_H")
    batch = ji.output_jacobian(scene, speeds, angles, omega0, inputs=inputs, program="compact")
    alone = ji.output_jacobian(
        scene, speeds[1:2], angles[1:2], omega0[1:2], inputs=inputs, program="compact"
    )
    for k in ("cor_n", "vt_out", "omega_out"):
        np.testing.assert_array_equal(np.asarray(alone[k])[0], np.asarray(batch[k])[1], k)


@pytest.mark.slow  # the capture-speed search's programs
def test_capture_speed_function_with_the_jkr_law():
    """``jaximpact.capture_speed`` scans from the JKR sticking speed and finds the reference's
    capture speed (bisection) to 1e-6 (measured 3e-9), normal and oblique."""
    case = dict(w=0.3, C_H=1.0, moments="analytical")
    scene, p = jkr_scene(**case), jkr_params(**case)
    found = ji.capture_speed(scene, angle_deg=[0.0, 30.0])
    assert list(np.asarray(found.status)) == [0, 0]
    for angle, v in zip((0.0, 30.0), np.asarray(found.speed), strict=True):
        want = ref.capture_speed(p, angle, 0.0, lo=1e-3, hi=2.0, rel_tol=1e-8)
        assert v == pytest.approx(want, rel=1e-6)

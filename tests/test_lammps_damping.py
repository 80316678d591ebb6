"""LAMMPS's normal damping models (``model.damping``): the engine against the exact reference,
closed-form properties of the laws, the energy ledger, derivatives and the scene's checks.
(LAMMPS itself: tests/test_lammps_reference.py, slow.)"""

import math

import jax
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import jaximpact as ji
from jaximpact import reference as R
from jaximpact._model.laws import tsuji_alpha

jax.config.update("jax_enable_x64", True)

TABLE1 = ji.table1_scene()
RADIUS = float(TABLE1.particle.radius)
DENSITY = float(TABLE1.particle.density)
K = float(TABLE1.contact.K)
MASS = DENSITY * 4.0 / 3.0 * math.pi * RADIUS**3
TIGHT = {"rtol": 1e-10, "atol": 1e-12}

# (normal law, w, damping, eta_n): each damping once, each law at least once
CASES = [
    ("brach_dunn", 0.0, "velocity", 3e-3),
    pytest.param("brach_dunn", 0.0, "tsuji", 0.5, marks=pytest.mark.slow),
    ("dmt", 0.05, "viscoelastic", 1e11),
    pytest.param("jkr", 0.05, "mass_velocity", 1e6, marks=pytest.mark.slow),
]


def scene(normal="brach_dunn", w=0.0, damping="velocity", eta=1e-4, **solver):
    contact = {"C_H": 0.0, "C_A": 0.0, "f0": 0.0, "eta_n": eta}
    if normal != "brach_dunn":
        contact["w"] = w
    model = {"adhesion": w > 0, "rolling_moments": "none", "normal": normal, "damping": damping}
    return TABLE1.replace(model=model, contact=contact, solver=solver or TIGHT)


def reference(normal, w, damping, eta, speed, angle, omega0):
    p = R.Params(
        radius=RADIUS, density=DENSITY, K=K, friction=0.3, rolling_moments="none",
        adhesion=w > 0, normal=normal, w=w, damping=damping, eta_n=eta,
    )  # fmt: skip
    return R.simulate_impact(p, speed, angle, omega0)


@pytest.mark.parametrize("normal,w,damping,eta", CASES)
def test_engine_against_the_exact_reference(normal, w, damping, eta):
    # normal and oblique spinning impacts, 0.1-10 m/s, rebounds; rtol 1e-10: within 5e-8 of
    # the speed (measured 1e-9 .. 2.8e-8 over every law x damping; slow sliding DMT with
    # Tsuji's damping 3.9e-7 at rtol 1e-10, 1.5e-10 at 1e-12: the solver's tolerance)
    speed = np.array([0.1, 0.7, 3.0, 10.0, 0.3, 2.0])
    angle = np.array([0.0, 0.0, 0.0, 0.0, 40.0, -25.0])
    omega0 = np.array([0.0, 0.0, 0.0, 0.0, 2e4, -1e4])
    out = ji.simulate(scene(normal, w, damping, eta), speed, angle, omega0)
    for i, (v, a, om) in enumerate(zip(speed, angle, omega0, strict=True)):
        ref = reference(normal, w, damping, eta, float(v), float(a), float(om))
        assert ref.status == "rebound" and int(out.status[i]) == 0
        assert abs(float(out.vn_out[i]) - ref.vn_out) / v < 5e-8, (i, v)
        assert abs(float(out.vt_out[i]) - ref.vt_out) / v < 5e-8, (i, v)
        assert abs(float(out.omega_out[i]) - ref.omega_out) * RADIUS / v < 5e-8, (i, v)


def _scale_free_restitution(alpha):
    """Restitution of ``x'' = -x^1.5 - alpha x^0.25 x'`` (Hertz with Tsuji's damping in the
    units where mass, stiffness and speed are 1), integrated here independently."""

    def rhs(t, y):
        x = max(y[0], 0.0)
        return [y[1], -(x**1.5) - alpha * x**0.25 * y[1]]

    def out(t, y):
        return y[0]

    out.terminal, out.direction = True, -1
    sol = solve_ivp(rhs, [0, 100], [0.0, 1.0], events=out, rtol=1e-12, atol=1e-14)
    return -sol.y_events[0][0][1]


def test_tsuji_damping_gives_one_restitution_at_every_speed():
    # Tsuji's damping scales as the Hertz stiffness: the restitution does not depend on the
    # speed, and it is that of the scale-free equation (LAMMPS's alpha(0.5) = 0.3407 gives
    # 0.6161, not 0.5: LAMMPS's polynomial does not return the e it takes)
    assert tsuji_alpha(0.5) == pytest.approx(0.34074062, rel=1e-7)
    assert abs(tsuji_alpha(1.0)) < 5e-4  # 3e-4: about undamped at e = 1
    speed = np.geomspace(0.05, 20.0, 8)
    cor = np.asarray(ji.simulate(scene(damping="tsuji", eta=0.5), speed).cor_n)
    assert np.ptp(cor) < 1e-8
    assert cor[0] == pytest.approx(_scale_free_restitution(tsuji_alpha(0.5)), abs=1e-8)


@pytest.mark.parametrize(
    "damping,eta,exponent", [("velocity", 1e-6, -0.2), ("viscoelastic", 1e9, 0.2)]
)
def test_weak_damping_scales_with_speed_as_its_law_says(damping, eta, exponent):
    # weak damping: 1 - e ~ eta_eff t_c ~ v^(-1/5) for a constant eta (the contact time goes
    # as v^(-1/5)) and v^(+1/5) for eta ~ a ~ n^0.5 (the overlap goes as v^(4/5))
    speed = np.geomspace(0.1, 10.0, 5)
    cor = np.asarray(ji.simulate(scene(damping=damping, eta=eta), speed).cor_n)
    slope = np.polyfit(np.log(speed), np.log(1.0 - cor), 1)[0]
    assert slope == pytest.approx(exponent, abs=2e-3)


def test_the_damping_loss_is_the_lost_energy():
    # normal impacts without adhesion: the ledger's damping loss is all the energy lost
    speed = np.array([0.05, 0.5, 5.0])
    for damping, eta in [("velocity", 3e-3), ("tsuji", 0.5)]:
        out = ji.simulate(scene(damping=damping, eta=eta), speed)
        lost = 0.5 * MASS * speed**2 * (1.0 - np.asarray(out.cor_n) ** 2)
        np.testing.assert_allclose(np.asarray(out.loss_hertz_damping), lost, rtol=1e-7, atol=0)


def test_the_derivative_in_eta_n_against_central_differences_of_the_reference():
    base = scene(damping="viscoelastic", eta=1e11)

    def cor(log_eta):
        eta = jax.numpy.exp(log_eta)
        return ji.simulate(base.replace(contact={"eta_n": eta}), 1.0, 30.0, 1e4).cor_n

    grad = float(jax.grad(cor)(math.log(1e11)))
    v_n = math.cos(math.radians(30.0))

    def ref(eta):
        return reference("brach_dunn", 0.0, "viscoelastic", eta, 1.0, 30.0, 1e4).vn_out / v_n

    h = 1e-4
    fd = (ref(1e11 * math.exp(h)) - ref(1e11 * math.exp(-h))) / (2 * h)
    assert grad == pytest.approx(fd, rel=1e-4)


def test_the_scene_checks_name_the_field():
    # (Scene.replace builds no new Scene: simulate checks what it changed)
    with pytest.raises(ji.SceneError, match="contact.C_H must be 0 with model.damping"):
        ji.simulate(TABLE1.replace(model={"damping": "velocity"}, contact={"eta_n": 1e-4}))
    with pytest.raises(ji.SceneError, match=r"contact.eta_n must be in \(0, 1\]"):
        ji.simulate(scene(damping="tsuji", eta=1.5))
    with pytest.raises(ji.SceneError, match="model.damping must be one of"):
        scene(damping="linear")
    with pytest.raises(ji.SceneError, match='not "thornton_ning"'):
        TABLE1.replace(model={"damping": "tsuji", "normal": "thornton_ning"})


def test_scene_files_take_the_damping_and_refuse_a_lone_coefficient(tmp_path):
    text = (
        "[particle]\nradius = 2e-5\ndensity = 2500.0\n[contact]\nK = 5e10\nC_H = 0.0\n"
        'eta_n = 0.7\n[model]\nadhesion = false\nrolling_moments = "none"\n'
    )
    lone = tmp_path / "lone.toml"
    lone.write_text(text)
    with pytest.raises(ji.SceneError, match="contact.eta_n is the coefficient of a LAMMPS"):
        ji.load_scene(lone)
    good = tmp_path / "tsuji.toml"
    good.write_text(text + 'damping = "tsuji"\n')
    loaded = ji.load_scene(good)
    assert loaded.model.damping == "tsuji" and float(loaded.contact.eta_n) == 0.7


def test_a_sphere_the_damping_stops_is_captured_not_rebounding():
    # Table 1's sphere, velocity damping 0.03 kg/s: at 0.01-1 m/s the damping takes all the
    # normal energy before the overlap returns to 0 (the exact reference creeps to its time
    # limit); it was reported rebounding with cor_n 0.9999 when the exit shell's energy ran out
    speed = np.array([0.01, 0.1, 1.0, 10.0])
    out = ji.simulate(scene(damping="velocity", eta=3e-2, rtol=1e-8), speed)
    assert np.asarray(out.status).tolist() == [1, 1, 1, 0]
    assert np.all(np.asarray(out.cor_n)[:3] == 0.0)
    assert 0 < float(out.cor_n[3]) < 0.01
    ref = reference("brach_dunn", 0.0, "velocity", 3e-2, 1.0, 0.0, 0.0)
    assert ref.status == "failed" and ref.vn_out < 1e-6  # creeping: no rebound speed


def test_jkr_pull_off_release_against_its_closed_form_and_the_reference():
    # model.jkr_release = "pull_off" (LAMMPS's JKR): the contact ends where the force is least,
    # a = (9 pi w r^2 / (8 E*))^(1/3), F = -1.5 pi w r; an elastic impact then loses the JKR
    # potential there (less than at the snap-off): e = sqrt(1 - 2 V(n_p) / (m v^2))
    w, E = 0.1, 0.75 * K
    a_p, n_p, force = R.jkr.pull_off(RADIUS, E, w)
    assert force == pytest.approx(-1.5 * math.pi * w * RADIUS, rel=1e-12)
    assert a_p == pytest.approx((9 * math.pi * w * RADIUS**2 / (8 * E)) ** (1 / 3), rel=1e-12)
    assert R.jkr.snap_off(RADIUS, E, w)[1] < n_p < 0
    params = R.Params(
        radius=RADIUS, density=DENSITY, K=K, rolling_moments="none", normal="jkr", w=w,
        jkr_release="pull_off",
    )  # fmt: skip
    barrier = params.jkr_barrier
    assert 0 < barrier < R.jkr.energy_loss(RADIUS, E, w)
    speed = np.array([0.01, 0.03, 0.3, 3.0])
    base = scene("jkr", w, "hertzian", 0.0).replace(model={"jkr_release": "pull_off"})
    out = ji.simulate(base, speed)
    closed = np.sqrt(1.0 - 2.0 * barrier / (MASS * speed**2))
    np.testing.assert_allclose(np.asarray(out.cor_n), closed, rtol=0, atol=2e-8)
    np.testing.assert_allclose(
        np.asarray(out.loss_adhesion_damping), barrier, rtol=1e-9
    )  # the ledger's JKR loss is the potential at the release
    # damped, oblique and spinning: the engine against the exact reference
    damped = scene("jkr", w, "tsuji", 0.7).replace(model={"jkr_release": "pull_off"})
    out = ji.simulate(damped, np.array([0.02, 0.5, 2.0]), 35.0, 1e4)
    for i, v in enumerate([0.02, 0.5, 2.0]):
        p = R.Params(
            radius=RADIUS, density=DENSITY, K=K, friction=0.3, rolling_moments="none",
            normal="jkr", w=w, damping="tsuji", eta_n=0.7, jkr_release="pull_off",
        )  # fmt: skip
        ref = R.simulate_impact(p, v, 35.0, 1e4)
        assert ref.status == "rebound" and int(out.status[i]) == 0
        assert abs(float(out.vn_out[i]) - ref.vn_out) / v < 5e-8
        assert abs(float(out.omega_out[i]) - ref.omega_out) * RADIUS / v < 5e-8
    with pytest.raises(ji.SceneError, match='jkr_release = "pull_off" is for model.normal'):
        TABLE1.replace(model={"jkr_release": "pull_off"})

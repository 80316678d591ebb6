"""LAMMPS's tangential history springs (``model.tangential = "lammps_linear_history"`` and
``"lammps_mindlin"``): the engine against the exact reference, the sliding impact's closed
form, the energy ledger and the scene's checks. (LAMMPS itself: tests/test_lammps_reference.py,
slow.)"""

import math

import jax
import numpy as np
import pytest

import jaximpact as ji
from jaximpact import reference as R

jax.config.update("jax_enable_x64", True)

TABLE1 = ji.table1_scene()
RADIUS = float(TABLE1.particle.radius)
DENSITY = float(TABLE1.particle.density)
K = float(TABLE1.contact.K)
SPRINGS = {"lammps_linear_history": {"k_t": 2e4}, "lammps_mindlin": {"G_star": 2e10}}


def scene(tangential, normal="brach_dunn", w=0.0, damping="hertzian", eta=0.0, friction=0.3):
    contact = {"C_H": 0.0, "C_A": 0.0, "f0": 0.0, "friction": friction, **SPRINGS[tangential]}
    model = {"adhesion": w > 0, "rolling_moments": "none", "normal": normal,
             "tangential": tangential}  # fmt: skip
    if damping != "hertzian":
        model["damping"], contact["eta_n"] = damping, eta
    if normal != "brach_dunn":
        contact["w"] = w
    if normal == "jkr":
        model["jkr_release"] = "pull_off"
    return TABLE1.replace(model=model, contact=contact, solver={"rtol": 1e-10, "atol": 1e-12})


@pytest.mark.parametrize(
    "tangential,normal,w,damping,eta",
    [
        ("lammps_linear_history", "brach_dunn", 0.0, "hertzian", 0.0),
        pytest.param("lammps_linear_history", "dmt", 0.05, "tsuji", 0.7, marks=pytest.mark.slow),
        ("lammps_mindlin", "brach_dunn", 0.0, "velocity", 1e-3),
        pytest.param("lammps_mindlin", "jkr", 0.05, "hertzian", 0.0, marks=pytest.mark.slow),
    ],
)
def test_engine_against_the_exact_reference(tangential, normal, w, damping, eta):
    # sticking, slipping and spinning impacts; within 1e-5 of the speed (measured 1e-6 ..
    # 6.4e-6 over both springs x Hertz, DMT, JKR: the cap's regularization, as jaximpact's
    # own Mindlin spring, 2.5e-6)
    speed = np.array([0.1, 1.0, 5.0, 1.0, 2.0])
    angle = np.array([30.0, 45.0, 70.0, 10.0, 60.0])
    omega0 = np.array([0.0, 1e4, -2e4, 5e4, 0.0])
    out = ji.simulate(scene(tangential, normal, w, damping, eta), speed, angle, omega0)
    for i, v in enumerate(speed):
        p = R.Params(
            radius=RADIUS, density=DENSITY, K=K, friction=0.3, rolling_moments="none",
            adhesion=w > 0, normal=normal, w=w, damping=damping, eta_n=eta,
            tangential=tangential, jkr_release="pull_off" if normal == "jkr" else "snap_off",
            **SPRINGS[tangential],
        )  # fmt: skip
        ref = R.simulate_impact(p, float(v), float(angle[i]), float(omega0[i]))
        assert ref.status == "rebound" and int(out.status[i]) == 0, (i, ref.status)
        assert abs(float(out.vn_out[i]) - ref.vn_out) / v < 1e-5, i
        assert abs(float(out.vt_out[i]) - ref.vt_out) / v < 1e-5, i
        assert abs(float(out.omega_out[i]) - ref.omega_out) * RADIUS / v < 1e-5, i


def test_a_sliding_impact_takes_the_coulomb_impulse():
    # undamped Hertz (e = 1), a grazing angle and a stiff spring: the spring's cap f N / k_t
    # (0 at first touch) grows far slower than the slip moves the spring, so the contact
    # slides throughout and the friction impulse is f (1 + e) m v_n (a soft spring, 2e3 N/m,
    # whose cap grows about as fast as the slip, sticks for part of the contact: 75 % of it)
    f, speed, angle = 0.1, 2.0, 75.0
    v_n, v_t = speed * math.cos(math.radians(angle)), speed * math.sin(math.radians(angle))
    for k_t in (2e5, 2e6):
        sc = scene("lammps_linear_history", friction=f).replace(contact={"k_t": k_t})
        out = ji.simulate(sc, speed, angle, 0.0)
        assert float(out.cor_n) == pytest.approx(1.0, abs=1e-8)
        assert float(out.vt_out) == pytest.approx(v_t - 2.0 * f * v_n, abs=1e-5 * speed)
        # the spin from the same impulse at the radius: 2 f v_n m r / (0.4 m r^2)
        assert float(out.omega_out) * RADIUS == pytest.approx(5.0 * f * v_n, abs=1e-5 * speed)


def test_the_ledger_closes_with_the_springs_losses():
    # LAMMPS's springs have no normal force: the change of a Mindlin stiffness does work on
    # the spring, and the history dropped at the end is lost; both are in loss_friction
    speed = np.array([0.1, 1.0, 5.0])
    angle = np.array([30.0, 45.0, 70.0])
    for tangential in SPRINGS:
        out = ji.simulate(scene(tangential, damping="velocity", eta=1e-3), speed, angle, 1e4)
        lost = sum(
            np.asarray(getattr(out, k))
            for k in ("loss_hertz_damping", "loss_adhesion_damping", "loss_friction")
        )
        balance = np.asarray(out.energy_in) - np.asarray(out.energy_out) - lost
        assert np.max(np.abs(balance) / np.asarray(out.energy_in)) < 2e-6, tangential


def test_the_scene_checks_name_the_field():
    with pytest.raises(ji.SceneError, match="contact.k_t .* must be"):
        ji.simulate(TABLE1.replace(model={"tangential": "lammps_linear_history"}), 1.0, 30.0)
    with pytest.raises(ji.SceneError, match="model.tangential must be one of"):
        TABLE1.replace(model={"tangential": "linear"})
    with pytest.raises(ji.SceneError, match='works with model.tangential = "rigid" only'):
        TABLE1.replace(model={"normal": "thornton_ning", "tangential": "lammps_mindlin"})

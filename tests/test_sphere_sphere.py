"""Sphere-sphere impacts (``[target]``): the flat wall as the limit of a large second sphere,
the reduced-radius and reduced-mass identity of two equal spheres, and oblique spinning
impacts of both spins against the exact reference (which has no state for the second spin:
it follows from the pair's angular momentum)."""

import equinox as eqx
import numpy as np
import pytest
from reference_checks import LOSSES, check_derivatives, check_impacts, random_impacts

import jaximpact as ji
from jaximpact import reference as ref

R = 35e-6


def with_target(scene, radius, density, omega0=0.0):
    return eqx.tree_at(
        lambda s: s.target,
        scene,
        ji.Target(radius=radius, density=density, omega0=omega0),
        is_leaf=lambda x: x is None,
    )


ARGS = (np.array([0.1, 1.0, 3.0]), np.array([0.0, 30.0, -60.0]), np.array([0.0, 1e4, 3e4]))


@pytest.mark.slow  # two programs
def test_a_huge_second_sphere_is_the_wall():
    """``r2 = 1e9 m`` (and a huge density): the wall's results to 1e-8 of the speed (the
    reduced radius differs from the wall's in the 14th digit, which changes the adaptive
    steps: measured 2.2e-9 in the spin of a 3 m/s, -60 deg impact)."""
    wall = ji.table1_scene()
    far = with_target(wall, 1e9, 1e25)
    a, b = ji.simulate(wall, *ARGS, program="compact"), ji.simulate(far, *ARGS, program="compact")
    speed = ARGS[0]
    for k, scale in (("vn_out", speed), ("vt_out", speed), ("omega_out", speed / R)):
        err = np.abs(np.asarray(getattr(a, k)) - np.asarray(getattr(b, k))) / scale
        assert np.max(err) < 1e-8, k
    np.testing.assert_allclose(np.asarray(a.contact_time), np.asarray(b.contact_time), rtol=1e-8)


@pytest.mark.slow  # six programs
def test_two_equal_spheres_head_on_are_a_half_radius_sphere_on_the_wall():
    """Normal impact of two equal spheres (r, rho): the relative motion is the wall impact of
    a sphere of radius r/2 and the same reduced mass m/2 (density 4 rho), whatever the law
    (to 1e-8: ``r r / (2 r)`` and ``r / 2`` may differ in the last digit, and the adaptive
    steps with them)."""
    base = ji.table1_scene()
    for law in ("brach_dunn", "dmt", "jkr"):
        scene = base.with_normal_law(law)
        pair = with_target(scene, R, 8000.0)
        half = scene.replace(particle={"radius": R / 2, "density": 4 * 8000.0})
        speeds = np.array([0.05, 0.3, 2.0])
        a = ji.simulate(pair, speeds, 0.0, 0.0, program="compact")
        b = ji.simulate(half, speeds, 0.0, 0.0, program="compact")
        np.testing.assert_array_equal(np.asarray(a.status), np.asarray(b.status))
        for k, rtol in (("cor_n", 1e-8), ("contact_time", 1e-7), ("max_overlap", 1e-7)):
            np.testing.assert_allclose(
                np.asarray(getattr(a, k)), np.asarray(getattr(b, k)), rtol=rtol, atol=1e-15,
                err_msg=law,
            )  # fmt: skip


TARGETS = [(20e-6, 2500.0, 0.0), (35e-6, 8000.0, 3e4), (100e-6, 1000.0, -1e4)]


@pytest.mark.parametrize("r2, rho2, omega2", TARGETS)
def test_oblique_spinning_impacts_match_the_reference(r2, rho2, omega2):
    """Statuses equal, relative velocities and the particle's spin within 1e-7 of the speed
    (measured 8e-9), the ledger closed (both spins' energy counted)."""
    scene = with_target(ji.table1_scene(), r2, rho2, omega2)
    p = ref.table1_params(radius2=r2, density2=rho2, omega2=omega2)
    speeds = np.geomspace(0.01, 5.0, 8)
    angles, omega0 = random_impacts(5, speeds, R)
    check_impacts(scene, p, speeds, angles, omega0)
    res = ji.simulate(scene, speeds, angles, omega0)
    for i, v in enumerate(speeds):
        q = ref.simulate_impact(p, v, angles[i], omega0[i])
        assert float(res.energy_in[i]) == pytest.approx(q.energy_in, rel=1e-12)
        # the second sphere's spin: the reference's follows from the pair's angular momentum
        assert float(res.omega2_out[i]) * r2 == pytest.approx(q.omega2_out * r2, abs=1e-7 * v)


def test_second_spin_keeps_the_pairs_angular_momentum():
    """The target's spin after the impact (``omega2_out``, a state of the engine) with the
    particle's spin and the relative tangential velocity keep the pair's angular momentum
    about the contact, ``I1 (w1 - w10) + I2 (w2 - w20) + (r + r2) m* (vt - vt0) = 0``, to
    1e-9 of ``(r + r2) m* speed``; a wall scene has no such output."""
    r2, rho2, omega2 = TARGETS[1]
    scene = with_target(ji.table1_scene(), r2, rho2, omega2)
    p = ref.table1_params(radius2=r2, density2=rho2, omega2=omega2)
    speeds = np.geomspace(0.01, 5.0, 8)
    angles, omega0 = random_impacts(5, speeds, R)
    res = ji.simulate(scene, speeds, angles, omega0)
    I1, I2 = p.mass * p.k2, p.mass2 * p.kappa * r2**2
    arm = (p.radius + r2) * p.reduced_mass
    vt0 = speeds * np.sin(np.radians(angles))
    balance = (
        I1 * (np.asarray(res.omega_out) - omega0)
        + I2 * (np.asarray(res.omega2_out) - omega2)
        + arm * (np.asarray(res.vt_out) - vt0)
    )
    assert np.all(np.abs(balance) < 1e-9 * arm * speeds), balance / (arm * speeds)
    assert np.any(np.abs(np.asarray(res.omega2_out) - omega2) > 1e-3 * np.abs(omega2))
    assert ji.simulate(ji.table1_scene(), speeds[:2], angles[:2], omega0[:2]).omega2_out is None


# Kharaz, Gorham & Salman (2001): alumina, E = 380 GPa, nu = 0.23 (as in test_mindlin.py)
G_ALUMINA = 380e9 / (2 * 1.23) / (2 - 0.23)


def test_mindlin_spring_with_a_second_sphere_matches_the_reference():
    """``model.tangential = "mindlin"`` with a ``[target]``: the spring of the reduced
    radius, both spins. Against the exact reference's Mindlin model of the pair (its second
    spin from the pair's angular momentum): statuses equal, rebound velocities and both spins
    within 1e-5 of the speed (the Mindlin target; measured 3e-6), both ledgers closed, the
    pair's angular momentum kept; and the reference's pair with a huge second sphere is its
    wall impact."""
    base = ji.load_scene("kharaz2001").replace(
        model={"tangential": "mindlin"}, contact={"G_star": G_ALUMINA}
    )
    r, rho, c = float(base.particle.radius), float(base.particle.density), base.contact

    def twin(**target):
        return ref.Params(
            radius=r, density=rho, K=float(c.K), C_H=float(c.C_H), friction=float(c.friction),
            adhesion=False, rolling_moments="none", tangential="mindlin", G_star=G_ALUMINA,
            **target,
        )  # fmt: skip

    speeds = np.array([1.0, 2.5, 3.9, 4.5])
    angles, omega0 = np.array([5.0, 20.0, 40.0, -60.0]), np.array([0.0, 2e3, -1e3, 5e3])
    for r2, rho2, omega2 in ((r, 3900.0, 0.0), (3 * r, 2000.0, 1500.0)):
        scene = with_target(base, r2, rho2, omega2)
        p = twin(radius2=r2, density2=rho2, omega2=omega2)
        res = ji.simulate(scene, speeds, angles, omega0)
        for i, v in enumerate(speeds):
            q = ref.simulate_impact(p, v, angles[i], omega0[i])
            assert q.status == "rebound" and int(res.status[i]) == ji.Status.REBOUND
            assert abs(q.ledger_residual) < 1e-9  # relative to the energy in
            assert float(res.energy_in[i]) == pytest.approx(q.energy_in, rel=1e-12)
            for k, arm in (("vn_out", 1.0), ("vt_out", 1.0), ("omega_out", r), ("omega2_out", r2)):
                got, exact = float(getattr(res, k)[i]) * arm, getattr(q, k) * arm
                assert got == pytest.approx(exact, abs=1e-5 * v), (k, v, r2)
        losses = sum(np.asarray(getattr(res, k)) for k in LOSSES)
        ledger = np.asarray(res.energy_in) - np.asarray(res.energy_out) - losses
        assert np.all(np.abs(ledger) < 1e-7 * np.asarray(res.energy_in))
        I1, I2 = p.mass * p.k2, p.mass2 * p.kappa * r2**2
        arm = (r + r2) * p.reduced_mass
        balance = (
            I1 * (np.asarray(res.omega_out) - omega0)
            + I2 * (np.asarray(res.omega2_out) - omega2)
            + arm * (np.asarray(res.vt_out) - speeds * np.sin(np.radians(angles)))
        )
        assert np.all(np.abs(balance) < 1e-9 * arm * speeds)
    wall = ref.simulate_impact(twin(), 3.0, 30.0, 1000.0)
    far = ref.simulate_impact(twin(radius2=1e9, density2=1e25), 3.0, 30.0, 1000.0)
    for k in ("vn_out", "vt_out"):
        assert getattr(far, k) == pytest.approx(getattr(wall, k), abs=1e-12 * 3.0)
    assert far.omega_out * r == pytest.approx(wall.omega_out * r, abs=1e-12 * 3.0)


@pytest.mark.slow  # a Jacobian program
def test_derivatives_with_a_second_sphere_match_the_reference():
    """``d/dC_H``, friction, speed, angle and the target's radius, density and spin of a
    spinning oblique rebound on a second sphere against the reference's central
    differences."""
    r2, rho2 = 50e-6, 2500.0
    scene = with_target(ji.table1_scene(), r2, rho2, 5e3)
    p = ref.table1_params(radius2=r2, density2=rho2, omega2=5e3)
    inputs = ("C_H", "friction", "speed", "angle_deg", "radius2", "density2", "omega2")
    check_derivatives(scene, p, 1.0, 35.0, 0.1 * 1.0 / R, inputs)


def test_scene_file_target_section(tmp_path):
    path = tmp_path / "pair.toml"
    path.write_text(
        "[particle]\nradius = 35e-6\ndensity = 8000.0\n[contact]\nK = 11.4e10\n"
        "[target]\nradius = 50e-6\ndensity = 2500.0\nomega0 = 1e3\n"
    )
    scene = ji.load_scene(path)
    assert float(scene.target.radius) == 50e-6 and float(scene.target.omega0) == 1e3
    path.write_text(path.read_text().replace("radius = 50e-6", "radius = -1.0"))
    with pytest.raises(ji.SceneError, match="target.radius must be finite and in"):
        ji.load_scene(path)
    mindlin = ji.scene_path("kharaz2001_mindlin").read_text()
    path.write_text(mindlin + "\n[target]\nradius = 1e-3\ndensity = 1000.0\n")
    pair = ji.load_scene(path)  # the Mindlin spring combines with a second sphere
    assert pair.model.tangential == "mindlin" and float(pair.target.radius) == 1e-3

"""The DMT normal law (``model.normal = "dmt"``): its force against the closed forms, elastic
impacts against their energy balance, whole impacts against the exact switched reference, its
derivatives against central differences of that reference, and the scene file's rules."""

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
from scipy.optimize import brentq

import jaximpact as ji
from jaximpact import reference as ref
from jaximpact._engine.simulate import _scaled, required_terms, scene_parameters
from jaximpact._model import dynamics as dyn
from jaximpact._model import laws
from jaximpact.wall_law import adhesion_speed

R, RHO, K = 35e-6, 8000.0, 11.4e10


def dmt_scene(w=5.0, C_H=0.22, friction=0.3, moments="analytical", **model):
    return ji.table1_scene().replace(
        contact={"w": w, "f0": 0.0, "C_H": C_H, "friction": friction},
        model={"normal": "dmt", "rolling_moments": moments, **model},
    )


def dmt_params(w=5.0, C_H=0.22, friction=0.3, moments="analytical"):
    return ref.table1_params(
        normal="dmt", w=w, f0=0.0, C_H=C_H, friction=friction, rolling_moments=moments
    )


def test_force_is_hertz_plus_the_constant_pull_off():
    """In contact the force is Hertz plus ``2 pi w r`` whatever the overlap and speed; at zero
    overlap the sphere is held by the DMT pull-off force ``2 pi w R`` (SI and Hertz units)."""
    w = 0.7
    n = jnp.array([1e-12, 1e-9, 3e-8, 2e-7])
    got = laws.dmt_adhesion_force(n, R, w)
    np.testing.assert_allclose(np.asarray(got), 2 * math.pi * w * R, rtol=1e-15)
    scene = dmt_scene(w=w)
    params = scene_parameters(scene)
    terms = required_terms(scene, params, 30.0, 1e4)
    assert terms.adhesion and not terms.ring
    p, u = _scaled(params, 1.0, 30.0, 1e4)
    y = {"n": jnp.array(0.3), "ndot": jnp.array(0.2), "vt": jnp.array(0.5), "w": jnp.array(0.1)}
    f = dyn.contact_loads(terms, p, y)
    hertz = -p.K * jnp.sqrt(p.radius) * 0.3**1.5
    pull = 2 * math.pi * w * R / (u.mass * u.speed / u.time)  # N in Hertz units
    np.testing.assert_allclose(float(f["F_A"]), pull, rtol=1e-12)
    np.testing.assert_allclose(float(f["F_n"]), float(hertz * (1 + p.C_H * 0.2) + pull), rtol=1e-12)
    # The peeling moment belongs to the ring: only the Hertzian moment acts.
    assert float(f["M_A"]) == 0.0 and float(f["M_H"]) < 0.0
    # The reference's force is the same law.
    fc = ref.contact_forces(dmt_params(w=w), 1e-9, 0.01, 1e3)
    assert fc["F_A"] == pytest.approx(2 * math.pi * w * R, rel=1e-15)
    assert fc["F_AD"] == 0.0 and fc["M_A"] == 0.0


def test_elastic_impact_conserves_energy_and_reaches_the_closed_form_overlap():
    """Without damping or friction a DMT impact is elastic (the constant force does as much work
    on the way in as on the way out): ``cor_n = 1``; its largest overlap solves
    ``(2/5) K sqrt(r) n^2.5 - 2 pi w r n = m v^2 / 2``."""
    w = 2.0
    scene = dmt_scene(w=w, C_H=0.0, friction=0.0, moments="none")
    speeds = np.array([0.003, 0.05, 1.0, 10.0])
    res = ji.simulate(scene, speeds, 0.0, 0.0)
    mass = RHO * 4 / 3 * math.pi * R**3
    assert np.all(np.asarray(res.status) == ji.Status.REBOUND)
    np.testing.assert_allclose(np.asarray(res.cor_n), 1.0, atol=1e-8)
    for v, got in zip(speeds, np.asarray(res.max_overlap), strict=True):

        def balance(n, v=v):
            return 0.4 * K * math.sqrt(R) * n**2.5 - 2 * math.pi * w * R * n - 0.5 * mass * v * v

        want = brentq(balance, 1e-15, 1e-3, xtol=1e-30, rtol=1e-15)
        assert got == pytest.approx(want, rel=1e-7), v


LOSSES = ("loss_hertz_damping", "loss_adhesion_damping", "loss_friction", "loss_rolling")


def test_slow_elastic_exits_keep_their_energy():
    """An undamped DMT impact rebounds with ``cor_n = 1`` at any speed (no force out of
    contact): down to 1e-6 of the adhesion speed ``v_ad``, where the well is 1e12 times the
    impact's energy, ``cor_n`` stays within 1e-6 of 1. The exit speed comes from the energy
    balance (``dynamics.balanced_normal_energy``); from ``ndot^2/2 + V(n)`` it was 2.7e-3 off
    at 1e-4 v_ad, 3e-2 at 3e-5, and the impacts at 1e-5 and 1e-6 v_ad were reported captured.
    Oblique too (the rigid tangential law does no work on the normal motion)."""
    w = 5.0
    scene = dmt_scene(w=w, C_H=0.0, moments="none")
    params = scene_parameters(scene)
    v_ad = float(adhesion_speed(params["radius"], params["density"], params["K"], 0.0, w, "dmt"))
    ratios = np.array([1.0, 1e-1, 1e-2, 1e-3, 1e-4, 3e-5, 1e-5, 1e-6])
    for angle in (0.0, 40.0):
        res = ji.simulate(scene, v_ad * ratios, angle, 0.0)
        assert list(res.status_names) == ["rebound"] * ratios.size, angle
        np.testing.assert_allclose(np.asarray(res.cor_n), 1.0, rtol=0, atol=1e-6)
        # the ledger closes (friction's loss the only one)
        lost = sum(np.asarray(getattr(res, k)) for k in LOSSES)
        np.testing.assert_allclose(np.asarray(res.energy_out) + lost, res.energy_in, 1e-9)
        assert np.all(np.asarray(res.loss_hertz_damping) == 0.0)


def test_capture_in_the_first_step_is_seen():
    """An adhesion far stronger than the impact (w = 1e3 J/m^2 on r = 10 nm: the adhesion speed
    is 8 km/s) captures the sphere within the solver's first step, as the reference says. The
    event function started at 0 (the overlap at the floor), so that step's fall below zero
    was no crossing, and the solve ran to max_steps."""
    scene = dmt_scene(w=1e3).replace(particle={"radius": 1e-8})
    res = ji.simulate(scene, [1e-4, 1e-2], 0.0, 0.0)
    assert list(res.status_names) == ["captured", "captured"]
    assert np.all(np.asarray(res.steps) < 20)
    p = ref.table1_params(normal="dmt", w=1e3, f0=0.0, radius=1e-8)
    assert ref.simulate_impact(p, 1e-4, 0.0, 0.0).status == "captured"


@pytest.mark.slow  # two programs (JKR's w = 0 runs by default)
def test_zero_work_of_adhesion_is_the_hertz_law():
    """``w = 0`` compiles no adhesion, and gives the Brach-Dunn law without adhesion exactly."""
    dmt = dmt_scene(w=0.0)
    bd = ji.table1_scene().replace(contact={"f0": 0.0, "C_H": 0.22}, model={"adhesion": False})
    args = (np.array([0.1, 1.0, 3.0]), np.array([0.0, 30.0, -60.0]), np.array([0.0, 1e4, 3e4]))
    a, b = ji.simulate(dmt, *args), ji.simulate(bd, *args)
    for k in ("cor_n", "vt_out", "omega_out", "contact_time", "loss_friction"):
        np.testing.assert_array_equal(np.asarray(getattr(a, k)), np.asarray(getattr(b, k)), k)


# Rebounds and captures on both sides of the capture speed, oblique and spinning.
CASES = [
    (5.0, 0.22, "analytical"),
    pytest.param(0.5, 2.0, "none", marks=pytest.mark.slow),
    pytest.param(50.0, 0.5, "lambda", marks=pytest.mark.slow),
]


@pytest.mark.parametrize("w, C_H, moments", CASES)
def test_impacts_match_the_exact_reference(w, C_H, moments):
    """Whole impacts against the switched, event-located reference (rtol 1e-12): every status
    the same, velocities and spin within 1e-7 of the speed (measured 1e-9), the ledger closed
    (to 1e-7 of the energy exchanged: slow impacts exchange far more with the adhesion than
    they bring in)."""
    lam = 1e-9 if moments == "lambda" else 0.0
    scene = dmt_scene(w=w, C_H=C_H, moments=moments).replace(model={"lambda_": lam})
    p = ref.Params(**{**dmt_params(w=w, C_H=C_H, moments=moments).__dict__, "lam": lam})
    speeds = np.geomspace(1e-3, 5.0, 10)
    angles, omega0 = random_impacts(17, speeds, R)

    def exchanged(res, i):
        return float(res.energy_in[i]) + 2 * math.pi * w * R * float(res.max_overlap[i])

    seen = check_impacts(scene, p, speeds, angles, omega0, exchanged=exchanged)
    assert seen == {"rebound", "captured"} or moments != "analytical"
    res = ji.simulate(scene, speeds, angles, omega0)
    assert np.all(np.asarray(res.loss_adhesion_damping) == 0.0)  # no ring, no its damping


@pytest.mark.slow  # a Jacobian program (JKR's runs by default)
def test_derivatives_match_central_differences_of_the_reference():
    """``d/dw``, ``d/dC_H`` and the impact's inputs of a spinning oblique rebound, from
    ``output_jacobian``, against the reference's Richardson-checked central differences."""
    inputs = ("w", "C_H", "friction", "speed", "angle_deg")
    check_derivatives(dmt_scene(w=2.0), dmt_params(w=2.0), 0.4, 35.0, 0.1 * 0.4 / R, inputs)


def test_batch_does_not_change_a_lane():
    """An impact gives bitwise the same result alone and inside a batch of other impacts."""
    scene = dmt_scene(w=5.0)
    speeds = np.array([0.02, 0.05, 0.3, 2.0])
    angles = np.array([0.0, 40.0, -20.0, 60.0])
    omega0 = np.array([0.0, 2e4, -1e4, 0.0])
    check_batch_exact(scene, speeds, angles, omega0)


@pytest.mark.slow  # reverse and forward programs
def test_jax_grad_in_w_through_simulate():
    """``jax.grad`` of a rebound's ``cor_n`` in ``w`` is finite and agrees with ``jax.jacfwd``."""

    def cor(w):
        scene = dmt_scene(w=w)
        return ji.simulate(scene, 0.3, 20.0, 0.0, program="compact").cor_n

    g = jax.grad(cor)(2.0)
    f = jax.jacfwd(cor)(2.0)
    assert np.isfinite(float(g)) and float(g) == pytest.approx(float(f), rel=1e-6)


def _write(tmp_path, text):
    path = tmp_path / "scene.toml"
    path.write_text(text)
    return path


BASE = """
[particle]
radius = 35e-6
density = 8000.0
[contact]
K = 11.4e10
C_H = 0.22
friction = 0.3
"""


def test_scene_file_selects_the_law_and_names_wrong_keys(tmp_path):
    scene = ji.load_scene(_write(tmp_path, BASE + 'w = 0.5\n[model]\nnormal = "dmt"\n'))
    assert scene.model.normal == "dmt" and scene.model.adhesion
    assert float(scene.contact.w) == 0.5
    with pytest.raises(ji.SceneError, match="contact.f0 is the adhesion ring"):
        ji.load_scene(_write(tmp_path, BASE + 'f0 = 3.0\nw = 0.5\n[model]\nnormal = "dmt"\n'))
    with pytest.raises(ji.SceneError, match='contact.w .* only with model.normal = "dmt"'):
        ji.load_scene(_write(tmp_path, BASE + "w = 0.5\n"))
    with pytest.raises(ji.SceneError, match="model.normal must be one of"):
        ji.load_scene(_write(tmp_path, BASE + '[model]\nnormal = "hooke"\n'))
    with pytest.raises(ji.SceneError, match=r"contact.w must be finite and in \[0, 1e4\]"):
        ji.load_scene(_write(tmp_path, BASE + 'w = -1.0\n[model]\nnormal = "dmt"\n'))


def test_with_normal_law_carries_the_adhesion_over():
    """Brach-Dunn to DMT/JKR: ``w`` gives the ring's force at its adhesive equilibrium
    overlap; back to Brach-Dunn the same ``f0``; the same law is the scene itself."""
    scene = ji.table1_scene()
    f0, K_, r = 325.0, float(scene.contact.K), float(scene.particle.radius)
    n_eq = 2 * math.pi * f0 / K_
    for law in ("dmt", "jkr"):
        other = scene.with_normal_law(law)
        assert other.model.normal == law and float(other.contact.f0) == 0.0
        w = float(other.contact.w)
        assert 2 * math.pi * w * r == pytest.approx(2 * math.pi * math.sqrt(r * n_eq) * f0)
        back = other.with_normal_law("brach_dunn")
        assert float(back.contact.f0) == pytest.approx(f0, rel=1e-12)
        assert float(back.contact.w) == 0.0
    assert scene.with_normal_law("brach_dunn") is scene
    with pytest.raises(ji.SceneError, match="model.normal must be one of"):
        scene.with_normal_law("hooke")


def test_compare_by_law_name_maps_the_fitted_names():
    """``fit --compare brach_dunn,jkr,dmt`` on a Brach-Dunn scene: DMT and JKR with ``w`` for
    ``f0`` and without the ring's ``C_A``; the scene's own law is not fitted twice; a name a
    law does not use is refused before any computing."""
    from types import SimpleNamespace

    from fitting._least_squares.objective import FitError
    from fitting.cli import _compared_models, _law_names

    args = SimpleNamespace(compare=["brach_dunn,jkr,dmt"], prior=[])
    models = _compared_models(args, ("C_A", "C_H", "f0"), None)
    assert list(models) == ["jkr", "dmt"]
    for law, (scene, names, _) in models.items():
        assert scene.model.normal == law and names == ("C_H", "w")
    assert _law_names(("w", "C_H"), "jkr", "brach_dunn") == ("f0", "C_A", "C_H")
    with pytest.raises(FitError, match="f0 is the Brach-Dunn ring's"):
        _compared_models(SimpleNamespace(compare=["dmt=f0,C_H"], prior=[]), ("f0",), None)


def test_compare_prior_for_another_models_parameter(capsys):
    """With ``--compare`` a ``--prior`` may name a parameter only a compared model fits (``w``
    of the DMT law), and one that no model fits is refused before any computing."""
    from jaximpact.cli import main

    base = ["fit", "kharaz2001", "--params", "friction", "--posterior", "--no-progress"]
    code = main([*base, "--compare", "dmt=friction,w", "--prior", "K=loguniform:1e9:1e12"])
    assert code == 2
    assert "--prior K: not among the fitted parameters of any model" in capsys.readouterr().err
    code = main([*base, "--prior", "w=loguniform:1e-3:10"])
    assert code == 2 and "--prior w" in capsys.readouterr().err


@pytest.mark.slow  # a Mindlin program
def test_dmt_with_the_mindlin_spring_matches_the_reference():
    """The DMT law with the Mindlin tangential spring against the reference's Mindlin model:
    within 1e-5 of the speed at the default settings (measured 1.3e-6; the Mindlin scene's
    own accuracy, BENCHMARKS.md "Tangential compliance")."""
    scene = dmt_scene(w=5.0).replace(contact={"G_star": 3e10}, model={"tangential": "mindlin"})
    p = ref.Params(**{**dmt_params(w=5.0).__dict__, "tangential": "mindlin", "G_star": 3e10})
    speeds = np.geomspace(0.05, 5.0, 6)
    angles, omega0 = random_impacts(2, speeds, R)
    check_impacts(scene, p, speeds, angles, omega0, tol=1e-5)


def test_with_normal_law_keeps_the_mindlin_spring():
    for law in ("dmt", "jkr"):
        scene = ji.load_scene("kharaz2001_mindlin").with_normal_law(law)
        assert (scene.model.normal, scene.model.tangential) == (law, "mindlin")
        assert float(scene.contact.G_star) > 0

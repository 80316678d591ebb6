"""Scene files: loading, derived constants, and rejection of every invalid value by name."""

import math

import pytest

import jaximpact as ji
from jaximpact import SceneError

BASE = """
[particle]
radius = 35e-6
density = 8000.0
[contact]
K = 11.4e10
f0 = 325.0
C_A = 0.88
C_H = 0.22
friction = 0.3
"""


def write(tmp_path, text):
    path = tmp_path / "scene.toml"
    path.write_text(text)
    return path


def test_embedded_scene_is_table1():
    scene = ji.load_scene()
    assert float(scene.particle.radius) == 35e-6
    assert float(scene.contact.C_A) == pytest.approx(0.8818, rel=1e-3)
    assert float(scene.contact.C_H) == pytest.approx(0.2204, rel=1e-3)
    assert float(scene.impact.omega0) == pytest.approx(math.radians(1e6))
    assert scene.model.rolling_moments == "analytical" and scene.model.adhesion


def test_zeta_conversion_matches_eq21(tmp_path):
    # C = zeta (r^3 K v^0.5 / m)^-0.4, computed here independently.
    r, rho, K, v = 35e-6, 8000.0, 11.4e10, 1.66
    m = rho * 4 / 3 * math.pi * r**3
    expected = 400 * (r**3 * K * math.sqrt(v) / m) ** -0.4
    text = BASE.replace("C_A = 0.88", "zeta_A = 400.0\nreference_speed = 1.66")
    scene = ji.load_scene(write(tmp_path, text))
    assert float(scene.contact.C_A) == pytest.approx(expected, rel=1e-12)


def test_stiffness_from_elastic_constants(tmp_path):
    text = BASE.replace("K = 11.4e10", "E1 = 200e9\nnu1 = 0.3\nE2 = 70e9\nnu2 = 0.2")
    scene = ji.load_scene(write(tmp_path, text))
    e_star = 1 / ((1 - 0.3**2) / 200e9 + (1 - 0.2**2) / 70e9)
    assert float(scene.contact.K) == pytest.approx(4 / 3 * e_star, rel=1e-6)


def test_adhesion_defaults_to_f0_positive(tmp_path):
    scene = ji.load_scene(write(tmp_path, BASE.replace("f0 = 325.0", "f0 = 0.0")))
    assert not scene.model.adhesion


@pytest.mark.parametrize(
    "old, new, field",
    [
        ("radius = 35e-6", "radius = -1.0", "particle.radius"),
        ("radius = 35e-6", "radius = nan", "particle.radius"),
        ("density = 8000.0", "density = 0.0", "particle.density"),
        ("K = 11.4e10", "K = -3.0", "contact.K"),
        ("K = 11.4e10", "E1 = 1e9\nnu1 = 0.7\nE2 = 1e9\nnu2 = 0.2", "contact.nu1"),
        ("K = 11.4e10", "E1 = -1e9\nnu1 = 0.3\nE2 = 1e9\nnu2 = 0.2", "contact.E1"),
        ("K = 11.4e10", "K = 1e10\nE1 = 1e9", "contact.K"),
        ("f0 = 325.0", "f0 = -1.0", "contact.f0"),
        ("C_A = 0.88", "C_A = -0.1", "contact.C_A"),
        ("C_H = 0.22", "C_H = inf", "contact.C_H"),
        ("friction = 0.3", "friction = -0.3", "contact.friction"),
        ("friction = 0.3", "friction = 0.3\nfricton = 0.2", "contact.fricton"),
        ("friction = 0.3", 'friction = "high"', "contact.friction"),
        ("C_A = 0.88", "zeta_A = 400.0", "contact.reference_speed"),
        ("[contact]", "[contakt]\nx = 1\n[contact]", "contakt"),
    ],
)
def test_invalid_values_are_named(tmp_path, old, new, field):
    with pytest.raises(SceneError, match=field):
        ji.load_scene(write(tmp_path, BASE.replace(old, new)))


@pytest.mark.parametrize(
    "extra, field",
    [
        ('[model]\nrolling_moments = "sideways"', "model.rolling_moments"),
        ("[model]\nlambda = -1e-3", "model.lambda"),
        ('[model]\nrolling_moments = "lambda"', "model.lambda"),
        ("[model]\nrotation = 1", "model.rotation"),
        ('[model]\nfriction_load = "gross"', "model.friction_load"),
        ("[impact]\nspeed = 0.0", "impact.speed"),
        ("[impact]\nspeed = 1.0\nangle_deg = 90.0", "impact.angle_deg"),
        ("[impact]\nspeed = 1.0\nspin = 3.0", "impact.spin"),
        ("[solver]\nrtol = 0.0", "solver.rtol"),
        ("[solver]\nmax_steps = 2.5", "solver.max_steps"),
        ('[solver]\nmethod = "euler"', "solver.method"),
        ("[solver]\nslip_width = -1e-3", "solver.slip_width"),
        ('[solver]\noutputs = "some"', "solver.outputs"),
    ],
)
def test_invalid_sections_are_named(tmp_path, extra, field):
    with pytest.raises(SceneError, match=field):
        ji.load_scene(write(tmp_path, BASE + extra))


@pytest.mark.parametrize(
    "old, new, rule",
    [
        (
            "radius = 35e-6",
            "radius = nan",
            r"particle.radius must be finite and in \[1e-0?9, 1\] m",
        ),
        ("C_H = 0.22", "C_H = inf", r"contact.C_H must be finite and in \[0, "),
    ],
)
def test_non_finite_values_are_refused_with_their_range(tmp_path, old, new, rule):
    """A NaN or infinite value names the field and its allowed range (was only "must be
    finite")."""
    with pytest.raises(SceneError, match=rule):
        ji.load_scene(write(tmp_path, BASE.replace(old, new)))


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(SceneError, match="not found"):
        ji.load_scene(tmp_path / "nope.toml")
    with pytest.raises(SceneError, match="TOML"):
        ji.load_scene(write(tmp_path, "[particle\nradius = 1"))
    with pytest.raises(SceneError, match=r"particle\.radius"):
        ji.load_scene(write(tmp_path, BASE.replace("radius = 35e-6\n", "")))

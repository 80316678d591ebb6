"""jaximpact._io.lammps: the LAMMPS (29 Sep 2021) commands of a scene, checked against numbers
derived by hand from that version's source (fix_wall_gran.cpp, pair_granular.cpp), and the
refusals of what LAMMPS cannot reproduce. No LAMMPS needed."""

import pytest

import jaximpact as ji
from jaximpact._io import lammps

K = 1.14e11  # Table 1's K (Pa)


def _scene(**model):
    base = {"adhesion": False, "rolling_moments": "none"}
    base.update(model)
    return ji.table1_scene().replace(contact={"C_H": 0.0, "friction": 0.3}, model=base)


def _numbers(line, after):
    """The numbers following the word ``after`` in a command line."""
    words = line.split()
    i = words.index(after)
    out = []
    for w in words[i + 1 :]:
        try:
            out.append(float(w))
        except ValueError:
            break
    return out


def test_hertz_wall_line_gives_K_as_kn():
    line = lammps.wall_fix(_scene())
    assert line.splitlines()[0].startswith("# tangential models are not mapped yet")
    cmd = line.splitlines()[1]
    assert cmd.startswith("fix wall all wall/gran granular hertz ")
    assert _numbers(cmd, "hertz") == [K, 0.0]  # kn = K (F = kn sqrt(R) delta^1.5), eta 0
    assert "damping velocity" in cmd
    assert cmd.endswith("tangential linear_nohistory 0 0 zplane 0.0 NULL")


def test_hertz_material_wall_uses_one_minus_nu():
    # fix_wall_gran.cpp: kn = 4/3 E / (2 (1 - nu)); with nu = 0.3, kn = K needs
    # E = 1.5 * 1.14e11 * 0.7 = 1.197e11
    cmd = lammps.wall_fix(_scene(), material=True, poisson=0.3).splitlines()[1]
    E, eta, nu = _numbers(cmd, "hertz/material")
    assert E == pytest.approx(1.197e11, rel=1e-15)
    assert (eta, nu) == (0.0, 0.3)


def test_pair_material_uses_one_minus_nu_squared():
    # pair_granular.cpp: kn = 4/3 mix_stiffnessE(E, E, nu, nu) = 4/3 E / (2 (1 - nu^2));
    # E = 1.5 * 1.14e11 * 0.91 = 1.5561e11
    lines = lammps.pair_commands(_scene(), material=True, poisson=0.3)
    assert lines[0] == "pair_style granular"
    assert lines[-1].startswith("pair_coeff * * hertz/material ")
    assert _numbers(lines[-1], "hertz/material")[0] == pytest.approx(1.5561e11, rel=1e-15)
    assert lines[-1].endswith("damping velocity tangential linear_history 0 0 0")


def test_dmt_and_jkr_take_half_the_work_of_adhesion_as_coh():
    for law in ("dmt", "jkr"):
        scene = _scene(normal=law, adhesion=True).replace(contact={"w": 0.5, "f0": 0.0})
        cmd = lammps.wall_fix(scene, poisson=0.25).splitlines()[1]
        E, eta, nu, coh = _numbers(cmd, law)
        assert E == pytest.approx(1.5 * K * 0.75, rel=1e-15)  # 1.2825e11
        assert (eta, nu, coh) == (0.0, 0.25, 0.25)  # coh = w / 2


def test_lammps_dampings_are_rendered_with_eta_n():
    if "damping" not in ji.Model.__dataclass_fields__:
        pytest.skip("jaximpact's Model has no damping field yet")
    for damping, eta in (("velocity", 2e-5), ("mass_velocity", 3e6), ("tsuji", 0.7)):
        scene = _scene(damping=damping).replace(contact={"eta_n": eta})
        cmd = lammps.wall_fix(scene).splitlines()[1]
        assert _numbers(cmd, "hertz") == [K, eta]
        assert f"damping {damping} " in cmd


def test_contact_law_without_a_scene():
    law = lammps.ContactLaw("hertz", 1e10, damping="viscoelastic", eta_n=1e8)
    assert "hertz 10000000000.0 100000000.0 damping viscoelastic" in lammps.wall_fix(law)
    assert lammps.tsuji_alpha(1.0) == pytest.approx(
        1.2728 - 4.2783 + 11.087 - 22.348 + 27.467 - 18.022 + 4.8218
    )
    assert lammps.tsuji_alpha(0.0) == 1.2728


def test_pulloff_distances_of_this_version():
    law = lammps.ContactLaw("jkr", 1e11, w=0.1)  # coh 0.05, E* 7.5e10
    # pair: a^3 = 9 pi coh R^2 / (4 E*): the load-controlled pull-off, overlap
    # mu (x^2 - sqrt(2 pi x)) with x^(3/2) = 3 sqrt(2 pi) / 4, mu = (w^2 R / E*^2)^(1/3)
    R = 1e-5
    mu = (0.1**2 * R / 7.5e10**2) ** (1 / 3)
    x = (3 * (2 * 3.141592653589793) ** 0.5 / 4) ** (2 / 3)
    expected = mu * (x * x - (2 * 3.141592653589793 * x) ** 0.5)
    assert lammps.pair_pulloff_overlap(law, R) == pytest.approx(expected, rel=1e-12)
    # wall: R instead of R^2 (as written in fix_wall_gran.cpp): a^3 = 9 pi 0.05 1e-5 / (4
    # 7.5e10) = 4.712e-17, a = 3.612e-6, a^2/R - 2 sqrt(pi coh a / E*) = 1.3047e-6 - 5.5e-9
    assert lammps.wall_pulloff_distance(law, R) == pytest.approx(1.2992e-6, rel=1e-4)


def test_impact_script_has_the_wall_and_the_stop():
    law = lammps.ContactLaw("hertz", 1e10)
    text = lammps.impact_script(law, 2.0, radius=1e-5, density=2500.0, dt=1e-10, max_steps=99)
    assert "units si" in text and "atom_style sphere" in text
    assert "create_atoms 1 single 0.0 0.0 1.0000300000000001e-05" in text  # r + 1.5 v dt
    assert "velocity ball set 0.0 0.0 -2.0" in text
    assert "fix integrate ball nve/sphere" in text and "zplane 0.0 NULL" in text
    assert "fix stop all halt 1 v_left > 0.5 error soft" in text and "run 99" in text
    pair = lammps.impact_script(
        lammps.ContactLaw("jkr", 1e10, w=0.1), 1.0, radius=1e-5, density=2500.0, dt=1e-10,
        max_steps=9, partner_radius=1e-3,
    )  # fmt: skip
    assert "fix hold partner freeze" in pair and "pair_coeff * * jkr " in pair


@pytest.mark.parametrize(
    "model, contact, field",
    [
        ({"adhesion": True}, {"f0": 325.0}, "model.normal = 'brach_dunn'"),
        ({}, {"C_H": 0.2}, "model.damping = 'hertzian'"),
        ({"normal": "thornton_ning", "adhesion": True}, {"w": 0.5, "p_y": 1e10},
         "model.normal = 'thornton_ning'"),
    ],
)  # fmt: skip
def test_laws_lammps_lacks_are_refused(model, contact, field):
    scene = _scene(**model).replace(contact=contact)
    with pytest.raises(ValueError, match="LAMMPS") as err:
        lammps.wall_fix(scene)
    assert field in str(err.value)


def test_tangential_motion_is_refused():
    scene = _scene()
    with pytest.raises(ValueError, match=r"contact\.friction"):
        lammps.wall_fix(scene, angle_deg=30.0)
    with pytest.raises(ValueError, match=r"contact\.friction"):
        lammps.pair_commands(scene, omega0=10.0)
    mindlin = scene.replace(model={"tangential": "mindlin"}, contact={"G_star": 3e10})
    with pytest.raises(ValueError, match=r"model\.tangential"):
        lammps.wall_fix(mindlin, angle_deg=30.0)
    assert "hertz" in lammps.wall_fix(mindlin)  # a normal impact without spin is fine


def test_bad_arguments():
    with pytest.raises(ValueError, match="poisson"):
        lammps.youngs_modulus(1e10, 0.5)
    with pytest.raises(ValueError, match="geometry"):
        lammps.youngs_modulus(1e10, 0.3, "cylinder")
    with pytest.raises(ValueError, match="tsuji"):
        lammps.ContactLaw("hertz", 1e10, damping="tsuji", eta_n=2.0)


def _lammps_tangential(model, **contact):
    from jaximpact._model import scene as scene_module

    if model not in scene_module.TANGENTIAL_MODELS:
        pytest.skip(f"jaximpact's Model does not take tangential = {model!r} yet")
    return _scene(tangential=model).replace(contact=contact)


def test_lammps_linear_history_is_rendered_for_oblique_impacts():
    scene = _lammps_tangential("lammps_linear_history", k_t=2e5, friction=0.25)
    line = lammps.wall_fix(scene, angle_deg=40.0, omega0=1e4)
    assert line.splitlines()[0].startswith("# tangential linear_history: k_t = 200000 N/m")
    assert line.endswith("tangential linear_history 200000.0 0 0.25 zplane 0.0 NULL")
    pair = lammps.pair_commands(scene, angle_deg=-40.0)
    assert pair[-1].endswith("damping velocity tangential linear_history 200000.0 0 0.25")
    law = lammps.contact_law(scene, angle_deg=10.0)
    assert (law.tangential, law.k_t, law.mu) == ("linear_history", 2e5, 0.25)


def test_lammps_mindlin_writes_eight_G_star_not_null():
    # fix_wall_gran.cpp's NULL would be E/4 (2 - nu)(1 + nu), not 8 G* = 2 E/((2 - nu)(1 + nu))
    scene = _lammps_tangential("lammps_mindlin", G_star=3e10, friction=0.3)
    for cmd in (lammps.wall_fix(scene, angle_deg=30.0).splitlines()[1],
                lammps.pair_commands(scene, omega0=5.0)[-1]):  # fmt: skip
        assert _numbers(cmd, "mindlin") == [2.4e11, 0.0, 0.3]
        assert "NULL" not in cmd.split("mindlin")[1].split("zplane")[0]


def test_lammps_tangential_refusals():
    scene = _lammps_tangential("lammps_linear_history", k_t=2e5)
    rolling = scene.replace(model={"rolling_moments": "analytical"})
    with pytest.raises(ValueError, match=r"model\.rolling_moments"):
        lammps.wall_fix(rolling, angle_deg=30.0)
    assert "linear_history" in lammps.wall_fix(rolling)  # normal, no spin: no rolling either
    frozen = scene.replace(model={"rotation": False})
    with pytest.raises(ValueError, match=r"model\.rotation"):
        lammps.wall_fix(frozen, omega0=10.0)
    with pytest.raises(ValueError, match="lammps_linear_history"):  # rigid: says what to use
        lammps.wall_fix(_scene(), angle_deg=30.0)
    with pytest.raises(ValueError, match="k_t"):
        lammps.ContactLaw("hertz", 1e10, tangential="mindlin", k_t=0.0)


def test_oblique_script_sets_the_tangential_velocity_and_spin():
    law = lammps.ContactLaw("hertz", 1e10, tangential="linear_history", k_t=1e5, mu=0.2)
    text = lammps.oblique_script(law, 2.0, 30.0, -1e4, radius=1e-5, density=2500.0, dt=1e-10,
                                 max_steps=99)  # fmt: skip
    assert "velocity ball set 0.9999999999999999 0.0 -1.7320508075688774" in text
    assert "set atom 1 omega 0.0 -10000.0 0.0" in text
    assert "tangential linear_history 100000.0 0 0.2 zplane 0.0 NULL" in text
    # the halt looks one step ahead: x + dt (v + dt f / (2 m))
    assert "variable left equal ((z[1]+1e-10*(vz[1]+0.5*1e-10*fz[1]/mass[1]))>1e-05)" in text
    assert "fix state ball store/state 1 omegay tqy" in text
    assert text.rstrip().endswith('ty=${tyf} mass=${massf}"')
    pair = lammps.oblique_script(
        lammps.ContactLaw("jkr", 1e10, w=0.1, tangential="mindlin", k_t=1e11, mu=0.2), 1.0, 45.0,
        0.0, radius=1e-5, density=2500.0, dt=1e-10, max_steps=9, partner_radius=0.1,
    )  # fmt: skip
    assert "neighbor 5e-06 nsq" in pair and "tangential mindlin 100000000000.0 0 0.2" in pair
    assert "set atom 1 omega" not in pair

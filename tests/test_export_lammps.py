"""``jaximpact export lammps FIT.json``: the LAMMPS commands of a fitted normal law, on small
hand-made fit JSONs (no fit is run): the commands (those of ``jaximpact._io.lammps`` for the
scene with the fitted values), the comments, the refusals (exit 2, one line naming the file or
field) and the fit JSON's ``scene`` record. The slow test runs the exported file in LAMMPS
(``include``d unchanged into an impact script) against ``jaximpact.simulate``."""

import json
import math
import shutil
import sys
from pathlib import Path

import pytest

import jaximpact as ji
from jaximpact import cli
from jaximpact._io import lammps
from jaximpact._io.scene_files import scene_from_dict
from jaximpact.parameters import with_parameters

ROOT = Path(__file__).resolve().parents[1]
R, RHO, K = 1e-5, 2500.0, 1e11

DMT_SCENE = """\
# a 10 um glass-like sphere: DMT with LAMMPS's velocity damping
[particle]
radius = 1e-5
density = 2500.0

[contact]
K = 1e11
w = 0.5
C_A = 0.0
C_H = 0.0
friction = 0.0
eta_n = 1e-9

[model]
normal = "dmt"
damping = "velocity"
rotation = false
rolling_moments = "none"
"""

POSTERIOR = {"median": 0.451, "q05": 0.42, "q95": 0.48}


def _fit_json(tmp_path, params, scene_text=DMT_SCENE, name="fit.json", **extra):
    document = {"status": "converged", "params": params, "data": {"source": "rebounds.csv"}}
    if scene_text is not None:
        document["scene"] = {"source": "glass.toml", "embedded": False, "toml": scene_text}
    document.update(extra)
    path = tmp_path / name
    path.write_text(json.dumps(document, indent=2))
    return path


def _params(w=0.45, eta_n=2e-9, posterior=True):
    out = {"w": {"value": w, "stderr": 0.02}, "eta_n": {"value": eta_n, "stderr": 1e-10}}
    if posterior:
        out["w"]["posterior"] = dict(POSTERIOR)
    return out


def _fitted(values, scene_text=DMT_SCENE):
    import tomllib

    return with_parameters(scene_from_dict(tomllib.loads(scene_text)), values)


def _commands(text):
    return [line for line in text.splitlines() if line and not line.startswith("#")]


def _export(args, capsys):
    code = cli.main(["export", "lammps", *map(str, args)])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


def test_wall_commands_are_the_fitted_scenes_with_comments(tmp_path, capsys):
    fit = _fit_json(tmp_path, _params())
    out_file = tmp_path / "sub" / "wall.in"
    code, out, err = _export([fit, "-o", out_file], capsys)
    assert code == 0, err
    assert out.strip() == f"wrote {out_file}"
    text = out_file.read_text()
    law = lammps.contact_law(_fitted({"w": 0.45, "eta_n": 2e-9}))
    assert _commands(text) == _commands(lammps.wall_fix(law))
    assert _commands(text) == [
        "fix wall all wall/gran granular dmt 105000000000.0 2e-09 0.3 0.225 damping velocity "
        "tangential linear_nohistory 0 0 zplane 0.0 NULL"
    ]
    assert "units si" in text and "LAMMPS 29 Sep 2021" in text
    # the posterior's median and 90 % interval where the JSON has one, else value +- stderr
    assert "#   w = 0.451 [0.42, 0.48] J/m^2 (0.45 +- 0.02)" in text
    assert "#   eta_n = 2e-09 +- 1e-10 kg/s" in text
    # where each LAMMPS number came from
    assert "E = 1.5 K (1 - nu) = 1.05e+11 Pa with K = 1e+11 Pa (the scene's" in text
    assert "coh = w/2 = 0.225 J/m^2 with w = 0.45 (fitted)" in text
    assert "damping velocity coefficient = eta_n = 2e-09 kg/s (fitted)" in text
    assert "scene: glass.toml (as recorded in" in text
    assert not [p for p in out_file.parent.iterdir() if p.name != "wall.in"]  # no temp files


def test_stdout_without_posterior_and_pair_hertz_material(tmp_path, capsys):
    scene = DMT_SCENE.replace('normal = "dmt"', 'normal = "brach_dunn"\nadhesion = false')
    scene = scene.replace('damping = "velocity"', 'damping = "mass_velocity"')
    scene = scene.replace("w = 0.5\n", "")
    fit = _fit_json(tmp_path, {"K": {"value": 2e11, "stderr": None}}, scene_text=scene)
    code, out, err = _export([fit, "--geometry", "pair", "--material", "--poisson", "0.25"], capsys)
    assert code == 0, err
    assert "least-squares value +- standard error (no posterior in the fit JSON)" in out
    assert "#   K = 2e+11 +- undefined Pa" in out
    E = 1.5 * 2e11 * (1 - 0.25**2)
    assert f"E = 1.5 K (1 - nu^2) = {E:.6g} Pa with K = 2e+11 Pa (fitted" in out
    assert "damping mass_velocity coefficient = eta_n = 1e-09 1/s" in out
    assert _commands(out) == [
        "pair_style granular",
        f"pair_coeff * * hertz/material {E!r} 1e-09 0.25 damping mass_velocity "
        "tangential linear_history 0 0 0",
    ]
    # without --material: hertz kn = K
    code, out, _ = _export([fit], capsys)
    assert code == 0
    assert "kn = K = 2e+11 Pa (fitted" in out
    assert _commands(out)[0].startswith("fix wall all wall/gran granular hertz 200000000000.0 ")


def test_scene_with_a_target_defaults_to_the_pair(tmp_path, capsys):
    scene = DMT_SCENE + "\n[target]\nradius = 1e-3\ndensity = 2500.0\n"
    code, out, err = _export([_fit_json(tmp_path, _params(), scene_text=scene)], capsys)
    assert code == 0, err
    assert _commands(out)[0] == "pair_style granular"
    assert "[target] sphere: radius 0.001 m" in out


def test_an_unconverged_fit_is_exported_with_a_warning(tmp_path, capsys):
    fit = _fit_json(tmp_path, _params(), status="not converged")
    code, out, err = _export([fit], capsys)
    assert code == 0
    assert "# WARNING: the fit's status is 'not converged'" in out
    assert err.startswith("warning:") and str(fit) in err


def test_a_json_without_scene_names_the_file_and_takes_scene(tmp_path, capsys):
    fit = _fit_json(tmp_path, _params(), scene_text=None, name="old.json")
    code, out, err = _export([fit], capsys)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and str(fit) in err and "'scene'" in err and "--scene" in err
    scene_file = tmp_path / "glass.toml"
    scene_file.write_text(DMT_SCENE)
    code, out, err = _export([fit, "--scene", scene_file], capsys)
    assert code == 0, err
    assert f"scene: {scene_file}" in out
    assert "coh = w/2 = 0.225" in out


RING = (ROOT / "jaximpact" / "scenes" / "table1.toml").read_text()
KHARAZ = (ROOT / "jaximpact" / "scenes" / "kharaz2001.toml").read_text()


@pytest.mark.parametrize(
    "params, scene, extra_args, words",
    [
        ({"C_H": {"value": 0.1, "stderr": 0.01}}, DMT_SCENE, [], ["params.C_H", "Hertzian"]),
        ({"friction": {"value": 0.1}}, DMT_SCENE, [], ["params.friction", "tangential"]),
        ({"K": {"value": 1e11}}, RING, [], ["adhesion ring", "fit instead", "'dmt'"]),
        ({"K": {"value": 1e11}}, KHARAZ, [], ["contact.C_H > 0", "fit instead", "eta_n"]),
        (_params(), DMT_SCENE.replace('"dmt"', '"jkr"'), [], ["'jkr'", "--geometry pair"]),
        ({"w": {"value": None}}, DMT_SCENE, [], ["params.w.value: null"]),
        ({"zeta": {"value": 1.0}}, DMT_SCENE, [], ["params.zeta", "not a jaximpact"]),
        ({"w": {"value": -1.0}}, DMT_SCENE, [], ["contact.w"]),
        (_params(), "[particle]\nradius = 1e-5\n", [], ["scene.toml", "[contact]"]),
        (_params(), DMT_SCENE, ["--poisson", "0.7"], ["--poisson", "(-1, 0.5)"]),
    ],
)
def test_refusals_exit_2_with_one_line(tmp_path, capsys, params, scene, extra_args, words):
    fit = _fit_json(tmp_path, params, scene_text=scene)
    out_file = tmp_path / "out.in"
    code, out, err = _export([fit, "-o", out_file, *extra_args], capsys)
    assert code == 2, (out, err)
    assert err.startswith("error: ") and err.count("\n") == 1, err
    for word in words:
        assert word in err, (word, err)
    assert not out_file.exists()


@pytest.mark.parametrize(
    "content, words",
    [
        ('{"params": ', ["not valid JSON", "line 1"]),
        ("[1, 2]", ["no 'params'"]),
        ('{"params": {}}', ["no 'params'"]),
    ],
)
def test_bad_json_exits_2_naming_the_file(tmp_path, capsys, content, words):
    fit = tmp_path / "bad.json"
    fit.write_text(content)
    code, _, err = _export([fit], capsys)
    assert code == 2 and err.startswith(f"error: {fit}: ") and err.count("\n") == 1
    for word in words:
        assert word in err


def test_missing_file_and_bad_output_exit_2(tmp_path, capsys):
    code, _, err = _export([tmp_path / "nope.json"], capsys)
    assert code == 2 and "nope.json: fit JSON not found" in err
    code, _, err = _export([_fit_json(tmp_path, _params()), "-o", tmp_path], capsys)
    assert code == 2 and "is a directory" in err
    with pytest.raises(SystemExit) as exit_:  # argparse's own refusal
        cli.main(["export", "lammps", str(tmp_path / "fit.json"), "--geometry", "cone"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and "'cone'" in err


def test_the_fit_json_records_its_scene(tmp_path, monkeypatch):
    from fitting._commands.fit_steps import _scene_record

    record = _scene_record(None)
    assert record["source"] == "table1" and record["embedded"] is True
    assert record["toml"] == RING
    path = tmp_path / "glass.toml"
    path.write_text(DMT_SCENE)
    monkeypatch.chdir(tmp_path)
    assert _scene_record("glass.toml") == {
        "source": "glass.toml",
        "embedded": False,
        "toml": DMT_SCENE,
    }


def _benchmark():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import lammps_impacts

    return lammps_impacts


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("lmp") is None, reason="lmp (LAMMPS) is not installed")
def test_exported_wall_runs_in_lammps_and_matches_simulate(tmp_path, capsys):
    """The exported file, ``include``d unchanged after our own setup lines, gives the rebound
    ``jaximpact.simulate`` gives for the fitted scene, within LAMMPS's time-step error (the
    rebound at t_c/200, /400, /800, extrapolated; tolerance as tests/test_lammps_reference.py:
    10x the two finest steps' difference, at least 1e-5)."""
    import numpy as np

    B = _benchmark()
    eta = B.eta_for_loss("velocity", 0.1, R, RHO, K, 1.0)
    fit = _fit_json(tmp_path, _params(w=0.45, eta_n=eta))
    exported = tmp_path / "wall.in"
    code, _, err = _export([fit, "-o", exported], capsys)
    assert code == 0, err
    scene = _fitted({"w": 0.45, "eta_n": eta})
    law = lammps.contact_law(scene)
    speeds = (0.3, 2.0)
    expected = ji.simulate(scene, np.array(speeds), 0.0, 0.0)
    for speed, cor_n, status in zip(speeds, expected.cor_n, expected.status_names, strict=True):
        assert status == "rebound"
        tc = lammps.contact_time_estimate(R, RHO, K, speed)
        cors = []
        for n in (200, 400, 800):
            script = lammps.impact_script(
                law, speed, radius=R, density=RHO, dt=tc / n, max_steps=int(B.TIME_LIMIT * n)
            )
            ours = lammps.wall_fix(law)
            assert script.count(ours) == 1
            row = B.run_scripts([script.replace(ours, f"include {exported}")])[0]
            assert row is not None and math.isfinite(row["vz"]), (speed, n, row)
            cors.append(B._rebound(row, law, R, RHO, speed, tc / n, None))
        cor_x, _ = B.richardson(cors)
        tol = max(10 * abs(cors[-1] - cors[-2]), 1e-5)
        assert cor_x == pytest.approx(float(cor_n), abs=tol), (speed, cors, float(cor_n))

"""Tests of the fitting package: recovery, gradients, real data, bad input, honest failure."""

import dataclasses
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fitting
import jaximpact
from jaximpact.cli import main as cli_main

# Distinct from the Table 1 values, so recovery cannot succeed by staying at the scene's values.
TRUTH = {"C_A": 0.75, "C_H": 0.25, "f0": 300.0}

KHARAZ_SCENE_TOML = """\
# 5 mm alumina on a rigid anvil (Chung & Ooi 2011): K = 4/3 E/(1 - nu^2), E = 380 GPa, nu = 0.23
[particle]
radius = 2.5e-3
density = 4000.0
[contact]
K = 5.349663886249251e11
f0 = 0.0
C_A = 0.0
C_H = 0.008
friction = 0.2
[model]
rotation = true
adhesion = false
rolling_moments = "none"
[impact]
speed = 3.9
angle_deg = 45.0
"""


def _write_long(path, speed, angle, observable, value):
    lines = ["speed,angle_deg,observable,value"]
    lines += [
        f"{float(s)!r},{float(a)!r},{o},{float(v)!r}"
        for s, a, o, v in zip(speed, angle, observable, value, strict=True)
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def kharaz25(tmp_path_factory):
    """The Kharaz data at incidence >= 25 degrees (where the rigid Coulomb model applies)."""
    obs = fitting.load_kharaz2001()
    keep = obs.angle_deg >= 25
    path = tmp_path_factory.mktemp("kharaz") / "kharaz25.csv"
    return _write_long(
        path, obs.speed[keep], obs.angle_deg[keep], obs.observable[keep], obs.value[keep]
    )


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_synthetic_recovery_of_C_A_C_H_f0(tmp_path):
    scene = jaximpact.table1_scene()
    speed = np.geomspace(0.3, 5.0, 24)
    angle = np.tile([0.0, 0.0, 30.0, 45.0, 60.0, 0.0], 4)
    truth = fitting.Objective(scene, _dummy_obs(tmp_path), list(TRUTH)).scene_at(TRUTH)
    clean = np.asarray(jaximpact.simulate(truth, speed, angle, 0.0).cor_n)
    assert np.all(clean > 0.3)
    noisy = clean * (1 + 0.003 * np.random.default_rng(1).standard_normal(clean.size))
    data = _write_long(tmp_path / "syn.csv", speed, angle, ["cor_n"] * speed.size, noisy)

    initial = {"C_A": 2.5 * TRUTH["C_A"], "C_H": 0.4 * TRUTH["C_H"], "f0": 2.0 * TRUTH["f0"]}
    result = fitting.fit(scene, data, list(TRUTH), initial=initial, progress=False)
    print(fitting.summary(result))
    assert result.converged, result.message
    assert result.n_data == 24
    for name, true in TRUTH.items():
        value, err = result.values[name], result.stderr[name]
        assert abs(value - true) < 4 * err, (name, value, err)
        assert err < 0.2 * value, (name, err)
    # The noise is about 0.3 %: the residual scale (in units of 0.01) should be about 0.2.
    assert 0.1 < result.residual_scale < 0.4
    assert np.allclose(np.diag(result.correlation), 1.0)


def _dummy_obs(tmp_path):
    return _write_long(tmp_path / "dummy.csv", [1.0], [0.0], ["cor_n"], [0.7])


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_objective_gradient_matches_finite_differences(tmp_path):
    # Finite differences of an adaptive solve are only as good as its tolerance (as in
    # test_simulate): tight tolerances, a relative step of 1e-3.
    scene = jaximpact.table1_scene(rtol=1e-11, atol=1e-13)
    data = _write_long(
        tmp_path / "d.csv",
        [0.5, 1.0, 2.0, 3.0, 1.5],
        [0.0, 30.0, 45.0, 0.0, 45.0],
        ["cor_n", "cor_n", "cor_t", "cor_n", "omega_out"],
        [0.7, 0.7, 0.8, 0.6, 1000.0],
    )
    names = ["C_A", "C_H", "f0", "friction"]
    objective = fitting.Objective(scene, data, names)
    u0 = jnp.asarray(
        fitting.to_unbounded(names, [objective.initial[n] for n in names]), jnp.float64
    )
    cost = jax.jit(lambda u: 0.5 * jnp.sum(objective.residuals(fitting.to_physical(names, u)) ** 2))
    grad = np.asarray(jax.jit(jax.grad(cost))(u0))
    h = 1e-3
    fd = np.array([(cost(u0 + h * e) - cost(u0 - h * e)) / (2 * h) for e in np.eye(len(names))])
    np.testing.assert_allclose(grad, fd, rtol=3e-3, atol=1e-3 * np.max(np.abs(fd)))


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_kharaz_friction_via_cli(tmp_path, kharaz25, capsys):
    scene = tmp_path / "kharaz.toml"
    scene.write_text(KHARAZ_SCENE_TOML)
    out, plot = tmp_path / "fit.json", tmp_path / "fit.png"
    argv = ["fit", str(scene), str(kharaz25), "--params", "friction", "-o", str(out)]
    rc = cli_main([*argv, "--plot", str(plot), "--starts", "2", "--no-progress"])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    result = json.loads(out.read_text())
    friction = result["params"]["friction"]
    print(printed)
    assert result["converged"] is True
    assert 0.085 <= friction["value"] <= 0.105  # published sliding friction: 0.092
    assert 0 < friction["stderr"] < 0.01
    assert result["n_data"] == 12
    assert result["correlation"] == [[pytest.approx(1.0)]]
    assert {"compile", "solve", "total"} <= set(result["timings"])
    assert "friction" in printed and "converged" in printed
    assert plot.stat().st_size > 1000
    assert not list(tmp_path.glob(".*tmp*"))  # atomic writes leave no temporary files


@pytest.mark.slow  # about 30 s, mostly compilation
def test_lbfgs_agrees_with_lm_on_kharaz(kharaz25):
    result = fitting.fit(
        fitting.kharaz2001_scene(friction=0.2),
        kharaz25,
        ["friction"],
        solver="lbfgs",
        progress=False,
    )
    assert result.converged, result.message
    assert 0.085 <= result.values["friction"] <= 0.105


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_iteration_limit_reports_not_converged(tmp_path, kharaz25):
    result = fitting.fit(
        fitting.kharaz2001_scene(friction=0.3),  # two steps of at most e in logit at least
        kharaz25,
        ["friction"],
        max_steps=1,
        progress=False,
    )
    assert result.converged is False and result.status == "not converged"
    assert "iteration limit" in result.message
    assert any("iteration limit" in p for p in result.problems)
    assert "NOT CONVERGED" in fitting.summary(result)
    fitting.write_json(tmp_path / "fit.json", result)
    assert json.loads((tmp_path / "fit.json").read_text())["converged"] is False


def _fake_result(**fields):
    n = len(fields["status"])
    base = {name: jnp.zeros(n) for name in jaximpact.ImpactResult.__dataclass_fields__}
    base.update({k: jnp.asarray(v) for k, v in fields.items()})
    return jaximpact.ImpactResult(**base)


def test_capture_and_failure_residuals(tmp_path):
    data = _write_long(
        tmp_path / "c.csv",
        [1.0, 2.0, 3.0, 4.0, 5.0],
        [0.0, 0.0, 0.0, 0.0, 30.0],
        ["captured", "captured", "captured", "cor_n", "rebound_angle_deg"],
        [1.0, 0.0, 0.0, 0.5, 20.0],
    )
    objective = fitting.Objective(jaximpact.table1_scene(), data, ["f0"])
    nan = math.nan
    t_h = np.asarray(objective.hertz_time())  # Hertz contact time of each impact
    result = _fake_result(
        status=jnp.array([0, 1, 0, 2, 1]),  # rebound, captured, rebound, failed, captured
        cor_n=jnp.array([0.2, 0.0, 0.004, nan, 0.0]),
        rebound_angle_deg=jnp.array([1.0, nan, 2.0, nan, nan]),
        contact_time=jnp.asarray(t_h * np.array([1.0, 1.0, 1.0, nan, 2.0])),
    )
    r = np.asarray(objective.residuals_from_result(result))
    # observed captured, model rebounds with cor_n 0.2: pulled toward capture (0.2 / 0.01);
    # observed rebound, model captures at T_c = T_H: cor_n continued to -(1 + e^-1)/2, so
    # (0.01 + (1 + e^-1)/2) / 0.01; observed rebound, model rebounds with cor_n 0.004 < 0.01:
    # partway up the barrier; failed impact: the failure residual; a rebound angle where the
    # model captures at T_c = 2 T_H: 1e3 (1 + e^-2) / 2.
    cont = 0.5 * (1 + math.exp(-1))
    expected = [20.0, (0.01 + cont) / 0.01, 0.6, 1e3, 500 * (1 + math.exp(-2))]
    np.testing.assert_allclose(r, expected)
    for field in ("cor_n", "contact_time"):
        grad = jax.grad(
            lambda c, field=field: jnp.sum(
                objective.residuals_from_result(dataclasses.replace(result, **{field: c})) ** 2
            )
        )(getattr(result, field))
        assert np.all(np.isfinite(np.asarray(grad)))
    # The capture surrogate has a gradient in the capture time (the way out of capture).
    g_t = jax.grad(
        lambda c: jnp.sum(
            objective.residuals_from_result(dataclasses.replace(result, contact_time=c)) ** 2
        )
    )(result.contact_time)
    assert np.asarray(g_t)[1] != 0 and np.asarray(g_t)[4] != 0


def test_bad_inputs(tmp_path, kharaz25, capsys):
    scene = fitting.kharaz2001_scene()
    with pytest.raises(fitting.FitError, match="unknown parameter 'mu'"):
        fitting.fit(scene, kharaz25, ["mu"], progress=False)
    with pytest.raises(fitting.FitError, match="no parameters"):
        fitting.fit(scene, kharaz25, [], progress=False)
    with pytest.raises(fitting.FitError, match="unknown solver"):
        fitting.fit(scene, kharaz25, ["friction"], solver="newton", progress=False)
    with pytest.raises(fitting.FitError, match="must be finite and > 0"):
        fitting.fit(scene, kharaz25, ["f0"], progress=False)  # f0 = 0 cannot start a log fit
    empty = tmp_path / "empty.csv"
    empty.write_text("# nothing\nspeed,angle_deg,observable,value\n")
    with pytest.raises(fitting.DataError, match="no usable observations"):
        fitting.fit(scene, empty, ["friction"], progress=False)
    nan_file = _write_long(tmp_path / "nan.csv", [3.9], [45.0], ["cor_t"], [math.nan])
    with pytest.raises(fitting.DataError, match="line 2"):
        fitting.fit(scene, nan_file, ["friction"], progress=False)
    obs = fitting.load_observations(kharaz25)
    bad = dataclasses.replace(obs, value=np.where(np.arange(len(obs)) == 3, np.nan, obs.value))
    with pytest.raises(fitting.FitError, match="non-finite value"):
        fitting.Objective(scene, bad, ["friction"])
    normal = _write_long(tmp_path / "n.csv", [3.9], [0.0], ["cor_t"], [0.5])
    with pytest.raises(fitting.FitError, match="line 2: cor_t observed at a normal impact"):
        fitting.Objective(scene, normal, ["friction"])
    # The CLI prints the message and exits with status 2.
    assert cli_main(["fit", str(kharaz25), "--params", "C_A", "bogus"]) == 2
    assert "unknown parameter 'bogus'" in capsys.readouterr().err
    assert cli_main(["fit", str(empty), "--params", "C_A"]) == 2
    assert "no usable observations" in capsys.readouterr().err

"""Fits in seconds and fits that never claim what they did not find (issue 10, parts 2 and 3).

One compiled residual-and-Jacobian program serves every start and iteration; forward and
reverse Jacobians agree; a fit started where the model captures every impact walks out of the
capture region or says why not (exit 3); the report carries rank, condition number,
sensitivities, the parameters the data cannot identify and the reduced chi-square; a model
that cannot describe the data ends as a misfit; the compilation cache follows
JAXIMPACT_CACHE_DIR.

The synthetic microsphere data are made here with the simulator (the engine's numbers may
move slightly between versions; nothing below depends on its exact outputs). All fits of the
microsphere data share one compiled program (same impacts, parameters and batch size; the
observed values and sigmas are inputs of the program), and the CLI runs load it from the
module's compilation cache, so the module compiles the big program once.
"""

import json
import math
import os
import shutil
import subprocess
import sys

import jax
import numpy as np
import pytest

import fitting
import jaximpact
from jaximpact import cli as ji_cli
from jaximpact._io import cache as _cache

TRUTH = {"C_A": 0.75, "C_H": 0.25, "f0": 300.0}
NAMES = list(TRUTH)
NEAR = {"C_A": 1.5, "C_H": 0.15, "f0": 500.0}  # a start the fit recovers from
CAPTURE_START = {"C_A": 0.05, "C_H": 2.0, "f0": 2000.0}  # the model captures every impact


def _jaximpact_command():
    exe = shutil.which("jaximpact", path=os.path.dirname(sys.executable))
    return [exe] if exe else [sys.executable, "-m", "jaximpact.cli"]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A fresh compilation cache for this module (in-process and for the CLI runs); the
    process's previous setting is restored afterwards."""
    path = tmp_path_factory.mktemp("jit-cache")
    before = jax.config.jax_compilation_cache_dir
    jaximpact.enable_compilation_cache(path)
    yield path
    from jax.experimental.compilation_cache import compilation_cache

    compilation_cache.reset_cache()
    jax.config.update("jax_compilation_cache_dir", before)


@pytest.fixture(scope="module")
def micro(tmp_path_factory, cache):
    """25 impacts of the Table 1 microsphere (0.3-5 m/s, 0-60 deg) with cor_n observed:
    ``data`` (0.3 % noise, no sigma), ``sigma`` (the same values with sigma = 0.002) and
    ``scatter`` (5 % scatter, but claimed sigma = 0.003: no model fits that within sigma)."""
    folder = tmp_path_factory.mktemp("micro")
    speed = np.geomspace(0.3, 5.0, 25)
    angle = np.tile([0.0, 0.0, 30.0, 45.0, 60.0], 5)

    def write(name, values, sigma=None):
        head = "speed,angle_deg,observable,value" + (",sigma" if sigma else "")
        rows = [
            f"{float(s)!r},{float(a)!r},cor_n,{float(v)!r}" + (f",{sigma}" if sigma else "")
            for s, a, v in zip(speed, angle, values, strict=True)
        ]
        path = folder / name
        path.write_text("\n".join([head, *rows]) + "\n")
        return path

    # The model's cor_n at the truth, from the fit's own program (value 0, scale 1): the same
    # compiled program then serves every fit below.
    placeholder = write("placeholder.csv", np.full(speed.size, 0.5))
    objective = fitting.Objective(jaximpact.load_scene(), placeholder, NAMES)
    program = fitting.ResidualProgram(objective, 1)
    u_truth = fitting.to_unbounded(NAMES, [TRUTH[n] for n in NAMES])
    r, _, status = program(u_truth[None], value=0.0, scale=1.0)
    assert np.all(status == jaximpact.Status.REBOUND)
    clean = r[0]
    rng = np.random.default_rng(1)
    noisy = clean * (1 + 0.003 * rng.standard_normal(clean.size))
    scattered = clean * (1 + 0.05 * rng.standard_normal(clean.size))

    return {
        "data": write("micro.csv", noisy),
        "sigma": write("micro_sigma.csv", noisy, 0.002),
        "scatter": write("micro_scatter.csv", scattered, 0.003),
    }


@pytest.fixture(scope="module")
def near_fit(micro):
    return fitting.fit(jaximpact.load_scene(), micro["data"], NAMES, initial=NEAR, progress=False)


def test_one_compiled_program_serves_every_iteration(near_fit):
    result = near_fit
    assert result.status == "converged", result.message
    for name, true in TRUTH.items():
        assert abs(result.values[name] - true) < 4 * result.stderr[name], name
    # Compiled once (by the fixture, which traced it), then called once per iteration (plus
    # the start) by this fit: no trace and no compilation during the fit.
    assert result.program["source"] == "memory"
    assert result.program["traces"] == 0 and result.program["compiles"] == 0
    assert result.program["calls"] == result.starts[0].steps + 1 > 3
    assert result.jacobian == "fwd"


def test_new_values_and_starts_reuse_the_compiled_program(micro, near_fit):
    # Same impacts and parameters, other observed values and sigmas: no trace, no compile.
    again = fitting.fit(jaximpact.load_scene(), micro["sigma"], NAMES, initial=NEAR, progress=False)
    assert again.program["source"] == "memory"
    assert again.program["traces"] == 0 and again.program["compiles"] == 0
    assert again.status == "converged", again.message
    # Sigmas given: a reduced chi-square, near 1 for the honest 0.3 % noise.
    assert 0.3 < again.reduced_chi2 < 3.0
    assert 0 < again.p_value <= 1
    np.testing.assert_allclose(again.theta, near_fit.theta, rtol=1e-3)


def test_report_fields(near_fit, tmp_path):
    result = near_fit
    assert result.rank == 3 and result.unidentifiable == []
    assert math.isfinite(result.condition_number) and result.condition_number >= 1
    assert set(result.sensitivity) == set(NAMES)
    assert all(v > 0 for v in result.sensitivity.values())
    assert math.isnan(result.reduced_chi2)  # no sigmas in this file
    text = fitting.summary(result)
    assert "rank 3 of 3" in text and "sensitivity" in text and "status: converged" in text
    fitting.write_json(tmp_path / "fit.json", result)
    out = json.loads((tmp_path / "fit.json").read_text())
    assert out["status"] == "converged" and out["converged"] is True
    assert out["rank"] == 3 and out["unidentifiable"] == [] and out["problems"] == []
    assert out["reduced_chi2"] is None and out["dof"] == 22
    assert len(out["singular_values"]) == 3
    for name in NAMES:
        p = out["params"][name]
        assert p["identifiable"] is True and p["sensitivity"] > 0 and p["stderr"] > 0
    assert set(out["program"]) == {"traces", "compiles", "calls", "source"}


def test_scatter_beyond_sigma_is_a_misfit(micro):
    result = fitting.fit(
        jaximpact.load_scene(), micro["scatter"], NAMES, initial=NEAR, progress=False
    )
    assert result.status == "misfit" and not result.converged
    assert result.reduced_chi2 > 10
    assert "reduced chi-square" in result.message
    assert "MISFIT" in fitting.summary(result)


def test_rank_deficient_fit_names_the_parameters():
    # A zero Jacobian column (a parameter the residuals do not depend on) is named.
    jac = np.array([[1.0, 0.0], [2.0, 0.0], [0.5, 0.0]])
    d = fitting._least_squares.fit._diagnose(
        jac, 1.0, 3, ("C_H", "f0"), np.array([0.25, 300.0]), True
    )
    assert d["rank"] == 1 and d["unidentifiable"] == ["f0"]
    assert d["stderr"]["f0"] == math.inf and math.isfinite(d["stderr"]["C_H"])
    assert d["undetermined"] and "f0" in d["undetermined"][0]


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_capture_start_walks_out_or_exits_3(micro, cache, near_fit, tmp_path):
    """The issue's case: from C_A=0.05 C_H=2 f0=2000 the model captures every impact."""
    objective = fitting.Objective(jaximpact.load_scene(), micro["data"], NAMES)
    program = fitting.ResidualProgram(objective, 1)  # the fixture's program, from memory
    u0 = fitting.to_unbounded(NAMES, [CAPTURE_START[n] for n in NAMES])
    _, jac, status = program(u0[None])
    assert program.stats["source"] == "memory"
    assert np.all(status == jaximpact.Status.CAPTURED)
    # ... and its residuals there still have a gradient (the capture surrogate; not in C_A,
    # the damping of the separating ring, since these captures come before separation).
    assert np.all(np.isfinite(jac)) and np.any(jac[0, :, 1:] != 0)

    out = tmp_path / "fit.json"
    init = [f"{k}={v}" for k, v in CAPTURE_START.items()]
    cmd = [*_jaximpact_command(), "fit", str(micro["data"]), "--params", *NAMES]
    cmd += ["--init", *init, "--starts", "1", "--no-progress", "-o", str(out)]
    # One XLA device, as in this process, so that the compiled program is the cached one.
    env = {**os.environ, "JAXIMPACT_CACHE_DIR": str(cache)}
    env["XLA_FLAGS"] = "--xla_force_host_platform_device_count=1"
    run = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    print(run.stdout, run.stderr)
    assert run.returncode in (0, 3), run.stderr
    assert "Traceback" not in run.stderr
    result = json.loads(out.read_text())
    # Usually "cache" (traced and compiled by the fixture); in the full suite an earlier test's
    # global JAX settings can change the cache key, so only require a known source here (cache
    # reuse itself is tested by test_new_values_and_starts_reuse_the_compiled_program).
    assert result["program"]["source"] in ("cache", "traced")
    # It left the capture region: the start's residual cost is far above the final one.
    assert result["starts"][0]["steps"] > 1
    if run.returncode == 0:
        assert result["status"] == "converged"
        for name, true in TRUTH.items():
            assert result["params"][name]["value"] == pytest.approx(true, rel=0.2)
    else:
        assert result["status"] != "converged" and result["converged"] is False
        assert result["problems"]
        assert run.stderr.strip().splitlines()[-1].startswith("error: fit ")
        assert "status: converged" not in run.stdout
    # Never "converged" with undefined standard errors.
    if result["converged"]:
        assert all(p["stderr"] is not None for p in result["params"].values())


@pytest.mark.slow  # about 50 s: compiling reverse mode through the solve
def test_forward_and_reverse_jacobians_agree(tmp_path):
    # A small case: 3 oblique impacts of the 5 mm sphere (no adhesion), two parameters.
    data = tmp_path / "k.csv"
    data.write_text(
        "speed,angle_deg,observable,value\n"
        "3.9,30,cor_t,0.8\n3.9,45,rebound_angle_deg,40\n3.9,60,omega_out,900\n"
    )
    scene = fitting.kharaz2001_scene(friction=0.12)
    objective = fitting.Objective(scene, data, ["friction", "C_H"])
    u = np.array([fitting.to_unbounded(["friction", "C_H"], [0.12, 0.008])])
    r_f, jac_f, _ = fitting.ResidualProgram(objective, 1, jacobian="fwd")(u)
    r_r, jac_r, _ = fitting.ResidualProgram(objective, 1, jacobian="rev")(u)
    np.testing.assert_allclose(r_f, r_r, rtol=1e-12, atol=1e-12)
    assert np.all(np.abs(jac_f) > 0)
    np.testing.assert_allclose(jac_f, jac_r, rtol=1e-7, atol=1e-9 * np.max(np.abs(jac_f)))


def test_second_process_loads_the_compiled_program(micro, tmp_path):
    """A fit run again in a new process loads the compiled program from the cache (no
    tracing, lowering or compiling) and gives the same numbers."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}  # the CLI's own settings
    env["JAXIMPACT_CACHE_DIR"] = str(tmp_path / "cache")
    cmd = [*_jaximpact_command(), "fit", str(micro["data"]), "--params", *NAMES]
    cmd += ["--init", *(f"{k}={v}" for k, v in NEAR.items()), "--starts", "1", "--no-progress"]
    results = []
    for run_index in range(2):
        out = tmp_path / f"fit{run_index}.json"
        run = subprocess.run([*cmd, "-o", str(out)], capture_output=True, text=True, env=env)
        assert run.returncode == 0, run.stderr
        results.append(json.loads(out.read_text()))
    assert [r["program"]["source"] for r in results] == ["traced", "cache"]
    assert [p["value"] for p in results[0]["params"].values()] == [
        p["value"] for p in results[1]["params"].values()
    ]


@pytest.mark.slow  # two fresh processes, each compiling (about 30 s on 2 cores)
def test_cached_fit_program_runs_after_other_programs(micro, tmp_path):
    """A process that compiles another program first (a notebook's ``simulate``, then a
    fit) runs the fit's program from the cache and gives the numbers of a process that did
    not. (The compiled executables once kept with ``jax.experimental.serialize_executable``
    failed in such a process with XLA's "NOT_FOUND: Function ... not found", seen with one
    cache's state and not reproduced from an empty cache: they are no longer kept, see
    ``jaximpact._io.cache``.)"""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["JAXIMPACT_CACHE_DIR"] = str(tmp_path / "cache")
    code = (
        "import sys, jax, numpy as np\n"
        "jax.config.update('jax_enable_x64', True)\n"
        "import jaximpact, fitting\n"
        "if sys.argv[1] == 'after':\n"
        "    np.asarray(jaximpact.simulate(jaximpact.table1_scene(), 1.0, 30.0).cor_n)\n"
        f"r = fitting.fit(jaximpact.table1_scene(), {str(micro['data'])!r}, {NAMES!r},\n"
        f"                initial={NEAR!r}, starts=1, progress=False)\n"
        "print(r.status, *r.theta)\n"
    )
    out = []
    for order in ("alone", "after"):
        run = subprocess.run([sys.executable, "-c", code, order], capture_output=True,
                             text=True, env=env, timeout=600)  # fmt: skip
        assert run.returncode == 0, run.stderr[-2000:]
        out.append(run.stdout.split())
    assert out[0][0] == "converged" and out[0] == out[1]


def test_cache_dir_from_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("JAXIMPACT_CACHE_DIR", "off")
    assert _cache.cache_dir() is None
    assert jaximpact.enable_compilation_cache() is None
    monkeypatch.setenv("JAXIMPACT_CACHE_DIR", str(tmp_path / "c"))
    assert _cache.cache_dir() == tmp_path / "c"
    assert _cache.cache_dir(tmp_path / "x") == tmp_path / "x"  # an explicit path wins
    monkeypatch.delenv("JAXIMPACT_CACHE_DIR")
    assert _cache.cache_dir().name == "jax-compilation-cache"


@pytest.mark.parametrize("setting", ["path", "off"])
def test_cli_cache_setting(tmp_path, setting):
    # The CLI turns the cache on before running a command: with a path the directory is
    # made, with "off" nothing is written (not even the default user cache directory).
    bad = tmp_path / "bad.csv"
    bad.write_text("speed,angle_deg\n-1,0\n")  # exits 2 before any compilation
    target = tmp_path / "cache"
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "xdg")}
    env["JAXIMPACT_CACHE_DIR"] = str(target) if setting == "path" else "off"
    run = subprocess.run(
        [*_jaximpact_command(), "simulate", "--impacts", str(bad)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert run.returncode == 2 and "line 2" in run.stderr
    assert target.is_dir() == (setting == "path")
    assert not (tmp_path / "xdg").exists()


@pytest.mark.parametrize("setting", ["path", "off", "jax's own"])
def test_import_turns_the_cache_on_unless_told_otherwise(tmp_path, setting):
    """``import jaximpact`` in a fresh process: the cache in $JAXIMPACT_CACHE_DIR; none with
    "off"; a JAX cache directory set before the import is kept."""
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "xdg")}
    env["JAXIMPACT_CACHE_DIR"] = "off" if setting == "off" else str(tmp_path / "ours")
    own = str(tmp_path / "own")
    code = "import jax\n"
    if setting == "jax's own":
        code += f"jax.config.update('jax_compilation_cache_dir', {own!r})\n"
    code += "import jaximpact\nprint(jax.config.jax_compilation_cache_dir)\n"
    run = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300
    )
    assert run.returncode == 0, run.stderr
    expected = {"path": str(tmp_path / "ours"), "off": "None", "jax's own": own}[setting]
    assert run.stdout.strip() == expected
    assert (tmp_path / "ours").is_dir() == (setting == "path")
    assert not (tmp_path / "xdg").exists()


def test_fit_in_float32_warns(tmp_path):
    """``fitting.fit`` where JAX runs in float32 (no jax_enable_x64): a warning that says
    how to switch, before anything else (here the bad name's error follows it)."""
    data = tmp_path / "d.csv"
    data.write_text("speed,angle_deg,observable,value\n1,0,cor_n,0.6\n2,0,cor_n,0.5\n")
    code = (
        "import warnings, fitting, jaximpact\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        "    try:\n"
        f"        fitting.fit(jaximpact.table1_scene(), {str(data)!r}, ['bogus'])\n"
        "    except ValueError as err:\n"
        "        print('error:', err)\n"
        "print('warned:', [str(w.message) for w in caught])\n"
    )
    env = {**os.environ, "JAXIMPACT_CACHE_DIR": "off"}
    run = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300
    )
    assert run.returncode == 0, run.stderr
    assert "float32" in run.stdout and "jax_enable_x64" in run.stdout
    assert "bogus" in run.stdout


def test_cli_computation_failure_exits_1(monkeypatch, capsys):
    def boom(args):
        raise RuntimeError("XLA ran out of luck\nsecond line")

    monkeypatch.setattr(ji_cli, "cmd_simulate", boom)
    assert ji_cli.main(["simulate"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: computation failed: RuntimeError: XLA ran out of luck")
    assert err.count("\n") == 1 and "Traceback" not in err


@pytest.mark.slow  # about 30 s: two compilations of the paper's impacts
def test_cached_simulate_matches_simulate(cache, capsys):
    # With the cache on, `jaximpact simulate` runs a traced program from the cache; its table
    # is the one `simulate` gives directly.
    assert jax.config.jax_compilation_cache_dir == str(cache)
    result = ji_cli._simulate_from_cache(
        jaximpact.load_scene(),
        jaximpact.tables.ImpactTable(
            **{k: np.array(v) for k, v in ji_cli.PAPER_IMPACTS.items()},
            columns=tuple(ji_cli.PAPER_IMPACTS),
        ),
    )
    assert result is not None
    direct = jaximpact.simulate(
        jaximpact.load_scene(), *(np.array(v) for v in ji_cli.PAPER_IMPACTS.values())
    )
    for name in ("status", "cor_n", "vt_out", "omega_out", "contact_time", "energy_out"):
        np.testing.assert_array_equal(getattr(result, name), getattr(direct, name), name)


@pytest.mark.slow  # about 30 s: its own program (Kharaz impacts, friction)
def test_microsphere_scene_on_kharaz_data_is_a_misfit():
    # The Table 1 microsphere (radius ~ um, adhesive) cannot describe 5 mm alumina spheres.
    result = fitting.fit(
        jaximpact.load_scene(), fitting.kharaz2001_path(), ["friction"], progress=False
    )
    assert result.status == "misfit" and not result.converged
    assert "does not describe the data" in result.message


@pytest.mark.slow  # about 40 s: the optax loop is a program of its own
def test_adam_still_works_with_forward_gradients(tmp_path):
    data = tmp_path / "k.csv"
    obs = fitting.load_kharaz2001()
    keep = obs.angle_deg >= 25
    rows = [
        f"{float(s)!r},{float(a)!r},{o},{float(v)!r}"
        for s, a, o, v in zip(
            obs.speed[keep],
            obs.angle_deg[keep],
            obs.observable[keep],
            obs.value[keep],
            strict=True,
        )
    ]
    data.write_text("speed,angle_deg,observable,value\n" + "\n".join(rows) + "\n")
    result = fitting.fit(
        fitting.kharaz2001_scene(friction=0.2),
        data,
        ["friction"],
        solver="adam",
        learning_rate=0.1,
        max_steps=300,
        progress=False,
    )
    assert result.optimizer_converged, result.message
    assert 0.085 <= result.values["friction"] <= 0.105

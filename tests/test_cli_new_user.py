"""What a new user meets on the command line (issue 13), through the installed command.

The tests run ``jaximpact`` in a subprocess, as a user would, where it computes (and once per
kind of error), and check the exit status and that an error is one line naming the user's path
or field, with no traceback. Errors found before anything is computed are also checked through
``jaximpact.cli.main`` in this process (:func:`run_here`: the same code from the parsed
arguments on, without a second interpreter's 1-2 s of imports per call).
"""

import itertools
import os
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

import jaximpact
from jaximpact.tables import COLUMN_UNITS, RESULT_COLUMNS, read_results


def _command():
    exe = shutil.which("jaximpact", path=os.path.dirname(sys.executable))
    return [exe] if exe else [sys.executable, "-m", "jaximpact.cli"]


def run(*args, cwd=None):
    # The test run's compilation cache (conftest.py), as a user's runs share one: the commands
    # that simulate the same scene compile it once (and take the cached path).
    env = dict(os.environ)
    return subprocess.run(
        [*_command(), *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        timeout=600,
    )


def run_here(*args, cwd=None):
    """``jaximpact ARGS`` through :func:`jaximpact.cli.main` in this process: its exit status
    (argparse's own exits included) and what it printed, as :func:`run` returns them."""
    import contextlib
    import io
    import types

    from jaximpact.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.ExitStack() as stack:
        if cwd is not None:
            stack.enter_context(contextlib.chdir(cwd))
        stack.enter_context(contextlib.redirect_stdout(out))
        stack.enter_context(contextlib.redirect_stderr(err))
        try:
            code = main([str(a) for a in args])
        except SystemExit as exit_:  # as the interpreter maps it: None 0, a message 1
            code = 0 if exit_.code is None else exit_.code if isinstance(exit_.code, int) else 1
    return types.SimpleNamespace(returncode=code, stdout=out.getvalue(), stderr=err.getvalue())


def one_line_error(proc, code=2):
    assert proc.returncode == code, (proc.returncode, proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    return lines[0]


def test_version_and_description():
    proc = run("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"jaximpact {jaximpact.__version__}"
    text = run_here("--help").stdout
    for command in ("simulate", "sweep", "fit", "show", "scenes"):
        assert f"  {command}  " in text.split("positional arguments")[0], command


def test_solver_outputs_rebound_in_toml(tmp_path):
    scene = tmp_path / "rebound.toml"
    text = jaximpact.default_scene_path().read_text() + '\n[solver]\noutputs = "rebound"\n'
    scene.write_text(text)
    out = tmp_path / "r.csv"
    proc = run("simulate", scene, "-o", out)
    assert proc.returncode == 0, proc.stderr
    res = read_results(out)
    assert res["status"][0] == "rebound" and 0 < res["cor_n"][0] < 1
    # "rebound" integrates only the motion: no ledger (NaN, written empty).
    assert np.isnan(res["energy_out"][0])
    bad = tmp_path / "bad.toml"
    bad.write_text(jaximpact.default_scene_path().read_text() + "\n[solver]\noutputs = 3\n")
    assert "solver.outputs" in one_line_error(run_here("simulate", bad))


def test_missing_and_unwritable_files_exit_2_before_computing(tmp_path):
    line = one_line_error(run("simulate", "--impacts", tmp_path / "nope.csv"))
    assert str(tmp_path / "nope.csv") in line and "not found" in line
    line = one_line_error(run_here("simulate", tmp_path / "nope.toml"))
    assert "nope.toml" in line and "table1" in line  # names the embedded scenes too
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    target = blocker / "results.csv"
    start = time.perf_counter()
    line = one_line_error(run_here("simulate", "-o", target))
    assert str(target) in line and ".tmp" not in line
    assert not target.exists()
    # fit: the data file and the outputs too, before any compiling.
    line = one_line_error(run_here("fit", tmp_path / "nope.csv", "--params", "f0"))
    assert "nope.csv" in line and "not found" in line
    line = one_line_error(run_here("fit", "kharaz2001", "--params", "friction", "-o", target))
    assert str(target) in line
    # An empty path (`-o "$OUT"` with OUT unset) is a bad path, not "no output".
    line = one_line_error(run_here("simulate", "-o", ""))
    assert "empty path" in line and "results CSV" in line
    line = one_line_error(run_here("fit", "kharaz2001", "--params", "friction", "--plot", ""))
    assert "empty path" in line and "plot" in line
    # Every one of these stopped before simulating: together well under one compilation.
    assert time.perf_counter() - start < 120


def test_simulate_creates_missing_output_directories(tmp_path):
    out = tmp_path / "new" / "deeper" / "results.csv"
    proc = run("simulate", "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert list(read_results(out)["status"]) == ["rebound"] * 3
    assert not [p for p in out.parent.iterdir() if p.name != "results.csv"]  # no leftovers


def test_units_in_table_and_help(tmp_path):
    proc = run("simulate")
    assert proc.returncode == 0, proc.stderr
    header, units = proc.stdout.splitlines()[1:3]
    assert header.split()[:3] == ["speed", "angle_deg", "omega0"]
    assert units.split()[:3] == ["[m/s]", "[deg]", "[rad/s]"]
    assert "[s]" in units and "[m]" in units  # contact_time, max_overlap
    assert "omega_out rad/s" in run_here("simulate", "--help").stdout
    assert set(RESULT_COLUMNS) <= set(COLUMN_UNITS)


def test_all_failed_exits_1_with_reasons(tmp_path):
    scene = tmp_path / "tight.toml"
    scene.write_text(jaximpact.default_scene_path().read_text() + "\n[solver]\nmax_steps = 16\n")
    out = tmp_path / "r.csv"
    proc = run("simulate", scene, "-o", out)
    line = one_line_error(proc, code=1)
    assert "all 1 impact(s) failed" in line and "max_steps" in line
    res = read_results(out)  # still written: the reasons are the result
    assert list(res["status"]) == ["failed"] and list(res["failure_reason"]) == ["max_steps"]
    assert "failure_reason" in proc.stdout and "max_steps" in proc.stdout


def test_failure_reason_in_impact_result():
    scene = jaximpact.table1_scene(max_steps=16)
    res = jaximpact.simulate(scene, [1.0, 2.0], 0.0, 0.0)
    assert list(res.failure_reasons) == ["max_steps", "max_steps"]
    ok = jaximpact.simulate(jaximpact.table1_scene(), [1.0, 0.001], 0.0, 0.0)
    assert list(ok.status_names) == ["rebound", "captured"]
    assert list(ok.failure_reasons) == ["", ""]
    assert list(ok.columns()["failure_reason"]) == ["", ""]


def test_show_prints_derived_quantities(tmp_path):
    proc = run_here("show")
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout
    c = jaximpact.load_scene().contact
    # C_A and C_H derived from zeta at the reference speed, with where they came from.
    assert f"{float(c.C_A):.6g} s/m  (from zeta_A = 400 at 1.66 m/s)" in text
    assert f"{float(c.C_H):.6g} s/m  (from zeta_H = 100 at 1.66 m/s)" in text
    assert "auto -> tsit5" in text and "stiffness estimate" in text
    # The Hertz length of the default impact: (5 m v^2 / (4 K sqrt r))^(2/5).
    p = jaximpact.load_scene().particle
    m = float(p.density) * 4 / 3 * np.pi * float(p.radius) ** 3
    n_star = (5 * m * 1.66**2 / (4 * float(c.K) * np.sqrt(float(p.radius)))) ** 0.4
    assert f"{n_star:.6g} m" in text
    scene = tmp_path / "elastic.toml"
    scene.write_text(
        "[particle]\nradius = 1e-5\ndensity = 2500\n"
        "[contact]\nE1 = 7e10\nnu1 = 0.2\nE2 = 2e11\nnu2 = 0.3\nfriction = 0.2\n"
        "[impact]\nspeed = 1.0\nangle_deg = 0.0\n"
    )
    text = run_here("show", scene).stdout
    K = jaximpact.hertz_stiffness(7e10, 0.2, 2e11, 0.3)
    assert f"{float(K):.6g} Pa  (from E1" in text
    left = text.split("left out")[1]
    assert "adhesion" in left and "tangential motion" in left  # f0 = 0, normal, no spin


def test_embedded_scenes_by_name(tmp_path):
    proc = run_here("scenes")
    assert proc.returncode == 0 and "table1" in proc.stdout and "kharaz2001" in proc.stdout
    out = tmp_path / "k.csv"
    proc = run("simulate", "kharaz2001", "-o", out)
    assert proc.returncode == 0, proc.stderr
    res = read_results(out)
    # The scene's [impact]: 3.9 m/s at 45 degrees, and a near-elastic normal rebound.
    assert res["speed"][0] == 3.9 and res["angle_deg"][0] == 45.0
    assert 0.97 < res["cor_n"][0] < 0.99
    # A path with the same text is still a path: a local file named like a scene is read.
    (tmp_path / "mine.toml").write_text(jaximpact.scene_path("kharaz2001").read_text())
    assert run_here("show", "mine.toml", cwd=tmp_path).returncode == 0


def test_fit_embedded_kharaz_data_by_name(tmp_path):
    out = tmp_path / "fit.json"
    proc = run("fit", "kharaz2001", "--params", "friction", "--no-progress", "-o", out)
    assert proc.returncode == 0, proc.stderr
    import json

    result = json.loads(out.read_text())
    # The rigid model on all angles; the published sliding friction is 0.092.
    assert 0.085 < result["params"]["friction"]["value"] < 0.105, result["params"]
    assert "embedded kharaz2001" in proc.stdout
    # the data by name, not the path the package is installed at
    assert "(embedded data set kharaz2001)" in proc.stdout
    assert "kharaz2001_oblique_impact.csv" not in proc.stdout


def test_jaximpact_never_imports_fitting():
    code = (
        "import sys, pkgutil, importlib, jaximpact\n"
        "for m in pkgutil.walk_packages(jaximpact.__path__, 'jaximpact.'):\n"
        "    importlib.import_module(m.name)\n"
        "from jaximpact.cli import build_parser\n"
        "build_parser(plugins=False)\n"
        "assert not [m for m in sys.modules if m.split('.')[0] == 'fitting'], 'fitting imported'\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    # ... and the fit command still arrives, from the entry point fitting registers.
    assert "fit" in run("fit", "--help").stdout


@pytest.mark.parametrize("args", [("simulate", "--precision", "float16"), ("bogus",)])
def test_bad_options_exit_2(args):
    proc = run(*args)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr


def test_fit_data_examples_of_the_guide_load(tmp_path):
    """The two fit-data examples of the fitting guide (docs/fitting.md, "Fit data") are files
    fitting reads."""
    import pathlib

    import fitting

    guide = (pathlib.Path(__file__).parents[1] / "docs" / "fitting.md").read_text()
    section = guide.split("**Fit data**")[1].split("\n## ")[0]
    blocks = [b.split("```", 1)[0] for b in section.split("```\n")[1::2]]
    assert len(blocks) == 2
    for k, text in enumerate(blocks):
        path = tmp_path / f"example{k}.csv"
        path.write_text(text)
        obs = fitting.load_observations(path)
        assert len(obs) == 2, text  # two observations in each example


def test_sweep_takes_an_embedded_scene_by_name(tmp_path):
    import pyarrow.parquet as pq

    out = tmp_path / "k.parquet"
    # Normal impacts: the smallest program of the scene (its oblique one compiled in 51 s of
    # the default test run on 2 cores); the scene's [impact] angle is 45 deg.
    proc = run("sweep", "kharaz2001", "--grid", "angle_deg=0", "-o", out, "--no-progress")
    assert proc.returncode == 0, proc.stderr
    table = pq.read_table(out)  # a plain Parquet reader opens the directory
    assert table.column("speed").to_pylist() == [3.9]  # the scene's [impact] speed
    assert table.column("angle_deg").to_pylist() == [0.0]
    assert table.schema.field("vt_out").metadata == {b"unit": b"m/s"}


# ---------------------------------------------------------------------------------------------
# Issue 24: tried again as a new user would.


def test_impacts_file_without_omega0_prints_and_writes(tmp_path):
    """Item 1: an impacts CSV without the optional omega0 column (it crashed the table
    printer with KeyError after writing -o)."""
    impacts = tmp_path / "imp.csv"
    impacts.write_text("speed,angle_deg\n1.0,30\n2.0,0\n")
    out = tmp_path / "r.csv"
    proc = run("simulate", "table1", "--impacts", impacts, "-o", out)
    assert proc.returncode == 0, proc.stderr
    res = read_results(out)
    assert list(res)[:3] == ["speed", "angle_deg", "status"]  # the columns as given
    assert list(res["status"]) == ["rebound", "rebound"]
    header, _, first, second = proc.stdout.splitlines()[1:5]
    assert header.split()[:3] == ["speed", "angle_deg", "omega0"]
    assert first.split()[:4] == ["1", "30", "0", "rebound"]  # omega0 shown as its default
    assert second.split()[:4] == ["2", "0", "0", "rebound"]


def test_output_through_a_symbolic_link_keeps_the_link(tmp_path):
    """Item 5: -o LINK writes the link's target, atomically in the target's directory; the
    link stays a link, and the replaced file keeps its permissions."""
    from jaximpact.tables import write_results

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    target = tmp_path / "b" / "target.csv"
    target.write_text("old\n")
    target.chmod(0o640)
    link = tmp_path / "a" / "link.csv"
    link.symlink_to(target)
    results = {n: [0.0] for n in RESULT_COLUMNS}
    results.update(status=["rebound"], failure_reason=[""])
    write_results(link, {"speed": [1.0], "angle_deg": [0.0]}, results)
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert read_results(link)["speed"][0] == 1.0 and read_results(target)["speed"][0] == 1.0
    assert (target.stat().st_mode & 0o777) == 0o640
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["link.csv"]
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["target.csv"]
    # A link to a file not yet created: the file is created where the link points.
    new = tmp_path / "b" / "new.csv"
    (tmp_path / "a" / "dangling.csv").symlink_to(new)
    write_results(tmp_path / "a" / "dangling.csv", {"speed": [2.0], "angle_deg": [0.0]}, results)
    assert (tmp_path / "a" / "dangling.csv").is_symlink() and read_results(new)["speed"][0] == 2.0
    # A plot written through a link as well.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from fitting._least_squares.report import _atomic_savefig

    picture = tmp_path / "b" / "fig.png"
    picture.write_bytes(b"")
    (tmp_path / "a" / "fig.png").symlink_to(picture)
    fig = plt.figure()
    _atomic_savefig(fig, tmp_path / "a" / "fig.png")
    plt.close(fig)
    assert (tmp_path / "a" / "fig.png").is_symlink()
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_outputs_that_are_not_regular_files_are_refused(tmp_path):
    """Item 5: a pipe (or a link to one, or a device) is never replaced by a results file:
    exit 2, one line naming the path, before computing."""
    from jaximpact._io.paths import FileProblem, output_target

    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    link = tmp_path / "link.csv"
    link.symlink_to(fifo)
    loop = tmp_path / "loop.csv"
    loop.symlink_to(loop)
    for path, words in ((fifo, "is a pipe"), (link, "is a pipe (a link to")):
        line = one_line_error(run_here("simulate", "-o", path))
        assert str(path) in line and words in line and "regular file" in line, line
        assert fifo.is_fifo() and link.is_symlink()
    with pytest.raises(FileProblem, match="is a device"):
        output_target("/dev/null", "results CSV")
    with pytest.raises(FileProblem, match="never ends"):
        output_target(loop)
    picture = tmp_path / "pipe.png"
    os.mkfifo(picture)
    line = one_line_error(run_here("fit", "kharaz2001", "--params", "friction", "--plot", picture))
    assert str(picture) in line and "is a pipe" in line and picture.is_fifo()


def test_plot_format_checked_before_the_fit(tmp_path):
    """Item 6: `--plot fit.xyz` ran the whole fit and wrote the JSON before matplotlib refused
    the format; now exit 2 at once, one line naming the option, the file and the formats."""
    out = tmp_path / "fit.json"
    for option, name in (("--plot", "fit.xyz"), ("--plot", "fit"), ("--profile-plot", "p.bad")):
        extra = ("--profile", "friction") if option == "--profile-plot" else ()
        start = time.perf_counter()
        proc = run_here(
            "fit", "kharaz2001", "--params", "friction", "-o", out, option, tmp_path / name, *extra
        )
        line = one_line_error(proc)
        assert f"{option} {tmp_path / name}" in line and "png" in line and "pdf" in line, line
        assert time.perf_counter() - start < 60  # before compiling anything
        assert not out.exists()


def test_input_ranges_are_one_table_in_simulate_fit_and_design(tmp_path):
    """Item 4: friction 6 ran in simulate while the fit refused 2 with an unstated bound of
    1.5; speed 1e6 m/s ran. Now every input has one documented range, refused alike by the
    scene, simulate, an impacts file, the fit's starting values, priors and design."""
    import re
    from pathlib import Path

    import fitting
    from fitting._bayesian.priors import parse_prior
    from jaximpact._model.ranges import RANGES
    from jaximpact.tables import TableError, read_impacts

    rule = "friction must be finite and in [0, 10]"
    scene = jaximpact.table1_scene()
    with pytest.raises(jaximpact.SceneError) as err:
        scene.replace(contact={"friction": 11.0})
    assert f"contact.{rule}" in str(err.value) and "got 11.0" in str(err.value)
    with pytest.raises(fitting.FitError) as err:
        fitting.to_unbounded(["friction"], np.array([11.0]))
    assert rule in str(err.value) and "np.float64" not in str(err.value)
    impacts = tmp_path / "imp.csv"
    impacts.write_text("speed,angle_deg,friction\n1,30,11\n")
    with pytest.raises(TableError, match=re.escape(rule)):
        read_impacts(impacts)
    candidates = tmp_path / "cand.csv"
    candidates.write_text("speed,angle_deg\n1,30\n")
    with pytest.raises(jaximpact.SceneError, match=re.escape(rule)):
        fitting.design(scene, candidates, ["friction"], 1, values={"friction": 11.0})
    with pytest.raises(fitting.FitError, match=re.escape("[0, 10]")):
        parse_prior("friction", "loguniform:0.01:20")
    # Inside the range everywhere: a fit may start at friction 2 or 6 (refused before).
    assert np.all(np.isfinite(fitting.to_unbounded(["friction"], [2.0])))
    assert np.all(np.isfinite(fitting.to_unbounded(["friction"], [6.0])))
    scene.replace(contact={"friction": 6.0})
    with pytest.raises(
        jaximpact.SceneError, match=re.escape("speed must be finite and in (0, 1000] m/s")
    ):
        jaximpact.simulate(scene, 1e6)
    # docs/input_ranges.md states exactly the ranges (and units) the code applies, for every
    # input the code has a range for.
    doc = (Path(__file__).parents[1] / "docs" / "input_ranges.md").read_text()
    rows = re.findall(r"^\| (`[^|]+) \| ([^|]+?) \| ([^|]+?) \|", doc, re.M)
    alias = {"E1": "E", "E2": "E", "nu1": "nu", "nu2": "nu", "zeta_A": "zeta", "zeta_H": "zeta"}
    documented = {
        alias.get(name, name): (unit, interval)
        for names, unit, interval in rows
        for name in re.findall(r"`(\w+)`", names)
    }
    assert set(documented) == set(RANGES)
    for name, allowed in RANGES.items():
        unit, interval = documented[name]
        assert unit == allowed.unit, name
        assert f"{interval} {unit}".removesuffix(" 1") == allowed.interval(), name


def test_implausible_overlap_is_flagged_not_refused(tmp_path):
    """Item 4: a result beyond the small-strain range of Hertz contact (maximum overlap above
    0.1 of the radius) gets a warning and a flag column; inputs beyond a hard limit exit 2."""
    scene = tmp_path / "soft.toml"
    scene.write_text(
        "[particle]\nradius = 1e-3\ndensity = 1000\n"
        "[contact]\nK = 1e6\nC_H = 0.0\nfriction = 0.2\n"
        "[impact]\nspeed = 0.1\nangle_deg = 20\n"
    )
    impacts = tmp_path / "imp.csv"
    impacts.write_text("speed,angle_deg\n0.01,20\n5.0,20\n")
    out = tmp_path / "r.csv"
    proc = run("simulate", scene, "--impacts", impacts, "-o", out)
    assert proc.returncode == 0, proc.stderr
    warning = [line for line in proc.stderr.splitlines() if line.startswith("warning:")]
    assert len(warning) == 1 and "1 of 2 impact(s) physically implausible" in warning[0]
    assert "large_overlap" in warning[0] and "0.1 of the radius" in warning[0]
    res = read_results(out)
    assert list(res["implausible"]) == ["", "large_overlap"]
    assert res["max_overlap"][1] > 0.1e-3 > 10 * res["max_overlap"][0]  # the flag's reason
    assert "implausible" in proc.stdout.splitlines()[1]  # the printed table shows the flag
    # The Python API gives the same flags.
    s = jaximpact.load_scene(scene)
    result = jaximpact.simulate(s, res["speed"], 20.0)
    assert list(jaximpact.implausible_impacts(s, result, res["speed"], 20.0)) == [
        "",
        "large_overlap",
    ]
    impacts.write_text("speed,angle_deg\n1e6,20\n")
    line = one_line_error(run_here("simulate", scene, "--impacts", impacts))
    assert "line 2, column 'speed'" in line and "(0, 1000] m/s" in line


def test_fit_and_design_warn_about_implausible_impacts(tmp_path):
    """Item 4: fit and design warn when the values make an impact implausible (elastic
    Hertz estimate of the overlap, the same 0.1 of the radius)."""
    import fitting
    from fitting._design import DesignResult
    from fitting._least_squares.fit import _implausible_impacts
    from jaximpact.tables import ImpactTable

    soft = jaximpact.table1_scene().replace(contact={"K": 1e6, "f0": 0.0})
    data = tmp_path / "d.csv"
    data.write_text("speed,angle_deg,cor_n\n0.01,0,0.9\n5.0,0,0.5\n3.0,0,0.6\n")
    objective = fitting.Objective(soft, data, ["C_H"], method="tsit5")
    assert _implausible_impacts(objective, soft) == 2
    assert _implausible_impacts(objective, jaximpact.table1_scene()) == 0
    table = ImpactTable(speed=[0.01, 5.0], angle_deg=[0.0, 0.0])
    empty = np.zeros(0, int)
    result = DesignResult(
        ("C_H",),
        ("cor_n",),
        table,
        empty,
        empty,
        empty,
        np.array([1]),
        np.ones(1),
        np.ones(1),
        np.zeros((2, 1, 1)),
        0.0,
        np.ones((2, 1)),
        implausible=np.array([1]),
    )
    (warning,) = result.warnings()
    assert "1 of 2 candidate impacts are physically implausible" in warning
    assert "1 of them chosen" in warning


def test_one_line_messages_for_bad_options_and_names(tmp_path):
    """Item 7: argparse's usage block, --params swallowing the data name, unknown data names,
    the `<table>` placeholder, numpy reprs, plurals."""
    line = one_line_error(run_here("simulate", "--precision", "float16"))
    assert "--precision" in line and "float16" in line and "float64" in line and "float32" in line
    line = one_line_error(run_here("bogus"))
    assert "bogus" in line and "simulate" in line
    line = one_line_error(run_here("fit", "--params", "friction", "kharaz2001"))
    assert "'kharaz2001'" in line and "comma list" in line and "--params friction" in line
    line = one_line_error(
        run_here("fit", "--init", "friction=0.2", "kharaz2001", "--params", "friction")
    )
    assert "missing DATA" in line and "'kharaz2001' looks like an argument: --init" in line
    line = one_line_error(run_here("fit", tmp_path / "nosuch.csv", "--params", "friction"))
    assert "not found" in line and "kharaz2001, kharaz2001_mindlin" in line
    from fitting._least_squares.objective import FITTABLE
    from fitting.cli import split_names

    assert split_names("--params", ["friction,G_star", "C_A"], FITTABLE) == (
        "friction",
        "G_star",
        "C_A",
    )
    from jaximpact.sweep import GridSource, SweepError, parse_grid

    defaults = {"speed": 1.0, "angle_deg": 0.0, "omega0": 0.0}
    with pytest.raises(SweepError) as err:
        GridSource(parse_grid(["speed=-1,1"]), defaults)
    assert str(err.value) == (
        "grid speed: value -1.0 out of range: speed must be finite and in (0, 1000] m/s"
    )
    from jaximpact.tables import TableError, check_impact_value

    with pytest.raises(TableError) as err:
        check_impact_value("speed", np.float64(-2.0))
    assert "np.float64" not in str(err.value) and "value -2.0" in str(err.value)
    from jaximpact.sweep import SweepSummary
    from jaximpact.sweep.cli import summary_line

    done = SweepSummary("out", 64, 1, 64, 0, 1, 0, 0, 0.01, 1, True, 64)
    text = summary_line(done)
    assert "64 impacts in 1 chunk of 64 on 1 device;" in text
    assert "this run: 0 chunks, 0 impacts in 0.0 s," in text and "/s" not in text
    many = SweepSummary("out", 128, 2, 64, 2, 0, 128, 0, 2.0, 2, True, 128)
    assert "2 chunks, 128 impacts in 2.0 s (64 impacts/s)" in summary_line(many)


def test_compare_names_what_it_accepts():
    """A --compare item that is neither a file, an embedded scene nor a law lists all three;
    thornton_ning (a law a swap cannot set up: its p_y) says to give a scene file; the help
    names it. Refused before any fit (exit 2)."""
    base = ("fit", "kharaz2001", "--params", "friction", "--posterior", "--compare")
    done = run_here(*base, "hertzz")
    line = one_line_error(done)
    assert done.returncode == 2
    assert "hertzz" in line and "kharaz2001_mindlin" in line and "brach_dunn, dmt, jkr" in line
    done = run_here(*base, "thornton_ning")
    assert done.returncode == 2
    assert "contact.p_y" in one_line_error(done) and "scene file" in one_line_error(done)
    # laws that differ only in adhesion, on a scene without it, without w fitted: one model
    done = run_here(*base, "dmt,jkr")
    assert done.returncode == 2
    line = one_line_error(done)
    assert "--compare dmt" in line and "no adhesion" in line and "w" in line
    assert "thornton_ning needs its own scene file" in " ".join(
        run_here("fit", "--help").stdout.split()
    )


def test_python_api_errors_name_the_argument():
    """Item 7: a string speed, the string "1.0", an empty list, shapes that do not broadcast
    and a scene that is not a Scene are refused by name, before anything is converted."""
    scene = jaximpact.table1_scene()
    cases = [
        ((scene, "1.0"), "speed must be a number or an array of numbers, got the text '1.0'"),
        ((scene, "fast"), "speed must be a number"),
        ((scene, 1.0, ["a"]), "angle_deg must be a number or an array of numbers, got text"),
        ((scene, []), "speed is empty"),
        ((scene, 1.0, 0.0, np.zeros((0, 2))), "omega0 is empty"),
        ((scene, [1.0, 2.0], [10.0, 20.0, 30.0]), "speed (2,), angle_deg (3,)"),
        (
            (scene.replace(contact={"f0": np.array([1.0, 2.0, 3.0])}), [1.0, 2.0]),
            "speed (2,), contact.f0 (3,)",
        ),
        (("table1", 1.0), "scene must be a jaximpact.Scene"),
    ]
    for args, message in cases:
        with pytest.raises(jaximpact.SceneError) as err:
            jaximpact.simulate(*args)
        assert message in str(err.value), (args, str(err.value))
    # Scene values too: the text "1.0" is no number there either.
    for value, message in (("1.0", "got the text '1.0'"), ([], "is empty"), (True, "booleans")):
        with pytest.raises(jaximpact.SceneError) as err:
            scene.replace(contact={"f0": value})
        assert str(err.value).startswith("contact.f0 ") and message in str(err.value)


def test_fit_refuses_fewer_observations_than_parameters_before_compiling(tmp_path):
    """Item 3: one data row for three parameters compiled for 12 s and then reported an
    empty list of undetermined parameters; now exit 2 at once, naming both counts."""
    data = tmp_path / "one.csv"
    data.write_text("speed,angle_deg,cor_n\n1.0,0,0.7\n")
    start = time.perf_counter()
    line = one_line_error(run_here("fit", data, "--params", "C_A,C_H,f0", "--no-progress"))
    assert "1 independent observation for 3 parameters (C_A, C_H, f0)" in line, line
    assert time.perf_counter() - start < 60
    # Repeating one measurement adds no independent observation.
    data.write_text("speed,angle_deg,cor_n\n1.0,0,0.7\n1.0,0,0.71\n1.0,0,0.69\n")
    line = one_line_error(run_here("fit", data, "--params", "C_A,C_H", "--no-progress"))
    assert "1 independent observation (3 rows) for 2 parameters" in line, line


def _inequalities_hold(text):
    """Every `A > B` and `A, above the limit B` with numbers in ``text`` is true."""
    import re

    number = r"([0-9.]+(?:e[+-]?[0-9]+)?|inf)"
    pairs = re.findall(number + r" > " + number, text)
    pairs += re.findall(number + r", above the limit " + number, text)
    return all(float(a) > float(b) for a, b in pairs), pairs


@pytest.mark.parametrize("sigma_known", [False, True])
def test_undetermined_parameters_are_named_with_true_numbers(sigma_known):
    """Item 3: fewer residuals than parameters gave rank 1 of 3 with `condition number 1 >
    1e+08`, no names and finite standard errors; a dependent pair of columns must name both."""
    import math

    from fitting._least_squares.fit import _diagnose

    names = ("C_A", "C_H", "f0")
    theta = np.array([0.9, 0.2, 300.0])
    rng = np.random.default_rng(1)
    cases = {
        "one row": rng.normal(size=(1, 3)),
        "two rows": rng.normal(size=(2, 3)),
        "C_A and C_H move together": np.c_[np.tile(rng.normal(size=(5, 1)), 2), rng.normal(size=5)],
    }
    for what, jac in cases.items():
        d = _diagnose(jac, 0.1, len(jac), names, theta, sigma_known)
        assert d["rank"] < 3, what
        assert d["unidentifiable"], what
        if what == "C_A and C_H move together":
            assert d["unidentifiable"] == ["C_A", "C_H"]
        for name in d["unidentifiable"]:
            assert d["stderr"][name] == math.inf, (what, d["stderr"])
        (message,) = [m for m in d["undetermined"] if "do not determine" in m]
        assert f"do not determine {', '.join(d['unidentifiable'])}:" in message, message
        ok, pairs = _inequalities_hold(message)
        assert ok, (what, pairs, message)
        if len(jac) < 3:
            assert d["condition_number"] == math.inf and "no sensitivity" in message, message


@pytest.mark.parametrize("rows", [1, 4])
def test_a_parameter_that_moves_no_residual_is_named_not_determined(rows):
    """Friction of impacts that roll from the start: sensitivity 1.4e-15, a one-parameter
    Jacobian of condition number 1, rank 1 of 1, and (one row, no sigmas) "no residual
    variance" as the only reason; now the parameter is named, with its sensitivity."""
    import math

    from fitting._least_squares.fit import _diagnose

    jac = np.full((rows, 1), 1.4e-15)
    d = _diagnose(jac, 0.5, rows, ("friction",), np.array([0.1]), False)
    assert d["unidentifiable"] == ["friction"]
    assert d["stderr"]["friction"] == math.inf
    (message,) = [m for m in d["undetermined"] if "do not determine friction" in m]
    assert "sensitivity" in message and "moves no residual" in message
    # a parameter the data do move (sigmas given) is not flagged
    d = _diagnose(np.full((rows, 1), 3.0), 0.5, rows, ("friction",), np.array([0.1]), True)
    assert d["unidentifiable"] == [] and not d["undetermined"]


def test_fit_summary_with_sigmas_never_says_no_sigmas():
    """Item 3: data with sigma columns and no degrees of freedom printed "no sigmas: no
    chi-square"; the summary says why there is no chi-square, with right plurals."""
    from types import SimpleNamespace

    import fitting

    def result(sigma_known, n_data):
        obs = SimpleNamespace(source="d.csv")
        return fitting.FitResult(
            params=("C_A", "f0"),
            values={"C_A": 1.0, "f0": 300.0},
            stderr={"C_A": 0.1, "f0": 3.0},
            correlation=np.eye(2),
            covariance=np.eye(2),
            cost=0.0,
            converged=True,
            n_data=n_data,
            condition_number=float("inf"),
            residual_scale=1.0,
            warnings=[],
            timings={"total": 1.0, "compile": 0.5, "solve": 0.5},
            solver="lm",
            starts=[],
            residuals=np.zeros(n_data),
            scene=None,
            objective=SimpleNamespace(observations=obs, sigma_known=sigma_known),
            rms_residual=0.0,
        )

    text = fitting.summary(result(True, 2))
    assert "no sigmas" not in text and "no degrees of freedom" in text
    assert "2 observations for 2 parameters" in text and "condition number infinite" in text
    text = fitting.summary(result(False, 1))
    assert "to 1 observation (" in text and "no sigmas: no chi-square" in text


def _captured_figure(monkeypatch, module):
    """Replace a plotting module's file writer; returns the list that receives the figure."""
    figures = []
    monkeypatch.setattr(module, "_atomic_savefig", lambda fig, path: figures.append(fig))
    return figures


def test_fit_plot_labels_every_curve_and_axis(tmp_path, monkeypatch):
    """Item 8: the model curve in the legend, one label per curve (the per-angle curves of a
    synthetic fit had none), units on every axis, the fitted values with their uncertainty."""
    import fitting
    import fitting._least_squares.report as report

    data = tmp_path / "d.csv"
    rows = [f"{v},{a},0.5,0.8" for a in (20.0, 40.0) for v in (1.0, 2.0, 3.0)]
    data.write_text("speed,angle_deg,cor_n,cor_t\n" + "\n".join(rows) + "\n")
    scene = jaximpact.load_scene("kharaz2001")
    objective = fitting.Objective(scene, data, ["friction"], method="tsit5")
    result = fitting.FitResult(
        params=("friction",),
        values={"friction": 0.1},
        stderr={"friction": 0.0064},
        correlation=np.eye(1),
        covariance=np.eye(1),
        cost=0.0,
        converged=True,
        n_data=12,
        condition_number=1.0,
        residual_scale=1.0,
        warnings=[],
        timings={"total": 1.0, "compile": 0.5, "solve": 0.5},
        solver="lm",
        starts=[],
        residuals=np.zeros(12),
        scene=objective.scene_at({"friction": 0.1}),
        objective=objective,
    )
    figures = _captured_figure(monkeypatch, report)
    report.plot_fit(tmp_path / "fit.png", result)
    (fig,) = figures
    axes = fig.axes
    assert [ax.get_ylabel().replace("\n", " ") for ax in axes] == [
        "normal restitution, cor_n (dimensionless)",
        "tangential restitution, cor_t (dimensionless)",
    ]
    assert axes[-1].get_xlabel() == "impact speed (m/s)"
    for ax in axes:
        curves = [line for line in ax.get_lines() if line.get_linestyle() == "-"]
        assert sorted(line.get_label() for line in curves) == ["model, 20 deg", "model, 40 deg"]
        assert len({line.get_color() for line in curves}) == 2  # told apart by colour too
    legend = [t.get_text() for t in axes[0].get_legend().get_texts()]
    assert {"model, 20 deg", "model, 40 deg", "model at the data", "data"} <= set(legend)
    assert "friction = 0.1 \u00b1 0.0064" in axes[0].get_title()
    _assert_axis_labels_inside_and_apart(fig)


def _assert_axis_labels_inside_and_apart(fig):
    """Every axis label lies inside the figure, and the stacked panels' y labels do not run
    into each other (a long label such as "tangential restitution, cor_t (dimensionless)" on
    a short panel was cut to "angential ..." and overlapped its neighbour's)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    boxes = []
    for ax in fig.axes:
        for label in (ax.xaxis.label, ax.yaxis.label):
            if not label.get_text():
                continue
            box = label.get_window_extent(renderer)
            inside = box.x0 >= 0 and box.y0 >= 0 and box.x1 <= fig.bbox.x1 and box.y1 <= fig.bbox.y1
            assert inside, (label.get_text(), box, fig.bbox)
        if ax.yaxis.label.get_text():
            boxes.append(ax.yaxis.label.get_window_extent(renderer))
    for a, b in itertools.combinations(boxes, 2):
        assert not a.overlaps(b), (a, b)


def test_profile_and_corner_plots_have_units_and_unclipped_titles(tmp_path, monkeypatch):
    """Item 8: the profile's x axis has the parameter's unit; the corner plot's title is not
    cut off and does not overlap the panels, whose marginals give value and interval."""
    from types import SimpleNamespace

    import fitting._bayesian.report as posterior_report
    import fitting._least_squares.report as report
    from fitting._least_squares.profile import Profile, plot_profile

    figures = _captured_figure(monkeypatch, report)
    grid = np.linspace(250.0, 350.0, 7)
    prof = Profile(
        "f0", grid, ((grid - 300) / 20) ** 2, {}, np.ones(7, bool), 300.0, 20.0, 261.0, 339.0
    )
    plot_profile(tmp_path / "p.png", prof)
    (fig,) = figures
    ax = fig.axes[0]
    assert ax.get_xlabel() == "f0 (N/m)" and "(dimensionless)" in ax.get_ylabel()
    assert "f0 = 300 \u00b1 20 N/m" in ax.get_title() and "[261, 339] N/m" in ax.get_title()

    from matplotlib.backends.backend_agg import FigureCanvasAgg

    rng = np.random.default_rng(0)
    draws = np.stack([rng.normal(0.9, 0.1, (4, 200)), rng.normal(300, 20, (4, 200))], axis=-1)
    summary = {
        n: {
            "median": float(np.median(d)),
            "q05": float(np.quantile(d, 0.05)),
            "q95": float(np.quantile(d, 0.95)),
        }
        for n, d in (("C_A", draws[..., 0]), ("f0", draws[..., 1]))
    }
    for params in (("C_A", "f0"), ("C_A",)):
        figures = _captured_figure(monkeypatch, posterior_report)
        post = SimpleNamespace(
            params=params,
            draws=draws[..., : len(params)],
            fit=SimpleNamespace(values={"C_A": 0.9, "f0": 300.0}),
            summary=summary,
            chains=4,
            converged=True,
        )
        posterior_report.plot_corner(tmp_path / "c.png", post)
        (fig,) = figures
        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        renderer = canvas.get_renderer()
        title = fig._suptitle.get_window_extent(renderer)
        inside = 0 <= title.x0 and title.x1 <= fig.bbox.x1 and title.y1 <= fig.bbox.y1
        assert inside, (params, title, fig.bbox)
        for ax in fig.axes:
            if ax.axison:
                assert ax.get_tightbbox(renderer).y1 <= title.y0 + 1, "a panel overlaps the title"
        if len(params) == 1:  # a histogram of readable size, not a small one under the title
            assert fig.get_figwidth() >= 4.5 and fig.axes[0].get_position().height > 0.5
        assert "(4 chains x 200 draws)" in " ".join(fig._suptitle.get_text().split())
        s = summary["C_A"]
        assert fig.axes[0].get_title() == (
            f"C_A = {s['median']:.3g} s/m\n90 %: [{s['q05']:.3g}, {s['q95']:.3g}]"
        )
        bottom = fig.axes[-len(params) :]
        assert [ax.get_xlabel() for ax in bottom] == [
            f"{n} ({u})" for n, u in zip(params, ("s/m", "N/m")[: len(params)], strict=True)
        ]
    # SMC's chains are independent populations of particles: the title says so
    figures = _captured_figure(monkeypatch, posterior_report)
    posterior_report.plot_corner(
        tmp_path / "c.png", SimpleNamespace(**{**vars(post), "sampler": "smc"})
    )
    (fig,) = figures
    assert "(4 populations x 200 particles)" in " ".join(fig._suptitle.get_text().split())


@pytest.mark.slow  # a fit and a plot in a fresh process (~20 s): CI's second step
def test_fit_plot_says_it_is_drawing(tmp_path):
    """Item 8: `--plot` spent seconds simulating the model in silence after the report; it now
    costs less (one compact simulate for the data and the curves) and says what it draws and
    how long it took, on one line of stderr."""
    import re

    png = tmp_path / "fit.png"
    proc = run("fit", "kharaz2001", "--params", "friction", "--plot", png)
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("drawing")]
    assert len(lines) == 1, proc.stderr
    assert re.fullmatch(
        rf"drawing {re.escape(str(png))} \(the fitted model\) \.\.\. [0-9.]+ s", lines[0]
    )
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"wrote {png}" in proc.stdout


# -- per-row parameters of the newer laws: w, G_star, p_y -------------------------------------

DMT_SCENE = """
[particle]
radius = 2.5e-6
density = 2500.0
[contact]
K = 1.0e10
w = 0.05
friction = 0.3
C_H = 0.1
[model]
normal = "dmt"
"""


@pytest.mark.parametrize(
    "scene, column, value, expected",
    [
        ("table1", "G_star", "1e9", 'G_star is used only with model.tangential = "mindlin"'),
        ("dmt.toml", "p_y", "1e8", "p_y (limiting contact pressure) is used only with"),
        ("table1", "w", "0.05", "w (work of adhesion) is used only with"),
        ("dmt.toml", "f0", "300", "f0 is the Brach-Dunn ring's; the dmt law takes w"),
    ],
)
def test_per_row_column_the_scene_does_not_use_is_refused(tmp_path, scene, column, value,
                                                          expected):  # fmt: skip
    """A column whose values could change nothing (the scene's laws do not read it) is bad
    input: exit 2, one line naming the file, the column and the law that would use it; the
    same for a sweep's grid axis."""
    (tmp_path / "dmt.toml").write_text(DMT_SCENE)
    (tmp_path / "impacts.csv").write_text(f"speed,angle_deg,{column}\n1.0,30,{value}\n")
    proc = run_here("simulate", scene, "--impacts", "impacts.csv", cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "impacts.csv: column " + column in lines[0], lines
    assert expected in lines[0]
    proc = run_here("sweep", scene, "--grid", f"{column}={value}", "-o", "s.parquet",
                    "--no-progress", cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 2 and expected in proc.stderr, proc.stderr
    assert not (tmp_path / "s.parquet").exists()


def test_per_row_w_column_gives_the_impacts_of_scenes_with_that_w(tmp_path):
    """An impacts CSV may vary the DMT law's w per row (as fit does): each row's result is
    that of the scene with its w."""
    import jaximpact as ji
    from jaximpact.cli import check_columns_used, scene_with_overrides
    from jaximpact.tables import read_impacts

    (tmp_path / "dmt.toml").write_text(DMT_SCENE)
    (tmp_path / "impacts.csv").write_text("speed,angle_deg,w\n0.5,30,0.01\n0.5,30,0.2\n")
    scene = ji.load_scene(tmp_path / "dmt.toml")
    table = read_impacts(tmp_path / "impacts.csv")
    check_columns_used(scene, table.overrides, "impacts.csv")
    rows = ji.simulate(scene_with_overrides(scene, dict(table.overrides)), table.speed,
                       table.angle_deg)  # fmt: skip
    for k, w in enumerate((0.01, 0.2)):
        alone = ji.simulate(scene.replace(contact={"w": w}), 0.5, 30.0)
        np.testing.assert_allclose(rows.cor_n[k], alone.cor_n, rtol=1e-6)
        np.testing.assert_allclose(rows.omega_out[k], alone.omega_out, rtol=1e-6)
    assert abs(float(rows.cor_n[0] - rows.cor_n[1])) > 0.01  # w matters here

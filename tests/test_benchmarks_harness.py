"""benchmarks/ as a harness: ``python -m benchmarks --list`` names every script, the quick
modes pass options the scripts have, and BENCHMARKS.md's table of targets is the one that
``python -m benchmarks targets`` makes from the committed result files and targets.toml.
Reads files and runs ``--list`` only: no benchmark runs."""

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import benchmarks  # noqa: E402
from benchmarks import targets  # noqa: E402

SCRIPTS = sorted(
    p.stem
    for p in (ROOT / "benchmarks").glob("*.py")
    if not p.name.startswith("_")  # _common.py, __init__.py, __main__.py
)


def test_list_names_every_script_with_a_description_and_a_run_time():
    out = subprocess.run(
        [sys.executable, "-m", "benchmarks", "--list"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    listed = [line.split()[0] for line in out.splitlines() if line and not line[0].isspace()]
    assert listed == SCRIPTS
    for name in SCRIPTS:
        d = benchmarks.describe(name)
        assert d["description"], name
        assert "quick" in d["quick"] or name in benchmarks.MODULES, name
        if name not in benchmarks.MODULES:
            assert d["run_time"] != "not stated", f"{name}: no run time in its docstring"


def _options(name):
    """The option strings that ``benchmarks/NAME.py`` passes to ``add_argument``."""
    tree = ast.parse((ROOT / "benchmarks" / f"{name}.py").read_text(encoding="utf-8"))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "add_argument":
            found |= {a.value for a in node.args if isinstance(a, ast.Constant)}
    return found


def test_every_script_has_a_quick_entry_and_its_options_exist():
    for name in SCRIPTS:
        if name in benchmarks.MODULES:
            continue
        assert name in benchmarks.QUICK, f"{name}: say its quick mode, or why it has none"
        quick = benchmarks.QUICK[name]
        if isinstance(quick, str):
            assert quick.startswith("none"), name
            continue
        args, _ = quick
        script = "run_all" if name in benchmarks.SECTIONS else name
        flags = {a for a in args if a.startswith("-")}
        assert flags <= _options(script), f"{name}: {flags - _options(script)} unknown"


def test_quick_command_lines():
    cmd = benchmarks.command("loop_kernels", quick=True, args=["--update", "X.md"])
    assert cmd[0].endswith("benchmarks/loop_kernels.py")
    assert cmd[1:] == ["--n", "1000", "--repeats", "1", "--update", "X.md"]
    cmd = benchmarks.command("stability", quick=True)
    assert cmd[0].endswith("benchmarks/run_all.py")
    assert cmd[1:] == ["--quick", "--only", "stability"]
    with pytest.raises(ValueError, match="no quick mode"):
        benchmarks.command("posterior_grid", quick=True)


# Scripts that print a table without write_result, and where their figures live instead.
OWN_DATA_FILES = {
    "normal_law_comparison": "--out: JSON lines of every data set (benchmarks/results/)",
    "posterior_sbc": "--out: JSON lines of every replication (benchmarks/results/)",
    "posterior_grid": "--json: every case (benchmarks/results/posterior_grid.json)",
    "stability": "a section of run_all.py, which writes run_all_stability.json",
    "work_precision": "a section of run_all.py, which writes run_all_work_precision.json",
    "summary": "a module: the At a glance rows from run_all's data",
    "targets": "reads the result files",
}


def test_scripts_that_print_tables_write_result_files():
    missing = []
    for name in SCRIPTS:
        text = (ROOT / "benchmarks" / f"{name}.py").read_text(encoding="utf-8")
        prints_table = "|---" in text or "table(" in text
        writes = "write_result(" in text or "results_dir()" in text
        if prints_table and not writes and name not in OWN_DATA_FILES:
            missing.append(name)
    assert not missing, f"print a table but write no result file: {missing}"


def test_run_time_is_read_from_the_docstring():
    assert benchmarks.run_time("X.\n\nDuration: about 4 minutes on 2 cores.\n") == (
        "about 4 minutes on 2 cores"
    )
    assert benchmarks.run_time("Run: x (about 5 minutes on 2 cores; y)") == (
        "about 5 minutes on 2 cores"
    )
    assert benchmarks.run_time("nothing") == "not stated"


def test_the_committed_targets_table_is_the_generated_one():
    text = (ROOT / "BENCHMARKS.md").read_text(encoding="utf-8")
    assert text.count(targets.BEGIN) == 1 and text.count(targets.END) == 1
    assert targets.committed(text) == targets.table(), (
        "BENCHMARKS.md's targets table is out of date: python -m benchmarks targets"
    )
    # the table opens the file: the first section after the introduction
    headings = [line for line in text.splitlines() if line.startswith("## ")]
    assert headings[0] == "## Targets"


def test_every_target_points_to_a_result_or_is_kept_in_targets_toml():
    text = (ROOT / "BENCHMARKS.md").read_text(encoding="utf-8")
    headings = {line.lstrip("#").strip() for line in text.splitlines() if line.startswith("#")}
    entries = targets.load_targets()
    assert entries
    for e in entries:
        assert {"figure", "target", "section"} <= set(e), e
        assert e["section"] in headings, f"no section {e['section']!r} in BENCHMARKS.md"
        if "result" in e:
            path = ROOT / "benchmarks" / "results" / e["result"]
            assert path.is_file(), path
            values = targets.lookup(json.loads(path.read_text(encoding="utf-8")), e["value"])
            assert values and all(isinstance(v, int | float) for v in values), e
            assert "at_most" in e or "at_least" in e, e
        else:
            assert {"measured", "met", "cpu", "date"} <= set(e), e
            assert e["met"] in ("yes", "no", "partly"), e
        row = targets.row(e)
        assert row["cpu"] and row["date"], e


def test_targets_rows_from_a_result_file(tmp_path):
    (tmp_path / "r.json").write_text(
        json.dumps(
            {
                "info": {"cpu": "Intel(R) Xeon(R) Processor (AVX-512)", "cores": 2,
                         "date": "2026-12-01 10:00"},
                "cases": [{"s": 12.0}, {"s": 31.5}],
            }
        )
    )  # fmt: skip
    e = {"figure": "f", "target": "30 s", "section": "S", "result": "r.json",
         "value": "cases.*.s", "reduce": "max", "format": "{:.1f} s", "at_most": 30}  # fmt: skip
    r = targets.row(e, results=tmp_path)
    assert (r["measured"], r["met"]) == ("31.5 s", "no")
    assert (r["cpu"], r["date"]) == ("Intel Xeon (AVX-512), 2 cores", "2026-12-01")
    rows = {"figures": [{"case": "a b", "cache": "cold", "s": 1.0},
                        {"case": "a b", "cache": "warm", "s": 2.0}]}  # fmt: skip
    assert targets.lookup(rows, "figures.[case=a b,cache=warm].s") == [2.0]
    assert targets.lookup(rows, "figures.*.s") == [1.0, 2.0]
    assert targets.anchor("Posterior with SMC, end to end") == "#posterior-with-smc-end-to-end"
    assert targets.anchor("Compared with a scipy `solve_ivp` loop") == (
        "#compared-with-a-scipy-solve_ivp-loop"
    )

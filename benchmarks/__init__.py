"""jaximpact's benchmarks: one entry point over the scripts in this folder.

``python -m benchmarks --list`` lists them (description, run time, quick mode);
``python -m benchmarks NAME [--quick] [ARGS ...]`` runs ``benchmarks/NAME.py`` (each script
also runs on its own, ``python benchmarks/NAME.py``); ``python -m benchmarks targets`` writes
the table of targets at the top of BENCHMARKS.md from ``benchmarks/results/`` and
``benchmarks/targets.toml``.

This module reads the scripts' source only (no jax import): the description is the first line
of each script's docstring, the run time the docstring's ``Duration:`` sentence (else its first
"about N minutes").
"""

import ast
import re
from pathlib import Path

HERE = Path(__file__).resolve().parent

# Scripts that are a section of run_all.py rather than a command of their own: NAME runs
# ``run_all.py --only SECTION``.
SECTIONS = {"work_precision": "work_precision", "stability": "stability"}

# Modules that other scripts import and that do nothing when run.
MODULES = {
    "summary": 'module of run_all.py (rows of the "At a glance" table)',
    "scipy_peer": "module of throughput.py --scipy-ratio (the scipy peer)",
}

# --quick: the arguments that make a small run of a script (before the user's own), and the
# time it takes where it was timed; a string instead of a list says why the script has no
# quick mode. On 2 cores most quick runs are dominated by compiling: seconds to minutes. Quick runs
# write their result files to a temporary folder (JAXIMPACT_BENCHMARK_RESULTS), never over
# the committed ones in benchmarks/results/.
QUICK = {
    "accuracy_catalogue": (["--quick"], "about 2 minutes; the script's own: 7 scenes"),
    "run_all": (["--quick"], "minutes; the script's own: fewer impacts and settings"),
    "work_precision": (["--quick"], "minutes; run_all.py --quick --only work_precision"),
    "stability": (["--quick"], "minutes; run_all.py --quick --only stability"),
    "first_result": (["--only", "simulate 3"], "20 s on 2 loaded cores; one entry point"),
    "capture_speed_statuses": (["--scenes", "3"], "not timed; three scenes per law"),
    "dmt_slow_exits": "none: the whole run is about 20 s",
    "lammps_impacts": (["--quick"], "about 1 minute; the script's own: 3 combinations, 4 cases"),
    "lammps_oblique": (["--quick"], "about 1 minute; the script's own: 3 combinations, 4 cases"),
    "xla_options": (["--rounds", "1"], "not timed; two processes"),
    "loop_kernels": (["--n", "1000", "--repeats", "1"], "not timed; six processes compiling"),
    "isa_comparison": (
        ["--n", "1000", "--repeats", "1", "--rounds", "1", "--precisions", "float64"],
        "not timed; three processes compiling",
    ),
    "near_capture_band": (["--n", "2000", "--block", "1000"], "not timed; mostly compiling"),
    "noise_sbc": (["--replications", "2"], "not timed; mostly compiling"),
    "sweep_host": (
        ["--rows", "65536", "--chunks", "32768", "--threads", "1"],
        "not timed; 65,536 impacts are solved first",
    ),
    "gradient_cost": (
        ["--sets", "1", "--params", "1", "--repeats", "1"],
        "not timed; mostly compiling",
    ),
    "fused_step": (["--lanes", "256", "--repeats", "1"], "not timed; six variants compiling"),
    "wall_law_benchmark": (
        ["--scenes", "1", "--points", "100", "--skip-derivatives"],
        "a few minutes: the default wall law is built in full",
    ),
    "thornton_ning_accuracy": "none: compiling dominates (--impacts 100 took over 100 s)",
    "fit_benchmark": "none: every figure is a fresh process's wall time (--repeats 1: 1 minute)",
    "posterior_end_to_end": "none: fresh processes end to end (--cases gaussian: about 40 s)",
    "kharaz_mindlin_posterior": "none: the real data's posterior and its grid",
    "posterior_grid": "none: a grid posterior a case (--cases near_capture: minutes)",
    "posterior_sbc": "none: calibration needs its replications (--replications N --out FILE)",
    "posterior_benchmark": "none: choose the parts (--time, --coverage N, --design)",
    "normal_law_comparison": "none: model comparison over synthetic data sets (--sets N)",
    "derivative_accuracy": "none: the reference's finite differences are the cost",
    "rolling_derivatives": "none: the reference's finite differences are the cost",
    "mindlin_reference": "none: 40 reference impacts (about 1 minute)",
    "tangential_compliance": "none: two fits to the Kharaz data",
    "term_contributions": "none: three reference histories and throughput's rates",
    "throughput": "none: choose the part (--paths, --profile, --scipy-ratio)",
    "sweep_benchmark": "none: a 1,000,000-impact sweep (--n, --scaling-n to shrink it)",
    "wall_law_kink": "none: the roll survey of the whole grid comes first",
    "wall_law_radius": "none: a wall law over a radius range (--radius LO HI to shrink it)",
    "openfoam_wall_law": "none: needs OpenFOAM and wmake (1-3 minutes)",
    "thornton_ning_oracle": "none: seconds already (numpy and scipy only)",
    "targets": "none: seconds already (reads the result files)",
}

_TIME = re.compile(
    r"(?:about|~)\s*[\d.,]+(?:\s*-\s*[\d.,]+)?\s*(?:minutes?|min|hours?|seconds?|s)\b"
    r"(?:\s+(?:on|a)\s+[\w ]*?(?:cores?|case))?",
    flags=re.I,
)


def _docstring(path):
    return ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""


def run_time(doc):
    """The run time a docstring states: its ``Duration:`` sentence, else its first "about N
    minutes"; "not stated" without either."""
    m = re.search(r"^Duration:\s*(.+?)(?:\.\s*$|\.\s|$)", doc, flags=re.M)
    if m:
        return " ".join(m.group(1).replace("``", "").split())
    m = _TIME.search(" ".join(doc.split()))
    return m.group(0) if m else "not stated"


def scripts():
    """``{name: path}`` of every script in benchmarks/ (the private ``_*.py`` modules and
    this package's own files left out), sorted by name."""
    return {
        p.stem: p
        for p in sorted(HERE.glob("*.py"))
        if not p.name.startswith("_") and p.stem not in ("__init__", "__main__")
    }


def describe(name):
    """``{"name", "description", "run_time", "quick"}`` of one script, from its source."""
    doc = _docstring(scripts()[name])
    first = " ".join(doc.split("\n\n", 1)[0].split())
    first = re.sub(r"\s*\(issues? \d+[^()]*(?:\([^()]*\)[^()]*)*\)", "", first)  # history
    quick = QUICK.get(name, "none stated")
    if isinstance(quick, tuple):
        quick = f"quick ({quick[1]}): {' '.join(_quote(a) for a in quick[0])}"
    else:
        quick = f"quick: {quick}"
    if name in MODULES:
        quick = MODULES[name]
    return {"name": name, "description": first, "run_time": run_time(doc), "quick": quick}


def command(name, quick=False, args=()):
    """The command line (a list) that ``python -m benchmarks NAME`` runs, after ``python``."""
    if name in SECTIONS:
        base = [str(HERE / "run_all.py"), *(["--quick"] if quick else []), "--only", name]
        return base + list(args)
    if name not in scripts():
        raise KeyError(name)
    extra = []
    if quick:
        q = QUICK.get(name)
        if not isinstance(q, tuple):
            raise ValueError(f"{name} has no quick mode: {q or 'none stated'}")
        extra = q[0]
    return [str(scripts()[name]), *extra, *args]


def _quote(arg):
    return f'"{arg}"' if " " in arg else arg

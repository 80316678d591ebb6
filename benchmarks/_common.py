"""Shared pieces of the benchmarks: held-out impacts, error measures, timing, machine facts."""

import datetime
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
FIGURES = ROOT / "benchmarks" / "figures"
ERROR_KEYS = ("cor_n", "vt", "omega", "contact_time")


def held_out(n, seed=1, speeds=(0.1, 10.0)):
    """Held-out impacts: log-uniform speeds, angles -70..70 deg, |omega0| <= 3e4 rad/s.

    The first tenth is normal (angle 0), the first twentieth also without spin.
    """
    rng = np.random.default_rng(seed)
    speed = 10 ** rng.uniform(np.log10(speeds[0]), np.log10(speeds[1]), n)
    angle = rng.uniform(-70.0, 70.0, n)
    omega0 = rng.uniform(-3e4, 3e4, n)
    angle[: max(n // 10, 1)] = 0.0
    omega0[: max(n // 20, 1)] = 0.0
    return speed, angle, omega0


def reference_rows(params, speed, angle, omega0, **options):
    """Exact switched reference (float64, rtol 1e-12) for each impact, as a dict of arrays."""
    from jaximpact import reference as ref

    rows = [
        ref.simulate_impact(params, float(s), float(a), float(w), **options)
        for s, a, w in zip(speed, angle, omega0, strict=True)
    ]
    out = {k: np.array([getattr(r, k) for r in rows], float) for k in FIELDS[1:] if k != "cor_n"}
    out["cor_n"] = out["vn_out"] / (np.asarray(speed) * np.cos(np.radians(angle)))
    out["status"] = np.array([r.status for r in rows])
    return out


FIELDS = (
    "status",
    "vn_out",
    "cor_n",
    "vt_out",
    "omega_out",
    "contact_time",
    "loss_hertz_damping",
    "loss_adhesion_damping",
    "loss_friction",
    "loss_rolling",
)


def as_dict(res):
    """A ``simulate`` result as a dict of numpy arrays, status as names (rebound/captured/...)."""
    from jaximpact import Status

    out = {k: np.atleast_1d(np.asarray(getattr(res, k), float)) for k in FIELDS[1:]}
    out["status"] = np.array([Status.NAMES[int(c)] for c in np.atleast_1d(res.status)])
    return out


def output_errors(res, exact, speed, radius):
    """Per-impact errors of ``res`` against ``exact`` (dicts from :func:`as_dict` or
    :func:`reference_rows`), scaled by the impact: ``|d cor_n|``,
    ``|d vt_out|/speed``, ``|d omega_out| r/speed`` (impacts both call rebounds) and the relative
    contact time (impacts with equal status). NaN where not applicable. Also returns the number
    of status mismatches."""
    speed = np.asarray(speed, float)
    same = res["status"] == exact["status"]
    rebound = same & (exact["status"] == "rebound")
    err = {
        "cor_n": np.abs(res["cor_n"] - exact["cor_n"]),
        "vt": np.abs(res["vt_out"] - exact["vt_out"]) / speed,
        "omega": np.abs(res["omega_out"] - exact["omega_out"]) * radius / speed,
        "contact_time": np.abs(res["contact_time"] / exact["contact_time"] - 1.0),
    }
    for k in ("cor_n", "vt", "omega"):
        err[k] = np.where(rebound, err[k], np.nan)
    err["contact_time"] = np.where(same, err["contact_time"], np.nan)
    return err, int(np.sum(~same))


def max_error(err, keys=ERROR_KEYS):
    vals = [np.nanmax(err[k]) if np.any(np.isfinite(err[k])) else 0.0 for k in keys]
    return float(max(vals))


def median_time(fn, repeats=3):
    """Median wall time of ``fn()`` (which must block until its result is ready)."""
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def interleaved_timings(fns, repeats):
    """Warm-up and repeats of several computations side by side: ``fns`` is ``{name: fn}``,
    each ``fn()`` blocking until its result is ready. A first call of each in turn (compiling),
    then ``repeats`` rounds that call each once in turn (a shared machine's load moves all
    alike). Returns ``{name: {"result", "first", "times", "median", "compile"}}``: the first
    call's result and seconds, the repeats' seconds and their median, and ``compile``, the
    first call less the median (at least 0)."""
    out = {}
    for name, fn in fns.items():
        t = time.perf_counter()
        result = fn()
        out[name] = {"result": result, "first": time.perf_counter() - t, "times": []}
    for _ in range(repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            fn()
            out[name]["times"].append(time.perf_counter() - t)
    for r in out.values():
        r["median"] = float(np.median(r["times"])) if r["times"] else float("nan")
        r["compile"] = max(r["first"] - r["median"], 0.0) if r["times"] else r["first"]
    return out


def load_average():
    """The 1-, 5- and 15-minute load averages as text, e.g. ``"1.4 1.7 1.5"``."""
    return " ".join(f"{x:.1f}" for x in os.getloadavg())


def machine():
    """CPU model, core count, memory, versions."""
    import diffrax
    import jax
    import scipy

    cpu = platform.processor() or platform.machine()
    vectors = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
            if line.startswith("flags"):
                flags = set(line.split(":", 1)[1].split())
                vectors = (
                    "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else ("no AVX2")
                )
            if line == "":  # the first processor's lines are enough
                break
    except OSError:
        pass
    # the widest vector unit XLA uses here (rates differ by about 2x: BENCHMARKS.md, "By
    # instruction set"), unless XLA_FLAGS limits it
    limit = [f for f in os.environ.get("XLA_FLAGS", "").split() if "max_isa" in f]
    if vectors:
        cpu += f" ({vectors}" + (f", XLA limited: {limit[0]}" if limit else "") + ")"
    mem = ""
    try:
        kb = int(Path("/proc/meminfo").read_text().split()[1])
        mem = f"{kb / 2**20:.0f} GiB"
    except (OSError, ValueError, IndexError):
        pass
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
        ).stdout.strip()
        # the measured code: uncommitted changes to the packages make the commit approximate
        changed = subprocess.run(
            ["git", "status", "--porcelain", "--", "jaximpact", "fitting"],
            cwd=ROOT,
            capture_output=True,
            text=True,
        ).stdout.strip()
        if changed:
            commit += " with uncommitted changes"
    except OSError:
        commit = "?"
    return {
        "date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M"),
        "cpu": cpu,
        "cores": os.cpu_count(),
        "memory": mem,
        "python": platform.python_version(),
        "jax": jax.__version__,
        "diffrax": diffrax.__version__,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "commit": commit,
        "load": load_average(),
    }


def write_atomic(path: Path, data: bytes | str):
    """Write via a temporary file in the same folder and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def results_dir():
    """Where benchmarks write their result files: ``benchmarks/results/``, or the folder in
    ``JAXIMPACT_BENCHMARK_RESULTS`` (``python -m benchmarks NAME --quick`` sets it to a
    temporary folder, so that a smoke run never replaces a committed result)."""
    return Path(os.environ.get("JAXIMPACT_BENCHMARK_RESULTS") or ROOT / "benchmarks" / "results")


def plain(x):
    """``x`` as JSON can hold it: numpy arrays and numbers as lists and Python numbers, tuples
    as lists, dict keys as text (a tuple key joined by " / "), anything else as its text."""
    if isinstance(x, dict):
        return {
            (" / ".join(map(str, k)) if isinstance(k, tuple) else str(k)): plain(v)
            for k, v in x.items()
        }
    if isinstance(x, list | tuple):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist())
    if isinstance(x, np.bool_ | bool):
        return bool(x)
    if isinstance(x, np.integer | int):
        return int(x)
    if isinstance(x, np.floating | float):
        return float(x)
    if x is None or isinstance(x, str):
        return x
    if hasattr(x, "__array__"):  # a jax array
        return plain(np.asarray(x))
    return str(x)


def write_result(name, figures, info, command=None):
    """Write ``results_dir()/NAME.json``: ``{"benchmark", "command", "info", "figures"}``, with
    ``info`` the :func:`machine` description (date, CPU, cores, load, versions, commit) taken
    at the run's start and ``figures`` the measured numbers (made plain by :func:`plain`).
    Returns the path, or None (with a message) when it could not be written: a benchmark's
    printed output is never lost to its result file."""
    import json

    data = {"benchmark": name, "command": command, "info": info, "figures": figures}
    path = results_dir() / f"{name}.json"
    try:
        write_atomic(path, json.dumps(plain(data), indent=1) + "\n")
    except (OSError, TypeError, ValueError) as e:
        print(f"[{name}] result file not written: {e}", file=sys.stderr, flush=True)
        return None
    print(f"[{name}] figures written to {path}", file=sys.stderr, flush=True)
    return path


def save_figure(fig, name):
    """Save a matplotlib figure as ``benchmarks/figures/NAME.png`` (atomically, < 300 KB)."""
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    write_atomic(FIGURES / f"{name}.png", buf.getvalue())
    return f"benchmarks/figures/{name}.png"


def table(header, rows):
    """A Markdown table."""
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(out)


def fmt(x, spec=".1e"):
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "–"
    return format(x, spec)


def measured_line(info, command, settings=None, note=None):
    """The line every generated section of BENCHMARKS.md starts with: the command that
    reproduces it, then when, on which commit and machine, how loaded, with which versions;
    ``settings``: the solver settings measured; ``note``: anything else about the run (e.g.
    "another job ran on the same cores")."""
    line = (
        f"`{command}`. Measured {info['date']}, commit {info['commit']}, {info['cpu']}, "
        f"{info['cores']} cores, {info['memory']}, load average {info['load']} at the start; "
        f"Python {info['python']}, jax {info['jax']}, diffrax {info['diffrax']}, "
        f"numpy {info['numpy']}, scipy {info['scipy']}."
    )
    if settings:
        line += f" Settings: {settings}."
    if note:
        line += " " + note.strip().rstrip(".") + "."
    return line + "\n"


def default_settings():
    """The simulator's default solver settings, as the library computes them (not copied)."""
    import jax.numpy as jnp

    import jaximpact as ji
    from jaximpact._engine.solvers import default_slip_width, default_tolerances

    solver = ji.table1_scene().solver
    parts = []
    for name, dtype in (("float64", jnp.float64), ("float32", jnp.float32)):
        rtol, atol = default_tolerances(dtype, solver.rtol, solver.atol)
        try:
            width = default_slip_width(dtype, solver.slip_width, rtol)
        except TypeError:  # a version whose default width does not depend on rtol
            width = default_slip_width(dtype, solver.slip_width)
        parts.append(f"{name} rtol {rtol:g} / atol {atol:g}, slip_width {width:g}")
    return (
        f'`method = "{solver.method}"`; '
        + "; ".join(parts)
        + f"; ring_width {solver.ring_width:g}; max_steps {solver.max_steps}"
    )


def _heading(line):
    """(level, title) of a Markdown ATX heading line, else None."""
    m = re.match(r"^(#{1,6})\s+(.*?)\s*#*\s*$", line)
    return (len(m.group(1)), m.group(2)) if m else None


def replace_section(path, section):
    """Put ``section`` (Markdown that starts with its heading line, e.g. ``## Fit time``) in
    place of that section of ``path``: from the heading line to the next heading of the same
    or a higher level (``## `` ends a ``### `` section too). HTML comments and blank lines
    right before that next heading stay. The rest of the file is kept byte for byte; a
    section the file lacks is appended. Written atomically (temporary file and rename)."""
    path = Path(path)
    first = section.lstrip("\n").split("\n", 1)[0]
    head = _heading(first)
    if head is None:
        raise ValueError(f"a section starts with its heading line, got {first!r}")
    level, title = head
    body = section.strip("\n") + "\n"
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True) if path.exists() else []
    start = next(
        (i for i, x in enumerate(lines) if _heading(x.rstrip("\n")) == (level, title)), None
    )
    if start is None:
        text = "".join(lines).rstrip("\n")
        write_atomic(path, (text + "\n\n" if text else "") + body)
        return False
    end = next(
        (
            i
            for i in range(start + 1, len(lines))
            if (h := _heading(lines[i].rstrip("\n"))) and h[0] <= level
        ),
        len(lines),
    )
    keep = end  # trailing comments (markers such as <!-- ...: end -->) and blank lines stay
    while keep > start + 1 and (
        not lines[keep - 1].strip() or lines[keep - 1].lstrip().startswith("<!--")
    ):
        keep -= 1
    tail = lines[keep:end]
    if end < len(lines) and not any(x.strip() == "" for x in tail[-1:]):
        tail.append("\n")  # a blank line before the next heading
    gap = "\n" if tail and tail[0].strip() else ""
    text = "".join(lines[:start]) + body + gap + "".join(tail) + "".join(lines[end:])
    write_atomic(path, text)
    return True

"""jaximpact: simulate microsphere impacts (Brach, Dunn & Cheng 1999) on JAX.

commands:
  simulate  impacts of a scene: a table on screen, a results CSV with -o
  sweep     millions of impacts (a file or a grid) to a resumable Parquet dataset
  fit       identify contact parameters (C_A, C_H, f0, friction, ...) from rebound data;
            --posterior (sequential Monte Carlo), --profile NAME
  design    choose the impacts to measure next (D-optimal, from candidate rows)
  wall-law  a wall law for CFD codes: capture speed, rebound tables, C/OpenFOAM/Fluent code
  export    a fitted model as another code's input: export lammps FIT.json (LAMMPS commands)
  show      a scene as resolved: derived quantities, solver, the terms it compiles
  scenes    the embedded scenes, by name (every SCENE argument takes a name or a path)

units: SI throughout (m, s, kg, rad); angles in degrees from the surface normal.
exit status: 0 ok; 1 the computation failed; 2 bad input (file, field, option); 3 a fit or
posterior that did not produce a trustworthy answer.
"""

import argparse
import math
import os
import sys

from ._engine.devices import use_all_cpu_cores
from ._io.cache import enable_compilation_cache

# Exit status: 0 ok, 1 computation failed, 2 bad input (file, field, option), 3 the fit did
# not converge (or is undetermined, or a misfit; see fitting/cli.py).
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2

#: Subcommands other packages add (the ``fit`` command of ``fitting``): entry points of this
#: group, each a function ``add(subparsers)``. jaximpact itself never imports ``fitting``.
PLUGIN_GROUP = "jaximpact.commands"

PAPER_IMPACTS = {
    "speed": [1.66] * 3,
    "angle_deg": [0.0, 40.0, -40.0],
    "omega0": [math.radians(1e6)] * 3,
}
SHOWN_COLUMNS = (
    "speed",
    "angle_deg",
    "omega0",
    "status",
    "cor_n",
    "vt_out",
    "omega_out",
    "rebound_angle_deg",
    "contact_time",
    "roll_time",
    "max_overlap",
)


def check_columns_used(scene, names, source) -> None:
    """Refuse a per-row parameter column that the scene does not use (its values would change
    nothing: ``G_star`` without the Mindlin spring, say), naming the file and the column."""
    from ._io.csv_rows import TableError
    from .parameters import unused_reason

    for name in names:
        reason = unused_reason(scene, name)
        if reason is not None:
            raise TableError(f"{source}: column {name}: {reason}")


def scene_with_overrides(scene, overrides: dict):
    """The scene with per-impact parameter arrays (impacts-CSV columns) put in place (names
    of ``jaximpact.parameters.PARAMETERS``)."""
    from .parameters import with_parameters

    return with_parameters(scene, overrides)


def _table(columns: dict, names) -> str:
    """A right-aligned text table: names, then units in brackets, then the rows."""
    from ._io.tables import COLUMN_UNITS

    units = {n: f"[{COLUMN_UNITS[n]}]" if COLUMN_UNITS.get(n) else "" for n in names}
    cells = {n: [_fmt(v) for v in columns[n]] for n in names}
    width = {n: max(len(n), len(units[n]), *(len(c) for c in cells[n])) for n in names}
    lines = ["  ".join(n.rjust(width[n]) for n in names)]
    lines.append("  ".join(units[n].rjust(width[n]) for n in names))
    for i in range(len(cells[names[0]])):
        lines.append("  ".join(cells[n][i].rjust(width[n]) for n in names))
    return "\n".join(lines)


def _fmt(v) -> str:
    if isinstance(v, str):
        return v
    return "" if v != v else f"{v:.6g}"


def failure_summary(reasons) -> str:
    """``2 max_steps (the solver's step limit was reached), 1 nonfinite (...)``."""
    from collections import Counter

    from ._io.tables import FAILURE_REASONS

    counts = Counter(r for r in reasons if r)
    return ", ".join(f"{k} {r} ({FAILURE_REASONS[r]})" for r, k in sorted(counts.items()))


def cmd_simulate(args) -> int:
    import jax

    if args.precision == "float64":
        jax.config.update("jax_enable_x64", True)
    import numpy as np

    from . import implausible_impacts, load_scene, simulate
    from ._io.paths import check_readable, prepare_output, write_failed
    from ._io.scene_files import describe_scene_source
    from ._io.tables import ImpactTable, read_impacts, write_results
    from ._model.ranges import IMPLAUSIBLE

    # Every file first: a missing input or an unwritable output is reported before computing.
    scene = load_scene(args.scene)
    if args.impacts:
        check_readable(args.impacts, "impacts file")
        table = read_impacts(args.impacts)
        check_columns_used(scene, table.overrides, args.impacts)
    elif args.scene is None:
        table = ImpactTable(
            **{k: np.array(v) for k, v in PAPER_IMPACTS.items()}, columns=tuple(PAPER_IMPACTS)
        )
    else:
        i = scene.impact
        table = ImpactTable(
            speed=np.atleast_1d(float(i.speed)),
            angle_deg=np.atleast_1d(float(i.angle_deg)),
            omega0=np.atleast_1d(float(i.omega0)),
            columns=("speed", "angle_deg", "omega0"),
        )
    if args.output is not None:  # an empty path is refused, not ignored
        prepare_output(args.output, "results CSV")

    result = _simulate_from_cache(scene, table)
    scene_rows = scene_with_overrides(scene, dict(table.overrides))
    if result is None:
        program = "compact" if table.speed.size <= CACHED_SIMULATE_MAX else "throughput"
        result = simulate(scene_rows, table.speed, table.angle_deg, table.omega0, program=program)
    columns = result.columns()
    # Physically implausible results (docs/input_ranges.md): a flag column and a warning.
    flags = implausible_impacts(scene_rows, result, table.speed, table.angle_deg)
    columns["implausible"] = flags
    if args.output:
        try:
            write_results(args.output, table.as_columns(), columns)
        except OSError as err:
            raise write_failed(args.output, err) from None
    # Every impact input, given or defaulted (an impacts file may leave out omega0).
    inputs = {"speed": table.speed, "angle_deg": table.angle_deg, "omega0": table.omega0}
    shown = {**inputs, **table.overrides, **columns}
    reasons = columns["failure_reason"]
    n, failed = len(table.speed), int(np.sum(reasons != ""))
    flagged = int(np.sum(flags != ""))
    names = list(SHOWN_COLUMNS) + (["failure_reason"] if failed else [])
    names += ["implausible"] if flagged else []
    print(f"scene: {describe_scene_source(args.scene)}; {n} impact(s); SI units")
    if n <= 50 or args.output is None:
        print(_table(shown, names))
    if args.output:
        print(f"wrote {args.output}")
    if flagged:
        kinds = ", ".join(f"{k} ({IMPLAUSIBLE[k]})" for k in sorted(set(flags) - {""}))
        print(
            f"warning: {flagged} of {n} impact(s) physically implausible: {kinds}; see the "
            "implausible column and docs/input_ranges.md",
            file=sys.stderr,
        )
    if failed == n:
        print(f"error: all {n} impact(s) failed: {failure_summary(reasons)}", file=sys.stderr)
        return EXIT_FAILED
    if failed:
        print(
            f"warning: {failed} of {n} impact(s) failed: {failure_summary(reasons)}; "
            "see the failure_reason column",
            file=sys.stderr,
        )
    return 0


# Up to this many impacts, `jaximpact simulate` runs a traced program kept in the cache (a
# warm run then skips the seconds of tracing); larger batches are split over all devices by
# `simulate` itself, which a cached single-device program would not do. Up to this many, the
# program is also the compact one (`simulate(program="compact")`: half the compiling, and a
# smaller program to load, for about 2x the time per impact).
CACHED_SIMULATE_MAX = 4096


def _simulate_from_cache(scene, table):
    """``simulate`` of the table's impacts through a traced program from the cache.

    The program takes every float parameter and the impacts as inputs, so it serves any values
    of the same shape and scene switches. Under a trace the simulator cannot look at values,
    so this path is taken only where that changes nothing: the impacts need the tangential
    terms (not all normal without spin), adhesion and rolling-moment terms are not left out
    for zero values, and the solver method is resolved here from the concrete values exactly
    as ``simulate`` does. Returns ``None`` (use the normal path) otherwise, or with the cache
    off, for a scene with a ``[target]`` sphere, or on any problem building the program.
    """
    import jax
    import numpy as np

    from ._engine.results import ImpactResult
    from ._engine.simulate import integration_settings, scene_parameters
    from ._io.cache import cached_program

    n = table.speed.size
    if not jax.config.jax_compilation_cache_dir or not 1 <= n <= CACHED_SIMULATE_MAX:
        return None
    if scene.target is not None:
        return None  # sphere-sphere: this program was never checked with a [target]
    try:
        dtype = jax.numpy.result_type(float)
        values = {k: np.asarray(v, dtype=float) for k, v in scene_parameters(scene).items()}
        values.update({k: np.asarray(v, dtype=float) for k, v in table.overrides.items()})
        values = {k: np.broadcast_to(v, (n,)).astype(dtype) for k, v in values.items()}
        speed, angle, omega0 = (
            np.asarray(x, dtype=dtype) for x in (table.speed, table.angle_deg, table.omega0)
        )
        m = scene.model
        if np.all(angle == 0) and np.all(omega0 == 0):
            return None  # the normal path drops the tangential terms
        if m.adhesion and np.all(values["f0"] == 0):
            return None  # ... and the adhesion terms
        if m.rolling_moments == "lambda" and np.all(values["lambda"] == 0):
            return None
        if (
            m.rolling_moments == "analytical"
            and np.all(values["C_A"] == 0)
            and np.all(values["C_H"] == 0)
        ):
            return None
        method = integration_settings(scene, values, speed, angle, dtype, None).method
        names = tuple(values)
        fields = tuple(ImpactResult.__dataclass_fields__)

        def run(params, speed, angle, omega0):
            s = scene_with_overrides(scene, dict(zip(names, params, strict=True)))
            r = simulate(s, speed, angle, omega0, method=method, program="compact")
            return tuple(getattr(r, f) for f in fields)

        from . import simulate

        args = (tuple(values[k] for k in names), speed, angle, omega0)
        key = f"simulate|{jax.tree_util.tree_structure(scene)}|{method}|{names}|compact"
        program, _ = cached_program("simulate", run, args, key)
        out = program(*args)
    except Exception:  # anything unexpected: the normal path
        return None
    return ImpactResult(**dict(zip(fields, out, strict=True)))


def cmd_scenes(args) -> int:
    from ._io.scene_files import embedded_scenes, scene_path

    known = embedded_scenes()
    width = max(map(len, known))
    print("embedded scenes (give the name wherever a SCENE is asked for):")
    for name, about in known.items():
        print(f"  {name.ljust(width)}  {about}")
        if args.paths:
            print(f"  {''.ljust(width)}  {scene_path(name)}")
    return 0


def cmd_show(args) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    from ._io.show import scene_report

    print(scene_report(args.scene))
    return 0


def _plugins(sub) -> None:
    """Add the subcommands other installed packages register (``fit``, from ``fitting``)."""
    from importlib.metadata import entry_points

    for entry in entry_points(group=PLUGIN_GROUP):
        try:
            add = entry.load()
        except ImportError:  # a plugin whose package is broken: leave its command out
            continue
        add(sub)


SCENE_HELP = "scene: an embedded name (see `jaximpact scenes`) or a TOML file; default table1"


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (``error: ...``, exit 2), like every other
    error of the command, instead of argparse's usage block; its subcommands' parsers too."""

    def error(self, message):
        message = " ".join(message.split())
        self.exit(EXIT_BAD_INPUT, f"error: {message}; see `{self.prog} --help`\n")


def build_parser(plugins: bool = True) -> argparse.ArgumentParser:
    from . import __version__
    from ._io.tables import COLUMN_UNITS
    from .sweep.cli import add_sweep_command

    parser = Parser(
        prog="jaximpact",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"jaximpact {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    units = ", ".join(f"{k} {v}" for k, v in COLUMN_UNITS.items() if v and v != "1")
    sim = sub.add_parser(
        "simulate",
        help="simulate impacts of a scene",
        description="Simulate impacts. Without SCENE: the embedded Table 1 "
        "scene on the paper's three impacts (1.66 m/s; 0, +40, -40 deg; "
        "omega0 = 1e6 deg/s). With SCENE and no --impacts: the scene's [impact].",
        epilog=f"units (SI; CSV headers keep the bare names): {units}; cor_n, cor_t and friction "
        "are dimensionless. Exit status: 0 ok (a warning line counts failed impacts, each with "
        "its failure_reason); 1 every impact failed, or the computation failed; 2 bad input.",
    )
    sim.add_argument("scene", nargs="?", help=SCENE_HELP)
    sim.add_argument(
        "--impacts",
        help="impacts CSV (speed m/s, angle_deg, [omega0 rad/s], [parameter "
        "columns overriding the scene per row]); default: the scene's [impact]",
    )
    sim.add_argument(
        "-o",
        "--output",
        help="write the results CSV here (atomically; missing directories are created)",
    )
    sim.add_argument("--precision", choices=("float64", "float32"), default="float64")
    sim.set_defaults(func=cmd_simulate)
    add_sweep_command(sub)
    from .wall_law.cli import add_wall_law_command

    add_wall_law_command(sub)
    show = sub.add_parser(
        "show",
        help="a scene as resolved: derived quantities, solver, compiled terms",
        description="Print a scene as jaximpact resolves it: K (and where it came from), "
        "C_A and C_H (from zeta where given), the moment of inertia, the Hertz length and "
        "time scales of the scene's [impact], the solver and why it was picked, and which "
        "terms the impact compiles and which it leaves out.",
    )
    show.add_argument("scene", nargs="?", help=SCENE_HELP)
    show.set_defaults(func=cmd_show)
    scenes = sub.add_parser("scenes", help="list the embedded scenes")
    scenes.add_argument("--paths", action="store_true", help="also print each scene's file")
    scenes.set_defaults(func=cmd_scenes)
    if plugins:
        _plugins(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
        try:  # one XLA device per CPU core: simulate and sweep shard batches over them
            use_all_cpu_cores()
        except RuntimeError:  # JAX already started (cli.main called from Python): keep it
            pass
    # Compiled programs on disk ($JAXIMPACT_CACHE_DIR, "off" to disable): a second run of the
    # same command loads them instead of compiling again.
    enable_compilation_cache()
    try:
        return args.func(args)
    except ValueError as err:  # SceneError, TableError: bad input, named by field or line
        print(f"error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as err:  # a file that cannot be read or written
        where = f"{err.filename}: " if err.filename else ""
        print(f"error: {where}{err.strerror or err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # the computation itself: one line, no traceback
        if os.environ.get("JAXIMPACT_DEBUG"):
            raise
        text = " ".join(str(err).split())[:300]
        print(f"error: computation failed: {type(err).__name__}: {text}", file=sys.stderr)
        return EXIT_FAILED


def entry() -> None:
    """The ``jaximpact`` console command: :func:`main`, then exit without the interpreter's
    teardown. Unloading JAX's and XLA's modules takes about 0.3 s of a 2 s warm ``simulate``
    and serves nothing: every output is written, closed and renamed into place, and every
    worker thread joined, before ``main`` returns."""
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    sys.exit(main())

"""Command-line interface: ``jaximpact simulate`` (and ``jaximpact fit``, see fitting/)."""

import argparse
import math
import sys

SECTION_OF = {
    "radius": "particle",
    "density": "particle",
    "K": "contact",
    "f0": "contact",
    "C_A": "contact",
    "C_H": "contact",
    "friction": "contact",
    "lambda": "model",
}
PAPER_IMPACTS = {
    "speed": [1.66] * 3,
    "angle_deg": [0.0, 40.0, -40.0],
    "omega0": [math.radians(1e6)] * 3,
}


def scene_with_overrides(scene, overrides: dict):
    """The scene with per-impact parameter arrays (impacts-CSV columns) put in place."""
    sections = {}
    for name, values in overrides.items():
        field = "lambda_" if name == "lambda" else name
        sections.setdefault(SECTION_OF[name], {})[field] = values
    return scene.replace(**sections) if sections else scene


def _table(columns: dict, names) -> str:
    width = {n: max(len(n), *(len(_fmt(v)) for v in columns[n])) for n in names}
    lines = ["  ".join(n.rjust(width[n]) for n in names)]
    for i in range(len(columns[names[0]])):
        lines.append("  ".join(_fmt(columns[n][i]).rjust(width[n]) for n in names))
    return "\n".join(lines)


def _fmt(v) -> str:
    if isinstance(v, str):
        return v
    return "" if v != v else f"{v:.6g}"


def cmd_simulate(args) -> int:
    import jax

    if args.precision == "float64":
        jax.config.update("jax_enable_x64", True)
    import numpy as np

    from . import load_scene, simulate
    from .tables import ImpactTable, read_impacts, write_results

    scene = load_scene(args.scene)
    if args.impacts:
        table = read_impacts(args.impacts)
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
    scene = scene_with_overrides(scene, dict(table.overrides))
    result = simulate(scene, table.speed, table.angle_deg, table.omega0)
    columns = result.columns()
    if args.output:
        write_results(args.output, table.as_columns(), columns)
    shown = {**table.as_columns(), **columns}
    names = [
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
    ]
    print(
        f"scene: {args.scene or 'embedded Table 1 (Brach, Dunn & Cheng 1999)'}; "
        f"{len(table.speed)} impact(s); SI units"
    )
    if len(table.speed) <= 50 or args.output is None:
        print(_table(shown, names))
    failed = int(np.sum(columns["status"] == "failed"))
    if args.output:
        print(f"wrote {args.output}")
    if failed:
        print(f"warning: {failed} impact(s) failed; see the status column", file=sys.stderr)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaximpact", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    sim = sub.add_parser(
        "simulate",
        help="simulate impacts of a scene",
        description="Simulate impacts. Without SCENE: the embedded Table 1 "
        "scene on the paper's three impacts (1.66 m/s; 0, +40, -40 deg; "
        "omega0 = 1e6 deg/s).",
    )
    sim.add_argument("scene", nargs="?", help="scene file (TOML); default: embedded Table 1")
    sim.add_argument(
        "--impacts",
        help="impacts CSV (speed, angle_deg[, omega0][, parameter "
        "columns overriding the scene per row]); default: the scene's [impact]",
    )
    sim.add_argument("-o", "--output", help="write the results CSV here (atomically)")
    sim.add_argument("--precision", choices=("float64", "float32"), default="float64")
    sim.set_defaults(func=cmd_simulate)
    try:
        from fitting.cli import add_fit_command
    except ImportError:
        pass
    else:
        add_fit_command(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except ValueError as err:  # SceneError, TableError: bad input, named by field or line
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

"""``jaximpact wall-law``: tabulate a scene's wall law and generate code for CFD solvers."""

from __future__ import annotations

import argparse
import sys
import time

EPILOG = """\
grids: --angle and --spin take one SPEC each, --speed one SPEC, --radius one or more values:
    VALUE                    one value              --spin 0
    V1,V2,...                a list                 --angle 0,30,60
    START:STOP:NUM           NUM values, linear     --angle 0:85:171  (ends included)
    START:STOP:NUM:log       NUM values, geometric  --speed 1.001:200:40:log
  --angle: degrees from the normal, in [0, 89.9] (a negative tangential speed is mirrored);
  --spin: rad/s (default 0: CFD parcels rarely carry spin); --radius: m (default the scene's;
  two or more: nodes are added between them until the capture speed at every interval's
  midpoint is within --capture-tol of the table's, and where the results bend; radii that
  stick at every speed become stick rows, and the jump to them is located to 0.2 %);
  --speed: the speed over the capture speed (>= 1; the node 1 is added) for a scene with
  adhesion, the speed in m/s for one without. Defaults: angles 0 to 85 every 0.5 deg, then
  the intervals where the table bends sharply (the onset of rolling) split to 1/16 deg
  (--no-refine: not); 64 speed ratios from 1 to 200 even in asinh(sqrt(ratio - 1)), then,
  for one radius, the speed intervals where a row bends sharply split (--speed-tol); without
  adhesion 49 speeds 0.01-100 m/s.

output (in DIR, each file written atomically):
  wall_law.nc            NetCDF-4 (xarray.open_dataset): coordinates radius, angle_deg,
                         omega0, speed_ratio; capture_speed, cor_n, cor_t, vt_out, omega_out,
                         rebound_angle_deg, ... with units; the scene as attributes
  wall_law.parquet       the same as a long table (one row per cell; units as field metadata)
  jaximpact_wall_law.h   dependency-free C99: jaximpact_wall_law(radius, vn, vt, omega, ...)
  openfoam/              patch interaction model jaximpactWallLaw (wmake libso; see
                         openfoam/cloudProperties.jaximpact)
  fluent/                DEFINE_DPM_BC UDF jaximpact_wall_law_bc

uncertainty: --draws FILE.nc (from jaximpact fit --posterior --draws) adds, per cell, the
  probability of capture and the mean, sd, 5 and 95 % quantiles of cor_n over up to
  --max-draws draws (each draw simulates the whole table once more).

exit status: 0 done; 1 the computation failed (a capture speed or an impact of the grid);
  2 bad input (one line naming the option, field or file).
"""


def _values(option: str, spec: str, name: str):
    """The values of ``--option SPEC`` (the sweep grid syntax)."""
    from .._model.scene import SceneError
    from ..sweep import SweepError, parse_grid

    try:
        return parse_grid([f"{name}={spec}"])[name]
    except SweepError as err:
        text = str(err).replace(f"grid '{name}={spec}'", f"{option} {spec!r}")
        text = text.replace("NAME=", "").replace(f"{name} ", f"{option} ")
        raise SceneError(text) from None


def _speed_tol(text: str):
    """``--speed-tol``: a number in (0, 1), or ``off``."""
    if text.strip().lower() == "off":
        return False
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"must be a number in (0, 1) or 'off', got {text!r}")
    return value


def cmd_wall_law(args) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    from .. import load_scene
    from .._io.paths import FileProblem, prepare_output
    from .._io.scene_files import describe_scene_source
    from .._model.scene import SceneError
    from ._codegen import HEADER_NAME, write_code
    from ._io import read_draws, write_netcdf, write_parquet
    from ._table import WallLawError, wall_law

    started = time.perf_counter()
    scene = load_scene(args.scene)
    radius = None
    if args.radius:
        radius = np.concatenate([_values("--radius", r, "radius") for r in args.radius])
    angle = _values("--angle", args.angle, "angle_deg") if args.angle else None
    spin = _values("--spin", args.spin, "omega0") if args.spin else (0.0,)
    speed = _values("--speed", args.speed, "speed") if args.speed else None
    if args.max_draws < 1:
        raise SceneError(f"--max-draws must be an integer >= 1, got {args.max_draws}")
    if not 0 < args.capture_tol < 1:
        raise SceneError(f"--capture-tol must be in (0, 1), got {args.capture_tol}")
    if args.check < 0:
        raise SceneError(f"--check must be an integer >= 0, got {args.check}")
    draws = read_draws(args.draws) if args.draws else None
    try:  # the writer's dependencies, before any computing
        import h5netcdf  # noqa: F401
        import h5py  # noqa: F401
        import xarray  # noqa: F401
    except ImportError:
        raise SceneError(
            'wall-law writes NetCDF with xarray and h5netcdf: pip install "jaximpact[wall-law]"'
        ) from None
    out = args.output
    from pathlib import Path

    directory = Path(out)
    if directory.exists() and not directory.is_dir():
        raise FileProblem(out, "is a file; -o names a directory for the wall law's files")
    created = not directory.exists()
    prepare_output(directory / "wall_law.nc", "NetCDF file")

    scene_name = describe_scene_source(args.scene)
    progress = None if args.quiet else (lambda m: print(f"  {m}", file=sys.stderr))
    try:
        law = wall_law(
            scene,
            radius=radius,
            angle_deg=angle,
            omega0=spin,
            speed_ratio=speed,
            draws=draws,
            max_draws=args.max_draws,
            refine=not args.no_refine,
            speed_tol=args.speed_tol,
            capture_tol=args.capture_tol,
            progress=progress,
            layout=args.layout,
        )
    except (WallLawError, SceneError) as err:
        if created and not any(directory.iterdir()):  # leave nothing behind
            directory.rmdir()
        if isinstance(err, SceneError):
            raise
        print(f"error: {err}", file=sys.stderr)
        return 1
    write_netcdf(directory / "wall_law.nc", law, scene_name)
    write_parquet(directory / "wall_law.parquet", law, scene_name)
    write_code(law, directory, scene_name)
    _report(law, scene, scene_name, args.check)
    for name in ("wall_law.nc", "wall_law.parquet", HEADER_NAME, "openfoam/", "fluent/"):
        print(f"wrote {directory / name}")
    print(f"done in {time.perf_counter() - started:.1f} s")
    return 0


def _report(law, scene, scene_name, check) -> None:
    """What the table holds (and, with ``--check N``, its errors against simulate)."""
    R, U, W, X = law.shape
    A = law.angle_deg.size
    print(f"scene: {scene_name}")
    nodes = f"{R} radius x {A} angle x {W} spin x {X} speed nodes"
    if law.aligned:
        nodes += f" (results on {U} nodes of the kink-aligned angle coordinate)"
    print(f"wall law: {nodes}, {law.impacts} impacts simulated in {law.seconds:.1f} s")
    if law.speed_axis == "capture_ratio":
        _report_capture(law)
    else:
        print("the scene has no adhesion: nothing sticks; the speed axis is in m/s")
    if law.uncertainty:
        print(f"uncertainty: {law.uncertainty['draws']} posterior draws")
    if check:
        _report_check(law, scene, check)


def _report_capture(law) -> None:
    """The capture speeds, the stick rows, the build's radius nodes and refinement, and the
    rows that end below the largest speed ratio (an adhesive scene's table)."""
    import numpy as np

    from ._rows import SPEED_MAX

    vc = law.capture_speed[np.isfinite(law.capture_speed)]
    if vc.size:
        print(f"capture speed: {vc.min():.6g} to {vc.max():.6g} m/s")
    stick = law.stick.all(axis=(1, 2))
    if stick.any():
        print(
            f"sticks at every speed (stick rows): {int(law.stick.sum())} of "
            f"{law.stick.size} (radius, angle, spin) rows, radii up to "
            f"{law.radius[np.flatnonzero(law.stick.any(axis=(1, 2)))[-1]]:.6g} m"
        )
    _report_build(law.radius_report, law.shape[0])
    above = int(np.sum(law.top_ratio < law.speed_ratio[-1]))
    if above:
        again = int(np.sum(law.captured_above_top == 1))
        print(
            f"{above} rows end below the largest speed ratio: {again} stick again above "
            f"their top (captured there), {above - again} reach the speed range's "
            f"{SPEED_MAX:g} m/s (their last results, flagged as clamped)"
        )
    multiple = int(np.sum(law.capture_status == 2))
    if multiple:
        print(
            f"warning: at {multiple} (radius, angle, spin) capture is not one threshold; "
            "the table sticks below the capture speed, and above a row's top where it "
            "sticks again (capture_status 'multiple')",
            file=sys.stderr,
        )


def _report_build(report: dict, R: int) -> None:
    """The build report (``WallLaw.radius_report``): radius nodes and the intervals left
    unresolved, the aligned layout's results check, the refined cells, unconverged capture
    speeds."""
    if "checked_midpoints" in report:
        print(
            f"radius nodes: {R}, {report['checked_midpoints']} midpoints checked "
            f"(capture speed within {report['capture_tol']:g})"
        )
        bands = report["unresolved"]
        if bands:
            widest = max(hi / lo - 1 for lo, hi, _ in bands)
            print(
                f"  {len(bands)} radius intervals not resolved to that (the jump to the "
                f"stick rows, or a capture speed not found), the widest {widest:.2%} of "
                "the radius"
            )
    if "results_tol" in report:
        print(
            f"aligned results: {report['checked_radii']} radius midpoints checked against "
            f"simulate (within {report['results_tol']:g} on the aligned nodes, or split)"
        )
        left = report.get("results_unresolved", [])
        if left:
            lo, hi = min(b[0] for b in left), max(b[1] for b in left)
            print(
                f"  {len(left)} radius intervals not resolved to that (at the smallest "
                f"radius step), between {lo:.6g} and {hi:.6g} m"
            )
    for stage, (sim, total) in report.get("new_cells", {}).items():
        if total > sim:
            print(
                f"{stage}: {total - sim} of {total} new cells interpolated "
                "(their rows within the refinement tolerance), not simulated"
            )
    if report.get("not_converged"):
        print(
            f"warning: {report['not_converged']} capture speeds of table rows are the "
            "root find's best estimate (not converged)",
            file=sys.stderr,
        )


def _report_check(law, scene, check: int) -> None:
    """The table's errors against simulate at ``check`` random points (``--check N``)."""
    import numpy as np

    from ._check import compare_with_simulate, random_points

    pts = random_points(law, check, seed=0)
    c = compare_with_simulate(law, scene, pts)
    # outside the table (above a row's top, beyond an axis) the table says so: its
    # answers there are the documented fallback, counted apart
    flagged = (c["code"] & 2) == 2
    near = np.abs(c["speed_ratio"] - 1.0) <= 5e-3
    # the radius intervals the build reports as unresolved: counted apart
    r, bands = pts["radius"][:, None], law.unresolved_radii
    apart = ((r >= bands[:, 0]) & (r <= bands[:, 1])).any(axis=1)
    near |= apart
    disagree = ~c["status_agree"] & ~near
    # within 0.5 % of the capture speed the results change steeply with the speed ratio
    # (cor_n like sqrt(x - 1)), so the capture speed's own tolerance dominates there
    parts = []
    for name, label in (("cor_n", "cor_n"), ("cor_t", "cor_t"), ("spin_ratio", "spin")):
        e = c["error"][name][~flagged & ~near]
        e = e[np.isfinite(e)]
        if e.size:
            parts.append(f"{label} {e.max():.2e} ({np.percentile(e, 99):.2e})")
    print(
        f"check against simulate at {check} random points: {int(flagged.sum())} flagged "
        f"as clamped, {int(apart.sum())} in the unresolved radius intervals (counted "
        f"apart); stick/rebound disagreements beyond 0.5 % of the capture speed: "
        f"{int((disagree & ~flagged).sum())} (and {int((disagree & flagged).sum())} "
        f"flagged); errors of the other rebounds beyond 0.5 % of the capture speed, "
        f"largest (99th percentile): " + ", ".join(parts)
    )


def add_wall_law_command(sub) -> None:
    """Register ``jaximpact wall-law`` on the subcommand parsers ``sub``."""
    p = sub.add_parser(
        "wall-law",
        help="a wall law for CFD codes: capture speed, rebound tables, C/OpenFOAM/Fluent code",
        description="Tabulate a scene's wall law: for each radius, incidence angle and spin the "
        "capture speed, and above it cor_n, cor_t, the rebound spin and angle against the "
        "speed relative to the capture speed; write it as NetCDF and Parquet with a C99 "
        "header, an OpenFOAM patch interaction model and a Fluent UDF that apply it.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scene", nargs="?", help="scene: an embedded name or a TOML file")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory")
    p.add_argument("--radius", nargs="+", metavar="R", help="radii, m (default the scene's)")
    p.add_argument("--angle", metavar="SPEC", help="incidence angles, deg (see below)")
    p.add_argument("--spin", metavar="SPEC", help="spins, rad/s (default 0)")
    p.add_argument("--speed", metavar="SPEC", help="speed ratios (or m/s without adhesion)")
    p.add_argument("--draws", metavar="FILE.nc", help="posterior draws (fit --posterior --draws)")
    p.add_argument("--max-draws", type=int, default=20, help="draws used (default 20)")
    p.add_argument("--no-refine", action="store_true", help="no second pass on sharp bends")
    p.add_argument(
        "--speed-tol",
        type=_speed_tol,
        default=None,
        metavar="TOL",
        help="split speed intervals where a row's interpolation misses by more than TOL "
        "('off': not; default 1e-3 for one radius, off across a radius range)",
    )
    p.add_argument(
        "--capture-tol",
        type=float,
        default=1e-3,
        metavar="TOL",
        help="several radii: relative error of the capture speed between nodes (default 1e-3)",
    )
    p.add_argument(
        "--check",
        type=int,
        default=0,
        metavar="N",
        help="compare the table with simulate at N random points and print the errors",
    )
    p.add_argument(
        "--layout",
        choices=("grid", "aligned"),
        default=None,
        help="grid: results on the angles, refined where they bend; aligned: on an angle "
        "coordinate that follows the kinks of rolling (57 angle nodes; needs adhesion). "
        "Default: aligned for a radius range of a scene with adhesion at one spin, else grid",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(func=cmd_wall_law)

"""``jaximpact fit``: fit scene parameters to observed rebounds from the command line."""

from __future__ import annotations

import argparse
import sys

__all__ = ["add_fit_command", "cmd_fit"]

_DESCRIPTION = """\
Fit scene parameters to observed rebounds by weighted least squares, with standard errors
from the Jacobian at the optimum. SCENE is an embedded scene name (`jaximpact scenes`) or a
TOML file; DATA an embedded data set name or a CSV file (wide or long form; README, "Fit
data"). With one positional argument it is the data: an embedded data set brings its own
scene (`jaximpact fit kharaz2001 --params friction`), a file uses the embedded table1 scene.
Embedded data: kharaz2001 (Kharaz, Gorham & Salman 2001: 5 mm alumina spheres on glass at
3.9 m/s, 0-60 degrees; cor_t, omega_out, rebound_angle_deg); kharaz2001_mindlin: the same
data with the scene of that name (tangential compliance: `--params friction G_star`).

Without sigma columns each observable is weighted by a default scale (cor_n, cor_t: 0.01;
vt_out: 1 % of the speed; omega_out: 1 % of speed/radius; rebound_angle_deg: 1 degree) and
the standard errors are scaled by the residual variance. The report gives the Jacobian's
rank and condition number, each parameter's sensitivity, the parameters the data cannot
identify, and the reduced chi-square when sigmas are given.

Exit status: 0 converged (values and standard errors valid); 1 computation failed; 2 bad
input (a file, field or option, named in the message); 3 the fit did not produce a
trustworthy answer: not converged, uncertainty undefined (a parameter the data do not
determine), or the model does not describe the data (misfit). The report and the JSON
are still written, with the reason."""


def add_fit_command(subparsers) -> argparse.ArgumentParser:
    """Add the ``fit`` sub-command to a ``jaximpact`` argument parser's subparsers.

    Arguments:
        subparsers: the object returned by ``ArgumentParser.add_subparsers``.

    Returns:
        argparse.ArgumentParser: the ``fit`` parser.
    """
    p = subparsers.add_parser(
        "fit",
        help="fit scene parameters to observed rebounds",
        description=_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "files",
        nargs="+",
        metavar="[SCENE] DATA",
        help="optional scene (name or TOML file; default: the data set's own, else table1), "
        "then the observations (embedded name or CSV file)",
    )
    p.add_argument(
        "--params",
        nargs="+",
        required=True,
        metavar="NAME",
        help="parameters to fit: C_A C_H f0 friction K G_star lambda radius density",
    )
    p.add_argument(
        "-o", "--output", metavar="FIT.json", help="write the result as JSON (atomically)"
    )
    p.add_argument("--plot", metavar="FIT.png", help="plot data against the fitted model")
    p.add_argument("--starts", type=int, default=3, help="number of starts (default 3)")
    p.add_argument(
        "--spread",
        type=float,
        default=3.0,
        help="starts after the first lie up to this factor from the initial guess (default 3)",
    )
    p.add_argument("--solver", choices=("lm", "adam", "lbfgs"), default="lm")
    p.add_argument("--max-steps", type=int, default=200, help="iterations per start")
    p.add_argument(
        "--init",
        nargs="+",
        default=[],
        metavar="NAME=VALUE",
        help="starting values overriding the scene's (SI units)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the multi-start spread")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_fit)
    return p


def _parse_init(items) -> dict[str, float]:
    from ._objective import FitError

    out = {}
    for item in items:
        name, sep, text = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[name.strip()] = float(text)
        except ValueError:
            raise FitError(f"--init expects NAME=VALUE, got {item!r}") from None
    return out


def _kharaz2001():
    from ._data import kharaz2001_path

    return str(kharaz2001_path())


#: Observation data sets shipped with fitting, by name (each may have a scene of that name).
EMBEDDED_DATA = {"kharaz2001": _kharaz2001, "kharaz2001_mindlin": _kharaz2001}

#: Exit status of a fit that ran but whose result cannot be trusted (see the description).
EXIT_NOT_CONVERGED = 3


def cmd_fit(args) -> int:
    """Run ``jaximpact fit``; returns the exit status (0 converged, 3 not converged,
    undetermined or misfit).

    Raises:
        FitError, DataError, SceneError (all ``ValueError``): bad input; ``jaximpact.cli.main``
            prints the message and exits with status 2.
    """
    import jax

    # Float64 before any array exists: the simulator's tolerances and the Jacobian-based
    # uncertainty need it.
    jax.config.update("jax_enable_x64", True)

    import jaximpact
    from jaximpact._paths import check_readable, prepare_output, write_failed
    from jaximpact._scene_io import describe_scene_source

    from ._fit import fit
    from ._objective import FitError, check_names
    from ._report import plot_fit, summary, write_json

    if len(args.files) > 2:
        raise FitError(f"expected [SCENE] DATA, got {len(args.files)} files")
    scene_path, data_path = (None, args.files[0]) if len(args.files) == 1 else args.files
    if data_path in EMBEDDED_DATA:
        if scene_path is None and data_path in jaximpact.embedded_scenes():
            scene_path = data_path  # the data set's own scene
        data_path = EMBEDDED_DATA[data_path]()
    else:
        check_readable(data_path, "data file")
    names = check_names(args.params)
    scene = jaximpact.load_scene(scene_path)
    # Outputs are checked before the fit: a typo in -o must not cost the computation.
    for path, what in ((args.output, "fit JSON"), (args.plot, "plot")):
        if path:
            prepare_output(path, what)
    result = fit(
        scene,
        data_path,
        names,
        initial=_parse_init(args.init),
        solver=args.solver,
        starts=args.starts,
        spread=args.spread,
        seed=args.seed,
        max_steps=args.max_steps,
        progress=not args.no_progress,
    )
    print(f"scene: {describe_scene_source(scene_path)}")
    print(summary(result))
    for path, write in ((args.output, write_json), (args.plot, plot_fit)):
        if path:
            try:
                write(path, result)
            except OSError as err:
                raise write_failed(path, err) from None
            print(f"wrote {path}")
    if not result.converged:
        print(f"error: fit {result.message}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0

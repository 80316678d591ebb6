"""``jaximpact design``: choose the impacts to measure next (D-optimal experiment design)."""

from __future__ import annotations

import argparse
import sys

from .words import parse_pairs, split_names

__all__ = ["add_design_command", "cmd_design"]


_DESIGN_DESCRIPTION = """\
Choose N impacts from candidate rows (an impacts CSV: speed, angle_deg[, omega0]) that most
reduce the uncertainty of the named parameters: greedy D-optimal on the Fisher information
J^T S^-1 J of the observables to be measured (J: forward-mode derivatives with respect to the
log-parameters at the scene's values, or averaged in log-det over posterior draws with
--draws DRAWS.nc from fit --posterior). Default noise: 1 % of each observable's natural scale
(cor_n, cor_t: 0.01; vt_out: 1 % of the speed; omega_out: 1 % of speed/radius; rebound angle:
1 degree); --sigma sets it per observable. Candidates the model captures, or whose outcome
(rebound or capture) changes when a parameter moves by 10 %, are dropped (counted in the
report). DESIGN.csv lists the chosen rows in the order chosen, with the log-det gain of each.

Exit status: 0 written; 1 computation failed; 2 bad input (named in the message)."""


def add_design_command(subparsers) -> argparse.ArgumentParser:
    """Add the ``design`` sub-command to a ``jaximpact`` argument parser's subparsers."""
    p = subparsers.add_parser(
        "design",
        help="choose the impacts to measure next (D-optimal experiment design)",
        description=_DESIGN_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scene", nargs="?", default=None, help="scene name or TOML (default table1)")
    p.add_argument(
        "--params",
        nargs="+",
        required=True,
        metavar="NAME",
        help="parameters to determine, as a comma list (C_A,f0) or separate words (then put "
        "SCENE before --params)",
    )
    p.add_argument("--candidates", required=True, metavar="CAND.csv")
    p.add_argument("--n", type=int, required=True, help="impacts to choose")
    p.add_argument("--observables", nargs="+", default=["cor_n"], metavar="NAME")
    p.add_argument("--sigma", nargs="+", default=[], metavar="OBSERVABLE=SIGMA")
    p.add_argument(
        "--draws",
        metavar="DRAWS.nc",
        help="posterior draws (written by fit --posterior --draws): design for the mean "
        "log-det over them instead of at the scene's values",
    )
    p.add_argument("--max-draws", type=int, default=20, help="draws used (default 20)")
    p.add_argument("-o", "--output", required=True, metavar="DESIGN.csv")
    p.set_defaults(func=cmd_design)
    return p


def cmd_design(args) -> int:
    """Run ``jaximpact design``; returns 0 (bad input raises a ``ValueError``: exit 2)."""
    import jax

    jax.config.update("jax_enable_x64", True)

    import jaximpact
    from jaximpact._io.paths import check_readable, prepare_output, write_failed

    from .._bayesian.report import read_draws
    from .._data import OBSERVABLES
    from .._design import design, write_design
    from .._least_squares.objective import FITTABLE, FitError, check_names

    names = check_names(split_names("--params", args.params, FITTABLE, "design"))
    sigma = parse_pairs(args.sigma, "--sigma", "OBSERVABLE=SIGMA", "design")
    if args.n < 1:
        raise FitError(f"--n must be an integer >= 1, got {args.n}")
    if args.max_draws < 1:
        raise FitError(f"--max-draws must be an integer >= 1, got {args.max_draws}")
    check_readable(args.candidates, "candidates file")
    draws = read_draws(args.draws, names) if args.draws else None
    prepare_output(args.output, "design CSV")
    scene = jaximpact.load_scene(args.scene)
    result = design(
        scene,
        args.candidates,
        names,
        args.n,
        observables=split_names("--observables", args.observables, OBSERVABLES, "design"),
        sigma=sigma,
        draws=draws,
        max_draws=args.max_draws,
    )
    print(result.message())
    for warning in result.warnings():
        print(f"warning: {warning}", file=sys.stderr)
    for k, i in enumerate(result.chosen):
        t = result.candidates
        print(
            f"  {k + 1:3d}: speed {t.speed[i]:.4g} m/s, angle {t.angle_deg[i]:.4g} deg, "
            f"omega0 {t.omega0[i]:.4g} rad/s; gain {result.gain[k]:.3g}"
        )
    try:
        write_design(args.output, result)
    except OSError as err:
        raise write_failed(args.output, err) from None
    print(f"wrote {args.output}")
    return 0

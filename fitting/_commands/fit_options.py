"""The options of ``jaximpact fit``: its description, arguments and option groups."""

from __future__ import annotations

import argparse

__all__ = ["EXIT_NOT_CONVERGED", "LOO_REFITS", "fit_parser"]

_DESCRIPTION = """\
Fit scene parameters to observed rebounds by weighted least squares, with standard errors
from the Jacobian at the optimum. SCENE is an embedded scene name (`jaximpact scenes`) or a
TOML file; DATA an embedded data set name or a CSV file (wide or long form; README, "Fit
data"). With one positional argument it is the data: an embedded data set brings its own
scene (`jaximpact fit kharaz2001 --params friction`), a file uses the embedded table1 scene.
Embedded data: kharaz2001 (Kharaz, Gorham & Salman 2001: 5 mm alumina spheres on glass at
3.9 m/s, 0-60 degrees; cor_t, omega_out, rebound_angle_deg); kharaz2001_mindlin: the same
data with the scene of that name (tangential compliance: `--params friction G_star`);
kharaz2001_lammps: the same data with LAMMPS's contact model (Hertz, Tsuji's damping, LAMMPS's
mindlin history spring: `--params friction G_star`, then `jaximpact export lammps`).

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

#: Exit status of a fit that ran but whose result cannot be trusted (see the description).
EXIT_NOT_CONVERGED = 3
#: ``--loo-refits``'s default: fitting._bayesian.loo.MAX_REFITS (not imported here: JAX).
LOO_REFITS = 10


def fit_parser(subparsers) -> argparse.ArgumentParser:
    """The ``fit`` sub-command's parser, added to a ``jaximpact`` argument parser's
    subparsers (``fitting.cli.add_fit_command`` sets the function it runs).

    Arguments:
        subparsers: the object returned by ``ArgumentParser.add_subparsers``.

    Returns:
        argparse.ArgumentParser: the ``fit`` parser.
    """
    from jaximpact.parameters import FITTABLE

    p = subparsers.add_parser(
        "fit",
        help="fit scene parameters to observed rebounds",
        description=_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "files",
        nargs="*",
        metavar="[SCENE] DATA",
        help="optional scene (name or TOML file; default: the data set's own, else table1), "
        "then the observations (embedded name or CSV file); give them before the options",
    )
    p.add_argument(
        "--params",
        nargs="+",
        required=True,
        metavar="NAME",
        help="parameters to fit, as a comma list (friction,G_star) or separate words "
        "(friction G_star: then put [SCENE] DATA before --params, which takes every word up to "
        "the next option); from " + " ".join(FITTABLE),
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
    _add_compare_options(_add_posterior_options(p))
    _add_profile_options(p)
    return p


def _add_posterior_options(p):
    """The option group of ``fit`` for the posterior; returns it (for the ``--compare``
    options, :func:`_add_compare_options`)."""
    g = p.add_argument_group(
        "posterior (docs/posterior.md)",
        "--posterior samples the Bayesian posterior after the fit (sequential Monte Carlo by "
        "default; --chains: independent populations, --samples: particles each). Exit 3 when "
        "an R-hat exceeds 1.01, a bulk or tail ESS is below 400, a transition diverged or a "
        "proposal misses part of the posterior.",
    )
    g.add_argument("--posterior", action="store_true", help="sample the posterior")
    g.add_argument(
        "--prior",
        nargs="+",
        default=[],
        metavar="NAME=SPEC",
        help="prior of a parameter: NAME=loguniform:LO:HI or NAME=normal:MU:SD (SI units); "
        "default log-uniform over a physical range (docs/posterior.md)",
    )
    g.add_argument("--likelihood", choices=("gaussian", "student-t"), default="gaussian")
    g.add_argument("--nu", type=float, default=4.0, help="Student-t degrees of freedom (4)")
    g.add_argument(
        "--noise",
        choices=("auto", "integrated", "sampled"),
        default="auto",
        help="noise factors of observables without sigmas: auto (default) integrates them out "
        "in closed form with the Gaussian likelihood (drawn afterwards from their exact "
        "conditional) and samples them with student-t; integrated or sampled forces one",
    )
    g.add_argument("--chains", type=int, default=4, help="number of chains (default 4)")
    g.add_argument("--samples", type=int, default=1000, help="draws per chain (default 1000)")
    g.add_argument("--warmup", type=int, default=300, help="warm-up steps per chain (default 300)")
    g.add_argument(
        "--sampler",
        choices=("auto", "smc", "independence", "hmc"),
        default="auto",
        help="auto (default) = smc: tempered sequential Monte Carlo from the fit's t (where it "
        "covers the posterior) or the prior, in independent populations; independence: "
        "independence Metropolis on a t proposal (nearly Gaussian posteriors); hmc: HMC",
    )
    g.add_argument(
        "--moves",
        choices=("values", "mala"),
        default="values",
        help="SMC's local moves: values (default: a random walk) or mala (Langevin steps along "
        "the log density's gradient: a second compiled program, several times a value's cost "
        "per evaluation; docs/posterior.md)",
    )
    g.add_argument("--draws", metavar="FILE.nc", help="write the draws (ArviZ InferenceData)")
    g.add_argument("--corner", metavar="FILE.png", help="corner plot of the draws")
    g.add_argument(
        "--predictive", metavar="FILE.png", help="data against the posterior predictive band"
    )
    return g


def _add_compare_options(g) -> None:
    """The options of ``fit --compare``, in the posterior's option group ``g``."""
    g.add_argument(
        "--compare",
        nargs="+",
        default=[],
        metavar="SCENE[=PARAMS]",
        help="also fit and sample each of these scenes (embedded name or TOML file) on the same "
        "data with the same options, then compare all the models by PSIS-LOO (ArviZ; exact "
        "refits where its Pareto k exceeds 0.7, see --loo-refits); "
        "=PARAMS: that scene's own fitted parameters as a comma list (default: --params); "
        "a normal law (brach_dunn, dmt, jkr; a comma list) is the scene with that law, f0 and "
        "w swapped in the fitted names (thornton_ning needs its own scene file: its p_y)",
    )
    g.add_argument(
        "--compare-plot", metavar="FILE.png", help="each compared model's band against the data"
    )
    g.add_argument(
        "--loo-refits",
        type=int,
        metavar="N",
        help="with --compare: in each model, up to N observations (highest Pareto k first) "
        "whose PSIS-LOO estimate is unreliable (k > 0.7) get their exact leave-one-out term: "
        "the posterior sampled again without the observation, each refit costing about as much "
        f"as the model's posterior (default {LOO_REFITS}; 0: PSIS-LOO only)",
    )


def _add_profile_options(p) -> None:
    """The option group of ``fit`` for the profile likelihood."""
    g = p.add_argument_group("profile likelihood")
    g.add_argument(
        "--profile",
        metavar="NAME",
        help="profile likelihood of one fitted parameter: the others re-fitted along a grid",
    )
    g.add_argument("--profile-points", type=int, default=15, help="grid points (default 15)")
    g.add_argument("--profile-plot", metavar="FILE.png", help="plot of the profile")

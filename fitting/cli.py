"""``jaximpact fit``: fit scene parameters to observed rebounds from the command line."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

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
        "the next option); from C_A C_H f0 friction K G_star w p_y lambda radius density",
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
    _add_posterior_options(p)
    p.set_defaults(func=cmd_fit)
    return p


def _add_posterior_options(p) -> None:
    """The option groups of ``fit`` for the posterior and the profile likelihood."""
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
    g = p.add_argument_group("profile likelihood")
    g.add_argument(
        "--profile",
        metavar="NAME",
        help="profile likelihood of one fitted parameter: the others re-fitted along a grid",
    )
    g.add_argument("--profile-points", type=int, default=15, help="grid points (default 15)")
    g.add_argument("--profile-plot", metavar="FILE.png", help="plot of the profile")


def _parse_init(items) -> dict[str, float]:
    from ._least_squares.objective import FitError

    out = {}
    for item in items:
        name, sep, text = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[name.strip()] = float(text)
        except ValueError:
            raise FitError(
                f"--init expects NAME=VALUE, got {item!r}{_swallowed('--init', item)}"
            ) from None
    return out


def _looks_positional(item: str) -> bool:
    """Whether a word an option took looks like a SCENE or DATA argument instead."""
    import os

    import jaximpact

    return (
        item in EMBEDDED_DATA
        or item in jaximpact.embedded_scenes()
        or item.lower().endswith((".csv", ".toml"))
        or os.path.exists(item)
    )


def _swallowed(option: str, item: str, command: str = "fit") -> str:
    """A hint for an option that took a positional argument as one of its words, or ``""``."""
    if not _looks_positional(item):
        return ""
    first = "the scene and data" if command == "fit" else "the scene"
    return (
        f" ({item!r} looks like an argument: {option} takes every word up to the next option; "
        f"give {first} before the options)"
    )


def split_names(option: str, items, allowed, command: str = "fit") -> tuple[str, ...]:
    """The names an option was given, as separate words or comma lists (``a,b c``).

    Raises:
        FitError: a name not in ``allowed``; where it looks like the scene or data argument
            (the option took every word up to the next option), the message says how to give
            them.
    """
    from ._least_squares.objective import FitError

    names = tuple(n.strip() for item in items for n in str(item).split(",") if n.strip())
    for name in names:
        if name not in allowed and _looks_positional(name):
            first, example = (
                ("the scene and data", "jaximpact fit kharaz2001 --params friction,G_star")
                if command == "fit"
                else ("the scene", "jaximpact design table1 --params C_A,f0 --candidates C.csv")
            )
            raise FitError(
                f"{option}: {name!r} is not a name of {option} but was read as one ({option} "
                f"takes every word up to the next option); give {first} before the options, "
                f"or the names as one comma list: `{example}`"
            )
    return names


def _kharaz2001():
    from ._data import kharaz2001_path

    return str(kharaz2001_path())


#: Observation data sets shipped with fitting, by name (each may have a scene of that name).
EMBEDDED_DATA = {"kharaz2001": _kharaz2001, "kharaz2001_mindlin": _kharaz2001}

#: Exit status of a fit that ran but whose result cannot be trusted (see the description).
EXIT_NOT_CONVERGED = 3
#: ``--loo-refits``'s default: fitting._bayesian.loo.MAX_REFITS (not imported here: JAX).
LOO_REFITS = 10


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
    from jaximpact._io.scene_files import describe_scene_source

    from ._least_squares.objective import FITTABLE, FitError, check_names
    from ._least_squares.report import (
        plot_fit,
        result_dict,
        summary,
        write_json_dict,
    )

    params = split_names("--params", args.params, FITTABLE)
    scene_path, data_path = _fit_files(args)
    names = check_names(params)
    # With --compare a prior may be for a parameter only another model fits (checked below).
    own = [p for p in args.prior if not args.compare or p.partition("=")[0].strip() in names]
    priors = _parse_priors(own, names) if args.posterior else {}
    posterior_outputs = (
        (args.draws, "draws file"),
        (args.corner, "corner plot"),
        (args.predictive, "predictive plot"),
        (args.compare_plot, "comparison plot"),
    )
    _check_fit_options(args, names, posterior_outputs)
    scene = jaximpact.load_scene(scene_path)
    alternatives = _compared_models(args, names, scene_path)
    fitted = set(names).union(*(set(m[1]) for m in alternatives.values()))
    for spec in args.prior:
        name = spec.partition("=")[0].strip()
        if args.compare and name not in fitted:
            raise FitError(f"--prior {name}: not among the fitted parameters of any model")
    if args.posterior:  # a bad prior in the scene's [priors] must not cost the fit either
        from ._bayesian.priors import priors_for

        priors_for(names, priors, scene.priors)
    _check_fit_outputs(args, posterior_outputs)
    progress = not args.no_progress
    result = _run_fit(args, scene, data_path, names, _parse_init(args.init))
    print(f"scene: {describe_scene_source(scene_path)}")
    print(summary(result))
    document = result_dict(result)
    drawn = lambda what, draw: _drawn(what, draw, progress)  # noqa: E731
    outputs = [(args.plot, drawn("the fitted model", lambda path: plot_fit(path, result)))]
    failed = [] if result.converged else [f"fit {result.message}"]
    if args.profile is not None and result.converged:
        outputs.append(_fit_profile(args, result, document, drawn, progress))
    # The posterior is the answer where the data leave a parameter undetermined (the
    # least-squares uncertainty is undefined there, the posterior's is not).
    sampled = result.converged or result.status == "undetermined"
    if args.posterior and sampled:
        post = _fit_posterior(args, scene, names, priors, result, document, outputs, drawn)
        if not post.converged:
            failed.append(f"posterior {post.message}")
        elif result.status == "undetermined":
            failed.remove(f"fit {result.message}")
            print(
                "the least-squares uncertainty is undefined (the data leave a parameter open); "
                "the posterior describes it",
                file=sys.stderr,
            )
        if alternatives:
            label = scene_path or "table1"
            failed += _fit_compare(args, {label: post}, alternatives, data_path, document,
                                   outputs, drawn)  # fmt: skip
    if (args.posterior and not sampled) or (args.profile and not result.converged):
        print(
            "the least-squares fit did not converge: no "
            + ("posterior or profile" if args.posterior and args.profile else
               "posterior" if args.posterior else "profile"),
            file=sys.stderr,
        )  # fmt: skip
    outputs.insert(0, (args.output, lambda path: write_json_dict(path, document)))
    _write_outputs(outputs)
    if failed:
        for reason in failed:
            print(f"error: {reason}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0


def _fit_files(args) -> tuple:
    """``[SCENE] DATA`` of ``jaximpact fit``: the scene path (``None``: the default, or an
    embedded data set's own scene) and the data file, checked readable."""
    import jaximpact
    from jaximpact._io.paths import FileProblem, check_readable

    from ._least_squares.objective import FitError

    if not args.files:
        for option, items in (("--init", args.init), ("--prior", args.prior)):
            for item in items:
                if _swallowed(option, item):
                    raise FitError(f"missing DATA{_swallowed(option, item)}")
        raise FitError(
            "missing DATA: jaximpact fit [SCENE] DATA --params NAME[,NAME...] (the data: an "
            f"embedded data set, {', '.join(EMBEDDED_DATA)}, or a CSV file)"
        )
    if len(args.files) > 2:
        raise FitError(
            f"expected [SCENE] DATA, got {len(args.files)} arguments: " + " ".join(args.files)
        )
    scene_path, data_path = (None, args.files[0]) if len(args.files) == 1 else args.files
    if data_path in EMBEDDED_DATA:
        if scene_path is None and data_path in jaximpact.embedded_scenes():
            scene_path = data_path  # the data set's own scene
        data_path = EMBEDDED_DATA[data_path]()
    else:
        try:
            check_readable(data_path, "data file")
        except FileProblem as err:
            if "not found" not in str(err):
                raise
            raise FileProblem(
                data_path,
                "data file not found (embedded data sets, by name: "
                + ", ".join(EMBEDDED_DATA)
                + ")",
            ) from None
    return scene_path, data_path


def _check_fit_options(args, names, posterior_outputs) -> None:
    """The options of ``jaximpact fit`` that must agree with each other (``FitError``)."""
    from ._least_squares.objective import FitError

    if not args.posterior:
        for option, (path, _) in zip(
            ("--draws", "--corner", "--predictive", "--compare-plot"), posterior_outputs,
            strict=True,
        ):  # fmt: skip
            if path:
                raise FitError(f"{option} needs --posterior")
        if args.prior:
            raise FitError("--prior needs --posterior")
        if args.compare:
            raise FitError("--compare needs --posterior (models are compared by their posteriors)")
    if args.compare_plot and not args.compare:
        raise FitError("--compare-plot needs --compare")
    if args.loo_refits is not None and not args.compare:
        raise FitError("--loo-refits needs --compare")
    if args.loo_refits is not None and args.loo_refits < 0:
        raise FitError(f"--loo-refits must be an integer >= 0, got {args.loo_refits}")
    for label, value, least in (
        ("--chains", args.chains, 1),
        ("--samples", args.samples, 4),
        ("--warmup", args.warmup, 1),
        ("--profile-points", args.profile_points, 3),
    ):
        if value < least:
            raise FitError(f"{label} must be an integer >= {least}, got {value}")
    if not args.nu > 0:
        raise FitError(f"--nu must be > 0, got {args.nu}")
    if args.noise == "integrated" and args.likelihood != "gaussian":
        raise FitError(
            "--noise integrated needs --likelihood gaussian (the Student-t likelihood has no "
            "closed-form integral over its noise factors)"
        )
    if args.profile is not None and args.profile not in names:
        raise FitError(f"--profile {args.profile}: not among the fitted --params {list(names)}")
    if args.profile_plot and args.profile is None:
        raise FitError("--profile-plot needs --profile NAME")
    if args.draws or args.compare:
        from ._bayesian.report import import_arviz

        import_arviz("--draws" if args.draws else "--compare")


def _check_fit_outputs(args, posterior_outputs) -> None:
    """Outputs are checked before the fit: a typo in -o must not cost the computation."""
    from jaximpact._io.paths import prepare_output

    from ._least_squares.report import check_plot_path

    for option, path in (
        ("--plot", args.plot),
        ("--profile-plot", args.profile_plot),
        ("--corner", args.corner),
        ("--predictive", args.predictive),
        ("--compare-plot", args.compare_plot),
    ):
        if path:
            check_plot_path(path, option)
    for path, what in (
        (args.output, "fit JSON"),
        (args.plot, "plot"),
        (args.profile_plot, "profile plot"),
        *posterior_outputs,
    ):
        if path is not None:  # an empty path is refused, not ignored
            prepare_output(path, what)


def _fit_profile(args, result, document, drawn, progress) -> tuple:
    """``--profile NAME``: the profile, printed and added to ``document``; its plot output."""
    from ._least_squares.profile import plot_profile, profile, profile_summary

    prof = profile(result, args.profile, points=args.profile_points, progress=progress)
    print(profile_summary(prof))
    document["profile"] = prof.as_dict()
    return (args.profile_plot, drawn("the profile", lambda path: plot_profile(path, prof)))


def _fit_posterior(args, scene, names, priors, result, document, outputs, drawn):
    """``--posterior``: the posterior, printed and added to ``document``, its outputs added to
    ``outputs``; returns it."""
    from ._bayesian.report import (
        add_to_result_dict,
        plot_corner,
        plot_predictive,
        posterior_summary,
        write_draws,
    )

    post = _sample(args, scene, names, priors, result)
    print(posterior_summary(post))
    add_to_result_dict(document, post)
    outputs += [
        (args.draws, lambda path: write_draws(path, post)),
        (args.corner, drawn("the posterior draws", lambda path: plot_corner(path, post))),
        (
            args.predictive,
            drawn("the posterior predictive", lambda path: plot_predictive(path, post)),
        ),
    ]
    return post


def _run_fit(args, scene, data_path, names, initial):
    """The least-squares fit with the command's options."""
    from ._least_squares.fit import fit

    return fit(
        scene, data_path, names, initial=initial, solver=args.solver, starts=args.starts,
        spread=args.spread, seed=args.seed, max_steps=args.max_steps,
        progress=not args.no_progress,
    )  # fmt: skip


def _sample(args, scene, names, priors, result):
    """The posterior after the fit ``result``, with the command's options."""
    from ._bayesian.posterior import sample_posterior

    return sample_posterior(
        scene, result.objective.observations, names, priors=priors,
        likelihood=args.likelihood, nu=args.nu, chains=args.chains, draws=args.samples,
        warmup=args.warmup, seed=args.seed, fit_result=result, sampler=args.sampler,
        progress=not args.no_progress, noise=args.noise, moves=args.moves,
    )  # fmt: skip


def _embedded_scene_names() -> list[str]:
    """The scenes embedded in the package, by name."""
    from jaximpact._io.scene_files import embedded_scenes

    return list(embedded_scenes())


def _compared_models(args, names, scene_path) -> dict:
    """``--compare``: ``{label: (scene, fitted names, priors)}`` of each other model, every
    scene read and every name checked before any computing (bad input: ``ValueError``).

    An item that names a normal law (``brach_dunn``, ``dmt``, ``jkr``; several may be given as
    one comma list) is the fitted scene with that law (``Scene.with_normal_law``) and the fitted
    names carried over (:func:`_law_names`); the fitted scene's own law is not fitted twice."""
    import jaximpact
    from jaximpact._model.scene import NORMAL_LAWS

    from ._bayesian.priors import PRIOR_RANGES, priors_for
    from ._least_squares.objective import FITTABLE, FitError, check_names

    items = []
    for item in args.compare:
        if "=" not in item and "," in item:
            items += [x.strip() for x in item.split(",") if x.strip()]
        else:
            items.append(item)
    base = None
    out = {}
    for item in items:
        label, sep, own = item.partition("=")
        label = label.strip()
        if not label:
            raise FitError(f"--compare expects SCENE or SCENE=NAME[,NAME...], got {item!r}")
        law = label in NORMAL_LAWS and not Path(label).exists()
        if law and label == "thornton_ning":
            raise FitError(
                "--compare thornton_ning: a law swap cannot choose the Thornton-Ning law's "
                "limiting pressure contact.p_y (and its w > 0): give a scene file with "
                'model.normal = "thornton_ning" instead'
            )
        if not law and not Path(label).exists() and label not in _embedded_scene_names():
            raise FitError(
                f"--compare {label}: not a scene file, an embedded scene "
                f"({', '.join(_embedded_scene_names())}) or a normal law "
                f"({', '.join(n for n in NORMAL_LAWS if n != 'thornton_ning')})"
            )
        if law:
            base = base or jaximpact.load_scene(scene_path)
            if label == base.model.normal:
                continue  # the fitted scene is that law
        if label in out or label == (scene_path or "table1"):
            raise FitError(f"--compare {label}: the same model twice")
        try:
            if sep:
                model_names = check_names(split_names("--compare", [own], FITTABLE))
            else:
                model_names = _law_names(names, base.model.normal, label) if law else names
        except FitError as err:
            raise FitError(f"--compare {item}: {err}") from None
        scene = base.with_normal_law(label) if law else jaximpact.load_scene(label)
        strength = "f0" if law and label == "brach_dunn" else "w"
        if law and strength not in model_names and not float(getattr(scene.contact, strength)) > 0:
            raise FitError(
                f"--compare {label}: this scene has no adhesion ({strength} = 0 after the swap, "
                f"not fitted), and without adhesion the {label} law is the same model as the "
                f"scene's own ({base.model.normal}): fit {strength} too ({label}=NAME,...,"
                f"{strength}) or compare scenes that differ"
            )
        if law and "w" in model_names and not float(scene.contact.w) > 0:
            # a scene without adhesion: w starts at its default prior's centre (0.1 J/m^2)
            lo, hi = PRIOR_RANGES["w"]
            scene = scene.replace(contact={"w": math.sqrt(lo * hi)}, model={"adhesion": True})
        check_names(model_names, scene)
        # --prior applies to each model that fits that parameter
        priors = _parse_priors(
            [p for p in args.prior if p.partition("=")[0].strip() in model_names], model_names
        )
        priors_for(model_names, priors, scene.priors)
        out[label] = (scene, model_names, priors)
    return out


def _law_names(names, law, other) -> tuple:
    """The fitted names of one normal law carried to another: ``f0`` and ``w`` swap; ``C_A``
    (the ring's damping) is dropped for DMT and JKR, and fitted with Brach-Dunn's ``f0`` when
    the adhesion was fitted."""
    out = []
    for name in names:
        if name == "f0" and other != "brach_dunn":
            out.append("w")
        elif name == "w" and other == "brach_dunn":
            out += ["f0"] + ([] if "C_A" in names else ["C_A"])
        elif name == "C_A" and other != "brach_dunn":
            continue
        else:
            out.append(name)
    return tuple(dict.fromkeys(out))


def _fit_compare(args, posteriors, alternatives, data_path, document, outputs, drawn) -> list:
    """``--compare``: fit and sample each other model, compare all by PSIS-LOO (printed and
    in ``document["comparison"]``); returns the reasons for exit status 3 (a model whose fit
    or posterior did not converge; the comparison leaves out a model it could not sample)."""
    from ._bayesian.loo import compare_models, refit_without
    from ._bayesian.report import (
        add_to_result_dict,
        comparison_summary,
        plot_comparison,
        posterior_summary,
    )
    from ._least_squares.report import result_dict, summary

    failed, models = [], {}
    init = _parse_init(args.init)
    for label, (scene, model_names, priors) in alternatives.items():
        print(f"\n== model {label}: {', '.join(model_names)} ==")
        own_init = {k: v for k, v in init.items() if k in model_names}
        result = _run_fit(args, scene, data_path, model_names, own_init)
        print(summary(result))
        entry = result_dict(result)
        models[label] = entry
        if not (result.converged or result.status == "undetermined"):
            failed.append(f"{label}: fit {result.message} (left out of the comparison)")
            continue
        post = _sample(args, scene, model_names, priors, result)
        print(posterior_summary(post))
        add_to_result_dict(entry, post)
        if not post.converged:
            failed.append(f"{label}: posterior {post.message}")
        posteriors[label] = post
    refits = LOO_REFITS if args.loo_refits is None else args.loo_refits
    progress = not args.no_progress

    def refit(name, i):
        return refit_without(posteriors[name], i, progress=progress)

    def announce(name, i, n, total):
        print(f"refitting model {name} without observation {i + 1} ({n} of {total}): its "
              "exact leave-one-out term (PSIS's Pareto k above 0.7)", file=sys.stderr)  # fmt: skip

    rows = []
    if len(posteriors) > 1:
        rows = compare_models(
            posteriors, refit=refit if refits else False, max_refits=refits, announce=announce
        )
    if rows:
        print("\n" + comparison_summary(rows))
    else:
        print("\nno comparison: fewer than two models were sampled", file=sys.stderr)
    document["comparison"] = {"models": models, "loo": rows}
    outputs.append(
        (args.compare_plot,
         drawn("the compared models", lambda path: plot_comparison(path, posteriors)))
    )  # fmt: skip
    return failed


def _write_outputs(outputs) -> None:
    """Each ``(path, write)`` with a path: written, and said so (a failure names the path)."""
    from jaximpact._io.paths import write_failed

    for path, write in outputs:
        if path is not None:
            try:
                write(path)
            except OSError as err:
                raise write_failed(path, err) from None
            print(f"wrote {path}")


def _drawn(what: str, draw, progress: bool):
    """``draw(path)``, saying on stderr (one line) what it draws and how long it took: a plot
    of the model simulates it again (seconds, mostly compiling), which would otherwise look
    like a hang after the report."""

    def write(path):
        if not progress:
            return draw(path)
        print(f"drawing {path} ({what}) ...", end="", file=sys.stderr, flush=True)
        start = time.perf_counter()
        try:
            draw(path)
        except BaseException:
            print(" failed", file=sys.stderr, flush=True)
            raise
        print(f" {time.perf_counter() - start:.1f} s", file=sys.stderr, flush=True)

    return write


def _parse_priors(items, names) -> dict:
    """``NAME=SPEC`` items -> ``{name: Prior}`` (bad input: a `FitError` naming the field)."""
    from ._bayesian.priors import parse_prior
    from ._least_squares.objective import FitError

    out = {}
    for item in items:
        name, sep, spec = item.partition("=")
        name = name.strip()
        if not sep:
            raise FitError(
                f"--prior expects NAME=loguniform:LO:HI or NAME=normal:MU:SD, got {item!r}"
                + _swallowed("--prior", item)
            )
        if name not in names:
            raise FitError(f"--prior {name}: not among the fitted --params {list(names)}")
        out[name] = parse_prior(name, spec)
    return out


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

    from ._bayesian.report import read_draws
    from ._data import OBSERVABLES
    from ._design import design, write_design
    from ._least_squares.objective import FITTABLE, FitError, check_names

    names = check_names(split_names("--params", args.params, FITTABLE, "design"))
    sigma = {}
    for item in args.sigma:
        name, sep, text = item.partition("=")
        try:
            if not sep:
                raise ValueError
            sigma[name.strip()] = float(text)
        except ValueError:
            raise FitError(
                f"--sigma expects OBSERVABLE=SIGMA, got {item!r}"
                + _swallowed("--sigma", item, "design")
            ) from None
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

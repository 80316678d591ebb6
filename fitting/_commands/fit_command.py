"""``jaximpact fit``: the command, and the checks of its inputs before anything is computed."""

from __future__ import annotations

import argparse
import sys

from .compare import _compared_models, _fit_compare
from .fit_options import EXIT_NOT_CONVERGED, fit_parser
from .fit_steps import (
    _drawn,
    _fit_posterior,
    _fit_profile,
    _prepare_posterior,
    _run_fit,
    _scene_record,
    _write_outputs,
)
from .words import EMBEDDED_DATA, _parse_init, _parse_priors, _swallowed, split_names

__all__ = ["add_fit_command", "cmd_fit"]


def add_fit_command(subparsers) -> argparse.ArgumentParser:
    """Add the ``fit`` sub-command to a ``jaximpact`` argument parser's subparsers.

    Arguments:
        subparsers: the object returned by ``ArgumentParser.add_subparsers``.

    Returns:
        argparse.ArgumentParser: the ``fit`` parser.
    """
    p = fit_parser(subparsers)
    p.set_defaults(func=cmd_fit)
    return p


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

    from jaximpact._io.scene_files import describe_scene_source

    from .._least_squares.report import (
        plot_fit,
        result_dict,
        summary,
        write_json_dict,
    )

    scene_path, data_path, names, priors, scene, alternatives = _fit_inputs(args)
    scene_record = _scene_record(scene_path)  # its text as loaded, before the fit
    progress = not args.no_progress
    if args.posterior:  # the sampler's program compiles while the fit runs
        _prepare_posterior(args, scene, data_path, names, priors)
    result = _run_fit(args, scene, data_path, names, _parse_init(args.init))
    print(f"scene: {describe_scene_source(scene_path)}")
    print(summary(result))
    document = result_dict(result)
    document["scene"] = scene_record  # what `jaximpact export` rebuilds the scene from
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


def _fit_inputs(args) -> tuple:
    """Every input of ``jaximpact fit`` read and checked before anything is computed (bad
    input: a ``ValueError`` naming it): ``(scene_path, data_path, names, priors, scene,
    alternatives)``, the last the other models of ``--compare``."""
    import jaximpact

    from .._least_squares.objective import FITTABLE, FitError, check_names

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
        from .._bayesian.priors import priors_for

        priors_for(names, priors, scene.priors, scene.model.damping)
    _check_fit_outputs(args, posterior_outputs)
    return scene_path, data_path, names, priors, scene, alternatives


def _fit_files(args) -> tuple:
    """``[SCENE] DATA`` of ``jaximpact fit``: the scene path (``None``: the default, or an
    embedded data set's own scene) and the data file, checked readable."""
    import jaximpact
    from jaximpact._io.paths import FileProblem, check_readable

    from .._least_squares.objective import FitError

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
    from .._least_squares.objective import FitError

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
        from .._bayesian.report import import_arviz

        import_arviz("--draws" if args.draws else "--compare")


def _check_fit_outputs(args, posterior_outputs) -> None:
    """Outputs are checked before the fit: a typo in -o must not cost the computation."""
    from jaximpact._io.paths import prepare_output

    from .._least_squares.report import check_plot_path

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

"""The steps of ``jaximpact fit`` after its inputs are checked: the fit, the profile and the
posterior with the command's options, and the writing of their outputs."""

from __future__ import annotations

import sys
import time


def _fit_profile(args, result, document, drawn, progress) -> tuple:
    """``--profile NAME``: the profile, printed and added to ``document``; its plot output."""
    from .._least_squares.profile import plot_profile, profile, profile_summary

    prof = profile(result, args.profile, points=args.profile_points, progress=progress)
    print(profile_summary(prof))
    document["profile"] = prof.as_dict()
    return (args.profile_plot, drawn("the profile", lambda path: plot_profile(path, prof)))


def _fit_posterior(args, scene, names, priors, result, document, outputs, drawn):
    """``--posterior``: the posterior, printed and added to ``document``, its outputs added to
    ``outputs``; returns it."""
    from .._bayesian.report import (
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
    from .._least_squares.fit import fit

    return fit(
        scene, data_path, names, initial=initial, solver=args.solver, starts=args.starts,
        spread=args.spread, seed=args.seed, max_steps=args.max_steps,
        progress=not args.no_progress,
    )  # fmt: skip


def _prepare_posterior(args, scene, data_path, names, priors) -> None:
    """``--posterior`` with SMC: its program compiled in a background thread while the fit
    runs (``fitting._bayesian.posterior.prepare_posterior``)."""
    if args.sampler not in ("smc", "auto"):
        return
    from .._bayesian.posterior import prepare_posterior

    prepare_posterior(
        scene, data_path, names, priors=priors, likelihood=args.likelihood, nu=args.nu,
        draws=args.samples, noise=args.noise, moves=args.moves,
    )  # fmt: skip


def _sample(args, scene, names, priors, result):
    """The posterior after the fit ``result``, with the command's options."""
    from .._bayesian.posterior import sample_posterior

    return sample_posterior(
        scene, result.objective.observations, names, priors=priors,
        likelihood=args.likelihood, nu=args.nu, chains=args.chains, draws=args.samples,
        warmup=args.warmup, seed=args.seed, fit_result=result, sampler=args.sampler,
        progress=not args.no_progress, noise=args.noise, moves=args.moves,
    )  # fmt: skip


def _scene_record(scene_path) -> dict:
    """The fit JSON's ``scene``: the scene the fit started from, as given (``source``: an
    embedded name, or the file as the user wrote it; ``embedded``: whether it is a name) and
    its TOML text (``toml``), so that the JSON alone rebuilds the fitted scene (``jaximpact
    export lammps``) after the file has moved or changed. The fitted values are not in the
    text: they are ``params[NAME].value``."""
    from jaximpact._io.scene_files import embedded_scenes
    from jaximpact._io.scene_files import scene_path as path_of

    name = "table1" if scene_path is None else str(scene_path)
    embedded = isinstance(scene_path, (str, type(None))) and name in embedded_scenes()
    text = path_of(scene_path).read_text(encoding="utf-8")
    return {"source": name, "embedded": embedded, "toml": text}


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

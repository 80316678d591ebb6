"""``jaximpact fit --compare``: the other models, read and checked before any computing, then
fitted, sampled and compared with the first by PSIS-LOO."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from .fit_options import LOO_REFITS
from .fit_steps import _run_fit, _sample
from .words import _parse_init, _parse_priors, split_names


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

    from .._bayesian.priors import PRIOR_RANGES, priors_for
    from .._least_squares.objective import FITTABLE, FitError, check_names

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
        priors_for(model_names, priors, scene.priors, scene.model.damping)
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
    from .._bayesian.loo import compare_models, refit_without
    from .._bayesian.report import (
        add_to_result_dict,
        comparison_summary,
        plot_comparison,
        posterior_summary,
    )
    from .._least_squares.report import result_dict, summary

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

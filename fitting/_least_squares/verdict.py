"""The verdict on a fit's best start: its status, the problems behind it and the warnings.

A fit is reported ``converged`` only if the optimizer converged, no impact failed, the
uncertainty is defined (full rank, finite standard errors) and the model describes the data
(``diagnose``: the misfit test); otherwise its ``status`` says which, and ``problems`` says why.
"""

from __future__ import annotations

import numpy as np

import jaximpact
from jaximpact._model.ranges import IMPLAUSIBLE, RANGES, implausible

from .objective import Objective
from .results import distinct_minima
from .transforms import BOUNDS


def _verdict(objective, names, theta, runs, status, d, starts) -> tuple:
    """The fit's status name, its problems and warnings, and the values for its scene (a
    value outside its documented range replaced by the nearest inside)."""
    best = runs[0][0]
    n_failed = int(np.sum(status >= jaximpact.Status.MAX_STEPS))
    warnings, problems = list(d["warnings"]), []
    if not best.converged:
        problems.append(f"the optimizer did not converge: {best.message}")
    if n_failed:
        problems.append(f"{n_failed} impact(s) failed to simulate at the final values")
    problems.extend(d["undetermined"])
    problems.extend(d["misfit"])
    n_captured = _capture_mismatch(objective, status)
    if n_captured:
        problems.insert(
            len(problems) - len(d["undetermined"]) - len(d["misfit"]),
            f"the fit ended where the model captures {n_captured} impact(s) that the data "
            "show rebounding (stuck in the capture region: start with less adhesion or "
            "damping, or use more starts)",
        )
    # A fitted value outside its documented range (a log-scale parameter has no upper end):
    # not an answer; the result's scene holds the nearest value inside, for reports and plots.
    outside = {nm: v for nm, v in best.values.items() if not RANGES[nm].contains(v)}
    for nm, v in outside.items():
        problems.append(
            f"{nm} = {v:.4g} left its documented range {RANGES[nm].interval()} "
            "(docs/input_ranges.md)"
        )
    scene_values = {
        nm: float(np.clip(v, RANGES[nm].lo, RANGES[nm].hi)) if nm in outside else v
        for nm, v in best.values.items()
    }
    warnings += _value_warnings(objective, names, theta, runs, starts, scene_values)
    if not best.converged or n_failed or n_captured or outside:
        status_name = "not converged"
    elif d["undetermined"]:
        status_name = "undetermined"
    elif d["misfit"]:
        status_name = "misfit"
    else:
        status_name = "converged"
    return status_name, problems, warnings, scene_values


def _value_warnings(objective, names, theta, runs, starts, scene_values) -> list[str]:
    """Warnings on the fitted values: implausible impacts, a value at its bound, starts that
    converged to different minima."""
    warnings = []
    implausible_at = _implausible_impacts(objective, objective.scene_at(scene_values))
    if implausible_at:
        warnings.append(
            f"physically implausible at {implausible_at} of {objective._speed.size} impact(s): "
            f"{IMPLAUSIBLE['large_overlap']} (elastic Hertz estimate at the fitted values)"
        )
    for i, nm in enumerate(names):
        if nm in BOUNDS:
            lo, hi = BOUNDS[nm]
            if min(theta[i] - lo, hi - theta[i]) < 1e-3 * (hi - lo):
                warnings.append(f"{nm} = {theta[i]:.4g} is at its bound ({lo}, {hi})")
    n_conv = sum(run[0].converged for run in runs)
    minima = distinct_minima([run[0] for run in runs], names)
    if starts > 1 and len(minima) > 1:
        warnings.append(
            f"{n_conv} of {starts} starts converged to {len(minima)} distinct minima (costs "
            f"{minima[0].cost:.6g} .. {minima[-1].cost:.6g}; each listed under 'minima'): "
            "the values above are the lowest; a posterior's reference covers each one with "
            "posterior mass"
        )
    return warnings


def _implausible_impacts(objective: Objective, scene) -> int:
    """How many of the data's impacts the fitted scene makes physically implausible
    (``jaximpact._ranges.implausible``, from the elastic Hertz estimate of the overlap)."""
    imp = objective.observations.impacts
    n = imp.speed.size

    def value(name, section, field):
        given = imp.overrides.get(name)
        return np.broadcast_to(
            given if given is not None else np.asarray(getattr(getattr(scene, section), field)),
            (n,),
        )

    flags = implausible(
        value("radius", "particle", "radius"),
        np.full(n, np.nan),
        value("density", "particle", "density"),
        value("K", "contact", "K"),
        imp.speed,
        imp.angle_deg,
    )
    return int(np.sum(flags != ""))


def _capture_mismatch(objective: Objective, status) -> int:
    """Impacts the model captures although the data show a rebound there."""
    obs = objective.observations
    rebound = (obs.observable != "captured") | (obs.value < 0.5)
    captured = np.asarray(status)[obs.impact_index] == jaximpact.Status.CAPTURED
    return int(np.unique(obs.impact_index[rebound & captured]).size)

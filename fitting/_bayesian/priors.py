"""Priors of the fitted parameters, as log densities in the solver variables ``u``.

The sampler moves ``u`` (``_transforms``: ``p = exp(u)``, or a scaled sigmoid for friction),
so every prior here is the density of ``u``: the density of ``p`` times ``|dp/du|`` (the
Jacobian term of the change of variables).

Default: log-uniform over :data:`PRIOR_RANGES`, a documented physical range wide enough for
any microsphere or millimetre sphere (docs/posterior.md), inside each parameter's documented
input range (docs/input_ranges.md), as every prior given must be; a log-uniform prior is flat in
``u = ln p``, so it adds nothing to the gradient inside the range and ``-inf`` outside.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import jax.numpy as jnp

from jaximpact._model.ranges import RANGES
from jaximpact.parameters import FITTABLE, PARAMETERS

from .._least_squares.objective import FitError
from .._least_squares.transforms import BOUNDS

__all__ = ["PRIOR_KINDS", "PRIOR_RANGES", "Prior", "default_prior", "parse_prior", "priors_for"]

#: Default prior ranges (SI): log-uniform between these values (the parameter registry's
#: ``default_prior``, ``jaximpact.parameters``, where each range's unit and use are given).
PRIOR_RANGES = {n: PARAMETERS[n].default_prior for n in FITTABLE}

PRIOR_KINDS = ("loguniform", "normal")


@dataclass(frozen=True)
class Prior:
    """``loguniform`` between ``a`` and ``b`` (``0 < a < b``), or ``normal`` with mean ``a``
    and standard deviation ``b`` (on the physical value, truncated to its allowed range)."""

    kind: str
    a: float
    b: float

    def describe(self) -> str:
        return f"{self.kind}:{self.a:g}:{self.b:g}"

    def log_density_u(self, name: str, u):
        """Log density of the solver variable ``u`` (JAX; differentiable)."""
        if name in BOUNDS:
            lo, hi = BOUNDS[name]
            s = 1.0 / (1.0 + jnp.exp(-u))
            p = lo + (hi - lo) * s
            log_jac = jnp.log(hi - lo) + jnp.log(s) + jnp.log1p(-s)
        else:
            p = jnp.exp(u)
            log_jac = u
        if self.kind == "loguniform":
            inside = (p >= self.a) & (p <= self.b)
            value = -jnp.log(p) + log_jac - math.log(math.log(self.b / self.a))
            return jnp.where(inside, value, -jnp.inf)
        z = (p - self.a) / self.b
        return -0.5 * z**2 - math.log(self.b * math.sqrt(2 * math.pi)) + log_jac


#: The default log-uniform prior of ``eta_n`` by ``model.damping`` (its unit is the model's):
#: wide, from microspheres to millimetre spheres and damping ratios of 1e-3 to about 1.
ETA_N_PRIORS = {
    "velocity": (1e-9, 1e3),  # kg/s
    "mass_velocity": (1e1, 1e11),  # 1/s
    "viscoelastic": (1e4, 1e17),  # 1/(m s)
    "tsuji": (0.05, 1.0),  # Tsuji's restitution coefficient
}


def default_prior(name: str, damping: str | None = None) -> Prior:
    """The default log-uniform prior of ``name`` (``damping``: the scene's ``model.damping``,
    which sets ``eta_n``'s)."""
    if PRIOR_RANGES[name] is None:  # a unit that depends on the scene (eta_n)
        if damping in ETA_N_PRIORS:
            return Prior("loguniform", *ETA_N_PRIORS[damping])
        raise FitError(
            f"{name} has no default prior (its unit depends on the scene: "
            f"{PARAMETERS[name].unit}); give one, e.g. --prior {name}=loguniform:LO:HI"
        )
    lo, hi = PRIOR_RANGES[name]
    return Prior("loguniform", lo, hi)


def parse_prior(name: str, text: str, where: str | None = None) -> Prior:
    """``loguniform:LO:HI`` or ``normal:MU:SD`` -> a `Prior` of parameter ``name``
    (``where``: how an error names it; default "prior of NAME").

    Raises:
        FitError: a malformed specification (the message names the parameter and the rule).
    """
    parts = str(text).split(":")
    kind = parts[0].strip().lower()
    where = where or f"prior of {name}"
    if kind not in PRIOR_KINDS or len(parts) != 3:
        raise FitError(f"{where}: expected loguniform:LO:HI or normal:MU:SD, got {text!r}")
    try:
        a, b = float(parts[1]), float(parts[2])
    except ValueError:
        raise FitError(f"{where}: numbers expected in {text!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise FitError(f"{where}: finite numbers expected in {text!r}")
    if kind == "loguniform" and not 0 < a < b:
        raise FitError(f"{where}: loguniform needs 0 < LO < HI, got {text!r}")
    if kind == "normal" and not b > 0:
        raise FitError(f"{where}: normal needs SD > 0, got {text!r}")
    # The prior lives inside the documented range of the parameter (docs/input_ranges.md),
    # as every value a simulation accepts.
    allowed = RANGES[name]
    ends = (a, b) if kind == "loguniform" else (a,)
    if not all(allowed.contains(x) for x in ends):
        what = "LO and HI" if kind == "loguniform" else "MU"
        raise FitError(
            f"{where}: {what} of {text!r} must lie in the documented range of {name}, "
            f"{allowed.interval()} (docs/input_ranges.md)"
        )
    return Prior(kind, a, b)


def priors_for(
    names: Sequence[str],
    given: Mapping[str, object] | None,
    scene_priors: Sequence[tuple[str, str]] = (),
    damping: str | None = None,
) -> dict[str, Prior]:
    """The prior of every fitted name: ``given`` (a `Prior` or its text), else the scene's
    ``[priors]`` entry (``scene.priors``; entries of names not fitted are ignored, so one scene
    serves several fits), else the default (``damping``: the scene's ``model.damping``).

    Raises:
        FitError: a prior given for a name that is not fitted, or a malformed one.
    """
    from_scene = dict(scene_priors)
    given = dict(given or {})
    for name in given:
        if name not in names:
            raise FitError(f"prior given for {name!r}, which is not fitted ({list(names)})")
    out = {}
    for name in names:
        p = given.get(name)
        if p is None and name in from_scene:
            p = parse_prior(name, from_scene[name], f"scene priors.{name}")
        out[name] = (
            default_prior(name, damping)
            if p is None
            else p
            if isinstance(p, Prior)
            else parse_prior(name, p)
        )
    return out

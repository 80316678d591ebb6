"""Solver variables: the unconstrained ``u`` that the fit moves, and the physical values.

``p = exp(u)`` for positive parameters (C_A, C_H, f0, K, G_star, w, lambda, radius, density) and
``p = lo + (hi - lo) sigmoid(u)`` for the bounded ones (:data:`BOUNDS`: friction, over its
whole documented range, (0, 10); docs/input_ranges.md). Starting values are checked against
the same ranges as a scene's values (``jaximpact._ranges.RANGES``), so that simulate, fit and
design accept and refuse the same values.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaximpact._model.ranges import RANGES, range_text
from jaximpact.parameters import PARAMETERS

from .objective import FitError

__all__ = ["BOUNDS", "dphys_du", "to_physical", "to_unbounded"]

#: Bounded parameters: ``name -> (lo, hi)``, the ends of their documented range (a start must
#: lie strictly between them); all other fittable parameters are positive (log scale). The
#: registry's transform says which (``jaximpact.parameters``: ``"logit"`` or ``"log"``).
BOUNDS = {name: (p.lower, p.upper) for name, p in PARAMETERS.items() if p.transform == "logit"}


def to_unbounded(names: Sequence[str], values) -> np.ndarray:
    """Physical values -> unconstrained solver variables (log, or logit for bounded ones).

    Raises:
        FitError: a value outside its documented range (``RANGES``), or at an end that the
            transform cannot reach (0 for a log-scale parameter, either end of ``BOUNDS``).
    """
    u = []
    for name, p in zip(names, np.asarray(values, dtype=float).tolist(), strict=True):
        allowed = RANGES[name]
        if not allowed.contains(p):
            raise FitError(
                f"initial {name} = {p!r}: {range_text(name)} (docs/input_ranges.md, the same "
                "range as in a scene)"
            )
        if name in BOUNDS:
            lo, hi = BOUNDS[name]
            if not lo < p < hi:
                raise FitError(
                    f"initial {name} = {p!r} must be inside {allowed.inner()} (it is fitted on "
                    f"a logit scale over its range {allowed.interval()}, whose ends it cannot "
                    "reach); give a starting value inside"
                )
            u.append(PARAMETERS[name].to_unbounded(p))
        else:
            if not p > 0:
                raise FitError(
                    f"initial {name} = {p!r} must be finite and > 0 (it is fitted on a log "
                    "scale); give a positive starting value"
                )
            u.append(PARAMETERS[name].to_unbounded(p))
    return np.array(u)


def to_physical(names: Sequence[str], u):
    """Unconstrained variables -> physical values (works on numpy or JAX arrays)."""
    out = []
    for i, name in enumerate(names):
        if name in BOUNDS:
            lo, hi = BOUNDS[name]
            out.append(lo + (hi - lo) * jax.nn.sigmoid(u[i]))
        else:
            out.append(jnp.exp(u[i]))
    return jnp.stack(out)


def dphys_du(names, p) -> np.ndarray:
    """``dp/du`` of each parameter at physical values ``p`` (numpy)."""
    d = []
    for name, v in zip(names, p, strict=True):
        if name in BOUNDS:
            lo, hi = BOUNDS[name]
            d.append((v - lo) * (hi - v) / (hi - lo))
        else:
            d.append(v)
    return np.array(d)

"""The sampler's coordinates ``x``: every sampled quantity on the whole real line.

A parameter with a log-uniform prior on ``[a, b]`` and a noise factor (log-uniform on
:data:`NOISE_FACTOR_RANGE`) are sampled as the logit of their position in the prior's range on
a log scale, ``x = logit((ln p - ln a) / (ln b - ln a))``: the prior of ``x`` is then the
standard logistic density, proper and free of walls, and a posterior piled against an end of
the prior becomes an exponential tail in ``x`` that a sampler can follow (a wall would reject
every step across it). A parameter with a normal prior is sampled in the fit's own solver
variable ``u`` (``_transforms``: ``ln p``, or a logit for friction), with its prior's density
in ``u``.

The simulator takes ``u`` (:meth:`SamplingSpace.to_u`); the priors, their samples and the
change of a covariance from ``u`` to ``x`` are here, so that every sampler and the grid share
one definition of the posterior density.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from jaximpact._model.ranges import RANGES

from .._least_squares.transforms import BOUNDS, to_unbounded
from .priors import Prior

__all__ = ["NOISE_FACTOR_RANGE", "SamplingSpace"]

#: Range of the sampled noise factors (log-uniform prior).
NOISE_FACTOR_RANGE = (1e-3, 1e3)


@dataclass(frozen=True)
class SamplingSpace:
    """Coordinates ``x = (parameters, log noise factors)`` of a posterior.

    Attributes:
        names: the fitted parameters, then ``noise`` (the noise factors' names).
        priors: ``{name: Prior}`` of the parameters.
    """

    names: tuple[str, ...]
    noise: tuple[str, ...]
    priors: dict[str, Prior]

    @property
    def dim(self) -> int:
        return len(self.names) + len(self.noise)

    def _box(self, i: int) -> tuple[float, float] | None:
        """``(ln a, ln b)`` of coordinate ``i`` if it is a logit of a log-uniform range."""
        if i >= len(self.names):
            lo, hi = NOISE_FACTOR_RANGE
            return math.log(lo), math.log(hi)
        prior = self.priors[self.names[i]]
        return (math.log(prior.a), math.log(prior.b)) if prior.kind == "loguniform" else None

    # -- JAX: what the log density is built from ----------------------------------------------

    def to_u(self, x):
        """``x (d,) -> (u (p,), log noise factors (k,))`` (JAX, differentiable)."""
        out = []
        for i in range(self.dim):
            box = self._box(i)
            if box is None:
                out.append(x[i])
                continue
            log_p = box[0] + (box[1] - box[0]) * jax.nn.sigmoid(x[i])
            name = self.names[i] if i < len(self.names) else None
            if name in BOUNDS:  # friction: the fit's u is a logit over BOUNDS, not ln p
                lo, hi = BOUNDS[name]
                s = (jnp.exp(log_p) - lo) / (hi - lo)
                out.append(jnp.log(s) - jnp.log1p(-s))
            else:
                out.append(log_p)
        z = jnp.stack(out)
        p = len(self.names)
        return z[:p], z[p:]

    def log_prior(self, x):
        """Log density of the prior in ``x`` (JAX; normalized for log-uniform priors)."""
        total = 0.0
        for i in range(self.dim):
            if self._box(i) is None:
                name = self.names[i]
                total = total + self.priors[name].log_density_u(name, x[i])
            else:  # standard logistic
                total = total + jax.nn.log_sigmoid(x[i]) + jax.nn.log_sigmoid(-x[i])
        return total

    # -- numpy: placing a reference distribution ----------------------------------------------

    def from_physical(self, theta: Sequence[float], log_noise: Sequence[float]) -> np.ndarray:
        """Physical parameter values and log noise factors -> ``x`` (numpy), clipped to
        ``|x| <= 30`` where a value lies at or beyond its prior's end."""
        theta = np.asarray(theta, float)
        u = to_unbounded(self.names, theta) if len(self.names) else np.zeros(0)
        z = np.concatenate([np.log(theta), np.asarray(log_noise, float)])
        x = np.empty(self.dim)
        for i in range(self.dim):
            box = self._box(i)
            if box is None:
                x[i] = u[i]
            else:
                s = np.clip((z[i] - box[0]) / (box[1] - box[0]), 1e-13, 1 - 1e-13)
                x[i] = np.log(s) - np.log1p(-s)
        return np.clip(x, -30.0, 30.0)

    def dx_dlog(self, x: np.ndarray) -> np.ndarray:
        """``dx / d ln p`` (or ``dx/du`` where ``x = u``) of each coordinate at ``x`` (numpy):
        the factor that carries a standard deviation in ``ln p`` into ``x``."""
        out = np.ones(self.dim)
        for i in range(self.dim):
            box = self._box(i)
            if box is not None:
                s = 1.0 / (1.0 + np.exp(-x[i]))
                out[i] = 1.0 / ((box[1] - box[0]) * max(s * (1 - s), 1e-300))
        return out

    def prior_sd(self) -> np.ndarray:
        """A standard deviation of each coordinate under its prior (logistic: pi/sqrt(3);
        a normal prior: its sd carried into ``u`` at the mean, at most 10)."""
        out = np.full(self.dim, math.pi / math.sqrt(3.0))
        for i in range(len(self.names)):
            prior = self.priors[self.names[i]]
            if prior.kind == "normal":
                out[i] = min(10.0, prior.b / max(prior.a, prior.b))
        return out

    def sample_prior(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` independent draws of ``x`` from the prior (numpy)."""
        X = rng.logistic(size=(n, self.dim))
        for i, name in enumerate(self.names):
            prior = self.priors[name]
            if prior.kind == "normal":
                lo, hi = self._normal_support(name)
                a, b = (lo - prior.a) / prior.b, (hi - prior.a) / prior.b
                p = stats.truncnorm.rvs(a, b, loc=prior.a, scale=prior.b, size=n, random_state=rng)
                X[:, i] = [to_unbounded([name], [v])[0] for v in p]
        return X

    def log_prior_normalized(self, X: np.ndarray) -> np.ndarray:
        """Normalized log prior density of the rows of ``X`` (numpy): :meth:`log_prior` with
        each normal prior divided by its mass inside the parameter's range."""
        X = np.asarray(X, float)
        total = np.zeros(len(X))
        for i in range(self.dim):
            if self._box(i) is not None:  # standard logistic, in numpy (called per move)
                a = np.abs(X[:, i])
                total -= a + 2.0 * np.log1p(np.exp(-a))
                continue
            name = self.names[i]
            prior = self.priors[name]
            total += np.asarray(
                jax.vmap(lambda u, n=name, p=prior: p.log_density_u(n, u))(jnp.asarray(X[:, i]))
            )
            if prior.kind == "normal":
                lo, hi = self._normal_support(name)
                mass = stats.norm.cdf(hi, prior.a, prior.b) - stats.norm.cdf(lo, prior.a, prior.b)
                total = total - math.log(max(mass, 1e-300))
        return total

    @staticmethod
    def _normal_support(name: str) -> tuple[float, float]:
        """Where a normal prior of ``name`` has mass: its documented range, open at the ends
        the solver variable cannot reach."""
        allowed = RANGES[name]
        lo, hi = allowed.lo, allowed.hi
        eps = 1e-12 * max(1.0, abs(hi)) if math.isfinite(hi) else 0.0
        return max(lo, 0.0) + eps, hi - eps if math.isfinite(hi) else math.inf

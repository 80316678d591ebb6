"""The moves of SMC's populations (``fitting._bayesian.smc``): the independence proposal, a
Gaussian mixture fitted to the particles by EM, and the drift of MALA steps along the
tempered log density's gradient."""

from __future__ import annotations

import math

import numpy as np
from scipy.special import logsumexp

#: The independence proposal: a Gaussian mixture fitted to the population by EM (at most
#: COMPONENTS components, each with its own covariance, so that a curved ridge is covered by
#: straight pieces that follow it), its covariances widened by MIXTURE_WIDTH^2, mixed with a
#: Student-t (WIDE_NU degrees of freedom) on the population's mean and twice its standard
#: deviations (share WIDE). The wide part gives the proposal heavier tails than the target,
#: without which an independence sampler cannot grow a population that is too narrow.
COMPONENTS = 8

MIXTURE_WIDTH = 1.2

EM_ITERATIONS = 40

WIDE = 0.25

WIDE_NU = 3.0


def _gaussian_log_densities(Y, means, chols):
    """``(n, m)`` log densities of the rows of ``Y`` under each Gaussian component."""
    n, d = Y.shape
    out = np.empty((n, len(means)))
    for j, (mean, chol) in enumerate(zip(means, chols, strict=True)):
        z = np.linalg.solve(chol, (Y - mean).T)
        out[:, j] = (
            -0.5 * np.sum(z * z, axis=0)
            - np.sum(np.log(np.diag(chol)))
            - 0.5 * d * math.log(2 * math.pi)
        )
    return out


def _fit_mixture(rng, X: np.ndarray, chol: np.ndarray):
    """A Gaussian mixture fitted to ``X`` by EM (k-means++ starts in the population's
    whitened coordinates, covariances regularized by 1e-4 of the population's): ``(log
    weights, means, Cholesky factors)``."""
    n, d = X.shape
    m = max(1, min(COMPONENTS, n // (10 * (d + 1))))
    W = np.linalg.solve(chol, X.T).T
    centres = [W[rng.integers(n)]]
    for _ in range(1, m):  # k-means++: each new centre far from the others
        d2 = np.min(((W[:, None, :] - np.array(centres)[None]) ** 2).sum(-1), axis=1)
        centres.append(W[rng.choice(n, p=d2 / d2.sum()) if d2.sum() > 0 else rng.integers(n)])
    labels = np.argmin(((W[:, None, :] - np.array(centres)[None]) ** 2).sum(-1), axis=1)
    resp = np.eye(m)[labels]
    floor = 1e-4 * (chol @ chol.T) + 1e-12 * np.eye(d)
    for it in range(EM_ITERATIONS + 1):
        weight = resp.sum(axis=0) + 1e-12
        means = (resp.T @ X) / weight[:, None]
        chols = []
        for j in range(m):
            dev = X - means[j]
            cov = (resp[:, j, None] * dev).T @ dev / weight[j] + floor
            chols.append(np.linalg.cholesky(cov))
        log_w = np.log(weight / n)
        if it == EM_ITERATIONS:
            break
        log_p = _gaussian_log_densities(X, means, chols) + log_w
        resp = np.exp(log_p - logsumexp(log_p, axis=1, keepdims=True))
    return log_w, means, chols


def _independence_proposal(rng, X: np.ndarray, chol: np.ndarray, n: int):
    """``n`` draws of the independence proposal fitted to the particles ``X`` (``chol``: the
    Cholesky factor of the population's covariance), and its log density ``Y -> (n,)``."""
    d = X.shape[1]
    log_w, means, chols = _fit_mixture(rng, X, chol)
    chols = [MIXTURE_WIDTH * c for c in chols]
    mean = X.mean(axis=0)
    component = rng.choice(len(means), size=n, p=np.exp(log_w) / np.exp(log_w).sum())
    Z = rng.standard_normal((n, d))
    Xp = np.empty((n, d))
    for j in range(len(means)):
        pick = component == j
        Xp[pick] = means[j] + Z[pick] @ chols[j].T
    wide = rng.uniform(size=n) < WIDE
    g = rng.chisquare(WIDE_NU, (n, 1))
    Xp[wide] = (mean + 2.0 * (Z @ chol.T) / np.sqrt(g / WIDE_NU))[wide]
    log_det = float(np.sum(np.log(np.diag(chol))))

    def log_q(Y):
        mixture = logsumexp(_gaussian_log_densities(Y, means, chols) + log_w, axis=1)
        y = np.linalg.solve(chol, (Y - mean).T).T / 2.0
        t = (
            math.lgamma((WIDE_NU + d) / 2)
            - math.lgamma(WIDE_NU / 2)
            - 0.5 * d * math.log(WIDE_NU * math.pi)
            - d * math.log(2.0)
            - log_det
            - 0.5 * (WIDE_NU + d) * np.log1p(np.sum(y * y, axis=1) / WIDE_NU)
        )
        return np.logaddexp(math.log1p(-WIDE) + mixture, math.log(WIDE) + t)

    return Xp, log_q


#: A MALA step's drift is at most this many proposal standard deviations long (in the
#: population's whitened coordinates): where the gradient is steep (a particle far out in a
#: thin ridge's tail) the full drift throws every proposal away and the particle never moves
#: (seen: a curved ridge's sd 30 % wide); truncated, the step is a random walk there
#: (Roberts & Tweedie 1996, MALTA). The drift is a fixed function of the position: the
#: Metropolis-Hastings ratio stays exact.
MALA_MAX_DRIFT = 2.0


def _langevin_drift(gradient, chol, h) -> np.ndarray:
    """``h^2 / 2 Sigma grad`` (``Sigma = chol chol^T``), each row's length in whitened
    coordinates capped at :data:`MALA_MAX_DRIFT` ``h``."""
    whitened = 0.5 * h * h * (np.asarray(gradient) @ chol)
    length = np.linalg.norm(whitened, axis=1, keepdims=True)
    cap = MALA_MAX_DRIFT * h
    whitened = whitened * np.minimum(1.0, cap / np.maximum(length, 1e-300))
    return whitened @ chol.T


def _tempered_gradient(beta: float, grad_posterior, reference, X) -> np.ndarray:
    """Gradient of ``ln pi_b = (1 - b) ln q0 + b ln posterior`` at ``X`` (the reference's by
    central differences; a non-finite entry as 0: that particle's step is a random walk;
    ``reference``: the SMC reference, a ``Reference``)."""
    g = beta * np.asarray(grad_posterior, float)
    if beta < 1.0:
        g = g + (1.0 - beta) * _numerical_gradient(reference.log_density, X)
    return np.where(np.isfinite(g), g, 0.0)


def _numerical_gradient(f, X) -> np.ndarray:
    """Central differences of ``f: (n, d) -> (n,)`` at the rows of ``X``."""
    X = np.asarray(X, float)
    out = np.empty_like(X)
    for j in range(X.shape[1]):
        h = 1e-5 * (1.0 + np.abs(X[:, j]))
        up, down = X.copy(), X.copy()
        up[:, j] += h
        down[:, j] -= h
        out[:, j] = (np.asarray(f(up)) - np.asarray(f(down))) / (2 * h)
    return out

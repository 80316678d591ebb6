"""The exact posterior of the sampler's own density on a grid (:func:`grid_reference`): the
reference that the samplers are checked against, in tests and benchmarks.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .._least_squares.fit import FitResult
from .._least_squares.objective import FitError
from .._least_squares.transforms import dphys_du
from .priors import priors_for
from .programs import (
    BLOCK,
    SAMPLING_RTOL,
    _at_tolerance,
    _blocks,
    _integrates,
    _noise_groups,
    _x_batch_log_density,
)
from .smc_posterior import REFERENCE_WIDTH, _reference, _x_judged
from .space import SamplingSpace


def posterior_setup(
    fit_result: FitResult,
    priors: Mapping[str, object] | None = None,
    likelihood: str = "gaussian",
    nu: float = 4.0,
    rtol: float | None = SAMPLING_RTOL,
    noise: str = "auto",
):
    """The posterior that :func:`sample_posterior` samples, for a fit's data and parameters:
    ``(space, batch log density X (n, d) -> (n,) in the sampler's coordinates, the objective
    at the sampling tolerance, noise groups)``. The grid reference of the benchmarks and tests
    evaluates exactly this density (with noise factors integrated out, the marginal posterior
    of the physical parameters)."""
    objective = fit_result.objective
    names = tuple(fit_result.params)
    prior_map = priors_for(names, priors, objective.scene.priors, objective.scene.model.damping)
    groups, noise_names = _noise_groups(objective)
    integrated = _integrates(noise, likelihood, noise_names)
    space = SamplingSpace(names, () if integrated else noise_names, prior_map)
    sampled = _at_tolerance(objective, rtol)
    full = _x_batch_log_density(
        sampled, space, groups, likelihood, nu, integrated=len(noise_names) if integrated else 0
    )
    return space, lambda X: full(X)[:, 0], sampled, groups


def grid_reference(
    fit_result: FitResult,
    priors: Mapping[str, object] | None = None,
    *,
    likelihood: str = "gaussian",
    nu: float = 4.0,
    points: int = 40,
    half_width: float = 8.0,
    axes: str = "whitened",
    rtol: float | None = SAMPLING_RTOL,
    progress: bool = False,
) -> dict:
    """The exact posterior of :func:`sample_posterior` on a grid, as a yardstick for samplers
    (1-3 parameters; observables without sigmas: their noise factors integrated out, the
    Gaussian likelihood's marginal posterior).

    ``axes="whitened"``: the grid lies in the fit's whitened coordinates ``g`` (``x = centre +
    L g``, ``L`` the Cholesky factor of the fit's covariance carried into the sampler's
    coordinates ``x``, a parameter the data leave open at its prior's width), over ``|g| <=
    half_width``, refined once to where the mass is (``_grid``). A grid along the parameters'
    own axes cannot resolve a ridge thinner than its cells (a C_A-f0 ridge 70x thinner than
    long is common); along the ridge's axes it can. Where more than 1e-6 of the mass lies on
    the box's faces the box is doubled (up to twice). It cannot follow a ridge that curves away
    from the fit's axes: check its face mass and compare two resolutions.
    ``axes="parameters"``: the grid lies in ``ln p`` over each log-uniform prior's whole
    range (nothing is outside it), refined once: robust where the posterior is wide or curved,
    fine enough for 2 parameters (``points`` of 100-200).
    The physical values' mean, sd and 5/50/95 % quantiles come from the cells as weighted
    points.

    Returns ``{name: {mean, sd, q05, median, q95}}`` plus ``"_grid"`` (the `GridPosterior`
    in ``g``) and ``"_face_mass"`` (the mass on the box's faces).
    """
    space, batch, _, groups = posterior_setup(fit_result, priors, likelihood, nu, rtol)
    if space.noise:
        raise FitError(
            "grid_reference needs the noise factors integrated out (the Gaussian likelihood) "
            "or sigmas for every datum"
        )
    names = space.names
    theta = np.asarray(fit_result.theta, float)
    dpdu = dphys_du(names, theta)
    cov_u = np.asarray(fit_result.covariance) / np.outer(dpdu, dpdu)
    reference = _reference(space, theta, cov_u, [], groups)
    centre, chol = reference.mean, np.linalg.cholesky(reference.cov / REFERENCE_WIDTH**2)
    evaluate = _blocks(batch, BLOCK)
    if axes == "parameters":
        return _grid_in_parameters(space, evaluate, points, progress)
    return _grid_whitened(space, evaluate, centre, chol, points, half_width, progress)


def _grid_in_parameters(space, evaluate, points, progress) -> dict:
    """``axes="parameters"``: the grid in ``ln p`` over each log-uniform prior's range."""
    from .grid import grid_posterior

    d, names = space.dim, space.names
    ends = [space._box(i) for i in range(d)]
    if any(e is None for e in ends):
        raise FitError("axes='parameters' needs log-uniform priors")
    start = np.array([a for a, _ in ends])
    width = np.array([b - a for a, b in ends])

    def log_density(L):  # ln p -> x, with the Jacobian |dx / d ln p|
        q = np.clip((L - start) / width, 1e-300, 1 - 1e-16)
        return evaluate(np.log(q) - np.log1p(-q)) - np.sum(np.log(width * q * (1 - q)), 1)

    grid = grid_posterior(
        log_density, start, start + width, names=names, points=points, block=BLOCK,
        to_physical=lambda i, u: np.exp(u), progress=progress,
    )  # fmt: skip
    return {**grid.summary, "_grid": grid, "_face_mass": 0.0}


def _grid_whitened(space, evaluate, centre, chol, points, half_width, progress) -> dict:
    """``axes="whitened"``: the grid in the fit's whitened coordinates, its box doubled
    (up to twice) while more than 1e-6 of the mass lies on its faces."""
    from .grid import grid_posterior

    d, names = space.dim, space.names
    for _ in range(3):
        grid = grid_posterior(
            lambda G: evaluate(centre + G @ chol.T), [-half_width] * d, [half_width] * d,
            names=names, points=points, block=BLOCK, progress=progress,
        )  # fmt: skip
        face = _face_mass(grid, half_width)
        if face <= 1e-6:
            break
        half_width *= 2
    mesh = np.stack(np.meshgrid(*grid.axes, indexing="ij"), axis=-1).reshape(-1, d)
    # Each cell's mass spread over SUB^d points inside it (its density is the centre's: the
    # midpoint rule), so that the cells, projected on a parameter's axis, give a smooth CDF.
    h = np.array([a[1] - a[0] for a in grid.axes])
    offsets = (np.arange(SUB) + 0.5) / SUB - 0.5
    sub = np.stack(np.meshgrid(*[offsets * hi for hi in h], indexing="ij"), -1).reshape(-1, d)
    cells = (mesh[:, None, :] + sub[None]).reshape(-1, d)
    weight = np.repeat(grid.mass.reshape(-1), len(sub)) / len(sub)
    keep = weight > 1e-14 * weight.max()
    values = _x_judged(space, centre + cells[keep] @ chol.T)
    return _weighted_summary(names, values, weight[keep] / weight[keep].sum(), grid, face)


#: Points per cell and dimension that carry a whitened grid cell's mass into the summary.
SUB = 4


def _weighted_summary(names, values, weight, grid, face) -> dict:
    """Mean, sd and 5/50/95 % quantiles of each column of ``values`` weighted by ``weight``."""
    out = {"_grid": grid, "_face_mass": face}
    for i, name in enumerate(names):
        v = values[:, i]
        mean = float(weight @ v)
        order = np.argsort(v)
        cdf = np.cumsum(weight[order]) - 0.5 * weight[order]
        q05, median, q95 = np.interp([0.05, 0.5, 0.95], cdf, v[order])
        out[name] = {
            "mean": mean,
            "sd": float(np.sqrt(weight @ (v - mean) ** 2)),
            "q05": float(q05),
            "median": float(median),
            "q95": float(q95),
        }
    return out


def _face_mass(grid, half_width) -> float:
    """Mass of the cells on the faces of the box ``|g| <= half_width`` (after refinement, only
    faces that are still at the box's edge count)."""
    mass = grid.mass
    total = 0.0
    for i, axis in enumerate(grid.axes):
        h = axis[1] - axis[0]
        for end, index in ((-half_width, 0), (half_width, -1)):
            if abs(axis[index] - end) < h:
                total += float(np.take(mass, index, axis=i).sum())
    return total

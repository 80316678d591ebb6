"""What a fit returns: each start's end (:class:`StartResult`), the fit's result
(:class:`FitResult`), and the distinct minima the starts ended at."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

import jaximpact

from .objective import Objective
from .transforms import to_unbounded

__all__ = ["SAME_COST", "SAME_VALUES", "STATUSES", "FitResult", "StartResult", "distinct_minima"]

#: Values of :attr:`FitResult.status`, in the order they are checked.
STATUSES = ("not converged", "undetermined", "misfit", "converged")


@dataclass
class StartResult:
    """One start of a multi-start fit: initial and final values, cost, convergence."""

    initial: dict[str, float]
    values: dict[str, float]
    cost: float
    converged: bool
    steps: int
    message: str


@dataclass
class FitResult:
    """Result of :func:`fit`.

    Attributes:
        params: fitted parameter names.
        values, stderr: ``{name: float}``, physical units (stderr ``inf`` where the data do not
            determine the parameter, NaN where no residual variance exists).
        correlation, covariance: ``(p, p)`` numpy arrays, physical parameters.
        cost: ``1/2 sum r^2`` at the optimum (residuals in scales).
        status: ``"converged"``, ``"not converged"`` (optimizer, failed impacts, or stuck
            where the model captures impacts that the data show rebounding),
            ``"undetermined"`` (the uncertainty is undefined: rank-deficient Jacobian or
            non-finite standard errors) or ``"misfit"`` (the model does not describe the data).
        converged: ``status == "converged"``: the only state in which the values and standard
            errors can be taken as the answer.
        optimizer_converged: the best start met the optimizer's convergence test.
        problems: why the status is not ``"converged"`` (empty when it is).
        n_data, dof: observations, and ``n_data - len(params)``.
        rank, condition_number, singular_values: of the residual Jacobian in the solver
            variables.
        sensitivity: ``{name: |dr/d ln p|}``: how much the residual vector (in scales) changes
            per relative change of each parameter.
        unidentifiable: names of the parameters the data do not determine.
        reduced_chi2: ``2 cost / dof`` when every observation has a sigma, else NaN;
            ``p_value``: its chi-square upper tail probability.
        rms_residual: ``sqrt(2 cost / n_data)``, in scales.
        residual_scale: ``s``, the factor applied to the standard errors (1 if sigma is known).
        warnings: human-readable warnings (identifiability, convergence, failures).
        timings: seconds: ``compile`` (the programs, or loading them), ``solve`` (all starts),
            ``total`` (including data loading and checks).
        solver, jacobian: ``"lm"``, ``"adam"`` or ``"lbfgs"``; ``"fwd"`` or ``"rev"``.
        program: counts of the residual program's ``traces``, ``compiles`` and ``calls``, and
            where it came from (``source``: traced, cache (traced before; compiled, or
            loaded from JAX's compilation cache) or memory).
        starts: every start, best first.
        residuals: the weighted residuals at the optimum.
        scene: the scene with the fitted values in place.
        objective: the `Objective` (for reports and plots).
        message: the status and its reasons, one line.
    """

    params: tuple[str, ...]
    values: dict[str, float]
    stderr: dict[str, float]
    correlation: np.ndarray
    covariance: np.ndarray
    cost: float
    converged: bool
    n_data: int
    condition_number: float
    residual_scale: float
    warnings: list[str]
    timings: dict[str, float]
    solver: str
    starts: list[StartResult]
    residuals: np.ndarray
    scene: jaximpact.Scene
    objective: Objective = field(repr=False)
    message: str = ""
    status: str = "converged"
    optimizer_converged: bool = True
    problems: list[str] = field(default_factory=list)
    dof: int = 0
    rank: int = 0
    singular_values: np.ndarray = field(default_factory=lambda: np.zeros(0))
    sensitivity: dict[str, float] = field(default_factory=dict)
    unidentifiable: list[str] = field(default_factory=list)
    reduced_chi2: float = math.nan
    p_value: float = math.nan
    rms_residual: float = math.nan
    jacobian: str = "fwd"
    program: dict = field(default_factory=dict)

    @property
    def theta(self) -> np.ndarray:
        """Fitted values as an array in :attr:`params` order."""
        return np.array([self.values[n] for n in self.params])

    @property
    def minima(self) -> list[StartResult]:
        """The distinct minima the converged starts ended at, best first (one start each):
        :func:`distinct_minima` of :attr:`starts`."""
        return distinct_minima(self.starts, self.params)


#: Two converged starts ended at the same minimum when their costs agree to this relative
#: tolerance and their values (in the solver's variables: ln p, a logit for friction) to
#: this absolute one.
SAME_COST = 1e-3
SAME_VALUES = 1e-3


def distinct_minima(starts: Sequence[StartResult], names: Sequence[str]) -> list[StartResult]:
    """The converged ``starts`` with one start per distinct end point, lowest cost first."""
    kept: list[tuple[StartResult, np.ndarray]] = []
    for start in sorted((s for s in starts if s.converged), key=lambda s: s.cost):
        u = np.asarray(to_unbounded(list(names), [start.values[n] for n in names]), float)
        same = any(
            abs(start.cost - other.cost) <= SAME_COST * max(abs(other.cost), 1e-12)
            and np.max(np.abs(u - v)) <= SAME_VALUES
            for other, v in kept
        )
        if not same:
            kept.append((start, u))
    return [start for start, _ in kept]

"""Experiment design: which impacts to measure next, by greedy D-optimal choice.

Each candidate impact ``i`` contributes the Fisher information ``F_i = J_i^T S_i^-1 J_i`` about
the log-parameters, where ``J_i`` holds the derivatives of its observables with respect to
``ln p`` at the scene's values (forward mode, from the fit's compiled residual program) and
``S_i`` their noise variances. The chosen set maximizes ``log det(ridge I + sum F_i)``
greedily: each step adds the candidate with the largest gain in log-determinant. The small
ridge (``ridge`` times the mean diagonal of the average candidate's information) makes the
first picks well defined while fewer impacts than parameters are chosen.

Noise: ``sigma`` per observable in its unit; default the fit's default scales
(:data:`fitting.DEFAULT_SCALES`: cor_n and cor_t 0.01, vt_out 1 % of the speed, omega_out 1 %
of speed/radius, rebound angle 1 degree), i.e. a 1 % measurement of each observable's natural
scale.

Near the capture threshold the model is least smooth (the rebound ends in a capture over a
short range of speed) and its derivatives promise information a measurement may not deliver:
candidates that the model captures at the scene's values, and those whose outcome (rebound
or capture) changes when any parameter moves by ``perturbation`` (relative) either way, are
dropped before the choice, and counted in the result.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

import jaximpact
from jaximpact._model.ranges import IMPLAUSIBLE, implausible
from jaximpact.tables import (
    ImpactTable,
    atomic_write_text,
    number_text,
    read_impacts,
    readonly_array,
)

from ._data import OBSERVABLES, Observations
from ._least_squares.objective import (
    FitError,
    Objective,
    check_names,
    default_scales,
    get_parameter,
)
from ._least_squares.program import ResidualProgram
from ._least_squares.transforms import dphys_du, to_unbounded

__all__ = ["DesignResult", "design", "log_det_information", "write_design"]

#: Observables a design can plan for (``captured`` carries no smooth information).
DESIGN_OBSERVABLES = tuple(n for n in OBSERVABLES if n != "captured")


@dataclass
class DesignResult:
    """Result of :func:`design`.

    Attributes:
        params, observables: what the design is for.
        candidates: the candidate `ImpactTable`.
        usable: indices of the candidates kept (see the module docstring on the others).
        dropped_captured, dropped_near_capture: indices of the candidates dropped.
        chosen: indices of the chosen candidates, in the order chosen.
        gain: log-det gain of each pick (nats); log_det: after each pick (with the ridge).
        information: ``(n_candidates, p, p)`` Fisher information of each candidate in
            ``ln p`` (zero for dropped ones).
        ridge: the ridge added to the information matrix.
        sigma: ``(n_candidates, k)`` the noise assumed for each candidate's observables.
        draws: number of parameter draws the information was averaged over (0: a point
            design at the scene's values); ``information`` is then the mean over them.
        implausible: indices of the candidates whose impact is physically implausible at the
            scene's values (``jaximpact._ranges.implausible``: an elastic Hertz overlap above
            0.1 of the radius); kept, but warned about.
    """

    params: tuple[str, ...]
    observables: tuple[str, ...]
    candidates: ImpactTable
    usable: np.ndarray
    dropped_captured: np.ndarray
    dropped_near_capture: np.ndarray
    chosen: np.ndarray
    gain: np.ndarray
    log_det: np.ndarray
    information: np.ndarray
    ridge: float
    sigma: np.ndarray
    draws: int = 0
    implausible: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, int))

    def warnings(self) -> list[str]:
        """Warnings about the candidates (physically implausible impacts)."""
        if not len(self.implausible):
            return []
        chosen = int(np.isin(self.chosen, self.implausible).sum())
        return [
            f"{len(self.implausible)} of {len(self.candidates)} candidate impacts are physically "
            f"implausible at the scene's values ({IMPLAUSIBLE['large_overlap']}; elastic Hertz "
            f"estimate); {chosen} of them chosen"
        ]

    def message(self) -> str:
        where = (
            f" (mean log-det over {self.draws} posterior draws)"
            if self.draws
            else " (at the scene's values)"
        )
        return (
            f"design: {len(self.chosen)} of {len(self.candidates)} candidate impacts chosen "
            f"for {', '.join(self.params)} from {', '.join(self.observables)}{where}; dropped "
            f"{len(self.dropped_captured)} captured at the scene's values and "
            f"{len(self.dropped_near_capture)} near the capture threshold (outcome changes "
            "within the parameter perturbation" + (" or at a draw)" if self.draws else ")")
        )


def log_det_information(information: np.ndarray, subset, ridge: float = 0.0) -> float:
    """``log det(ridge I + sum_{i in subset} F_i)``."""
    p = information.shape[-1]
    m = ridge * np.eye(p) + np.sum(information[np.asarray(subset, dtype=int)], axis=0)
    sign, value = np.linalg.slogdet(m)
    return float(value) if sign > 0 else -math.inf


def greedy_d_optimal(info: np.ndarray, usable, n: int, *, ridge: float = 1e-6):
    """Greedy D-optimal choice of ``n`` of the ``usable`` candidates, each once.

    ``info``: ``(c, p, p)`` information of each candidate, or ``(k, c, p, p)`` at ``k``
    parameter draws: then each pick maximizes the mean over the draws of the log-determinant
    (pseudo-Bayesian D-optimality; Chaloner & Verdinelli 1995). The ridge is ``ridge`` times
    the mean diagonal of the usable candidates' information. Returns ``(chosen, gain,
    log_det, ridge_abs)``: indices in the order chosen, the (mean) log-det gain of each pick
    and the (mean) log-det after it (with the ridge), and the absolute ridge."""
    usable = np.asarray(usable, dtype=int)
    info = np.asarray(info)
    info = info[None] if info.ndim == 3 else info
    p = info.shape[-1]
    ridge_abs = ridge * float(np.mean(np.trace(info[:, usable], axis1=2, axis2=3))) / p
    m = ridge_abs * np.broadcast_to(np.eye(p), (len(info), p, p))
    current = float(np.mean(np.linalg.slogdet(m)[1]))
    available = np.zeros(info.shape[1], bool)
    available[usable] = True
    chosen, gains, logdets = [], [], []
    for _ in range(n):
        sign, trial = np.linalg.slogdet(m[:, None] + info)  # (k, c)
        trial = np.where(np.all(sign > 0, axis=0), np.mean(trial, axis=0), -np.inf)
        trial = np.where(available, trial, -np.inf)
        best = int(np.argmax(trial))
        chosen.append(best)
        gains.append(float(trial[best] - current))
        current = float(trial[best])
        logdets.append(current)
        m = m + info[:, best]
        available[best] = False
    return np.array(chosen), np.array(gains), np.array(logdets), ridge_abs


def _candidate_observations(table: ImpactTable, observables, source) -> Observations:
    """Every observable at every candidate, with placeholder values (the program gets its own)."""
    n, k = len(table), len(observables)
    index = np.repeat(np.arange(n), k)
    return Observations(
        speed=readonly_array(table.speed[index]),
        angle_deg=readonly_array(table.angle_deg[index]),
        omega0=readonly_array(table.omega0[index]),
        observable=readonly_array(np.tile(list(observables), n), str),
        value=readonly_array(np.full(n * k, 0.5)),
        sigma=readonly_array(np.full(n * k, np.nan)),
        line=readonly_array(np.repeat(np.arange(n), k) + 2, np.int64),
        impact_index=readonly_array(index, np.int64),
        impacts=table,
        source=source,
        provenance="",
        layout="long",
    )


def design(
    scene: jaximpact.Scene,
    candidates,
    params: Sequence[str],
    n: int,
    *,
    observables: Sequence[str] = ("cor_n",),
    sigma: Mapping[str, float] | None = None,
    values: Mapping[str, float] | None = None,
    ridge: float = 1e-6,
    perturbation: float = 0.1,
    method: str | None = None,
    draws=None,
    max_draws: int = 20,
) -> DesignResult:
    """Choose ``n`` impacts from ``candidates`` that most reduce the parameters' uncertainty.

    **Arguments:**
    - `scene`: parameter values at which the information is computed (with `values`).
    - `candidates`: an `ImpactTable` or the path of an impacts CSV (speed, angle_deg[, omega0]).
    - `params`: the parameters to determine.
    - `n`: impacts to choose (at most the usable candidates).
    - `observables`: what will be measured at each impact (default ``cor_n``).
    - `sigma`: ``{observable: sigma}`` in the observable's unit (default: see the module).
    - `values`: parameter values overriding the scene's.
    - `ridge`: relative ridge (see the module docstring).
    - `perturbation`: relative parameter change for the near-capture test.
    - `draws`: parameter draws instead of one value: an array ``(s, p)`` (physical values in
      `params` order) or a `PosteriorResult` of the same parameters. The information is
      computed at `max_draws` of them (evenly spaced) and each pick maximizes its mean
      log-determinant over them (pseudo-Bayesian D-optimal); the near-capture test runs at
      the draws' median (unless `values` are given), and a candidate captured at any draw
      is dropped as near the threshold.

    **Raises:** `FitError` for bad names, options or too few usable candidates.
    """
    names = check_names(params)
    observables, sigma = _check_options(observables, sigma, n, ridge, perturbation)
    candidates, source = _candidates(candidates, observables)

    from ._least_squares.objective import set_parameters

    at_draws = _draw_subset(draws, names, max_draws)
    if at_draws is not None and not values:
        values = dict(zip(names, np.median(at_draws, axis=0).tolist(), strict=True))
    scene = set_parameters(scene, dict(values or {}))
    theta = np.array([get_parameter(scene, nm) for nm in names])
    obs = _candidate_observations(candidates, observables, source or "candidates")
    objective = Objective(scene, obs, names, method=method)
    program = ResidualProgram(objective, 1)
    radius = get_parameter(scene, "radius")
    scale = default_scales(obs.observable, obs.speed, radius)
    for o, s in sigma.items():
        scale = np.where(obs.observable == o, s, scale)
    jacs, rebound, stable = _jacobians(program, names, theta, scale, perturbation, at_draws)
    n_cand = len(candidates)
    usable, dropped_captured, dropped_near = _usable(jacs, rebound, stable, n_cand, n)
    per = jacs.reshape(len(jacs), n_cand, len(observables), len(names))
    info = np.einsum("sckp,sckq->scpq", per, per)
    info[:, ~np.isin(np.arange(n_cand), usable)] = 0.0
    chosen, gains, logdets, ridge_abs = greedy_d_optimal(info, usable, n, ridge=ridge)
    return DesignResult(
        params=names,
        observables=observables,
        candidates=candidates,
        usable=usable,
        dropped_captured=dropped_captured,
        dropped_near_capture=dropped_near,
        chosen=chosen,
        gain=gains,
        log_det=logdets,
        information=info.mean(axis=0),
        ridge=ridge_abs,
        sigma=scale.reshape(n_cand, len(observables)),
        draws=0 if at_draws is None else len(at_draws),
        implausible=_implausible_candidates(scene, candidates),
    )


def _implausible_candidates(scene, candidates) -> np.ndarray:
    """Indices of the candidates flagged physically implausible (elastic Hertz estimate)."""
    return np.flatnonzero(
        implausible(
            get_parameter(scene, "radius"),
            np.nan,
            get_parameter(scene, "density"),
            get_parameter(scene, "K"),
            candidates.speed,
            candidates.angle_deg,
        )
        != ""
    )


def _usable(jacs, rebound, stable, n_cand: int, n: int) -> tuple:
    """The usable candidates (rebound, away from the capture threshold, finite Jacobian), and
    those dropped as captured or near the threshold; too few usable: ``FitError``."""
    # jacs: (draws or 1, n_cand * observables, p)
    dropped_captured = np.flatnonzero(~rebound)
    dropped_near = np.flatnonzero(rebound & ~stable)
    usable = np.flatnonzero(
        rebound & stable & np.all(np.isfinite(jacs.reshape(len(jacs), n_cand, -1)), axis=(0, 2))
    )
    if n > len(usable):
        raise FitError(
            f"n = {n} but only {len(usable)} usable candidates ({len(dropped_captured)} "
            f"captured, {len(dropped_near)} near the capture threshold dropped)"
        )
    return usable, dropped_captured, dropped_near


def _check_options(observables, sigma, n, ridge, perturbation) -> tuple[tuple, dict]:
    """``design``'s options checked (``FitError``); the observables and sigmas."""
    observables = tuple(observables)
    if not observables:
        raise FitError("observables: name at least one of " + ", ".join(DESIGN_OBSERVABLES))
    for o in observables:
        if o not in DESIGN_OBSERVABLES:
            raise FitError(
                f"observables: unknown or unusable {o!r}; allowed: {', '.join(DESIGN_OBSERVABLES)}"
            )
    sigma = dict(sigma or {})
    for o, s in sigma.items():
        if o not in observables:
            raise FitError(f"sigma given for {o!r}, which is not among the observables")
        if not (math.isfinite(s) and s > 0):
            raise FitError(f"sigma of {o} must be finite and > 0, got {number_text(s)}")
    if not (isinstance(n, int | np.integer) and n >= 1):
        raise FitError(f"n must be an integer >= 1, got {number_text(n)}")
    if not (ridge > 0 and math.isfinite(ridge)):
        raise FitError(f"ridge must be > 0, got {number_text(ridge)}")
    if not 0 < perturbation < 1:
        raise FitError(f"perturbation must be in (0, 1), got {number_text(perturbation)}")
    return observables, sigma


def _candidates(candidates, observables) -> tuple:
    """The candidate impacts (read if a path) and their source, checked for the design."""
    source = ""
    if not isinstance(candidates, ImpactTable):
        source = str(candidates)
        candidates = read_impacts(candidates)
    if candidates.overrides:
        raise FitError(
            f"{source or 'candidates'}: per-impact parameter columns "
            f"({', '.join(candidates.overrides)}) are not supported in a design"
        )
    if "cor_t" in observables and np.any(candidates.angle_deg == 0):
        rows = np.flatnonzero(candidates.angle_deg == 0)
        if candidates.lines is not None:
            where = "line " + ", ".join(str(int(candidates.lines[i])) for i in rows[:5])
        else:
            where = "row " + ", ".join(str(int(i)) for i in rows[:5])
        more = f" and {len(rows) - 5} more" if len(rows) > 5 else ""
        raise FitError(
            f"{source or 'candidates'}, {where}{more}: angle_deg = 0, where cor_t (an "
            "observable) is undefined; remove the normal impacts or leave cor_t out"
        )

    return candidates, source


def _jacobians(program, names, theta, scale, perturbation, at_draws) -> tuple:
    """The Jacobians in ln p of every candidate's observables (at ``theta``, or at each draw),
    which candidates rebound, and which stay on the same side of the capture threshold when
    a parameter moves by ``perturbation`` (or at every draw)."""
    rebound_code = jaximpact.Status.REBOUND

    def at(th):
        """Jacobian in ln p (the solver variable u is ln p except for bounded parameters) and
        status of every candidate at parameter values ``th``."""
        _, jac, status = program(to_unbounded(names, th)[None], value=0.0, scale=scale)
        return jac[0] * (th / dphys_du(names, th))[None, :], status[0]

    jac, status = at(theta)
    rebound = status == rebound_code
    stable = rebound.copy()
    u0 = to_unbounded(names, theta)
    for i in range(len(names)):
        for sign in (-1.0, 1.0):
            u = u0.copy()
            u[i] = to_unbounded([names[i]], [theta[i] * (1 + sign * perturbation)])[0]
            _, _, st = program(u[None], value=0.0, scale=scale)
            stable &= (st[0] == rebound_code) == rebound
    if at_draws is None:
        jacs = jac[None]
    else:  # the information at every draw; captured at any draw: near the threshold
        per_draw = [at(th) for th in at_draws]
        jacs = np.stack([j for j, _ in per_draw])
        for _, st in per_draw:
            stable &= st == rebound_code
    return jacs, rebound, stable


def _draw_subset(draws, names, max_draws: int):
    """``max_draws`` evenly spaced rows ``(k, p)`` of the draws (an array or a
    `PosteriorResult`), or None without draws."""
    if draws is None:
        return None
    if hasattr(draws, "draws") and hasattr(draws, "params"):  # a PosteriorResult
        if tuple(draws.params) != tuple(names):
            raise FitError(f"draws are of {tuple(draws.params)}, not of {tuple(names)}")
        draws = np.asarray(draws.draws).reshape(-1, len(names))
    draws = np.asarray(draws, dtype=float)
    if draws.ndim != 2 or draws.shape[1] != len(names) or len(draws) == 0:
        raise FitError(f"draws must be an array (draws, {len(names)}) for {', '.join(names)}")
    if not np.all(np.isfinite(draws)):
        raise FitError("draws must be finite")
    if not (isinstance(max_draws, int | np.integer) and max_draws >= 1):
        raise FitError(f"max_draws must be an integer >= 1, got {number_text(max_draws)}")
    pick = np.linspace(0, len(draws) - 1, min(max_draws, len(draws))).round().astype(int)
    return draws[pick]


def write_design(path, result: DesignResult) -> None:
    """DESIGN.csv: the chosen impacts in the order chosen, with ``gain_logdet`` (nats added to
    ``log det`` of the information) and ``log_det`` after the pick; atomically."""
    t = result.candidates
    lines = [
        "# jaximpact design: greedy D-optimal (fitting._design) for "
        + ", ".join(result.params)
        + "; observables "
        + ", ".join(result.observables),
        "order,speed,angle_deg,omega0,gain_logdet,log_det",
    ]
    for k, i in enumerate(result.chosen):
        lines.append(
            f"{k + 1},{float(t.speed[i])!r},{float(t.angle_deg[i])!r},{float(t.omega0[i])!r},"
            f"{result.gain[k]:.6g},{result.log_det[k]:.6g}"
        )
    atomic_write_text(path, "\n".join(lines) + "\n")

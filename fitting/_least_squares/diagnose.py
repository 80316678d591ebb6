"""The diagnosis of a least-squares optimum from its Jacobian: standard errors, covariance and
correlation, rank and identifiability, and the misfit test."""

import math

import numpy as np

from .program import _count
from .transforms import dphys_du

#: Identifiability: a singular value of ``J`` below ``1/MAX_CONDITION`` of the largest is zero
#: (rank deficient); a parameter whose share of such a direction exceeds ``NULL_SHARE``, or
#: whose standard error exceeds ``MAX_RELATIVE_STDERR`` of its value, is named as not
#: identified; correlations beyond ``MAX_CORRELATION`` are warned about.
MAX_CORRELATION = 0.95
MAX_CONDITION = 1e8
NULL_SHARE = 0.1
#: A parameter whose standard error exceeds this fraction of its value is not determined.
MAX_RELATIVE_STDERR = 1.0
#: A parameter whose sensitivity ``|dr/d ln p|`` (default scales per unit change of ``ln p``)
#: is below this is not determined whatever the condition number says: doubling it moves no
#: residual by more than 1e-8 of a scale (friction of an impact that rolls from the start:
#: 1.4e-15, where a one-parameter Jacobian's condition number is 1).
MIN_SENSITIVITY = 1e-8

#: Misfit with sigmas: chi-square p-value below this and reduced chi-square above
#: ``MISFIT_CHI2``; without sigmas: rms residual above ``MISFIT_RMS`` default scales.
MISFIT_P_VALUE = 1e-4
MISFIT_CHI2 = 2.0
MISFIT_RMS = 10.0


def _diagnose(jac, cost, n, names, theta, sigma_known) -> dict:
    """Uncertainty, identifiability and misfit from the Jacobian ``jac`` in ``u`` at the optimum.

    Returns a dict: ``stderr``, ``covariance``, ``correlation``, ``rank``,
    ``condition_number``, ``singular_values``, ``sensitivity``, ``unidentifiable``,
    ``reduced_chi2``, ``p_value``, ``residual_scale``, and the messages ``warnings``,
    ``undetermined`` and ``misfit`` (lists of strings).
    """
    p = len(names)
    dpdu = dphys_du(names, theta)
    warnings, undetermined, misfit = [], [], []
    nan_pp = np.full((p, p), np.nan)
    out = {
        "stderr": dict.fromkeys(names, math.nan),
        "covariance": nan_pp,
        "correlation": nan_pp.copy(),
        "rank": 0,
        "condition_number": math.inf,
        "singular_values": np.full(p, np.nan),
        "sensitivity": dict.fromkeys(names, math.nan),
        "unidentifiable": list(names),
        "reduced_chi2": math.nan,
        "p_value": math.nan,
        "residual_scale": math.nan,
    }
    s2 = _residual_variance(out, cost, n, p, sigma_known, undetermined, misfit)
    if not np.all(np.isfinite(jac)):
        undetermined.append("the Jacobian is not finite at the optimum")
        out.update(warnings=warnings, undetermined=undetermined, misfit=misfit)
        return out
    sv, vt, keep, bad = _rank(out, jac, names, theta, dpdu, undetermined)
    corr = _covariance(out, names, dpdu, sv, vt, keep, bad, s2)
    if out["rank"] == p and not all(math.isfinite(e) for e in out["stderr"].values()):
        if not undetermined:
            undetermined.append("the standard errors are not finite")
    _loose(out, names, theta, vt, undetermined)
    if out["rank"] == p:
        for i in range(p):
            for j in range(i + 1, p):
                if abs(corr[i, j]) > MAX_CORRELATION:
                    warnings.append(
                        f"strongly correlated: {names[i]} and {names[j]} (corr "
                        f"{corr[i, j]:+.3f}); the data determine a combination of them "
                        "better than each one"
                    )
    out.update(warnings=warnings, undetermined=undetermined, misfit=misfit)
    return out


def _residual_variance(out, cost, n, p, sigma_known, undetermined, misfit) -> float:
    """The residual variance ``s2`` (1 with sigmas given); the misfit test into ``out``."""
    dof = n - p
    if sigma_known:
        s2 = 1.0
    elif dof > 0:
        s2 = 2 * cost / dof
    else:
        s2 = math.nan
        undetermined.append(
            f"{_count(n, 'observation')} for {_count(p, 'parameter')} and no sigmas: no "
            "residual variance, so no standard errors"
        )
    out["residual_scale"] = math.sqrt(s2) if math.isfinite(s2) else math.nan

    if sigma_known and dof > 0 and math.isfinite(cost):
        from scipy.stats import chi2

        out["reduced_chi2"] = 2 * cost / dof
        out["p_value"] = float(chi2.sf(2 * cost, dof))
        if out["p_value"] < MISFIT_P_VALUE and out["reduced_chi2"] > MISFIT_CHI2:
            misfit.append(
                f"the model does not describe the data: reduced chi-square "
                f"{out['reduced_chi2']:.3g} for {dof} degrees of freedom (expected 1 +- "
                f"{math.sqrt(2 / dof):.2g}; p = {out['p_value']:.2g})"
            )
    elif not sigma_known and dof > 0 and math.isfinite(s2) and math.sqrt(s2) > MISFIT_RMS:
        misfit.append(
            f"the model does not describe the data: the residuals are {math.sqrt(s2):.3g} "
            f"default scales (rms, {dof} degrees of freedom), more than {MISFIT_RMS:g} (with "
            "sigmas given, this would be a reduced chi-square of about "
            f"{s2:.3g})"
        )
    return s2


def _rank(out, jac, names, theta, dpdu, undetermined) -> tuple:
    """Sensitivities, singular values, rank and the parameters in undetermined directions
    into ``out``; returns ``sv, vt`` (the SVD), ``keep`` (the directions kept) and ``bad``
    (the parameters not identified)."""
    p = len(names)
    # Sensitivity per relative change: |dr/d ln p| = |dr/du| p / (dp/du).
    with np.errstate(divide="ignore", invalid="ignore"):
        sens = np.linalg.norm(jac, axis=0) * np.abs(theta) / np.abs(dpdu)
    out["sensitivity"] = {nm: float(v) for nm, v in zip(names, sens, strict=True)}
    # Every one of the p directions, also where there are fewer residuals than parameters:
    # the directions no residual sees have singular value 0 (a full V, zeros appended).
    _, sv, vt = np.linalg.svd(jac, full_matrices=True)
    sv = np.concatenate([sv, np.zeros(p - sv.size)])
    out["singular_values"] = sv
    keep = sv > sv[0] / MAX_CONDITION if sv[0] > 0 else np.zeros(p, bool)
    out["rank"] = int(np.sum(keep))
    out["condition_number"] = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    null = vt[~keep]
    bad = np.any(np.abs(null) > NULL_SHARE, axis=0) if null.size else np.zeros(p, bool)
    insensitive = np.isfinite(sens) & (sens < MIN_SENSITIVITY) & ~bad
    bad = bad | insensitive
    out["unidentifiable"] = [nm for nm, b in zip(names, bad, strict=True) if b]
    if insensitive.any():
        undetermined.append(
            "the data do not determine "
            + ", ".join(
                f"{nm} (sensitivity |dr/d ln p| {sens[i]:.2g} scales, below "
                f"{MIN_SENSITIVITY:g}: changing it moves no residual)"
                for i, nm in enumerate(names)
                if insensitive[i]
            )
        )
    if out["rank"] < p:
        combos = []
        for v in null:
            terms = [
                f"{v[j]:+.2f} {names[j]}" for j in np.argsort(-np.abs(v)) if abs(v[j]) > NULL_SHARE
            ]
            combos.append(" ".join(terms))
        cond = out["condition_number"]
        why = (
            f"{_count(int(np.sum(sv == 0)), 'direction')} with no sensitivity at all"
            if not math.isfinite(cond)
            else f"condition number {cond:.3g}, above the limit {MAX_CONDITION:g}"
        )
        undetermined.append(
            f"the data do not determine {', '.join(out['unidentifiable'])}: the Jacobian has "
            f"rank {out['rank']} of {p} ({why}); undetermined direction(s) in "
            "log-parameters: " + "; ".join(combos)
        )
    return sv, vt, keep, bad


def _covariance(out, names, dpdu, sv, vt, keep, bad, s2) -> np.ndarray:
    """Covariance, correlation and standard errors into ``out`` (NaN/inf for the parameters
    not identified); returns the correlation."""
    inv = np.where(keep, 1.0 / np.where(keep, sv, 1.0) ** 2, 0.0)
    cov_u = (vt.T * inv) @ vt * s2
    cov_u[bad, :] = np.nan
    cov_u[:, bad] = np.nan
    cov_u[bad, bad] = np.inf
    cov = cov_u * np.outer(dpdu, dpdu)
    d = np.sqrt(np.abs(np.diag(cov_u)))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_u / np.outer(d, d)
    np.fill_diagonal(corr, np.where(np.isfinite(np.diag(cov_u)), 1.0, np.nan))
    out["covariance"], out["correlation"] = cov, corr
    out["stderr"] = {
        nm: float(np.sqrt(cov[i, i])) if cov[i, i] >= 0 else math.nan for i, nm in enumerate(names)
    }
    return corr


def _loose(out, names, theta, vt, undetermined) -> None:
    """Full rank, but a standard error beyond the value itself: not determined either."""
    p = len(names)
    rel = {
        nm: out["stderr"][nm] / abs(v) if v != 0 else math.inf
        for nm, v in zip(names, theta, strict=True)
    }
    loose = [nm for nm in names if math.isfinite(rel[nm]) and rel[nm] > MAX_RELATIVE_STDERR]
    if out["rank"] == p and loose:
        v = vt[-1]
        combo = " ".join(
            f"{v[j]:+.2f} {names[j]}" for j in np.argsort(-np.abs(v)) if abs(v[j]) > NULL_SHARE
        )
        undetermined.append(
            f"the data do not determine {', '.join(loose)}: relative standard error "
            + ", ".join(f"{100 * rel[nm]:.3g} %" for nm in loose)
            + f" (> {100 * MAX_RELATIVE_STDERR:g} %); the least determined direction in "
            f"log-parameters is {combo} (condition number {out['condition_number']:.3g})"
        )
        out["unidentifiable"] = [nm for nm in names if nm in loose]

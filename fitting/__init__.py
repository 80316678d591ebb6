"""fitting: identify contact parameters (C_A, C_H, f0, friction, K, lambda) from rebound data.

Typical use::

    import jax; jax.config.update("jax_enable_x64", True)
    import jaximpact, fitting
    obs = fitting.load_observations("data.csv")
    result = fitting.fit(jaximpact.table1_scene(), obs, ["C_A", "C_H", "f0"], starts=3)
    print(fitting.summary(result))
    fitting.write_json("fit.json", result); fitting.plot_fit("fit.png", result)

or, from the shell, ``jaximpact fit [SCENE.toml] DATA.csv --params C_A C_H f0``.
"""

import importlib

# The public names and the modules that define them, imported on first use (PEP 562): the
# ``jaximpact`` command loads ``fitting.cli`` for its ``fit`` command at every start, and an
# eager import of the samplers (scipy.stats, arviz) cost every command about 0.6 s.
_EXPORTS = {
    "LOO": "._bayesian.loo",
    "compare_models": "._bayesian.loo",
    "exact_loo_refits": "._bayesian.loo",
    "loo": "._bayesian.loo",
    "pointwise_log_likelihood": "._bayesian.loo",
    "refit_without": "._bayesian.loo",
    "PosteriorResult": "._bayesian.posterior",
    "posterior_predictive": "._bayesian.posterior",
    "prepare_posterior": "._bayesian.posterior",
    "sample_posterior": "._bayesian.posterior",
    "PRIOR_RANGES": "._bayesian.priors",
    "Prior": "._bayesian.priors",
    "plot_corner": "._bayesian.report",
    "plot_predictive": "._bayesian.report",
    "posterior_summary": "._bayesian.report",
    "write_draws": "._bayesian.report",
    "OBSERVABLES": "._data",
    "DataError": "._data",
    "Observations": "._data",
    "kharaz2001_path": "._data",
    "load_kharaz2001": "._data",
    "load_observations": "._data",
    "DesignResult": "._design",
    "design": "._design",
    "log_det_information": "._design",
    "write_design": "._design",
    "BOUNDS": "._least_squares.fit",
    "SOLVERS": "._least_squares.fit",
    "STATUSES": "._least_squares.fit",
    "FitResult": "._least_squares.fit",
    "StartResult": "._least_squares.fit",
    "fit": "._least_squares.fit",
    "to_physical": "._least_squares.fit",
    "to_unbounded": "._least_squares.fit",
    "DEFAULT_SCALES": "._least_squares.objective",
    "FITTABLE": "._least_squares.objective",
    "FitError": "._least_squares.objective",
    "Objective": "._least_squares.objective",
    "Profile": "._least_squares.profile",
    "plot_profile": "._least_squares.profile",
    "profile": "._least_squares.profile",
    "ResidualProgram": "._least_squares.program",
    "plot_fit": "._least_squares.report",
    "result_dict": "._least_squares.report",
    "summary": "._least_squares.report",
    "write_json": "._least_squares.report",
    "kharaz2001_scene": "._scenes",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'fitting' has no attribute {name!r}")
    value = getattr(importlib.import_module(_EXPORTS[name], __name__), name)
    globals()[name] = value  # the next access is a plain attribute
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))

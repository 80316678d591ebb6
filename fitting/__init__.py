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

from ._bayesian.loo import LOO as LOO
from ._bayesian.loo import compare_models as compare_models
from ._bayesian.loo import loo as loo
from ._bayesian.loo import pointwise_log_likelihood as pointwise_log_likelihood
from ._bayesian.posterior import PosteriorResult as PosteriorResult
from ._bayesian.posterior import posterior_predictive as posterior_predictive
from ._bayesian.posterior import sample_posterior as sample_posterior
from ._bayesian.priors import PRIOR_RANGES as PRIOR_RANGES
from ._bayesian.priors import Prior as Prior
from ._bayesian.report import plot_corner as plot_corner
from ._bayesian.report import plot_predictive as plot_predictive
from ._bayesian.report import posterior_summary as posterior_summary
from ._bayesian.report import write_draws as write_draws
from ._data import OBSERVABLES as OBSERVABLES
from ._data import DataError as DataError
from ._data import Observations as Observations
from ._data import kharaz2001_path as kharaz2001_path
from ._data import load_kharaz2001 as load_kharaz2001
from ._data import load_observations as load_observations
from ._design import DesignResult as DesignResult
from ._design import design as design
from ._design import log_det_information as log_det_information
from ._design import write_design as write_design
from ._least_squares.fit import BOUNDS as BOUNDS
from ._least_squares.fit import SOLVERS as SOLVERS
from ._least_squares.fit import STATUSES as STATUSES
from ._least_squares.fit import FitResult as FitResult
from ._least_squares.fit import StartResult as StartResult
from ._least_squares.fit import fit as fit
from ._least_squares.fit import to_physical as to_physical
from ._least_squares.fit import to_unbounded as to_unbounded
from ._least_squares.objective import DEFAULT_SCALES as DEFAULT_SCALES
from ._least_squares.objective import FITTABLE as FITTABLE
from ._least_squares.objective import FitError as FitError
from ._least_squares.objective import Objective as Objective
from ._least_squares.profile import Profile as Profile
from ._least_squares.profile import plot_profile as plot_profile
from ._least_squares.profile import profile as profile
from ._least_squares.program import ResidualProgram as ResidualProgram
from ._least_squares.report import plot_fit as plot_fit
from ._least_squares.report import result_dict as result_dict
from ._least_squares.report import summary as summary
from ._least_squares.report import write_json as write_json
from ._scenes import kharaz2001_scene as kharaz2001_scene

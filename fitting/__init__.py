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
from ._fit import BOUNDS as BOUNDS
from ._fit import SOLVERS as SOLVERS
from ._fit import STATUSES as STATUSES
from ._fit import FitResult as FitResult
from ._fit import StartResult as StartResult
from ._fit import fit as fit
from ._fit import to_physical as to_physical
from ._fit import to_unbounded as to_unbounded
from ._objective import DEFAULT_SCALES as DEFAULT_SCALES
from ._objective import FITTABLE as FITTABLE
from ._objective import FitError as FitError
from ._objective import Objective as Objective
from ._posterior import PosteriorResult as PosteriorResult
from ._posterior import posterior_predictive as posterior_predictive
from ._posterior import sample_posterior as sample_posterior
from ._posterior_report import plot_corner as plot_corner
from ._posterior_report import plot_predictive as plot_predictive
from ._posterior_report import posterior_summary as posterior_summary
from ._posterior_report import write_draws as write_draws
from ._priors import PRIOR_RANGES as PRIOR_RANGES
from ._priors import Prior as Prior
from ._profile import Profile as Profile
from ._profile import plot_profile as plot_profile
from ._profile import profile as profile
from ._program import ResidualProgram as ResidualProgram
from ._report import plot_fit as plot_fit
from ._report import result_dict as result_dict
from ._report import summary as summary
from ._report import write_json as write_json
from ._scenes import kharaz2001_scene as kharaz2001_scene

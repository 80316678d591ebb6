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
from ._program import ResidualProgram as ResidualProgram
from ._report import plot_fit as plot_fit
from ._report import result_dict as result_dict
from ._report import summary as summary
from ._report import write_json as write_json
from ._scenes import kharaz2001_scene as kharaz2001_scene

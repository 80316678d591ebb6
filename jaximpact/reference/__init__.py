"""Exact (switched, non-smooth) float64 reference implementation of the impact model, the
yardstick for the smooth JAX model. It depends on numpy and scipy only, imports nothing else
from ``jaximpact`` and works in SI units throughout. The model: docs/reference.md."""

from ._derivatives import DERIVATIVE_INPUTS as DERIVATIVE_INPUTS
from ._derivatives import DERIVATIVE_OUTPUTS as DERIVATIVE_OUTPUTS
from ._derivatives import capture_speed as capture_speed
from ._derivatives import output_derivatives as output_derivatives
from ._forces import contact_forces as contact_forces
from ._forces import hertz_scales as hertz_scales
from ._forces import normal_potential as normal_potential
from ._forces import ring_integrals as ring_integrals
from ._impact import impact_history as impact_history
from ._impact import simulate_impact as simulate_impact
from ._params import FRICTION_LOADS as FRICTION_LOADS
from ._params import ROLLING_MOMENTS as ROLLING_MOMENTS
from ._params import TABLE1_OMEGA0 as TABLE1_OMEGA0
from ._params import TABLE1_SPEED as TABLE1_SPEED
from ._params import ImpactResult as ImpactResult
from ._params import Params as Params
from ._params import table1_params as table1_params
from ._params import zeta_to_c as zeta_to_c

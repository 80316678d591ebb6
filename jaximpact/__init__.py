"""jaximpact: a differentiable simulator of microsphere impact (Brach, Dunn & Cheng 1999)."""

from ._engine.api import implausible_impacts as implausible_impacts
from ._engine.api import simulate as simulate
from ._engine.devices import use_all_cpu_cores as use_all_cpu_cores
from ._engine.results import ImpactResult as ImpactResult
from ._engine.results import Status as Status
from ._engine.sensitivity import output_jacobian as output_jacobian
from ._engine.settings import Integration as Integration
from ._engine.settings import integration_settings as integration_settings
from ._engine.settings import required_terms as required_terms
from ._engine.settings import scene_parameters as scene_parameters
from ._engine.settings import stiffness_estimate as stiffness_estimate
from ._io.cache import enable_compilation_cache as enable_compilation_cache
from ._io.scene_files import default_scene_path as default_scene_path
from ._io.scene_files import embedded_scenes as embedded_scenes
from ._io.scene_files import load_scene as load_scene
from ._io.scene_files import scene_from_dict as scene_from_dict
from ._io.scene_files import scene_path as scene_path
from ._model.scene import Contact as Contact
from ._model.scene import Impact as Impact
from ._model.scene import Model as Model
from ._model.scene import Particle as Particle
from ._model.scene import Scene as Scene
from ._model.scene import SceneError as SceneError
from ._model.scene import Solver as Solver
from ._model.scene import Target as Target
from ._model.scene import damping_from_zeta as damping_from_zeta
from ._model.scene import hertz_stiffness as hertz_stiffness
from ._model.scene import table1_scene as table1_scene
from .wall_law import CaptureSpeed as CaptureSpeed
from .wall_law import CaptureStatus as CaptureStatus
from .wall_law import WallLaw as WallLaw
from .wall_law import capture_speed as capture_speed
from .wall_law import wall_law as wall_law

__version__ = "0.1.0"

# JAX's persistent compilation cache on by default (``$JAXIMPACT_CACHE_DIR``, else the user
# cache directory; ``JAXIMPACT_CACHE_DIR=off`` or a cache directory of the user's own keeps it
# as it is): the first call of a new process loads what an earlier one compiled.
from ._io.cache import enable_default_cache as _enable_default_cache  # noqa: E402

_enable_default_cache()

"""jaximpact: a differentiable simulator of microsphere impact (Brach, Dunn & Cheng 1999)."""

from ._api import implausible_impacts as implausible_impacts
from ._api import simulate as simulate
from ._cache import enable_compilation_cache as enable_compilation_cache
from ._devices import use_all_cpu_cores as use_all_cpu_cores
from ._results import ImpactResult as ImpactResult
from ._results import Status as Status
from ._scene import Contact as Contact
from ._scene import Impact as Impact
from ._scene import Model as Model
from ._scene import Particle as Particle
from ._scene import Scene as Scene
from ._scene import SceneError as SceneError
from ._scene import Solver as Solver
from ._scene import damping_from_zeta as damping_from_zeta
from ._scene import hertz_stiffness as hertz_stiffness
from ._scene import table1_scene as table1_scene
from ._scene_io import default_scene_path as default_scene_path
from ._scene_io import embedded_scenes as embedded_scenes
from ._scene_io import load_scene as load_scene
from ._scene_io import scene_from_dict as scene_from_dict
from ._scene_io import scene_path as scene_path
from ._sensitivity import output_jacobian as output_jacobian
from ._simulate import Integration as Integration
from ._simulate import integration_settings as integration_settings
from ._simulate import required_terms as required_terms
from ._simulate import scene_parameters as scene_parameters
from ._simulate import stiffness_estimate as stiffness_estimate
from .wall_law import CaptureSpeed as CaptureSpeed
from .wall_law import CaptureStatus as CaptureStatus
from .wall_law import WallLaw as WallLaw
from .wall_law import capture_speed as capture_speed
from .wall_law import wall_law as wall_law

__version__ = "0.1.0"

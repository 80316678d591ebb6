"""jaximpact: a differentiable simulator of microsphere impact (Brach, Dunn & Cheng 1999).

The public names are imported on first use (``import jaximpact`` itself imports JAX and
nothing else that a call may not need: the solver libraries, the wall law and the file
readers come with the first name that uses them).
"""

import importlib
import importlib.util
import sys
import types

__version__ = "0.1.0"

# public name -> the module that defines it (imported on first use)
_EXPORTS = {
    "implausible_impacts": "._engine.api",
    "simulate": "._engine.api",
    "use_all_cpu_cores": "._engine.devices",
    "ImpactResult": "._engine.results",
    "Status": "._engine.results",
    "output_jacobian": "._engine.sensitivity",
    "Integration": "._engine.settings",
    "integration_settings": "._engine.settings",
    "required_terms": "._engine.settings",
    "scene_parameters": "._engine.settings",
    "stiffness_estimate": "._engine.settings",
    "enable_compilation_cache": "._io.cache",
    "default_scene_path": "._io.scene_files",
    "embedded_scenes": "._io.scene_files",
    "load_scene": "._io.scene_files",
    "scene_from_dict": "._io.scene_files",
    "scene_path": "._io.scene_files",
    "Contact": "._model.scene",
    "Impact": "._model.scene",
    "Model": "._model.scene",
    "Particle": "._model.scene",
    "Scene": "._model.scene",
    "SceneError": "._model.scene",
    "Solver": "._model.scene",
    "Target": "._model.scene",
    "damping_from_zeta": "._model.scene",
    "hertz_stiffness": "._model.scene",
    "table1_scene": "._model.scene",
    "CaptureSpeed": ".wall_law",
    "CaptureStatus": ".wall_law",
    "WallLaw": ".wall_law",
    "capture_speed": ".wall_law",
    "wall_law": ".wall_law",
}
__all__ = list(_EXPORTS)


class _Package(types.ModuleType):
    """The package's module type: a public name is imported where it is first asked for."""

    def __getattr__(self, name):
        if name not in _EXPORTS:
            # a subpackage (``jaximpact.reference``) as an attribute, as before
            if name.startswith("__") or importlib.util.find_spec(f"{__name__}.{name}") is None:
                raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
            return importlib.import_module(f"{__name__}.{name}")
        value = getattr(importlib.import_module(_EXPORTS[name], __name__), name)
        self.__dict__[name] = value
        return value

    def __setattr__(self, name, value):
        # Python sets a subpackage as an attribute of its parent when it is first imported:
        # ``jaximpact.wall_law`` stays the function, as it was before names were imported on
        # first use (the subpackage is ``sys.modules["jaximpact.wall_law"]``).
        if name in _EXPORTS and getattr(value, "__name__", None) == f"{__name__}.{name}":
            value = getattr(value, name)
        super().__setattr__(name, value)

    def __dir__(self):
        return sorted({*super().__dir__(), *_EXPORTS})


sys.modules[__name__].__class__ = _Package

# JAX's persistent compilation cache on by default (``$JAXIMPACT_CACHE_DIR``, else the user
# cache directory; ``JAXIMPACT_CACHE_DIR=off`` or a cache directory of the user's own keeps it
# as it is): the first call of a new process loads what an earlier one compiled.
from ._io.cache import enable_default_cache as _enable_default_cache  # noqa: E402

_enable_default_cache()

# Step loops compiled as single kernels where JAX's backends have not started and nobody chose
# XLA's loop options (``JAXIMPACT_XLA_OPTIONS=off`` leaves them alone): ``_engine.devices``.
from ._engine.devices import loop_kernels_at_import as _loop_kernels_at_import  # noqa: E402

_loop_kernels_at_import()

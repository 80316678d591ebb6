"""The arguments of ``simulate`` checked before anything is converted: the scene's type, the
impact arguments' kinds and every shape that must broadcast (scene parameters included)."""

import numpy as np

from .scene import Scene, SceneError, _argument_shape

#: The scene's float parameters, by field name, as ``simulate`` broadcasts them.
SCENE_ARRAYS = (
    ("particle", "radius"),
    ("particle", "density"),
    ("contact", "K"),
    ("contact", "f0"),
    ("contact", "C_A"),
    ("contact", "C_H"),
    ("contact", "friction"),
    ("contact", "G_star"),
    ("contact", "w"),
    ("contact", "p_y"),
    ("contact", "eta_n"),
    ("model", "lambda_"),
    ("target", "radius"),
    ("target", "density"),
    ("target", "omega0"),
)


def check_simulate_arguments(scene, speed=None, angle_deg=None, omega0=None) -> None:
    """Check what ``simulate`` was given before anything is converted, naming the argument:
    a scene that is not a `Scene`, an impact argument that is text, booleans or empty, and
    arguments and scene parameters whose shapes do not broadcast together. Traced arguments
    pass (only their shapes are checked); the values are checked by `check_impact`.

    Raises:
        SceneError: naming the argument (and, for shapes, every non-scalar one).
    """
    if not isinstance(scene, Scene):
        raise SceneError(
            "scene must be a jaximpact.Scene (jaximpact.load_scene(NAME or PATH), "
            f"jaximpact.table1_scene()), got {type(scene).__name__}"
        )
    shapes = {}
    for name, value in (("speed", speed), ("angle_deg", angle_deg), ("omega0", omega0)):
        if value is not None:
            shapes[name] = _argument_shape(name, value)
    for section, field in SCENE_ARRAYS:
        if getattr(scene, section) is None:
            continue
        shapes[f"{section}.{field.rstrip('_')}"] = tuple(
            np.shape(getattr(getattr(scene, section), field))
        )
    try:
        np.broadcast_shapes(*shapes.values())
    except ValueError:
        given = ", ".join(f"{name} {shape}" for name, shape in shapes.items() if shape)
        raise SceneError(
            f"shapes that do not broadcast together: {given}; give scalars, or arrays of one "
            "shape (one value per impact)"
        ) from None

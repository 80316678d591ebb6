"""The public ``simulate`` (its arguments checked by name before anything is converted) and
the plausibility flags of its results."""

import functools

import numpy as np

from .._model.arguments import check_simulate_arguments
from .._model.ranges import implausible
from . import simulate as _simulate


@functools.wraps(_simulate.simulate)
def simulate(scene, speed=None, angle_deg=None, omega0=None, **options):
    check_simulate_arguments(scene, speed, angle_deg, omega0)
    return _simulate.simulate(scene, speed, angle_deg, omega0, **options)


def implausible_impacts(scene, result, speed=None, angle_deg=None) -> np.ndarray:
    """The plausibility flag of each impact of ``simulate(scene, speed, angle_deg, ...)``:
    ``"large_overlap"`` where the maximum overlap exceeds 0.1 of the radius (beyond the
    small-strain range of Hertz contact; docs/input_ranges.md), else ``""``.

    The simulated ``result.max_overlap`` is used where it is known; where it is not (a failed
    impact, or ``solver.outputs = "rebound"``) the elastic Hertz estimate from ``speed`` and
    ``angle_deg`` (default: the scene's ``[impact]``). Concrete values only (numpy).
    """
    speed = scene.impact.speed if speed is None else speed
    angle_deg = scene.impact.angle_deg if angle_deg is None else angle_deg
    flags = implausible(
        scene.particle.radius,
        result.max_overlap,
        scene.particle.density,
        scene.contact.K,
        speed,
        angle_deg,
    )
    return np.broadcast_to(flags, np.shape(result.status)).copy()

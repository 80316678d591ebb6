"""The input checks of :func:`capture_speed` (``SceneError``)."""

import jax
import numpy as np

from .._model.scene import SceneError

SPEED_MAX = 1000.0  # m/s, the top of the speed range (docs/input_ranges.md)


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _checked_options(scene, rtol, speed_range):
    """``capture_speed``'s scene and options checked (``SceneError``); the speed range as
    floats."""
    if scene.target is not None:  # the scan and the margin are those of a wall
        raise SceneError(
            "capture_speed is the capture of impacts on a wall; the scene has a [target] "
            "sphere (remove it)"
        )
    if not 0 < rtol < 1e-2:
        raise SceneError(f"rtol must be in (0, 0.01), got {rtol!r}")
    if speed_range is not None:
        lo, hi = (float(x) for x in speed_range)
        if not 0 < lo < hi <= SPEED_MAX:
            raise SceneError(f"speed_range must satisfy 0 < lo < hi <= {SPEED_MAX:g} m/s")
        speed_range = (lo, hi)
    return speed_range


def _checked_concrete(values, angle, omega) -> tuple[np.ndarray, np.ndarray]:
    """The search's inputs checked concrete and in range (``SceneError``); the angle and spin
    as numpy arrays."""
    leaves = [*values, angle, omega]
    if not all(_is_concrete(x) for x in leaves):
        raise SceneError(
            "capture_speed needs concrete values: call it outside jax.jit and jax.vmap "
            "(jax.grad, jax.jacfwd and jax.jvp work; pass arrays to batch)"
        )
    a, w = np.asarray(angle, dtype=float), np.asarray(omega, dtype=float)
    if not np.all(np.isfinite(a) & (np.abs(a) < 90.0)):
        raise SceneError("angle_deg must be finite and in (-90, 90) deg")
    if not np.all(np.isfinite(w) & (np.abs(w) <= 1e9)):
        raise SceneError("omega0 must be finite and in [-1e9, 1e9] rad/s")
    return a, w

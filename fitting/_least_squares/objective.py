"""The fitting objective: weighted residuals of observed impacts against ``jaximpact.simulate``.

Every distinct observed impact is simulated once, all of them in one batched, jitted call; each
observation then picks its impact's output. A residual is ``(model - observed) / scale``, where
``scale`` is the observation's ``sigma`` when the data give one, else a documented default
(:data:`DEFAULT_SCALES`), so that observables in different units balance.

Captures have no rebound to compare, so the model's normal restitution is continued below
zero for an impact the model captures: ``cor_n = -(1 + depth) / 2`` with the capture depth
``depth = exp(-T_c / T_H)``, where ``T_c`` is the time at which the capture is declared and
``T_H`` the undamped Hertz contact time of that impact (``2.94 n*/v_n``,
``n* = (5 m v_n^2 / (4 K sqrt(r)))^(2/5)``). A deeper capture (more damping, stronger
adhesion) is mostly declared earlier, so the continued value falls toward -1; it is never above
-1/2, so a capture always costs more than any rebound with ``cor_n >= 0`` and a step into the
capture region is never preferred to staying out. It has a gradient, so that a fit started
where the model captures impacts that the data show rebounding walks out of the capture
region instead of stopping there (where the capture is declared very late, ``T_c >> T_H``,
the gradient fades: a fit stuck there ends with a zero-sensitivity diagnosis, not a claim).

* ``cor_n`` observed: residual ``(cor_n - observed) / scale`` with the continued ``cor_n``;
* ``captured`` observed (1 for a captured sphere, 0 for a rebound) -- a smooth one-sided
  constraint: observed captured: ``max(cor_n, 0) / scale`` (zero once the model captures, else
  a pull toward capture); observed rebound: ``max(scale - cor_n, 0) / scale`` (zero while the
  model rebounds with ``cor_n >= scale``, ``(scale + (1 + depth)/2) / scale`` while it
  captures). ``scale`` is ``sigma`` if given, else 0.01;
* any other rebound quantity (``cor_t``, ``vt_out``, ``omega_out``, ``rebound_angle_deg``)
  observed at an impact the model captures: ``failure_residual * (1 + depth) / 2`` with
  ``depth = exp(-T_c / T_H)``: large, and falling toward the capture threshold.

A failed simulation (step limit, non-finite state) or a model output that does not exist where
the data have a value gives the large finite residual ``failure_residual`` (default 1e3, i.e. a
thousand scales), never NaN, with zero gradient.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

import jaximpact
from jaximpact import scene_parameters, stiffness_estimate
from jaximpact._engine.simulate import _simulate
from jaximpact.parameters import FITTABLE as FITTABLE_NAMES
from jaximpact.parameters import parameter_value, place, unused_reason, with_parameters

from .._data import OBSERVABLES, Observations, load_observations

__all__ = [
    "DEFAULT_SCALES",
    "FITTABLE",
    "FitError",
    "Objective",
    "default_scales",
    "get_parameter",
    "set_parameters",
]


class FitError(ValueError):
    """A problem with a fit's inputs: unknown parameter, unusable data, bad option."""


#: Fittable parameters: ``name -> (scene section, field)``, in the order of the registry
#: (``jaximpact.parameters``: each one's unit, range, default prior and transform).
FITTABLE = {name: place(name) for name in FITTABLE_NAMES}

#: Default residual scales (used where an observation has no sigma), as text for reports.
DEFAULT_SCALES = {
    "cor_n": "0.01",
    "cor_t": "0.01",
    "vt_out": "0.01 * speed (m/s)",
    "omega_out": "0.01 * speed / radius (rad/s)",
    "rebound_angle_deg": "1 degree",
    "captured": "0.01 (a margin on cor_n; see fitting._objective)",
}

# Model outputs an observation can compare with, in this order; "captured" uses cor_n.
_OUTPUTS = ("cor_n", "cor_t", "vt_out", "omega_out", "rebound_angle_deg")


def default_scales(observable, speed, radius) -> np.ndarray:
    """The default scale of each observation (see :data:`DEFAULT_SCALES`).

    Arguments:
        observable: observable names (array of str).
        speed: impact speed of each observation (m/s).
        radius: sphere radius for each observation (m).

    Returns:
        np.ndarray: the scales, in the observable's unit.
    """
    observable = np.asarray(observable)
    speed = np.asarray(speed, dtype=float)
    radius = np.broadcast_to(np.asarray(radius, dtype=float), speed.shape)
    scale = np.full(speed.shape, 0.01)
    scale = np.where(observable == "vt_out", 0.01 * speed, scale)
    scale = np.where(observable == "omega_out", 0.01 * speed / radius, scale)
    return np.where(observable == "rebound_angle_deg", 1.0, scale)


def check_names(params: Sequence[str], scene: jaximpact.Scene | None = None) -> tuple[str, ...]:
    """Validate parameter names (and, given the scene, that it uses each of them).

    Raises:
        FitError: no names, an unknown name, a repeated name, ``G_star`` for a scene
            without the Mindlin tangential spring, ``w`` without the DMT law or ``f0`` with it.
    """
    params = tuple(params)
    if not params:
        raise FitError("no parameters to fit; name some of: " + ", ".join(FITTABLE))
    for name in params:
        if name not in FITTABLE:
            raise FitError(f"unknown parameter {name!r}; fittable: {', '.join(FITTABLE)}")
    if len(set(params)) != len(params):
        raise FitError(f"parameter named twice in {list(params)}")
    for name in params if scene is not None else ():
        reason = unused_reason(scene, name)
        if reason is not None:
            raise FitError(reason)
    return params


def get_parameter(scene: jaximpact.Scene, name: str) -> float:
    """The scene's value of a fittable parameter (a float; must be a scalar)."""
    if name not in FITTABLE:
        raise KeyError(name)
    value = np.asarray(parameter_value(scene, name), dtype=float)
    if value.ndim != 0:
        raise FitError(f"scene parameter {name} is an array; a fitted parameter must be scalar")
    return float(value)


def set_parameters(scene: jaximpact.Scene, values: Mapping[str, object]) -> jaximpact.Scene:
    """A copy of ``scene`` with parameters (fittable names; floats or traced arrays) replaced."""
    unknown = [name for name in values if name not in FITTABLE]
    if unknown:
        raise KeyError(unknown[0])
    return with_parameters(scene, values)


@jax.jit
def _batched_stiffness(params, speed, angle_deg):
    return jax.vmap(stiffness_estimate, in_axes=(0, None, None))(params, speed, angle_deg)


class Objective:
    """Weighted residuals of observations against the model, as a function of the parameters.

    **Arguments:**
    - `scene`: the `jaximpact.Scene` giving every parameter that is not fitted.
    - `observations`: an `Observations` (see `load_observations`) or a path to a data file.
    - `params`: names of the fitted parameters (keys of :data:`FITTABLE`).
    - `failure_residual`: residual of a failed simulation or missing model output (scales).
    - `method`: ODE method for the fit; default: the scene's, where ``"auto"`` is resolved
      once from the stiffness at ``check_values`` (or the scene's values) since the choice
      cannot be made on traced values.
    - `check_values`: parameter sets (dicts) at which the stiffness is estimated.
    - `loop`: the simulator's step loop for the values (``jaximpact._engine.simulate``'s
      ``_simulate``); default its ``default_loop``. ``"pool"`` refills lanes as impacts
      finish: for batches whose impacts need very different step counts (a posterior's
      points from the prior).

    Call :meth:`residuals` with the physical parameter values (a 1-D array in `params` order).
    The residual function is jitted once; new values do not recompile it.

    **Raises:** `FitError` for unknown or repeated parameter names, no usable observation, a
    parameter given both as fitted and as a per-impact data column, ``cor_t`` or
    ``rebound_angle_deg`` observed where the model cannot define it (normal impact without
    spin for ``cor_t``), or non-finite values.
    """

    def __init__(
        self,
        scene: jaximpact.Scene,
        observations,
        params: Sequence[str],
        *,
        failure_residual: float = 1e3,
        method: str | None = None,
        check_values: Sequence[Mapping[str, float]] = (),
        loop: str | None = None,
    ):
        self.params = check_names(params, scene)
        self.loop = loop
        if not isinstance(observations, Observations):
            observations = load_observations(observations)
        obs = observations
        if len(obs) == 0:
            raise FitError(f"{obs.source}: no observations to fit")
        for name in ("value", "speed", "angle_deg", "omega0"):
            if not np.all(np.isfinite(getattr(obs, name))):
                raise FitError(f"{obs.source}: non-finite {name} in the observations")
        if np.any(np.asarray(obs.sigma)[np.isfinite(obs.sigma)] <= 0):
            raise FitError(f"{obs.source}: sigma must be > 0")
        unknown = set(np.unique(obs.observable)) - set(OBSERVABLES)
        if unknown:
            raise FitError(f"{obs.source}: unknown observable(s) {sorted(unknown)}")
        for name in obs.impacts.overrides:
            reason = unused_reason(scene, name)
            if reason is not None:
                raise FitError(f"{obs.source}: column {name}: {reason}")
        clash = set(self.params) & set(obs.impacts.overrides)
        if clash:
            raise FitError(
                f"{obs.source}: {sorted(clash)} given per impact in the data and also fitted"
            )
        bad_t = (obs.observable == "cor_t") & (obs.angle_deg == 0)
        if np.any(bad_t):
            line = int(obs.line[np.argmax(bad_t)])
            raise FitError(f"{obs.source}, line {line}: cor_t observed at a normal impact")
        self.observations = obs
        self.scene = scene
        self.failure_residual = float(failure_residual)
        self.n_data = len(obs)

        impacts = obs.impacts
        dtype = jnp.result_type(float)
        self._speed = jnp.asarray(impacts.speed, dtype)
        self._angle = jnp.asarray(impacts.angle_deg, dtype)
        self._omega0 = jnp.asarray(impacts.omega0, dtype)
        self._overrides = {k: np.asarray(v) for k, v in impacts.overrides.items()}

        radius = self._overrides.get("radius", get_parameter(scene, "radius"))
        radius = np.broadcast_to(radius, impacts.speed.shape)[obs.impact_index]
        sigma = np.asarray(obs.sigma, dtype=float)
        #: Whether every observation has its own sigma (then the scales are absolute).
        self.sigma_known = bool(np.all(np.isfinite(sigma)))
        self.scale = np.where(
            np.isfinite(sigma), sigma, default_scales(obs.observable, obs.speed, radius)
        )
        self._scale = jnp.asarray(self.scale, dtype)
        self._value = jnp.asarray(obs.value, dtype)
        self._index = jnp.asarray(obs.impact_index)
        # Model output compared with each observation: its own, or cor_n for "captured".
        compared = ["cor_n" if n == "captured" else str(n) for n in obs.observable]
        self._outputs = tuple(n for n in _OUTPUTS if n in compared)
        self._column = jnp.asarray([self._outputs.index(n) for n in compared])
        self._is_capture = jnp.asarray(obs.observable == "captured")
        # Rebound quantities other than cor_n: undefined where the model captures.
        self._is_other = jnp.asarray(~np.isin(obs.observable, ("captured", "cor_n")))

        self.initial = {name: get_parameter(scene, name) for name in self.params}
        self.method = self._resolve_method(method, [self.initial, *check_values])
        self._residuals = jax.jit(self._residuals_impl)
        self._simulate = jax.jit(self._simulate_impl)

    # -- building blocks ---------------------------------------------------------------------

    def _resolve_method(self, method, value_sets) -> str:
        method = method or self.scene.solver.method
        if method != "auto":
            return method
        # All value sets in one compiled call (op by op, each set cost ~0.3 s of dispatch).
        sets = []
        for values in value_sets:
            scene = self._scene_with(dict(values))
            params = scene_parameters(scene)
            sets.append(
                {
                    k: np.broadcast_to(np.asarray(v, float), self._speed.shape)
                    for k, v in params.items()
                }
            )
        batch = {k: np.stack([p[k] for p in sets]) for k in sets[0]}
        stiff = _batched_stiffness(batch, self._speed, self._angle)
        return "kvaerno5" if float(np.max(stiff)) > self.scene.solver.stiffness_limit else "tsit5"

    def _scene_with(self, values: Mapping[str, object]) -> jaximpact.Scene:
        """The scene with fitted values and the data's per-impact overrides in place."""
        return set_parameters(self.scene, {**self._overrides, **values})

    def _simulate_impl(self, theta, adjoint=None, program="throughput"):
        # The compared outputs need no energy ledger: integrating only the motion compiles and
        # runs in ~0.6x the time of the full state (BENCHMARKS.md, "Fit time").
        scene = self._scene_with(dict(zip(self.params, theta, strict=True)))
        scene = scene.replace(solver={"outputs": "rebound"})
        return _simulate(
            scene,
            self._speed,
            self._angle,
            self._omega0,
            method=self.method,
            adjoint=adjoint,
            program=program,
            loop=self.loop,
        )

    def hertz_time(self, theta=None):
        """Undamped Hertz contact time of each distinct impact (s): the time scale of the
        capture surrogate (see the module docstring). ``theta``: fitted values (default: the
        scene's)."""
        values = {} if theta is None else dict(zip(self.params, theta, strict=True))
        scene = self._scene_with(values)
        radius = jnp.asarray(scene.particle.radius)
        mass = jnp.asarray(scene.particle.density) * (4.0 / 3.0) * jnp.pi * radius**3
        v_n = self._speed * jnp.cos(jnp.deg2rad(self._angle))
        ratio = 5.0 * mass * v_n**2 / (4.0 * jnp.asarray(scene.contact.K) * jnp.sqrt(radius))
        return 2.94 * ratio**0.4 / v_n  # n* = ratio^(2/5)

    def _residuals_impl(self, theta, adjoint=None):
        result = self._simulate_impl(theta, adjoint)
        return self.residuals_from_result(result, self.hertz_time(theta))

    def _output(self, result: jaximpact.ImpactResult, name: str):
        """One model output at the distinct impacts, safe to differentiate.

        The rebound angle is recomputed here with both ``arctan2`` arguments masked: the
        simulator's own ``rebound_angle_deg`` of a captured impact is ``arctan2(0, 0)`` behind
        a ``where``, whose reverse-mode gradient is NaN and breaks the whole batch's Jacobian.
        """
        if name != "rebound_angle_deg":
            return getattr(result, name)
        rebound = result.status == jaximpact.Status.REBOUND
        vn = jnp.where(rebound, result.vn_out, 1.0)
        vt = jnp.where(rebound, result.vt_out, 0.0)
        return jnp.where(rebound, jnp.rad2deg(jnp.arctan2(vt, vn)), jnp.nan)

    def residuals_from_result(
        self, result: jaximpact.ImpactResult, hertz_time=None, value=None, scale=None
    ):
        """Residuals of every observation, given the model's result at the distinct impacts.

        Arguments:
            result: the `ImpactResult` at the distinct impacts.
            hertz_time: each impact's Hertz contact time (s), the scale of the capture
                surrogate; default :meth:`hertz_time` at the scene's values.
            value, scale: the observed values and their scales (default: the objective's);
                arguments so that a compiled program can take them as inputs.
        """
        if hertz_time is None:
            hertz_time = self.hertz_time()
        value = self._value if value is None else value
        scale = self._scale if scale is None else scale
        captured = result.status == jaximpact.Status.CAPTURED
        # Depth of capture in (0, 1]; both inputs masked ("double where") so that the NaN
        # contact time of a failed impact never reaches a derivative.
        t_c = jnp.where(captured, result.contact_time, 0.0)
        t_h = jnp.where(captured, hertz_time, 1.0)
        depth = jnp.where(captured, jnp.exp(-t_c / t_h), 0.0)
        # cor_n continued below zero (see the module docstring).
        cor_n = jnp.where(captured, -0.5 * (1.0 + depth), result.cor_n)

        # Only the outputs the data observe enter the graph (see _output on why that matters).
        outputs = jnp.stack(
            [cor_n if name == "cor_n" else self._output(result, name) for name in self._outputs]
        )
        model = outputs[self._column, self._index]
        failed = result.status[self._index] >= jaximpact.Status.MAX_STEPS
        captured_obs = captured[self._index]
        other = self._is_other
        missing = ~jnp.isfinite(model) & ~(captured_obs & other)
        bad = failed | missing
        # Mask the input too, so that no NaN reaches the gradient through the unused branch.
        model = jnp.where(bad | (captured_obs & other), 0.0, model)
        ordinary = (model - value) / scale
        observed_captured = value > 0.5
        capture = jnp.where(
            observed_captured,
            jnp.maximum(model, 0.0) / scale,
            jnp.maximum(scale - model, 0.0) / scale,
        )
        r = jnp.where(self._is_capture, capture, ordinary)
        # A rebound quantity observed where the model captures: large, falling with the depth.
        r = jnp.where(
            captured_obs & other, 0.5 * self.failure_residual * (1.0 + depth[self._index]), r
        )
        return jnp.where(bad, self.failure_residual, r)

    # -- public --------------------------------------------------------------------------------

    def fingerprint(self) -> str:
        """A digest of everything a compiled residual program of this objective depends on
        besides the code: the scene (structure, switches and values), the observed impacts and
        observables, the fitted names and the settings; not the observed values and scales,
        which the program takes as inputs. Equal digests mean interchangeable programs (a
        cache key)."""
        h = hashlib.sha256()
        leaves, treedef = jax.tree_util.tree_flatten(self.scene)
        h.update(str(treedef).encode())
        arrays = [
            *leaves,
            self._speed,
            self._angle,
            self._omega0,
            self._index,
            self._column,
            self._is_capture,
            self._is_other,
            *(self._overrides[k] for k in sorted(self._overrides)),
        ]
        for a in arrays:
            a = np.asarray(a)
            h.update(f"{a.dtype}{a.shape}".encode())
            h.update(np.ascontiguousarray(a).tobytes())
        settings = (
            self.params,
            self.method,
            self.loop,
            self.failure_residual,
            self._outputs,
            sorted(self._overrides),
        )
        h.update(repr(settings).encode())
        return h.hexdigest()

    def residuals(self, theta):
        """Weighted residuals (one per observation) at physical parameter values ``theta``.

        Arguments:
            theta: 1-D array of the fitted parameters in :attr:`params` order (SI units).

        Returns:
            jax.Array: residuals, dimensionless (in scales), finite.
        """
        return self._residuals(jnp.asarray(theta, jnp.result_type(float)))

    def simulate(self, theta) -> jaximpact.ImpactResult:
        """The model's `ImpactResult` at the distinct observed impacts (the motion only: the
        energy ledger, ``max_overlap`` and ``roll_time`` are NaN, as with ``[solver] outputs =
        "rebound"``)."""
        return self._simulate(jnp.asarray(theta, jnp.result_type(float)))

    def model_values(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """Model value of each observation (``captured``: 1.0 or 0.0) and the impact status.

        Returns:
            (values, status): numpy arrays, one entry per observation (NaN where undefined).
        """
        result = self.simulate(theta)
        status = np.asarray(result.status)[self.observations.impact_index]
        values = np.empty(self.n_data)
        for i, (name, k) in enumerate(
            zip(self.observations.observable, self.observations.impact_index, strict=True)
        ):
            if name == "captured":
                values[i] = float(np.asarray(result.status)[k] == jaximpact.Status.CAPTURED)
            else:
                values[i] = float(np.asarray(getattr(result, name))[k])
        values[status >= jaximpact.Status.MAX_STEPS] = np.nan
        return values, status

    def scene_at(self, values: Mapping[str, float]) -> jaximpact.Scene:
        """The scene with the given fitted values (without the data's per-impact overrides)."""
        return set_parameters(self.scene, {k: float(v) for k, v in values.items()})

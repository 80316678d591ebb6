"""``output_jacobian``: derivatives of an impact's outputs with respect to its inputs."""

import diffrax
import jax
import jax.numpy as jnp

from .._model.scene import Scene
from ..parameters import PARAMETERS, parameter_value, with_parameters
from .simulate import simulate

#: Outputs that :func:`output_jacobian` differentiates, and the inputs it differentiates by
#: default (names of the impacts CSV); it takes any of the impact's three and every parameter
#: of the registry (``jaximpact.parameters.PARAMETERS``: also ``G_star``, ``w``, ``p_y`` where
#: the scene's laws use them, ``radius2``, ``density2``, ``omega2`` with a ``[target]``).
OUTPUTS = ("cor_n", "vt_out", "omega_out", "rebound_angle_deg", "contact_time")
INPUTS = (
    "f0", "C_A", "C_H", "friction", "K", "radius", "density", "lambda",
    "speed", "angle_deg", "omega0",
)  # fmt: skip
#: The impact's own inputs (the others are scene parameters).
IMPACT_INPUTS = ("speed", "angle_deg", "omega0")


def output_jacobian(
    scene: Scene, speed, angle_deg, omega0=0.0, inputs=INPUTS, mode="fwd", program="throughput"
):
    """Jacobian of ``OUTPUTS`` with respect to ``inputs`` for each impact of a batch.

    **Arguments:** the scene and impacts as in `simulate` (1-D arrays or scalars); `inputs`,
    names from ``IMPACT_INPUTS`` and ``jaximpact.parameters.PARAMETERS`` (default
    ``INPUTS``); `mode`: ``"fwd"`` (``jax.jacfwd``, cheap for few inputs) or ``"rev"``
    (``jax.jacrev``); `program`: as in `simulate` (``"compact"`` compiles in about half the
    time).

    **Returns:** ``{output: array (impacts, len(inputs))}``.

    Each impact is its own function of its own inputs (the batch does not change a lane's
    arithmetic), so one Jacobian of the batch sum gives every impact's row.

    **Raises:** `ValueError` for an input name that is neither an impact's nor a parameter's.
    """
    speed, angle_deg, omega0 = jnp.broadcast_arrays(
        *(
            jnp.atleast_1d(jnp.asarray(x, jnp.result_type(float)))
            for x in (speed, angle_deg, omega0)
        )
    )
    size = speed.shape[0]
    unknown = [k for k in inputs if k not in IMPACT_INPUTS and k not in PARAMETERS]
    if unknown:
        raise ValueError(
            f"unknown input(s) {unknown}; known: {', '.join(IMPACT_INPUTS)} and the scene's "
            f"parameters {', '.join(PARAMETERS)}"
        )
    current = {
        "speed": speed, "angle_deg": angle_deg, "omega0": omega0,
        **{
            k: parameter_value(scene, k)
            for k in PARAMETERS
            if parameter_value(scene, k) is not None
        },
    }  # fmt: skip
    x0 = jnp.stack(
        [jnp.broadcast_to(jnp.asarray(current[k], speed.dtype), (size,)) for k in inputs]
    )
    adjoint = diffrax.ForwardMode() if mode == "fwd" else None

    def outputs(x):
        values = dict(zip(inputs, x, strict=True))
        impact = {k: values.pop(k, current[k]) for k in IMPACT_INPUTS}
        res = simulate(with_parameters(scene, values), **impact, adjoint=adjoint, program=program)
        return {k: getattr(res, k) for k in OUTPUTS}

    # Each impact depends on its own inputs only: perturbing input j of every impact at once
    # (forward) or differentiating the batch sum (reverse) gives every impact's row together.
    if mode == "fwd":
        basis = jnp.repeat(jnp.eye(len(inputs), dtype=x0.dtype)[:, :, None], size, axis=2)
        jac = jax.vmap(lambda v: jax.jvp(outputs, (x0,), (v,))[1])(basis)
        return {k: v.T for k, v in jac.items()}
    if mode != "rev":
        raise ValueError(f"mode must be 'fwd' or 'rev', got {mode!r}")
    jac = jax.jacrev(lambda x: {k: jnp.sum(v) for k, v in outputs(x).items()})(x0)
    return {k: v.T for k, v in jac.items()}

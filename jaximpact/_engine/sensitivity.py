"""``output_jacobian``: derivatives of an impact's outputs with respect to its inputs."""

import diffrax
import jax
import jax.numpy as jnp

from .._model.scene import Scene
from .simulate import simulate

#: Outputs and inputs that :func:`output_jacobian` knows (names of the impacts CSV).
OUTPUTS = ("cor_n", "vt_out", "omega_out", "rebound_angle_deg", "contact_time")
INPUTS = (
    "f0", "C_A", "C_H", "friction", "K", "radius", "density", "lambda",
    "speed", "angle_deg", "omega0",
)  # fmt: skip
_SECTIONS = {
    "f0": ("contact", "f0"), "C_A": ("contact", "C_A"), "C_H": ("contact", "C_H"),
    "friction": ("contact", "friction"), "K": ("contact", "K"),
    "radius": ("particle", "radius"), "density": ("particle", "density"),
    "lambda": ("model", "lambda_"),
    "G_star": ("contact", "G_star"),  # model.tangential = "mindlin" only
    "w": ("contact", "w"),  # model.normal = "dmt", "jkr" or "thornton_ning" only
    "p_y": ("contact", "p_y"),  # model.normal = "thornton_ning" only
    # a second sphere ([target]) only
    "radius2": ("target", "radius"),
    "density2": ("target", "density"),
    "omega2": ("target", "omega0"),
}  # fmt: skip


def _with_values(scene: Scene, values: dict) -> Scene:
    sections: dict = {}
    for name, value in values.items():
        section, field = _SECTIONS[name]
        sections.setdefault(section, {})[field] = value
    return scene.replace(**sections) if sections else scene


def output_jacobian(
    scene: Scene, speed, angle_deg, omega0=0.0, inputs=INPUTS, mode="fwd", program="throughput"
):
    """Jacobian of ``OUTPUTS`` with respect to ``inputs`` for each impact of a batch.

    **Arguments:** the scene and impacts as in `simulate` (1-D arrays or scalars); `inputs`,
    names from ``INPUTS``; `mode`: ``"fwd"`` (``jax.jacfwd``, cheap for few inputs) or ``"rev"``
    (``jax.jacrev``); `program`: as in `simulate` (``"compact"`` compiles in about half the
    time).

    **Returns:** ``{output: array (impacts, len(inputs))}``.

    Each impact is its own function of its own inputs (the batch does not change a lane's
    arithmetic), so one Jacobian of the batch sum gives every impact's row.
    """
    speed, angle_deg, omega0 = jnp.broadcast_arrays(
        *(
            jnp.atleast_1d(jnp.asarray(x, jnp.result_type(float)))
            for x in (speed, angle_deg, omega0)
        )
    )
    size = speed.shape[0]
    current = {
        "speed": speed, "angle_deg": angle_deg, "omega0": omega0,
        **{
            k: getattr(getattr(scene, s), f)
            for k, (s, f) in _SECTIONS.items()
            if getattr(scene, s) is not None
        },
    }  # fmt: skip
    x0 = jnp.stack(
        [jnp.broadcast_to(jnp.asarray(current[k], speed.dtype), (size,)) for k in inputs]
    )
    adjoint = diffrax.ForwardMode() if mode == "fwd" else None

    def outputs(x):
        values = dict(zip(inputs, x, strict=True))
        impact = {k: values.pop(k, current[k]) for k in ("speed", "angle_deg", "omega0")}
        res = simulate(_with_values(scene, values), **impact, adjoint=adjoint, program=program)
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

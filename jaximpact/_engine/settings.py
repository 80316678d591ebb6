"""What a batch of impacts needs before it is solved: the scene's parameters by name
(:func:`scene_parameters`), the model terms the batch uses (:func:`required_terms`), the
solver settings (:class:`Integration`, :func:`integration_settings`) and the parameters in
Hertz units (``_scaled``)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._model import dynamics as dyn
from .._model import laws
from .._model.scene import INERTIA_FACTOR, Scene, SceneError, _is_concrete, check_range
from .._model.units import ScaledParameters, hertz_units
from .solvers import (
    CAP_WIDTH,
    CONTACT_FLOOR,
    SLIP_RELAXATION,
    default_slip_width,
    default_tolerances,
)

PARAMETERS = ("radius", "density", "K", "f0", "C_A", "C_H", "friction", "lambda")


def scene_parameters(scene: Scene) -> dict:
    """The scene's float parameters by their impacts-CSV column names (and ``G_star`` when the
    scene uses the Mindlin tangential spring, ``w`` with the DMT or JKR normal law, ``eta_n``
    with a LAMMPS normal damping,
    ``radius2``, ``density2`` and ``omega2`` with a second sphere)."""
    params = {
        "radius": scene.particle.radius,
        "density": scene.particle.density,
        "K": scene.contact.K,
        "f0": scene.contact.f0,
        "C_A": scene.contact.C_A,
        "C_H": scene.contact.C_H,
        "friction": scene.contact.friction,
        "lambda": scene.model.lambda_,
    }
    if scene.model.tangential in ("mindlin", "lammps_mindlin"):
        params["G_star"] = scene.contact.G_star
    if scene.model.tangential == "lammps_linear_history":
        params["k_t"] = scene.contact.k_t
    if scene.model.normal in ("dmt", "jkr", "thornton_ning"):
        params["w"] = scene.contact.w
    if scene.model.normal == "thornton_ning":
        params["p_y"] = scene.contact.p_y
    if scene.model.damping != "hertzian":
        params["eta_n"] = scene.contact.eta_n
    if scene.target is not None:
        params.update(
            radius2=scene.target.radius, density2=scene.target.density, omega2=scene.target.omega0
        )
    return params


class Integration(eqx.Module):
    """Resolved numerical settings (static)."""

    method: str = eqx.field(static=True)
    rtol: float = eqx.field(static=True)
    atol: float = eqx.field(static=True)
    dt: float = eqx.field(static=True)
    max_steps: int = eqx.field(static=True)
    # The form of Tsit5's stage sums (``LaneTsit5.stages``; ``simulate(program=...)``).
    stages: str = eqx.field(static=True, default="per_state")


def _all(values, predicate) -> bool:
    """``predicate`` holds for every element of every value, known without tracing."""
    return all(_is_concrete(v) and bool(np.all(predicate(np.asarray(v)))) for v in values)


def required_terms(scene: Scene, params: dict, angle_deg, omega0) -> dyn.Terms:
    """The terms an impact batch needs, from the switches and, where concrete, the values.

    A normal impact without spin needs no tangential or rotational state; zero ``f0`` needs no
    adhesion terms; zero ``lambda`` (or zero ``C_A`` and ``C_H``) needs no rolling moments.
    Under ``jit``/``grad`` the values are traced and only the switches decide.
    """
    m, s = scene.model, scene.solver
    if m.damping != "hertzian":  # (a scene changed by Scene.replace is checked here)
        scene._check_lammps_damping()
    if m.tangential in ("mindlin", "lammps_mindlin"):
        check_range(
            f"contact.G_star (model.tangential = '{m.tangential}')", params["G_star"], positive=True
        )
    if m.tangential == "lammps_linear_history":
        check_range(
            "contact.k_t (model.tangential = 'lammps_linear_history')", params["k_t"], positive=True
        )
    spins = [omega0] + ([params["omega2"]] if "omega2" in params else [])
    tangential = not _all([angle_deg, *spins], lambda v: v == 0)
    strength = params["f0"] if m.normal == "brach_dunn" else params["w"]
    adhesion = m.adhesion and not _all([strength], lambda v: v == 0)
    moments = m.rolling_moments
    if moments == "lambda" and _all([params["lambda"]], lambda v: v == 0):
        moments = "none"
    if moments == "analytical" and _all([params["C_A"], params["C_H"]], lambda v: v == 0):
        moments = "none"
    rotation = m.rotation and tangential
    return dyn.Terms(
        tangential=tangential,
        rotation=rotation,
        adhesion=adhesion,
        rolling_moments=moments if rotation else "none",
        friction_load=m.friction_load,
        slip_width=default_slip_width(jnp.result_type(float), s.slip_width, s.rtol),
        ring_width=s.ring_width,
        ledger=s.outputs == "full",
        contact_floor=CONTACT_FLOOR,
        slip_relaxation=SLIP_RELAXATION,
        mindlin=tangential and m.tangential != "rigid",
        cap_width=CAP_WIDTH if m.tangential != "rigid" else 0.0,
        spring=m.tangential if m.tangential != "rigid" else "mindlin",
        normal=m.normal,
        target=scene.target is not None,
        damping=m.damping,
        jkr_release=m.jkr_release,
    )


def stiffness_estimate(params: dict, speed, angle_deg, damping: str = "hertzian"):
    """Fastest relaxation rate of the damping and rolling-moment terms, in Hertz units
    (``damping``: the scene's ``model.damping``).

    An explicit solver needs of the order of this many steps per impact; ``method="auto"``
    switches to the implicit Kvaerno5 above ``solver.stiffness_limit``.
    """
    p, _ = _scaled(params, speed, angle_deg, 0.0, damping)
    a = jnp.sqrt(p.radius)  # contact radius at unit overlap
    rates = [
        1.25 * p.C_H,  # Hertz damping
        2 * jnp.pi * p.f0 * p.C_A * a,  # adhesion damping
        p.lam * p.C_A * a / p.inertia,  # constant-lambda moment
        jnp.pi * p.f0 * p.C_A * a**3 / p.inertia,  # peeling moment M_A
        p.K / 5 * p.C_H * p.radius**1.5 / p.inertia,  # Hertzian rolling moment M_H
    ]
    if p.inertia2 is not None:  # the moments turn a second sphere too
        rates += [r * p.inertia / p.inertia2 for r in rates[2:]]
    if p.eta_n is not None:  # a LAMMPS normal damping (mass 1): eta_n at unit overlap
        rates.append(laws.lammps_damping_coefficient(damping, a, p.eta_n, p.K))
    return jnp.max(jnp.stack([jnp.max(r) for r in rates]))


# One compiled program instead of a dozen dispatched operations (about 0.1 s of a warm
# command-line run); values are concrete where it is called (``integration_settings``).
_stiffness_estimate_jit = jax.jit(stiffness_estimate, static_argnames="damping")


def _scaled(params, speed, angle_deg, omega0, damping="hertzian"):
    theta = jnp.deg2rad(angle_deg)
    v_n = speed * jnp.cos(theta)
    mass = params["density"] * (4.0 / 3.0) * jnp.pi * params["radius"] ** 3
    radius, target = params["radius"], None
    if "radius2" in params:  # a sphere-sphere impact: reduced radius and mass
        mass2 = params["density2"] * (4.0 / 3.0) * jnp.pi * params["radius2"] ** 3
        target = (radius, mass, params["radius2"], mass2)
        radius = radius * params["radius2"] / (radius + params["radius2"])
        mass = mass * mass2 / (mass + mass2)
    units = hertz_units(mass, radius, params["K"], v_n)
    p = ScaledParameters.from_si(
        units,
        radius=radius,
        K=params["K"],
        f0=params["f0"],
        C_A=params["C_A"],
        C_H=params["C_H"],
        friction=params["friction"],
        lam=params["lambda"],
        inertia_factor=INERTIA_FACTOR,
        G_star=params.get("G_star"),
        k_t=params.get("k_t"),
        w_adhesion=params.get("w"),
        target=target,
        p_yield=params.get("p_y"),
        damping=damping,
        eta_n=params.get("eta_n"),
    )
    return p, units


# ``simulate(program=...)``: what the program is made for -> the form of Tsit5's stage sums.
PROGRAMS = {"throughput": "per_state", "compact": "loop"}


def integration_settings(scene, params, speed, angle_deg, dtype, method=None) -> Integration:
    """The solver ``simulate`` runs for these impacts: method (``auto`` resolved), tolerances.

    ``params`` as :func:`scene_parameters` gives them (arrays or scalars), ``speed`` and
    ``angle_deg`` the impacts, ``dtype`` the float type; ``method`` overrides the scene's.
    """
    s = scene.solver
    method = method or s.method
    rtol, atol = default_tolerances(dtype, s.rtol, s.atol)
    if method == "auto":
        method = "tsit5"
        # A slip width below the solver's noise (~rtol) lets the slip wander into the steep part
        # of the friction switch, which an explicit solver crosses only with tiny steps.
        if default_slip_width(dtype, s.slip_width, rtol) < 30 * rtol:
            method = "kvaerno5"
        elif _all(list(params.values()) + [speed, angle_deg], lambda v: True):
            rate = _stiffness_estimate_jit(params, speed, angle_deg, scene.model.damping)
            if float(rate) > s.stiffness_limit:
                method = "kvaerno5"
    if method not in ("tsit5", "dopri5", "dopri8", "rk4", "kvaerno3", "kvaerno5"):
        raise SceneError(f"solver.method {method!r} is not a known method")
    max_steps = s.max_steps
    if scene.model.tangential == "lammps_linear_history":
        # A constant tangential stiffness makes the Coulomb cap f N / k_t vanish like n^1.5 at
        # the end of the contact, where the spring then slides: stiff there even with the
        # switch's width floor (860-1,420 steps on Table 1 with k_t = 2e4 N/m; 41,500 for a
        # stiff spring, 7.8e5 N/m, on a 6.4 um sphere at 0.34 m/s).
        max_steps = max(max_steps, LINEAR_SPRING_MAX_STEPS)
    return Integration(method=method, rtol=rtol, atol=atol, dt=s.dt, max_steps=max_steps)


#: The least step limit with ``model.tangential = "lammps_linear_history"``.
LINEAR_SPRING_MAX_STEPS = 131072

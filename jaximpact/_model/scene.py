"""The ``Scene``: particle, contact, model switches, default impact and solver settings.

The structure mirrors the TOML scene file section by section. Float parameters are JAX array
leaves (differentiable, no recompilation when their values change); switches and solver
settings are static fields (they decide which terms and states are compiled).
"""

import math
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .ranges import RANGES, range_text

INERTIA_FACTOR = 0.4  # k^2 / r^2 of a solid sphere (CONVENTIONS)

RollingMoments = Literal["none", "analytical", "lambda"]
FrictionLoad = Literal["net", "hertz"]
#: ``model.tangential``: the rigid Coulomb law, jaximpact's energy-consistent Mindlin spring, or
#: LAMMPS's history springs (``tangential linear_history`` and ``mindlin``, without tangential
#: damping), with LAMMPS's Coulomb load and no normal force of the spring.
TANGENTIAL_MODELS = ("rigid", "mindlin", "lammps_linear_history", "lammps_mindlin")
#: The spring models (a tangential displacement state ``xi``).
SPRING_MODELS = TANGENTIAL_MODELS[1:]
#: The normal contact laws of ``model.normal`` (docs/physics.md, "Normal laws").
NORMAL_LAWS = ("brach_dunn", "dmt", "jkr", "thornton_ning")
#: The normal damping of ``model.damping``: Brach-Dunn's Hertzian damping (``contact.C_H``) or
#: one of LAMMPS's damping models (``contact.eta_n``; ``laws.LAMMPS_DAMPING``).
DAMPING_MODELS = ("hertzian", "velocity", "mass_velocity", "viscoelastic", "tsuji")
#: Where a JKR contact ends (``model.jkr_release``): the snap-off (displacement control) or the
#: pull-off (load control: the force's minimum, LAMMPS's rule).
JKR_RELEASES = ("snap_off", "pull_off")
SolverMethod = Literal["auto", "tsit5", "dopri5", "dopri8", "rk4", "kvaerno3", "kvaerno5"]


class SceneError(ValueError):
    """An invalid scene value; the message names the field and the allowed range."""


def _array(x):
    return jnp.asarray(x, dtype=jnp.result_type(float))


def _numbers(field: str):
    """The converter of a float field: refuses text (``"1.0"`` is not silently a number),
    booleans and empty arrays by the field's name, then makes a float array."""

    def convert(x):
        _argument_shape(field, x)
        return _array(x)

    return convert


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def check_range(
    name, value, *, positive=False, nonnegative=False, lower=None, upper=None, upper_inclusive=True
):
    """Raise ``SceneError`` naming ``name`` if a concrete value is non-finite or out of range.

    Traced values are not checked (they are checked where they were concrete, e.g. on loading).
    """
    if not _is_concrete(value):
        return
    v = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(v)):
        raise SceneError(f"{name} must be finite, got {_show(v)}")
    if positive and np.any(v <= 0):
        raise SceneError(f"{name} must be > 0, got {_show(v)}")
    if nonnegative and np.any(v < 0):
        raise SceneError(f"{name} must be >= 0, got {_show(v)}")
    if lower is not None and np.any(v <= lower):
        raise SceneError(
            f"{name} must be in ({lower}, {upper}{']' if upper_inclusive else ')'}, got {_show(v)}"
        )
    if upper is not None and np.any(v > upper if upper_inclusive else v >= upper):
        raise SceneError(
            f"{name} must be in ({lower}, {upper}{']' if upper_inclusive else ')'}, got {_show(v)}"
        )


def check_input(field: str, name: str, value) -> None:
    """Raise ``SceneError`` naming ``field`` if a concrete value is outside the documented
    range of input ``name`` (``jaximpact._ranges.RANGES``; docs/input_ranges.md).

    Traced values are not checked (they are checked where they were concrete).
    """
    if not _is_concrete(value):
        return
    v = np.asarray(value, dtype=float)
    ok = RANGES[name].contains(v)
    if not np.all(ok):
        bad = np.flatnonzero(~np.ravel(ok))[0]
        got = repr(float(v)) if v.ndim == 0 else f"{float(v.ravel()[bad])!r} (element {bad})"
        raise SceneError(f"{range_text(name, field)} (docs/input_ranges.md), got {got}")


def _show(v):
    v = np.asarray(v)
    if v.ndim == 0:
        return repr(float(v))
    return f"an array with min {float(v.min())!r}, max {float(v.max())!r}"


class Particle(eqx.Module):
    """The sphere. **Arguments:** `radius` (m, > 0), `density` (kg/m^3, > 0)."""

    radius: jax.Array = eqx.field(converter=_numbers("particle.radius"))
    density: jax.Array = eqx.field(converter=_numbers("particle.density"))

    def __check_init__(self):
        check_input("particle.radius", "radius", self.radius)
        check_input("particle.density", "density", self.density)

    @property
    def mass(self):
        """Mass ``rho 4/3 pi r^3`` (kg)."""
        return self.density * (4.0 / 3.0) * jnp.pi * self.radius**3


class Target(eqx.Module):
    """A second sphere struck instead of the flat wall (sphere-sphere impacts).

    **Arguments:** `radius` (m, > 0), `density` (kg/m^3, > 0), `omega0` (rad/s, its spin
    before the impact, in the sense of ``impact.omega0``: the spin that rolls the partner
    under the particle is positive). The normal motion is the relative one, with the reduced
    radius ``r r2 / (r + r2)`` in every contact law and the reduced mass ``m m2 / (m + m2)``;
    the friction turns both spheres, and the rolling moments oppose their relative spin. A
    very large ``radius`` (and ``density``) is the flat wall.
    """

    radius: jax.Array = eqx.field(converter=_numbers("target.radius"))
    density: jax.Array = eqx.field(converter=_numbers("target.density"))
    omega0: jax.Array = eqx.field(converter=_numbers("target.omega0"), default=0.0)

    def __check_init__(self):
        check_input("target.radius", "radius2", self.radius)
        check_input("target.density", "density2", self.density)
        check_input("target.omega0", "omega2", self.omega0)

    @property
    def mass(self):
        """Mass ``rho 4/3 pi r^3`` (kg)."""
        return self.density * (4.0 / 3.0) * jnp.pi * self.radius**3


class Contact(eqx.Module):
    """Contact constants of the sphere-surface pair.

    **Arguments:**
    - `K`: Hertz stiffness (Pa, > 0), ``K = 4 / (3 pi (k1 + k2))`` (eq. 3-4), i.e. ``4 E*/3``.
    - `f0`: adhesion ring line force (N/m, >= 0).
    - `C_A`, `C_H`: adhesion and Hertzian damping constants (s/m, >= 0).
    - `friction`: Coulomb coefficient (>= 0).
    - `G_star`: effective shear modulus (Pa, > 0) of the tangential (Mindlin) stiffness
      ``k_t = 8 G* a``, ``1/G* = (2 - nu1)/G1 + (2 - nu2)/G2``; used only with
      ``model.tangential = "mindlin"`` (0, the default, means "not given").
    - `w`: work of adhesion (J/m^2, >= 0) of the DMT and JKR normal laws (``model.normal =
      "dmt"`` or ``"jkr"``): the energy per unit area that separates the two surfaces,
      ``w = 2 gamma`` for one material of surface energy ``gamma``; the pull-off force is
      ``2 pi w r`` (DMT) or ``1.5 pi w r`` (JKR, Thornton-Ning).
    - `p_y`: limiting contact pressure (Pa, > 0) of the Thornton-Ning law (``model.normal =
      "thornton_ning"``): the contact yields where the JKR pressure at its centre reaches it
      (0, the default, means "not given").
    - `k_t`: the tangential stiffness (N/m, > 0) of ``model.tangential =
      "lammps_linear_history"`` (LAMMPS's ``k_t``; 0, the default, means "not given").
    - `eta_n`: the coefficient of a LAMMPS normal damping (``model.damping``), as LAMMPS's
      ``damping`` keyword takes it: kg/s (``"velocity"``), 1/s (``"mass_velocity"``),
      1/(m s) (``"viscoelastic"``), or the restitution coefficient in (0, 1] that sets Tsuji's
      alpha (``"tsuji"``). Unused with the Hertzian damping (the default).
    """

    K: jax.Array = eqx.field(converter=_numbers("contact.K"))
    f0: jax.Array = eqx.field(converter=_numbers("contact.f0"))
    C_A: jax.Array = eqx.field(converter=_numbers("contact.C_A"))
    C_H: jax.Array = eqx.field(converter=_numbers("contact.C_H"))
    friction: jax.Array = eqx.field(converter=_numbers("contact.friction"))
    G_star: jax.Array = eqx.field(converter=_numbers("contact.G_star"), default=0.0)
    w: jax.Array = eqx.field(converter=_numbers("contact.w"), default=0.0)
    p_y: jax.Array = eqx.field(converter=_numbers("contact.p_y"), default=0.0)
    eta_n: jax.Array = eqx.field(converter=_numbers("contact.eta_n"), default=0.0)
    k_t: jax.Array = eqx.field(converter=_numbers("contact.k_t"), default=0.0)

    def __check_init__(self):
        for name in ("K", "f0", "C_A", "C_H", "friction", "G_star", "w", "p_y", "eta_n", "k_t"):
            check_input(f"contact.{name}", name, getattr(self, name))


class Model(eqx.Module):
    """Which physics is in the model.

    **Arguments:**
    - `rotation`: spin degree of freedom (``False``: the sphere slides without turning).
    - `adhesion`: ring adhesion force and adhesion damping.
    - `rolling_moments`: ``"none"``, ``"analytical"`` (peeling ``M_A`` + Hertzian ``M_H``,
      eq. 12, 18) or ``"lambda"`` (constant-lambda law ``-lambda C_A a w``, eq. 19-22).
    - `friction_load`: ``"net"`` (``|F_n|``, eq. 6, default) or ``"hertz"`` (compressive Hertz
      force ``K sqrt(r) n^1.5``).
    - `lambda_`: the lambda of the constant-lambda law (N m, >= 0); TOML key ``lambda``.
    - `tangential`: ``"rigid"`` (default: Coulomb friction on a rigid contact) or ``"mindlin"``
      (an elastic tangential spring ``8 G* a`` capped by Coulomb friction; needs
      ``contact.G_star``; docs/physics.md, "Tangential compliance"), or LAMMPS's history
      springs ``"lammps_linear_history"`` (``contact.k_t``) and ``"lammps_mindlin"`` (``8 G*
      a``), capped at ``friction`` times LAMMPS's critical normal force, without the spring's
      normal force (docs/physics.md, "LAMMPS tangential springs").
    - `normal`: the normal contact law: ``"brach_dunn"`` (default: Hertz, Hertzian damping,
      the adhesion ring ``2 pi a f0`` and its damping) or ``"dmt"`` (Hertz, Hertzian damping
      and the constant DMT adhesion ``2 pi w r`` while in contact, from ``contact.w``; no ring,
      so no adhesion damping and no peeling moment) or ``"jkr"`` (the JKR force of the contact
      radius, Hertzian damping of its Hertzian part ``K a^3 / r``, contact until the snap-off
      overlap ``< 0``) or ``"thornton_ning"`` (JKR until the centre pressure reaches
      ``contact.p_y``, then plastic loading and elastic JKR unloading along a flatter curve;
      needs ``contact.w > 0`` and ``contact.p_y > 0``, rigid tangential contact only);
      docs/physics.md, "Normal laws".
    - `damping`: the normal damping: ``"hertzian"`` (default: Brach-Dunn's ``C_H`` times the
      Hertz force) or one of LAMMPS's (``pair_style granular``, version 29 Sep 2021):
      ``"velocity"``, ``"mass_velocity"``, ``"viscoelastic"``, ``"tsuji"``, the force
      ``-eta ndot`` with ``eta`` = ``eta_n``, ``eta_n m``, ``eta_n a m`` or ``alpha(eta_n)
      sqrt(m K a)`` (``contact.eta_n``; ``contact.C_H`` must then be 0); not with
      Thornton-Ning; docs/physics.md, "LAMMPS damping".
    - `jkr_release`: where a JKR contact ends as the sphere leaves: ``"snap_off"`` (default:
      the least overlap of the stable branch, displacement control) or ``"pull_off"`` (where
      the force is least, ``-1.5 pi w r``: load control, as LAMMPS's ``jkr`` does).
    """

    rotation: bool = eqx.field(static=True, default=True)
    adhesion: bool = eqx.field(static=True, default=True)
    rolling_moments: str = eqx.field(static=True, default="analytical")
    friction_load: str = eqx.field(static=True, default="net")
    lambda_: jax.Array = eqx.field(converter=_numbers("model.lambda"), default=0.0)
    tangential: str = eqx.field(static=True, default="rigid")
    normal: str = eqx.field(static=True, default="brach_dunn")
    damping: str = eqx.field(static=True, default="hertzian")
    jkr_release: str = eqx.field(static=True, default="snap_off")

    def __check_init__(self):
        if self.jkr_release not in JKR_RELEASES:
            raise SceneError(
                f"model.jkr_release must be 'snap_off' or 'pull_off', got {self.jkr_release!r}"
            )
        if self.jkr_release != "snap_off" and self.normal != "jkr":
            raise SceneError(
                f'model.jkr_release = "{self.jkr_release}" is for model.normal = "jkr" '
                f'(the scene has "{self.normal}")'
            )
        if self.damping not in DAMPING_MODELS:
            raise SceneError(
                f"model.damping must be one of {', '.join(repr(d) for d in DAMPING_MODELS)}, "
                f"got {self.damping!r}"
            )
        if self.damping != "hertzian" and self.normal == "thornton_ning":
            raise SceneError(
                f'model.damping = "{self.damping}" (LAMMPS) works with model.normal = '
                '"brach_dunn", "dmt" or "jkr", not "thornton_ning"'
            )
        if self.normal not in NORMAL_LAWS:
            raise SceneError(
                f"model.normal must be one of {', '.join(repr(n) for n in NORMAL_LAWS)}, got "
                f"{self.normal!r}"
            )
        if self.normal == "thornton_ning" and self.tangential != "rigid":
            raise SceneError(
                'model.normal = "thornton_ning" works with model.tangential = "rigid" only, '
                f'got "{self.tangential}"'
            )
        if self.normal == "thornton_ning" and not self.adhesion:
            raise SceneError(
                'model.normal = "thornton_ning" needs model.adhesion = true (its law is JKR\'s)'
            )
        if self.tangential not in TANGENTIAL_MODELS:
            raise SceneError(
                f"model.tangential must be one of {', '.join(map(repr, TANGENTIAL_MODELS))}, "
                f"got {self.tangential!r}"
            )
        if self.rolling_moments not in ("none", "analytical", "lambda"):
            raise SceneError(
                "model.rolling_moments must be one of 'none', 'analytical', "
                f"'lambda', got {self.rolling_moments!r}"
            )
        if self.friction_load not in ("net", "hertz"):
            raise SceneError(
                f"model.friction_load must be 'net' or 'hertz', got {self.friction_load!r}"
            )
        for name in ("rotation", "adhesion"):
            if not isinstance(getattr(self, name), bool):
                raise SceneError(f"model.{name} must be true or false, got {getattr(self, name)!r}")
        check_input("model.lambda", "lambda", self.lambda_)


class Impact(eqx.Module):
    """One impact: `speed` (m/s, > 0), `angle_deg` (from the normal, in (-90, 90)),
    `omega0` (rad/s; positive with a positive angle is the rolling sense)."""

    speed: jax.Array = eqx.field(converter=_numbers("impact.speed"))
    angle_deg: jax.Array = eqx.field(converter=_numbers("impact.angle_deg"), default=0.0)
    omega0: jax.Array = eqx.field(converter=_numbers("impact.omega0"), default=0.0)

    def __check_init__(self):
        check_impact(self.speed, self.angle_deg, self.omega0, prefix="impact.")


def check_impact(speed, angle_deg, omega0, prefix=""):
    """Validate concrete impact inputs against their documented ranges (raises ``SceneError``
    naming the field and the range)."""
    check_input(f"{prefix}speed", "speed", speed)
    check_input(f"{prefix}angle_deg", "angle_deg", angle_deg)
    check_input(f"{prefix}omega0", "omega0", omega0)


def _argument_shape(name: str, value) -> tuple:
    """The shape of an impact argument of ``simulate``, refusing what is not numbers."""
    wrong = f"{name} must be a number or an array of numbers"
    if isinstance(value, (str, bytes)):
        raise SceneError(f"{wrong}, got the text {value!r}")
    if isinstance(value, jax.Array):  # concrete or traced
        dtype, shape = value.dtype, value.shape
    else:
        try:
            array = np.asarray(value)
        except (TypeError, ValueError) as err:
            raise SceneError(f"{wrong} ({' '.join(str(err).split())})") from None
        dtype, shape = array.dtype, array.shape
    if dtype.kind not in "iuf":
        kinds = {"b": "booleans", "U": "text", "S": "text", "c": "complex numbers"}
        raise SceneError(f"{wrong}, got {kinds.get(dtype.kind, f'values of type {dtype}')}")
    if 0 in shape:
        raise SceneError(f"{name} is empty (shape {shape}): give at least one value")
    return tuple(shape)


class Solver(eqx.Module):
    """Numerical settings (all static). Tolerances are dimensionless (Hertz units).

    **Arguments:**
    - `method`: ``"auto"`` (Tsit5, or Kvaerno5 when the scene is estimated to be stiff),
      ``"tsit5"``, ``"dopri5"``, ``"dopri8"``, ``"rk4"`` (Runge-Kutta-Gill, fixed step ``dt``),
      ``"kvaerno3"``, ``"kvaerno5"`` (implicit, for stiff scenes).
    - `rtol`, `atol`: adaptive-step tolerances; ``None`` picks them from the float precision.
    - `dt`: step of the fixed-step method, in units of the Hertz time ``n*/v_n``.
    - `slip_width`: width of the slip-sign regularization, as a fraction of the normal speed;
      ``None``: 3e-4 in float64, 3e-3 in float32 (above float32's rounding noise), or
      ``100 rtol`` where that is larger.
    - `ring_width`: width of the adhesion-ring separation switch, fraction of the normal speed
      (1e-8: its error is about ``ring_width / cor_n``, which near the capture speed was the
      largest error left at 1e-6; the ring law's slope is bounded, so a narrow switch costs no
      steps).
    - `max_steps`: step limit per impact; an impact that reaches it is reported as failed.
    - `outputs`: ``"full"`` (default) or ``"rebound"``: only status, rebound velocities, spin,
      angles and contact time (energy ledger, ``max_overlap`` and ``roll_time`` are NaN);
      for sweeps and fits that need no ledger. 1.2-1.3x faster where step loops are single
      kernels (``use_all_cpu_cores()``, the command line); on one CPU device with XLA's
      default settings 0.8x (XLA fuses the smaller step into more recomputation;
      BENCHMARKS.md "By batch size and scene options").
    - `stiffness_limit`: with ``method="auto"``, the estimated stiffness (fastest relaxation rate
      times the Hertz time) above which the implicit solver is used. Tsit5 needs about that many
      steps per impact (lambda = 5e-3 N m on the Table 1 sphere: estimate 1109, 1191 steps);
      Kvaerno5 compiles for 20-40 s and costs about 10x per step, so 1000 (measured in
      BENCHMARKS.md, "Stability catalogue").
    """

    method: str = eqx.field(static=True, default="auto")
    rtol: float | None = eqx.field(static=True, default=None)
    atol: float | None = eqx.field(static=True, default=None)
    dt: float = eqx.field(static=True, default=0.01)
    slip_width: float | None = eqx.field(static=True, default=None)
    ring_width: float = eqx.field(static=True, default=1e-8)
    max_steps: int = eqx.field(static=True, default=4096)
    stiffness_limit: float = eqx.field(static=True, default=1000.0)
    outputs: str = eqx.field(static=True, default="full")

    def __check_init__(self):
        methods = ("auto", "tsit5", "dopri5", "dopri8", "rk4", "kvaerno3", "kvaerno5")
        if self.method not in methods:
            raise SceneError(f"solver.method must be one of {methods}, got {self.method!r}")
        for name in ("rtol", "atol"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and 0 < v < 1):
                raise SceneError(f"solver.{name} must be in (0, 1), got {v!r}")
        for name in ("dt", "slip_width", "ring_width", "stiffness_limit"):
            v = getattr(self, name)
            if v is None and name == "slip_width":
                continue
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise SceneError(f"solver.{name} must be a finite number > 0, got {v!r}")
        if self.outputs not in ("full", "rebound"):
            raise SceneError(f"solver.outputs must be 'full' or 'rebound', got {self.outputs!r}")
        if not (isinstance(self.max_steps, int) and self.max_steps >= 16):
            raise SceneError(f"solver.max_steps must be an integer >= 16, got {self.max_steps!r}")


class Scene(eqx.Module):
    """A complete simulation set-up: ``particle``, ``contact``, ``model``, ``impact``, ``solver``
    (and ``priors`` for a Bayesian fit, which the simulation ignores).

    Replace parts with ``eqx.tree_at`` or :meth:`replace`, e.g.
    ``scene.replace(contact={"f0": 0.0})``.
    """

    particle: Particle
    contact: Contact
    # Factories, not instances: building JAX arrays at import would start the JAX backend before
    # a user (or `jaximpact sweep --distributed`) can configure it.
    model: Model = eqx.field(default_factory=Model)
    impact: Impact = eqx.field(default_factory=lambda: Impact(speed=1.0))
    solver: Solver = eqx.field(default_factory=Solver)
    # ((name, "loguniform:LO:HI" | "normal:MU:SD"), ...): the scene file's [priors], read by
    # `fitting.sample_posterior`; the simulation ignores them.
    priors: tuple[tuple[str, str], ...] = eqx.field(static=True, default=())
    # A second sphere struck instead of the flat wall (None: the wall).
    target: Target | None = None

    def __check_init__(self):
        if self.model.normal == "thornton_ning":
            check_range(
                "contact.w (needed by model.normal = 'thornton_ning')",
                self.contact.w,
                positive=True,
            )
            check_range(
                "contact.p_y (needed by model.normal = 'thornton_ning')",
                self.contact.p_y,
                positive=True,
            )
            self._check_yield_after_touch()
        if self.model.tangential in ("mindlin", "lammps_mindlin"):
            check_range(
                f"contact.G_star (needed by model.tangential = '{self.model.tangential}')",
                self.contact.G_star,
                positive=True,
            )
        if self.model.tangential == "lammps_linear_history":
            check_range(
                "contact.k_t (needed by model.tangential = 'lammps_linear_history')",
                self.contact.k_t,
                positive=True,
            )
        if self.model.damping != "hertzian":
            self._check_lammps_damping()

    def _check_lammps_damping(self):
        """A LAMMPS damping replaces the Hertzian one: ``C_H`` must be 0; Tsuji's coefficient
        is a restitution coefficient in (0, 1]."""
        c, damping = self.contact, self.model.damping
        if _is_concrete(c.C_H) and np.any(np.asarray(c.C_H) != 0):
            raise SceneError(
                f'contact.C_H must be 0 with model.damping = "{damping}" (got {_show(c.C_H)} '
                "s/m): C_H is the Hertzian damping, which the LAMMPS damping replaces; give its "
                "coefficient as contact.eta_n"
            )
        if damping == "tsuji" and _is_concrete(c.eta_n):
            e = np.asarray(c.eta_n, float)
            if np.any(~((e > 0) & (e <= 1))):
                raise SceneError(
                    'contact.eta_n must be in (0, 1] with model.damping = "tsuji" (the '
                    f"restitution coefficient that sets Tsuji's alpha), got {_show(c.eta_n)}"
                )

    def _check_yield_after_touch(self):
        """Thornton-Ning: the contact must not yield before it forms, i.e. ``p_y`` above the
        JKR centre pressure at first touch, ``0.5875 (E*^2 w / r)^(1/3)`` (at the zero-overlap
        radius ``(2 pi w r^2 / E*)^(1/3)``; reduced radius with a target)."""
        c, r = self.contact, self.particle.radius
        if not all(_is_concrete(x) for x in (c.K, c.w, c.p_y, r)):
            return
        if self.target is not None:
            r = r * self.target.radius / (r + self.target.radius)
        E = 0.75 * np.asarray(c.K, float)
        x0 = (2.0 * np.pi) ** (1.0 / 3.0)
        touch = (2.0 / np.pi * x0 - np.sqrt(2.0 / np.pi / x0)) * (E * E * c.w / r) ** (1.0 / 3.0)
        if np.any(np.asarray(c.p_y) <= touch):
            raise SceneError(
                f"contact.p_y must be above the JKR centre pressure at first touch, "
                f"{float(np.max(touch)):.4g} Pa for this K, w and radius (got {_show(c.p_y)}): "
                "below it the contact would yield before it forms, outside the Thornton-Ning "
                "law's range"
            )

    def with_normal_law(self, law: str) -> "Scene":
        """This scene with another normal law (``model.normal``), its adhesion carried over:
        ``f0`` and ``w`` are converted where the one needed is 0, by equal adhesion force at
        the Brach-Dunn law's adhesive equilibrium overlap ``2 pi f0 / K`` (``2 pi a f0 = 2 pi
        w r``: ``w = f0 sqrt(2 pi f0 / (K r))``); a starting point for a fit, not an
        equivalence (the laws differ in shape)."""
        if law not in NORMAL_LAWS:
            raise SceneError(f"model.normal must be one of {NORMAL_LAWS}, got {law!r}")
        if law == self.model.normal:
            return self
        c, r = self.contact, self.particle.radius
        if self.model.normal == "brach_dunn":
            w = (
                c.w
                if np.all(np.asarray(c.w) > 0)
                else c.f0 * jnp.sqrt(2 * jnp.pi * c.f0 / (c.K * r))
            )
            f0 = 0.0
        else:
            w = c.w
            f0 = (c.w**2 * c.K * r / (2 * jnp.pi)) ** (1 / 3) if law == "brach_dunn" else 0.0
        model = {"normal": law}
        if law != "jkr":  # the release rule is JKR's
            model["jkr_release"] = "snap_off"
        return self.replace(contact={"f0": f0, "w": w if law != "brach_dunn" else 0.0}, model=model)

    def replace(self, **sections):
        """A copy with fields replaced: ``scene.replace(contact={"f0": 1.0}, solver={...})``."""
        new = self
        for section, fields in sections.items():
            part = getattr(self, section)
            if part is None:
                raise SceneError(f"the scene has no [{section}] to replace fields of")
            kwargs = {f: getattr(part, f) for f in part.__dataclass_fields__}
            unknown = set(fields) - set(kwargs)
            if unknown:
                raise SceneError(
                    f"unknown field(s) {sorted(unknown)} in [{section}]; allowed: {sorted(kwargs)}"
                )
            kwargs.update(fields)
            new = eqx.tree_at(lambda s, sec=section: getattr(s, sec), new, type(part)(**kwargs))
        return new


def hertz_stiffness(E1, nu1, E2, nu2):
    """``K = 4 / (3 pi (k1 + k2))`` with ``k_i = (1 - nu_i^2) / (pi E_i)`` (eq. 3-4), in Pa."""
    for name, v in (("E1", E1), ("E2", E2)):
        check_input(f"contact.{name}", "E", v)
    for name, v in (("nu1", nu1), ("nu2", nu2)):
        check_input(f"contact.{name}", "nu", v)
    k1 = (1 - nu1**2) / (math.pi * E1)
    k2 = (1 - nu2**2) / (math.pi * E2)
    return 4.0 / (3.0 * math.pi * (k1 + k2))


def shear_modulus_star(E1, nu1, E2, nu2):
    """``G* = 1 / ((2 - nu1)/G1 + (2 - nu2)/G2)`` with ``G_i = E_i / (2 (1 + nu_i))``, in Pa.

    The effective shear modulus of Mindlin's tangential stiffness ``8 G* a`` (a rigid anvil:
    ``E2 -> inf``, ``G* = G1 / (2 - nu1)``).
    """
    total = 0.0
    for E, nu in ((E1, nu1), (E2, nu2)):
        if math.isfinite(E):
            total += (2.0 - nu) * 2.0 * (1.0 + nu) / E
    return 1.0 / total


def damping_from_zeta(zeta, radius, density, K, reference_speed):
    """``C = zeta (r^3 K v^0.5 / m)^-0.4`` (eq. 21, 24): s/m from the paper's zeta at speed v."""
    mass = density * 4.0 / 3.0 * math.pi * radius**3
    return zeta * (radius**3 * K * reference_speed**0.5 / mass) ** -0.4


def table1_scene(**solver) -> Scene:
    """The paper's Table 1 scene (Brach, Dunn & Cheng 1999).

    r = 35 um, rho = 8000 kg/m^3, K = 11.4e10 Pa, f0 = 325 N/m, zeta_A = 400 and zeta_H = 100 at
    1.66 m/s (C_A = 0.882 s/m, C_H = 0.220 s/m), analytical rolling moments. Table 1 gives no
    friction coefficient: f = 0.3 is this project's choice. Default impact: 1.66 m/s, normal,
    omega0 = 1e6 deg/s.
    """
    r, rho, K, v = 35e-6, 8000.0, 11.4e10, 1.66
    return Scene(
        particle=Particle(radius=r, density=rho),
        contact=Contact(
            K=K,
            f0=325.0,
            C_A=damping_from_zeta(400.0, r, rho, K, v),
            C_H=damping_from_zeta(100.0, r, rho, K, v),
            friction=0.3,
        ),
        model=Model(rotation=True, adhesion=True, rolling_moments="analytical"),
        impact=Impact(speed=v, angle_deg=0.0, omega0=math.radians(1e6)),
        solver=Solver(**solver),
    )

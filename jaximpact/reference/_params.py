"""The reference's inputs and outputs: the scene parameters in SI units with the model
switches (``Params``), Table 1 of the paper, and ``ImpactResult``."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from .jkr import energy_loss, potential, pull_off, snap_off

#: Values of ``Params.rolling_moments``.
ROLLING_MOMENTS = ("none", "analytical", "lambda")


#: Values of ``Params.friction_load``.
FRICTION_LOADS = ("net", "hertz")


NORMAL_LAWS = ("brach_dunn", "dmt", "jkr")


#: Values of ``Params.tangential``.
TANGENTIAL_MODELS = ("rigid", "mindlin", "lammps_linear_history", "lammps_mindlin")


#: Values of ``Params.damping``.
DAMPING_MODELS = ("hertzian", "velocity", "mass_velocity", "viscoelastic", "tsuji")


#: The paper's reference impact speed, m/s.
TABLE1_SPEED = 1.66


#: The spin of the paper's oblique impacts, 1e6 deg/s in rad/s.
TABLE1_OMEGA0 = 1e6 * math.pi / 180.0


@dataclass(frozen=True)
class Params:
    """Scene parameters in SI units and the model switches."""

    radius: float  # m
    density: float  # kg/m^3
    K: float  # Pa
    f0: float = 0.0  # N/m
    C_A: float = 0.0  # s/m
    C_H: float = 0.0  # s/m
    friction: float = 0.0
    lam: float = 0.0  # N m
    kappa: float = 0.4  # k^2 / r^2
    rotation: bool = True
    adhesion: bool = True
    rolling_moments: str = "analytical"
    friction_load: str = "net"
    # "rigid", "mindlin" (the elastic spring 8 G* a, see _MindlinModel) or LAMMPS's history
    # springs "lammps_linear_history" (k_t) and "lammps_mindlin" (8 G* a): no normal force of
    # the spring, Coulomb load LAMMPS's critical normal force
    tangential: str = "rigid"
    G_star: float = 0.0  # Pa, effective shear modulus (mindlin only)
    # "dmt": constant adhesion 2 pi w r in contact, no ring; "jkr": the JKR force, contact
    # down to the snap-off overlap (< 0)
    normal: str = "brach_dunn"
    w: float = 0.0  # J/m^2, work of adhesion (dmt and jkr)
    # A second sphere struck instead of the wall (radius2 = inf: the wall): radius (m),
    # density (kg/m^3) and its spin before the impact (rad/s, the sense of omega0)
    radius2: float = math.inf
    density2: float = 1.0
    omega2: float = 0.0
    # The normal damping: "hertzian" (C_H) or one of LAMMPS's ("velocity", "mass_velocity",
    # "viscoelastic", "tsuji"), whose coefficient eta_n is in LAMMPS's units (SI; tsuji: the
    # restitution coefficient that sets alpha)
    damping: str = "hertzian"
    eta_n: float = 0.0
    # Where a JKR contact ends: "snap_off" (the least overlap of the stable branch) or
    # "pull_off" (where the force is least: load control, LAMMPS's rule)
    jkr_release: str = "snap_off"
    k_t: float = 0.0  # N/m, LAMMPS's linear_history stiffness

    def __post_init__(self):
        if self.normal not in NORMAL_LAWS:
            raise ValueError(f"normal must be one of {NORMAL_LAWS}")
        if self.tangential not in TANGENTIAL_MODELS:
            raise ValueError(f"tangential must be one of {TANGENTIAL_MODELS}")
        if self.tangential in ("mindlin", "lammps_mindlin") and not self.G_star > 0:
            raise ValueError(f"G_star must be > 0 with tangential = {self.tangential!r}")
        if self.tangential == "lammps_linear_history" and not self.k_t > 0:
            raise ValueError("k_t must be > 0 with tangential = 'lammps_linear_history'")
        if self.jkr_release not in ("snap_off", "pull_off"):
            raise ValueError("jkr_release must be 'snap_off' or 'pull_off'")
        if self.damping not in DAMPING_MODELS:
            raise ValueError(f"damping must be one of {DAMPING_MODELS}")
        if self.damping != "hertzian" and self.C_H != 0:
            raise ValueError("C_H must be 0 with a LAMMPS damping")
        if self.rolling_moments not in ROLLING_MOMENTS:
            raise ValueError(f"rolling_moments must be one of {ROLLING_MOMENTS}")
        if self.friction_load not in FRICTION_LOADS:
            raise ValueError(f"friction_load must be one of {FRICTION_LOADS}")
        for name in ("radius", "density", "K", "kappa", "radius2", "density2"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")
        for name in ("f0", "C_A", "C_H", "friction", "lam", "w"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0")

    @property
    def target(self) -> bool:
        """A second sphere instead of the wall."""
        return math.isfinite(self.radius2)

    @property
    def reduced_radius(self) -> float:
        """The contact's radius: ``r r2 / (r + r2)`` (the sphere's own on the wall)."""
        if not self.target:
            return self.radius
        return self.radius * self.radius2 / (self.radius + self.radius2)

    @property
    def mass2(self) -> float:
        return self.density2 * 4.0 / 3.0 * math.pi * self.radius2**3

    @property
    def reduced_mass(self) -> float:
        """The normal motion's mass: ``m m2 / (m + m2)`` (the sphere's own on the wall)."""
        if not self.target:
            return self.mass
        return self.mass * self.mass2 / (self.mass + self.mass2)

    @property
    def ring(self) -> bool:
        """The Brach-Dunn adhesion ring (force, damping, peeling moment) acts."""
        return self.adhesion and self.normal == "brach_dunn"

    @property
    def adhesive_overlap(self) -> float:
        """The overlap where the Hertz force balances the adhesion at rest (0 without it)."""
        if not self.adhesion:
            return 0.0
        if self.normal == "dmt":
            r = self.reduced_radius
            return (2.0 * math.pi * self.w * math.sqrt(r) / self.K) ** (2.0 / 3.0)
        if self.normal == "jkr":  # the overlap scale mu = (w^2 R / E^2)^(1/3)
            return (self.w**2 * self.reduced_radius / (0.75 * self.K) ** 2) ** (1.0 / 3.0)
        return 2.0 * math.pi * self.f0 / self.K

    @property
    def jkr(self) -> bool:
        """The JKR law acts (with ``w = 0`` or without adhesion it is Hertz's)."""
        return self.adhesion and self.normal == "jkr" and self.w > 0

    @property
    def separation_overlap(self) -> float:
        """Where the contact ends: 0, or the JKR snap-off overlap (< 0)."""
        if not self.jkr:
            return 0.0
        if self.jkr_release == "pull_off":
            return pull_off(self.reduced_radius, 0.75 * self.K, self.w)[1]
        return snap_off(self.reduced_radius, 0.75 * self.K, self.w)[1]

    @property
    def jkr_barrier(self) -> float:
        """The JKR potential at the snap-off (0 without JKR): the energy an elastic JKR
        impact loses, which a sphere in contact must have to leave."""
        if not self.jkr:
            return 0.0
        if self.jkr_release == "pull_off":  # the JKR potential there (zero at first touch)
            r, E = self.reduced_radius, 0.75 * self.K
            return potential(pull_off(r, E, self.w)[0], r, E, self.w)
        return energy_loss(self.reduced_radius, 0.75 * self.K, self.w)

    @property
    def mass(self) -> float:
        return self.density * 4.0 / 3.0 * math.pi * self.radius**3

    @property
    def k2(self) -> float:
        """Squared centroidal radius of gyration."""
        return self.kappa * self.radius**2


def zeta_to_c(zeta: float, radius: float, density: float, K: float, speed: float) -> float:
    """Damping constant C [s/m] from the paper's zeta = C (r^3 K v^0.5 / m)^0.4 (eq. 21, 24)."""
    m = density * 4.0 / 3.0 * math.pi * radius**3
    return zeta / (radius**3 * K * math.sqrt(speed) / m) ** 0.4


def table1_params(**overrides) -> Params:
    """The paper's Table 1 scene (friction 0.3, not given in the paper; lambda 0).

    ``zeta_A = 400`` and ``zeta_H = 100`` at 1.66 m/s give ``C_A ~ 0.882`` and ``C_H ~ 0.220`` s/m.
    Keyword arguments override any field of :class:`Params`.
    """
    r, rho, K = 35e-6, 8000.0, 11.4e10
    base = dict(
        radius=r,
        density=rho,
        K=K,
        f0=325.0,
        C_A=zeta_to_c(400.0, r, rho, K, TABLE1_SPEED),
        C_H=zeta_to_c(100.0, r, rho, K, TABLE1_SPEED),
        friction=0.3,
        lam=0.0,
        rolling_moments="analytical",
    )
    base.update(overrides)
    return Params(**base)


@dataclass
class ImpactResult:
    """Outcome of one impact, SI units.  ``roll_time`` is NaN when the slip never reaches zero."""

    status: str  # "rebound" | "captured" | "failed"
    vn_out: float  # -ndot at the end (away from the surface)
    vt_out: float
    omega_out: float
    contact_time: float
    roll_time: float
    max_overlap: float
    energy_in: float
    energy_out: float
    loss_hertz_damping: float
    loss_adhesion_damping: float
    loss_friction: float
    loss_rolling: float
    n_out: float = 0.0  # overlap at the end (0 for a rebound, > 0 for a capture)
    omega2_out: float = math.nan  # a second sphere's spin at the end (NaN: none, or no rotation)
    n_segments: int = 0  # integration restarts + 1
    message: str = ""
    history: dict | None = field(default=None, repr=False)

    @property
    def total_loss(self) -> float:
        return (
            self.loss_hertz_damping
            + self.loss_adhesion_damping
            + self.loss_friction
            + self.loss_rolling
        )

    @property
    def ledger_residual(self) -> float:
        """(energy_in - energy_out - total_loss) / energy_in; zero up to solver error."""
        return (self.energy_in - self.energy_out - self.total_loss) / self.energy_in

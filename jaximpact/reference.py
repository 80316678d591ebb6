"""Exact (switched, non-smooth) float64 reference implementation of the impact model.

This module is the yardstick for the smooth JAX model.  It depends on numpy and scipy only,
imports nothing else from ``jaximpact`` and works in SI units throughout.

Model (Brach, Dunn & Cheng 1999, with the project's errata)
----------------------------------------------------------
State: overlap ``n`` [m] (contact when ``n > 0``), ``ndot`` [m/s] (> 0 approaching), tangential
velocity ``tdot`` [m/s] and spin ``w`` [rad/s], signed so that ``tdot == r w`` is pure rolling;
slip ``s = tdot - r w``.  ``m = rho 4/3 pi r^3``, ``k^2 = kappa r^2`` (solid sphere: 2/5),
contact radius ``a = sqrt(r n)``.  Every force and moment is zero for ``n <= 0``.

Normal force (positive toward the surface)::

    F_H  = -K sqrt(r) n^1.5                      Hertz
    F_HD = -K sqrt(r) n^1.5 C_H ndot             Hertz damping
    F_A  = 2 pi a f0                             adhesion ring (if adhesion)
    F_AD = f0 C_A a I0                           adhesion damping (if adhesion)
    F_n  = F_H + F_HD + F_A + F_AD

The ring point at angle alpha moves normally at ``u = ndot + b cos(alpha)`` with ``b = w a``;
where ``u < 0`` (separating) it carries the attractive line force ``f0 C_A (-u)``.  Hence
``I0 = int_0^2pi max(-u, 0) dalpha`` and the peeling moment ``M_A = f0 C_A a^2 I1`` with
``I1 = int_0^2pi max(-u, 0) cos(alpha) dalpha`` (closed form in :func:`ring_integrals`).
The spin enters the ring only for ``rolling_moments == "analytical"``; otherwise ``b = 0`` and
``M_A = 0``.

Rolling moment ``M``::

    "analytical": M = M_A + M_H,  M_H = -(K/5) sqrt(n/r) C_H a^4 w
    "lambda":     M = -lam C_A a w
    "none":       M = 0

Friction (exact Coulomb): load ``N = |F_n|`` ("net") or ``N = K sqrt(r) n^1.5`` ("hertz").
Sliding (``s != 0``): ``F_t = -f N sgn(s)``.  Pure rolling (``s == 0``): ``F_t = F_req =
r M / (k^2 + r^2)``, the force that keeps ``s' = 0``, as long as ``|F_req| <= f N``; beyond that
sliding resumes with ``sgn(s) = -sgn(F_req)``.  Without rotation (no spin dof, ``w == 0``) the
slip is ``tdot`` and a sphere whose ``tdot`` reaches 0 sticks (``F_t = 0``).

With ``Params.tangential = "mindlin"`` the friction law is replaced by an elastic tangential
spring capped by Coulomb friction, switched exactly (stick/slip events): see the section
"The Mindlin tangential spring" at the end of this module.

Equations of motion::

    m nddot = F_n,   m tddot = F_t,   m k^2 wdot = -r F_t + M

Energy ledger (extra ODE states): ``loss_hertz_damping = int -F_HD ndot``, ``loss_adhesion_damping
= int -F_AD ndot``, ``loss_friction = int -F_t s``, ``loss_rolling = int -M w``.  With the
normal potential ``V(n) = (2/5) K sqrt(r) n^2.5 - (4/3) pi f0 sqrt(r) n^1.5`` (f0 term only with
adhesion), ``energy_in - energy_out`` equals the sum of the losses.  (``F_AD ndot`` alone can be
positive when a spinning ring partly separates while the centre approaches; ``F_AD ndot + M_A w``
never is.)

End of an impact: rebound when ``n`` returns to 0 while separating; capture when the normal
energy ``E = m ndot^2 / 2 + V(n)`` falls below 0 (exact without spin; with spin the partial ring
can feed a little rotational energy back into E, so :func:`simulate_impact` accepts
``detect_capture=False`` to check a capture by integrating on).  Anything else is "failed".

Numerics
--------
``scipy.integrate.solve_ivp`` (DOP853 by default) on a rescaled copy of the SI state (overlap
scale ``L``: the Hertz peak overlap or the adhesive one ``2 pi f0 / K``, whichever is larger;
time scale ``T`` of the stiffness there), so that tolerances mean the same for every scene.  The
slip ``s`` is integrated in place of ``tdot`` (``tdot = s + r w``): its rate is exactly zero in
pure rolling, and its sign is resolved far below the size of ``tdot``.  Every switch is an event
and the integration restarts there: slip reaching zero, ``F_req`` reaching ``+-f N``, the
ring-regime boundaries ``ndot = +-b`` (kinks of the ring integrals), ``F_n = 0`` (kink of
``|F_n|``), separation and capture.  The ``sqrt(n)`` singularity of the adhesion force at
``n = 0`` is side-stepped: contact starts at ``n = 1e-12 L`` at ``t = n / v_n`` (free approach
before) and ends when ``n`` comes back down to that value; what this neglects is
``O((1e-12)^1.5)`` relative, far below the solver tolerance.  The time to cross the last
``1e-12 L`` is added to the contact time.  ``roll_time`` is the first time the slip reaches zero
(0 when the impact starts without slip, NaN if never; without rotation: the time ``tdot``
reaches zero and the sphere sticks).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.integrate import solve_ivp

__all__ = [
    "ImpactResult",
    "Params",
    "TABLE1_OMEGA0",
    "TABLE1_SPEED",
    "capture_speed",
    "contact_forces",
    "hertz_scales",
    "impact_history",
    "normal_potential",
    "ring_integrals",
    "simulate_impact",
    "table1_params",
    "zeta_to_c",
]

ROLLING_MOMENTS = ("none", "analytical", "lambda")
FRICTION_LOADS = ("net", "hertz")

TABLE1_SPEED = 1.66  # m/s, the paper's reference impact speed
TABLE1_OMEGA0 = 1e6 * math.pi / 180.0  # 1e6 deg/s in rad/s

_N_EPS = 1e-12  # contact starts and ends at n = _N_EPS * L (sqrt(n) singularity, see docstring)
_LOOKAHEAD = 1e-9  # in time scales T: how far ahead to look to tell the side of a kink at a restart
_MAX_STALLS = 50  # consecutive zero-length segments before giving up


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
    tangential: str = "rigid"  # or "mindlin": the elastic spring 8 G* a (see _MindlinModel)
    G_star: float = 0.0  # Pa, effective shear modulus (mindlin only)

    def __post_init__(self):
        if self.tangential not in ("rigid", "mindlin"):
            raise ValueError("tangential must be 'rigid' or 'mindlin'")
        if self.tangential == "mindlin" and not self.G_star > 0:
            raise ValueError("G_star must be > 0 with tangential = 'mindlin'")
        if self.rolling_moments not in ROLLING_MOMENTS:
            raise ValueError(f"rolling_moments must be one of {ROLLING_MOMENTS}")
        if self.friction_load not in FRICTION_LOADS:
            raise ValueError(f"friction_load must be one of {FRICTION_LOADS}")
        for name in ("radius", "density", "K", "kappa"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")
        for name in ("f0", "C_A", "C_H", "friction", "lam"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0")

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


def hertz_scales(p: Params, v_n: float) -> tuple[float, float]:
    """Peak overlap n* of an undamped, non-adhesive Hertz impact at normal speed v_n, and n*/v_n."""
    n_star = (5.0 * p.mass * v_n**2 / (4.0 * p.K * math.sqrt(p.radius))) ** 0.4
    return n_star, n_star / v_n


def ring_integrals(ndot: float, b: float) -> tuple[float, float]:
    """I0 = int max(-u,0) da and I1 = int max(-u,0) cos(a) da over [0, 2pi], u = ndot + b cos(a)."""
    ab = abs(b)
    if ndot >= ab:  # the whole ring approaches (or is at rest): no damping
        return 0.0, 0.0
    if ndot <= -ab:  # the whole ring separates
        return -2.0 * math.pi * ndot, -math.pi * b
    # partial ring: u < 0 for beta < alpha < 2 pi - beta, cos(beta) = -ndot/|b|
    c = -ndot / ab
    beta = math.acos(c)
    sb = math.sqrt(max(1.0 - c * c, 0.0))
    i0 = -2.0 * ndot * (math.pi - beta) + 2.0 * ab * sb
    i1 = 2.0 * ndot * sb - ab * (math.pi - beta) + ab * sb * c  # (b/2) sin(2 beta) = b sb c
    return i0, (i1 if b > 0 else -i1)


def contact_forces(p: Params, n: float, ndot: float, w: float) -> dict:
    """Normal force parts, rolling moments and friction load at a state (SI).

    Returns a dict with F_H, F_HD, F_A, F_AD, F_n, M_A, M_H, M and N.
    """
    out = dict(F_H=0.0, F_HD=0.0, F_A=0.0, F_AD=0.0, F_n=0.0, M_A=0.0, M_H=0.0, M=0.0, N=0.0)
    if not n > 0:
        return out
    r = p.radius
    a = math.sqrt(r * n)
    hertz = p.K * math.sqrt(r) * n**1.5
    out["F_H"] = -hertz
    out["F_HD"] = -hertz * p.C_H * ndot
    analytical = p.rolling_moments == "analytical"
    if p.adhesion:
        out["F_A"] = 2.0 * math.pi * a * p.f0
        i0, i1 = ring_integrals(ndot, w * a if analytical else 0.0)
        out["F_AD"] = p.f0 * p.C_A * a * i0
        if analytical:
            out["M_A"] = p.f0 * p.C_A * a * a * i1
    if analytical:
        out["M_H"] = -(p.K / 5.0) * math.sqrt(n / r) * p.C_H * a**4 * w
        out["M"] = out["M_A"] + out["M_H"]
    elif p.rolling_moments == "lambda":
        out["M"] = -p.lam * p.C_A * a * w
    out["F_n"] = out["F_H"] + out["F_HD"] + out["F_A"] + out["F_AD"]
    out["N"] = abs(out["F_n"]) if p.friction_load == "net" else hertz
    return out


def normal_potential(p: Params, n: float) -> float:
    """V(n), the potential of F_H + F_A (zero out of contact)."""
    if not n > 0:
        return 0.0
    v = 0.4 * p.K * math.sqrt(p.radius) * n**2.5
    if p.adhesion:
        v -= 4.0 / 3.0 * math.pi * p.f0 * math.sqrt(p.radius) * n**1.5
    return v


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


# Tangential modes: +1 / -1 sliding with that slip sign, 0 pure rolling (or sticking without
# rotation), 2 frictionless (f == 0: F_t = 0 and no tangential switches at all).
_ROLL, _FREE = 0, 2


class _Model:
    """The switched right-hand side, event functions and mode logic.

    Internal SI state: ``[n, ndot, s, w, loss_HD, loss_AD, loss_F, loss_R]``.  The slip ``s`` is
    integrated itself (``tdot = s + r w``): in pure rolling its rate is exactly zero, and while
    sliding its sign is resolved far below the size of ``tdot`` (no cancellation in
    ``tdot - r w``), which the switching logic relies on.
    """

    def __init__(self, p: Params):
        self.p = p
        self.m = p.mass
        self.r = p.radius
        self.k2 = p.k2 if p.rotation else 0.0
        self.f = p.friction

    def slip(self, y) -> float:
        return y[2]

    def tdot(self, y) -> float:
        return y[2] + self.r * y[3] if self.p.rotation else y[2]

    def required_force(self, M: float) -> float:
        """Friction that keeps s' = 0 (pure rolling)."""
        return self.r * M / (self.k2 + self.r**2) if self.p.rotation else 0.0

    def friction_force(self, mode: int, fc: dict) -> float:
        if mode in (1, -1):
            return -self.f * fc["N"] * mode
        if mode == _ROLL:
            return self.required_force(fc["M"])
        return 0.0

    def rhs(self, y, mode: int) -> list:
        n, ndot, w = y[0], y[1], y[3]
        fc = contact_forces(self.p, n, ndot, w)
        F_t = self.friction_force(mode, fc)
        M = fc["M"]
        s = y[2]
        if self.p.rotation:
            wdot = (-self.r * F_t + M) / (self.m * self.k2)
            # s' = tddot - r wdot, written so that it is exactly zero in pure rolling
            sdot = (
                0.0
                if mode == _ROLL
                else (F_t * (self.k2 + self.r**2) - self.r * M) / (self.m * self.k2)
            )
        else:
            wdot = 0.0
            sdot = F_t / self.m
        return [
            ndot,
            fc["F_n"] / self.m,
            sdot,
            wdot,
            -fc["F_HD"] * ndot,
            -fc["F_AD"] * ndot,
            -F_t * s,
            -M * w,
        ]

    def normal_energy(self, y) -> float:
        return 0.5 * self.m * y[1] ** 2 + normal_potential(self.p, y[0])

    def mechanical_energy(self, y) -> float:
        ke_t = 0.5 * self.m * self.tdot(y) ** 2
        return self.normal_energy(y) + ke_t + 0.5 * self.m * self.k2 * y[3] ** 2

    def decide(self, y, h_look: float = 0.0) -> int:
        """Mode at zero slip: roll if friction can hold it, else slide against the imbalance.

        The test is also made a look-ahead time ``h_look`` later along the rolling motion: where
        the load passes through zero (``F_n = 0`` with the net load) the cone closes for an
        instant only, and sliding there would last no time at all. Deciding "slide" at that
        instant made the sliding segment end at once and the run stall at the switch (seen for
        slips of 1e-6 of the speed near normal incidence).
        """
        if self.f == 0:
            return _FREE
        if not self.p.rotation:
            return _ROLL

        def holds(z):
            fc = contact_forces(self.p, z[0], z[1], z[3])
            return abs(self.required_force(fc["M"])) <= self.f * fc["N"], fc

        ok, fc = holds(y)
        if ok or (h_look > 0 and holds(y + h_look * np.array(self.rhs(y, _ROLL)))[0]):
            return _ROLL
        return -1 if self.required_force(fc["M"]) > 0 else 1

    def project_to_rolling(self, y) -> np.ndarray:
        """Remove the round-off slip left at a switch by a tiny tangential impulse.

        The kinetic energy it changes (~1e-16 relative) is booked as friction loss, so that the
        ledger stays exact.
        """
        y = np.array(y, dtype=float)
        ke0 = 0.5 * self.m * (self.tdot(y) ** 2 + self.k2 * y[3] ** 2)
        if self.p.rotation:
            dv = -y[2] / (1.0 + self.r**2 / self.k2)  # impulse / m; s changes by -s
            y[3] -= self.r * dv / self.k2
        y[2] = 0.0
        y[6] -= 0.5 * self.m * (self.tdot(y) ** 2 + self.k2 * y[3] ** 2) - ke0
        return y

    def kink_functions(self) -> list:
        """Functions whose zeros are kinks of the right-hand side (not mode switches)."""
        p = self.p
        out = []
        if p.adhesion and p.f0 * p.C_A > 0:
            if p.rolling_moments == "analytical":
                out.append(lambda y: y[1] - y[3] * math.sqrt(self.r * max(y[0], 0.0)))
                out.append(lambda y: y[1] + y[3] * math.sqrt(self.r * max(y[0], 0.0)))
            else:
                out.append(lambda y: y[1])
        if self.f > 0 and p.friction_load == "net":
            out.append(self.normal_force)
        return out

    def normal_force(self, y) -> float:
        return contact_forces(self.p, y[0], y[1], y[3])["F_n"]

    def mode_functions(self, mode: int, sign_fn: float) -> list:
        """(function, next mode or None to decide) pairs whose downward zero ends the mode.

        ``sign_fn`` is the sign of F_n over the segment (a restart happens where it changes).  The
        rolling limits use ``sign_fn * F_n`` instead of ``|F_n|``: equal within the segment, but
        smooth, so that a dip of ``f |F_n| - |F_req|`` below zero just before ``F_n = 0`` shows
        as a sign change over the step that crosses the kink.
        """
        if mode in (1, -1):
            return [(lambda y: mode * self.slip(y), None)]
        p = self.p
        moments = p.rolling_moments == "analytical" or (
            p.rolling_moments == "lambda" and p.lam * p.C_A > 0
        )
        if mode == _ROLL and p.rotation and moments:

            def load_and_req(y):
                fc = contact_forces(p, y[0], y[1], y[3])
                load = sign_fn * fc["F_n"] if p.friction_load == "net" else fc["N"]
                return self.f * load, self.required_force(fc["M"])

            def upper(y):  # F_req rising through +f N: friction saturates at +f N, slip < 0
                fn, req = load_and_req(y)
                return fn - req

            def lower(y):
                fn, req = load_and_req(y)
                return fn + req

            return [(upper, -1), (lower, 1)]
        return []


def _make_event(g, S, terminal, direction):
    def ev(tau, z):
        return g(z * S)

    ev.terminal = terminal
    ev.direction = direction
    return ev


def _segment_end(sol, y_new, dt, T, stalls) -> tuple[int, str]:
    """How a ``solve_ivp`` segment ended: the updated count of zero-length segments in a row,
    and a message when the run must stop there (solver failure, time limit, stalled)."""
    if sol.status == -1 or not np.all(np.isfinite(y_new)):
        return stalls, f"solver failure: {sol.message}"
    if sol.status == 0:
        return stalls, "time limit reached"
    stalls = stalls + 1 if dt <= 1e-14 * T else 0
    return stalls, "stalled at a switch" if stalls > _MAX_STALLS else ""


def _fired_events(specs, sol) -> list:
    """The kinds of the terminal events that stopped the segment (earliest kinds first on
    exact ties, as listed in ``specs``)."""
    return [
        spec[3]
        for spec, te in zip(specs, sol.t_events, strict=True)
        if spec[1] and len(te) and te[-1] == sol.t[-1]
    ]


def simulate_impact(
    p: Params,
    speed: float,
    angle_deg: float = 0.0,
    omega0: float = 0.0,
    *,
    rtol: float = 1e-12,
    atol: float = 1e-15,
    method: str = "DOP853",
    t_max: float | None = None,
    detect_capture: bool = True,
    history: bool = False,
    n_samples: int | None = None,
    max_segments: int = 20000,
) -> ImpactResult:
    """Simulate one impact with the exact switched model.

    ``speed`` [m/s] > 0, ``angle_deg`` from the normal in (-90, 90), ``omega0`` [rad/s] (ignored,
    i.e. taken as 0, when ``p.rotation`` is False).  ``rtol``/``atol`` apply to the rescaled state
    (overlap scale L, time scale T, see :func:`hertz_scales`).  ``t_max`` [s] defaults to 1000 T;
    reaching it gives status "failed".  ``detect_capture=False`` disables the capture event (the
    run then ends in a rebound or at ``t_max``).  With ``history=True`` the result carries the
    time history (see :func:`impact_history`).
    """
    if not speed > 0:
        raise ValueError("speed must be > 0")
    if not -90.0 < angle_deg < 90.0:
        raise ValueError("angle_deg must lie in (-90, 90)")
    if p.tangential == "mindlin":
        if history:
            raise ValueError("history is not available with tangential = 'mindlin'")
        return _simulate_mindlin(
            p, speed, angle_deg, omega0, rtol=rtol, atol=atol, method=method, t_max=t_max,
            detect_capture=detect_capture, max_segments=max_segments,
        )  # fmt: skip
    model = _Model(p)
    m, r = model.m, model.r
    th = math.radians(angle_deg)
    v_n, v_t = speed * math.cos(th), speed * math.sin(th)
    w0 = float(omega0) if p.rotation else 0.0

    # Scales: overlap L (Hertz peak, or the adhesive equilibrium 2 pi f0 / K if larger), time T
    # (stiffness at overlap L), velocities V = L/T.
    n_star, _ = hertz_scales(p, v_n)
    L = max(n_star, 2.0 * math.pi * p.f0 / p.K if p.adhesion else 0.0)
    T = math.sqrt(m / (p.K * math.sqrt(r) * math.sqrt(L)))
    V = L / T
    Vt = max(V, abs(v_t), r * abs(w0))
    E0 = m * max(V, speed, Vt) ** 2
    S = np.array([L, V, Vt, Vt / r, E0, E0, E0, E0])
    # The slip's sign decides the friction direction: resolve it far below the other errors.
    atol_vec = np.full(8, atol)
    atol_vec[2] = atol * 1e-6
    if t_max is None:
        t_max = 1000.0 * T

    n_eps = _N_EPS * L
    t = n_eps / v_n
    y = np.array([n_eps, v_n, v_t - r * w0 if p.rotation else v_t, w0, 0, 0, 0, 0], dtype=float)
    energy_in = 0.5 * m * speed**2 + 0.5 * m * model.k2 * w0**2

    slip0 = model.slip(y)
    if model.f == 0:
        mode = _FREE
    elif slip0 == 0:
        mode = model.decide(y)
    else:
        mode = 1 if slip0 > 0 else -1
    roll_time = 0.0 if (mode == _ROLL and slip0 == 0) else math.nan

    base_events = [(lambda y: y[0] - n_eps, True, -1, "rebound")]
    if detect_capture:
        base_events.append((model.normal_energy, True, -1, "captured"))
    base_events.append((lambda y: y[1], False, -1, "turn"))  # max overlap at ndot = 0
    kinks = model.kink_functions()
    h_look = _LOOKAHEAD * T

    status, message = "failed", ""
    max_overlap = n_eps
    segments = []  # (t0, t1, OdeSolution or None, mode, ts, ys) for the history
    stalls = 0
    n_seg = 0
    while True:
        if n_seg >= max_segments:
            message = "too many segments"
            break
        n_seg += 1
        # A kink event must fire only when leaving the side the state is on (or moving into,
        # when it sits on the kink after a restart), else it would fire at once again.
        y_look = y + h_look * np.array(model.rhs(y, mode))

        def side(g, y=y, y_look=y_look):
            g1 = g(y_look)
            return 1.0 if (g1 if g1 != 0 else g(y)) >= 0 else -1.0

        specs = list(base_events)
        for g, nxt in model.mode_functions(mode, side(model.normal_force)):
            specs.append((g, True, -1, ("mode", nxt)))
        for g in kinks:
            specs.append((g, True, -side(g), "kink"))
        events = [_make_event(g, S, term, d) for g, term, d, _ in specs]

        seg_mode = mode

        def fun(tau, z, seg_mode=seg_mode):
            return np.array(model.rhs(z * S, seg_mode)) * T / S

        sol = solve_ivp(
            fun,
            (t / T, t_max / T),
            y / S,
            method=method,
            rtol=rtol,
            atol=atol_vec,
            events=events,
            dense_output=history,
        )
        ys = sol.y * S[:, None]
        max_overlap = max(max_overlap, float(np.max(ys[0])))
        for (_, _, _, kind), ye in zip(specs, sol.y_events, strict=True):
            if kind == "turn" and len(ye):
                max_overlap = max(max_overlap, float(np.max(ye[:, 0])) * L)
        t_new = float(sol.t[-1]) * T
        y_new = ys[:, -1].copy()
        if history:
            segments.append((t, t_new, sol.sol, mode, sol.t * T, ys))
        stalls, message = _segment_end(sol, y_new, t_new - t, T, stalls)
        y, t = y_new, t_new
        if message:
            break
        fired = _fired_events(specs, sol)
        if "rebound" in fired:
            status = "rebound"
            break
        if "captured" in fired:
            status = "captured"
            break
        mode_events = [k for k in fired if isinstance(k, tuple)]
        if mode in (1, -1) and mode * y[2] <= 0 and not mode_events:
            # the slip reached zero together with a kink: same as the slip event
            mode_events = [("mode", None)]
        if mode_events:
            y = model.project_to_rolling(y)
            nxt = mode_events[0][1]
            if nxt is None:  # the slip reached zero
                if math.isnan(roll_time):
                    roll_time = t
                mode = model.decide(y, h_look)
            else:  # rolling can no longer be held: slide against the imbalance
                mode = nxt
        elif mode == _ROLL:
            # A restart at a kink (F_n = 0 above all, where the load vanishes): check again
            # that friction can still hold the rolling.
            y = model.project_to_rolling(y)
            mode = model.decide(y, h_look)

    contact_time = t
    if status == "rebound" and y[1] < 0:
        contact_time += y[0] / -y[1]  # the last n_eps, crossed at constant speed
    hist = None
    if history:
        hist = _build_history(model, segments, S, T, v_n, y, t, contact_time, n_samples)
    return ImpactResult(
        status=status,
        vn_out=float(-y[1]),
        vt_out=float(model.tdot(y)),
        omega_out=float(y[3]),
        contact_time=float(contact_time),
        roll_time=float(roll_time),
        max_overlap=float(max_overlap),
        energy_in=float(energy_in),
        energy_out=float(model.mechanical_energy(y)),
        loss_hertz_damping=float(y[4]),
        loss_adhesion_damping=float(y[5]),
        loss_friction=float(y[6]),
        loss_rolling=float(y[7]),
        n_out=float(y[0]) if status != "rebound" else 0.0,
        n_segments=n_seg,
        message=message,
        history=hist,
    )


def _history_row(model: _Model, y, mode: int) -> list:
    fc = contact_forces(model.p, y[0], y[1], y[3])
    F_t = model.friction_force(mode, fc) if y[0] > 0 else 0.0
    return [y[0], y[1], model.tdot(y), y[3], y[2], fc["F_n"], F_t, fc["M"], fc["N"], mode]


_HIST_KEYS = ("n", "ndot", "tdot", "w", "slip", "F_n", "F_t", "M", "N", "mode")


def _build_history(model, segments, S, T, v_n, y_end, t_end, contact_time, n_samples) -> dict:
    y_start = segments[0][5][:, 0]
    y0 = y_start.copy()
    y0[0] = 0.0
    rows_t, rows = [0.0], [_history_row(model, y0, segments[0][3])]
    if n_samples is None:
        # the solver's own steps; segment boundaries appear twice (forces may jump there)
        for _, _, _, mode, ts, ys in segments:
            for k in range(len(ts)):
                rows_t.append(float(ts[k]))
                rows.append(_history_row(model, ys[:, k], mode))
        if contact_time > t_end:
            y1 = y_end.copy()
            y1[0] = 0.0
            rows_t.append(contact_time)
            rows.append(_history_row(model, y1, segments[-1][3]))
    else:
        rows_t, rows = [], []
        for tq in np.linspace(0.0, contact_time, int(n_samples)):
            if tq <= segments[0][0]:  # before the analytic start: free approach
                yq = y_start.copy()
                yq[0] = v_n * tq
                mode = segments[0][3]
            elif tq >= t_end:  # the last n_eps
                yq = y_end.copy()
                yq[0] = max(y_end[0] + y_end[1] * (tq - t_end), 0.0)
                mode = segments[-1][3]
            else:
                seg = next(sg for sg in segments if sg[0] <= tq <= sg[1])
                yq = seg[2](tq / T) * S
                mode = seg[3]
            rows_t.append(float(tq))
            rows.append(_history_row(model, yq, mode))
    arr = np.array(rows)
    out = {"t": np.array(rows_t)}
    for j, key in enumerate(_HIST_KEYS):
        out[key] = arr[:, j]
    out["mode"] = out["mode"].astype(int)
    return out


def impact_history(
    p: Params,
    speed: float,
    angle_deg: float = 0.0,
    omega0: float = 0.0,
    n_samples: int | None = None,
    **options,
) -> tuple[dict, ImpactResult]:
    """Time history of one impact, for plotting.

    Returns ``(hist, result)``; ``hist`` maps t, n, ndot, tdot, w, slip, F_n, F_t, M, N and mode
    (+1/-1 sliding, 0 rolling or sticking, 2 frictionless) to arrays.  Without ``n_samples`` the
    rows are the solver's steps (each switch appears twice: forces jump there); with it, an even
    grid of ``n_samples`` times over the contact from the dense output.
    """
    res = simulate_impact(p, speed, angle_deg, omega0, history=True, n_samples=n_samples, **options)
    return res.history, res


def capture_speed(
    p: Params,
    angle_deg: float = 0.0,
    omega0: float = 0.0,
    lo: float = 1e-3,
    hi: float = 10.0,
    rel_tol: float = 1e-6,
    **options,
) -> float:
    """Bisection for the speed below which the impact is captured (``lo`` must capture, ``hi``
    rebound)."""

    def captured(v):
        st = simulate_impact(p, v, angle_deg, omega0, **options).status
        if st == "failed":
            raise RuntimeError(f"impact at {v} m/s failed")
        return st == "captured"

    if not captured(lo) or captured(hi):
        raise ValueError("the bracket [lo, hi] does not straddle the capture speed")
    while hi - lo > rel_tol * hi:
        mid = 0.5 * (lo + hi)
        if captured(mid):
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


#: Outputs and inputs of :func:`output_derivatives` (names as in ``jaximpact.ImpactResult`` and
#: the impacts CSV; ``lambda`` is ``Params.lam``).
DERIVATIVE_OUTPUTS = ("cor_n", "vt_out", "omega_out", "rebound_angle_deg", "contact_time")
DERIVATIVE_INPUTS = (
    "f0", "C_A", "C_H", "friction", "K", "radius", "density", "lambda",
    "speed", "angle_deg", "omega0",
)  # fmt: skip


def _outputs(res: ImpactResult, speed: float, angle_deg: float) -> dict:
    v_n = speed * math.cos(math.radians(angle_deg))
    return {
        "cor_n": res.vn_out / v_n,
        "vt_out": res.vt_out,
        "omega_out": res.omega_out,
        "rebound_angle_deg": math.degrees(math.atan2(res.vt_out, res.vn_out)),
        "contact_time": res.contact_time,
    }


def output_derivatives(
    p: Params,
    speed: float,
    angle_deg: float = 0.0,
    omega0: float = 0.0,
    inputs=DERIVATIVE_INPUTS,
    rel_step: float = 1e-4,
    **options,
) -> tuple[dict, dict]:
    """Derivatives of the outputs by central differences of the exact model, Richardson-checked.

    For each input ``x`` the central difference ``D(h)`` is taken at ``h`` and ``h/2`` (``h =
    rel_step * |x|``; for ``angle_deg`` ``rel_step * 180/pi`` degrees, for ``omega0``
    ``rel_step * speed / radius``); the Richardson value ``(4 D(h/2) - D(h)) / 3`` is returned
    with ``|Richardson - D(h/2)|`` as its error estimate (large where a regime switch lies
    within the step, or the reference's own noise, ~rtol / h, dominates).

    Returns ``(jac, err)``: dicts ``output -> input -> value``. Inputs whose value is 0 (a
    central difference would leave the allowed range) are skipped. ``options`` go to
    :func:`simulate_impact` (default ``rtol=1e-12``).
    """
    x0 = {
        "f0": p.f0, "C_A": p.C_A, "C_H": p.C_H, "friction": p.friction, "K": p.K,
        "radius": p.radius, "density": p.density, "lambda": p.lam,
        "speed": speed, "angle_deg": angle_deg, "omega0": omega0,
    }  # fmt: skip
    if p.tangential == "mindlin":
        x0["G_star"] = p.G_star

    def run(name, value):
        x = dict(x0, **{name: value})
        q = replace(
            p,
            **{
                ("lam" if k == "lambda" else k): x[k]
                for k in x0
                if k not in ("speed", "angle_deg", "omega0")
            },
        )
        res = simulate_impact(q, x["speed"], x["angle_deg"], x["omega0"], **options)
        if res.status == "failed":  # a rare stall at a switch: a second try at another rtol
            retry = dict(options, rtol=0.5 * options.get("rtol", 1e-12))
            res = simulate_impact(q, x["speed"], x["angle_deg"], x["omega0"], **retry)
        if res.status != "rebound":
            raise RuntimeError(
                f"{name} = {value!r}: the reference did not rebound ({res.status}: {res.message})"
            )
        return _outputs(res, x["speed"], x["angle_deg"])

    steps = {"angle_deg": rel_step * 180.0 / math.pi, "omega0": rel_step * speed / p.radius}
    jac = {k: {} for k in DERIVATIVE_OUTPUTS}
    err = {k: {} for k in DERIVATIVE_OUTPUTS}
    for name in inputs:
        h = steps.get(name, rel_step * abs(x0[name]))
        if h == 0:
            continue
        d = []
        for hh in (h, h / 2):
            up, down = run(name, x0[name] + hh), run(name, x0[name] - hh)
            d.append({k: (up[k] - down[k]) / (2 * hh) for k in DERIVATIVE_OUTPUTS})
        for k in DERIVATIVE_OUTPUTS:
            jac[k][name] = (4 * d[1][k] - d[0][k]) / 3
            err[k][name] = abs(jac[k][name] - d[1][k])
    return jac, err


# ---------------------------------------------------------------------------------------------
# The Mindlin tangential spring (``tangential = "mindlin"``), switched exactly
# ---------------------------------------------------------------------------------------------
#
# Elastic tangential displacement ``xi``; stiffness ``k_t = 8 G* a``, ``a = sqrt(r n)``; force on
# the sphere ``F_t = -k_t xi``, with the spring's normal force ``F_U = -k_t'(n) xi^2 / 2`` (the
# spring has the potential ``U = k_t xi^2 / 2``). Modes: stick (``xi' = s``, the slip velocity
# ``s = tdot - r w``) while ``k_t |xi| < f N``; slip with sign ``+-1``: ``xi = +-c``, ``c = f N /
# k_t`` exactly (the force is ``-+f N``), until ``+-s`` falls below ``c'`` (the stick motion would
# take ``xi`` inside the cap). Both switches are events. ``N`` is the friction load of
# ``contact_forces`` (without ``F_U``). The friction loss is booked from the work of the spring's
# forces: ``loss_friction = -int (F_t s + F_U ndot) dt - U_end``.

_STICK = 0


class _MindlinModel:
    """State ``[n, ndot, tdot, w, xi, work_t, loss_HD, loss_AD, loss_R]`` (SI)."""

    def __init__(self, p: Params):
        self.p = p
        self.m = p.mass
        self.r = p.radius
        self.k2 = p.k2 if p.rotation else 0.0
        self.f = p.friction
        self.rigid = _Model(p)  # for the kink functions of the normal force

    def stiffness(self, n):
        return 8.0 * self.p.G_star * math.sqrt(self.r * n) if n > 0 else 0.0

    def stiffness_slope(self, n):
        return 4.0 * self.p.G_star * math.sqrt(self.r / n) if n > 0 else 0.0

    def slip(self, y):
        return y[2] - self.r * y[3] if self.p.rotation else y[2]

    def cap(self, y):
        k = self.stiffness(y[0])
        if k <= 0:
            return 0.0
        return self.f * contact_forces(self.p, y[0], y[1], y[3])["N"] / k

    def xi(self, y, mode):
        return y[4] if mode == _STICK else mode * self.cap(y)

    def rhs(self, y, mode):
        n, ndot, w = y[0], y[1], y[3]
        fc = contact_forces(self.p, n, ndot, w)
        xi = self.xi(y, mode)
        F_t = -self.stiffness(n) * xi
        F_U = -0.5 * self.stiffness_slope(n) * xi * xi
        s = self.slip(y)
        wdot = (-self.r * F_t + fc["M"]) / (self.m * self.k2) if self.p.rotation else 0.0
        return [
            ndot,
            (fc["F_n"] + F_U) / self.m,
            F_t / self.m,
            wdot,
            s if mode == _STICK else 0.0,
            F_t * s + F_U * ndot,
            -fc["F_HD"] * ndot,
            -fc["F_AD"] * ndot,
            -fc["M"] * w,
        ]

    def cap_rate(self, y, mode):
        """``dc/dt`` along the motion: closed form without adhesion, else a central difference
        along the flow (relative error ~1e-9; it only places the slip-to-stick event)."""
        p, n, ndot = self.p, y[0], y[1]
        if n <= 0 or self.f == 0:
            return 0.0
        nddot = self.rhs(y, mode)[1]
        if not p.adhesion:
            kr = p.K * math.sqrt(self.r)
            if p.friction_load == "hertz":
                load, load_rate = kr * n**1.5, 1.5 * kr * math.sqrt(n) * ndot
            else:
                g = 1.0 + p.C_H * ndot
                sign = 1.0 if g >= 0 else -1.0
                load = sign * kr * n**1.5 * g
                load_rate = sign * kr * (1.5 * math.sqrt(n) * ndot * g + n**1.5 * p.C_H * nddot)
            k = self.stiffness(n)
            return self.f * (load_rate - load * self.stiffness_slope(n) * ndot / k) / k
        h = 1e-7 * n / max(abs(ndot), 1e-300)
        d = np.array(self.rhs(y, mode))
        up, down = np.array(y, float) + h * d, np.array(y, float) - h * d
        return (self.cap(up) - self.cap(down)) / (2.0 * h)

    def spring_energy(self, y, mode):
        return 0.5 * self.stiffness(y[0]) * self.xi(y, mode) ** 2

    def normal_energy(self, y):
        return 0.5 * self.m * y[1] ** 2 + normal_potential(self.p, y[0])

    def mechanical_energy(self, y, mode):
        kinetic = 0.5 * self.m * (y[2] ** 2 + self.k2 * y[3] ** 2)
        return self.normal_energy(y) + kinetic + self.spring_energy(y, mode)

    def mode_functions(self, mode):
        """(function, next mode) pairs whose downward zero ends the mode."""
        if self.f == 0:
            return []
        if mode == _STICK:

            def limit(y):
                return self.f * contact_forces(self.p, y[0], y[1], y[3])["N"]

            return [
                (lambda y: limit(y) - self.stiffness(y[0]) * y[4], 1),
                (lambda y: limit(y) + self.stiffness(y[0]) * y[4], -1),
            ]
        return [(lambda y: mode * self.slip(y) - self.cap_rate(y, mode), _STICK)]


def _simulate_mindlin(
    p, speed, angle_deg, omega0, *, rtol, atol, method, t_max, detect_capture, max_segments
):
    model = _MindlinModel(p)
    m, r = model.m, model.r
    th = math.radians(angle_deg)
    v_n, v_t = speed * math.cos(th), speed * math.sin(th)
    w0 = float(omega0) if p.rotation else 0.0
    n_star, _ = hertz_scales(p, v_n)
    L = max(n_star, 2.0 * math.pi * p.f0 / p.K if p.adhesion else 0.0)
    T = math.sqrt(m / (p.K * math.sqrt(r) * math.sqrt(L)))
    V = L / T
    Vt = max(V, abs(v_t), r * abs(w0))
    E0 = m * max(V, speed, Vt) ** 2
    S = np.array([L, V, Vt, Vt / r, L, E0, E0, E0, E0])
    if t_max is None:
        t_max = 1000.0 * T
    n_eps = _N_EPS * L
    t = n_eps / v_n
    y = np.array([n_eps, v_n, v_t, w0, 0.0, 0.0, 0.0, 0.0, 0.0])
    energy_in = 0.5 * m * speed**2 + 0.5 * m * model.k2 * w0**2
    mode = _STICK
    roll_time = 0.0 if model.slip(y) == 0 else math.nan

    base = [(lambda y: y[0] - n_eps, True, -1, "rebound")]
    if detect_capture and p.adhesion:
        base.append((model.normal_energy, True, -1, "captured"))
    base.append((lambda y: y[1], False, -1, "turn"))
    base.append((model.slip, False, 0, "zero_slip"))
    kinks = model.rigid.kink_functions()
    h_look = _LOOKAHEAD * T
    status, message, max_overlap, stalls, n_seg = "failed", "", n_eps, 0, 0
    while True:
        if n_seg >= max_segments:
            message = "too many segments"
            break
        n_seg += 1
        y_look = y + h_look * np.array(model.rhs(y, mode))

        def side(g, y=y, y_look=y_look):
            g1 = g(y_look)
            return 1.0 if (g1 if g1 != 0 else g(y)) >= 0 else -1.0

        specs = list(base)
        for g, nxt in model.mode_functions(mode):
            specs.append((g, True, -1, ("mode", nxt)))
        for g in kinks:
            specs.append((g, True, -side(g), "kink"))
        events = [_make_event(g, S, term, d) for g, term, d, _ in specs]

        def fun(tau, z, seg_mode=mode):
            return np.array(model.rhs(z * S, seg_mode)) * T / S

        sol = solve_ivp(
            fun, (t / T, t_max / T), y / S, method=method, rtol=rtol, atol=atol, events=events
        )
        ys = sol.y * S[:, None]
        max_overlap = max(max_overlap, float(np.max(ys[0])))
        for (_, _, _, kind), te, ye in zip(specs, sol.t_events, sol.y_events, strict=True):
            if kind == "turn" and len(ye):
                max_overlap = max(max_overlap, float(np.max(ye[:, 0])) * L)
            if kind == "zero_slip" and len(te) and math.isnan(roll_time):
                roll_time = float(te[0]) * T
        t_new, y_new = float(sol.t[-1]) * T, ys[:, -1].copy()
        stalls, message = _segment_end(sol, y_new, t_new - t, T, stalls)
        y, t = y_new, t_new
        if message:
            break
        fired = _fired_events(specs, sol)
        if "rebound" in fired:
            status = "rebound"
            break
        if "captured" in fired:
            status = "captured"
            break
        switches = [k[1] for k in fired if isinstance(k, tuple)]
        if switches:
            y[4] = model.xi(y, mode)  # slip -> stick: xi stays where the cap left it
            mode = switches[0]
            if mode != _STICK:
                y[4] = model.xi(y, mode)

    y[4] = model.xi(y, mode)
    contact_time = t
    if status == "rebound" and y[1] < 0:
        contact_time += y[0] / -y[1]
    spring = model.spring_energy(y, _STICK)
    return ImpactResult(
        status=status,
        vn_out=float(-y[1]),
        vt_out=float(y[2]),
        omega_out=float(y[3]),
        contact_time=float(contact_time),
        roll_time=float(roll_time),
        max_overlap=float(max_overlap),
        energy_in=float(energy_in),
        energy_out=float(model.mechanical_energy(y, _STICK)),
        loss_hertz_damping=float(y[6]),
        loss_adhesion_damping=float(y[7]),
        loss_friction=float(-y[5] - spring),
        loss_rolling=float(y[8]),
        n_out=float(y[0]) if status != "rebound" else 0.0,
        n_segments=n_seg,
        message=message,
    )

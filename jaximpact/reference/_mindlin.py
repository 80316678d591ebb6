"""The Mindlin tangential model: an elastic tangential spring that sticks and slips, and its
segment loop."""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from . import jkr
from ._forces import contact_forces, hertz_scales, normal_potential
from ._params import ImpactResult, Params
from ._rigid import _Model
from ._segments import _LOOKAHEAD, _N_EPS, _fired_events, _make_event, _segment_end

_STICK = 0


class _MindlinModel:
    """State ``[n, ndot, tdot, w, xi, work_t, loss_HD, loss_AD, loss_R]`` (SI); ``tdot`` is the
    relative tangential velocity. With a second sphere (``p.target``, with rotation) its spin
    follows from the pair's angular momentum, as in the rigid model (no extra state)."""

    def __init__(self, p: Params, vt0: float = 0.0, w0: float = 0.0):
        self.p = p
        self.m = p.reduced_mass  # the relative motion's (the sphere's own on the wall)
        self.r = p.radius  # the sphere's moment arm
        self.rc = p.reduced_radius  # the contact's radius (the sphere's on the wall)
        self.k2 = p.k2 if p.rotation else 0.0
        self.I1 = p.mass * self.k2
        self.f = p.friction
        # the kink functions of the normal force, and a second sphere's spin and inertia
        self.rigid = _Model(p, vt0, w0)
        self.pair = self.rigid.pair

    def contact_radius(self, n):
        """Hertz's ``sqrt(r n)``, or JKR's stable branch down to the snap-off (0 outside)."""
        p = self.p
        if p.jkr:
            if not n > p.separation_overlap:
                return 0.0
            return jkr.contact_radius(n, self.rc, 0.75 * p.K, p.w)
        return math.sqrt(self.rc * n) if n > 0 else 0.0

    def stiffness(self, n):
        if self.p.tangential == "lammps_linear_history":  # constant, in contact
            return self.p.k_t if self.contact_radius(n) > 0 else 0.0
        return 8.0 * self.p.G_star * self.contact_radius(n)

    def stiffness_slope(self, n):
        p = self.p
        if p.tangential == "lammps_linear_history":
            return 0.0
        if p.jkr:  # 1 / (dn/da), dn/da = 2 a / r - sqrt(2 pi w / (E a)) / 2 (> 0 above n_c)
            a = self.contact_radius(n)
            if a <= 0:
                return 0.0
            dn_da = 2.0 * a / self.rc - 0.5 * math.sqrt(2.0 * math.pi * p.w / (0.75 * p.K * a))
            return 8.0 * p.G_star / dn_da if dn_da > 0 else 0.0
        return 4.0 * p.G_star * math.sqrt(self.rc / n) if n > 0 else 0.0

    def spin2(self, y):
        """The second sphere's spin (0 on the wall; the state holds the relative tangential
        velocity itself)."""
        return self.rigid.spin2_from(y[2], y[3]) if self.pair else 0.0

    def ring_spin(self, y):
        """The spin the ring and the rolling moments see: relative to the second sphere."""
        return y[3] - self.spin2(y) if self.pair else y[3]

    def slip(self, y):
        if not self.p.rotation:
            return y[2]
        s = y[2] - self.r * y[3]
        return s - self.rigid.r2 * self.spin2(y) if self.pair else s

    def forces(self, y):
        return contact_forces(self.p, y[0], y[1], self.ring_spin(y))

    def cap(self, y):
        k = self.stiffness(y[0])
        if k <= 0:
            return 0.0
        return self.f * self.forces(y)["N"] / k

    def xi(self, y, mode):
        return y[4] if mode == _STICK else mode * self.cap(y)

    def rhs(self, y, mode):
        n, ndot = y[0], y[1]
        fc = self.forces(y)
        xi = self.xi(y, mode)
        F_t = -self.stiffness(n) * xi
        # jaximpact's spring pushes the sphere out (-dU/dn); LAMMPS's has no normal force
        lammps = self.p.tangential.startswith("lammps_")
        F_U = 0.0 if lammps else -0.5 * self.stiffness_slope(n) * xi * xi
        s = self.slip(y)
        wdot = (-self.r * F_t + fc["M"]) / self.I1 if self.p.rotation else 0.0
        return [
            ndot,
            (fc["F_n"] + F_U) / self.m,
            F_t / self.m,
            wdot,
            s if mode == _STICK else 0.0,
            F_t * s + F_U * ndot,
            -fc["F_HD"] * ndot,
            -fc["F_AD"] * ndot,
            -fc["M"] * self.ring_spin(y),
        ]

    def cap_rate(self, y, mode):
        """``dc/dt`` along the motion: closed form without adhesion, else a central difference
        along the flow (relative error ~1e-9; it only places the slip-to-stick event)."""
        p, n, ndot = self.p, y[0], y[1]
        n_end = p.separation_overlap  # 0, or JKR's snap-off overlap
        if n <= n_end or self.f == 0:
            return 0.0
        nddot = self.rhs(y, mode)[1]
        if not p.adhesion and p.damping == "hertzian" and p.tangential == "mindlin":
            kr = p.K * math.sqrt(self.rc)
            if p.friction_load == "hertz":
                load, load_rate = kr * n**1.5, 1.5 * kr * math.sqrt(n) * ndot
            else:
                g = 1.0 + p.C_H * ndot
                sign = 1.0 if g >= 0 else -1.0
                load = sign * kr * n**1.5 * g
                load_rate = sign * kr * (1.5 * math.sqrt(n) * ndot * g + n**1.5 * p.C_H * nddot)
            k = self.stiffness(n)
            return self.f * (load_rate - load * self.stiffness_slope(n) * ndot / k) / k
        h = 1e-7 * (n - n_end) / max(abs(ndot), 1e-300)
        d = np.array(self.rhs(y, mode))
        up, down = np.array(y, float) + h * d, np.array(y, float) - h * d
        return (self.cap(up) - self.cap(down)) / (2.0 * h)

    def spring_energy(self, y, mode):
        return 0.5 * self.stiffness(y[0]) * self.xi(y, mode) ** 2

    def normal_energy(self, y):
        return 0.5 * self.m * y[1] ** 2 + normal_potential(self.p, y[0])

    def capture_energy(self, y):
        """The normal energy left to climb to the separation (JKR: the snap-off's barrier)."""
        return self.normal_energy(y) - self.p.jkr_barrier

    def kinetic_energy(self, y):
        """Of the tangential motion and the spins."""
        kinetic = 0.5 * (self.m * y[2] ** 2 + self.I1 * y[3] ** 2)
        return kinetic + (0.5 * self.rigid.I2 * self.spin2(y) ** 2 if self.pair else 0.0)

    def mechanical_energy(self, y, mode):
        return self.normal_energy(y) + self.kinetic_energy(y) + self.spring_energy(y, mode)

    def kink_functions(self):
        return self.rigid.kink_functions(spin=self.ring_spin, normal_force=self.normal_force)

    def normal_force(self, y):
        return self.forces(y)["F_n"]

    def mode_functions(self, mode):
        """(function, next mode) pairs whose downward zero ends the mode."""
        if self.f == 0:
            return []
        if mode == _STICK:

            def limit(y):
                return self.f * self.forces(y)["N"]

            return [
                (lambda y: limit(y) - self.stiffness(y[0]) * y[4], 1),
                (lambda y: limit(y) + self.stiffness(y[0]) * y[4], -1),
            ]
        return [(lambda y: mode * self.slip(y) - self.cap_rate(y, mode), _STICK)]


def _simulate_mindlin(
    p, speed, angle_deg, omega0, *, rtol, atol, method, t_max, detect_capture, max_segments
):
    th = math.radians(angle_deg)
    v_n, v_t = speed * math.cos(th), speed * math.sin(th)
    w0 = float(omega0) if p.rotation else 0.0
    model = _MindlinModel(p, v_t, w0)
    m, r = model.m, model.r
    n_star, _ = hertz_scales(p, v_n)
    L = max(n_star, p.adhesive_overlap)
    T = math.sqrt(m / (p.K * math.sqrt(model.rc) * math.sqrt(L)))
    V = L / T
    Vt = max(V, abs(v_t), r * abs(w0))
    E0 = m * max(V, speed, Vt) ** 2
    S = np.array([L, V, Vt, Vt / r, L, E0, E0, E0, E0])
    if t_max is None:
        t_max = 1000.0 * T
    n_eps = _N_EPS * L
    # JKR: the contact starts at first touch with a finite radius (the spring unloaded) and
    # ends n_eps above the snap-off overlap n_c < 0
    n_c = p.separation_overlap
    n0 = 0.0 if p.jkr else n_eps
    t = n0 / v_n
    y = np.array([n0, v_n, v_t, w0, 0.0, 0.0, 0.0, 0.0, 0.0])
    energy_in = 0.5 * m * v_n**2 + model.kinetic_energy(y)
    roll_time = 0.0 if model.slip(y) == 0 else math.nan

    run = _MindlinRun(model, S, L, T, rtol, atol, method, detect_capture and p.adhesion, n_eps, n_c)
    mode = _STICK
    if detect_capture and p.jkr and model.capture_energy(y) < 0:
        run.status, run.roll_time = "captured", roll_time  # below JKR's sticking speed
    else:
        y, t, mode = run.integrate(y, t, t_max, roll_time, max_segments)

    y[4] = model.xi(y, mode)
    contact_time = t
    if run.status == "rebound" and y[1] < 0:
        contact_time += (y[0] - n_c) / -y[1]
    spring = model.spring_energy(y, _STICK)
    energy_out = model.mechanical_energy(y, _STICK)
    if run.status == "rebound" and p.jkr:
        # The snap-off: the barrier's energy is lost (as in the rigid model), and so is the
        # spring's, since JKR's contact radius does not vanish there (docs/physics.md).
        energy_out -= p.jkr_barrier + spring
        y[7] += p.jkr_barrier
        spring = 0.0
    return ImpactResult(
        status=run.status,
        vn_out=float(-y[1]),
        vt_out=float(y[2]),
        omega_out=float(y[3]),
        contact_time=float(contact_time),
        roll_time=float(run.roll_time),
        max_overlap=float(run.max_overlap),
        energy_in=float(energy_in),
        energy_out=float(energy_out),
        loss_hertz_damping=float(y[6]),
        loss_adhesion_damping=float(y[7]),
        loss_friction=float(-y[5] - spring),
        loss_rolling=float(y[8]),
        n_out=float(y[0]) if run.status != "rebound" else 0.0,
        omega2_out=float(model.spin2(y)) if model.pair else math.nan,
        n_segments=run.n_seg,
        message=run.message,
    )


class _MindlinRun:
    """The segment loop of the Mindlin model: stick and slip phases of the tangential spring,
    until a rebound, a capture or a failure."""

    def __init__(self, model, S, L, T, rtol, atol, method, detect_capture, n_eps, n_c=0.0):
        self.model, self.S, self.L, self.T = model, S, L, T
        self.rtol, self.atol, self.method = rtol, atol, method
        self.base = [(lambda y: y[0] - n_c - n_eps, True, -1, "rebound")]
        if detect_capture:
            self.base.append((model.capture_energy, True, -1, "captured"))
        self.base.append((lambda y: y[1], False, -1, "turn"))
        self.base.append((model.slip, False, 0, "zero_slip"))
        self.kinks = model.kink_functions()
        self.h_look = _LOOKAHEAD * T
        self.status, self.message, self.max_overlap, self.n_seg = "failed", "", n_eps, 0

    def integrate(self, y, t, t_max, roll_time, max_segments):
        """Segments from ``(t, y)``, sticking first, until the impact ends; its final state,
        time and mode."""
        model = self.model
        self.roll_time = roll_time
        mode = _STICK
        stalls = 0
        while True:
            if self.n_seg >= max_segments:
                self.message = "too many segments"
                break
            self.n_seg += 1
            specs, sol, t_new, y_new = self.segment(y, t, t_max, mode)
            stalls, self.message = _segment_end(sol, y_new, t_new - t, self.T, stalls)
            y, t = y_new, t_new
            if self.message:
                break
            fired = _fired_events(specs, sol)
            if "rebound" in fired:
                self.status = "rebound"
                break
            if "captured" in fired:
                self.status = "captured"
                break
            switches = [k[1] for k in fired if isinstance(k, tuple)]
            if switches:
                y[4] = model.xi(y, mode)  # slip -> stick: xi stays where the cap left it
                mode = switches[0]
                if mode != _STICK:
                    y[4] = model.xi(y, mode)
        return y, t, mode

    def segment(self, y, t, t_max, mode):
        """One segment in ``mode`` up to its first terminal event: its event specs, the
        solution, and the end time and state."""
        model, S, T = self.model, self.S, self.T
        y_look = y + self.h_look * np.array(model.rhs(y, mode))

        def side(g, y=y, y_look=y_look):
            g1 = g(y_look)
            return 1.0 if (g1 if g1 != 0 else g(y)) >= 0 else -1.0

        specs = list(self.base)
        for g, nxt in model.mode_functions(mode):
            specs.append((g, True, -1, ("mode", nxt)))
        for g in self.kinks:
            specs.append((g, True, -side(g), "kink"))
        events = [_make_event(g, S, term, d) for g, term, d, _ in specs]

        def fun(tau, z, seg_mode=mode):
            return np.array(model.rhs(z * S, seg_mode)) * T / S

        sol = solve_ivp(
            fun, (t / T, t_max / T), y / S, method=self.method, rtol=self.rtol, atol=self.atol,
            events=events,
        )  # fmt: skip
        ys = sol.y * S[:, None]
        self.max_overlap = max(self.max_overlap, float(np.max(ys[0])))
        for (_, _, _, kind), te, ye in zip(specs, sol.t_events, sol.y_events, strict=True):
            if kind == "turn" and len(ye):
                self.max_overlap = max(self.max_overlap, float(np.max(ye[:, 0])) * self.L)
            if kind == "zero_slip" and len(te) and math.isnan(self.roll_time):
                self.roll_time = float(te[0]) * T
        t_new, y_new = float(sol.t[-1]) * T, ys[:, -1].copy()
        return specs, sol, t_new, y_new

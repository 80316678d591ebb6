"""``simulate_impact``: one impact with the exact switched model, and ``impact_history``."""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from ._forces import hertz_scales
from ._mindlin import _simulate_mindlin
from ._params import ImpactResult, Params
from ._rigid import _FREE, _ROLL, _Model
from ._segments import _LOOKAHEAD, _N_EPS, _build_history, _fired_events, _make_event, _segment_end


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
    if p.tangential != "rigid":
        if history:
            raise ValueError(f"history is not available with tangential = {p.tangential!r}")
        return _simulate_mindlin(
            p, speed, angle_deg, omega0, rtol=rtol, atol=atol, method=method, t_max=t_max,
            detect_capture=detect_capture, max_segments=max_segments,
        )  # fmt: skip
    th = math.radians(angle_deg)
    v_n, v_t = speed * math.cos(th), speed * math.sin(th)
    w0 = float(omega0) if p.rotation else 0.0
    model = _Model(p, v_t, w0)
    m, r = model.m, model.r
    S, L, T, atol_vec = _rigid_scales(model, p, speed, v_n, v_t, w0, atol)
    if t_max is None:
        t_max = 1000.0 * T

    n_eps = _N_EPS * L
    # JKR: the force is finite at first touch (the solve starts there) and the contact ends
    # at the snap-off overlap n_c < 0 (the run stops n_eps above it)
    n_c = p.separation_overlap
    n0 = 0.0 if p.jkr else n_eps
    t = n0 / v_n
    s0 = v_t - r * w0 if p.rotation else v_t
    if model.pair:
        s0 -= p.radius2 * p.omega2
    y = np.array([n0, v_n, s0, w0, 0, 0, 0, 0], dtype=float)
    energy_in = 0.5 * m * v_n**2 + model.tangential_energy(y)
    mode, roll_time = _initial_mode(model, y)

    run = _RigidRun(model, S, L, T, rtol, atol_vec, method, history, detect_capture, n_eps, n_c)
    if detect_capture and model.capture_energy(y) < 0:
        run.status, run.roll_time = "captured", roll_time  # below JKR's sticking speed
    else:
        y, t = run.integrate(y, t, t_max, mode, roll_time, max_segments)
    return _rigid_result(p, model, run, y, t, energy_in, S, T, v_n, history, n_samples)


def _rigid_result(p: Params, model, run, y, t, energy_in, S, T, v_n, history, n_samples):
    """The :class:`ImpactResult` of a finished run (state ``y`` at time ``t``): the last
    stretch to the separation level crossed at constant speed, the JKR snap-off's loss, and
    the history where asked for."""
    n_c = p.separation_overlap
    contact_time = t
    if run.status == "rebound" and y[1] < 0:
        contact_time += (y[0] - n_c) / -y[1]  # the last n_eps, crossed at constant speed
    energy_out = model.mechanical_energy(y)
    if run.status == "rebound" and p.jkr:  # the snap-off: the barrier's energy is lost
        energy_out -= p.jkr_barrier
        y[5] += p.jkr_barrier
    hist = None
    if history and run.segments:  # (none for a JKR sphere stuck at first touch)
        hist = _build_history(model, run.segments, S, T, v_n, y, t, contact_time, n_samples)
    return ImpactResult(
        status=run.status,
        vn_out=float(-y[1]),
        vt_out=float(model.tdot(y)),
        omega_out=float(y[3]),
        contact_time=float(contact_time),
        roll_time=float(run.roll_time),
        max_overlap=float(run.max_overlap),
        energy_in=float(energy_in),
        energy_out=float(energy_out),
        loss_hertz_damping=float(y[4]),
        loss_adhesion_damping=float(y[5]),
        loss_friction=float(y[6]),
        loss_rolling=float(y[7]),
        n_out=float(y[0]) if run.status != "rebound" else 0.0,
        omega2_out=float(model.spin2(y)) if model.pair else math.nan,
        n_segments=run.n_seg,
        message=run.message,
        history=hist,
    )


def _rigid_scales(model, p: Params, speed, v_n, v_t, w0, atol):
    """The state's scales ``S``, the overlap and time scales ``L`` and ``T``, and the absolute
    tolerances."""
    m, r = model.m, model.r
    # Scales: overlap L (Hertz peak, or the adhesive equilibrium overlap if larger), time T
    # (stiffness at overlap L), velocities V = L/T.
    n_star, _ = hertz_scales(p, v_n)
    L = max(n_star, p.adhesive_overlap)
    T = math.sqrt(m / (p.K * math.sqrt(r) * math.sqrt(L)))
    V = L / T
    Vt = max(V, abs(v_t), r * abs(w0))
    E0 = m * max(V, speed, Vt) ** 2
    S = np.array([L, V, Vt, Vt / r, E0, E0, E0, E0])
    # The slip's sign decides the friction direction: resolve it far below the other errors.
    atol_vec = np.full(8, atol)
    atol_vec[2] = atol * 1e-6
    return S, L, T, atol_vec


def _initial_mode(model, y) -> tuple[int, float]:
    """The tangential mode at first touch, and the rolling time if it rolls from the start."""
    slip0 = model.slip(y)
    if model.f == 0:
        mode = _FREE
    elif slip0 == 0:
        mode = model.decide(y)
    else:
        mode = 1 if slip0 > 0 else -1
    roll_time = 0.0 if (mode == _ROLL and slip0 == 0) else math.nan
    return mode, roll_time


class _RigidRun:
    """The segment loop of the rigid-friction model: integrate until an event, switch the
    tangential mode, restart; ends in a rebound, a capture or a failure."""

    def __init__(
        self, model, S, L, T, rtol, atol_vec, method, history, detect_capture, n_eps, n_c=0.0
    ):
        self.model, self.S, self.L, self.T = model, S, L, T
        self.rtol, self.atol_vec, self.method, self.history = rtol, atol_vec, method, history
        self.base_events = [(lambda y: y[0] - n_c - n_eps, True, -1, "rebound")]
        if detect_capture:
            self.base_events.append((model.capture_energy, True, -1, "captured"))
        self.base_events.append((lambda y: y[1], False, -1, "turn"))  # max overlap at ndot = 0
        self.kinks = model.kink_functions()
        self.h_look = _LOOKAHEAD * T
        self.status, self.message = "failed", ""
        self.max_overlap = n_eps
        self.segments = []  # (t0, t1, OdeSolution or None, mode, ts, ys) for the history
        self.n_seg = 0

    def integrate(self, y, t, t_max, mode, roll_time, max_segments):
        """Segments from ``(t, y)`` in ``mode`` until the impact ends; its final state."""
        model, h_look = self.model, self.h_look
        self.roll_time = roll_time
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
            mode_events = [k for k in fired if isinstance(k, tuple)]
            if mode in (1, -1) and mode * y[2] <= 0 and not mode_events:
                # the slip reached zero together with a kink: same as the slip event
                mode_events = [("mode", None)]
            if mode_events:
                y = model.project_to_rolling(y)
                nxt = mode_events[0][1]
                if nxt is None:  # the slip reached zero
                    if math.isnan(self.roll_time):
                        self.roll_time = t
                    mode = model.decide(y, h_look)
                else:  # rolling can no longer be held: slide against the imbalance
                    mode = nxt
            elif mode == _ROLL:
                # A restart at a kink (F_n = 0 above all, where the load vanishes): check again
                # that friction can still hold the rolling.
                y = model.project_to_rolling(y)
                mode = model.decide(y, h_look)
        return y, t

    def segment(self, y, t, t_max, mode):
        """One segment in ``mode`` up to its first terminal event: its event specs, the
        solution, and the end time and state."""
        model, S, T = self.model, self.S, self.T
        # A kink event must fire only when leaving the side the state is on (or moving into,
        # when it sits on the kink after a restart), else it would fire at once again.
        y_look = y + self.h_look * np.array(model.rhs(y, mode))

        def side(g, y=y, y_look=y_look):
            g1 = g(y_look)
            return 1.0 if (g1 if g1 != 0 else g(y)) >= 0 else -1.0

        specs = list(self.base_events)
        for g, nxt in model.mode_functions(mode, side(model.normal_force)):
            specs.append((g, True, -1, ("mode", nxt)))
        for g in self.kinks:
            specs.append((g, True, -side(g), "kink"))
        events = [_make_event(g, S, term, d) for g, term, d, _ in specs]

        seg_mode = mode

        def fun(tau, z, seg_mode=seg_mode):
            return np.array(model.rhs(z * S, seg_mode)) * T / S

        sol = solve_ivp(
            fun,
            (t / T, t_max / T),
            y / S,
            method=self.method,
            rtol=self.rtol,
            atol=self.atol_vec,
            events=events,
            dense_output=self.history,
        )
        ys = sol.y * S[:, None]
        self.max_overlap = max(self.max_overlap, float(np.max(ys[0])))
        for (_, _, _, kind), ye in zip(specs, sol.y_events, strict=True):
            if kind == "turn" and len(ye):
                self.max_overlap = max(self.max_overlap, float(np.max(ye[:, 0])) * self.L)
        t_new = float(sol.t[-1]) * T
        y_new = ys[:, -1].copy()
        if self.history:
            self.segments.append((t, t_new, sol.sol, mode, sol.t * T, ys))
        return specs, sol, t_new, y_new


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

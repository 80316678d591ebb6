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

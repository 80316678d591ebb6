"""The peer a user would otherwise write: the same smooth model in numpy, ``solve_ivp`` in a loop.

The right-hand side is a plain-Python transcription of ``jaximpact/_model/laws.py`` and
``_dynamics.py`` (Hertz units, the same regularized friction and adhesion ring), integrated with
``scipy.integrate.solve_ivp`` (RK45 or LSODA) and terminal events for separation and capture.
Only the four motion states are integrated (no energy ledger), which favours the peer.
"""

import math

import numpy as np
from scipy.integrate import solve_ivp


def _ring(ndot, b, width):
    """Regularized ring integrals (I0, I1), as ``_laws.ring_integrals``."""
    b_eff = math.sqrt(b * b + width * width)
    if b_eff > 0:
        u0 = ndot + width * width / b_eff
        c = min(max(-u0 / b_eff, -1.0), 1.0)
    else:
        u0 = ndot
        c = 1.0 if u0 < 0 else -1.0
    s = math.sqrt(max(1.0 - c * c, 0.0))
    beta = math.atan2(s, c)
    return -2.0 * u0 * (math.pi - beta) + 2.0 * b_eff * s, -b * (c * s + math.pi - beta)


def make_rhs(p, slip_width, ring_width, adhesion, moments):
    """dy/dt of y = (n, ndot, vt, w) in Hertz units; ``p`` a dict of scaled parameters."""
    r, K, f0, C_A, C_H, mu, inertia = (
        p[k] for k in ("radius", "K", "f0", "C_A", "C_H", "friction", "inertia")
    )
    sqrt_r = math.sqrt(r)

    def rhs(t, y):
        n, ndot, vt, w = y
        if n > 0:
            sn = math.sqrt(n)
            hertz = K * sqrt_r * n * sn
            F_n = -hertz * (1.0 + C_H * ndot)
            M = 0.0
            if moments:
                M = -(K / 5.0) * C_H * r**1.5 * n * n * sn * w
            if adhesion:
                a = math.sqrt(r * n)
                i0, i1 = _ring(ndot, w * a if moments else 0.0, ring_width)
                F_n += 2.0 * math.pi * a * f0 + f0 * C_A * a * i0
                if moments:
                    M += f0 * C_A * a * a * i1
        else:
            F_n, M = 0.0, 0.0
        limit = mu * abs(F_n)
        z = (vt - r * w) / slip_width
        step = math.tanh(z * z)
        hold = min(max(r * M / (inertia + r * r), -limit), limit)
        F_t = (1.0 - step) * hold - limit * math.copysign(step, z)
        return [ndot, F_n, F_t, (-r * F_t + M) / inertia]

    return rhs


def simulate_loop(
    params,
    speed,
    angle,
    omega0,
    *,
    method="RK45",
    rtol=1e-8,
    atol=1e-10,
    slip_width=1e-3,
    ring_width=1e-6,
):
    """Simulate each impact with ``solve_ivp``; ``params`` a ``reference.Params`` (analytical
    moments or none). Returns a dict like ``benchmarks._common.as_dict``."""
    out = {k: [] for k in ("status", "cor_n", "vt_out", "omega_out", "contact_time")}
    m = params.mass
    moments = params.rolling_moments == "analytical"
    for v, ang, w0 in zip(speed, angle, omega0, strict=True):
        th = math.radians(ang)
        v_n, v_t = v * math.cos(th), v * math.sin(th)
        L = (5.0 * m * v_n**2 / (4.0 * params.K * math.sqrt(params.radius))) ** 0.4
        T = L / v_n
        rs = params.radius / L
        p = dict(
            radius=rs,
            K=params.K * L * T**2 / m,
            f0=params.f0 * T**2 / m if params.adhesion else 0.0,
            C_A=params.C_A * L / T,
            C_H=params.C_H * L / T,
            friction=params.friction,
            inertia=params.kappa * rs * rs,
        )
        rhs = make_rhs(p, slip_width, ring_width, params.adhesion and p["f0"] > 0, moments)

        def separation(t, y):
            return y[0]

        separation.terminal, separation.direction = True, -1.0

        def capture(t, y, p=p):
            n = max(y[0], 0.0)
            e = 0.5 * y[1] ** 2 + 0.4 * p["K"] * math.sqrt(p["radius"]) * n**2.5
            return e - (4.0 / 3.0) * math.pi * p["f0"] * math.sqrt(p["radius"]) * n**1.5

        capture.terminal, capture.direction = True, -1.0
        y0 = [0.0, 1.0, v_t / v_n, w0 * T]
        sol = solve_ivp(
            rhs, (0.0, 1e5), y0, method=method, rtol=rtol, atol=atol, events=[separation, capture]
        )
        y = sol.y[:, -1]
        if sol.status == 1 and len(sol.t_events[0]):
            status, y, t_end = "rebound", sol.y_events[0][0], sol.t_events[0][0]
        elif sol.status == 1:
            status, y, t_end = "captured", sol.y_events[1][0], sol.t_events[1][0]
        else:
            status, t_end = "failed", sol.t[-1]
        out["status"].append(status)
        out["cor_n"].append(-y[1] if status == "rebound" else 0.0)
        out["vt_out"].append(y[2] * v_n)
        out["omega_out"].append(y[3] / T)
        out["contact_time"].append(t_end * T)
    return {k: np.array(v) for k, v in out.items()}

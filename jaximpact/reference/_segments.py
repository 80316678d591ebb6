"""Event-driven integration in segments: scipy events, the end of a segment, and the time
history assembled from the segments."""

from __future__ import annotations

import numpy as np

from ._rigid import _Model

_N_EPS = (
    1e-12  # contact starts and ends at n = _N_EPS * L (sqrt(n) singularity, see docs/reference.md)
)


_LOOKAHEAD = 1e-9  # in time scales T: how far ahead to look to tell the side of a kink at a restart


_MAX_STALLS = 50  # consecutive zero-length segments before giving up


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


def _history_row(model: _Model, y, mode: int) -> list:
    fc = model.forces(y)
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

"""New nodes of a wall-law table: radius nodes until the interpolated capture speed meets its
tolerance (both layouts), and, in the tensor-product layout, new radius, angle and speed
nodes where linear interpolation of the results would miss by more than the tolerance
(estimated from second differences); a new node's cell is simulated only where its own rows
need it, elsewhere filled with the interpolation of its interval's ends (module docstring of
:mod:`._table`, "Refinement")."""

from __future__ import annotations

import math

import numpy as np

from ._capture import CaptureStatus
from ._law import NOT_SIMULATED, OUTPUTS, _u, capture_coordinate
from ._rows import _top

#: Radius nodes: at most this many bisections of the given intervals, and none narrower than
#: RADIUS_MIN_STEP in log r (0.1 % of the radius).
RADIUS_LEVELS = 12
RADIUS_MIN_STEP = 1e-3
#: A new node's cell is filled by interpolation (not simulated) only where its rows' estimated
#: miss is below this share of the tolerance: the second-difference estimate was seen 1.5x
#: below the true miss of a filled cell (spin, 1.53e-3 at a tolerance of 1e-3).
FILL_SHARE = 0.5


def _refined(ctx, rows, angle, tol, say):
    """Split the angle intervals where linear interpolation would miss by more than ``tol``
    (kinks: the onset of rolling), in batches of pass 1's lane count (one compiled program);
    the rows and angles merged and sorted by angle. The new angles are simulated only at the
    radii whose own rows need them (:func:`_new_nodes`)."""
    miss = _refinement(rows, angle)  # (R, A - 1)
    extra, owner = _split(angle, miss.max(axis=0), tol, most=8)
    if not extra.size:
        return rows, angle
    R = miss.shape[0]
    need = miss[:, owner] > FILL_SHARE * tol  # (R, E)
    say(f"refining: {extra.size} more angles where the table bends sharply")
    t = (extra - angle[owner]) / (angle[owner + 1] - angle[owner])
    more = _new_nodes(
        ctx, rows, 1, owner, t, need, ctx.radius, angle, extra, "pass 2 (refined angles)"
    )
    rows = {k: np.concatenate([_grid(rows[k], R, ctx), more[k]], axis=1) for k in rows}
    angle = np.concatenate([angle, extra])
    order = np.argsort(angle)
    return {k: _flat_rows(v[:, order]) for k, v in rows.items()}, angle[order]


def _refined_speeds(ctx, rows, radius, angle, tol, say):
    """Split the speed intervals (in ``u``) where linear interpolation of a row would miss by
    more than ``tol`` (the onset of rolling crosses the speed axis at a ratio that changes
    with the angle; ``cor_n`` bends near the capture speed), as :func:`_refined` does for
    angles. A row takes a new node's impact where its own miss in that interval is above
    :data:`FILL_SHARE` of the tolerance or where it is not a plain rebounding row (a top, a
    second capture); elsewhere the node holds the interpolation of its interval's ends. The
    rows' tops and the node at the capture speed are then worked out again."""
    x = ctx.x
    u = _u(x, ctx.adhesive)
    R = radius.size
    n, X = rows["cor_n"].reshape(-1, x.size).shape
    top = rows["top"].reshape(n)
    held = x[None, :] > top[:, None]  # above the row's top: its last values repeated
    miss = np.zeros((X - 1, n))
    for f in _results(rows, angle, held.reshape(rows["cor_n"].shape)):
        miss = np.maximum(miss, _interval_miss(f.reshape(n, X), u, axis=1, by=0))
    extra_u, owner = _split(u, miss.max(axis=1), tol, most=8)
    if not extra_u.size:
        return rows
    if ctx.adhesive:
        extra = 1.0 + np.sinh(extra_u) ** 2
    else:
        extra = extra_u**5
    say(f"refining: {extra.size} more speed nodes where the rows bend sharply")
    flat = {k: v.reshape((n,) + v.shape[2:]) for k, v in rows.items()}
    stick = ~np.isfinite(flat["v_ref"])
    plain = (
        ~stick
        & (flat["again"] == 0)
        & (top >= x[-1])
        & (flat["status"][:, 1 if ctx.adhesive else 0 :] == 0).all(axis=1)
    )
    need = (miss[owner].T > FILL_SHARE * tol) | ~plain[:, None]  # (n, E)
    need &= ~stick[:, None]
    t = (extra_u - u[owner]) / (u[owner + 1] - u[owner])
    new = {k: (1.0 - t) * flat[k][:, owner] + t * flat[k][:, owner + 1] for k in OUTPUTS}
    new["status"] = np.where(stick[:, None], NOT_SIMULATED, flat["status"][:, owner])
    new["speed"] = flat["v_ref"][:, None] * extra[None, :]
    cells = np.argwhere(need)
    ctx.new_cells["pass 3"] = (int(cells.shape[0]), int(need.size))
    say(
        f"pass 3 (refined speeds): simulating {cells.shape[0]} of {need.size} new (row, "
        f"speed) cells (the others: their rows' interpolation is within the tolerance)"
    )
    if cells.size:
        r, a, w = ctx._flat(radius, angle)
        i, k = cells[:, 0], cells[:, 1]
        got = ctx.impacts_at(r[i], a[i], w[i], new["speed"][i, k], "pass 3 (refined speeds)")
        for name, v in got.items():
            new[name][i, k] = v
    merged = {k: np.concatenate([flat[k], new[k]], axis=1) for k in (*OUTPUTS, "status", "speed")}
    x = np.concatenate([x, extra])
    order = np.argsort(x)
    x = x[order]
    merged = {k: v[:, order] for k, v in merged.items()}
    top, again = _top(ctx, merged, x, stick)
    out = {**flat, **merged, "top": top, "again": again}
    ctx.x = x
    return {k: v.reshape((R, -1) + v.shape[1:]) for k, v in out.items()}


def _grid(values, R, ctx):
    """Rows ``(R, A*W[, X])`` as ``(R, A, W[, X])``."""
    W = ctx.omega.size
    return values.reshape((R, -1, W) + values.shape[2:])


def _flat_rows(values):
    """Rows ``(R, A, W[, X])`` as ``(R, A*W[, X])``."""
    return values.reshape((values.shape[0], -1) + values.shape[3:])


def _clean(rows, R, ctx) -> np.ndarray:
    """``(R, A)``: (radius, angle) cells whose rows (every spin) rebound at every simulated
    speed up to the last node with one capture status: the cells between two such cells can
    take their linear interpolation (:func:`_new_nodes`)."""
    ok = np.isfinite(rows["v_ref"]) & (rows["again"] == 0)
    ok &= rows["top"] >= ctx.x[-1]
    ok &= (rows["status"] == 0).all(axis=-1)
    status = rows["c_status"]
    ok &= np.isin(status, (CaptureStatus.THRESHOLD, CaptureStatus.NO_ADHESION))
    return _grid(ok, R, ctx).all(axis=2)


def _new_nodes(ctx, rows, axis, owner, t, need, radius, angle, extra, stage) -> dict:
    """Rows at new nodes along ``axis`` (0: radius, at ``log r``; 1: angle) that split the
    intervals ``owner`` at fractions ``t``: ``(E, A, W[, X])`` or ``(R, E, W[, X])``.

    A (node, other axis) cell is simulated where ``need`` says its own rows bend (their
    estimated miss above :data:`FILL_SHARE` of the tolerance) or where either end of its
    interval is not :func:`_clean`; elsewhere it is the linear interpolation of the
    interval's ends: the value the table interpolates there without the node, so filling it
    changes nothing where the rows did not need it, and a tensor-product table still holds
    it (the generated C code reads tensor products). Capture speeds of simulated cells
    between clean ends are searched near the interpolated ones (:meth:`_Context.lanes`'s
    ``guess``).
    """
    R, W = radius.size, ctx.omega.size
    clean = _clean(rows, R, ctx)
    grid = {k: _grid(v, R, ctx) for k, v in rows.items()}
    if axis == 0:
        ends_clean = clean[owner] & clean[owner + 1]  # (E, A)
        lo = {k: v[owner] for k, v in grid.items()}
        hi = {k: v[owner + 1] for k, v in grid.items()}
        cos_lo = cos_hi = cos_new = np.cos(np.radians(angle))[None, :, None]
        tt = t[:, None, None]
    else:
        ends_clean = clean[:, owner] & clean[:, owner + 1]  # (R, E)
        lo = {k: v[:, owner] for k, v in grid.items()}
        hi = {k: v[:, owner + 1] for k, v in grid.items()}
        cos_lo = np.cos(np.radians(angle[owner]))[None, :, None]
        cos_hi = np.cos(np.radians(angle[owner + 1]))[None, :, None]
        cos_new = np.cos(np.radians(extra))[None, :, None]
        tt = t[None, :, None]
    simulated = need | ~ends_clean
    with np.errstate(divide="ignore", invalid="ignore"):
        out = _interpolated(ctx, lo, hi, tt, cos_lo, cos_hi, cos_new)
    # (new node, angle) or (radius, new node); those between clean ends first: their
    # capture speeds are searched near the interpolated ones (one kind of search per batch)
    cells = np.argwhere(simulated)
    guessed = ends_clean[cells[:, 0], cells[:, 1]] & ctx.adhesive
    order = np.argsort(~guessed, kind="stable")
    cells, guessed = cells[order], guessed[order]
    ctx.new_cells[stage.split(" (")[0]] = (int(cells.shape[0]), int(simulated.size))
    ctx.say(
        f"{stage}: simulating {cells.shape[0]} of {simulated.size} new (radius, angle) "
        f"cells (the others: their rows' interpolation is within the tolerance)"
    )
    if cells.size:
        if axis == 0:
            r_cell, a_cell = np.exp(extra)[cells[:, 0]], angle[cells[:, 1]]
        else:
            r_cell, a_cell = radius[cells[:, 0]], extra[cells[:, 1]]
        r = np.repeat(r_cell, W)
        a = np.repeat(a_cell, W)
        w = np.tile(ctx.omega, cells.shape[0])
        guess = out["v_c"][cells[:, 0], cells[:, 1]].reshape(-1)
        guess = np.where(np.repeat(guessed, W), guess, np.nan)
        found = ctx.lanes(r, a, w, stage, guess=guess)
        for k, v in found.items():
            out[k][cells[:, 0], cells[:, 1]] = v.reshape((cells.shape[0], W) + v.shape[1:])
    return out


def _interpolated(ctx, lo, hi, t, cos_lo, cos_hi, cos_new) -> dict:
    """The rows between clean ends ``lo`` and ``hi`` at fraction ``t`` as the table
    interpolates them: the results linearly, the capture speed through ``g = (v_c
    cos)^(-1/4)`` (module docstring)."""
    out = {}
    for name in OUTPUTS:
        t4 = t[..., None]
        out[name] = (1.0 - t4) * lo[name] + t4 * hi[name]
    if ctx.adhesive:
        g = (1.0 - t) * (lo["v_c"] * cos_lo) ** -0.25 + t * (hi["v_c"] * cos_hi) ** -0.25
        v_c = g**-4 / cos_new
        out["v_c"], out["v_ref"] = v_c, v_c.copy()
    else:
        out["v_c"], out["v_ref"] = lo["v_c"].copy(), lo["v_ref"].copy()
    out["speed"] = out["v_ref"][..., None] * ctx.x
    for name in ("c_status", "status", "top", "again"):
        out[name] = lo[name].copy()
    return out


def _radius_nodes(ctx, radius, angle, tol, say):
    """Radius nodes between the given ones (bisection in ``log r``) until the capture speed
    at every interval's midpoint is within ``tol`` of its interpolation (module docstring),
    on the grid's first-pass angles. Intervals narrower than :data:`RADIUS_MIN_STEP` in ``log
    r`` are left as they are and reported. Returns ``(radius nodes, report)``."""
    nodes = list(np.asarray(radius, dtype=float))
    say(f"radius nodes: capture speeds at {len(nodes)} radii")
    v_nodes = ctx.capture_speeds(np.asarray(nodes), angle)  # sets the batch of every pass
    g = {r: capture_coordinate(v, angle) for r, v in zip(nodes, v_nodes, strict=True)}
    pending = list(zip(nodes[:-1], nodes[1:], strict=True))
    unresolved, checked = [], 0
    for level in range(RADIUS_LEVELS):
        if not pending:
            break
        mids = np.sqrt(np.array([lo * hi for lo, hi in pending]))
        say(f"radius nodes, level {level + 1}: checking {mids.size} midpoints")
        v_mid = ctx.capture_speeds(mids, angle, unsure_as_nan=True)
        checked += mids.size
        split = []
        for (lo, hi), m, vm in zip(pending, mids, v_mid, strict=True):
            g_mid = capture_coordinate(vm, angle)
            w = (np.log(m) - np.log(lo)) / (np.log(hi) - np.log(lo))
            miss = _g_miss(g[lo] + w * (g[hi] - g[lo]), g_mid)
            if miss <= tol:
                continue
            if np.log(hi / lo) < 2 * RADIUS_MIN_STEP or np.isnan(vm).any():
                # (a midpoint whose capture speed was not found is not made a node)
                unresolved.append((float(lo), float(hi), float(miss)))
                continue
            g[m] = g_mid
            nodes.append(float(m))
            split += [(lo, m), (m, hi)]
        pending = split
    unresolved += [(float(lo), float(hi), math.nan) for lo, hi in pending]
    nodes = np.array(sorted(nodes))
    if unresolved:
        say(f"radius nodes: {len(unresolved)} intervals left wider than the tolerance needs")
    report = {"checked_midpoints": checked, "unresolved": unresolved, "capture_tol": tol}
    return nodes, report


def _g_miss(g_interp, g_true) -> float:
    """The largest relative error of the capture speed from ``g_interp`` against
    ``g_true`` (``inf`` where one says stick and the other does not)."""
    both_stick = (g_interp <= 0) & (g_true <= 0)
    one_stick = (g_interp <= 0) ^ (g_true <= 0)
    if np.isnan(g_true).any():
        return math.nan
    if one_stick.any():
        return math.inf
    ok = ~both_stick
    if not ok.any():
        return 0.0
    return float(np.max(np.abs((g_true[ok] / g_interp[ok]) ** 4 - 1.0)))


def _refined_radii(ctx, rows, radius, angle, tol, say):
    """Split the radius intervals (``log r``) where linear interpolation of the results would
    miss by more than ``tol`` (second differences, as for the angles; stick rows left out);
    the rows and radii merged and sorted by radius. The new radii are
    simulated only at the angles whose own rows need them (:func:`_new_nodes`)."""
    miss, live = _radius_refinement(rows, radius, angle, 1 if ctx.adhesive else 0)
    lr = np.log(radius)
    extra, owner = _split(lr, miss.max(axis=1), tol, most=4)
    if not extra.size:
        return rows, radius
    # (an interval next to a stick row has no estimate there: simulated)
    need = (miss[owner] > FILL_SHARE * tol) | ~(live[owner] & live[owner + 1])
    say(f"refining: {extra.size} more radii where the results bend sharply")
    t = (extra - lr[owner]) / (lr[owner + 1] - lr[owner])
    more = _new_nodes(ctx, rows, 0, owner, t, need, radius, angle, extra, "pass 1b (refined radii)")
    R = radius.size
    rows = {k: np.concatenate([_grid(rows[k], R, ctx), more[k]], axis=0) for k in rows}
    radius = np.concatenate([radius, np.exp(extra)])
    order = np.argsort(radius)
    return {k: _flat_rows(v[order]) for k, v in rows.items()}, radius[order]


def _radius_refinement(rows: dict, radius, angle, first: int):
    """The miss of linear interpolation in ``log r`` of ``cor_n``, ``cor_t`` or
    ``spin_ratio`` per (radius interval, angle), ``(R - 1, A)`` (see :func:`_refinement`;
    ``first``: the first simulated speed node), and which (radius, angle) cells rebound
    above their capture speed at every spin, ``(R, A)`` (stick rows are left out of the
    estimate)."""
    R, A = radius.size, angle.size
    live = np.isfinite(rows["v_ref"])  # (R, A*W): not a stick row
    X = rows["cor_n"].shape[-1]
    # only simulated rebounds: not the capture node, not the nodes above a row's top, not a
    # stick row
    with np.errstate(invalid="ignore"):  # (stick rows: inf / inf; left out as not live)
        x = rows["speed"] / rows["v_ref"][..., None]
    held = (x > rows["top"][..., None] * (1 + 1e-12)) | (np.arange(X) < first)
    held |= ~live[..., None]
    lr = np.log(radius)
    miss = np.zeros((R - 1, A))
    for f in _results(rows, angle, held):
        miss = np.maximum(miss, _interval_miss(f.reshape(R, A, -1), lr, axis=0, by=1))
    return miss, live.reshape(R, A, -1).all(axis=2)


def _refinement(rows: dict, angle) -> np.ndarray:
    """The miss of linear interpolation in angle of ``cor_n``, ``cor_t`` or ``spin_ratio``
    per (radius, angle interval), ``(R, A - 1)``.

    The miss of an interval is estimated from the second differences at its two ends (a kink
    inside it gives ``|d2| ~ h * (jump of the slope)`` and a miss up to ``|d2| / 4``); an
    interval is split into ``ceil(miss / tol)`` parts (at most 8).
    """
    A = angle.size
    R = rows["cor_n"].shape[0]
    miss = np.zeros((R, A - 1))
    for f in _results(rows, angle):
        miss = np.maximum(miss, _interval_miss(f.reshape(R, A, -1), angle, axis=1, by=0).T)
    return miss


def _results(rows: dict, angle, held=None):
    """``cor_n``, ``cor_t``'s error scale (``vt_ratio / sin(angle)``: cor_t's error is vt's
    over sin) and ``spin_ratio`` as ``(R, A, W*X)`` arrays, NaN where ``held``."""
    R, A = rows["cor_n"].shape[0], angle.size
    sin = np.sin(np.radians(angle))
    for name in ("cor_n", "vt_ratio", "spin_ratio"):
        f = rows[name] if held is None else np.where(held, np.nan, rows[name])
        f = f.reshape(R, A, -1)
        if name == "vt_ratio":
            f = f / np.where(sin > 0, sin, np.inf)[None, :, None]
        yield f


def _interval_miss(f, nodes, axis: int, by: int) -> np.ndarray:
    """Per interval of ``nodes`` (along ``axis`` of ``f``) and index of axis ``by``: half the
    largest second difference at the interval's two ends, each node's miss by its
    neighbours' line on the non-uniform grid (NaN entries count as 0); ``(intervals,
    f.shape[by])``."""
    f = np.moveaxis(f, (axis, by), (0, 1))
    h = np.diff(nodes)
    h0, h1 = h[:-1], h[1:]
    shape = (-1,) + (1,) * (f.ndim - 1)
    w0 = (h1 / (h0 + h1)).reshape(shape)
    w1 = (h0 / (h0 + h1)).reshape(shape)
    d2 = np.abs(w0 * f[:-2] + w1 * f[2:] - f[1:-1])
    d2 = np.max(np.nan_to_num(d2, nan=0.0).reshape(d2.shape[:2] + (-1,)), axis=2)
    edge = np.zeros((1, f.shape[1]))
    node = np.concatenate([edge, d2, edge])
    return np.maximum(node[:-1], node[1:]) / 2.0


def _split(nodes, miss, tol: float, most: int):
    """New nodes splitting each interval into ``ceil(miss / tol)`` equal parts (at most
    ``most``), and the interval each lies in."""
    h = np.diff(nodes)
    parts = np.minimum(np.ceil(miss / tol), most).astype(int)
    new, owner = [], []
    for j, m in enumerate(parts):
        if m > 1:
            new.append(nodes[j] + h[j] * np.arange(1, m) / m)
            owner.append(np.full(m - 1, j))
    if not new:
        return np.array([]), np.array([], int)
    return np.concatenate(new), np.concatenate(owner)

"""The kink-aligned layout of the wall law (``wall_law(..., layout="aligned")``).

Rolling puts two kinks into the tangential results (:data:`~._law.KINKS`): below an angle
``theta*`` the sphere reaches rolling before it leaves the wall, above it it slides through;
and in fast impacts, below a smaller angle it still rolls when it leaves, above it the
rolling gives way to sliding again before it leaves. On a tensor product of angles the kinks
move across the angle nodes as the speed ratio and the radius change, and linear
interpolation needs hundreds of angles to resolve them (574 at one radius). Here the results
are tabulated against the aligned coordinate ``u`` of :func:`~._law.kink_coordinate`
(piecewise linear in the angle between ``0``, the kinks and the top angle), in which the
kinks are the nodes ``u = 1`` and ``u = 2`` at every (radius, spin, speed ratio); the kink
angles are a table of their own over (radius, spin, speed ratio). Measured at one radius
(BENCHMARKS.md, "Wall law: kink-aligned angles"): 33 nodes of ``u`` aligned with ``theta*``
alone at the 64 default speed ratios met 1e-3 in ``cor_n``, ``cor_t`` and ``omega_out r /
speed``; over 1-100 um the second kink (at 50-90 m/s) left ``cor_t`` 2.3e-3 off without a
node of its own.

What stays as in the tensor-product layout: the capture speed on its (radius, angle, spin)
grid, interpolated through ``g = (v_c cos)^(-1/4)``; the speed ratio; each row's top and the
stick rows. A cell (radius node, ``u``, spin, speed ratio) is simulated at the angle
``theta(u; theta*)`` and at the speed ratio times the capture speed the table interpolates at
that angle, so that a query on a node reproduces the cell.

The kinks at a (radius, spin, speed ratio) node: the first angle of a coarse scan (every 5
deg) at which the sphere no longer rolls when it leaves (its slip at exit is not 0), and the
first at which it no longer reaches rolling (``roll_time`` not finite), each then bisected;
where the scan never gets there, the table's top angle.

Radius nodes: first those of the capture speed (as in the tensor-product layout), then the
results are checked at the midpoint (in ``log r``) of every interval, on every ``u`` node and
every fourth speed ratio, against ``simulate`` at the speeds the table would use there; an
interval whose check misses by more than the tolerance gets the midpoint as a node.
"""

from __future__ import annotations

import numpy as np

from ._capture import CaptureStatus
from ._law import (
    KINKS,
    NOT_SIMULATED,
    OUTPUTS,
    WallLaw,
    _cell,
    _multilinear,
    capture_coordinate,
    capture_from_coordinate,
    kink_angle,
    scene_attributes,
)
from ._refine import RADIUS_LEVELS, RADIUS_MIN_STEP
from ._rows import _top

#: Nodes of the aligned coordinate, intervals per segment: below the first kink, between the
#: kinks, and above the second. The first two are denser toward their start, as
#: ``(k/n)^1.5``: the tangential results bend at small angles as rolling resistance takes the
#: small tangential speed (a uniform 16 below theta* left ``cor_t`` 1.6e-2 off at 1.4 deg),
#: and in fast impacts the first kink lies below 1 deg, so that the second segment holds the
#: small angles (8 uniform intervals there left ``cor_t`` 3e-3 off at 2 deg, 424 m/s).
KINK_SEGMENTS = (24, 12, 20)
KINK_GRADING = (1.5, 1.5, 1.0)
#: A rebound whose slip at exit (``vt_out - omega_out r``) is below this fraction of the
#: impact speed still rolls when it leaves (rolling is an exact state of the model: 1e-16).
ROLLING_SLIP = 1e-9
#: Coarse scan for the kinks: this many angles from 0 to the table's top, then bisection.
KINK_SCAN = 18
KINK_BISECTIONS = 12
#: Default tolerance of the results' radius check (the outputs' own interpolation in ``u``
#: and speed adds about 6.5e-4 at one radius; the issue's target is 1e-3).
ALIGNED_TOL = 5e-4
#: The radius check uses every this many speed ratios.
CHECK_EVERY = 4


def kink_nodes(segments=KINK_SEGMENTS, grading=KINK_GRADING) -> np.ndarray:
    """The nodes of the aligned coordinate (see :data:`KINK_SEGMENTS`): 0, then
    ``segments[j]`` intervals in ``[j, j + 1]``, as ``j + (k/n)^grading[j]``."""
    parts = [np.zeros(1)]
    for j, (n, p) in enumerate(zip(segments, grading, strict=True)):
        parts.append(j + np.linspace(0.0, 1.0, n + 1)[1:] ** p)
    return np.concatenate(parts)


class _CaptureRows:
    """Capture speeds of radius nodes, interpolated as the lookup does (``g = (v_c
    cos)^(-1/4)`` multilinear in log radius, angle and spin)."""

    def __init__(self, radius, angle, omega, v_c):
        self.log_r, self.angle, self.omega = np.log(radius), angle, omega
        self.g = capture_coordinate(v_c, angle)

    def at(self, r, theta, w):
        r, theta, w = np.broadcast_arrays(r, theta, w)
        ir, wr, _ = _cell(self.log_r, np.log(r))
        ia, wa, _ = _cell(self.angle, theta)
        iw, ww, _ = _cell(self.omega, w)
        return capture_from_coordinate(_multilinear(self.g, (ir, ia, iw), (wr, wa, ww)), theta)


def aligned_law(ctx, scene, radius, angle, omega, x, refine, tol, say) -> tuple:
    """The aligned table on the radius nodes ``radius`` (capture-speed nodes), refined in
    radius where the results' check at an interval's midpoint misses by more than ``tol``.
    Returns ``(WallLaw, report)``."""
    u_nodes = kink_nodes()
    top = float(angle[-1])
    nodes = _full_nodes(ctx, radius, angle, omega, x, u_nodes, top, "aligned nodes")
    report = {"kink_rows_changing_more_than_once": nodes.pop("multiple"), "checked_radii": 0}
    unresolved = []
    pending = list(zip(radius[:-1], radius[1:], strict=True)) if refine else []
    for level in range(RADIUS_LEVELS):
        if not pending:
            break
        law = _assembled(scene, nodes, angle, omega, x, u_nodes)
        mids = np.sqrt(np.array([lo * hi for lo, hi in pending]))
        say(f"aligned radius check, level {level + 1}: {mids.size} midpoints")
        miss = _check(ctx, law, mids, u_nodes, top, f"radius check {level + 1}")
        report["checked_radii"] += mids.size
        grow, split = [], []
        for (lo, hi), m, e in zip(pending, mids, miss, strict=True):
            if e <= tol:
                continue
            if np.log(hi / lo) < 2 * RADIUS_MIN_STEP:
                unresolved.append((float(lo), float(hi), float(e)))
                continue
            grow.append(m)
            split += [(lo, m), (m, hi)]
        if grow:
            say(f"aligned radius check, level {level + 1}: {len(grow)} more radius nodes")
            more = _full_nodes(ctx, np.array(grow), angle, omega, x, u_nodes, top, "new radii")
            report["kink_rows_changing_more_than_once"] += more.pop("multiple")
            nodes = _merged(nodes, more)
        pending = split
    unresolved += [(float(lo), float(hi), float("nan")) for lo, hi in pending]
    report.update(results_tol=float(tol), results_unresolved=unresolved)
    return _assembled(scene, nodes, angle, omega, x, u_nodes), report


def _full_nodes(ctx, radii, angle, omega, x, u_nodes, top, stage) -> dict:
    """Everything the table holds at radius nodes ``radii``: capture speeds and statuses
    ``(n, A, W)``, the kink angles ``(n, K, W, X)``, and the cells ``(n, U, W, X)``."""
    radii = np.asarray(radii, dtype=float)
    v_c = ctx.capture_speeds(radii, angle)
    keys = [
        (float(r), float(a), float(w)) for r in radii for a in angle for w in omega
    ]  # ctx.known holds each lane's (capture speed, status)
    c_status = np.array([ctx.known[k][1] for k in keys]).reshape(v_c.shape)
    cap = _CaptureRows(radii, angle, omega, v_c)
    kinks, multiple = _kink_angles(ctx, cap, radii, omega, x, top, stage)
    cells = _cells(ctx, cap, radii, omega, x, u_nodes, kinks, top, stage)
    X = x.size
    n, U, W = radii.size, u_nodes.size, omega.size
    flat = {k: v.reshape(n * U * W, X) for k, v in cells.items() if k != "speed"}
    stick = ~np.isfinite(cells["v_ref"]).any(axis=-1).reshape(-1)
    top_x, again = _top(ctx, flat, x, stick)
    status = flat["status"].reshape(n, U, W, X)
    status[..., 0] = np.where(np.isfinite(cells["v_ref"][..., 0]), 0, NOT_SIMULATED)
    return {
        "radius": radii,
        "v_c": v_c,
        "c_status": c_status,
        "kinks": np.moveaxis(kinks, 0, 1),
        "speed": cells["speed"],
        "status": status,
        "top": top_x.reshape(n, U, W),
        "again": again.reshape(n, U, W),
        "multiple": multiple,
        **{k: flat[k].reshape(n, U, W, X) for k in OUTPUTS},
    }


def _kink_angles(ctx, cap, radii, omega, x, top, stage):
    """The kink angles ``(K, n, W, X)`` (deg, :data:`~._law.KINKS`' order) and the number of
    (radius, spin, speed) rows whose regime goes back along the scan (its first change to
    each regime is taken)."""
    n, W = radii.size, omega.size
    K = len(KINKS)
    xq = np.where(x == 1.0, 1.0 + 1e-6, x)  # at the capture speed itself: just above it
    scan = np.linspace(0.0, top, KINK_SCAN)
    shape = (n, W, x.size, scan.size)
    r = np.broadcast_to(radii[:, None, None, None], shape)
    w = np.broadcast_to(omega[None, :, None, None], shape)
    xx = np.broadcast_to(xq[None, None, :, None], shape)
    th = np.broadcast_to(scan[None, None, None, :], shape)
    regime = _regimes(ctx, cap, r, th, w, xx, f"{stage}: kink scan").reshape(shape)
    back = (np.diff(regime, axis=-1) < 0).any(axis=-1)
    r3, w3, x3 = (np.broadcast_to(v[..., 0], (K,) + shape[:-1]) for v in (r, w, xx))
    beyond = regime[None] > np.arange(K)[:, None, None, None, None]  # (K, n, W, X, scan)
    k = np.argmax(beyond, axis=-1)  # first scan angle past kink j
    never = ~beyond.any(axis=-1)
    lo, hi = scan[np.maximum(k - 1, 0)], scan[k]
    live = ~never & (k > 0)
    level_of = np.broadcast_to(np.arange(K)[:, None, None, None], live.shape)
    for level in range(KINK_BISECTIONS):
        mid = 0.5 * (lo + hi)
        got = _regimes(ctx, cap, r3[live], mid[live], w3[live], x3[live], "")
        if level == 0:
            ctx.say(f"{stage}: kink bisection ({KINK_BISECTIONS} x {int(live.sum())} impacts)")
        past = np.zeros(lo.shape, bool)
        past[live] = got > level_of[live]
        lo = np.where(live & ~past, mid, lo)
        hi = np.where(live & past, mid, hi)
    kinks = np.where(never, top, np.where(k == 0, 0.0, 0.5 * (lo + hi)))
    return kinks, int(back.sum())


def _regimes(ctx, cap, r, theta, w, x, stage) -> np.ndarray:
    """The rolling regime of flat lanes at ``x`` times the interpolated capture speed: 0 the
    sphere reaches rolling and still rolls when it leaves, 1 it reaches rolling and slides
    again, 2 it never rolls (captured: as it was when the contact ended). Lanes not simulated
    (a stick cell, above the speed range) count as 0, so that they make no change of their
    own."""
    r, theta, w, x = (np.asarray(v, dtype=float).ravel() for v in (r, theta, w, x))
    speed = x * cap.at(r, theta, w)
    got = ctx.impacts_at(r, theta, w, np.where(np.isfinite(speed), speed, np.inf), stage,
                         rolled=True)  # fmt: skip
    with np.errstate(invalid="ignore"):
        slides = ~(np.abs(got["vt_ratio"] - got["spin_ratio"]) <= ROLLING_SLIP)
    regime = np.where(got["rolled"], np.where(slides & (got["status"] == 0), 1, 0), 2)
    return np.where(got["status"] == NOT_SIMULATED, 0, regime)


def _cells(ctx, cap, radii, omega, x, u_nodes, kinks, top, stage) -> dict:
    """The result cells ``(n, U, W, X)`` at ``theta(u; kinks)`` and ``x`` times the
    interpolated capture speed there (the ``x = 1`` column is not simulated: :func:`_top`
    sets it)."""
    n, U, W, X = radii.size, u_nodes.size, omega.size, x.size
    shape = (n, U, W, X)
    theta = kink_angle(u_nodes[None, :, None, None], kinks[:, :, None, :, :], top)
    r = np.broadcast_to(radii[:, None, None, None], shape)
    w = np.broadcast_to(omega[None, None, :, None], shape)
    v_ref = cap.at(r, theta, w)
    speed = x[None, None, None, :] * v_ref
    run = np.where(np.isfinite(speed), speed, np.inf)
    run[..., 0] = np.inf  # the capture speed itself: set by _top
    got = ctx.impacts_at(r.ravel(), theta.ravel(), w.ravel(), run.ravel(), f"{stage}: cells")
    out = {k: v.reshape(shape) for k, v in got.items()}
    out["speed"], out["v_ref"], out["theta"] = speed, v_ref, theta
    return out


def _check(ctx, law: WallLaw, radii, u_nodes, top, stage) -> np.ndarray:
    """Largest miss of ``law`` (per radius in ``radii``) against ``simulate`` on the cells a
    node at that radius would have (every ``u``, every :data:`CHECK_EVERY`-th speed ratio
    above 1), at the speeds the table interpolates there, in the issue's measures (``cor_n``,
    ``cor_t``, the spin in units of speed / radius); NaN-free (0 where nothing rebounds)."""
    omega, x = law.omega0, law.speed_ratio
    cols = np.unique(np.append(np.arange(1, x.size, CHECK_EVERY), x.size - 1))
    cap = _CaptureRows(law.radius, law.angle_deg, omega, law.capture_speed)
    kinks, _ = _kink_angles(ctx, cap, radii, omega, x[cols], top, stage)
    cells = _cells(ctx, cap, radii, omega, x[cols], u_nodes, kinks, top, stage)
    n, U, W, C = cells["speed"].shape
    r = np.broadcast_to(radii[:, None, None, None], (n, U, W, C))
    w = np.broadcast_to(omega[None, None, :, None], (n, U, W, C))
    th = np.radians(cells["theta"])
    speed = np.where(np.isfinite(cells["speed"]), cells["speed"], 1.0)
    code, vn_out, vt_out, om_out = law.evaluate(r, speed * np.cos(th), speed * np.sin(th), w)
    ok = (cells["status"] == 0) & (code == 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        table = {
            "cor_n": vn_out / (speed * np.cos(th)),
            "vt_ratio": vt_out / speed,
            "spin_ratio": om_out * r / speed,
        }
    # cor_t: the tangential miss over the tangential impact speed (none at 0 deg)
    sin = np.sin(th)
    scale = {"cor_n": 1.0, "vt_ratio": np.where(sin > 0, sin, np.inf), "spin_ratio": 1.0}
    miss = np.zeros(n)
    for name in OUTPUTS:
        e = np.where(ok, np.abs(table[name] - cells[name]) / scale[name], 0.0)
        miss = np.maximum(miss, e.reshape(n, -1).max(axis=1))
    return miss


def _merged(a: dict, b: dict) -> dict:
    """Node sets merged and sorted by radius."""
    out = {k: np.concatenate([a[k], b[k]]) for k in a}
    order = np.argsort(out["radius"])
    return {k: v[order] for k, v in out.items()}


def _assembled(scene, nodes, angle, omega, x, u_nodes) -> WallLaw:
    """The :class:`WallLaw` of the nodes; cells without results (stick cells) take the
    nearest radius's that has them (as the tensor-product layout's stick rows do)."""
    nodes = {k: v.copy() for k, v in nodes.items()}
    for name in (*OUTPUTS, "kinks"):
        _fill_along_radius(nodes[name])
    stick = ~np.isfinite(nodes["v_c"])
    for name in (*OUTPUTS, "kinks"):  # none left where no radius has results
        nodes[name] = np.where(np.isfinite(nodes[name]), nodes[name], 0.0)
    return WallLaw(
        radius=nodes["radius"],
        angle_deg=angle,
        omega0=omega,
        speed_ratio=x,
        speed_axis="capture_ratio",
        capture_speed=nodes["v_c"],
        capture_status=np.where(stick, CaptureStatus.ALL_CAPTURED, nodes["c_status"]).astype(int),
        reference_speed=nodes["v_c"],
        speed=nodes["speed"],
        status=nodes["status"].astype(int),
        cor_n=nodes["cor_n"],
        vt_ratio=nodes["vt_ratio"],
        spin_ratio=nodes["spin_ratio"],
        scene=scene_attributes(scene),
        top_ratio=nodes["top"],
        captured_above_top=nodes["again"],
        kink_angles=np.moveaxis(nodes["kinks"], 1, 0),
        kink_u=u_nodes,
    )


def _fill_along_radius(values: np.ndarray) -> None:
    """NaN entries take the value of the nearest radius (axis 0) where it is finite, in
    place."""
    bad = ~np.isfinite(values)
    if not bad.any():
        return
    flat = values.reshape(values.shape[0], -1)
    badf = bad.reshape(values.shape[0], -1)
    for j in np.flatnonzero(badf.any(axis=0)):
        live = np.flatnonzero(~badf[:, j])
        if live.size:
            for i in np.flatnonzero(badf[:, j]):
                flat[i, j] = flat[live[np.argmin(np.abs(live - i))], j]

"""The wall law: rebound tables over radius, incidence angle, spin and speed, tabulated against
the speed relative to the capture speed, and their interpolation (the same arithmetic as the
generated C function).

Axes
----
- ``radius`` (m): the sphere radii (default: the scene's); interpolated linearly in
  ``log(radius)``.
- ``angle_deg`` (deg, >= 0): incidence from the normal; a query with negative tangential speed
  is mirrored (tangential speed and spin change sign, and so do their results).
- ``omega0`` (rad/s): initial spin, signed so that ``v_t = r omega`` is rolling.
- ``speed_ratio``: the impact speed over the reference speed of its (radius, angle, spin): the
  capture speed where the scene has adhesion (``speed_axis = "capture_ratio"``: below 1 the
  sphere sticks, the boundary is exact), else 1 m/s (``speed_axis = "speed"``: the ratio is the
  speed in m/s). Interpolated linearly in ``u = asinh(sqrt(x - 1))`` (capture ratio: ``cor_n``
  goes like ``sqrt(x - 1)`` just above the capture speed, where ``u ~ sqrt(x - 1)``, and
  changes slowly with ``log x`` far above it, where ``u ~ (log x)/2 + log 2``) or
  ``u = x^0.2`` (speed: the damping enters as ``v^0.2``, eq. 21/24 of the paper).

Capture speed across radius and angle: the table interpolates ``g = (v_c cos(angle))^(-1/4)``
(multilinear in log radius, angle and spin) and inverts it, ``v_c = g^-4 / cos(angle)``. The
capture speed falls about like ``r^-2`` at large radii (``g`` about linear in ``log r``) and
grows without bound toward the radius below which the sphere sticks at every speed: such a
radius is a *stick row* with ``g = 0``, so that between it and the next rebounding radius the
interpolated capture speed rises to infinity instead of jumping. Radius nodes are added
(bisection in ``log r``) until the capture speed at every interval's midpoint is within
``capture_tol`` of its interpolation.

Layouts: this module's tensor product of angles (``layout="grid"``), described here, or the
kink-aligned layout of :mod:`._aligned` (``layout="aligned"``, the default for a radius range
of an adhesive scene), whose results are on an angle coordinate that follows the kinks of
rolling (``kink_angles``, ``kink_u``); the capture speed, the speed axis, the rows' tops and
the stick rows are the same in both.

Refinement: radius and angle intervals are split where linear interpolation of the results
would miss by more than ``refine_tol`` (an estimate from second differences). The table is a
tensor product (the generated C code reads one), so a new node gets a cell at every radius
(or angle); a cell is simulated only where its own rows need the node, and elsewhere holds
the interpolation of its interval's ends, which is what the table gives there without it.

Each (radius, angle, spin) row is valid up to ``top_ratio``: the largest speed ratio of the row
within the speed range (1000 m/s) below any speed at which the sphere sticks again. A query
above it is flagged as clamped and answered as captured where the rows stick again there
(``captured_above_top``, interpolated, at least 0.5), else with the row's last valid values.

Tabulated (dimensionless, so that they interpolate smoothly): ``cor_n = vn_out / v_n``,
``vt_ratio = vt_out / speed`` and ``spin_ratio = omega_out r / speed``. The node at
``speed_ratio = 1`` (capture mode) is the capture speed itself: ``cor_n = 0`` there (the
model's limit) and the tangential results are extrapolated linearly in ``u`` from the next two
nodes (the simulator cannot tell a rebound from a capture exactly at the threshold).

Where the code lives: this module checks the axes and builds the table (:func:`wall_law`);
the table and its interpolation are :mod:`._law`, the simulated rows :mod:`._rows`, the new
radius, angle and speed nodes :mod:`._refine`, the kink-aligned layout :mod:`._aligned` and
the posterior spread :mod:`._uncertainty`.
"""

from __future__ import annotations

import time

import numpy as np

from .._engine.settings import scene_parameters
from .._model.scene import SceneError
from ._aligned import ALIGNED_TOL, aligned_law
from ._law import KINK_MIN_DEG as KINK_MIN_DEG
from ._law import OUTPUTS, WallLaw, WallLawError, scene_attributes
from ._law import _cell as _cell
from ._law import kink_angle as kink_angle
from ._law import kink_coordinate as kink_coordinate
from ._refine import _radius_nodes, _refined, _refined_radii, _refined_speeds
from ._rows import SPEED_MAX, _Context
from ._uncertainty import _uncertainty

# (The names imported "as" themselves, and ``WallLawError``, ``SPEED_MAX``, ``_Context`` and
# ``_uncertainty``, are kept importable from here, where tests, benchmarks and the command
# line import them.)

__all__ = [
    "DEFAULT_ANGLES",
    "DEFAULT_SPEED_RATIOS",
    "DEFAULT_SPEEDS",
    "WallLaw",
    "WallLawError",
    "wall_law",
]

#: Default incidence angles (deg) of the first pass: 0 to 85, every 0.5 degree.
DEFAULT_ANGLES = np.linspace(0.0, 85.0, 171)
#: Default speed ratios (capture mode): 1 to 200, 64 nodes even in ``asinh(sqrt(x - 1))``.
DEFAULT_SPEED_RATIOS = 1.0 + np.sinh(np.linspace(0.0, np.arcsinh(np.sqrt(199.0)), 64)) ** 2
#: Default speeds (m/s) for scenes without adhesion: 0.01 to 100 m/s, geometric.
DEFAULT_SPEEDS = np.geomspace(0.01, 100.0, 49)
#: Default ``speed_tol`` of a one-radius table: the accuracy aimed for (cor_n, cor_t and
#: omega_out r / speed within 1e-3). Measured on Table 1 at 12,000 random points: largest
#: errors 2.2e-4, 3.4e-4 and 8.1e-4 (with 177 more speed nodes), against 3.9e-4, 2.0e-3 and
#: 4.8e-3 without the speed pass (BENCHMARKS.md, "Wall law").
SPEED_TOL = 1e-3
#: Default ``refine_tol`` of the tensor-product layout.
REFINE_TOL = 2e-4


def _check_axis(name: str, values, lo=None, hi=None, lo_open=False, unit=""):
    v = np.asarray(values, dtype=float).ravel()
    if v.size == 0:
        raise SceneError(f"{name}: at least one value is needed")
    if not np.all(np.isfinite(v)):
        raise SceneError(f"{name}: values must be finite")
    if np.any(np.diff(np.sort(v)) == 0):
        raise SceneError(f"{name}: values must be distinct")
    low = (v <= lo if lo_open else v < lo) if lo is not None else np.zeros(v.shape, bool)
    bad = low | (v > hi if hi is not None else False)
    if np.any(bad):
        side = "(" if lo_open else "["
        allowed = f"{side}{lo:g}, {hi:g}] {unit}".rstrip()
        raise SceneError(f"{name}: {v[bad][0]:g} is outside the allowed range {allowed}")
    return np.sort(v)


def wall_law(
    scene,
    radius=None,
    angle_deg=None,
    omega0=(0.0,),
    speed_ratio=None,
    *,
    draws=None,
    max_draws: int = 20,
    refine: bool = True,
    refine_tol: float | None = None,
    speed_tol: float | bool | None = None,
    capture_tol: float = 1e-3,
    progress=None,
    layout: str | None = None,
) -> WallLaw:
    """Tabulate the wall law of ``scene`` (module docstring).

    **Arguments:**
    - `scene`: a `Scene` (scalar parameters).
    - `radius`: radii (m); default the scene's. With two or more (and `refine`), the first
      and last bound the table's range and nodes are added between them where the capture
      speed or the outputs need them (module docstring).
    - `angle_deg`: incidence angles (deg, in [0, 90)); default :data:`DEFAULT_ANGLES`.
    - `omega0`: spins (rad/s); default 0 only (CFD parcels rarely carry spin).
    - `speed_ratio`: speeds over the capture speed (>= 1; the node 1 is added), default
      :data:`DEFAULT_SPEED_RATIOS`; for a scene without adhesion, speeds in m/s (default
      :data:`DEFAULT_SPEEDS`).
    - `draws`: posterior draws, a dict ``name -> 1-D array`` of scene parameters (or ``None``):
      the table then carries the capture probability and the spread of ``cor_n`` per cell.
    - `max_draws`: at most this many draws are used (evenly spaced).
    - `refine`: split the angle intervals where linear interpolation would miss by more than
      `refine_tol` (default 2e-4) in ``cor_n``, ``cor_t`` or ``omega_out r / speed`` (the
      onset of rolling puts a kink in them): a second pass on those angles only.
    - `speed_tol`: split the speed intervals where linear interpolation (in the speed
      coordinate) of a row would miss by more than this (the onset of rolling crosses the
      speed axis at a ratio that moves with the angle); ``False``: not. Default (``None``):
      :data:`SPEED_TOL` for a table of one radius; not across a radius range, where every
      new speed node adds a cell to each (radius, angle) row (BENCHMARKS.md, "Wall law").
    - `capture_tol`: with several radii, the largest relative error of the interpolated
      capture speed at the midpoint (in log radius) of any two neighbouring radius nodes.
    - `progress`: a callable taking a one-line message, or None.
    - `layout`: ``"grid"`` (results on the tensor product of the angles, refined where the
      rows bend) or ``"aligned"`` (results against the kink-aligned angle coordinate,
      :mod:`jaximpact.wall_law._aligned`: 57 angle nodes instead of hundreds; needs
      adhesion; `refine_tol` is then the results' radius check, default 5e-4, and the angle
      and speed passes are not run). Default (``None``): ``"aligned"`` for a radius range
      of an adhesive scene at one spin (1-100 um in about 3 minutes on 2 cores instead of
      26), else ``"grid"`` (with spin nodes the aligned layout was not verified: at 5 spins
      over +-2e4 rad/s its spin was 0.17 off at a spin node; docs/open_points.md).

    **Returns:** a :class:`WallLaw`.

    **Raises:** `SceneError` (bad input, naming it); :class:`WallLawError` where a capture
    speed or an impact of the grid failed.
    """
    from .._engine.api import simulate

    say = progress or (lambda message: None)
    start = time.perf_counter()
    base, radius, angle, omega, x, adhesive = _grid_axes(
        scene, radius, angle_deg, omega0, speed_ratio
    )
    layout = _checked_layout(layout, adhesive, radius, omega, refine_tol, speed_tol, capture_tol)
    ctx = _Context(simulate, scene, base, radius, omega, x, adhesive, say)
    report = {}
    if refine and adhesive and radius.size >= 2:
        radius, report = _radius_nodes(ctx, radius, angle, capture_tol, say)
        ctx.radius = radius
    if layout == "aligned":
        law = _aligned_layout(ctx, scene, angle, refine, refine_tol, report)
    else:
        law = _grid_layout(ctx, scene, angle, refine, refine_tol, speed_tol, report)
    return _finished(law, simulate, scene, draws, max_draws, say, ctx.impacts, start)


def _checked_layout(layout, adhesive, radius, omega, refine_tol, speed_tol, capture_tol) -> str:
    """The layout of the table (``None``: :func:`wall_law`'s default for these axes), the
    tolerances checked (a :class:`SceneError` naming a bad one)."""
    if speed_tol not in (None, False) and not (
        isinstance(speed_tol, float | int) and 0 < speed_tol < 1
    ):
        raise SceneError(f"speed_tol must be in (0, 1), False or None, got {speed_tol!r}")
    if not (isinstance(capture_tol, float | int) and 0 < capture_tol < 1):
        raise SceneError(f"capture_tol must be in (0, 1), got {capture_tol!r}")
    if refine_tol is not None and not (isinstance(refine_tol, float | int) and refine_tol > 0):
        raise SceneError(f"refine_tol must be > 0, got {refine_tol!r}")
    if layout is None:
        layout = "aligned" if adhesive and radius.size >= 2 and omega.size == 1 else "grid"
    if layout not in ("grid", "aligned"):
        raise SceneError(f"layout must be 'grid' or 'aligned', got {layout!r}")
    if layout == "aligned" and not adhesive:
        raise SceneError(
            "layout 'aligned' tabulates against the capture speed: the scene needs adhesion"
        )
    if layout == "aligned" and speed_tol not in (None, False):
        raise SceneError("speed_tol (--speed-tol) is the grid layout's speed pass, not aligned's")
    return layout


def _aligned_layout(ctx, scene, angle, refine, refine_tol, report) -> WallLaw:
    """The kink-aligned layout (:mod:`._aligned`) on the context's radius nodes, with its
    build report."""
    ctx.lane_batch(angle.size * ctx.omega.size)
    tol = ALIGNED_TOL if refine_tol is None else refine_tol
    law, aligned = aligned_law(
        ctx, scene, ctx.radius, angle, ctx.omega, ctx.x, refine, tol, ctx.say
    )
    law.radius_report = {
        **report,
        **aligned,
        "layout": "aligned",
        "not_converged": ctx.not_converged,
        "refine_tol": tol if refine else None,
        "speed_tol": None,
        "new_cells": {},
    }
    return law


def _grid_layout(ctx, scene, angle, refine, refine_tol, speed_tol, report) -> WallLaw:
    """The tensor-product layout: the first pass on the grid's angles, then (``refine``) new
    radius, angle and speed nodes where the rows bend (module docstring, "Refinement"), with
    its build report."""
    radius, say = ctx.radius, ctx.say
    refine_tol = REFINE_TOL if refine_tol is None else refine_tol
    rows = ctx.angles(angle, batch=None, stage="pass 1 (the grid's angles)")
    if refine and radius.size >= 3:
        rows, radius = _refined_radii(ctx, rows, radius, angle, refine_tol, say)
        ctx.radius = radius
    if refine and angle.size >= 3:
        rows, angle = _refined(ctx, rows, angle, refine_tol, say)
    if speed_tol is None:
        speed_tol = SPEED_TOL if radius.size == 1 else False
    if refine and speed_tol and ctx.x.size >= 3:
        rows = _refined_speeds(ctx, rows, radius, angle, speed_tol, say)
    law = _assembled(scene, rows, radius, angle, ctx.omega, ctx.x, ctx.adhesive)
    law.radius_report = {
        **report,
        "not_converged": ctx.not_converged,
        "refine_tol": refine_tol,
        "speed_tol": float(speed_tol) if refine and speed_tol else None,
        "new_cells": ctx.new_cells,
    }
    if not refine:
        law.radius_report["refine_tol"] = None
    return law


def _finished(law, simulate, scene, draws, max_draws, say, impacts, start) -> WallLaw:
    """``law`` with its posterior spread (``draws``), build time and impact count."""
    if draws is not None:
        law.uncertainty = _uncertainty(simulate, scene, law, draws, max_draws, say)
        impacts += law.uncertainty["draws"] * law.speed.size
    law.seconds = time.perf_counter() - start
    law.impacts = impacts
    return law


def _grid_axes(scene, radius, angle_deg, omega0, speed_ratio):
    """The scene's scalar parameters and the checked axes of the table: ``(base, radius,
    angle, omega, x, adhesive)``; ``x`` is the speed over the capture speed (node 1 first)
    for an adhesive scene, the speed in m/s otherwise."""
    if scene.target is not None:
        raise SceneError(
            "wall_law tabulates impacts on a wall; the scene has a [target] sphere (remove it)"
        )
    params = scene_parameters(scene)
    for k, v in params.items():
        if np.ndim(v) != 0:
            raise SceneError(f"wall_law needs a scene with one value per parameter ({k})")
    base = {k: float(v) for k, v in params.items()}
    radius = _check_axis(
        "radius (--radius)", [base["radius"]] if radius is None else radius, 1e-9, 1.0, unit="m"
    )
    angle = _check_axis(
        "angle_deg (--angle)",
        DEFAULT_ANGLES if angle_deg is None else angle_deg,
        0.0,
        89.9,
        unit="deg",
    )
    omega = _check_axis("omega0 (--spin)", omega0, -1e9, 1e9, unit="rad/s")
    strength = base["f0"] if scene.model.normal == "brach_dunn" else base["w"]
    adhesive = bool(scene.model.adhesion) and strength > 0
    if adhesive:
        x = _check_axis(
            "speed_ratio (--speed)",
            DEFAULT_SPEED_RATIOS if speed_ratio is None else speed_ratio,
            1.0,
            SPEED_MAX,
            unit="(speed / capture speed)",
        )
        if x[0] != 1.0:
            x = np.concatenate([[1.0], x])
        if x.size < 3:
            raise SceneError("speed_ratio: at least two values above 1 are needed")
    else:
        x = _check_axis(
            "speed (--speed, m/s: the scene has no adhesion)",
            DEFAULT_SPEEDS if speed_ratio is None else speed_ratio,
            0.0,
            SPEED_MAX,
            lo_open=True,
            unit="m/s",
        )
    return base, radius, angle, omega, x, adhesive


def _assembled(scene, rows, radius, angle, omega, x, adhesive) -> WallLaw:
    """The :class:`WallLaw` of the computed rows, reshaped to (radius, angle, spin[, speed])."""
    R, A, W, X = radius.size, angle.size, omega.size, x.size
    rows = _filled_stick_rows(rows, R)
    return WallLaw(
        radius=radius,
        angle_deg=angle,
        omega0=omega,
        speed_ratio=x,
        speed_axis="capture_ratio" if adhesive else "speed",
        capture_speed=rows["v_c"].reshape(R, A, W),
        capture_status=rows["c_status"].reshape(R, A, W).astype(int),
        reference_speed=rows["v_ref"].reshape(R, A, W),
        speed=rows["speed"].reshape(R, A, W, X),
        status=rows["status"].reshape(R, A, W, X).astype(int),
        cor_n=rows["cor_n"].reshape(R, A, W, X),
        vt_ratio=rows["vt_ratio"].reshape(R, A, W, X),
        spin_ratio=rows["spin_ratio"].reshape(R, A, W, X),
        scene=scene_attributes(scene),
        top_ratio=rows["top"].reshape(R, A, W),
        captured_above_top=rows["again"].reshape(R, A, W),
    )


def _filled_stick_rows(rows: dict, R: int) -> dict:
    """Stick rows (captured at every speed) hold no results; a cell between one and a
    rebounding radius interpolates them where the query is faster than the interpolated
    capture speed, so they take the nearest rebounding radius's results (same angle and
    spin): in the speed-ratio coordinate the results change slowly with radius."""
    stick = ~np.isfinite(rows["v_ref"])  # (R, A*W)
    if not stick.any():
        return rows
    rows = {k: v.copy() for k, v in rows.items()}
    for j in range(stick.shape[1]):
        live = np.flatnonzero(~stick[:, j])
        for i in np.flatnonzero(stick[:, j]):
            for name in OUTPUTS:
                if live.size:
                    near = live[np.argmin(np.abs(live - i))]
                    rows[name][i, j] = rows[name][near, j]
                else:
                    rows[name][i, j] = 0.0
    return rows

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
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .._engine.simulate import PARAMETERS, scene_parameters
from .._model.scene import SceneError
from ._capture import RTOL, CaptureStatus, _root, _search, scene_with

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
SPEED_MAX = 1000.0  # m/s (docs/input_ranges.md)
OUTPUTS = ("cor_n", "vt_ratio", "spin_ratio")
#: Status of a cell that was not simulated (a stick row, or a speed above SPEED_MAX).
NOT_SIMULATED = -1
#: Default ``speed_tol`` of a one-radius table: the accuracy aimed for (cor_n, cor_t and
#: omega_out r / speed within 1e-3). Measured on Table 1 at 12,000 random points: largest
#: errors 2.2e-4, 3.4e-4 and 8.1e-4 (with 177 more speed nodes), against 3.9e-4, 2.0e-3 and
#: 4.8e-3 without the speed pass (BENCHMARKS.md, "Wall law").
SPEED_TOL = 1e-3
#: Default ``refine_tol`` of the tensor-product layout.
REFINE_TOL = 2e-4
#: Radius nodes: at most this many bisections of the given intervals, and none narrower than
#: RADIUS_MIN_STEP in log r (0.1 % of the radius).
RADIUS_LEVELS = 12
RADIUS_MIN_STEP = 1e-3
#: Several radii: each batch holds whole radii's worth of lanes of the first pass, at least
#: RADII_PER_BATCH radii and MIN_BATCH_LANES lanes (a batch of a few hundred lanes spends
#: most of its time in the calls' overhead: 18 angles x 8 radii ran 2,900 impacts/s).
RADII_PER_BATCH = 8
MIN_BATCH_LANES = 2048
#: A new node between two nodes of one capture threshold: its capture speed is searched from
#: the interpolated one, scanning these multiples of it (a bracket of 2 %) instead of six
#: decades (:func:`_Context._capture_near`).
NEAR_SCAN = np.array([0.98, 0.998, 1.002, 1.02])
#: A new node's cell is filled by interpolation (not simulated) only where its rows' estimated
#: miss is below this share of the tolerance: the second-difference estimate was seen 1.5x
#: below the true miss of a filled cell (spin, 1.53e-3 at a tolerance of 1e-3).
FILL_SHARE = 0.5


class WallLawError(RuntimeError):
    """The wall law could not be built (a capture speed or an impact of the grid failed)."""


@dataclass
class WallLaw:
    """A tabulated wall law (numpy arrays; see the module docstring for the axes).

    Arrays ``(radius, angle_deg, omega0)``: ``capture_speed`` (m/s; 0 without adhesion),
    ``capture_status`` (:class:`CaptureStatus`), ``reference_speed`` (m/s). Arrays ``(radius,
    angle_deg, omega0, speed_ratio)``: ``speed`` (m/s), ``status`` (simulate's codes; the
    ``speed_ratio = 1`` node is set, not simulated: 0), ``cor_n``, ``vt_ratio``, ``spin_ratio``
    and, for reading, ``cor_t`` (NaN at angle 0), ``vt_out`` (m/s), ``omega_out`` (rad/s),
    ``rebound_angle_deg``. ``uncertainty``: with posterior draws, ``capture_probability`` and
    ``cor_n_mean``, ``cor_n_sd``, ``cor_n_q05``, ``cor_n_q95`` (over the draws that rebound)
    per cell, and ``draws``, the number used.
    """

    radius: np.ndarray
    angle_deg: np.ndarray
    omega0: np.ndarray
    speed_ratio: np.ndarray
    speed_axis: str
    capture_speed: np.ndarray
    capture_status: np.ndarray
    reference_speed: np.ndarray
    speed: np.ndarray
    status: np.ndarray
    cor_n: np.ndarray
    vt_ratio: np.ndarray
    spin_ratio: np.ndarray
    scene: dict
    seconds: float = 0.0
    impacts: int = 0
    uncertainty: dict = field(default_factory=dict)
    top_ratio: np.ndarray | None = None
    captured_above_top: np.ndarray | None = None
    radius_report: dict = field(default_factory=dict)
    # The kink-aligned layout (``layout="aligned"``, :mod:`._aligned`): ``kink_angles``
    # ``(kink, radius, spin, speed)``, the angles of the kinks of the tangential results
    # (:data:`KINKS`: below the first the sphere still rolls when it leaves, below the second
    # it reaches rolling), and the nodes of the aligned angle coordinate
    # (:func:`kink_coordinate`), which then index the results' second axis (and
    # ``top_ratio``'s) instead of ``angle_deg``; the capture speed stays on ``angle_deg``.
    # ``None``: the tensor-product layout.
    kink_angles: np.ndarray | None = None
    kink_u: np.ndarray | None = None

    def __post_init__(self):
        if self.top_ratio is None:
            self.top_ratio = np.full(self.capture_speed.shape, float(self.speed_ratio[-1]))
        if self.captured_above_top is None:
            self.captured_above_top = np.zeros(self.capture_speed.shape)

    @property
    def aligned(self) -> bool:
        """The kink-aligned layout (results against :func:`kink_coordinate`)."""
        return self.kink_angles is not None

    @property
    def unresolved_radii(self) -> np.ndarray:
        """``(n, 2)``: the radius intervals (m) the build reports as not resolved to its
        tolerances (the capture speed's next to the stick rows, and the aligned layout's
        results check at the smallest radius step); a query inside one is flagged as
        clamped."""
        report = self.radius_report or {}
        bands = list(report.get("unresolved", [])) + list(report.get("results_unresolved", []))
        return np.array([(lo, hi) for lo, hi, *_ in bands], dtype=float).reshape(-1, 2)

    @property
    def theta_star(self) -> np.ndarray:
        """``(radius, spin, speed)``: the angle (deg) below which the sphere reaches rolling
        before it leaves (the last of :attr:`kink_angles`)."""
        return self.kink_angles[-1]

    @property
    def cell_angle_deg(self) -> np.ndarray:
        """``(radius, angle or u, spin, speed)``: the incidence angle of each result cell."""
        if not self.aligned:
            return np.broadcast_to(self.angle_deg[None, :, None, None], self.shape)
        kinks = self.kink_angles[:, :, None, :, :]
        return kink_angle(self.kink_u[None, :, None, None], kinks, self.angle_deg[-1])

    @property
    def stick(self) -> np.ndarray:
        """``(radius, angle, spin)``: rows where the sphere sticks at every speed scanned."""
        return ~np.isfinite(self.reference_speed)

    @property
    def reference_table(self) -> np.ndarray:
        """What is interpolated for the reference speed (module docstring): in capture mode
        ``(v_c cos(angle))^(-1/4)``, 0 on stick rows; else the reference speed."""
        if self.speed_axis != "capture_ratio":
            return np.asarray(self.reference_speed, dtype=float)
        return capture_coordinate(self.reference_speed, self.angle_deg)

    @property
    def u_top(self) -> np.ndarray:
        """``top_ratio`` in the speed coordinate ``u`` (what the C function interpolates)."""
        return self.u_of(self.top_ratio)

    # ----- derived, for reading -----
    # (NaN in the cells that are not a rebound: captured above a row's top, not simulated)
    def _rebounds(self, values) -> np.ndarray:
        return np.where(self.status == 0, values, np.nan)

    @property
    def cor_t(self) -> np.ndarray:
        sin = np.sin(np.radians(self.cell_angle_deg))
        with np.errstate(invalid="ignore", divide="ignore"):
            return self._rebounds(np.where(sin > 0, self.vt_ratio / sin, np.nan))

    @property
    def vt_out(self) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            return self._rebounds(self.vt_ratio * self.speed)

    @property
    def omega_out(self) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            return self._rebounds(self.spin_ratio * self.speed / self.radius[:, None, None, None])

    @property
    def rebound_angle_deg(self) -> np.ndarray:
        cos = np.cos(np.radians(self.cell_angle_deg))
        with np.errstate(invalid="ignore"):
            vn = self.cor_n * self.speed * cos
            out = np.degrees(np.arctan2(self.vt_out, vn))
        return np.where(self.cor_n > 0, out, np.nan)

    @property
    def shape(self) -> tuple:
        return self.cor_n.shape

    # ----- interpolation (the generated C function does the same arithmetic) -----
    def reference_at(self, idx, w, angle):
        """The reference speed at interpolation cells ``idx`` with weights ``w``: capture
        mode interpolates ``g = (v_c cos(angle))^(-1/4)`` (the normal capture speed changes
        slowly with the angle; ``v_c`` itself grows like ``1 / cos``) and inverts it; ``inf``
        where ``g`` is 0 (a stick row's cell: captured at every speed)."""
        if self.speed_axis != "capture_ratio":
            return _multilinear(self.reference_speed, idx, w)
        return capture_from_coordinate(_multilinear(self.reference_table, idx, w), angle)

    def u_of(self, x):
        """The interpolation coordinate of the speed ratio (module docstring)."""
        return _u(x, self.speed_axis == "capture_ratio")

    def evaluate(self, radius, vn, vt, omega=0.0):
        """The wall law at impacts given by ``radius`` (m), normal speed ``vn`` (m/s, > 0,
        toward the wall), tangential speed ``vt`` (m/s, signed) and spin ``omega`` (rad/s,
        ``vt = r omega`` rolling). Arrays broadcast.

        Returns ``(code, vn_out, vt_out, omega_out)``: ``code`` bit 0 (1) set where captured,
        bit 1 (2) where an input was outside the table and clamped to its edge, above a row's
        valid top, or in a radius interval not resolved to the build's tolerances
        (:attr:`unresolved_radii`), bit 2 (4)
        where the input is invalid (radius or ``vn`` not > 0, or not finite); ``vn_out`` (m/s,
        away from the wall), ``vt_out`` (m/s), ``omega_out`` (rad/s): all 0 where captured or
        invalid.
        """
        radius, vn, vt, omega = np.broadcast_arrays(
            *(np.asarray(v, dtype=float) for v in (radius, vn, vt, omega))
        )
        with np.errstate(invalid="ignore"):
            valid = (radius > 0) & (vn > 0) & np.isfinite(radius + vn + vt + omega)
        radius, vn = np.where(valid, radius, self.radius[0]), np.where(valid, vn, 1.0)
        vt, omega = np.where(valid, vt, 0.0), np.where(valid, omega, 0.0)
        sign = np.where(vt < 0, -1.0, 1.0)
        vt_abs, om = np.abs(vt), omega * sign
        speed = np.hypot(vn, vt_abs)
        angle = np.degrees(np.arctan2(vt_abs, vn))
        clamped = np.zeros(radius.shape, bool)
        for lo, hi in self.unresolved_radii:  # the table misses its tolerance there
            clamped |= (radius >= lo) & (radius <= hi)
        # radius: log, angle and spin: linear
        ir, wr, c = _cell(np.log(self.radius), np.log(radius))
        clamped |= c
        ia, wa, c = _cell(self.angle_deg, angle)
        clamped |= c
        iw, ww, c = _cell(self.omega0, om)
        clamped |= c
        v_ref = self.reference_at((ir, ia, iw), (wr, wa, ww), angle)
        captured = (speed < v_ref) if self.speed_axis == "capture_ratio" else speed < 0
        x = speed / v_ref
        u_nodes = self.u_of(self.speed_ratio)
        u = self.u_of(x)
        ix, wx, c = _cell(u_nodes, u)
        clamped |= c & ~captured
        if self.aligned:  # the results' angle axis: the aligned coordinate at this theta*
            kinks = [_multilinear(k, (ir, iw, ix), (wr, ww, wx)) for k in self.kink_angles]
            ia, wa, _ = _cell(self.kink_u, kink_coordinate(angle, kinks, self.angle_deg[-1]))
        # above the row's valid top: captured where the rows stick again there, else the
        # row's last values (the speed range's top); flagged as clamped either way. Also
        # flagged: a query above the top of any row its cell interpolates from (those rows'
        # cells above their top repeat their last values, not the impact's).
        u_top = _multilinear(self.u_top, (ir, ia, iw), (wr, wa, ww))
        lowest_top = _corner_min(self.u_top, (ir, ia, iw), (wr, wa, ww))
        again = _multilinear(self.captured_above_top, (ir, ia, iw), (wr, wa, ww))
        slack = 1e-9 * max(1.0, float(u_nodes[-1] - u_nodes[0]))
        above = (u > u_top + slack) & ~captured
        clamped |= above | ((u > lowest_top + slack) & ~captured)
        captured |= above & (again >= 0.5)
        out = {}
        for name in OUTPUTS:
            out[name] = _multilinear(getattr(self, name), (ir, ia, iw, ix), (wr, wa, ww, wx))
        captured &= valid
        clamped &= valid
        dead = captured | ~valid
        vn_out = np.where(dead, 0.0, out["cor_n"] * vn)
        vt_out = np.where(dead, 0.0, out["vt_ratio"] * speed * sign)
        omega_out = np.where(dead, 0.0, out["spin_ratio"] * speed / radius * sign)
        code = captured.astype(int) | (clamped.astype(int) << 1) | ((~valid).astype(int) << 2)
        return code, vn_out, vt_out, omega_out


#: The kinks of the aligned layout, in the order of their angles: below ``rolls_at_exit`` the
#: sphere reaches rolling and still rolls when it leaves; between it and ``reaches_rolling``
#: (``theta*``) it reaches rolling and slides again before it leaves (fast impacts, where the
#: normal force falls faster than friction can hold the rolling); above, it slides through.
KINKS = ("rolls_at_exit", "reaches_rolling")
#: The first kink is used no lower than this (deg): where the sphere slides at every angle (no
#: friction, or spin) the coordinate stays defined.
KINK_MIN_DEG = 0.5


def kink_breaks(kinks, top) -> list:
    """The breakpoints ``[0, k_1, ..., k_K, top]`` (deg) of the aligned coordinate: the kink
    angles clipped to ``[KINK_MIN_DEG, top]`` and made nondecreasing."""
    out, lo = [np.zeros(np.shape(kinks[0]))], KINK_MIN_DEG
    for k in kinks:
        lo = np.clip(k, lo, top)
        out.append(lo)
    return out + [np.full(np.shape(kinks[0]), float(top))]


def kink_coordinate(theta, kinks, top):
    """The aligned angle coordinate (deg in, dimensionless out): piecewise linear, ``j + (theta
    - b_j) / (b_(j+1) - b_j)`` between the breakpoints ``b`` of :func:`kink_breaks`, so that
    kink ``j`` is the node ``u = j + 1`` at every (radius, spin, speed); ``kinks``: a sequence
    (``KINKS``' order) of arrays that broadcast with ``theta``. The generated C function
    computes the same."""
    theta = np.asarray(theta, dtype=float)
    b = kink_breaks(kinks, top)
    u = 0.0
    for lo, hi in zip(b[:-1], b[1:], strict=True):
        u = u + np.clip((theta - lo) / np.maximum(hi - lo, 1e-9), 0.0, 1.0)
    return u


def kink_angle(u, kinks, top):
    """The angle (deg) of the aligned coordinate ``u`` (the inverse of
    :func:`kink_coordinate`)."""
    b = kink_breaks(kinks, top)
    theta = 0.0
    for j, (lo, hi) in enumerate(zip(b[:-1], b[1:], strict=True)):
        theta = theta + np.clip(u - j, 0.0, 1.0) * (hi - lo)
    return theta


def _u(x, capture_ratio: bool):
    """The interpolation coordinate of the speed axis (module docstring)."""
    x = np.asarray(x, dtype=float)
    if capture_ratio:
        return np.arcsinh(np.sqrt(np.maximum(x - 1.0, 0.0)))
    return np.maximum(x, 0.0) ** 0.2


def _cell(nodes, q):
    """Lower node index, weight of the upper node and whether ``q`` was clamped."""
    nodes = np.asarray(nodes, dtype=float)
    q = np.asarray(q, dtype=float)
    if nodes.size == 1:
        scale = max(1.0, abs(float(nodes[0])))
        return np.zeros(q.shape, int), np.zeros(q.shape), np.abs(q - nodes[0]) > 1e-9 * scale
    # a query off an end by rounding only (e.g. an angle from atan2) is not clamped
    slack = 1e-9 * max(1.0, float(nodes[-1] - nodes[0]))
    lo_out, hi_out = q < nodes[0] - slack, q > nodes[-1] + slack
    qc = np.clip(q, nodes[0], nodes[-1])
    i = np.clip(np.searchsorted(nodes, qc, side="right") - 1, 0, nodes.size - 2)
    w = (qc - nodes[i]) / (nodes[i + 1] - nodes[i])
    return i, w, lo_out | hi_out


def _corners(table, idx, w):
    """``(weight, value)`` of each corner of the cell at ``idx`` (one index per axis) with
    weights ``w``, in the order the generated C code visits them."""
    table = np.asarray(table)
    d = len(idx)
    for corner in range(2**d):
        bits = [(corner >> k) & 1 for k in range(d)]
        ii = tuple(
            np.minimum(i + b, table.shape[k] - 1)
            for k, (i, b) in enumerate(zip(idx, bits, strict=True))
        )
        weight = 1.0
        for k, b in enumerate(bits):
            weight = weight * (w[k] if b else 1.0 - w[k])
        yield weight, table[ii]


def _multilinear(table, idx, w):
    """Multilinear interpolation in the cell at ``idx`` with weights ``w`` (corners summed in
    the generated C code's order, so the two agree bit for bit)."""
    out = 0.0
    for weight, value in _corners(table, idx, w):
        out = out + weight * value
    return out


def _corner_min(table, idx, w):
    """The smallest value of ``table`` over the corners of the cell at ``idx`` that carry
    weight in :func:`_multilinear` (as the generated C code)."""
    out = np.inf
    for weight, value in _corners(table, idx, w):
        out = np.where(weight > 0, np.minimum(out, value), out)
    return out


def scene_attributes(scene) -> dict:
    """The scene as flat attributes (``contact.f0`` -> value; switches as text)."""
    attrs = {}
    for section in ("particle", "contact", "model", "solver"):
        part = getattr(scene, section)
        for name in part.__dataclass_fields__:
            value = getattr(part, name)
            arr = np.asarray(value)
            key = f"{section}.{name.rstrip('_')}"
            if arr.dtype.kind in "fiu" and arr.ndim == 0:
                attrs[key] = float(arr) if arr.dtype.kind == "f" else int(arr)
            elif arr.dtype.kind == "b" and arr.ndim == 0:
                attrs[key] = str(bool(arr)).lower()
            elif isinstance(value, str) or value is None:
                attrs[key] = "" if value is None else value
            elif arr.ndim > 0:
                attrs[key] = np.asarray(arr, dtype=float).ravel().tolist().__repr__()
    return attrs


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
    ctx = _Context(simulate, scene, base, radius, omega, x, adhesive, say)
    report = {}
    if refine and adhesive and radius.size >= 2:
        radius, report = _radius_nodes(ctx, radius, angle, capture_tol, say)
        ctx.radius = radius
    if layout == "aligned":
        from ._aligned import ALIGNED_TOL, aligned_law

        ctx.lane_batch(angle.size * omega.size)
        tol = ALIGNED_TOL if refine_tol is None else refine_tol
        law, aligned = aligned_law(ctx, scene, radius, angle, omega, x, refine, tol, say)
        law.radius_report = {
            **report,
            **aligned,
            "layout": "aligned",
            "not_converged": ctx.not_converged,
            "refine_tol": tol if refine else None,
            "speed_tol": None,
            "new_cells": {},
        }
        return _finished(law, simulate, scene, draws, max_draws, say, ctx.impacts, start)
    refine_tol = REFINE_TOL if refine_tol is None else refine_tol
    rows = ctx.angles(angle, batch=None, stage="pass 1 (the grid's angles)")
    if refine and radius.size >= 3:
        rows, radius = _refined_radii(ctx, rows, radius, angle, refine_tol, say)
        ctx.radius = radius
    if refine and angle.size >= 3:
        rows, angle = _refined(ctx, rows, angle, refine_tol, say)
    if speed_tol is None:
        speed_tol = SPEED_TOL if radius.size == 1 else False
    if refine and speed_tol and x.size >= 3:
        rows = _refined_speeds(ctx, rows, radius, angle, speed_tol, say)
        x = ctx.x
    law = _assembled(scene, rows, radius, angle, omega, x, adhesive)
    law.radius_report = {
        **report,
        "not_converged": ctx.not_converged,
        "refine_tol": refine_tol,
        "speed_tol": float(speed_tol) if refine and speed_tol else None,
        "new_cells": ctx.new_cells,
    }
    if not refine:
        law.radius_report["refine_tol"] = None
    return _finished(law, simulate, scene, draws, max_draws, say, ctx.impacts, start)


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


def _top(ctx, rows, x, stick):
    """Each row's top (its last speed node before the first that is not a rebound) and
    whether it is captured again above it; the outputs above the top held at the top's, and
    the tangential results at the capture speed extrapolated (module docstring), in place.
    ``rows``: ``status`` and the outputs, ``(n, X)``."""
    status = rows["status"]
    n, X = status.shape
    first = 1 if ctx.adhesive else 0
    bad = np.zeros((n, X), bool)
    bad[:, first:] = status[:, first:] != 0
    first_bad = np.argmax(bad, axis=1)
    top = np.where(bad.any(axis=1), first_bad - 1, X - 1)
    top = np.where(stick, X - 1, np.maximum(top, 0))
    # captured again above the top (not only cut by the speed range): sticks there
    again = bad.any(axis=1) & ~stick & (status[np.arange(n), first_bad] == 1)
    for name in OUTPUTS:
        col = rows[name]
        held = np.take_along_axis(col, top[:, None], axis=1)
        col[:] = np.where(np.arange(X)[None, :] > top[:, None], held, col)
        col[stick] = np.nan  # filled from the nearest rebounding radius (_assembled)
    if ctx.adhesive:  # the node at the capture speed itself (module docstring)
        u = _u(x, True)
        t = (u[0] - u[1]) / (u[2] - u[1])
        for name in ("vt_ratio", "spin_ratio"):
            col = rows[name]
            col[:, 0] = col[:, 1] + t * (col[:, 2] - col[:, 1])
        rows["cor_n"][:, 0] = 0.0
    return x[top], again.astype(float)


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


class _Context:
    """Computes table rows (capture speed and outputs) for sets of angles, all radii and
    spins, in batches of one lane count."""

    def __init__(self, simulate, scene, base, radius, omega, x, adhesive, say):
        self.simulate, self.scene, self.base = simulate, scene, base
        self.radius, self.omega, self.x, self.adhesive, self.say = radius, omega, x, adhesive, say
        self.batch = None
        self.impacts = 0
        self.not_converged = 0  # capture speeds of table rows taken as the root find left them
        self.known = {}  # (radius, angle, spin) -> (capture speed, status) already found
        self.label = ""  # which pass and batch the progress lines are about
        self.new_cells = {}  # pass -> (new cells simulated, new cells)

    def params(self, r) -> dict:
        """The scene's parameters for lanes of radii ``r`` (one value per lane)."""
        params = {k: np.full(r.size, v) for k, v in self.base.items()}
        params["radius"] = r
        return params

    def _flat(self, radius, angle):
        R, A, W = radius.size, angle.size, self.omega.size
        r = np.broadcast_to(radius[:, None, None], (R, A, W)).reshape(-1)
        a = np.broadcast_to(angle[None, :, None], (R, A, W)).reshape(-1)
        w = np.broadcast_to(self.omega[None, None, :], (R, A, W)).reshape(-1)
        return r, a, w

    def angles(self, angle, batch=None, stage="", radius=None) -> dict:
        """Rows for ``angle`` (and ``radius``, default the context's): arrays ``(R, A, W[,
        X])`` flattened to ``(R, A*W[, X])``; ``stage``: named in the progress lines (with
        the batch, where there are several)."""
        radius = self.radius if radius is None else np.asarray(radius, dtype=float)
        R, A, W = radius.size, angle.size, self.omega.size
        r, a, w = self._flat(radius, angle)
        if self.batch is None and radius.size > 1:
            self.lane_batch(A * W)
        if self.batch is None:
            self.batch = batch or r.size
        rows = self.lanes(r, a, w, stage, batch)
        return {k: v.reshape((R, A * W) + v.shape[1:]) for k, v in rows.items()}

    def lanes(self, r, a, w, stage="", batch=None, guess=None) -> dict:
        """Rows of the lanes ``(r, a, w)`` (flat), in batches of one lane count (padded);
        ``guess``: their capture speeds as interpolated, to search near."""
        n = r.size
        batch = batch or self.batch or n
        parts = []
        batches = -(-n // batch)
        for lo in range(0, n, batch):
            part = f", batch {lo // batch + 1} of {batches}" if batches > 1 else ""
            self.label = f"{stage}{part}: " if stage else ""
            idx = np.arange(lo, min(lo + batch, n))
            pad = np.concatenate([idx, np.full(batch - idx.size, idx[-1])])
            near = None if guess is None else guess[pad]
            out = self._lanes(r[pad], a[pad], w[pad], near)
            parts.append({k: v[: idx.size] for k, v in out.items()})
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}

    def lane_batch(self, lanes_per_radius: int) -> int:
        """The lane count of every batch (one compiled program): whole radii of the first
        pass's angles and spins (:data:`RADII_PER_BATCH`, :data:`MIN_BATCH_LANES`), set on
        first use."""
        if self.batch is None:
            radii = max(RADII_PER_BATCH, -(-MIN_BATCH_LANES // lanes_per_radius))
            self.batch = radii * lanes_per_radius
        return self.batch

    def impacts_at(self, r, a, w, speed, stage="", rolled=False) -> dict:
        """Impacts of lanes ``(r, a, w)`` at ``speed`` (flat; no capture search), in batches of
        the passes' lane count (one compiled program): ``status`` (:data:`NOT_SIMULATED` above
        the speed range) and the outputs; with ``rolled``, also whether the sphere reached
        rolling before it left (``roll_time`` finite)."""
        n = r.size
        batch = self.batch or n
        status = np.full(n, NOT_SIMULATED)
        out = {k: np.full(n, np.nan) for k in OUTPUTS}
        if rolled:
            out["rolled"] = np.zeros(n, bool)
        run = speed <= SPEED_MAX
        idx_all = np.flatnonzero(run)
        batches = -(-idx_all.size // batch)
        every = -(-batches // 10)  # about ten progress lines, however many batches
        for b, lo in enumerate(range(0, idx_all.size, batch)):
            idx = idx_all[lo : lo + batch]
            pad = np.concatenate([idx, np.full(batch - idx.size, idx[-1])])
            if stage and (b % every == 0 or b == batches - 1):
                self.say(f"{stage}, batch {b + 1} of {batches}: {idx.size} impacts")
            res = self.simulate(
                scene_with(self.scene, self.params(r[pad])), speed[pad], a[pad], w[pad]
            )
            got = _table_outputs(res, r[pad], speed[pad])
            if rolled:
                got["rolled"] = np.isfinite(np.asarray(res.roll_time))
            m = idx.size
            status[idx] = got.pop("status")[:m]
            for name, v in got.items():
                out[name][idx] = v[:m]
            self.impacts += m
        _check_grid(status >= 2, speed, a, w, r)
        return {"status": status, **out}

    def capture_speeds(self, radius, angle, unsure_as_nan=False) -> np.ndarray:
        """Capture speeds ``(R, A, W)`` (``inf`` where the sphere sticks at every speed) in
        batches of one lane count (one compiled program for every call); with
        ``unsure_as_nan``, NaN where the root find did not converge (else an error)."""
        r, a, w = self._flat(radius, angle)
        n = r.size
        batch = self.lane_batch(angle.size * self.omega.size)
        out = []
        for lo in range(0, n, batch):
            idx = np.arange(lo, min(lo + batch, n))
            pad = np.concatenate([idx, np.full(batch - idx.size, idx[-1])])
            out.append(self._capture(r[pad], a[pad], w[pad], unsure_as_nan)[0][: idx.size])
        return np.concatenate(out).reshape(radius.size, angle.size, self.omega.size)

    def _capture(self, r, a, w, unsure_as_nan=False, guess=None):
        """Capture speeds and statuses of lanes (``inf`` where all captured; where the root
        find did not converge, its best estimate, counted in ``not_converged``, or NaN with
        ``unsure_as_nan``); ``guess``: interpolated capture speeds to search near."""
        n = r.size
        keys = list(zip(r.tolist(), a.tolist(), w.tolist(), strict=True))
        if all(k in self.known for k in keys):  # found by the radius pass already
            v_c = np.array([self.known[k][0] for k in keys])
            c_status = np.array([self.known[k][1] for k in keys])
        else:
            if guess is not None and np.isfinite(guess).any():
                v_c, c_status = self._capture_near(r, a, w, guess)
            else:
                v_c, c_status = self._capture_scan(r, a, w)
            found = zip(v_c.tolist(), c_status.tolist(), strict=True)
            self.known.update(zip(keys, found, strict=True))
        ok = (CaptureStatus.THRESHOLD, CaptureStatus.MULTIPLE, CaptureStatus.ALL_CAPTURED)
        unsure = c_status == CaptureStatus.NOT_CONVERGED
        bad = ~np.isin(c_status, ok) & ~unsure
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise WallLawError(
                f"{int(bad.sum())} of {n} capture speeds could not be found, e.g. radius "
                f"{r[i]:g} m, angle {a[i]:g} deg, spin {w[i]:g} rad/s: "
                f"{CaptureStatus.NAMES[int(c_status[i])]}"
            )
        v_c = np.where(c_status == CaptureStatus.ALL_CAPTURED, np.inf, v_c)
        if unsure_as_nan:
            return np.where(unsure, np.nan, v_c), c_status
        self.not_converged += int(unsure.sum())
        return v_c, c_status

    def _capture_scan(self, r, a, w):
        """:func:`capture_speed` of the lanes: its scan over six decades and root find."""
        n = r.size
        params = self.params(r)
        names = tuple(params)
        # the table's own program (throughput), whatever the batch: the capture node and the
        # rows above it from one program, and no second one to compile
        found = _search(
            self.scene, names, tuple(params[k] for k in names), a, w, True, RTOL, None,
            program="throughput",
        )  # fmt: skip
        self.impacts += found["evaluations"] * n
        return np.asarray(found["speed"], dtype=float), np.asarray(found["status"])

    def _capture_near(self, r, a, w, guess):
        """Capture speeds of lanes between nodes of one threshold, from the interpolated
        ``guess``: the root find of :func:`capture_speed` on a scan of :data:`NEAR_SCAN`
        times the guess (4 speeds instead of 19). A lane whose threshold is not inside
        that bracket (or that has no guess: NaN) gets the full search, in a batch of the
        same lane count. Searching near the guess does not look for thresholds far from it:
        the status is that of the bracket (the neighbours had one threshold each)."""
        from .._engine.api import simulate

        n = r.size
        params = self.params(r)
        known = np.isfinite(guess) & (guess > 0)
        near = np.minimum(np.where(known, guess, 1.0)[:, None] * NEAR_SCAN[None, :], SPEED_MAX)
        res = _root(simulate, self.scene, params, a, w, RTOL, None, grid=near)
        self.impacts += res["evaluations"] * n
        v_c, c_status = res["speed"], res["status"]
        miss = np.flatnonzero(~known | (c_status != CaptureStatus.THRESHOLD))
        if miss.size:
            pad = np.concatenate([miss, np.full(n - miss.size, miss[-1])])
            v_far, st_far = self._capture_scan(r[pad], a[pad], w[pad])
            v_c[miss], c_status[miss] = v_far[: miss.size], st_far[: miss.size]
        return v_c, c_status

    def _lanes(self, r, a, w, guess=None) -> dict:
        n, x = r.size, self.x
        X = x.size
        params = self.params(r)
        lane_scene = scene_with(self.scene, params)
        if self.adhesive:
            self.say(f"{self.label}capture speeds of {n} (radius, angle, spin) lanes")
            v_c, c_status = self._capture(r, a, w, guess=guess)
            v_ref = v_c
        else:
            v_c = np.zeros(n)
            c_status = np.full(n, CaptureStatus.NO_ADHESION)
            v_ref = np.ones(n)
        stick = ~np.isfinite(v_ref)
        speed = v_ref[:, None] * x[None, :]
        # Cells not simulated: stick rows and speeds above the speed range. They are run at
        # a harmless speed (the batch keeps its shape: one compiled program) and discarded.
        skip = stick[:, None] | ~(speed <= SPEED_MAX)
        first = 1 if self.adhesive else 0
        harmless = np.where(stick, 1.0, v_ref * x[min(first, X - 1)])
        run_speed = np.where(skip, harmless[:, None], speed)
        status = np.zeros((n, X), int)
        out = {k: np.full((n, X), np.nan) for k in OUTPUTS}
        self.say(f"{self.label}{n * X} impacts ({n} lanes x {X} speeds)")
        for k in range(first, X):  # one batch shape: one compiled program with the capture's
            s = run_speed[:, k]
            got = _table_outputs(self.simulate(lane_scene, s, a, w), r, s)
            status[:, k] = got.pop("status")
            for name, v in got.items():
                out[name][:, k] = v
            self.impacts += n
        status = np.where(skip, NOT_SIMULATED, status)
        _check_grid((status >= 2) & ~skip, speed, a, w, r)
        # The row's top: its last node before the first that is not a rebound (captured
        # again, or above the speed range); the nodes above it repeat the top's results.
        top, again = _top(self, {"status": status, **out}, x, stick)
        return {
            "v_c": v_c,
            "c_status": c_status,
            "v_ref": v_ref,
            "speed": speed,
            "status": status,
            "top": top,
            "again": again,
            **out,
        }


def _table_outputs(res, r, speed) -> dict:
    """A simulated batch's ``status`` and tabulated results (module docstring) as numpy
    arrays: ``cor_n``, ``vt_ratio = vt_out / speed``, ``spin_ratio = omega_out r / speed``."""
    return {
        "status": np.asarray(res.status),
        "cor_n": np.asarray(res.cor_n),
        "vt_ratio": np.asarray(res.vt_out) / speed,
        "spin_ratio": np.asarray(res.omega_out) * r / speed,
    }


def _check_grid(failed, speed, a, w, r) -> None:
    """Raise :class:`WallLawError` naming an impact where ``failed`` (lanes first, then
    speeds, if 2-D)."""
    if failed.any():
        first = tuple(int(j[0]) for j in np.nonzero(failed))
        i = first[0]
        raise WallLawError(
            f"{int(failed.sum())} impacts of the grid failed, e.g. speed "
            f"{speed[first]:.6g} m/s, angle {a[i]:g} deg, spin {w[i]:g} rad/s, radius "
            f"{r[i]:g} m"
        )


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


def capture_coordinate(v_c, angle):
    """``g = (v_c cos(angle))^(-1/4)`` of capture speeds ``v_c (..., A, W)`` at the angles
    ``angle (A,)`` (deg), 0 where ``v_c`` is infinite (module docstring)."""
    normal = v_c * np.cos(np.radians(angle))[:, None]
    with np.errstate(divide="ignore"):
        return np.where(np.isfinite(normal), normal ** (-0.25), 0.0)


def capture_from_coordinate(g, angle):
    """The capture speed of an interpolated ``g`` at ``angle`` (deg): ``g^-4 / cos(angle)``,
    ``inf`` where ``g`` is 0 (captured at every speed)."""
    g2 = g * g
    with np.errstate(divide="ignore"):
        normal = np.where(g > 0, 1.0 / np.where(g > 0, g2 * g2, 1.0), np.inf)
    return normal / np.cos(np.radians(angle))


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


def _uncertainty(simulate, scene, law, draws, max_draws, say) -> dict:
    """Capture probability and spread of ``cor_n`` per cell over posterior draws, each draw
    simulated at the table's speeds (those of the scene's own values)."""
    names = [k for k in draws if k in PARAMETERS or k in ("G_star", "w")]
    if not names:
        raise SceneError("draws: no scene parameter among " + ", ".join(map(str, draws)))
    columns = [np.asarray(draws[k], dtype=float).ravel() for k in names]
    size = columns[0].size
    if size == 0 or any(c.size != size for c in columns):
        raise SceneError("draws: every parameter needs the same number (> 0) of draws")
    if not all(np.all(np.isfinite(c)) for c in columns):
        raise SceneError("draws: values must be finite")
    if not (isinstance(max_draws, int) and max_draws >= 1):
        raise SceneError(f"max_draws must be an integer >= 1, got {max_draws!r}")
    pick = np.linspace(0, size - 1, min(max_draws, size)).round().astype(int)
    R, A, W, X = law.shape
    n = R * A * W
    r = np.broadcast_to(law.radius[:, None, None], (R, A, W)).reshape(-1)
    ang = law.cell_angle_deg.reshape(n, X)  # (the aligned layout's differ along the speed)
    om = np.broadcast_to(law.omega0[None, None, :], (R, A, W)).reshape(-1)
    base = {k: float(v) for k, v in scene_parameters(scene).items()}
    speed = law.speed.reshape(n, X)
    # cells not simulated for the table (stick rows, above the speed range): not for the
    # draws either (run at a harmless speed, left NaN)
    skip = law.status.reshape(n, X) == NOT_SIMULATED
    speed = np.where(skip, 1.0, speed)
    captured = np.zeros((pick.size, n, X), bool)
    cor_n = np.full((pick.size, n, X), np.nan)
    # every simulated cell of a draw in one batch (a call per speed column ran 574-lane
    # batches: 22 s per draw of the one-radius table, against about 4 s)
    cell = np.flatnonzero(~skip.ravel())
    row, column = np.divmod(cell, X)
    say(f"{pick.size} posterior draws x {cell.size} impacts")
    for d, j in enumerate(pick):
        p = {k: np.full(cell.size, v) for k, v in base.items()}
        p["radius"] = r[row]
        for k, c in zip(names, columns, strict=True):
            p[k] = np.full(cell.size, c[j])
        res = simulate(scene_with(scene, p), speed[row, column], ang[row, column], om[row])
        st = np.asarray(res.status)
        failed = st >= 2
        if np.any(failed):
            raise WallLawError(f"draw {int(j)}: {int(np.sum(failed))} impacts failed")
        captured[d, row, column] = st == 1
        cor_n[d, row, column] = np.where(st == 0, np.asarray(res.cor_n), np.nan)
    shape4 = law.shape
    with np.errstate(invalid="ignore"), _quiet():
        stats = {
            "capture_probability": np.where(skip, np.nan, captured.mean(axis=0)),
            "cor_n_mean": np.nanmean(cor_n, axis=0),
            "cor_n_sd": np.nanstd(cor_n, axis=0),
            "cor_n_q05": np.nanquantile(cor_n, 0.05, axis=0),
            "cor_n_q95": np.nanquantile(cor_n, 0.95, axis=0),
        }
    out = {k: v.reshape(shape4) for k, v in stats.items()}
    out["draws"] = int(pick.size)
    out["parameters"] = names
    return out


class _quiet:
    """Silence numpy's all-NaN slice warnings (cells captured at every draw)."""

    def __enter__(self):
        import warnings

        self._w = warnings.catch_warnings()
        self._w.__enter__()
        warnings.simplefilter("ignore", RuntimeWarning)

    def __exit__(self, *exc):
        return self._w.__exit__(*exc)

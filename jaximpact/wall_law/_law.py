"""The tabulated wall law (:class:`WallLaw`) and its interpolation, the arithmetic the
generated C function repeats: the cell and weights of a query on each axis, multilinear
interpolation in the C code's corner order, the capture-speed coordinate ``g = (v_c
cos)^(-1/4)`` and the kink-aligned angle coordinate (axes and coordinates: the docstring of
:mod:`._table`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

OUTPUTS = ("cor_n", "vt_ratio", "spin_ratio")
#: Status of a cell that was not simulated (a stick row, or a speed above SPEED_MAX).
NOT_SIMULATED = -1


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

"""The rows of a wall-law table: for (radius, angle, spin) lanes, the capture speed and the
results at every speed node (:class:`_Context`), simulated in batches of one lane count (one
compiled program), and each row's top (:func:`_top`)."""

from __future__ import annotations

import numpy as np

from ._capture import RTOL, CaptureStatus, _root, _search, scene_with
from ._law import NOT_SIMULATED, OUTPUTS, WallLawError, _u

SPEED_MAX = 1000.0  # m/s (docs/input_ranges.md)


#: Several radii: each batch holds whole radii's worth of lanes of the first pass, at least
#: RADII_PER_BATCH radii and MIN_BATCH_LANES lanes (a batch of a few hundred lanes spends
#: most of its time in the calls' overhead: 18 angles x 8 radii ran 2,900 impacts/s).
RADII_PER_BATCH = 8
MIN_BATCH_LANES = 2048
#: A new node between two nodes of one capture threshold: its capture speed is searched from
#: the interpolated one, scanning these multiples of it (a bracket of 2 %) instead of six
#: decades (:func:`_Context._capture_near`).
NEAR_SCAN = np.array([0.98, 0.998, 1.002, 1.02])


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

"""The switched rigid-friction model: right-hand side, kink and mode-switch event functions,
and the rolling/sliding decision (exact Coulomb friction)."""

from __future__ import annotations

import math

import numpy as np

from ._forces import contact_forces, normal_potential
from ._params import Params

# Tangential modes: +1 / -1 sliding with that slip sign, 0 pure rolling (or sticking without
# rotation), 2 frictionless (f == 0: F_t = 0 and no tangential switches at all).
_ROLL, _FREE = 0, 2


class _Model:
    """The switched right-hand side, event functions and mode logic.

    Internal SI state: ``[n, ndot, s, w, loss_HD, loss_AD, loss_F, loss_R]``.  The slip ``s`` is
    integrated itself (``tdot = s + r w``): in pure rolling its rate is exactly zero, and while
    sliding its sign is resolved far below the size of ``tdot`` (no cancellation in
    ``tdot - r w``), which the switching logic relies on.
    """

    def __init__(self, p: Params, vt0: float = 0.0, w0: float = 0.0):
        self.p = p
        self.m = p.reduced_mass  # the relative motion's (the sphere's own on the wall)
        self.r = p.radius
        self.k2 = p.k2 if p.rotation else 0.0
        self.f = p.friction
        # A second sphere (p.target, with rotation): its spin follows from the pair's angular
        # momentum, I1 (w - w0) + I2 (w2 - w20) + (r + r2) m* (vt - vt0) = 0 (no extra state).
        self.pair = p.target and p.rotation
        if self.pair:
            self.I1, self.r2 = p.mass * p.k2, p.radius2
            self.I2 = p.mass2 * p.kappa * p.radius2**2
            self.start = (vt0, w0, p.omega2)
            # s' = F_t / m_slip - M * lever in rolling: 1/m_slip = 1/m* + r^2/I1 + r2^2/I2
            self.inv_m_slip = 1.0 / self.m + self.r**2 / self.I1 + self.r2**2 / self.I2
            self.lever = self.r / self.I1 - self.r2 / self.I2

    def slip(self, y) -> float:
        return y[2]

    def spin2(self, y) -> float:
        """The second sphere's spin (0 on the wall)."""
        return self.spin2_from(self.tdot(y), y[3]) if self.pair else 0.0

    def spin2_from(self, vt, w) -> float:
        """The second sphere's spin at relative tangential velocity ``vt`` and particle spin
        ``w``, from the pair's angular momentum (a pair only)."""
        vt0, w0, w20 = self.start
        return w20 - ((self.r + self.r2) * self.m * (vt - vt0) + self.I1 * (w - w0)) / self.I2

    def ring_spin(self, y) -> float:
        """The spin the ring and the rolling moments see: relative to the second sphere."""
        return y[3] - self.spin2(y) if self.pair else y[3]

    def forces(self, y) -> dict:
        return contact_forces(self.p, y[0], y[1], self.ring_spin(y))

    def tdot(self, y) -> float:
        if not self.pair:
            return y[2] + self.r * y[3] if self.p.rotation else y[2]
        # vt = s + r w + r2 w2(vt, w), solved for vt (w2 is linear in vt)
        vt0, w0, w20 = self.start
        a = (self.r + self.r2) * self.m / self.I2
        b = self.I1 / self.I2
        top = y[2] + self.r * y[3] + self.r2 * (w20 + a * vt0 - b * (y[3] - w0))
        return top / (1.0 + self.r2 * a)

    def required_force(self, M: float) -> float:
        """Friction that keeps s' = 0 (pure rolling)."""
        if self.pair:
            return M * self.lever / self.inv_m_slip
        return self.r * M / (self.k2 + self.r**2) if self.p.rotation else 0.0

    def friction_force(self, mode: int, fc: dict) -> float:
        if mode in (1, -1):
            return -self.f * fc["N"] * mode
        if mode == _ROLL:
            return self.required_force(fc["M"])
        return 0.0

    def rhs(self, y, mode: int) -> list:
        ndot, w = y[1], y[3]
        fc = self.forces(y)
        F_t = self.friction_force(mode, fc)
        M = fc["M"]
        s = y[2]
        if self.pair:
            wdot = (-self.r * F_t + M) / self.I1
            sdot = 0.0 if mode == _ROLL else F_t * self.inv_m_slip - M * self.lever
            w = self.ring_spin(y)  # the rolling moment's power
        elif self.p.rotation:
            wdot = (-self.r * F_t + M) / (self.m * self.k2)
            # s' = tddot - r wdot, written so that it is exactly zero in pure rolling
            sdot = (
                0.0
                if mode == _ROLL
                else (F_t * (self.k2 + self.r**2) - self.r * M) / (self.m * self.k2)
            )
        else:
            wdot = 0.0
            sdot = F_t / self.m
        return [
            ndot,
            fc["F_n"] / self.m,
            sdot,
            wdot,
            -fc["F_HD"] * ndot,
            -fc["F_AD"] * ndot,
            -F_t * s,
            -M * w,
        ]

    def normal_energy(self, y) -> float:
        return 0.5 * self.m * y[1] ** 2 + normal_potential(self.p, y[0])

    def capture_energy(self, y) -> float:
        """Negative once the sphere can no longer leave: the normal energy below the barrier
        at the separation (0, or JKR's snap-off potential)."""
        return self.normal_energy(y) - self.p.jkr_barrier

    def mechanical_energy(self, y) -> float:
        return self.normal_energy(y) + self.tangential_energy(y)

    def tangential_energy(self, y) -> float:
        """Kinetic energy of the tangential motion and the spins."""
        if self.pair:
            return 0.5 * (
                self.m * self.tdot(y) ** 2 + self.I1 * y[3] ** 2 + self.I2 * self.spin2(y) ** 2
            )
        return 0.5 * self.m * (self.tdot(y) ** 2 + self.k2 * y[3] ** 2)

    def decide(self, y, h_look: float = 0.0) -> int:
        """Mode at zero slip: roll if friction can hold it, else slide against the imbalance.

        The test is also made a look-ahead time ``h_look`` later along the rolling motion: where
        the load passes through zero (``F_n = 0`` with the net load) the cone closes for an
        instant only, and sliding there would last no time at all. Deciding "slide" at that
        instant made the sliding segment end at once and the run stall at the switch (seen for
        slips of 1e-6 of the speed near normal incidence).
        """
        if self.f == 0:
            return _FREE
        if not self.p.rotation:
            return _ROLL

        def holds(z):
            fc = self.forces(z)
            return abs(self.required_force(fc["M"])) <= self.f * fc["N"], fc

        ok, fc = holds(y)
        if ok or (h_look > 0 and holds(y + h_look * np.array(self.rhs(y, _ROLL)))[0]):
            return _ROLL
        return -1 if self.required_force(fc["M"]) > 0 else 1

    def project_to_rolling(self, y) -> np.ndarray:
        """Remove the round-off slip left at a switch by a tiny tangential impulse.

        The kinetic energy it changes (~1e-16 relative) is booked as friction loss, so that the
        ledger stays exact.
        """
        y = np.array(y, dtype=float)
        ke0 = self.tangential_energy(y)
        if self.pair:
            J = -y[2] / self.inv_m_slip  # the impulse that takes s to zero
            y[3] -= self.r * J / self.I1
        elif self.p.rotation:
            dv = -y[2] / (1.0 + self.r**2 / self.k2)  # impulse / m; s changes by -s
            y[3] -= self.r * dv / self.k2
        y[2] = 0.0
        y[6] -= self.tangential_energy(y) - ke0
        return y

    def kink_functions(self, spin=None, normal_force=None) -> list:
        """Functions whose zeros are kinks of the right-hand side (not mode switches);
        ``spin`` and ``normal_force`` (functions of the state) for another model's state."""
        p = self.p
        spin = spin or self.ring_spin
        out = []
        if p.ring and p.f0 * p.C_A > 0:
            if p.rolling_moments == "analytical":
                r = p.reduced_radius
                out.append(lambda y: y[1] - spin(y) * math.sqrt(r * max(y[0], 0.0)))
                out.append(lambda y: y[1] + spin(y) * math.sqrt(r * max(y[0], 0.0)))
            else:
                out.append(lambda y: y[1])
        if self.f > 0 and p.friction_load == "net":
            out.append(normal_force or self.normal_force)
        return out

    def normal_force(self, y) -> float:
        return self.forces(y)["F_n"]

    def mode_functions(self, mode: int, sign_fn: float) -> list:
        """(function, next mode or None to decide) pairs whose downward zero ends the mode.

        ``sign_fn`` is the sign of F_n over the segment (a restart happens where it changes).  The
        rolling limits use ``sign_fn * F_n`` instead of ``|F_n|``: equal within the segment, but
        smooth, so that a dip of ``f |F_n| - |F_req|`` below zero just before ``F_n = 0`` shows
        as a sign change over the step that crosses the kink.
        """
        if mode in (1, -1):
            return [(lambda y: mode * self.slip(y), None)]
        p = self.p
        moments = p.rolling_moments == "analytical" or (
            p.rolling_moments == "lambda" and p.lam * p.C_A > 0
        )
        if mode == _ROLL and p.rotation and moments:

            def load_and_req(y):
                fc = self.forces(y)
                load = sign_fn * fc["F_n"] if p.friction_load == "net" else fc["N"]
                return self.f * load, self.required_force(fc["M"])

            def upper(y):  # F_req rising through +f N: friction saturates at +f N, slip < 0
                fn, req = load_and_req(y)
                return fn - req

            def lower(y):
                fn, req = load_and_req(y)
                return fn + req

            return [(upper, -1), (lower, 1)]
        return []

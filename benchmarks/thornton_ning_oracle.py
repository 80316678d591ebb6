# ruff: noqa: E501, B023  (a standalone research oracle: long report lines, closures used at once)
"""Standalone numerical reconstruction of the Thornton & Ning (1998) adhesive
elastic-plastic normal impact (sphere on a rigid flat wall: R* = R, m* = m).

numpy/scipy only.  Written from the equations collected in docs/thornton_ning.md
(no third-party code copied).  Conventions:

  w      work of adhesion (Dupre), J/m^2.  TN's Gamma is this w: their pull-off
         force is P_c = 1.5 pi Gamma R* (eq 50), i.e. JKR with w.
  E      E* (contact modulus), R = R*, m = m*.
  delta  overlap (approach) alpha, positive in compression.  P > 0 repulsive.

Laws
  (a) elastic JKR: P(a) = 4 E a^3/(3R) - sqrt(8 pi w E a^3),
      delta(a) = a^2/R - sqrt(2 pi w a / E).  Snap-in at delta = 0
      (a0^3 = 2 pi w R^2/E, P = -8/9 P_c); snap-off at the end of the stable
      branch, d delta/da = 0, a_c^3 = pi w R^2/(8E), P = -5/9 P_c.
  (b) TN elastic-plastic adhesive.  Yield when the JKR centre pressure
      p0(a) = 2 E a/(pi R) - sqrt(2 w E/(pi a)) reaches p_y  (TN eq 65) -> a_y.
      Plastic loading, reading "A" (closed form; PyGran's ThorntonNing and the
      exact integral of LIGGGHTS' plastic stiffness when P1 = 4 E a^3/(3R)):
          P(a) = 4 E a_y^3/(3R) + pi p_y (a^2 - a_y^2) - a_y sqrt(8 pi w E a),
          delta(a) = JKR geometry with R   (a^2/R - sqrt(2 pi w a/E)).
      Reading "B" (LIGGGHTS-PUBLIC normal_model_thornton_ning.h, incremental):
          dP/d delta = (3 pi R p_y sqrt(P1) - 2 a_y E sqrt(P_c)) / (3 sqrt(P1) - sqrt(P_c)),
          P1 = P + 2 P_c + 2 sqrt(P_c (P + P_c))   (TN eq 60 applied to the current P).
      Unloading: JKR with R_p from continuity at the maximum,
          4 E a_m^3/(3 R_p) - sqrt(8 pi w E a_m^3) = P_max,
      delta shifted so that the curve passes through (delta_max, P_max);
      pull-off 1.5 pi w R_p (TN eq 77); separation at the stable-branch end
      a_c(R_p)^3 = pi w R_p^2/(8E).
  (c) w = 0 reduces (b) to Thornton (1997): Hertz to a_y = pi p_y R/(2E), then
      P = P_y + pi p_y R (delta - delta_y), unloading Hertz with
      R_p = 4 E a*^3/(3 P*), a*^2 = R delta*.

Restitution from exact energy balance along the branches (the force is a
single-valued function of delta on each branch, so this equals a time
integration); `ode_check` integrates m x'' = -P(x) with solve_ivp as a check.
Run:  python oracle.py

Duration: seconds (numpy and scipy only).
"""

import warnings

import numpy as np
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq

PI = np.pi


class Contact:
    def __init__(self, R, E, m, w, py=np.inf, reading="A"):
        self.R, self.E, self.m, self.w, self.py = R, E, m, w, py
        self.reading = reading
        self.Pc = 1.5 * PI * w * R
        self.a0 = (2 * PI * w * R**2 / E) ** (1 / 3)
        self.ay = self._yield_radius() if np.isfinite(py) else np.inf

    # ---- JKR curve with curvature radius Rc ---------------------------------
    def P_jkr(self, a, Rc):
        return 4 * self.E * a**3 / (3 * Rc) - np.sqrt(8 * PI * self.w * self.E * a**3)

    def d_jkr(self, a, Rc):
        return a**2 / Rc - np.sqrt(2 * PI * self.w * a / self.E)

    def dd_jkr(self, a, Rc):
        return 2 * a / Rc - 0.5 * np.sqrt(2 * PI * self.w / (self.E * a))

    def ac(self, Rc):
        return (PI * self.w * Rc**2 / (8 * self.E)) ** (1 / 3)

    # ---- yield ---------------------------------------------------------------
    def p0(self, a):
        return 2 * self.E * a / (PI * self.R) - np.sqrt(2 * self.w * self.E / (PI * a))

    def _yield_radius(self):
        hi = self.R
        while self.p0(hi) < self.py:
            hi *= 2
        return brentq(lambda a: self.p0(a) - self.py, 1e-30 * self.R, hi, xtol=1e-30, rtol=1e-15)

    # ---- loading curve (reading A) ---------------------------------------------
    def P_load(self, a):
        if a <= self.ay:
            return self.P_jkr(a, self.R)
        E, w, ay = self.E, self.w, self.ay
        return (
            4 * E * ay**3 / (3 * self.R)
            + PI * self.py * (a**2 - ay**2)
            - ay * np.sqrt(8 * PI * w * E * a)
        )

    def W_load(self, amax):
        """work done against the contact from snap-in (delta=0) to a = amax"""
        f = lambda a: self.P_load(a) * self.dd_jkr(a, self.R)
        pts = [p for p in (self.ay,) if self.a0 < p < amax]
        return quad(f, self.a0, amax, points=pts or None, limit=200, epsabs=0, epsrel=1e-12)[0]

    # ---- one impact, reading A ---------------------------------------------------
    def impact_A(self, V):
        K = 0.5 * self.m * V**2
        lo = self.a0
        hi = max(2 * self.a0, 1e-3 * self.R)
        while self.W_load(hi) < K:
            hi *= 2
        am = brentq(lambda a: self.W_load(a) - K, lo, hi, xtol=1e-30, rtol=1e-14)
        Pm = self.P_load(am)
        return self._unload(am, Pm, K)

    def _unload(self, am, Pm, K):
        w, E = self.w, self.E
        Rp = 4 * E * am**3 / (3 * (Pm + np.sqrt(8 * PI * w * E * am**3)))
        if am <= self.ay:
            Rp = self.R  # never yielded: elastic JKR unloading
        acp = self.ac(Rp)
        Wret = quad(
            lambda a: self.P_jkr(a, Rp) * self.dd_jkr(a, Rp),
            acp,
            am,
            limit=200,
            epsabs=0,
            epsrel=1e-12,
        )[0]
        e2 = Wret / K
        return dict(e=np.sqrt(e2) if e2 > 0 else 0.0, e2=e2, amax=am, Pmax=Pm, Rp=Rp)

    # ---- one impact, reading B (LIGGGHTS incremental plastic stiffness) -----------
    def impact_B(self, V):
        K = 0.5 * self.m * V**2
        R, E, Pc, ay, py = self.R, self.E, self.Pc, self.ay, self.py
        Wy = self.W_load(ay)
        if K <= Wy:  # no yield: identical to A
            return self.impact_A(V)
        dy = self.d_jkr(ay, R)
        Py = self.P_jkr(ay, R)

        def P1of(P):
            return P + 2 * Pc + 2 * np.sqrt(Pc * max(P + Pc, 0.0))

        def rhs(d, y):
            P = y[0]
            s1, sc = np.sqrt(P1of(P)), np.sqrt(Pc)
            k = (3 * PI * R * py * s1 - 2 * ay * E * sc) / (3 * s1 - sc)
            return [k, P]  # dP/dd, dW/dd

        ev = lambda d, y: y[1] - (K - Wy)
        ev.terminal = True
        span = dy + 10 * (K / (PI * R * py)) ** 0.5 + 10 * R
        sol = solve_ivp(
            rhs,
            (dy, span),
            [Py, 0.0],
            events=ev,
            rtol=1e-11,
            atol=1e-30,
            max_step=(span - dy) / 2000,
        )
        Pm = sol.y_events[0][0][0]
        P1m = P1of(Pm)
        am = (3 * R * P1m / (4 * E)) ** (1 / 3)  # LIGGGHTS: radius from JKR inversion of P_max
        return self._unload(am, Pm, K)

    def impact(self, V):
        return self.impact_A(V) if self.reading == "A" else self.impact_B(V)

    # ---- derived velocities -----------------------------------------------------------
    def V_yield(self):
        Wy = self.W_load(self.ay) if self.ay > self.a0 else -np.inf
        return np.sqrt(2 * Wy / self.m) if Wy > 0 else 0.0

    def V_stick(self, Vlo, Vhi, n=200):
        """bisection on e2(V) = 0 between a sticking Vlo and a rebounding Vhi"""
        f = lambda V: self.impact(V)["e2"]
        assert f(Vlo) <= 0 < f(Vhi), (f(Vlo), f(Vhi))
        for _ in range(n):
            mid = 0.5 * (Vlo + Vhi)
            if f(mid) > 0:
                Vhi = mid
            else:
                Vlo = mid
            if Vhi - Vlo < 1e-13 * Vhi:
                break
        return 0.5 * (Vlo + Vhi)


def e_thornton1997(r):
    """Thornton (1997) / TN eq 44, r = V_y / V_i (valid for r <= 1)."""
    return (
        np.sqrt(6 * np.sqrt(3) / 5)
        * np.sqrt(1 - r**2 / 6)
        * (r / (r + 2 * np.sqrt(6 / 5 - r**2 / 5))) ** 0.25
    )


# ---- a direct time integration (check of the energy bookkeeping) ---------------
def ode_check(c, V):
    """integrate m x'' = -P for reading A; returns e = v_out / V."""
    R = c.R

    def a_of_d_load(d):
        f = lambda a: c.d_jkr(a, R) - d
        hi = max(2 * c.a0, np.sqrt(R * max(d, 0)) * 2 + c.a0)
        while f(hi) < 0:
            hi *= 2
        return brentq(f, c.ac(R), hi, xtol=1e-30, rtol=1e-14)

    def rhs_load(t, y):
        return [y[1], -c.P_load(a_of_d_load(y[0])) / c.m]

    turn = lambda t, y: y[1]
    turn.terminal, turn.direction = True, -1
    scale_t = 50 * (c.m / (c.E * np.sqrt(R))) ** 0.4 * max(V, 1e-9) ** -0.2
    s1 = solve_ivp(
        rhs_load,
        (0, scale_t),
        [0.0, V],
        events=turn,
        rtol=1e-10,
        atol=1e-30,
        max_step=scale_t / 4000,
    )
    dm = s1.y_events[0][0][0]
    am = a_of_d_load(dm)
    Pm = c.P_load(am)
    Rp = c.R if am <= c.ay else 4 * c.E * am**3 / (3 * (Pm + np.sqrt(8 * PI * c.w * c.E * am**3)))
    off = dm - c.d_jkr(am, Rp)
    acp = c.ac(Rp)
    dsep = off + c.d_jkr(acp, Rp)

    def a_of_d_unl(d):
        f = lambda a: off + c.d_jkr(a, Rp) - d
        return brentq(f, acp, am * (1 + 1e-9) + 1e-30, xtol=1e-30, rtol=1e-14)

    def rhs_unl(t, y):
        dd = max(y[0], dsep)
        return [y[1], -c.P_jkr(a_of_d_unl(min(dd, dm)), Rp) / c.m]

    sep = lambda t, y: y[0] - dsep
    sep.terminal, sep.direction = True, -1
    stop = lambda t, y: y[1]  # re-approach = stuck
    stop.terminal, stop.direction = True, 1
    s2 = solve_ivp(
        rhs_unl,
        (0, 20 * scale_t),
        [dm, 0.0],
        events=[sep, stop],
        rtol=1e-10,
        atol=1e-30,
        max_step=scale_t / 4000,
    )
    if len(s2.t_events[0]):
        return -s2.y_events[0][0][1] / V
    return 0.0


def main():
    warnings.simplefilter("ignore")
    out = []
    pr = lambda s: (print(s), out.append(s))
    # material: sphere on a rigid wall
    R, E, rho, w = 5e-6, 1.0e10, 2500.0, 0.1
    m = 4 / 3 * PI * rho * R**3
    Fc = 1.5 * PI * w * R

    pr("== (a) elastic JKR ==")
    el = Contact(R, E, m, w)
    cW = (1 + 3 * 2 ** (5 / 3)) * PI ** (5 / 3) / 10
    Vs_th = np.sqrt(2 * cW / m) * (w**5 * R**4 / E**2) ** (1 / 6)
    Vs = el.V_stick(0.5 * Vs_th, 2 * Vs_th)
    cs = Vs / (Fc**5 / (m**3 * R * E**2)) ** (1 / 6)
    c_rho = Vs / (w**5 / (rho**3 * E**2 * R**5)) ** (1 / 6)
    c_TN = Vs / ((w**5 * R**4 / E**2) ** (1 / 6) / np.sqrt(m))
    pr(
        f"V_s bisection = {Vs:.10e} m/s ; closed form sqrt(2 c_W/m)(w^5R^4/E^2)^(1/6) = {Vs_th:.10e}"
    )
    pr(f"c_s  in V_s = c_s (F_c^5/(m^3 R E^2))^(1/6), F_c = 1.5 pi w R : {cs:.6f}")
    pr(f"c^2  in V_s = (c^2/m)^(1/2) (w^5 R^4/E^2)^(1/6)   [TN eq 54: 14.18] : {c_TN**2:.4f}")
    pr(f"c_rho in V_s = c_rho (w^5/(rho^3 E^2 R^5))^(1/6)  [TN: 1.84]     : {c_rho:.6f}")
    pr(
        f"   (compare 1.03483 * 2^(5/6) = {1.03483 * 2 ** (5 / 6):.6f}; sqrt(3*2*c_W/(4 pi)) = {np.sqrt(3 * 2 * cW / (4 * PI)):.6f})"
    )
    for k in (1.5, 3.0, 10.0):
        r = el.impact(k * Vs)
        pr(
            f"V/V_s = {k:5.1f}: e(energy) = {r['e']:.8f}, sqrt(1-(V_s/V)^2) = {np.sqrt(1 - 1 / k**2):.8f}, "
            f"e(ODE) = {ode_check(el, k * Vs):.6f}"
        )

    pr("\n== (c) Thornton 1997, no adhesion (w = 0) ==")
    py = 0.5e9
    na = Contact(R, E, m, 0.0, py)
    Vy = 1.56 * np.sqrt(py**5 / (E**4 * rho))
    Vy_exact = (PI / (2 * E)) ** 2 * np.sqrt(8 * PI * R**3 / (15 * m)) * py**2.5
    pr(
        f"a_y = {na.ay:.6e} (pi p_y R/(2E) = {PI * py * R / (2 * E):.6e}); V_y(eq 10 exact) = {Vy_exact:.6e}, "
        f"1.56(...)^(1/2) = {Vy:.6e}, oracle = {na.V_yield():.6e}"
    )
    pr(" V/V_y     e_oracle     e_eq44      e_eq46=1.185(Vy/V)^(1/4)")
    for k in (1.0001, 1.5, 2, 5, 10, 30, 100, 1000):
        r = na.impact(k * Vy_exact)
        pr(f"{k:8.4f}  {r['e']:.6f}   {e_thornton1997(1 / k):.6f}   {1.185 * k**-0.25:.6f}")

    pr("\n== (b) TN adhesive elastic-plastic ==")
    for py in (1.0e9, 0.3e9, 0.1e9, 0.05e9):
        for reading in ("A", "B"):
            c = Contact(R, E, m, w, py, reading)
            Vy_na = (PI / (2 * E)) ** 2 * np.sqrt(8 * PI * R**3 / (15 * m)) * py**2.5
            Vy_ad = c.V_yield()
            Vs_p = c.V_stick(1e-6 * Vs, 1e3 * Vs) if c.impact(1e3 * Vs)["e2"] > 0 else np.nan
            pr(
                f"p_y = {py:.2e} reading {reading}: a_y = {c.ay:.4e} (a0 = {c.a0:.4e}), "
                f"V_y(adh, oracle) = {Vy_ad:.4e}, V_y(eq 10) = {Vy_na:.4e}, V_s = {Vs_p:.6e} "
                f"(elastic V_s = {Vs:.6e})"
            )
            pr("   V [m/s]     e_oracle   e_eq81(Vy_adh)  e_eq81(Vy_eq10)   Rp/R")
            for V in np.array([1.2, 2, 5, 20, 100, 1000]) * (Vs_p if np.isfinite(Vs_p) else Vs):
                r = c.impact(V)

                def e81(Vy_):
                    ep = 1.0 if V <= Vy_ else e_thornton1997(Vy_ / V)
                    x = ep**2 - (Vs / V) ** 2
                    return np.sqrt(x) if x > 0 else 0.0

                pr(
                    f"  {V:10.4e}   {r['e']:.6f}   {e81(Vy_ad):.6f}       {e81(Vy_na):.6f}       {r['Rp'] / R:.4f}"
                )
    pr("\nODE check, reading A, p_y = 0.3 GPa, V = 20 V_s (plastic):")
    c = Contact(R, E, m, w, 0.3e9, "A")
    pr(f"  e(energy) = {c.impact(20 * Vs)['e']:.6f}, e(ODE) = {ode_check(c, 20 * Vs):.6f}")
    return out


if __name__ == "__main__":
    main()

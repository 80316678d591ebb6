"""How well a wall law reproduces ``simulate`` at random points between its nodes."""

from __future__ import annotations

import numpy as np

from .._engine.settings import scene_parameters
from ._capture import scene_with
from ._law import WallLaw, _cell
from ._rows import SPEED_MAX

__all__ = ["random_points", "compare_with_simulate"]


def random_points(law: WallLaw, n: int, seed: int = 0, below: float = 0.5) -> dict:
    """``n`` random impacts inside the table: radius log-uniform, angle and spin uniform,
    and the speed ratio log-uniform from ``below`` (captures included, capture mode) or the
    first node to the last node."""
    rng = np.random.default_rng(seed)
    r = np.exp(rng.uniform(np.log(law.radius[0]), np.log(law.radius[-1]), n))
    angle = rng.uniform(law.angle_deg[0], law.angle_deg[-1], n)
    omega = rng.uniform(law.omega0[0], law.omega0[-1], n)
    lo = below if law.speed_axis == "capture_ratio" else law.speed_ratio[0]
    x = np.exp(rng.uniform(np.log(lo), np.log(law.speed_ratio[-1]), n))
    return {"radius": r, "angle_deg": angle, "omega0": omega, "speed_ratio": x}


def compare_with_simulate(law: WallLaw, scene, points: dict, evaluate=None) -> dict:
    """Evaluate the table (``law.evaluate``, or ``evaluate(radius, vn, vt, omega)`` with the
    same returns, e.g. the compiled C function) and ``simulate`` at ``points`` (as
    :func:`random_points` gives them; the speed is the ratio times the interpolated
    reference speed). Returns the inputs, both results and the errors."""
    from .._engine.api import simulate

    evaluate = evaluate or law.evaluate
    r, angle, omega, x = (points[k] for k in ("radius", "angle_deg", "omega0", "speed_ratio"))
    # the reference speed at each point, interpolated as the table does
    th = np.radians(angle)
    ir, wr, _ = _cell(np.log(law.radius), np.log(r))
    ia, wa, _ = _cell(law.angle_deg, angle)
    iw, ww, _ = _cell(law.omega0, omega)
    v_ref = law.reference_at((ir, ia, iw), (wr, wa, ww), angle)
    # where the table sticks at every speed (below the stick radius), the ratio in m/s
    # (and no faster than the speed range: a point above it is taken at its top)
    speed = np.minimum(x * np.where(np.isfinite(v_ref), v_ref, 1.0), SPEED_MAX)
    vn, vt = speed * np.cos(th), speed * np.sin(th)
    code, vn_out, vt_out, omega_out = evaluate(r, vn, vt, omega)
    params = {k: float(v) for k, v in scene_parameters(scene).items()}
    params = {k: np.full(r.size, v) for k, v in params.items()}
    params["radius"] = r
    res = simulate(scene_with(scene, params), speed, angle, omega)
    status = np.asarray(res.status)
    sim_captured = status == 1
    tab_captured = (np.asarray(code) & 1) == 1
    rebound = (status == 0) & ~tab_captured
    with np.errstate(invalid="ignore", divide="ignore"):
        err = {
            "cor_n": np.where(rebound, np.abs(vn_out / vn - np.asarray(res.cor_n)), np.nan),
            "cor_t": np.where(
                rebound & (vt > 0), np.abs((vt_out - np.asarray(res.vt_out)) / vt), np.nan
            ),
            "spin_ratio": np.where(
                rebound, np.abs((omega_out - np.asarray(res.omega_out)) * r / speed), np.nan
            ),
        }
    return {
        "speed": speed,
        "speed_ratio": x,
        "status_sim": status,
        "captured_table": tab_captured,
        "status_agree": sim_captured == tab_captured,
        "near_capture": np.abs(x - 1.0) <= 1e-3,
        "failed": status >= 2,
        "error": err,
        "code": np.asarray(code),
    }

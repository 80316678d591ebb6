"""The posterior spread of a wall law: capture probability and spread of ``cor_n`` per cell
over posterior draws of the scene's parameters."""

from __future__ import annotations

import numpy as np

from .._engine.settings import PARAMETERS, scene_parameters
from .._model.scene import SceneError
from ._capture import scene_with
from ._law import NOT_SIMULATED, WallLawError


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

"""Slow exits: an undamped DMT impact's ``cor_n`` against its energy oracle (1: the DMT law has no
force out of contact and no damping here) from the adhesion speed ``v_ad`` down to 1e-6 v_ad.

Run: ``python benchmarks/dmt_slow_exits.py`` (about 20 s). Prints BENCHMARKS.md's "Slow exits"
table: per ``v / v_ad``, the status and ``|cor_n - 1|`` at normal incidence and at 40 deg
(friction 0.3, no rolling moments), and the steps.

Scene: Table 1's sphere (r = 35 um, 8000 kg/m^3, K = 1.14e11 Pa) with ``normal = "dmt"``,
``w = 5`` J/m^2, ``C_H = 0`` (``v_ad = 0.113`` m/s). Far below ``v_ad`` the adhesive well is
``(v_ad/v)^2`` times the impact's energy.
"""

import sys
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import jaximpact as ji  # noqa: E402
from jaximpact.wall_law import adhesion_speed  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import machine, write_result  # noqa: E402

RATIOS = (1.0, 1e-1, 1e-2, 1e-3, 1e-4, 3e-5, 1e-5, 1e-6)
W = 5.0


def main():
    info = machine()
    scene = ji.table1_scene().replace(
        contact={"w": W, "f0": 0.0, "C_H": 0.0, "friction": 0.3},
        model={"normal": "dmt", "rolling_moments": "none"},
    )
    p = ji.scene_parameters(scene)
    v_ad = float(adhesion_speed(p["radius"], p["density"], p["K"], 0.0, W, "dmt"))
    speeds = v_ad * np.array(RATIOS)
    rows = {a: ji.simulate(scene, speeds, a, 0.0) for a in (0.0, 40.0)}
    print(f"v_ad = {v_ad:.4g} m/s")
    print("| v / v_ad | 0 deg: status | abs(cor_n - 1) | steps | 40 deg: status | abs(cor_n - 1) |")
    print("|---|---|---|---|---|---|")
    figures = []
    for k, ratio in enumerate(RATIOS):
        cells = []
        for a in (0.0, 40.0):
            res = rows[a]
            status = res.status_names[k]
            err = abs(float(np.asarray(res.cor_n)[k]) - 1.0)
            cells += [status, f"{err:.1e}"]
            if a == 0.0:
                cells.append(str(int(np.asarray(res.steps)[k])))
        print(f"| {ratio:g} | " + " | ".join(cells) + " |")
        figures.append({
            "v_over_v_ad": ratio,
            **{f"{a:g} deg": {
                "status": rows[a].status_names[k],
                "abs_cor_n_minus_1": abs(float(np.asarray(rows[a].cor_n)[k]) - 1.0),
                "steps": int(np.asarray(rows[a].steps)[k]),
            } for a in (0.0, 40.0)},
        })  # fmt: skip
    write_result("dmt_slow_exits", {"v_ad": v_ad, "rows": figures}, info,
                 "python benchmarks/dmt_slow_exits.py")  # fmt: skip


if __name__ == "__main__":
    main()

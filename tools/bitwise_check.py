"""Bitwise check of a refactoring: the same impacts before and after give identical bits.

``python tools/bitwise_check.py save PATH`` runs a fixed batch through ``jaximpact.simulate``
(2,000 random oblique spinning impacts as in ``benchmarks/throughput.py``: 0.5-5 m/s,
-60..60 deg, |omega0| <= 2e4 rad/s) on several scenes (Table 1, Kharaz 2001 with the Mindlin
spring, a JKR scene, a Thornton-Ning scene), in float64 and float32, plus two small wall laws
(grid and aligned layouts) with their C header and a results CSV, and saves every field to
``PATH`` (``.npz``). ``python tools/bitwise_check.py compare PATH`` recomputes the same and
compares bitwise (``np.array_equal`` with ``equal_nan``: NaN where NaN was, every other value
bit for bit); it exits 1 on any difference.

Each precision runs in a subprocess (``jax_enable_x64`` is set before jax is imported).
"""

import difflib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

N = 2000


def impacts(n=N, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.5, 5.0, n), rng.uniform(-60.0, 60.0, n), rng.uniform(-2e4, 2e4, n)


def scenes(ji):
    r, rho = 20e-6, 2500.0
    jkr = ji.Scene(
        particle=ji.Particle(radius=r, density=rho),
        contact=ji.Contact(K=6.6e10, f0=0.0, C_A=0.5, C_H=0.2, friction=0.3, w=0.1),
        model=ji.Model(normal="jkr", rolling_moments="analytical"),
    )
    tn = ji.Scene(
        particle=ji.Particle(radius=5e-6, density=rho),
        contact=ji.Contact(K=4e10 / 3, f0=0.0, C_A=0.5, C_H=0.0, friction=0.3, w=0.1, p_y=3e8),
        model=ji.Model(normal="thornton_ning", rolling_moments="analytical"),
    )
    return {
        "table1": ji.table1_scene(),
        "kharaz2001_mindlin": ji.load_scene(ji.scene_path("kharaz2001_mindlin")),
        "jkr_mindlin": jkr.replace(contact={"G_star": 2.6e10}, model={"tangential": "mindlin"}),
        "thornton_ning": tn,
    }


def worker(x64: bool, out: str) -> None:
    import jax

    jax.config.update("jax_enable_x64", x64)
    import jaximpact as ji

    tag = "f64" if x64 else "f32"
    arrays = {}
    speed, angle, omega0 = impacts()
    for name, scene in scenes(ji).items():
        res = ji.simulate(scene, speed, angle, omega0)
        for field in res.__dataclass_fields__:
            arrays[f"{tag}/{name}/{field}"] = np.asarray(getattr(res, field))
    if x64:
        arrays.update(wall_laws(ji))
    # text as fixed-width strings (an object array would need pickle to load)
    arrays = {k: v.astype(str) if v.dtype == object else v for k, v in arrays.items()}
    np.savez(out, **arrays)


def wall_laws(ji) -> dict:
    from jaximpact._io.tables import read_results, write_results
    from jaximpact.wall_law import c_header, wall_law

    arrays = {}
    scene = ji.table1_scene()
    ratios = 1.0 + np.sinh(np.linspace(0.0, np.arcsinh(np.sqrt(99.0)), 8)) ** 2
    laws = {
        "grid": wall_law(scene, angle_deg=(20.0, 40.0, 60.0), omega0=(-2e4, 2e4),
                         speed_ratio=ratios, speed_tol=1e-2),
        "aligned": wall_law(scene, angle_deg=np.linspace(0.0, 85.0, 6), omega0=(0.0,),
                            speed_ratio=ratios, layout="aligned", refine=False),
    }  # fmt: skip
    for name, law in laws.items():
        for field, value in vars(law).items():
            if isinstance(value, np.ndarray) and value.dtype != object:
                arrays[f"wall_law/{name}/{field}"] = value
        arrays[f"wall_law/{name}/radius_report"] = np.array(
            json.dumps(law.radius_report, sort_keys=True, default=str)
        )
        header = c_header(law, "table1")
        arrays[f"wall_law/{name}/c_header"] = np.frombuffer(header.encode(), np.uint8)
    speed, angle, omega0 = impacts(50)
    res = ji.simulate(scene, speed, angle, omega0)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "results.csv"
        write_results(path, {"speed": speed, "angle_deg": angle, "omega0": omega0}, res.columns())
        arrays["results_csv"] = np.frombuffer(path.read_bytes(), np.uint8)
        for k, v in read_results(path).items():
            arrays[f"results_csv/{k}"] = np.asarray(v)
    return arrays


def run_all() -> dict:
    arrays = {}
    with tempfile.TemporaryDirectory() as d:
        for x64 in (True, False):
            out = str(Path(d) / f"{x64}.npz")
            subprocess.run([sys.executable, __file__, "worker", str(int(x64)), out], check=True)
            with np.load(out) as f:
                arrays.update({k: f[k] for k in f.files})
    return arrays


def equal(a, b) -> bool:
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.dtype.kind in "fc":
        same_nan = np.array_equal(np.isnan(a), np.isnan(b))
        bits = a.view(np.uint8) == b.view(np.uint8)  # bit for bit (also -0.0 and NaN payloads)
        return bool(same_nan and np.array_equal(a, b, equal_nan=True) and np.all(bits))
    return bool(np.array_equal(a, b))


def main(argv) -> int:
    if argv[:1] == ["worker"]:
        worker(bool(int(argv[1])), argv[2])
        return 0
    if len(argv) != 2 or argv[0] not in ("save", "compare"):
        print(__doc__)
        return 2
    mode, path = argv
    arrays = run_all()
    if mode == "save":
        np.savez(path, **arrays)
        print(f"saved {len(arrays)} arrays to {path}")
        return 0
    with np.load(path) as f:
        saved = {k: f[k] for k in f.files}
    missing = sorted(set(saved) ^ set(arrays))
    differ = sorted(k for k in set(saved) & set(arrays) if not equal(saved[k], arrays[k]))
    for k in missing:
        print(f"only in one of the two: {k}")
    for k in differ:
        print(f"differs: {k}")
        if saved[k].dtype == np.uint8:  # a text: its changed lines
            before = saved[k].tobytes().decode().splitlines()
            now = arrays[k].tobytes().decode().splitlines()
            for line in difflib.unified_diff(before, now, "saved", "now", n=0, lineterm=""):
                print("    " + line)
    print(f"{len(arrays)} arrays compared: {len(differ)} differ, {len(missing)} missing")
    return 1 if differ or missing else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""The kink-aligned layout of the wall law (``wall_law(..., layout="aligned")``): results
tabulated against an angle coordinate in which the onset of rolling is a fixed node. The
cells reproduce ``simulate``, ``theta*`` separates the impacts that reach rolling from those
that slide through, the C function computes what Python does, the files say the layout, and
the table meets the issue's 1e-3 at random points (slow)."""

import numpy as np
import pytest
from test_wall_law import GCC, RATIOS, SHIM, c_wall_law, compile_c

import jaximpact as ji
from jaximpact.wall_law import compare_with_simulate, random_points, wall_law, write_wall_law
from jaximpact.wall_law._aligned import kink_nodes
from jaximpact.wall_law._table import KINK_MIN_DEG, kink_angle, kink_coordinate

ANGLES = np.linspace(0.0, 85.0, 18)
SPINS = (0.0, 2e4)


@pytest.fixture(scope="module")
def scene():
    return ji.table1_scene()


@pytest.fixture(scope="module")
def law(scene):
    return wall_law(
        scene, angle_deg=ANGLES, omega0=SPINS, speed_ratio=RATIOS, layout="aligned", refine=False
    )


def test_kink_coordinate_puts_each_kink_on_its_node():
    first = np.array([5.0, 40.0, 85.0, 0.0, 30.0])
    star = np.array([10.0, 60.0, 85.0, 0.0, 30.0])  # the last: the two kinks at one angle
    kinks = (first, star)
    u = kink_coordinate(np.stack([first, star]), kinks, 85.0)
    assert np.allclose(u[0, :2], 1.0) and np.allclose(u[1, :2], 2.0)
    theta = np.linspace(0.0, 85.0, 35)[:, None]
    u = kink_coordinate(theta, kinks, 85.0)
    assert np.all(np.diff(u, axis=0) >= 0)  # monotone in the angle for every pair of kinks
    assert np.all(np.diff(u[:, :2], axis=0) > 0)
    np.testing.assert_allclose(kink_angle(u, kinks, 85.0), theta + 0 * u, atol=1e-12)
    # kinks at 0 (slides at every angle) are used as KINK_MIN_DEG: still defined
    assert kink_coordinate(KINK_MIN_DEG, (0.0, 0.0), 85.0) == pytest.approx(1.0)
    assert kink_coordinate(KINK_MIN_DEG + 1.0, (0.0, 0.0), 85.0) > 2.0
    nodes = kink_nodes()
    assert nodes[0] == 0.0 and nodes[-1] == 3.0 and 1.0 in nodes and 2.0 in nodes
    assert np.all(np.diff(nodes) > 0)


def test_cells_reproduce_simulate_and_the_lookup_reproduces_the_cells(law, scene):
    """Every rebounding cell (above the capture speed) is ``simulate`` at its angle and
    speed, and the table evaluated there returns it (to rounding: the query's speed ratio,
    theta* and aligned coordinate are recomputed from the speed and angle)."""
    assert law.aligned and law.shape == (1, kink_nodes().size, len(SPINS), RATIOS.size)
    angle = np.asarray(law.cell_angle_deg)
    ok = (law.status == 0) & (np.arange(RATIOS.size) > 0)
    r = law.radius[0]
    th = np.radians(angle[ok])
    speed = law.speed[ok]
    w = np.broadcast_to(np.asarray(SPINS)[None, None, :, None], law.shape)[ok]
    res = ji.simulate(scene, speed, angle[ok], w)
    np.testing.assert_allclose(np.asarray(res.cor_n), law.cor_n[ok], atol=1e-12)
    np.testing.assert_allclose(np.asarray(res.vt_out) / speed, law.vt_ratio[ok], atol=1e-12)
    code, vn_out, vt_out, om_out = law.evaluate(r, speed * np.cos(th), speed * np.sin(th), w)
    assert np.all(code == 0)
    np.testing.assert_allclose(vn_out / (speed * np.cos(th)), law.cor_n[ok], atol=1e-9)
    np.testing.assert_allclose(vt_out / speed, law.vt_ratio[ok], atol=1e-9)
    np.testing.assert_allclose(om_out * r / speed, law.spin_ratio[ok], atol=1e-9)


def test_kinks_separate_the_rolling_regimes(law, scene):
    """Just below ``theta*`` the sphere reaches rolling before it leaves, just above it it
    slides through; just below the first kink it still rolls when it leaves (no slip at
    exit), just above it it slides again before it leaves (where the kinks lie inside the
    table and apart: at this radius and up to 9 m/s the first lies 0.03-0.2 deg below
    theta*), at the speeds the table uses."""
    from jaximpact.wall_law._aligned import _CaptureRows

    cap = _CaptureRows(law.radius, law.angle_deg, law.omega0, law.capture_speed)
    r = law.radius[0]
    first, star = law.kink_angles[:, 0]  # (spin, speed) each
    inside = (star > 1.0) & (star < 84.0)
    inside[:, 0] = False  # the capture speed itself
    apart = (first > 1.0) & (first < star - 0.02)
    apart[:, 0] = False
    assert inside.sum() >= 8 and apart.sum() >= 8
    for kink, where in ((star, inside), (first, apart)):
        j, k = np.nonzero(where)
        w = np.asarray(SPINS)[j]
        for side in (-0.005, 0.005):  # (the bisections' last interval: 0.0012 deg)
            a = kink[j, k] + side
            speed = RATIOS[k] * cap.at(r, a, w)
            res = ji.simulate(scene, speed, a, w)
            assert np.all(np.asarray(res.status) == 0)
            rolled = np.isfinite(np.asarray(res.roll_time))
            slip = np.abs(np.asarray(res.vt_out) - np.asarray(res.omega_out) * r) / speed
            if kink is star:
                assert np.all(rolled == (side < 0)), side
            else:
                assert np.all(rolled), side
                assert np.all((slip <= 1e-9) == (side < 0)), side


@pytest.mark.skipif(GCC is None, reason="no C compiler")
def test_c_header_matches_the_python_interpolation(law, tmp_path):
    lib = compile_c(tmp_path, law, SHIM, "shim")
    evaluate = c_wall_law(lib)
    rng = np.random.default_rng(7)
    n = 3000
    radius = np.where(rng.random(n) < 0.9, law.radius[0], law.radius[0] * 1.3)
    vn = rng.uniform(0.01, 2.0, n)
    vt = rng.uniform(-3.0, 3.0, n)
    spin = rng.uniform(-1e4, 3e4, n)
    got = evaluate(radius, vn, vt, spin)
    want = law.evaluate(radius, vn, vt, spin)
    np.testing.assert_array_equal(got[0], want[0])
    assert {0, 1, 2} <= set(np.unique(want[0]))
    for g, w in zip(got[1:], want[1:], strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-13, atol=1e-13)


@pytest.mark.skipif(GCC is None, reason="no C compiler")
def test_unresolved_radius_intervals_are_flagged_as_clamped(law, tmp_path):
    """A radius inside an interval the build reports as not resolved to its tolerances gets
    the clamped bit, in Python and in the C function, with the same outputs as before."""
    import dataclasses

    r0 = law.radius[0]
    flagged = dataclasses.replace(law, radius_report={"results_unresolved": [(r0, r0, 0.1)]})
    assert flagged.unresolved_radii.shape == (1, 2)
    vn, vt = np.full(50, 1.0), np.linspace(0.0, 3.0, 50)
    plain = law.evaluate(r0, vn, vt, 0.0)
    got = flagged.evaluate(r0, vn, vt, 0.0)
    assert np.all(plain[0] & 2 == 0) and np.all(got[0] & 2 == 2)
    np.testing.assert_array_equal(got[0], plain[0] | 2)
    for g, p in zip(got[1:], plain[1:], strict=True):
        np.testing.assert_array_equal(g, p)
    evaluate = c_wall_law(compile_c(tmp_path, flagged, SHIM, "shim_unresolved"))
    c_got = evaluate(np.full(50, r0), vn, vt, np.zeros(50))
    np.testing.assert_array_equal(c_got[0], got[0])


def test_files_say_the_layout(law, tmp_path):
    xr = pytest.importorskip("xarray")
    import pyarrow.parquet as pq

    write_wall_law(law, tmp_path, "table1")
    with xr.open_dataset(tmp_path / "wall_law.nc") as ds:
        assert ds.attrs["layout"] == "aligned"
        assert tuple(ds["cor_n"].dims) == ("radius", "kink_u", "omega0", "speed_ratio")
        assert tuple(ds["capture_speed"].dims) == ("radius", "angle_deg", "omega0")
        dims = ("kink", "radius", "omega0", "speed_ratio")
        assert tuple(ds["kink_angle_deg"].dims) == dims
        assert list(ds["kink"].values) == ["rolls_at_exit", "reaches_rolling"]
        np.testing.assert_array_equal(ds["kink_angle_deg"].values, law.kink_angles)
        np.testing.assert_array_equal(ds["kink_u"].values, law.kink_u)
        np.testing.assert_array_equal(ds["cell_angle_deg"].values, law.cell_angle_deg)
    table = pq.read_table(tmp_path / "wall_law.parquet")
    angle = np.asarray(table.column("angle_deg").to_pylist())
    np.testing.assert_array_equal(angle, np.asarray(law.cell_angle_deg).ravel())
    header = (tmp_path / "jaximpact_wall_law.h").read_text()
    assert "#define JAXIMPACT_WL_ALIGNED 1" in header


@pytest.mark.slow  # a batch of its own (9 s)
def test_posterior_draws_simulate_each_cell_at_its_angle(law, scene):
    """Draws equal to the scene's own parameters reproduce the table: no capture where the
    cell rebounds and ``cor_n_mean`` equal to ``cor_n`` (each cell simulated at its own
    angle, which changes along the speed axis in this layout)."""
    from jaximpact._engine.api import simulate
    from jaximpact.wall_law._table import _uncertainty

    f0 = float(scene.contact.f0)
    out = _uncertainty(simulate, scene, law, {"f0": np.full(2, f0)}, 2, lambda m: None)
    live = (law.status == 0) & (np.arange(RATIOS.size) > 0)
    assert out["draws"] == 2 and out["cor_n_mean"].shape == law.shape
    assert np.all(out["capture_probability"][live] == 0.0)
    np.testing.assert_allclose(out["cor_n_mean"][live], law.cor_n[live], atol=1e-12)


def test_refused_without_adhesion(scene):
    with pytest.raises(ji.SceneError, match="layout 'aligned'.*needs adhesion"):
        wall_law(scene.replace(contact={"f0": 0.0}), layout="aligned")
    with pytest.raises(ji.SceneError, match="layout must be"):
        wall_law(scene, layout="tilted")
    with pytest.raises(ji.SceneError, match="speed_tol.*grid layout"):
        wall_law(scene, layout="aligned", speed_tol=1e-3)


def _errors(law, scene, n, seed):
    """Largest and 99th-percentile errors at ``n`` random points, leaving out the points
    above a row's valid top (clamped: the table holds the row's last results there)."""
    c = compare_with_simulate(law, scene, random_points(law, n, seed=seed))
    clamped = (c["code"] & 2) == 2
    out = {}
    for name, e in c["error"].items():
        e = e[np.isfinite(e) & ~clamped]
        out[name] = (float(e.max()), float(np.percentile(e, 99)))
    far = ~c["status_agree"] & (np.abs(c["speed_ratio"] - 1.0) > 5e-3)
    return out, int(far.sum())


@pytest.mark.slow  # the default 171 capture angles and 64 speed ratios, 4,000 points
def test_one_radius_meets_the_tolerance(scene):
    """At one radius (default angles and speed ratios): cor_n, cor_t and omega_out r / speed
    within 1e-3 of simulate at 4,000 random points (measured 2026-11-28: 3.9e-4, 5.9e-4 and
    5.9e-4), no status disagreement beyond 0.5 % of the capture speed."""
    law = wall_law(scene, layout="aligned")
    errors, far = _errors(law, scene, 4000, seed=1)
    assert far == 0
    for name, (largest, _) in errors.items():
        assert largest < 1e-3, (name, largest)


@pytest.mark.slow  # about 4 minutes: the command's build over 1-100 um, 1,500 points
def test_two_decade_table_from_the_command_against_simulate(tmp_path):
    """``jaximpact wall-law table1 --radius 1e-6 100e-6 --check 1500`` in a subprocess, as a
    user runs it (one device per core): the default layout for a range is the aligned one;
    against simulate at random points outside the radius intervals the build reports as
    unresolved (next to the stick radius), no stick/rebound disagreement beyond 0.5 % of the
    capture speed outside the points flagged as clamped, and the unflagged rebounds' errors
    beyond 0.5 % of the capture speed within the issue's 1e-3. Measured 2026-11-28 with two
    aligned kinks (benchmarks/wall_law_radius.py, 4,000 points of another seed): cor_n 8.1e-4,
    cor_t 7.7e-4, spin 5.6e-4; 23 points in the unresolved intervals (9.47-10.2 um)."""
    import re
    import subprocess
    import sys

    proc = subprocess.run(
        [sys.executable, "-m", "jaximpact.cli", "wall-law", "table1", "--radius", "1e-6",
         "100e-6", "--check", "1500", "--quiet", "-o", str(tmp_path / "wl")],
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert f"results on {kink_nodes().size} nodes of the kink-aligned angle coordinate" in out
    assert "radius midpoints checked against simulate" in out
    line = next(x for x in out.splitlines() if x.startswith("check against simulate"))
    assert re.search(r"capture speed: 0 \(", line), line
    for name in ("cor_n", "cor_t", "spin"):
        largest, p99 = (float(v) for v in re.search(rf"{name} (\S+) \((\S+)\)", line).groups())
        assert largest < 1e-3 and p99 < 1e-3, line

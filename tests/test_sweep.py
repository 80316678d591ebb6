"""Tests of ``jaximpact sweep`` (jaximpact/sweep.py): equality with ``simulate``, kill and
resume, multi-device sharding, the process share of a distributed run, and bad input.

Chunks of 64 impacts keep every run short; the in-process sweeps share one compilation (same
model terms, solver and chunk size). Subprocess runs exercise the command line, a real SIGKILL
and forced host devices.
"""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

import jaximpact as ji
from jaximpact.cli import main, scene_with_overrides
from jaximpact.sweep import (
    GridSource,
    SweepError,
    parse_grid,
    read_impacts_file,
    read_sweep,
    read_sweep_columns,
    run_sweep,
)
from jaximpact.tables import RESULT_COLUMNS, read_impacts

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

CHUNK = 64
N = 150  # three chunks: 64 + 64 + 22 (the last one padded)


def write_impacts(path, n=N, seed=0):
    """An impacts CSV of oblique spinning impacts with a per-row f0 override."""
    rng = np.random.default_rng(seed)
    cols = {
        "speed": rng.uniform(0.5, 4.0, n),
        "angle_deg": rng.uniform(-60, 60, n),
        "omega0": rng.uniform(-2e4, 2e4, n),
        "f0": rng.uniform(100, 400, n),
    }
    lines = [",".join(cols)] + [
        ",".join(repr(float(v)) for v in row) for row in zip(*cols.values(), strict=True)
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def run_cli(args, env_extra=None, timeout=300):
    env = {k: v for k, v in os.environ.items() if k != "JAXIMPACT_SWEEP_KILL_AFTER"}
    env.update(env_extra or {})
    return subprocess.run(
        [sys.executable, "-m", "jaximpact.cli", "sweep", *args, "--no-progress"],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def assert_same(a, b, rtol=0.0):
    assert list(a) == list(b)
    np.testing.assert_array_equal(a["status"], b["status"])
    for name in a:
        if name != "status":
            np.testing.assert_allclose(a[name], b[name], rtol=rtol, atol=0, equal_nan=True)


@pytest.fixture(scope="module")
def impacts(tmp_path_factory):
    return write_impacts(tmp_path_factory.mktemp("impacts") / "impacts.csv")


@pytest.fixture(scope="module")
def reference(impacts, tmp_path_factory):
    """An uninterrupted single-device, single-process sweep of ``impacts``."""
    out = tmp_path_factory.mktemp("ref") / "results.parquet"
    summary = run_sweep(read_impacts_file(impacts), out, chunk_size=CHUNK, progress=False)
    assert summary.complete and summary.chunks_run == 3 and summary.impacts_run == N
    return out, read_sweep_columns(out)


# ---------------------------------------------------------------------------------------------
# (1) Same numbers as simulate


def test_sweep_equals_simulate_row_for_row(impacts, reference):
    out, got = reference
    table = read_impacts(impacts)
    scene = scene_with_overrides(ji.load_scene(), dict(table.overrides))
    expected = {
        **table.as_columns(),
        **ji.simulate(scene, table.speed, table.angle_deg, table.omega0).columns(),
    }
    assert list(got) == [*table.columns, *RESULT_COLUMNS]
    assert len(got["speed"]) == N  # padding dropped
    # Chunks of 64 against one batch of 150: the same model and solver, per-impact arithmetic.
    assert_same(got, expected, rtol=1e-12)
    assert sorted(p.name for p in out.iterdir()) == [
        "manifest-00000.json",
        "part-000000.parquet",
        "part-000001.parquet",
        "part-000002.parquet",
    ]
    assert pq.read_table(out / "part-000002.parquet").num_rows == N - 2 * CHUNK
    assert read_sweep(out).schema.field("status").type == pa.string()


def test_grid_sweep_equals_simulate_on_the_product(tmp_path):
    axes = parse_grid(["speed=0.5:4:5:log", "angle_deg=-50,20,45", "omega0=1e4", "f0=150:350:5"])
    source = GridSource(axes, {"speed": 1.0, "angle_deg": 0.0, "omega0": 0.0})
    assert source.n == 75 and source.columns == ("speed", "angle_deg", "omega0", "f0")
    run_sweep(source, tmp_path / "g", chunk_size=CHUNK, progress=False)
    got = read_sweep_columns(tmp_path / "g")
    s, a, f = np.meshgrid(axes["speed"], axes["angle_deg"], axes["f0"], indexing="ij")
    s, a, f = s.ravel(), a.ravel(), f.ravel()  # the last axis varies fastest
    np.testing.assert_array_equal(got["speed"], s)
    np.testing.assert_array_equal(got["f0"], f)
    np.testing.assert_array_equal(got["omega0"], np.full(75, 1e4))
    res = ji.simulate(ji.load_scene().replace(contact={"f0": f}), s, a, 1e4)
    assert_same({k: got[k] for k in RESULT_COLUMNS}, res.columns(), rtol=1e-12)


def test_parquet_impacts_give_the_same_results(impacts, reference, tmp_path):
    table = read_impacts(impacts)
    pq.write_table(pa.table(table.as_columns()), tmp_path / "impacts.parquet")
    run_sweep(
        read_impacts_file(tmp_path / "impacts.parquet"),
        tmp_path / "out",
        chunk_size=CHUNK,
        progress=False,
    )
    assert_same(read_sweep_columns(tmp_path / "out"), reference[1])


# ---------------------------------------------------------------------------------------------
# (2) Kill and resume


def test_killed_sweep_resumes_to_the_uninterrupted_result(impacts, reference, tmp_path):
    out = tmp_path / "results.parquet"
    args = ["--impacts", str(impacts), "-o", str(out), "--chunk-size", str(CHUNK)]
    # SIGKILL right after chunk 1's part file is written, before the manifest lists it.
    killed = run_cli(args, {"JAXIMPACT_SWEEP_KILL_AFTER": "1"})
    assert killed.returncode == -9, killed.stderr
    manifest = json.loads((out / "manifest-00000.json").read_text())
    assert manifest["completed"] == [0]
    assert (out / "part-000001.parquet").exists()  # written, not listed: redone on resume
    with pytest.raises(SweepError, match="incomplete"):
        read_sweep(out)
    assert read_sweep(out, allow_partial=True).num_rows == CHUNK
    first = (out / "part-000000.parquet").stat().st_mtime_ns

    resumed = run_cli(args)
    assert resumed.returncode == 0, resumed.stderr
    assert "this run: 2 chunk(s)" in resumed.stdout and "1 already done" in resumed.stdout
    assert (out / "part-000000.parquet").stat().st_mtime_ns == first  # finished work untouched
    got = read_sweep_columns(out)
    assert len(got["speed"]) == N  # nothing lost or duplicated
    assert_same(got, reference[1])
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp")]


def test_rerunning_a_finished_sweep_does_nothing(impacts, reference, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(reference[0], out)
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.suffix == ".parquet"}
    summary = run_sweep(read_impacts_file(impacts), out, chunk_size=CHUNK, progress=False)
    assert summary.chunks_run == 0 and summary.chunks_skipped == 3 and summary.complete
    after = {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.suffix == ".parquet"}
    assert after == before


# ---------------------------------------------------------------------------------------------
# (3) Several devices, several processes


def test_four_forced_host_devices_match_one_device(impacts, reference, tmp_path):
    flags = (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4").strip()
    env = {"XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu"}
    out = tmp_path / "four.parquet"
    run = run_cli(["--impacts", str(impacts), "-o", str(out), "--chunk-size", str(CHUNK)], env)
    assert run.returncode == 0, run.stderr
    assert "on 4 device(s)" in run.stdout
    # 16 impacts per device against 64 on one: the same per-impact arithmetic.
    assert_same(read_sweep_columns(out), reference[1], rtol=1e-12)

    bad = run_cli(
        ["--impacts", str(impacts), "-o", str(tmp_path / "bad"), "--chunk-size", "66"], env
    )
    assert bad.returncode == 2
    assert "--chunk-size 66 must be a positive multiple of the number of local devices (4" in (
        bad.stderr
    )


def test_process_shares_merge_to_the_whole_sweep(impacts, reference, tmp_path):
    out = tmp_path / "shared"
    source = read_impacts_file(impacts)
    first = run_sweep(
        source, out, chunk_size=CHUNK, progress=False, process_index=1, process_count=2
    )
    assert first.chunks_run == 1 and not first.complete  # chunk 1 of 0, 1, 2
    with pytest.raises(SweepError, match="2 of 3 chunks not done"):
        read_sweep(out)
    second = run_sweep(
        source, out, chunk_size=CHUNK, progress=False, process_index=0, process_count=2
    )
    assert second.chunks_run == 2 and second.complete
    assert {p.name for p in out.glob("manifest-*.json")} == {
        "manifest-00000.json",
        "manifest-00001.json",
    }
    assert_same(read_sweep_columns(out), reference[1])
    # A later single-process run sees both manifests: nothing left to do.
    again = run_sweep(source, out, chunk_size=CHUNK, progress=False)
    assert again.chunks_run == 0 and again.chunks_skipped == 3


# ---------------------------------------------------------------------------------------------
# (4) Bad input


@pytest.mark.parametrize(
    "spec, message",
    [
        ("speed", "expected NAME=VALUE"),
        ("speed=", "expected NAME=VALUE"),
        ("=1", "expected NAME=VALUE"),
        ("spead=1", "unknown name 'spead'"),
        ("speed=1:2", "expected NAME=VALUE"),
        ("speed=1:2:3:lin", "expected NAME=VALUE"),
        ("speed=1:2:x", "NUM 'x' is not an integer"),
        ("speed=1:2:0", "NUM must be >= 1"),
        ("speed=0:1:3:log", "log range needs START > 0"),
        ("speed=a,1", "'a' is not a number"),
        ("speed=1,nan", "'nan' is not finite"),
    ],
)
def test_bad_grid_syntax(spec, message):
    with pytest.raises(SweepError, match=message):
        parse_grid([spec])


def test_bad_grid_values_and_repeats():
    with pytest.raises(SweepError, match="speed given twice"):
        parse_grid(["speed=1", "speed=2"])
    defaults = {"speed": 1.0, "angle_deg": 0.0, "omega0": 0.0}
    with pytest.raises(SweepError, match="angle_deg must be finite, with -90 < angle_deg < 90"):
        GridSource(parse_grid(["angle_deg=-90:90:5"]), defaults)
    with pytest.raises(SweepError, match="f0 must be finite and >= 0"):
        GridSource(parse_grid(["f0=-1,1"]), defaults)


def test_cli_reports_bad_grid_with_status_2(tmp_path, capsys):
    assert main(["sweep", "--grid", "speed=1:5", "-o", str(tmp_path / "o"), "--no-progress"]) == 2
    assert "error: grid 'speed=1:5': expected NAME=VALUE" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_changed_settings_are_refused_unless_restart(impacts, reference, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(reference[0], out)
    with pytest.raises(SweepError, match="other settings.*chunk size 64.*--restart"):
        run_sweep(read_impacts_file(impacts), out, chunk_size=32, progress=False)
    changed = write_impacts(tmp_path / "changed.csv", seed=1)
    with pytest.raises(SweepError, match="other settings"):
        run_sweep(read_impacts_file(changed), out, chunk_size=CHUNK, progress=False)
    assert read_sweep_columns(out)["speed"].tolist() == reference[1]["speed"].tolist()

    summary = run_sweep(
        read_impacts_file(changed), out, chunk_size=CHUNK, progress=False, restart=True
    )
    assert summary.chunks_run == 3
    np.testing.assert_array_equal(read_sweep_columns(out)["speed"], read_impacts(changed).speed)

    (tmp_path / "file").write_text("")
    with pytest.raises(SweepError, match="not a directory"):
        run_sweep(read_impacts_file(impacts), tmp_path / "file", chunk_size=CHUNK, progress=False)


def test_read_sweep_rejects_what_is_not_a_sweep(tmp_path):
    with pytest.raises(SweepError, match="no sweep manifest"):
        read_sweep(tmp_path)


def test_two_processes_with_jax_distributed(tmp_path):
    """Two local processes under ``--distributed`` (CPU): each writes its share and manifest."""
    import socket

    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    out = tmp_path / "dist.parquet"
    grid = ["--grid", "speed=0.5:4:10", "--grid", "angle_deg=-50:50:10", "--grid", "omega0=1e4"]
    env = {k: v for k, v in os.environ.items() if k != "JAXIMPACT_SWEEP_KILL_AFTER"}
    env["JAX_PLATFORMS"] = "cpu"
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "jaximpact.cli", "sweep", *grid, "-o", str(out)]
            + ["--chunk-size", str(CHUNK), "--no-progress", "--distributed"]
            + ["--coordinator", f"localhost:{port}", "--num-processes", "2"]
            + ["--process-id", str(i)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in (0, 1)
    ]
    outputs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outputs
    assert "this run: 1 chunk(s), 64 impacts" in outputs[0][0]  # chunk 0 (of 0, 1)
    assert "this run: 1 chunk(s), 36 impacts" in outputs[1][0]  # chunk 1, the padded one
    manifests = sorted(p.name for p in out.glob("manifest-*.json"))
    assert manifests == ["manifest-00000.json", "manifest-00001.json"]
    got = read_sweep_columns(out)
    assert len(got["speed"]) == 100
    # Against one process (same chunks): simulate on one batch of 100 may differ in its
    # vectorized tail rows at the solver-tolerance level (a rounding flips a step decision).
    source = GridSource(parse_grid(grid[1::2]), {"speed": 1.0, "angle_deg": 0.0, "omega0": 0.0})
    run_sweep(source, tmp_path / "one", chunk_size=CHUNK, progress=False)
    assert_same(got, read_sweep_columns(tmp_path / "one"), rtol=1e-12)

"""Tests of ``jaximpact sweep`` (jaximpact/sweep.py): equality with ``simulate``, kill and
resume, multi-device sharding, the process share of a distributed run, the Parquet layout
(readers, units, sweeps of the older layout), failure counts and bad input or files.

Chunks of 64 impacts keep every run short; the in-process sweeps share one compilation (same
model terms, solver and chunk size). Subprocess runs of the installed ``jaximpact`` command
exercise exit codes and messages, a real SIGKILL and forced host devices.
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

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
from jaximpact.tables import COLUMN_UNITS, RESULT_COLUMNS, TEXT_RESULT_COLUMNS, read_impacts

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


def jaximpact_command() -> list[str]:
    """The installed console script (next to this interpreter), else ``python -m``."""
    script = os.path.join(os.path.dirname(sys.executable), "jaximpact")
    return [script] if os.path.exists(script) else [sys.executable, "-m", "jaximpact.cli"]


def run_cli(args, env_extra=None, timeout=300):
    env = {k: v for k, v in os.environ.items() if k != "JAXIMPACT_SWEEP_KILL_AFTER"}
    # Two devices with XLA's default compilation, as in this process: the CLI's loop kernels
    # (its default) compile the same arithmetic differently, and the results here compare bits.
    env["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
    env.update(env_extra or {})
    return subprocess.run(
        [*jaximpact_command(), "sweep", *args, "--no-progress"],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def assert_same(a, b, rtol=0.0):
    assert list(a) == list(b)
    for name in TEXT_RESULT_COLUMNS:
        if name not in a:  # `implausible`: simulate's results CSV only, not the sweep's
            continue
        np.testing.assert_array_equal(np.asarray(a[name], str), np.asarray(b[name], str))
    for name in a:
        if name not in TEXT_RESULT_COLUMNS:
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
    # Chunks of 64 against one batch of 150: the same model, solver and per-impact arithmetic,
    # so the same bits.
    assert_same(got, expected)
    assert sorted(p.name for p in out.iterdir()) == [
        "_manifest-00000.json",
        "part-000000.parquet",
        "part-000001.parquet",
        "part-000002.parquet",
    ]
    assert pq.read_table(out / "part-000002.parquet").num_rows == N - 2 * CHUNK
    schema = read_sweep(out).schema
    assert schema.field("status").type == pa.string()
    assert schema.field("failure_reason").type == pa.string()


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
    assert_same({k: got[k] for k in RESULT_COLUMNS}, res.columns())


def test_chunks_solved_as_simulate_solves_them_compile_once(tmp_path, monkeypatch, caplog):
    """Inside its program a sweep solves a chunk in sub-chunks as ``simulate`` does (here 16
    lanes at a time, instead of 4096, so that 64-impact chunks have several): the same bits as
    ``simulate`` on the whole batch. Its program compiles once for three chunks (the last one
    padded), and a second sweep of other values of the same model compiles nothing at all."""
    import logging

    import jaximpact._engine.simulate as simulate_module

    monkeypatch.setattr(simulate_module, "CHUNK_ONE_DEVICE", 16)
    monkeypatch.setattr(simulate_module, "CHUNK_LOOP_KERNEL", 16)  # (set by import jaximpact)
    # Normal impacts without adhesion: a small program of its own (no other test compiles it).
    defaults = {"speed": 1.0, "angle_deg": 0.0, "omega0": 0.0}
    scene = ji.load_scene().replace(contact={"f0": 0.0})

    def sweep(speeds, out):
        source = GridSource(parse_grid([f"speed={speeds}", "f0=0"]), defaults)
        # JAX logs each compilation at DEBUG (WARNING under jax.log_compiles, whose setting
        # is per thread: the sweep calls its program from a thread of its own).
        with caplog.at_level(logging.DEBUG, logger="jax._src.interpreters.pxla"):
            caplog.clear()
            run_sweep(source, out, chunk_size=CHUNK, progress=False)
            compiled = [r.getMessage() for r in caplog.records if "Compiling" in r.getMessage()]
        return read_sweep_columns(out), compiled

    got, compiled = sweep("0.3:4:150", tmp_path / "a")
    assert len(got["speed"]) == N
    assert sum("sweep_chunk" in m for m in compiled) == 1, compiled
    res = ji.simulate(scene, got["speed"], 0.0, 0.0)
    assert_same({k: got[k] for k in RESULT_COLUMNS}, res.columns())
    assert set(got["status"]) == {"rebound"}

    again, compiled = sweep("0.4:3:150", tmp_path / "b")
    assert compiled == []
    assert not np.array_equal(again["vn_out"], got["vn_out"])


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


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_killed_sweep_resumes_to_the_uninterrupted_result(impacts, reference, tmp_path):
    out = tmp_path / "results.parquet"
    args = ["--impacts", str(impacts), "-o", str(out), "--chunk-size", str(CHUNK)]
    # SIGKILL right after chunk 1's part file is written, before the manifest lists it.
    killed = run_cli(args, {"JAXIMPACT_SWEEP_KILL_AFTER": "1"})
    assert killed.returncode == -9, killed.stderr
    manifest = json.loads((out / "_manifest-00000.json").read_text())
    assert manifest["completed"] == [0]
    assert (out / "part-000001.parquet").exists()  # written, not listed: redone on resume
    with pytest.raises(SweepError, match="incomplete"):
        read_sweep(out)
    assert read_sweep(out, allow_partial=True).num_rows == CHUNK
    first = (out / "part-000000.parquet").stat().st_mtime_ns

    resumed = run_cli(args)
    assert resumed.returncode == 0, resumed.stderr
    assert "this run: 2 chunks" in resumed.stdout and "1 already done" in resumed.stdout
    assert (out / "part-000000.parquet").stat().st_mtime_ns == first  # finished work untouched
    got = read_sweep_columns(out)
    assert len(got["speed"]) == N  # nothing lost or duplicated
    assert_same(got, reference[1])
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp")]


def test_chosen_columns_are_stored_read_and_kept_when_continuing(impacts, reference, tmp_path):
    """``columns=``: the part files hold the inputs, status and the chosen columns, with the
    reference's numbers; continuing takes the sweep's choice, another choice is refused."""
    out = tmp_path / "few.parquet"
    first = run_sweep(
        read_impacts_file(impacts), out, chunk_size=CHUNK, progress=False,
        columns="contact_time, cor_n", process_index=0, process_count=1,
    )  # fmt: skip
    assert first.complete
    got = read_sweep_columns(out)
    inputs = ["speed", "angle_deg", "omega0", "f0"]
    assert list(got) == [*inputs, "status", "cor_n", "contact_time"]  # status first, then order
    assert_same(got, {k: reference[1][k] for k in got})
    schema = pq.read_schema(out / "part-000000.parquet")
    assert schema.names == list(got)
    again = run_sweep(read_impacts_file(impacts), out, chunk_size=CHUNK, progress=False)
    assert again.chunks_run == 0 and again.complete  # its own columns, not all of them
    with pytest.raises(SweepError, match="result_columns"):
        run_sweep(read_impacts_file(impacts), out, chunk_size=CHUNK, progress=False,
                  columns=["cor_n"])  # fmt: skip
    with pytest.raises(SweepError, match="'bogus' not a result column"):
        run_sweep(read_impacts_file(impacts), tmp_path / "new", columns="bogus,cor_n")
    assert not (tmp_path / "new").exists()


def test_compression_of_the_part_files(impacts, reference, tmp_path):
    """Uncompressed by default (the fastest to write); ``compression=`` picks a codec, with
    the same numbers; an unknown codec is refused before anything is written."""
    out = tmp_path / "zstd.parquet"
    run_sweep(read_impacts_file(impacts), out, chunk_size=CHUNK, progress=False,
              compression="zstd")  # fmt: skip
    codec = pq.ParquetFile(out / "part-000000.parquet").metadata.row_group(0).column(0)
    assert codec.compression == "ZSTD"
    assert_same(read_sweep_columns(out), reference[1])
    plain = pq.ParquetFile(reference[0] / "part-000000.parquet").metadata.row_group(0)
    assert plain.column(0).compression == "UNCOMPRESSED"
    with pytest.raises(SweepError, match="compression: 'gzip'"):
        run_sweep(read_impacts_file(impacts), tmp_path / "new", compression="gzip")
    assert not (tmp_path / "new").exists()


def test_float32_stored_results(impacts, reference, tmp_path):
    """``stored_precision="float32"``: result columns float32 (inputs float64), each the
    float64 result rounded to float32; part of the settings (continuing keeps it)."""
    out = tmp_path / "f32.parquet"
    run_sweep(read_impacts_file(impacts), out, chunk_size=CHUNK, progress=False,
              stored_precision="float32")  # fmt: skip
    schema = pq.read_schema(out / "part-000000.parquet")
    assert schema.field("speed").type == pa.float64()
    assert schema.field("cor_n").type == pa.float32() and schema.field("status").type == pa.string()
    got = read_sweep_columns(out)
    ref = reference[1]
    for name in ("cor_n", "vt_out", "omega_out", "contact_time"):
        np.testing.assert_array_equal(got[name], ref[name].astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(got["speed"], ref["speed"])
    again = run_sweep(read_impacts_file(impacts), out, chunk_size=CHUNK, progress=False)
    assert again.chunks_run == 0 and again.complete  # its own precision
    with pytest.raises(SweepError, match="stored_precision"):
        run_sweep(read_impacts_file(impacts), out, chunk_size=CHUNK, progress=False,
                  stored_precision="float64")  # fmt: skip


def test_writer_commits_in_order_while_writes_overlap():
    """Part files are written on several threads at once (the later ones may finish first);
    the manifest records them in submission order, at most ``threads`` held at a time."""
    import threading
    import time

    from jaximpact.sweep._writer import _Writer

    committed, in_flight, peak = [], [0], [0]
    lock = threading.Lock()

    def write(chunk):
        with lock:
            in_flight[0] += 1
            peak[0] = max(peak[0], in_flight[0])
        time.sleep(0.02 * (4 - chunk % 4))  # later chunks of each group finish first
        with lock:
            in_flight[0] -= 1

    writer = _Writer(write, committed.append, threads=3)
    for chunk in range(12):
        writer.submit(chunk)
    writer.finish()
    writer.close()
    assert committed == list(range(12)) and peak[0] == 3

    def broken(chunk):
        if chunk == 2:
            raise OSError("disk full")

    committed.clear()
    writer = _Writer(broken, committed.append, threads=2)
    with pytest.raises(OSError, match="disk full"):
        for chunk in range(6):
            writer.submit(chunk)
        writer.finish()
    writer.close()
    assert committed == [0, 1]  # nothing after the failed chunk is recorded


def test_rerunning_a_finished_sweep_does_nothing(impacts, reference, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(reference[0], out)
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.suffix == ".parquet"}
    summary = run_sweep(read_impacts_file(impacts), out, chunk_size=CHUNK, progress=False)
    assert summary.chunks_run == 0 and summary.chunks_skipped == 3 and summary.complete
    after = {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.suffix == ".parquet"}
    assert after == before


def test_continuing_deletes_the_temporaries_a_killed_run_left(impacts, reference, tmp_path):
    # A run killed while a writer thread was writing chunk 2 leaves its temporary behind.
    out = tmp_path / "copy"
    shutil.copytree(reference[0], out)
    manifest = out / "_manifest-00000.json"
    content = json.loads(manifest.read_text())
    content["completed"] = [0, 1]
    manifest.write_text(json.dumps(content))
    (out / "part-000002.parquet").unlink()
    stale = [out / ".part-000002.parquet.0123456789ab.tmp", out / "._manifest-00000.json.ab.tmp"]
    for path in stale:
        path.write_bytes(b"half written")
    summary = run_sweep(read_impacts_file(impacts), out, chunk_size=CHUNK, progress=False)
    assert summary.chunks_run == 1 and summary.complete
    assert not [p.name for p in out.iterdir() if p.name.endswith(".tmp")]
    assert_same(read_sweep_columns(out), reference[1])


# ---------------------------------------------------------------------------------------------
# (3) Several devices, several processes


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_four_forced_host_devices_match_one_device(impacts, reference, tmp_path):
    flags = (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4").strip()
    env = {"XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu"}
    out = tmp_path / "four.parquet"
    run = run_cli(["--impacts", str(impacts), "-o", str(out), "--chunk-size", str(CHUNK)], env)
    assert run.returncode == 0, run.stderr
    assert "on 4 devices;" in run.stdout
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
    assert {p.name for p in out.glob("*manifest-*.json")} == {
        "_manifest-00000.json",
        "_manifest-00001.json",
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
    with pytest.raises(SweepError, match=r"angle_deg must be finite and in \(-90, 90\) deg"):
        GridSource(parse_grid(["angle_deg=-90:90:5"]), defaults)
    with pytest.raises(SweepError, match=r"f0 must be finite and in \[0, 1e6\] N/m"):
        GridSource(parse_grid(["f0=-1,1"]), defaults)


def test_cli_reports_bad_grid_with_status_2(tmp_path, capsys):
    assert main(["sweep", "--grid", "speed=1:5", "-o", str(tmp_path / "o"), "--no-progress"]) == 2
    assert "error: grid 'speed=1:5': expected NAME=VALUE" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_default_chunk_size_by_precision_and_kept_when_continuing(impacts, reference, tmp_path):
    from jaximpact.sweep import default_chunk_size

    assert default_chunk_size(np.float64) == 8192
    assert default_chunk_size(np.float32) == 32768
    assert default_chunk_size(np.float32, devices=2) == 32768
    # a sweep begun with 64-impact chunks continues with them when no chunk size is given
    out = tmp_path / "copy"
    shutil.copytree(reference[0], out)
    summary = run_sweep(read_impacts_file(impacts), out, progress=False)
    assert (summary.chunk_size, summary.chunks_run, summary.chunks_skipped) == (CHUNK, 0, 3)
    assert summary.complete


def test_changed_settings_are_refused_unless_restart(impacts, reference, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(reference[0], out)
    with pytest.raises(SweepError) as err:
        run_sweep(read_impacts_file(impacts), out, chunk_size=32, progress=False)
    assert str(err.value) == (
        f"{out}: a sweep made with other settings: chunk_size: 64 in the sweep, 32 now. "
        "Use --restart to discard its results, or another -o"
    )
    changed = write_impacts(tmp_path / "changed.csv", seed=1)
    with pytest.raises(SweepError, match=r"other settings: impacts file: other content, sha256"):
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


def test_refusal_names_every_setting_that_differs():
    from jaximpact.sweep._store import _setting_differences

    grid = {"grid": [["speed", ["1.0", "2.0"]]], "defaults": {"angle_deg": "0.0", "omega0": "0.0"}}
    old = {
        "format": "jaximpact-sweep/1",
        "jaximpact": "0.1.0",
        "scene": "embedded Table 1",
        "scene_sha256": "a" * 64,
        "impacts": grid,
        "precision": "float64",
        "chunk_size": 8192,
    }
    assert _setting_differences(old, dict(old)) == ["the settings hash differs"]
    new = {
        **old,
        "jaximpact": "0.2.0",
        "scene": "mine.toml",
        "scene_sha256": "b" * 64,
        "impacts": {"grid": [["speed", ["1.0", "3.0"]]], "defaults": {**grid["defaults"]}},
        "precision": "float32",
        "chunk_size": 1024,
    }
    new["impacts"]["defaults"]["omega0"] = "100.0"
    assert _setting_differences(old, new) == [
        "jaximpact version: 0.1.0 in the sweep, 0.2.0 now",
        "scene: other content, embedded Table 1 in the sweep, mine.toml now",
        "grid speed: 1.0,2.0 in the sweep, 1.0,3.0 now",
        "omega0 (the scene's [impact]): 0.0 in the sweep, 100.0 now",
        "precision: float64 in the sweep, float32 now",
        "chunk_size: 8192 in the sweep, 1024 now",
    ]
    axes = {"grid": [["speed", [str(float(v)) for v in range(10)]]], "defaults": grid["defaults"]}
    assert _setting_differences({**old, "impacts": axes}, {**old, "impacts": grid}) == [
        "grid speed: 10 values 0.0..9.0 in the sweep, 1.0,2.0 now"
    ]
    assert _setting_differences(old, {**old, "impacts": {"impacts_sha256": "c" * 64}}) == [
        "impacts: a grid in the sweep, an impacts file now"
    ]
    # two changes, one of them a stored-output setting: both named (only the chunk size was)
    assert _setting_differences(
        old, {**old, "chunk_size": 1024, "result_columns": ["status", "cor_n"]}
    ) == [
        "chunk_size: 8192 in the sweep, 1024 now",
        "result_columns: None in the sweep, ['status', 'cor_n'] now",
    ]


def test_read_sweep_rejects_what_is_not_a_sweep(tmp_path):
    with pytest.raises(SweepError, match="no sweep manifest"):
        read_sweep(tmp_path)


@pytest.mark.slow  # compiles programs of its own: CI's second step
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
    # Two devices with XLA's default compilation, as in this process: the CLI's loop kernels
    # (its default) compile the same arithmetic differently, and the results here compare bits.
    env["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
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
    assert "this run: 1 chunk, 64 impacts" in outputs[0][0]  # chunk 0 (of 0, 1)
    assert "this run: 1 chunk, 36 impacts" in outputs[1][0]  # chunk 1, the padded one
    manifests = sorted(p.name for p in out.glob("*manifest-*.json"))
    assert manifests == ["_manifest-00000.json", "_manifest-00001.json"]
    got = read_sweep_columns(out)
    assert len(got["speed"]) == 100
    # Against one process (same chunks): simulate on one batch of 100 may differ in its
    # vectorized tail rows at the solver-tolerance level (a rounding flips a step decision).
    source = GridSource(parse_grid(grid[1::2]), {"speed": 1.0, "angle_deg": 0.0, "omega0": 0.0})
    run_sweep(source, tmp_path / "one", chunk_size=CHUNK, progress=False)
    assert_same(got, read_sweep_columns(tmp_path / "one"), rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# (5) The Parquet layout: any reader, units, sweeps of the older layout


def _pyarrow_read_table(out):
    table = pq.read_table(out)
    return table.column_names, table.column("speed").to_numpy()


def _pyarrow_dataset(out):
    import pyarrow.dataset as ds

    table = ds.dataset(out).to_table()
    return table.column_names, table.column("speed").to_numpy()


def _pandas(out):
    pd = pytest.importorskip("pandas")
    frame = pd.read_parquet(out)
    return list(frame.columns), frame["speed"].to_numpy()


def _polars(out):
    pl = pytest.importorskip("polars")
    frame = pl.read_parquet(f"{out}/*.parquet")  # a bare directory: polars wants a glob
    return frame.columns, frame["speed"].to_numpy()


def _duckdb(out):
    duckdb = pytest.importorskip("duckdb")
    relation = duckdb.sql(f"SELECT * FROM read_parquet('{out}/*.parquet')")
    return relation.columns, relation.fetchnumpy()["speed"]


@pytest.mark.parametrize(
    "reader", [_pyarrow_read_table, _pyarrow_dataset, _pandas, _polars, _duckdb]
)
def test_parquet_readers_open_the_sweep_directory(reader, reference, tmp_path):
    out = tmp_path / "results.parquet"
    shutil.copytree(reference[0], out)
    # What a kill during an atomic write leaves behind: readers must skip these as well.
    (out / ".part-000003.parquet.0123456789ab.tmp").write_bytes(b"PAR1 torn")
    (out / "._manifest-00000.json.0123456789ab.tmp").write_text("{")
    columns, speed = reader(out)
    assert list(columns) == list(reference[1])
    np.testing.assert_array_equal(np.sort(speed), np.sort(reference[1]["speed"]))


def test_units_are_parquet_field_metadata(reference):
    out = reference[0]
    for table in (pq.read_schema(out / "part-000000.parquet"), read_sweep(out).schema):
        for name in table.names:
            unit = COLUMN_UNITS[name]
            assert table.field(name).metadata == ({b"unit": unit.encode()} if unit else None)
    assert pq.read_table(out).schema.field("speed").metadata == {b"unit": b"m/s"}
    assert read_sweep(out).schema.field("contact_time").metadata == {b"unit": b"s"}


def test_failure_reason_is_null_unless_failed(reference):
    table = read_sweep(reference[0])
    failed = np.array(table.column("status").to_pylist()) == "failed"
    reasons = table.column("failure_reason")
    assert reasons.null_count == np.sum(~failed)
    assert (read_sweep_columns(reference[0])["failure_reason"] == "").sum() == np.sum(~failed)


def make_old_layout(out):
    """Turn a sweep into one written before failure_reason: manifest-*.json names, parts
    without failure_reason nor units, no result_columns / failures in the manifest."""
    new = out / "_manifest-00000.json"
    manifest = json.loads(new.read_text())
    del manifest["result_columns"], manifest["failures"]
    new.unlink()
    for part in out.glob("part-*.parquet"):
        table = pq.read_table(part).drop_columns(["failure_reason"])
        bare = pa.Table.from_arrays(table.columns, names=table.column_names)
        pq.write_table(bare.replace_schema_metadata(table.schema.metadata), part)
    return manifest


def test_old_layout_sweep_reads_and_resumes_with_one_schema(impacts, reference, tmp_path):
    out = tmp_path / "old.parquet"
    shutil.copytree(reference[0], out)
    manifest = make_old_layout(out)
    (out / "manifest-00000.json").write_text(json.dumps(manifest))
    table = read_sweep(out)
    assert table.column_names == list(reference[1])
    assert table.column("failure_reason").null_count == N
    assert_same(read_sweep_columns(out), reference[1])

    # Interrupted before chunk 2: the resume renames the manifest and keeps the old columns.
    manifest["completed"] = [0, 1]
    (out / "manifest-00000.json").write_text(json.dumps(manifest))
    (out / "part-000002.parquet").unlink()
    summary = run_sweep(read_impacts_file(impacts), out, chunk_size=CHUNK, progress=False)
    assert summary.chunks_run == 1 and summary.complete and summary.legacy_columns
    assert sorted(p.name for p in out.glob("*manifest*")) == ["_manifest-00000.json"]
    schemas = {tuple(pq.read_schema(p).names) for p in out.glob("part-*.parquet")}
    assert schemas == {tuple(n for n in reference[1] if n != "failure_reason")}
    assert pq.read_table(out).num_rows == N
    assert_same(read_sweep_columns(out), reference[1])


# ---------------------------------------------------------------------------------------------
# (6) Progress bar, files, failures


def test_no_progress_bar_for_short_work(impacts, reference, tmp_path, capsys):
    out = tmp_path / "copy"
    shutil.copytree(reference[0], out)
    run_sweep(read_impacts_file(impacts), out, chunk_size=CHUNK)  # nothing left to do
    small = read_impacts_file(write_impacts(tmp_path / "small.csv", n=40))
    run_sweep(small, tmp_path / "small", chunk_size=CHUNK)  # one chunk
    assert capsys.readouterr().err == ""


def test_non_sweep_directory_is_refused(impacts, tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    for restart in (False, True):
        with pytest.raises(SweepError) as err:
            run_sweep(read_impacts_file(impacts), mine, chunk_size=CHUNK, restart=restart)
        assert str(err.value) == (
            f"{mine}: not empty and not a sweep output (no _manifest-*.json; it holds "
            "'notes.txt'); choose a new or empty directory for -o"
        )
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]


def test_unwritable_output_is_refused_before_computing(impacts, tmp_path, monkeypatch):
    import jaximpact.sweep._run as sweep_module

    def no_computing(*args, **kwargs):
        raise AssertionError("computed before checking the output")

    real_open = os.open

    def read_only(path, *args, **kwargs):
        if "_write-test-" in str(path):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(sweep_module, "_model_config", no_computing)
    monkeypatch.setattr(os, "open", read_only)
    with pytest.raises(SweepError) as err:
        run_sweep(read_impacts_file(impacts), tmp_path / "a" / "b", chunk_size=CHUNK)
    assert str(err.value) == (
        f"{tmp_path / 'a' / 'b'}: cannot write in the output directory (Permission denied)"
    )
    assert not list((tmp_path / "a" / "b").iterdir())  # created (parents too), left empty


def _file_problem(tmp_path, case):
    """``(arguments, the path the message must name, its reason)`` for a bad-file case."""
    good = ["--grid", "speed=1"]
    out = tmp_path / "out.parquet"
    if case == "missing impacts":
        return ["--impacts", str(tmp_path / "nope.csv"), "-o", str(out)], "nope.csv", "No such"
    if case == "impacts is a directory":
        return ["--impacts", str(tmp_path), "-o", str(out)], str(tmp_path), "Is a directory"
    if case == "impacts not Parquet":
        (tmp_path / "bad.parquet").write_text("speed,angle_deg\n1,0\n")
        return (
            ["--impacts", str(tmp_path / "bad.parquet"), "-o", str(out)],
            "bad.parquet",
            "not a readable Parquet file",
        )
    if case == "impacts unreadable":
        (tmp_path / "secret.csv").write_text("speed,angle_deg\n1,0\n")
        (tmp_path / "secret.csv").chmod(0)
        return ["--impacts", str(tmp_path / "secret.csv"), "-o", str(out)], "secret", "denied"
    if case == "output is a file":
        out.write_text("")
        return [*good, "-o", str(out)], str(out), "exists and is not a directory"
    if case == "output parent is a file":
        (tmp_path / "file").write_text("")
        target = tmp_path / "file" / "sub" / "out.parquet"
        return [*good, "-o", str(target)], str(target), f"({tmp_path / 'file'} is not a directory)"
    if case == "output read-only":
        out.mkdir()
        out.chmod(0o555)
        return [*good, "-o", str(out)], str(out), "cannot write in the output directory"
    if case == "output not a sweep":
        out.mkdir()
        (out / "thesis.tex").write_text("")
        return [*good, "-o", str(out)], str(out), "not empty and not a sweep output"
    raise AssertionError(case)


@pytest.mark.parametrize(
    "case",
    [
        "missing impacts",
        "impacts is a directory",
        "impacts not Parquet",
        "impacts unreadable",
        "output is a file",
        "output parent is a file",
        "output read-only",
        "output not a sweep",
    ],
)
def test_file_problems_exit_2_with_one_line(case, tmp_path):
    if case in ("impacts unreadable", "output read-only") and os.geteuid() == 0:
        pytest.skip("root reads and writes regardless of permissions")
    args, path, reason = _file_problem(tmp_path, case)
    run = run_cli(args, timeout=120)
    assert run.returncode == 2, run.stderr
    assert run.stdout == ""
    line = run.stderr.strip()
    assert "\n" not in line and "Traceback" not in line
    assert line.startswith("error: ") and path in line and reason in line, line


@pytest.fixture(scope="module")
def step_limited_scene(tmp_path_factory):
    """Table 1 with a step limit that normal impacts (about 180-240 steps) stay under and
    oblique ones at 40 deg (about 270-330) exceed (no initial spin)."""
    path = tmp_path_factory.mktemp("scene") / "limited.toml"
    scene = Path(ji.default_scene_path()).read_text()
    path.write_text(scene + "\n[solver]\nmax_steps = 250\n")
    return path


def test_failures_are_counted_per_reason_and_all_failed_exits_1(
    step_limited_scene, tmp_path, capsys
):
    grid = ["--grid", "speed=0.3:4:8:log", "--grid", "angle_deg=0,40", "--grid", "omega0=0"]
    out = tmp_path / "mixed.parquet"
    common = ["--chunk-size", str(CHUNK), "--no-progress"]
    assert main(["sweep", str(step_limited_scene), *grid, "-o", str(out), *common]) == 0
    explained = "8 max_steps (the solver's step limit was reached)"
    assert capsys.readouterr().err == (
        f"warning: 8 of 16 impacts failed: {explained}; see the status and failure_reason columns\n"
    )
    got = read_sweep_columns(out)
    failed = got["status"] == "failed"
    np.testing.assert_array_equal(failed, got["angle_deg"] == 40)
    np.testing.assert_array_equal(got["failure_reason"], np.where(failed, "max_steps", ""))
    assert read_sweep(out).column("failure_reason").null_count == 8
    manifest = json.loads((out / "_manifest-00000.json").read_text())
    assert manifest["failures"] == {"max_steps": 8}

    grid[3] = "angle_deg=40"
    out = tmp_path / "all.parquet"
    assert main(["sweep", str(step_limited_scene), *grid, "-o", str(out), *common]) == 1
    assert capsys.readouterr().err == (
        f"error: all 8 impacts of the sweep failed: {explained}; see the failure_reason column\n"
    )
    assert read_sweep(out).num_rows == 8  # the results are written all the same


def test_describe_failures_orders_by_count():
    from jaximpact.sweep import describe_failures

    assert describe_failures({"nonfinite": 1, "max_steps": 2, "unrecorded": 1}) == (
        "2 max_steps (the solver's step limit was reached), 1 nonfinite (the state became NaN "
        "or infinite), 1 unrecorded (written before failure_reason was recorded)"
    )

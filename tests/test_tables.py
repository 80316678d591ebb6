"""Tests of the impacts/results CSV layer (jaximpact.tables)."""

import math
import os

import numpy as np
import pytest

from jaximpact import tables
from jaximpact.tables import (
    IMPACT_PARAMETER_COLUMNS,
    RESULT_COLUMNS,
    ImpactTable,
    TableError,
    atomic_write_text,
    read_impacts,
    read_results,
    write_results,
)


def write(tmp_path, text, name="impacts.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def results_for(n, **changes):
    """A complete results mapping for ``n`` rows, with distinct exact values."""
    results = {"status": ["rebound"] * n}
    for k, name in enumerate(RESULT_COLUMNS[1:]):
        results[name] = np.arange(n) + k / 7.0
    results.update(changes)
    return results


# ----------------------------------------------------------------------------------------------
# Reading


def test_read_impacts_with_comments_blank_lines_whitespace_and_overrides(tmp_path):
    path = write(
        tmp_path,
        "# batch for a test\n"
        "#\n"
        "\n"
        " speed , angle_deg, omega0 ,friction,K\n"
        "1.5, 10, 0, 0.3, 1e11\n"
        "# a comment between rows\n"
        "\n"
        "2.0 ,-40.5 ,100,0.1 , 2e11   \n",
    )
    table = read_impacts(path)
    assert len(table) == 2
    assert table.columns == ("speed", "angle_deg", "omega0", "friction", "K")
    np.testing.assert_array_equal(table.speed, [1.5, 2.0])
    np.testing.assert_array_equal(table.angle_deg, [10.0, -40.5])
    np.testing.assert_array_equal(table.omega0, [0.0, 100.0])
    assert set(table.overrides) == {"friction", "K"}
    np.testing.assert_array_equal(table.overrides["friction"], [0.3, 0.1])
    np.testing.assert_array_equal(table.lines, [5, 8])
    assert table.source == str(path)
    assert table.overrides_at(1) == {"friction": 0.1, "K": 2e11}
    assert list(table.as_columns()) == list(table.columns)
    for array in (table.speed, table.angle_deg, table.omega0, table.overrides["K"]):
        assert array.dtype == np.float64
        assert not array.flags.writeable  # the frozen table cannot be changed through its arrays


def test_omega0_defaults_to_zero_and_is_not_an_input_column(tmp_path):
    table = read_impacts(write(tmp_path, "angle_deg,speed\n30,1\n-30,2\n"))
    np.testing.assert_array_equal(table.omega0, [0.0, 0.0])
    assert table.columns == ("angle_deg", "speed")
    assert table.overrides == {}


def test_crlf_and_byte_order_mark(tmp_path):
    path = tmp_path / "excel.csv"
    path.write_bytes("\ufeff# c\r\nspeed,angle_deg\r\n1,0\r\n2,x\r\n".encode())
    with pytest.raises(TableError, match="line 4, column 'angle_deg'"):
        read_impacts(path)


BAD_IMPACTS = [
    # (file text, line, column or None, a fragment of the problem)
    ("# c\nspeed\n1\n", 2, "angle_deg", "required column missing"),
    ("# c\nangle_deg\n1\n", 2, "speed", "required column missing"),
    ("speed,angle_deg,colour\n1,0,2\n", 1, "colour", "allowed columns: speed, angle_deg, omega0"),
    ("speed,angle_deg,speed\n1,0,1\n", 1, "speed", "named twice"),
    ("# c\n# c\nspeed,angle_deg\n1,0\n\n1,0,3\n", 6, None, "expected 2 fields"),
    ("speed,angle_deg\n1\n", 2, None, "found 1"),
    ("speed,angle_deg\n1,0\nfast,0\n", 3, "speed", "not a number: 'fast'"),
    ("speed,angle_deg\n1,\n", 2, "angle_deg", "empty value"),
    ("speed,angle_deg\n1,nan\n", 2, "angle_deg", "finite"),
    ("speed,angle_deg\ninf,0\n", 2, "speed", "finite"),
    ("speed,angle_deg\n0,0\n", 2, "speed", "> 0"),
    ("speed,angle_deg\n-1,0\n", 2, "speed", "> 0"),
    ("speed,angle_deg\n1,90\n", 2, "angle_deg", "-90 < angle_deg < 90"),
    ("speed,angle_deg\n1,-90\n", 2, "angle_deg", "-90 < angle_deg < 90"),
    ("speed,angle_deg\n1,120\n", 2, "angle_deg", "-90 < angle_deg < 90"),
    ("speed,angle_deg,omega0\n1,0,-inf\n", 2, "omega0", "finite"),
    ("speed,angle_deg,radius\n1,0,0\n", 2, "radius", "radius must be finite and > 0"),
    ("speed,angle_deg,density\n1,0,-1\n", 2, "density", "> 0"),
    ("speed,angle_deg,K\n1,0,0\n", 2, "K", "> 0"),
    ("speed,angle_deg,f0\n1,0,-0.1\n", 2, "f0", "f0 must be finite and >= 0"),
    ("speed,angle_deg,C_A\n1,0,-1\n", 2, "C_A", ">= 0"),
    ("speed,angle_deg,C_H\n1,0,-1\n", 2, "C_H", ">= 0"),
    ("speed,angle_deg,friction\n1,0,-0.3\n", 2, "friction", ">= 0"),
    ("speed,angle_deg,lambda\n1,0,-1e-9\n", 2, "lambda", ">= 0"),
    ("# only a header\nspeed,angle_deg\n# and comments\n\n", 2, None, "no data rows"),
]


@pytest.mark.parametrize(("text", "line", "column", "problem"), BAD_IMPACTS)
def test_read_impacts_errors_name_file_line_and_column(tmp_path, text, line, column, problem):
    path = write(tmp_path, text)
    with pytest.raises(TableError) as info:
        read_impacts(path)
    message = str(info.value)
    assert isinstance(info.value, ValueError)
    assert message.startswith(str(path))
    assert f"line {line}" in message
    assert problem in message
    if column is not None:
        assert f"column '{column}'" in message
    assert (info.value.line, info.value.column) == (line, column)


def test_allowed_parameter_values_at_the_bounds_are_accepted(tmp_path):
    header = "speed,angle_deg," + ",".join(IMPACT_PARAMETER_COLUMNS)
    zeros = {"f0", "C_A", "C_H", "friction", "lambda"}
    row = "1e-6,89.999," + ",".join("0" if n in zeros else "1e-9" for n in IMPACT_PARAMETER_COLUMNS)
    table = read_impacts(write(tmp_path, f"{header}\n{row}\n"))
    assert set(table.overrides) == set(IMPACT_PARAMETER_COLUMNS)


def test_empty_file_has_no_header(tmp_path):
    with pytest.raises(TableError, match="no header"):
        read_impacts(write(tmp_path, "# nothing here\n\n"))


def test_impact_table_built_in_code_is_validated():
    table = ImpactTable(speed=[1.0, 2.0], angle_deg=[0.0, 45.0])
    assert table.columns == ("speed", "angle_deg")
    np.testing.assert_array_equal(table.omega0, [0.0, 0.0])
    assert table.lines is None
    with pytest.raises(TableError, match=r"row 1: value -1\.0 out of range"):
        ImpactTable(speed=[1.0, -1.0], angle_deg=[0.0, 0.0])
    with pytest.raises(TableError, match="length"):
        ImpactTable(speed=[1.0, 2.0], angle_deg=[0.0])
    with pytest.raises(TableError, match="unknown parameter"):
        ImpactTable(speed=[1.0], angle_deg=[0.0], overrides={"colour": [1.0]})
    with pytest.raises(TableError, match="no rows"):
        ImpactTable(speed=[], angle_deg=[])


# ----------------------------------------------------------------------------------------------
# Writing


def test_write_results_round_trip_column_order_and_exact_floats(tmp_path):
    table = read_impacts(write(tmp_path, "speed,angle_deg,friction\n1.66,40,0.3\n1.66,-40,0.1\n"))
    awkward = [0.1 + 0.2, 1 / 3]
    results = results_for(
        2,
        status=["rebound", "captured"],
        vn_out=awkward,
        cor_t=[math.nan, 2.5e-300],
        roll_time=[np.nan, np.nan],
    )
    out = tmp_path / "results.csv"
    write_results(out, table, results, comments=["scene: default.toml", "two\nlines"])

    lines = out.read_text().splitlines()
    assert lines[:3] == ["# scene: default.toml", "# two", "# lines"]
    assert lines[3] == "speed,angle_deg,friction," + ",".join(RESULT_COLUMNS)
    assert lines[4].startswith("1.66,40.0,0.3,rebound,0.30000000000000004,")
    header = lines[3].split(",")
    first, second = lines[4].split(","), lines[5].split(",")
    assert first[header.index("cor_t")] == ""  # NaN is an empty field
    assert second[header.index("cor_t")] == "2.5e-300"
    assert first[header.index("roll_time")] == second[header.index("roll_time")] == ""

    back = read_results(out)
    assert list(back) == ["speed", "angle_deg", "friction", *RESULT_COLUMNS]
    np.testing.assert_array_equal(back["status"], ["rebound", "captured"])
    assert back["vn_out"].tolist() == awkward  # bit-exact
    for name in RESULT_COLUMNS[1:]:
        np.testing.assert_array_equal(back[name], np.asarray(results[name], dtype=float))
    np.testing.assert_array_equal(back["friction"], [0.3, 0.1])


def test_write_results_from_a_mapping_and_quoted_status(tmp_path):
    out = tmp_path / "r.csv"
    inputs = {"speed": [1.0], "angle_deg": [0], "omega0": [3]}
    write_results(out, inputs, results_for(1, status=["failed: step limit, 10000 steps"]))
    back = read_results(out)
    assert list(back)[:3] == ["speed", "angle_deg", "omega0"]
    assert back["status"][0] == "failed: step limit, 10000 steps"


BAD_RESULTS = [
    ({"status": None}, "missing: ['status']"),
    ({"bounce": [1.0]}, "unknown: ['bounce']"),
    ({"vn_out": [1.0, 2.0, 3.0]}, "differ in length"),
    ({"vn_out": ["fast"]}, "column 'vn_out': values are not numbers"),
    ({"status": ["re\nbound"]}, "invalid status"),
    ({"status": [""]}, "invalid status"),
    ({"status": ["# rebound"]}, "invalid status"),
]


@pytest.mark.parametrize(("change", "problem"), BAD_RESULTS)
def test_bad_results_write_nothing(tmp_path, change, problem):
    results = results_for(1)
    for name, values in change.items():
        if values is None:
            del results[name]
        else:
            results[name] = values
    out = tmp_path / "r.csv"
    with pytest.raises(TableError) as info:
        write_results(out, {"speed": [1.0], "angle_deg": [0.0]}, results)
    assert problem in str(info.value)
    assert str(out) in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_input_column_named_like_a_result_column_is_refused(tmp_path):
    with pytest.raises(TableError, match="column 'status'"):
        write_results(tmp_path / "r.csv", {"speed": [1.0], "status": [0.0]}, results_for(1))


# ----------------------------------------------------------------------------------------------
# Atomic writes


def test_atomic_write_text_replaces_whole_file(tmp_path):
    out = tmp_path / "report.json"
    atomic_write_text(out, "old\n")
    atomic_write_text(out, '{"new": true}\n')
    assert out.read_text() == '{"new": true}\n'
    assert [p.name for p in tmp_path.iterdir()] == ["report.json"]


@pytest.mark.parametrize("failing", ["replace", "fsync"])
def test_failed_write_leaves_old_file_and_no_temporary(tmp_path, monkeypatch, failing):
    out = tmp_path / "results.csv"
    out.write_text("previous results\n")

    def fail(*args, **kwargs):
        raise OSError("disk trouble")

    monkeypatch.setattr(tables.os, failing, fail)
    with pytest.raises(OSError, match="disk trouble"):
        write_results(out, {"speed": [1.0], "angle_deg": [0.0]}, results_for(1))
    assert out.read_text() == "previous results\n"
    assert [p.name for p in tmp_path.iterdir()] == ["results.csv"]


def test_interrupt_midway_removes_temporary(tmp_path, monkeypatch):
    # Even a KeyboardInterrupt between the write and the rename leaves nothing behind.
    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(tables.os, "replace", interrupt)
    with pytest.raises(KeyboardInterrupt):
        atomic_write_text(tmp_path / "x.txt", "data")
    assert list(tmp_path.iterdir()) == []


def test_unencodable_text_creates_nothing(tmp_path):
    with pytest.raises(UnicodeEncodeError):
        atomic_write_text(tmp_path / "x.txt", "bad \udc80 surrogate")
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_respects_umask(tmp_path):
    # A temporary from tempfile.mkstemp would be 0o600; results are ordinary files.
    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "x.txt", "data")
    finally:
        os.umask(old)
    assert (tmp_path / "x.txt").stat().st_mode & 0o777 == 0o644

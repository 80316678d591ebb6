"""Tests of the impacts/results CSV layer (jaximpact.tables)."""

import math
import os

import numpy as np
import pytest

from jaximpact.tables import (
    COLUMN_UNITS,
    FAILURE_REASONS,
    IMPACT_COLUMNS,
    IMPACT_PARAMETER_COLUMNS,
    OPTIONAL_RESULT_COLUMNS,
    RESULT_COLUMNS,
    TEXT_RESULT_COLUMNS,
    ImpactTable,
    TableError,
    atomic_write_text,
    parse_number,
    read_csv_rows,
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
    results = {"status": ["rebound"] * n, "failure_reason": [""] * n}
    numeric = [name for name in RESULT_COLUMNS if name not in TEXT_RESULT_COLUMNS]
    for k, name in enumerate(numeric):
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
    ("speed,angle_deg\n0,0\n", 2, "speed", "speed must be finite and in (0, 1000] m/s"),
    ("speed,angle_deg\n-1,0\n", 2, "speed", "(0, 1000] m/s"),
    ("speed,angle_deg\n1,90\n", 2, "angle_deg", "angle_deg must be finite and in (-90, 90) deg"),
    ("speed,angle_deg\n1,-90\n", 2, "angle_deg", "angle_deg must be finite and in (-90, 90) deg"),
    ("speed,angle_deg\n1,120\n", 2, "angle_deg", "angle_deg must be finite and in (-90, 90) deg"),
    ("speed,angle_deg,omega0\n1,0,-inf\n", 2, "omega0", "finite"),
    ("speed,angle_deg,radius\n1,0,0\n", 2, "radius", "radius must be finite and in [1e-9, 1] m"),
    ("speed,angle_deg,density\n1,0,-1\n", 2, "density", "(0, 1e5] kg/m^3"),
    ("speed,angle_deg,K\n1,0,0\n", 2, "K", "(0, 1e13] Pa"),
    ("speed,angle_deg,f0\n1,0,-0.1\n", 2, "f0", "f0 must be finite and in [0, 1e6] N/m"),
    ("speed,angle_deg,C_A\n1,0,-1\n", 2, "C_A", "[0, 1e4] s/m"),
    ("speed,angle_deg,C_H\n1,0,-1\n", 2, "C_H", "[0, 1e4] s/m"),
    (
        "speed,angle_deg,friction\n1,0,-0.3\n",
        2,
        "friction",
        "friction must be finite and in [0, 10]",
    ),
    ("speed,angle_deg,lambda\n1,0,-1e-9\n", 2, "lambda", "[0, 100] N m"),
    # The upper ends of the documented ranges (docs/input_ranges.md; issue 24, item 4).
    ("speed,angle_deg\n1e6,0\n", 2, "speed", "(0, 1000] m/s"),
    ("speed,angle_deg,omega0\n1,0,2e9\n", 2, "omega0", "[-1e9, 1e9] rad/s"),
    ("speed,angle_deg,radius\n1,0,35\n", 2, "radius", "[1e-9, 1] m"),
    ("speed,angle_deg,friction\n1,0,11\n", 2, "friction", "[0, 10]"),
    ("speed,angle_deg,K\n1,0,1e14\n", 2, "K", "(0, 1e13] Pa"),
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


LOCATED = [
    # (file content, line, column or None, a fragment of the problem): lines count as in an
    # editor, comment and blank lines included
    pytest.param(
        "# a\n# b\nspeed,angle_deg\n1,0\n# c\n\nfast,0\n",
        7,
        "speed",
        "not a number: 'fast'",
        id="not-a-number",
    ),
    pytest.param(
        "# a\n\n# b\nspeed\n1\n", 4, "angle_deg", "required column missing", id="missing-column"
    ),
    pytest.param(
        "# a\nspeed,angle_deg\n# b\n1,0\n#c\n1,95\n",
        6,
        "angle_deg",
        "angle_deg must be finite and in (-90, 90) deg",
        id="out-of-range",
    ),
    pytest.param(
        "# a\nspeed,angle_deg\n1,0\n# b\n\n1,0,7\n",
        6,
        None,
        "expected 2 fields (speed, angle_deg), found 3",
        id="ragged-long",
    ),
    pytest.param("# a\nspeed,angle_deg\n\n2\n", 4, None, "found 1", id="ragged-short"),
    pytest.param(
        '# a\nspeed,angle_deg\n"1,5",0\n', 3, "speed", "not a number: '1,5'", id="quoted-comma"
    ),
    pytest.param(
        '# a\n"speed","angle,deg"\n1,0\n', 2, "angle,deg", "unknown column", id="quoted-header"
    ),
    pytest.param(
        '# a\nspeed,angle_deg\n1,0\n# b\n"2,0\n3,0\n',
        5,
        None,
        "quoted field is not closed",
        id="unclosed-quote",
    ),
    pytest.param('speed,angle_deg\n1,"0', 2, None, "not closed", id="unclosed-quote-at-end"),
    pytest.param(
        '# a\nspeed,"angle_deg\n1,0\n', 2, None, "not a complete CSV line", id="unclosed-header"
    ),
    pytest.param(
        "\ufeff# a\nspeed,angle_deg\n1,0\n1,-91\n", 4, "angle_deg", "(-90, 90) deg", id="bom"
    ),
    pytest.param(
        "\ufeffspeed,angle_deg\n0,0\n", 2, "speed", "(0, 1000] m/s", id="bom-before-header"
    ),
    pytest.param(
        "# a\r\n\r\nspeed,angle_deg\r\n1,0\r\n# b\r\n1,x\r\n", 6, "angle_deg", "'x'", id="crlf"
    ),
    pytest.param("# a\rspeed,angle_deg\r1,x\r", 3, "angle_deg", "'x'", id="cr"),
    pytest.param(b"# a\nspeed,angle_deg\n1,\xff\n", 3, None, "not UTF-8", id="not-utf8"),
    pytest.param("", None, None, "no header row", id="empty-file"),
    pytest.param("# only\n\n#  comments\n", None, None, "no header row", id="only-comments"),
    pytest.param("# a\nspeed,angle_deg\n# b\n\n", 2, None, "no data rows", id="no-rows"),
]


@pytest.mark.parametrize(("content", "line", "column", "problem"), LOCATED)
def test_errors_are_located_as_an_editor_shows_them(tmp_path, content, line, column, problem):
    path = tmp_path / "impacts.csv"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(TableError) as info:
        read_impacts(path)
    error = info.value
    where = ", ".join(
        [str(path)]
        + ([f"line {line}"] if line is not None else [])
        + ([f"column '{column}'"] if column is not None else [])
    )
    assert str(error).startswith(f"{where}: ")
    assert problem in str(error)
    assert (error.path, error.line, error.column) == (str(path), line, column)


def test_crlf_bom_and_quotes_read_like_plain_text(tmp_path):
    plain = read_impacts(write(tmp_path, "# c\nspeed,angle_deg,K\n1.5,10,1e11\n\n2,-20,2e11\n"))
    path = tmp_path / "excel.csv"
    path.write_bytes(
        '\ufeff# c\r\n"speed", angle_deg ,K\r\n" 1.5 ",10,1e11\r\n\r\n2,"-20", 2e11 \r\n'.encode()
    )
    fancy = read_impacts(path)
    assert fancy.columns == plain.columns == ("speed", "angle_deg", "K")
    for name in ("speed", "angle_deg", "omega0"):
        np.testing.assert_array_equal(getattr(fancy, name), getattr(plain, name))
    np.testing.assert_array_equal(fancy.overrides["K"], plain.overrides["K"])
    np.testing.assert_array_equal(fancy.lines, plain.lines)
    np.testing.assert_array_equal(fancy.lines, [3, 5])


def test_results_errors_are_located(tmp_path):
    out = tmp_path / "r.csv"
    write_results(out, {"speed": [1.0, 2.0], "angle_deg": [0.0, 0.0]}, results_for(2))
    header, first, second = out.read_text().splitlines()
    fields = second.split(",")
    fields[header.split(",").index("energy_in")] = "lots"
    path = write(tmp_path, f"# a\n{header}\n# b\n{first}\n\n{','.join(fields)}\n", "edited.csv")
    with pytest.raises(TableError) as info:
        read_results(path)
    assert (info.value.line, info.value.column) == (6, "energy_in")
    assert "not a number: 'lots'" in str(info.value)

    path = write(tmp_path, "# a\nspeed,angle_deg,status\n1,0,rebound\n", "short.csv")
    with pytest.raises(TableError, match=r"short\.csv, line 2: the header must end with"):
        read_results(path)


def test_large_file_keeps_every_row_and_its_line(tmp_path):
    # Several pyarrow blocks (about 1 MiB each): line numbers must not drift at block borders.
    rows = [f"{1 + k % 97}.{k:06d},{(k % 170) - 85}" for k in range(120_000)]
    text = "# big\nspeed,angle_deg\n"
    for k, row in enumerate(rows):
        text += row + "\n" + ("# every 1000\n\n" if k % 1000 == 999 else "")
    path = write(tmp_path, text, "big.csv")
    table = read_impacts(path)
    assert len(table) == len(rows)
    assert table.lines[0] == 3 and table.lines[-1] == 3 + len(rows) - 1 + 2 * (
        len(rows) // 1000 - 1
    )
    assert table.speed[-1] == float(rows[-1].split(",")[0])
    lines = text.splitlines()
    bad = lines.index(rows[-500])
    lines[bad] = rows[-500] + ",3"
    write(tmp_path, "\n".join(lines) + "\n", "big.csv")
    with pytest.raises(TableError) as info:
        read_impacts(path)
    assert info.value.line == bad + 1
    assert "found 3" in str(info.value)


NUMBERS = ["1", "-2.5", "+3", "1.", ".5", "1e3", "1E-3", "+.5e+2", "007", " 4 "]
NOT_NUMBERS = ["1_000", "0x10", "1e", "e5", ".", "1.2.3", "one", "\u0661", "1 2", "--1"]


@pytest.mark.parametrize("text", NUMBERS)
def test_numbers_read_as_python_reads_them(tmp_path, text):
    assert parse_number(text) == float(text)
    table = read_impacts(write(tmp_path, f"speed,angle_deg,omega0\n1,0,0\n2,0,{text}\n"))
    assert table.omega0[1] == float(text)


@pytest.mark.parametrize("text", NOT_NUMBERS)
def test_not_numbers_are_refused_alike(tmp_path, text):
    with pytest.raises(TableError, match="line 7, column 'x': not a number"):
        parse_number(text, line=7, column="x")
    path = write(tmp_path, f"# c\nspeed,angle_deg\n1,0\n2,{text}\n")
    with pytest.raises(TableError) as info:
        read_impacts(path)
    assert (info.value.line, info.value.column) == (4, "angle_deg")
    assert f"not a number: {text.strip()!r}" in str(info.value)


def test_read_csv_rows_structure(tmp_path):
    path = write(
        tmp_path,
        "\n# Title\n#\n#   indented\n\n# last\n\n a , b ,c\n1, x ,\n# mid\n\n2,,nan\n",
    )
    rows = read_csv_rows(path)
    assert rows.preamble == ("Title", "", "  indented", "", "last")
    assert (rows.header, rows.header_line, len(rows)) == (("a", "b", "c"), 8, 2)
    assert rows.lines.tolist() == [9, 12]
    assert list(rows.records()) == [
        (9, {"a": "1", "b": "x", "c": ""}),
        (12, {"a": "2", "b": "", "c": "nan"}),
    ]
    np.testing.assert_array_equal(rows.numbers("a"), [1.0, 2.0])
    np.testing.assert_array_equal(rows.numbers("c", empty_as_nan=True), [np.nan, np.nan])
    with pytest.raises(TableError, match="line 9, column 'c': empty value"):
        rows.numbers("c")
    with pytest.raises(TableError, match="line 9, column 'b': not a number: 'x'"):
        rows.numbers("b", empty_as_nan=True)


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
    table = read_impacts(
        write(tmp_path, "speed,angle_deg,friction\n1.66,40,0.3\n1.66,-40,0.1\n1,0,0\n")
    )
    awkward = [0.1 + 0.2, 1 / 3, -0.0]
    results = results_for(
        3,
        status=["rebound", "captured", "failed"],
        failure_reason=["", "", "max_steps"],
        vn_out=awkward,
        cor_t=[math.nan, 2.5e-300, math.inf],
        roll_time=[np.nan, np.nan, np.nan],
    )
    out = tmp_path / "results.csv"
    write_results(out, table, results, comments=["scene: default.toml", "two\nlines"])

    lines = out.read_text().splitlines()
    assert lines[:3] == ["# scene: default.toml", "# two", "# lines"]
    assert lines[3] == "speed,angle_deg,friction," + ",".join(RESULT_COLUMNS)
    assert lines[4].startswith("1.66,40.0,0.3,rebound,0.30000000000000004,")
    assert lines[4].endswith(",")  # no failure reason: the last field is empty
    assert lines[6].endswith(",max_steps")
    header = lines[3].split(",")
    first, second, third = (line.split(",") for line in lines[4:7])
    assert first[header.index("cor_t")] == ""  # NaN is an empty field
    assert second[header.index("cor_t")] == "2.5e-300"
    assert third[header.index("cor_t")] == "inf"
    assert first[header.index("roll_time")] == second[header.index("roll_time")] == ""

    back = read_results(out)
    assert list(back) == ["speed", "angle_deg", "friction", *RESULT_COLUMNS]
    np.testing.assert_array_equal(back["status"], ["rebound", "captured", "failed"])
    np.testing.assert_array_equal(back["failure_reason"], ["", "", "max_steps"])
    assert back["vn_out"].tolist() == awkward  # bit-exact
    assert math.copysign(1.0, back["vn_out"][2]) == -1.0  # even the sign of zero
    for name in RESULT_COLUMNS:
        if name not in TEXT_RESULT_COLUMNS:
            expected = np.asarray(results[name], dtype=float)
            np.testing.assert_array_equal(back[name], expected, err_msg=name)
            assert back[name].dtype == np.float64
            assert back[name].flags.writeable  # plain arrays, as before
    np.testing.assert_array_equal(back["friction"], [0.3, 0.1, 0.0])


def test_write_results_from_a_mapping_and_quoted_status(tmp_path):
    out = tmp_path / "r.csv"
    inputs = {"speed": [1.0, 2.0], "angle_deg": [0, 1], "omega0": [3, 4]}
    status = ["failed: step limit, 10000 steps", 'said "no", twice']
    write_results(out, inputs, results_for(2, status=status))
    assert '"said ""no"", twice"' in out.read_text()  # quoted, inner quotes doubled
    back = read_results(out)
    assert list(back)[:3] == ["speed", "angle_deg", "omega0"]
    assert back["status"].tolist() == status
    np.testing.assert_array_equal(back["omega0"], [3.0, 4.0])  # no field shifted by a comma


def test_old_results_file_without_failure_reason_reads_back(tmp_path):
    old_columns = RESULT_COLUMNS[:-1]
    assert old_columns[-1] == "loss_rolling"
    numbers = ",".join(str(k) for k in range(len(old_columns) - 1))
    path = write(
        tmp_path,
        "# written before failure_reason existed\n"
        f"speed,angle_deg,{','.join(old_columns)}\n"
        f"1.5,30,rebound,{numbers}\n"
        f"2.5,-30,failed,{','.join([''] * (len(old_columns) - 1))}\n",
        "old.csv",
    )
    back = read_results(path)
    assert list(back) == ["speed", "angle_deg", *old_columns]
    assert "failure_reason" not in back
    assert back["status"].tolist() == ["rebound", "failed"]
    np.testing.assert_array_equal(back["speed"], [1.5, 2.5])
    np.testing.assert_array_equal(back["vn_out"], [0.0, np.nan])
    np.testing.assert_array_equal(back["loss_rolling"], [len(old_columns) - 2, np.nan])


def test_invalid_failure_reason_is_refused_on_reading(tmp_path):
    out = tmp_path / "r.csv"
    results = results_for(2, status=["failed", "failed"], failure_reason=["nonfinite", ""])
    write_results(out, {"speed": [1.0, 2.0], "angle_deg": [0.0, 0.0]}, results)
    text = out.read_text().replace(",nonfinite\n", ",overheated\n")
    path = write(tmp_path, "# edited by hand\n" + text, "edited.csv")
    with pytest.raises(TableError) as info:
        read_results(path)
    assert (info.value.line, info.value.column) == (3, "failure_reason")
    message = str(info.value)
    assert message.startswith(f"{path}, line 3, column 'failure_reason'")
    assert "'overheated'" in message
    assert all(reason in message for reason in FAILURE_REASONS)


def test_every_column_has_a_unit():
    assert set(COLUMN_UNITS) == {
        *IMPACT_COLUMNS,
        *IMPACT_PARAMETER_COLUMNS,
        *RESULT_COLUMNS,
        *OPTIONAL_RESULT_COLUMNS,
    }
    assert COLUMN_UNITS["speed"] == "m/s" and COLUMN_UNITS["energy_in"] == "J"
    assert COLUMN_UNITS["status"] == COLUMN_UNITS["failure_reason"] == ""


BAD_RESULTS = [
    ({"status": None}, "missing: ['status']"),
    ({"bounce": [1.0]}, "unknown: ['bounce']"),
    ({"vn_out": [1.0, 2.0, 3.0]}, "differ in length"),
    ({"vn_out": ["fast"]}, "column 'vn_out': values are not numbers"),
    ({"status": ["re\nbound"]}, "invalid status"),
    ({"status": [""]}, "invalid status"),
    ({"status": ["# rebound"]}, "invalid status"),
    ({"failure_reason": ["overheated"]}, "column 'failure_reason': row 0: invalid failure reason"),
    ({"failure_reason": ["max_steps", ""]}, "differ in length"),
    ({"failure_reason": None}, "missing: ['failure_reason']"),
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

    monkeypatch.setattr(os, failing, fail)
    with pytest.raises(OSError, match="disk trouble"):
        write_results(out, {"speed": [1.0], "angle_deg": [0.0]}, results_for(1))
    assert out.read_text() == "previous results\n"
    assert [p.name for p in tmp_path.iterdir()] == ["results.csv"]


def test_interrupt_midway_removes_temporary(tmp_path, monkeypatch):
    # Even a KeyboardInterrupt between the write and the rename leaves nothing behind.
    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupt)
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

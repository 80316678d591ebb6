"""Tests of observation loading (fitting._data) and the bundled Kharaz (2001) data."""

import numpy as np
import pytest

from fitting._data import (
    OBSERVABLES,
    DataError,
    kharaz2001_path,
    load_kharaz2001,
    load_observations,
)
from jaximpact.tables import TableError


def write(tmp_path, text, name="obs.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


# ----------------------------------------------------------------------------------------------
# The bundled data set


def test_kharaz2001_file_is_bundled_with_its_provenance():
    path = kharaz2001_path()
    assert path.name == "kharaz2001_oblique_impact.csv"
    text = path.read_text(encoding="utf-8")
    assert text.startswith("# Oblique impact of 5 mm aluminium oxide spheres")
    assert "doi:10.1016/S0032-5910(01)00283-2" in text


def test_kharaz2001_contents():
    # Counts verified by reading the file: 17 comment lines, the header on line 18, and 24 data
    # rows (lines 19-42) at 3.9 m/s without spin: 8 cor_t, 7 omega_out, 9 rebound_angle_deg,
    # every one at a different angle (digitized from different figures), so 24 distinct impacts.
    obs = load_observations(kharaz2001_path())
    assert obs.layout == "long"
    assert len(obs) == 24
    assert obs.counts() == {"cor_t": 8, "omega_out": 7, "rebound_angle_deg": 9}
    assert len(obs.impacts) == 24
    assert len(np.unique(obs.angle_deg)) == 24
    np.testing.assert_array_equal(obs.line, np.arange(19, 43))
    np.testing.assert_array_equal(obs.speed, 3.9)
    np.testing.assert_array_equal(obs.omega0, 0.0)
    assert np.isnan(obs.sigma).all()
    assert obs.impacts.overrides == {}
    assert obs.impacts.columns == ("speed", "angle_deg")
    # first and last rows, as printed in the file
    assert (obs.observable[0], obs.angle_deg[0], obs.value[0]) == ("cor_t", 1.84, 0.79344)
    assert (obs.observable[-1], obs.angle_deg[-1], obs.value[-1]) == (
        "rebound_angle_deg",
        60.208,
        57.474,
    )
    assert obs.angle_deg.min() == 0.016 and obs.angle_deg.max() == 60.328
    # the provenance is the leading comment block, without the '#'
    first = obs.provenance.splitlines()[0]
    assert (
        first == "Oblique impact of 5 mm aluminium oxide spheres on a thick soda-lime glass anvil."
    )
    assert len(obs.provenance.splitlines()) == 17
    assert "Kharaz, D.A. Gorham, A.D. Salman" in obs.provenance
    assert "#" not in obs.provenance


def test_load_kharaz2001_helper_matches_path():
    a, b = load_kharaz2001(), load_observations(kharaz2001_path())
    np.testing.assert_array_equal(a.value, b.value)
    np.testing.assert_array_equal(a.observable, b.observable)


# ----------------------------------------------------------------------------------------------
# Wide and long layouts

WIDE = """\
# Made-up observations for a test.
#   second provenance line
speed, angle_deg, omega0, friction, cor_n, sigma_cor_n, omega_out, status
1.0,   30,        0,      0.3,      0.9,   0.01,        120,
1.0,   30,        0,      0.3,      0.91,  0.01,        ,          rebound
# a comment between rows
2.0,  -45,        10,     0.2,      ,      ,            -50,       captured
3.0,   10,        0,      0.3,      ,      ,            ,
"""

LONG = """\
# Made-up observations for a test.
#   second provenance line
speed,angle_deg,omega0,friction,observable,value,sigma
1.0,30,0,0.3,cor_n,0.9,0.01
1.0,30,0,0.3,omega_out,120,
1.0,30,0,0.3,cor_n,0.91,0.01
1.0,30,0,0.3,captured,0,
2.0,-45,10,0.2,omega_out,-50,
2.0,-45,10,0.2,captured,1,
"""


def test_wide_and_long_layouts_give_the_same_observations(tmp_path):
    wide = load_observations(write(tmp_path, WIDE, "wide.csv"))
    long = load_observations(write(tmp_path, LONG, "long.csv"))
    assert (wide.layout, long.layout) == ("wide", "long")
    assert len(wide) == len(long) == 6
    for name in ("speed", "angle_deg", "omega0", "observable", "value", "sigma", "impact_index"):
        np.testing.assert_array_equal(getattr(wide, name), getattr(long, name), err_msg=name)
    for name in ("speed", "angle_deg", "omega0"):
        np.testing.assert_array_equal(getattr(wide.impacts, name), getattr(long.impacts, name))
    np.testing.assert_array_equal(wide.impacts.overrides["friction"], [0.3, 0.2])
    np.testing.assert_array_equal(long.impacts.overrides["friction"], [0.3, 0.2])
    assert (
        wide.provenance
        == long.provenance
        == ("Made-up observations for a test.\n  second provenance line")
    )


def test_wide_details(tmp_path):
    obs = load_observations(write(tmp_path, WIDE))
    # empty cells are "not observed"; row 3.0 m/s observes nothing, so it adds no impact
    assert obs.observable.tolist() == [
        "cor_n",
        "omega_out",
        "cor_n",
        "captured",
        "omega_out",
        "captured",
    ]
    assert obs.line.tolist() == [4, 4, 5, 5, 7, 7]
    assert obs.impact_index.tolist() == [0, 0, 0, 0, 1, 1]
    assert len(obs.impacts) == 2
    assert obs.impacts.lines.tolist() == [4, 7]
    assert obs.impacts.columns == ("speed", "angle_deg", "omega0", "friction")
    np.testing.assert_array_equal(obs.sigma[:3], [0.01, np.nan, 0.01])
    assert obs.value[obs.observable == "captured"].tolist() == [0.0, 1.0]
    assert obs.counts() == {"cor_n": 2, "omega_out": 2, "captured": 2}
    assert not obs.value.flags.writeable
    assert obs.source.endswith("obs.csv")


def test_crlf_bom_and_quoted_fields_read_like_plain_text(tmp_path):
    plain = load_observations(write(tmp_path, WIDE, "plain.csv"))
    lines = WIDE.splitlines()
    # quotes (right after the comma: a quote after a space is text, as in Python's csv module)
    lines[2] = '"speed", angle_deg,"omega0", friction, cor_n, sigma_cor_n, omega_out,"status"'
    lines[4] = '1.0,"30" ,0,0.3,0.91,0.01,"",rebound'
    path = tmp_path / "excel.csv"
    path.write_bytes(("\ufeff" + "\r\n".join(lines) + "\r\n").encode())
    fancy = load_observations(path)
    assert fancy.provenance == plain.provenance
    for name in ("observable", "value", "sigma", "line", "speed", "angle_deg", "impact_index"):
        np.testing.assert_array_equal(getattr(fancy, name), getattr(plain, name), err_msg=name)


@pytest.mark.parametrize(
    ("content", "line", "problem"),
    [
        (b'# c\nspeed,angle_deg,cor_n\n1,0,0.9\n# c\n1,0,"0.8\n', 5, "not closed"),
        (b"# c\nspeed,angle_deg,cor_n\n1,0,0.9\n1,0,\xe9\n", 4, "not UTF-8"),
        (b"# c\r\n\r\nspeed,angle_deg,cor_n\r\n1,0,0.9,1\r\n", 4, "found 4"),
    ],
)
def test_malformed_files_are_located_data_errors(tmp_path, content, line, problem):
    path = tmp_path / "obs.csv"
    path.write_bytes(content)
    with pytest.raises(DataError) as info:
        load_observations(path)
    assert info.value.line == line
    assert str(info.value).startswith(f"{path}, line {line}: ")
    assert problem in str(info.value)


def test_every_observable_is_accepted_in_both_layouts(tmp_path):
    wide = "speed,angle_deg," + ",".join(OBSERVABLES) + "\n1,20," + ",".join(["1"] * 6) + "\n"
    long = "speed,angle_deg,observable,value\n" + "".join(f"1,20,{n},1\n" for n in OBSERVABLES)
    a = load_observations(write(tmp_path, wide, "w.csv"))
    b = load_observations(write(tmp_path, long, "l.csv"))
    assert a.observable.tolist() == b.observable.tolist() == list(OBSERVABLES)


# ----------------------------------------------------------------------------------------------
# Validation

BAD_DATA = [
    # (file text, line, column or None, a fragment of the problem)
    # long layout
    ("# c\nspeed,angle_deg,observable,value\n1,0,cor_x,1\n", 3, "observable", "unknown observable"),
    ("speed,angle_deg,observable\n1,0,cor_n\n", 1, "value", "required column missing"),
    ("angle_deg,observable,value\n0,cor_n,1\n", 1, "speed", "required column missing"),
    ("speed,angle_deg,observable,value,weight\n1,0,cor_n,1,2\n", 1, "weight", "allowed columns"),
    ("speed,angle_deg,observable,value\n1,0,cor_n,nan\n", 2, "value", "finite"),
    ("speed,angle_deg,observable,value\n1,0,cor_n,-inf\n", 2, "value", "finite"),
    ("speed,angle_deg,observable,value\n1,0,cor_n,high\n", 2, "value", "not a number"),
    ("speed,angle_deg,observable,value\n1,0,cor_n,\n", 2, "value", "empty value"),
    ("speed,angle_deg,observable,value,sigma\n1,0,cor_n,1,0\n", 2, "sigma", "> 0"),
    ("speed,angle_deg,observable,value,sigma\n1,0,cor_n,1,-0.1\n", 2, "sigma", "> 0"),
    ("speed,angle_deg,observable,value,sigma\n1,0,cor_n,1,inf\n", 2, "sigma", "finite"),
    ("speed,angle_deg,observable,value\n1,0,captured,0.5\n", 2, "value", "0 or 1"),
    ("speed,angle_deg,observable,value\n0,0,cor_n,1\n", 2, "speed", "(0, 1000] m/s"),
    ("speed,angle_deg,observable,value\n1,90,cor_n,1\n", 2, "angle_deg", "(-90, 90) deg"),
    ("speed,angle_deg,observable,value\n1,0,cor_n\n", 2, None, "expected 4 fields"),
    ("# c\nspeed,angle_deg,observable,value\n\n", 2, None, "no usable observations"),
    # wide layout
    ("speed,angle_deg,vn_out\n1,0,1\n", 1, "vn_out", "allowed columns"),
    ("speed,cor_n\n1,0.9\n", 1, "angle_deg", "required column missing"),
    ("speed,angle_deg,sigma_cor_t\n1,0,1\n", 1, "sigma_cor_t", "no column 'cor_t'"),
    ("speed,angle_deg,omega0\n1,0,1\n", 1, None, "no observed columns"),
    ("speed,angle_deg,cor_n\n1,0,\n2,0,\n", 1, None, "no usable observations"),
    ("speed,angle_deg,cor_n\n1,0,0.9\n1,0,abc\n", 3, "cor_n", "not a number"),
    ("speed,angle_deg,cor_n\n1,0,nan\n", 2, "cor_n", "finite"),
    ("speed,angle_deg,cor_n,sigma_cor_n\n1,0,0.9,0\n", 2, "sigma_cor_n", "> 0"),
    ("speed,angle_deg,cor_n,sigma_cor_n\n1,0,,0.1\n", 2, "sigma_cor_n", "sigma given but"),
    ("speed,angle_deg,cor_n\n1,,0.9\n", 2, "angle_deg", "empty value"),
    ("speed,angle_deg,friction,cor_n\n1,0,-1,0.9\n", 2, "friction", "[0, 10]"),
    ("speed,angle_deg,status\n1,0,failed\n", 2, "status", "allowed: rebound, captured"),
    ("speed,angle_deg,captured,status\n1,0,1,captured\n", 1, "status", "not both"),
    ("speed,angle_deg,captured\n1,0,2\n", 2, "captured", "0 or 1"),
    ("speed,angle_deg,cor_n,cor_n\n1,0,1,1\n", 1, "cor_n", "named twice"),
]


@pytest.mark.parametrize(("text", "line", "column", "problem"), BAD_DATA)
def test_errors_name_file_line_and_column(tmp_path, text, line, column, problem):
    path = write(tmp_path, text)
    with pytest.raises(DataError) as info:
        load_observations(path)
    message = str(info.value)
    assert isinstance(info.value, TableError) and isinstance(info.value, ValueError)
    assert message.startswith(str(path))
    assert f"line {line}" in message
    assert problem in message
    if column is not None:
        assert f"column '{column}'" in message
    assert (info.value.line, info.value.column) == (line, column)


def test_empty_file(tmp_path):
    with pytest.raises(DataError, match="no header"):
        load_observations(write(tmp_path, ""))

"""The command line: default job, impacts files with per-row overrides, atomic output, errors."""

import math

import numpy as np

from jaximpact import cli
from jaximpact.tables import read_results


def test_default_job_prints_three_paper_impacts(capsys):
    assert cli.main(["simulate"]) == 0
    out = capsys.readouterr().out
    assert "Table 1" in out
    assert out.count(" rebound ") == 3


def test_impacts_file_with_overrides_and_results_csv(tmp_path, capsys):
    impacts = tmp_path / "impacts.csv"
    impacts.write_text(
        "# two impacts, the second without adhesion\n"
        "speed,angle_deg,omega0,f0\n"
        "1.0,30,0,325\n"
        "1.0,30,0,0\n"
    )
    out = tmp_path / "results.csv"
    assert cli.main(["simulate", "--impacts", str(impacts), "-o", str(out)]) == 0
    res = read_results(out)
    assert list(res["status"]) == ["rebound", "rebound"]
    np.testing.assert_allclose(res["f0"], [325.0, 0.0])
    # Adhesion damping dissipates: the adhesive row rebounds more slowly.
    assert res["cor_n"][0] < res["cor_n"][1]
    assert res["loss_adhesion_damping"][1] == 0.0
    ledger = res["energy_in"] - res["energy_out"]
    losses = sum(
        res[k]
        for k in ("loss_hertz_damping", "loss_adhesion_damping", "loss_friction", "loss_rolling")
    )
    np.testing.assert_allclose(ledger, losses, rtol=1e-5)
    assert math.isclose(res["speed"][0], 1.0)


def test_bad_input_exits_2_with_line_and_column(tmp_path, capsys):
    impacts = tmp_path / "impacts.csv"
    impacts.write_text("speed,angle_deg\n1.0,30\n-2.0,10\n")
    out = tmp_path / "results.csv"
    assert cli.main(["simulate", "--impacts", str(impacts), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "line 3" in err and "speed" in err
    assert not out.exists()  # nothing half written


def test_bad_scene_exits_2(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text("[particle]\nradius = 1e-6\ndensity = 1000\n[contact]\nK = 1e9\nf = 0.3\n")
    assert cli.main(["simulate", str(scene)]) == 2
    assert "contact.f" in capsys.readouterr().err

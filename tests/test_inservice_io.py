"""In-service recording files (survey.inservice_io) and ``trolley inservice simulate``: round trips
through the files with the FRD sign conversion, clear errors naming file/row/column, the command."""
from __future__ import annotations

import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from survey import inservice_io as io
from survey.commands.inservice import register
from trolley.inservice import irregularity as irr
from trolley.inservice import vehicle as vh


@pytest.fixture(scope="module")
def run():
    p = vh.VehicleParameters()
    track = irr.irregularity_from_psd(30.0, seed=4, lead_in_m=40.0)
    return p, vh.simulate_run(p, track, 20.0, 30.0, seed=1, curvature_1_m=2e-4)


@pytest.fixture()
def folder(tmp_path, run):
    p, r = run
    io.write_recording(tmp_path / "rec", io.recording_from_run(r, p))
    return tmp_path / "rec"


def test_recording_round_trip(folder, run):
    p, r = run
    rec = io.read_recording(folder)
    for a, b in ((rec.t_s, r.t_s), (rec.s_m, r.s_m), (rec.wheelset_ay_m_s2, r.wheelset_ay_m_s2),
                 (rec.wheelset_wz_rad_s, r.wheelset_wz_rad_s), (rec.frame_ay_m_s2, r.frame_ay_m_s2)):
        np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-15)
    assert rec.nominal == p.nominal()
    assert rec.curvature_1_m == 2e-4 and rec.speed_m_s == 20.0 and rec.rate_hz == 200.0
    assert (rec.sigma_acc_m_s2, rec.sigma_gyro_rad_s) == (0.01, 5e-4)
    assert rec.wheelset_sensor_m == pytest.approx((p.a_bogie + p.a_wheelset, p.d_p, p.r0))


def test_files_carry_frd_signs(folder, run):
    """In the files lateral/curvature are positive to the right and the yaw rate clockwise."""
    _, r = run
    import pandas as pd
    df = pd.read_csv(folder / "sensors.csv")
    np.testing.assert_allclose(df["wheelset_ay_m_s2"], -r.wheelset_ay_m_s2, rtol=1e-8)
    np.testing.assert_allclose(df["wheelset_wz_rad_s"], -r.wheelset_wz_rad_s, rtol=1e-8)
    assert "curvature_1_m = -0.0002" in (folder / "inservice.toml").read_text()


def test_truth_round_trip_and_signs(tmp_path, run):
    _, r = run
    path = tmp_path / "truth.csv"
    io.write_truth(path, r.s_m, r.alignment_m, r.vertical_m, r.curvature_1_m)
    back = io.read_truth(path)
    np.testing.assert_allclose(back["alignment_m"], r.alignment_m, rtol=1e-8, atol=1e-15)
    np.testing.assert_allclose(back["vertical_m"], r.vertical_m, rtol=1e-8, atol=1e-15)
    assert np.all(back["curvature_1_m"] == 2e-4)
    import pandas as pd
    np.testing.assert_allclose(pd.read_csv(path)["alignment_m"], -r.alignment_m, rtol=1e-8, atol=1e-15)
    # the irregularity the vehicle saw is the one in the file
    lat, vert, _ = irr.irregularity_from_psd(30.0, seed=4, lead_in_m=40.0).at(back["s_m"])
    np.testing.assert_allclose(back["alignment_m"], lat, rtol=1e-8, atol=1e-15)


def _edit(path, old, new):
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize("fname,old,new,message", [
    ("sensors.csv", "\n0.01,", "\nabc,", "sensors.csv: row 4, column t_s: not a finite number"),
    ("sensors.csv", "frame_ay_m_s2", "frame_ay", "sensors.csv: missing column frame_ay_m_s2"),
    ("sensors.csv", "\n0.01,", "\n0.0,", "sensors.csv: row 4, column t_s: time goes backwards"),
    ("inservice.toml", "rate_hz = 200.0\n", "", "inservice.toml: missing key run.rate_hz"),
    ("inservice.toml", "speed_m_s = 20.0", "speed_m_s = -1.0", "inservice.toml: run.speed_m_s must be > 0"),
    ("inservice.toml", "conicity = 0.15", 'conicity = "x"', "inservice.toml: vehicle.conicity must be a finite number"),
    ("inservice.toml", "trolley-inservice/1", "other/1", "inservice.toml: format must be"),
    ("inservice.toml", "[sensors]", "[sensor]", "inservice.toml: missing table [sensors]"),
    ("inservice.toml", "frame_sensor_m = [", "frame_sensor_m = [1.0, ", "inservice.toml: sensors.frame_sensor_m must be 3"),
])
def test_bad_recordings_name_file_row_column(folder, fname, old, new, message):
    _edit(folder / fname, old, new)
    with pytest.raises(io.InserviceFormatError, match=message.replace("[", r"\[")):
        io.read_recording(folder)


@pytest.mark.parametrize("edit, message", [
    # pandas took the comment for a one-column header: "row 2: 6 cells, the header has 1 columns (a
    # decimal comma? use a point: 0.5)"
    (lambda text: "# logger 2.1, SI units\n" + text,
     "sensors.csv: row 1: a comment line ('# logger 2.1, SI units') above the header; the format has no comment "
     "lines, the column names come first (delete the line)"),
    (lambda text: "\n  \n# logger\n" + text,
     "sensors.csv: row 3: a comment line ('# logger') above the header; the format has no comment lines, the "
     "column names come first (delete the line)"),
    (lambda text: "#" + text, "sensors.csv: row 1: the header starts with '#' ('#t_s,s_m,speed_m_s,wheelset_ay_m_s2,w"
                              "...'): write the column names without it"),
    # in the data: "row 5, column t_s: not a finite number ('# wheel change')"
    (lambda text: text.replace("\n0.015,", "\n# wheel change\n0.015,", 1),
     "sensors.csv: row 5: a comment line ('# wheel change'); the format has no comment lines, every row after the "
     "header is data (delete the line)"),
])
def test_a_comment_line_in_sensors_csv_is_named_as_one(folder, edit, message):
    path = folder / "sensors.csv"
    assert path.read_text().split("\n")[4].startswith("0.015,")
    path.write_text(edit(path.read_text()))
    with pytest.raises(io.InserviceFormatError) as info:
        io.read_recording(folder)
    assert str(info.value) == message


def test_a_comment_line_in_truth_csv_is_named_as_one(tmp_path, run):
    _, r = run
    path = tmp_path / "truth.csv"
    io.write_truth(path, r.s_m, r.alignment_m, r.vertical_m, r.curvature_1_m)
    path.write_text("# seed 4\n" + path.read_text())
    with pytest.raises(io.InserviceFormatError, match=r"^truth.csv: row 1: a comment line \('# seed 4'\) above the "
                                                      "header; the format has no comment lines"):
        io.read_truth(path)


def test_missing_files(tmp_path, folder):
    with pytest.raises(io.InserviceFormatError, match="not a folder"):
        io.read_recording(tmp_path / "nope")
    (folder / "sensors.csv").unlink()
    with pytest.raises(io.InserviceFormatError, match="sensors.csv: file not found"):
        io.read_recording(folder)
    with pytest.raises(io.InserviceFormatError, match="truth.csv: file not found"):
        io.read_truth(tmp_path / "truth.csv")


def _app():
    app = typer.Typer()
    register(app)

    @app.command()
    def other():  # a second command keeps "inservice" a group
        pass
    return app


def test_simulate_command_writes_recording_and_truth(tmp_path):
    out = tmp_path / "out"
    res = CliRunner().invoke(_app(), ["inservice", "simulate", "--out", str(out), "--length-m", "20",
                                      "--curvature-1-m", "0.001", "--no-noise", "--no-vertical", "--seed", "3"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout.strip().splitlines()[-1])
    assert summary["samples"] == 201 and summary["noise"] is False
    assert 1.0 < summary["first_lateral_mode_hz"] < 1.5
    rec = io.read_recording(out / "recording")
    truth = io.read_truth(out / "truth.csv")
    assert rec.sigma_acc_m_s2 == 0.0 and rec.curvature_1_m == -0.001
    assert np.all(truth["curvature_1_m"] == -0.001) and np.all(truth["vertical_m"] == 0.0)
    assert not (out / "recording" / "truth.csv").exists()
    # right-hand curve: the centripetal acceleration points right, i.e. positive in the file
    import pandas as pd
    assert pd.read_csv(out / "recording" / "sensors.csv")["wheelset_ay_m_s2"].mean() == pytest.approx(0.4, rel=0.05)


def test_simulate_command_resonance_case_2(tmp_path):
    out = tmp_path / "out"
    res = CliRunner().invoke(_app(), ["inservice", "simulate", "--out", str(out), "--length-m", "20",
                                      "--resonance", "--no-random-lateral", "--no-vertical", "--no-noise"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout.strip().splitlines()[-1])
    lam = summary["harmonic_wavelength_m"]
    assert lam == pytest.approx(summary["first_lateral_mode_wavelength_m"])
    truth = io.read_truth(out / "truth.csv")
    np.testing.assert_allclose(truth["alignment_m"], 1e-3 * np.sin(2 * np.pi * truth["s_m"] / lam), atol=1e-9)


@pytest.mark.parametrize("args,message", [
    (["--resonance", "--harmonic-wavelength-m", "15"], "not both"),
    (["--no-random-lateral"], "needs a harmonic"),
])
def test_simulate_command_refuses_bad_options(tmp_path, args, message):
    out = tmp_path / "out"
    res = CliRunner().invoke(_app(), ["inservice", "simulate", "--out", str(out), "--length-m", "20", *args])
    assert res.exit_code == 2 and message in res.output
    assert not out.exists()

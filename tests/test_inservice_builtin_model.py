"""The built-in calibration of ``trolley inservice process`` without ``--model``
(survey.inservice_model.BUILTIN_MODEL_PATH): it is the calibration of the built-in vehicle, it is
used exactly when a recording is of that vehicle with the paper's virtual accelerometers, and the
recording's ``accelerometers_sense_gravity`` key is read, written and checked against a model."""
from __future__ import annotations

import json
import os

import numpy as np
import pandas as pd
import pytest
from test_inservice_io import _app
from typer.testing import CliRunner

from survey import inservice_io as io
from survey.inservice_model import BUILTIN_MODEL_PATH, model_provenance, read_model
from trolley.inservice.bogie import nominal_parameters
from trolley.inservice.vehicle import DEFAULT_VEHICLE_NAME, VehicleParameters


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    """A 120 m run of the built-in vehicle, as `trolley inservice simulate` writes it."""
    folder = tmp_path_factory.mktemp("builtin") / "run"
    res = CliRunner().invoke(_app(), ["inservice", "simulate", "--out", str(folder), "--seed", "3",
                                      "--length-m", "120"])
    assert res.exit_code == 0, res.output
    return folder


def _process(recording, out, *extra):
    res = CliRunner().invoke(_app(), ["inservice", "process", str(recording), "--out", str(out), *extra])
    assert res.exit_code == 0, res.output
    return res, json.loads((out / "summary.json").read_text())


def test_the_builtin_model_is_the_default_calibration_of_the_builtin_vehicle():
    m = read_model(BUILTIN_MODEL_PATH)
    assert model_provenance(BUILTIN_MODEL_PATH) == (
        f"calibrated for {DEFAULT_VEHICLE_NAME} at 20 m/s, 200 Hz, 400 m, seeds 1000-1003")
    assert m.params.KIND == "bogie" and m.params.sensor_gravity is False
    assert m.dt_s == pytest.approx(0.005, rel=1e-9)
    # every design parameter but the four Eq. 6 identifies is the built-in vehicle's nominal value:
    # a change to the vehicle or to nominal_parameters makes the shipped file stale, and this fails
    nominal = nominal_parameters(VehicleParameters(), "bogie")
    identified = {"kx", "cx", "ky", "cy"}
    for name, value in vars(nominal).items():
        if name not in identified:
            assert getattr(m.params, name) == pytest.approx(value, rel=1e-12), name
    assert m.innovation_rms is not None and m.sigma_scale == pytest.approx(1.006, abs=5e-4)


def test_process_without_model_uses_the_builtin_calibration_for_the_builtin_vehicle(default_run, tmp_path):
    res, summary = _process(default_run / "recording", tmp_path / "o1")
    assert "the built-in model, calibrated for " + DEFAULT_VEHICLE_NAME in res.stderr
    assert summary["calibrated"] is True and summary["model"].startswith("built-in (calibrated for")
    assert summary["vehicle_check"] == {"checked": True, "matches": True, "differences": {}}
    assert summary["consistency"]["checked"] is True
    # the same estimate, to the bit, as naming the file with --model
    _, named = _process(default_run / "recording", tmp_path / "o2", "--model", str(BUILTIN_MODEL_PATH))
    a = pd.read_csv(tmp_path / "o1" / "irregularities.csv")
    b = pd.read_csv(tmp_path / "o2" / "irregularities.csv")
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert named["consistency"] == summary["consistency"]


@pytest.mark.parametrize("edit, said", [
    (("conicity = 0.15", "conicity = 0.25"), "differs from the built-in vehicle's in 1 key (conicity)"),
    (("accelerometers_sense_gravity = false", "accelerometers_sense_gravity = true"),
     "its accelerometers sense gravity"),
])
def test_another_vehicle_or_real_accelerometers_fall_back_to_the_nominal_model(default_run, tmp_path, edit, said):
    rec = tmp_path / "rec"
    rec.mkdir()
    text = (default_run / "recording" / "inservice.toml").read_text()
    assert edit[0] in text
    (rec / "inservice.toml").write_text(text.replace(edit[0], edit[1]))
    (rec / "sensors.csv").write_bytes((default_run / "recording" / "sensors.csv").read_bytes())
    res, summary = _process(rec, tmp_path / "out")
    assert said in res.stderr and "uncalibrated nominal parameters" in res.stderr
    assert summary["calibrated"] is False and summary["model"] == "nominal (recording [vehicle])"
    assert summary["recording_accelerometers_sense_gravity"] is ("sense_gravity = true" in edit[1])


def test_a_model_for_other_accelerometers_than_the_recordings_is_said(default_run, tmp_path):
    rec = tmp_path / "rec"
    rec.mkdir()
    text = (default_run / "recording" / "inservice.toml").read_text()
    (rec / "inservice.toml").write_text(text.replace("accelerometers_sense_gravity = false",
                                                     "accelerometers_sense_gravity = true"))
    (rec / "sensors.csv").write_bytes((default_run / "recording" / "sensors.csv").read_bytes())
    res, _ = _process(rec, tmp_path / "out", "--model", str(BUILTIN_MODEL_PATH))
    assert "sensors.accelerometers_sense_gravity is true, the model was calibrated without --sensor-gravity" \
        in res.stderr
    res, _ = _process(default_run / "recording", tmp_path / "out2", "--model", str(BUILTIN_MODEL_PATH))
    assert "accelerometers_sense_gravity" not in res.stderr


def test_the_gravity_key_is_optional_boolean_and_round_trips(default_run, tmp_path):
    text = (default_run / "recording" / "inservice.toml").read_text()
    csv = (default_run / "recording" / "sensors.csv").read_bytes()
    for name, body, expected in (("absent", text.replace("accelerometers_sense_gravity = false\n", ""), False),
                                 ("true", text.replace("sense_gravity = false", "sense_gravity = true"), True),
                                 ("text", text.replace("sense_gravity = false", 'sense_gravity = "yes"'), None)):
        rec = tmp_path / name
        rec.mkdir()
        (rec / "inservice.toml").write_text(body)
        (rec / "sensors.csv").write_bytes(csv)
        if expected is None:
            with pytest.raises(io.InserviceFormatError,
                               match="inservice.toml: sensors.accelerometers_sense_gravity must be true or false"):
                io.read_recording(rec)
            continue
        r = io.read_recording(rec)
        assert r.sense_gravity is expected
        io.write_recording(tmp_path / f"{name}_again", r)
        assert io.read_recording(tmp_path / f"{name}_again").sense_gravity is expected


@pytest.mark.slow
def test_calibrate_with_its_defaults_gives_the_builtin_model(tmp_path):
    # (50 s of CPU) the shipped file is what `calibrate` writes today with its defaults
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    res = CliRunner(env=env).invoke(_app(), ["inservice", "calibrate", "--out", str(tmp_path / "m.toml")])
    assert res.exit_code == 0, res.output
    assert model_provenance(tmp_path / "m.toml") == model_provenance(BUILTIN_MODEL_PATH)
    new, shipped = read_model(tmp_path / "m.toml"), read_model(BUILTIN_MODEL_PATH)
    assert vars(new.params) == pytest.approx(vars(shipped.params), rel=1e-6)
    for a, b in ((new.Q, shipped.Q), (new.R, shipped.R), (new.S, shipped.S), (new.innovation_rms,
                                                                              shipped.innovation_rms)):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-30)
    assert new.sigma_scale == pytest.approx(shipped.sigma_scale, rel=1e-6)


def test_speed_fits_by_hand():
    from dataclasses import replace

    from trolley.inservice.identification import SPEED_TOLERANCE, speed_fits

    m = replace(read_model(BUILTIN_MODEL_PATH), speed_m_s=20.0)
    assert SPEED_TOLERANCE == 0.03
    assert speed_fits(m, 20.0).fits and speed_fits(m, [19.4, 20.6]).fits
    assert not speed_fits(m, [19.39, 20.0]).fits and not speed_fits(m, [20.0, 20.61]).fits
    c = speed_fits(m, np.array([19.0, 23.5, 21.0]))
    assert (c.calibration_m_s, c.low_m_s, c.high_m_s, c.fits) == (20.0, 19.0, 23.5, False)
    assert speed_fits(replace(m, speed_m_s=None), 20.0) is None


def test_the_calibration_speed_round_trips_and_is_optional(tmp_path):
    from dataclasses import replace

    from survey.inservice_model import ModelFileError, model_toml_text, write_model

    m = read_model(BUILTIN_MODEL_PATH)
    assert m.speed_m_s == 20.0
    write_model(tmp_path / "m.toml", replace(m, speed_m_s=17.25))
    assert read_model(tmp_path / "m.toml").speed_m_s == 17.25
    old = model_toml_text(replace(m, speed_m_s=None))
    assert "speed_m_s" not in old
    (tmp_path / "old.toml").write_text(old)
    assert read_model(tmp_path / "old.toml").speed_m_s is None
    (tmp_path / "bad.toml").write_text(model_toml_text(m).replace("speed_m_s = 20.0", "speed_m_s = -20.0"))
    with pytest.raises(ModelFileError, match="bad.toml: noise.speed_m_s must be > 0"):
        read_model(tmp_path / "bad.toml")


def test_process_says_when_the_recording_is_at_another_speed_than_the_calibration(default_run, tmp_path):
    from openpyxl import load_workbook

    _, summary = _process(default_run / "recording", tmp_path / "same")
    assert summary["speed_check"] == {"checked": True, "calibration_m_s": 20.0, "recording_low_m_s": 20.0,
                                      "recording_high_m_s": 20.0, "tolerance": 0.03, "fits": True}
    # the same sensor data said to be recorded at 22.5-25 m/s (the chainage following that speed):
    # the model's Q, R, S are the 20 m/s runs'
    rec = tmp_path / "fast"
    rec.mkdir()
    (rec / "inservice.toml").write_text((default_run / "recording" / "inservice.toml").read_text())
    df = pd.read_csv(default_run / "recording" / "sensors.csv")
    v = np.linspace(22.5, 25.0, len(df))
    df["speed_m_s"] = v
    df["s_m"] = df["s_m"].iloc[0] + np.r_[0.0, np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(df["t_s"]))]
    df.to_csv(rec / "sensors.csv", index=False)
    res, summary = _process(rec, tmp_path / "out")
    assert summary["speed_check"]["fits"] is False
    assert (summary["speed_check"]["recording_low_m_s"], summary["speed_check"]["recording_high_m_s"]) == (22.5, 25.0)
    assert ("sensors.csv: recorded at 22.5-25 m/s, differs by more than 3% from the calibration's 20 m/s; "
            "calibrate at the recording's speed (--speed-m-s)") in " ".join(res.stderr.split())
    ws = load_workbook(tmp_path / "out" / "inservice.xlsx").active
    head = [ws.cell(1, j).value for j in range(1, ws.max_column + 1)]
    assert head[-1] == "speed_check" and ws.cell(2, len(head)).value.startswith("recorded at 22.5-25 m/s, DIFFERS")
    # an older model file without the calibration speed: not checked, and said why
    from dataclasses import replace

    from survey.inservice_model import write_model

    write_model(tmp_path / "old.toml", replace(read_model(BUILTIN_MODEL_PATH), speed_m_s=None))
    _, summary = _process(rec, tmp_path / "out_old", "--model", str(tmp_path / "old.toml"))
    assert summary["speed_check"]["checked"] is False and "no calibration speed" in summary["speed_check"]["reason"]


def _edited(default_run, tmp_path, toml=None, csv=None, name="rec"):
    """A copy of the default run's recording with inservice.toml / sensors.csv edited."""
    rec = tmp_path / name
    rec.mkdir()
    text = (default_run / "recording" / "inservice.toml").read_text()
    (rec / "inservice.toml").write_text(toml(text) if toml else text)
    df = pd.read_csv(default_run / "recording" / "sensors.csv")
    if csv:
        df = csv(df)
    df.to_csv(rec / "sensors.csv", index=False)
    return rec


def _slow_start(df):
    v = df["speed_m_s"].to_numpy(dtype=float, copy=True)
    v[4] = 0.04
    return df.assign(speed_m_s=v)


def _dropped_row(df):
    return df.drop(index=57).reset_index(drop=True)


@pytest.mark.parametrize("toml, csv, said", [
    # (bug hunt 2026-11-26) each of these gave exit 0 and an all-empty estimate, or used the wrong model
    (lambda t: t.replace("accelerometers_sense_gravity", "accelerometer_senses_gravity"), None,
     "inservice.toml: unknown key sensors.accelerometer_senses_gravity (did you mean "
     "sensors.accelerometers_sense_gravity?)"),
    (None, lambda df: df.assign(t_s=df["t_s"] * 1000.0),
     "run.rate_hz = 200, but the samples of sensors.csv are 5 s apart (0.2 Hz): column t_s in seconds?"),
    (None, lambda df: df.assign(speed_m_s=df["speed_m_s"] * 1000.0),
     "column speed_m_s: the chainage s_m advances at 0.001 times the speed column's value"),
    (None, _slow_start, "sensors.csv: row 6, column speed_m_s: 0.04 m/s is below 1 m/s"),
    (None, _dropped_row, "sensors.csv: row 59, column t_s: a step of 0.01 s after 0.28 s where the samples are "
                         "0.005 s apart"),
])
def test_a_recording_that_contradicts_itself_is_refused_naming_where(default_run, tmp_path, toml, csv, said):
    rec = _edited(default_run, tmp_path, toml, csv)
    res = CliRunner().invoke(_app(), ["inservice", "process", str(rec), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and said in " ".join(res.output.split()), res.output
    assert not (tmp_path / "out").exists()


def test_a_recording_of_another_named_vehicle_does_not_get_the_builtin_model(default_run, tmp_path):
    # (bug hunt 2026-11-26) a vehicle file differing only in values a recording's [vehicle] does not
    # hold wrote the same inservice.toml, and process said "which is this recording's vehicle"
    assert 'name = "' + DEFAULT_VEHICLE_NAME + '"' in (default_run / "recording" / "inservice.toml").read_text()
    rec = _edited(default_run, tmp_path, lambda t: t.replace(f'name = "{DEFAULT_VEHICLE_NAME}"', 'name = "EMU 3"'))
    assert io.read_recording(rec).vehicle_name == "EMU 3"
    res, summary = _process(rec, tmp_path / "out")
    assert "its vehicle is 'EMU 3', the built-in model's" in " ".join(res.stderr.split())
    assert summary["calibrated"] is False


def test_a_silent_logger_does_not_fit_and_other_rates_and_the_forward_filter_are_warned(default_run, tmp_path):
    # (bug hunt 2026-11-26) every sensor column 0 "fitted the calibration" (ratios 0.00); a model
    # used at another filter rate, and the forward filter with a model tuned for the smoother, were
    # 2-4 times worse with only a note, or no word
    rec = _edited(default_run, tmp_path, csv=lambda df: df.assign(
        wheelset_ay_m_s2=0.0, wheelset_wz_rad_s=0.0, frame_ay_m_s2=0.0))
    res, summary = _process(rec, tmp_path / "out")
    cons = summary["consistency"]
    assert cons["checked"] and cons["consistent"] is False and cons["low"] == 0.3
    assert max(cons["innovation_rms_ratio"].values()) < 0.3
    assert "innovations 0.00 x the calibration's (< 0.3): a sensor silent or read at a wrong scale?" in \
        " ".join(res.stderr.split())
    res, summary = _process(default_run / "recording", tmp_path / "o2", "--filter-rate-hz", "100")
    assert "the filter runs at 100 Hz and the model was calibrated at 200 Hz" in " ".join(res.stderr.split())
    res, summary = _process(default_run / "recording", tmp_path / "o3", "--smoother", "none")
    assert "--smoother none is the paper's forward filter alone" in " ".join(res.stderr.split())
    # a recording under 200 m has no 3-200 m band: its honesty is null, not missing
    res, summary = _process(default_run / "recording", tmp_path / "o4", "--truth", str(default_run / "truth.csv"))
    assert summary["honesty_rms_error_over_sigma"] is None


def test_a_semicolon_separated_sensors_csv_says_so(default_run, tmp_path):
    # (bug hunt 2026-11-26) "missing column t_s" though t_s was in the header
    rec = _edited(default_run, tmp_path)
    df = pd.read_csv(rec / "sensors.csv")
    df.to_csv(rec / "sensors.csv", sep=";", decimal=",", index=False)
    res = CliRunner().invoke(_app(), ["inservice", "process", str(rec), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2
    assert "sensors.csv: row 1: the columns are separated by ';'" in " ".join(res.output.split())


def test_a_row_cut_short_is_named_as_such(default_run, tmp_path):
    # (bug hunt 2026-11-26) it was "not a finite number ('nan')", as for a cell holding nan
    rec = _edited(default_run, tmp_path)
    lines = (rec / "sensors.csv").read_text().split("\n")
    lines[10] = ",".join(lines[10].split(",")[:4])
    (rec / "sensors.csv").write_text("\n".join(lines))
    res = CliRunner().invoke(_app(), ["inservice", "process", str(rec), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and "sensors.csv: row 11: 4 cells, the header has 6 columns" in res.output

"""``trolley inservice process`` on what a data logger really writes (bug hunt 26b): time stamps
that jitter, a clock a few ppm off, epoch seconds, model files cut short or hand-edited."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from test_inservice_io import _app
from test_inservice_process import recording  # noqa: F401  (the fixture)
from typer.testing import CliRunner

from survey import inservice_io as io
from survey.inservice_model import BUILTIN_MODEL_PATH


def _copy(recording, tmp_path, t=None):  # noqa: F811
    """The fixture's recording with its time column replaced by ``t(t_s)``."""
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "inservice.toml").write_bytes((recording / "recording" / "inservice.toml").read_bytes())
    df = pd.read_csv(recording / "recording" / "sensors.csv")
    if t is not None:
        df["t_s"] = t(df["t_s"].to_numpy())
    df.to_csv(rec / "sensors.csv", index=False, float_format="%.17g")
    return rec


def _jitter(t):
    return t + np.random.default_rng(3).uniform(-1e-3, 1e-3, t.size)      # +-20 % of a 5 ms step


@pytest.mark.parametrize("stamps, process", [
    (_jitter, False),                          # software time stamps (refused when read)
    (lambda t: 1.7e9 + t, True),               # epoch seconds (a float64 holds them to 0.24 us)
    (lambda t: t * 1.00005, True),             # a clock 50 ppm fast
])
def test_jittering_time_stamps_are_read_as_the_uniform_samples_they_are(recording, tmp_path, stamps,  # noqa: F811
                                                                         process):
    # (bug hunt 26b) +-20 us of jitter at 200 Hz was refused as "a gap or a dropped sample?"; epoch
    # seconds and a clock 50 ppm off made the filter rate "differ from the calibration's" (199.995 Hz):
    # a warning of a J several times larger and no consistency check
    rec = _copy(recording, tmp_path, stamps)
    back = io.read_recording(rec)
    assert back.t_s[0] == 0.0 and np.allclose(np.diff(back.t_s), 0.005, rtol=1e-4, atol=0.0)
    if not process:
        return
    res = CliRunner().invoke(_app(), ["inservice", "process", str(rec), "--out", str(tmp_path / "out"),
                                      "--model", str(BUILTIN_MODEL_PATH)])
    assert res.exit_code == 0, res.output
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["consistency"]["checked"] is True, summary["consistency"]
    assert "the filter runs at" not in res.stderr


@pytest.mark.parametrize("stamps, said", [
    (lambda t: np.where(np.arange(t.size) >= 700, t + 0.005, t),
     "row 702, column t_s: a step of 0.01 s after 3.495 s where the samples are 0.005 s apart"),
    (lambda t: np.where(t > 3.75, 3.75 + (t - 3.75) * 1.2, t),
     "row 2, column t_s: 0 s is more than half a sample from the uniform rate of the whole file"),
])
def test_a_dropped_sample_or_a_rate_that_changes_is_still_refused(recording, tmp_path, stamps, said):  # noqa: F811
    rec = _copy(recording, tmp_path, stamps)
    res = CliRunner().invoke(_app(), ["inservice", "process", str(rec), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and said in " ".join(res.output.split()), res.output
    assert not (tmp_path / "out").exists()


def _model_text():
    return BUILTIN_MODEL_PATH.read_text(encoding="utf-8")


@pytest.mark.parametrize("edit, said", [
    # (bug hunt 26b) cut after r_matrix (s_matrix is the last line): the full matrices were dropped
    # for the diagonals, J 0.28 -> 1.16 mm on seed 1, exit 0
    (lambda t: t[:t.index("s_matrix = ")], "missing key noise.s_matrix: q_matrix, r_matrix, s_matrix go together"),
    # a typo read as absent: no consistency check, "calibrated before the check existed"
    (lambda t: t.replace("innovation_rms =", "innovation_rm ="),
     "unknown key noise.innovation_rm (did you mean noise.innovation_rms?)"),
    (lambda t: t.replace('kind = "bogie"\n', ""),
     "unknown key parameters.a (the paper design model has no such parameter: is the file's kind right?)"),
])
def test_a_model_file_cut_short_or_mistyped_is_refused(tmp_path, edit, said):
    from survey.inservice_model import ModelFileError, read_model

    path = tmp_path / "model.toml"
    path.write_text(edit(_model_text()), encoding="utf-8")
    with pytest.raises(ModelFileError) as exc:
        read_model(path)
    assert said in str(exc.value)


def test_older_model_files_are_still_read(tmp_path):
    import re

    from survey.inservice_model import read_model

    # before the calibration speed, the consistency reference, the full matrices and sensor_gravity
    text = _model_text()
    for key in ("speed_m_s", "innovation_rms", "q_matrix", "r_matrix", "s_matrix", "sensor_gravity"):
        text = re.sub(rf"^{key} = .*\n", "", text, flags=re.M)
    path = tmp_path / "old.toml"
    path.write_text(text, encoding="utf-8")
    old = read_model(path)
    assert old.S is None and old.speed_m_s is None and old.innovation_rms is None


def test_irregularities_keep_their_grid_at_any_chainage_and_killed_runs_leave_nothing(
        recording, tmp_path):  # noqa: F811
    # (bug hunt 26b) s_m written with %.6g: at 123456 m four rows per metre had one chainage
    rec = _copy(recording, tmp_path)
    df = pd.read_csv(rec / "sensors.csv")
    df.assign(s_m=df["s_m"] + 123456.0).to_csv(rec / "sensors.csv", index=False, float_format="%.17g")
    # (bug hunt 26b) and into an --out where a run killed -9 while writing left its temporaries: they
    # stayed, a full copy of each output per kill; a file of the user's stays
    (tmp_path / "out").mkdir()
    stale = [tmp_path / "out" / n for n in (".irregularities.csv.k1ll3d_9.csv", ".inservice.xlsx.abcd1234.xlsx")]
    for p in (*stale, tmp_path / "out" / ".notes.txt.abcd1234.txt"):
        p.write_text("partial")
    res = CliRunner().invoke(_app(), ["inservice", "process", str(rec), "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    s = pd.read_csv(tmp_path / "out" / "irregularities.csv")["s_m"].to_numpy()
    assert s[0] == 123556.0 and np.allclose(np.diff(s), 0.25, rtol=0.0, atol=1e-9)
    assert not any(p.exists() for p in stale) and (tmp_path / "out" / ".notes.txt.abcd1234.txt").exists()


def test_a_train_standing_in_a_station_is_told_to_leave_those_rows_out(recording, tmp_path):  # noqa: F811
    # (bug hunt 26b) speed 0 got "must be > 0", without the hint a speed of 0.5 m/s got
    rec = _copy(recording, tmp_path)
    df = pd.read_csv(rec / "sensors.csv")
    n = len(df)
    v = np.where(np.arange(n) >= n - 40, 0.0, df["speed_m_s"])
    s = np.where(np.arange(n) >= n - 40, df["s_m"].iloc[n - 41], df["s_m"])
    df.assign(speed_m_s=v, s_m=s).to_csv(rec / "sensors.csv", index=False, float_format="%.17g")
    with pytest.raises(io.InserviceFormatError) as exc:
        io.read_recording(rec)
    assert str(exc.value).startswith(f"sensors.csv: row {n - 40 + 2}, column speed_m_s: 0 m/s is below 1 m/s, where")
    assert str(exc.value).endswith("(starting or stopping): leave those rows out")


def test_a_model_of_a_faster_rate_is_not_answered_with_a_filter_rate_the_recording_cannot_reach(
        recording, tmp_path):  # noqa: F811
    # (bug hunt 26b) a 1000 Hz model on a 200 Hz recording said "use --filter-rate-hz 1000", which
    # changes nothing (J 0.59 mm, rms error/sigma 1.98 on seed 1)
    text = BUILTIN_MODEL_PATH.read_text(encoding="utf-8")
    model = tmp_path / "model_1k.toml"
    model.write_text(text.replace("dt_s = 0.004999999999999005", "dt_s = 0.001"), encoding="utf-8")
    res = CliRunner().invoke(_app(), ["inservice", "process", str(recording / "recording"), "--out",
                                      str(tmp_path / "out"), "--model", str(model)])
    said = " ".join(res.stderr.split())
    assert res.exit_code == 0 and "the model was calibrated at 1000 Hz" in said, res.output
    assert "--filter-rate-hz 1000" not in said and "calibrate at this rate (--rate-hz 200 --filter-rate-hz 200)" in said


def test_a_tab_separated_sensors_csv_says_so(recording, tmp_path):  # noqa: F811
    # (bug hunt 26b) "missing column t_s" though t_s was in the header, as for ';' before
    rec = _copy(recording, tmp_path)
    pd.read_csv(rec / "sensors.csv").to_csv(rec / "sensors.csv", sep="\t", index=False)
    with pytest.raises(io.InserviceFormatError, match="sensors.csv: row 1: the columns are separated by tabs"):
        io.read_recording(rec)


@pytest.mark.parametrize("chainage, said", [
    (lambda s: 5000.0 - s, "row 3, column s_m: the chainage decreases along the run (against the chainage direction?)"),
    (lambda s: np.where(s > 150.0, 150.0, s),
     "row 503, column s_m: the chainage does not advance at a speed of 20 m/s"),
    (lambda s: np.where(s > 150.0, s - 100.0, s), "row 503, column s_m: the chainage goes back by 99.9 m"),
])
def test_a_chainage_that_does_not_advance_is_named_as_such(recording, tmp_path, chainage, said):  # noqa: F811
    # (bug hunt 26b) a train running down the line, an odometer that dropped out or was reset: "the
    # chainage s_m advances at -1 times the speed column's value: speed in m/s, chainage in m?"
    rec = _copy(recording, tmp_path)
    df = pd.read_csv(rec / "sensors.csv")
    df.assign(s_m=chainage(df["s_m"].to_numpy())).to_csv(rec / "sensors.csv", index=False, float_format="%.17g")
    with pytest.raises(io.InserviceFormatError) as exc:
        io.read_recording(rec)
    assert str(exc.value).startswith("sensors.csv: " + said), str(exc.value)


def test_run_settings_and_sensor_positions_that_do_not_describe_the_columns_are_said(recording, tmp_path):  # noqa: F811
    """[run] speed_m_s in km/h, a start chainage of another run and a sensor position in mm are read
    but not used by the filter (it reads the columns; its model has its own positions): the reader
    notes each, naming the key and both values, and ``process`` warns and keeps going."""
    rec = _copy(recording, tmp_path)
    toml = (rec / "inservice.toml").read_text()
    assert "speed_m_s = 20" in toml and "start_chainage_m = " in toml and "frame_sensor_m = [" in toml
    assert io.read_recording(rec).notes == ()
    first = float(pd.read_csv(rec / "sensors.csv")["s_m"].iloc[0])
    lines = []
    for line in toml.splitlines():
        if line.startswith("speed_m_s"):
            line = "speed_m_s = 72.0"
        elif line.startswith("start_chainage_m"):
            line = f"start_chainage_m = {first + 5000.0!r}"
        elif line.startswith("frame_sensor_m"):
            line = "frame_sensor_m = [10780.0, 0.0, 460.0]"
        lines.append(line)
    (rec / "inservice.toml").write_text("\n".join(lines) + "\n")
    notes = io.read_recording(rec).notes
    assert len(notes) == 3
    assert notes[0].startswith("inservice.toml: run.speed_m_s = 72, but sensors.csv's speed_m_s runs 20-20 m/s")
    assert f"run.start_chainage_m = {first + 5000.0:g}, but sensors.csv's s_m starts at {first:g} m" in notes[1]
    assert "sensors.frame_sensor_m: x = 10780 m is beyond 20 m from the car body centre (millimetres?)" in notes[2]
    res = CliRunner().invoke(_app(), ["inservice", "process", str(rec), "--out", str(tmp_path / "out"),
                                      "--model", str(BUILTIN_MODEL_PATH)])
    assert res.exit_code == 0, res.output
    said = " ".join(res.stderr.split())
    assert all(f"warning: {' '.join(n.split())}" in said for n in notes)
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["recording_notes"] == list(notes)

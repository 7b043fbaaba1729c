"""``trolley inservice``: what a field user's slips must never do (review of 2026-11-26): overwrite
a recording, leave part of the outputs, write invalid JSON, eat the brackets of a message, or take
a nonsense value from a model or recording file."""
from __future__ import annotations

import hashlib
import json
from dataclasses import replace

import numpy as np
import pytest
from test_inservice_io import _app
from test_inservice_process import P, recording, write_model_recording  # noqa: F401  (the fixture)
from typer.testing import CliRunner

from survey import inservice_io as io
from survey.atomicwrite import write_text_atomic
from survey.inservice_model import ModelFileError, model_toml_text, read_model, write_model
from trolley.inservice.identification import EstimatorModel


def _digest(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


def _run(*args):
    return CliRunner().invoke(_app(), ["inservice", *map(str, args)])


def test_calibrate_refuses_a_recordings_file_before_simulating(recording, tmp_path):  # noqa: F811
    before = _digest(recording)
    for target in ("recording/sensors.csv", "recording/inservice.toml"):
        res = _run("calibrate", "--out", recording / target)
        assert res.exit_code == 2 and "would overwrite the data file" in res.stderr, res.output
    res = _run("calibrate", "--out", tmp_path)
    assert res.exit_code == 2 and "is a folder" in res.stderr
    # a run too short for the 3-200 m band after the start-up is refused by the option itself
    res = _run("calibrate", "--out", tmp_path / "m.toml", "--length-m", "200")
    assert res.exit_code == 2 and "--length-m" in res.stderr
    assert _digest(recording) == before and not (tmp_path / "m.toml").exists()


def test_simulate_never_replaces_a_recording_it_did_not_make(recording, tmp_path):  # noqa: F811
    field = tmp_path / "field"
    for p in recording.rglob("*"):
        if p.is_file():
            (field / p.relative_to(recording)).parent.mkdir(parents=True, exist_ok=True)
            (field / p.relative_to(recording)).write_bytes(p.read_bytes())
    before = _digest(field)
    res = _run("simulate", "--out", field, "--length-m", "10")
    assert res.exit_code == 2 and "was not made by `trolley inservice simulate`" in res.stderr, res.output
    assert _digest(field) == before
    # its own folder it writes again (same seed: the same recording)
    own = tmp_path / "own"
    assert _run("simulate", "--out", own, "--length-m", "10").exit_code == 0
    first = _digest(own)
    assert _run("simulate", "--out", own, "--length-m", "10").exit_code == 0
    assert _digest(own) == first and (own / "recording" / "sensors.csv").exists()


def test_process_of_a_short_recording_writes_valid_json_with_null_for_bands_it_cannot_hold(recording, tmp_path):  # noqa: F811
    out = tmp_path / "out"
    res = _run("process", recording / "recording", "--out", out, "--truth", recording / "truth.csv")
    assert res.exit_code == 0, res.output

    def no_nan(token):
        raise AssertionError(f"summary.json holds {token}")

    summary = json.loads((out / "summary.json").read_text(), parse_constant=no_nan)
    # the 150 m recording holds D1 and D2, not D3 (70-200 m) nor 3-200 m
    acc = summary["accuracy"]
    assert acc["D1"]["J_mm"] is not None and acc["D3"]["J_mm"] is None and acc["3-200"]["Jrel"] is None
    assert summary == json.loads(res.stdout) and summary["sensor_gravity"] is False


def test_process_writes_all_outputs_or_none_and_never_into_a_recording(recording, tmp_path):  # noqa: F811
    out = tmp_path / "out"
    (out / "inservice.xlsx").mkdir(parents=True)
    res = _run("process", recording / "recording", "--out", out)
    assert res.exit_code == 2 and "inservice.xlsx" in res.stderr and "is a folder" in res.stderr, res.output
    assert sorted(p.name for p in out.iterdir()) == ["inservice.xlsx"]
    before = _digest(recording)
    res = _run("process", recording / "recording", "--out", recording / "recording")
    assert res.exit_code == 2 and "input folder" in res.stderr
    assert _digest(recording) == before


def test_messages_keep_their_brackets(recording, tmp_path):  # noqa: F811
    res = _run("process", tmp_path / "data" / "[old]" / "rec", "--out", tmp_path / "o")
    assert res.exit_code == 2 and "[old]" in res.stderr and "not a folder" in res.stderr
    rec = tmp_path / "rec"
    (rec).mkdir()
    for name in ("inservice.toml", "sensors.csv"):
        (rec / name).write_bytes((recording / "recording" / name).read_bytes())
    toml = (rec / "inservice.toml").read_text()
    (rec / "inservice.toml").write_text(toml.replace("[sensors]", "[sensorz]"))
    res = _run("process", rec, "--out", tmp_path / "o")
    assert res.exit_code == 2 and "missing table [sensors]" in res.stderr


@pytest.mark.parametrize("edit, message", [
    (("curvature_1_m = -0.0", "curvature_1_m = 1500.0"), "run.curvature_1_m must be within +-0.01 1/m"),
    (("m_wheelset_kg = ", "m_wheelset_kg = -"), "vehicle.m_wheelset_kg must be > 0"),
    (("f23_n_m = 0", "f23_n_m = -1"), "vehicle.f23_n_m must be >= 0"),
])
def test_a_recordings_nonsense_values_are_refused(recording, tmp_path, edit, message):  # noqa: F811
    rec = tmp_path / "rec"
    rec.mkdir()
    for name in ("inservice.toml", "sensors.csv"):
        (rec / name).write_bytes((recording / "recording" / name).read_bytes())
    toml = (rec / "inservice.toml").read_text()
    assert edit[0] in toml
    (rec / "inservice.toml").write_text(toml.replace(edit[0], edit[1], 1))
    with pytest.raises(io.InserviceFormatError, match=message.replace("+", r"\+").replace(".", r"\.")):
        io.read_recording(rec)
    res = _run("process", rec, "--out", tmp_path / "o")
    assert res.exit_code == 2 and "inservice.toml" in res.stderr and not (tmp_path / "o").exists()


def _model():
    return EstimatorModel(P.with_opt([1e6, 2e4, 3e6, 4e4]), np.diag(np.arange(1.0, 8.0) * 1e-9),
                          np.diag([1e-4, 2.5e-7, 1e-4, 0.09]), 0.005, 0.8, 0.1, 30.0, 0.3)


@pytest.mark.parametrize("edit, message", [
    (("sigma_scale = 0.8", "sigma_scale = -1.0"), "noise.sigma_scale must be > 0"),
    (("q_xi_factor = 30.0", "q_xi_factor = 0.0"), "noise.q_xi_factor must be > 0"),
    (("dt_s = 0.005", "dt_s = 1e-30"), "noise.dt_s must be 1e-05-0.2 s"),
    (("r_diagonal = [0.0001", "r_diagonal = [-0.0001"), "noise.r_diagonal must be 4 finite numbers >= 0"),
    (("r_diagonal = [0.0001", "r_diagonal = [0.0"), "noise.r_matrix (or r_diagonal) must be positive definite"),
])
def test_a_model_files_nonsense_values_are_refused(tmp_path, edit, message):
    text = model_toml_text(_model())
    assert edit[0] in text
    path = tmp_path / "model.toml"
    write_text_atomic(path, text.replace(edit[0], edit[1], 1))
    with pytest.raises(ModelFileError, match="model.toml: " + message.replace("[", r"\[").replace(".", r"\.")
                       .replace("(", r"\(").replace(")", r"\)")):
        read_model(path)


@pytest.mark.parametrize("edit, message", [
    # one number too many: the 8 numbers were all printed, the lengths not
    (("q_diagonal = [", "q_diagonal = [1e-09, "),
     "noise.q_diagonal must be 7 finite numbers >= 0, got 8 (the paper design model has 7 states)"),
    (("r_diagonal = [0.0001, ", "r_diagonal = ["), "noise.r_diagonal must be 4 finite numbers >= 0, got 3"),
    # a full matrix written with one row missing (49 numbers printed before)
    (("q_matrix = [1e-09, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, ", "q_matrix = ["),
     "noise.q_matrix must be 49 finite numbers, got 42 (7x7 row by row (the paper design model has 7 states))"),
    (("s_matrix = [0.0, ", "s_matrix = [[0.0], "), "noise.s_matrix must be 28 finite numbers; number 1 is a list"),
    (("r_diagonal = [0.0001, 2.5e-07", "r_diagonal = [0.0001, -2.5e-07"),
     "noise.r_diagonal must be 4 finite numbers >= 0; number 2 is -2.5e-07"),
    (("r_diagonal = [0.0001, 2.5e-07", 'r_diagonal = [0.0001, "2.5e-07"'),
     "noise.r_diagonal must be 4 finite numbers >= 0; number 2 is '2.5e-07'"),
    (("q_diagonal = [1e-09, 2e-09, 3.0000000000000004e-09, 4e-09, 5e-09, 6.000000000000001e-09, 7.000000000000001e-09]",
      'q_diagonal = "1e-09 2e-09 3e-09 4e-09 5e-09 6e-09 7e-09"'),
     "noise.q_diagonal must be 7 finite numbers >= 0 in a list [...], got '1e-09 2e-09 3e-09 4e-09 5e-09 6e-09 ..."),
])
def test_a_model_vector_of_the_wrong_length_or_kind_says_what_is_wrong_not_all_its_numbers(
        recording, tmp_path, edit, message):  # noqa: F811
    text = model_toml_text(replace(_model(), S=np.zeros((7, 4))))
    assert edit[0] in text
    path = tmp_path / "model.toml"
    path.write_text(text.replace(edit[0], edit[1], 1), encoding="utf-8")
    with pytest.raises(ModelFileError) as info:
        read_model(path)
    assert str(info.value) == "model.toml: " + message
    # the command's line is the same: one line, exit 2, nothing written
    res = _run("process", recording / "recording", "--out", tmp_path / "o", "--model", path)
    assert res.exit_code == 2 and res.stderr == f"error: model.toml: {message}\n", res.stderr
    assert not (tmp_path / "o").exists()


def test_a_folder_given_to_model_or_truth_is_one_line_naming_the_option(recording, tmp_path):  # noqa: F811
    # it was "error: sim: file not found in /tmp" (--model) and "error: /tmp/sim: Is a directory" (--truth)
    empty, holding = tmp_path / "empty", tmp_path / "calibrated"
    empty.mkdir()
    holding.mkdir()
    write_model(holding / "model.toml", _model())
    for option, folder, said in (
            ("--model", empty, "is a folder, not a model file (`trolley inservice calibrate --out FILE` writes one)"),
            ("--model", holding, f"is a folder, not a model file (did you mean {holding / 'model.toml'}?)"),
            ("--truth", recording, f"is a folder, not a truth file (did you mean {recording / 'truth.csv'}?)"),
            ("--truth", empty, "is a folder, not a truth file (`trolley inservice simulate --out OUT` writes "
                               "OUT/truth.csv)")):
        res = _run("process", recording / "recording", "--out", tmp_path / "o", option, folder)
        assert res.exit_code == 2 and res.stderr == f"error: {option} {folder}: {said}\n", res.stderr
        assert not (tmp_path / "o").exists()


def test_a_full_r_matrix_that_is_not_positive_definite_is_refused(tmp_path):
    m = _model()
    S = np.zeros((7, 4))
    R = m.R.copy()
    R[0, 1] = R[1, 0] = 1.0            # |correlation| > 1 between the wheelset accelerometer and gyro
    write_model(tmp_path / "model.toml", replace(m, R=R, S=S))
    with pytest.raises(ModelFileError, match="noise.r_matrix .* must be positive definite"):
        read_model(tmp_path / "model.toml")
    Q = m.Q.copy()
    Q[0, 1] = 1.0                       # not symmetric
    write_model(tmp_path / "model.toml", replace(m, Q=Q, S=S))
    with pytest.raises(ModelFileError, match="noise.q_matrix must be symmetric"):
        read_model(tmp_path / "model.toml")


def test_a_write_into_a_missing_folder_names_the_users_file_not_the_temporary(tmp_path):
    target = tmp_path / "gone" / "summary.json"
    with pytest.raises(OSError) as info:
        write_text_atomic(target, "{}")
    assert info.value.filename == str(target)

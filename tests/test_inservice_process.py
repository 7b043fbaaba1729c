"""``trolley inservice process``: outputs, signs in the files, J/Jrel in summary.json, the model file
round trip and clear errors (exit 2, nothing written)."""
from __future__ import annotations

import json
from dataclasses import asdict

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from test_inservice_io import _app
from typer.testing import CliRunner

from survey import inservice_io as io
from survey.inservice_model import ModelFileError, model_toml_text, read_model, write_model
from trolley.inservice.identification import EstimatorModel
from trolley.inservice.model import ModelParameters, simulate_response

P = ModelParameters()
#: the [vehicle] keys beyond the SM's (the whole car's geometry)
EXTRA = {"half_wheelbase_m": 1.28, "half_bogie_spacing_m": 9.5, "m_frame_kg": 2615.0, "m_body_kg": 32000.0}


def write_model_recording(folder, p, t, xi, V=20.0, start_m=0.0, nominal=None, extra=None, sensors=None):
    """A recording of design model ``p`` itself running at V over the alignment xi(t), noise-free,
    or of the given ``sensors`` (N, 3)."""
    Z = simulate_response(p, V, t, xi)[1] if sensors is None else sensors
    rate = 1.0 / float(t[1] - t[0])
    rec = io.InserviceRecording(
        nominal=nominal or asdict(P), vehicle_extra=extra or EXTRA, speed_m_s=V, rate_hz=rate,
        start_chainage_m=start_m, curvature_1_m=0.0, sigma_acc_m_s2=0.01, sigma_gyro_rad_s=5e-4,
        wheelset_sensor_m=(10.78, 1.0, 0.46), frame_sensor_m=(9.5, 0.0, 0.6), t_s=t, s_m=V * t + start_m,
        speed_arr_m_s=np.full_like(t, V), wheelset_ay_m_s2=Z[:, 0], wheelset_wz_rad_s=Z[:, 1],
        frame_ay_m_s2=Z[:, 2])
    io.write_recording(folder, rec)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A 150 m recording of the SM itself at 20 m/s (noise-free) with a 12 m harmonic alignment
    and its truth.csv."""
    tmp = tmp_path_factory.mktemp("ins")
    V, dt = 20.0, 0.005
    t = np.arange(1501) * dt
    s = V * t
    xi = 1e-3 * np.sin(2 * np.pi * s / 12.0)
    write_model_recording(tmp / "recording", P, t, xi, V, start_m=100.0)
    io.write_truth(tmp / "truth.csv", s + 100.0, xi, np.zeros_like(s), 0.0)
    return tmp


def test_process_writes_outputs_with_accuracy(recording, tmp_path):
    out = tmp_path / "out"
    res = CliRunner().invoke(_app(), ["inservice", "process", str(recording / "recording"), "--out", str(out),
                                      "--truth", str(recording / "truth.csv")])
    assert res.exit_code == 0, res.output
    for f in ("irregularities.csv", "summary.json", "alignment.png", "inservice.xlsx"):
        assert (out / f).is_file(), f
    df = pd.read_csv(out / "irregularities.csv")
    assert list(df.columns) == ["s_m", "alignment_mm", "sigma_alignment_mm"]
    assert df["s_m"].iloc[0] == 100.0 and np.allclose(np.diff(df["s_m"]), 0.25)
    # files carry alignment positive to the RIGHT: the estimate matches minus the internal truth
    s = df["s_m"].to_numpy()
    truth_right_mm = -np.sin(2 * np.pi * (s - 100.0) / 12.0)
    inner = (s > 130.0) & (s < 230.0)
    assert np.sqrt(np.mean((df["alignment_mm"].to_numpy() - truth_right_mm)[inner] ** 2)) < 0.1
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["accuracy"]) == {"D1", "D2", "D3", "3-200"}
    assert summary["accuracy"]["D1"]["Jrel"] < 0.08
    assert summary["accuracy"]["D1"]["rms_true_mm"] == pytest.approx(1 / np.sqrt(2), rel=0.01)
    from openpyxl import load_workbook
    ws = load_workbook(out / "inservice.xlsx").active
    assert ws.cell(1, 1).value == "recording" and ws.cell(4, 2).value == "alignment_mm"
    assert ws.cell(1, 5).value == "model" and ws.cell(2, 5).value == (
        summary["model"] if summary["calibrated"] else f"UNCALIBRATED: {summary['model']}, default noise; neither the "
        "accuracy nor honest sigmas (trolley inservice calibrate)")
    assert ws.cell(5, 1).value == 100.0 and ws.max_row == 4 + len(df)


def test_process_forward_filter_only_and_without_truth(recording, tmp_path):
    out = tmp_path / "out"
    res = CliRunner().invoke(_app(), ["inservice", "process", str(recording / "recording"), "--out", str(out),
                                      "--smoother", "none"])
    assert res.exit_code == 0, res.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["smoother"] == "none" and "accuracy" not in summary


@pytest.mark.parametrize("args, message", [
    (["--smoother", "ukf"], "'ukf' is not one of"),
    (["--truth", "MISSING"], "truth.csv"),
    (["--model", "MISSING"], "no such file"),
])
def test_process_refuses_bad_input_without_output(recording, tmp_path, args, message):
    out = tmp_path / "out"
    args = [a.replace("MISSING", str(tmp_path / "nope" / ("truth.csv" if "truth" in message else "model.toml")))
            for a in args]
    res = CliRunner().invoke(_app(), ["inservice", "process", str(recording / "recording"), "--out", str(out), *args])
    assert res.exit_code == 2
    assert message in res.stderr
    assert "Traceback" not in res.output
    assert not out.exists()


def test_model_file_round_trip_and_errors(tmp_path):
    m = EstimatorModel(P.with_opt([1e6, 2e4, 3e6, 4e4]), np.diag(np.arange(1.0, 8.0) * 1e-9),
                       np.diag([1e-4, 2.5e-7, 1e-4, 0.09]), 0.005, 0.8, 0.1, 30.0, 0.3)
    write_model(tmp_path / "model.toml", m)
    r = read_model(tmp_path / "model.toml")
    assert r.params == m.params and np.array_equal(r.Q, m.Q) and np.array_equal(r.R, m.R)
    assert (r.dt_s, r.sigma_scale, r.q_xi_factor) == (0.005, 0.8, 30.0)
    # at another rate the per-step Q scales with dt, the virtual measurement's pull per second is kept
    h = r.at_dt(0.0025)
    assert np.allclose(h.Q, m.Q / 2) and h.R[3, 3] == pytest.approx(2 * m.R[3, 3]) and h.R[0, 0] == m.R[0, 0]
    # with correlated noises the full Q, R and S go through the file exactly
    S = np.arange(28.0).reshape(7, 4) * 1e-9
    Qf = m.Q + 1e-12 * np.ones((7, 7))
    write_model(tmp_path / "model_s.toml", replace(m, Q=Qf, S=S))
    rs = read_model(tmp_path / "model_s.toml")
    assert np.array_equal(rs.Q, Qf) and np.array_equal(rs.S, S) and np.array_equal(rs.R, m.R)
    assert r.S is None and r.innovation_rms is None
    # the consistency reference is optional (older files) and checked when present
    write_model(tmp_path / "model_nu.toml", replace(m, innovation_rms=np.array([0.14, 0.41, 0.19])))
    assert np.array_equal(read_model(tmp_path / "model_nu.toml").innovation_rms, [0.14, 0.41, 0.19])
    (tmp_path / "bad3.toml").write_text((tmp_path / "model_nu.toml").read_text().replace("[0.14,", "[-0.14,"))
    with pytest.raises(ModelFileError, match=r"bad3.toml: noise.innovation_rms must be 3 numbers > 0"):
        read_model(tmp_path / "bad3.toml")
    # (bug hunt 2026-11-26) 0 and a negative value get the same message; a negative conicity is
    # refused like a zero mass
    (tmp_path / "bad4.toml").write_text((tmp_path / "model_nu.toml").read_text().replace("[0.14,", "[0.0,"))
    with pytest.raises(ModelFileError, match=r"bad4.toml: noise.innovation_rms must be 3 numbers > 0"):
        read_model(tmp_path / "bad4.toml")
    (tmp_path / "bad5.toml").write_text(model_toml_text(m).replace("conicity = 0.15", "conicity = -0.15"))
    with pytest.raises(ModelFileError, match=r"bad5.toml: .*conicity must be >= 0"):
        read_model(tmp_path / "bad5.toml")
    bad = model_toml_text(m).replace("kx = 1000000.0", 'kx = "stiff"')
    (tmp_path / "bad.toml").write_text(bad)
    with pytest.raises(ModelFileError, match="bad.toml: parameters.kx must be a finite number"):
        read_model(tmp_path / "bad.toml")
    (tmp_path / "bad2.toml").write_text(model_toml_text(m).replace("q_diagonal = [", "q_diagonal = [1.0, "))
    with pytest.raises(ModelFileError, match="noise.q_diagonal must be 7"):
        read_model(tmp_path / "bad2.toml")


def test_process_writes_the_band_passed_alignment_with_its_sigma(tmp_path):
    # a 300 m recording of the bogie design model itself (noise-free, 8 m + 20 m harmonics) whose
    # [vehicle] table has the bogie keys: the nominal bogie model is used (uncalibrated: default noise),
    # the 3-200 m columns are the band-pass of the unfiltered estimate and follow the band-passed
    # truth (alignment positive to the RIGHT in the file)
    from trolley.inservice.bogie import BogieParameters

    b = BogieParameters()
    V, dt = 20.0, 0.005
    t = np.arange(3001) * dt
    s = V * t
    xi = 1e-3 * np.sin(2 * np.pi * s / 8.0) + 1e-3 * np.sin(2 * np.pi * s / 20.0)
    nominal = {**asdict(P), **{k: getattr(b, k) for k in ("m", "I", "l", "ls", "conicity", "r0", "f11", "f22",
                                                          "kx", "cx", "ky", "cy")}}
    extra = {"half_wheelbase_m": b.a, "half_bogie_spacing_m": 9.5, "m_frame_kg": b.mf, "m_body_kg": 2 * b.mb,
             **{k: getattr(b, v) for k, v in io.BOGIE_KEYS.items()}}
    write_model_recording(tmp_path / "rec", b, t, xi, V, nominal=nominal, extra=extra)
    assert io.bogie_nominal(io.read_recording(tmp_path / "rec")) == {**{k: getattr(b, k) for k in (
        "m", "I", "l", "ls", "conicity", "r0", "f11", "f22", "kx", "cx", "ky", "cy", "a", "mf", "mb")},
        **{v: getattr(b, v) for v in io.BOGIE_KEYS.values()}}
    io.write_truth(tmp_path / "truth.csv", s, xi, np.zeros_like(s), 0.0)
    out = tmp_path / "out"
    res = CliRunner().invoke(_app(), ["inservice", "process", str(tmp_path / "rec"), "--out", str(out),
                                      "--truth", str(tmp_path / "truth.csv")])
    assert res.exit_code == 0, res.output
    df = pd.read_csv(out / "irregularities.csv")
    assert list(df.columns) == ["s_m", "alignment_mm", "sigma_alignment_mm", "alignment_3_200m_mm",
                                "sigma_alignment_3_200m_mm"]
    from trolley.bands import bandpass_wavelength
    truth_band_right_mm = -1e3 * bandpass_wavelength(np.interp(df["s_m"], s, xi), 0.25, 3.0, 200.0)
    inner = (df["s_m"] > 40.0) & (df["s_m"] < 260.0)
    err = (df["alignment_3_200m_mm"] - truth_band_right_mm)[inner]
    rms_true = np.sqrt(np.mean(truth_band_right_mm[inner] ** 2))
    assert np.sqrt(np.mean(err ** 2)) < 0.3 * rms_true          # measured 0.25 (default noise)
    own = bandpass_wavelength(df["alignment_mm"].to_numpy(), 0.25, 3.0, 200.0)
    assert np.sqrt(np.mean((df["alignment_3_200m_mm"] - own)[inner] ** 2)) < 0.02 * rms_true
    assert (df["sigma_alignment_3_200m_mm"][inner] > 0).all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["design_model"] == "bogie" and summary["calibrated"] is False
    assert "the built-in model does not fit the recording: its [vehicle] differs" in res.stderr
    assert "uncalibrated" in res.stderr and summary["model"] == "nominal (recording [vehicle])"
    assert np.isfinite(summary["honesty_rms_error_over_sigma"])
    from openpyxl import load_workbook
    ws = load_workbook(out / "inservice.xlsx").active
    assert [ws.cell(4, j).value for j in range(1, 6)] == list(df.columns)
    # the client's workbook says it too, not only the terminal (bug hunt 26b)
    assert ws.cell(1, 5).value == "model" and ws.cell(2, 5).value.startswith(
        "UNCALIBRATED: nominal (recording [vehicle]), default noise; neither the accuracy nor honest sigmas")


def test_process_checks_that_the_recording_fits_the_calibrated_model(tmp_path):
    # recordings of the SM itself (random alignments, sensor noise) against a model file whose
    # innovation reference comes from another such recording: a recording like it fits; one with
    # the wheelset accelerometer mounted the wrong way round does not: warning on stderr, flagged in
    # summary.json and the workbook, and the outputs are still written (exit 0)
    from openpyxl import load_workbook

    from test_inservice_estimator import TIGHT_NOISE, noisy_sm_run

    from trolley.inservice.estimator import discrete_model, estimate, innovation_rms

    V, dt = 20.0, 0.005
    t, _, Z = noisy_sm_run(1)
    # (without S the model file keeps Q's diagonal only)
    Q = np.diag(np.diag(discrete_model(P, V, dt, noise=TIGHT_NOISE).Q))
    ref = innovation_rms(estimate(P, t, V * t, V, Z, Q=Q, R=TIGHT_NOISE.r()))[:3]
    write_model(tmp_path / "model.toml", EstimatorModel(P, Q, TIGHT_NOISE.r(), dt, innovation_rms=ref))
    results = {}
    for name, flip in (("fits", None), ("backwards", 0)):
        t, xi, Z = noisy_sm_run(2, flip)
        write_model_recording(tmp_path / name, P, t, xi, V, sensors=Z)
        out = tmp_path / f"out_{name}"
        res = CliRunner().invoke(_app(), ["inservice", "process", str(tmp_path / name), "--out", str(out),
                                          "--model", str(tmp_path / "model.toml")])
        assert res.exit_code == 0, res.output
        cons = json.loads((out / "summary.json").read_text())["consistency"]
        results[name] = (cons, res.stderr, load_workbook(out / "inservice.xlsx").active)
    cons, err, ws = results["fits"]
    assert cons["checked"] and cons["consistent"] and cons["limit"] == 1.6
    assert all(abs(v - 1.0) < 0.05 for v in cons["innovation_rms_ratio"].values()), cons
    assert "does not fit" not in err
    head = [c.value for c in ws[1]]
    col = head.index("model_check") + 1
    assert ws.cell(2, col).value.startswith("fits")
    assert ws.cell(2, head.index("vehicle_check") + 1).value == "the recording's vehicle is the model's"
    cons, err, ws = results["backwards"]
    assert cons["checked"] and not cons["consistent"] and cons["innovation_rms_ratio"]["wheelset_ay"] > 5.0, cons
    assert "does not fit the calibrated model" in err and "wheelset accelerometer" in err
    assert ws.cell(2, col).value.startswith("DOES NOT FIT")
    # without a model nothing is compared, and summary.json says why
    out = tmp_path / "out_nominal"
    res = CliRunner().invoke(_app(), ["inservice", "process", str(tmp_path / "fits"), "--out", str(out)])
    assert res.exit_code == 0, res.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["consistency"] == summary["vehicle_check"] == {
        "checked": False, "reason": "no calibrated model (--model)"}


def test_process_says_when_the_recording_is_of_another_vehicle(tmp_path):
    # a model is calibrated for one vehicle: a recording whose [vehicle] has another conicity and
    # body mass is processed (exit 0) but said to differ, on stderr, in summary.json and the
    # workbook, naming each key with both values; the identified suspension values (Eq. 6) and a
    # value typed to 7 significant digits are not differences
    from openpyxl import load_workbook

    from trolley.inservice.estimator import NoiseDensities, discrete_model

    V, dt = 20.0, 0.005
    t = np.arange(800) * dt
    xi = 1e-3 * np.sin(2 * np.pi * V * t / 15.0)
    model = replace(P, kx=2.0e6, cy=3.0e5)            # as identified: not the nominal primary values
    noise = NoiseDensities()
    write_model(tmp_path / "model.toml", EstimatorModel(model, discrete_model(P, V, dt, noise=noise).Q, noise.r(), dt))
    typed = {**asdict(P), "mf": round(P.mf * (1 + 3e-7), 4)}
    other = {**asdict(P), "conicity": 0.2}
    extra = {**EXTRA, "m_body_kg": 28000.0}           # (the paper model compares the supported mass only)
    for name, nominal, ex in (("same", typed, EXTRA), ("other", other, extra)):
        write_model_recording(tmp_path / name, P, t, xi, V, nominal=nominal, extra=ex)
        res = CliRunner().invoke(_app(), ["inservice", "process", str(tmp_path / name), "--out",
                                          str(tmp_path / f"out_{name}"), "--model", str(tmp_path / "model.toml")])
        assert res.exit_code == 0, res.output
    same = json.loads((tmp_path / "out_same" / "summary.json").read_text())["vehicle_check"]
    assert same == {"checked": True, "matches": True, "differences": {}}
    summary = json.loads((tmp_path / "out_other" / "summary.json").read_text())
    assert summary["vehicle_check"] == {"checked": True, "matches": False,
                                        "differences": {"conicity": {"recording": 0.2, "model": 0.15}}}
    assert "conicity 0.2 (model 0.15)" in res.stderr and "--vehicle" in res.stderr
    ws = load_workbook(tmp_path / "out_other" / "inservice.xlsx").active
    head = [c.value for c in ws[1]]
    assert ws.cell(2, head.index("vehicle_check") + 1).value.startswith("DIFFERS from the model's vehicle: conicity")
    # the bogie model compares the whole car's keys as well: the body mass (half of it per bogie)
    from trolley.inservice.bogie import BogieParameters

    bog = BogieParameters()
    rec = io.read_recording(tmp_path / "other")
    rec.vehicle_extra.update({k: 1.0 for k in io.BOGIE_KEYS})
    diffs = io.vehicle_differences(rec, bog)
    assert diffs["m_body_kg"] == (28000.0, 32000.0) and diffs["conicity"] == (0.2, 0.15)
    assert diffs["izz_frame_kg_m2"] == (1.0, bog.If) and "kx_primary_n_m" not in diffs


def test_process_refuses_a_recording_too_long_for_the_memory(recording, tmp_path, monkeypatch):
    # (review 26: an hour's recording needed some 14 GB and went to swap or the OOM killer without a
    # word) the memory is estimated before the filter's arrays; a machine too small for it says so
    import survey.limits

    from survey.commands.inservice import process_memory_bytes

    need = process_memory_bytes(1501, 20)
    monkeypatch.setattr(survey.limits, "physical_memory_bytes", lambda: int(1.9 * need))
    out = tmp_path / "out"
    args = ["inservice", "process", str(recording / "recording"), "--out", str(out)]
    res = CliRunner().invoke(_app(), args)
    assert res.exit_code == 2, res.output
    msg = " ".join(res.output.split())
    assert str(recording / "recording" / "sensors.csv") in msg and "1501 samples" in msg, msg
    assert "GB of memory" in msg and "shorter parts" in msg, msg
    assert not out.exists()
    monkeypatch.setattr(survey.limits, "physical_memory_bytes", lambda: int(2.1 * need))
    res = CliRunner().invoke(_app(), args)
    assert res.exit_code == 0, res.output

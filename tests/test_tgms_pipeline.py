"""TGMS end to end: synthetic recording -> folder -> process -> irregularities against truth, and
the CLI's handling of bad input."""
from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from survey import tgms_io
from survey.cli import app
from trolley.tgms.accuracy import accuracy
from trolley.tgms.params import TgmsParams
from trolley.tgms.pipeline import process
from trolley.tgms.simulate import SimulationSettings, simulate


@pytest.fixture(scope="module")
def sim_folder(tmp_path_factory):
    """A 180 m recording at 12 m/s (one whole curve, so the curvature matching has an exit)."""
    rec, truth = simulate(SimulationSettings(length_m=180.0, speed_m_s=12.0, seed=11, camera_rate_hz=40.0))
    d = tmp_path_factory.mktemp("tgms") / "rec"
    tgms_io.write_recording(d, rec)
    tgms_io.write_truth(d / "truth.csv", truth)
    return d, rec, truth


@pytest.fixture(scope="module")
def processed(sim_folder):
    d, rec, truth = sim_folder
    rec2 = tgms_io.read_recording(d)
    return rec2, process(rec2), tgms_io.read_truth(d / "truth.csv")


def test_folder_round_trip(sim_folder):
    d, rec, _ = sim_folder
    back = tgms_io.read_recording(d)
    assert np.allclose(back.imu_f_m_s2, rec.imu_f_m_s2, rtol=1e-8, atol=1e-7)
    assert np.array_equal(back.enc_count, rec.enc_count)
    assert np.allclose(back.lasers["right"].v_px, rec.lasers["right"].v_px, atol=6e-4)
    assert np.array_equal(back.lasers["left"].frame, rec.lasers["left"].frame)
    assert back.config.cameras["left"].K == pytest.approx(rec.config.cameras["left"].K)
    assert back.config.track.start_station_m == pytest.approx(rec.config.track.start_station_m)
    s = np.linspace(20, 180, 9)
    assert back.alignment.evaluate(s).rho_h_1_m == pytest.approx(rec.alignment.evaluate(s).rho_h_1_m)


def test_accuracy_against_truth_meets_the_targets(processed):
    rec, res, truth = processed
    acc = accuracy(res.frames, truth, res.vision.t_s, laser_offset_m=res.laser_offset_m)
    # targets of the issue (3-25 m band, std in mm), as reported and registered on the true stations
    limits = {"gauge_variation": 0.15, "cross_level": 0.15, "alignment": 0.7, "vertical_profile": 0.35}
    for name, lim in limits.items():
        assert acc.std_mm[name] < lim, (name, acc.std_mm)
        assert acc.std_registered_mm[name] < lim, (name, acc.std_registered_mm)
    # and the irregularities are really there (errors much smaller than the signal)
    from trolley.bands import bandpass_wavelength
    sig = np.nanstd(bandpass_wavelength(truth["cross_level_mm"], 0.05, 3.0, 25.0))
    assert acc.std_mm["cross_level"] < 0.2 * sig


def test_odometry_matched_the_curve_and_stations_are_close(processed):
    rec, res, truth = processed
    assert len(res.odometry.anchors_design_m) == 1
    s_true = np.interp(res.odometry.t_s, truth["t_s"], truth["s_m"])
    moving = res.odometry.v_m_s > 1.0
    # the encoder is off by its 0.1 % scale error; on a ride with one curve the matching cannot do
    # much better than that stretch over the curve (see trolley.tgms.odometry)
    err_app = np.abs(res.odometry.s_app_m - s_true)[moving].max()
    assert 0.1 < err_app < 0.2
    assert np.abs(res.odometry.s_m - s_true)[moving].max() < err_app + 0.05


def test_flagged_frames_give_empty_cells_never_guesses(sim_folder):
    d, rec, truth = sim_folder
    lp = rec.lasers["right"]
    drop = (lp.frame >= 560) & (lp.frame < 600)          # 1 s (14-15 s, ~12 m) without the right rail
    rec2 = dataclasses.replace(rec, lasers={"left": rec.lasers["left"],
                                            "right": type(lp)(lp.frame[~drop], lp.t_s[~drop], lp.u_px[~drop], lp.v_px[~drop])})
    res = process(rec2, match_curves=False)
    t_gap = (rec.lasers["left"].t_s[rec.lasers["left"].frame == 565][0], rec.lasers["left"].t_s[rec.lasers["left"].frame == 595][0])
    s_gap = np.interp(t_gap, res.odometry.t_s, res.odometry.s_m)
    g = res.grid
    inside = (g.s_m > s_gap[0]) & (g.s_m < s_gap[1])
    assert inside.sum() > 20
    assert np.isnan(g.gauge_variation_m[inside]).all() and np.isnan(g.alignment_m[inside]).all()


def test_cli_process_writes_csv_and_plots(sim_folder, tmp_path):
    d, _, _ = sim_folder
    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["tgms", "process", str(d), "--out", str(out), "--band", "D1"])
    assert r.exit_code == 0, r.output
    import json
    summary = json.loads(r.stdout)
    assert summary["accuracy_3_25m"]["std_mm"]["gauge_variation"] < 0.15
    # a clean ride gets no warning (0.3 m between frames on the 0.25 m grid fills every cell)
    assert summary["warnings"] == [] and "warning" not in r.stderr
    data = tgms_io.read_irregularities(out / "irregularities.csv")
    assert list(data)[:5] == tgms_io.IRREGULARITY_COLUMNS
    assert np.allclose(np.diff(data["s_m"]), 0.25)
    for name in ("gauge_variation", "cross_level", "alignment", "vertical_profile"):
        assert (out / f"{name}.png").stat().st_size > 1000
    # the empty cells are counted after the band-pass (its record ends), not before
    data_cells = {n: int(np.isnan(data[f"{n}_mm"]).sum()) for n in ("gauge_variation", "alignment")}
    assert {n: summary["empty_cells"][n] for n in data_cells} == data_cells
    assert data_cells["alignment"] > 0
    # a band whose long wavelengths this 180 m record cannot hold: refused, nothing written
    r = CliRunner().invoke(app, ["tgms", "process", str(d), "--out", str(tmp_path / "d3"), "--band", "D3",
                                 "--no-plots"])
    assert r.exit_code == 2 and "is too short for wavelengths up to 200 m" in r.stderr, r.output
    assert not (tmp_path / "d3" / "irregularities.csv").exists()


def _copy(sim_folder, tmp_path):
    d, _, _ = sim_folder
    dst = tmp_path / "bad"
    shutil.copytree(d, dst)
    return dst


def test_cli_bad_input_names_the_item(sim_folder, tmp_path):
    runner = CliRunner()
    # missing calibration key
    dst = _copy(sim_folder, tmp_path)
    text = (dst / "tgms.toml").read_text()
    start = text.index("[camera.right]")
    k_line = text.index("K = ", start)
    (dst / "tgms.toml").write_text(text[:k_line] + text[text.index("\n", k_line) + 1:])
    r = runner.invoke(app, ["tgms", "process", str(dst), "--out", str(tmp_path / "o1")])
    assert r.exit_code == 2 and "camera.right.K" in r.stderr
    assert not (tmp_path / "o1" / "irregularities.csv").exists()
    # laser plane that the camera cannot see
    dst2 = tmp_path / "bad2"
    shutil.copytree(sim_folder[0], dst2)
    text = (dst2 / "tgms.toml").read_text()
    start = text.index("[camera.left]")
    lp = text.index("laser_plane = ", start)
    text = text[:lp] + "laser_plane = [1.0, 0.0, 0.0, 1.0]" + text[text.index("\n", lp):]
    (dst2 / "tgms.toml").write_text(text)
    r = runner.invoke(app, ["tgms", "process", str(dst2), "--out", str(tmp_path / "o2")])
    assert r.exit_code == 2 and "camera left" in r.stderr and "laser plane" in r.stderr
    # a non-numeric pixel
    dst3 = tmp_path / "bad3"
    shutil.copytree(sim_folder[0], dst3)
    lines = (dst3 / "laser_left.csv").read_text().splitlines()
    parts = lines[5].split(",")
    parts[2] = "abc"
    lines[5] = ",".join(parts)
    (dst3 / "laser_left.csv").write_text("\n".join(lines) + "\n")
    r = runner.invoke(app, ["tgms", "process", str(dst3), "--out", str(tmp_path / "o3")])
    assert r.exit_code == 2 and "laser_left.csv: row 6, column u_px" in r.stderr
    # empty laser file (no frames)
    dst4 = tmp_path / "bad4"
    shutil.copytree(sim_folder[0], dst4)
    (dst4 / "laser_right.csv").write_text("frame,t_s,u_px,v_px\n")
    r = runner.invoke(app, ["tgms", "process", str(dst4), "--out", str(tmp_path / "o4")])
    assert r.exit_code == 2 and "laser_right.csv" in r.stderr and "no data rows" in r.stderr


def test_params_file_round_trip(tmp_path):
    from survey.commands.tgms import params_toml_text, read_params
    p = TgmsParams(accel_noise_m_s2_sqrt_hz=2e-3, orientation="madgwick")
    f = tmp_path / "p.toml"
    f.write_text(params_toml_text(p, {"loglik": 1.5}))
    assert read_params(f) == p
    f.write_text('cutoff_wavelength_m = -3.0\n')
    with pytest.raises(ValueError, match="p.toml: parameter cutoff_wavelength_m"):
        read_params(f)


def test_ekf_variant_agrees_with_truth_and_with_the_ltv(processed):
    rec, res, truth = processed
    res_e = process(rec, TgmsParams(trajectory="ekf"), match_curves=True)
    acc = accuracy(res_e.frames, truth, res_e.vision.t_s, laser_offset_m=res_e.laser_offset_m)
    assert acc.std_registered_mm["alignment"] < 0.7 and acc.std_registered_mm["vertical_profile"] < 0.35
    # two independent trajectory estimators agree in the band far better than the motion itself
    from trolley.bands import bandpass_wavelength
    d = bandpass_wavelength(res_e.grid.alignment_m - res.grid.alignment_m, 0.25, 3.0, 25.0)
    sig = bandpass_wavelength(res.grid.alignment_m, 0.25, 3.0, 25.0)
    assert np.nanstd(d) < 0.25 * np.nanstd(sig)


def test_cml_tuning_does_not_lower_the_likelihood(processed):
    import dataclasses as dc
    from trolley.tgms.tuning import tune_cml
    rec, _, _ = processed
    bad = dc.replace(TgmsParams(), accel_disturbance_m_s2=30.0, gyro_noise_rad_sqrt_s=1e-3)
    p, info = tune_cml(rec, base=bad, max_evaluations=40, seed=1, decades=2.0)
    assert info["loglik"] > info["loglik_default"] + 10.0
    assert p.accel_disturbance_m_s2 < 30.0


def test_cli_simulate_writes_a_readable_folder(tmp_path):
    import json
    out = tmp_path / "sim"
    r = CliRunner().invoke(app, ["tgms", "simulate", "--out", str(out), "--length-m", "60", "--speed-m-s", "8",
                                 "--camera-rate-hz", "10", "--seed", "4", "--rail-profile", "54E1"])
    assert r.exit_code == 0, r.output
    info = json.loads(r.stdout)
    rec = tgms_io.read_recording(out)
    assert rec.config.track.rail_profile == "54E1"
    assert info["frames"] == 1 + max(int(rec.lasers[s].frame.max()) for s in ("left", "right"))
    truth = tgms_io.read_truth(out / "truth.csv")
    assert truth["s_m"][-1] - truth["s_m"][0] == pytest.approx(60.0, abs=0.5)


def test_band_option_parsing():
    from survey.commands.tgms import parse_band
    assert parse_band("D1", 0.25) == (3.0, 25.0)
    assert parse_band("none", 0.25) is None
    assert parse_band("3-70", 0.25) == (3.0, 70.0)
    assert parse_band("3", 0.25) == (0.625, 3.0)
    with pytest.raises(ValueError, match="need 0 < SHORT < LONG"):
        parse_band("25-3", 0.25)
    for text in ("inf", "3-inf", "nan"):
        with pytest.raises(ValueError, match="finite"):
            parse_band(text, 0.25)
    with pytest.raises(ValueError, match=r"the cut-off LONG must exceed 2.5 steps \(0.625 m at --step-m 0.25\)"):
        parse_band("0.1", 0.25)
    # (bug hunt) the short edge obeys the same 2.5 steps: D1 (3-25 m) on a 5 m grid was
    # accepted while --band 3 at --step-m 2 was refused
    for text in ("D1", "3-25", "12-30"):
        with pytest.raises(ValueError, match=r"short edge \d+ m is below 2.5 steps \(12.5 m at --step-m 5\).*"
                                             r"use --step-m \d\.?\d* or less"):
            parse_band(text, 5.0)
    assert parse_band("D2", 5.0) == (25.0, 70.0) and parse_band("12.5-30", 5.0) == (12.5, 30.0)
    assert parse_band("D1", 1.2) == (3.0, 25.0)


def test_params_out_of_range_are_refused_naming_the_key():
    # a finite positive value far from the default, inf and 1e300 overflow later, far from the file
    for key, value in (("cutoff_wavelength_m", float("inf")), ("accel_noise_m_s2_sqrt_hz", 1e300),
                       ("gyro_noise_rad_sqrt_s", 1e-20)):
        with pytest.raises(ValueError, match=f"parameter {key} must be a finite number within"):
            TgmsParams.from_dict({key: value})
    assert TgmsParams.from_dict({"cutoff_wavelength_m": 1e9}).cutoff_wavelength_m == 1e9


def test_cml_constraints():
    from trolley.tgms.tuning import attitude_crossover_hz, satisfies_constraint
    p = TgmsParams()
    assert attitude_crossover_hz(p.gyro_noise_rad_sqrt_s, p.accel_disturbance_m_s2, 0.01) == pytest.approx(
        4.4e-5 * 9.80665 / (0.3 * 0.1) / (2 * np.pi))
    assert satisfies_constraint(p, "kf") and satisfies_constraint(p, "ekf")
    # the degenerate optimum found without the constraint: accelerometers explain everything
    assert not satisfies_constraint(TgmsParams(gyro_noise_rad_sqrt_s=0.169, accel_disturbance_m_s2=0.035), "kf")
    # Gonzalez-Carbajal 2023 Eq. 19
    assert not satisfies_constraint(TgmsParams(ekf_u_acc_m2_s4=2e-3, ekf_u_pos_m2=1e-2), "ekf")


def test_laser_planes_ahead_of_the_imu():
    """Laser planes 0.3 m ahead of the IMU: the cut is at s + 0.3 and the TGMS's relative yaw and
    pitch act through that lever arm; the exact transform keeps the accuracy of the x = 0 case."""
    rec, tr = simulate(SimulationSettings(length_m=180.0, speed_m_s=12.0, seed=11, camera_rate_hz=40.0,
                                          laser_plane_x_m=0.3))
    truth = dataclasses.asdict(tr)
    res = process(rec)
    ok = np.isfinite(res.laser_offset_m) & res.vision.ok
    assert np.median(res.laser_offset_m[ok]) == pytest.approx(0.3, abs=0.005)
    acc = accuracy(res.frames, truth, res.vision.t_s, laser_offset_m=res.laser_offset_m)
    limits = {"gauge_variation": 0.15, "cross_level": 0.15, "alignment": 0.7, "vertical_profile": 0.35}
    for name, lim in limits.items():
        assert acc.std_mm[name] < lim, (name, acc.std_mm)
    # the 0.3 m shift is real: registering the frames at the IMU's stations instead is clearly worse
    acc_wrong = accuracy(res.frames, truth, res.vision.t_s, laser_offset_m=0.0)
    assert acc_wrong.std_registered_mm["cross_level"] > 2 * acc.std_registered_mm["cross_level"]


def test_cli_tune_then_process_with_the_params_file(sim_folder, tmp_path):
    """`tgms tune` writes a parameter file within its evaluation budget; `tgms process --params`
    runs with exactly those parameters; the band-passed output flags its edge-transient cells."""
    import json
    from survey.commands.tgms import read_params
    d, _, _ = sim_folder
    pfile = tmp_path / "p.toml"
    r = CliRunner().invoke(app, ["tgms", "tune", str(d), "--out", str(pfile), "--evaluations", "12"])
    assert r.exit_code == 0, r.output
    info = json.loads(r.stdout)
    assert info["evaluations"] <= 12
    assert info["loglik"] >= info["loglik_default"]
    tuned = read_params(pfile)
    assert tuned.to_dict() == info["params"]
    out = tmp_path / "o"
    r = CliRunner().invoke(app, ["tgms", "process", str(d), "--out", str(out), "--params", str(pfile),
                                 "--band", "D1", "--no-plots"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["params"] == tuned.to_dict()
    data = tgms_io.read_irregularities(out / "irregularities.csv")
    s, edge = data["s_m"], data["band_edge"]
    # D1's long edge is 25 m: the first and last 25 m of the record are flagged, the middle not
    assert (edge[s < s[0] + 24.0] == 1).all() and (edge[s > s[-1] - 24.0] == 1).all()
    assert (edge[(s > s[0] + 26.0) & (s < s[-1] - 26.0)] == 0).all()


def test_band_edge_flags_split_at_long_gaps_only():
    from survey.commands.tgms import band_edge_flags
    v = np.ones(1000)                   # 250 m at 0.25 m
    v[500:504] = np.nan                 # 1 m gap: bridged by the 3-25 m filter, no edge
    assert band_edge_flags(v, 0.25, 3.0, 25.0)[150:850].sum() == 0
    v[500:520] = np.nan                 # 5 m gap: splits the record
    f = band_edge_flags(v, 0.25, 3.0, 25.0)
    assert f[499] == 1 and f[520] == 1 and f[500:520].sum() == 0
    # cells closer than 25 m (100 cells) to a record end are flagged, the others not
    assert f[:100].all() and not f[100:400].any() and f[400:500].all()
    assert f[520:620].all() and not f[620:900].any() and f[900:].all()


def test_tune_without_any_usable_frame_is_a_clear_error(sim_folder, tmp_path):
    d, _, _ = sim_folder
    dst = tmp_path / "sparse"
    shutil.copytree(d, dst)
    for side in ("left", "right"):
        lines = (dst / f"laser_{side}.csv").read_text().splitlines()
        # ~4 points per frame: every frame is flagged (< 20 inliers)
        (dst / f"laser_{side}.csv").write_text("\n".join([lines[0]] + lines[1::50]) + "\n")
    r = CliRunner().invoke(app, ["tgms", "tune", str(dst), "--out", str(tmp_path / "p.toml"), "--evaluations", "10"])
    assert r.exit_code == 2
    assert "no camera frame could be used" in r.stderr and "Traceback" not in r.output
    assert not (tmp_path / "p.toml").exists()


def test_95_percent_intervals_cover_the_truth(processed):
    """Coverage of the 1.96-sigma intervals (unfiltered, mean error removed) on a simulated ride.
    They are conservative (docs/tgms.md): measured 0.97-1.0 here and 0.82-1.0 on the benchmark
    rides; the assertion is the fraction a useful interval must reach."""
    rec, res, truth = processed
    acc = accuracy(res.frames, truth, res.vision.t_s, laser_offset_m=res.laser_offset_m)
    for name in ("gauge_variation", "cross_level", "alignment", "vertical_profile"):
        assert acc.coverage95[name] >= 0.8, (name, acc.coverage95)
    assert acc.coverage95["gauge_variation"] >= 0.9 and acc.coverage95["cross_level"] >= 0.9


def test_madgwick_keeps_the_vision_only_gauge_sigma(processed):
    rec, res, _ = processed
    res_m = process(rec, TgmsParams(orientation="madgwick"))
    g = res_m.grid
    ok = np.isfinite(g.gauge_variation_m)
    assert np.isfinite(g.sigma_gauge_variation_m[ok]).all()
    # the same vision sigma as the kf variant (the roll term is second order for the gauge)
    med = np.nanmedian(g.sigma_gauge_variation_m)
    assert med == pytest.approx(np.nanmedian(res.grid.sigma_gauge_variation_m), rel=0.02)
    # the roll-dependent sigmas have no roll covariance to use: empty, not understated
    assert np.isnan(g.sigma_cross_level_m).all() and np.isnan(g.sigma_alignment_m).all()


def test_cli_warns_that_orientation_is_ignored_with_the_ekf(sim_folder, tmp_path):
    d, _, _ = sim_folder
    r = CliRunner().invoke(app, ["tgms", "process", str(d), "--out", str(tmp_path / "o"), "--trajectory", "ekf",
                                 "--orientation", "madgwick", "--no-plots"])
    assert r.exit_code == 0, r.output
    assert "--orientation madgwick is ignored" in r.stderr
    import json
    assert [w.split(":")[0] for w in json.loads(r.stdout)["warnings"]] == ["--orientation madgwick is ignored"]


@pytest.mark.parametrize("edit, said", [
    # (bug hunt 2026-11-26) each gave exit 0 with wrong measurements, an endless run, or an
    # "fmin" message naming nothing
    (lambda df: df[(df["t_s"] < 12.0) | (df["t_s"] > 12.1)], "imu.csv: row 6002, column t_s: a gap of 0.104 s after 11.998 s"),
    (lambda df: df.assign(t_s=df["t_s"] * 1000.0), "tgms.toml: imu.rate_hz = 500, but the samples of imu.csv are 2 s"),
])
def test_an_imu_with_a_gap_or_in_ms_is_refused(sim_folder, tmp_path, edit, said):
    import pandas as pd

    dst = _copy(sim_folder, tmp_path)
    df = pd.read_csv(dst / "imu.csv")
    edit(df).to_csv(dst / "imu.csv", index=False, float_format="%.9g")
    r = CliRunner().invoke(app, ["tgms", "process", str(dst), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and said in " ".join(r.stderr.split()), r.stderr
    assert not (tmp_path / "o").exists()


def _reverse_after_row_6000(df):
    c = df["count"].to_numpy().copy()
    c[5999:] = 2 * c[5998] - c[5999:]         # data row 5999 (file row 6001) on, the counts fall again
    return df.assign(count=c)


@pytest.mark.parametrize("edit, said", [
    (lambda df: df.assign(count=-df["count"]), "encoder.csv: row 649, column count: the count goes backwards (-1 after 0)"),
    # (bug hunt) an encoder reversing midway: refused at the row where the counts start to fall
    (_reverse_after_row_6000, "encoder.csv: row 6001, column count: the count goes backwards ("),
], ids=["from-the-start", "midway"])
def test_an_encoder_counting_backwards_is_refused_naming_the_row(sim_folder, tmp_path, edit, said):
    import pandas as pd

    dst = _copy(sim_folder, tmp_path)
    df = pd.read_csv(dst / "encoder.csv")
    edit(df).to_csv(dst / "encoder.csv", index=False)
    for cmd in (["process", str(dst), "--out", str(tmp_path / "o")], ["tune", str(dst), "--out", str(tmp_path / "p.toml")]):
        r = CliRunner().invoke(app, ["tgms", *cmd])
        assert r.exit_code == 2 and said in r.stderr, r.stderr


def _edit_lasers(dst, edit):
    """Rewrite laser_left.csv and laser_right.csv of a copied recording by ``edit(left, right)``."""
    import pandas as pd

    dfs = [pd.read_csv(dst / f"laser_{side}.csv") for side in ("left", "right")]
    for side, df in zip(("left", "right"), edit(*dfs)):
        df.to_csv(dst / f"laser_{side}.csv", index=False)


def _late_row_of_frame_3(left, right):
    t = left["t_s"].to_numpy().copy()
    t[np.flatnonzero(left["frame"].to_numpy() == 3)[-1]] += 0.01      # 0.4 frame periods at 40 Hz
    return left.assign(t_s=t), right


@pytest.mark.parametrize("edit, said", [
    # (bug hunt) every frame number of the right camera one too high gave exit 0 and 13x
    # the gauge error; its times were never compared with the left camera's
    (lambda left, right: (left, right.assign(frame=right["frame"] + 1)),
     "laser_right.csv: row 2, column t_s: frame 1 at 0 s, but laser_left.csv row 106 has it at 0.025 s, 1 frame "
     "period apart: rows with the same frame number are the same instant"),
    (lambda left, right: (left, right.assign(t_s=right["t_s"] + 0.5)),
     "laser_right.csv: row 2, column t_s: frame 0 at 0.5 s, but laser_left.csv row 2 has it at 0 s, 20 frame periods"),
    (_late_row_of_frame_3, "laser_left.csv: row 414, column t_s: frame 3 at 0.085 s, but its row 312 says 0.075 s"),
    # 100 s late: "zero-size array to reduction operation fmin"
    (lambda left, right: (left.assign(t_s=left["t_s"] + 100.0), right.assign(t_s=right["t_s"] + 100.0)),
     "laser_left.csv and laser_right.csv start at 100 s (column t_s), when imu.csv has ended (22.88 s): the files "
     "share no time"),
], ids=["right-frames-plus-1", "right-times-plus-0.5s", "a-row-late-within-its-frame", "cameras-100s-late"])
def test_camera_frames_at_other_times_than_their_number_says_are_refused(sim_folder, tmp_path, edit, said):
    dst = _copy(sim_folder, tmp_path)
    _edit_lasers(dst, edit)
    r = CliRunner().invoke(app, ["tgms", "process", str(dst), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and said in " ".join(r.stderr.split()), r.stderr
    assert not (tmp_path / "o").exists()


def _process_json(dst, out, *extra):
    import json

    r = CliRunner().invoke(app, ["tgms", "process", str(dst), "--out", str(out), "--no-plots", *extra])
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout), " ".join(r.stderr.split())


def test_a_camera_file_that_ends_early_leaves_its_stretch_empty_and_says_so(sim_folder, tmp_path):
    # (bug hunt) laser_right.csv cut half-way: exit 0, no warning, irregularities.csv
    # ended half-way with empty_cells 0
    dst = _copy(sim_folder, tmp_path)
    truth = tgms_io.read_truth(dst / "truth.csv")
    _edit_lasers(dst, lambda left, right: (left, right[right["frame"] < 500]))
    summary, err = _process_json(dst, tmp_path / "o")
    said = [w for w in summary["warnings"] if w.startswith("laser_right.csv has no rows for frames 500-")]
    assert len(said) == 1 and said[0] in err and "which laser_left.csv has: no right-rail profile there" in said[0]
    t = float(said[0].split("(t_s ")[1].split("-")[0])
    s_lo, s_hi = (float(x) for x in said[0].split(", s ")[1].split(" m)")[0].split("-"))
    assert t == pytest.approx(12.5) and s_lo == pytest.approx(np.interp(t, truth["t_s"], truth["s_m"]), abs=0.5)
    data = tgms_io.read_irregularities(tmp_path / "o" / "irregularities.csv")
    s = data["s_m"]
    # the grid still runs to the end of the ride, empty from where the right camera stopped
    assert s[-1] > truth["s_m"][-1] - 2.0 and s_hi > s[-1] - 1.0
    assert np.isnan(data["gauge_variation_mm"][s > s_lo + 0.5]).all()
    assert np.isfinite(data["gauge_variation_mm"][(s > 30.0) & (s < s_lo - 1.0)]).mean() > 0.95
    assert summary["empty_cells"]["gauge_variation"] == int(np.isnan(data["gauge_variation_mm"]).sum()) > 100


def _thin_frames(left, right, keep):
    """Every frame number not kept by ``keep(frame)`` loses all but 4 of its laser points (flagged)."""
    out = []
    for df in (left, right):
        f = df["frame"]
        rank = df.groupby("frame").cumcount()
        out.append(df[keep(f) | (rank < 4)])
    return out


@pytest.mark.parametrize("edit, said", [
    # (bug hunt) 5 Hz cameras at 10 m/s: 784 of 793 cells empty, accuracy null, no word
    (lambda left, right: (left[left["frame"] % 10 == 0], right[right["frame"] % 10 == 0]),
     r"^the camera frames are 2\.\d+ m apart along the track \(median; 4 Hz at \d+\.?\d* m/s\), more than the 0\.5 m "
     r"across which irregularities.csv interpolates: (\d+) of (\d+) cells are empty; record at \d+\.?\d* Hz or more"),
    # most frames flagged by the profile fit, the frames themselves close together
    (lambda left, right: _thin_frames(left, right, lambda f: f % 5 == 0),
     r"^(\d+) of (\d+) cells of irregularities.csv \(\d+ %\) are empty \(no usable frame within 0.5 m\): \d+ of \d+ "
     r"camera frames were flagged by the profile fit"),
])
def test_mostly_empty_output_is_warned_with_the_reason(sim_folder, tmp_path, edit, said):
    import re

    dst = _copy(sim_folder, tmp_path)
    _edit_lasers(dst, edit)
    summary, err = _process_json(dst, tmp_path / "o")
    assert len(summary["warnings"]) == 1 and "warning: " + summary["warnings"][0] in err, summary["warnings"]
    m = re.search(said, summary["warnings"][0])
    assert m, summary["warnings"][0]
    empty, total = int(m[1]), int(m[2])
    assert empty == summary["empty_cells"]["gauge_variation"] and empty > 0.5 * total == 0.5 * summary["rows"]


def test_a_processing_rate_below_the_cameras_is_refused_naming_the_file(sim_folder, tmp_path):
    # (bug hunt) process_rate_hz = 7 with 100 Hz cameras: exit 0, cross level 20x worse
    from survey.commands.tgms import check_process_rate
    d, rec, _ = sim_folder
    pfile = tmp_path / "p.toml"
    pfile.write_text('format = "trolley-tgms-params/1"\nprocess_rate_hz = 7.0\n')
    r = CliRunner().invoke(app, ["tgms", "process", str(d), "--out", str(tmp_path / "o"), "--params", str(pfile)])
    assert r.exit_code == 2 and (f"{pfile}: parameter process_rate_hz = 7 Hz is below the camera frame rate (40 Hz, "
                                 "laser_left.csv and laser_right.csv)") in " ".join(r.stderr.split()), r.stderr
    assert not (tmp_path / "o").exists()
    # the cameras' rate is the limit (40 Hz here); above 100 Hz the default 100 Hz is
    check_process_rate(TgmsParams(process_rate_hz=40.0), rec, None)
    with pytest.raises(ValueError, match="process_rate_hz = 39 Hz is below"):
        check_process_rate(TgmsParams(process_rate_hz=39.0), rec, None)
    fast = dataclasses.replace(rec, lasers={s: dataclasses.replace(lp, t_s=lp.t_s / 5.0) for s, lp in rec.lasers.items()})
    check_process_rate(TgmsParams(), fast, None)
    with pytest.raises(ValueError, match=r"below the camera frame rate \(200 Hz.*use at least 100 Hz"):
        check_process_rate(TgmsParams(process_rate_hz=90.0), fast, None)


def test_camera_frames_only_while_standing_are_a_clear_error(sim_folder, tmp_path):
    # frames only in the first 0.4 s (at rest): no frame has a station ("zero-size array to
    # reduction operation fmin" before)
    dst = _copy(sim_folder, tmp_path)
    _edit_lasers(dst, lambda left, right: (left[left["frame"] < 16], right[right["frame"] < 16]))
    r = CliRunner().invoke(app, ["tgms", "process", str(dst), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "no camera frame was taken while the vehicle moved within the IMU and encoder record " \
        "(frames at 0-0.375 s, IMU at" in " ".join(r.stderr.split()), r.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("name", ["encoder.csv", "imu.csv"])
def test_camera_frames_outside_the_encoder_or_imu_record_are_refused(sim_folder, tmp_path, name):
    # (bug hunt 2026-11-26) encoder.csv cut at 15 s of a 26 s ride: exit 0, the output ended at
    # 89.5 m with 2.2 mm of cross-level error; an IMU cut likewise
    import pandas as pd

    dst = _copy(sim_folder, tmp_path)
    df = pd.read_csv(dst / name)
    end = float(df["t_s"].iloc[len(df) // 2])
    df[df["t_s"] <= end].to_csv(dst / name, index=False)
    r = CliRunner().invoke(app, ["tgms", "process", str(dst), "--out", str(tmp_path / "o")])
    said = "laser_left.csv and laser_right.csv run to"
    assert r.exit_code == 2 and said in r.stderr and f"{name} ends at {end:.6g} s" in " ".join(r.stderr.split()), r.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("edit, said", [
    (lambda d: (d / "tgms.toml").write_text((d / "tgms.toml").read_text().replace(
        "start_station_m = 10.0", "start_station_m = 300.0")), "beyond the end of the alignment alignment.xml"),
    (lambda d: (d / "encoder.csv").write_text("t_s,count\n" + "".join(
        f"{t},{int(c) + 1000000}\n" for t, c in (ln.split(",") for ln in (d / "encoder.csv").read_text().split()[1:]))),
     "encoder.csv: row 2, column count: count 1000000 puts the TGMS at"),
], ids=["ride-past-the-end", "count-not-0-at-the-start"])
def test_an_encoder_running_off_the_alignment_is_refused_naming_the_row(sim_folder, tmp_path, edit, said):
    """(bug hunt) A ride past the design's end was processed on a straight extrapolation (exit 0,
    32 mm of cross-level error); a count that does not start at 0 ended in an internal IndexError."""
    dst = _copy(sim_folder, tmp_path)
    edit(dst)
    r = CliRunner().invoke(app, ["tgms", "process", str(dst), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and said in r.stderr, r.stderr
    assert not (tmp_path / "o").exists()

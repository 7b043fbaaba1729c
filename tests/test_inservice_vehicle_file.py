"""The vehicle file of ``trolley inservice simulate | calibrate --vehicle`` (survey.inservice_vehicle):
round trip, partial files, refused values with the key named, the hunting check, and a simulated
recording that carries the file's vehicle and sensor noise."""
from __future__ import annotations

from dataclasses import fields, replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_inservice_io import _app
from typer.testing import CliRunner

from survey import inservice_io as io
from survey.inservice_vehicle import KEYS, RANGES, VehicleFileError, read_vehicle, vehicle_toml_text, write_vehicle
from trolley.inservice.vehicle import (DEFAULT_VEHICLE_NAME, SIGMA_ACC_M_S2, SIGMA_GYRO_RAD_S, VehicleParameters,
                                       largest_growth_rate)

RUN_CONDITIONS = {"conicity_factor", "creep_factor", "sensor_gravity"}


def _file(tmp_path, body: str, name="v.toml"):
    path = tmp_path / name
    path.write_text('format = "trolley-inservice-vehicle/1"\n' + body, encoding="utf-8")
    return path


def test_every_vehicle_parameter_has_a_key_and_the_file_round_trips(tmp_path):
    assert set(KEYS.values()) == {f.name for f in fields(VehicleParameters)} - RUN_CONDITIONS
    assert len(set(KEYS.values())) == len(KEYS)
    odd = replace(VehicleParameters(), m_body=28123.5, cy_s=0.0, conicity=0.2125, h_s=1.05)
    write_vehicle(tmp_path / "v.toml", odd, 'EMU "Talent" car 2', 0.02, 1e-3)
    vf = read_vehicle(tmp_path / "v.toml")
    assert vf.params == odd and vf.name == 'EMU "Talent" car 2' and vf.defaults == ()
    assert (vf.sigma_acc_m_s2, vf.sigma_gyro_rad_s) == (0.02, 1e-3)


@settings(max_examples=25, deadline=None)
@given(st.dictionaries(st.sampled_from(sorted(KEYS)), st.floats(0.0, 1.0), max_size=6))
def test_a_partial_file_keeps_the_default_vehicle_for_the_keys_it_leaves_out(tmp_path_factory, fractions):
    # values anywhere in each key's range: the keys written are the file's, every other one the
    # Manchester vehicle's, and `defaults` names exactly those left out
    values = {k: RANGES[k][0] + f * (RANGES[k][1] - RANGES[k][0]) for k, f in fractions.items()}
    body = "[vehicle]\n" + "".join(f"{k} = {v!r}\n" for k, v in values.items())
    path = _file(tmp_path_factory.mktemp("v"), body)
    try:
        vf = read_vehicle(path)
    except VehicleFileError as exc:     # overlapping bogies or a body below its frame
        assert "must exceed" in str(exc)
        return
    base = VehicleParameters()
    for key, field in KEYS.items():
        assert getattr(vf.params, field) == (values[key] if key in values else getattr(base, field))
    assert set(vf.defaults) == set(KEYS) - set(values)
    assert vf.name == "v" and (vf.sigma_acc_m_s2, vf.sigma_gyro_rad_s) == (SIGMA_ACC_M_S2, SIGMA_GYRO_RAD_S)


@pytest.mark.parametrize("body, message", [
    ("[vehicle]\nm_bdy_kg = 30000.0\n", "unknown key vehicle.m_bdy_kg (did you mean m_body_kg?)"),
    ("[vehicle]\nm_body_kg = -3.0\n", "vehicle.m_body_kg must be > 0, got -3"),
    ("[vehicle]\nkz_primary_n_m = 0\n", "vehicle.kz_primary_n_m must be > 0, got 0"),
    ("[vehicle]\ncy_secondary_per_side_n_s_m = -1\n", "vehicle.cy_secondary_per_side_n_s_m must be >= 0"),
    ("[vehicle]\nconicity = \"0.15\"\n", "vehicle.conicity must be a finite number, got '0.15'"),
    ("[vehicle]\nconicity = nan\n", "vehicle.conicity must be a finite number"),
    ("[vehicle]\nhalf_bogie_spacing_m = 2.0\nhalf_wheelbase_m = 2.5\n",
     "vehicle.half_bogie_spacing_m (2 m) must exceed vehicle.half_wheelbase_m (2.5 m): the bogies would overlap"),
    ("[vehicle]\nh_body_m = 0.5\n", "vehicle.h_body_m (0.5 m) must exceed vehicle.h_frame_m (0.6 m)"),
    ("[vehicle]\n[sensors]\nsigma_acc_m_s2 = -0.01\n", "sensors.sigma_acc_m_s2 must be >= 0"),
    ("[vehicle]\n[sensors]\nsigma_gyro = 0.001\n", "unknown key sensors.sigma_gyro (did you mean sigma_gyro_rad_s?)"),
    ("[vehicle]\n[run]\nspeed_m_s = 20.0\n", "unknown key or table 'run'"),
    ("name = 3\n[vehicle]\n", "name must be a text, got 3"),
    ("", "missing table [vehicle]"),
    ("[vehicle]\nhalf_primary_spacing_m = 1000.0\n", "vehicle.half_primary_spacing_m = 1000 is outside 0.3..1.5"),
    ("[vehicle]\nflange_clearance_m = 9.1\n", "vehicle.flange_clearance_m = 9.1 is outside 0.001..0.03"),
    ("[vehicle]\n[sensors]\nsigma_acc_m_s2 = 1e200\n", "sensors.sigma_acc_m_s2 = 1e+200 is outside 0..10"),
])
def test_bad_values_are_refused_naming_the_file_and_key(tmp_path, body, message):
    with pytest.raises(VehicleFileError) as err:
        read_vehicle(_file(tmp_path, body))
    assert str(err.value).startswith("v.toml: ") and message in str(err.value)


def test_the_wrong_format_and_a_missing_file_are_refused(tmp_path):
    path = tmp_path / "v.toml"
    path.write_text('format = "trolley-inservice-model/1"\n[vehicle]\n')
    with pytest.raises(VehicleFileError, match='format must be "trolley-inservice-vehicle/1"'):
        read_vehicle(path)
    with pytest.raises(VehicleFileError, match="file not found"):
        read_vehicle(tmp_path / "none.toml")


def test_the_default_vehicle_is_stable_to_60_m_s_and_a_soft_yaw_one_hunts():
    # the Manchester vehicle's critical speed lies between 60 and 80 m/s; without yaw stiffness in
    # the primary suspension (kx 30 kN/m instead of 31 MN/m) the wheelsets hunt from 20 m/s
    p = VehicleParameters()
    assert largest_growth_rate(p, 60.0) < -0.5 < 0.5 < largest_growth_rate(p, 80.0)
    soft = replace(p, kx_p=3e4)
    assert largest_growth_rate(soft, 20.0) > 0.2


def _run(*args):
    return CliRunner().invoke(_app(), ["inservice", *map(str, args)])


def test_vehicle_command_writes_the_default_vehicle_and_never_replaces_a_file(tmp_path):
    out = tmp_path / "vehicle.toml"
    res = _run("vehicle", "--out", out)
    assert res.exit_code == 0, res.output
    vf = read_vehicle(out)
    assert vf.params == VehicleParameters() and vf.name == DEFAULT_VEHICLE_NAME and vf.defaults == ()
    out.write_text(out.read_text().replace("m_body_kg = 32000.0", "m_body_kg = 30000.0"))
    before = out.read_bytes()
    res = _run("vehicle", "--out", out)
    assert res.exit_code == 2 and "exists" in res.stderr and out.read_bytes() == before


def test_simulate_runs_the_files_vehicle_and_sensor_noise(tmp_path):
    # a heavier wheelset with another wheel radius and noiseless gyro: the recording's [vehicle]
    # and [sensors] carry them, and the gyro channel is exactly the true yaw rate's (its noise 0)
    veh = _file(tmp_path, 'name = "test car"\n[vehicle]\nm_wheelset_kg = 1500.0\nr0_m = 0.43\n'
                          '[sensors]\nsigma_acc_m_s2 = 0.02\nsigma_gyro_rad_s = 0.0\n')
    res = _run("simulate", "--out", tmp_path / "run", "--vehicle", veh, "--length-m", 20, "--seed", 4)
    assert res.exit_code == 0, res.output
    assert '"vehicle": "test car"' in res.stdout
    rec = io.read_recording(tmp_path / "run" / "recording")
    assert rec.nominal["m"] == 1500.0 and rec.nominal["r0"] == 0.43
    assert (rec.sigma_acc_m_s2, rec.sigma_gyro_rad_s) == (0.02, 0.0)
    assert rec.wheelset_sensor_m[2] == 0.43        # the axle box is at the wheel centre
    # the same run without the gyro noise in the default vehicle differs only by that vehicle:
    # reproduce the file's run in the library and compare the gyro channel
    from trolley.inservice.irregularity import irregularity_from_psd
    from trolley.inservice.vehicle import simulate_run

    p = replace(VehicleParameters(), m_wheelset=1500.0, r0=0.43)
    run = simulate_run(p, irregularity_from_psd(20.0, seed=4), 20.0, 20.0, seed=5, sigma_acc_m_s2=0.02,
                       sigma_gyro_rad_s=0.0)
    assert np.allclose(-rec.wheelset_wz_rad_s, -run.wheelset_wz_rad_s_true, rtol=0, atol=1e-9 * 10)
    assert np.std(rec.wheelset_ay_m_s2 - run.wheelset_ay_true_m_s2) == pytest.approx(0.02, rel=0.2)


def test_simulate_and_calibrate_refuse_a_hunting_vehicle_and_a_bad_file_before_simulating(tmp_path):
    soft = _file(tmp_path, "[vehicle]\nkx_primary_n_m = 30000.0\n", "soft.toml")
    res = _run("simulate", "--out", tmp_path / "run", "--vehicle", soft)
    assert res.exit_code == 2 and "the vehicle hunts at 20 m/s" in res.stderr
    assert not (tmp_path / "run").exists()
    res = _run("calibrate", "--out", tmp_path / "m.toml", "--vehicle", soft, "--speed-m-s", 30)
    assert res.exit_code == 2 and "hunts at 30 m/s" in res.stderr and not (tmp_path / "m.toml").exists()
    bad = _file(tmp_path, "[vehicle]\nconicty = 0.2\n", "bad.toml")
    res = _run("calibrate", "--out", tmp_path / "m.toml", "--vehicle", bad)
    assert res.exit_code == 2 and "bad.toml: unknown key vehicle.conicty (did you mean conicity?)" in res.stderr
    for out in (bad, tmp_path / "sub" / ".." / "bad.toml"):      # (sub does not exist)
        res = _run("calibrate", "--out", out, "--vehicle", bad)
        assert res.exit_code == 2 and "is the --vehicle file" in res.stderr, res.output
    assert not (tmp_path / "sub").exists()


def test_the_model_file_names_what_it_was_calibrated_for(tmp_path):
    from survey.inservice_model import model_toml_text, read_model
    from trolley.inservice.estimator import NoiseDensities, discrete_model
    from trolley.inservice.identification import EstimatorModel
    from trolley.inservice.model import ModelParameters

    p, noise = ModelParameters(), NoiseDensities()
    mdl = EstimatorModel(p, discrete_model(p, 20.0, 0.005, noise=noise).Q, noise.r(), 0.005)
    text = model_toml_text(mdl, provenance="calibrated for test\ncar at 20 m/s")
    assert text.splitlines()[2] == "# calibrated for test car at 20 m/s"
    (tmp_path / "m.toml").write_text(text)
    assert read_model(tmp_path / "m.toml").params == p
    assert vehicle_toml_text(VehicleParameters(), "x", 0.01, 5e-4).count("\n[") == 2


def test_a_vehicle_without_some_dampers_is_not_taken_for_hunting(tmp_path):
    # cz_primary = 0 leaves undamped vertical modes whose eigenvalues sit at +-1e-14 1/s: rounding,
    # not hunting (it was refused at 10 m/s and accepted at 20)
    from survey.commands.inservice_simulate import vehicle_for_run
    from trolley.inservice.vehicle import HUNTING_TOLERANCE_1_S, integration_step_s

    path = _file(tmp_path, "[vehicle]\ncz_primary_n_s_m = 0.0\n")
    for v in (5.0, 10.0, 20.0, 50.0):
        params, _, _ = vehicle_for_run(path, v)
        assert abs(largest_growth_rate(params, v)) < HUNTING_TOLERANCE_1_S
    # the default vehicle integrates at the 1 ms step the docs give
    assert integration_step_s(VehicleParameters(), 20.0, 200.0) == pytest.approx(1e-3)

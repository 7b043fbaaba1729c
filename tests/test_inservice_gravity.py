"""Accelerometers that sense gravity (trolley.inservice.model.with_sensor_gravity): the roll state's
gains by hand and against the truth simulator's contact geometry, observability, the filter on
data from its own model, the truth's roll column, and the model file. What the roll state gains on
the truth simulator's runs is measured in benchmarks/bench_inservice.py (section "gravity")."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_inservice_bogie import _own_model_run

from survey.inservice_model import ModelFileError, read_model, write_model
from trolley.inservice.bogie import XI_POS, BogieParameters
from trolley.inservice.contact import ContactParameters, rolling_radius_difference
from trolley.inservice.estimator import discrete_model, estimate, observability_rank
from trolley.inservice.identification import EstimatorModel
from trolley.inservice.irregularity import irregularity_from_psd
from trolley.inservice.model import G_M_S2, ModelParameters
from trolley.inservice.vehicle import VehicleParameters, simulate_run

MODELS = [ModelParameters(), BogieParameters()]


@pytest.mark.parametrize("p", MODELS, ids=lambda p: p.KIND)
def test_the_roll_state_enters_the_accelerometers_with_g_and_nothing_else_changes(p):
    g = replace(p, sensor_gravity=True)
    F0, B0, H0, D0 = p.state_space(20.0)
    F, B, H, D = g.state_space(20.0)
    n = p.n_state
    assert g.n_state == n + 1 and g.state_kinds == p.state_kinds + ("roll",)
    assert np.array_equal(F[:n, :n], F0) and not F[n].any() and not F[:n, n].any()   # a random walk
    assert np.array_equal(B[:n], B0) and not B[n].any() and np.array_equal(D, D0)
    # by hand: g on the roll for both accelerometers, nothing for the gyro and the virtual xi = 0
    assert np.array_equal(H[:, n], [G_M_S2, 0.0, G_M_S2, 0.0])
    # the profile roll alpha (y - xi) / l on the wheelset accelerometer only
    dH = H[:, :n] - H0
    k = G_M_S2 * p.conicity / p.l
    expected = np.zeros_like(dH)
    expected[0, 0], expected[0, XI_POS] = k, -k
    assert np.allclose(dH, expected, rtol=0.0, atol=1e-14 * np.abs(H0).max())


def test_the_profile_roll_gain_is_the_truth_simulators_contact_geometry_for_small_shifts():
    # the truth senses g (cross level + delta r) / 2b with delta r from the wheel profiles; for a
    # small shift of the wheelset relative to the rails that is g alpha (y - xi) / b
    vp = VehicleParameters()
    p = replace(BogieParameters(conicity=vp.conicity, l=vp.b), sensor_gravity=True)
    H0 = replace(p, sensor_gravity=False).state_space(20.0)[2]
    gain = (p.state_space(20.0)[2] - np.pad(H0, ((0, 0), (0, 1))))[0, 0]
    for shift in (1e-5, -2e-5):
        truth = 9.81 * rolling_radius_difference(shift, ContactParameters(conicity=vp.conicity)) / (2 * vp.b)
        assert gain * shift == pytest.approx(truth, rel=3e-3)       # (9.80665 against the truth's 9.81)


@pytest.mark.parametrize("p", MODELS, ids=lambda p: p.KIND)
def test_with_gravity_every_state_stays_observable_but_not_from_the_gyro_alone(p):
    g = replace(p, sensor_gravity=True)
    dm = discrete_model(g, 20.0, 0.005)
    n = g.n_state
    assert observability_rank(dm.F, dm.H) == n
    assert observability_rank(dm.F, dm.H[:3]) == n - 1               # a common offset, as without
    # the accelerometers are what sees the roll
    assert observability_rank(dm.F, dm.H[[1, 3]]) < n


def test_the_gravity_filter_on_its_own_model_has_errors_within_sigma():
    g = replace(BogieParameters(), sensor_gravity=True)
    n = g.n_state - 1
    sq = []
    # the roll's error is correlated over the whole run (16 runs: rms 0.96, single runs 0.61-1.82),
    # so the normalised errors are pooled over 8 runs
    for seed in range(8):
        t, s, X, Z, noise = _own_model_run(g, 3000, seed)
        e = estimate(g, t, s, 20.0, Z, noise=noise, initial_covariance=np.eye(g.n_state) * 1e-14)
        sq.append(((e.x - X)[100:, [0, 1, 2, 6, n]] / e.sigma[100:, [0, 1, 2, 6, n]]) ** 2)
    nees = np.sqrt(np.mean(np.concatenate(sq), axis=0))
    assert np.all((nees > 0.75) & (nees < 1.3)), nees                 # y, psi, y_f, xi and the roll


def test_the_truths_roll_column_is_its_cross_level_over_the_contact_distance():
    vp = VehicleParameters(sensor_gravity=True)
    run = simulate_run(vp, irregularity_from_psd(30.0, seed=3), 20.0, 30.0, sensor_noise=False, seed=4)
    for kind, n in (("paper", 7), ("bogie", 15)):
        X = run.reference_states(kind, roll=True)
        assert X.shape == (len(run.t_s), n + 1)
        assert np.array_equal(X[:, :n], run.reference_states(kind))
        assert np.array_equal(X[:, n], run.cross_level_m / (2 * vp.b)) and np.abs(X[:, n]).max() > 1e-5
    # the sensed gravity is what the accelerometers gain over the same run without it
    plain = simulate_run(VehicleParameters(), irregularity_from_psd(30.0, seed=3), 20.0, 30.0, sensor_noise=False,
                         seed=4)
    roll = run.cross_level_m / (2 * vp.b)
    profile = rolling_radius_difference(run.wheelset_y_m - run.alignment_m, vp.contact) / (2 * vp.b)
    assert np.allclose(run.wheelset_ay_m_s2 - plain.wheelset_ay_m_s2, 9.81 * (roll + profile), atol=1e-9)


def test_the_model_file_keeps_sensor_gravity_and_refuses_anything_but_a_boolean(tmp_path):
    p = replace(BogieParameters().with_opt([2e7, 1e4, 4e6, 100.0]), sensor_gravity=True)
    n = p.n_state
    rng = np.random.default_rng(2)
    A = rng.standard_normal((n, n)) * 1e-6
    m = EstimatorModel(p, A @ A.T, np.diag([1e-4, 2.5e-7, 1e-4, 0.09]), 0.005, 1.3, 1.0, 8.0, 0.36,
                       rng.standard_normal((n, 4)) * 1e-9, np.array([0.3, 0.6, 0.27]))
    path = tmp_path / "model.toml"
    write_model(path, m)
    text = path.read_text()
    assert "sensor_gravity = true" in text
    r = read_model(path)
    assert r.params == p and r.params.n_state == 21 and np.array_equal(r.Q, m.Q) and np.array_equal(r.S, m.S)
    # a file written before the key existed: the paper's virtual sensors (its Q, R, S are 20 states wide)
    old = replace(m, params=replace(p, sensor_gravity=False), Q=m.Q[:-1, :-1], S=m.S[:-1])
    write_model(path, old)
    path.write_text(path.read_text().replace("sensor_gravity = false\n", ""))
    assert read_model(path).params.sensor_gravity is False
    for bad in ("1.0", '"yes"', "1"):
        write_model(path, m)
        path.write_text(text.replace("sensor_gravity = true", f"sensor_gravity = {bad}"))
        with pytest.raises(ModelFileError, match=r"model.toml: parameters.sensor_gravity must be true or false"):
            read_model(path)

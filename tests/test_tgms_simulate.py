"""The TGMS simulator's encoder drift (creep and rolling-radius variation, on by default): off,
the recordings are those of the constant-scale encoder bit for bit; on, the encoder (and only the
encoder) departs from the single-scale model by the order the figures imply."""
from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest

from trolley.tgms.simulate import (CONSTANT_ENCODER, ENCODER_DRIFT, SimulationSettings, encoder_distance, rolling_radius_variation,
                                   simulate)

# a short, cheap ride (2 camera frames per second: the cameras are not under test)
SHORT = SimulationSettings(length_m=120.0, speed_m_s=10.0, seed=5, camera_rate_hz=2.0)


def test_drift_off_gives_the_counts_of_the_constant_scale_encoder():
    """Digest of the counts recorded by the simulator before the drift existed: switched off, the
    encoder is the old constant-scale one bit for bit; by default the drift is on."""
    st = SimulationSettings()
    assert {k: getattr(st, k) for k in ENCODER_DRIFT} == ENCODER_DRIFT
    rec, _ = simulate(dataclasses.replace(SHORT, **CONSTANT_ENCODER))
    assert len(rec.enc_count) == 8700 and rec.enc_count[-1] == 65412
    assert hashlib.sha256(rec.enc_count.astype(np.int64).tobytes()).hexdigest()[:16] == "bd81f261f66ff627"


def test_drift_changes_only_the_encoder_and_by_the_expected_order():
    """With the drift on, the IMU and camera data are unchanged (the drift's draws come last), the
    counts stay monotone integers, and the station difference to the constant-scale encoder is of
    the order of c V^2 / 2 (5 mm at 10 m/s) plus eps_rms * 120 m (12 mm), not zero and not more."""
    mpc = None
    for seed in (1, 2, 3):
        st = dataclasses.replace(SHORT, seed=seed)
        rec0, _ = simulate(dataclasses.replace(st, **CONSTANT_ENCODER))
        rec1, _ = simulate(st)
        mpc = rec0.config.encoder.metres_per_count * (1 + st.wheel_scale_error)
        assert np.array_equal(rec0.imu_w_rad_s, rec1.imu_w_rad_s)
        assert np.array_equal(rec0.imu_f_m_s2, rec1.imu_f_m_s2)
        for side in ("left", "right"):
            assert np.array_equal(rec0.lasers[side].u_px, rec1.lasers[side].u_px)
        assert rec1.enc_count.dtype.kind == "i" and np.all(np.diff(rec1.enc_count) >= 0)
        d = (rec1.enc_count - rec0.enc_count) * mpc
        assert 1e-3 < np.max(np.abs(d)) < 0.06, (seed, np.max(np.abs(d)))


def test_rolling_radius_variation_has_its_rms_and_correlation_length():
    """Over 1000 correlation lengths the sample rms is within 10 % of 1e-4 and the autocorrelation at
    one correlation length is exp(-1) within 0.1; rms 0 draws nothing."""
    rng = np.random.default_rng(0)
    s = np.arange(0.0, 100_000.0, 1.0)
    e = rolling_radius_variation(rng, s, 1e-4, 100.0)
    assert np.std(e) == pytest.approx(1e-4, rel=0.1)
    x = e - e.mean()
    rho = np.sum(x[:-100] * x[100:]) / np.sum(x * x)
    assert rho == pytest.approx(np.exp(-1.0), abs=0.1)
    state = rng.bit_generator.state
    assert not np.any(rolling_radius_variation(rng, s, 0.0, 100.0))
    assert rng.bit_generator.state == state


def test_encoder_creep_leaves_c_times_the_change_of_v_squared_over_two():
    """Without a radius variation the wheel lags by int c a ds = c (v^2 - v0^2) / 2."""
    t = np.linspace(0.0, 20.0, 20001)
    v = 2.0 + 10.0 * np.sin(np.pi * t / 40.0) ** 2
    a = np.gradient(v, t)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    d = encoder_distance(s, a, np.zeros_like(s), 1e-4)
    assert np.all(np.diff(d) >= 0)
    np.testing.assert_allclose(s - d, 1e-4 * (v ** 2 - v[0] ** 2) / 2, atol=2e-7)

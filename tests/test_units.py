"""Unit conversions: hand-computed values and round trips."""
import numpy as np
from hypothesis import given, strategies as st

from trolley import units


def test_gyro_bias_hand_value():
    # 15 deg/h is one degree every 4 minutes: pi/180/240 rad/s
    assert np.isclose(units.deg_h_to_rad_s(15.0), np.pi / 180.0 / 240.0, rtol=1e-15)


def test_arw_hand_value():
    # 60 deg/sqrt(h) = 1 deg/sqrt(s)
    assert np.isclose(units.deg_sqrt_h_to_rad_sqrt_s(60.0), np.pi / 180.0, rtol=1e-15)


def test_micro_g():
    assert np.isclose(units.ug_to_m_s2(1e6), units.STANDARD_GRAVITY_M_S2)


@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_round_trips(x):
    assert np.isclose(units.rad_s_to_deg_h(units.deg_h_to_rad_s(x)), x, rtol=1e-12, atol=1e-12)
    assert np.isclose(units.rad_sqrt_s_to_deg_sqrt_h(units.deg_sqrt_h_to_rad_sqrt_s(x)), x, rtol=1e-12, atol=1e-12)
    assert np.isclose(units.m_to_mm(units.mm_to_m(x)), x, rtol=1e-12, atol=1e-12)
    assert np.isclose(units.m_s2_to_ug(units.ug_to_m_s2(x)), x, rtol=1e-12, atol=1e-9)

"""Decimation of fast in-service recordings before the filter (trolley.inservice.resample), in the
truth simulator's runs and in `trolley inservice process`."""
from __future__ import annotations

import json
import numpy as np
import pandas as pd
import pytest
from test_inservice_io import _app
from test_inservice_process import write_model_recording
from typer.testing import CliRunner

from trolley.inservice.irregularity import irregularity_from_psd
from trolley.inservice.model import ModelParameters
from trolley.inservice.resample import decimated, decimation_factor
from trolley.inservice.vehicle import VehicleParameters, simulate_run


@pytest.mark.parametrize("rate, target, q", [(1000.0, 200.0, 5), (999.99999, 200.0, 5), (200.0, 200.0, 1),
                                             (150.0, 200.0, 1), (2000.0, 300.0, 6), (1000.0, 250.0, 4)])
def test_decimation_factor_never_goes_below_the_filter_rate(rate, target, q):
    assert decimation_factor(rate, target) == q
    assert rate / q >= target * (1 - 1e-6) or q == 1


def test_decimation_keeps_the_band_and_cuts_the_white_noise():
    rng = np.random.default_rng(3)
    t = np.arange(20000) / 1000.0
    sine = np.sin(2 * np.pi * 5.0 * t)                  # a 3 m wave at 15 m/s
    noise = 0.01 * rng.standard_normal((len(t), 2))
    (tk,), Z = decimated(5, [t], np.column_stack([sine, noise]))
    assert np.array_equal(tk, t[::5]) and Z.shape == (4000, 3)
    assert np.max(np.abs(Z[50:-50, 0] - sine[::5][50:-50])) < 2e-3
    # white noise keeps the part below the new band edge: 0.01 / sqrt(5) for an ideal filter
    assert np.std(Z[:, 1:], axis=0) == pytest.approx(0.01 / np.sqrt(5), rel=0.1)
    with pytest.raises(ValueError, match="too few"):
        decimated(5, [t[:100]], noise[:100])


def test_a_decimated_run_is_the_slower_run_without_its_noise_above_the_band():
    vp = VehicleParameters()
    track = irregularity_from_psd(60.0, seed=4)
    fast = simulate_run(vp, track, 20.0, 60.0, rate_hz=1000.0, sensor_noise=False).decimated(5)
    slow = simulate_run(vp, track, 20.0, 60.0, rate_hz=200.0, sensor_noise=False)
    # the same 1 ms integration steps; the start of the lead-in differs by less than one output period
    assert np.allclose(fast.t_s, slow.t_s) and np.allclose(fast.wheelset_y_m, slow.wheelset_y_m, rtol=0, atol=1e-8)
    assert fast.rate_hz == 200.0
    inner = slice(40, -40)
    for a, b in ((fast.wheelset_ay_m_s2, slow.wheelset_ay_m_s2), (fast.frame_ay_m_s2, slow.frame_ay_m_s2),
                 (fast.wheelset_wz_rad_s, slow.wheelset_wz_rad_s)):
        assert np.sqrt(np.mean((a - b)[inner] ** 2)) < 0.03 * np.sqrt(np.mean(b[inner] ** 2))


def test_process_decimates_a_fast_recording_to_the_filter_rate(tmp_path):
    P = ModelParameters()
    V = 20.0
    outs = {}
    for rate in (200.0, 1000.0):
        t = np.arange(int(7.5 * rate) + 1) / rate
        s = V * t
        xi = 1e-3 * np.sin(2 * np.pi * s / 12.0)
        write_model_recording(tmp_path / f"r{rate:g}", P, t, xi, V)
        out = tmp_path / f"o{rate:g}"
        res = CliRunner().invoke(_app(), ["inservice", "process", str(tmp_path / f"r{rate:g}"), "--out", str(out)])
        assert res.exit_code == 0, res.output
        outs[rate] = (pd.read_csv(out / "irregularities.csv"), json.loads((out / "summary.json").read_text()))
    (slow, js), (fast, jf) = outs[200.0], outs[1000.0]
    assert (jf["sensor_rate_hz"], jf["filter_rate_hz"]) == pytest.approx((1000.0, 200.0))
    assert js["filter_rate_hz"] == pytest.approx(200.0) and jf["samples"] == 7501
    n = min(len(slow), len(fast))
    inner = slice(120, n - 120)
    d = fast["alignment_mm"].to_numpy()[:n] - slow["alignment_mm"].to_numpy()[:n]
    assert np.sqrt(np.mean(d[inner] ** 2)) < 0.02          # mm, against a 1 mm wave

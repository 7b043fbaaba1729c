"""Sensor rate of the in-service estimator: recordings sampled faster than the filter needs are
low-passed and decimated before it.

The Kalman filter of Munoz 2021 (trolley.inservice.estimator) needs the band of the shortest
EN 13848 wave at the running speed (3 m at 20 m/s: 6.7 Hz); axle-box and frame sensors are often
read at one to several kHz. Running the filter at the full rate costs CPU in proportion; decimating
first keeps the filter's cost and lowers the white noise per sample by about the square root of the
factor (the noise outside the new band is filtered out), which is what sets the floor of the long
waves (docs/inservice.md, "Sensor rate and the D3 band").

Decimation is scipy.signal.decimate with its zero-phase FIR anti-alias filter (order 20 q, Hamming
window, cut-off at 0.8 of the new Nyquist frequency), applied along the samples; times, chainages
and speeds are taken at the kept samples.

References
----------
S. Munoz et al., IEEE Access 9 (2021), Sec. V (sensor noise per sample).
scipy.signal.decimate.
"""
from __future__ import annotations

import numpy as np

#: default rate the filter runs at, Hz (the recordings of `trolley inservice simulate` are this fast)
FILTER_RATE_HZ = 200.0


def decimation_factor(rate_hz: float, filter_rate_hz: float = FILTER_RATE_HZ) -> int:
    """The integer factor q >= 1 that brings ``rate_hz`` down to no less than ``filter_rate_hz``."""
    if not (rate_hz > 0 and filter_rate_hz > 0):
        raise ValueError(f"rates must be > 0 Hz, got {rate_hz} and {filter_rate_hz}")
    # a rate read from sample times (1 / median dt) is a hair off its nominal value
    return max(1, int(np.floor(rate_hz / filter_rate_hz + 1e-6)))


def decimated(q: int, samples, channels):
    """Every q-th sample of ``samples`` and the anti-alias filtered, decimated ``channels``.

    Parameters
    ----------
    q : decimation factor (:func:`decimation_factor`); 1 returns the inputs.
    samples : sequence of (N,) arrays taken at the kept samples only (times, chainages, speeds,
        smooth reference states).
    channels : (N, C) sensor channels, low-passed before they are decimated.

    Returns
    -------
    samples : list of (M,) arrays, M = ceil(N / q).
    channels : (M, C) array.
    """
    Z = np.asarray(channels, float)
    if q <= 1:
        return [np.asarray(x) for x in samples], Z
    from scipy.signal import decimate

    need = 3 * (20 * q + 1) + 1          # the zero-phase FIR's padding
    if len(Z) < need:
        raise ValueError(f"{len(Z)} samples are too few to decimate by {q} (need {need})")
    return [np.asarray(x)[::q] for x in samples], decimate(Z, q, ftype="fir", axis=0, zero_phase=True)

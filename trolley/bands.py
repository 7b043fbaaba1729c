"""Zero-phase wavelength band-pass filtering of track irregularities (EN 13848 D1/D2/D3).

EN 13848-1 evaluates longitudinal level and alignment as band-passed profiles in the wavelength
ranges D1 (3-25 m), D2 (25-70 m) and D3 (70-200 m; 70-150 m for longitudinal level in some
editions). This module turns a profile sampled on a uniform chainage grid into its band-passed
form. It is shared by the trolley survey sheet and the TGMS pipeline.

Filter
------
A cascade of a Butterworth high-pass (cut-off wavelength ``long_m``) and a Butterworth low-pass
(cut-off wavelength ``short_m``), each of order :data:`FILTER_ORDER` (4), designed digitally
(bilinear transform, scipy.signal.butter) in spatial frequency (cycles/m, sample rate
1/step_m) and run forward and backward (scipy.signal.sosfiltfilt), so the result has zero phase
and the magnitude response is the square of the single-pass one. The single-pass cut-offs are
pre-warped so that the *combined* forward-backward response is exactly -3 dB (1/sqrt 2 in
amplitude) at the band-edge wavelengths ``short_m`` and ``long_m`` (to 1e-4 when the edges
are close, as in D3, where the two stages overlap a little); in the pass band the
response is flat (a 10 m wave through D1 keeps 99.97 % of its amplitude) and it falls with
16th power of frequency ratio outside (80 dB/decade per edge in amplitude).

If ``short_m`` is at or below two samples (the shortest wavelength the grid can hold), the
low-pass stage is left out: the sampling itself limits the band.

NaN gaps
--------
Samples that are NaN (not measured) are handled per 1-D record:

* gaps of at most ``max_gap_m`` (default: ``short_m``, i.e. shorter than any wave in the band)
  are bridged by linear interpolation for the filter; the output is NaN again at those samples;
* longer gaps split the record into segments filtered independently;
* segments shorter than ``long_m`` (one longest wavelength of the band) cannot hold the band and
  give NaN.

Each segment is detrended (least-squares line; the high-pass removes a line anyway) and padded
by odd reflection (scipy's ``padtype="odd"``) over up to one ``long_m``; values near a segment end
still carry the filter's start-up transient, because no padding is the track's real continuation.
Measured for D3 on a 3 km record of a unit 10 m sine (which D3 should remove): leakage 3.8e-2
within 100 m of an end, 1.2e-2 beyond 200 m, 1.0e-3 beyond 400 m, 1.8e-5 beyond 800 m (steady
state 3.8e-7). Worse for waves in and near the band: over sines of 0.8 ``short_m`` to 1.3
``long_m`` at eight phases on a 1500 m record (0.625 m grid), the largest error against the
steady response, as a fraction of the amplitude, is 0.29-0.31 beyond half a ``long_m`` from
an end, 0.09 beyond one ``long_m`` (:data:`SETTLED_WAVELENGTHS`), 0.025 beyond 1.5 and 0.007
beyond 2, in each of D1, D2 and D3. ``edge_m`` (:func:`band` with ``settled=True``: one
``long_m``) leaves the values that close to a segment end empty, as a survey sheet whose values
are checked against limits must: a regular 16 mm, 100 m wave showed 18.7 mm in D3 40 m from the
end, a false defect against an 18 mm limit.

References
----------
EN 13848-1:2019, wavelength ranges D1-D3 (see shared/research/anchors.md section 2.1).
Munoz 2021 (shared/papers/munoz2021-lateral-irregularity-kalman-bogie.txt): accuracy per D band.
"""
from __future__ import annotations

import numpy as np

#: EN 13848 wavelength bands, (shortest, longest) wavelength in metres.
BANDS: dict[str, tuple[float, float]] = {"D1": (3.0, 25.0), "D2": (25.0, 70.0), "D3": (70.0, 200.0)}

#: values within this many of the band's longest wavelength of a segment end are left empty by
#: :func:`band` with ``settled=True`` (the start-up transient: below 9 % of a wave's amplitude
#: beyond it, module docstring)
SETTLED_WAVELENGTHS = 1.0

#: Butterworth order of each edge (per pass; forward-backward doubles the roll-off).
FILTER_ORDER = 4

# Ratio r with 1 / (1 + r**(2N)) = 1/sqrt(2): single-pass power gain at the band edge that
# makes the forward-backward amplitude gain 1/sqrt(2) (-3 dB).
_EDGE_RATIO = (np.sqrt(2.0) - 1.0) ** (1.0 / (2 * FILTER_ORDER))


def band_sos(step_m: float, short_m: float, long_m: float) -> np.ndarray:
    """Second-order sections of the single-pass band-pass filter.

    Parameters
    ----------
    step_m : sample spacing along the track, m.
    short_m, long_m : band-edge wavelengths, m (``0 < short_m < long_m``).

    Returns
    -------
    sos : (n, 6) second-order sections for ``scipy.signal.sosfiltfilt``; the combined
        forward-backward response is -3 dB at ``1/short_m`` and ``1/long_m`` cycles/m.
    """
    from scipy.signal import butter

    if not (step_m > 0 and 0 < short_m < long_m):
        raise ValueError(f"need step_m > 0 and 0 < short_m < long_m, got {step_m}, {short_m}, {long_m}")
    fs = 1.0 / step_m
    if long_m <= 2.0 * step_m:
        raise ValueError(f"long_m={long_m} m is not longer than two samples of {step_m} m")
    # bilinear-warped frequency axis: |H|^2 depends on tan(pi f / fs)
    w_hp = np.tan(np.pi / (long_m * fs)) * _EDGE_RATIO
    sos = [butter(FILTER_ORDER, np.arctan(w_hp) * fs / np.pi, btype="highpass", fs=fs, output="sos")]
    if short_m > 2.0 * step_m:
        w_lp = np.tan(np.pi / (short_m * fs)) / _EDGE_RATIO
        f_lp = np.arctan(w_lp) * fs / np.pi
        if f_lp < 0.5 * fs * 0.999:
            sos.append(butter(FILTER_ORDER, f_lp, btype="lowpass", fs=fs, output="sos"))
    return np.vstack(sos)


def _filter_segment(sos: np.ndarray, y: np.ndarray, pad: int) -> np.ndarray:
    from scipy.signal import detrend, sosfiltfilt

    # The high-pass removes a line exactly in steady state; removing it first (least squares)
    # only shortens the start-up transients at the segment ends.
    return sosfiltfilt(sos, detrend(y, axis=-1, type="linear"), padtype="odd",
                       padlen=min(pad, y.shape[-1] - 1))


def _without_edges(y: np.ndarray, n_edge: int) -> np.ndarray:
    """``y`` (last axis along the track) with ``n_edge`` samples at each end set to NaN."""
    if n_edge > 0:
        y[..., :n_edge] = np.nan
        y[..., max(y.shape[-1] - n_edge, 0):] = np.nan
    return y


def _filter_record(sos: np.ndarray, y: np.ndarray, step_m: float, long_m: float,
                   max_gap_m: float, pad: int, n_edge: int = 0) -> np.ndarray:
    """Band-pass one 1-D record with NaN gaps (see module docstring)."""
    out = np.full(y.shape, np.nan)
    good = np.isfinite(y)
    if not good.any():
        return out
    idx = np.flatnonzero(good)
    # split where a gap (missing samples x step) is longer than max_gap_m
    jumps = np.flatnonzero((np.diff(idx) - 1) * step_m > max_gap_m * (1 + 1e-9))
    starts = np.r_[idx[0], idx[jumps + 1]]
    stops = np.r_[idx[jumps], idx[-1]] + 1
    min_len = int(np.ceil(long_m / step_m))
    for a, b in zip(starts, stops):
        if b - a < min_len:
            continue
        seg = y[a:b]
        ok = good[a:b]
        if not ok.all():
            pos = np.arange(b - a)
            seg = np.interp(pos, pos[ok], seg[ok])
        res = _without_edges(_filter_segment(sos, seg, pad), n_edge)
        res[~ok] = np.nan
        out[a:b] = res
    return out


def bandpass_wavelength(x, step_m: float, short_m: float, long_m: float, axis: int = -1,
                        max_gap_m: float | None = None, edge_m: float = 0.0) -> np.ndarray:
    """Zero-phase band-pass of a profile between two wavelengths.

    Parameters
    ----------
    x : array_like, profile (e.g. lateral or vertical deviation) on a uniform grid; NaN = gap.
    step_m : grid spacing along the track, m.
    short_m, long_m : band-edge wavelengths, m; the response is -3 dB at both.
    axis : axis of ``x`` along the track.
    max_gap_m : longest NaN gap bridged by interpolation (default ``short_m``); longer gaps
        split the record.
    edge_m : values less than ``edge_m`` from a segment end are NaN (the start-up transient;
        module docstring). 0 keeps them all.

    Returns
    -------
    y : ndarray (float, same shape as ``x``), the band-passed profile; NaN in gaps, in
        segments shorter than ``long_m`` and within ``edge_m`` of a segment end.

    References
    ----------
    EN 13848-1 wavelength ranges; scipy.signal.butter / sosfiltfilt.
    """
    x = np.asarray(x, dtype=float)
    sos = band_sos(step_m, short_m, long_m)
    gap = short_m if max_gap_m is None else float(max_gap_m)
    pad = int(np.ceil(long_m / step_m))
    # a station k samples from the end is k * step_m from it; it is kept when that is >= edge_m
    n_edge = int(np.ceil(edge_m / step_m - 1e-9)) if edge_m > 0 else 0
    xm = np.moveaxis(x, axis, -1)
    n = xm.shape[-1]
    min_len = int(np.ceil(long_m / step_m))
    if n == 0:
        return x.copy()
    if np.isfinite(xm).all():
        if n < min_len:
            return np.full(x.shape, np.nan)
        y = _without_edges(_filter_segment(sos, xm, pad), n_edge)
        return np.moveaxis(y, -1, axis)
    flat = xm.reshape(-1, n)
    out = np.empty(flat.shape)
    # loop over records (channels), not samples
    for i, rec in enumerate(flat):
        out[i] = _filter_record(sos, rec, step_m, long_m, gap, pad, n_edge)
    return np.moveaxis(out.reshape(xm.shape), -1, axis)


def band(x, step_m: float, name: str, axis: int = -1, settled: bool = False) -> np.ndarray:
    """Band-pass ``x`` in the EN 13848 band ``name`` ("D1", "D2" or "D3"); see
    :func:`bandpass_wavelength`. With ``settled`` the values within :data:`SETTLED_WAVELENGTHS`
    of the band's longest wavelength of a segment end are NaN."""
    try:
        short_m, long_m = BANDS[name]
    except KeyError:
        raise ValueError(f"unknown band {name!r}; known: {', '.join(BANDS)}") from None
    edge = SETTLED_WAVELENGTHS * long_m if settled else 0.0
    return bandpass_wavelength(x, step_m, short_m, long_m, axis=axis, edge_m=edge)


def band_gain(wavelength_m, step_m: float, short_m: float, long_m: float) -> np.ndarray:
    """Amplitude gain of :func:`bandpass_wavelength` (forward-backward) at given wavelengths.

    Parameters
    ----------
    wavelength_m : array_like, wavelengths, m.
    step_m, short_m, long_m : as in :func:`bandpass_wavelength`.

    Returns
    -------
    gain : ndarray, |H|^2 of the single-pass filter (zero phase, so this is the whole response).
    """
    from scipy.signal import sosfreqz

    f = 1.0 / np.asarray(wavelength_m, dtype=float)
    _, h = sosfreqz(band_sos(step_m, short_m, long_m), worN=np.atleast_1d(f), fs=1.0 / step_m)
    return np.abs(h) ** 2

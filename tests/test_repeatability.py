"""Two surveys of one track compared (trolley.repeatability, ``trolley compare``): hand-computable
offsets on lines and circles, the sigma of a difference, a local movement found as one stretch,
and two simulated surveys of one track agreeing within their sigmas."""
from __future__ import annotations

import inspect
import json
import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from trolley.bands import band
from trolley.repeatability import compare_tracks, track_difference
from trolley.trackgeometry import TrackInput

STEP = 0.625


def track(E, N, H, sigma_m=(5e-4, 4e-4, 3e-4), cov_EN=None, cant=None, sigma_cant=None, gauge=None,
          chainage=None) -> TrackInput:
    n = np.size(E)
    full = np.full(n, np.nan)
    return TrackInput(
        chainage_m=STEP * np.arange(n) if chainage is None else chainage, E_m=np.asarray(E, float),
        N_m=np.asarray(N, float), H_m=np.asarray(H, float), sigma_E_m=np.full(n, sigma_m[0]),
        sigma_N_m=np.full(n, sigma_m[1]), sigma_H_m=np.full(n, sigma_m[2]), lateral_dev_m=full, vertical_dev_m=full,
        gauge_m=full if gauge is None else gauge, cant_m=full if cant is None else cant,
        cov_EN_m2=None if cov_EN is None else np.full(n, cov_EN),
        sigma_cant_m=None if sigma_cant is None else np.full(n, sigma_cant))


def line(bearing, n, start=0.0, offset=0.0, dh=0.0, e0=500000.0, n0=3000000.0, h0=50.0, grade=0.004):
    """Stations along a straight line of grid bearing ``bearing``, moved ``offset`` to its right."""
    s = start + STEP * np.arange(n)
    dE, dN = math.sin(bearing), math.cos(bearing)
    return (e0 + s * dE + offset * dN, n0 + s * dN - offset * dE, h0 + grade * s + dh)


@settings(max_examples=40, deadline=None)
@given(bearing=st.floats(0.0, 2 * math.pi), offset=st.floats(-0.02, 0.02), dh=st.floats(-0.02, 0.02),
       shift=st.floats(0.0, 0.99), reverse=st.booleans())
def test_a_parallel_track_differs_by_its_offset_whatever_its_direction_and_stations(bearing, offset, dh, shift,
                                                                                    reverse):
    """B: the same straight line moved ``offset`` to the right and ``dh`` up, its stations shifted
    by a fraction of a step and run either way: the difference is exactly the offset, the sigma
    sqrt(sA^2 + sB^2) of the lateral projection by hand."""
    a = track(*line(bearing, 200), cov_EN=1e-8)
    E, N, H = line(bearing, 210, start=-3.0 + shift * STEP, offset=offset, dh=dh)
    if reverse:
        E, N, H = E[::-1], N[::-1], H[::-1]
    b = track(E, N, H, sigma_m=(3e-4, 6e-4, 2e-4), cov_EN=-2e-8)
    d = track_difference(a, b)
    assert d.beside.all()
    # to 10 nm: the grid coordinates are 5e5-3e6 m, whose float64 spacing is 0.06-0.5 nm, and the
    # interpolation along B and the difference lose a few of those (1.07 nm seen at 1e-9)
    np.testing.assert_allclose(d.lateral_m, offset, atol=1e-8)
    np.testing.assert_allclose(d.vertical_m, dh, atol=1e-9)
    c, s = math.cos(bearing), math.sin(bearing)

    def lat_var(sE, sN, cov):   # (cos psi, -sin psi) . C . (cos psi, -sin psi)
        return c * c * sE**2 + s * s * sN**2 - 2 * s * c * cov

    np.testing.assert_allclose(d.sigma_lateral_m, math.sqrt(lat_var(5e-4, 4e-4, 1e-8) + lat_var(3e-4, 6e-4, -2e-8)),
                               rtol=1e-9)
    np.testing.assert_allclose(d.sigma_vertical_m, math.hypot(3e-4, 2e-4), rtol=1e-12)


def test_on_a_curve_the_inner_track_is_to_the_right_by_the_radius_difference():
    """A runs clockwise on a 300 m circle (a right-hand curve), B on the circle 12 mm smaller at
    other stations: B is 12 mm to the right of A, to within the chord's sag between B's stations
    (0.625^2 / (8 x 300) m = 0.16 um)."""
    R, d = 300.0, 0.012
    ta = np.arange(400) * STEP / R
    tb = (np.arange(420) - 10.3) * STEP / (R - d)
    a = track(R * np.sin(ta), R * np.cos(ta), np.zeros_like(ta))
    b = track((R - d) * np.sin(tb), (R - d) * np.cos(tb), np.zeros_like(tb))
    diff = track_difference(a, b)
    assert diff.beside.all()
    np.testing.assert_allclose(diff.lateral_m, d, atol=STEP**2 / (8 * R) + 1e-9)


def test_stations_beyond_the_other_tracks_ends_or_too_far_are_not_compared():
    a = track(*line(0.3, 400))
    b = track(*line(0.3, 161, start=100.0))                    # 100-200 m of A's 0-249.375 m
    c = compare_tracks(a, b)
    s = c.difference.station_m
    np.testing.assert_array_equal(c.difference.beside, (s >= 100.0 - 1e-9) & (s <= 200.0 + 1e-9))
    assert c.common_m == pytest.approx(100.0)
    assert np.isnan(c.difference.lateral_m[~c.difference.beside]).all()
    with pytest.raises(ValueError, match="do not run beside each other"):
        compare_tracks(a, track(*line(0.3, 400, offset=4.5)))  # the neighbouring track
    # within --max-offset-m it is compared
    assert compare_tracks(a, track(*line(0.3, 400, offset=4.5)), max_offset_m=5.0).rms_m["lateral"] == \
        pytest.approx(4.5)


def test_a_local_lift_is_one_stretch_beyond_three_sigma_where_it_exceeds_them():
    """B: A lifted by a 4 mm cosine bump over 200-220 m (a tamping lift). The vertical difference
    sigma is sqrt(2) x 0.3 mm, so the stations whose lift exceeds 3 x 0.424 mm form one stretch,
    its ends and largest value by hand; lateral and cant stay within."""
    n = 640
    s = STEP * np.arange(n)
    lift = np.where(np.abs(s - 210.0) < 10.0, 2e-3 * (1 + np.cos(np.pi * (s - 210.0) / 10.0)), 0.0)
    E, N, H = line(1.0, n)
    cant = np.full(n, 0.001)
    a = track(E, N, H, cant=cant, sigma_cant=2e-4)
    b = track(E, N, H + lift, cant=cant + 1e-4, sigma_cant=2e-4)
    c = compare_tracks(a, b, limit=3.0)
    sig = math.hypot(3e-4, 3e-4)
    over = s[lift > 3 * sig]
    assert [x.quantity for x in c.stretches] == ["vertical"]
    st_ = c.stretches[0]
    assert (st_.start_m, st_.end_m, st_.stations) == (over[0], over[-1], over.size)
    assert st_.max_abs_diff_m == pytest.approx(4e-3, abs=1e-12) and st_.at_m == pytest.approx(210.0)
    assert st_.max_abs_z == pytest.approx(4e-3 / sig)
    assert not c.agree and c.beyond == {"lateral": 0, "vertical": over.size, "cant": 0}
    assert c.rms_z["cant"] == pytest.approx(1e-4 / math.hypot(2e-4, 2e-4))
    # the band RMS are the lift's own, band-passed (D3 needs more than this 400 m record beyond its
    # settled edges)
    for name in ("D1", "D2"):
        lifted = band(lift, STEP, name, settled=True)
        assert c.band_rms_m["vertical"][name] == pytest.approx(np.sqrt(np.nanmean(lifted**2)), rel=1e-9)
        assert c.band_rms_m["lateral"][name] == pytest.approx(0.0, abs=1e-12)
    assert np.isnan(c.band_rms_m["vertical"]["D3"])


def _write_track(path, t: TrackInput, distance_m=None) -> None:
    cols = {"chainage_m": t.chainage_m, "E_m": t.E_m, "N_m": t.N_m, "H_m": t.H_m,
            "sigma_E_mm": 1e3 * t.sigma_E_m, "sigma_N_mm": 1e3 * t.sigma_N_m, "sigma_H_mm": 1e3 * t.sigma_H_m,
            "lateral_dev_mm": "", "vertical_dev_mm": "", "gauge_mm": 1435.0, "cant_mm": "", "twist_mm": ""}
    if distance_m is not None:
        cols["distance_m"] = distance_m
    pd.DataFrame(cols).to_csv(path, index=False, float_format="%.6f")


def test_compare_cli_writes_the_table_and_plot_and_fails_on_request(tmp_path):
    from survey.cli import app
    from survey.commands.compare import compare
    from trolley.repeatability import DEFAULT_LIMIT

    assert inspect.signature(compare).parameters["limit"].default.default == DEFAULT_LIMIT
    n = 480
    s = STEP * np.arange(n)
    E, N, H = line(2.0, n)
    slew = np.where(np.abs(s - 150.0) < 8.0, 1.5e-3 * (1 + np.cos(np.pi * (s - 150.0) / 8.0)), 0.0)
    _write_track(tmp_path / "a.csv", track(E, N, H, chainage=1000.0 + s))
    right = np.array([math.cos(2.0), -math.sin(2.0)])      # the right normal of bearing 2 rad
    _write_track(tmp_path / "b.csv", track(E + slew * right[0], N + slew * right[1], H, chainage=1000.0 + s))
    runner = CliRunner()
    args = ["compare", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), "--csv", str(tmp_path / "d.csv"),
            "--plot", str(tmp_path / "d.png")]
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["agree"] is False and out["stretches_beyond"][0]["quantity"] == "lateral"
    assert out["stretches_beyond"][0]["at_chainage_m"] == pytest.approx(1150.0)
    assert out["max_abs_mm"]["lateral"] == pytest.approx(3.0, abs=1e-3) and out["max_abs_mm"]["gauge"] == pytest.approx(0.0, abs=1e-9)
    table = pd.read_csv(tmp_path / "d.csv")
    assert table.columns[:3].tolist() == ["chainage_m", "distance_m", "lateral_diff_mm"]
    assert table["lateral_diff_mm"].max() == pytest.approx(3.0, abs=1e-3)
    assert (tmp_path / "d.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert runner.invoke(app, args + ["--fail-on-disagreement"]).exit_code == 1
    # bad input: one line, exit 2, nothing written over an input
    r = runner.invoke(app, ["compare", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), "--limit", "0"])
    assert r.exit_code == 2 and "--limit" in r.stderr
    before = (tmp_path / "b.csv").read_bytes()
    r = runner.invoke(app, ["compare", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), "--csv",
                            str(tmp_path / "b.csv")])
    assert r.exit_code == 2 and "--csv" in r.stderr and (tmp_path / "b.csv").read_bytes() == before
    r = runner.invoke(app, ["compare", str(tmp_path / "a.csv"), str(tmp_path / "nothing.csv")])
    assert r.exit_code == 2 and "nothing.csv" in r.stderr


def test_two_simulated_surveys_of_one_track_agree_within_their_sigmas():
    """Two RLG surveys of one track (``track_seed``; their own sensor errors, fixes and setups),
    from the full 3-D simulator, each processed by the engine: their difference is within its
    sigma (no station beyond 3.5 sigma, RMS difference/sigma 0.5-1.6 on this pair: its stations
    are few independent samples), and the repeat of the relative geometry in D1 is a few um."""
    from dataclasses import replace
    from pathlib import Path

    from survey.commands.simulate import project_settings
    from trolley.engine import ProcessConfig, process_session
    from trolley.landxml import parse_landxml
    from trolley.truthsim import SimulationConfig, simulate_survey

    kwargs, _, xml = project_settings(Path(__file__).resolve().parents[1] / "projects" / "demo")
    design = parse_landxml(xml)
    base = replace(SimulationConfig(**kwargs), length_m=360.0, track_seed=5)
    tracks = []
    for seed in (1, 2):
        r = process_session(simulate_survey(design, replace(base, seed=seed)).session, design, ProcessConfig(),
                            with_observability=False)
        tracks.append(r.stations)             # a TrackInput
    c = compare_tracks(*tracks, limit=3.5)
    assert c.common_m > 300.0 and c.agree
    for q in ("lateral", "vertical"):
        assert 0.5 < c.rms_z[q] < 1.6, (q, c.rms_z)
    assert c.band_rms_m["lateral"]["D1"] < 0.05e-3 and c.band_rms_m["vertical"]["D1"] < 0.05e-3


def test_compare_gives_the_drawing_chainage_across_a_station_equation_and_reads_tracks_of_old_versions(tmp_path):
    """Track A's file has a station equation at 100 m (chainage 1100 is followed by 1150:
    ``chainage_m`` jumps, ``distance_m`` runs on) and neither ``cov_EN_mm2`` nor ``sigma_cant_mm``
    (a track.csv of before 2026-11-26): the difference table and the stretch carry A's drawing
    chainage, and what the files do not hold is null, not invented."""
    from survey.cli import app

    n = 480
    s = STEP * np.arange(n)
    drawing = np.where(s < 100.0, 1000.0 + s, 1050.0 + s)
    E, N, H = line(0.5, n)
    lift = np.where(np.abs(s - 200.0) < 8.0, 1.5e-3 * (1 + np.cos(np.pi * (s - 200.0) / 8.0)), 0.0)
    _write_track(tmp_path / "a.csv", track(E, N, H, chainage=drawing), distance_m=s)
    _write_track(tmp_path / "b.csv", track(E, N, H + lift, chainage=drawing), distance_m=s)
    r = CliRunner().invoke(app, ["compare", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), "--csv",
                                 str(tmp_path / "d.csv")])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    (stretch,) = out["stretches_beyond"]
    assert stretch["quantity"] == "vertical" and stretch["at_chainage_m"] == pytest.approx(1250.0)
    assert 1242.0 < stretch["from_chainage_m"] < 1250.0 < stretch["to_chainage_m"] < 1258.0
    assert out["rms_z"]["cant"] is None and out["sigma_median_mm"]["cant"] is None
    table = pd.read_csv(tmp_path / "d.csv")
    np.testing.assert_allclose(table["chainage_m"], drawing, atol=1e-4)
    np.testing.assert_allclose(table["distance_m"], s, atol=1e-4)
    assert table["cant_diff_mm"].isna().all()


def test_stations_of_a_across_a_gap_in_b_are_not_compared():
    """B: A's circle (a 300 m curve) with 100 stations (62.5 m) deleted in the middle. Before,
    A's stations there were compared with B's chord across the gap (1.6 m of sag: out of
    --max-offset-m in its middle, 0.06-0.48 m and hundreds of sigma near its ends); now they are not
    beside B, nor is anything interpolated across it. One missing station is bridged, as the
    survey sheet does (trackgeometry.GAP_STEPS)."""
    R = 300.0
    th = np.arange(640) * STEP / R
    E, N, H = R * np.sin(th), R * np.cos(th), np.zeros_like(th)
    a = track(E, N, H)
    keep = np.r_[0:300, 400:640]
    c = compare_tracks(a, track(E[keep], N[keep], H[keep], chainage=STEP * keep))
    assert c.agree and c.beyond["lateral"] == 0
    np.testing.assert_array_equal(c.difference.beside, np.isin(np.arange(640), keep))
    assert c.common_m == pytest.approx(STEP * (639 - 101))
    one = np.r_[0:300, 301:640]
    c = compare_tracks(a, track(E[one], N[one], H[one], chainage=STEP * one))
    assert c.difference.beside.all() and abs(c.difference.lateral_m[300]) < STEP**2 / (2 * R)


def test_a_backward_run_has_its_cant_turned_to_as_direction():
    """B runs the other way along A (its stations increase against A's): its left rail is A's
    right one, so its cant is -A's (FORMATS.md: + when the left rail is higher facing increasing
    chainage). Before, the cant difference was -2 x A's cant (240 mm in a 120 mm curve)."""
    n = 200
    E, N, H = line(0.7, n)
    cant = np.linspace(0.0, 0.12, n)
    a = track(E, N, H, cant=cant, sigma_cant=1e-4)
    b = track(E[::-1], N[::-1], H[::-1], cant=-cant[::-1], sigma_cant=1e-4)
    c = compare_tracks(a, b)
    np.testing.assert_allclose(c.difference.cant_m, 0.0, atol=1e-12)
    assert c.agree


def test_a_difference_against_a_zero_sigma_is_not_agreement(tmp_path):
    """Both files give sigma 0 and B is 50 mm higher: no ratio can be formed, and before the
    command said "the surveys agree within their sigmas", JSON agree true, exit 0 with
    --fail-on-disagreement. Identical files with zero sigmas still agree."""
    from survey.cli import app

    E, N, H = line(0.2, 100)
    _write_track(tmp_path / "a.csv", track(E, N, H, sigma_m=(0.0, 0.0, 0.0)))
    _write_track(tmp_path / "b.csv", track(E, N, H + 0.05, sigma_m=(0.0, 0.0, 0.0)))
    r = CliRunner().invoke(app, ["compare", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"),
                                 "--fail-on-disagreement"])
    assert r.exit_code == 1, r.output
    out = json.loads(r.stdout)
    assert out["agree"] is False and out["stations_zero_sigma"] == {"lateral": 0, "vertical": 100, "cant": 0}
    assert "agree" not in r.stderr and "zero sigma" in r.stderr
    r = CliRunner().invoke(app, ["compare", str(tmp_path / "a.csv"), str(tmp_path / "a.csv"),
                                 "--fail-on-disagreement"])
    assert r.exit_code == 0 and json.loads(r.stdout)["agree"] is True

"""The survey engine on data from the full 3-D truth simulator: errors inside their own sigmas."""
from pathlib import Path

import numpy as np
import pytest

from trolley.engine import ProcessConfig, process_session
from trolley.landxml import parse_landxml
from trolley.sensors import IMU_PRESETS
from trolley.truthsim import SimulationConfig, simulate_survey
from trolley.validation import track_errors

DEMO = Path(__file__).resolve().parents[1] / "projects" / "demo" / "alignment.xml"


@pytest.fixture(scope="module")
def design():
    return parse_landxml(DEMO.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def simulated(design):
    cfg = SimulationConfig(length_m=360.0, static_s=300.0, imu=IMU_PRESETS["rlg"], imu_rate_hz=100.0, seed=7)
    return simulate_survey(design, cfg)


def _errors(result, truth):
    tj = result.trajectory
    e = track_errors(tj.t_s, tj.distance_m, tj.enh_m, tj.sigma_enh_m, truth)
    return e.lateral_m, e.sigma_lateral_m, e.vertical_m, e.sigma_vertical_m


def test_smoothed_track_is_within_its_sigmas(design, simulated):
    result = process_session(simulated.session, design, ProcessConfig(smoother="rts"), with_observability=False)
    lat, s_lat, dh, s_h = _errors(result, simulated.truth)
    assert result.summary["fixes_rejected"] == 0
    assert np.sqrt(np.mean(lat**2)) < 1.0e-3
    assert np.sqrt(np.mean(dh**2)) < 1.0e-3
    for e, s in ((lat, s_lat), (dh, s_h)):
        ratio = np.sqrt(np.mean((e / s) ** 2))
        assert 0.5 < ratio < 1.5, ratio
        assert np.max(np.abs(e / s)) < 4.5


def test_rts_and_two_filter_give_the_same_track(design, simulated):
    cfg = dict(with_observability=False)
    rts = process_session(simulated.session, design, ProcessConfig(smoother="rts"), **cfg)
    tfs = process_session(simulated.session, design, ProcessConfig(smoother="tfs"), **cfg)
    assert np.max(np.abs(rts.trajectory.enh_m - tfs.trajectory.enh_m)) < 1e-9
    assert np.allclose(rts.trajectory.sigma_enh_m, tfs.trajectory.sigma_enh_m, rtol=1e-7, atol=0)


def test_smoothing_beats_filtering(design, simulated):
    cfg = dict(with_observability=False)
    sm = process_session(simulated.session, design, ProcessConfig(smoother="rts"), **cfg)
    fl = process_session(simulated.session, design, ProcessConfig(smoother="none"), **cfg)
    lat_s = _errors(sm, simulated.truth)[0]
    lat_f = _errors(fl, simulated.truth)[0]
    assert np.sqrt(np.mean(lat_s**2)) < 0.5 * np.sqrt(np.mean(lat_f**2))


def test_blunder_fix_is_rejected_and_kept(design, simulated):
    import copy
    session = copy.deepcopy(simulated.session)
    session.fixes.enh_m[3, 0] += 0.02  # 20 mm blunder in E on the fourth fix
    result = process_session(session, design, ProcessConfig(), with_observability=False)
    f = result.fixes
    assert len(f.t_s) == len(simulated.session.fixes)
    bad = np.flatnonzero(~f.accepted)
    assert list(bad) == [3]
    assert "chi-square" in f.reason[3]
    forced = process_session(session, design, ProcessConfig(force_accept=(str(f.point[3]),)),
                             with_observability=False)
    assert forced.fixes.accepted[3]


def test_stations_follow_formats_and_design(design, simulated):
    result = process_session(simulated.session, design, ProcessConfig(step_m=0.625), with_observability=False)
    st = result.stations
    assert np.allclose(np.diff(st.chainage_m), 0.625, atol=1e-6)
    # deviations from the design equal the simulated irregularities to within the track sigma
    truth = simulated.truth
    assert np.nanmax(np.abs(st.lateral_dev_m)) < 0.01
    # cant from the trolley roll against the true cant
    true_cant = np.interp(st.chainage_m, truth.chainage_m,
                          simulated.session.meta.trolley.rail_spacing_m * np.sin(truth.roll_rad))
    assert np.sqrt(np.mean((st.cant_m - true_cant) ** 2)) < 0.5e-3
    assert np.all(np.isfinite(st.gauge_m[5:-5]))


def test_vectorised_and_filterpy_loops_give_the_same_track(design, simulated):
    cfg = dict(with_observability=False)
    fast = process_session(simulated.session, design, ProcessConfig(vectorised=True), **cfg)
    loop = process_session(simulated.session, design, ProcessConfig(vectorised=False), **cfg)
    assert np.max(np.abs(fast.trajectory.enh_m - loop.trajectory.enh_m)) < 1e-9
    assert np.allclose(fast.trajectory.sigma_enh_m, loop.trajectory.sigma_enh_m, rtol=1e-7, atol=0)
    assert np.allclose(fast.fixes.nis, loop.fixes.nis, rtol=1e-9)

"""The survey engine on data from the full 3-D truth simulator: errors inside their own sigmas."""
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from trolley.engine import ProcessConfig, filter_nodes, process_session, session_observability_ranks
from trolley.landxml import parse_landxml
from trolley.sensors import IMU_PRESETS
from trolley.session import Fixes
from trolley.truthsim import SimulationConfig, simulate_survey
from trolley.validation import track_errors

DEMO = Path(__file__).resolve().parents[1] / "projects" / "demo" / "alignment.xml"
SHORT = dict(length_m=360.0, static_s=300.0, imu_rate_hz=100.0)
NO_OBS = dict(with_observability=False)


@pytest.fixture(scope="module")
def design():
    return parse_landxml(DEMO.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def simulated(design):
    return simulate_survey(design, SimulationConfig(**SHORT, imu=IMU_PRESETS["rlg"], seed=7))


def _errors(result, truth):
    tj = result.trajectory
    e = track_errors(tj.t_s, tj.distance_m, tj.enh_m, tj.sigma_enh_m, truth, cov_EN_m2=tj.cov_EN_m2)
    return e.lateral_m, e.sigma_lateral_m, e.vertical_m, e.sigma_vertical_m


def _pooled_normalised_errors(design, seeds, config=ProcessConfig(), **sim):
    """error / sigma, lateral and vertical, pooled over several simulated sessions, and the RMS errors."""
    lat_q, vert_q, lat_e, vert_e = [], [], [], []
    for seed in seeds:
        s = simulate_survey(design, SimulationConfig(**{**SHORT, **sim}, seed=seed))
        r = process_session(s.session, design, config, **NO_OBS)
        assert r.summary["fixes_rejected"] == 0, seed
        lat, s_lat, dh, s_h = _errors(r, s.truth)
        lat_q.append(lat / s_lat)
        vert_q.append(dh / s_h)
        lat_e.append(lat)
        vert_e.append(dh)
    return [np.concatenate(x) for x in (lat_q, vert_q, lat_e, vert_e)]


def _assert_honest(q, max_outside_3_sigma):
    rms = np.sqrt(np.mean(q**2))
    assert 0.7 < rms < 1.3, rms
    assert np.mean(np.abs(q) > 3.0) <= max_outside_3_sigma, np.mean(np.abs(q) > 3.0)


def test_smoothed_track_is_within_its_sigmas(design):
    # Along the track the errors are correlated over a fix interval (60 m), so one 360 m session
    # holds only about six independent samples and its RMS(e/s) scatters from 0.4 to 1.6 between
    # seeds; pooled over 12 sessions (about 70 intervals) the statistic is stable. At most 1 % of
    # the samples outside 3 sigma: Gaussian errors give 0.27 %; 1 % leaves room for the
    # correlation (a whole interval is in or out together), while a systematic misfit of the
    # sigmas (e.g. the position states interpolated in time across a stop: 5.7 sigma, 2 %) fails.
    lat_q, vert_q, lat, dh = _pooled_normalised_errors(design, range(12), imu=IMU_PRESETS["rlg"])
    assert np.sqrt(np.mean(lat**2)) < 0.6e-3
    assert np.sqrt(np.mean(dh**2)) < 0.6e-3
    _assert_honest(lat_q, 0.01)
    _assert_honest(vert_q, 0.01)


def test_mems_with_heading_from_the_fixes(design):
    # A MEMS unit cannot gyrocompass; without initial_heading_deg the heading comes from the
    # first two fixes more than 10 m apart. Its sigma must hold the gyro drift until half-way
    # along that chord, else the filter trusts a heading that is already wrong. The MEMS gyro
    # (3 deg/h) is beyond the paper's linearisation: allow 2 % outside 3 sigma.
    sim = simulate_survey(design, SimulationConfig(**SHORT, imu=IMU_PRESETS["mems"], initial_heading=False, seed=1))
    r = process_session(sim.session, design, ProcessConfig(), **NO_OBS)
    assert r.summary["heading_source"] == "fixes"
    true_yaw = np.interp(r.alignment.t_end_s, sim.truth.t_s, np.unwrap(sim.truth.yaw_rad))
    err = np.angle(np.exp(1j * (r.alignment.heading_rad - true_yaw)))
    assert abs(err) < 3.0 * np.deg2rad(r.summary["heading_sigma_deg"])
    lat_q, vert_q, _, _ = _pooled_normalised_errors(design, range(12), imu=IMU_PRESETS["mems"],
                                                    initial_heading=False)
    _assert_honest(lat_q, 0.02)
    _assert_honest(vert_q, 0.02)


def test_fog_with_a_given_initial_heading(design):
    sim = simulate_survey(design, SimulationConfig(**SHORT, imu=IMU_PRESETS["fog"], initial_heading=True, seed=2))
    given = sim.session.meta.initial_heading_rad
    assert np.isfinite(given)
    r = process_session(sim.session, design, ProcessConfig(), **NO_OBS)
    assert r.summary["heading_source"] == "given"
    # the given heading is the trolley's heading at the start, to rounding
    assert abs(np.angle(np.exp(1j * (r.alignment.heading_rad - given)))) < 1e-12
    lat_q, vert_q, _, _ = _pooled_normalised_errors(design, range(12), imu=IMU_PRESETS["fog"], initial_heading=True)
    # 2 %: with the E-N covariance the lateral sigma is no longer ~12 % conservative (pooled RMS
    # 1.09 against 0.96 without it), and one seed of twelve (9, RMS 1.76) holds the tail: its
    # samples are one or two independent intervals, not thousands
    _assert_honest(lat_q, 0.02)
    _assert_honest(vert_q, 0.01)


def test_session_without_a_design_uses_distance_from_the_first_fix(design, simulated):
    with_design = process_session(simulated.session, design, ProcessConfig(), **NO_OBS)
    r = process_session(simulated.session, None, ProcessConfig(step_m=0.625), **NO_OBS)
    st = r.stations
    assert st.chainage_m[0] == 0.0
    assert np.allclose(np.diff(st.chainage_m), 0.625, atol=1e-9)
    assert np.all(np.isnan(st.lateral_dev_m)) and np.all(np.isnan(st.vertical_dev_m))
    # the same trajectory as with the design (the design only places the stations)
    assert np.array_equal(r.trajectory.enh_m, with_design.trajectory.enh_m)
    # chainage is the 3-D path length from the first fix: against the truth's own path length
    # at the point of the true path (IMU-rate samples, 1 cm apart) nearest to each station
    from scipy.spatial import cKDTree
    tr = simulated.truth
    p = np.column_stack([tr.E_m, tr.N_m, tr.H_m])[tr.t_s >= r.alignment.t_end_s]
    p = p[np.concatenate([[True], np.linalg.norm(np.diff(p, axis=0), axis=1) > 0])]  # not the stops' repeats
    seg = np.diff(p, axis=0)
    true_length = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
    xyz = np.column_stack([st.E_m, st.N_m, st.H_m])
    j = np.minimum(cKDTree(p).query(xyz)[1], len(seg) - 1)
    tangent = seg[j] / np.linalg.norm(seg[j], axis=1)[:, None]
    true_at_station = true_length[j] + np.einsum("ij,ij->i", xyz - p[j], tangent)
    assert np.max(np.abs(st.chainage_m - true_at_station)) < 2e-3
    # and each station is the trajectory point at its time
    for i in range(3):
        pos = [st.E_m, st.N_m, st.H_m][i]
        assert np.max(np.abs(pos - np.interp(st.t_s, r.trajectory.t_s, r.trajectory.enh_m[:, i]))) < 1e-6


def test_rts_and_two_filter_give_the_same_track(design, simulated):
    rts = process_session(simulated.session, design, ProcessConfig(smoother="rts"), **NO_OBS)
    tfs = process_session(simulated.session, design, ProcessConfig(smoother="tfs"), **NO_OBS)
    assert np.max(np.abs(rts.trajectory.enh_m - tfs.trajectory.enh_m)) < 1e-9
    assert np.allclose(rts.trajectory.sigma_enh_m, tfs.trajectory.sigma_enh_m, rtol=1e-9, atol=0)


def test_smoothing_beats_filtering(design, simulated):
    sm = process_session(simulated.session, design, ProcessConfig(smoother="rts"), **NO_OBS)
    fl = process_session(simulated.session, design, ProcessConfig(smoother="none"), **NO_OBS)
    lat_s = _errors(sm, simulated.truth)[0]
    lat_f = _errors(fl, simulated.truth)[0]
    assert np.sqrt(np.mean(lat_s**2)) < 0.5 * np.sqrt(np.mean(lat_f**2))


def test_blunder_fix_is_rejected_and_kept(design, simulated):
    import copy
    session = copy.deepcopy(simulated.session)
    session.fixes.enh_m[3, 0] += 0.02  # 20 mm blunder in E on the fourth fix
    result = process_session(session, design, ProcessConfig(), **NO_OBS)
    f = result.fixes
    assert len(f.t_s) == len(simulated.session.fixes)
    bad = np.flatnonzero(~f.accepted)
    assert list(bad) == [3]
    assert "chi-square" in f.reason[3]
    forced = process_session(session, design, ProcessConfig(force_accept=(str(f.point[3]),)), **NO_OBS)
    assert forced.fixes.accepted[3]


def test_stations_follow_formats_and_design(design, simulated):
    result = process_session(simulated.session, design, ProcessConfig(step_m=0.625), **NO_OBS)
    st = result.stations
    assert np.allclose(np.diff(st.chainage_m), 0.625, atol=1e-6)
    # the run goes from chainage 0 to 360: the stations at both ends are there, although the
    # projected ends of the trajectory lie a fraction of a millimetre inside
    assert st.chainage_m[0] == 0.0 and st.chainage_m[-1] == pytest.approx(360.0, abs=1e-9)
    assert len(st.chainage_m) == 577
    # deviations from the design equal the simulated irregularities to within the track sigma
    truth = simulated.truth
    assert np.nanmax(np.abs(st.lateral_dev_m)) < 0.01
    # cant from the trolley roll against the true cant
    true_cant = np.interp(st.chainage_m, truth.chainage_m,
                          simulated.session.meta.trolley.rail_spacing_m * np.sin(truth.roll_rad))
    assert np.sqrt(np.mean((st.cant_m - true_cant) ** 2)) < 0.5e-3
    assert np.all(np.isfinite(st.gauge_m[5:-5]))


def test_nodes_at_every_start_and_stop(simulated):
    r = process_session(simulated.session, None, ProcessConfig(), **NO_OBS)
    dr = r.dead_reckoning
    nodes = filter_nodes(dr, np.array([], dtype=int), 1.0, 10.0)
    moving = np.diff(dr.distance_m) > 0
    # no node interval mixes standing and moving blocks
    for a, b in zip(nodes[:-1], nodes[1:]):
        assert moving[a:b].all() or not moving[a:b].any()
    # no gap longer than 10 s (plus one block), none wider than 1 m of travel
    dt_block = np.max(np.diff(dr.t_s))
    assert np.max(np.diff(dr.t_s[nodes])) <= 10.0 + dt_block
    # a node at the first block past each metre: gaps up to a metre plus one block's travel
    assert np.max(np.diff(dr.travel_m[nodes])) <= 1.0 + np.max(np.diff(dr.travel_m)) + 1e-9
    # the time grid only fills gaps: while walking (~1 m/s, 10 s > 1 m) it adds no node, so the
    # moving intervals are one per metre boundary crossed plus the starts and stops
    walk = np.diff(dr.travel_m[nodes]) > 0
    crossed = np.diff(np.floor(dr.travel_m[nodes]))
    starts = np.count_nonzero(np.diff(moving.astype(np.int8)) == 1) + int(moving[0])
    assert np.count_nonzero(walk) <= np.count_nonzero(crossed[walk]) + 2 * starts


def test_observability_from_the_session(design, simulated):
    r = process_session(simulated.session, design, ProcessConfig())
    assert r.observability_ranks == (3, 5)
    assert r.summary["observability_ranks"] == [3, 5]
    # the same session cut before the trolley first moves, with the static alignment shortened to
    # its first 100 s: the trolley never moves, the fixes see the position only (vertical 1 of 3,
    # level 2 of 5)
    s = simulated.session
    t_end = s.imu_t_s[0] + SHORT["static_s"] - 1.0
    assert np.ptp(s.odo_distance_m[s.odo_t_s <= t_end]) == 0.0
    f = s.fixes.t_s <= t_end
    i = s.imu_t_s <= t_end
    o = s.odo_t_s <= t_end
    standing = dataclasses.replace(
        s, meta=dataclasses.replace(s.meta, static_s=100.0), imu_t_s=s.imu_t_s[i], imu_w_rad_s=s.imu_w_rad_s[i], imu_f_m_s2=s.imu_f_m_s2[i],
        odo_t_s=s.odo_t_s[o], odo_distance_m=s.odo_distance_m[o],
        fixes=Fixes(s.fixes.t_s[f], s.fixes.point[f], s.fixes.enh_m[f], s.fixes.sigma_m[f]),
        gauge_t_s=None, gauge_m=None)
    rs = process_session(standing, design, ProcessConfig())
    assert rs.observability_ranks == (1, 2)
    # and the helper on the moving session's own dead reckoning, fixes at its stops
    fix_blocks = np.searchsorted(r.dead_reckoning.t_s, s.fixes.t_s)
    assert session_observability_ranks(r.dead_reckoning, fix_blocks, 1.0) == (3, 5)
    assert session_observability_ranks(r.dead_reckoning, fix_blocks[:1], 1.0) == (3, 5)  # one stop: whole run


def test_progress_reports_sub_steps_in_order(design, simulated):
    seen = []
    process_session(simulated.session, design, ProcessConfig(), progress=lambda step, f: seen.append((step, f)),
                    **NO_OBS)
    fractions = [f for _, f in seen]
    steps = [s for s, _ in seen]
    assert fractions == sorted(fractions) and fractions[0] == 0.0 and fractions[-1] == 1.0
    for name in ("dead reckoning", "forward filter, pass 1", "rts smoother, pass 1", "stations"):
        assert any(s.startswith(name) for s in steps), name


# ------------------------------------------------------------------------------------------
# the crew turns the trolley around at a stop (issue 7: lever arm and signs follow)
# ------------------------------------------------------------------------------------------
TURNED = dict(turn_at_stops=(2, 4), trolley=dataclasses.replace(
    SimulationConfig().trolley, prism_lever_arm_m=np.array([0.05, 0.35, -0.60])))


def test_turned_and_lifted_trolley_errors_stay_inside_their_sigmas(design):
    # Turned at stops 2 and 4 and lifted off the track (a train) at stop 3, each time put back
    # 4 cm short of where it was, with the prism 0.35 m to the side: the dead reckoning runs
    # backwards in the trolley frame, the pitch error changes sign at a turn, the lever arm turns
    # with the trolley, the position gains the placement uncertainty along the track at each
    # handling. Pooled as the untouched test, with the same limits; every fix accepted.
    handled = dict(TURNED, lift_at_stops=(3,), placement_offset_m=-0.04)
    for grade, outside in (("rlg", 0.01), ("mems", 0.02)):
        lat_q, vert_q, lat, dh = _pooled_normalised_errors(design, range(6), imu=IMU_PRESETS[grade], **handled)
        if grade == "rlg":
            assert np.sqrt(np.mean(lat**2)) < 0.6e-3
            assert np.sqrt(np.mean(dh**2)) < 0.6e-3
        _assert_honest(lat_q, outside)
        _assert_honest(vert_q, outside)


@pytest.mark.parametrize("with_design", [True, False])
def test_cant_keeps_its_sign_when_the_trolley_is_turned(design, with_design):
    sim = simulate_survey(design, SimulationConfig(**SHORT, imu=IMU_PRESETS["rlg"], seed=3, **TURNED))
    assert np.diff(sim.session.odo_distance_m).min() < 0  # the odometer counted down after the first turn
    r = process_session(sim.session, design if with_design else None, ProcessConfig(), **NO_OBS)
    st = r.stations
    assert r.summary["fixes_rejected"] == 0
    # the stations' true cant, at the true chainage of each station's time
    true_s = np.interp(st.t_s, sim.truth.t_s, sim.truth.chainage_m)
    true_cant = sim.truth.at_chainage(true_s).cant_m
    assert np.ptp(true_cant) > 0.05  # the stretch runs through the canted curve
    turned = sim.truth.motion.facing(st.t_s) < 0
    assert 0.3 < turned.mean() < 0.7  # both ways round are in the survey
    # a roll of the turned trolley taken as the cant would be off by twice the cant
    assert np.max(np.abs(st.cant_m - true_cant)) < 1e-3
    assert np.all(np.diff(st.chainage_m) > 0)


def test_gauge_is_never_bridged_across_a_sensor_gap(design, simulated):
    s = simulated.session
    keep = (s.gauge_t_s < 500.0) | (s.gauge_t_s > 560.0)  # the sensor silent for 60 s
    cut = dataclasses.replace(s, gauge_t_s=s.gauge_t_s[keep], gauge_m=s.gauge_m[keep])
    st = process_session(cut, design, ProcessConfig(), **NO_OBS).stations
    inside = (st.t_s > 500.5) & (st.t_s < 559.5)
    assert inside.sum() > 10
    assert np.all(np.isnan(st.gauge_m[inside]))
    outside = (st.t_s < 499.0) | (st.t_s > 561.0)
    assert np.all(np.isfinite(st.gauge_m[outside & (st.t_s > s.gauge_t_s[0]) & (st.t_s < s.gauge_t_s[-1])]))


def test_placement_noise_keeps_the_fix_after_a_lift(design):
    # put back 4 cm further along: without the placement uncertainty the fix after the lift is a
    # 4 cm blunder to the filter (rejected); with it, it re-anchors the position
    sim = simulate_survey(design, SimulationConfig(**SHORT, imu=IMU_PRESETS["rlg"], lift_at_stops=(2,),
                                                   placement_offset_m=0.04, seed=5))
    after = np.flatnonzero(sim.session.fixes.t_s > sim.truth.motion.handling_start_s[0])[0]
    naive = process_session(sim.session, design, ProcessConfig(placement_sigma_m=0.0), **NO_OBS)
    assert not naive.fixes.accepted[after] and naive.fixes.nis[after] > 100.0
    r = process_session(sim.session, design, ProcessConfig(), **NO_OBS)
    assert r.summary["fixes_rejected"] == 0
    lat, s_lat, dh, s_h = _errors(r, sim.truth)
    assert np.max(np.abs(lat / s_lat)) < 4.0 and np.max(np.abs(dh / s_h)) < 4.0


def _demo_settings_run(imu: str, seed: int, moved_east_m: float = 0.0, moved=(), track_seed=None):
    from survey.commands.simulate import project_settings
    kwargs, _, xml = project_settings(DEMO.parent)
    design = parse_landxml(xml)
    sim = simulate_survey(design, SimulationConfig(**{**kwargs, "imu": IMU_PRESETS[imu], "seed": seed,
                                                      "track_seed": track_seed}))
    sim.session.fixes.enh_m[list(moved), 0] += moved_east_m
    return sim, process_session(sim.session, design, ProcessConfig(), **NO_OBS)


@pytest.mark.parametrize("seed", [17, 26])
def test_mems_correct_fixes_are_not_rejected_in_a_cascade(seed):
    # The demo project's settings with a MEMS IMU; the forward gate rejected the last six fixes
    # of seed 17 (its linear error model drops the second order of a 1.5 deg heading error: 20 mm
    # along the track per interval), the track 0.33 m off (RMS), and four of seed 26 after one
    # correct fix just over the gate. Against the smoothed track of the others they agree.
    sim, r = _demo_settings_run("mems", seed)
    assert r.summary["fixes_rejected"] == 0 and r.summary["longest_rejected_run"] == 0
    assert r.summary["fixes_readmitted"] >= 3
    assert any("against the smoothed track of the other fixes (data snooping)" in x for x in r.fixes.reason)
    lat, s_lat, dh, s_h = _errors(r, sim.truth)
    for e, s in ((lat, s_lat), (dh, s_h)):
        assert np.sqrt(np.mean(e**2)) < 3e-3
        assert np.max(np.abs(e / s)) < 4.5
    _assert_cant_levelled_and_honest(sim, r)


def test_relinearised_pass_keeps_the_correct_fixes_of_a_large_mems_heading_error():
    # MEMS seed 25 on track seed 1012 (a repeat survey of seed 24): the heading, taken from the
    # fixes, drifts to 3.7 deg by fix 14. The first pass's linear model misses the second order
    # of it (speed x heading error x its growth, about 20 mm along the track per 60 m); the gate
    # rejected fix 14 (NIS 46, 5.7 sigma along the track) and the six after it. The relinearised
    # pass's model kept the correction's positions integrated along the previous pass's headings
    # and saw the same mismatch (its forward NIS 25-322 on correct fixes), so the snooping found
    # the rejected fixes still off (statistic 32.5 to 502) and the track ended 0.44 m off in
    # height. With the correction's positions integrated along the corrected headings the
    # snooping takes all seven back.
    sim, r = _demo_settings_run("mems", 25, track_seed=1012)
    assert r.summary["fixes_rejected"] == 0 and r.summary["fixes_readmitted"] == 7
    lat, s_lat, dh, s_h = _errors(r, sim.truth)
    for e, s in ((lat, s_lat), (dh, s_h)):
        assert np.sqrt(np.mean(e**2)) < 3e-3
        assert np.max(np.abs(e / s)) < 4.5


def _assert_cant_levelled_and_honest(sim, r):
    # The roll is levelled at every stop: there its error is the accelerometers' level error,
    # nearly the same at every stop (it changes with the cant through the z bias: 0.09 mm here).
    # The relinearisation used to tilt it again through the heading error (1.5 and 0.7 mm of
    # scatter on these seeds). Between the stops the gyros' drift is a bridge whose size the
    # cant sigma carries (error_models.levelled_roll_variance).
    from trolley.engine import level_sigma_rad
    tj = r.trajectory
    rail = sim.session.meta.trolley.rail_spacing_m
    e = rail * (np.sin(tj.roll_rad) - np.sin(np.interp(tj.t_s, sim.truth.t_s, sim.truth.roll_rad)))
    pinned = np.unique(np.clip(sim.session.fixes.t_s, tj.t_s[0], tj.t_s[-1]))
    at_stops = np.interp(pinned, tj.t_s, e)
    assert np.ptp(at_stops) < 0.3e-3
    bridge = e - np.interp(tj.t_s, pinned, at_stops)
    level = level_sigma_rad(r.alignment, r.config)
    bridge_sigma = rail * np.sqrt(np.mean(tj.roll_sigma_rad**2 - level**2))
    assert 0.7 < np.sqrt(np.mean(bridge**2)) / bridge_sigma < 1.3
    st = r.stations
    cant_error = st.cant_m - rail * np.sin(np.interp(st.t_s, sim.truth.t_s, sim.truth.roll_rad))
    assert np.max(np.abs(cant_error / st.sigma_cant_m)) < 3.5


@pytest.mark.parametrize("imu, moved_m", [("rlg", 0.05), ("mems", 0.1)])
def test_a_bad_setup_measuring_three_stops_is_rejected_and_the_right_fixes_after_it_kept(imu, moved_m):
    # fixes 5-7 moved east together: the forward gate rejected the first two, took the third (its
    # sigma grown over three intervals), then rejected the right ones after it (RLG: 12 of 13)
    sim, r = _demo_settings_run(imu, 0, moved_m, (5, 6, 7))
    assert list(np.flatnonzero(~r.fixes.accepted)) == [5, 6, 7]
    assert r.summary["fixes_readmitted"] >= 1  # the right ones the gate had rejected after the run
    lat, s_lat, dh, s_h = _errors(r, sim.truth)
    assert np.max(np.abs(lat / s_lat)) < 4.5 and np.max(np.abs(dh / s_h)) < 4.5


def test_fix_covariances_turn_with_the_grid():
    # a fix's E, N, H covariance in the filter's N, E, D frame: without a grid the axes swap (the
    # E-N covariance stays, the H-rows change sign with D); with a projected grid the E-N part is
    # turned by the convergence and scaled, as the positions are
    from trolley.engine import fix_covariances
    from trolley.projection import GridFactors

    c = np.array([[4.0, 1.5, 0.2], [1.5, 1.0, -0.1], [0.2, -0.1, 0.25]]) * 1e-8
    r = fix_covariances(c)[0]
    np.testing.assert_allclose(r, [[1.0e-8, 1.5e-8, 0.1e-8], [1.5e-8, 4.0e-8, -0.2e-8], [0.1e-8, -0.2e-8, 0.25e-8]])
    from trolley.engine import grid_to_ned
    g = GridFactors(latitude_rad=0.5, longitude_rad=0.2, convergence_rad=0.02, point_scale=1.0004, height_m=50.0,
                    radius_m=6.37e6)
    L = np.column_stack([grid_to_ned(e[None], np.zeros(3), g)[0] for e in np.eye(3)])
    np.testing.assert_allclose(fix_covariances(c, g)[0], L @ c @ L.T, rtol=1e-12)
    # the horizontal variance is kept but for the scale (a turn keeps the trace), and the turn moves
    # the correlation
    rg = fix_covariances(c, g)[0]
    assert np.isclose(np.trace(rg[:2, :2]), np.trace(c[:2, :2]) * abs(np.linalg.det(L[:2, :2])), rtol=1e-9, atol=0.0)
    assert not np.isclose(rg[0, 1], r[0, 1], rtol=1e-2, atol=0.0)

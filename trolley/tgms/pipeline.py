"""The whole TGMS processing chain for one recording (Escalona 2021 Sec. 11, modules 2-7):

vision (Eq. 19 + profile fit) -> IMU averaged to the processing rate -> odometry (Eq. 40-43) ->
track preprocessor (design TF kinematics at the nominal TGMS offset) -> relative attitude (Eq. 39
or Briales Sec. 5.2) -> relative trajectory (Eq. 46, or the 12-state smoother) -> irregularities
(Eq. 24, 27) per camera frame -> uniform station grid -> optional band-pass.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from trolley.tgms.camera import pixels_to_tgms
from trolley.tgms.irregularities import (Irregularities, irregularities, rails_in_laser_track_frame,
                                          resample_irregularities)
from trolley.tgms.odometry import Odometry, min_grid_samples, odometry
from trolley.tgms.orientation import RelativeAttitude, attitude_kf, attitude_madgwick, relative_yaw
from trolley.tgms.params import TgmsParams
from trolley.tgms.profiles import rail_profile
from trolley.tgms.recording import Recording
from trolley.tgms.track import TrackKinematics, track_kinematics
from trolley.tgms.trajectory import RelativeTrajectory, trajectory_ltv
from trolley.tgms.vision import FitOptions, RailFit, fit_rail

#: shortest stretch of track a recording must cover, m (a few camera frames' worth of irregularity)
MIN_TRACK_M = 10.0
#: speed below which a camera frame gets no station (standing still: the frames repeat one cut)
MOVING_M_S = 0.5


@dataclass
class VisionResult:
    """Per-frame output of the vision for both rails (frames paired by frame number)."""

    frame: np.ndarray
    t_s: np.ndarray
    left: RailFit
    right: RailFit
    x_left_m: np.ndarray | None = None
    x_right_m: np.ndarray | None = None

    @property
    def ok(self) -> np.ndarray:
        return self.left.ok & self.right.ok


@dataclass
class TgmsResult:
    """Everything the processing produced.

    Attributes
    ----------
    vision, odometry, kinematics, attitude, trajectory : intermediate results.
    frames : irregularities at every camera frame (station from the odometry).
    grid : irregularities on the uniform station grid (before band filtering).
    r0_z_m : nominal TGMS offset below (z) the TF origin estimated from the vision.
    laser_offset_m : per frame, station of the laser cut minus station of the IMU (x of the planes).
    timings_s : wall time of each stage.
    """

    vision: VisionResult
    odometry: Odometry
    kinematics: TrackKinematics
    attitude: RelativeAttitude
    trajectory: RelativeTrajectory
    frames: Irregularities
    grid: Irregularities
    r0_z_m: float
    timings_s: dict = field(default_factory=dict)
    laser_offset_m: np.ndarray | None = None


def run_vision(rec: Recording, options: FitOptions = FitOptions()) -> VisionResult:
    """Eq. 19 for every laser pixel and the robust profile fit of every frame, both cameras."""
    cfg = rec.config
    prof = rail_profile(cfg.track.rail_profile, cfg.track.rail_inclination)
    n_frames = 1 + max(int(rec.lasers[s].frame.max()) if len(rec.lasers[s].frame) else 0 for s in ("left", "right"))
    t = np.full(n_frames, np.nan)
    fits, xs = {}, {}
    for side in ("left", "right"):
        lp = rec.lasers[side]
        pts = pixels_to_tgms(cfg.cameras[side], lp.u_px, lp.v_px)
        good = np.all(np.isfinite(pts), axis=1)
        fits[side] = fit_rail(prof, lp.frame[good], pts[good, 1], pts[good, 2], n_frames, side, options)
        # where along x the laser cut the rail (the lever arm of the laser plane ahead of the IMU)
        cnt = np.bincount(lp.frame[good], minlength=n_frames)
        with np.errstate(invalid="ignore", divide="ignore"):
            xs[side] = np.bincount(lp.frame[good], pts[good, 0], minlength=n_frames) / cnt
        tf = np.full(n_frames, np.nan)
        tf[lp.frame] = lp.t_s
        t = np.where(np.isfinite(t), t, tf)
    return VisionResult(frame=np.arange(n_frames), t_s=t, left=fits["left"], right=fits["right"],
                        x_left_m=xs["left"], x_right_m=xs["right"])


def average_to_grid(t: np.ndarray, x: np.ndarray, t_grid: np.ndarray) -> np.ndarray:
    """Mean of a sampled signal over each processing interval [t_k - dt/2, t_k + dt/2], through the
    trapezoidal running integral (exact block average for any input rate)."""
    dt = t_grid[1] - t_grid[0]
    cum = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(t)[:, None], axis=0)])
    lo = np.clip(t_grid - dt / 2, t[0], t[-1])
    hi = np.clip(t_grid + dt / 2, t[0], t[-1])
    c_lo = np.column_stack([np.interp(lo, t, cum[:, i]) for i in range(x.shape[1])])
    c_hi = np.column_stack([np.interp(hi, t, cum[:, i]) for i in range(x.shape[1])])
    width = np.maximum(hi - lo, 1e-12)[:, None]
    return (c_hi - c_lo) / width


def process(rec: Recording, params: TgmsParams = TgmsParams(), step_m: float = 0.25,
            match_curves: bool = True, fit_options: FitOptions = FitOptions(),
            progress: Callable[[str, float], None] | None = None) -> TgmsResult:
    """Irregularities of one recording.

    Parameters
    ----------
    rec : the recording.
    params : estimator settings (see ``trolley tgms tune``).
    step_m : station step of the output grid.
    match_curves : correct the encoder station by curvature matching (Eq. 40-43).
    fit_options : profile-fit settings.
    progress : optional ``progress(step, fraction)`` called before each stage with the fraction
        of the run done, from the stage shares of a 1 km run (docs/tgms.md, timings).

    Returns
    -------
    TgmsResult
    """
    tim = {}
    cfg = rec.config

    def report(step: str, fraction: float) -> None:
        if progress is not None:
            progress(step, fraction)

    report("vision (profile fit of every frame)", 0.0)
    t0 = time.perf_counter()
    vis = run_vision(rec, fit_options)
    tim["vision"] = time.perf_counter() - t0
    if not vis.ok.any():
        raise ValueError("no camera frame could be used (every frame flagged by the profile fit)")
    # processing grid and IMU averaged onto it
    report("odometry", 0.70)
    t1 = time.perf_counter()
    dt = 1.0 / params.process_rate_hz
    t_grid = np.arange(rec.imu_t_s[0] + dt / 2, rec.imu_t_s[-1] - dt / 2, dt)
    need = min_grid_samples(dt)
    if t_grid.size < need:
        raise ValueError(f"imu.csv covers {rec.imu_t_s[-1] - rec.imu_t_s[0]:.3g} s; the encoder's smoothing at "
                         f"{params.process_rate_hz:g} Hz needs at least {(need + 1) * dt:.3g} s")
    w = average_to_grid(rec.imu_t_s, rec.imu_w_rad_s, t_grid)
    f = average_to_grid(rec.imu_t_s, rec.imu_f_m_s2, t_grid)
    s0 = cfg.track.start_station_m if cfg.track.start_station_m is not None else rec.alignment.start_chainage_m
    odo = odometry(t_grid, rec.enc_t_s, rec.enc_count, cfg.encoder.metres_per_count, s0, w[:, 2],
                   rec.alignment, match=match_curves, windows=params.odometry_windows,
                   method=params.odometry_method)
    covered = float(np.ptp(odo.s_m))
    if not covered >= MIN_TRACK_M:
        raise ValueError(f"encoder.csv gives {max(covered, 0.0):.2f} m of track during the IMU record "
                         f"({rec.enc_t_s[0]:g}-{rec.enc_t_s[-1]:g} s against {rec.imu_t_s[0]:g}-{rec.imu_t_s[-1]:g} s); "
                         f"at least {MIN_TRACK_M:g} m are needed")
    tim["odometry"] = time.perf_counter() - t1
    # nominal offset of the TGMS above the rails (Gonzalez-Carbajal 2023 Eq. 14's delta), from the vision
    Zv = 0.5 * (vis.left.z_m + vis.right.z_m)
    r0_z = -float(np.nanmedian(Zv))
    report("track kinematics", 0.73)
    t2 = time.perf_counter()
    kin = track_kinematics(rec.alignment, t_grid, odo.s_m, np.array([0.0, 0.0, r0_z]))
    kin.v_m_s, kin.a_m_s2 = odo.v_m_s, odo.a_m_s2
    tim["track"] = time.perf_counter() - t2
    report("orientation", 0.75)
    t3 = time.perf_counter()
    if params.orientation == "madgwick":
        att = attitude_madgwick(kin, w, f, params)
    else:
        att = attitude_kf(kin, w, f, params)
    tim["orientation"] = time.perf_counter() - t3
    report("trajectory", 0.84)
    t4 = time.perf_counter()
    if params.trajectory == "ekf":
        from trolley.tgms.ekf import trajectory_ekf
        traj = trajectory_ekf(kin, w, f, att, params)
        att = traj.attitude        # the 12-state smoother estimates the attitude jointly
    else:
        traj = trajectory_ltv(kin, f, att.roll_rad, att.pitch_rad, params)
    tim["trajectory"] = time.perf_counter() - t4
    # irregularities at the camera frames
    report("irregularities", 0.92)
    t5 = time.perf_counter()
    tf = vis.t_s
    inside = np.isfinite(tf) & (tf >= t_grid[0]) & (tf <= t_grid[-1])
    tfi = np.where(inside, tf, t_grid[0])

    def at(x):
        return np.where(inside, np.interp(tfi, t_grid, x), np.nan)

    s_f = at(odo.s_m)
    moving = at(odo.v_m_s) > MOVING_M_S
    s_f = np.where(moving, s_f, np.nan)
    if not np.isfinite(s_f).any():
        raise ValueError(f"no camera frame was taken while the vehicle moved within the IMU and encoder record "
                         f"(frames at {np.nanmin(tf):.6g}-{np.nanmax(tf):.6g} s, IMU at {t_grid[0]:.6g}-"
                         f"{t_grid[-1]:.6g} s)")
    L, R = vis.left, vis.right
    roll_f, ry_f, rz_f = at(att.roll_rad), at(traj.dr_y_m), r0_z + at(traj.dr_z_m)
    # first-order form (Eq. 24, 27) for the sigmas; the values come from the exact transform below
    fr = irregularities(s_f, L.y_m, L.z_m, R.y_m, R.z_m, roll_f, ry_f, rz_f, cfg.track.half_rail_spacing_m,
                        L.sigma_y_m, L.sigma_z_m, R.sigma_y_m, R.sigma_z_m, at(att.sigma_roll_rad),
                        at(traj.sigma_y_m), at(traj.sigma_z_m))
    yaw = att.yaw_rad if att.yaw_rad is not None else relative_yaw(kin, w, params)
    x_l = np.where(np.isfinite(vis.x_left_m), vis.x_left_m, 0.0)
    x_r = np.where(np.isfinite(vis.x_right_m), vis.x_right_m, 0.0)
    s_las = s_f + 0.5 * (x_l + x_r)
    use = np.isfinite(s_f) & np.isfinite(L.y_m) & np.isfinite(R.y_m) & np.isfinite(roll_f) & np.isfinite(ry_f)
    if use.any():
        ql, qr = rails_in_laser_track_frame(
            rec.alignment, s_f[use], s_las[use], roll_f[use], at(att.pitch_rad)[use], at(yaw)[use],
            ry_f[use], rz_f[use], np.column_stack([x_l[use], L.y_m[use], L.z_m[use]]),
            np.column_stack([x_r[use], R.y_m[use], R.z_m[use]]))
        Lr = cfg.track.half_rail_spacing_m
        fr.gauge_variation_m[use] = qr[:, 1] - ql[:, 1] - 2 * Lr
        fr.cross_level_m[use] = qr[:, 2] - ql[:, 2]
        fr.alignment_m[use] = 0.5 * (ql[:, 1] + qr[:, 1])
        fr.vertical_profile_m[use] = -0.5 * (ql[:, 2] + qr[:, 2])
    for name in fr.NAMES:
        getattr(fr, f"{name}_m")[~use] = np.nan
        getattr(fr, f"sigma_{name}_m")[~use] = np.nan
    # every frame taken while moving keeps its station, usable or not: the grid spans the stretch
    # the cameras saw, and what they could not measure (a camera file that ends early, flagged
    # frames at the ends) is there as empty cells, not cut off (bug hunt: a right camera
    # file ending half-way gave an irregularities.csv ending half-way, with no empty cell)
    fr.s_m = np.where(np.isfinite(s_f), s_las, np.nan)
    grid = resample_irregularities(fr, step_m)
    tim["irregularities"] = time.perf_counter() - t5
    report("irregularities", 1.0)
    return TgmsResult(vision=vis, odometry=odo, kinematics=kin, attitude=att, trajectory=traj,
                      frames=fr, grid=grid, r0_z_m=r0_z, timings_s=tim, laser_offset_m=0.5 * (x_l + x_r))

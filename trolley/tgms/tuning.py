"""Constrained maximum-likelihood (CML) tuning of the TGMS noise parameters
(Gonzalez-Carbajal 2023 Sec. 4.2).

The parameters are chosen to maximise the Gaussian log-likelihood of the filter innovations for
the recorded data, log p(y0 | p), with a global optimiser (scipy's ``differential_evolution``
instead of MATLAB's surrogate optimisation) over a box of 10^-4..10^4 around each parameter's
default, searched in log10, followed by a Nelder-Mead refinement of the best point (the
likelihood evaluations are whole filter runs, so the budget is small).

What is tuned: the 12-state smoother (``model="ekf"``, the paper's own case, parameters grouped
per axis, Eq. 19 enforced), or the relative-attitude filter. For the latter, Eq. 39 has
real measurements (the track-compensated accelerometers), so its three noise parameters (gyro
noise, gyro-bias random walk, accelerometer disturbance) are estimated by CML. The LTV trajectory
model takes the accelerometers as *inputs* and has only the virtual zero-position measurements,
whose likelihood is maximised by r = 0; the paper's constraint u_y_ac <= u_y_pos / 10 (Eq. 19)
exists to stop exactly that. We apply it in its physical meaning instead: the virtual
measurements may not act on wavelengths shorter than 4 times the longest wavelength of interest
(cut-off >= 100 m for D1), and the trajectory parameters are not changed by the tuning.
The same degeneracy exists for the attitude (see :func:`satisfies_constraint`): a second
constraint keeps the gyro/accelerometer crossover below 0.05 Hz.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import differential_evolution, minimize

from trolley.tgms.orientation import attitude_kf
from trolley.tgms.params import TgmsParams
from trolley.tgms.recording import Recording

TUNED = ("gyro_noise_rad_sqrt_s", "gyro_bias_rw_rad_s_sqrt_s", "accel_disturbance_m_s2")
TUNED_EKF = ("ekf_q_angle_rad2_s3", "ekf_q_jerk_m2_s5", "gyro_noise_rad_sqrt_s", "ekf_u_acc_m2_s4", "ekf_u_pos_m2")


#: Highest crossover frequency allowed between gyro and accelerometer in the attitude estimate.
MAX_ATTITUDE_CROSSOVER_HZ = 0.05


def attitude_crossover_hz(gyro_noise: float, accel_sigma: float, dt: float) -> float:
    """Steady-state crossover of a gyro-integrating attitude filter corrected by tilt from the
    accelerometers: omega_c = sqrt(q / r), q = gyro_noise^2, r = (accel_sigma / g)^2 dt."""
    from trolley.tgms.track import GRAVITY_M_S2
    return gyro_noise * GRAVITY_M_S2 / (accel_sigma * np.sqrt(dt)) / (2 * np.pi)


def satisfies_constraint(p: TgmsParams, model: str = "ekf") -> bool:
    """The constraints of the search.

    * Gonzalez-Carbajal 2023 Eq. 19 (``ekf``): u_y^ac <= u_y^pos / 10 (SI; u_pos at 10 m/s).
    * Its analogue for the attitude (both models): the accelerometers may correct the attitude only
      below MAX_ATTITUDE_CROSSOVER_HZ. Without it the likelihood is maximised by explaining the
      (coloured, unmodelled) relative accelerations of the body as tilt: on a simulated ride the
      unconstrained optimum had a 75 Hz crossover and 0.16 rad roll errors (67 mm cross level).
    """
    dt = 1.0 / p.process_rate_hz
    if model == "ekf":
        if p.ekf_u_acc_m2_s4 > p.ekf_u_pos_m2 / 10.0:
            return False
        sig = np.sqrt(p.ekf_u_acc_m2_s4)
    else:
        sig = p.accel_disturbance_m_s2
    return attitude_crossover_hz(p.gyro_noise_rad_sqrt_s, sig, dt) <= MAX_ATTITUDE_CROSSOVER_HZ


def tune_cml(rec: Recording, base: TgmsParams = TgmsParams(), max_evaluations: int = 60,
             seed: int = 0, decades: float = 4.0, model: str = "kf"):
    """CML estimate of the noise parameters for one recording.

    ``model="kf"`` tunes the relative-attitude filter (three parameters); ``model="ekf"`` tunes the
    12-state smoother of Gonzalez-Carbajal 2023 (q_angle, q_jerk, u_gyro, u_acc, u_pos: the 13 of
    their Eq. 16 grouped by axis) under the constraint of their Eq. 19, and sets
    ``trajectory="ekf"``.

    Parameters
    ----------
    rec : the recording.
    base : starting parameters (the box is ``decades`` around them, in log10).
    max_evaluations : rough budget of likelihood evaluations (each one filter run).
    seed : seed of the optimiser.
    decades : half-width of the search box in decades (Gonzalez-Carbajal 2023 Eq. 17 uses 4).

    Returns
    -------
    (TgmsParams, info) with info = {"loglik", "loglik_default", "evaluations"}.

    References
    ----------
    Gonzalez-Carbajal 2023 Sec. 4.2, Eq. 17, 19.
    """
    from trolley.tgms.ekf import trajectory_ekf
    from trolley.tgms.odometry import odometry
    from trolley.tgms.pipeline import average_to_grid, run_vision
    from trolley.tgms.track import track_kinematics

    cfg = rec.config
    dt = 1.0 / base.process_rate_hz
    t = np.arange(rec.imu_t_s[0] + dt / 2, rec.imu_t_s[-1] - dt / 2, dt)
    w = average_to_grid(rec.imu_t_s, rec.imu_w_rad_s, t)
    f = average_to_grid(rec.imu_t_s, rec.imu_f_m_s2, t)
    s0 = cfg.track.start_station_m if cfg.track.start_station_m is not None else rec.alignment.start_chainage_m
    odo = odometry(t, rec.enc_t_s, rec.enc_count, cfg.encoder.metres_per_count, s0, w[:, 2], rec.alignment)
    vis = run_vision(rec)
    r0_z = -float(np.nanmedian(0.5 * (vis.left.z_m + vis.right.z_m)))
    kin = track_kinematics(rec.alignment, t, odo.s_m, np.array([0.0, 0.0, r0_z]))
    kin.v_m_s, kin.a_m_s2 = odo.v_m_s, odo.a_m_s2
    names = TUNED_EKF if model == "ekf" else TUNED
    if model == "ekf":
        base = dataclasses.replace(base, trajectory="ekf")
    x0 = np.log10([getattr(base, k) for k in names])
    count = [0]

    def negll(x):
        count[0] += 1
        p = dataclasses.replace(base, **{k: float(10 ** v) for k, v in zip(names, x)})
        if not satisfies_constraint(p, model):
            return 1e30
        if model == "ekf":
            ll = trajectory_ekf(kin, w, f, None, p, smooth=False).loglik
        else:
            ll = attitude_kf(kin, w, f, p, smooth=False).loglik
        return -ll if np.isfinite(ll) else 1e30

    ll0 = -negll(x0)
    bounds = [(v - decades, v + decades) for v in x0]
    # half the budget for the global search, half for a local (Nelder-Mead) refinement of its best
    popsize = 5
    maxiter = max(1, (max_evaluations // 2) // (popsize * len(names)) - 1)
    res = differential_evolution(negll, bounds, seed=seed, popsize=popsize, maxiter=maxiter, tol=1e-6,
                                 polish=False, x0=x0)
    loc = minimize(negll, res.x, method="Nelder-Mead", bounds=bounds,
                   options={"maxfev": max(10, max_evaluations - count[0]), "xatol": 0.02, "fatol": 0.1})
    x_best, f_best = (loc.x, loc.fun) if loc.fun < res.fun else (res.x, res.fun)
    best = dataclasses.replace(base, **{k: float(10 ** v) for k, v in zip(names, x_best)})
    return best, {"loglik": float(-f_best), "loglik_default": float(ll0), "evaluations": int(count[0])}

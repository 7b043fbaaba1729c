"""Constrained maximum-likelihood (CML) tuning of the TGMS noise parameters
(Gonzalez-Carbajal 2023 Sec. 4.2).

The parameters are chosen to maximise the Gaussian log-likelihood of the filter innovations for
the recorded data, log p(y0 | p), with a global optimiser (scipy's ``differential_evolution``
instead of MATLAB's surrogate optimisation) over a box of 10^-4..10^4 around each parameter's
default, searched in log10.

What is tuned here, and the deviation from the paper: our relative-attitude filter (Eq. 39) has
real measurements (the track-compensated accelerometers), so its three noise parameters (gyro
noise, gyro-bias random walk, accelerometer disturbance) are estimated by CML. The LTV trajectory
model takes the accelerometers as *inputs* and has only the virtual zero-position measurements,
whose likelihood is maximised by r = 0; the paper's constraint u_y_ac <= u_y_pos / 10 (Eq. 19)
exists to stop exactly that. We apply it in its physical meaning instead: the virtual
measurements may not act on wavelengths shorter than 4 times the longest wavelength of interest
(cut-off >= 100 m for D1), and the trajectory parameters are not changed by the tuning.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import differential_evolution

from trolley.tgms.orientation import attitude_kf
from trolley.tgms.params import TgmsParams
from trolley.tgms.recording import Recording

TUNED = ("gyro_noise_rad_sqrt_s", "gyro_bias_rw_rad_s_sqrt_s", "accel_disturbance_m_s2")


def tune_cml(rec: Recording, base: TgmsParams = TgmsParams(), max_evaluations: int = 60,
             seed: int = 0, decades: float = 4.0):
    """CML estimate of the attitude-filter noise parameters for one recording.

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
    from trolley.tgms.pipeline import average_to_grid
    from trolley.tgms.odometry import odometry
    from trolley.tgms.track import track_kinematics

    cfg = rec.config
    dt = 1.0 / base.process_rate_hz
    t = np.arange(rec.imu_t_s[0] + dt / 2, rec.imu_t_s[-1] - dt / 2, dt)
    w = average_to_grid(rec.imu_t_s, rec.imu_w_rad_s, t)
    f = average_to_grid(rec.imu_t_s, rec.imu_f_m_s2, t)
    s0 = cfg.track.start_station_m if cfg.track.start_station_m is not None else rec.alignment.start_chainage_m
    odo = odometry(t, rec.enc_t_s, rec.enc_count, cfg.encoder.metres_per_count, s0, w[:, 2], rec.alignment)
    kin = track_kinematics(rec.alignment, t, odo.s_m, np.array([0.0, 0.0, -0.45]))
    x0 = np.log10([getattr(base, k) for k in TUNED])
    count = [0]

    def negll(x):
        count[0] += 1
        p = dataclasses.replace(base, **{k: float(10 ** v) for k, v in zip(TUNED, x)})
        ll = attitude_kf(kin, w, f, p, smooth=False).loglik
        return -ll if np.isfinite(ll) else 1e30

    ll0 = -negll(x0)
    popsize = 5
    maxiter = max(1, max_evaluations // (popsize * len(TUNED)) - 1)
    res = differential_evolution(negll, [(v - decades, v + decades) for v in x0], seed=seed,
                                 popsize=popsize, maxiter=maxiter, tol=1e-6, polish=False, x0=x0)
    best = dataclasses.replace(base, **{k: float(10 ** v) for k, v in zip(TUNED, res.x)})
    return best, {"loglik": float(-res.fun), "loglik_default": float(ll0), "evaluations": int(count[0])}

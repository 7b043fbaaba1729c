"""Constrained maximum-likelihood (CML) tuning of the TGMS noise parameters
(Gonzalez-Carbajal 2023 Sec. 4.2).

The parameters are chosen to maximise the Gaussian log-likelihood of the filter innovations for
the recorded data, log p(y0 | p), with a global optimiser (scipy's ``differential_evolution``
instead of MATLAB's surrogate optimisation) searched in log10, followed by a Nelder-Mead
refinement of the best point. The number of likelihood evaluations (whole filter runs) is a hard
limit: the search stops at the budget and returns the best point seen.

Search box (``box``):

* ``"absolute"``: Eq. 17, 1e-4 <= p_i <= 1e4 in the paper's parameterisation (every p_i a
  variance or PSD in SI: u^omega = gyro density^2 / dt per sample, u^ac = accelerometer variance,
  q = PSDs, u^pos at 10 m/s; for the attitude filter the gyro-bias random walk as a variance
  rate). Not the default: for a MEMS IMU at 100 Hz the physical gyro variance (1.9e-7 rad^2/s^2
  for 0.15 deg/sqrt(h)) and bias random walk (1e-12) lie *below* the box, so the box excludes
  the true values.
* ``"relative"`` (default): ``decades`` (4) either side of each default, the same width as Eq. 17
  but centred on the IMU's data-sheet values.

What is tuned (``model``):

* ``"ekf"``: the 12-state smoother, the paper's own case (q_angle, q_jerk, u_gyro, u_acc, u_pos:
  the 13 of Eq. 16 grouped by axis) under Eq. 19, u_y^ac <= u_y^pos / 10; sets
  ``trajectory="ekf"``.
* ``"kf"``: the relative-attitude filter (Eq. 39: gyro noise, gyro-bias random walk,
  accelerometer disturbance). Eq. 19 concerns the position measurements, which this filter does
  not have; its analogue applies (see :func:`satisfies_constraint`).
* ``"ltv"``: the attitude filter as for ``"kf"``, then the LTV trajectory of Eq. 46
  (accelerometer noise density and cut-off wavelength) with the attitude kept. Its only
  measurements are the virtual zero positions, so its likelihood grows as the virtual
  measurements gain weight (r -> 0); Eq. 19 is what bounds it: with u^ac = density^2 / dt and
  u^pos = u^ac / omega_c^4 it reads omega_c <= 10^-1/4 rad/s, i.e. a cut-off wavelength
  >= 2 pi V / 0.562 at the ride's fastest (95th percentile) speed. Half the budget goes to each
  stage.
"""
from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np
from scipy.optimize import differential_evolution, minimize

from trolley.tgms.orientation import attitude_kf
from trolley.tgms.params import TgmsParams
from trolley.tgms.recording import Recording

TUNED = ("gyro_noise_rad_sqrt_s", "gyro_bias_rw_rad_s_sqrt_s", "accel_disturbance_m_s2")
TUNED_LTV = ("accel_noise_m_s2_sqrt_hz", "cutoff_wavelength_m")
TUNED_EKF = ("ekf_q_angle_rad2_s3", "ekf_q_jerk_m2_s5", "gyro_noise_rad_sqrt_s", "ekf_u_acc_m2_s4", "ekf_u_pos_m2")


#: Highest crossover frequency allowed between gyro and accelerometer in the attitude estimate.
MAX_ATTITUDE_CROSSOVER_HZ = 0.05


def attitude_crossover_hz(gyro_noise: float, accel_sigma: float, dt: float) -> float:
    """Steady-state crossover of a gyro-integrating attitude filter corrected by tilt from the
    accelerometers: omega_c = sqrt(q / r), q = gyro_noise^2, r = (accel_sigma / g)^2 dt."""
    from trolley.tgms.track import GRAVITY_M_S2
    return gyro_noise * GRAVITY_M_S2 / (accel_sigma * np.sqrt(dt)) / (2 * np.pi)


def satisfies_constraint(p: TgmsParams, model: str = "ekf", v_m_s: float = 10.0) -> bool:
    """The constraints of the search.

    * Gonzalez-Carbajal 2023 Eq. 19 (``ekf``): u_y^ac <= u_y^pos / 10 (SI; u_pos at 10 m/s).
    * Eq. 19 for the LTV model (``ltv``): u^ac = density^2 / dt, u^pos = u^ac / omega_c^4 with
      omega_c = 2 pi V / cutoff, so it holds when omega_c(v_m_s) <= 10^-1/4 rad/s.
    * Its analogue for the attitude (``kf``, ``ekf``): the accelerometers may correct the attitude
      only below MAX_ATTITUDE_CROSSOVER_HZ. Without it the likelihood is maximised by explaining
      the (coloured, unmodelled) relative accelerations of the body as tilt: on a simulated ride
      the unconstrained optimum had a 75 Hz crossover and 0.16 rad roll errors (67 mm cross level).
    """
    dt = 1.0 / p.process_rate_hz
    if model == "ltv":
        wc = 2 * np.pi * v_m_s / p.cutoff_wavelength_m
        return bool(wc ** 4 <= 0.1)
    if model == "ekf":
        if p.ekf_u_acc_m2_s4 > p.ekf_u_pos_m2 / 10.0:
            return False
        sig = np.sqrt(p.ekf_u_acc_m2_s4)
    else:
        sig = p.accel_disturbance_m_s2
    return attitude_crossover_hz(p.gyro_noise_rad_sqrt_s, sig, dt) <= MAX_ATTITUDE_CROSSOVER_HZ


#: Paper form of each parameter (Gonzalez-Carbajal 2023 Eq. 16): p = value^power / dt^per_sample.
PAPER_FORM = {"gyro_noise_rad_sqrt_s": (2, 1), "gyro_bias_rw_rad_s_sqrt_s": (2, 0), "accel_disturbance_m_s2": (2, 0),
              "ekf_q_angle_rad2_s3": (1, 0), "ekf_q_jerk_m2_s5": (1, 0), "ekf_u_acc_m2_s4": (1, 0),
              "ekf_u_pos_m2": (1, 0), "accel_noise_m_s2_sqrt_hz": (2, 1), "cutoff_wavelength_m": (1, 0)}


def search_box(names, base: TgmsParams, box: str = "relative", decades: float = 4.0) -> list[tuple[float, float]]:
    """log10 bounds of each parameter's value (in TgmsParams units).

    ``"absolute"``: 1e-4 <= p <= 1e4 in the paper form (``PAPER_FORM``), Gonzalez-Carbajal 2023
    Eq. 17 (the cut-off wavelength, not a variance, keeps 1e-4..1e4 m); ``"relative"``: ``decades``
    either side of ``base``.
    """
    if box not in ("relative", "absolute"):
        raise ValueError(f"box must be 'relative' or 'absolute', got {box!r}")
    log_dt = np.log10(1.0 / base.process_rate_hz)
    out = []
    for k in names:
        if box == "relative":
            c = np.log10(getattr(base, k))
            out.append((c - decades, c + decades))
        else:
            power, per_sample = PAPER_FORM[k]
            # log10 p = power log10 v - per_sample log10 dt
            out.append(((-4.0 + per_sample * log_dt) / power, (4.0 + per_sample * log_dt) / power))
    return out


class _BudgetSpent(Exception):
    pass


def _maximise(negll, names, base, bounds, max_evaluations, seed):
    """Differential evolution then Nelder-Mead in log10, never more than ``max_evaluations`` calls
    of ``negll``. Returns (best params, best negll, evaluations, negll at the defaults).

    The search starts from the defaults clipped into the box; when the box excludes the defaults
    (the "absolute" box and a MEMS gyro), they are evaluated as well, and kept when nothing in
    the box is better: a tuning never returns worse parameters than it started from.
    """
    xd = np.log10([getattr(base, k) for k in names])
    x0 = np.clip(xd, [b[0] for b in bounds], [b[1] for b in bounds])
    state = {"n": 0, "x": x0, "f": np.inf}

    def counted(x):
        if state["n"] >= max_evaluations:
            raise _BudgetSpent
        state["n"] += 1
        v = negll(x)
        if v < state["f"]:
            state["x"], state["f"] = np.array(x, dtype=float), v
        return v

    f0 = counted(x0)
    if not np.array_equal(x0, xd):
        state["n"] += 1
        f_default = negll(xd)       # outside the box: evaluated, never moved to
    else:
        f_default = f0
    popsize = 5
    maxiter = max(1, (max_evaluations // 2) // (popsize * len(names)) - 1)
    try:
        res = differential_evolution(counted, bounds, seed=seed, popsize=popsize, maxiter=maxiter, tol=1e-6,
                                     polish=False, x0=x0)
        minimize(counted, res.x, method="Nelder-Mead", bounds=bounds,
                 options={"maxfev": max(1, max_evaluations - state["n"]), "xatol": 0.02, "fatol": 0.1})
    except _BudgetSpent:
        pass
    if f_default <= state["f"]:
        return base, f_default, state["n"], f_default
    best = dataclasses.replace(base, **{k: float(10 ** v) for k, v in zip(names, state["x"])})
    return best, state["f"], state["n"], f_default


def tune_cml(rec: Recording, base: TgmsParams = TgmsParams(), max_evaluations: int = 60,
             seed: int = 0, decades: float = 4.0, model: str = "kf", box: str = "relative",
             progress: Callable[[str, float], None] | None = None):
    """CML estimate of the noise parameters for one recording.

    Parameters
    ----------
    rec : the recording.
    base : starting parameters (and the centre of the "relative" box).
    max_evaluations : hard limit on likelihood evaluations (each one filter run), >= 2.
    seed : seed of the optimiser.
    decades : half-width of the "relative" box in decades.
    model : "kf", "ltv" or "ekf" (see the module docstring).
    box : "relative" or "absolute" (Eq. 17), see :func:`search_box`.
    progress : optional ``progress(step, fraction)``: the vision first (fraction 0), then the
        likelihood evaluations against ``max_evaluations`` (the CLI's progress bar).

    Returns
    -------
    (TgmsParams, info) with info = {"loglik", "loglik_default", "evaluations"}; for "ltv" the
    log-likelihoods are those of the trajectory stage.

    Raises
    ------
    ValueError : no camera frame usable, or bad ``model``/``box``/``max_evaluations``.

    References
    ----------
    Gonzalez-Carbajal 2023 Sec. 4.2, Eq. 16, 17, 19.
    """
    from trolley.tgms.ekf import trajectory_ekf
    from trolley.tgms.odometry import odometry
    from trolley.tgms.pipeline import average_to_grid, run_vision
    from trolley.tgms.track import track_kinematics
    from trolley.tgms.trajectory import trajectory_ltv

    if model not in ("kf", "ltv", "ekf"):
        raise ValueError(f"model must be 'kf', 'ltv' or 'ekf', got {model!r}")
    if max_evaluations < 2:
        raise ValueError("max_evaluations must be at least 2")
    cfg = rec.config
    dt = 1.0 / base.process_rate_hz
    t = np.arange(rec.imu_t_s[0] + dt / 2, rec.imu_t_s[-1] - dt / 2, dt)
    w = average_to_grid(rec.imu_t_s, rec.imu_w_rad_s, t)
    f = average_to_grid(rec.imu_t_s, rec.imu_f_m_s2, t)
    s0 = cfg.track.start_station_m if cfg.track.start_station_m is not None else rec.alignment.start_chainage_m
    odo = odometry(t, rec.enc_t_s, rec.enc_count, cfg.encoder.metres_per_count, s0, w[:, 2], rec.alignment,
                   windows=base.odometry_windows, method=base.odometry_method)
    if progress is not None:
        progress("vision (profile fit of every frame)", 0.0)
    vis = run_vision(rec)
    if not vis.ok.any():
        raise ValueError("no camera frame could be used (every frame flagged by the profile fit), "
                         "so the TGMS height delta is unknown")
    r0_z = -float(np.nanmedian(0.5 * (vis.left.z_m + vis.right.z_m)))
    kin = track_kinematics(rec.alignment, t, odo.s_m, np.array([0.0, 0.0, r0_z]))
    kin.v_m_s, kin.a_m_s2 = odo.v_m_s, odo.a_m_s2

    calls = 0

    def run(names, stage_base, ll_of, constraint, budget):
        def negll(x):
            nonlocal calls
            calls += 1
            if progress is not None:
                progress(f"likelihood, evaluation {calls} of at most {max_evaluations}",
                         min(calls / max_evaluations, 1.0))
            p = dataclasses.replace(stage_base, **{k: float(10 ** v) for k, v in zip(names, x)})
            if not constraint(p):
                return 1e30
            ll = ll_of(p)
            return -ll if np.isfinite(ll) else 1e30
        return _maximise(negll, names, stage_base, search_box(names, stage_base, box, decades), budget, seed)

    if model == "ekf":
        base = dataclasses.replace(base, trajectory="ekf")
        best, fb, n, f0 = run(TUNED_EKF, base, lambda p: trajectory_ekf(kin, w, f, None, p, smooth=False).loglik,
                              lambda p: satisfies_constraint(p, "ekf"), max_evaluations)
        return best, {"loglik": float(-fb), "loglik_default": float(-f0), "evaluations": int(n)}
    budget_att = max_evaluations if model == "kf" else max(1, max_evaluations // 2)
    best, fb, n, f0 = run(TUNED, base, lambda p: attitude_kf(kin, w, f, p, smooth=False).loglik,
                          lambda p: satisfies_constraint(p, "kf"), budget_att)
    if model == "kf":
        return best, {"loglik": float(-fb), "loglik_default": float(-f0), "evaluations": int(n)}
    att = attitude_kf(kin, w, f, best)
    v_fast = float(np.percentile(kin.v_m_s[kin.v_m_s > 2.0], 95)) if (kin.v_m_s > 2.0).any() else 2.0
    best2, fb2, n2, f02 = run(TUNED_LTV, dataclasses.replace(best, trajectory="ltv"),
                              lambda p: trajectory_ltv(kin, f, att.roll_rad, att.pitch_rad, p, smooth=False).loglik,
                              lambda p: satisfies_constraint(p, "ltv", v_fast), max_evaluations - n)
    return best2, {"loglik": float(-fb2), "loglik_default": float(-f02), "evaluations": int(n + n2)}

"""Tunable parameters of the TGMS processing (what ``trolley tgms tune`` writes and ``process``
reads), SI units."""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields


#: how far from its default a numeric parameter may be, either way (a factor)
RANGE_FACTOR = 1e8


@dataclass(frozen=True)
class TgmsParams:
    """Noise parameters and choices of the TGMS estimators.

    Attributes
    ----------
    process_rate_hz : rate of the orientation and trajectory estimators (IMU averaged to it).
    gyro_noise_rad_sqrt_s : gyro white noise (angle random walk) assumed by the filters.
    gyro_bias_rw_rad_s_sqrt_s : random walk of the gyro bias states.
    accel_disturbance_m_s2 : 1-sigma of the accelerations the orientation filter does not model
        (relative motion of the TGMS), per processing sample.
    madgwick_beta_rad_s : gain of the gradient-descent variant (Briales Sec. 5.2).
    madgwick_zeta_rad_s2 : gyro-bias gain of the gradient-descent variant.
    accel_noise_m_s2_sqrt_hz : accelerometer input noise density of the trajectory model.
    cutoff_wavelength_m : wavelength at which the virtual zero-position measurements take over
        (their variance follows the speed so that the cut-off is fixed in space).
    ekf_q_angle_rad2_s3 : PSD of the angular accelerations of the 12-state smoother (q_phi = q_theta
        = q_psi of Gonzalez-Carbajal 2023 Eq. 16).
    ekf_q_jerk_m2_s5 : PSD of the jerks (q_y = q_z).
    ekf_u_acc_m2_s4 : variance of one accelerometer sample (u_x^ac = u_y^ac = u_z^ac).
    ekf_u_pos_m2 : variance of the virtual position measurements at 10 m/s (u_y^pos = u_z^pos); it
        scales with (10 m/s / V)^4 so that they act at a fixed wavelength.
    orientation : "kf" (Escalona Eq. 39) or "madgwick" (Briales Sec. 5.2).
    trajectory : "ltv" (Escalona Eq. 46) or "ekf" (Gonzalez-Carbajal 2023 Appendix 1).
    odometry_windows : curvature-matching windows, "curve" (whole curves, anchored at their exit,
        Eq. 41 as printed) or "entry_exit" (every curve entry and exit), see
        ``trolley.tgms.odometry.match_curves``.
    odometry_method : "fused" (heading fit and Eq. 41 anchors combined into one encoder scale
        error by their variances), "heading" or "anchors" (Eq. 41 anchors and the linear re-mapping
        of Escalona Fig. 11), see ``trolley.tgms.odometry.odometry``.
    """

    process_rate_hz: float = 100.0
    gyro_noise_rad_sqrt_s: float = 4.4e-5
    gyro_bias_rw_rad_s_sqrt_s: float = 1e-6
    accel_disturbance_m_s2: float = 0.3
    madgwick_beta_rad_s: float = 3e-4
    madgwick_zeta_rad_s2: float = 1e-5
    accel_noise_m_s2_sqrt_hz: float = 3e-3
    cutoff_wavelength_m: float = 100.0
    ekf_q_angle_rad2_s3: float = 1e-3
    ekf_q_jerk_m2_s5: float = 10.0
    ekf_u_acc_m2_s4: float = 1e-3
    ekf_u_pos_m2: float = 1e-2
    orientation: str = "kf"
    trajectory: str = "ltv"
    odometry_windows: str = "curve"
    odometry_method: str = "fused"

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TgmsParams":
        """Parameters from a mapping; unknown keys are a ValueError naming them.

        Every number must be finite and within :data:`RANGE_FACTOR` times its default either way
        (an infinite cut-off or a noise of 1e300 only overflows later, far from the file)."""
        names = {f.name: f.type for f in fields(cls)}
        unknown = [k for k in d if k not in names]
        if unknown:
            raise ValueError(f"unknown parameter {unknown[0]!r}")
        kw = {}
        for k, v in d.items():
            if k in ("orientation", "trajectory", "odometry_windows", "odometry_method"):
                kw[k] = str(v)
            else:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
                    raise ValueError(f"parameter {k} must be a positive number, got {v!r}")
                default = getattr(cls, k)
                lo, hi = default / RANGE_FACTOR, default * RANGE_FACTOR
                if not lo <= v <= hi:
                    raise ValueError(f"parameter {k} must be a finite number within {lo:.3g}-{hi:.3g} "
                                     f"({RANGE_FACTOR:.0e} times the default {default:g} either way), got {v!r}")
                kw[k] = float(v)
        p = cls(**kw)
        if p.orientation not in ("kf", "madgwick"):
            raise ValueError(f"orientation must be 'kf' or 'madgwick', got {p.orientation!r}")
        if p.trajectory not in ("ltv", "ekf"):
            raise ValueError(f"trajectory must be 'ltv' or 'ekf', got {p.trajectory!r}")
        if p.odometry_windows not in ("curve", "entry_exit"):
            raise ValueError(f"odometry_windows must be 'curve' or 'entry_exit', got {p.odometry_windows!r}")
        if p.odometry_method not in ("fused", "heading", "anchors"):
            raise ValueError(f"odometry_method must be 'fused', 'heading' or 'anchors', got {p.odometry_method!r}")
        return p

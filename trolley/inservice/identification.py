"""Identification of the SM's equivalent suspension and of the filter's Q and R.

Implements Munoz et al. 2021:

* Sec. III-D, Eq. 5-6: p_opt = [kx, cx, ky, cy] by least squares between the reference (complete
  model, CM) response and the SM driven by the same alignment, ``scipy.optimize.least_squares``
  on log-parameters. Eq. 6 sums squared state errors over the channels; as y (m) and psi (rad)
  differ by orders of magnitude each channel is divided by its reference rms first.
  Besides the paper's states y, psi any measured channel (the sensors) can be a target: the
  output-error form needs only the recording and the true alignment of a surveyed track.
* Sec. IV-B, Eq. 26-29: Q = mean of e_x e_x^T with e_x,k = x_k - F x_(k-1), R = mean of
  e_z e_z^T with e_z,k = z_k - H x_k, from reference states and measurements.

References
----------
Munoz, Ros, Urda, Escalona, IEEE Access 9 (2021), Eq. 5-6, 26-29.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trolley.inservice.estimator import DiscreteModel
from trolley.inservice.model import MEASUREMENT_NAMES, STATE_NAMES, ModelParameters, simulate_response


@dataclass(frozen=True)
class IdentificationResult:
    """Identified parameters, the normalised Eq. 6 cost at the start and at the optimum."""

    params: ModelParameters
    cost_initial: float
    cost: float
    nfev: int
    channels: tuple[str, ...]


def sm_channels(p: ModelParameters, speed_m_s: float, t_s, xi_m, channels, curvature_1_m=None) -> np.ndarray:
    """Chosen channels (names in STATE_NAMES or MEASUREMENT_NAMES[:3]) of the SM response, (N, C)."""
    X, Z = simulate_response(p, speed_m_s, t_s, xi_m, curvature_1_m)
    cols = []
    for c in channels:
        if c in STATE_NAMES:
            cols.append(X[:, STATE_NAMES.index(c)])
        elif c in MEASUREMENT_NAMES[:3]:
            cols.append(Z[:, MEASUREMENT_NAMES.index(c)])
        else:
            raise ValueError(f"unknown channel {c!r}; known: {', '.join(STATE_NAMES + MEASUREMENT_NAMES[:3])}")
    return np.column_stack(cols)


def identify_suspension(p0: ModelParameters, speed_m_s: float, t_s, xi_m, reference: dict,
                        skip_s: float = 2.0, curvature_1_m=None) -> IdentificationResult:
    """Equivalent primary suspension p_opt = [kx, cx, ky, cy] by least squares (Eq. 6).

    Parameters
    ----------
    p0 : starting parameters (p_fix is kept; p_opt is the starting point).
    speed_m_s : constant forward speed of the reference run, m/s.
    t_s : (N,) uniform sample times, s.
    xi_m : (N,) true alignment under the instrumented wheelset, m.
    reference : channel name -> (N,) reference response, e.g. {"y_m": y, "psi_rad": psi} (the
        paper) or the sensor channels.
    skip_s : the first seconds (start-up transient from rest) are left out of the cost.
    curvature_1_m : design curvature (1/m) of the reference run, or None.

    Returns
    -------
    IdentificationResult
    """
    from scipy.optimize import least_squares

    channels = tuple(reference)
    t = np.asarray(t_s, float)
    ref = np.column_stack([np.asarray(reference[c], float) for c in channels])
    use = t >= t[0] + skip_s
    scale = np.sqrt(np.mean(ref[use] ** 2, axis=0))
    if np.any(scale == 0) or use.sum() < 10:
        raise ValueError("reference channels must be non-zero over more than 10 samples after skip_s")

    def resid(logp):
        p = p0.with_opt(np.exp(logp))
        r = (sm_channels(p, speed_m_s, t, xi_m, channels, curvature_1_m)[use] - ref[use]) / scale
        return r.ravel() / np.sqrt(use.sum())

    x0 = np.log(np.maximum(p0.popt, 1.0))
    r0 = resid(x0)
    sol = least_squares(resid, x0, bounds=(np.log(1e2), np.log(1e9)), x_scale=1.0, diff_step=1e-3,
                        xtol=1e-8, ftol=1e-10)
    return IdentificationResult(p0.with_opt(np.exp(sol.x)), float(r0 @ r0), float(2 * sol.cost),
                                int(sol.nfev), channels)


def covariances_from_residuals(model: DiscreteModel, X, Z):
    """Q and R from reference states and measurements (Munoz 2021 Eq. 26-29).

    Parameters
    ----------
    model : discrete SM (F, H) at the reference run's speed and sample interval.
    X : (N, 7) reference states [y, psi, y_f, y', psi', y_f', xi] (from the CM).
    Z : (N, 4) measurements [y'', psi', y_f'', 0] (sensor data with noise, virtual xi = 0).

    Returns
    -------
    Q : (7, 7) mean of e_x e_x^T, e_x,k = x_k - F x_(k-1) (Eq. 26-27).
    R : (4, 4) mean of e_z e_z^T, e_z,k = z_k - H x_k (Eq. 28-29).
    """
    X = np.asarray(X, float)
    Z = np.asarray(Z, float)
    ex = X[1:] - X[:-1] @ model.F.T
    ez = Z - X @ model.H.T
    Q = ex.T @ ex / len(ex)
    R = ez.T @ ez / len(ez)
    return 0.5 * (Q + Q.T), 0.5 * (R + R.T)

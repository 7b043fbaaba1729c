"""Analytic accuracy budget of one interval between two position fixes (Jiang 2017 Sec. 5).

The smoothed position variance along an interval of length ``T`` between two total-station
fixes, in closed form, for the vertical (Jiang 2017 Eq. 40), longitudinal (Eq. 44) and lateral
(Eq. 45) directions; its exact breakdown into sources; the inverse sizing of Fig. 6b/d/f (largest
equivalent gyro bias, angle random walk, odometer scale-factor noise, fix spacing that keep the
worst point of the interval within a target); and a Monte Carlo check of the same linear error
models (:mod:`trolley.error_models`) run through a Kalman filter and RTS smoother whose gains are
computed once and applied to all runs.

The model (read from Jiang 2017 Eq. 17-25 and 30-46)
---------------------------------------------------
All three directions share one structure (``docs/budget_derivation.md``): a position error
``r(t) = r0 + v * integral_0^t a(s) ds`` driven by an angle-like error
``a(t) = a0 - b t + W(t)`` (``a0`` the initial pitch/heading error or the odometer scale error,
``b`` the equivalent gyro bias, ``W`` a Brownian motion of PSD ``q``: the angle random walk or the
odometer scale-factor noise). ``P(0) = diag(p_r, p_a, p_b)`` is the covariance *after* the fix at
``t = 0`` (the paper's Eq. 32 and 41: its forward Riccati solution Eq. 33 starts from it with no
update at 0), and one fix of variance ``sigma_r^2`` arrives at ``t = T``. With a single scalar
measurement the smoothed variance is ``Var r(t) - Cov(r(t), z)^2 / Var z``:

    A(t) = p_r + p_a v^2 t^2 + q v^2 t^3 / 3 + p_b v^2 t^4 / 4
    C(t) = p_r + p_a v^2 t T + q v^2 (3 t^2 T - t^3) / 6 + p_b v^2 t^2 T^2 / 4
    V    = p_r + sigma_r^2 + p_a v^2 T^2 + q v^2 T^3 / 3 + p_b v^2 T^4 / 4
    p(t) = A(t) - C(t)^2 / V

which is Eq. 44 exactly and Eq. 40 and 45 with their last term corrected (Eq. 45 prints
``sigma_w^4 t (t - 4T)`` for ``sigma_w^4 t (4T - t)``; Eq. 40 in addition carries the wrong sign
on the whole last term). ``tests/test_budget_closed_forms.py`` checks this against forward filter
plus RTS and two-filter smoothers on a fine grid to 1e-6 relative, and shows the printed forms
fail that check.

With a diffuse prior before the first fix, ``p_r = sigma_r^2`` (the paper's choice for Fig. 6).

References
----------
Q. Jiang, W. Wu, M. Jiang, Y. Li, "A New Filtering and Smoothing Algorithm for Railway Track
Surveying Based on Landmark and IMU/Odometer", Sensors 17 (2017) 1438, Sec. 5, Eq. 27-46, Fig. 6.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
import scipy.optimize

from trolley import error_models as em
from trolley.sensors import OdometerFigures

DIRECTIONS = ("vertical", "lateral", "longitudinal")
SOURCES = ("initial_position", "initial_angle", "gyro_bias", "random_walk", "fix_noise")
#: what the sizable parameters are called in messages
PARAMETER_LABELS = {
    "gyro_bias_rad_s": "equivalent gyro bias",
    "gyro_bias_instability_rad_s": "gyro bias instability",
    "gyro_arw_rad_sqrt_s": "angle random walk",
    "odo_scale_noise_per_sqrt_s": "odometer scale noise",
    "fix_spacing_m": "fix spacing",
}


class TargetNotReachableError(ValueError):
    """No value of the sized parameter keeps the worst point within the target.

    Raised by the inverse sizing when the target is below what the other sources already give
    with the sized parameter at zero.
    """

    def __init__(self, parameter: str, direction: str, floor_m: float, target_m: float) -> None:
        self.parameter = parameter
        self.direction = direction
        self.floor_m = floor_m
        self.target_m = target_m
        label = PARAMETER_LABELS.get(parameter, parameter)
        zero = "a 1 nm spacing" if parameter == "fix_spacing_m" else f"no {label}"
        super().__init__(
            f"no {label} meets the {direction} target of {target_m * 1e3:.3f} mm: with "
            f"{zero} the worst point is already {floor_m * 1e3:.3f} mm")


@dataclass(frozen=True)
class BudgetCase:
    """One interval to budget, all SI. Fields may be numpy arrays that broadcast (grids).

    Attributes
    ----------
    initial : uncertainty after the first fix (Jiang 2017 Eq. 32, 41). ``position_m`` is the
        position sigma left by the fix at t=0 (the fix sigma for a diffuse prior).
    noise : angle random walk and odometer scale-factor noise (Eq. 20, 25).
    fix_sigma_m : sigma of the fix at t=T, each axis.
    speed_m_s : trolley speed v_odo.
    fix_spacing_m : distance between the fixes; T = fix_spacing_m / speed_m_s.
    """

    initial: em.InitialUncertainty
    noise: em.ChannelNoise
    fix_sigma_m: float = 0.6e-3
    speed_m_s: float = 1.0
    fix_spacing_m: float = 60.0

    @property
    def interval_s(self):
        """T, the time between the fixes."""
        return np.asarray(self.fix_spacing_m, dtype=float) / np.asarray(self.speed_m_s, dtype=float)


@dataclass(frozen=True)
class ChannelParameters:
    """The five variances of one direction in the common model ``p(t) = A - C^2 / V``.

    Attributes
    ----------
    p_r : position variance after the first fix, m^2.
    fix_var : variance of the fix at T, m^2.
    p_a : variance of the initial angle-like error (pitch, heading, odometer scale error).
    q : PSD of its random walk (ARW^2 or odometer scale-noise^2), 1/s.
    p_b : variance of the equivalent gyro bias, (rad/s)^2 (zero for the longitudinal direction).
    """

    p_r: np.ndarray
    fix_var: np.ndarray
    p_a: np.ndarray
    q: np.ndarray
    p_b: np.ndarray


def channel_parameters(case: BudgetCase, direction: str) -> ChannelParameters:
    """Map a case onto the common model for one direction (Jiang 2017 Eq. 40, 44, 45).

    Vertical: pitch error, ARW, pitch-axis equivalent bias. Lateral: heading error, ARW, yaw-axis
    equivalent bias. Longitudinal: odometer scale error and its noise, no bias.
    """
    ini, nz = case.initial, case.noise
    p_r = np.asarray(ini.position_m, dtype=float) ** 2
    fix_var = np.asarray(case.fix_sigma_m, dtype=float) ** 2
    if direction == "vertical":
        return ChannelParameters(p_r, fix_var, np.asarray(ini.pitch_rad, float) ** 2,
                                 np.asarray(nz.gyro_arw_rad_sqrt_s, float) ** 2,
                                 np.asarray(ini.gyro_bias_y_rad_s, float) ** 2)
    if direction == "lateral":
        return ChannelParameters(p_r, fix_var, np.asarray(ini.heading_rad, float) ** 2,
                                 np.asarray(nz.gyro_arw_rad_sqrt_s, float) ** 2,
                                 np.asarray(ini.gyro_bias_z_rad_s, float) ** 2)
    if direction == "longitudinal":
        return ChannelParameters(p_r, fix_var, np.asarray(ini.odo_scale_error, float) ** 2,
                                 np.asarray(nz.odo_scale_noise_per_sqrt_s, float) ** 2,
                                 np.zeros(()))
    raise ValueError(f"unknown direction {direction!r}; expected one of {DIRECTIONS}")


def _acv(t, T, v, c: ChannelParameters):
    """A(t), C(t), V of the common model (see the module docstring), broadcast."""
    v2 = np.asarray(v, dtype=float) ** 2
    A = c.p_r + v2 * (c.p_a * t**2 + c.q * t**3 / 3.0 + c.p_b * t**4 / 4.0)
    C = c.p_r + v2 * (c.p_a * t * T + c.q * (3.0 * t**2 * T - t**3) / 6.0 + c.p_b * t**2 * T**2 / 4.0)
    V = c.p_r + c.fix_var + v2 * (c.p_a * T**2 + c.q * T**3 / 3.0 + c.p_b * T**4 / 4.0)
    return A, C, V


def smoothed_variance(t, T, v, c: ChannelParameters) -> np.ndarray:
    """Smoothed position variance at time t in [0, T] (Jiang 2017 Eq. 40/44/45, corrected).

    Evaluated as the sum of :func:`variance_sources` (non-negative terms written without the
    cancellation of ``A - C^2 / V``, which loses digits when a drift term dwarfs the fix variance).

    Parameters
    ----------
    t : time since the first fix, s (any shape broadcasting with the parameters).
    T : interval between the fixes, s.
    v : speed, m/s.
    c : the direction's variances (:func:`channel_parameters`).

    Returns
    -------
    ndarray of variances, m^2.
    """
    parts = variance_sources(t, T, v, c)
    return (parts["initial_position"] + parts["initial_angle"] + parts["gyro_bias"]
            + parts["random_walk"] + parts["fix_noise"])


def smoothed_variance_direct(t, T, v, c: ChannelParameters) -> np.ndarray:
    """``A(t) - C(t)^2 / V``: the same variance in its direct (cancelling) form, for checks."""
    A, C, V = _acv(t, T, v, c)
    return A - C**2 / V


def variance_sources(t, T, v, c: ChannelParameters) -> dict[str, np.ndarray]:
    """Exact additive breakdown of :func:`smoothed_variance` into its independent sources.

    The smoothed estimate is ``g z`` with ``g = C / V``; its error ``r(t) - g (r(T) + n)`` is a sum
    of independent terms, one per source, whose variances add up to ``A - C^2 / V`` exactly:
    initial position ``(1-g)^2 p_r``, initial angle ``p_a v^2 (t - g T)^2``, gyro bias
    ``p_b v^2 (t^2 - g T^2)^2 / 4``, random walk ``Var(X_t - g X_T)`` of the integrated random
    walk ``X`` and fix noise ``g^2 sigma_r^2`` (``docs/budget_derivation.md``). ``1 - g``,
    ``t - g T`` and ``t^2 - g T^2`` are formed from their expanded numerators so that nothing
    cancels.

    Returns
    -------
    dict source name -> variance, m^2 (keys :data:`SOURCES`).
    """
    t = np.asarray(t, dtype=float)
    T = np.asarray(T, dtype=float)
    v2 = np.asarray(v, dtype=float) ** 2
    _, C, V = _acv(t, T, v, c)
    g = C / V
    u = T - t  # >= 0
    # V - C, t V - C T and t^2 V - C T^2, expanded (see docs/budget_derivation.md)
    one_minus_g = (c.fix_var + v2 * (c.p_a * T * u + c.q * u * (2 * T**2 + 2 * T * t - t**2) / 6.0
                                     + c.p_b * T**2 * u * (T + t) / 4.0)) / V
    t_minus_gT = (t * c.fix_var - u * c.p_r
                  + v2 * (c.q * T * t * u * (2 * T - t) / 6.0 + c.p_b * t * T**3 * u / 4.0)) / V
    t2_minus_gT2 = (t**2 * c.fix_var - (T**2 - t**2) * c.p_r
                    - v2 * (c.p_a * t * T**2 * u + c.q * T**2 * t**2 * u / 6.0)) / V
    # random walk: X_t - g X_T = (1-g) X_t - g (X_T - X_t), with Var X_t = q v^2 t^3/3,
    # Var(X_T - X_t) = q v^2 u^2 (T + 2t)/3, Cov(X_t, X_T - X_t) = q v^2 t^2 u / 2
    rw = c.q * v2 * (one_minus_g**2 * t**3 / 3.0 + g**2 * u**2 * (T + 2 * t) / 3.0
                     - 2.0 * g * one_minus_g * t**2 * u / 2.0)
    return {
        "initial_position": one_minus_g**2 * c.p_r,
        "initial_angle": c.p_a * v2 * t_minus_gT**2,
        "gyro_bias": c.p_b * v2 * t2_minus_gT2**2 / 4.0,
        "random_walk": rw,
        "fix_noise": g**2 * c.fix_var,
    }


def _derivatives(t, T, v, c: ChannelParameters):
    """p'(t) and p''(t) of the smoothed variance (for locating its maximum)."""
    v2 = np.asarray(v, dtype=float) ** 2
    _, C, V = _acv(t, T, v, c)
    dA = v2 * (2 * c.p_a * t + c.q * t**2 + c.p_b * t**3)
    ddA = v2 * (2 * c.p_a + 2 * c.q * t + 3 * c.p_b * t**2)
    dC = v2 * (c.p_a * T + c.q * (6 * t * T - 3 * t**2) / 6.0 + c.p_b * t * T**2 / 2.0)
    ddC = v2 * (c.q * (T - t) + c.p_b * T**2 / 2.0)
    return dA - 2 * C * dC / V, ddA - 2 * (dC**2 + C * ddC) / V


@dataclass
class WorstPoint:
    """Largest smoothed variance along the interval and where it is.

    Attributes
    ----------
    variance : m^2, shape of the broadcast parameters.
    time_s : time of the worst point since the first fix.
    """

    variance: np.ndarray
    time_s: np.ndarray


def worst_point(T, v, c: ChannelParameters, n_grid: int = 33, newton_steps: int = 6) -> WorstPoint:
    """Maximum over t in [0, T] of the smoothed variance, vectorised over parameter grids.

    ``p(t)`` is a polynomial of degree 8 in t (V does not depend on t) with at most four local
    maxima, broad on the scale of T; a grid of 33 points (direct form, cheap) brackets the largest
    and Newton steps on ``p'(t) = 0`` inside the bracketing cell find it. The value returned is
    the cancellation-free form at the better of the grid point and the Newton point.
    """
    T = np.asarray(T, dtype=float)
    s = np.linspace(0.0, 1.0, n_grid)
    shape = np.broadcast_shapes(T.shape, np.shape(v), *(np.shape(x) for x in
                                (c.p_r, c.fix_var, c.p_a, c.q, c.p_b)))
    Tb = np.broadcast_to(T, shape)[..., None]
    cb = ChannelParameters(*(np.broadcast_to(np.asarray(x, float), shape)[..., None]
                             for x in (c.p_r, c.fix_var, c.p_a, c.q, c.p_b)))
    vb = np.broadcast_to(np.asarray(v, float), shape)[..., None]
    tg = s * Tb
    pg = smoothed_variance_direct(tg, Tb, vb, cb)
    i = np.argmax(pg, axis=-1)[..., None]
    best_t = np.take_along_axis(tg, i, -1)
    lo = np.take_along_axis(tg, np.maximum(i - 1, 0), -1)
    hi = np.take_along_axis(tg, np.minimum(i + 1, n_grid - 1), -1)
    t = _newton_max(best_t, lo, hi, Tb, vb, cb, newton_steps)
    # the fixes themselves are candidates in the cancellation-free form too: where the bias
    # drift is ~1e8 times the fix sigma the direct form cancels at the ends and its grid picked
    # an inner node (0.480 mm at 8750 m of 10 km, where the fixes hold 0.600 mm: a false PASS)
    cand_t = np.concatenate([best_t, t, np.zeros_like(t), Tb], axis=-1)
    cand_p = smoothed_variance(cand_t, Tb, vb, cb)
    k = np.argmax(cand_p, axis=-1)[..., None]
    return WorstPoint(np.take_along_axis(cand_p, k, -1)[..., 0], np.take_along_axis(cand_t, k, -1)[..., 0])


def _newton_max(t, lo, hi, T, v, c: ChannelParameters, steps: int):
    """Newton steps towards a local maximum of p(t), kept inside [lo, hi]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(steps):
            d1, d2 = _derivatives(t, T, v, c)
            step = np.where(d2 < 0, d1 / d2, 0.0)
            t = np.clip(t - np.nan_to_num(step), lo, hi)
    return t


@dataclass
class DirectionBudget:
    """The budget of one direction (all SI).

    Attributes
    ----------
    mid_sigma_m, max_sigma_m : 1-sigma at mid-interval and at the worst point.
    worst_time_s : time of the worst point since the first fix.
    mid_sources_m2, max_sources_m2 : variance breakdown (:func:`variance_sources`) at those points.
    """

    mid_sigma_m: float
    max_sigma_m: float
    worst_time_s: float
    mid_sources_m2: dict[str, float]
    max_sources_m2: dict[str, float]


def direction_budget(case: BudgetCase, direction: str) -> DirectionBudget:
    """Mid-interval and worst-point sigma of one direction with their breakdowns."""
    c = channel_parameters(case, direction)
    T = float(case.interval_s)
    v = float(case.speed_m_s)
    wp = worst_point(T, v, c)
    tw = float(wp.time_s)
    mid = variance_sources(T / 2, T, v, c)
    mx = variance_sources(tw, T, v, c)
    return DirectionBudget(
        mid_sigma_m=float(np.sqrt(smoothed_variance(T / 2, T, v, c))),
        max_sigma_m=float(np.sqrt(wp.variance)),
        worst_time_s=tw,
        mid_sources_m2={k: float(x) for k, x in mid.items()},
        max_sources_m2={k: float(x) for k, x in mx.items()},
    )


def budget(case: BudgetCase) -> dict[str, DirectionBudget]:
    """:func:`direction_budget` for the three directions."""
    return {d: direction_budget(case, d) for d in DIRECTIONS}


def sigma_along(case: BudgetCase, t) -> dict[str, np.ndarray]:
    """1-sigma of each direction at the times t (s since the first fix)."""
    T, v = case.interval_s, case.speed_m_s
    return {d: np.sqrt(smoothed_variance(np.asarray(t, float), T, v, channel_parameters(case, d)))
            for d in DIRECTIONS}


# ----------------------------------------------------------------------------- inverse sizing

#: sizable parameters -> (case field setter, directions it acts on)
def _with_gyro_bias(case: BudgetCase, x: float) -> BudgetCase:
    return replace(case, initial=replace(case.initial, gyro_bias_y_rad_s=x, gyro_bias_z_rad_s=x))


def _with_arw(case: BudgetCase, x: float) -> BudgetCase:
    return replace(case, noise=replace(case.noise, gyro_arw_rad_sqrt_s=x))


def _with_odo_noise(case: BudgetCase, x: float) -> BudgetCase:
    return replace(case, noise=replace(case.noise, odo_scale_noise_per_sqrt_s=x))


def _with_fix_spacing(case: BudgetCase, x: float) -> BudgetCase:
    return replace(case, fix_spacing_m=x)


SIZABLE: dict[str, tuple[Callable[[BudgetCase, float], BudgetCase], float, float]] = {
    # name -> (setter, a starting scale for the bracket, the largest value searched), SI.
    # Beyond the cap (200 deg/h, 34 deg/sqrt(h), 1e-2/sqrt(s), 10 km) the sized term is so much
    # larger than the fix variance that A - C^2/V is lost to rounding; a limit that high is
    # reported as unbounded.
    "gyro_bias_rad_s": (_with_gyro_bias, 1e-7, 1e-3),
    "gyro_arw_rad_sqrt_s": (_with_arw, 1e-6, 1e-2),
    "odo_scale_noise_per_sqrt_s": (_with_odo_noise, 1e-5, 1e-2),
    "fix_spacing_m": (_with_fix_spacing, 10.0, 1e4),
}


def worst_sigma(case: BudgetCase, direction: str) -> float:
    """Worst 1-sigma along the interval of one direction, m."""
    c = channel_parameters(case, direction)
    return float(np.sqrt(worst_point(float(case.interval_s), float(case.speed_m_s), c).variance))


def max_allowed(case: BudgetCase, parameter: str, direction: str, target_m: float,
                xtol_rel: float = 1e-12, max_expansions: int = 200) -> float:
    """Largest value of one parameter that keeps the worst point of a direction within target.

    The worst sigma grows monotonically with each parameter (more prior variance or process
    noise can only raise the smoothed variance; a longer interval likewise), so the limit is the
    root of ``worst_sigma(x) - target``. It is bracketed from ``[0, x1]`` with ``x1`` doubled
    until the worst sigma exceeds the target, then found with ``scipy.optimize.brentq``.

    Parameters
    ----------
    case : the other inputs, held fixed.
    parameter : a key of :data:`SIZABLE`.
    direction : one of :data:`DIRECTIONS`.
    target_m : 1-sigma target.

    Returns
    -------
    The limit in SI; ``inf`` if the parameter does not raise this direction above the target
    at any value up to the cap of :data:`SIZABLE` (it does not act on it, or its effect
    saturates below the target).

    Raises
    ------
    TargetNotReachableError
        If the target is not met even with the parameter at its smallest value.
    ValueError
        For a non-positive target or an unknown parameter.
    """
    if parameter not in SIZABLE:
        raise ValueError(f"unknown parameter {parameter!r}; expected one of {sorted(SIZABLE)}")
    setter, x1, cap = SIZABLE[parameter]
    # the fix spacing cannot be zero (T = 0 has no interval); start from a tiny spacing
    x0 = 1e-9 if parameter == "fix_spacing_m" else 0.0
    return _largest_within(lambda x: worst_sigma(setter(case, x), direction), target_m, x0, x1, cap,
                           parameter, direction, xtol_rel, max_expansions)


def _largest_within(worst: Callable[[float], float], target_m: float, x0: float, x1: float, cap: float,
                    parameter: str, direction: str, xtol_rel: float = 1e-12,
                    max_expansions: int = 200) -> float:
    """Root of ``worst(x) = target`` for a worst sigma increasing in x: bracket, then brentq.

    The bracket ``[x0, hi]`` grows by doubling ``hi`` from ``x1`` until the worst sigma exceeds the
    target; ``inf`` if it does not by ``cap``. Raises :class:`TargetNotReachableError` if
    ``worst(x0)`` already reaches the target.
    """
    if not np.isfinite(target_m) or target_m <= 0:
        raise ValueError(f"target must be a positive number of metres, got {target_m!r}")

    def f(x: float) -> float:
        return worst(x) - target_m

    f0 = f(x0)
    if f0 >= 0:
        raise TargetNotReachableError(parameter, direction, f0 + target_m, target_m)
    hi = x1
    for _ in range(max_expansions):
        if f(hi) > 0:
            break
        if hi >= cap:
            return float("inf")
        x0, hi = hi, min(hi * 2.0, cap)
    else:
        return float("inf")
    x = float(scipy.optimize.brentq(f, x0, hi, xtol=1e-300, rtol=max(xtol_rel, 4 * np.finfo(float).eps)))
    # brentq's root may sit a few ulps on the failing side; the limit reported is fed back by
    # users, so it must meet the target itself (it was 1e-14 mm over and printed FAIL)
    step = 4 * np.finfo(float).eps * max(abs(x), np.finfo(float).tiny)
    while f(x) > 0 and x > x0:
        x, step = max(x - step, x0), 2.0 * step
    return x


def _linear_split(case: BudgetCase, direction: str, parameter: str):
    """Channel parameters with the sized variance x split out: c(x) = c0 + x * c1."""
    c = channel_parameters(case, direction)
    zero = np.zeros(())
    if parameter == "gyro_bias_rad_s":
        c0 = replace(c, p_b=zero)
        c1 = ChannelParameters(zero, zero, zero, zero, np.ones(()) if direction != "longitudinal" else zero)
    elif parameter == "gyro_arw_rad_sqrt_s":
        act = direction != "longitudinal"
        c0 = replace(c, q=zero) if act else c
        c1 = ChannelParameters(zero, zero, zero, np.ones(()) if act else zero, zero)
    elif parameter == "odo_scale_noise_per_sqrt_s":
        act = direction == "longitudinal"
        c0 = replace(c, q=zero) if act else c
        c1 = ChannelParameters(zero, zero, zero, np.ones(()) if act else zero, zero)
    else:
        raise ValueError(f"{parameter!r} does not enter the variances linearly; use max_allowed")
    return c0, c1


def _quadratic_root(t, T, v, c0: ChannelParameters, c1: ChannelParameters, tau2):
    """The x >= 0 with p(t; c0 + x c1) = tau^2: nan if none (target below p(t; c0)), inf if any.

    ``(A0 + x A1 - tau^2)(V0 + x V1) - (C0 + x C1)^2 = a x^2 + b x + cc`` with ``a >= 0``
    (Cauchy-Schwarz) and ``cc < 0`` when the target is reachable: one positive root, taken in the
    form ``2 (-cc) / (b + sqrt(b^2 - 4 a cc))`` that does not cancel.
    """
    A0, C0, V0 = _acv(t, T, v, c0)
    A1, C1, V1 = _acv(t, T, v, c1)
    a = A1 * V1 - C1**2
    b = (A0 - tau2) * V1 + A1 * V0 - 2 * C0 * C1
    cc = (A0 - tau2) * V0 - C0**2
    with np.errstate(divide="ignore", invalid="ignore"):
        root = 2.0 * (-cc) / (b + np.sqrt(np.maximum(b * b - 4.0 * a * cc, 0.0)))
    root = np.where(np.isnan(root) | (root < 0), np.inf, root)
    return np.where(cc >= 0, np.nan, root)


def max_allowed_grid(case: BudgetCase, parameter: str, direction: str, target_m,
                     n_grid: int = 33, polish_steps: int = 6) -> np.ndarray:
    """Vectorised :func:`max_allowed` over parameter grids (requirement curves, Fig. 6b/d/f).

    The sized variance ``x`` (bias^2, ARW^2 or scale-noise^2) enters A, C and V linearly, so at
    each t the equation ``p(t; x) = target^2`` is a quadratic in x with one positive root
    ``x*(t)`` (:func:`_quadratic_root`). The limit is ``min_t x*(t)``: a grid minimum, then
    alternating steps that move t to the worst point of ``p(.; x)`` (Newton on ``p'(t) = 0``,
    which is where ``dx*/dt = 0``) and x to ``x*(t)``. ``case`` fields may be arrays (e.g. ARW
    along one axis, fix spacing along another).

    Returns
    -------
    ndarray of limits in SI units of the parameter (bias rad/s, ARW rad/sqrt(s), noise
    1/sqrt(s)); ``nan`` where no value meets the target, ``inf`` where any value up to the
    cap of :data:`SIZABLE` does.

    Notes
    -----
    Where the target lies within about 0.1 % of the level at which the parameter's effect
    saturates (a gyro bias the fixes estimate, say), the target is exceeded only in a narrow
    window of t around the worst point; the grid may miss it and report ``inf`` where
    :func:`max_allowed` finds the finite (and ill-conditioned) limit.
    """
    c0, c1 = _linear_split(case, direction, parameter)
    T = np.asarray(case.interval_s, dtype=float)
    v = np.asarray(case.speed_m_s, dtype=float)
    tau2 = np.asarray(target_m, dtype=float) ** 2
    shape = np.broadcast_shapes(T.shape, v.shape, tau2.shape, *(np.shape(x) for x in
                                (c0.p_r, c0.fix_var, c0.p_a, c0.q, c0.p_b)))
    # trailing axis for the t grid; leave the parameters unbroadcast (fewer, smaller temporaries)
    ex = lambda x: np.asarray(x, float)[..., None]  # noqa: E731
    Tb, vb, tb2 = ex(T), ex(v), ex(tau2)
    cb0 = ChannelParameters(*(ex(x) for x in (c0.p_r, c0.fix_var, c0.p_a, c0.q, c0.p_b)))
    cb1 = ChannelParameters(*(ex(x) for x in (c1.p_r, c1.fix_var, c1.p_a, c1.q, c1.p_b)))
    tg = np.broadcast_to(np.linspace(0.0, 1.0, n_grid) * Tb, shape + (n_grid,))
    root = np.broadcast_to(_quadratic_root(tg, Tb, vb, cb0, cb1, tb2), shape + (n_grid,))
    infeasible = np.isnan(root).any(axis=-1)[..., None]
    rootf = np.where(np.isnan(root), np.inf, root)
    i = np.argmin(rootf, axis=-1)[..., None]
    x = np.take_along_axis(rootf, i, -1)
    t = np.take_along_axis(tg, i, -1)
    lo = np.take_along_axis(tg, np.maximum(i - 1, 0), -1)
    hi = np.take_along_axis(tg, np.minimum(i + 1, n_grid - 1), -1)
    finite = np.isfinite(x) & ~infeasible
    for _ in range(polish_steps):
        xs = np.where(finite, x, 0.0)
        cx = ChannelParameters(*(p0 + xs * p1 for p0, p1 in zip(
            (cb0.p_r, cb0.fix_var, cb0.p_a, cb0.q, cb0.p_b), (cb1.p_r, cb1.fix_var, cb1.p_a, cb1.q, cb1.p_b))))
        t_new = _newton_max(t, lo, hi, Tb, vb, cx, 2)
        x_new = _quadratic_root(t_new, Tb, vb, cb0, cb1, tb2)
        # x*(t) is minimal where p(.; x) peaks: accept only steps that lower the limit
        take = finite & np.isfinite(x_new) & (x_new < x)
        x = np.where(take, x_new, x)
        t = np.where(take, t_new, t)
    # the quadratic carries the cancellation of A V - C^2; two Newton steps in x on the
    # cancellation-free p(t; x) = tau^2 at the worst t remove it
    for _ in range(2):
        xs = np.where(finite, x, 0.0)
        cx = ChannelParameters(*(p0 + xs * p1 for p0, p1 in zip(
            (cb0.p_r, cb0.fix_var, cb0.p_a, cb0.q, cb0.p_b), (cb1.p_r, cb1.fix_var, cb1.p_a, cb1.q, cb1.p_b))))
        A, C, V = _acv(t, Tb, vb, cx)
        A1, C1, V1 = _acv(t, Tb, vb, cb1)
        dp = A1 - 2 * C * C1 / V + C**2 * V1 / V**2
        with np.errstate(divide="ignore", invalid="ignore"):
            step = (smoothed_variance(t, Tb, vb, cx) - tb2) / dp
        x = np.where(finite & (dp > 0) & np.isfinite(step), x - step, x)
    x = np.where(infeasible, np.nan, x)[..., 0]
    x = np.sqrt(x)
    return np.where(x > SIZABLE[parameter][2], np.inf, x)


# ----------------------------------------------------------------------------- Monte Carlo

@dataclass
class MonteCarloResult:
    """RMS of the smoothed position error over simulated intervals beside the analytic sigma.

    Attributes
    ----------
    runs : number of simulated intervals.
    times_s : (K,) node times.
    rms_m : direction -> (K,) RMS of the smoothed error over the runs.
    sigma_m : direction -> (K,) analytic 1-sigma at the nodes.
    mid_index, worst_index : direction -> node index of mid-interval and of the analytic worst point.
    block_runs : runs simulated at once (memory cap, :func:`monte_carlo_block_runs`).
    """

    runs: int
    times_s: np.ndarray
    rms_m: dict[str, np.ndarray]
    sigma_m: dict[str, np.ndarray]
    mid_index: int
    worst_index: dict[str, int] = field(default_factory=dict)
    block_runs: int = 0

    def relative_sampling_error(self) -> float:
        """1-sigma relative error of an RMS over ``runs`` Gaussian samples, ~1/sqrt(2N)."""
        return 1.0 / np.sqrt(2.0 * self.runs)


def _sqrt_psd(Q: np.ndarray) -> np.ndarray:
    """A square root L with L L^T = Q for a positive semidefinite (possibly singular) Q."""
    w, U = np.linalg.eigh(Q)
    return U * np.sqrt(np.clip(w, 0.0, None))[..., None, :]


def _gains(F, Q, P0, H, R, fix_nodes, scale):
    """Kalman gains at the fix nodes and RTS gains, from one covariance run (shared by all runs).

    Uses the existing forward filter for the covariances; the RTS gain is
    ``C_k = P_post[k] F_k^T P_prior[k+1]^-1`` (Jiang 2017 Eq. 28), formed in scaled states.
    """
    from trolley.smoothers import Measurements, forward_filter

    K = F.shape[0] + 1
    n = P0.shape[0]
    m = H.shape[0]
    meas = Measurements(np.asarray(fix_nodes), np.zeros((len(fix_nodes), m)), H, R)
    fwd = forward_filter(F, Q, np.zeros(n), P0, meas, gate_probability=None)
    d = scale
    Pp = fwd.P_prior / d[None, :, None] / d[None, None, :]
    Pf = fwd.P_post / d[None, :, None] / d[None, None, :]
    Fs = F / d[None, :, None] * d[None, None, :]
    # Pf F^T Pp^+ : the pseudo-inverse because a state with zero variance (a bias set to 0)
    # keeps Pp singular; in scaled states its other eigenvalues are O(1)
    C = Pf[:-1] @ np.swapaxes(Fs, -1, -2) @ np.linalg.pinv(Pp[1:], hermitian=True)
    C = C / d[None, None, :] * d[None, :, None]  # back to SI: D C' D^-1
    Kg = {}
    for k in fix_nodes:
        S = H @ fwd.P_prior[k] @ H.T + R
        Kg[int(k)] = fwd.P_prior[k] @ H.T @ np.linalg.inv(S)
    return Kg, C


#: memory for the simulated runs of one Monte Carlo block (the arrays of nodes x states x runs)
MONTE_CARLO_MEMORY_BYTES = 256 * 2**20
#: nodes of a simulated interval at most (its grid step grows beyond dt_s for longer intervals)
MONTE_CARLO_MAX_NODES = 20_000
#: float64 arrays of nodes x runs alive at once per simulated run: in :meth:`_Channel.errors` the
#: truth, its process noise (and the draw it is made from), the predicted, filtered and smoothed
#: states and their difference (7 x 5 level states, the 3 vertical errors kept meanwhile), plus
#: the three rotated direction errors and one square
_MC_ARRAYS_PER_NODE_RUN = 7 * len(em.LEVEL_STATES) + len(em.VERTICAL_STATES) + 4


def monte_carlo_block_runs(nodes: int, memory_bytes: int = MONTE_CARLO_MEMORY_BYTES) -> int:
    """Runs per Monte Carlo block so that its arrays of ``nodes`` x states x runs fit the memory.

    At least 1 (a single run of a very long interval may exceed ``memory_bytes``).
    """
    per_run = 8 * int(nodes) * _MC_ARRAYS_PER_NODE_RUN
    return max(1, int(memory_bytes) // per_run)


def monte_carlo(case: BudgetCase, runs: int, dt_s: float = 1.0, heading_rad: float = 0.3,
                seed: int | None = None, memory_bytes: int = MONTE_CARLO_MEMORY_BYTES,
                prior_position_m: float | None = None,
                progress: Callable[[str, float], None] | None = None) -> MonteCarloResult:
    """Monte Carlo of the budget: simulate ``runs`` intervals of the linear error models.

    Both channels of :mod:`trolley.error_models` (vertical, and level at heading ``heading_rad``)
    are discretised exactly with :func:`trolley.error_models.van_loan` on a grid of ``dt_s``;
    the truth starts from ``P(0)`` of the case (after the first fix), the fix at T is simulated
    with the fix sigma, and a Kalman filter plus RTS smoother with gains shared by all runs
    estimates the errors. The level errors are rotated to longitudinal and lateral (Eq. 43).
    Runs are processed in blocks sized so that the block's arrays (nodes x states x runs,
    :func:`monte_carlo_block_runs`) stay within ``memory_bytes``: a long interval with many runs
    takes more blocks, not more memory. The random draws depend on the block size, so a seed
    reproduces a result for the same ``memory_bytes``.

    With ``prior_position_m`` the first fix is simulated too: the true position starts with that
    sigma and a fix arrives at t = 0 as well; the case's ``initial.position_m`` must then be the
    sigma after that fix, ``sqrt(p s^2 / (p + s^2))`` (see ``docs/budget_derivation.md``), for
    the analytic sigma to apply. This checks the reading of P(0) by simulation.

    ``progress(step, fraction)``, when given, is called after each pass (truth, filter, smoother)
    of each channel of each block with the fraction of the work done (the CLI's progress bar);
    it does not change the random draws.

    Returns
    -------
    MonteCarloResult
    """
    if runs < 2:
        raise ValueError("a Monte Carlo needs at least 2 runs")
    rng = np.random.default_rng(seed)
    T = float(case.interval_s)
    # a very long, slow interval gets a coarser grid, not gigabytes: the discretisation is exact
    # (van_loan) at any step, only the profile is sampled more sparsely (bug hunt 2026-11-26:
    # 10 km at 0.01 m/s, 1e6 nodes, took 2.7 GB past the block cap with its per-node gains)
    K = min(int(np.ceil(T / dt_s - 1e-9)) + 1, MONTE_CARLO_MAX_NODES)
    # an even number of steps puts a node at T/2, where the "mid" figure is compared with the
    # analytic mid-interval sigma (it was the node nearest T/2: 0.447 against 0.424 mm for T = 2.5 s)
    if (K - 1) % 2:
        K = K + 1 if K < MONTE_CARLO_MAX_NODES else K - 1
    dt = T / (K - 1)
    v = float(case.speed_m_s)
    ini, nz = case.initial, case.noise
    fix_var = float(case.fix_sigma_m) ** 2
    paper_noise = replace(nz, gyro_bias_rw_rad_s_sqrt_s=0.0)
    Av, Gv = em.vertical_matrices(v)
    Fv, Qv = em.van_loan(Av, Gv, em.vertical_noise_psd(paper_noise), dt)
    fix_nodes = [K - 1]
    if prior_position_m is not None:
        ini = replace(ini, position_m=prior_position_m)
        fix_nodes = [0, K - 1]
    P0v = em.vertical_initial_covariance(ini)
    Al, Gl = em.level_matrices(v * np.cos(heading_rad), v * np.sin(heading_rad))
    Fl, Ql = em.van_loan(Al, Gl, em.level_noise_psd(paper_noise), dt)
    P0l = em.level_initial_covariance(ini)
    vert = _Channel(Fv, Qv, P0v, em.VERTICAL_H, np.array([[fix_var]]), K, fix_nodes)
    level = _Channel(Fl, Ql, P0l, em.LEVEL_H, np.eye(2) * fix_var, K, fix_nodes)
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    sumsq = {d: np.zeros(K) for d in DIRECTIONS}
    block = monte_carlo_block_runs(K, memory_bytes)
    done = 0
    while done < runs:
        n = min(block, runs - done)
        if progress is None:
            ev = vert.errors(rng, n)
            el = level.errors(rng, n)
        else:
            def tick(channel: int, f: float, done=done, n=n) -> None:
                progress(f"Monte Carlo, runs {done + 1}-{done + n} of {runs}", (done + n * (channel + f) / 2) / runs)

            ev = vert.errors(rng, n, lambda f: tick(0, f))
            el = level.errors(rng, n, lambda f: tick(1, f))
        err = {"vertical": ev[..., 0],
               "longitudinal": c * el[..., 0] + s * el[..., 1],
               "lateral": -s * el[..., 0] + c * el[..., 1]}
        for d in DIRECTIONS:
            sumsq[d] += np.sum(err[d] ** 2, axis=1)
        done += n
    times = np.arange(K) * dt
    sig = sigma_along(case, times)
    rms = {d: np.sqrt(sumsq[d] / runs) for d in DIRECTIONS}
    mid = (K - 1) // 2
    worst = {d: int(np.argmax(sig[d])) for d in DIRECTIONS}
    return MonteCarloResult(runs, times, rms, sig, mid, worst, block)


class _Channel:
    """One channel of the Monte Carlo: its model and the gains shared by all runs.

    ``fix_nodes`` are the nodes with a position fix: ``[K-1]`` (P0 after the first fix, the
    paper's reading) or ``[0, K-1]`` (P0 a prior before the first fix).
    """

    def __init__(self, F1, Q1, P0, H, R, K, fix_nodes):
        self.F1, self.Q1, self.P0, self.H, self.R, self.K = F1, Q1, P0, H, R, K
        self.fix_nodes = [int(k) for k in fix_nodes]
        F = np.repeat(F1[None], K - 1, 0)
        Q = np.repeat(Q1[None], K - 1, 0)
        self.Kg, self.C = _gains(F, Q, P0, H, R, self.fix_nodes, _safe_scale(P0, Q1))
        self.L0, self.LQ, self.LR = _sqrt_psd(P0), _sqrt_psd(Q1), _sqrt_psd(R)

    def errors(self, rng, runs: int, tick: Callable[[float], None] | None = None) -> np.ndarray:
        """Smoothed minus true states, (K, runs, n), for ``runs`` fresh intervals.

        Truth: x0 ~ N(0, P0), x[k+1] = F x[k] + w, fixes z = H x[k] + n at the fix nodes. The
        loops run over the nodes; the runs are a batch axis of matrix products with the gains
        computed once. ``tick(fraction)``, when given, is called after the truth, the filter and
        the smoother pass (1/3, 2/3, 1).
        """
        tick = tick if tick is not None else (lambda f: None)
        K, F1, H = self.K, self.F1, self.H
        n = self.P0.shape[0]
        m = H.shape[0]
        x = np.empty((K, runs, n))
        x[0] = rng.standard_normal((runs, n)) @ self.L0.T
        w = rng.standard_normal((K - 1, runs, n)) @ self.LQ.T
        for k in range(K - 1):
            x[k + 1] = x[k] @ F1.T + w[k]
        z = {k: x[k] @ H.T + rng.standard_normal((runs, m)) @ self.LR.T for k in self.fix_nodes}
        tick(1 / 3)
        # forward filter (prior mean zero) and RTS: x_s[k] = x_f[k] + C_k (x_s[k+1] - x_pred[k+1])
        x_pred = np.empty_like(x)
        x_filt = np.empty_like(x)
        for k in range(K):
            x_pred[k] = 0.0 if k == 0 else x_filt[k - 1] @ F1.T
            x_filt[k] = x_pred[k]
            if k in z:
                x_filt[k] = x_pred[k] + (z[k] - x_pred[k] @ H.T) @ self.Kg[k].T
        tick(2 / 3)
        xs = np.empty_like(x)
        xs[-1] = x_filt[-1]
        for k in range(K - 2, -1, -1):
            xs[k] = x_filt[k] + (xs[k + 1] - x_pred[k + 1]) @ self.C[k].T
        tick(1.0)
        return xs - x


def _safe_scale(P0: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """State scaling for the gain computation: sqrt(diag P0), or of Q where P0 has a zero."""
    d = np.sqrt(np.diag(P0))
    alt = np.sqrt(np.diag(Q))
    d = np.where(d > 0, d, alt)
    return np.where(d > 0, d, 1.0)


# ----------------------------------------------------------------------------- from datasheet figures

#: per direction, the generic sources of :func:`variance_sources` under the names people use
SOURCE_NAMES: dict[str, dict[str, str]] = {
    "vertical": {"initial_position": "initial_position", "initial_angle": "level_error",
                 "gyro_bias": "gyro_bias", "random_walk": "angle_random_walk", "fix_noise": "fix_noise"},
    "lateral": {"initial_position": "initial_position", "initial_angle": "heading_error",
                "gyro_bias": "gyro_bias", "random_walk": "angle_random_walk", "fix_noise": "fix_noise"},
    "longitudinal": {"initial_position": "initial_position", "initial_angle": "odo_scale_error",
                     "random_walk": "odo_scale_noise", "fix_noise": "fix_noise"},
}


#: Odometer scale-factor error at the start of an interval, the budget's default: 0. Deliberately
#: not ``trolley.sensors.OdometerFigures.scale_error`` (1e-4, the engine's prior before any fix):
#: in a survey the fixes of the preceding intervals estimate the constant scale error (the level
#: channel is observable, Jiang 2017 Eq. 26), and the paper's Sec. 5 analysis treats it so: its
#: Fig. 6f odometer limit of about 1.1e-5/sqrt(s) is reproduced with 0 (1.110e-5), not with
#: Eq. 46's 0.002 deg (9.30e-6) or 1e-4 (7.98e-6). ``--odo-scale-error`` sets a residual.
BUDGET_ODO_SCALE_ERROR = 0.0


@dataclass(frozen=True)
class SensorFigures:
    """What an engineer knows before buying, all SI (the edges convert with trolley.units).

    Exactly one of ``equivalent_gyro_bias_rad_s`` (the equivalent bias of Jiang 2017 Eq. 15-16,
    used as given) and ``gyro_bias_instability_rad_s`` (the datasheet figure, from which the
    equivalent bias is derived) must be set.

    Attributes
    ----------
    gyro_arw_rad_sqrt_s : angle random walk.
    equivalent_gyro_bias_rad_s : equivalent gyro bias, used as given.
    gyro_bias_instability_rad_s : datasheet bias instability.
    heading_error_rad : initial heading error; None: from a gyrocompassing alignment.
    level_error_rad : initial equivalent level (pitch) error, Jiang 2017 Sec. 5: 0.005 deg.
    odo_scale_noise_per_sqrt_s : odometer scale-factor noise (PSD root); default the odometer of
        :class:`trolley.sensors.OdometerFigures` (8e-6, Jiang 2017 Eq. 46).
    odo_scale_error : odometer scale-factor error left after calibration (constant over the
        interval); default :data:`BUDGET_ODO_SCALE_ERROR`.
    fix_spacing_m, speed_m_s, fix_sigma_m : the interval.
    latitude_rad : site latitude (Earth-rate projection, gyrocompassing).
    gyrocompassing : whether the IMU can find north by itself (False: heading_error_rad required).
    """

    gyro_arw_rad_sqrt_s: float
    equivalent_gyro_bias_rad_s: float | None = None
    gyro_bias_instability_rad_s: float | None = None
    heading_error_rad: float | None = None
    level_error_rad: float = 0.005 * np.pi / 180.0
    odo_scale_noise_per_sqrt_s: float = OdometerFigures.scale_noise_per_sqrt_s
    odo_scale_error: float = BUDGET_ODO_SCALE_ERROR
    fix_spacing_m: float = 60.0
    speed_m_s: float = 1.0
    fix_sigma_m: float = 0.6e-3
    latitude_rad: float = 30.0 * np.pi / 180.0
    gyrocompassing: bool = True


@dataclass(frozen=True)
class ResolvedCase:
    """A budget case with the record of how its equivalent bias and heading error were found.

    Attributes
    ----------
    case : the case to evaluate.
    equivalent_gyro_bias_rad_s : the equivalent bias used for both gyro axes.
    heading_error_rad : the heading error used.
    bias_route : "given" (equivalent bias as given) or "derived" (from the bias instability).
    heading_route : "given" or "gyrocompassing".
    explanation : one sentence saying how, for the user.
    """

    case: BudgetCase
    equivalent_gyro_bias_rad_s: float
    heading_error_rad: float
    bias_route: str
    heading_route: str
    explanation: str


def resolve_case(fig: SensorFigures) -> ResolvedCase:
    """Build the budget case from sensor figures (Jiang 2017 Eq. 6 and the text after Fig. 6).

    Derived route: the heading error is the given one, or that of a gyrocompassing alignment with
    the bias instability (``BI / (omega_ie cos L)``); the equivalent bias is
    :func:`trolley.error_models.equivalent_gyro_bias` ``= BI + omega_ie cos(L) |phi_D|``. Given
    route: the equivalent bias is used as is and a missing heading error comes from
    gyrocompassing with it (the paper's convention for Fig. 6). The paper applies one equivalent
    bias to both gyro axes; so does this function (per Eq. 6 the heading term belongs to the
    pitch axis, so the lateral figure is conservative: ``docs/budget.md``).

    The initial position sigma is the fix sigma (diffuse prior before the first fix).

    Raises
    ------
    ValueError
        For missing, contradictory, negative or non-finite figures, or a zero speed or spacing.
    """
    given = fig.equivalent_gyro_bias_rad_s is not None
    derived = fig.gyro_bias_instability_rad_s is not None
    if given == derived:
        raise ValueError("give exactly one of the equivalent gyro bias and the gyro bias instability")
    checks = {
        "gyro angle random walk": fig.gyro_arw_rad_sqrt_s,
        "gyro bias": fig.equivalent_gyro_bias_rad_s if given else fig.gyro_bias_instability_rad_s,
        "level error": fig.level_error_rad,
        "odometer scale noise": fig.odo_scale_noise_per_sqrt_s,
        "odometer scale error": fig.odo_scale_error,
        "fix sigma": fig.fix_sigma_m,
    }
    if fig.heading_error_rad is not None:
        checks["heading error"] = fig.heading_error_rad
    for name, x in checks.items():
        if not np.isfinite(x) or x < 0:
            raise ValueError(f"{name} must be a finite number >= 0, got {x!r}")
    for name, x in (("speed", fig.speed_m_s), ("fix spacing", fig.fix_spacing_m), ("fix sigma", fig.fix_sigma_m)):
        if not np.isfinite(x) or x <= 0:
            raise ValueError(f"{name} must be a finite number > 0, got {x!r}")
    if not np.isfinite(fig.latitude_rad) or abs(fig.latitude_rad) >= np.pi / 2:
        raise ValueError("latitude must lie strictly between -90 and 90 degrees (gyrocompassing needs cos L > 0)")
    bias_in = fig.equivalent_gyro_bias_rad_s if given else fig.gyro_bias_instability_rad_s
    if fig.heading_error_rad is not None:
        heading, heading_route = float(fig.heading_error_rad), "given"
    else:
        if not fig.gyrocompassing:
            raise ValueError("this IMU cannot find north by gyrocompassing: give the heading error")
        heading = abs(em.heading_error_from_gyrocompassing(bias_in, fig.latitude_rad))
        heading_route = "gyrocompassing"
    if given:
        bias = float(bias_in)
        how = "equivalent gyro bias used as given (Jiang 2017 Eq. 15-16)"
    else:
        bias = float(em.equivalent_gyro_bias(bias_in, heading, fig.latitude_rad))
        how = ("equivalent gyro bias = bias instability + Earth rate x cos(latitude) x |heading error| "
               "(Jiang 2017 Eq. 6, text after Fig. 6)")
    if heading_route == "gyrocompassing":
        how += "; heading error from gyrocompassing = bias / (Earth rate x cos(latitude))"
    ini = em.InitialUncertainty(position_m=fig.fix_sigma_m, pitch_rad=fig.level_error_rad,
                                heading_rad=heading, gyro_bias_y_rad_s=bias, gyro_bias_z_rad_s=bias,
                                odo_scale_error=fig.odo_scale_error)
    noise = em.ChannelNoise(fig.gyro_arw_rad_sqrt_s, fig.odo_scale_noise_per_sqrt_s)
    case = BudgetCase(ini, noise, fig.fix_sigma_m, fig.speed_m_s, fig.fix_spacing_m)
    return ResolvedCase(case, bias, heading, "given" if given else "derived", heading_route, how)


def with_gyro_bias_instability(fig: SensorFigures, bias_instability_rad_s: float) -> BudgetCase:
    """The case of ``fig`` with another datasheet bias instability, re-resolved.

    :func:`resolve_case` runs again, so everything that follows the bias instability follows it:
    the equivalent bias (Jiang 2017 Eq. 6) and, without a given heading error, the
    gyrocompassing heading error ``BI / (omega_ie cos L)``. A given heading error stays.
    """
    return resolve_case(replace(fig, equivalent_gyro_bias_rad_s=None,
                                gyro_bias_instability_rad_s=bias_instability_rad_s)).case


def max_gyro_bias_instability(fig: SensorFigures, direction: str, target_m: float) -> float:
    """Largest datasheet bias instability keeping the worst point of a direction within target.

    Not the equivalent-bias limit of :func:`max_allowed` minus the Earth-rate term at the current
    heading error: with a gyrocompassing heading the heading error grows with the bias
    instability, so the equivalent bias is ``2 BI`` and the lateral heading error term grows too.
    The case is re-resolved at each trial value (:func:`with_gyro_bias_instability`) and the root
    found by the bracketing search of :func:`max_allowed`.

    Returns
    -------
    The limit in rad/s; ``inf`` if none up to the cap of the equivalent bias (200 deg/h) exceeds
    the target.

    Raises
    ------
    TargetNotReachableError
        If even a perfect gyro (zero bias instability) misses the target.
    ValueError
        If ``fig`` gives the equivalent bias (no bias instability to size) or a bad target.
    """
    if fig.gyro_bias_instability_rad_s is None:
        raise ValueError("the bias instability is sized on the derived route only (figures give the equivalent bias)")
    _, x1, cap = SIZABLE["gyro_bias_rad_s"]
    return _largest_within(lambda x: worst_sigma(with_gyro_bias_instability(fig, x), direction), target_m,
                           0.0, x1, cap, "gyro_bias_instability_rad_s", direction)


def perfect_imu_floor(resolved: ResolvedCase) -> dict[str, float]:
    """Worst 1-sigma of vertical and lateral with a perfect gyro (no bias, no ARW).

    The heading error is kept if it was given, zeroed if it came from the gyro (gyrocompassing).
    A target below this cannot be met by any IMU.
    """
    case = resolved.case
    heading = case.initial.heading_rad if resolved.heading_route == "given" else 0.0
    ideal = replace(case, initial=replace(case.initial, gyro_bias_y_rad_s=0.0, gyro_bias_z_rad_s=0.0,
                                          heading_rad=heading),
                    noise=replace(case.noise, gyro_arw_rad_sqrt_s=0.0))
    return {d: worst_sigma(ideal, d) for d in ("vertical", "lateral")}

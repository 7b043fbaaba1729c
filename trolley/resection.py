"""Free-station resection on CPIII control points, and the polar observation model it rests on.

A total station set up anywhere near the track measures horizontal directions, zenith angles and
slope distances to three or more CPIII prisms of known grid coordinates (eight, four pairs, is the
Chinese practice). A weighted least-squares adjustment (Gauss-Newton through
``scipy.optimize.least_squares`` with the analytic Jacobian) gives the station position E, N, H and
the orientation of the horizontal circle, their covariance, per-point residuals and the a posteriori
sigma0. Outliers are found by Baarda's data snooping: each observation's residual divided by its own
sigma, sqrt(q_vv), gives a standardized residual w ~ N(0, 1); a point whose largest |w| exceeds the
tolerance is flagged. Nothing is dropped automatically: the crew decides, ``suggest_point_to_drop``
names the candidate, and ``resect(..., exclude=...)`` recomputes without it.

Conventions (``docs/conventions.md``, section "Total station"):

- grid E, N, H (H up); azimuth clockwise from grid north, ``az = atan2(dE, dN)``;
- ``hz`` horizontal circle reading, clockwise, ``hz = az - orientation`` in [0, 2 pi): the
  orientation unknown is the grid azimuth of the circle's zero direction;
- ``zenith`` from the zenith (pi/2 = horizontal), face I; face II must be reduced beforehand;
- slope distance from the instrument's axis point to the prism, already corrected for prism
  constant and atmosphere; the station height H is the height of the instrument's axis point;
- Earth curvature and refraction (coefficient k) lower the apparent height difference by
  (1 - k) hd^2 / (2 R), as instruments model it; it is 0.5 mm at 90 m and can be switched off.

References
----------
Ghilani, C. D. (2017). Adjustment Computations, 6th ed., ch. 15 (resection), ch. 21 (blunder
detection). Baarda, W. (1968). A testing procedure for use in geodetic networks.
"""
from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.optimize import least_squares

from trolley import units

TWO_PI = 2.0 * np.pi


class ResectionError(ValueError):
    """The resection cannot be computed (too few points, bad geometry, inconsistent input)."""


@dataclass(frozen=True)
class InstrumentSigmas:
    """A priori 1-sigma of one total-station observation.

    Attributes
    ----------
    direction_rad : horizontal direction (default 0.5 arc second).
    zenith_rad : zenith angle (default 0.5 arc second).
    distance_m : constant part of the distance sigma (default 0.6 mm).
    distance_scale : part proportional to the distance (default 1 ppm = 1e-6).
    """

    direction_rad: float = units.arcsec_to_rad(0.5)
    zenith_rad: float = units.arcsec_to_rad(0.5)
    distance_m: float = 0.0006
    distance_scale: float = 1e-6

    def distance_sigma_m(self, distance_m: np.ndarray) -> np.ndarray:
        """Sigma of slope distances ``distance_m`` (constant + ppm part, added linearly as datasheets do)."""
        return self.distance_m + self.distance_scale * np.abs(np.asarray(distance_m, dtype=float))


@dataclass(frozen=True)
class PolarModel:
    """Earth curvature and refraction in the polar observation model.

    Attributes
    ----------
    refraction_k : coefficient of refraction (0.13 is the usual instrument default).
    earth_radius_m : radius of the Earth used for the curvature term.
    curvature_refraction : apply the (1 - k) hd^2 / (2 R) height correction.
    grid_scale : grid distance / horizontal distance measured: the projection scale factor
        times the height reduction of the project grid (1.0 when the grid is a low-distortion
        one; 10 ppm off is 1 mm at 100 m).
    """

    refraction_k: float = 0.13
    earth_radius_m: float = 6.378e6
    curvature_refraction: bool = True
    grid_scale: float = 1.0

    @property
    def height_drop_per_m2(self) -> float:
        """c in dH_apparent = dH - c hd^2, in 1/m."""
        if not self.curvature_refraction:
            return 0.0
        return (1.0 - self.refraction_k) / (2.0 * self.earth_radius_m)


@dataclass(frozen=True)
class ResectionConfig:
    """Weights, model and outlier tolerance of a free-station resection.

    Attributes
    ----------
    sigmas : a priori instrument sigmas.
    model : curvature and refraction model (must match the one the observations follow).
    max_standardized_residual : flag a point when one of its observations has |w| above this
        (3.29 is the two-sided 0.1 % critical value of data snooping).
    max_point_residual_m : flag a point when its residual across, along or in height exceeds this
        (None: no metric tolerance).
    """

    sigmas: InstrumentSigmas = field(default_factory=InstrumentSigmas)
    model: PolarModel = field(default_factory=PolarModel)
    max_standardized_residual: float = 3.29
    max_point_residual_m: float | None = 0.002


@dataclass
class PolarObservations:
    """Polar observations from one station, one row per pointing (face I).

    A NaN marks an observation that was not taken (e.g. a direction without distance).
    """

    hz_rad: np.ndarray
    zenith_rad: np.ndarray
    slope_distance_m: np.ndarray

    def __post_init__(self) -> None:
        self.hz_rad = np.atleast_1d(np.asarray(self.hz_rad, dtype=float))
        self.zenith_rad = np.atleast_1d(np.asarray(self.zenith_rad, dtype=float))
        self.slope_distance_m = np.atleast_1d(np.asarray(self.slope_distance_m, dtype=float))
        if not (self.hz_rad.shape == self.zenith_rad.shape == self.slope_distance_m.shape):
            raise ResectionError("hz, zenith and slope distance arrays differ in length")

    def __len__(self) -> int:
        return int(self.hz_rad.shape[0])

    def as_array(self) -> np.ndarray:
        """(n, 3) array of hz, zenith, slope distance."""
        return np.column_stack([self.hz_rad, self.zenith_rad, self.slope_distance_m])


@dataclass(frozen=True)
class PointResidual:
    """Residuals of one pointing (observed minus computed from the adjusted station).

    Attributes
    ----------
    point_id : CPIII point id.
    hz_rad, zenith_rad, distance_m : residuals of the three observations (NaN if not observed).
    across_m, along_m, height_m : the same residuals as a displacement of the target: horizontal
        across the line of sight (positive to the right seen from the station), horizontal along
        it (positive away from the station) and up.
    standardized : |w| of hz, zenith, distance (NaN if not observed or no redundancy).
    max_standardized : largest |w| of the three.
    flagged : the point exceeds a tolerance of the configuration.
    reason : why it is flagged ("" when not).
    """

    point_id: str
    hz_rad: float
    zenith_rad: float
    distance_m: float
    across_m: float
    along_m: float
    height_m: float
    standardized: tuple[float, float, float]
    max_standardized: float
    flagged: bool
    reason: str


@dataclass(frozen=True)
class Resection:
    """Result of a free-station resection.

    Attributes
    ----------
    station_enh_m : (3,) E, N, H of the instrument's axis point.
    orientation_rad : grid azimuth of the horizontal circle's zero, in [0, 2 pi).
    covariance : (4, 4) a priori covariance of (E, N, H, orientation) (instrument sigmas trusted).
    sigma0 : a posteriori standard deviation of unit weight (1 when the sigmas are right).
    dof : degrees of freedom (observations minus 4).
    residuals : one entry per pointing, in input order (excluded points are not listed).
    excluded : point ids left out of this solution.
    """

    station_enh_m: np.ndarray
    orientation_rad: float
    covariance: np.ndarray
    sigma0: float
    dof: int
    residuals: tuple[PointResidual, ...]
    excluded: tuple[str, ...] = ()

    @property
    def covariance_aposteriori(self) -> np.ndarray:
        """Covariance scaled by sigma0^2 (when dof > 0)."""
        return self.covariance * (self.sigma0**2 if self.dof > 0 else 1.0)

    @property
    def setup_covariance(self) -> np.ndarray:
        """The covariance of (E, N, H, orientation) to carry to the points measured from this setup:
        the a priori one scaled by :func:`variance_factor` (sigma0^2 when sigma0 > 1)."""
        return self.covariance * variance_factor(self.sigma0, self.dof)

    @property
    def station_sigma_m(self) -> np.ndarray:
        """(3,) a priori 1-sigma of E, N, H."""
        return np.sqrt(np.diag(self.covariance)[:3])

    @property
    def orientation_sigma_rad(self) -> float:
        """A priori 1-sigma of the orientation."""
        return float(np.sqrt(self.covariance[3, 3]))

    @property
    def flagged_points(self) -> tuple[str, ...]:
        """Ids of flagged points, worst first."""
        bad = [r for r in self.residuals if r.flagged]
        bad.sort(key=lambda r: -np.nan_to_num(r.max_standardized, nan=0.0))
        return tuple(dict.fromkeys(r.point_id for r in bad))


#: false-alarm level of the overlap check: that of the rule it replaced, 3 sigma on each of three
#: independent axes (1 - 0.9973^3 = 0.81 % of correct overlaps), now spent on one joint test
OVERLAP_ALPHA = float(1.0 - (1.0 - 2.0 * stats.norm.sf(3.0)) ** 3)
#: an overlap difference whose Mahalanobis length sqrt(d' C^-1 d) exceeds this is more than the two
#: setups and the two measurements explain: sqrt of the chi-square (3 dof) quantile at OVERLAP_ALPHA,
#: 3.436
OVERLAP_SIGMA_LIMIT = float(np.sqrt(stats.chi2.isf(OVERLAP_ALPHA, 3)))


@dataclass(frozen=True)
class OverlapCheck:
    """A point measured from two station setups.

    Attributes
    ----------
    point_id : the point.
    difference_enh_m : (3,) second minus first, E, N, H.
    horizontal_m : horizontal length of the difference.
    within_tolerance : all of |dE|, |dN|, |dH| within the tolerance.
    tolerance_m : the tolerance used.
    covariance_enh_m2 : (3, 3) covariance of the difference, the sum of both positions' (NaN when
        they were not given).
    sigma_limit : the Mahalanobis length the difference may reach and still be explained by the two
        setups and measurements (:data:`OVERLAP_SIGMA_LIMIT`).
    """

    point_id: str
    difference_enh_m: np.ndarray
    horizontal_m: float
    within_tolerance: bool
    tolerance_m: float
    covariance_enh_m2: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    sigma_limit: float = OVERLAP_SIGMA_LIMIT

    @property
    def sigma_enh_m(self) -> np.ndarray:
        """(3,) 1-sigma of the difference per axis (NaN without covariances)."""
        return np.sqrt(np.diag(self.covariance_enh_m2))

    @property
    def difference_enh_mm(self) -> np.ndarray:
        """The difference in mm (for display)."""
        return units.m_to_mm(self.difference_enh_m)

    @property
    def normalized(self) -> np.ndarray:
        """(3,) |difference| / its sigma per axis (NaN without sigmas), for display: the verdict is
        :attr:`mahalanobis`."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.abs(self.difference_enh_m) / self.sigma_enh_m

    @property
    def max_normalized(self) -> float:
        """The largest of :attr:`normalized` (NaN without sigmas)."""
        z = self.normalized
        return float(np.max(z)) if np.all(np.isfinite(z)) else float("nan")

    @property
    def mahalanobis(self) -> float:
        """sqrt(d' C^-1 d), the difference measured in its own joint sigma, E-N-H correlations
        included (NaN without covariances): chi-distributed with 3 dof for a correct overlap."""
        c = self.covariance_enh_m2
        if not np.all(np.isfinite(c)):
            return float("nan")
        d = self.difference_enh_m
        return float(np.sqrt(d @ np.linalg.solve(c, d)))

    @property
    def consistent(self) -> bool | None:
        """The difference's Mahalanobis length is within :attr:`sigma_limit`: the two positions agree
        as well as the setups and measurements allow (None without covariances)."""
        m = self.mahalanobis
        return None if not np.isfinite(m) else bool(m <= self.sigma_limit)


def variance_factor(sigma0: float, dof: int) -> float:
    """The factor the a priori covariance of a resection is scaled by before it is used: sigma0^2
    when sigma0 > 1, else 1 (also without redundancy, dof <= 0, or a sigma0 that is not finite).

    A sigma0 above 1 says the observations scatter more than the a priori sigmas allow (a noisier
    instrument, CPIII coordinates off by their own network errors, a centring error): the a priori
    covariance is then too small by sigma0^2, and the a posteriori one, sigma0^2 Q, is used
    (Ghilani 2017, ch. 5 and 16). The global test of the variance factor (dof sigma0^2 against
    chi-square on the redundancy) does not decide here: with 8 points (dof 20) it misses about half
    of the setups whose noise is 1.3 times the a priori and keeps their covariance too small, while
    scaling whenever sigma0 > 1 stays close to honest from 1.3 times up and costs a few per cent of
    conservatism when the a priori sigmas are right (docs/field_session.md, "sigma0";
    benchmarks/fix_sigma/sigma0_policy.py). A sigma0 below 1 does not shrink the covariance: the a
    priori sigmas are the instrument's stated accuracy, which a few dozen residuals do not overrule.
    """
    s0 = float(sigma0)
    if dof <= 0 or not np.isfinite(s0):
        return 1.0
    return max(1.0, s0 * s0)


def wrap_to_pi(angle_rad: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(angle_rad, dtype=float) + np.pi) % TWO_PI - np.pi


def _polar_parts(station: np.ndarray, points: np.ndarray, model: PolarModel):
    d = np.atleast_2d(points) - station[None, :]
    u, v, w = d[:, 0], d[:, 1], d[:, 2]
    hd = np.hypot(u, v) / model.grid_scale  # horizontal distance as the instrument measures it
    c = model.height_drop_per_m2
    a = w - c * hd**2  # apparent height difference seen in the instrument's horizon
    sd = np.hypot(hd, a)
    return u, v, hd, a, sd, c


def observations_from_station(station: np.ndarray, orientation: float, points: np.ndarray,
                              model: PolarModel = PolarModel()) -> PolarObservations:
    """Polar observations (hz, zenith, slope distance) of ``points`` from a station.

    Parameters
    ----------
    station : (3,) E, N, H of the instrument's axis point, m.
    orientation : grid azimuth of the horizontal circle's zero, rad.
    points : (n, 3) or (3,) target E, N, H, m.
    model : curvature and refraction.

    Returns
    -------
    PolarObservations with hz in [0, 2 pi), zenith in (0, pi), slope distance in m.
    """
    station = np.asarray(station, dtype=float)
    u, v, hd, a, sd, _ = _polar_parts(station, np.asarray(points, dtype=float), model)
    hz = np.mod(np.arctan2(u, v) - orientation, TWO_PI)
    return PolarObservations(hz, np.arctan2(hd, a), sd)


def point_from_observation(station: np.ndarray, orientation: float, obs: PolarObservations,
                           model: PolarModel = PolarModel()) -> np.ndarray:
    """Target coordinates from polar observations: the exact inverse of ``observations_from_station``.

    Returns
    -------
    (n, 3) E, N, H, m.
    """
    station = np.asarray(station, dtype=float)
    hd = obs.slope_distance_m * np.sin(obs.zenith_rad)
    a = obs.slope_distance_m * np.cos(obs.zenith_rad)
    az = obs.hz_rad + orientation
    hd_grid = hd * model.grid_scale
    return np.column_stack([station[0] + hd_grid * np.sin(az), station[1] + hd_grid * np.cos(az),
                            station[2] + a + model.height_drop_per_m2 * hd**2])


def observation_jacobian(station: np.ndarray, points: np.ndarray,
                         model: PolarModel = PolarModel()) -> np.ndarray:
    """d(hz, zenith, slope distance) / d(target E, N, H), one 3x3 block per point.

    The derivative with respect to the station position is its negative; d hz / d orientation = -1.

    Returns
    -------
    (n, 3, 3) array.
    """
    u, v, hd, a, sd, c = _polar_parts(np.asarray(station, dtype=float), np.asarray(points, dtype=float), model)
    n = u.shape[0]
    zero = np.zeros(n)
    k = model.grid_scale
    hd_grid = hd * k
    g_hd = np.stack([u / (hd_grid * k), v / (hd_grid * k), zero], axis=1)
    g_a = -2.0 * c * hd[:, None] * g_hd
    g_a[:, 2] = 1.0
    g_hz = np.stack([v / hd_grid**2, -u / hd_grid**2, zero], axis=1)
    g_z = (a[:, None] * g_hd - hd[:, None] * g_a) / sd[:, None] ** 2
    g_sd = (hd[:, None] * g_hd + a[:, None] * g_a) / sd[:, None]
    return np.stack([g_hz, g_z, g_sd], axis=1)


def _initial_station(points: np.ndarray, obs: np.ndarray, model: PolarModel) -> np.ndarray:
    """Closed-form start: a 2-D similarity (Helmert) fit of the polar sketch to the grid, then H."""
    ok = np.all(np.isfinite(obs), axis=1)
    if np.count_nonzero(ok) < 2:
        raise ResectionError("need at least 2 pointings with direction, zenith and distance")
    p, o = points[ok], obs[ok]
    hd = o[:, 2] * np.sin(o[:, 1])
    hd_grid = hd * model.grid_scale
    x, y = hd_grid * np.sin(o[:, 0]), hd_grid * np.cos(o[:, 0])  # E-like, N-like in the circle's frame
    # grid = S + R x with R = [[a, b], [-b, a]] for a clockwise rotation by the orientation
    m = p.shape[0]
    design = np.zeros((2 * m, 4))
    design[0::2] = np.column_stack([x, y, np.ones(m), np.zeros(m)])
    design[1::2] = np.column_stack([y, -x, np.zeros(m), np.ones(m)])
    rhs = np.empty(2 * m)
    rhs[0::2], rhs[1::2] = p[:, 0], p[:, 1]
    (ca, sb, e0, n0), *_ = np.linalg.lstsq(design, rhs, rcond=None)
    orientation = float(np.mod(np.arctan2(sb, ca), TWO_PI))
    h0 = np.mean(p[:, 2] - o[:, 2] * np.cos(o[:, 1]) - model.height_drop_per_m2 * hd**2)
    return np.array([e0, n0, h0, orientation])


def _residual_vector(x: np.ndarray, points: np.ndarray, obs: np.ndarray, model: PolarModel) -> np.ndarray:
    """Observed minus computed, (n, 3), hz wrapped."""
    comp = observations_from_station(x[:3], x[3], points, model).as_array()
    r = obs - comp
    r[:, 0] = wrap_to_pi(r[:, 0])
    return r


def resect(point_ids: Sequence[str], points_enh_m: np.ndarray, observations: PolarObservations,
           config: ResectionConfig = ResectionConfig(), exclude: Collection[str] = ()) -> Resection:
    """Free-station resection by weighted least squares.

    Parameters
    ----------
    point_ids : (n,) id of the CPIII point of each pointing (a point may be pointed more than once).
    points_enh_m : (n, 3) known grid coordinates of each pointing's point.
    observations : the n pointings (NaN for an observation not taken).
    config : sigmas, model and tolerances.
    exclude : point ids to leave out (the crew dropped them).

    Returns
    -------
    Resection: station, orientation, covariance, sigma0, residuals and flags.

    Raises
    ------
    ResectionError : fewer than 3 distinct points, fewer than 4 observations, or singular geometry.
    """
    ids = np.asarray([str(i) for i in point_ids], dtype=object)
    pts = np.asarray(points_enh_m, dtype=float).reshape(-1, 3)
    obs = observations.as_array()
    if not (ids.shape[0] == pts.shape[0] == obs.shape[0]):
        raise ResectionError("point ids, coordinates and observations differ in length")
    keep = ~np.isin(ids, list(exclude)) if exclude else np.ones(ids.shape[0], bool)
    ids, pts, obs = ids[keep], pts[keep], obs[keep]
    if len(set(ids.tolist())) < 3:
        raise ResectionError(f"need at least 3 distinct points, have {len(set(ids.tolist()))}")
    if not np.all(np.isfinite(pts)):
        raise ResectionError("control point coordinates must be finite")

    mask = np.isfinite(obs)  # (n, 3) which observations exist
    n_obs = int(mask.sum())
    if n_obs < 4:
        raise ResectionError(f"need at least 4 observations, have {n_obs}")
    model, sig = config.model, config.sigmas
    x0 = _initial_station(pts, obs, model)

    def sigma_of(sd: np.ndarray) -> np.ndarray:
        s = np.empty(obs.shape)
        s[:, 0], s[:, 1] = sig.direction_rad, sig.zenith_rad
        s[:, 2] = sig.distance_sigma_m(sd)
        return s

    # weights use the observed distance (fixed during the iteration, as is customary)
    sigma = sigma_of(np.where(mask[:, 2], obs[:, 2], 0.0))
    obs_f = np.where(mask, obs, 0.0)

    def fun(x: np.ndarray) -> np.ndarray:
        return (_residual_vector(x, pts, obs_f, model) / sigma)[mask]

    def jac(x: np.ndarray) -> np.ndarray:
        # residual = observed - computed: its derivative is minus the observation's derivative
        jp = observation_jacobian(x[:3], pts, model)  # d obs / d target
        a = np.zeros((pts.shape[0], 3, 4))
        a[:, :, :3] = jp  # d obs / d station = -jp, so d residual / d station = +jp
        a[:, 0, 3] = 1.0  # d hz / d orientation = -1
        return (a / sigma[:, :, None])[mask]

    sol = least_squares(fun, x0, jac=jac, method="lm", xtol=1e-14, ftol=1e-14, gtol=1e-14)
    x = sol.x
    a_w = jac(x)  # whitened design matrix
    normal = a_w.T @ a_w
    if np.linalg.cond(normal) > 1e14:
        raise ResectionError("singular geometry: the points do not fix the station")
    cov = np.linalg.inv(normal)
    v_w = fun(x)
    dof = n_obs - 4
    sigma0 = float(np.sqrt(v_w @ v_w / dof)) if dof > 0 else float("nan")

    # Baarda: Q_vv (whitened) = I - A N^-1 A^T; w = v / sqrt(q_vv)
    qvv = 1.0 - np.einsum("ij,jk,ik->i", a_w, cov, a_w)
    w_flat = np.where(qvv > 1e-10, np.abs(v_w) / np.sqrt(np.clip(qvv, 1e-10, None)), np.nan)
    w = np.full(obs.shape, np.nan)
    w[mask] = w_flat
    resid = np.full(obs.shape, np.nan)
    resid[mask] = (v_w * sigma[mask])

    # residual as a target displacement: solve J_point d = v (unobserved components set to 0)
    jp = observation_jacobian(x[:3], pts, model)
    disp = np.linalg.solve(jp, np.nan_to_num(resid)[:, :, None])[:, :, 0]
    az = np.arctan2(pts[:, 0] - x[0], pts[:, 1] - x[1])
    along_u = np.column_stack([np.sin(az), np.cos(az)])
    across_u = np.column_stack([np.cos(az), -np.sin(az)])
    along = np.sum(disp[:, :2] * along_u, axis=1)
    across = np.sum(disp[:, :2] * across_u, axis=1)
    height = disp[:, 2]

    tol_w, tol_m = config.max_standardized_residual, config.max_point_residual_m
    residuals = []
    for i in range(ids.shape[0]):
        max_w = float(np.nanmax(w[i])) if np.any(np.isfinite(w[i])) else float("nan")
        reasons = []
        if np.isfinite(max_w) and max_w > tol_w:
            reasons.append(f"standardized residual {max_w:.1f} > {tol_w:g}")
        if tol_m is not None:
            worst_m = max(abs(across[i]), abs(along[i]), abs(height[i]))
            if worst_m > tol_m:
                reasons.append(f"residual {units.m_to_mm(worst_m):.1f} mm > {units.m_to_mm(tol_m):g} mm")
        residuals.append(PointResidual(
            point_id=str(ids[i]), hz_rad=float(resid[i, 0]), zenith_rad=float(resid[i, 1]),
            distance_m=float(resid[i, 2]), across_m=float(across[i]), along_m=float(along[i]),
            height_m=float(height[i]), standardized=(float(w[i, 0]), float(w[i, 1]), float(w[i, 2])),
            max_standardized=max_w, flagged=bool(reasons), reason="; ".join(reasons)))

    return Resection(station_enh_m=x[:3].copy(), orientation_rad=float(np.mod(x[3], TWO_PI)),
                     covariance=cov, sigma0=sigma0, dof=dof, residuals=tuple(residuals),
                     excluded=tuple(sorted(set(map(str, exclude)))))


def suggest_point_to_drop(result: Resection) -> str | None:
    """The point the crew should consider dropping: the flagged one with the largest |w|, or None.

    Data snooping tests one outlier at a time: drop (or re-measure) this point, recompute with
    ``resect(..., exclude=...)``, and look again.
    """
    flagged = result.flagged_points
    return flagged[0] if flagged else None


def setup_covariance_at(setup_covariance: np.ndarray, station_enh_m: np.ndarray,
                        points_enh_m: np.ndarray) -> np.ndarray:
    """Covariance of the grid E, N, H that a station setup's own errors give the points measured from it.

    An instrument given the resected station S and orientation o puts a point at
    ``S + hd_grid (sin(hz + o), cos(hz + o)) + (0, 0, dh)`` (:func:`point_from_observation`): its
    derivative with respect to S is the identity and with respect to o is (dN, -dE, 0), where
    (dE, dN) is the point's grid offset from the station (the offset turns about the station). The
    covariance is ``J C J^T`` with ``J = [I3 | (dN, -dE, 0)^T]``, the general law of propagation of
    variances (Ghilani 2017, ch. 6), C the setup's (E, N, H, orientation) covariance with its
    correlations. It is exact to first order: the orientation sigma of a setup is about 1e-6 rad.

    Every point measured from one setup shares the same setup error: these covariances are the
    diagonal blocks of a joint covariance whose off-diagonal blocks ``J_i C J_j^T`` are not zero.

    Parameters
    ----------
    setup_covariance : (4, 4) covariance of E, N, H, orientation (``Resection.covariance``).
    station_enh_m : (3,) the resected station the instrument was given.
    points_enh_m : (3,) or (n, 3) the points measured from it, grid E, N, H.

    Returns
    -------
    (n, 3, 3) covariance of E, N, H per point, m^2.
    """
    c = np.asarray(setup_covariance, dtype=float).reshape(4, 4)
    d = np.atleast_2d(np.asarray(points_enh_m, dtype=float)) - np.asarray(station_enh_m, dtype=float).reshape(3)
    jac = np.zeros((d.shape[0], 3, 4))
    jac[:, :, :3] = np.eye(3)
    jac[:, 0, 3] = d[:, 1]
    jac[:, 1, 3] = -d[:, 0]
    return jac @ c @ np.swapaxes(jac, 1, 2)


def polar_covariance(station_enh_m: np.ndarray, points_enh_m: np.ndarray, sigmas: InstrumentSigmas,
                     model: PolarModel = PolarModel()) -> np.ndarray:
    """Covariance of grid E, N, H of points computed from one polar measurement each (Hz, zenith,
    slope distance), from the instrument's a priori sigmas: the measurement's own part of a fix.

    The point is :func:`point_from_observation` of the readings; its Jacobian with respect to them
    is the inverse of :func:`observation_jacobian` (the two are exact inverses), and the covariance
    is ``J S J^T`` with S = diag(direction^2, zenith^2, distance^2) (the general law of propagation
    of variances, Ghilani 2017, ch. 6), the distance sigma at the point's own distance (constant +
    ppm). Horizontally the direction sigma times the horizontal distance lies across the line of
    sight and the distance sigma along it, so the E-N covariance has a correlation set by the line's
    azimuth; in height the zenith sigma times the slope distance. The orientation of the circle is
    the setup's (:func:`setup_covariance_at`), not the measurement's.

    Parameters
    ----------
    station_enh_m : (3,) the instrument's axis point, grid E, N, H, m.
    points_enh_m : (3,) or (n, 3) the measured points, grid E, N, H, m.
    sigmas : a priori sigmas of direction, zenith and distance.
    model : the polar model the points are computed with (curvature, refraction, grid scale).

    Returns
    -------
    (n, 3, 3) covariance of E, N, H per point, m^2.

    References
    ----------
    Ghilani, C. D. (2017). Adjustment Computations, 6th ed., ch. 6 (propagation of errors).
    """
    station = np.asarray(station_enh_m, dtype=float).reshape(3)
    points = np.atleast_2d(np.asarray(points_enh_m, dtype=float))
    jac = np.linalg.inv(observation_jacobian(station, points, model))  # d(E, N, H) / d(hz, zenith, sd)
    sd = observations_from_station(station, 0.0, points, model).slope_distance_m
    var = np.column_stack([np.full(sd.shape, sigmas.direction_rad ** 2), np.full(sd.shape, sigmas.zenith_rad ** 2),
                           sigmas.distance_sigma_m(sd) ** 2])
    return (jac * var[:, None, :]) @ np.swapaxes(jac, 1, 2)


def fix_covariance(sigmas: InstrumentSigmas, setup_covariance: np.ndarray, station_enh_m: np.ndarray,
                   points_enh_m: np.ndarray, model: PolarModel = PolarModel(), factor: float = 1.0) -> np.ndarray:
    """Covariance of the grid E, N, H of prism fixes measured from a station setup: the polar
    measurement's own covariance (:func:`polar_covariance`) plus the setup's error carried to each
    fix (:func:`setup_covariance_at`), both scaled by the setup's variance factor.

    The two parts are independent: the setup's error comes from its CPIII pointings, the
    measurement's from the pointing at the prism. Both rest on the same a priori instrument sigmas,
    and the setup's sigma0 says how those fit the instrument on this day: a sigma0 above 1 scales
    both (:func:`variance_factor`; docs/field_session.md, "The fix sigma and the station setup",
    measures it).

    Parameters
    ----------
    sigmas : a priori instrument sigmas (the resection's).
    setup_covariance : (4, 4) a priori covariance of E, N, H, orientation of the setup
        (``Resection.covariance``).
    station_enh_m : (3,) the station the instrument was given.
    points_enh_m : (3,) or (n, 3) the fixes, grid E, N, H.
    model : the polar model the fixes are computed with.
    factor : the setup's :func:`variance_factor` (1: the a priori sigmas as they are).

    Returns
    -------
    (n, 3, 3) covariance per fix, m^2.
    """
    return float(factor) * (polar_covariance(station_enh_m, points_enh_m, sigmas, model)
                            + setup_covariance_at(setup_covariance, station_enh_m, points_enh_m))


def covariance_with_sigmas(covariance: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """The covariance with the correlations of ``covariance`` and the 1-sigma ``sigma``: D R D.

    A fix is stored with its per-axis sigmas only (FORMATS.md section 1); its correlations are
    computed again from its setup, and this puts them on the stored sigmas, so that the overlap check
    uses exactly the sigmas the crew and the record show.

    Parameters
    ----------
    covariance : (3, 3) covariance whose correlations are taken.
    sigma : (3,) the 1-sigma per axis.

    Returns
    -------
    (3, 3) covariance, m^2.
    """
    c = np.asarray(covariance, dtype=float).reshape(3, 3)
    d = np.sqrt(np.diag(c))
    scale = np.asarray(sigma, dtype=float).reshape(3) / d
    return c * np.outer(scale, scale)


def overlap_check(point_id: str, first_enh_m: np.ndarray, second_enh_m: np.ndarray,
                  tolerance_m: float = 0.002, first_covariance: np.ndarray | None = None,
                  second_covariance: np.ndarray | None = None,
                  sigma_limit: float = OVERLAP_SIGMA_LIMIT) -> OverlapCheck:
    """Compare a point measured from two station setups.

    The tolerance is the project's requirement; the covariance says what the two setups can hold.
    The two positions are independent (each setup's error comes from its own CPIII pointings, each
    measurement's from its own pointing at the point), so the covariance C of the difference is the
    sum of theirs. The difference d is tested jointly: d' C^-1 d follows chi-square with 3 dof for
    a correct overlap, so its square root is compared with ``sigma_limit`` (the correlation of a
    polar measurement's E and N, across and along its line of sight, makes a per-axis test blind
    along one diagonal and too strict along the other).

    Parameters
    ----------
    point_id : the point (e.g. a trolley stop or a CPIII point measured from both stations).
    first_enh_m, second_enh_m : (3,) its E, N, H from the first and the second setup.
    tolerance_m : largest acceptable difference per axis.
    first_covariance, second_covariance : (3, 3) covariance of each position (the measurement and
        its setup carried to the point: :func:`fix_covariance`), both or neither.
    sigma_limit : the Mahalanobis length the difference may reach and still be explained by them.

    Returns
    -------
    OverlapCheck with the difference second minus first and its covariance.
    """
    d = np.asarray(second_enh_m, dtype=float).reshape(3) - np.asarray(first_enh_m, dtype=float).reshape(3)
    if (first_covariance is None) != (second_covariance is None):
        raise ValueError("overlap_check: give the covariance of both positions or of neither")
    if first_covariance is None:
        cov = np.full((3, 3), np.nan)
    else:
        cov = (np.asarray(first_covariance, dtype=float).reshape(3, 3)
               + np.asarray(second_covariance, dtype=float).reshape(3, 3))
    return OverlapCheck(point_id=str(point_id), difference_enh_m=d, horizontal_m=float(np.hypot(d[0], d[1])),
                        within_tolerance=bool(np.all(np.abs(d) <= tolerance_m)), tolerance_m=float(tolerance_m),
                        covariance_enh_m2=cov, sigma_limit=float(sigma_limit))

"""In-memory form of a raw stop-and-go session (FORMATS.md section 1), as arrays.

The survey layer reads and writes the session folder; the science works on these containers.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from trolley.sensors import ImuFigures, OdometerFigures


@dataclass(frozen=True)
class TrolleyGeometry:
    """Trolley geometry from ``session.toml [trolley]``.

    Attributes
    ----------
    prism_lever_arm_m : prism position in the trolley FRD frame from the track reference point.
    imu_misalignment_rad : nominal IMU-to-trolley mounting angles (roll, pitch, yaw about FRD), rad.
    rail_spacing_m : distance between the rail centre lines (cant = rail_spacing * sin(roll)).
    nominal_gauge_m : nominal track gauge.
    """

    prism_lever_arm_m: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -0.60]))
    imu_misalignment_rad: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rail_spacing_m: float = 1.500
    nominal_gauge_m: float = 1.435


@dataclass(frozen=True)
class SessionMeta:
    """Metadata of a raw session (``session.toml``), in SI units.

    Attributes
    ----------
    latitude_rad, height_m : site, for the Earth-rate terms; the latitude may be NaN when a
        ``crs`` is given: it is then derived from the CRS and the fixes
        (:func:`trolley.projection.session_site`).
    trolley : trolley geometry.
    imu : IMU datasheet figures (the filters' Q and P0 come from these).
    odometer : odometer figures.
    fix_sigma_m : default 1-sigma of a total-station fix per axis.
    static_s : length of the initial static period.
    initial_heading_rad : heading to use instead of gyrocompassing, or NaN.
    design_alignment : path of the LandXML design, relative to the session folder, or None.
    design_alignment_name : ``Alignment/@name`` to read from a design file holding several.
    crs : the project grid's coordinate reference system (EPSG code, PROJ string), or None: the
        grid is then taken as a local map with true north and ground scale.
    vertical_datum : name of the height datum of H, or None.
    """

    latitude_rad: float
    height_m: float = 0.0
    trolley: TrolleyGeometry = field(default_factory=TrolleyGeometry)
    imu: ImuFigures | None = None
    odometer: OdometerFigures = field(default_factory=OdometerFigures)
    fix_sigma_m: float = 0.0006
    static_s: float = 900.0
    initial_heading_rad: float = float("nan")
    design_alignment: str | None = None
    design_alignment_name: str | None = None
    crs: str | None = None
    vertical_datum: str | None = None


@dataclass
class Fixes:
    """Total-station prism fixes: one row per measurement (grid E, N, H; sigmas per axis and, when
    known, the covariances between the axes).

    A polar measurement's error is not the same along every axis: across the line of sight it is
    the direction sigma times the distance, along it the distance sigma, so E and N are correlated
    by the line's azimuth (``trolley.resection.polar_covariance``). Without ``cov_m2`` the axes
    are taken as independent.
    """

    t_s: np.ndarray
    point: np.ndarray  # labels (object array of str)
    enh_m: np.ndarray  # (n, 3) E, N, H
    sigma_m: np.ndarray  # (n, 3)
    #: (n, 3) covariances E-N, E-H, N-H, m^2 (fixes.csv ``cov_EN_m2, cov_EH_m2, cov_NH_m2``); None: 0
    cov_m2: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def take(self, index) -> "Fixes":
        """The fixes at ``index`` (a boolean mask or integer indices), every per-fix array with
        them: the covariances too, which would otherwise belong to other fixes."""
        return Fixes(t_s=np.asarray(self.t_s)[index], point=np.asarray(self.point, dtype=object)[index],
                     enh_m=np.asarray(self.enh_m)[index], sigma_m=np.asarray(self.sigma_m)[index],
                     cov_m2=None if self.cov_m2 is None else np.asarray(self.cov_m2)[index])

    def covariance_enh_m2(self) -> np.ndarray:
        """(n, 3, 3) covariance of each fix's grid E, N, H, m^2."""
        sig = np.atleast_2d(np.asarray(self.sigma_m, dtype=float))
        c = np.zeros((sig.shape[0], 3, 3))
        c[:, [0, 1, 2], [0, 1, 2]] = sig ** 2
        if self.cov_m2 is not None:
            cov = np.atleast_2d(np.asarray(self.cov_m2, dtype=float))
            for k, (i, j) in enumerate(((0, 1), (0, 2), (1, 2))):
                c[:, i, j] = c[:, j, i] = cov[:, k]
        return c


def off_diagonal(covariance_m2: np.ndarray) -> np.ndarray:
    """(n, 3) covariances E-N, E-H, N-H of (n, 3, 3) E, N, H covariances (``Fixes.cov_m2``)."""
    c = np.asarray(covariance_m2, dtype=float).reshape(-1, 3, 3)
    return np.column_stack([c[:, 0, 1], c[:, 0, 2], c[:, 1, 2]])


@dataclass
class RawSession:
    """A whole raw session as arrays (FORMATS.md section 1).

    Attributes
    ----------
    meta : session metadata.
    imu_t_s : (N,) IMU sample times; imu_w_rad_s, imu_f_m_s2 : (N, 3) angular rate and specific
        force in the IMU's FRD frame as measured.
    odo_t_s, odo_distance_m : cumulative odometer distance.
    fixes : prism fixes.
    gauge_t_s, gauge_m : gauge sensor, or None.
    """

    meta: SessionMeta
    imu_t_s: np.ndarray
    imu_w_rad_s: np.ndarray
    imu_f_m_s2: np.ndarray
    odo_t_s: np.ndarray
    odo_distance_m: np.ndarray
    fixes: Fixes
    gauge_t_s: np.ndarray | None = None
    gauge_m: np.ndarray | None = None

"""Map projections of the project grid: grid convergence, point scale factor, height reduction.

The CPIII network and the design are given in a projected grid (E, N, H); the IMU measures
against true north and the odometer and the total station measure ground distances. At a site
the two are related, to first order, by a rotation and a scale:

- the grid convergence gamma: the true azimuth of a line is its grid bearing plus gamma
  (gamma > 0 east of the central meridian in the northern hemisphere; for Transverse Mercator
  gamma ~ (lon - lon0) sin(lat));
- the combined scale factor ``grid distance / horizontal ground distance = k R / (R + h)``: the
  point scale factor k of the projection (Transverse Mercator: k ~ k0 (1 + x^2 / (2 R^2))) times
  the height reduction R / (R + h) of a distance measured at ellipsoidal height h down to the
  ellipsoid, R the Gaussian mean radius sqrt(M N) at the site.

Both come from pyproj (``Proj.get_factors``, PROJ's analytic or numerically differentiated
projection factors) at the site's longitude and latitude, which are themselves the inverse
projection of the site's grid coordinates: no hand-typed latitude is needed once the CRS is known.

Why here, in ``trolley/``: this is a pure computation on numbers handed in (a CRS string and
coordinates); pyproj reads its own bundled projection database to resolve an EPSG code, as scipy
reads its own tables, but this module opens no file of ours and keeps no state. The engine needs
the factors, and ``trolley/`` may not import ``survey/``.

The site is taken as one point: over a 1.2 km survey 200 km off the central meridian k varies
by 6e-6 (0.4 mm over a 60 m leg, absorbed by the odometer scale state), and the change of gamma
along the site is the rotation of true north that the transport rate of the dead reckoning
already follows (``trolley.earth.transport_rate_n``).

References
----------
Snyder, J. P. (1987). Map Projections: A Working Manual. USGS Prof. Paper 1395, Sec. 8
(Transverse Mercator: Eq. 8-10 scale factor, 8-13 convergence), Sec. 4 (scale factors h, k).
Ghilani, C. D., Wolf, P. R. (2012). Elementary Surveying, 13th ed., ch. 20 (grid and ground
distances: elevation factor R / (R + h), combined factor).
Jiang 2017 Sec. 2: the CPIII coordinates are in the project's grid; the IMU's heading is true.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CrsError", "GridFactors", "crs_info", "grid_factors", "site_factors",
           "gaussian_radius_m", "session_site", "same_crs"]

#: A projection whose meridional and parallel scales differ by more than this is not conformal:
#: a distance then has no single reduction to the grid.
CONFORMAL_TOLERANCE = 1e-7


class CrsError(ValueError):
    """A coordinate reference system that cannot serve as the project grid."""


@dataclass(frozen=True)
class CrsInfo:
    """A validated project CRS.

    Attributes
    ----------
    text : the CRS as the user gave it (EPSG code, PROJ string, WKT).
    name : PROJ's name of the horizontal CRS.
    epsg : its EPSG code, or None.
    vertical_datum : name of the vertical part of a compound CRS, or "".
    """

    text: str
    name: str
    epsg: int | None
    vertical_datum: str = ""


@dataclass(frozen=True)
class GridFactors:
    """The grid at one site.

    Attributes
    ----------
    latitude_rad, longitude_rad : geodetic position of the site (the CRS's own datum).
    convergence_rad : grid convergence gamma: true azimuth = grid bearing + gamma.
    point_scale : point scale factor k of the projection (grid / ellipsoid distance).
    height_m : ellipsoidal height used for the height reduction.
    radius_m : Gaussian mean radius of curvature sqrt(M N) at the site.
    """

    latitude_rad: float
    longitude_rad: float
    convergence_rad: float
    point_scale: float
    height_m: float
    radius_m: float

    @property
    def height_reduction(self) -> float:
        """R / (R + h): ellipsoid distance / horizontal distance at height h."""
        return self.radius_m / (self.radius_m + self.height_m)

    @property
    def combined_scale(self) -> float:
        """Grid distance / horizontal ground distance, k R / (R + h)."""
        return self.point_scale * self.height_reduction

    def grid_to_local(self, d_enh) -> np.ndarray:
        """Grid offsets (..., 3) E, N, H to ground offsets along true east, true north, up.

        The horizontal part is turned by gamma (grid bearing + gamma = true azimuth) and divided
        by the combined scale; heights are not scaled.
        """
        d = np.asarray(d_enh, dtype=float)
        c, s = np.cos(self.convergence_rad), np.sin(self.convergence_rad)
        k = self.combined_scale
        out = d.copy()
        out[..., 0] = (c * d[..., 0] + s * d[..., 1]) / k
        out[..., 1] = (-s * d[..., 0] + c * d[..., 1]) / k
        return out

    def local_to_grid(self, d_enh) -> np.ndarray:
        """The inverse of :meth:`grid_to_local`."""
        d = np.asarray(d_enh, dtype=float)
        c, s = np.cos(self.convergence_rad), np.sin(self.convergence_rad)
        k = self.combined_scale
        out = d.copy()
        out[..., 0] = k * (c * d[..., 0] - s * d[..., 1])
        out[..., 1] = k * (s * d[..., 0] + c * d[..., 1])
        return out


def _crs(text: str):
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    if not isinstance(text, str) or not text.strip():
        raise CrsError("the CRS is empty: give an EPSG code (e.g. EPSG:32650) or a PROJ string")
    try:
        crs = CRS.from_user_input(text.strip())
    except CRSError as exc:
        raise CrsError(f"{text!r} is not a coordinate reference system pyproj knows ({exc})") from None
    vertical = ""
    if crs.is_compound:
        subs = crs.sub_crs_list
        horizontal = [c for c in subs if c.is_projected]
        vert = [c for c in subs if c.is_vertical]
        if not horizontal:
            raise CrsError(f"{text!r}: the compound CRS has no projected part for the grid E, N")
        vertical = vert[0].name if vert else ""
        crs = horizontal[0]
    if not crs.is_projected:
        raise CrsError(f"{text!r} ({crs.name}) is not a projected CRS: the project grid needs "
                       "E, N in metres (e.g. a UTM or Gauss-Krueger zone)")
    units = {ax.unit_name for ax in crs.axis_info[:2]}
    if not units <= {"metre", "meter"}:
        raise CrsError(f"{text!r} ({crs.name}) has axes in {', '.join(sorted(units))}, not metres")
    return crs, vertical


def crs_info(text: str) -> CrsInfo:
    """Validate a CRS given as an EPSG code, PROJ string or WKT (``pyproj.CRS.from_user_input``).

    Raises
    ------
    CrsError
        Unknown to pyproj, not projected (no grid E, N), or not in metres.
    """
    crs, vertical = _crs(text)
    return CrsInfo(text=text.strip(), name=crs.name, epsg=crs.to_epsg(), vertical_datum=vertical)


def same_crs(a: str, b: str) -> bool:
    """Whether two CRS texts (EPSG code, WKT, PROJ string) define the same CRS (axis order aside)."""
    from pyproj import CRS

    return CRS.from_user_input(a).equals(CRS.from_user_input(b), ignore_axis_order=True)


def gaussian_radius_m(latitude_rad: float, semi_major_m: float = 6378137.0,
                      inverse_flattening: float = 298.257223563) -> float:
    """Gaussian mean radius sqrt(M N) of the ellipsoid at a latitude (Ghilani & Wolf ch. 20)."""
    f = 1.0 / inverse_flattening if inverse_flattening else 0.0
    e2 = f * (2.0 - f)
    w2 = 1.0 - e2 * np.sin(latitude_rad) ** 2
    return float(semi_major_m * np.sqrt(1.0 - e2) / w2)


def grid_factors(crs_text: str, e_m: float, n_m: float, height_m: float = 0.0) -> GridFactors:
    """Convergence, point scale and height reduction of the grid at a point.

    Parameters
    ----------
    crs_text : the project CRS (see :func:`crs_info`).
    e_m, n_m : grid coordinates of the site.
    height_m : ellipsoidal height of the site (the orthometric height where the geoid
        undulation is unknown: 10 m of undulation is 1.6e-6 of scale).

    Returns
    -------
    GridFactors

    Raises
    ------
    CrsError
        Bad CRS, coordinates outside the projection's domain, or a projection that is not
        conformal (no single scale factor for a distance).

    References
    ----------
    Snyder 1987 Sec. 4 (h, k and the convergence from the projection's derivatives), as computed
    by PROJ (``pyproj.Proj.get_factors``).
    """
    from pyproj import Proj, Transformer

    crs, _ = _crs(crs_text)
    to_geo = Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True)
    lon, lat = to_geo.transform(float(e_m), float(n_m))
    if not (np.isfinite(lon) and np.isfinite(lat)):
        raise CrsError(f"E {e_m:.3f} N {n_m:.3f} is outside the domain of {crs.name}")
    f = Proj(crs).get_factors(lon, lat)
    conv, h_scale, k_scale = f.meridian_convergence, f.meridional_scale, f.parallel_scale
    if not all(np.isfinite(v) for v in (conv, h_scale, k_scale)):
        raise CrsError(f"{crs.name}: no projection factors at E {e_m:.3f} N {n_m:.3f} "
                       f"(lon {lon:.6f}, lat {lat:.6f} deg)")
    if abs(h_scale - k_scale) > CONFORMAL_TOLERANCE * k_scale:
        raise CrsError(f"{crs.name} is not conformal (meridional scale {h_scale:.9f}, parallel "
                       f"scale {k_scale:.9f}): a survey grid must be")
    ell = crs.ellipsoid
    lat_rad = float(np.deg2rad(lat))
    radius = gaussian_radius_m(lat_rad, ell.semi_major_metre, ell.inverse_flattening)
    return GridFactors(latitude_rad=lat_rad, longitude_rad=float(np.deg2rad(lon)),
                       convergence_rad=float(np.deg2rad(conv)), point_scale=float(k_scale),
                       height_m=float(height_m), radius_m=radius)


def outside_domain(crs_text: str, e_m, n_m) -> np.ndarray:
    """True for each grid point (E, N) that the CRS cannot take to latitude and longitude (the
    domain check of :func:`grid_factors`, for many points in one call)."""
    from pyproj import Transformer

    crs, _ = _crs(crs_text)
    to_geo = Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True)
    lon, lat = to_geo.transform(np.asarray(e_m, dtype=float), np.asarray(n_m, dtype=float), errcheck=False)
    return ~(np.isfinite(lon) & np.isfinite(lat))


def site_factors(crs_text: str, points_enh_m) -> GridFactors:
    """:func:`grid_factors` at the centroid of a site's points (CPIII or fixes), (n, 3) E, N, H."""
    p = np.atleast_2d(np.asarray(points_enh_m, dtype=float))
    if p.shape[0] == 0:
        raise CrsError("no points to place the site by")
    c = p.mean(axis=0)
    return grid_factors(crs_text, c[0], c[1], c[2] if p.shape[1] > 2 else 0.0)


def session_site(meta, points_enh_m):
    """A session's grid at its site, and its metadata with the latitude derived from it.

    Parameters
    ----------
    meta : ``trolley.session.SessionMeta``.
    points_enh_m : (n, 3) grid points of the site (the fixes, or the CPIII points).

    Returns
    -------
    (SessionMeta, GridFactors or None)
        Without ``meta.crs``: ``meta`` unchanged and None. With it: the factors at the centroid
        and ``meta`` whose NaN latitude is replaced by the site's (a latitude given by hand is
        kept: the caller may compare it).
    """
    from dataclasses import replace

    if not meta.crs:
        return meta, None
    factors = site_factors(meta.crs, points_enh_m)
    if not np.isfinite(meta.latitude_rad):
        meta = replace(meta, latitude_rad=factors.latitude_rad)
    return meta, factors

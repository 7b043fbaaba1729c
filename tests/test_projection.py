"""Grid convergence, point scale and height reduction (trolley/projection.py) against hand formulas
and independent computations (forward projection of a meridian step, geodesic distances)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trolley.projection import CrsError, crs_info, gaussian_radius_m, grid_factors, site_factors

UTM32 = "EPSG:32632"   # central meridian 9 deg E, k0 = 0.9996, false easting 500 km
K0 = 0.9996


def _grid(lon_deg, lat_deg, crs=UTM32):
    from pyproj import Transformer
    return Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon_deg, lat_deg)


def test_convergence_small_dlon_is_dlon_sin_lat():
    # 0.2 deg east of the central meridian at 48 deg N: gamma = dlon sin(lat) (Snyder Eq. 8-13,
    # next term dlon^3 sin cos^2 / 3 is 1e-6 of it)
    lon, lat = 9.2, 48.0
    e, n = _grid(lon, lat)
    f = grid_factors(UTM32, e, n)
    hand = math.radians(0.2) * math.sin(math.radians(lat))
    assert f.convergence_rad == pytest.approx(hand, rel=2e-5)
    assert math.degrees(f.latitude_rad) == pytest.approx(lat, abs=1e-9)
    assert math.degrees(f.longitude_rad) == pytest.approx(lon, abs=1e-9)


def test_convergence_sign_west_and_south():
    e, n = _grid(8.5, 48.0)
    assert grid_factors(UTM32, e, n).convergence_rad < 0
    e, n = _grid(9.5, -30.0, "EPSG:32732")  # southern hemisphere: east of CM, negative
    assert grid_factors("EPSG:32732", e, n).convergence_rad < 0


def test_point_scale_is_k0_one_plus_x2_over_2r2():
    # 150 km east of the central meridian at 45 deg N
    lat = 45.0
    e = 650000.0
    _, n = _grid(9.0, lat)
    f = grid_factors(UTM32, e, n)
    x = (e - 500000.0) / K0  # distance on the ellipsoid, not the grid
    R = gaussian_radius_m(f.latitude_rad)
    hand = K0 * (1.0 + x * x / (2.0 * R * R))
    assert f.point_scale == pytest.approx(hand, abs=2e-8)
    # on the central meridian k = k0 exactly
    e0, n0 = _grid(9.0, lat)
    assert grid_factors(UTM32, e0, n0).point_scale == pytest.approx(K0, abs=1e-9)  # PROJ differentiates numerically


def test_convergence_from_a_meridian_step():
    # independent: project a 1e-5 deg step north along the meridian; its grid bearing is -gamma
    lon, lat = 11.7, 28.0
    e1, n1 = _grid(lon, lat)
    e2, n2 = _grid(lon, lat + 1e-5)
    f = grid_factors(UTM32, e1, n1)
    assert -math.atan2(e2 - e1, n2 - n1) == pytest.approx(f.convergence_rad, abs=2e-8)


def test_scale_from_a_geodesic():
    # independent: grid distance / ellipsoid (geodesic) distance of a 100 m line is k
    from pyproj import Geod, Transformer

    e, n = 700000.0, 3100000.0
    f = grid_factors(UTM32, e, n)
    inv = Transformer.from_crs(UTM32, "EPSG:4326", always_xy=True)
    lon1, lat1 = inv.transform(e - 50.0, n - 20.0)
    lon2, lat2 = inv.transform(e + 50.0, n + 20.0)
    _, _, s = Geod(ellps="WGS84").inv(lon1, lat1, lon2, lat2)
    assert math.hypot(100.0, 40.0) / s == pytest.approx(f.point_scale, abs=2e-9)


def test_height_reduction_and_combined_scale_hand_case():
    # 500 m up at 45 deg: R / (R + h) with R = sqrt(M N)
    e, n = _grid(9.0, 45.0)
    f = grid_factors(UTM32, e, n, height_m=500.0)
    a, inv_f = 6378137.0, 298.257223563
    e2 = (2 - 1 / inv_f) / inv_f
    s2 = math.sin(math.radians(45.0)) ** 2
    M = a * (1 - e2) / (1 - e2 * s2) ** 1.5
    N = a / math.sqrt(1 - e2 * s2)
    R = math.sqrt(M * N)
    assert f.radius_m == pytest.approx(R, rel=1e-12)
    assert f.height_reduction == pytest.approx(R / (R + 500.0), rel=1e-15)
    assert f.combined_scale == pytest.approx(K0 * R / (R + 500.0), abs=1e-9)
    # a 100.000 m horizontal ground distance is this long on the grid
    assert 100.0 * f.combined_scale == pytest.approx(99.95216, abs=1e-5)


@given(st.floats(-5e3, 5e3), st.floats(-5e3, 5e3), st.floats(-50, 50), st.floats(-0.05, 0.05),
       st.floats(0.999, 1.001))
@settings(max_examples=60, deadline=None)
def test_grid_local_round_trip_and_rotation(de, dn, dh, gamma, k):
    from trolley.projection import GridFactors

    f = GridFactors(0.5, 0.2, gamma, k, 0.0, 6.371e6)
    d = np.array([de, dn, dh])
    loc = f.grid_to_local(d)
    assert np.allclose(f.local_to_grid(loc), d, atol=1e-9)
    # length / k, height untouched, true azimuth = grid bearing + gamma
    assert math.hypot(*loc[:2]) == pytest.approx(math.hypot(de, dn) / k, abs=1e-9)
    assert loc[2] == dh
    if math.hypot(de, dn) > 1.0:
        az_t = math.atan2(loc[0], loc[1])
        az_g = math.atan2(de, dn)
        assert math.remainder(az_t - az_g - gamma, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)


def test_site_factors_is_the_centroid():
    pts = np.array([[699950.0, 3099950.0, 40.0], [700050.0, 3100050.0, 60.0]])
    a = site_factors("EPSG:32650", pts)
    b = grid_factors("EPSG:32650", 700000.0, 3100000.0, 50.0)
    assert a == b


def test_crs_info_and_errors():
    info = crs_info(" EPSG:32650 ")
    assert info.epsg == 32650 and "UTM zone 50N" in info.name and info.vertical_datum == ""
    comp = crs_info("EPSG:25832+5783")  # ETRS89 / UTM 32N + DHHN92 height
    assert comp.epsg == 25832 and comp.vertical_datum == "DHHN92 height"
    assert crs_info("+proj=tmerc +lat_0=0 +lon_0=117 +k=1 +x_0=500000 +y_0=0 +ellps=GRS80 +units=m").name
    with pytest.raises(CrsError, match="not a projected CRS"):
        crs_info("EPSG:4326")
    with pytest.raises(CrsError, match="not a coordinate reference system"):
        crs_info("EPSG:99999999")
    with pytest.raises(CrsError, match="empty"):
        crs_info("  ")
    with pytest.raises(CrsError, match="not metres"):
        crs_info("EPSG:2263")  # NAD83 / New York Long Island (ftUS)
    with pytest.raises(CrsError, match="not conformal"):
        grid_factors("EPSG:3035", 5321000.0, 2210000.0)  # LAEA Europe, 1000 km off its centre

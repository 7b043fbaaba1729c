"""Pin-hole camera with Brown-Conrady distortion and a laser plane (Escalona 2021 Sec. 4).

A camera is calibrated by its intrinsic matrix ``K`` (M^int), its pose in the TGMS frame
(``R_tgms_cam`` = A^{tgms,cam}, camera axes in the TGMS frame, and ``t_tgms_cam_m`` = u_cam^tgms),
four distortion coefficients [k1, k2, p1, p2] and the laser plane A x + B y + C z + D = 0 in the
TGMS frame. Camera axes follow the usual computer-vision convention (x right in the image, y down,
z along the optical axis).

* :func:`project` is Eq. 17 with M^ext of Eq. 18, plus the Brown-Conrady distortion of the
  normalised image coordinates (used by the simulator).
* :func:`pixels_to_tgms` solves Eq. 19 in closed form: undistort the pixel, build the viewing ray
  and intersect it with the laser plane. Vectorised over any number of pixels.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Camera:
    """One laser-line camera (SI units, TGMS frame FRD).

    Attributes
    ----------
    K : (3, 3) intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], pixels.
    R_tgms_cam : (3, 3) rotation, columns are the camera axes in the TGMS frame (A^{tgms,cam}).
    t_tgms_cam_m : (3,) camera centre in the TGMS frame.
    distortion : (4,) Brown-Conrady [k1, k2, p1, p2].
    laser_plane : (4,) [A, B, C, D] with A x + B y + C z + D = 0 in the TGMS frame.
    image_size_px : (width, height) of the sensor; pixels outside are not detected.
    name : "left" or "right".
    """

    K: np.ndarray
    R_tgms_cam: np.ndarray
    t_tgms_cam_m: np.ndarray
    distortion: np.ndarray = field(default_factory=lambda: np.zeros(4))
    laser_plane: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))
    image_size_px: tuple[int, int] = (648, 488)
    name: str = "camera"


def _distort(xn: np.ndarray, yn: np.ndarray, dist: np.ndarray):
    k1, k2, p1, p2 = dist
    r2 = xn * xn + yn * yn
    radial = 1.0 + k1 * r2 + k2 * r2 * r2
    xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
    return xd, yd


def _undistort(xd: np.ndarray, yd: np.ndarray, dist: np.ndarray, iterations: int = 8):
    """Invert :func:`_distort` by fixed-point iteration (converges for the mild lenses used here)."""
    if not np.any(dist):
        return xd, yd
    k1, k2, p1, p2 = dist
    xn, yn = xd.copy(), yd.copy()
    for _ in range(iterations):
        r2 = xn * xn + yn * yn
        radial = 1.0 + k1 * r2 + k2 * r2 * r2
        dx = 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
        dy = p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
        xn = (xd - dx) / radial
        yn = (yd - dy) / radial
    return xn, yn


def project(cam: Camera, points_tgms: np.ndarray):
    """Pixel coordinates of TGMS-frame points (Escalona 2021 Eq. 17-18 with lens distortion).

    Parameters
    ----------
    cam : Camera.
    points_tgms : (n, 3) points in the TGMS frame, m.

    Returns
    -------
    u_px, v_px, depth_m : arrays (n,); depth is the coordinate along the optical axis (> 0 in front).
    """
    pc = (np.asarray(points_tgms) - cam.t_tgms_cam_m) @ cam.R_tgms_cam   # = A^T (u - u_cam)
    depth = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xn, yn = pc[:, 0] / depth, pc[:, 1] / depth
    xd, yd = _distort(xn, yn, cam.distortion)
    K = cam.K
    u = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
    v = K[1, 1] * yd + K[1, 2]
    return u, v, depth


def pixels_to_tgms(cam: Camera, u_px: np.ndarray, v_px: np.ndarray) -> np.ndarray:
    """Points on the laser plane seen at pixels (u, v): the solution of Escalona 2021 Eq. 19.

    Parameters
    ----------
    cam : Camera.
    u_px, v_px : pixel coordinates (n,).

    Returns
    -------
    (n, 3) points in the TGMS frame, m; rows are NaN where the ray misses the plane (parallel or
    behind the camera).

    References
    ----------
    Escalona 2021 Eq. 17-19.
    """
    K = cam.K
    yd = (np.asarray(v_px, float) - K[1, 2]) / K[1, 1]
    xd = (np.asarray(u_px, float) - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    xn, yn = _undistort(xd, yd, cam.distortion)
    rays = np.column_stack([xn, yn, np.ones_like(xn)]) @ cam.R_tgms_cam.T   # camera -> TGMS axes
    n = cam.laser_plane[:3]
    denom = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -(cam.laser_plane[3] + n @ cam.t_tgms_cam_m) / denom
    lam = np.where((np.abs(denom) > 1e-12) & (lam > 0), lam, np.nan)
    return cam.t_tgms_cam_m + lam[:, None] * rays


def check_camera(cam: Camera) -> None:
    """Raise ValueError naming the camera if its calibration is unusable: K or R not valid, or the
    laser plane does not meet the camera's view (the rays through the image centre, its corners
    and edge midpoints all miss it)."""
    K = np.asarray(cam.K, float)
    # the zeros too: a K written transposed ([[fx,0,0],[0,fy,0],[cx,cy,1]]) passed and left 98 % of
    # the frames flagged with exit 0 (bug hunt 2026-11-27)
    if (K.shape != (3, 3) or K[0, 0] <= 0 or K[1, 1] <= 0 or abs(K[2, 2] - 1) > 1e-9
            or np.any(np.abs([K[1, 0], K[2, 0], K[2, 1]]) > 1e-9)):
        raise ValueError(f"camera {cam.name}: K must be [[fx,0,cx],[0,fy,cy],[0,0,1]] with fx, fy > 0 "
                         f"(got {np.array2string(K, separator=',').replace(chr(10), '')})")
    R = np.asarray(cam.R_tgms_cam, float)
    if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError(f"camera {cam.name}: R_tgms_cam is not a rotation matrix")
    if np.linalg.norm(cam.laser_plane[:3]) < 1e-12:
        raise ValueError(f"camera {cam.name}: laser_plane normal [A, B, C] is zero")
    plane = np.asarray(cam.laser_plane, float)
    centre = np.asarray(cam.t_tgms_cam_m, float)
    if abs(plane[:3] @ centre + plane[3]) / np.linalg.norm(plane[:3]) < 1e-6:
        # every ray meets it at the camera itself: no triangulation (the message said "parallel to
        # it or meet it behind the camera", which sent one looking at the rotation)
        raise ValueError(f"camera {cam.name}: the laser plane passes through the camera centre t_tgms_cam_m "
                         "(A x + B y + C z + D = 0 there): the camera must view the laser line from off its plane")
    w, h = cam.image_size_px
    # the centre, the four corners and the edge midpoints: a plane seen only near an edge of the
    # image (a camera looking past the rail) still meets the view
    u = np.array([w / 2.0, 0.0, w, 0.0, w, w / 2.0, w / 2.0, 0.0, w])
    v = np.array([h / 2.0, 0.0, 0.0, h, h, 0.0, h, h / 2.0, h / 2.0])
    p = pixels_to_tgms(cam, u, v)
    if not np.any(np.all(np.isfinite(p), axis=1)):
        raise ValueError(f"camera {cam.name}: the laser plane does not meet the camera's view "
                         "(the rays through the image centre, corners and edge midpoints are parallel to "
                         "it or meet it behind the camera)")


def look_at(centre: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Rotation A^{tgms,cam} of a camera at ``centre`` whose optical axis points at ``target``, with
    image rows (camera y) as close as possible to the TGMS x axis (forward)."""
    z = np.asarray(target, float) - np.asarray(centre, float)
    z /= np.linalg.norm(z)
    y = np.array([1.0, 0.0, 0.0]) - z[0] * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    return np.column_stack([x, y, z])

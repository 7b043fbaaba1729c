"""Rail-head profiles (EN 13674-1 60E1 and 54E1) and their signed-distance field.

The head of a new rail is made of standard arcs and lines (Escalona 2021 Sec. 5, Fig. 6b): a R300
crown, R80 shoulders, R13 gauge/field corners and 1:20 head flanks. The transition abscissae between
the arcs are not all printed in the standard's summary tables; here the R300/R80 tangency is placed
at the abscissa given in :data:`HEADS` and the R80/R13/flank tangencies follow from tangency, so the
shape is tangent-continuous and within a few hundredths of a millimetre of the drawing where the
camera sees it (crown, gauge corner, gauge face).

Rail-profile frame (FRD track axes, one per rail; Escalona 2021 Eq. 7, 9): the head is tilted
towards the track centre by the rail inclination 1:N; the origin is at the *gauge point*
laterally (innermost point of the head 14 mm below the running surface) and at the running surface
(highest point of the tilted head) vertically. Coordinates below are those of the RIGHT rail
(gauge face towards -y); the left rail is its mirror image in y.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

#: Depth of the gauge point below the running surface, m (EN 13848-1).
GAUGE_POINT_DEPTH_M = 0.014


@dataclass(frozen=True)
class HeadShape:
    """Dimensions of one rail head (m): head width at the gauge-point depth, crown radius, shoulder
    radius, corner radius, half-width at which the crown arc ends, flank slope (1:N) and depth to
    which the flank is modelled."""

    name: str
    width_m: float
    r_crown_m: float = 0.300
    r_shoulder_m: float = 0.080
    r_corner_m: float = 0.013
    crown_half_width_m: float = 0.0102
    flank_slope: float = 20.0
    flank_depth_m: float = 0.034


#: The two heads the TGMS knows (EN 13674-1).
HEADS: dict[str, HeadShape] = {
    "60E1": HeadShape("60E1", width_m=0.072, crown_half_width_m=0.0102, flank_depth_m=0.0375),
    "54E1": HeadShape("54E1", width_m=0.070, crown_half_width_m=0.0100, flank_depth_m=0.0350),
}


def head_shape(name: str) -> HeadShape:
    """The head called ``name`` ("60E1" or "54E1"); ValueError otherwise."""
    try:
        return HEADS[name]
    except KeyError:
        raise ValueError(f"unknown rail profile {name!r}; known: {', '.join(HEADS)}") from None


def _primitives(h: HeadShape):
    """Arcs and lines of the symmetric head in (eta, zeta): eta lateral (+ to the right), zeta depth
    below the crown (down +). Returns a list of ('arc', cx, cz, r, a0, a1) with angles measured of
    the outward normal from the -zeta axis (up), and ('line', x0, z0, x1, z1)."""
    c300 = np.array([0.0, h.r_crown_m])
    g1 = np.arcsin(h.crown_half_width_m / h.r_crown_m)
    c80 = c300 + (h.r_crown_m - h.r_shoulder_m) * np.array([np.sin(g1), -np.cos(g1)])
    # flank: through (w/2, gauge depth), narrower at the top by 1:N
    d = np.array([1.0, h.flank_slope]) / np.hypot(1.0, h.flank_slope)
    n_in = np.array([-d[1], d[0]])          # points into the head (towards -eta)
    p_w = np.array([h.width_m / 2, GAUGE_POINT_DEPTH_M])
    base = p_w + h.r_corner_m * n_in
    # |base + lam d - c80| = r80 - r13
    rr = h.r_shoulder_m - h.r_corner_m
    b = base - c80
    bq = 2 * b @ d
    cq = b @ b - rr ** 2
    lam = (-bq - np.sqrt(bq ** 2 - 4 * cq)) / 2     # the upper of the two solutions
    c13 = base + lam * d
    t80 = c80 + h.r_shoulder_m * (c13 - c80) / np.linalg.norm(c13 - c80)
    t13 = c13 - h.r_corner_m * n_in
    a80 = np.arctan2(t80[0] - c80[0], -(t80[1] - c80[1]))
    a13 = np.arctan2(-n_in[0], n_in[1])             # outward normal at the flank tangency
    flank_end = t13 + d * (h.flank_depth_m - t13[1]) / d[1]
    prims = [("arc", 0.0, c300[1], h.r_crown_m, -g1, g1)]
    for sgn in (1.0, -1.0):
        if sgn > 0:
            prims.append(("arc", c80[0], c80[1], h.r_shoulder_m, g1, a80))
            prims.append(("arc", c13[0], c13[1], h.r_corner_m, a80, a13))
            prims.append(("line", t13[0], t13[1], flank_end[0], flank_end[1]))
        else:
            prims.append(("arc", -c80[0], c80[1], h.r_shoulder_m, -a80, -g1))
            prims.append(("arc", -c13[0], c13[1], h.r_corner_m, -a13, -a80))
            prims.append(("line", -t13[0], t13[1], -flank_end[0], flank_end[1]))
    return prims


def _polyline(h: HeadShape, step_m: float = 2e-5) -> np.ndarray:
    """Dense outline of the symmetric head from the left flank end to the right one, (n, 2)."""
    prims = _primitives(h)
    order = [6, 5, 4, 0, 1, 2, 3]
    pts = []
    for i in order:
        p = prims[i]
        if p[0] == "arc":
            _, cx, cz, r, a0, a1 = p
            n = max(int(abs(a1 - a0) * r / step_m), 2)
            a = np.linspace(a0, a1, n)
            seg = np.column_stack([cx + r * np.sin(a), cz - r * np.cos(a)])
        else:
            _, x0, z0, x1, z1 = p
            n = max(int(np.hypot(x1 - x0, z1 - z0) / step_m), 2)
            tt = np.linspace(0.0, 1.0, n)
            seg = np.column_stack([x0 + tt * (x1 - x0), z0 + tt * (z1 - z0)])
            if i == 6:
                seg = seg[::-1]
        pts.append(seg)
    return np.vstack(pts)


def _signed_distance_exact(h: HeadShape, eta: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """Exact signed distance (> 0 outside the steel) from points to the head outline (arcs and
    lines, clamped to their ends); the sign comes from the outward normal of the nearest primitive
    (the head is convex)."""
    best = np.full(eta.shape, np.inf)
    sign = np.ones(eta.shape)
    for p in _primitives(h):
        if p[0] == "arc":
            _, cx, cz, r, a0, a1 = p
            ang = np.arctan2(eta - cx, -(zeta - cz))
            inside = (ang >= min(a0, a1)) & (ang <= max(a0, a1))
            rad = np.hypot(eta - cx, zeta - cz)
            d = np.abs(rad - r)
            sg = np.sign(rad - r)
            ends_d, ends_s = [], []
            for a in (a0, a1):
                ex, ez = cx + r * np.sin(a), cz - r * np.cos(a)
                ends_d.append(np.hypot(eta - ex, zeta - ez))
                ends_s.append(np.sign((eta - ex) * np.sin(a) - (zeta - ez) * np.cos(a)))
            first = ends_d[0] <= ends_d[1]
            de = np.where(first, ends_d[0], ends_d[1])
            se = np.where(first, ends_s[0], ends_s[1])
            d = np.where(inside, d, de)
            sg = np.where(inside, sg, se)
        else:
            _, x0, z0, x1, z1 = p
            vx, vz = x1 - x0, z1 - z0
            L2 = vx * vx + vz * vz
            t = np.clip(((eta - x0) * vx + (zeta - z0) * vz) / L2, 0.0, 1.0)
            ex, ez = eta - (x0 + t * vx), zeta - (z0 + t * vz)
            d = np.hypot(ex, ez)
            # outward normal of a flank: away from the head centre line (eta = 0)
            nx, nz = vz, -vx
            if nx * x0 < 0:
                nx, nz = -nx, -nz
            sg = np.sign(ex * nx + ez * nz)
        closer = d < best
        best = np.where(closer, d, best)
        sign = np.where(closer, sg, sign)
    return np.where(sign < 0, -best, best)


@dataclass(frozen=True)
class RailProfile:
    """A rail head placed in its rail-profile frame (right rail), with its signed-distance field.

    Attributes
    ----------
    name : "60E1" or "54E1".
    inclination : rail inclination 1:N (0 = upright).
    outline_m : (n, 2) outline (y, z) in the rail-profile frame, gauge corner included.
    grid_y0_m, grid_z0_m, grid_step_m : origin and spacing of the distance grid.
    sdf_m : (ny, nz) signed distance, > 0 outside the steel.
    grad : (2, ny, nz) gradient of ``sdf_m`` (unit outward normal near the outline).
    """

    name: str
    inclination: float
    outline_m: np.ndarray
    grid_y0_m: float
    grid_z0_m: float
    grid_step_m: float
    sdf_m: np.ndarray
    grad: np.ndarray

    def signed_distance(self, y: np.ndarray, z: np.ndarray):
        """Bilinear lookup of the signed distance and its gradient at points (y, z) of the
        rail-profile frame. Returns (d, gy, gz, inside_grid)."""
        fy = (y - self.grid_y0_m) / self.grid_step_m
        fz = (z - self.grid_z0_m) / self.grid_step_m
        ny, nz = self.sdf_m.shape
        ok = (fy >= 0) & (fy < ny - 1) & (fz >= 0) & (fz < nz - 1)
        fy = np.clip(fy, 0, ny - 1.000001)
        fz = np.clip(fz, 0, nz - 1.000001)
        iy = fy.astype(np.intp)
        iz = fz.astype(np.intp)
        ty = fy - iy
        tz = fz - iz
        w00 = (1 - ty) * (1 - tz)
        w10 = ty * (1 - tz)
        w01 = (1 - ty) * tz
        w11 = ty * tz
        flat = iy * nz + iz
        out = []
        for arr in (self.sdf_m.ravel(), self.grad[0].ravel(), self.grad[1].ravel()):
            out.append(arr[flat] * w00 + arr[flat + nz] * w10 + arr[flat + 1] * w01
                       + arr[flat + nz + 1] * w11)
        return out[0], out[1], out[2], ok


def _head_to_rp(h: HeadShape, inclination: float):
    """Rotation angle and offset taking symmetric-head (eta, zeta) to right-rail-profile (y, z)."""
    beta = np.arctan(1.0 / inclination) if inclination else 0.0
    # right rail leans towards the track centre (-y): FRD roll of -beta
    ang = -beta
    c, s = np.cos(ang), np.sin(ang)
    line = _polyline(h)
    y = c * line[:, 0] - s * line[:, 1]
    z = s * line[:, 0] + c * line[:, 1]
    z_top = z.min()
    band = np.abs(z - (z_top + GAUGE_POINT_DEPTH_M)) < 2e-5
    # gauge face is the -y side of the right rail
    y_g = y[band & (y < y[np.argmin(z)])].min()
    return ang, y_g, z_top


@lru_cache(maxsize=8)
def rail_profile(name: str, inclination: float = 40.0, step_m: float = 1.5e-4) -> RailProfile:
    """The rail-profile model for head ``name`` tilted 1:``inclination`` (cached).

    Parameters
    ----------
    name : "60E1" or "54E1".
    inclination : N of the 1:N rail inclination towards the track centre; 0 for upright rails.
    step_m : spacing of the signed-distance grid (0.15 mm keeps the bilinear error below 1 um).

    Returns
    -------
    RailProfile

    References
    ----------
    Escalona 2021 Sec. 5 and Fig. 6b; EN 13674-1 head radii; EN 13848-1 gauge point.
    """
    h = head_shape(name)
    ang, y_g, z_top = _head_to_rp(h, inclination)
    c, s = np.cos(ang), np.sin(ang)
    line = _polyline(h)
    outline = np.column_stack([c * line[:, 0] - s * line[:, 1] - y_g,
                               s * line[:, 0] + c * line[:, 1] - z_top])
    y0, y1, z0, z1 = -0.025, 0.100, -0.025, 0.065
    gy = np.arange(y0, y1 + step_m / 2, step_m)
    gz = np.arange(z0, z1 + step_m / 2, step_m)
    Y, Z = np.meshgrid(gy, gz, indexing="ij")
    # back to the symmetric head's coordinates for the exact distance
    yy, zz = Y + y_g, Z + z_top
    eta = c * yy + s * zz
    zeta = -s * yy + c * zz
    sdf = _signed_distance_exact(h, eta, zeta)
    grad = np.array(np.gradient(sdf, step_m, step_m))
    return RailProfile(name, float(inclination), outline, y0, z0, step_m, sdf, grad)


def outline_normals(outline: np.ndarray) -> np.ndarray:
    """Unit outward normals (pointing out of the steel, i.e. up/outwards) along an outline."""
    t = np.gradient(outline, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    n = np.column_stack([t[:, 1], -t[:, 0]])
    # the crown normal must point up (-z)
    if n[np.argmin(outline[:, 1]), 1] > 0:
        n = -n
    return n

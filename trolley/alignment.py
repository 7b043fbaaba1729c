"""Design track geometry: horizontal alignment, vertical profile and applied cant.

The horizontal alignment is a chain of straights, circular arcs and clothoid transitions
(curvature linear in chainage). Positions are exact: arcs in closed form, clothoids with the
Fresnel integrals (``scipy.special.fresnel``), never a polyline. The vertical profile is a chain
of constant grades joined by symmetric parabolic vertical curves centred on the PVIs; the
applied cant is linear in height between cant stations. Evaluation and projection are vectorised over
chainage / point arrays.

The curvatures returned by :meth:`Alignment.evaluate` are the ones that drive the track-frame
kinematics of Escalona et al. (2021), Eq. 4-5: horizontal curvature ``rho_h``, vertical
curvature ``rho_v``, twist curvature ``rho_tw`` and the spatial derivative of the horizontal
curvature ``rho_h'`` (``drho_h_ds``).

Conventions (see ``docs/conventions.md``, section "Design geometry"):

- grid coordinates E, N, H (H up); ``heading_rad`` is the grid bearing, clockwise from grid
  north towards east, in [0, 2 pi) (the yaw of an NED/FRD frame);
- ``rho_h = d(heading)/ds`` > 0 when the track turns right (clockwise seen from above);
- ``slope_rad = arctan(dH/ds)`` > 0 when rising; ``rho_v = d(slope)/ds``;
- ``cant_rad`` is the roll of the track plane in the FRD trolley frame, > 0 when the LEFT rail
  is higher (the outer rail of a right-hand curve); ``rho_tw = d(cant)/ds``;
- every derivative is taken with respect to the chainage ``s`` (the horizontal arc length of
  the alignment, as in design practice); with grades of 1 % the 3-D arc length differs from it
  by 5e-5 relative.
- Outside [start, end] the alignment continues on its end tangents (straight, constant grade,
  constant cant); :class:`Projection` flags such points with ``inside = False``.

References
----------
Escalona, J. L., Urda, P., Munoz, S. (2021). A track geometry measuring system based on
multibody kinematics, inertial sensors and computer vision. Sensors 21(3), 683. Eq. 4-5.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, Union

import numpy as np
from scipy.special import fresnel

from trolley.stationing import Stationing

__all__ = [
    "Line",
    "Arc",
    "Clothoid",
    "Element",
    "HorizontalAlignment",
    "HorizontalSample",
    "VerticalProfile",
    "CantProfile",
    "Alignment",
    "AlignmentSample",
    "Projection",
]

#: Clothoids with |dk/ds| below this (1/m^2) are evaluated as arcs (position error < 1e-9 m
#: for elements up to 1 km).
_CLOTHOID_MIN_RATE_1_M2 = 1e-20
#: Above this Fresnel argument the Fresnel differences lose digits; use Gauss-Legendre instead.
_FRESNEL_MAX_ARG = 20.0
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(32)
_TWO_PI = 2.0 * np.pi


# --------------------------------------------------------------------------------------------
# horizontal elements
# --------------------------------------------------------------------------------------------
def _check_length(length_m: float, what: str) -> None:
    if not (np.isfinite(length_m) and length_m > 0.0):
        raise ValueError(f"{what}: length_m must be finite and > 0, got {length_m!r}")


def _check_finite(value: float, what: str) -> None:
    if not np.isfinite(value):
        raise ValueError(f"{what} must be finite, got {value!r}")


@dataclass(frozen=True)
class Line:
    """Straight: zero curvature.

    Attributes
    ----------
    length_m : length along the chainage, m (> 0).
    """

    length_m: float

    def __post_init__(self) -> None:
        _check_length(self.length_m, "Line")

    @property
    def curvature_start_1_m(self) -> float:
        return 0.0

    @property
    def curvature_end_1_m(self) -> float:
        return 0.0


@dataclass(frozen=True)
class Arc:
    """Circular arc of constant curvature.

    Attributes
    ----------
    length_m : arc length, m (> 0).
    curvature_1_m : 1/R, positive when turning right (clockwise seen from above).
    """

    length_m: float
    curvature_1_m: float

    def __post_init__(self) -> None:
        _check_length(self.length_m, "Arc")
        _check_finite(self.curvature_1_m, "Arc curvature_1_m")

    @property
    def curvature_start_1_m(self) -> float:
        return float(self.curvature_1_m)

    @property
    def curvature_end_1_m(self) -> float:
        return float(self.curvature_1_m)


@dataclass(frozen=True)
class Clothoid:
    """Clothoid transition: curvature linear in chainage from start to end value.

    Attributes
    ----------
    length_m : length, m (> 0).
    curvature_start_1_m, curvature_end_1_m : curvature at the two ends, 1/m, positive when
        turning right. The clothoid parameter is A = sqrt(L / |k_end - k_start|).
    """

    length_m: float
    curvature_start_1_m: float
    curvature_end_1_m: float

    def __post_init__(self) -> None:
        _check_length(self.length_m, "Clothoid")
        _check_finite(self.curvature_start_1_m, "Clothoid curvature_start_1_m")
        _check_finite(self.curvature_end_1_m, "Clothoid curvature_end_1_m")


Element = Union[Line, Arc, Clothoid]


def _displacement(u, heading0, k0, c):
    """Complex displacement (N + iE) from an element start after a local length ``u``.

    Integrates exp(i theta(v)) for v in [0, u], theta(v) = heading0 + k0 v + c v^2 / 2: in
    closed form for arcs/straights (chord along the mean direction), with the Fresnel integrals
    for clothoids. All arguments broadcast; ``u`` may be negative.
    """
    u = np.asarray(u, dtype=float)
    heading0, k0, c = np.broadcast_arrays(np.asarray(heading0, float), np.asarray(k0, float),
                                          np.asarray(c, float))
    heading0 = np.broadcast_to(heading0, u.shape)
    k0 = np.broadcast_to(k0, u.shape)
    c = np.broadcast_to(c, u.shape)
    out = np.empty(u.shape, dtype=complex)

    arc = np.abs(c) < _CLOTHOID_MIN_RATE_1_M2
    if np.any(arc):
        ua, ka = u[arc], k0[arc]
        # chord 2 sin(k u / 2) / k = u sin(x) / x, x = k u / 2, along the mean direction
        x = 0.5 * ka * ua
        small = np.abs(x) < 1e-4
        x_safe = np.where(small, 1.0, x)
        ratio = np.where(small, 1.0 - x * x / 6.0, np.sin(x_safe) / x_safe)
        out[arc] = ua * ratio * np.exp(1j * (heading0[arc] + x))

    clo = ~arc
    if np.any(clo):
        uc, kc, cc, hc = u[clo], k0[clo], c[clo], heading0[clo]
        sg = np.sign(cc)
        scale = np.sqrt(np.abs(cc) / np.pi)
        w0 = kc / cc  # distance from the zero-curvature point of the clothoid to the start
        t0 = scale * w0
        t1 = scale * (uc + w0)
        res = np.empty(uc.shape, dtype=complex)
        fres = (np.abs(t0) <= _FRESNEL_MAX_ARG) & (np.abs(t1) <= _FRESNEL_MAX_ARG)
        if np.any(fres):
            s0, c0 = fresnel(t0[fres])
            s1, c1 = fresnel(t1[fres])
            phi0 = hc[fres] - 0.5 * kc[fres] * w0[fres]
            res[fres] = (np.exp(1j * phi0) / scale[fres]
                         * ((c1 - c0) + 1j * sg[fres] * (s1 - s0)))
        gl = ~fres
        if np.any(gl):
            # near-circular clothoid: the Fresnel differences would cancel; Gauss-Legendre
            # with 32 nodes is exact to rounding for turning angles up to several radians
            ug = uc[gl][:, None]
            v = 0.5 * ug * (_GL_NODES[None, :] + 1.0)
            theta = hc[gl][:, None] + kc[gl][:, None] * v + 0.5 * cc[gl][:, None] * v * v
            res[gl] = 0.5 * uc[gl] * (np.exp(1j * theta) @ _GL_WEIGHTS)
        out[clo] = res
    return out


@dataclass
class HorizontalSample:
    """Horizontal alignment evaluated at chainages (arrays of the shape of ``s``)."""

    E_m: np.ndarray
    N_m: np.ndarray
    heading_rad: np.ndarray
    rho_h_1_m: np.ndarray
    drho_h_ds_1_m2: np.ndarray


class HorizontalAlignment:
    """A chain of :class:`Line`, :class:`Arc` and :class:`Clothoid` elements.

    Build with :meth:`from_elements` (each element starts where the previous ends, with the
    same heading: G1 continuity by construction) or :meth:`from_anchored_elements` (each element
    starts at its own start point and heading, as a design file gives them, so that a small
    direction break at one join does not move every later element; the gap and the direction
    break at each join are kept in ``join_gap_m`` and ``join_turn_rad``).

    Attributes
    ----------
    elements : tuple of the elements.
    start_E_m, start_N_m, start_heading_rad, start_chainage_m : start of the first element.
    element_chainage_m : (n+1,) chainage of each element start, and of the end.
    element_E_m, element_N_m, element_heading_rad : (n+1,) position and heading at the start of
        each element and at the end of the last one (heading not wrapped).
    element_end_E_m, element_end_N_m, element_end_heading_rad : (n,) where each element's own
        geometry ends (equal to the next element's start when chained).
    join_gap_m, join_turn_rad : (n-1,) distance and heading change from the end of element i to
        the start of element i+1 (zero when chained).
    """

    def __init__(self, start_E_m: float, start_N_m: float, start_heading_rad: float,
                 elements: Sequence[Element], start_chainage_m: float = 0.0,
                 anchors: tuple[Sequence[float], Sequence[float], Sequence[float]] | None = None
                 ) -> None:
        elements = tuple(elements)
        if not elements:
            raise ValueError("a horizontal alignment needs at least one element")
        for i, el in enumerate(elements):
            if not isinstance(el, (Line, Arc, Clothoid)):
                raise TypeError(f"element {i} is {type(el).__name__}, expected Line, Arc or Clothoid")
        for name, v in (("start_E_m", start_E_m), ("start_N_m", start_N_m),
                        ("start_heading_rad", start_heading_rad),
                        ("start_chainage_m", start_chainage_m)):
            _check_finite(float(v), name)
        self.elements = elements
        self.start_E_m = float(start_E_m)
        self.start_N_m = float(start_N_m)
        self.start_heading_rad = float(start_heading_rad)
        self.start_chainage_m = float(start_chainage_m)

        n = len(elements)
        lengths = np.array([el.length_m for el in elements], dtype=float)
        self._k0 = np.array([el.curvature_start_1_m for el in elements], dtype=float)
        k1 = np.array([el.curvature_end_1_m for el in elements], dtype=float)
        self._c = (k1 - self._k0) / lengths
        self._length = lengths
        s = np.empty(n + 1)
        s[0] = self.start_chainage_m
        s[1:] = self.start_chainage_m + np.cumsum(lengths)
        h = np.empty(n + 1)
        z = np.empty(n + 1, dtype=complex)  # N + iE relative to the start point (keeps digits)
        turn = self._k0 * lengths + 0.5 * self._c * lengths * lengths
        if anchors is None:
            h[0] = self.start_heading_rad
            z[0] = 0.0
            for i in range(n):  # a handful of elements: chain their end states
                z[i + 1] = z[i] + _displacement(lengths[i], h[i], self._k0[i], self._c[i])
                h[i + 1] = h[i] + turn[i]
            end_z, end_h = z[1:].copy(), h[1:].copy()
        else:
            a_E, a_N, a_h = (np.asarray(a, dtype=float).ravel() for a in anchors)
            if not (a_E.shape == a_N.shape == a_h.shape == (n,)):
                raise ValueError(f"anchors must hold {n} start points and headings, one per element")
            if not all(np.all(np.isfinite(a)) for a in (a_E, a_N, a_h)):
                raise ValueError("anchor start points and headings must be finite")
            if a_E[0] != self.start_E_m or a_N[0] != self.start_N_m or a_h[0] != self.start_heading_rad:
                raise ValueError("the first anchor must be the start point and heading")
            z[:n] = (a_N - self.start_N_m) + 1j * (a_E - self.start_E_m)
            # unwrap so that headings change continuously across joins
            h[:n] = a_h[0] + np.concatenate(([0.0], np.cumsum(
                np.remainder(np.diff(a_h) - turn[:-1] + np.pi, _TWO_PI) - np.pi + turn[:-1])))
            end_z = z[:n] + _displacement(lengths, h[:n], self._k0, self._c)
            end_h = h[:n] + turn
            z[n], h[n] = end_z[-1], end_h[-1]
        self.element_end_E_m = end_z.imag + self.start_E_m
        self.element_end_N_m = end_z.real + self.start_N_m
        self.element_end_heading_rad = end_h
        self.join_gap_m = np.abs(z[1:n] - end_z[:-1])
        self.join_turn_rad = h[1:n] - end_h[:-1]
        self.element_chainage_m = s
        self.element_heading_rad = h
        self._origin = complex(self.start_N_m, self.start_E_m)
        self._z = z
        self.element_E_m = z.imag + self.start_E_m
        self.element_N_m = z.real + self.start_N_m

    @classmethod
    def from_elements(cls, start_E_m: float, start_N_m: float, start_heading_rad: float,
                      elements: Sequence[Element], start_chainage_m: float = 0.0
                      ) -> "HorizontalAlignment":
        """Chain ``elements`` from a start point and grid bearing.

        Parameters
        ----------
        start_E_m, start_N_m : grid coordinates of the start, m.
        start_heading_rad : grid bearing at the start (clockwise from north), rad.
        elements : sequence of :class:`Line`, :class:`Arc`, :class:`Clothoid`.
        start_chainage_m : chainage of the start, m.

        Returns
        -------
        HorizontalAlignment
        """
        return cls(start_E_m, start_N_m, start_heading_rad, elements, start_chainage_m)

    @classmethod
    def from_anchored_elements(cls, start_E_m, start_N_m, start_heading_rad,
                               elements: Sequence[Element], start_chainage_m: float = 0.0
                               ) -> "HorizontalAlignment":
        """Elements each starting at its own point and grid bearing (no chaining).

        Parameters
        ----------
        start_E_m, start_N_m, start_heading_rad : (n,) start point (m) and grid bearing (rad,
            clockwise from north) of each element, as the design file gives them.
        elements : n :class:`Line`, :class:`Arc`, :class:`Clothoid`.
        start_chainage_m : chainage of the first start, m; each element then takes the chainage
            of the lengths before it (gaps at joins add none).

        Returns
        -------
        HorizontalAlignment
        """
        E, N, h = (np.asarray(a, dtype=float).ravel() for a in (start_E_m, start_N_m, start_heading_rad))
        if E.size == 0:
            raise ValueError("a horizontal alignment needs at least one element")
        return cls(E[0], N[0], h[0], elements, start_chainage_m, anchors=(E, N, h))

    @property
    def end_chainage_m(self) -> float:
        return float(self.element_chainage_m[-1])

    @property
    def length_m(self) -> float:
        return float(self.element_chainage_m[-1] - self.element_chainage_m[0])

    def element_index(self, s) -> np.ndarray:
        """Index of the element holding chainage ``s``; -1 before the start, n after the end.

        Element starts belong to the element they start (the end chainage to the last one).
        """
        s = np.asarray(s, dtype=float)
        idx = np.searchsorted(self.element_chainage_m, s, side="right") - 1
        n = len(self.elements)
        idx = np.where(s == self.element_chainage_m[-1], n - 1, idx)
        return np.where(s > self.element_chainage_m[-1], n, idx)

    def _local(self, s):
        """Per-point element parameters (start state, k0, c) and local length u.

        Before the start / after the end the alignment continues on the end tangents, modelled
        as straights (k0 = c = 0) from the first element's start / last element's end.
        """
        s = np.asarray(s, dtype=float)
        n = len(self.elements)
        idx = self.element_index(s)
        j = np.clip(idx, 0, n)  # n -> the end state (straight continuation)
        ext = (idx < 0) | (idx >= n)
        k0 = np.where(ext, 0.0, self._k0[np.minimum(j, n - 1)])
        c = np.where(ext, 0.0, self._c[np.minimum(j, n - 1)])
        u = s - self.element_chainage_m[j]
        return j, u, self._z[j], self.element_heading_rad[j], k0, c

    def _evaluate_complex(self, s):
        j, u, z0, h0, k0, c = self._local(s)
        z = z0 + _displacement(u, h0, k0, c)
        heading = h0 + k0 * u + 0.5 * c * u * u
        return z, heading, k0 + c * u, c

    def evaluate(self, s) -> HorizontalSample:
        """Position, grid bearing and curvature at chainages ``s``.

        Parameters
        ----------
        s : array_like, chainage, m.

        Returns
        -------
        HorizontalSample
            E, N (m), heading in [0, 2 pi) (rad), rho_h = d(heading)/ds (1/m) and its
            derivative d(rho_h)/ds (1/m^2) (Escalona 2021, Eq. 4-5).
        """
        shape = np.shape(s)
        z, heading, k, c = self._evaluate_complex(np.asarray(s, dtype=float).ravel())
        z, heading, k, c = (np.reshape(x, shape) for x in (z, heading, k, np.broadcast_to(c, k.shape)))
        return HorizontalSample(E_m=z.imag + self.start_E_m, N_m=z.real + self.start_N_m, heading_rad=np.mod(heading, _TWO_PI),
                                rho_h_1_m=k, drho_h_ds_1_m2=np.array(c, dtype=float))

    def project(self, E_m, N_m, *, tol_m: float = 1e-11, max_iter: int = 30):
        """Chainage and lateral offset (positive right) of points in plan.

        Each point is first given to the element whose osculating arc (mean curvature of the
        element, plus the straight continuations beyond the ends) passes nearest to it; Newton's
        method then solves (P - X(s)) . T(s) = 0 on the exact geometry,
        ds = a / (1 - rho_h d) with a, d the along-track and lateral offsets, stepping into the
        neighbouring element when the foot point leaves the current one. All points are iterated
        together (vectorised); the loop over elements only builds the start guesses.

        Parameters
        ----------
        E_m, N_m : array_like of the same shape, grid coordinates, m.
        tol_m : stop when every chainage update is below this, m.
        max_iter : iteration cap.

        Returns
        -------
        chainage_m, lateral_m : ndarrays of the points' shape.
        """
        E = np.asarray(E_m, dtype=float)
        N = np.asarray(N_m, dtype=float)
        E, N = np.broadcast_arrays(E, N)
        shape = E.shape
        # offsets from the alignment start: keeps ~13 more digits than 3e6-m grid values
        p = ((N - self.start_N_m) + 1j * (E - self.start_E_m)).ravel()
        s = self._seed(p)
        lateral = np.empty(p.shape)
        active = np.arange(p.size)
        for _ in range(max_iter):
            sa, pa = s[active], p[active]
            z, heading, k, _ = self._evaluate_complex(sa)
            local = (pa - z) * np.exp(-1j * heading)
            lateral[active] = local.imag
            denom = 1.0 - k * local.imag
            # a point near a centre of curvature has no unique foot point; keep the step sane
            denom = np.where(np.abs(denom) < 1e-3, np.copysign(1e-3, denom), denom)
            ds = local.real / denom
            s[active] = sa + ds
            # converged points keep the lateral offset of the last foot point: moving it by
            # ds < tol changes the offset by O(ds^2 rho)
            active = active[np.abs(ds) > tol_m]
            if active.size == 0:
                break
        return s.reshape(shape), lateral.reshape(shape)

    def _seed(self, p: np.ndarray) -> np.ndarray:
        """Start chainages for Newton: nearest element by its osculating-arc approximation.

        Each element is replaced by the arc of its mean curvature through its start point; the
        distance to it is |w.imag| (straight) or ||p - centre| - R| (arc) when the foot point
        falls on the element, else the distance to the element's nearer end point.
        """
        n = len(self.elements)
        best_d2 = np.full(p.shape, np.inf)
        best_s = np.zeros(p.shape)
        # candidates: -1 = straight before the start, 0..n-1 elements, n = straight after end
        for j in range(-1, n + 1):
            if j == -1:
                z0, h0, km, lo, hi = self._z[0], self.element_heading_rad[0], 0.0, -np.inf, 0.0
                s0, z_lo, z_hi = self.element_chainage_m[0], None, self._z[0]
            elif j == n:
                z0, h0, km, lo, hi = self._z[n], self.element_heading_rad[n], 0.0, 0.0, np.inf
                s0, z_lo, z_hi = self.element_chainage_m[n], self._z[n], None
            else:
                L = self._length[j]
                z0, h0 = self._z[j], self.element_heading_rad[j]
                km = self._k0[j] + 0.5 * self._c[j] * L
                lo, hi, s0 = 0.0, L, self.element_chainage_m[j]
                z_lo, z_hi = self._z[j], self._z[j + 1]
            t0 = complex(np.cos(h0), np.sin(h0))
            if km == 0.0 or abs(km) * (hi - lo) < 1e-9:  # straight, or too flat for a centre
                w = (p - z0) * t0.conjugate()
                u = w.real
                d2 = w.imag * w.imag
            else:
                centre = z0 + 1j * t0 / km
                q = p - centre
                u = np.angle(q / (z0 - centre)) / km
                d2 = (np.abs(q) - 1.0 / abs(km)) ** 2
            if z_lo is not None:
                below = u < lo
                u = np.where(below, lo, u)
                d2 = np.where(below, np.abs(p - z_lo) ** 2, d2)
            if z_hi is not None:
                above = u > hi
                u = np.where(above, hi, u)
                d2 = np.where(above, np.abs(p - z_hi) ** 2, d2)
            better = d2 < best_d2
            best_d2 = np.where(better, d2, best_d2)
            best_s = np.where(better, s0 + u, best_s)
        return best_s


# --------------------------------------------------------------------------------------------
# vertical profile
# --------------------------------------------------------------------------------------------
class VerticalProfile:
    """Grades between PVIs, joined by vertical curves at the interior PVIs.

    Build with :meth:`from_pvis`. Two kinds of vertical curve:

    - parabola (the default): symmetric, centred on PVI i, of length L_i (from
      BVC = s_i - L_i/2 to EVC = s_i + L_i/2); the height there is
      H_i + g_{i-1} (s - s_i) + (g_i - g_{i-1}) (s - BVC)^2 / (2 L_i), the vertical radius
      L_i / |g_i - g_{i-1}|;
    - circle (``vertical_radius_m`` > 0): the circular arc of radius R in the (s, H) plane
      tangent to both grade lines, from s_i - T cos(a_in) to s_i + T cos(a_out), with
      a = arctan(g) and T = R tan(|a_out - a_in| / 2). Crest or sag follows the grades.

    Beyond the first/last PVI the end grades continue.

    Attributes
    ----------
    chainage_m, height_m : PVI stations and heights.
    curve_length_m : parabola length; for a circle, its arc length R |a_out - a_in|.
    vertical_radius_m : circle radius, 0 for a parabola (or no curve).
    curve_start_m, curve_end_m : chainages where each curve begins and ends.
    grade : (n-1,) grades dH/ds between PVIs.
    """

    def __init__(self, chainage_m, height_m, curve_length_m, vertical_radius_m=None, *,
                 overlap_tolerance_m: float = 0.0) -> None:
        s = np.asarray(chainage_m, dtype=float).ravel()
        H = np.asarray(height_m, dtype=float).ravel()
        L = np.array(curve_length_m, dtype=float).ravel()
        R = (np.zeros(s.shape) if vertical_radius_m is None
             else np.abs(np.array(vertical_radius_m, dtype=float).ravel()))
        if not (s.shape == H.shape == L.shape == R.shape):
            raise ValueError("chainage_m, height_m, curve_length_m (and vertical_radius_m) must "
                             "have the same length")
        if s.size < 2:
            raise ValueError("a vertical profile needs at least two PVIs")
        if not all(np.all(np.isfinite(a)) for a in (s, H, L, R)):
            raise ValueError("PVI chainages, heights, curve lengths and radii must be finite")
        if np.any(np.diff(s) <= 0):
            i = int(np.argmax(np.diff(s) <= 0)) + 1
            raise ValueError(f"PVI no. {i + 1}: chainage {float(s[i])!r} does not increase")
        if np.any(L < 0):
            raise ValueError(f"PVI {int(np.argmax(L < 0))}: negative vertical curve length")
        if L[0] != 0 or L[-1] != 0 or R[0] != 0 or R[-1] != 0:
            raise ValueError("the first and last PVI cannot carry a vertical curve (length 0)")
        g = np.diff(H) / np.diff(s)
        circle = R > 0
        bvc, evc = s - 0.5 * L, s + 0.5 * L
        # circle geometry: centre chainage cs, height at the BVC, R cos(a_in), and
        # sigma = +1 for a sag (centre above), -1 for a crest
        self._cs, self._h_bvc = np.zeros(s.shape), np.zeros(s.shape)
        self._r_cos_in, self._sigma = np.zeros(s.shape), np.zeros(s.shape)
        for i in np.flatnonzero(circle):  # a handful of PVIs
            a_in, a_out = np.arctan(g[i - 1]), np.arctan(g[i])
            turn = a_out - a_in
            if turn == 0.0:
                circle[i], R[i], L[i] = False, 0.0, 0.0
                bvc[i] = evc[i] = s[i]
                continue
            T = R[i] * np.tan(0.5 * abs(turn))
            sigma = np.sign(turn)
            bvc[i] = s[i] - T * np.cos(a_in)
            evc[i] = s[i] + T * np.cos(a_out)
            self._h_bvc[i] = H[i] - T * np.sin(a_in)
            self._cs[i] = bvc[i] - sigma * R[i] * np.sin(a_in)
            self._r_cos_in[i] = R[i] * np.cos(a_in)
            self._sigma[i] = sigma
            L[i] = R[i] * abs(turn)
        tol = max(1e-9 * max(1.0, float(np.max(np.abs(s)))), overlap_tolerance_m)
        overlap = evc[:-1] > bvc[1:] + tol
        if np.any(overlap):
            i = int(np.argmax(overlap))
            raise ValueError(f"vertical curves of PVI {i} (ends {evc[i]!r}) and PVI {i + 1} "
                             f"(begins {bvc[i + 1]!r}) overlap")
        self.chainage_m, self.height_m, self.curve_length_m = s, H, L
        self.vertical_radius_m = R
        self.curve_start_m, self.curve_end_m = bvc, evc
        self.grade = g
        self._circle = circle

    @classmethod
    def from_pvis(cls, chainage_m, height_m, curve_length_m, vertical_radius_m=None, *,
                  overlap_tolerance_m: float = 0.0) -> "VerticalProfile":
        """Profile from PVI chainages, heights and vertical-curve lengths (first/last 0).

        Parameters
        ----------
        chainage_m, height_m : PVI stations and heights, m.
        curve_length_m : length of the parabolic curve centred on each PVI, m.
        vertical_radius_m : optional; where > 0 the curve at that PVI is instead the circle of
            this radius tangent to both grades (its ``curve_length_m`` entry is then ignored).
        overlap_tolerance_m : adjacent curves may overlap by up to this (a design file's
            rounding); in the overlap the later curve holds.

        Returns
        -------
        VerticalProfile
        """
        return cls(chainage_m, height_m, curve_length_m, vertical_radius_m,
                   overlap_tolerance_m=overlap_tolerance_m)

    def evaluate(self, s):
        """Height H, dH/ds and d2H/ds2 at chainages ``s``.

        Returns
        -------
        H_m, dH_ds, d2H_ds2 : ndarrays of the shape of ``s``.
        """
        shape = np.shape(s)
        s = np.asarray(s, dtype=float).ravel()
        sp, Hp, g = self.chainage_m, self.height_m, self.grade
        seg = np.clip(np.searchsorted(sp, s, side="right") - 1, 0, len(g) - 1)
        H = Hp[seg] + g[seg] * (s - sp[seg])
        dH = g[seg].astype(float)
        d2H = np.zeros(s.shape)
        # a point can lie in the curve of either end PVI of its segment
        for cand in (seg, seg + 1):
            inside = (s > self.curve_start_m[cand]) & (s < self.curve_end_m[cand])
            if not np.any(inside):
                continue
            circ = self._circle[cand] & inside
            para = inside & ~circ
            if np.any(para):
                ci = cand[para]
                r = (g[ci] - g[ci - 1]) / self.curve_length_m[ci]  # d2H/ds2 on the curve
                x = s[para] - self.curve_start_m[ci]                # distance from the BVC
                H[para] = Hp[ci] + g[ci - 1] * (s[para] - sp[ci]) + 0.5 * r * x * x
                dH[para] = g[ci - 1] + r * x
                d2H[para] = r
            if np.any(circ):
                ci = cand[circ]
                R, sig = self.vertical_radius_m[ci], self._sigma[ci]
                x = s[circ] - self._cs[ci]
                root = np.sqrt((R - x) * (R + x))
                # H = centre height - sig * root, rewritten from the BVC so that no two
                # ~R-sized numbers are subtracted (x0 = sig R sin(a_in) is x at the BVC)
                x_bvc = s[circ] - self.curve_start_m[ci]
                H[circ] = self._h_bvc[ci] + sig * x_bvc * (2.0 * x - x_bvc) / (
                    self._r_cos_in[ci] + root)
                dH[circ] = sig * x / root
                d2H[circ] = sig * R * R / root ** 3
        return H.reshape(shape), dH.reshape(shape), d2H.reshape(shape)


# --------------------------------------------------------------------------------------------
# cant
# --------------------------------------------------------------------------------------------
class CantProfile:
    """Applied cant, linear in cant HEIGHT between stations and constant outside them.

    Design tools give cant as a height over the rail-centre distance b and ramp that height
    linearly (LandXML ``appliedCant``); the angle is asin(h / b), so the height is linear where
    sin(angle) is, for any b. Interpolating the angle instead was 0.163 mm high at the middle of
    a 0 -> 180 mm ramp (0.049 mm for 120 mm) on b = 1.5 m.

    Build with :meth:`from_stations`. Positive when the left rail is higher (FRD roll).

    Attributes
    ----------
    chainage_m, cant_rad : station arrays.
    """

    def __init__(self, chainage_m, cant_rad) -> None:
        s = np.asarray(chainage_m, dtype=float).ravel()
        c = np.asarray(cant_rad, dtype=float).ravel()
        if s.shape != c.shape or s.size < 1:
            raise ValueError("chainage_m and cant_rad must be non-empty and of the same length")
        if not (np.all(np.isfinite(s)) and np.all(np.isfinite(c))):
            raise ValueError("cant stations must be finite")
        if np.any(np.diff(s) <= 0):
            i = int(np.argmax(np.diff(s) <= 0)) + 1
            raise ValueError(f"cant station no. {i + 1}: chainage {float(s[i])!r} does not increase")
        if np.any(np.abs(c) >= np.pi / 2):
            raise ValueError("cant angles must be below pi/2 in magnitude")
        self.chainage_m, self.cant_rad = s, c

    @classmethod
    def from_stations(cls, chainage_m, cant_rad) -> "CantProfile":
        """Cant from station chainages (m) and cant angles (rad), linear in height in between.

        Returns
        -------
        CantProfile
        """
        return cls(chainage_m, cant_rad)

    def evaluate(self, s):
        """Cant angle and its derivative d(cant)/ds (the twist curvature rho_tw).

        At a station the derivative of the following ramp is returned.

        Returns
        -------
        cant_rad, rho_tw_1_m : ndarrays of the shape of ``s``.
        """
        s = np.asarray(s, dtype=float)
        sp, sin_p = self.chainage_m, np.sin(self.cant_rad)
        sin_c = np.interp(s, sp, sin_p)
        cant = np.arcsin(sin_c)
        if sp.size < 2:
            return cant, np.zeros(s.shape)
        rate = np.diff(sin_p) / np.diff(sp)          # d(sin cant)/ds on each ramp
        seg = np.searchsorted(sp, s, side="right") - 1
        inside = (seg >= 0) & (seg < sp.size - 1)
        rho_tw = np.where(inside, rate[np.clip(seg, 0, sp.size - 2)] / np.cos(cant), 0.0)
        return cant, rho_tw


# --------------------------------------------------------------------------------------------
# the whole alignment
# --------------------------------------------------------------------------------------------
@dataclass
class AlignmentSample:
    """The design alignment at chainages (all arrays of the shape of ``chainage_m``).

    Attributes
    ----------
    chainage_m : chainage s, m.
    E_m, N_m, H_m : grid position of the track centre line (H = 0 without a profile), m.
    heading_rad : grid bearing clockwise from north, [0, 2 pi).
    slope_rad : arctan(dH/ds), positive rising.
    cant_rad : roll of the track plane, positive when the left rail is higher.
    rho_h_1_m : horizontal curvature d(heading)/ds, positive turning right.
    drho_h_ds_1_m2 : d(rho_h)/ds.
    rho_v_1_m : vertical curvature d(slope)/ds.
    rho_tw_1_m : twist curvature d(cant)/ds.
    """

    chainage_m: np.ndarray
    E_m: np.ndarray
    N_m: np.ndarray
    H_m: np.ndarray
    heading_rad: np.ndarray
    slope_rad: np.ndarray
    cant_rad: np.ndarray
    rho_h_1_m: np.ndarray
    drho_h_ds_1_m2: np.ndarray
    rho_v_1_m: np.ndarray
    rho_tw_1_m: np.ndarray


@dataclass
class Projection:
    """Points projected onto the alignment (arrays of the points' shape).

    Attributes
    ----------
    chainage_m : chainage of the foot point, m.
    lateral_m : horizontal offset from the centre line, positive to the right facing
        increasing chainage, m.
    vertical_m : height above the design profile at the foot point (NaN without heights), m.
    inside : True when the foot point lies within [start, end] of the alignment.
    """

    chainage_m: np.ndarray
    lateral_m: np.ndarray
    vertical_m: np.ndarray
    inside: np.ndarray


class Alignment:
    """Design track geometry: horizontal alignment, optional vertical profile and cant.

    Parameters
    ----------
    horizontal : HorizontalAlignment
    profile : VerticalProfile, optional; without it H = 0 and the slope is 0.
    cant : CantProfile, optional; without it the cant is 0.
    name : alignment name (LandXML ``Alignment/@name``).
    stationing : the drawing stationing (station equations), optional; chainage everywhere
        else is the internal station (start station plus distance along the alignment).
    """

    def __init__(self, horizontal: HorizontalAlignment, profile: VerticalProfile | None = None,
                 cant: CantProfile | None = None, name: str = "",
                 stationing: Stationing | None = None) -> None:
        if not isinstance(horizontal, HorizontalAlignment):
            raise TypeError("horizontal must be a HorizontalAlignment")
        self.horizontal = horizontal
        self.profile = profile
        self.cant = cant
        self.name = name
        self.stationing = stationing

    def station(self, chainage_m) -> np.ndarray:
        """Drawing station (after the station equations) at internal chainages, m."""
        s = np.asarray(chainage_m, dtype=float)
        return s.copy() if self.stationing is None else self.stationing.station(s)

    @property
    def start_chainage_m(self) -> float:
        return float(self.horizontal.start_chainage_m)

    @property
    def end_chainage_m(self) -> float:
        return self.horizontal.end_chainage_m

    def evaluate(self, s) -> AlignmentSample:
        """Evaluate the design geometry at chainages ``s`` (vectorised).

        Parameters
        ----------
        s : array_like, chainage, m (any shape; outside the alignment its end tangents continue).

        Returns
        -------
        AlignmentSample
            Positions, angles and the curvatures rho_h, rho_h', rho_v, rho_tw of Escalona 2021,
            Eq. 4-5, with respect to the chainage.
        """
        s = np.asarray(s, dtype=float)
        hz = self.horizontal.evaluate(s)
        if self.profile is None:
            H = np.zeros(s.shape)
            slope = np.zeros(s.shape)
            rho_v = np.zeros(s.shape)
        else:
            H, dH, d2H = self.profile.evaluate(s)
            slope = np.arctan(dH)
            rho_v = d2H / (1.0 + dH * dH)
        if self.cant is None:
            cant = np.zeros(s.shape)
            rho_tw = np.zeros(s.shape)
        else:
            cant, rho_tw = self.cant.evaluate(s)
        return AlignmentSample(chainage_m=s.copy(), E_m=hz.E_m, N_m=hz.N_m, H_m=H,
                               heading_rad=hz.heading_rad, slope_rad=slope, cant_rad=cant,
                               rho_h_1_m=hz.rho_h_1_m, drho_h_ds_1_m2=hz.drho_h_ds_1_m2,
                               rho_v_1_m=rho_v, rho_tw_1_m=rho_tw)

    def translated(self, dE_m: float, dN_m: float) -> "Alignment":
        """The same alignment moved by (dE, dN) in the grid (same elements, bearings, profile, cant)."""
        h = self.horizontal
        moved = HorizontalAlignment(h.start_E_m + float(dE_m), h.start_N_m + float(dN_m), h.start_heading_rad,
                                    h.elements, h.start_chainage_m)
        return Alignment(moved, self.profile, self.cant, self.name)

    def project(self, E_m, N_m, H_m=None) -> Projection:
        """Project grid points onto the alignment.

        Parameters
        ----------
        E_m, N_m : array_like, grid coordinates, m.
        H_m : array_like, optional, heights, m.

        Returns
        -------
        Projection
            chainage, lateral offset (positive right), height above the profile, inside flag.
        """
        s, lateral = self.horizontal.project(E_m, N_m)
        if H_m is None:
            vertical = np.full(s.shape, np.nan)
        else:
            H = np.broadcast_to(np.asarray(H_m, dtype=float), s.shape)
            if self.profile is None:
                vertical = H.copy()
            else:
                vertical = H - self.profile.evaluate(s)[0]
        tol = 1e-9
        inside = (s >= self.start_chainage_m - tol) & (s <= self.end_chainage_m + tol)
        return Projection(chainage_m=s, lateral_m=lateral, vertical_m=vertical, inside=inside)

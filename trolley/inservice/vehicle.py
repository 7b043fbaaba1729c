"""Truth simulator of the in-service vehicle: a full car (car body, two bogie frames, four
wheelsets) with nonlinear wheel-rail contact, running over irregular straight or curved track.

Plays the role of the complete model (CM) of Munoz 2021 Sec. III-B (their reference [25]) that
generates the virtual measurements of Sec. V; it is independent of the estimator's simplified
model (Sec. III-C, ``trolley.inservice.model``), which it does not import.

Model
-----
Track-relative coordinates (small angles) in the frame that follows the *design* centre line at
the speed V: x forward, y left, z up, yaw counter-clockwise. 23 degrees of freedom:

* 4 wheelsets: lateral y_i and yaw psi_i; their bounce z_i and roll phi_i follow the rails
  (z_i = vertical profile, phi_i = cross level / 2b under wheelset i) and enter as inputs;
* 2 bogie frames and the car body: lateral y, yaw psi, roll phi, bounce z, pitch theta.

Suspensions are linear spring-dampers at their attachment points (primary: per axle box, x/y/z;
secondary: per side, x/y/z; an anti-roll bar between each frame and the body). With the small-angle
displacement of a point r of a body, d = (theta r_z - psi r_y, y + psi r_x - phi r_z,
z + phi r_y - theta r_x), each element's deflection is delta = J q + J_u u + delta_kappa and its
generalised force -J^T (k delta + c delta'), so K = J^T k J, C = J^T c J (assembled once).
delta_kappa is the exact deflection a constant curvature kappa imposes on the elements when every
body sits on the curve (the bodies are straight, the track is not). The vertical preloads P of
the springs give the geometric (gravity) stiffness in roll and pitch, +r_z P on the upper body and
-r_z P on the lower one (r_z: height of the attachment above the body's centre of gravity).

The wheel loads follow from the primary vertical spring forces F_L, F_R of each wheelset and its
vertical and roll inertia (m_w, I_xx,w) under the rail inputs:
N_L + N_R = m_w g + F_L + F_R + m_w z'', (N_L - N_R) b = (F_L - F_R) d_p + I_xx,w phi''.
The rails act on each wheelset through ``trolley.inservice.contact.wheelset_forces`` (rolling-radius
difference rising with the shift, gravitational stiffness and cross level, Kalker creep scaled
with the load and saturated by Shen-Hedrick-Elkins, flange deadband). In a curve every body gets
the centripetal term m V^2 kappa (no cant).

Parameters
----------
Masses, inertias, geometry and suspension: the Manchester benchmark vehicle 1 (Iwnicki 1998,
"The Manchester benchmarks for rail vehicle simulation", VSD 30(3-4) 295-313; the values as
quoted in the secondary literature; the primary source was not at hand): car body 32 t,
bogie frame 2615 kg, wheelset 1813 kg, wheel radius 0.46 m, bogie wheelbase 2.56 m, bogie
centres 19 m, primary per axle box kx 31.391 MN/m, ky 3.884 MN/m, kz 1.22 MN/m, cz 4 kN s/m
at +-1.0 m; secondary per side kx = ky = 0.16 MN/m, kz 0.43 MN/m, cz 20 kN s/m at +-1.0 m, lateral
damper 32 kN s/m per bogie, anti-roll bar 2.45 MN m/rad. Contact: ``ContactParameters`` defaults
(lambda0 = 0.15, Kalker f11 = 10 MN, f22 = 8.7 MN per wheel at 54.5 kN from Hertz + Kalker's
tables for a 0.46 m wheel on a 0.3 m rail crown, mu = 0.3, flange 9.1 mm / 14.6 MN/m).

Sensors (Munoz 2021 Sec. II and V): a lateral accelerometer and a yaw gyro on the axle box of the
leading wheelset of the leading bogie and a lateral accelerometer at the centre of the leading bogie
frame; absolute quantities: y'' + V^2 kappa, psi' + V kappa, y_f'' + V^2 kappa; white noise of
0.01 m/s^2 and 5e-4 rad/s (Sec. V). With ``sensor_gravity`` the accelerometers also see the
gravity component g phi of their roll (the wheelset's roll from cross level and profile, the
frame's roll), as real ones would; off by default, as in the paper's virtual sensors.

Integration: classical fixed-step Runge-Kutta 4 on the 46 states, the right-hand side one
matrix product plus the vectorised contact of the 4 wheelsets; the step is the largest divisor of
the output period below min(1 ms, 2 / |largest eigenvalue of the linearised system|). The rail
inputs at all stage times are evaluated before the loop (the speed is constant).

References
----------
S. Munoz, J. Ros, P. Urda, J. L. Escalona, IEEE Access 9 (2021) 60010-60025, Sec. II, III-B, V.
S. Iwnicki, "Manchester benchmarks for rail vehicle simulation", Vehicle System Dynamics 30 (1998).
A. H. Wickens, Fundamentals of Rail Vehicle Dynamics (2003): kinematic wavelength
2 pi sqrt(r0 b / lambda) (Klingel 1883).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from trolley.inservice.contact import ContactParameters, rolling_radius_difference, wheelset_forces
from trolley.inservice.irregularity import TrackIrregularity

#: gravity, m/s^2
G_M_S2 = 9.81
#: sensor noise of Munoz 2021 Sec. V
SIGMA_ACC_M_S2 = 0.01
SIGMA_GYRO_RAD_S = 5.0e-4
#: the vehicle of VehicleParameters' defaults
DEFAULT_VEHICLE_NAME = "Manchester benchmark vehicle 1"
#: number of generalised coordinates and of rail inputs
N_DOF = 23
N_INPUT = 8


@dataclass(frozen=True)
class VehicleParameters:
    """Full-vehicle parameters (SI; sources in the module docstring).

    Heights are of centres of gravity / attachment points above the rail top. ``d_p``/``d_s``:
    half lateral spacing of the primary / secondary elements; ``a_wheelset``: half bogie
    wheelbase; ``a_bogie``: half distance of the bogie centres. Primary values are per axle box,
    secondary per side (``cy_s`` per side too). ``conicity_factor`` and ``creep_factor`` scale
    the TRUTH's conicity and Kalker coefficients (robustness study) and are not part of the
    nominal values :meth:`nominal` gives to the estimator.
    """

    m_body: float = 32000.0
    ixx_body: float = 56800.0
    iyy_body: float = 1970000.0
    izz_body: float = 1970000.0
    h_body: float = 1.8
    m_frame: float = 2615.0
    ixx_frame: float = 1722.0
    iyy_frame: float = 1476.0
    izz_frame: float = 3067.0
    h_frame: float = 0.6
    m_wheelset: float = 1813.0
    ixx_wheelset: float = 1120.0
    izz_wheelset: float = 1120.0
    # wheel and contact figures: ContactParameters holds their one set of defaults
    r0: float = ContactParameters.r0
    b: float = ContactParameters.b
    a_wheelset: float = 1.28
    a_bogie: float = 9.5
    kx_p: float = 31.391e6
    ky_p: float = 3.884e6
    kz_p: float = 1.22e6
    cx_p: float = 0.0
    cy_p: float = 0.0
    cz_p: float = 4.0e3
    d_p: float = 1.0
    kx_s: float = 0.16e6
    ky_s: float = 0.16e6
    kz_s: float = 0.43e6
    cx_s: float = 0.0
    cy_s: float = 16.0e3
    cz_s: float = 20.0e3
    d_s: float = 1.0
    h_s: float = 1.0
    k_antiroll: float = 2.45e6
    conicity: float = ContactParameters.conicity
    conicity_growth_m: float = ContactParameters.conicity_growth_m
    f11: float = ContactParameters.f11
    f22: float = ContactParameters.f22
    mu: float = ContactParameters.mu
    flange_clearance_m: float = ContactParameters.flange_clearance_m
    flange_stiffness_n_m: float = ContactParameters.flange_stiffness_n_m
    conicity_factor: float = 1.0
    creep_factor: float = 1.0
    sensor_gravity: bool = False

    def __post_init__(self):
        for k, v in self.__dict__.items():
            if isinstance(v, bool):
                continue
            if not np.isfinite(v):
                raise ValueError(f"VehicleParameters.{k} = {v} is not finite")
        for k in ("m_body", "m_frame", "m_wheelset", "izz_wheelset", "r0", "b", "conicity", "f11", "f22",
                  "conicity_factor", "creep_factor", "mu"):
            if getattr(self, k) <= 0:
                raise ValueError(f"VehicleParameters.{k} must be > 0, got {getattr(self, k)}")

    @property
    def wheel_load_n(self) -> float:
        """Static wheel load N0 = g (m_body / 8 + m_frame / 4 + m_wheelset / 2), N."""
        return G_M_S2 * (self.m_body / 8.0 + self.m_frame / 4.0 + self.m_wheelset / 2.0)

    @property
    def contact(self) -> ContactParameters:
        """The TRUTH's contact parameters (conicity times ``conicity_factor``)."""
        return ContactParameters(r0=self.r0, b=self.b, conicity=self.conicity * self.conicity_factor,
                                 conicity_growth_m=self.conicity_growth_m, f11=self.f11, f22=self.f22,
                                 wheel_load_n=self.wheel_load_n, mu=self.mu,
                                 flange_clearance_m=self.flange_clearance_m,
                                 flange_stiffness_n_m=self.flange_stiffness_n_m)

    def nominal(self) -> dict:
        """Nominal parameters for the simplified model (Munoz 2021 Eq. 4; keys of model.ModelParameters).

        m, I: wheelset mass and yaw inertia; l = b; ls = d_p; conicity = lambda0 (nominal, without
        ``conicity_factor``); r0; mf = m_body / 4 + m_frame / 2 (Sec. III-D); f11, f22 per wheel
        (nominal, without ``creep_factor``), f23 = f33 = 0 (spin not modelled); kx, cx, ky, cy the
        real primary values per axle box (starting values for the identification of Eq. 6).
        """
        return {"m": self.m_wheelset, "I": self.izz_wheelset, "l": self.b, "ls": self.d_p,
                "conicity": self.conicity, "r0": self.r0, "mf": self.m_body / 4.0 + self.m_frame / 2.0,
                "f11": self.f11, "f22": self.f22, "f23": 0.0, "f33": 0.0,
                "kx": self.kx_p, "cx": self.cx_p, "ky": self.ky_p, "cy": self.cy_p}

    def sensor_positions(self) -> dict:
        """Sensor positions relative to the car body centre (x forward, y left, z above rail), m."""
        x0 = self.a_bogie + self.a_wheelset
        return {"wheelset_accelerometer": (x0, self.d_p, self.r0), "wheelset_gyro": (x0, self.d_p, self.r0),
                "frame_accelerometer": (self.a_bogie, 0.0, self.h_frame)}


# ---------------------------------------------------------------------------------------------
# assembly
def _wheelset_x(p: VehicleParameters) -> np.ndarray:
    return np.array([p.a_bogie + p.a_wheelset, p.a_bogie - p.a_wheelset,
                     -p.a_bogie + p.a_wheelset, -p.a_bogie - p.a_wheelset])


def _frame_dof(j: int, k: int) -> int:
    """Index of DOF k (0 y, 1 psi, 2 phi, 3 z, 4 theta) of frame j."""
    return 8 + 5 * j + k


_BODY = 18


@dataclass(frozen=True)
class _Bodies:
    """Centre positions (x along the vehicle, z height) and DOF indices of the 7 bodies."""

    x: np.ndarray
    h: np.ndarray


def _bodies(p: VehicleParameters) -> _Bodies:
    xw = _wheelset_x(p)
    return _Bodies(x=np.concatenate([xw, [p.a_bogie, -p.a_bogie, 0.0]]),
                   h=np.concatenate([np.full(4, p.r0), [p.h_frame, p.h_frame, p.h_body]]))


def _point_jacobian(body: int, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3, N_DOF) and (3, N_INPUT) rows: displacement of the point at offset r from a body's centre.

    Bodies 0-3 are the wheelsets (y, psi free; z, phi inputs), 4-5 the frames, 6 the car body.
    """
    jq = np.zeros((3, N_DOF))
    ju = np.zeros((3, N_INPUT))
    rx, ry, rz = r
    if body < 4:
        jq[1, body] = 1.0
        jq[0, 4 + body] = -ry
        jq[1, 4 + body] = rx
        ju[2, body] = 1.0
        ju[1, 4 + body] = -rz
        ju[2, 4 + body] = ry
        return jq, ju
    base = _frame_dof(body - 4, 0) if body < 6 else _BODY
    y, psi, phi, z, theta = range(base, base + 5)
    jq[0, theta] = rz
    jq[0, psi] = -ry
    jq[1, y] = 1.0
    jq[1, psi] = rx
    jq[1, phi] = -rz
    jq[2, z] = 1.0
    jq[2, phi] = ry
    jq[2, theta] = -rx
    return jq, ju


def _curve_gap(bod: _Bodies, a: int, b: int, point: np.ndarray, kappa: float) -> np.ndarray:
    """Exact (x, y) gap between the attachment points of bodies a and b when both sit on the curve.

    Expressed in the track frame of body a; zero on straight track.
    """
    if kappa == 0.0:
        return np.zeros(2)

    def world(k):
        xk = bod.x[k]
        c = np.array([np.sin(kappa * xk) / kappa, (1.0 - np.cos(kappa * xk)) / kappa])
        ang = kappa * xk
        rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
        return c + rot @ np.array([point[0] - xk, point[1]]), ang

    ga, ang_a = world(a)
    gb, _ = world(b)
    rot_back = np.array([[np.cos(ang_a), np.sin(ang_a)], [-np.sin(ang_a), np.cos(ang_a)]])
    return rot_back @ (gb - ga)


@dataclass
class _Linear:
    """Assembled linear part of the equations of motion."""

    mass: np.ndarray            # (N_DOF,) diagonal mass matrix
    kc: np.ndarray              # (N_DOF, 2 N_DOF) [K C] incl. the geometric stiffness
    j: np.ndarray               # (n_el, N_DOF)
    ju: np.ndarray              # (n_el, N_INPUT)
    k: np.ndarray               # (n_el,)
    c: np.ndarray               # (n_el,)
    gap: np.ndarray             # (n_el,) curvature deflections
    pz: np.ndarray              # (2, 4) element indices of the primary vertical springs, left/right
    preload_p: float            # primary vertical preload per axle box, N


def _assemble(p: VehicleParameters, kappa: float) -> _Linear:
    bod = _bodies(p)
    rows_q, rows_u, ks, cs, gaps = [], [], [], [], []
    kgeo = np.zeros((N_DOF, N_DOF))
    pz = np.zeros((2, 4), int)

    def element(a, b, point, kdir, cdir, preload=0.0):
        ra = point - np.array([bod.x[a], 0.0, bod.h[a]])
        rb = point - np.array([bod.x[b], 0.0, bod.h[b]])
        ja, jua = _point_jacobian(a, ra)
        jb, jub = _point_jacobian(b, rb)
        gap = _curve_gap(bod, a, b, point, kappa)
        first = len(ks)
        for d in range(3):
            rows_q.append(jb[d] - ja[d])
            rows_u.append(jub[d] - jua[d])
            ks.append(kdir[d])
            cs.append(cdir[d])
            gaps.append(gap[d] if d < 2 else 0.0)
        if preload:
            for body, r, sign in ((b, rb, 1.0), (a, ra, -1.0)):
                if body < 4:
                    continue
                base = _frame_dof(body - 4, 0) if body < 6 else _BODY
                kgeo[base + 2, base + 2] += sign * r[2] * preload
                kgeo[base + 4, base + 4] += sign * r[2] * preload
        return first + 2

    preload_p = G_M_S2 * (p.m_body / 8.0 + p.m_frame / 4.0)
    for i in range(4):
        for side, sgn in ((0, 1.0), (1, -1.0)):
            pz[side, i] = element(i, 4 + i // 2, np.array([bod.x[i], sgn * p.d_p, p.r0]),
                                  (p.kx_p, p.ky_p, p.kz_p), (p.cx_p, p.cy_p, p.cz_p), preload_p)
    for j in range(2):
        for sgn in (1.0, -1.0):
            element(4 + j, 6, np.array([bod.x[4 + j], sgn * p.d_s, p.h_s]),
                    (p.kx_s, p.ky_s, p.kz_s), (p.cx_s, p.cy_s, p.cz_s), G_M_S2 * p.m_body / 4.0)
        row = np.zeros(N_DOF)
        row[_frame_dof(j, 2)] = -1.0
        row[_BODY + 2] = 1.0
        rows_q.append(row)
        rows_u.append(np.zeros(N_INPUT))
        ks.append(p.k_antiroll)
        cs.append(0.0)
        gaps.append(0.0)
    j = np.array(rows_q)
    ju = np.array(rows_u)
    k = np.array(ks)
    c = np.array(cs)
    kmat = j.T @ (k[:, None] * j) + kgeo
    cmat = j.T @ (c[:, None] * j)
    mass = np.concatenate([np.full(4, p.m_wheelset), np.full(4, p.izz_wheelset)]
                          + [[m, izz, ixx, m, iyy] for m, izz, ixx, iyy in
                             ((p.m_frame, p.izz_frame, p.ixx_frame, p.iyy_frame),) * 2
                             + ((p.m_body, p.izz_body, p.ixx_body, p.iyy_body),)])
    return _Linear(mass=mass, kc=np.hstack([kmat, cmat]), j=j, ju=ju, k=k, c=c, gap=np.array(gaps),
                   pz=pz, preload_p=preload_p)


# ---------------------------------------------------------------------------------------------
# right-hand side
@dataclass
class _Inputs:
    """Rail inputs at a set of instants (leading axis: instants; wheelset axis: 4)."""

    xi: np.ndarray          # (T, 4) alignment under each wheelset
    u: np.ndarray           # (T, 8) [z_i, phi_i]
    ud: np.ndarray          # (T, 8)
    udd: np.ndarray         # (T, 8)
    cl: np.ndarray          # (T, 4) cross level, m


class _System:
    """Equations of motion x' = f(x, inputs) of the full vehicle at speed V on curvature kappa."""

    def __init__(self, p: VehicleParameters, speed_m_s: float, kappa: float):
        self.p = p
        self.v = float(speed_m_s)
        self.kappa = float(kappa)
        self.lin = _assemble(p, kappa)
        self.contact = p.contact
        lin = self.lin
        centripetal = np.zeros(N_DOF)
        centripetal[:4] = p.m_wheelset
        for j in range(2):
            centripetal[_frame_dof(j, 0)] = p.m_frame
        centripetal[_BODY] = p.m_body
        self.f_const = -lin.j.T @ (lin.k * lin.gap) - centripetal * self.v ** 2 * kappa
        self.fu = -np.hstack([lin.j.T @ (lin.k[:, None] * lin.ju), lin.j.T @ (lin.c[:, None] * lin.ju)])
        idx = lin.pz.ravel()
        self.jpz = lin.j[idx]
        self.jupz = lin.ju[idx]
        self.kpz = lin.k[idx]
        self.cpz = lin.c[idx]
        self.gpz = lin.gap[idx]

    def forcing(self, inp: _Inputs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Input-dependent parts per instant: generalised force (T, N_DOF), pz deflections (T, 8), rates (T, 8)."""
        uu = np.hstack([inp.u, inp.ud])
        f = uu @ self.fu.T + self.f_const
        d = inp.u @ self.jupz.T + self.gpz
        dd = inp.ud @ self.jupz.T
        return f, d, dd

    def rhs(self, x, xi, f, d, dd, udd, cl):
        """x' for states x (46,) or (46, N) and the matching inputs (trailing axis N when batched)."""
        p, lin, c = self.p, self.lin, self.contact
        q, qd = x[:N_DOF], x[N_DOF:]
        force = f - lin.kc @ x
        col = (slice(None),) + (None,) * (x.ndim - 1)  # broadcast per-element constants over a batch
        fz = lin.preload_p - (self.kpz[col] * (self.jpz @ q + d) + self.cpz[col] * (self.jpz @ qd + dd))
        f_l, f_r = fz[:4], fz[4:]
        n_sum = p.m_wheelset * (G_M_S2 + udd[:4]) + f_l + f_r
        n_diff = ((f_l - f_r) * p.d_p + p.ixx_wheelset * udd[4:]) / p.b
        n_l, n_r = 0.5 * (n_sum + n_diff), 0.5 * (n_sum - n_diff)
        fy, mz = wheelset_forces(q[:4] - xi, qd[:4], q[4:8], qd[4:8], n_l, n_r, cl, self.v, self.kappa, c,
                                 p.creep_factor)
        force[:4] += fy
        force[4:8] += mz
        acc = force / lin.mass[col]
        return np.concatenate([qd, acc])

    def jacobian(self, x0: np.ndarray | None = None, h: float = 1e-7) -> np.ndarray:
        """Numerical (central-difference) state matrix at x0 (default 0) on a perfect track."""
        n = 2 * N_DOF
        x0 = np.zeros(n) if x0 is None else x0
        z4, z8 = np.zeros((4, 2 * n)), np.zeros((8, 2 * n))
        f = np.repeat(self.f_const[:, None], 2 * n, axis=1)
        d = np.repeat(self.gpz[:, None], 2 * n, axis=1)
        xs = np.repeat(x0[:, None], 2 * n, axis=1) + np.hstack([h * np.eye(n), -h * np.eye(n)])
        fx = self.rhs(xs, z4, f, d, z8, z8, z4)
        return (fx[:, :n] - fx[:, n:]) / (2.0 * h)

    def equilibrium(self) -> np.ndarray:
        """Quasi-static state on the perfect (curved) track: the generalised forces vanish at rest.

        Solved with scipy.optimize.root (Powell's hybrid method; the flange and the creep
        saturation make plain Newton steps oscillate).
        """
        from scipy.optimize import root
        z4, z8 = np.zeros(4), np.zeros(8)
        zero_v = np.zeros(N_DOF)

        def residual(q):
            x = np.concatenate([q, zero_v])
            return self.rhs(x, z4, self.f_const, self.gpz, z8, z8, z4)[N_DOF:] * self.lin.mass

        if not np.any(self.f_const):
            return np.zeros(2 * N_DOF)
        sol = root(residual, np.zeros(N_DOF), method="hybr")
        if not sol.success or np.max(np.abs(residual(sol.x))) > 1e-3:
            raise ValueError(f"no steady curving state at speed {self.v} m/s, curvature {self.kappa} 1/m "
                             f"({sol.message})")
        return np.concatenate([sol.x, zero_v])


# ---------------------------------------------------------------------------------------------
# modes
@dataclass(frozen=True)
class Mode:
    """A mode of the linearised vehicle (centred on a perfect straight track).

    Attributes
    ----------
    frequency_hz : damped natural frequency.
    damping_ratio : -Re(s) / |s|.
    wavelength_m : V / f, the track wavelength that excites it at the speed.
    bogie_share : share of the mode's kinetic energy in the frames and wheelsets.
    lateral_share : share of the kinetic energy in lateral, yaw and roll motion.
    """

    frequency_hz: float
    damping_ratio: float
    wavelength_m: float
    bogie_share: float
    lateral_share: float


def modes(p: VehicleParameters, speed_m_s: float) -> list[Mode]:
    """All oscillatory modes of the linearised full vehicle at ``speed_m_s`` (sorted by frequency).

    Linearised about the centred position on a perfect straight track (contact slope lambda0,
    unsaturated creep, flange inactive), by central differences of the simulator's own
    right-hand side.
    """
    sysm = _System(p, speed_m_s, 0.0)
    a = sysm.jacobian()
    vals, vecs = np.linalg.eig(a)
    out = []
    lateral_dofs = np.zeros(N_DOF, bool)
    lateral_dofs[:8] = True
    for base in (_frame_dof(0, 0), _frame_dof(1, 0), _BODY):
        lateral_dofs[base:base + 3] = True
    bogie_dofs = np.zeros(N_DOF, bool)
    bogie_dofs[:_BODY] = True
    for s, v in zip(vals, vecs.T):
        if s.imag <= 1e-6 or -s.real / abs(s) > 0.9:
            continue  # real (creep-dominated) modes and numerically split pairs of them
        e = sysm.lin.mass * np.abs(v[N_DOF:]) ** 2
        out.append(Mode(frequency_hz=float(s.imag / (2 * np.pi)), damping_ratio=float(-s.real / abs(s)),
                        wavelength_m=float(speed_m_s * 2 * np.pi / s.imag),
                        bogie_share=float(e[bogie_dofs].sum() / e.sum()),
                        lateral_share=float(e[lateral_dofs].sum() / e.sum())))
    return sorted(out, key=lambda m: m.frequency_hz)


def linearised_eigenvalues(p: VehicleParameters, speed_m_s: float) -> np.ndarray:
    """Eigenvalues of the vehicle linearised about the centred running on a perfect straight track."""
    return np.linalg.eigvals(_System(p, speed_m_s, 0.0).jacobian())


def largest_growth_rate(p: VehicleParameters, speed_m_s: float, eigenvalues: np.ndarray | None = None) -> float:
    """The largest real part of the linearised vehicle's eigenvalues at ``speed_m_s``, 1/s.

    Positive when the centred running on a perfect straight track is unstable: above its critical
    speed a vehicle hunts (Wickens 2003, ch. 3), and its lateral motion is then a limit cycle set by
    the flanges, not the response to the irregularities that the estimator assumes. (The
    Manchester vehicle: -0.60 1/s at 60 m/s, +0.99 1/s at 80 m/s.) ``eigenvalues``: those of
    :func:`linearised_eigenvalues`, when already computed.
    """
    ev = linearised_eigenvalues(p, speed_m_s) if eigenvalues is None else eigenvalues
    return float(np.max(ev.real))


#: a growth rate below this is rounding, not hunting (undamped modes sit at +-1e-14 1/s), 1/s
HUNTING_TOLERANCE_1_S = 1e-6
#: the shortest integration step :func:`simulate_run` takes, s
MIN_STEP_S = 1e-5


def _substeps(largest_abs_eigenvalue: float, rate_hz: float) -> int:
    """Runge-Kutta steps per sample: the step is the largest divisor of the sample period at or
    below min(1 ms, 2 / |largest eigenvalue|)."""
    period = 1.0 / rate_hz
    return int(np.ceil(period / min(1e-3, 2.0 / largest_abs_eigenvalue)))


def integration_step_s(p: VehicleParameters, speed_m_s: float, rate_hz: float,
                       eigenvalues: np.ndarray | None = None) -> float:
    """The Runge-Kutta step :func:`simulate_run` takes on straight track, s (``eigenvalues`` as
    for :func:`largest_growth_rate`)."""
    ev = linearised_eigenvalues(p, speed_m_s) if eigenvalues is None else eigenvalues
    return 1.0 / rate_hz / _substeps(float(np.max(np.abs(ev))), rate_hz)


def first_lateral_mode(p: VehicleParameters, speed_m_s: float) -> Mode:
    """The first lateral mode of the bogie (resonance case of Munoz 2021 Sec. V-E).

    The lowest-frequency mode whose kinetic energy is mostly lateral/yaw/roll (> 50 %) with more
    than 5 % of it in the bogie frames and wheelsets. The bogies' kinematic modes couple with the
    car body's sway and yaw when their frequencies are close (shares of 10-60 % in the bogies),
    while the car body's own modes keep at most 2 % there (checked at 10, 20 and 40 m/s, with the
    conicity at 90 % and the Kalker coefficients at 50 %).
    """
    cands = [m for m in modes(p, speed_m_s) if m.lateral_share > 0.5 and m.bogie_share > 0.05]
    if not cands:
        raise ValueError("first_lateral_mode: no lateral bogie mode found")
    return cands[0]


def kinematic_wavelength(p: ContactParameters) -> float:
    """Klingel's kinematic wavelength of a free wheelset, 2 pi sqrt(r0 b / lambda0), m."""
    return float(2.0 * np.pi * np.sqrt(p.r0 * p.b / p.conicity))


def free_wheelset(p: ContactParameters, mass_kg: float, izz_kg_m2: float, speed_m_s: float, y0_m: float,
                  length_m: float, step_m: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Lateral motion of an unsuspended wheelset released at y0 on a perfect straight track.

    Uses the same contact forces as the vehicle (static wheel load ``p.wheel_load_n`` per wheel)
    and scipy's implicit Radau integrator (creep makes the free wheelset stiff at low speed).

    Returns
    -------
    (s_m, y_m) on a grid of ``step_m``.
    """
    from scipy.integrate import solve_ivp
    n0 = p.wheel_load_n

    def f(_t, x):
        fy, mz = wheelset_forces(x[0], x[2], x[1], x[3], n0, n0, 0.0, speed_m_s, 0.0, p)
        return [x[2], x[3], fy[0] / mass_kg, mz[0] / izz_kg_m2]

    s = np.arange(0.0, length_m, step_m)
    sol = solve_ivp(f, (0.0, s[-1] / speed_m_s), [y0_m, 0.0, 0.0, 0.0], method="Radau", t_eval=s / speed_m_s,
                    rtol=1e-8, atol=1e-12)
    return s, sol.y[0]


# ---------------------------------------------------------------------------------------------
# the run
@dataclass
class RunResult:
    """Sensor channels and true states of a simulated run at the sensor rate (internal signs:
    y left, yaw counter-clockwise, kappa left positive).

    Attributes
    ----------
    t_s : time since the leading wheelset passed chainage 0, s.
    s_m : chainage of the leading wheelset (the instrumented one), m.
    speed_m_s : forward speed, m/s.
    wheelset_ay_m_s2, wheelset_wz_rad_s, frame_ay_m_s2 : measured channels (with noise when on).
    alignment_m, vertical_m, cross_level_m : the true irregularities at s_m.
    curvature_1_m : design curvature (constant).
    wheelset_y_m, wheelset_psi_rad, wheelset_vy_m_s, wheelset_wz_rad_s_true : leading wheelset states.
    frame_y_m, frame_psi_rad, frame_vy_m_s, frame_wz_rad_s : leading bogie frame states (centre).
    trailing_y_m, trailing_psi_rad, trailing_vy_m_s, trailing_wz_rad_s : states of the leading bogie's
        trailing wheelset (not instrumented; the bogie design model's reference, ``trolley.inservice.bogie``).
    trailing_alignment_m : the true alignment under that wheelset.
    body_y_m, body_vy_m_s : lateral displacement and velocity of the car body above the leading
        bogie's centre.
    wheelset_ay_true_m_s2, frame_ay_true_m_s2 : the accelerations without noise.
    max_shift_m : largest |y - xi| of any wheelset during the recorded run (flange at 9.1 mm).
    sigma_acc_m_s2, sigma_gyro_rad_s : noise standard deviations applied (0 when off).
    rate_hz, step_s : output rate and integration step.
    """

    t_s: np.ndarray
    s_m: np.ndarray
    speed_m_s: np.ndarray
    wheelset_ay_m_s2: np.ndarray
    wheelset_wz_rad_s: np.ndarray
    frame_ay_m_s2: np.ndarray
    alignment_m: np.ndarray
    vertical_m: np.ndarray
    cross_level_m: np.ndarray
    curvature_1_m: float
    wheelset_y_m: np.ndarray
    wheelset_psi_rad: np.ndarray
    wheelset_vy_m_s: np.ndarray
    wheelset_wz_rad_s_true: np.ndarray
    frame_y_m: np.ndarray
    frame_psi_rad: np.ndarray
    frame_vy_m_s: np.ndarray
    frame_wz_rad_s: np.ndarray
    trailing_y_m: np.ndarray
    trailing_psi_rad: np.ndarray
    trailing_vy_m_s: np.ndarray
    trailing_wz_rad_s: np.ndarray
    trailing_alignment_m: np.ndarray
    body_y_m: np.ndarray
    body_vy_m_s: np.ndarray
    wheelset_ay_true_m_s2: np.ndarray
    frame_ay_true_m_s2: np.ndarray
    max_shift_m: float
    sigma_acc_m_s2: float
    sigma_gyro_rad_s: float
    rate_hz: float
    step_s: float
    params: VehicleParameters = field(repr=False, default_factory=VehicleParameters)

    def decimated(self, q: int) -> "RunResult":
        """The run as a recorder decimating by q would keep it (trolley.inservice.resample): the
        sensor channels low-passed and decimated, every other per-sample array at every q-th sample."""
        from dataclasses import fields

        from trolley.inservice.resample import decimated

        if q <= 1:
            return self
        n = len(self.t_s)
        names = [f.name for f in fields(self) if isinstance(getattr(self, f.name), np.ndarray)
                 and getattr(self, f.name).shape == (n,)]
        chans = ("wheelset_ay_m_s2", "wheelset_wz_rad_s", "frame_ay_m_s2")
        kept, z = decimated(q, [getattr(self, k) for k in names if k not in chans], self.sensors())
        new = dict(zip([k for k in names if k not in chans], kept))
        new.update(zip(chans, z.T.copy()))
        # white noise keeps about 1 / q of its power (1 / sqrt(q) of its std) below the new band
        return replace(self, **new, rate_hz=self.rate_hz / q, sigma_acc_m_s2=float(self.sigma_acc_m_s2 / np.sqrt(q)),
                       sigma_gyro_rad_s=float(self.sigma_gyro_rad_s / np.sqrt(q)))

    def sensors(self) -> np.ndarray:
        """(N, 3) measured channels [wheelset a_y, wheelset w_z, frame a_y] (the estimator's input)."""
        return np.column_stack([self.wheelset_ay_m_s2, self.wheelset_wz_rad_s, self.frame_ay_m_s2])

    def calibration_run(self) -> tuple:
        """(t_s, s_m, speed_m_s, sensors, true alignment): the run as a further calibration run of
        identification.calibrate (``extra_runs``) and identification.pooled_statistics."""
        return self.t_s, self.s_m, self.speed_m_s, self.sensors(), self.alignment_m

    def reference_states(self, kind: str = "paper", roll: bool = False) -> np.ndarray:
        """The run's true states in the order of a design model's state vector (the reference of the
        identification, Munoz 2021 Eq. 6 and 26-27).

        ``kind="paper"``: (N, 7) [y, psi, y_f, y', psi', y_f', xi] of Eq. 7 (leading wheelset, leading
        frame). ``kind="bogie"``: (N, 15) in the order of trolley.inservice.bogie.STATE_NAMES (the
        Eq. 7 states, the trailing wheelset, the frame's yaw and the car body above the bogie).
        ``roll``: one more column, the cross-level roll under the leading wheelset, cross level / 2 b
        (rad), the state of a design model whose accelerometers sense gravity
        (trolley.inservice.model.with_sensor_gravity).
        """
        paper = [self.wheelset_y_m, self.wheelset_psi_rad, self.frame_y_m, self.wheelset_vy_m_s,
                 self.wheelset_wz_rad_s_true, self.frame_vy_m_s, self.alignment_m]
        if kind == "paper":
            cols = paper
        elif kind == "bogie":
            cols = paper + [self.trailing_y_m, self.trailing_psi_rad, self.frame_psi_rad, self.trailing_vy_m_s,
                            self.trailing_wz_rad_s, self.frame_wz_rad_s, self.body_y_m, self.body_vy_m_s]
        else:
            raise ValueError(f"kind must be 'paper' or 'bogie', got {kind!r}")
        return np.column_stack(cols + ([self.cross_level_m / (2.0 * self.params.b)] if roll else []))


def _rail_inputs(track: TrackIrregularity, s_lead: np.ndarray, offsets: np.ndarray, v: float, b: float) -> _Inputs:
    sp = track.spline()
    s = s_lead[:, None] - offsets[None, :]
    val, d1, d2 = sp(s), sp(s, 1), sp(s, 2)
    cl, cld, cldd = val[..., 2], v * d1[..., 2], v * v * d2[..., 2]
    u = np.hstack([val[..., 1], cl / (2 * b)])
    ud = np.hstack([v * d1[..., 1], cld / (2 * b)])
    udd = np.hstack([v * v * d2[..., 1], cldd / (2 * b)])
    return _Inputs(xi=val[..., 0], u=u, ud=ud, udd=udd, cl=cl)


def simulate_run(params: VehicleParameters, track: TrackIrregularity, speed_m_s: float, length_m: float,
                 rate_hz: float = 200.0, sensor_noise: bool = True, seed: int = 0,
                 curvature_1_m: float = 0.0, sigma_acc_m_s2: float = SIGMA_ACC_M_S2,
                 sigma_gyro_rad_s: float = SIGMA_GYRO_RAD_S) -> RunResult:
    """Simulate the full vehicle over ``length_m`` of ``track`` and sample the sensors.

    Parameters
    ----------
    params : vehicle (truth) parameters.
    track : irregularities; its grid must start at least the vehicle length before 0 and reach length_m.
    speed_m_s : constant forward speed, m/s (> 0).
    length_m : recorded length from chainage 0, m.
    rate_hz : sensor rate.
    sensor_noise : add white noise to the sensors.
    seed : seed of the sensor noise.
    curvature_1_m : constant design curvature, 1/m, left positive (0: straight track).
    sigma_acc_m_s2, sigma_gyro_rad_s : standard deviations of that white noise per sample
        (default Munoz 2021 Sec. V: 0.01 m/s^2 on both accelerometers, 5e-4 rad/s on the gyro).

    Returns
    -------
    RunResult (Munoz 2021 Sec. V: the CM's virtual measurements).
    """
    if not speed_m_s > 0:
        raise ValueError(f"simulate_run: speed_m_s must be > 0, got {speed_m_s}")
    if not (length_m > 0 and rate_hz > 0):
        raise ValueError(f"simulate_run: length_m and rate_hz must be > 0, got {length_m}, {rate_hz}")
    if not (sigma_acc_m_s2 >= 0 and sigma_gyro_rad_s >= 0):
        raise ValueError(f"simulate_run: the noise sigmas must be >= 0, got {sigma_acc_m_s2}, {sigma_gyro_rad_s}")
    xw = _wheelset_x(params)
    offsets = xw[0] - xw
    if length_m > track.end_m + 1e-9:
        raise ValueError(f"simulate_run: the track ends at {track.end_m:.1f} m < length_m = {length_m}")
    sysm = _System(params, speed_m_s, curvature_1_m)
    lam = np.max(np.abs(np.linalg.eigvals(sysm.jacobian())))
    period = 1.0 / rate_hz
    sub = _substeps(lam, rate_hz)
    dt = period / sub
    if dt < MIN_STEP_S:
        # (a vehicle typed in the wrong units needed 24 GB for the inputs at every half step)
        raise ValueError(f"simulate_run: the vehicle's fastest mode (|eigenvalue| {lam:.3g} 1/s) needs a step of "
                         f"{dt:.3g} s, below {MIN_STEP_S:g} s: stiffer or lighter than any rail vehicle")
    # start with the rear wheelset 1 m after the grid start, on a whole number of output periods
    pre_time = (track.lead_in_m - offsets[-1] - 1.0) / speed_m_s
    n_pre = int(np.floor(pre_time / period))
    if n_pre < 1:
        raise ValueError(f"simulate_run: lead-in {track.lead_in_m} m is shorter than the vehicle "
                         f"({offsets[-1]:.1f} m) plus 1 m")
    n_rec = int(np.floor(length_m / speed_m_s * rate_hz + 1e-9)) + 1
    n_steps = (n_pre + n_rec - 1) * sub
    t_half = -n_pre * period + 0.5 * dt * np.arange(2 * n_steps + 1)
    inp = _rail_inputs(track, speed_m_s * t_half, offsets, speed_m_s, params.b)
    f_all, d_all, dd_all = sysm.forcing(inp)
    rhs = sysm.rhs
    x = sysm.equilibrium()
    keep = np.empty((n_rec, 2 * N_DOF))
    first_rec = n_pre * sub
    if first_rec == 0:
        keep[0] = x
    xi_a, udd_a, cl_a = inp.xi, inp.udd, inp.cl
    for n in range(n_steps):
        h0 = 2 * n
        hm = h0 + 1
        h1 = h0 + 2
        k1 = rhs(x, xi_a[h0], f_all[h0], d_all[h0], dd_all[h0], udd_a[h0], cl_a[h0])
        k2 = rhs(x + 0.5 * dt * k1, xi_a[hm], f_all[hm], d_all[hm], dd_all[hm], udd_a[hm], cl_a[hm])
        k3 = rhs(x + 0.5 * dt * k2, xi_a[hm], f_all[hm], d_all[hm], dd_all[hm], udd_a[hm], cl_a[hm])
        k4 = rhs(x + dt * k3, xi_a[h1], f_all[h1], d_all[h1], dd_all[h1], udd_a[h1], cl_a[h1])
        x = x + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        m = n + 1 - first_rec
        if m >= 0 and m % sub == 0:
            keep[m // sub] = x
    # accelerations at the samples, one batched call
    hs = 2 * (first_rec + sub * np.arange(n_rec))
    xdot = rhs(keep.T, xi_a[hs].T, f_all[hs].T, d_all[hs].T, dd_all[hs].T, udd_a[hs].T, cl_a[hs].T)
    t = t_half[hs]
    s = speed_m_s * t
    v2k = speed_m_s ** 2 * curvature_1_m
    ws_ay = xdot[N_DOF] + v2k
    fr_ay = xdot[N_DOF + _frame_dof(0, 0)] + v2k
    if params.sensor_gravity:
        dr = rolling_radius_difference(keep[:, 0] - inp.xi[hs, 0], params.contact)
        roll_w = (inp.cl[hs, 0] + dr) / (2 * params.b)
        ws_ay = ws_ay + G_M_S2 * roll_w
        fr_ay = fr_ay + G_M_S2 * keep[:, _frame_dof(0, 2)]
    wz_true = keep[:, N_DOF + 4] + speed_m_s * curvature_1_m
    rng = np.random.default_rng(seed)
    sa, sg = (float(sigma_acc_m_s2), float(sigma_gyro_rad_s)) if sensor_noise else (0.0, 0.0)
    noise = rng.standard_normal((3, n_rec)) if sensor_noise else np.zeros((3, n_rec))
    lat, vert, cl = track.at(s)
    shift = np.max(np.abs(keep[:, :4] - inp.xi[hs]))
    return RunResult(t_s=t, s_m=s, speed_m_s=np.full(n_rec, float(speed_m_s)),
                     wheelset_ay_m_s2=ws_ay + sa * noise[0], wheelset_wz_rad_s=wz_true + sg * noise[1],
                     frame_ay_m_s2=fr_ay + sa * noise[2], alignment_m=lat, vertical_m=vert, cross_level_m=cl,
                     curvature_1_m=float(curvature_1_m), wheelset_y_m=keep[:, 0].copy(),
                     wheelset_psi_rad=keep[:, 4].copy(), wheelset_vy_m_s=keep[:, N_DOF].copy(),
                     wheelset_wz_rad_s_true=wz_true, frame_y_m=keep[:, _frame_dof(0, 0)].copy(),
                     frame_psi_rad=keep[:, _frame_dof(0, 1)].copy(),
                     frame_vy_m_s=keep[:, N_DOF + _frame_dof(0, 0)].copy(),
                     frame_wz_rad_s=keep[:, N_DOF + _frame_dof(0, 1)].copy(), trailing_y_m=keep[:, 1].copy(),
                     trailing_psi_rad=keep[:, 5].copy(), trailing_vy_m_s=keep[:, N_DOF + 1].copy(),
                     trailing_wz_rad_s=keep[:, N_DOF + 5].copy(), trailing_alignment_m=inp.xi[hs, 1].copy(),
                     body_y_m=keep[:, _BODY] + params.a_bogie * keep[:, _BODY + 1],
                     body_vy_m_s=keep[:, N_DOF + _BODY] + params.a_bogie * keep[:, N_DOF + _BODY + 1],
                     wheelset_ay_true_m_s2=ws_ay,
                     frame_ay_true_m_s2=fr_ay, max_shift_m=float(shift), sigma_acc_m_s2=sa, sigma_gyro_rad_s=sg,
                     rate_hz=float(rate_hz), step_s=float(dt), params=params)


def with_factors(p: VehicleParameters, conicity_factor: float = 1.0, creep_factor: float = 1.0) -> VehicleParameters:
    """A copy with the truth's conicity and Kalker coefficients scaled (robustness study, Munoz 2021 Sec. V-D)."""
    return replace(p, conicity_factor=conicity_factor, creep_factor=creep_factor)

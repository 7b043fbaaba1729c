"""Bogie design model for the in-service alignment estimator: both wheelsets of the instrumented
bogie, its frame in lateral and yaw and the car body on the secondary suspension, the trailing
wheelset running over the alignment the leading one saw 2a earlier (beyond Munoz 2021).

Why a second model
------------------
The paper's simplified model (SM, :mod:`trolley.inservice.model`) holds one wheelset and a frame
that only moves sideways, with a quarter of the car body rigidly added to it; its primary yaw
springs act against a frame that cannot yaw. On a real bogie the stiff longitudinal primary
springs lock the wheelset's yaw to the frame's, the frame's yaw follows the lateral positions of
BOTH wheelsets, the trailing one running over xi(s - 2a), and above about 0.7 Hz the soft secondary
suspension isolates the car body, so the frame moves with its own mass only. The SM absorbs all of
this into four equivalent parameters and keeps an alignment error of 0.21 mm in D1 (3-25 m) with
noise-free sensors on the truth simulator. A linear non-causal regression from the same three
sensors to the D1 alignment with +-12 m of lags reached 0.11 mm on the same data (an experiment,
not in the code): the information is in the sensors. This model puts the missing mechanics back;
its D1 error is 0.09 mm (docs/inservice.md, benchmarks/bench_inservice.py).

Model
-----
Generalised coordinates q = [y1, psi1, y_f, y2, psi2, psi_f, y_b]: leading wheelset (instrumented)
lateral and yaw, frame lateral, trailing wheelset lateral and yaw, frame yaw, and the lateral
displacement of the car body's share carried by this bogie (half the body, ``mb``). Each wheelset
has the SM's contact (Kalker linear creep on conical treads, gravitational stiffness with the
physical sign, module :mod:`trolley.inservice.model`), driven by the alignment under it:
xi1 = xi(s) and xi2 = xi(s - 2a). Each axle box (per wheelset two, at +-ls) has a lateral
spring/damper ky, cy between the wheelset and the frame point at x_i = +-a (deflection
y_i - y_f - x_i psi_f) and a longitudinal one kx, cx (yaw deflection psi_i - psi_f). The body
share moves on the secondary lateral stiffness and damping ``ky_s``, ``cy_s`` (totals per bogie);
the frame's yaw is held by the secondary yaw stiffness and damping ``k_yaw_s``, ``c_yaw_s`` (the
body's yaw taken as steady). A whole car body in lateral and yaw, held at its other end by the
rear bogie over xi(s - 2 a_b), was tried as well: over seeds 1-10 of the benchmark it gave
J 0.322 mm over 3-200 m against 0.313 mm for this half body, with 7 more states, and was dropped.

The delay xi2(t) = xi1(t - 2a/V) is a Pade approximant of order ``pade_order`` (scipy.interpolate.pade
of exp(-x), realised by scipy.signal.tf2ss in the scaled time t/T); its error at the shortest D1
wave at 20 m/s (3 m, omega T = 5.4) is 0.5 % at order 5.

State (the first seven as the paper's Eq. 7, so that the alignment is x[6] in both models):
x = [y1, psi1, y_f, y1', psi1', y_f', xi, y2, psi2, psi_f, y2', psi2', psi_f', y_b, y_b', z_1 .. z_n]
with z the Pade states. Measurements as Eq. 8: [y1'' , psi1', y_f'', xi = 0] (+ V^2 kappa, V kappa,
V^2 kappa on curves).

Curved track: the same known input as the SM (centripetal V^2 kappa on every lateral coordinate,
the wheels' longitudinal creepage l kappa), plus the deflections a constant curvature imposes on
the primary suspension of a straight frame: y_i - y_f - x_i psi_f + kappa x_i^2 / 2 and
psi_i - psi_f + kappa x_i in track-relative coordinates.

References
----------
S. Munoz, J. Ros, P. Urda, J. L. Escalona, IEEE Access 9 (2021) 60010-60025, Eq. 3-4, 7-8, 13-15
(the SM this model extends).
A. H. Wickens, Fundamentals of Rail Vehicle Dynamics (2003), ch. 5 (the two-axle bogie).
G. A. Baker, P. Graves-Morris, Pade Approximants (1996) (the delay exp(-sT)).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from math import factorial

import numpy as np

from trolley.inservice.model import G_M_S2, DesignParameters

#: positions of q = [y1, psi1, y_f, y2, psi2, psi_f, y_b] and of their rates in the state vector
Q_POS = (0, 1, 2, 7, 8, 9, 13)
V_POS = (3, 4, 5, 10, 11, 12, 14)
#: position of the alignment xi (as in the paper's Eq. 7)
XI_POS = 6
#: number of mechanical states (before the Pade states)
N_MECH = 15
STATE_NAMES = ("y_m", "psi_rad", "yf_m", "vy_m_s", "wz_rad_s", "vyf_m_s", "xi_m", "y2_m", "psi2_rad",
               "psif_rad", "vy2_m_s", "wz2_rad_s", "wzf_rad_s", "yb_m", "vyb_m_s")
STATE_KINDS = ("y", "psi", "y", "vy", "wz", "vy", "xi", "y", "psi", "psi", "vy", "wz", "wz", "y", "vy")


@lru_cache(maxsize=8)
def _pade_unit(order: int):
    """State-space (A, B, C, D) of the [order/order] Pade approximant of exp(-x) in scaled time x."""
    from scipy.interpolate import pade
    from scipy.signal import tf2ss

    taylor = [(-1.0) ** k / factorial(k) for k in range(2 * order + 1)]
    num, den = pade(taylor, order)
    A, B, C, D = tf2ss(num.coeffs, den.coeffs)
    return A, B[:, 0], C[0], float(D[0, 0])


def pade_delay(delay_s: float, order: int):
    """(A, B, C, D) of z' = A z + B u, y = C z + D u approximating y(t) = u(t - delay_s)."""
    A, B, C, D = _pade_unit(order)
    return A / delay_s, B / delay_s, C, D


@dataclass(frozen=True)
class BogieParameters(DesignParameters):
    """Parameters of the bogie design model, SI.

    Attributes
    ----------
    m, I : wheelset mass (kg) and yaw inertia (kg m^2).
    l : half distance between the contact points, m.
    ls : half lateral spacing of the axle boxes, m.
    a : half bogie wheelbase, m.
    conicity, r0 : equivalent conicity (-) and centred rolling radius (m).
    mf : bogie frame mass, kg.
    If : frame yaw inertia, kg m^2.
    mb : the car body's share carried by this bogie (half the body), kg; it moves laterally on the
        secondary suspension ky_s, cy_s (totals per bogie, N/m and N s/m).
    f11, f22 : Kalker's longitudinal and lateral creep coefficients per wheel, N.
    k_yaw_s, c_yaw_s : secondary yaw stiffness (N m/rad) and damping (N m s/rad) of the frame.
    kx, cx, ky, cy : primary longitudinal and lateral stiffness (N/m) and damping (N s/m) per axle
        box; the equivalent values are identified (Eq. 6).
    pade_order : order of the Pade approximant of the wheelbase delay.
    sensor_gravity : the accelerometers also sense g times their roll, as real ones do (one more
        state, trolley.inservice.model.with_sensor_gravity); False: the paper's virtual sensors.
    """

    m: float = 1813.0
    I: float = 1120.0
    l: float = 0.7175
    ls: float = 1.0
    a: float = 1.28
    conicity: float = 0.15
    r0: float = 0.46
    mf: float = 2615.0
    If: float = 3067.0
    mb: float = 16000.0
    ky_s: float = 3.2e5
    cy_s: float = 3.2e4
    f11: float = 1.0e7
    f22: float = 8.7e6
    k_yaw_s: float = 3.2e5
    c_yaw_s: float = 0.0
    kx: float = 31.391e6
    cx: float = 0.0
    ky: float = 3.884e6
    cy: float = 0.0
    pade_order: int = 5
    sensor_gravity: bool = False

    #: model kind written to model.toml
    KIND = "bogie"
    POSITIVE = ("m", "I", "l", "ls", "a", "r0", "mf", "If", "mb")
    NONNEGATIVE = ("conicity", "f11", "f22")

    def __post_init__(self):
        self._check("bogie model parameter")
        if int(self.pade_order) != self.pade_order or not 1 <= self.pade_order <= 8:
            raise ValueError(f"pade_order must be an integer in 1-8, got {self.pade_order}")

    @property
    def _n_design_states(self) -> int:
        return N_MECH + int(self.pade_order)

    @property
    def _design_state_kinds(self) -> tuple[str, ...]:
        return STATE_KINDS + ("delay",) * int(self.pade_order)

    @property
    def gravitational_stiffness(self) -> float:
        """K_g per wheelset = (m + (mf + mb) / 2) g alpha / l, N/m (sign as model.ModelParameters)."""
        return (self.m + 0.5 * (self.mf + self.mb)) * G_M_S2 * self.conicity / self.l

    def _design_state_space(self, speed_m_s: float):
        return state_space(self, speed_m_s)

    def _design_full_states(self, mechanical, t_s, speed_m_s: float) -> np.ndarray:
        """Reference states with the Pade states appended (for Eq. 26-27 on a reference run).

        Parameters
        ----------
        mechanical : (N, 15) reference states in the order of :data:`STATE_NAMES`.
        t_s : (N,) uniform times, s.
        speed_m_s : constant speed, m/s.
        """
        from scipy.signal import lsim

        X = np.asarray(mechanical, float)
        A, B, C, D = pade_delay(2 * self.a / speed_m_s, int(self.pade_order))
        n = len(B)
        _, _, z = lsim((A, B[:, None], np.eye(n), np.zeros((n, 1))), X[:, XI_POS], np.asarray(t_s, float),
                       interp=True)
        return np.column_stack([X, np.reshape(z, (len(X), n))])


def matrices(p: BogieParameters, speed_m_s: float):
    """M, C, K (7x7), Kd1, Kd2 (7,) and Bk (7,) of the bogie model in q = [y1, psi1, y_f, y2, psi2, psi_f, y_b]."""
    V = float(speed_m_s)
    if not V > 0:
        raise ValueError(f"speed must be > 0 m/s, got {speed_m_s}")
    M = np.diag([p.m, p.I, p.mf, p.m, p.I, p.If, p.mb])
    K = np.zeros((7, 7))
    C = np.zeros((7, 7))
    Kd1, Kd2 = np.zeros(7), np.zeros(7)
    Bk = np.zeros(7)
    kg = p.gravitational_stiffness
    kpsi = 2 * p.f11 * p.l * p.conicity / p.r0
    for iy, ipsi, x, Kd in ((0, 1, p.a, Kd1), (3, 4, -p.a, Kd2)):
        K[iy, iy] += kg
        K[iy, ipsi] -= 2 * p.f22
        K[ipsi, iy] += kpsi
        C[iy, iy] += 2 * p.f22 / V
        C[ipsi, ipsi] += 2 * p.f11 * p.l ** 2 / V
        Kd[iy], Kd[ipsi] = kg, kpsi
        lat = np.zeros(7)
        lat[[iy, 2, 5]] = (1.0, -1.0, -x)
        yaw = np.zeros(7)
        yaw[[ipsi, 5]] = (1.0, -1.0)
        K += 2 * p.ky * np.outer(lat, lat) + 2 * p.kx * p.ls ** 2 * np.outer(yaw, yaw)
        C += 2 * p.cy * np.outer(lat, lat) + 2 * p.cx * p.ls ** 2 * np.outer(yaw, yaw)
        Bk -= 2 * p.ky * lat * x ** 2 / 2 + 2 * p.kx * p.ls ** 2 * yaw * x
        Bk[iy] -= p.m * V ** 2
        Bk[ipsi] -= 2 * p.f11 * p.l ** 2
    K[5, 5] += p.k_yaw_s
    C[5, 5] += p.c_yaw_s
    sec = np.zeros(7)
    sec[[2, 6]] = (1.0, -1.0)
    K += p.ky_s * np.outer(sec, sec)
    C += p.cy_s * np.outer(sec, sec)
    Bk[2] -= p.mf * V ** 2
    Bk[6] -= p.mb * V ** 2
    return M, C, K, Kd1, Kd2, Bk


def state_space(p: BogieParameters, speed_m_s: float):
    """Continuous state-space form of the bogie model, xi a random walk.

    Returns
    -------
    Fc : (n, n) state matrix, n = 15 + pade_order (the roll of model.with_sensor_gravity is added
        by BogieParameters.state_space).
    Bc : (n, 1) input matrix of the design curvature kappa.
    Hc : (4, n) measurement matrix: leading wheelset y'', psi', frame y_f'' and the virtual xi.
    Dc : (4, 1) direct feed of kappa (V^2 kappa, V kappa, V^2 kappa, 0).
    """
    V = float(speed_m_s)
    M, C, K, Kd1, Kd2, Bk = matrices(p, V)
    Mi = np.linalg.inv(M)
    Ap, Bp, Cp, Dp = pade_delay(2 * p.a / V, int(p.pade_order))
    n = N_MECH + int(p.pade_order)
    qp, vp = list(Q_POS), list(V_POS)
    zp = list(range(N_MECH, n))
    Fc = np.zeros((n, n))
    Fc[qp, vp] = 1.0
    Fc[np.ix_(vp, qp)] = -Mi @ K
    Fc[np.ix_(vp, vp)] = -Mi @ C
    Fc[vp, XI_POS] = Mi @ (Kd1 + Dp * Kd2)
    Fc[np.ix_(vp, zp)] = np.outer(Mi @ Kd2, Cp)
    Fc[np.ix_(zp, zp)] = Ap
    Fc[zp, XI_POS] = Bp
    Bc = np.zeros((n, 1))
    Bc[vp, 0] = Mi @ Bk
    e = np.eye(n)
    Hc = np.vstack([Fc[3], e[4], Fc[5], e[XI_POS]])
    Dc = np.array([[Bc[3, 0] + V ** 2], [V], [Bc[5, 0] + V ** 2], [0.0]])
    return Fc, Bc, Hc, Dc


def nominal_from_vehicle(vehicle) -> dict:
    """Nominal bogie-model parameters from a truth VehicleParameters (the values a user reads off
    the vehicle's data sheet; conicity and creep without the robustness factors)."""
    return {"m": vehicle.m_wheelset, "I": vehicle.izz_wheelset, "l": vehicle.b, "ls": vehicle.d_p,
            "a": vehicle.a_wheelset, "conicity": vehicle.conicity, "r0": vehicle.r0,
            "mf": vehicle.m_frame, "If": vehicle.izz_frame, "mb": vehicle.m_body / 2.0,
            "ky_s": 2 * vehicle.ky_s, "cy_s": 2 * vehicle.cy_s, "f11": vehicle.f11,
            "f22": vehicle.f22, "k_yaw_s": 2 * vehicle.kx_s * vehicle.d_s ** 2,
            "c_yaw_s": 2 * vehicle.cx_s * vehicle.d_s ** 2, "kx": vehicle.kx_p, "cx": vehicle.cx_p,
            "ky": vehicle.ky_p, "cy": vehicle.cy_p}


def nominal_parameters(vehicle, kind: str = "bogie"):
    """The nominal design model of ``kind`` ("bogie" or "paper") for a truth VehicleParameters:
    BogieParameters from :func:`nominal_from_vehicle`, or the paper's ModelParameters from
    ``vehicle.nominal()``."""
    from trolley.inservice.model import ModelParameters

    if kind == "bogie":
        return BogieParameters(**nominal_from_vehicle(vehicle))
    if kind == "paper":
        return ModelParameters(**vehicle.nominal())
    raise ValueError(f"kind must be 'bogie' or 'paper', got {kind!r}")

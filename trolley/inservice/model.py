"""Simplified estimator design model (SM) of Munoz 2021: one wheelset and a suspended frame.

Implements Munoz et al. 2021, Sec. III-C and IV-A: the generalised coordinates q = [y, psi, y_f]
(Eq. 2), the equations of motion M q'' + (Cs + Cc) q' + (Ks + Kc) q = Qc,0(xi) (Eq. 3) with the
parameters of Eq. 4, the state x = [y, psi, y_f, y', psi', y_f', xi] (Eq. 7), the continuous state
matrix Fc (Eq. 13) with xi a random walk (Eq. 10-11) and the measurement matrix Hc (Eq. 15).

Conventions
-----------
SI units. Track frame following the ideal (irregularity-free) centre line at the vehicle speed V;
y and y_f positive to the left, yaw psi counter-clockwise (nose to the left) positive. xi is the
lateral alignment (rail centre line displacement, positive to the left; no gauge variation).
Primary suspension: two axle boxes at +-ls, each with a longitudinal spring/damper kx, cx (giving
the yaw stiffness 2 kx ls^2 against the frame, whose yaw is constrained, Sec. III-D) and a lateral
spring/damper ky, cy (total 2 ky, 2 cy between wheelset and frame).

Wheel-rail contact (Kalker's linear theory, conical treads, knife-edge rails, no flange)
-------------------------------------------------------------------------------------------
Rolling radii r0 +- alpha (y - xi) (left/right), contact points at +-l. Creepages per wheel:
longitudinal -(l kappa + l psi'/V +- alpha (y - xi)/r0), lateral y'/V - psi (the rail's own
slope xi' cancels between the lateral velocity and the yaw relative to the rail), spin psi'/V
(the +-alpha/r0 parts cancel between the two wheels). Forces F = -f11 nu_x, F_y = -f22 nu_y -
f23 phi, M_z = f23 nu_y - f33 phi per wheel.

Gravitational stiffness K_g (checked against the physics)
---------------------------------------------------------
The printed Eq. 14 gives the first entry of Kd = dQc,0/dxi as ``2 alpha g (m - mf) / l``. With
the wheelset shifted by (y - xi) relative to the rails the conical treads roll it by
phi = alpha (y - xi) / l, which tilts the resultant of the wheel loads (the weight of the wheelset
plus the supported mass, W = (m + mf) g) by phi towards the rails' centre: a RESTORING lateral
force -W alpha (y - xi) / l. So K_g = + (m + mf) g alpha / l, entering Kc(1, 1) with a plus sign
and Kd(1) = + K_g. The printed ``(m - mf)`` is negative whenever the supported mass exceeds the
wheelset's (always: mf is a quarter of a car body plus half a bogie frame) and would make the
gravitational term DE-stabilising, which is unphysical; a factor 2 does not follow from this
derivation either (each wheel carries W/2 and both tilt by phi). This module uses
K_g = (m + mf) g alpha / l. The second entry, 2 alpha f11 l / r0, agrees with the printed Eq. 14.

Curved track (beyond the paper)
-------------------------------
A known design curvature kappa (1/m, positive to the left, no cant) enters as an input: in the
rotating track frame the wheelset and frame need the centripetal acceleration V^2 kappa and the
wheels' longitudinal creepages gain -+ l kappa. The accelerometers and the gyro measure absolute
quantities: y'' + V^2 kappa, psi' + V kappa, y_f'' + V^2 kappa.

References
----------
S. Munoz, J. Ros, P. Urda, J. L. Escalona, "Estimation of lateral track irregularity through
Kalman filtering techniques", IEEE Access 9 (2021) 60010-60025, Eq. 2-4, 7, 9-15.
A. H. Wickens, Fundamentals of Rail Vehicle Dynamics (2003): gravitational stiffness W lambda / l.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

#: standard gravity, m/s^2
G_M_S2 = 9.80665

#: names of the state vector x (Eq. 7)
STATE_NAMES = ("y_m", "psi_rad", "yf_m", "vy_m_s", "wz_rad_s", "vyf_m_s", "xi_m")
#: names of the measurement vector z (Eq. 8)
MEASUREMENT_NAMES = ("wheelset_ay_m_s2", "wheelset_wz_rad_s", "frame_ay_m_s2", "xi_virtual_m")
N_STATE = 7
N_MEAS = 4
#: index of the alignment xi in the state (Eq. 7; the bogie model keeps it there)
XI_INDEX = 6
#: kinds of the states of Eq. 7 (DesignParameters.state_kinds)
STATE_KINDS = ("y", "psi", "y", "vy", "wz", "vy", "xi")


class DesignParameters:
    """What the parameters of every design model share (this SM and trolley.inservice.bogie): the
    identified p_opt (Eq. 5), the check of the values, and the sensed gravity.

    Subclasses are frozen dataclasses with the fields of :attr:`OPT`, a field ``sensor_gravity``
    (bool), and name the fields that must be > 0 in :attr:`POSITIVE`. They give their own
    mechanics through ``_design_state_space``, ``_n_design_states``, ``_design_state_kinds`` and
    ``_design_full_states``; this class adds the roll state when ``sensor_gravity`` is set
    (:func:`with_sensor_gravity`)."""

    #: names of the parameters identified by optimisation (Eq. 5)
    OPT = ("kx", "cx", "ky", "cy")
    POSITIVE: tuple[str, ...] = ()
    #: fields that must be >= 0 (0: the hand-calculated cases without contact or creep)
    NONNEGATIVE: tuple[str, ...] = ()

    @property
    def n_state(self) -> int:
        """Number of states: the design model's, plus the roll with ``sensor_gravity``."""
        return self._n_design_states + int(self.sensor_gravity)

    @property
    def state_kinds(self) -> tuple[str, ...]:
        """What each state is, for the defaults that depend on it (estimator's Qc and P0, the
        tuning of identification): "y" lateral position, "psi" yaw, "vy" lateral velocity, "wz"
        yaw rate, "xi" the alignment, "delay" a state carrying xi to a later wheelset, "roll" the
        cross-level roll the accelerometers sense gravity through (last, with ``sensor_gravity``)."""
        return self._design_state_kinds + ((ROLL_KIND,) if self.sensor_gravity else ())

    def state_space(self, speed_m_s: float):
        """(Fc, Bc, Hc, Dc) of the design model (the interface the estimator uses for any model),
        with the roll state of :func:`with_sensor_gravity` appended when ``sensor_gravity`` is set."""
        mats = self._design_state_space(speed_m_s)
        return with_sensor_gravity(*mats, self.conicity, self.l) if self.sensor_gravity else mats

    def full_states(self, states, t_s, speed_m_s: float) -> np.ndarray:
        """Reference states for Eq. 26-27 in the order of the state vector.

        ``states`` holds the design model's reference states (each model's ``_design_full_states``
        says which) and, with ``sensor_gravity``, the true roll (cross level / 2 l under the
        instrumented wheelset, rad) as its last column
        (trolley.inservice.vehicle.RunResult.reference_states(kind, roll=True)).
        """
        X = np.asarray(states, float)
        if not self.sensor_gravity:
            return self._design_full_states(X, t_s, speed_m_s)
        return np.column_stack([self._design_full_states(X[:, :-1], t_s, speed_m_s), X[:, -1]])

    def _check(self, what: str) -> None:
        for k, v in asdict(self).items():
            if not np.isfinite(v):
                raise ValueError(f"{what} {k} = {v} is not finite")
        for k in self.POSITIVE:
            if getattr(self, k) <= 0:
                raise ValueError(f"{what} {k} must be > 0, got {getattr(self, k)}")
        for k in self.NONNEGATIVE:
            if getattr(self, k) < 0:
                raise ValueError(f"{what} {k} must be >= 0, got {getattr(self, k)}")
        if not isinstance(self.sensor_gravity, bool):
            raise ValueError(f"{what} sensor_gravity must be true or false, got {self.sensor_gravity!r}")

    def with_opt(self, popt):
        """A copy with p_opt = [kx, cx, ky, cy] replaced (Eq. 5)."""
        return replace(self, **dict(zip(self.OPT, (float(v) for v in popt))))

    @property
    def popt(self) -> np.ndarray:
        """p_opt = [kx, cx, ky, cy] (Eq. 5)."""
        return np.array([getattr(self, k) for k in self.OPT])


#: kind of the state a design model gains when its accelerometers sense gravity
ROLL_KIND = "roll"


def with_sensor_gravity(Fc, Bc, Hc, Dc, conicity: float, l: float):
    """A design model whose accelerometers also sense gravity through their roll (beyond the paper).

    An accelerometer fixed to a body that rolls by phi reads its lateral acceleration plus g phi
    (small angles). Munoz 2021's virtual sensors leave this out; real axle-box and frame
    accelerometers do not. Two rolls reach the sensors of the instrumented bogie:

    * the cross level under the wheelset, phi_c = cross level / 2 l: an unknown track input, here one
      more state, a random walk like xi (Eq. 10-11), appended last; the wheelset follows it, and
      the frame, carried on both wheelsets by the stiff vertical primary springs, follows it at the
      long wavelengths where it matters (its own roll on the secondary suspension is left to the
      model error of Eq. 26-29);
    * the profile roll of conical treads, alpha (y - xi) / l (as for the gravitational stiffness,
      module docstring), which depends on states the model already has.

    So the wheelset accelerometer's row of Hc gains g on phi_c and g alpha / l on y - xi, the frame
    accelerometer's row g on phi_c. At the long wavelengths g phi_c looks like a lateral
    acceleration; the gyro, which senses no gravity, is what tells them apart there.

    Parameters
    ----------
    Fc, Bc, Hc, Dc : the design model's state space (state_space of this module or of
        trolley.inservice.bogie); y at state 0, xi at :data:`XI_INDEX`.
    conicity, l : the treads' conicity alpha (-) and half the contact distance l (m).

    Returns
    -------
    Fc, Bc, Hc, Dc with one more state (the roll, rad; zero row of Fc: a random walk).
    """
    n = Fc.shape[0] + 1
    F = np.zeros((n, n))
    F[:-1, :-1] = Fc
    B = np.zeros((n, Bc.shape[1]))
    B[:-1] = Bc
    H = np.zeros((Hc.shape[0], n))
    H[:, :-1] = Hc
    H[[0, 2], -1] = G_M_S2
    H[0, 0] += G_M_S2 * conicity / l
    H[0, XI_INDEX] -= G_M_S2 * conicity / l
    return F, B, H, Dc


@dataclass(frozen=True)
class ModelParameters(DesignParameters):
    """Parameters p of the SM (Munoz 2021 Eq. 4-5), SI.

    Attributes
    ----------
    m, I : wheelset mass (kg) and yaw moment of inertia (kg m^2).
    l : half distance between the contact points, m.
    ls : half distance between the primary suspension elements, m.
    conicity : equivalent conicity alpha of the treads (-).
    r0 : centred rolling radius, m.
    mf : suspended mass carried by the wheelset (a quarter car body + half a bogie frame), kg.
    f11, f22, f23, f33 : Kalker's linear creep coefficients per wheel (N, N m, N m, N m^2).
    kx, cx : longitudinal primary stiffness (N/m) and damping (N s/m) per axle box (p_opt).
    ky, cy : lateral primary stiffness (N/m) and damping (N s/m) per axle box (p_opt).
    sensor_gravity : the accelerometers also sense g times their roll, as real ones do (one more
        state, :func:`with_sensor_gravity`); False: the paper's virtual sensors.
    """

    m: float = 1300.0
    I: float = 700.0
    l: float = 0.7175
    ls: float = 1.0
    conicity: float = 0.15
    r0: float = 0.43
    mf: float = 8000.0
    f11: float = 7.0e6
    f22: float = 6.0e6
    f23: float = 0.0
    f33: float = 0.0
    kx: float = 4.0e6
    cx: float = 2.0e4
    ky: float = 1.5e6
    cy: float = 2.0e4
    sensor_gravity: bool = False

    #: model kind written to model.toml (the bogie model of trolley.inservice.bogie is "bogie")
    KIND = "paper"
    POSITIVE = ("m", "I", "l", "ls", "r0", "mf")
    NONNEGATIVE = ("conicity", "f11", "f22")

    def __post_init__(self):
        self._check("model parameter")

    @property
    def gravitational_stiffness(self) -> float:
        """K_g = (m + mf) g alpha / l, N/m (see the module docstring for the sign check)."""
        return (self.m + self.mf) * G_M_S2 * self.conicity / self.l

    _n_design_states = N_STATE
    _design_state_kinds = STATE_KINDS

    def _design_state_space(self, speed_m_s: float):
        return state_space(self, speed_m_s)

    def _design_full_states(self, states, t_s, speed_m_s: float) -> np.ndarray:
        """The (N, 7) states of Eq. 7 as they are."""
        return states


def matrices(p: ModelParameters, speed_m_s: float):
    """Mass, damping and stiffness matrices of Eq. 3 and the input vectors.

    Parameters
    ----------
    p : model parameters (Eq. 4).
    speed_m_s : forward speed V, m/s (> 0).

    Returns
    -------
    M, C, K : (3, 3) arrays; C = Cs + Cc, K = Ks + Kc (Eq. 3).
    Kd : (3,) dQc,0/dxi (Eq. 14, with the physical sign of K_g).
    Bk : (3,) generalised force per unit design curvature kappa (curved track, beyond the paper).
    """
    V = float(speed_m_s)
    if not V > 0:
        raise ValueError(f"speed must be > 0 m/s, got {speed_m_s}")
    M = np.diag([p.m, p.I, p.mf])
    ky2, cy2 = 2 * p.ky, 2 * p.cy
    Ks = np.array([[ky2, 0.0, -ky2], [0.0, 2 * p.kx * p.ls ** 2, 0.0], [-ky2, 0.0, ky2]])
    Cs = np.array([[cy2, 0.0, -cy2], [0.0, 2 * p.cx * p.ls ** 2, 0.0], [-cy2, 0.0, cy2]])
    kg = p.gravitational_stiffness
    kpsi = 2 * p.f11 * p.l * p.conicity / p.r0
    Kc = np.array([[kg, -2 * p.f22, 0.0], [kpsi, 2 * p.f23, 0.0], [0.0, 0.0, 0.0]])
    Cc = np.array([[2 * p.f22 / V, 2 * p.f23 / V, 0.0],
                   [-2 * p.f23 / V, (2 * p.f11 * p.l ** 2 + 2 * p.f33) / V, 0.0],
                   [0.0, 0.0, 0.0]])
    Kd = np.array([kg, kpsi, 0.0])
    Bk = np.array([-p.m * V ** 2, -2 * p.f11 * p.l ** 2, -p.mf * V ** 2])
    return M, Cs + Cc, Ks + Kc, Kd, Bk


def state_space(p: ModelParameters, speed_m_s: float):
    """Continuous state-space form of the SM with xi as a random-walk state (Eq. 9-15).

    Parameters
    ----------
    p : model parameters.
    speed_m_s : forward speed, m/s.

    Returns
    -------
    Fc : (7, 7) continuous state matrix (Eq. 13); row 7 is zero (xi' = 0 + noise, Eq. 10).
    Bc : (7, 1) input matrix of the design curvature kappa (zero on straight track).
    Hc : (4, 7) measurement matrix (Eq. 15): rows 4 and 6 of Fc, psi' and the virtual xi.
    Dc : (4, 1) direct feed of kappa into the measurements (V^2 kappa, V kappa, V^2 kappa, 0).
    """
    M, C, K, Kd, Bk = matrices(p, speed_m_s)
    Mi = np.linalg.inv(M)
    Fc = np.zeros((N_STATE, N_STATE))
    Fc[0:3, 3:6] = np.eye(3)
    Fc[3:6, 0:3] = -Mi @ K
    Fc[3:6, 3:6] = -Mi @ C
    Fc[3:6, 6] = Mi @ Kd
    Bc = np.zeros((N_STATE, 1))
    Bc[3:6, 0] = Mi @ Bk
    Hc = np.vstack([Fc[3], np.eye(N_STATE)[4], Fc[5], np.eye(N_STATE)[6]])
    V = float(speed_m_s)
    Dc = np.array([[Bc[3, 0] + V ** 2], [V], [Bc[5, 0] + V ** 2], [0.0]])
    return Fc, Bc, Hc, Dc


@dataclass(frozen=True)
class Mode:
    """One vibration mode of the SM: damped frequency (Hz), damping ratio, undamped frequency (Hz)."""

    frequency_hz: float
    damping_ratio: float
    natural_frequency_hz: float


def eigenfrequencies(p: ModelParameters, speed_m_s: float) -> list[Mode]:
    """Modes of the mechanical part of the SM (the 6 states q, q'), oscillatory ones only.

    Parameters
    ----------
    p : model parameters.
    speed_m_s : forward speed, m/s (creep damping is proportional to 1/V).

    Returns
    -------
    modes : one Mode per complex-conjugate eigenvalue pair of Fc[:6, :6], sorted by frequency.
        Real (overdamped) eigenvalues and rigid-body zeros are left out.

    References
    ----------
    Munoz 2021 Sec. V-E (modal analysis for the resonance case).
    """
    Fc = state_space(p, speed_m_s)[0][:6, :6]
    lam = np.linalg.eigvals(Fc)
    lam = lam[lam.imag > 1e-9 * np.abs(lam)]
    wn = np.abs(lam)
    modes = [Mode(float(li.imag / (2 * np.pi)), float(-li.real / w), float(w / (2 * np.pi)))
             for li, w in zip(lam, wn)]
    return sorted(modes, key=lambda m: m.frequency_hz)


def simulate_response(p, speed_m_s: float, t_s, xi_m, curvature_1_m=None):
    """Noise-free response of a design model to a prescribed alignment xi(t) (Eq. 3 as an ODE in q).

    Parameters
    ----------
    p : model parameters: :class:`ModelParameters` (the SM) or any model with the same interface
        (``state_space(V)``, alignment at state 6), e.g. trolley.inservice.bogie.BogieParameters.
    speed_m_s : forward speed, m/s.
    t_s : (N,) uniformly increasing times, s.
    xi_m : (N,) alignment under the (leading) wheelset at those times, m.
    curvature_1_m : (N,) design curvature (1/m) or None for straight track.

    Returns
    -------
    X : (N, n) states (Eq. 7 for the SM), starting at rest.
    Z : (N, 4) noise-free measurements (Eq. 8, 15; the virtual xi row holds 0).

    Notes
    -----
    scipy.signal.lsim with a first-order hold on the inputs (xi and kappa); xi leaves the state
    and becomes the first input.
    """
    from scipy.signal import lsim

    t = np.asarray(t_s, float)
    xi = np.asarray(xi_m, float)
    kap = np.zeros_like(t) if curvature_1_m is None else np.broadcast_to(np.asarray(curvature_1_m, float), t.shape)
    Fc, Bc, Hc, Dc = p.state_space(speed_m_s)
    n = Fc.shape[0]
    keep = np.r_[0:XI_INDEX, XI_INDEX + 1:n]
    A = Fc[np.ix_(keep, keep)]
    B = np.column_stack([Fc[keep, XI_INDEX], Bc[keep, 0]])
    u = np.column_stack([xi, kap])
    _, _, xq = lsim((A, B, np.eye(n - 1), np.zeros((n - 1, 2))), u, t, interp=True)
    xq = np.reshape(xq, (len(t), n - 1))
    X = np.insert(xq, XI_INDEX, xi, axis=1)
    Z = X @ Hc.T + kap[:, None] * Dc[:, 0]
    Z[:, 3] = 0.0
    return X, Z

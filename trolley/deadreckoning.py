"""Static alignment and dead reckoning from gyros and odometer (Jiang 2017 Sec. 2-3, Eq. 7).

Attitude comes from the gyros alone, with Earth rate and transport rate compensated in the
local-level NED frame (Jiang 2017 Eq. 1: omega_in^n = omega_ie^n + omega_en^n); position
increments come from the odometer distance through the attitude and the IMU-to-trolley mounting
matrix (Eq. 7: d(Delta r^n) = C_b^n C_bt^b [ds, 0, 0]^T).

No per-sample Python loop: the attitude recursion

    C_b^n(k+1) = N_k C_b^n(k) B_k,   B_k = exp([alpha_k x]),   N_k = exp(-[zeta_k x])

is a product of rotations, and rotation products are associative, so all attitudes follow from
two prefix scans (Hillis-Steele doubling, log2(K) vectorised compositions with
scipy.spatial.transform.Rotation). To make the scan cheap the body increments are first
combined in blocks of ``block_size`` samples with the first-order commutation correction
(Bortz: alpha = sum a_j + 1/2 sum_{i<j} a_i x a_j), which leaves only third-order terms in
the block's angle (about 1e-5 rad per block at walking speed, so ~1e-15 rad; checked in
``tests/test_deadreckoning.py``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from trolley import earth
from trolley.error_models import heading_error_from_gyrocompassing


@dataclass(frozen=True)
class StaticAlignment:
    """Initial attitude from the static period.

    Attributes
    ----------
    imu_to_nav : attitude C_b^n of the IMU at the end of the static period.
    roll_rad, pitch_rad, heading_rad : Euler angles (ZYX) of the TROLLEY frame.
    level_sigma_rad : expected level error (accelerometer bias / g).
    heading_sigma_rad : expected heading error (gyrocompassing: bias / (omega_ie cos L), Jiang
        2017 Sec. 5), or the stated uncertainty of a given heading.
    heading_source : "gyrocompassing", "given" or "fixes".
    t_end_s : end of the static period.
    """

    imu_to_nav: Rotation
    roll_rad: float
    pitch_rad: float
    heading_rad: float
    level_sigma_rad: float
    heading_sigma_rad: float
    heading_source: str
    t_end_s: float


@dataclass
class DeadReckoning:
    """Dead-reckoned trajectory at block boundaries.

    Attributes
    ----------
    t_s : (K,) times.
    distance_m : (K,) odometer distance.
    trolley_to_nav : Rotation stack (K,) of C_bt^n, the trolley attitude.
    position_ned_m : (K, 3) position of the track reference point relative to the start, NED.
    """

    t_s: np.ndarray
    distance_m: np.ndarray
    trolley_to_nav: Rotation
    position_ned_m: np.ndarray

    def euler_rad(self) -> np.ndarray:
        """(K, 3) roll, pitch, yaw of the trolley (FRD w.r.t. NED, ZYX convention); read-only.

        Computed once per attitude stack (the engine asks for it several times per pass).
        """
        cached = self.__dict__.get("_euler")
        if cached is None or cached[0] is not self.trolley_to_nav:
            e = self.trolley_to_nav.as_euler("ZYX")[:, ::-1]
            e.flags.writeable = False
            cached = (self.trolley_to_nav, e)
            self.__dict__["_euler"] = cached
        return cached[1]

    @property
    def travel_m(self) -> np.ndarray:
        """(K,) distance travelled, never decreasing: the odometer counts down while the trolley
        runs backwards in its own frame (turned around), the travel still grows."""
        d = np.asarray(self.distance_m, dtype=float)
        out = np.empty_like(d)
        if d.size:
            out[0] = d[0]
            np.cumsum(np.abs(np.diff(d)), out=out[1:])
            out[1:] += d[0]
        return out


#: Heading change while standing that counts as the crew turning the trolley around, rad.
TURN_DETECTION_RAD = 0.5 * np.pi
#: Attitude change while the odometer stands that counts as the crew handling the trolley (lifting
#: it off the track for a train, turning it), rad: a trolley standing on the rails turns by the
#: gyro drift only (micro-radians).
HANDLING_DETECTION_RAD = 0.05

#: fewest IMU samples a static alignment averages (the levelling and the gyrocompassing)
MIN_STATIC_SAMPLES = 10


def _true_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starts and ends (exclusive) of the runs of True in a boolean array."""
    edges = np.diff(np.concatenate([[0], np.asarray(mask).astype(np.int8), [0]]))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def _ranges(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The indices of the ranges [lo[i], hi[i]) one after the other, and the range each is from."""
    n = hi - lo
    which = np.repeat(np.arange(n.size), n)
    return np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + lo[which], which


def handling_blocks(dr: DeadReckoning) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """DR blocks at which the crew handled the trolley while it stood, and whether it was turned.

    Handling is an attitude change of more than ``HANDLING_DETECTION_RAD`` while the odometer
    stands still (the trolley lifted off the track and put back); it is a turn when, at the end
    of that standstill, the heading is more than 90 deg from where it was when the trolley
    stopped. The block returned is the first beyond the threshold. Standing stretches are few
    (one per stop): the loop runs over stops, not samples.

    Returns
    -------
    blocks : (k,) int, sorted.
    turned : (k,) bool.
    heading_rad : (k,) the trolley's heading when it stopped, before the crew handled it.
    pitch_rad : (k,) its pitch then (the grade it stood on).
    """
    d = np.asarray(dr.distance_m, dtype=float)
    none = np.zeros(0, dtype=int), np.zeros(0, dtype=bool), np.zeros(0), np.zeros(0)
    if d.size < 2:
        return none
    standing = np.diff(d) == 0.0  # step k -> k+1
    starts, ends = _true_runs(standing)  # run of steps [a, b)
    if starts.size == 0:
        return none
    # every standing block against the block where its standstill began, in one stack
    at, run = _ranges(starts, ends + 1)  # blocks a..b
    R = dr.trolley_to_nav
    angle = (R[starts[run]].inv() * R[at]).magnitude()
    over = angle > HANDLING_DETECTION_RAD
    handled = np.flatnonzero(np.bincount(run[over], minlength=starts.size))
    if handled.size == 0:
        return none
    first = np.searchsorted(run[over], handled)  # the first block beyond the threshold, per run
    blocks = at[over][first]
    a, b = starts[handled], ends[handled]
    euler_a = R[a].as_euler("ZYX")
    yaw_a = euler_a[:, 0]
    yaw_b = R[b].as_euler("ZYX")[:, 0]
    # which way it faces at the end of the standstill (a full 360 deg is not a turn)
    turned = np.abs(np.angle(np.exp(1j * (yaw_b - yaw_a)))) > TURN_DETECTION_RAD
    return blocks.astype(int), turned, yaw_a, euler_a[:, 1]


def turn_blocks(dr: DeadReckoning) -> np.ndarray:
    """DR blocks at which the trolley was turned around (:func:`handling_blocks`)."""
    blocks, turned, _, _ = handling_blocks(dr)
    return blocks[turned]


def mounting_rotation(imu_misalignment_rad) -> Rotation:
    """C_b^bt, the rotation taking IMU-frame vectors into the trolley frame.

    The misalignment angles eps = (roll, pitch, yaw) of the IMU in the trolley frame (about its
    forward, right, down axes) give C_b^bt = Rz(yaw) Ry(pitch) Rx(roll), the same ZYX order as
    every attitude here (and the simulator's mounting); Jiang 2017 Eq. 10 is its small-angle
    transpose C_bt^b = I - [eps x].
    """
    e = np.asarray(imu_misalignment_rad, dtype=float)
    return Rotation.from_euler("ZYX", [e[2], e[1], e[0]])


def static_alignment(t_s: np.ndarray, w_rad_s: np.ndarray, f_m_s2: np.ndarray, static_s: float,
                     latitude_rad: float, imu_misalignment_rad, *, initial_heading_rad: float = np.nan,
                     gyro_bias_rad_s: float = 0.0, accel_bias_m_s2: float = 0.0,
                     gyrocompassing: bool = True, given_heading_sigma_rad: float = np.deg2rad(0.5)
                     ) -> StaticAlignment:
    """Levelling from the accelerometers and gyrocompassing (or a given heading).

    Parameters
    ----------
    t_s, w_rad_s, f_m_s2 : IMU samples (IMU frame).
    static_s : length of the static period from the first sample.
    latitude_rad : site latitude.
    imu_misalignment_rad : nominal mounting angles of the IMU in the trolley.
    initial_heading_rad : trolley heading to use instead of gyrocompassing (NaN: gyrocompass).
    gyro_bias_rad_s, accel_bias_m_s2 : datasheet figures, for the expected errors.
    gyrocompassing : False when the gyros cannot see the Earth rate (MEMS); then the heading must
        be given or is taken from the fixes later (heading 0 is returned with source "fixes").

    Returns
    -------
    StaticAlignment

    Raises
    ------
    ValueError if the static period holds fewer than 10 samples.
    """
    mask = t_s <= t_s[0] + static_s
    if np.count_nonzero(mask) < MIN_STATIC_SAMPLES:
        raise ValueError(f"the static period of {static_s} s holds only {np.count_nonzero(mask)} IMU samples")
    f = f_m_s2[mask].mean(axis=0)
    w = w_rad_s[mask].mean(axis=0)
    # IMU frame: stationary specific force is -g along the local down axis
    roll = np.arctan2(-f[1], -f[2])
    pitch = np.arctan2(f[0], np.hypot(f[1], f[2]))
    level = Rotation.from_euler("ZYX", [0.0, pitch, roll])  # IMU to the heading-free level frame
    w_level = level.apply(w)
    g = float(np.linalg.norm(f))
    b_to_bt = mounting_rotation(imu_misalignment_rad)
    if np.isfinite(initial_heading_rad):
        source = "given"
        heading_sigma = float(given_heading_sigma_rad)
        psi_imu = 0.0
    elif gyrocompassing:
        source = "gyrocompassing"
        # the levelled Earth rate is R_z(psi)^T [W cos L, 0, .]: x = W cos L cos psi, y = -W cos L sin psi
        psi_imu = float(np.arctan2(-w_level[1], w_level[0]))
        heading_sigma = heading_error_from_gyrocompassing(gyro_bias_rad_s, latitude_rad)
    else:
        source = "fixes"
        heading_sigma = np.pi
        psi_imu = 0.0
    C = Rotation.from_euler("ZYX", [psi_imu, pitch, roll])
    trolley = C * b_to_bt.inv()
    ypr = trolley.as_euler("ZYX")
    if source == "given":
        # rotating about the vertical adds the same angle to the yaw: match the trolley heading
        C = Rotation.from_euler("z", initial_heading_rad - ypr[0]) * C
        trolley = C * b_to_bt.inv()
        ypr = trolley.as_euler("ZYX")
    return StaticAlignment(
        imu_to_nav=C, roll_rad=float(ypr[2]), pitch_rad=float(ypr[1]), heading_rad=float(ypr[0]),
        level_sigma_rad=float(accel_bias_m_s2 / g) if g > 0 else 0.0,
        heading_sigma_rad=float(heading_sigma), heading_source=source,
        t_end_s=float(t_s[mask][-1]))


def _block_rotvecs(rate: np.ndarray, dt: np.ndarray, block: int, chunk_blocks: int = 4096) -> np.ndarray:
    """Rotation vectors of blocks of consecutive small rotations (Bortz first-order correction).

    Parameters
    ----------
    rate, dt : (n, 3) angular rates (any memory layout) and (n,) intervals: the increments are
        ``rate * dt``.
    block : increments per block; the last block may be short.
    chunk_blocks : blocks handled per step. The work runs in two reused component-major
        buffers of ``chunk_blocks * block`` samples: fresh arrays the size of a 10 km run cost
        more in page faults than the arithmetic.

    Returns
    -------
    (ceil(n / block), 3) rotation vectors.
    """
    n = rate.shape[0]
    nb = -(-n // block)
    out = np.empty((nb, 3))
    size = min(chunk_blocks, nb) * block
    a_buf, before_buf = np.empty((3, size)), np.empty((3, size))
    for b0 in range(0, nb, chunk_blocks):
        b1 = min(nb, b0 + chunk_blocks)
        i0, i1 = b0 * block, min(n, b1 * block)
        a = a_buf[:, :(b1 - b0) * block]
        np.multiply(rate[i0:i1].T, dt[i0:i1], out=a[:, :i1 - i0])
        a[:, i1 - i0:] = 0.0
        a = a.reshape(3, b1 - b0, block)
        before = before_buf[:, :(b1 - b0) * block].reshape(3, b1 - b0, block)
        np.cumsum(a, axis=2, out=before)
        before -= a  # the sum of the increments before each one in its block

        def dot(u, v):  # per-block sum of u * v, without a temporary the size of the chunk
            return np.einsum("bk,bk->b", u, v)
        cross = np.stack([dot(before[1], a[2]) - dot(before[2], a[1]),
                          dot(before[2], a[0]) - dot(before[0], a[2]),
                          dot(before[0], a[1]) - dot(before[1], a[0])])
        out[b0:b1] = (a.sum(axis=2) + 0.5 * cross).T
    return out


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of scalar-last quaternions (scipy's [x, y, z, w] order), vectorised.

    ``Rotation.from_quat(quat_multiply(p, q)) == Rotation.from_quat(p) * Rotation.from_quat(q)``.
    scipy's ``Rotation.__mul__`` builds and normalises a new object per call; in the prefix
    scan below it took 90 % of a 10 km run, so the product is written out here.
    """
    px, py, pz, pw = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qx, qy, qz, qw = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(np.broadcast_shapes(p.shape, q.shape))
    out[..., 0] = pw * qx + px * qw + py * qz - pz * qy
    out[..., 1] = pw * qy - px * qz + py * qw + pz * qx
    out[..., 2] = pw * qz + px * qy - py * qx + pz * qw
    out[..., 3] = pw * qw - px * qx - py * qy - pz * qz
    return out


def _scan(q: np.ndarray, reverse: bool) -> np.ndarray:
    """Hillis-Steele doubling scan of quaternion products along axis 0."""
    n = q.shape[0]
    d = 1
    while d < n:
        a, b = q[:-d], q[d:]
        q = np.concatenate([q[:d], quat_multiply(b, a) if reverse else quat_multiply(a, b)])
        d *= 2
    return q


def prefix_compose(rot: Rotation, reverse: bool = False, chunk: int = 64) -> Rotation:
    """Inclusive prefix products of a rotation stack.

    ``reverse=False``: P[k] = R[0] * R[1] * ... * R[k]; ``reverse=True``: P[k] = R[k] * ... * R[0].

    Two levels, all vectorised: a sequential scan inside chunks of ``chunk`` rotations (run on
    all chunks at once), a doubling scan of the chunk totals, and one product to join them:
    O(n) products instead of the O(n log n) of a flat doubling scan.
    """
    q = rot.as_quat()
    n = q.shape[0]
    if n <= 2 * chunk:
        return Rotation.from_quat(_scan(q, reverse))
    m = -(-n // chunk)
    pad = np.zeros((m * chunk, 4))
    pad[:, 3] = 1.0
    pad[:n] = q
    blocks = pad.reshape(m, chunk, 4).copy()
    for j in range(1, chunk):  # chunk steps, each over all m chunks
        blocks[:, j] = quat_multiply(blocks[:, j], blocks[:, j - 1]) if reverse else \
            quat_multiply(blocks[:, j - 1], blocks[:, j])
    totals = _scan(blocks[:, -1], reverse)  # product of all chunks up to and including each
    before = np.concatenate([[[0.0, 0.0, 0.0, 1.0]], totals[:-1]])
    out = quat_multiply(blocks, before[:, None, :]) if reverse else quat_multiply(before[:, None, :], blocks)
    return Rotation.from_quat(out.reshape(-1, 4)[:n])


def dead_reckon(t_s: np.ndarray, w_rad_s: np.ndarray, odo_t_s: np.ndarray, odo_distance_m: np.ndarray,
                alignment: StaticAlignment, latitude_rad: float, height_m: float,
                imu_misalignment_rad, block_size: int = 10,
                progress: Callable[[float], None] | None = None) -> DeadReckoning:
    """Attitude by gyros and position by odometer from the end of the static alignment onwards.

    Parameters
    ----------
    t_s, w_rad_s : IMU times and angular rates (IMU frame, Earth rate included).
    odo_t_s, odo_distance_m : cumulative odometer distance.
    alignment : the initial attitude at ``alignment.t_end_s``.
    latitude_rad, height_m : site, for Earth rate and transport rate.
    imu_misalignment_rad : nominal mounting angles.
    block_size : IMU samples per attitude step (attitude and position are output per block).
    progress : optional callable, given the fraction done (0..1) after each vectorised step.

    Returns
    -------
    DeadReckoning, starting at the end of the static period at position zero.
    """
    start = int(np.searchsorted(t_s, alignment.t_end_s))
    t = t_s[start:]
    w = w_rad_s[start:]
    dt = np.diff(t)
    # each sample is the mean rate over the interval that ends at its time (what an IMU's delta
    # angles give, and what the simulator writes), so it integrates over (t[k-1], t[k]]
    alpha = _block_rotvecs(w[1:], dt, block_size)
    nb = alpha.shape[0]
    idx = np.minimum(np.arange(nb + 1) * block_size, t.shape[0] - 1)
    tb = t[idx]
    dtb = np.diff(tb)
    dist = np.interp(tb, odo_t_s, odo_distance_m)
    ddist = np.diff(dist)
    if progress is not None:
        progress(0.2)
    body_prefix = prefix_compose(Rotation.from_rotvec(alpha))
    if progress is not None:
        progress(0.5)
    b_to_bt = mounting_rotation(imu_misalignment_rad)
    w_ie = earth.earth_rate_n(latitude_rad)
    v_n = np.zeros((nb, 3))
    for npass in range(2):  # second pass: transport rate from the first pass's velocity
        if npass == 0:
            # Earth rate alone turns the nav frame about a fixed axis: the prefix is closed form
            nav_prefix = Rotation.from_rotvec(-w_ie[None, :] * (tb[1:] - tb[0])[:, None])
        else:
            zeta = (w_ie[None, :] + earth.transport_rate_n(v_n, latitude_rad, height_m)) * dtb[:, None]
            nav_prefix = prefix_compose(Rotation.from_rotvec(-zeta), reverse=True)
        q_att = quat_multiply(quat_multiply(nav_prefix.as_quat(), alignment.imu_to_nav.as_quat()),
                              body_prefix.as_quat())
        q_att = np.concatenate([alignment.imu_to_nav.as_quat()[None], q_att])
        trolley = Rotation.from_quat(quat_multiply(q_att, b_to_bt.inv().as_quat()))
        fwd = trolley.apply([1.0, 0.0, 0.0])
        mid = fwd[1:] + fwd[:-1]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        dr = mid * ddist[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            v_n = np.where(dtb[:, None] > 0, dr / dtb[:, None], 0.0)
        if progress is not None:
            progress(0.75 + 0.25 * npass)
    pos = np.zeros((nb + 1, 3))
    np.cumsum(dr, axis=0, out=pos[1:])
    return DeadReckoning(t_s=tb, distance_m=dist, trolley_to_nav=trolley, position_ned_m=pos)


def stop_levels(imu_t_s: np.ndarray, f_m_s2: np.ndarray, odo_t_s: np.ndarray, odo_distance_m: np.ndarray,
                stop_times_s: np.ndarray, imu_misalignment_rad, window_s: float = 10.0,
                min_samples: int = 20, w_rad_s: np.ndarray | None = None,
                max_rotation_rad: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch of the trolley from the accelerometers at each stop.

    While the trolley stands, the specific force is gravity alone, so the accelerometers level
    the trolley again at every stop (as in the static alignment). The gyro-integrated roll
    drifts with the equivalent x-axis bias and is not observable from the fixes (Jiang 2017
    Sec. 4.1 drops it), yet it moves the prism sideways by lever arm x roll error and it is the
    cant: these levels bound it.

    Parameters
    ----------
    imu_t_s, f_m_s2 : IMU times and specific force (IMU frame).
    odo_t_s, odo_distance_m : odometer, to keep only standing samples.
    stop_times_s : (S,) a time inside each stop (the fix times).
    imu_misalignment_rad : nominal mounting angles.
    window_s : half-width of the window around each stop time.
    min_samples : fewer standing samples than this gives NaN for that stop.
    w_rad_s : IMU angular rates; when given, only samples whose attitude is within
        ``max_rotation_rad`` of the attitude at the stop time count (the rotation vector, the
        integral of w dt from the stop time: the gyro noise and bias of 10 s, 1e-4 rad even for a
        MEMS unit, stay far below it), so a window never takes in the tilt of a trolley the
        crew lifts off the track, nor mixes the levels before and after it was turned around.

    Returns
    -------
    roll_rad, pitch_rad : (S,) trolley roll and pitch, NaN where the stop had too few samples.
    """
    lo = np.searchsorted(imu_t_s, stop_times_s - window_s)
    hi = np.searchsorted(imu_t_s, stop_times_s + window_s)
    # only the samples inside the windows: a few percent of a survey
    n_in = hi - lo
    idx, seg = _ranges(lo, hi)
    t = imu_t_s[idx]
    # standing: the odometer reads the same 0.05 s before and after, i.e. [t - 0.05, t + 0.05]
    # lies inside a run of equal odometer samples (found on the odometer's own samples)
    d = np.asarray(odo_distance_m, dtype=float)
    to = np.asarray(odo_t_s, dtype=float)
    run_a, run_b = _true_runs(np.diff(d) == 0.0)  # odometer samples a..b equal
    j = np.searchsorted(to[run_a], t - 0.05, side="right") - 1
    standing = (j >= 0) & (t + 0.05 <= to[run_b[np.maximum(j, 0)]] if run_b.size else np.zeros(t.size, bool))
    # component-major gathers: the sensor arrays are column views of the parsed files
    if w_rad_s is not None and idx.size:
        # rotation inside each window, measured from the stop time (small angles: the vector
        # integral of the rates is the rotation vector)
        cum = np.take(np.asarray(w_rad_s).T, idx, axis=1)
        cum *= np.diff(t, prepend=t[0])
        np.cumsum(cum, axis=1, out=cum)
        first = np.cumsum(n_in) - n_in
        at_stop = np.clip(np.searchsorted(imu_t_s, stop_times_s) - lo, 0, np.maximum(n_in - 1, 0))
        cum -= cum[:, np.minimum(first + at_stop, idx.size - 1)][:, seg]
        standing &= (cum * cum).sum(axis=0) < max_rotation_rad ** 2
    count = np.bincount(seg, weights=standing, minlength=len(lo))
    f = np.take(np.asarray(f_m_s2).T, idx, axis=1)
    f *= standing
    mean = np.column_stack([np.bincount(seg, weights=f[i], minlength=len(lo)) for i in range(3)])
    # the mean of the rotated samples is the rotated mean: one rotation per stop
    mean = np.atleast_2d(mounting_rotation(imu_misalignment_rad).apply(mean / np.maximum(count, 1)[:, None]))
    roll = np.arctan2(-mean[:, 1], -mean[:, 2])
    pitch = np.arctan2(mean[:, 0], np.hypot(mean[:, 1], mean[:, 2]))
    bad = count < min_samples
    roll[bad] = np.nan
    pitch[bad] = np.nan
    return roll, pitch


def levelled_stop_times(dr: DeadReckoning, stop_times_s: np.ndarray, stop_roll_rad: np.ndarray) -> np.ndarray:
    """The times at which :func:`with_roll_levelled` pins the roll: the stops with a level, a stop
    outside the dead reckoning moved to its nearer end, sorted and without repeats.

    The first fix is taken while the trolley stands for the static alignment, i.e. before the
    dead reckoning starts at the alignment's end; the trolley has not moved since, so its level
    holds at that end. Pinned at the fix's own time instead, the roll error the gyros gather
    from the start to the next stop was removed as if it had been gathering since the fix: a
    MEMS survey with the demo's 120 s alignment kept 0.76 mm of cant error at the start of the
    first interval."""
    return np.unique(_pinned_times(dr, stop_times_s, stop_roll_rad))


def _pinned_times(dr: DeadReckoning, stop_times_s: np.ndarray, stop_roll_rad: np.ndarray) -> np.ndarray:
    """The times of the stops with a level, moved into the dead reckoning's span, one per level."""
    ok = np.isfinite(stop_roll_rad)
    return np.clip(np.asarray(stop_times_s, dtype=float)[ok], dr.t_s[0], dr.t_s[-1])


def with_roll_levelled(dr: DeadReckoning, stop_times_s: np.ndarray, stop_roll_rad: np.ndarray) -> DeadReckoning:
    """The dead reckoning with its roll re-levelled at the stops (error interpolated in time,
    pinned at :func:`levelled_stop_times`; several levels at one pinned time are averaged)."""
    ok = np.isfinite(stop_roll_rad)
    if not ok.any():
        return dr
    ts = _pinned_times(dr, stop_times_s, stop_roll_rad)
    roll_dr = np.interp(ts, dr.t_s, dr.euler_rad()[:, 0])
    err = np.angle(np.exp(1j * (roll_dr - np.asarray(stop_roll_rad)[ok])))
    pinned, which = np.unique(ts, return_inverse=True)
    err = np.bincount(which, weights=err) / np.bincount(which)
    err_t = np.interp(dr.t_s, pinned, err)
    zeros = np.zeros_like(err_t)
    roll_fix = Rotation.from_rotvec(np.column_stack([-err_t, zeros, zeros])).as_quat()
    att = Rotation.from_quat(quat_multiply(dr.trolley_to_nav.as_quat(), roll_fix))
    return DeadReckoning(dr.t_s, dr.distance_m, att, dr.position_ned_m)

"""IMU twin: streams NovAtel RAWIMUSXB frames built from rate / specific-force arrays."""
from __future__ import annotations

import time

import numpy as np

from drivers import novatel
from drivers.twins.base import Faults, PtyTwin


class ImuTwin(PtyTwin):
    """A NovAtel OEM7 receiver logging RAWIMUSXB, fed by arrays.

    Parameters
    ----------
    t_s : (N,) sample times (s, any origin; the GPS time is ``sow0 + t_s - t_s[0]``).
    w_rad_s, f_m_s2 : (N, 3) angular rate and specific force in the trolley FRD frame.
    imu_type : RAWIMUSX IMU type (scale table ``novatel.IMU_SCALES``).
    rate_hz : data rate used for the increment scaling (default: the IMU type's rate).
    axes : axis map of the mounting (``novatel.axis_matrix``); the twin applies its inverse.
    week, sow0 : GPS week and seconds of week of the first sample.
    imu_info : (N,) IMU info bytes (bit 0 = IMU error), default 0.
    realtime : pace frames with the host clock (True) or send as fast as the pty allows.
    chunk_frames : frames per write.
    repeat : after the last sample start again, the time stamps continuing (an endless feed
        from a short stationary block); otherwise the twin falls silent at the end.
    """

    def __init__(self, t_s, w_rad_s, f_m_s2, imu_type: int = 26, rate_hz: float | None = None,
                 axes: str = "x,y,z", week: int = 2300, sow0: float = 100000.0, imu_info=None,
                 realtime: bool = True, chunk_frames: int = 32, faults: Faults | None = None,
                 link_path=None, repeat: bool = False) -> None:
        t = np.asarray(t_s, float)
        self.scale = novatel.imu_scale(imu_type, rate_hz)
        g, a = novatel.counts_from_si(w_rad_s, f_m_s2, self.scale, novatel.axis_matrix(axes))
        self.gyro_counts, self.accel_counts = g, a
        t0 = float(t[0]) if t.size else 0.0     # (no samples left: a session resumed after its last one)
        self.sow = sow0 + (t - t0)
        self.t_rel = t - t0
        info = np.zeros(t.size, np.uint8) if imu_info is None else np.asarray(imu_info, np.uint8)
        self.week, self.imu_type, self.imu_info = week, imu_type, info
        self.stream = novatel.encode_rawimusxb(week, self.sow, g, a, imu_type, info)
        self.n_frames = t.size
        # one repeat cycle lasts the block plus one sample period, so time steps stay uniform
        self.span_s = float(self.t_rel[-1] + np.median(np.diff(self.t_rel))) if t.size > 1 else 1.0
        self.repeat = repeat
        self.realtime = realtime
        self.chunk_frames = chunk_frames
        self.frames_sent = 0
        super().__init__(faults, link_path)

    def _encode_cycle(self, cycle: int) -> bytes:
        return novatel.encode_rawimusxb(self.week, self.sow + cycle * self.span_s, self.gyro_counts,
                                        self.accel_counts, self.imu_type, self.imu_info)

    def serve(self) -> None:
        L = novatel.FRAME_LEN
        t0 = self.origin()
        i = cycle = 0
        stream = self.stream
        if self.realtime and self.epoch is not None:
            # joining a running session: what was due before the port opened is not sent
            late = time.monotonic() - t0
            cycle = int(late // self.span_s) if self.repeat else 0
            i = min(int(np.searchsorted(self.t_rel, late - cycle * self.span_s, side="left")), self.n_frames)
            stream = self._encode_cycle(cycle) if cycle else stream
        while not self.stopped:
            if i >= self.n_frames:
                if not self.repeat:
                    break
                cycle, i = cycle + 1, 0
                stream = self._encode_cycle(cycle)
            base = cycle * self.span_s
            if self.realtime:
                now = time.monotonic() - t0 - base
                j = int(np.searchsorted(self.t_rel, now, side="right"))
                if j <= i:
                    time.sleep(min(0.005, max(0.0, self.t_rel[i] - now)))
                    continue
                j = min(j, i + 8 * self.chunk_frames)
            else:
                j = min(i + self.chunk_frames, self.n_frames)
            if not self.send(stream[i * L: j * L]) and not self.stopped:
                # port vanished: those frames are lost, like on a real unplug
                self.wait_ready()
            i = j
            self.frames_sent = cycle * self.n_frames + i

"""Gauge-sensor twin: streams ``$GG`` lines (docs/gauge_protocol.md) from gauge arrays."""
from __future__ import annotations

import time

import numpy as np

from drivers import gauge
from drivers.twins.base import Faults, PtyTwin


class GaugeTwin(PtyTwin):
    """A displacement transducer reporting full gauge, fed by arrays.

    Parameters
    ----------
    t_s, gauge_m : (N,) sample times and full gauge.
    status : (N,) status codes (``gauge.STATUS_*``), default all OK.
    realtime : pace lines with the host clock or send as fast as the pty allows.
    repeat : after the last sample start again with the line counter and the sensor clock
        continuing (an endless feed); otherwise the twin falls silent at the end.
    """

    def __init__(self, t_s, gauge_m, status=None, realtime: bool = True,
                 faults: Faults | None = None, link_path=None, repeat: bool = False) -> None:
        t = np.asarray(t_s, float)
        self.t_rel = t - (t[0] if t.size else 0.0)     # (no samples left: a session resumed after its last one)
        self.gauge_m = np.asarray(gauge_m, float)
        self.status = np.zeros(t.size, int) if status is None else np.asarray(status, int)
        self.span_s = float(self.t_rel[-1] + np.median(np.diff(self.t_rel))) if t.size > 1 else 1.0
        self.lines = self._lines_for(0)
        self.realtime = realtime
        self.repeat = repeat
        self.lines_sent = 0
        super().__init__(faults, link_path)

    def _lines_for(self, cycle: int) -> list[bytes]:
        n = self.t_rel.size
        return [gauge.format_line((cycle * n + k) % gauge.SEQ_MODULO,
                                  int(round((tr + cycle * self.span_s) * 1000)) % gauge.MS_MODULO, g, s)
                for k, (tr, g, s) in enumerate(zip(self.t_rel, self.gauge_m, self.status))]

    def serve(self) -> None:
        t0 = self.origin()
        n = len(self.lines)
        i = cycle = 0
        lines = self.lines
        if self.realtime and self.epoch is not None:
            # joining a running session: what was due before the port opened is not sent
            late = time.monotonic() - t0
            cycle = int(late // self.span_s) if self.repeat else 0
            i = min(int(np.searchsorted(self.t_rel, late - cycle * self.span_s, side="left")), n)
            lines = self._lines_for(cycle) if cycle else lines
        while not self.stopped:
            if i >= n:
                if not self.repeat:
                    break
                cycle, i = cycle + 1, 0
                lines = self._lines_for(cycle)
            if self.realtime:
                now = time.monotonic() - t0 - cycle * self.span_s
                j = int(np.searchsorted(self.t_rel, now, side="right"))
                if j <= i:
                    time.sleep(min(0.005, max(0.0, self.t_rel[i] - now)))
                    continue
            else:
                j = min(i + 16, n)
            if not self.send(b"".join(lines[i:j])) and not self.stopped:
                self.wait_ready()
            i = j
            self.lines_sent = cycle * n + i

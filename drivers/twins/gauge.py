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
    """

    def __init__(self, t_s, gauge_m, status=None, realtime: bool = True,
                 faults: Faults | None = None, link_path=None) -> None:
        t = np.asarray(t_s, float)
        self.t_rel = t - t[0]
        st = np.zeros(t.size, int) if status is None else np.asarray(status, int)
        self.lines = [gauge.format_line(k % gauge.SEQ_MODULO, int(round(tr * 1000)) % gauge.MS_MODULO, g, s)
                      for k, (tr, g, s) in enumerate(zip(self.t_rel, np.asarray(gauge_m, float), st))]
        self.realtime = realtime
        self.lines_sent = 0
        super().__init__(faults, link_path)

    def serve(self) -> None:
        t0 = time.monotonic()
        n = len(self.lines)
        i = 0
        while i < n and not self.stopped:
            if self.realtime:
                now = time.monotonic() - t0
                j = int(np.searchsorted(self.t_rel, now, side="right"))
                if j <= i:
                    time.sleep(min(0.005, max(0.0, self.t_rel[i] - now)))
                    continue
            else:
                j = min(i + 16, n)
            if not self.send(b"".join(self.lines[i:j])) and not self.stopped:
                self.wait_ready()
            i = j
            self.lines_sent = i

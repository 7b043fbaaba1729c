"""Odometer twin: a quadrature-counter module answering ``$0R0`` polls from distance arrays."""
from __future__ import annotations

import time

import numpy as np

from drivers import encoder
from drivers.twins.base import Faults, PtyTwin


class OdometerTwin(PtyTwin):
    """A BEI-style counter module on a pty.

    Parameters
    ----------
    t_s, distance_m : (N,) cumulative distance of the measuring wheel (e.g. truth simulator).
    cfg : wheel and counter settings used to turn distance into counts.
    offset_counts : counter value at distance 0 (put it near 2^bits to exercise rollover).
    mode : ``"index"``: the k-th poll is answered with sample k (deterministic, for tests);
        ``"time"``: answered with the sample at the elapsed host time since start.
    """

    def __init__(self, t_s, distance_m, cfg: encoder.OdometerConfig = encoder.OdometerConfig(),
                 offset_counts: int = 0, mode: str = "index", faults: Faults | None = None,
                 link_path=None) -> None:
        self.t_rel = np.asarray(t_s, float) - float(np.asarray(t_s, float)[0])
        self.cfg = cfg
        self.counts = np.rint(np.asarray(distance_m, float) / cfg.metres_per_count).astype(np.int64) + offset_counts
        self.mode = mode
        self.polls = 0
        self.sent_counts: list[int] = []
        super().__init__(faults, link_path)

    def _count_now(self, t0: float) -> int:
        if self.mode == "index":
            k = min(self.polls, self.counts.size - 1)
        else:
            k = max(int(np.searchsorted(self.t_rel, time.monotonic() - t0, side="right")) - 1, 0)
        return int(self.counts[k])

    def serve(self) -> None:
        buf = bytearray()
        t0 = time.monotonic()
        while not self.stopped:
            data = self.recv(0.05)
            if not data:
                continue
            buf += data
            while b"\r" in buf:
                i = buf.index(b"\r")
                cmd = bytes(buf[:i]).strip(b"\n")
                del buf[: i + 1]
                if cmd == encoder.READ_COMMAND[:-1]:
                    c = self._count_now(t0)
                    self.polls += 1
                    self.sent_counts.append(c % 2**self.cfg.bits)
                    rng = self.injector.rng
                    if self.faults.missing_rate and rng.random() < self.faults.missing_rate:
                        continue
                    self.send(encoder.format_read_reply(c, 0, self.cfg.bits))
                elif cmd.startswith(b"$0"):
                    self.send(b"*0ACK\r" if cmd[2:3] in (b"Q", b"I", b"F") else b"*0NACK\r")

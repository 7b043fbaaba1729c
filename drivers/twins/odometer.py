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
    repeat : (``"time"`` mode) after the last sample the profile starts again, the distance
        continuing from where it ended (an endless feed from a short block); otherwise the
        counter holds its last value.
    faults : byte faults on replies; ``missing_rate`` (no reply) and ``delay_rate``/``delay_s``
        (the module answers ``delay_s`` late, in order, as a busy device would) per poll.

    Attributes
    ----------
    sent_counts : counter value of every poll, in order (also for polls left unanswered).
    missing, delayed : poll indices (0-based) left unanswered / answered late.
    resets : poll indices answered first after a power cycle (counter restarted at 0).
    """

    def __init__(self, t_s, distance_m, cfg: encoder.OdometerConfig = encoder.OdometerConfig(),
                 offset_counts: int = 0, mode: str = "index", faults: Faults | None = None,
                 link_path=None, repeat: bool = False) -> None:
        self.t_rel = np.asarray(t_s, float) - float(np.asarray(t_s, float)[0])
        self.cfg = cfg
        self.counts = np.rint(np.asarray(distance_m, float) / cfg.metres_per_count).astype(np.int64) + offset_counts
        self.mode = mode
        self.repeat = repeat
        n = self.counts.size
        self.span_s = float(self.t_rel[-1] + (np.median(np.diff(self.t_rel)) if n > 1 else 1.0))
        # counts gained per cycle: the block plus its last step continued over the extra period
        self.cycle_counts = int(self.counts[-1] - self.counts[0] + (self.counts[-1] - self.counts[-2] if n > 1 else 0))
        self.polls = 0
        self.sent_counts: list[int] = []
        self.missing: list[int] = []
        self.delayed: list[int] = []
        self.resets: list[int] = []
        self.count_offset = 0  # counter value minus profile count (changes at a power cycle)
        self._zero_next = False
        super().__init__(faults, link_path)

    def power_up(self) -> None:
        """The counter module restarts: its count is 0 at the first poll after power-up."""
        self._zero_next = True

    def _count_now(self, t0: float) -> int:
        if self.mode == "index":
            k = min(self.polls, self.counts.size - 1)
            return int(self.counts[k])
        e = time.monotonic() - t0
        cycle = int(e // self.span_s) if self.repeat else 0
        k = max(int(np.searchsorted(self.t_rel, e - cycle * self.span_s, side="right")) - 1, 0)
        return int(self.counts[k]) + cycle * self.cycle_counts

    def serve(self) -> None:
        buf = bytearray()
        t0 = self.origin()
        f = self.faults
        rng = self.injector.rng
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
                    k = self.polls
                    if self._zero_next:
                        self._zero_next = False
                        self.count_offset = -c
                        self.resets.append(k)
                    c += self.count_offset
                    self.polls += 1
                    self.sent_counts.append(c % 2**self.cfg.bits)
                    if f.missing_rate and rng.random() < f.missing_rate:
                        self.missing.append(k)
                        continue
                    if f.delay_rate and rng.random() < f.delay_rate:
                        self.delayed.append(k)
                        time.sleep(f.delay_s)  # the module is busy: later polls wait in its buffer
                    self.send(encoder.format_read_reply(c, 0, self.cfg.bits))
                elif cmd.startswith(b"$0"):
                    self.send(b"*0ACK\r" if cmd[2:3] in (b"Q", b"I", b"F") else b"*0NACK\r")

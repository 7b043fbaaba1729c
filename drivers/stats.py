"""Link statistics shared by every driver: what arrived, what was kept, what was thrown away.

The byte counters balance: ``bytes_in == bytes_ok + bytes_discarded + bytes_pending`` at any
moment, so every byte received is accounted for (kept in a good frame, discarded, or still
waiting in the parser for the rest of its frame).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field


@dataclass
class Stats:
    """Counters of one device link (parser and port together).

    Attributes
    ----------
    frames_ok : frames (or lines) accepted.
    bad_checksum : frames whose checksum (CRC) failed.
    bad_format : lines that were complete but did not parse or were implausible.
    resyncs : times the parser skipped bytes to find the next frame start.
    timeouts : requests that got no reply in time.
    reconnects : times the port was re-opened after it disappeared.
    bytes_in, bytes_out : bytes read from / written to the port.
    bytes_ok : bytes that belong to accepted frames.
    bytes_discarded : bytes thrown away (garbage, bad frames, skipped while resynchronising).
    bytes_pending : bytes held by the parser waiting for the rest of a frame.
    queue_dropped : records dropped because the bounded queue was full (oldest dropped first).
    extra : protocol-specific counters (IMU time gaps and error bits, GeoCOM retries, ...) and
        the IMU data rate in use (``rate_hz``, a float).
    """

    frames_ok: int = 0
    bad_checksum: int = 0
    bad_format: int = 0
    resyncs: int = 0
    timeouts: int = 0
    reconnects: int = 0
    bytes_in: int = 0
    bytes_out: int = 0
    bytes_ok: int = 0
    bytes_discarded: int = 0
    bytes_pending: int = 0
    queue_dropped: int = 0
    extra: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict:
        """All counters as a plain dict (for ``stats.json``)."""
        return asdict(self)

    def balanced(self) -> bool:
        """Whether every byte received is accounted for."""
        return self.bytes_in == self.bytes_ok + self.bytes_discarded + self.bytes_pending

    def copy(self) -> "Stats":
        """An independent snapshot."""
        d = asdict(self)
        d["extra"] = dict(self.extra)
        return Stats(**d)

    def bump(self, key: str, n: int = 1) -> None:
        """Add ``n`` to the protocol-specific counter ``key``."""
        self.extra[key] = self.extra.get(key, 0) + n

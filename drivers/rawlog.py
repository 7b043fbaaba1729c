"""Raw byte log of a serial session: every chunk read or written, with its host time.

File layout: the magic line ``TROLLEY-RAWLOG/1\\n``, then records of
``direction (1 byte: '<' read from the device, '>' written to it, '!' the port was re-opened
after it had disappeared, no bytes) | t_host_s (float64 LE) | length (uint32 LE) | bytes``.
Feeding the '<' chunks (and the '!' marks) back through the same parser with their times
reproduces the records exactly (:func:`drivers.replay.replay`).
"""
from __future__ import annotations

import struct
import threading
from pathlib import Path
from typing import Iterator

MAGIC = b"TROLLEY-RAWLOG/1\n"
_HDR = struct.Struct("<cdI")
IN, OUT, RECONNECT = b"<", b">", b"!"


class RawLog:
    """Append-only raw byte log (thread-safe)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._f = open(self.path, "wb")
        self._f.write(MAGIC)
        self._lock = threading.Lock()

    def write(self, direction: bytes, t_host: float, data: bytes) -> None:
        """Append one chunk."""
        with self._lock:
            if self._f.closed:
                return
            self._f.write(_HDR.pack(direction, t_host, len(data)))
            self._f.write(data)

    def flush(self) -> None:
        """Push buffered chunks to disk (called on disconnect and stop)."""
        with self._lock:
            if not self._f.closed:
                self._f.flush()

    def close(self) -> None:
        """Flush and close."""
        with self._lock:
            if not self._f.closed:
                self._f.close()


def read_rawlog(path: str | Path) -> Iterator[tuple[bytes, float, bytes]]:
    """Chunks ``(direction, t_host_s, data)`` of a raw log, in order.

    Raises
    ------
    ValueError : not a raw log, or truncated (names the file and offset).
    """
    data = Path(path).read_bytes()
    if not data.startswith(MAGIC):
        raise ValueError(f"{path}: not a trolley raw log (missing {MAGIC!r})")
    pos = len(MAGIC)
    while pos < len(data):
        if pos + _HDR.size > len(data):
            raise ValueError(f"{path}: truncated chunk header at byte {pos}")
        d, t, n = _HDR.unpack_from(data, pos)
        pos += _HDR.size
        if pos + n > len(data):
            raise ValueError(f"{path}: truncated chunk at byte {pos}")
        yield d, t, data[pos: pos + n]
        pos += n

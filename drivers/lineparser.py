"""Streaming parser for line-based ASCII protocols (GeoCOM replies, encoder, gauge sensor).

Bytes are split at the terminator; each complete line is cut back to the *last* frame-start
marker in it (garbage before it is discarded and counted as a resync), then decoded by the
protocol's ``decode`` function. Lines longer than ``max_line`` without a terminator are
discarded. Every byte ends up in ``bytes_ok``, ``bytes_discarded`` or ``bytes_pending``.
"""
from __future__ import annotations

from typing import Callable

from drivers.stats import Stats


class ChecksumError(ValueError):
    """A line whose checksum does not match."""


class Unconfirmed(ValueError):
    """A well-formed line withheld until later lines confirm it (not a bad line): its bytes are
    discarded and counted in ``stats.extra["unconfirmed"]``."""


class LineParser:
    """Split a byte stream into lines and decode them.

    Parameters
    ----------
    stats : counters to update.
    decode : ``decode(line_str, t_host) -> record``; raises :class:`ChecksumError` for a bad
        checksum, :class:`Unconfirmed` for a line withheld and ``ValueError`` for a malformed
        or implausible line.
    start : frame-start marker (e.g. ``b"%R1P,"``).
    terminator : the byte that ends a line (``b"\\n"`` or ``b"\\r"``); other CR/LF are stripped.
    max_line : longest line accepted (bytes); longer runs without a terminator are garbage.
    """

    def __init__(self, stats: Stats, decode: Callable[[str, float], object], start: bytes,
                 terminator: bytes = b"\n", max_line: int = 512) -> None:
        self.stats = stats
        self.decode = decode
        self.start = start
        self.term = terminator
        self.max_line = max_line
        self._buf = bytearray()

    def feed(self, data: bytes, t_host: float) -> list:
        """Parse ``data`` received at ``t_host``; return the decoded records."""
        st = self.stats
        st.bytes_in += len(data)
        self._buf += data
        out: list = []
        buf = self._buf
        while True:
            i = buf.find(self.term)
            if i < 0:
                if len(buf) > self.max_line:
                    # keep only what could still be the start of a frame
                    j = buf.rfind(self.start)
                    cut = j if j > 0 else len(buf) - len(self.start) + 1
                    st.bytes_discarded += cut
                    st.resyncs += 1
                    del buf[:cut]
                break
            line = bytes(buf[: i + 1])
            del buf[: i + 1]
            self._line(line, t_host, out)
        st.bytes_pending = len(buf)
        return out

    def flush(self, t_host: float = float("nan")) -> list:
        """End of stream: the unterminated rest is discarded."""
        st = self.stats
        st.bytes_discarded += len(self._buf)
        self._buf.clear()
        st.bytes_pending = 0
        return []

    def on_bad(self, kind: str, text: str, t_host: float, out: list) -> None:
        """Hook for a rejected line that began with the frame marker (default: nothing)."""

    def _line(self, line: bytes, t_host: float, out: list) -> None:
        st = self.stats
        j = line.rfind(self.start)
        if j < 0:
            st.bytes_discarded += len(line)
            if line.strip(b"\r\n"):
                st.resyncs += 1
            return
        if j > 0:
            st.bytes_discarded += j
            st.resyncs += 1
            line = line[j:]
        text = line.decode("latin-1").strip("\r\n")
        try:
            rec = self.decode(text, t_host)
        except Unconfirmed:
            st.bytes_discarded += len(line)
            st.bump("unconfirmed")
            return
        except ChecksumError:
            st.bad_checksum += 1
            st.bytes_discarded += len(line)
            self.on_bad("checksum", text, t_host, out)
            return
        except ValueError:
            st.bad_format += 1
            st.bytes_discarded += len(line)
            self.on_bad("format", text, t_host, out)
            return
        st.frames_ok += 1
        st.bytes_ok += len(line)
        if rec is not None:
            out.append(rec)

"""One serial device link: pyserial port, reader thread, raw log, bounded queue, reconnect, stats.

The reader thread stamps every read with one monotonic host clock, appends it to the raw log,
feeds it to the protocol parser and puts the decoded records on a bounded queue (when full, the
oldest record is dropped and counted). When the port disappears (USB unplug; on a pty, the far
end closing) the link closes it, keeps everything already received, and re-opens the same path
as soon as it exists again (use a stable path such as ``/dev/serial/by-id/...``).
"""
from __future__ import annotations

import queue
import threading
import time
from pathlib import Path
from typing import Callable

import serial

from drivers.rawlog import IN, OUT, RECONNECT, RawLog
from drivers.stats import Stats

#: the one host clock of a session
CLOCK: Callable[[], float] = time.monotonic


class DeviceError(Exception):
    """A device link failed (port missing, not answering, closed). Names the device and port."""


class PortNotFound(DeviceError):
    """The serial port could not be opened."""


class PortClosed(DeviceError):
    """Writing to a link whose port is gone (disconnected)."""


class SerialLink:
    """A serial port with a reader thread feeding a protocol parser.

    Parameters
    ----------
    port : device path (``/dev/ttyUSB0``, a pty, or a stable symlink to one).
    parser : object with ``feed(data, t_host) -> records`` and a ``stats`` attribute; records
        may be a list (one queue item each) or a batch with ``len()`` (one queue item per batch).
    name : device name used in messages and logs.
    baudrate : line speed (ignored by ptys).
    raw_log : path of the raw byte log, or None.
    queue_size : bound of the record queue.
    reconnect : re-open the port after it disappears.
    idle_timeout_s : for streaming devices: a silence longer than this while connected counts
        once in ``stats.timeouts`` (None: not checked; request/reply clients count their own).
    clock : host clock (monotonic).
    """

    def __init__(self, port: str, parser, name: str = "device", baudrate: int = 115200,
                 raw_log: str | Path | None = None, queue_size: int = 100_000,
                 reconnect: bool = True, reconnect_interval_s: float = 0.05,
                 read_timeout_s: float = 0.05, idle_timeout_s: float | None = None,
                 clock: Callable[[], float] = CLOCK) -> None:
        self.port = str(port)
        self.parser = parser
        self.stats: Stats = parser.stats
        self.name = name
        self.baudrate = int(baudrate)
        self.rawlog = RawLog(raw_log) if raw_log else None
        self.queue: queue.Queue = queue.Queue(maxsize=queue_size)
        self.reconnect = reconnect
        self.reconnect_interval_s = reconnect_interval_s
        self.read_timeout_s = read_timeout_s
        self.idle_timeout_s = idle_timeout_s
        self.clock = clock
        self.connected = threading.Event()
        self.lock = threading.Lock()  # guards parser + stats
        self.fed = threading.Condition(self.lock)  # notified after every read is parsed
        self._ser: serial.Serial | None = None
        self._wlock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._was_open = False
        self.last_error: str = ""

    # ------------------------------------------------------------------ open / close
    def _open(self) -> None:
        # exclusive (flock): a second program on the port (another session, `devices record`)
        # split the bytes with this one silently; it is now refused with "Could not exclusively
        # lock port" (hunt27a)
        ser = serial.Serial(self.port, baudrate=self.baudrate, timeout=self.read_timeout_s,
                            write_timeout=2.0, exclusive=True)
        self._ser = ser
        if self._was_open:
            with self.lock:
                self.stats.reconnects += 1
            if self.rawlog:  # parsers that restart at a reconnect (odometer gate) replay the same
                self.rawlog.write(RECONNECT, self.clock(), b"")
        self._was_open = True
        self.connected.set()

    def open(self, timeout_s: float = 5.0) -> None:
        """Open the port now (retrying until ``timeout_s``).

        Raises
        ------
        PortNotFound : the port did not open in time.
        """
        deadline = self.clock() + timeout_s
        while True:
            try:
                self._open()
                return
            except (serial.SerialException, OSError) as e:
                self.last_error = str(e)
                if self.clock() >= deadline:
                    raise PortNotFound(f"{self.name}: cannot open {self.port}: {e}") from None
                time.sleep(self.reconnect_interval_s)

    def _drop_port(self, why: str) -> None:
        self.last_error = why
        self.connected.clear()
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception:  # closing a vanished port may fail; it is gone either way
                pass
        if self.rawlog:
            self.rawlog.flush()

    # ------------------------------------------------------------------ thread
    def start(self, open_timeout_s: float = 5.0) -> "SerialLink":
        """Open the port (if needed) and start the reader thread."""
        if self._ser is None:
            self.open(open_timeout_s)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"reader-{self.name}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the reader, close the port, flush and close the raw log."""
        self._stop.set()
        ser = self._ser
        if ser is not None:
            try:
                ser.cancel_read()
            except Exception:
                pass
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._drop_port("stopped")
        if self.rawlog:
            self.rawlog.close()

    def __enter__(self) -> "SerialLink":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _run(self) -> None:
        last_data = self.clock()
        silent = False
        while not self._stop.is_set():
            ser = self._ser
            if ser is None:
                if not self.reconnect:
                    return
                try:
                    self._open()
                except (serial.SerialException, OSError) as e:
                    self.last_error = str(e)
                    self._stop.wait(self.reconnect_interval_s)
                continue
            try:
                n = ser.in_waiting
                data = ser.read(n if n > 0 else 1)
            except (serial.SerialException, OSError, TypeError, AttributeError) as e:
                # TypeError/AttributeError: pyserial after a concurrent close (fd is None)
                self._drop_port(f"{self.name}: port lost: {e}")
                continue
            if not data:
                if (self.idle_timeout_s is not None and not silent
                        and self.clock() - last_data > self.idle_timeout_s):
                    silent = True
                    with self.lock:
                        self.stats.timeouts += 1
                continue
            t = self.clock()
            last_data, silent = t, False
            if self.rawlog:
                self.rawlog.write(IN, t, data)
            with self.lock:
                recs = self.parser.feed(data, t)
                self._put(recs)
                self.fed.notify_all()

    def _put(self, recs) -> None:
        if isinstance(recs, list):
            items = recs
        else:
            items = [recs] if len(recs) else []
        for r in items:
            while True:
                try:
                    self.queue.put_nowait(r)
                    break
                except queue.Full:
                    try:
                        self.queue.get_nowait()
                        self.stats.queue_dropped += 1  # caller holds self.lock
                    except queue.Empty:
                        pass

    # ------------------------------------------------------------------ I/O for clients
    def write(self, data: bytes) -> float:
        """Send bytes; returns the host time of the write.

        Raises
        ------
        PortClosed : the port is currently gone.
        """
        with self._wlock:
            ser = self._ser
            if ser is None:
                raise PortClosed(f"{self.name}: {self.port} is disconnected ({self.last_error})")
            try:
                ser.write(data)
            except (serial.SerialException, OSError, TypeError, AttributeError) as e:
                raise PortClosed(f"{self.name}: write to {self.port} failed: {e}") from None
            t = self.clock()
            with self.lock:
                self.stats.bytes_out += len(data)
            if self.rawlog:
                self.rawlog.write(OUT, t, data)
            return t

    def get(self, timeout_s: float | None = None):
        """Next record, or None after ``timeout_s``."""
        try:
            return self.queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def drain(self) -> list:
        """All records waiting in the queue."""
        out = []
        while True:
            try:
                out.append(self.queue.get_nowait())
            except queue.Empty:
                return out

    def snapshot(self) -> Stats:
        """A consistent copy of the counters."""
        with self.lock:
            return self.stats.copy()

"""Pseudo-terminal twin base: a pty pair, a worker thread, fault injection, port disappearance.

The twin owns the master side; the application opens the slave path with pyserial exactly as
it would open ``/dev/ttyUSB0``. Bytes the twin writes before the application has opened the
slave would be lost (pyserial flushes on open) and echoed back, so a twin waits until the slave
is in raw mode (pyserial's open clears ECHO) before it speaks (deps.md section 6).
"""
from __future__ import annotations

import os
import select
import termios
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class Faults:
    """Fault injection settings of a twin (all off by default).

    Attributes
    ----------
    corrupt_rate : probability per byte sent that it is changed (XOR with a random non-zero byte).
    drop_rate : probability per byte sent that it is dropped.
    garbage_rate : probability per write that a burst of random bytes is inserted.
    garbage_len : (min, max) length of a garbage burst.
    delay_rate, delay_s : probability that a reply is delayed, and by how long.
    missing_rate : probability that a reply is not sent at all.
    seed : random seed (faults are reproducible).
    """

    corrupt_rate: float = 0.0
    drop_rate: float = 0.0
    garbage_rate: float = 0.0
    garbage_len: tuple[int, int] = (1, 64)
    delay_rate: float = 0.0
    delay_s: float = 0.0
    missing_rate: float = 0.0
    seed: int = 0


class FaultInjector:
    """Applies :class:`Faults` to outgoing bytes and records every fault it injects.

    Offsets are positions in the *clean* stream (what the twin meant to send), so a test can
    say which frames were hit. ``corrupted``, ``dropped``: byte offsets; ``garbage``:
    (offset the burst was inserted before, length).
    """

    def __init__(self, faults: Faults | None) -> None:
        self.f = faults or Faults()
        self.rng = np.random.default_rng(self.f.seed)
        self.offset = 0
        self.corrupted: list[int] = []
        self.corrupted_from: list[int] = []
        self.corrupted_to: list[int] = []
        self.dropped: list[int] = []
        self.garbage: list[tuple[int, int]] = []

    @property
    def active(self) -> bool:
        f = self.f
        return bool(f.corrupt_rate or f.drop_rate or f.garbage_rate)

    def apply(self, data: bytes) -> bytes:
        """The bytes actually sent for ``data``."""
        n = len(data)
        base = self.offset
        self.offset += n
        if not self.active or n == 0:
            return data
        f, rng = self.f, self.rng
        a = np.frombuffer(data, np.uint8).copy()
        keep = np.ones(n, bool)
        if f.corrupt_rate:
            hit = np.flatnonzero(rng.random(n) < f.corrupt_rate)
            if hit.size:
                self.corrupted_from.extend(a[hit].tolist())
                a[hit] ^= rng.integers(1, 256, hit.size).astype(np.uint8)
                self.corrupted_to.extend(a[hit].tolist())
                self.corrupted.extend((base + hit).tolist())
        if f.drop_rate:
            drop = rng.random(n) < f.drop_rate
            keep &= ~drop
            self.dropped.extend((base + np.flatnonzero(drop)).tolist())
        out = a[keep].tobytes()
        if f.garbage_rate and rng.random() < f.garbage_rate:
            pos = int(rng.integers(0, n + 1))
            ln = int(rng.integers(f.garbage_len[0], f.garbage_len[1] + 1))
            junk = rng.integers(0, 256, ln).astype(np.uint8).tobytes()
            k = int(keep[:pos].sum())
            out = out[:k] + junk + out[k:]
            self.garbage.append((base + pos, ln))
        return out


def _slave_is_raw(fd: int) -> bool:
    try:
        return not (termios.tcgetattr(fd)[3] & termios.ECHO)
    except termios.error:
        return False


class Epoch:
    """A time origin shared by several twins: set by the first one that starts speaking.

    Twins fed from one session (``trolley devices simulate --session``) share it so that the
    IMU sample, odometer reading and gauge line of the same session time go out at the same
    host time, whichever port the application opens first.
    """

    def __init__(self) -> None:
        self._t0: float | None = None
        self._lock = threading.Lock()

    def get(self) -> float:
        """The origin (host monotonic time); set now if nobody has set it yet."""
        with self._lock:
            if self._t0 is None:
                self._t0 = time.monotonic()
            return self._t0

    @property
    def value(self) -> float | None:
        """The origin, or None while no twin has started speaking."""
        return self._t0


class PtyTwin:
    """A simulated device on a pty. Subclasses implement :meth:`serve` (the worker loop).

    Parameters
    ----------
    faults : fault injection settings.
    link_path : optional stable symlink to the slave (like ``/dev/serial/by-id/...``); it is
        re-pointed when the port comes back after :meth:`disappear`.
    """

    def __init__(self, faults: Faults | None = None, link_path: str | Path | None = None) -> None:
        self.faults = faults or Faults()
        self.injector = FaultInjector(self.faults)
        self.link_path = Path(link_path) if link_path else None
        self._stop = threading.Event()
        self._present = threading.Event()
        self._ready = threading.Event()  # present and opened by the application
        self._thread: threading.Thread | None = None
        self._io_lock = threading.RLock()
        self.bytes_sent = 0
        self.bytes_received = 0
        self.epoch: Epoch | None = None  # shared time origin (None: the twin's own start)
        self.epoch_offset_s = 0.0  # data time 0 of this twin is this long after the shared epoch
        self._open_pty()

    # ------------------------------------------------------------------ pty
    def _open_pty(self) -> None:
        self.master, self.slave = os.openpty()
        os.set_blocking(self.master, False)
        self.slave_path = os.ttyname(self.slave)
        if self.link_path:
            tmp = self.link_path.with_name(self.link_path.name + ".tmp")
            if tmp.is_symlink() or tmp.exists():
                tmp.unlink()
            os.symlink(self.slave_path, tmp)
            os.replace(tmp, self.link_path)
        self._present.set()

    def _close_pty(self) -> None:
        self._ready.clear()
        self._present.clear()
        if self.link_path and self.link_path.is_symlink():
            self.link_path.unlink()
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass

    @property
    def port(self) -> str:
        """Path the application opens (the stable link if any, else the slave)."""
        return str(self.link_path) if self.link_path else self.slave_path

    def wait_client(self, timeout_s: float = 10.0) -> bool:
        """Wait until the application has opened the slave (it is in raw mode)."""
        deadline = time.monotonic() + timeout_s
        while not self._stop.is_set():
            if self._present.is_set() and _slave_is_raw(self.slave):
                return True
            if time.monotonic() > deadline:
                return False
            time.sleep(0.005)
        return False

    def disappear(self, for_s: float, power_cycle: bool = False) -> None:
        """Simulate a USB unplug: the port vanishes for ``for_s`` seconds, then comes back.

        ``power_cycle``: the device was bus-powered and restarts (:meth:`power_up`).
        """
        with self._io_lock:
            self._close_pty()
        time.sleep(for_s)
        with self._io_lock:
            if power_cycle:
                self.power_up()
            self._open_pty()
        # let the application re-open before the device speaks again
        if self.wait_client(30.0):
            time.sleep(0.1)  # pyserial flushes the input just after switching to raw mode
            self._ready.set()

    # ------------------------------------------------------------------ I/O
    def send(self, data: bytes, inject: bool = True) -> bool:
        """Write ``data`` (after fault injection) to the master; blocks while the pty is full.

        Returns False if the twin was stopped or the port vanished before all was written.
        """
        out = self.injector.apply(data) if inject else data
        view = memoryview(out)
        while view.nbytes:
            if self._stop.is_set():
                return False
            with self._io_lock:
                if not self._ready.is_set():
                    return False
                try:
                    _, w, _ = select.select([], [self.master], [], 0.05)
                    if not w:
                        continue
                    k = os.write(self.master, view)
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError:
                    return False
            self.bytes_sent += k
            view = view[k:]
        return True

    def recv(self, timeout_s: float = 0.05) -> bytes:
        """Bytes from the application (empty after ``timeout_s``)."""
        with self._io_lock:
            if not self._present.is_set():
                time.sleep(timeout_s)
                return b""
            master = self.master
        try:
            r, _, _ = select.select([master], [], [], timeout_s)
            if not r:
                return b""
            data = os.read(master, 4096)
        except (BlockingIOError, InterruptedError, OSError, ValueError):
            return b""
        self.bytes_received += len(data)
        return data

    # ------------------------------------------------------------------ lifecycle
    def start(self, wait_client_s: float = 10.0) -> "PtyTwin":
        """Start the worker once the application has opened the port."""
        self._stop.clear()
        self._opened_before_start = _slave_is_raw(self.slave)

        def run() -> None:
            if self.wait_client(wait_client_s):
                if not self._opened_before_start:
                    time.sleep(0.1)  # pyserial flushes the input just after switching to raw mode
                self._ready.set()
                self.serve()

        self._thread = threading.Thread(target=run, name=type(self).__name__, daemon=True)
        self._thread.start()
        return self

    def power_up(self) -> None:
        """What the device does when it is powered again (default: nothing it keeps is lost)."""

    def origin(self) -> float:
        """Host time of data time 0: the shared epoch if any, else now (called at serve start)."""
        return self.epoch.get() + self.epoch_offset_s if self.epoch is not None else time.monotonic()

    def serve(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def wait_ready(self) -> None:
        """Block until the port is back and re-opened after :meth:`disappear` (or stopped)."""
        while not self.stopped and not self._ready.wait(0.01):
            pass

    def stop(self) -> None:
        """Stop the worker and close the pty."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        with self._io_lock:
            self._close_pty()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    def __enter__(self) -> "PtyTwin":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

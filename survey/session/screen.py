"""The crew's terminal: the live screen (rich) and the keys.

Keys (one key, no Enter): ``f`` fix, ``a`` accept a suspicious fix, ``r`` re-measure it, ``u`` undo
the last fix, ``n`` note (type the text, Enter), ``p`` pause / resume (train), ``t`` trolley turned
around, ``s`` station change, ``e`` end the session. During the station setup: ``a`` accept, ``d`` drop the suggested
point, ``m`` measure again; for a point the instrument could not measure, ``s`` skip it, ``m``
measure it again.
"""
from __future__ import annotations

import os
import queue
import select
import sys
import termios
import threading
import tty
from dataclasses import dataclass, field

from rich.console import Group
from rich.markup import escape
from rich.panel import Panel
from rich.text import Text
from rich.table import Table

KEYS_HELP = "f fix | u undo | n note | p pause/resume | t turned | s station change | e end"


@dataclass
class ScreenState:
    """What the live screen shows (updated by the session loop)."""

    session: str = ""
    phase: str = "starting"
    t_s: float = 0.0
    chainage_m: float = float("nan")
    speed_m_s: float = 0.0
    distance_since_fix_m: float = 0.0
    sigma_mm: float = float("nan")
    sigma_fix_here_mm: float = float("nan")
    standing: bool = True
    fixes_accepted: int = 0
    devices: list = field(default_factory=list)
    message: str = ""
    last_interval: str = ""
    prompt: str = KEYS_HELP
    progress: float | None = None


def render(s: ScreenState):
    """The live screen as a rich renderable."""
    top = Table.grid(padding=(0, 2))
    for _ in range(4):
        top.add_column()
    ch = "-" if s.chainage_m != s.chainage_m else f"{s.chainage_m:10.3f} m"
    sig = "-" if s.sigma_mm != s.sigma_mm else f"{s.sigma_mm:.2f} mm now"
    if s.sigma_fix_here_mm == s.sigma_fix_here_mm:
        sig += f", {s.sigma_fix_here_mm:.2f} mm if fixed here"
    top.add_row("chainage", ch, "speed", f"{s.speed_m_s:5.2f} m/s")
    top.add_row("since fix", f"{s.distance_since_fix_m:8.2f} m", "predicted 1-sigma", sig)
    top.add_row("time", f"{s.t_s:9.1f} s", "fixes", f"{s.fixes_accepted}")
    top.add_row("state", "[green]standing[/]" if s.standing else "[cyan]moving[/]", "phase", s.phase)
    dev = Table.grid(padding=(0, 2))
    for _ in range(4):
        dev.add_column()
    for h in s.devices:
        mark = "[green]ok[/]" if h.ok else f"[bold red]{escape(h.message or 'fault')}[/]"
        dev.add_row(h.name, mark, f"{h.samples} samples", f"{h.errors} errors")
    parts = [top, dev]
    if s.progress is not None:
        n = int(30 * max(0.0, min(1.0, s.progress)))
        parts.append(Text(f"[{'#' * n}{'.' * (30 - n)}] {100 * s.progress:5.1f} %"))
    if s.last_interval:
        parts.append(Text(s.last_interval))  # data (defect labels, messages): printed literally
    if s.message:
        parts.append(f"[bold yellow]{escape(s.message)}[/]")
    parts.append(f"[dim]{escape(s.prompt)}[/]")
    return Panel(Group(*parts), title=f"trolley survey {s.session}")


class KeyReader:
    """Reads single keys from the terminal (cbreak mode) on a thread; restores the terminal."""

    def __init__(self, stream=None) -> None:
        self.stream = stream or sys.stdin
        self.keys: queue.Queue[str] = queue.Queue()
        self._stop = threading.Event()
        self._fd = self.stream.fileno()
        self._saved = None
        self._thread = threading.Thread(target=self._run, name="keys", daemon=True)

    def start(self) -> "KeyReader":
        if os.isatty(self._fd):
            self._saved = termios.tcgetattr(self._fd)
            tty.setcbreak(self._fd)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            r, _, _ = select.select([self._fd], [], [], 0.1)
            if r:
                data = os.read(self._fd, 64)
                if not data:
                    return
                for ch in data.decode("utf-8", "replace"):
                    self.keys.put(ch)

    def get(self) -> str | None:
        try:
            return self.keys.get_nowait()
        except queue.Empty:
            return None

    def stop(self) -> None:
        self._stop.set()
        if self._saved is not None:
            termios.tcsetattr(self._fd, termios.TCSADRAIN, self._saved)

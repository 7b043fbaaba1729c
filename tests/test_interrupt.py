"""SIGTERM ends a command as Ctrl-C does (survey.errors.sigterm_as_interrupt): the writers' hidden
temporaries are removed, one line ``error: interrupted (SIGTERM)``, exit code 143 (Ctrl-C: 130).

Python's default for SIGTERM ended the process at once: no output appeared under its name (the
writes are atomic), but the temporary beside it stayed (closing notes of stop 26). The field
session's SIGTERM is in tests/test_session_run.py.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import pytest
import typer

from survey.errors import Terminated, guarded, sigterm_as_interrupt

HERE = os.path.dirname(__file__)


def _exit_code(func) -> tuple[int, str]:
    """Run ``func`` as a guarded command: (exit code, what it printed on stderr)."""
    from typer.testing import CliRunner

    app = typer.Typer()
    app.command()(guarded(func))

    @app.command()
    def other() -> None:        # a second command: the first keeps its name
        pass

    res = CliRunner().invoke(app, [func.__name__])
    return res.exit_code, res.stderr


def test_sigterm_in_a_guarded_command_is_a_keyboard_interrupt_and_exit_143():
    # (signal handlers are the main thread's: elsewhere the SIGTERM below would end pytest itself)
    assert threading.current_thread() is threading.main_thread()
    before = signal.getsignal(signal.SIGTERM)
    reached = []

    def work() -> None:
        assert signal.getsignal(signal.SIGTERM) not in (before, signal.SIG_DFL)
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)                       # (the handler raises before this ends)
        finally:
            reached.append("finally")           # what removes a writer's temporary

    code, err = _exit_code(work)
    assert (code, err, reached) == (143, "error: interrupted (SIGTERM)\n", ["finally"])
    assert signal.getsignal(signal.SIGTERM) == before      # put back after the command


def test_ctrl_c_in_a_guarded_command_is_one_line_and_exit_130():
    def work() -> None:
        raise KeyboardInterrupt

    # (typer turned it into exit 130 without a word)
    assert _exit_code(work) == (130, "error: interrupted (Ctrl-C)\n")


def test_only_the_first_sigterm_raises():
    """A clean-up that hangs is ended by the next SIGTERM, as a kill would end it, not interrupted
    half-way by a second exception."""
    with sigterm_as_interrupt():
        handler = signal.getsignal(signal.SIGTERM)
        with pytest.raises(Terminated):
            handler(signal.SIGTERM, None)
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL


def _track_csv(path, n: int) -> None:
    sys.path.insert(0, HERE)
    from test_export_reader import _track

    _track(path, n=n)


def test_sigterm_while_export_writes_leaves_no_temporary_and_no_output(tmp_path):
    """A real process, sent SIGTERM as soon as its first temporary appears (the workbook of a
    10 000-station track.csv takes some 0.4 s to write; the temporary is there all that time)."""
    _track_csv(tmp_path / "track.csv", 10_000)
    out = tmp_path / "out"
    out.mkdir()
    err = tmp_path / "stderr.txt"
    with open(err, "w") as fh:
        p = subprocess.Popen([sys.executable, "-m", "survey.cli", "export", "track.csv", "--xlsx", "out/survey.xlsx",
                              "--csv", "out/track_table.csv"], cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=fh)
    deadline = time.monotonic() + 60
    seen = []
    while not seen:
        assert p.poll() is None and time.monotonic() < deadline, "the export ended before a temporary was seen"
        seen = [n for n in os.listdir(out) if n.startswith(".")]
        time.sleep(0.002)
    p.send_signal(signal.SIGTERM)
    assert p.wait(timeout=30) == 143
    assert err.read_text().splitlines()[-1] == "error: interrupted (SIGTERM)", err.read_text()
    # before: the temporary seen stayed (.survey.xlsx.xxxxxxxx.xlsx); the outputs are all or none
    assert seen[0].startswith(".survey.xlsx.") and os.listdir(out) == []

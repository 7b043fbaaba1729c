"""Waiting on the background threads of the pty tests (not a test module)."""
from __future__ import annotations

import sqlite3
import time
from pathlib import Path
from typing import Callable


def wait_until(done: Callable[[], bool], timeout_s: float, poll_s: float = 0.01) -> bool:
    """Sleep in ``poll_s`` steps until ``done()`` or ``timeout_s`` has passed; ``done()`` at the end.

    The tests assert on what arrived, so a timeout is not an error here: it shows up as missing
    data in the test's own assertion.
    """
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        time.sleep(poll_s)
    return done()


def count_in_store(db: Path, sql: str) -> int:
    """``sql`` (a COUNT) on the project store read-only, while a session process writes it; 0 while
    the file is locked or not there yet (the caller polls)."""
    try:
        c = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=0.2)
        try:
            return int(c.execute(sql).fetchone()[0])
        finally:
            c.close()
    except sqlite3.Error:
        return 0

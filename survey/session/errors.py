"""Errors of a field session."""
from __future__ import annotations


class SessionAbort(RuntimeError):
    """The session cannot go on; ``hint`` says what the crew can try."""

    def __init__(self, message: str, hint: str = "") -> None:
        super().__init__(message)
        self.hint = hint

"""The CLI's last line of defence: known error types become one clear line on stderr, exit 2.

Every command is wrapped by :func:`guarded` (``survey/cli.py`` does it once for all commands), so
a bad input that a reader did not foresee still ends as ``error: <message>`` with exit code 2,
never as a Python traceback (DESIGN.md: bad input -> clear message, exit 2). Messages are
printed literally (no rich markup), on one line, with numpy scalar reprs (``np.float64(3.0)``)
shown as plain numbers; numpy's floating-point warnings are silenced (the readers check values
themselves). An error that is not a known input error (a bug) is reported as ``internal error``
with exit code 3; ``TROLLEY_DEBUG=1`` shows its traceback.
"""
from __future__ import annotations

import functools
import os
import re
import sqlite3
import warnings
from collections.abc import Callable

import typer

_NP_SCALAR = re.compile(r"np\.(?:float|int|uint|bool_?|str_)\w*\(([^()]*)\)")

#: Exit code of a bad input / unusable file (the project's convention).
EXIT_BAD_INPUT = 2
#: Exit code of an unexpected internal error.
EXIT_INTERNAL = 3


def one_line(message: object) -> str:
    """``message`` as one line: whitespace collapsed, numpy scalar reprs as plain numbers."""
    return " ".join(_NP_SCALAR.sub(r"\1", str(message)).split())


def os_error_text(exc: OSError) -> str:
    """``path: reason`` for an OSError (the user's path, the system's reason)."""
    reason = exc.strerror or str(exc)
    name = exc.filename
    if name is None:
        return reason
    extra = f" -> {exc.filename2}" if exc.filename2 else ""
    return f"{os.fsdecode(name)}{extra}: {reason}"


def error_text(exc: BaseException) -> str | None:
    """The one-line message of a known input error, None for anything else."""
    from rich.errors import MarkupError

    from drivers.geocom import GeoComError
    from drivers.serialport import DeviceError
    from survey.session.errors import SessionAbort
    from survey.store import StoreError

    if isinstance(exc, OSError):
        return one_line(os_error_text(exc))
    if isinstance(exc, MemoryError):
        return "not enough memory for this input (reduce the size or the rate parameters)"
    if isinstance(exc, sqlite3.Error):
        hint = " (is the disk full, or the store read-only?)" if isinstance(exc, sqlite3.OperationalError) else ""
        return one_line(f"project store: {exc}{hint}")
    if isinstance(exc, (ValueError, MarkupError, OverflowError, StoreError, SessionAbort, DeviceError,
                        GeoComError)):
        return one_line(exc) or type(exc).__name__
    return None


def guarded(func: Callable) -> Callable:
    """Wrap a typer command: known errors -> ``error: ...`` on stderr and exit 2."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        import numpy as np

        try:
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore", RuntimeWarning)
                return func(*args, **kwargs)
        except (typer.Exit, typer.Abort, typer.TyperException, KeyboardInterrupt, SystemExit):
            raise
        except Exception as exc:  # noqa: BLE001 - the last line of defence, see the module docstring
            if os.environ.get("TROLLEY_DEBUG"):
                raise
            text = error_text(exc)
            if text is None:
                typer.echo(f"internal error ({type(exc).__name__}): {one_line(exc)} "
                           "(TROLLEY_DEBUG=1 shows the traceback)", err=True)
                raise typer.Exit(code=EXIT_INTERNAL) from None
            typer.echo(f"error: {text}", err=True)
            raise typer.Exit(code=EXIT_BAD_INPUT) from None

    return wrapper


def guard_app(app: typer.Typer) -> None:
    """Wrap every command of ``app`` and of its sub-apps with :func:`guarded` (once)."""
    for cmd in app.registered_commands:
        if cmd.callback is not None and not getattr(cmd.callback, "_trolley_guarded", False):
            cmd.callback = guarded(cmd.callback)
            cmd.callback._trolley_guarded = True
    for group in app.registered_groups:
        if group.typer_instance is not None:
            guard_app(group.typer_instance)

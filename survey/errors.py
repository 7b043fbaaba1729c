"""The CLI's last line of defence: known error types become one clear line on stderr, exit 2.

Every command is wrapped by :func:`guarded` (``survey/cli.py`` does it once for all commands), so
a bad input that a reader did not foresee still ends as ``error: <message>`` with exit code 2,
never as a Python traceback (DESIGN.md: bad input -> clear message, exit 2). Messages are
printed literally (no rich markup), on one line, with numpy scalar reprs (``np.float64(3.0)``)
shown as plain numbers; numpy's floating-point warnings are silenced (the readers check values
themselves). An error that is not a known input error (a bug) is reported as ``internal error``
with exit code 3; ``TROLLEY_DEBUG=1`` shows its traceback.

Click's own usage errors (an option value typer cannot convert, an unknown option, a missing
argument) come out the same way, through the ``trolley`` group :class:`OneLineUsageErrors`
(:func:`usage_error_text`), instead of click's usage block and ``Error:`` line.

Ctrl-C and SIGTERM end a command the same way (:func:`sigterm_as_interrupt`): a
KeyboardInterrupt in the main thread, so every ``finally`` and ``except BaseException`` on the
way up runs (the atomic writers remove their temporaries, the field session stops its devices and
threads), then one line ``error: interrupted (Ctrl-C)`` or ``error: interrupted (SIGTERM)`` and
exit code 128 + the signal's number, as a shell reports a process the signal ended: 130 and 143.
"""
from __future__ import annotations

import functools
import os
import re
import signal
import sqlite3
import threading
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, NoReturn

import typer
# typer 0.29 carries its own copy of click (research/deps.md section 7)
from typer._click.exceptions import (BadOptionUsage, BadParameter, MissingParameter, NoArgsIsHelpError, NoSuchOption,
                                     UsageError)
from typer.core import TyperGroup

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


def refuse(text: str) -> NoReturn:
    """``error: <text>`` on stderr, exit code 2: how every bad input ends."""
    typer.echo(f"error: {text}", err=True)
    raise typer.Exit(code=EXIT_BAD_INPUT) from None


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread by :func:`sigterm_as_interrupt`: a KeyboardInterrupt, so
    that the code a Ctrl-C runs on its way out runs for it too."""


def interrupt_text(exc: KeyboardInterrupt) -> str:
    """``interrupted (SIGTERM)`` or ``interrupted (Ctrl-C)``: the start of an interrupted command's line."""
    return f"interrupted ({'SIGTERM' if isinstance(exc, Terminated) else 'Ctrl-C'})"


def interrupt_exit_code(exc: KeyboardInterrupt) -> int:
    """128 + the signal's number, as a shell reports a process the signal ended: 143 for SIGTERM,
    130 for Ctrl-C (typer's code for it, kept)."""
    return 128 + (signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT)


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`Terminated` in the main thread.

    Python's default for SIGTERM ends the process at once: no ``finally`` runs, and a command
    killed while writing left its hidden temporary beside the output (the output itself is
    atomic). Only the first SIGTERM raises; it puts the default back, so a second one ends a
    clean-up that hangs at once, as a kill would (the field session resumes from its store after
    any kill). Nothing is installed outside the main thread (signal handlers live there) or when
    SIGTERM is ignored (a parent that ignores it means it); the previous handler is put back at
    the end (``trolley devices simulate`` installs its own inside, which wins while it runs).
    """
    def on_sigterm(signum: int, frame: Any) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        raise Terminated()

    installed = False
    if threading.current_thread() is threading.main_thread() and \
            signal.getsignal(signal.SIGTERM) is not signal.SIG_IGN:
        previous = signal.signal(signal.SIGTERM, on_sigterm)
        installed = True
    try:
        yield
    finally:
        if installed:
            # (None: a handler set outside Python, which signal.signal cannot put back)
            signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def guarded(func: Callable) -> Callable:
    """Wrap a typer command: known errors -> ``error: ...`` on stderr and exit 2; Ctrl-C and
    SIGTERM -> ``error: interrupted (...)``, exit 130 or 143 (module docstring)."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        import numpy as np

        try:
            with sigterm_as_interrupt(), warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore", RuntimeWarning)
                return func(*args, **kwargs)
        except KeyboardInterrupt as exc:
            # (typer turned a Ctrl-C into exit 130 without a word)
            typer.echo(f"error: {interrupt_text(exc)}", err=True)
            raise typer.Exit(code=interrupt_exit_code(exc)) from None
        except (typer.Exit, typer.Abort, typer.TyperException, SystemExit):
            raise
        except Exception as exc:  # noqa: BLE001 - the last line of defence, see the module docstring
            if os.environ.get("TROLLEY_DEBUG"):
                raise
            text = error_text(exc)
            if text is None:
                typer.echo(f"internal error ({type(exc).__name__}): {one_line(exc)} "
                           "(TROLLEY_DEBUG=1 shows the traceback)", err=True)
                raise typer.Exit(code=EXIT_INTERNAL) from None
            refuse(text)

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


#: pydantic's error types of a number typer could not read, and of typer's ``min=``/``max=``
_NOT_A_NUMBER = {"int_parsing": "an integer", "int_from_float": "an integer", "int_type": "an integer",
                 "float_parsing": "a number", "float_type": "a number"}
_BOUNDS = {"greater_than_equal": (">=", "ge"), "less_than_equal": ("<=", "le"), "greater_than": (">", "gt"),
           "less_than": ("<", "lt")}


def _plain(text: str) -> str:
    """Click's sentence as the house writes a message: no capital first letter, no final full stop."""
    text = one_line(text).removesuffix(".")
    return text[:1].lower() + text[1:] if text[1:2].islower() else text


def _param_name(exc: BadParameter) -> str | None:
    """The option (its long name) or argument a click error is about, None when it names none."""
    hint = exc.param_hint
    if hint is not None:
        return hint if isinstance(hint, str) else " / ".join(hint)
    param = exc.param
    if param is None:
        return None
    if param.param_type_name == "option":
        return next((o for o in param.opts if o.startswith("--")), param.opts[0])
    return param.display_name_raw


def _value_text(exc: BadParameter) -> str:
    """What a BadParameter says about the value, with the value: typer's message of a number it
    could not read names no value ("Input should be a valid integer, unable to parse string as an
    integer"), and its min=/max= message is pydantic's ("Input should be greater than or equal to 10")."""
    errors = getattr(exc.__cause__, "errors", None)        # the pydantic ValidationError typer read it with
    errors = errors() if callable(errors) else None
    if not errors:
        return _plain(exc.message)
    error = errors[0]
    kind, value, bound = error.get("type"), error.get("input"), error.get("ctx") or {}
    if kind in _NOT_A_NUMBER:
        return f"must be {_NOT_A_NUMBER[kind]}, got {value!r}"
    if kind in _BOUNDS and _BOUNDS[kind][1] in bound:
        sign, key = _BOUNDS[kind]
        return f"must be {sign} {bound[key]}, got {value}"
    text = _plain(str(error.get("msg", exc.message)).removeprefix("Value error, "))
    return text if repr(value) in text else f"{text}, got {value!r}"


def usage_error_text(exc: UsageError) -> str:
    """The one line of a click usage error, naming the option first as the house's messages do.

    ``--seed: must be an integer, got 'abc'``; ``--sed: no such option (possible options: --seed,
    --speed-m-s)``, click's suggestion kept; ``KEY: required argument not given``; ``--device:
    requires an argument``; anything else is click's sentence (``no such command 'budgett'. Did you
    mean 'budget'?``).
    """
    if isinstance(exc, NoSuchOption):
        text = f"{exc.option_name}: no such option"
        if exc.possibilities:
            text += f" (possible options: {', '.join(sorted(exc.possibilities))})"
        return one_line(text)
    if isinstance(exc, BadOptionUsage):
        return one_line(f"{exc.option_name}: {_plain(exc.message.removeprefix(f'Option {exc.option_name!r} '))}")
    if isinstance(exc, BadParameter):
        name = _param_name(exc)
        if isinstance(exc, MissingParameter):
            text = f"required {exc.param_type or (exc.param.param_type_name if exc.param else 'parameter')} not given"
            choices = exc.param.get_missing_message(exc.ctx) if exc.param is not None else ""
            text += f" ({_plain(choices)})" if choices else ""
        else:
            text = _value_text(exc)
        return one_line(f"{name}: {text}" if name else f"invalid value: {text}")
    return _plain(exc.format_message())


@contextmanager
def _usage_errors_in_one_line() -> Iterator[None]:
    try:
        yield
    except NoArgsIsHelpError:       # `trolley`, `trolley devices` alone: click prints the help
        raise
    except UsageError as exc:
        refuse(usage_error_text(exc))


class OneLineUsageErrors(TyperGroup):
    """The ``trolley`` group (``typer.Typer(cls=...)``): click's usage errors are one line
    ``error: OPTION: ...`` on stderr with exit code 2, as every bad input, not click's usage
    block above an ``Error:`` line (docs/conventions.md "Errors, exit codes and what is refused").

    Click raises them as it parses the command line: in this group's ``make_context``
    (``trolley --bogus``) and in its ``invoke``, which parses and runs the sub-commands
    (``trolley budget --seed abc``), a command's own ``typer.BadParameter`` included. Help is
    left alone: ``--help`` is no error, and ``trolley`` or a group without a command raises
    click's NoArgsIsHelpError, which prints the help.
    """

    def make_context(self, info_name: str | None, args: list[str], parent: Any = None, **extra: Any) -> Any:
        with _usage_errors_in_one_line():
            return super().make_context(info_name, args, parent=parent, **extra)

    def invoke(self, ctx: Any) -> Any:
        with _usage_errors_in_one_line():
            return super().invoke(ctx)

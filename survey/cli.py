"""The ``trolley`` command: one typer app, one function per command.

Command groups live in ``survey/commands/<name>.py`` and register themselves here. Help texts
are plain click help (``rich_markup_mode=None`` on every typer app): option names are never cut
and ``[site]`` or ``[imu]`` in a help text are printed, not taken for rich markup.
"""
from __future__ import annotations

import importlib

from typing import Annotated

import typer

from survey.errors import guard_app

app = typer.Typer(
    name="trolley",
    help="Stop-and-go track surveying with a trolley: simulate, process, budget, export.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def _print_version(value: bool) -> None:
    if value:
        from survey.version import version

        typer.echo(f"trolley {version()}")
        raise typer.Exit()


@app.callback()
def trolley(
    version: Annotated[bool, typer.Option("--version", is_eager=True, callback=_print_version,
                                          help="Print the installed version and exit.")] = False,
) -> None:
    """Stop-and-go track surveying with a trolley: simulate, process, budget, export."""

# Each entry is a module in survey.commands exposing register(app).
COMMAND_MODULES: list[str] = [
    "engine",
    "devices",
    "project",
    "export",
    "simulate",
    "demo",
    "budget",
    "tgms",
    "survey",
    "inservice",
]

for _name in COMMAND_MODULES:
    importlib.import_module(f"survey.commands.{_name}").register(app)

# known errors -> one line on stderr, exit 2; never a traceback (survey/errors.py)
guard_app(app)


def _plain_help(typer_app: typer.Typer) -> None:
    """Plain click help for every command group, whatever its own Typer(...) said."""
    for group in typer_app.registered_groups:
        group.typer_instance.rich_markup_mode = None
        _plain_help(group.typer_instance)


_plain_help(app)


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()

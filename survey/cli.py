"""The ``trolley`` command: one typer app, one function per command.

Command groups live in ``survey/commands/<name>.py`` and register themselves here.
"""
from __future__ import annotations

import importlib

import typer

from survey.errors import guard_app

app = typer.Typer(
    name="trolley",
    help="Stop-and-go track surveying with a trolley: simulate, process, budget, export.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

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
]

for _name in COMMAND_MODULES:
    importlib.import_module(f"survey.commands.{_name}").register(app)

# known errors -> one line on stderr, exit 2; never a traceback (survey/errors.py)
guard_app(app)


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()

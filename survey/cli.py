"""The ``trolley`` command: one typer app, one function per command.

Command groups live in ``survey/commands/<name>.py`` and register themselves here. Help texts
are plain click help (``rich_markup_mode=None`` on every typer app): option names are never cut
and ``[site]`` or ``[imu]`` in a help text are printed, not taken for rich markup.
"""
from __future__ import annotations

import importlib

from typing import Annotated

import typer

from survey.errors import OneLineUsageErrors, guard_app

app = typer.Typer(
    name="trolley",
    help="Stop-and-go track surveying with a trolley: simulate, process, budget, export.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    cls=OneLineUsageErrors,     # click's usage errors as one line `error: ...`, exit 2
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
    "compare",
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


#: The one-line summaries of the command lists (``trolley --help``, ``trolley project --help``):
#: click cuts a longer first sentence with "..." at 80 columns, so each command says what it
#: does in a few words here; its own docstring keeps the full help text.
SHORT_HELP: dict[str, str] = {
    "process": "Filter and smooth a raw session into track.csv.",
    "export": "Track geometry, tolerances, survey sheet, plots, PDF.",
    "compare": "Two surveys of one track against their sigmas.",
    "simulate": "Simulate a stop-and-go survey and its truth.",
    "demo": "Survey the demo project end to end.",
    "budget": "Accuracy budget and IMU/odometer sizing.",
    "devices": "Check, record and simulate the serial instruments.",
    "project": "Project store: CPIII, design, sessions, header.",
    "tgms": "TGMS: cameras, lasers, IMU, encoder -> irregularities.",
    "survey": "The field survey session: start, resume.",
    "inservice": "In-service vehicle sensors -> lateral alignment.",
    "devices probe": "Check the instruments and what they answer.",
    "devices record": "Record imu.csv, odometer.csv, gauge.csv.",
    "devices simulate": "Start the device twins on pseudo-terminals.",
    "project new": "Create a project store.",
    "project import-cpiii": "Import CPIII control points.",
    "project import-alignment": "Import the design alignment (LandXML).",
    "project import-session": "Import a raw session folder.",
    "project export-session": "Write a stored session as a raw folder.",
    "project set-crs": "Set the CRS and vertical datum.",
    "project set": "Set a survey header field.",
    "project show": "Show settings, CPIII, design, sessions.",
    "tgms simulate": "Write a synthetic TGMS recording and truth.",
    "tgms process": "Process a recording into irregularities.csv.",
    "tgms tune": "Tune the noise parameters (constrained ML).",
    "survey start": "Start a field session.",
    "survey resume": "Continue a session after a crash or kill -9.",
    "inservice simulate": "Write a synthetic in-service recording.",
    "inservice process": "Estimate the lateral alignment (Munoz 2021).",
    "inservice calibrate": "Identify and tune the estimator.",
}


def _command_name(info: typer.models.CommandInfo) -> str:
    return info.name or info.callback.__name__.replace("_", "-")


def _plain_help(typer_app: typer.Typer, prefix: str = "") -> None:
    """Plain click help and short summaries for every command and group, whatever its own
    Typer(...) said."""
    for info in typer_app.registered_commands:
        info.short_help = info.short_help or SHORT_HELP.get(prefix + _command_name(info))
    for group in typer_app.registered_groups:
        group.typer_instance.rich_markup_mode = None
        group.short_help = group.short_help or SHORT_HELP.get(prefix + group.name)
        _plain_help(group.typer_instance, prefix + group.name + " ")


_plain_help(app)


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()

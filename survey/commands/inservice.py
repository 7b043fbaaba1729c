"""``trolley inservice ...``: lateral track alignment from inertial sensors on an in-service vehicle
(Munoz 2021).

* ``trolley inservice simulate --out DIR`` writes a synthetic recording and truth.csv
  (survey/commands/inservice_simulate.py).
"""
from __future__ import annotations

import typer

from survey.commands.inservice_simulate import simulate_cmd

inservice_app = typer.Typer(help="In-service vehicle: wheelset/bogie inertial sensors -> lateral alignment.",
                            no_args_is_help=True)
inservice_app.command("simulate")(simulate_cmd)


def register(app: typer.Typer) -> None:
    """Add the ``inservice`` command group to the ``trolley`` app."""
    app.add_typer(inservice_app, name="inservice")

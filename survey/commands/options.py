"""Option conventions shared by the ``trolley`` commands (docs/conventions.md, "Command line").

* Choices are ``Literal`` / ``Enum`` types, so typer lists them in the help and refuses any
  other value with exit code 2 before a command runs.
* One name per idea: lengths end in ``-m``, ports in ``-port``, plot folders are ``--plots``,
  tolerance sets ``--tolerances``. An option that was renamed keeps its old name as a hidden
  option; :func:`renamed` merges the two so that existing scripts keep working.
"""
from __future__ import annotations

from enum import Enum
from typing import Annotated, Any, Literal

import typer

#: IMU presets of trolley.sensors.IMU_PRESETS (tests/test_cli_conventions.py checks they agree).
ImuPreset = Literal["rlg", "fog", "mems"]
#: ``trolley budget --imu``: the presets, or figures given on the command line.
BudgetImu = Literal["rlg", "fog", "mems", "custom"]
#: trolley.engine.ProcessConfig.smoother.
Smoother = Literal["rts", "tfs", "none"]
#: trolley.inservice.estimator.estimate(smoother=...).
InserviceSmoother = Literal["rts", "none"]
#: design model of the in-service filter: trolley.inservice.bogie or the paper's simplified model
InserviceKind = Literal["bogie", "paper"]
#: trolley.tgms.params.TgmsParams.orientation and .trajectory, rail profiles of the TGMS simulator.
TgmsOrientation = Literal["kf", "madgwick"]
TgmsTrajectory = Literal["ltv", "ekf"]
TgmsModel = Literal["kf", "ltv", "ekf"]
TgmsBox = Literal["relative", "absolute"]
RailProfile = Literal["60E1", "54E1"]


#: ``--json`` of a command that prints a table or lines otherwise.
JsonFlag = Annotated[bool, typer.Option("--json", help="print the result as one JSON object on stdout")]
#: ``--json`` of a command whose stdout is its JSON summary in any case.
JsonAlways = Annotated[bool, typer.Option("--json", help="one JSON object on stdout (this command prints it in "
                                                         "any case; accepted like on every command)")]


class Device(str, Enum):
    """The serial instruments of drivers.twins.fleet.DEVICES (a list option needs an Enum)."""

    imu = "imu"
    odometer = "odometer"
    gauge = "gauge"
    totalstation = "totalstation"


def renamed(value: Any, old_value: Any, name: str, old_name: str, default: Any = None) -> Any:
    """The value of an option given under its name or its old, hidden name.

    Parameters
    ----------
    value : value of the option ``name`` (``default`` when not given).
    old_value : value of the hidden option ``old_name`` (None when not given).
    name, old_name : the option names, e.g. ``"--step-m"`` and ``"--step"``, for the message.
    default : default of ``name``.

    Returns
    -------
    ``old_value`` when it was given, else ``value``.

    Raises
    ------
    typer.BadParameter (exit code 2) when both were given with different values.
    """
    if old_value is None:
        return value
    if (value != default or _given(name)) and value != old_value:
        raise typer.BadParameter(f"give {name} only ({old_name} is its old name)", param_hint=old_name)
    return old_value


def _given(option: str) -> bool:
    """Whether ``option`` was typed on the command line (its default value included: ``--step 1.25
    --step-m 0.625`` gives both names different values even though 0.625 is the default)."""
    try:      # typer 0.29 carries its own copy of click
        from typer._click.core import ParameterSource
        from typer._click.globals import get_current_context
    except ImportError:
        from click.core import ParameterSource
        from click.globals import get_current_context

    ctx = get_current_context(silent=True)
    if ctx is None:
        return False
    for p in ctx.command.params:
        if option in p.opts:
            return ctx.get_parameter_source(p.name) == ParameterSource.COMMANDLINE
    return False


def old_name(new: str) -> str:
    """Help text of a hidden option kept for scripts written before ``new`` was renamed."""
    return f"old name of {new}"

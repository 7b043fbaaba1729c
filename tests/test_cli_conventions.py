"""CLI conventions (issue 15): version, help at 80 columns, choices, flags, --json, old option
names, progress shares, and python-control imported only for ``process --observability``."""
from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from importlib import metadata
from pathlib import Path
from typing import get_args

import numpy as np
import pytest
import typer
from hypothesis import given
from hypothesis import strategies as st
from typer.testing import CliRunner

from survey import jsonout
from survey.cli import app
from survey.commands.options import Device, ImuPreset, renamed
from survey.commands.progress import share

runner = CliRunner()
REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "projects" / "demo"


def strict_json(text: str):
    """json.loads that refuses NaN and Infinity (Python's json accepts them by default)."""
    def refuse(name):
        raise ValueError(f"not JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def all_commands():
    """(path, click command) of every command and group of the app, the root first."""
    def walk(cmd, path):
        yield path, cmd
        for name, sub in getattr(cmd, "commands", {}).items():
            yield from walk(sub, path + [name])
    return list(walk(typer.main.get_command(app), []))


def help_80(path):
    r = runner.invoke(app, path + ["--help"], env={"COLUMNS": "80"}, terminal_width=80)
    assert r.exit_code == 0, r.output
    return r.output


# ------------------------------------------------------------------------------------- version

def test_version_is_the_installed_package_metadata():
    r = runner.invoke(app, ["--version"])
    assert r.exit_code == 0
    assert r.stdout == f"trolley {metadata.version('trolley-survey')}\n"
    from survey.version import version
    assert version() == metadata.version("trolley-survey")


def test_shell_completion_is_offered():
    out = help_80([])
    assert "--install-completion" in out and "--show-completion" in out


# ---------------------------------------------------------------------------------------- help

COMMANDS = all_commands()


@pytest.mark.parametrize("path, cmd", COMMANDS, ids=[" ".join(p) or "trolley" for p, _ in COMMANDS])
def test_help_at_80_columns_shows_every_option_unbroken(path, cmd):
    out = help_80(path)
    assert max(len(line) for line in out.splitlines()) <= 80
    for p in cmd.params:
        names = list(p.opts) + list(getattr(p, "secondary_opts", []))
        for name in names:
            if not name.startswith("-"):
                continue
            found = re.search(rf"(^|[\s,/]){re.escape(name)}($|[\s,/])", out, re.M)
            if getattr(p, "hidden", False):
                assert not found, f"hidden {name} shown in `trolley {' '.join(path)} --help`"
            else:
                assert found, f"{name} missing or cut in `trolley {' '.join(path)} --help`"


GROUPS = [(p, c) for p, c in COMMANDS if getattr(c, "commands", None)]


@pytest.mark.parametrize("path, group", GROUPS, ids=[" ".join(p) or "trolley" for p, _ in GROUPS])
def test_command_lists_at_80_columns_show_whole_summaries(path, group):
    """Click cuts a summary that does not fit with "..."; every listed command says what it does
    in full (survey.cli.SHORT_HELP)."""
    out = help_80(path)
    listing = out[out.index("Commands:"):].splitlines()[1:]
    names = [line.split()[0] for line in listing if line.startswith("  ") and line.split()]
    assert sorted(names) == sorted(group.commands)
    for line in listing:
        assert not line.rstrip().endswith("..."), f"summary cut in `trolley {' '.join(path)} --help`: {line}"
        assert len(line.split(None, 1)) == 2, f"no summary in `trolley {' '.join(path)} --help`: {line}"


def test_help_keeps_square_brackets_of_the_toml_tables():
    out = help_80(["project", "new"])
    assert "[site]" in out and "[imu]" in out and "[design]" in out


def test_choices_are_listed_in_the_help():
    assert "<rts|tfs|none>" in help_80(["process"])
    assert "<rlg|fog|mems>" in help_80(["simulate"])
    assert "<rlg|fog|mems|custom>" in help_80(["budget"])
    assert "<kf|ltv|ekf>" in help_80(["tgms", "tune"])
    assert "imu|odometer|gauge|totalstation" in help_80(["devices", "simulate"])


@pytest.mark.parametrize("args", [
    ["process", "nowhere", "--out", "x", "--smoother", "kalman"],
    ["simulate", "--out", "x", "--imu", "laser"],
    ["demo", "--imu", "laser"],
    ["budget", "--imu", "gyroscope"],
    ["project", "new", "p", "--root", "nowhere", "--imu", "laser"],
    ["tgms", "simulate", "--out", "x", "--rail-profile", "UIC99"],
    ["tgms", "process", "nowhere", "--out", "x", "--trajectory", "spline"],
    ["tgms", "tune", "nowhere", "--out", "x", "--box", "huge"],
    ["devices", "simulate", "--device", "radar"],
])
def test_a_value_outside_the_choices_is_refused_with_exit_2(args, tmp_path):
    r = runner.invoke(app, args)
    assert r.exit_code == 2
    assert "is not one of" in r.stderr and "Traceback" not in r.output
    assert not (Path.cwd() / "x").exists()


def test_choice_types_agree_with_the_library():
    from drivers.twins.fleet import DEVICES
    from trolley.sensors import IMU_PRESETS
    assert get_args(ImuPreset) == tuple(IMU_PRESETS)
    assert tuple(d.value for d in Device) == DEVICES


@pytest.mark.parametrize("path, cmd", COMMANDS, ids=[" ".join(p) or "trolley" for p, _ in COMMANDS])
def test_booleans_are_flags(path, cmd):
    for p in cmd.params:
        if getattr(p, "is_flag", False) and p.default is False and not p.hidden:
            assert not p.secondary_opts, f"{p.opts} of `trolley {' '.join(path)}` has an off switch"


# ------------------------------------------------------------------------------ numeric options
# nan, inf and -inf get the finite-number message of survey.limits.check_finite on every float
# option of every command, old names included, and a value out of range its range message
# (typer's own range check answered nan with "Input should be less than or equal to 60",
# `devices simulate --seconds inf` ran until killed, `survey start --speedup inf` ran a session at
# an unbounded clock, and budget, project new and process each had their own wording). No option
# takes inf on purpose (as "no limit"); an option without an upper bound in the table has none in
# the code either.

#: each command's other arguments, chosen so that a run with valid option values stops at once on
#: a later check (exit code, what that check says): no simulation runs and no port is opened.
STOP = {
    "inservice simulate": (lambda t: ["--out", str(t / "mine")], 2, "was not made by"),
    "inservice calibrate": (lambda t: ["--out", str(t)], 2, "is a folder"),
    "inservice process": (lambda t: [str(t / "norec"), "--out", str(t / "o")], 2, "not a folder"),
    "devices probe": (lambda t: [], 2, "the serial port of the total station is required"),
    "devices record": (lambda t: ["--imu-port", str(t / "nodev"), "--seconds", "1", "--out", str(t / "mine")], 2,
                       "was not made by"),
    "devices simulate": (lambda t: ["--out", str(t / "none" / "ports.json"), "--seconds", "0"], 2,
                         "does not exist"),
    "process": (lambda t: [str(t / "nosession"), "--out", str(t / "o")], 2, "no such session folder"),
    "export": (lambda t: [str(t / "notrack"), "--csv", str(t / "o.csv")], 2, "no such file or folder"),
    "compare": (lambda t: [str(t / "notrack"), str(t / "notrack")], 2, "no such file or folder"),
    "simulate": (lambda t: ["--out", str(t / "mine"), "--project", str(DEMO)], 2, "already exists and is not empty"),
    "demo": (lambda t: ["--out", str(t / "afile")], 2, "exists and is not a folder"),
    "budget": (lambda t: ["--imu", "custom"], 2, "--imu custom needs --gyro-arw-deg-sqrt-h"),
    "project new": (lambda t: ["p", "--root", str(t / "afile"), "--no-toml"], 2, "is a file, not a folder of projects"),
    "tgms simulate": (lambda t: ["--out", str(t / "mine")], 2, "was not made by"),
    "tgms process": (lambda t: [str(t / "norec"), "--out", str(t / "o")], 2, "not a folder"),
    "survey start": (lambda t: ["nope", "--root", str(t), "--session", "s", "--simulate"], 2, "no project 'nope'"),
    "survey resume": (lambda t: ["nope", "--root", str(t), "--session", "s", "--simulate"], 2, "no project 'nope'"),
}

#: every float option: (command, option, values that must pass, values refused with their message)
NUMERIC = [
    ("inservice simulate", "--speed-m-s", ["2", "60"], [("1.99", "must be >= 2"), ("60.1", "must be <= 60")]),
    ("inservice simulate", "--length-m", ["10", "20000"], [("9", "must be >= 10"), ("20001", "must be <= 20000")]),
    ("inservice simulate", "--curvature-1-m", ["-0.01", "0.01"], [("-0.011", "must be >= -0.01"),
                                                                   ("0.011", "must be <= 0.01")]),
    ("inservice simulate", "--conicity-factor", ["0.1", "5"], [("0.09", "must be >= 0.1"), ("5.1", "must be <= 5")]),
    ("inservice simulate", "--creep-factor", ["0.05", "5"], [("0.04", "must be >= 0.05"), ("5.1", "must be <= 5")]),
    ("inservice simulate", "--harmonic-wavelength-m", ["1", "1000"], [("0.9", "must be >= 1"),
                                                                       ("1001", "must be <= 1000")]),
    ("inservice simulate", "--harmonic-amplitude-mm", ["0", "20"], [("-0.1", "must be >= 0"),
                                                                     ("20.1", "must be <= 20")]),
    ("inservice simulate", "--rate-hz", ["20", "2000"], [("19", "must be >= 20"), ("2001", "must be <= 2000")]),
    ("inservice process", "--filter-rate-hz", ["20", "5000"], [("19", "must be >= 20"), ("5001", "must be <= 5000")]),
    ("inservice calibrate", "--speed-m-s", ["2", "60"], [("1.99", "must be >= 2"), ("60.1", "must be <= 60")]),
    ("inservice calibrate", "--length-m", ["250", "5000"], [("249", "must be >= 250"), ("5001", "must be <= 5000")]),
    ("inservice calibrate", "--rate-hz", ["20", "2000"], [("19", "must be >= 20"), ("2001", "must be <= 2000")]),
    ("inservice calibrate", "--filter-rate-hz", ["20", "5000"], [("19", "must be >= 20"),
                                                                  ("5001", "must be <= 5000")]),
    ("devices probe", "--timeout-s", ["0.5", "600"], [("0", "must be > 0"), ("601", "must be <= 600")]),
    ("devices record", "--seconds", ["0", "5", "86400"], [("-1", "must be >= 0"), ("86401", "must be <= 86400")]),
    ("devices record", "--imu-rate-hz", ["200", "2000"], [("0", "must be > 0"), ("2001", "must be <= 2000")]),
    ("devices record", "--wheel-diameter-m", ["0.1", "2"], [("0", "must be > 0"), ("2.1", "must be <= 2")]),
    ("devices record", "--odometer-scale", ["1.0001", "0.5", "2"], [("0.4", "must be >= 0.5"),
                                                                   ("2.1", "must be <= 2")]),
    ("devices record", "--odometer-rate-hz", ["100", "1000"], [("99", "must be >= 100"), ("1001", "must be <= 1000")]),
    ("devices simulate", "--seconds", ["0", "1"], [("-1", "must be >= 0"), ("86401", "must be <= 86400")]),
    ("devices simulate", "--imu-rate-hz", ["1", "400"], [("0.5", "must be >= 1"), ("2001", "must be <= 2000")]),
    ("devices simulate", "--gauge-rate-hz", ["1", "100"], [("0.5", "must be >= 1"), ("1001", "must be <= 1000")]),
    ("devices simulate", "--speed-m-s", ["-1", "2", "30"], [("-30.1", "must be >= -30"), ("30.1", "must be <= 30")]),
    ("devices simulate", "--noise-angle-rad", ["0", "1e-5"], [("-1e-5", "must be >= 0"), ("0.011", "must be <= 0.01")]),
    ("devices simulate", "--noise-dist-m", ["0", "0.001"], [("-0.001", "must be >= 0"), ("1.1", "must be <= 1")]),
    *(("devices simulate", opt, ["0", "1"], [("-0.1", "must be >= 0"), ("1.1", "must be <= 1")])
      for opt in ("--corrupt-rate", "--drop-rate", "--garbage-rate", "--delay-rate", "--missing-rate")),
    ("devices simulate", "--delay-s", ["0", "2", "600"], [("-0.5", "must be >= 0"), ("601", "must be <= 600")]),
    ("process", "--step-m", ["0.001", "0.625", "100"], [("0", "must be > 0"), ("-0.625", "must be > 0"),
                                                         ("100.1", "must be <= 100"), ("1e300", "must be <= 100")]),
    *(("export", opt, ["0.5", "3", "100", "1000"], [("0", "must be > 0"), ("-3", "must be > 0"),
                                                    ("1000.1", "must be <= 1000")])
      for opt in ("--twist-base-m", "--chord-m", "--gauge-rate-base-m")),
    ("compare", "--limit", ["0.5", "4", "100"], [("0", "must be > 0"), ("100.1", "must be <= 100")]),
    ("compare", "--max-offset-m", ["0.01", "10"], [("0", "must be > 0"), ("10.1", "must be <= 10")]),
    ("simulate", "--length-m", ["1", "200"], [("0.99", "must be >= 1"), ("0", "must be >= 1")]),
    ("simulate", "--fix-spacing-m", ["10", "60", "1e4"], [("0", "must be > 0"), ("10001", "must be <= 10000")]),
    ("simulate", "--static-s", ["10", "120"], [("-1", "must be >= 0")]),
    ("simulate", "--rate-hz", ["50", "400"], [("0", "must be > 0")]),
    ("simulate", "--truth-step-m", ["0.01", "0.1", "5"], [("0", "must be > 0"), ("5.1", "must be <= 5")]),
    ("simulate", "--site-east-m", ["-1e7", "0", "200000", "1e7"], [("-1.0000001e7", "must be >= -1e+07"),
                                                                    ("1e12", "must be <= 1e+07")]),
    ("demo", "--speedup", ["0.5", "40", "1000"], [("0", "must be > 0"), ("-1", "must be > 0"),
                                                  ("1000.1", "must be <= 1000"), ("1e300", "must be <= 1000")]),
    # budget: the ranges of its error model (survey.commands.budget.RANGES)
    ("budget", "--gyro-bias-deg-h", ["0", "1000"], [("-0.1", "must be >= 0"), ("1000.1", "must be <= 1000")]),
    ("budget", "--gyro-bias-instability-deg-h", ["0", "1000"], [("-0.1", "must be >= 0"),
                                                                ("1000.1", "must be <= 1000")]),
    ("budget", "--gyro-arw-deg-sqrt-h", ["0", "34"], [("-0.1", "must be >= 0"), ("34.1", "must be <= 34")]),
    ("budget", "--heading-error-deg", ["0", "10"], [("-0.1", "must be >= 0"), ("10.1", "must be <= 10")]),
    ("budget", "--level-error-deg", ["0", "10"], [("-0.1", "must be >= 0"), ("10.1", "must be <= 10")]),
    ("budget", "--odo-scale-noise", ["0", "0.01"], [("-1e-6", "must be >= 0"), ("0.0101", "must be <= 0.01")]),
    ("budget", "--odo-scale-error", ["0", "0.01"], [("-1e-6", "must be >= 0"), ("0.0101", "must be <= 0.01")]),
    ("budget", "--fix-spacing-m", ["1", "10000"], [("0.9", "must be >= 1"), ("10001", "must be <= 10000")]),
    ("budget", "--speed-m-s", ["0.01", "30"], [("0", "must be >= 0.01"), ("30.1", "must be <= 30")]),
    ("budget", "--fix-sigma-mm", ["0.001", "1000"], [("0", "must be >= 0.001"), ("1001", "must be <= 1000")]),
    ("budget", "--latitude-deg", ["-85", "85"], [("-85.1", "must be >= -85"), ("85.1", "must be <= 85")]),
    ("budget", "--target-mm", ["0.01", "1000"], [("0", "must be > 0"), ("-1", "must be > 0"),
                                                 ("1000.1", "must be <= 1000")]),
    # the sites project.toml takes (survey.commands.simulate: MAX_LATITUDE_DEG, SITE_HEIGHT_RANGE_M)
    ("project new", "--latitude-deg", ["-85", "0", "85"], [("-85.1", "must be >= -85"), ("85.1", "must be <= 85")]),
    ("project new", "--height-m", ["-1000", "10000"], [("-1000.1", "must be >= -1000"),
                                                       ("10000.1", "must be <= 10000")]),
    ("tgms simulate", "--length-m", ["60", "1000"], [("59", "must be >= 60")]),
    ("tgms simulate", "--speed-m-s", ["1", "40"], [("0.9", "must be >= 1"), ("40.1", "must be <= 40")]),
    ("tgms simulate", "--camera-rate-hz", ["5", "500"], [("4.9", "must be >= 5"), ("500.1", "must be <= 500")]),
    ("tgms process", "--step-m", ["0.01", "0.25", "5"], [("0.009", "must be >= 0.01"), ("5.1", "must be <= 5")]),
    # inf passed `> 0` and the session ran at an unbounded clock
    *((c, "--speedup", ["0.5", "40", "1000"], [("0", "must be > 0"), ("-1", "must be > 0"),
                                                ("1000.1", "must be <= 1000")])
      for c in ("survey start", "survey resume")),
]


#: the hidden old names of float options (docs/conventions.md): (command, old name, new name, a valid
#: value, an out-of-range one and its message); the message names the option as it was typed
OLD_NAMES = [
    ("process", "--step", "--step-m", "1.25", ("0", "must be > 0")),
    ("export", "--twist-base", "--twist-base-m", "3", ("0", "must be > 0")),
    ("export", "--chord", "--chord-m", "10", ("0", "must be > 0")),
    ("export", "--gauge-rate-base", "--gauge-rate-base-m", "3", ("0", "must be > 0")),
    ("tgms process", "--step", "--step-m", "0.5", ("5.1", "must be <= 5")),
    ("project new", "--height", "--height-m", "50", ("-1001", "must be >= -1000")),
]


@pytest.fixture
def stop_dir(tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("not made by trolley\n")
    (tmp_path / "afile").write_text("a file where a folder is needed\n")
    return tmp_path


def run_option(command: str, base: list[str], option: str, value: str):
    r = runner.invoke(app, command.split() + base + [option, value])
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    assert "Traceback" not in r.output and "Input should be" not in r.stderr
    return r, " ".join(r.stderr.split())


def float_options(hidden: bool) -> set[tuple[str, str]]:
    """(command, option) of every float option of every command of the app (typer's tree; typer
    gives ``Optional[float]`` and ``float | None`` as float)."""
    return {(" ".join(path), p.opts[0]) for path, cmd in COMMANDS for p in cmd.params
            if bool(p.hidden) == hidden and getattr(p, "type_descriptor", None) is not None
            and p.type_descriptor.annotation is float}


def test_the_table_holds_every_float_option_of_every_command():
    """A float option added later without its check_finite would be missing here."""
    assert float_options(hidden=False) == {(c, o) for c, o, _, _ in NUMERIC}


def test_the_old_names_table_holds_every_hidden_float_option():
    assert float_options(hidden=True) == {(c, o) for c, o, *_ in OLD_NAMES}


@pytest.mark.parametrize("command, old, new, valid, bad", OLD_NAMES, ids=[f"{c} {o}" for c, o, *_ in OLD_NAMES])
def test_an_old_option_name_gets_the_same_checks_naming_the_old_name(command, old, new, valid, bad, stop_dir):
    make, code, says = STOP[command]
    for value in ("nan", "inf", "-inf"):
        r, err = run_option(command, make(stop_dir), old, value)
        assert r.exit_code == 2 and err == f"error: {old}: must be a finite number, got {value}", err
    value, message = bad
    r, err = run_option(command, make(stop_dir), old, value)
    assert r.exit_code == 2 and err.startswith(f"error: {old}: {message}, got "), err
    r, err = run_option(command, make(stop_dir), old, valid)
    assert r.exit_code == code and says in err, err


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
@pytest.mark.parametrize("command, option", [(c, o) for c, o, _, _ in NUMERIC],
                         ids=[f"{c} {o}" for c, o, _, _ in NUMERIC])
def test_a_float_option_that_is_not_finite_gets_the_finite_number_message(command, option, value, stop_dir):
    r, err = run_option(command, STOP[command][0](stop_dir), option, value)
    assert r.exit_code == 2
    assert err == f"error: {option}: must be a finite number, got {value}"


@pytest.mark.parametrize("command, option, values", [(c, o, v) for c, o, v, _ in NUMERIC],
                         ids=[f"{c} {o}" for c, o, _, _ in NUMERIC])
def test_valid_float_values_pass_the_option_checks(command, option, values, stop_dir):
    make, code, says = STOP[command]
    for value in values:
        r, err = run_option(command, make(stop_dir), option, value)
        assert r.exit_code == code and says in err and f"{option}:" not in err, (value, err)


@pytest.mark.parametrize("command, option, bad", [(c, o, b) for c, o, _, b in NUMERIC if b],
                         ids=[f"{c} {o}" for c, o, _, b in NUMERIC if b])
def test_a_float_option_out_of_its_range_is_refused_naming_it(command, option, bad, stop_dir):
    for value, says in bad:
        r, err = run_option(command, STOP[command][0](stop_dir), option, value)
        assert r.exit_code == 2 and err.startswith(f"error: {option}: {says}, got "), (value, err)


def test_a_resume_refuses_a_stored_speedup_that_is_not_finite(tmp_path):
    # a session started with --speedup inf before the option was checked holds inf in its start
    # event; a resume without --speedup takes it from there
    from survey.store import ProjectStore, SessionEvent

    assert runner.invoke(app, ["project", "new", "p", "--root", str(tmp_path), "--no-toml"]).exit_code == 0
    with ProjectStore.open_project(tmp_path, "p") as store:
        rec = store.create_session("s")
        store.add_event(rec.session_id, SessionEvent(0.0, "start", json.dumps(
            {"simulate": True, "speedup": math.inf, "script": None, "devices": None, "out": "sessions/s"})))
    r = runner.invoke(app, ["survey", "resume", "p", "--root", str(tmp_path), "--session", "s"])
    assert r.exit_code == 2
    assert "error: session s: its start event holds --speedup inf, not a finite number > 0" in r.stderr
    assert "try: give --speedup" in r.stderr


@pytest.mark.parametrize("kwargs, value, message", [
    # %g would print 5.0000001 as 5: "must be <= 5, got 5" contradicts itself
    ({"maximum": 5.0}, 5.0000001, "--x: must be <= 5, got 5.0000001"),
    ({"minimum": -85.0}, -85.00001, "--x: must be >= -85, got -85.00001"),
    ({"minimum": 2.0}, 1.5, "--x: must be >= 2, got 1.5"),
    ({"positive": True}, 0.0, "--x: must be > 0, got 0"),
    ({"maximum": 1e7}, 1e12, "--x: must be <= 1e+07, got 1e+12"),
    ({"maximum": 85.0, "why": "no gyrocompassing near the poles"}, 86.0,
     "--x: must be <= 85, got 86 (no gyrocompassing near the poles)"),
    # the reason is for the range: the finite-number message stays the same on every option
    ({"maximum": 85.0, "why": "no gyrocompassing near the poles"}, math.inf, "--x: must be a finite number, got inf"),
])
def test_check_finite_messages(kwargs, value, message):
    from survey.limits import check_finite

    with pytest.raises(ValueError) as exc:
        check_finite(value, "--x", **kwargs)
    assert str(exc.value) == message


@pytest.mark.parametrize("kwargs, value, message", [
    # every digit, not %g's 1e+12; an integer beyond a float's range is compared as it is
    ({"maximum": 1_000_000}, 10**12, "--x: must be <= 1000000, got 1000000000000"),
    ({"maximum": 5}, 10**400, f"--x: must be <= 5, got {10**400}"),
    ({"minimum": 50, "maximum": 4_000_000, "why": "a reason"}, 0, "--x: must be >= 50, got 0 (a reason)"),
])
def test_check_integer_messages(kwargs, value, message):
    from survey.limits import check_integer

    with pytest.raises(ValueError) as exc:
        check_integer(value, "--x", **kwargs)
    assert str(exc.value) == message
    check_integer(kwargs.get("minimum", 0), "--x", **kwargs)       # the limits themselves pass


@pytest.mark.parametrize("option, value, bad", [("--station", "0,0,nan,1.5", "nan"),
                                                ("--target", "10,inf,0.5", "inf"), ("--target", "-inf,20,0.5", "-inf")])
def test_a_coordinate_that_is_not_finite_gets_the_finite_number_message(option, value, bad):
    r, err = run_option("devices simulate", ["--seconds", "0"], option, value)
    assert r.exit_code == 2
    assert err == f"error: {option}: must be a finite number, got {bad}"


# ---------------------------------------------------------------------------------------- JSON

def test_json_writer_hand_cases():
    doc = {"a": float("nan"), "b": [1.5, float("inf"), -float("inf")], "c": np.array([1.0, np.nan]),
           "d": np.float32(2.5), "e": np.int64(7), "f": np.bool_(True), "g": Path("x/y.csv"), 3: None}
    assert strict_json(jsonout.dumps(doc)) == {"a": None, "b": [1.5, None, None], "c": [1.0, None],
                                               "d": 2.5, "e": 7, "f": True, "g": "x/y.csv", "3": None}
    with pytest.raises(TypeError):
        jsonout.dumps({"x": object()})


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=True, allow_infinity=True) | st.text(),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner, max_size=4),
    max_leaves=20)


@given(json_values)
def test_json_writer_is_always_valid_and_keeps_finite_values(x):
    back = strict_json(jsonout.dumps(x))

    def expected(v):
        if isinstance(v, float):
            return v if math.isfinite(v) else None
        if isinstance(v, list):
            return [expected(u) for u in v]
        if isinstance(v, dict):
            return {k: expected(u) for k, u in v.items()}
        return v
    assert back == expected(x)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "session"
    r = runner.invoke(app, ["simulate", "--out", str(out), "--project", str(DEMO), "--length-m", "120",
                            "--static-s", "60", "--rate-hz", "100", "--seed", "5", "--json"])
    assert r.exit_code == 0, r.output
    assert strict_json(r.stdout)["out"] == str(out)
    return out


@pytest.fixture(scope="module")
def processed(session, tmp_path_factory):
    out = tmp_path_factory.mktemp("proc") / "processed"
    r = runner.invoke(app, ["process", str(session), "--out", str(out), "--json"])
    assert r.exit_code == 0, r.output
    return out, strict_json(r.stdout)


def test_process_json_is_the_summary_and_nothing_else(processed):
    out, doc = processed
    assert Path(doc["track_csv"]) == out / "track.csv" and (out / "track.csv").is_file()
    on_disk = json.loads((out / "summary.json").read_text())
    for key in ("fixes_used", "fixes_rejected", "stations", "step_m", "smoother"):
        assert doc[key] == on_disk[key]
    assert doc["observability_ranks"] is None and doc["rejected_fixes"] == []


def test_export_and_project_commands_print_strict_json(processed, tmp_path):
    out, _ = processed
    r = runner.invoke(app, ["export", str(out), "--json"])
    assert r.exit_code == 0, r.output
    assert strict_json(r.stdout)["stations"] > 0
    root = tmp_path / "projects"
    r = runner.invoke(app, ["project", "new", "p", "--root", str(root), "--json"])
    assert r.exit_code == 0, r.output
    assert strict_json(r.stdout)["store"] == str(root / "p" / "project.sqlite")
    r = runner.invoke(app, ["project", "import-cpiii", str(DEMO / "cpiii.csv"), "-p", "p", "--root", str(root),
                            "--json"])
    assert r.exit_code == 0, r.output
    added = strict_json(r.stdout)["added"]
    r = runner.invoke(app, ["project", "show", "p", "--root", str(root), "--json"])
    assert strict_json(r.stdout)["cpiii"]["count"] == added > 0
    r = runner.invoke(app, ["project", "set", "crew", "A. Smith", "-p", "p", "--root", str(root), "--json"])
    assert r.exit_code == 0, r.output
    assert strict_json(r.stdout)["value"] == "A. Smith"


def test_tgms_json_is_strict_where_the_accuracy_has_no_value(tmp_path):
    rec = tmp_path / "rec"
    r = runner.invoke(app, ["tgms", "simulate", "--out", str(rec), "--length-m", "60", "--camera-rate-hz", "10",
                            "--json"])
    assert r.exit_code == 0, r.output
    assert strict_json(r.stdout)["frames"] > 0
    r = runner.invoke(app, ["tgms", "process", str(rec), "--out", str(tmp_path / "out"), "--no-plots", "--json"])
    assert r.exit_code == 0, r.output
    doc = strict_json(r.stdout)  # a 60 m ride leaves accuracy figures undefined (NaN before issue 15)

    def nulls(v):
        if isinstance(v, dict):
            return sum(nulls(u) for u in v.values())
        if isinstance(v, list):
            return sum(nulls(u) for u in v)
        return v is None
    assert nulls(doc["accuracy_3_25m"]) > 0


def test_survey_start_json_is_the_final_summary_alone(tmp_path):
    sys.path.insert(0, str(Path(__file__).parent))
    from session_project import make_project

    make_project(tmp_path / "projects")
    (tmp_path / "crew.txt").write_text("fix\nmove\nfix\nmove\nfix\nend\n")
    p = subprocess.run([sys.executable, "-m", "survey.cli", "survey", "start", "t1", "--root", "projects",
                        "--session", "s", "--simulate", "--speedup", "25", "--script", "crew.txt", "--json"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    doc = strict_json(p.stdout)
    assert doc["session"] == "s" and doc["fixes_accepted"] >= 2
    assert (tmp_path / doc["track_csv"]).is_file() and (tmp_path / doc["xlsx"]).is_file()  # relative to cwd


# --------------------------------------------------------------------------------- old names

def test_old_option_names_still_work_and_are_the_same_option(session, processed, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    r1 = runner.invoke(app, ["process", str(session), "--out", str(a), "--step", "2.5", "--json"])
    r2 = runner.invoke(app, ["process", str(session), "--out", str(b), "--step-m", "2.5", "--json"])
    assert r1.exit_code == r2.exit_code == 0
    assert strict_json(r1.stdout)["step_m"] == strict_json(r2.stdout)["step_m"] == 2.5
    assert (a / "track.csv").read_bytes() == (b / "track.csv").read_bytes()
    out, _ = processed
    csvs = {}
    for name, args in (("old", ["--chord", "20"]), ("new", ["--chord-m", "20"]), ("default", [])):
        csvs[name] = tmp_path / f"{name}.csv"
        r = runner.invoke(app, ["export", str(out), "--csv", str(csvs[name]), *args])
        assert r.exit_code in (0, 1), r.output
    assert csvs["old"].read_bytes() == csvs["new"].read_bytes() != csvs["default"].read_bytes()


def test_old_and_new_name_with_different_values_is_refused(session, tmp_path):
    r = runner.invoke(app, ["process", str(session), "--out", str(tmp_path / "o"), "--step", "1", "--step-m", "2"])
    assert r.exit_code == 2 and "--step-m" in r.stderr
    assert not (tmp_path / "o").exists()
    # the new name typed with its default value counts too (bug hunt 2026-11-26: 1.25 was used)
    r = runner.invoke(app, ["process", str(session), "--out", str(tmp_path / "o"), "--step", "1.25", "--step-m",
                            "0.625"])
    assert r.exit_code == 2 and "give --step-m only" in r.stderr
    assert not (tmp_path / "o").exists()


def test_renamed_hand_cases():
    assert renamed(0.625, None, "--step-m", "--step", 0.625) == 0.625
    assert renamed(0.625, 2.0, "--step-m", "--step", 0.625) == 2.0
    assert renamed(2.0, 2.0, "--step-m", "--step", 0.625) == 2.0
    with pytest.raises(typer.BadParameter):
        renamed(1.0, 2.0, "--step-m", "--step", 0.625)


# ---------------------------------------------------------------------------------- progress

def test_progress_share_maps_a_sub_step_onto_its_part_of_the_bar():
    seen = []
    sub = share(lambda step, f: seen.append((step, f)), 0.15, 0.95)
    sub("filter", 0.0)
    sub("filter", 0.5)
    sub("filter", 1.0)
    assert seen == [("filter", 0.15), ("filter", pytest.approx(0.55)), ("filter", pytest.approx(0.95))]
    assert share(None, 0.0, 1.0) is None


def test_an_error_under_a_progress_bar_is_one_line_when_stderr_is_no_terminal(tmp_path):
    # rich's bar printed an empty line above the error when it stopped on a pipe or a file
    import io

    from rich.console import Console

    from survey.commands.progress import progress_bar

    r = runner.invoke(app, ["export", str(tmp_path / "notrack"), "--csv", str(tmp_path / "o.csv")])
    assert r.exit_code == 2 and r.stderr == f"error: {tmp_path / 'notrack'}: no such file or folder\n", r.stderr
    for interactive in (False, True):
        out = io.StringIO()
        with progress_bar("reading", Console(file=out, force_terminal=interactive, force_interactive=interactive,
                                             width=100)) as report:
            report("computing", 0.5)
        # a terminal still gets its bar (transient: drawn, then cursor moves wipe it)
        assert ("computing" in out.getvalue()) == interactive and (out.getvalue() == "") != interactive, out.getvalue()


def test_monte_carlo_progress_rises_to_one_and_leaves_the_draws_alone():
    from trolley import budget as B
    from trolley.sensors import IMU_PRESETS
    from trolley.budget import SensorFigures
    figs = SensorFigures(gyro_bias_instability_rad_s=IMU_PRESETS["rlg"].gyro_bias_instability_rad_s,
                         gyro_arw_rad_sqrt_s=IMU_PRESETS["rlg"].gyro_arw_rad_sqrt_s, heading_error_rad=None,
                         level_error_rad=1e-4, fix_spacing_m=60.0, speed_m_s=1.0, fix_sigma_m=6e-4,
                         latitude_rad=0.5, gyrocompassing=True)
    case = B.resolve_case(figs).case
    seen = []
    memory = 8 * 61 * 40 * 7  # a few runs a block: several blocks
    with_bar = B.monte_carlo(case, 50, seed=3, memory_bytes=memory, progress=lambda s, f: seen.append(f))
    without = B.monte_carlo(case, 50, seed=3, memory_bytes=memory)
    assert with_bar.block_runs < 50
    for d in B.DIRECTIONS:
        np.testing.assert_array_equal(with_bar.rms_m[d], without.rms_m[d])
    assert np.all(np.diff(seen) >= 0) and seen[-1] == pytest.approx(1.0) and seen[0] < 0.5
    assert len(seen) == 6 * int(np.ceil(50 / with_bar.block_runs))


# ----------------------------------------------------------------------------- python-control

CHECK = """
import sys
from typer.testing import CliRunner
from survey.cli import app
r = CliRunner().invoke(app, sys.argv[1:])
assert r.exit_code == 0, r.output
print("control" in sys.modules)
"""


@pytest.mark.parametrize("extra, imported", [([], "False"), (["--observability"], "True")])
def test_control_is_imported_only_for_observability(session, tmp_path, extra, imported):
    p = subprocess.run([sys.executable, "-c", CHECK, "process", str(session), "--out", str(tmp_path / "o"),
                        "--json", *extra], capture_output=True, text=True, cwd=REPO)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip().splitlines()[-1] == imported


# ------------------------------------------------------------------- integer ranges, demo --out

#: integer options with a range: (command, option, values that must pass, values refused with
#: their message). A seed is written into project.toml / session.toml, the project store and the
#: simulators' JSON summaries, 64-bit integers all (inservice, tgms and devices answered -1 with
#: numpy's "expected non-negative integer", naming no option, and took 10^24). A line speed or
#: an encoder's pulses per revolution had no bound at all (--baud 0 is termios' B0, which hangs
#: the line up; --baud 10^12 overflowed pyserial's ioctl; --odometer-ppr 10^12 was taken).
SEED_LIMIT = [("-3", "must be >= 0"), (str(2**63), f"must be <= {2**63 - 1}")]
BAUD_WHY = "(the serial line speeds are 50 to 4000000 baud)"
INTEGERS = [
    *((c, "--seed", [], SEED_LIMIT)
      for c in ("simulate", "demo", "budget", "inservice simulate", "tgms simulate", "devices simulate")),
    ("simulate", "--track-seed", [], SEED_LIMIT),
    # its --extra-runs (3) take the seeds up to SEED+3 into the summary
    ("inservice calibrate", "--seed", [str(2**63 - 4)], [*SEED_LIMIT, (str(2**63 - 3), f"must be <= {2**63 - 4}")]),
    ("devices probe", "--baud", ["4000000"], [("0", "must be >= 50"), (str(10**12), "must be <= 4000000")]),
    ("devices record", "--imu-baud", ["4000000"], [("4000001", "must be <= 4000000")]),
    ("devices record", "--odometer-baud", [], [("49", "must be >= 50")]),
    ("devices record", "--gauge-baud", [], [("0", "must be >= 50")]),
    ("devices record", "--odometer-ppr", ["1000000"], [("0", "must be >= 1"), (str(10**12), "must be <= 1000000")]),
    ("devices record", "--odometer-decode", [], [("3", "must be 1, 2 or 4")]),
    ("devices record", "--odometer-bits", [], [("12", "must be 8, 16, 24 or 32")]),
]

#: integer options whose range is checked elsewhere: typer's min=/max= (an integer is never nan),
#: budget's own --monte-carlo check, the IMU types of NovAtel's scale table (a one-line error
#: listing the known types)
INTEGERS_ELSEWHERE = {("budget", "--monte-carlo"), ("devices record", "--imu-type"), ("devices simulate", "--imu-type"),
                      ("tgms tune", "--evaluations"), ("tgms tune", "--seed"), ("inservice calibrate", "--extra-runs")}


def test_the_integer_tables_hold_every_integer_option():
    """An integer option added later without its range would be missing here."""
    ints = {(" ".join(path), p.opts[0]) for path, cmd in COMMANDS for p in cmd.params
            if getattr(p, "type_descriptor", None) is not None and p.type_descriptor.annotation is int}
    assert ints == {(c, o) for c, o, _, _ in INTEGERS} | INTEGERS_ELSEWHERE


@pytest.mark.parametrize("command, option, valid, bad", INTEGERS, ids=[f"{c} {o}" for c, o, *_ in INTEGERS])
def test_an_integer_option_out_of_its_range_is_one_line_naming_it(command, option, valid, bad, stop_dir):
    # demo --seed -3 printed typer's usage text above the error (a BadParameter)
    make, code, says = STOP[command]
    for value, message in bad:
        r, _ = run_option(command, make(stop_dir), option, value)
        assert r.exit_code == 2 and r.stderr.startswith(f"error: {option}: {message}, got {value}"), r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and "Usage" not in r.stderr, r.stderr
        assert "baud" not in option or r.stderr.rstrip().endswith(BAUD_WHY), r.stderr
    # the largest values pass the option checks and the command stops at its later check
    for value in valid:
        r, err = run_option(command, make(stop_dir), option, value)
        assert r.exit_code == code and says in err and f"{option}:" not in err, (value, err)


def test_demo_out_is_refused_in_one_line_unless_empty_new_or_the_demos_own(tmp_path, monkeypatch):
    import survey.commands.demo as demo_cmd

    calls = []
    monkeypatch.setattr(demo_cmd, "demo_session", lambda project, out, imu, seed, *a, **k: calls.append((out, seed)) or {})
    # a file, and a folder of the user's with a survey.xlsx and a session/ the demo would have replaced
    (tmp_path / "afile").write_text("x")
    mine = tmp_path / "mine"
    (mine / "session").mkdir(parents=True)
    (mine / "survey.xlsx").write_text("the user's sheet")
    (mine / "session" / "notes.txt").write_text("the user's notes")
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "notes.txt").write_text("the user's notes")
    for out, says in ((tmp_path / "afile", "exists and is not a folder"),
                      (mine, f"{mine / 'session'} exists and was not made by `trolley demo`"),
                      (tmp_path / "notes", "exists, is not empty and was not made by `trolley demo`")):
        r = runner.invoke(app, ["demo", "--out", str(out)])
        assert r.exit_code == 2 and r.stderr.startswith(f"error: --out {out}: {says}"), r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and "Usage" not in r.stderr, r.stderr
    assert sorted(p.name for p in mine.rglob("*")) == ["notes.txt", "session", "survey.xlsx"] and not calls
    # a new folder and a demo output from before the marker on OUT (its marked project store) are the demo's:
    # marked before the run, default seed None (the project's: the demo stays deterministic)
    old = tmp_path / "old"
    (old / "project" / "demo").mkdir(parents=True)
    (old / "project" / ".made-by-trolley").write_text("demo\n")
    (old / "survey.xlsx").write_text("an old demo's sheet")
    for out in (tmp_path / "new", old, tmp_path / "new"):
        r = runner.invoke(app, ["demo", "--out", str(out)])
        assert r.exit_code == 0, r.stderr
        assert (out / ".made-by-trolley").read_text() == "demo\n"
    assert calls == [(tmp_path / "new", None), (old, None), (tmp_path / "new", None)]


# ---------------------------------------------------------------------- click's usage errors
# a value typer cannot read, an unknown option, a missing argument or option printed click's usage
# block and "Error: Invalid value for '--seed': Input should be a valid integer, unable to parse
# string as an integer", naming no value; now one line as every bad input (survey.errors)

@pytest.mark.parametrize("args, line", [
    (["budget", "--seed", "abc"], "error: --seed: must be an integer, got 'abc'"),
    (["budget", "--json", "--speed-m-s", "fast"], "error: --speed-m-s: must be a number, got 'fast'"),
    (["budget", "--sed", "3"], "error: --sed: no such option (possible options: --seed, --speed-m-s)"),
    (["project", "set"], "error: KEY: required argument not given"),
    (["process", "nowhere", "--json"], "error: --out: required option not given"),
    # typer's own min=/max= got pydantic's "Input should be greater than or equal to 10"
    (["tgms", "tune", "nowhere", "--out", "x.toml", "--evaluations", "5"],
     "error: --evaluations: must be >= 10, got 5"),
], ids=["int", "float-json", "unknown-option", "missing-argument", "missing-option", "typer-min"])
def test_a_click_usage_error_is_one_line_naming_the_option(args, line):
    r = runner.invoke(app, args)
    assert r.exit_code == 2 and r.stderr == line + "\n", r.stderr
    assert r.stdout == "" and "Usage" not in r.output and "Traceback" not in r.output


def test_help_is_still_click_help():
    r = runner.invoke(app, ["budget", "--help"])
    assert r.exit_code == 0 and r.stdout.startswith("Usage: trolley budget [OPTIONS]") and "--seed" in r.stdout
    r = runner.invoke(app, [])          # no command: the command list, as before (click: exit code 2)
    assert r.exit_code == 2 and "Commands:" in r.output and "budget" in r.output and "error" not in r.output


# ---------------------------------------------------------------------------- file names
# an output file's name ends in its format's suffix: `export --xlsx x.csv` wrote an Excel workbook
# named x.csv (survey.atomicwrite.check_suffix), refused before the inputs are even looked at

#: (command, option, suffix, the file it writes)
SUFFIXES = [
    ("export", "--xlsx", ".xlsx", "an Excel workbook"),
    ("export", "--pdf", ".pdf", "a PDF report"),
    ("export", "--csv", ".csv", "a CSV table"),
    ("compare", "--csv", ".csv", "a CSV table"),
    ("compare", "--plot", ".png", "a PNG image"),
]


@pytest.mark.parametrize("command, option, suffix, what", SUFFIXES, ids=[f"{c} {o}" for c, o, *_ in SUFFIXES])
def test_an_output_file_whose_name_lacks_its_formats_suffix_is_refused_first(command, option, suffix, what,
                                                                             stop_dir):
    make, code, says = STOP[command]
    for name, fixed in (("x.txt", "x" + suffix), ("x", "x" + suffix), ("x" + suffix + ".bak", "x" + suffix)):
        value = str(stop_dir / name)
        r, err = run_option(command, make(stop_dir), option, value)
        assert r.exit_code == 2 and r.stderr == (f"error: {option} {value}: the file name must end in {suffix} "
                                                 f"({what}; did you mean {stop_dir / fixed}?)\n"), r.stderr
    # the suffix in any case passes, and the command stops at its later check
    for name in ("x" + suffix, "x" + suffix.upper()):
        r, err = run_option(command, make(stop_dir), option, str(stop_dir / name))
        assert r.exit_code == code and says in err and "must end in" not in err, err
    assert sorted(p.name for p in stop_dir.iterdir()) == ["afile", "mine"]


# ---------------------------------------------------------------------------- file options
# an option that reads one file names itself when the file is missing or is a folder
# (survey.limits.check_file_option), before anything else is read: `survey start --script
# nosuch.txt` printed "[Errno 2] No such file or directory: 'nosuch.txt'", `tgms process --params
# /tmp` "/tmp: cannot read parameters ([Errno 21] Is a directory: '/tmp')", `--vehicle
# nosuch.toml` "nosuch.toml: file not found in ."

#: every option that reads one file: (command, option, what the folder message says it wants)
FILE_OPTIONS = [
    ("export", "--design", "a LandXML design file"),
    ("tgms process", "--params", "a parameter file"),
    ("survey start", "--script", "a script file"),
    ("survey start", "--devices", "a devices file"),
    ("survey resume", "--script", "a script file"),
    ("survey resume", "--devices", "a devices file"),
    ("inservice simulate", "--vehicle", "a vehicle file"),
    ("inservice calibrate", "--vehicle", "a vehicle file"),
    ("inservice process", "--truth", "a truth file"),
    ("inservice process", "--model", "a model file"),
]

#: every other option of type Path: what it writes, or a folder it reads
OTHER_PATH_OPTIONS = {
    *((c, "--out") for c in ("process", "simulate", "demo", "devices record", "devices simulate",
                             "project export-session", "tgms simulate", "tgms process", "tgms tune", "survey start",
                             "survey resume", "inservice simulate", "inservice vehicle", "inservice process",
                             "inservice calibrate")),
    ("export", "--xlsx"), ("export", "--pdf"), ("export", "--csv"), ("export", "--plots"), ("compare", "--csv"),
    ("compare", "--plot"), ("budget", "--plots"), ("budget", "--plot"), ("devices simulate", "--link-dir"),
    # folders read
    ("simulate", "--project"), ("devices simulate", "--session-dir"), ("devices simulate", "--session"),
    *((c, "--root") for c in ("project new", "project import-cpiii", "project import-alignment",
                              "project import-session", "project export-session", "project set-crs", "project set",
                              "project show", "survey start", "survey resume")),
}


def test_every_path_option_is_a_file_read_in_the_table_or_known_not_to_be():
    """A Path option added later must be placed: when it reads one file, the test below feeds it
    a missing file and a folder."""
    paths = {(" ".join(path), p.opts[0]) for path, cmd in COMMANDS for p in cmd.params
             if p.param_type_name == "option" and getattr(p, "type_descriptor", None) is not None
             and Path in (p.type_descriptor.annotation, *get_args(p.type_descriptor.annotation))}
    files = {(c, o) for c, o, _ in FILE_OPTIONS}
    assert not files & OTHER_PATH_OPTIONS
    assert paths == files | OTHER_PATH_OPTIONS


@pytest.mark.parametrize("command, option, what", FILE_OPTIONS, ids=[f"{c} {o}" for c, o, _ in FILE_OPTIONS])
def test_a_file_option_given_a_missing_file_or_a_folder_names_itself_first(command, option, what, stop_dir):
    make, code, says = STOP[command]
    missing, folder = stop_dir / "nosuch.txt", stop_dir / "mine"
    r, _ = run_option(command, make(stop_dir), option, str(missing))
    assert r.exit_code == 2 and r.stderr == f"error: {option} {missing}: no such file\n", r.stderr
    r, _ = run_option(command, make(stop_dir), option, str(folder))
    assert r.exit_code == 2 and r.stderr.startswith(f"error: {option} {folder}: is a folder, not {what}"), r.stderr
    assert len(r.stderr.splitlines()) == 1, r.stderr
    assert sorted(p.name for p in stop_dir.iterdir()) == ["afile", "mine"]
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt"]


def test_a_resume_names_the_file_its_start_named_when_it_has_gone(tmp_path):
    # a resume without --script/--devices takes the start's, which may have moved since
    from survey.store import ProjectStore, SessionEvent

    with ProjectStore.create(tmp_path, "p") as store:
        rec = store.create_session("s")
        store.add_event(rec.session_id, SessionEvent(0.0, "start", json.dumps({
            "simulate": False, "speedup": 1.0, "script": str(tmp_path / "gone.txt"),
            "devices": str(tmp_path / "PORTS.json"), "out": "sessions/s"})))
    (tmp_path / "PORTS.json").write_text("{}")
    r = runner.invoke(app, ["survey", "resume", "p", "--root", str(tmp_path), "--session", "s"])
    assert r.exit_code == 2 and r.stderr.splitlines() == [
        f"error: --script {tmp_path / 'gone.txt'}: no such file (the file the session started with)",
        "  try: give the option with the file's new place"], r.stderr


"""Resource limits, checked before anything is allocated (issue 12; DESIGN.md "bad input").

A parameter such as ``--step 1e-7`` or ``--rate-hz 1e7`` asks for arrays larger than the
machine's memory; numpy would try, swap the machine to a halt or die with a MemoryError deep
inside the science code. The commands estimate the size first and refuse with the option's
name. No paper section: this is input handling at the application's edge.
"""
from __future__ import annotations

import math
import os

#: Share of the physical memory one command may plan to use.
MEMORY_SHARE = 0.5


def physical_memory_bytes() -> int:
    """Physical memory of the machine, bytes (8 GiB when the system does not say)."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def check_allocation(count: float, bytes_each: float, what: str, advice: str = "choose a coarser value") -> None:
    """Refuse a planned allocation larger than :data:`MEMORY_SHARE` of the physical memory.

    Parameters
    ----------
    count : number of items (samples, stations, ...) the parameters ask for; may be inf or nan.
    bytes_each : memory one item needs through the computation, bytes (an estimate).
    what : what the user set, for the message (e.g. ``"--step 1e-07 over 120 m"``).
    advice : what to do instead, the message's end.

    Raises
    ------
    ValueError
        naming ``what``, the number of items and the memory they would need.
    """
    limit = MEMORY_SHARE * physical_memory_bytes()
    if not math.isfinite(count) or count * bytes_each > limit:
        need = "an unbounded amount" if not math.isfinite(count) else f"{count * bytes_each / 1e9:.3g} GB"
        n = "unbounded" if not math.isfinite(count) else f"{count:.3g}"
        raise ValueError(f"{what}: asks for {n} items, {need} of memory, more than this machine can give "
                         f"({limit / 1e9:.3g} GB); {advice}")


def shown(value: float) -> str:
    """``value`` as ``%g`` when that is the value itself, else with all its digits: "must be <= 5,
    got 5" for 5.0000001 would read as a contradiction."""
    short = f"{value:g}"
    return short if float(short) == value else repr(float(value))


def check_finite(value: float | None, option: str, *, positive: bool = False, minimum: float | None = None,
                 maximum: float | None = None, why: str = "") -> None:
    """Refuse nan, inf and (optionally) non-positive, too small or too large option values.

    (A typer ``min=``/``max=`` range would answer nan with "Input should be greater than or equal
    to ..."; check the range here, after the finiteness.) ``why``, when given, follows a range
    message in parentheses (``--latitude-deg: must be <= 85, got 86 (no gyrocompassing near the
    poles)``); the finite-number message is the same for every option.

    Raises
    ------
    ValueError
        ``<option>: must be a finite number, got nan`` or ``<option>: must be >= 1, got 0.5``.
    """
    if value is None:
        return
    if not math.isfinite(value):
        raise ValueError(f"{option}: must be a finite number, got {value}")
    reason = f" ({why})" if why else ""
    if positive and not value > 0:
        raise ValueError(f"{option}: must be > 0, got {shown(value)}{reason}")
    if minimum is not None and value < minimum:
        raise ValueError(f"{option}: must be >= {minimum:g}, got {shown(value)}{reason}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{option}: must be <= {maximum:g}, got {shown(value)}{reason}")


#: The largest seed: a TOML integer (project.toml, session.toml hold the seed) and an SQLite
#: INTEGER are 64-bit signed; a larger one was taken by numpy and then written where no TOML
#: reader or project store could read it back.
MAX_SEED = 2**63 - 1


def check_integer(value: int | None, option: str, *, minimum: int | None = None, maximum: int | None = None,
                  why: str = "") -> None:
    """Refuse an integer option value below ``minimum`` or above ``maximum``, with the messages of
    :func:`check_finite` and every number with all its digits (``--odometer-ppr: must be <=
    1000000, got 1000000000000 (...)``; ``%g`` would print 1e+12, and an integer beyond a float's
    range, 10**400, is compared as it is).

    Raises
    ------
    ValueError
    """
    if value is None:
        return
    reason = f" ({why})" if why else ""
    if minimum is not None and value < minimum:
        raise ValueError(f"{option}: must be >= {minimum}, got {value}{reason}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{option}: must be <= {maximum}, got {value}{reason}")


def check_seed(value: int | None, option: str = "--seed") -> None:
    """Refuse a negative seed or one above :data:`MAX_SEED`, with the messages of
    :func:`check_integer` (``--seed: must be >= 0, got -3``).

    Raises
    ------
    ValueError
    """
    check_integer(value, option, minimum=0)
    check_integer(value, option, maximum=MAX_SEED, why="a seed is a 64-bit integer in project.toml, session.toml, "
                                                       "the project store and the simulators' summaries")


def check_file_option(path: os.PathLike | str | None, option: str, what: str, usual_name: str,
                      made_by: str = "") -> None:
    """Refuse a missing file or a folder given to an option that reads one file, naming the
    option: the readers' own messages named neither the option nor, at times, what was wrong
    ("sim: file not found in /tmp", "/tmp/sim: Is a directory", "[Errno 2] No such file or
    directory: 'nosuch.txt'").

    Parameters
    ----------
    path : the option's value (None: not given).
    option : the option's name (``--model``).
    what : the file it wants, for the message (``a model file``).
    usual_name : the file's usual name: when the folder holds one, the message proposes it.
    made_by : what writes such a file, for the message when the folder holds none.

    Raises
    ------
    ValueError
        ``--model runs/a: is a folder, not a model file (did you mean runs/a/model.toml?)``,
        ``--script nosuch.txt: no such file``.
    """
    if path is None:
        return
    if os.path.isdir(path):
        inner = os.path.join(path, usual_name)
        hint = f"did you mean {inner}?" if os.path.isfile(inner) else made_by
        raise ValueError(f"{option} {path}: is a folder, not {what}" + (f" ({hint})" if hint else ""))
    if not os.path.exists(path):          # (a link to nothing too)
        raise ValueError(f"{option} {path}: no such file")
    # (an unreadable file is typer's: its Path type says "--params: path 'p.toml' is not readable")


def refuse_unknown(table: dict, known, where: str, fname: str, error: type[ValueError] = ValueError,
                   qualify: bool = True, otherwise: str = "") -> None:
    """A mistyped key would be read as absent (an optional one silently so): refused, with the
    nearest known key (``where.key`` when ``qualify``), else ``otherwise`` as the hint. ``where``
    is the table ("" at the top level); ``error`` names the file's own error type. The TOML files
    of the in-service vehicle, recording and model and of a TGMS recording use it."""
    import difflib

    for key in table:
        if key not in known:
            near = difflib.get_close_matches(key, sorted(known), n=1)
            dotted = f"{where}." if where else ""
            hint = f" (did you mean {dotted if qualify else ''}{near[0]}?)" if near else otherwise
            raise error(f"{fname}: unknown key {dotted}{key}{hint}")

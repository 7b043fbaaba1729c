"""The crew's actions as a script: a small line format that drives a field session without a keyboard.

One action per line; ``#`` starts a comment; blank lines are skipped. Times are in seconds of
session time (in a simulated session they pass ``--speedup`` times faster than the wall clock).

=================  ============================================================================
``wait S``         let ``S`` seconds of session time pass
``move``           the crew pushes the trolley to the next stop: wait until it moves, then until
                   it stands still again
``stop``           wait until the trolley stands still
``fix``            take a prism fix (the total station locks on the prism with ATR and measures)
``accept``         accept the last fix although its innovation test failed
``remeasure``      measure the last (suspicious) fix again
``undo``           undo the last accepted fix
``note TEXT``      a crew note at the current chainage
``pause``          pause the survey (train passing); ``resume`` continues
``turn``           the trolley was turned around
``station``        station change: the instrument is set up again on the CPIII near the trolley;
                   the prism at the current stop is measured from both stations (overlap check)
``end``            end the session (re-process, write the Excel sheet and the plots)
=================  ============================================================================

Station setup and static alignment run before the first action; the setup is accepted as
computed unless the script starts with ``setup drop POINT`` lines (points to leave out).
See ``docs/field_session.md``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

#: action name -> whether it takes an argument ("number", "text", "point" or None)
ACTIONS: dict[str, str | None] = {
    "wait": "number", "move": None, "stop": None, "fix": None, "accept": None, "remeasure": None,
    "undo": None, "note": "text", "pause": None, "resume": None, "turn": None, "station": None, "end": None,
    "setup": "text",
}


class ScriptError(ValueError):
    """A script line that cannot be read (the message names the file and line)."""


@dataclass(frozen=True)
class Action:
    """One crew action.

    Attributes
    ----------
    name : action name (a key of ``ACTIONS``).
    seconds : duration of ``wait``.
    text : note text, or the ``setup`` sub-command.
    line : 1-based line in the script file (0 when built in code).
    """

    name: str
    seconds: float = 0.0
    text: str = ""
    line: int = 0


def parse_script(text: str, source: str = "<script>") -> list[Action]:
    """Actions of a script text.

    Raises
    ------
    ScriptError : unknown action, missing or bad argument (names ``source:line``).
    """
    out: list[Action] = []
    for i, raw in enumerate(text.lstrip("\ufeff").splitlines(), start=1):     # (a BOM, as Notepad writes)
        line = raw.split("#", 1)[0].strip() if not raw.lstrip().startswith("note") else raw.strip()
        if not line:
            continue
        name, arg = (line.split(None, 1) + [""])[:2]         # a tab separates like a blank
        name, arg = name.lower(), arg.strip()
        if name not in ACTIONS:
            raise ScriptError(f"{source}:{i}: unknown action {name!r} (one of {', '.join(ACTIONS)})")
        kind = ACTIONS[name]
        if kind is None and arg:
            raise ScriptError(f"{source}:{i}: {name} takes no argument, got {arg!r}")
        if kind == "number":
            try:
                seconds = float(arg)
            except ValueError:
                raise ScriptError(f"{source}:{i}: {name} needs a number of seconds, got {arg!r}") from None
            if not seconds >= 0:
                raise ScriptError(f"{source}:{i}: {name} needs a non-negative number of seconds, got {arg!r}")
            out.append(Action(name, seconds=seconds, line=i))
        elif kind == "text":
            if not arg:
                raise ScriptError(f"{source}:{i}: {name} needs a text")
            if name == "setup":
                sub = arg.split(None, 1)
                if len(sub) != 2 or sub[0].lower() != "drop":
                    raise ScriptError(f"{source}:{i}: setup takes 'drop POINT', got {arg!r}")
                if any(a.name != "setup" for a in out):
                    # the first station setup runs before every other action: a later line would be
                    # applied to it all the same, out of the order the crew wrote
                    raise ScriptError(f"{source}:{i}: setup drop lines must come first, before any other action")
                arg = f"drop {sub[1].strip()}"
            out.append(Action(name, text=arg, line=i))
        else:
            out.append(Action(name, line=i))
    return out


def read_script(path: Path) -> list[Action]:
    """Actions of a script file (``ScriptError`` naming the file and line)."""
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise ScriptError(f"{path}: cannot read the script: {exc}") from None
    return parse_script(text, str(path))


def check_dropped_points(actions: list[Action], point_ids, source: str = "<script>") -> None:
    """Every ``setup drop POINT`` must name a CPIII point of the project (ids are case-sensitive):
    a typo would leave the point the crew meant to drop in the resection while the record says it
    was dropped. Raises ScriptError naming the line and the nearest id."""
    import difflib

    known = set(point_ids)
    for a in actions:
        if a.name != "setup":
            continue
        pid = a.text.split(None, 1)[1]
        if pid not in known:
            near = difflib.get_close_matches(pid, sorted(known), n=1) or [
                k for k in sorted(known) if k.lower() == pid.lower()][:1]
            hint = f" (did you mean {near[0]}?)" if near else ""
            raise ScriptError(f"{source}:{a.line}: setup drop {pid}: no CPIII point of that id in the project{hint}")


def survey_script(n_stops: int, note_every: int = 0, station_every: int = 0) -> str:
    """The script of a plain survey: a fix at the first stop, then move and fix ``n_stops - 1`` times, end.

    Parameters
    ----------
    n_stops : number of stops including the first (static alignment) one.
    note_every : add a note at every ``note_every``-th stop (0: none).
    station_every : change the station at every ``station_every``-th stop, after its fix (0: never).
    """
    lines = ["# generated: fix at every stop", "fix"]
    for k in range(1, n_stops):
        lines += ["move", "fix"]
        if note_every and k % note_every == 0:
            lines.append(f"note stop {k} checked")
        if station_every and k % station_every == 0 and k < n_stops - 1:
            lines.append("station")
    lines.append("end")
    return "\n".join(lines) + "\n"

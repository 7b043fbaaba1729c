"""The crew's script format (survey/session/script.py)."""
from __future__ import annotations

import pytest

from survey.session.script import (Action, ScriptError, check_dropped_points, parse_script, read_script,
                                   survey_script)


def test_every_action_and_comments():
    text = "# crew\nsetup drop CP0003L\nwait 2.5\nfix   # first stop\nmove\nstop\naccept\nremeasure\nundo\n" \
           "note rail clip loose # not a comment\npause\nresume\nturn\nstation\nend\n"
    acts = parse_script(text)
    assert [a.name for a in acts] == ["setup", "wait", "fix", "move", "stop", "accept", "remeasure", "undo",
                                      "note", "pause", "resume", "turn", "station", "end"]
    assert acts[1] == Action("wait", seconds=2.5, line=3)
    assert acts[0].text == "drop CP0003L"
    assert acts[8].text == "rail clip loose # not a comment"  # a note keeps its text as typed
    assert acts[2].line == 4


@pytest.mark.parametrize("text, line, words", [
    ("fix\njump\n", 2, "unknown action 'jump'"),
    ("wait\n", 1, "needs a number"),
    ("wait soon\n", 1, "needs a number"),
    ("wait -1\n", 1, "non-negative"),
    ("\n\nfix now\n", 3, "takes no argument"),
    ("note\n", 1, "needs a text"),
    ("setup keep CP1\n", 1, "setup takes 'drop POINT'"),
    ("setup drop\n", 1, "setup takes 'drop POINT'"),
    ("setup drop A\nfix\nsetup drop B\n", 3, "setup drop lines must come first"),
])
def test_errors_name_file_and_line(text, line, words):
    with pytest.raises(ScriptError) as e:
        parse_script(text, "crew.txt")
    assert str(e.value).startswith(f"crew.txt:{line}:") and words in str(e.value)


def test_generated_survey_script(tmp_path):
    p = tmp_path / "s.txt"
    p.write_text(survey_script(4, note_every=2, station_every=2))
    acts = read_script(p)
    names = [a.name for a in acts]
    assert names.count("fix") == 4 and names.count("move") == 3 and names[-1] == "end"
    assert names.count("station") == 1 and names[names.index("station") - 2] == "fix"  # after the stop's fix
    assert [a.text for a in acts if a.name == "note"] == ["stop 2 checked"]


def test_unreadable_script_names_the_file(tmp_path):
    with pytest.raises(ScriptError, match="cannot read"):
        read_script(tmp_path / "missing.txt")


def test_a_bom_and_tabs_read_like_plain_text(tmp_path):
    p = tmp_path / "notepad.txt"
    p.write_bytes("\ufeffsetup drop\tCP0003L\nwait\t5\nfix\r\nend\r\n".encode("utf-8"))
    acts = read_script(p)
    assert [a.name for a in acts] == ["setup", "wait", "fix", "end"]
    assert acts[0].text == "drop CP0003L" and acts[1].seconds == 5.0


def test_a_dropped_point_must_be_a_cpiii_point_of_the_project():
    acts = parse_script("setup drop CP0001L\nsetup drop cp0002r\nfix\n")
    with pytest.raises(ScriptError) as e:
        check_dropped_points(acts, ["CP0001L", "CP0002R", "CP0003L"], "crew.txt")
    assert str(e.value) == ("crew.txt:2: setup drop cp0002r: no CPIII point of that id in the project "
                            "(did you mean CP0002R?)")
    check_dropped_points(acts[:1], ["CP0001L"], "crew.txt")

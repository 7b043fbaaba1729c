"""What `trolley survey start` says to a new user who has not finished the project: the commands
it suggests name the project (a "try: `... --project NAME`" or "resume PROJECT" had to be
completed by hand, and `import-alignment FILE.xml` without --project fails), and a project
without CPIII points is refused before anything is stored (it was refused after the device
check, with a session stored that had to be resumed)."""
from __future__ import annotations

import shutil

from typer.testing import CliRunner

from session_project import DEMO, make_project
from survey.cli import app
from survey.store import ProjectStore

runner = CliRunner()


def _script(tmp_path):
    script = tmp_path / "crew.txt"
    script.write_text("fix\nend\n", encoding="utf-8")
    return script


def _start_with_only(tmp_path, command: str, file: str):
    """``survey start`` on a new project site1 given only ``file`` (through ``project COMMAND``)."""
    root = tmp_path / "projects"
    assert runner.invoke(app, ["project", "new", "site1", "--root", str(root)]).exit_code == 0
    assert runner.invoke(app, ["project", command, str(DEMO / file), "--project", "site1",
                               "--root", str(root)]).exit_code == 0
    return root, runner.invoke(app, ["survey", "start", "site1", "--session", "s1", "--simulate", "--script",
                                     str(_script(tmp_path)), "--root", str(root)])


def test_a_project_without_cpiii_is_refused_before_anything_is_stored(tmp_path):
    root, r = _start_with_only(tmp_path, "import-alignment", "alignment.xml")
    assert r.exit_code == 2
    assert "error: project 'site1' has 0 CPIII points; the free station needs at least 3" in r.stderr
    assert "`trolley project import-cpiii FILE --project site1`" in r.stderr
    assert "device check" not in r.output
    with ProjectStore.open(root / "site1") as store:
        assert store.sessions() == []
    out = root / "site1" / "sessions" / "s1"      # at most the empty folder of the writability check
    assert not out.exists() or not any(out.iterdir())


def test_a_project_without_design_names_the_project_in_the_import_command(tmp_path):
    _, r = _start_with_only(tmp_path, "import-cpiii", "cpiii.csv")
    assert r.exit_code == 2
    assert "`trolley project import-alignment FILE.xml --project site1`" in r.stderr


def test_a_session_name_taken_suggests_the_resume_of_that_session_in_that_project(tmp_path):
    root = tmp_path / "projects"
    folder = make_project(root, "site1")
    with ProjectStore.open(folder) as store:
        store.create_session("s1", store.session_meta("alignment.xml"))
    r = runner.invoke(app, ["survey", "start", "site1", "--session", "s1", "--simulate", "--script",
                            str(_script(tmp_path)), "--root", str(root)])
    assert r.exit_code == 2
    assert "session 's1' already exists in project 'site1'" in r.stderr
    assert "`trolley survey resume site1 --session s1`" in r.stderr


def test_a_devices_file_with_a_mistake_is_refused_before_anything_is_stored(tmp_path):
    """Each mistake is one line naming the file and what is wrong, exit 2, and no session is stored
    (they were found at the device check, with a session stored that had to be resumed, or never:
    a misspelt "odometr" ran without the odometer, a negative imu_rate_hz turned the IMU data round,
    an unknown odometer_config field was an internal error, exit 3)."""
    import json

    make_project(tmp_path)
    for name in ("imu", "odo", "ts"):
        (tmp_path / name).touch()  # ports that exist
    imu, odo, ts = (str(tmp_path / n) for n in ("imu", "odo", "ts"))
    cases = [({"imu": imu}, "no 'totalstation' port"),
             ({"imu": None, "totalstation": ts}, "'imu' must be the path of a serial port"),
             ({"imu": imu, "totalstation": ts, "odometr": odo}, "unknown key 'odometr' (did you mean 'odometer'?)"),
             ({"imu": imu, "totalstation": imu}, "'imu' and 'totalstation' name the same port"),
             ({"imu": imu, "totalstation": str(tmp_path / "nosuch")},
              f"totalstation port '{tmp_path / 'nosuch'}' does not exist; nothing was stored"),
             ({"imu": imu, "totalstation": ts, "imu_type": 999}, "imu_type 999 is not a NovAtel IMU type"),
             ({"imu": imu, "totalstation": ts, "imu_rate_hz": -5}, "imu_rate_hz must be a number of Hz"),
             ({"imu": imu, "totalstation": ts, "imu_axes": "x,y"}, "imu_axes: axis map 'x,y'"),
             ({"imu": imu, "totalstation": ts, "odometer_config": {"decodee": 4}},
              "odometer_config: unknown field 'decodee' (did you mean 'decode'?)"),
             ({"imu": imu, "totalstation": ts, "odometer_config": {"ppr": "abc"}},
              "odometer_config: ppr must be a whole number, not 'abc'")]
    for i, (data, message) in enumerate(cases):
        f = tmp_path / f"ports{i}.json"
        f.write_text(json.dumps(data), encoding="utf-8")
        r = runner.invoke(app, ["survey", "start", str(tmp_path / "t1"), "--session", f"s{i}", "--devices", str(f),
                                "--script", str(_script(tmp_path))])
        assert r.exit_code == 2, (data, r.output)
        assert f"error: {f}: {message}" in " ".join(r.stderr.split()), (data, r.stderr)
        assert "device check" not in r.output
    with ProjectStore.open(tmp_path / "t1") as st:
        assert st.sessions() == []

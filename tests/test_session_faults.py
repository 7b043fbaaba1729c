"""A device failing mid-session: the IMU port vanishes (USB unplug) and the total station finds no
prism for a while. The session pauses with a clear message, keeps everything already received, and
continues when the device is back."""
from __future__ import annotations

import threading
import time

from rich.console import Console

from session_project import make_project


def test_imu_unplug_and_total_station_fault_pause_and_resume(tmp_path):
    from drivers import geocom as gc
    from survey.commands.survey import simulated_world
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script
    from survey.store import ProjectStore

    make_project(tmp_path, length_m="60.0", static_s="10.0", stop_s="30.0")
    console = Console(stderr=True, record=True, width=150)
    with ProjectStore.open(tmp_path / "t1") as st:
        world = simulated_world(st, 15.0)
    holder, errors = {}, []
    script = parse_script("fix\nmove\nfix\nend\n")

    def run():
        try:
            with ProjectStore.open(tmp_path / "t1") as st:  # a connection per thread
                holder["fs"] = FieldSession(st, "faults", SessionConfig(script=script, out_dir=None),
                                            world=world, console=console)
                holder["fs"].run()
        except BaseException as e:  # reported by the assertions below
            errors.append(e)

    th = threading.Thread(target=run)
    th.start()
    deadline = time.monotonic() + 60
    while "fs" not in holder or not holder["fs"].accepted_fixes:  # first fix taken: the station is set up
        assert time.monotonic() < deadline and th.is_alive(), errors
        time.sleep(0.02)
    fs = holder["fs"]
    # the next fix finds no prism 6 times (more than one call's 5 attempts), then works
    world.twins["totalstation"].inject_rc(8710, rpc=gc.AUT_FINEADJUST, times=6)
    while not fs.aligned:
        time.sleep(0.02)
    world.twins["imu"].disappear(1.5)  # unplugged while the trolley moves; back after 1.5 s
    th.join(90)
    assert not th.is_alive() and not errors, errors
    with ProjectStore.open(tmp_path / "t1") as st:
        sid = fs.rec.session_id
        events = st.events(sid)
        faults = [e.detail for e in events if e.kind == "device_fault"]
        assert any(d.startswith("imu:") for d in faults), faults
        ts_faults = [d for d in faults if d.startswith("total station:")]
        assert ts_faults and "target" in ts_faults[0].lower(), faults
        assert sum(e.kind == "device_back" for e in events) >= 2
        # nothing received was lost: every frame the driver decoded is stored
        link = fs.acq.links["imu"]
        t, _, _ = st.imu_arrays(sid)
        assert link.stats.reconnects >= 1
        assert t.size == link.stats.frames_ok
        # the unplug lost the frames sent while the port was gone, and only those: one gap
        gaps = (t[1:] - t[:-1]) > 0.0075
        assert gaps.sum() == 1
        assert [f.accepted for f in st.fixes(sid)] == [True, True]
        text = console.export_text()
        assert "session paused; nothing received is lost" in " ".join(text.split())
        assert "the session continues" in text


def test_a_device_that_does_not_open_stops_the_start_with_the_reason(tmp_path):
    import json
    import os
    import subprocess
    import sys

    make_project(tmp_path / "projects")
    (tmp_path / "ports.json").write_text(json.dumps({"imu": str(tmp_path / "no-imu"),
                                                     "totalstation": str(tmp_path / "no-ts")}))
    (tmp_path / "crew.txt").write_text("fix\nend\n")
    r = subprocess.run([sys.executable, "-m", "survey.cli", "survey", "start", "t1", "--root", "projects",
                        "--session", "s1", "--devices", "ports.json", "--script", "crew.txt"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=60, env={**os.environ, "COLUMNS": "200"})
    err = " ".join(r.stderr.split())
    assert r.returncode == 2, r.stderr
    # refused before anything is stored (it was stored, and the crew told to resume it)
    assert f"imu port '{tmp_path / 'no-imu'}' does not exist; nothing was stored" in err
    assert "try: plug the device in" in err and "resume" not in err
    assert "Traceback" not in r.stderr


def test_a_session_runs_in_one_process_at_a_time(tmp_path):
    import os
    import subprocess
    import sys

    from survey.commands.survey import session_lock

    code = ("import sys, typer; from pathlib import Path; from survey.commands.survey import session_lock\n"
            "try:\n    with session_lock(Path(sys.argv[1]), 's1'): print('got it')\n"
            "except typer.Exit as e:\n    sys.exit(e.exit_code)")
    with session_lock(tmp_path, "s1"):
        r = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=30,
                           env={**os.environ, "COLUMNS": "200"})
        assert r.returncode == 2 and f"running in another process (pid {os.getpid()})" in r.stderr
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0 and "got it" in r.stdout  # released with the holder (or its crash)


def test_a_tolerance_set_that_cannot_be_loaded_stops_the_start(tmp_path):
    import os
    import shutil
    import subprocess
    import sys

    import trolley.tolerance_sets as sets

    own = tmp_path / "line7.toml"
    shutil.copy(os.path.join(os.path.dirname(sets.__file__), "en13848_5_alert.toml"), own)
    make_project(tmp_path / "projects", tolerance_set=str(own))
    own.unlink()  # the project names a file that is gone
    (tmp_path / "crew.txt").write_text("fix\nend\n")
    r = subprocess.run([sys.executable, "-m", "survey.cli", "survey", "start", "t1", "--root", "projects",
                        "--session", "s1", "--simulate", "--script", "crew.txt"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120, env={**os.environ, "COLUMNS": "200"})
    err = " ".join(r.stderr.split())
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"project tolerance set: {own}" in err
    from survey.store import ProjectStore

    with ProjectStore.open(tmp_path / "projects" / "t1") as st:
        assert st.sessions() == []  # nothing started

"""`trolley simulate` then `trolley process` through the CLI: the contract of track.csv, bad input."""
import json

import pandas as pd
import pytest
from typer.testing import CliRunner

from survey.cli import app

runner = CliRunner()
TRACK_COLUMNS = ("chainage_m,E_m,N_m,H_m,sigma_E_mm,sigma_N_mm,sigma_H_mm,"
                 "lateral_dev_mm,vertical_dev_mm,gauge_mm,cant_mm,twist_mm,distance_m,cov_EN_mm2,sigma_cant_mm").split(",")


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "session"
    r = runner.invoke(app, ["simulate", "--out", str(out), "--length-m", "180", "--static-s", "60",
                            "--rate-hz", "100", "--seed", "3"])
    assert r.exit_code == 0, r.output
    return out


def test_process_writes_track_csv_as_formats_says(session, tmp_path):
    out = tmp_path / "processed"
    r = runner.invoke(app, ["process", str(session), "--out", str(out), "--smoother", "tfs",
                             "--observability"])
    assert r.exit_code == 0, r.output
    track = pd.read_csv(out / "track.csv")
    assert list(track.columns) == TRACK_COLUMNS
    assert (track["chainage_m"].diff().dropna() - 0.625).abs().max() < 1e-6
    # a 0-180 m run: the end stations are there (its projected ends lie 0.4 mm inside)
    assert track["chainage_m"].iloc[0] == 0.0 and track["chainage_m"].iloc[-1] == 180.0
    # sub-millimetre sigmas between fixes, deviations present because the session names a design
    assert track["sigma_H_mm"].max() < 1.5
    assert track["lateral_dev_mm"].notna().all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["smoother"] == "tfs" and summary["fixes_rejected"] == 0
    assert summary["observability_ranks"] == [3, 5]
    fixes = pd.read_csv(out / "fixes.csv")
    assert len(fixes) == summary["fixes_used"]
    assert "fixes used / rejected" in r.stdout
    # the horizontal covariance is one (|rho| <= 1) and correlated; the cant's sigma is the rail
    # spacing times the level sigma, one value for the whole survey (cos(cant angle) aside)
    rho = track["cov_EN_mm2"] / (track["sigma_E_mm"] * track["sigma_N_mm"])
    assert rho.abs().max() <= 1.0 + 1e-9 and rho.abs().median() > 0.05
    sc = track["sigma_cant_mm"]
    assert sc.notna().all() and sc.max() - sc.min() < 0.01 * sc.max()
    assert 0.05 < sc.max() < 0.3          # RLG: hypot(50 ug / g, 0.003 deg) x 1.5 m = 0.11 mm


def test_bad_cell_names_file_row_column_and_writes_nothing(session, tmp_path):
    import shutil
    bad = tmp_path / "bad"
    shutil.copytree(session, bad)
    lines = (bad / "imu.csv").read_text().splitlines()
    cells = lines[10].split(",")
    cells[3] = "abc"
    lines[10] = ",".join(cells)
    (bad / "imu.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    r = runner.invoke(app, ["process", str(bad), "--out", str(out)])
    assert r.exit_code == 2
    assert "imu.csv" in r.stderr and "11" in r.stderr and "wz_rad_s" in r.stderr
    assert "Traceback" not in r.output
    assert not (out / "track.csv").exists()


def test_unknown_smoother_is_refused(session, tmp_path):
    r = runner.invoke(app, ["process", str(session), "--out", str(tmp_path / "o"), "--smoother", "ukf"])
    assert r.exit_code == 2 and "smoother" in r.stderr


def test_rerun_replaces_the_output_folder_whole_and_a_failure_keeps_the_old(session, tmp_path, monkeypatch):
    out = tmp_path / "processed"
    assert runner.invoke(app, ["process", str(session), "--out", str(out)]).exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert sorted(before) == ["fixes.csv", "summary.json", "track.csv"]
    # a failure while writing (after track.csv was written) leaves the old folder exactly as it was
    import survey.trackio as trackio

    def broken(result):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(trackio, "fixes_frame", broken)
    r = runner.invoke(app, ["process", str(session), "--out", str(out), "--step", "1.0"])
    assert r.exit_code == 2 and "No space left" in r.stderr and "Traceback" not in r.output
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["processed"]  # no partial folder left
    monkeypatch.undo()
    # a successful rerun replaces all three files
    assert runner.invoke(app, ["process", str(session), "--out", str(out), "--step", "1.0"]).exit_code == 0
    track = pd.read_csv(out / "track.csv")
    assert (track["chainage_m"].diff().dropna() - 1.0).abs().max() < 1e-6
    assert sorted(p.name for p in tmp_path.iterdir()) == ["processed"]


def test_a_field_sessions_processed_folder_is_replaced_field_record_and_all(session, tmp_path):
    # the end of a field session writes field_record.json beside track.csv; running the session (or
    # trolley process) again into that folder replaces it as a whole instead of refusing
    out = tmp_path / "processed"
    assert runner.invoke(app, ["process", str(session), "--out", str(out)]).exit_code == 0
    (out / "field_record.json").write_text("{}")
    r = runner.invoke(app, ["process", str(session), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in out.iterdir()) == ["fixes.csv", "summary.json", "track.csv"]


def test_output_folder_with_other_files_is_refused_and_left_alone(session, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    r = runner.invoke(app, ["process", str(session), "--out", str(out)])
    assert r.exit_code == 2 and "notes.txt" in r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    # the session folder itself can never be the output
    files = sorted(p.name for p in session.iterdir())
    r = runner.invoke(app, ["process", str(session), "--out", str(session)])
    assert r.exit_code == 2 and "not only the outputs" in r.stderr
    assert sorted(p.name for p in session.iterdir()) == files


def test_a_session_with_one_fix_has_valid_json_and_says_there_is_no_innovation(session, tmp_path):
    # (summary.json held NaN, which no JSON reader takes; the terminal said "nan mm")
    import shutil

    one = tmp_path / "one"
    shutil.copytree(session, one)
    lines = (one / "fixes.csv").read_text().splitlines()
    (one / "fixes.csv").write_text("\n".join(lines[:2]) + "\n")
    r = runner.invoke(app, ["process", str(one), "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    text = (tmp_path / "o" / "summary.json").read_text()
    def strict(constant):
        raise ValueError(f"not JSON: {constant}")

    summary = json.loads(text, parse_constant=strict)
    assert summary["rms_innovation_mm"] is None
    assert "none (no fix after the first was used)" in " ".join(r.output.split())


def test_an_odometer_scale_error_of_zero_is_processed(session, tmp_path):
    # 0 is a legal value (an odometer calibrated exactly); its initial variance 0 made the
    # smoother's state scaling divide by zero ("zero norm quaternions")
    import shutil

    import numpy as np

    zero = tmp_path / "zero"
    shutil.copytree(session, zero)
    text = (zero / "session.toml").read_text()
    assert "scale_error = " in text
    (zero / "session.toml").write_text("\n".join("scale_error = 0.0" if line.startswith("scale_error = ") else line
                                                 for line in text.splitlines()) + "\n")
    for folder, out in ((session, "a"), (zero, "b")):
        r = runner.invoke(app, ["process", str(folder), "--out", str(tmp_path / out)])
        assert r.exit_code == 0, r.output
    a, b = (pd.read_csv(tmp_path / o / "track.csv") for o in ("a", "b"))
    assert len(a) == len(b) and np.all(np.isfinite(b[["E_m", "N_m", "H_m"]].to_numpy()))
    assert np.max(np.abs(a[["E_m", "N_m", "H_m"]].to_numpy() - b[["E_m", "N_m", "H_m"]].to_numpy())) < 2e-3


def test_an_empty_gauge_file_is_a_session_without_gauge_readings(session, tmp_path):
    # FORMATS.md / docs/simulator.md: gauge.csv may be empty; a 0-byte file was "empty file, no header row"
    import shutil

    empty = tmp_path / "empty"
    shutil.copytree(session, empty)
    (empty / "gauge.csv").write_bytes(b"")
    r = runner.invoke(app, ["process", str(empty), "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    assert pd.read_csv(tmp_path / "o" / "track.csv")["gauge_mm"].isna().all()


def test_an_out_that_is_a_link_to_an_earlier_output_is_replaced_as_a_link(session, tmp_path):
    # (the link was renamed aside and never deleted: a hidden ".l.old-PID" stayed behind)
    target = tmp_path / "earlier"
    assert runner.invoke(app, ["process", str(session), "--out", str(target)]).exit_code == 0
    before = {p.name: p.read_bytes() for p in target.iterdir()}
    (tmp_path / "l").symlink_to(target)
    r = runner.invoke(app, ["process", str(session), "--out", str(tmp_path / "l"), "--step-m", "1.0"])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["earlier", "l"]
    assert not (tmp_path / "l").is_symlink() and (tmp_path / "l" / "track.csv").is_file()
    assert {p.name: p.read_bytes() for p in target.iterdir()} == before


def test_fixes_rejected_one_after_another_are_warned_about(session, tmp_path):
    import shutil

    from trolley.engine import longest_run

    assert longest_run([True, False, True, True, True, False, True, True]) == 3
    assert longest_run([False, False]) == 0 and longest_run([]) == 0
    # three fixes in a row 0.5 m off: the gate rejects them, and the user hears what that means
    bad = tmp_path / "bad"
    shutil.copytree(session, bad)
    fixes = pd.read_csv(bad / "fixes.csv")
    assert len(fixes) == 4
    fixes.loc[1:3, "E_m"] += 0.5
    fixes.to_csv(bad / "fixes.csv", index=False, float_format="%.6f")
    r = runner.invoke(app, ["process", str(bad), "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["longest_rejected_run"] == 3
    assert "3 fixes in a row were rejected" in " ".join(r.stderr.split())
    ok = runner.invoke(app, ["process", str(session), "--out", str(tmp_path / "clean")])
    assert "in a row were rejected" not in ok.stderr
    assert json.loads((tmp_path / "clean" / "summary.json").read_text())["longest_rejected_run"] == 0


def test_a_fix_the_user_accepts_is_used_and_an_unknown_one_refused(session, tmp_path):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(session, bad)
    fixes = pd.read_csv(bad / "fixes.csv")
    fixes.loc[2, "E_m"] += 0.05  # 50 mm: the gate rejects it
    fixes.to_csv(bad / "fixes.csv", index=False, float_format="%.6f")
    point = str(fixes.loc[2, "point"])
    r = runner.invoke(app, ["process", str(bad), "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    out = pd.read_csv(tmp_path / "o" / "fixes.csv", keep_default_na=False)
    assert out.accepted.tolist().count(0) == 1 and out.loc[out.point == point, "accepted"].item() == 0
    r = runner.invoke(app, ["process", str(bad), "--out", str(tmp_path / "f"), "--accept-fix", point])
    assert r.exit_code == 0, r.output
    out = pd.read_csv(tmp_path / "f" / "fixes.csv", keep_default_na=False)
    # used, and said so (this one is wrong: the right ones beside it are then rejected against it)
    assert out.loc[out.point == point, "accepted"].item() == 1
    assert out.loc[out.point == point, "reason"].item() == "accepted by the crew despite the gate"
    r = runner.invoke(app, ["process", str(bad), "--out", str(tmp_path / "g"), "--accept-fix", "CP9999"])
    assert r.exit_code == 2
    assert "--accept-fix CP9999: no fix with this point in" in " ".join(r.stderr.split())
    assert not (tmp_path / "g").exists()


def test_a_folder_from_the_wrong_step_is_named_with_what_to_run_instead(session, tmp_path):
    """`process` given a processed folder or a field session's output folder said only
    "session.toml: file missing"; it now says what the folder is and the command to run."""
    import shutil
    processed = tmp_path / "processed"
    assert runner.invoke(app, ["process", str(session), "--out", str(processed)]).exit_code == 0
    r = runner.invoke(app, ["process", str(processed), "--out", str(tmp_path / "again")])
    assert r.exit_code == 2
    line = r.stderr.strip()
    assert "\n" not in line and "a processed track (track.csv)" in line
    assert f"trolley export {processed} --xlsx FILE" in line
    # a field-session / demo output folder: DIR/session (raw) and DIR/processed (track)
    field = tmp_path / "field"
    shutil.copytree(session, field / "session")
    shutil.copytree(processed, field / "processed")
    r = runner.invoke(app, ["process", str(field), "--out", str(tmp_path / "again")])
    assert r.exit_code == 2
    line = r.stderr.strip()
    assert "\n" not in line and f"trolley process {field / 'session'} --out OUT" in line
    assert f"trolley export {field} --xlsx FILE" in line
    assert not (tmp_path / "again").exists()
    # any other folder without session.toml keeps the reader's message
    (tmp_path / "empty").mkdir()
    r = runner.invoke(app, ["process", str(tmp_path / "empty"), "--out", str(tmp_path / "again")])
    assert r.exit_code == 2 and "session.toml: file missing" in r.stderr

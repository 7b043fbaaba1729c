"""Bad input, hostile names and mistakes, command by command (issue 12).

Every probe runs one ``trolley`` command on a prepared bad input and checks what the user sees:
the documented exit code (2 = bad input), a message naming the file / row / column or the
option, no Python traceback, no rich-markup error, no ``np.float64(...)``, no hidden temporary
file named, and nothing written or changed on disk (every file in the probe's folder has the same
bytes afterwards and no new file appears, except where the probe says so).
"""
from __future__ import annotations

import hashlib
import os
import shutil
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import pytest
from typer.testing import CliRunner

from survey.cli import app

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "projects" / "demo"


@dataclass
class Inputs:
    """Pristine inputs made once: a raw session, its processing output, a TGMS recording."""

    session: Path
    processed: Path
    tgms: Path


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Inputs:
    base = tmp_path_factory.mktemp("inputs")
    run = CliRunner().invoke
    r = run(app, ["simulate", "--out", str(base / "sess"), "--project", str(DEMO), "--length-m", "120",
                  "--rate-hz", "50", "--static-s", "30", "--seed", "3"])
    assert r.exit_code == 0, r.stderr
    r = run(app, ["process", str(base / "sess"), "--out", str(base / "proc")])
    assert r.exit_code == 0, r.stderr
    r = run(app, ["tgms", "simulate", "--out", str(base / "tgms"), "--length-m", "60"])
    assert r.exit_code == 0, r.stderr
    return Inputs(base / "sess", base / "proc", base / "tgms")


# ------------------------------------------------------------------------------------------
# helpers that prepare a probe's files inside its own folder
# ------------------------------------------------------------------------------------------
def copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, symlinks=True)
    return dst


def set_cell(path: Path, row: int, column: str, value: str) -> None:
    """Set a cell of a CSV file (row as a spreadsheet numbers it: header = 1)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    head = lines[0].split(",")
    cells = lines[row - 1].split(",")
    cells[head.index(column)] = value
    lines[row - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def keep_rows(path: Path, n: int) -> None:
    """Keep the header and the first ``n`` data rows."""
    lines = path.read_text(encoding="utf-8").splitlines()
    path.write_text("\n".join(lines[:n + 1]) + "\n", encoding="utf-8")


def decimal_commas(path: Path) -> None:
    """Write every data row with decimal commas (a spreadsheet in a comma locale)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    path.write_text("\n".join(lines[:1] + [r.replace(".", ",") for r in lines[1:]]) + "\n", encoding="utf-8")


def insert_line(path: Path, after: int, text: str) -> None:
    """Insert a line after file line ``after`` (1-based)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    path.write_text("\n".join(lines[:after] + [text] + lines[after:]) + "\n", encoding="utf-8")


def duplicate_line(path: Path, line: int) -> None:
    """Repeat file line ``line`` (1-based) right after itself."""
    lines = path.read_text(encoding="utf-8").splitlines()
    insert_line(path, line, lines[line - 1])


def drop_rows(path: Path, first: int, last: int) -> None:
    """Delete the spreadsheet rows ``first``..``last`` (header = row 1)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    path.write_text("\n".join(lines[:first - 1] + lines[last:]) + "\n", encoding="utf-8")


def edit_text(path: Path, old: str, new: str) -> None:
    text = path.read_text(encoding="utf-8")
    assert old in text, (path, old)
    path.write_text(text.replace(old, new, 1), encoding="utf-8")


def new_project(root: Path, name: str = "p") -> None:
    r = CliRunner().invoke(app, ["project", "new", name, "--root", str(root), "--no-toml"])
    assert r.exit_code == 0, r.stderr


# ------------------------------------------------------------------------------------------
# the probes
# ------------------------------------------------------------------------------------------
@dataclass
class Probe:
    """One bad-input run.

    make(tmp, inputs) prepares files under tmp and returns the command line (without ``trolley``).
    says: substrings the error message must contain (the file / row / column or option).
    code: expected exit code.
    may_write: names of files the command may create (e.g. a project store it made before the
        bad step); everything else under tmp must be unchanged.
    """

    id: str
    make: Callable[[Path, Inputs], list[str]]
    says: tuple[str, ...] = ()
    code: int = 2
    may_write: tuple[str, ...] = field(default_factory=tuple)


def _sess(t: Path, i: Inputs) -> Path:
    return copy(i.session, t / "sess")


def _sess_in(t: Path, i: Inputs, folder: str) -> Path:
    """A copy of the raw session as ``t/folder/session``; returns ``t/folder``."""
    (t / folder).mkdir()
    copy(i.session, t / folder / "session")
    return t / folder


def _proc(t: Path, i: Inputs) -> Path:
    return copy(i.processed, t / "proc")


def _tg(t: Path, i: Inputs) -> Path:
    return copy(i.tgms, t / "rec")


def process_probe(edit: Callable[[Path], None], *extra: str) -> Callable[[Path, Inputs], list[str]]:
    def make(t, i):
        s = _sess(t, i)
        edit(s)
        return ["process", str(s), "--out", str(t / "out"), *extra]
    return make


def export_probe(edit: Callable[[Path], None], *extra: str) -> Callable[[Path, Inputs], list[str]]:
    def make(t, i):
        p = _proc(t, i)
        edit(p)
        return ["export", str(p), *[a.replace("{t}", str(t)) for a in extra]]
    return make


def tgms_params_probe(t: Path, i: Inputs, params_text: str) -> list[str]:
    """tgms process with --params a file holding ``params_text``."""
    (t / "e.toml").write_text(params_text, encoding="utf-8")
    return tgms_process_probe(lambda r: None, "--params", str(t / "e.toml"))(t, i)


def tgms_process_probe(edit: Callable[[Path], None], *extra: str) -> Callable[[Path, Inputs], list[str]]:
    def make(t, i):
        r = _tg(t, i)
        edit(r)
        return ["tgms", "process", str(r), "--out", str(t / "out"), "--no-plots", *extra]
    return make


def simulate_args(t: Path, *extra: str) -> list[str]:
    return ["simulate", "--out", str(t / "new"), "--project", str(DEMO), *extra]


def _nonutf8(path: Path) -> None:
    path.write_bytes(path.read_bytes().replace(b"rlg", b"rl\xe9", 1) if b"rlg" in path.read_bytes()
                     else b"\xff\xfe" + path.read_bytes())


def _session_design_escape(t: Path, i: Inputs) -> bool:
    """A processing output whose summary.json names a session whose session.toml names a design
    outside its folder."""
    s, p = _sess(t, i), _proc(t, i)
    edit_text(s / "session.toml", 'alignment = "alignment.xml"', 'alignment = "../../../../etc/hostname"')
    edit_text(p / "summary.json", f'"session_dir": "{i.session.resolve()}"', f'"session_dir": "{s.resolve()}"')
    return True


def _foreign_sqlite(root: Path) -> None:
    (root / "p").mkdir(parents=True)
    con = sqlite3.connect(root / "p" / "project.sqlite")
    con.execute("CREATE TABLE recipes (name TEXT, sugar_g REAL)")
    con.execute("INSERT INTO recipes VALUES ('cake', 200)")
    con.commit()
    con.close()


def _corrupt_store(root: Path) -> None:
    (root / "p").mkdir(parents=True)
    (root / "p" / "project.sqlite").write_bytes(b"SQLite format 3\x00" + os.urandom(3000))


def _project_toml_design(t: Path, design: str) -> Path:
    proj = t / "proj"
    shutil.copytree(DEMO, proj)
    edit_text(proj / "project.toml", 'alignment = "alignment.xml"', f'alignment = "{design}"')
    return proj


PROBES: list[Probe] = [
    # ---- process ------------------------------------------------------------------------
    Probe("process/decimal-commas-odometer", process_probe(lambda s: decimal_commas(s / "odometer.csv")),
          ("odometer.csv: row 2: 4 cells, the header has 2 columns", "decimal comma")),
    Probe("process/decimal-commas-fixes", process_probe(lambda s: decimal_commas(s / "fixes.csv")),
          ("fixes.csv: row 2:", "the header has", "decimal comma")),
    # a message names the session folder as given (relative here), not only "fixes.csv": with
    # several sessions the user must see which one (hunt22_files item 10)
    Probe("process/bad-fix-names-the-session-folder", lambda t, i: set_cell(copy(i.session, t / "day2") / "fixes.csv", 3,
                                                                            "t_s", "") or
          ["process", "w/day2", "--out", "w/out"], ("error: w/day2/fixes.csv: row 3, column t_s: empty value",)),
    Probe("process/bad-design-names-the-session-folder",
          lambda t, i: edit_text(copy(i.session, t / "day2") / "alignment.xml", "<Start>", "<Start>x") or
          ["process", "w/day2", "--out", "w/out"], ("error: w/day2/alignment.xml: <Alignment", "<Start> value 'x")),
    Probe("process/missing-folder", lambda t, i: ["process", str(t / "nope"), "--out", str(t / "o")], ("nope",)),
    Probe("process/session-is-a-file", lambda t, i: (t / "f.csv").write_text("x") and
          ["process", str(t / "f.csv"), "--out", str(t / "o")], ("f.csv",)),
    Probe("process/imu-1e308", process_probe(lambda s: set_cell(s / "imu.csv", 500, "wx_rad_s", "1e308")),
          ("imu.csv", "500", "wx_rad_s")),
    Probe("process/imu-text-cell", process_probe(lambda s: set_cell(s / "imu.csv", 7, "fz_m_s2", "abc")),
          ("imu.csv", "7", "fz_m_s2")),
    Probe("process/imu-inf", process_probe(lambda s: set_cell(s / "imu.csv", 9, "t_s", "inf")),
          ("imu.csv", "9", "t_s")),
    Probe("process/imu-decimal-comma", process_probe(lambda s: set_cell(s / "imu.csv", 4, "wy_rad_s", '"0,5"')),
          ("imu.csv", "4", "wy_rad_s")),
    Probe("process/imu-is-a-folder", process_probe(lambda s: ((s / "imu.csv").unlink(), (s / "imu.csv").mkdir())),
          ("imu.csv",)),
    Probe("process/imu-header-only", process_probe(lambda s: keep_rows(s / "imu.csv", 0)), ("imu.csv",)),
    Probe("process/fix-sigma-1e-300", process_probe(lambda s: set_cell(s / "fixes.csv", 2, "sigma_E_m", "1e-300")),
          ("fixes.csv", "2", "sigma_E_m")),
    Probe("process/fix-sigma-negative", process_probe(lambda s: set_cell(s / "fixes.csv", 3, "sigma_N_m", "-0.001")),
          ("fixes.csv", "3", "sigma_N_m")),
    Probe("process/odometer-one-row", process_probe(lambda s: keep_rows(s / "odometer.csv", 1)),
          ("odometer.csv",)),
    Probe("process/static-longer-than-data",
          process_probe(lambda s: edit_text(s / "session.toml", "static_s = 30.0", "static_s = 1e6")),
          ("static_s",)),
    Probe("process/static-inf",
          process_probe(lambda s: edit_text(s / "session.toml", "static_s = 30.0", "static_s = inf")),
          ("static_s",)),
    Probe("process/session-toml-not-utf8", process_probe(lambda s: _nonutf8(s / "session.toml")),
          ("session.toml", "UTF-8")),
    Probe("process/design-outside-folder",
          process_probe(lambda s: edit_text(s / "session.toml", 'alignment = "alignment.xml"',
                                            'alignment = "../../../etc/passwd"')), ("session.toml",)),
    Probe("process/out-is-the-session", lambda t, i: ["process", str(_sess(t, i)), "--out", str(t / "sess")],
          ("sess",)),
    Probe("process/out-is-a-file", lambda t, i: (t / "o").write_text("x") and
          ["process", str(_sess(t, i)), "--out", str(t / "o")], ("o",)),
    # the files each valid, but not one survey (a bug hunt: a 2 GB track of nonsense, a short one)
    Probe("process/odometer-jump", process_probe(lambda s: set_cell(s / "odometer.csv", 100, "distance_m", "9000000.0")),
          ("odometer.csv: row 100, column distance_m", "faster than 30 m/s", "in mm?")),
    Probe("process/imu-cut-short", process_probe(lambda s: keep_rows(s / "imu.csv", 3000)),
          ("fixes.csv: row", "column t_s", "is outside the IMU log", "imu.csv cut short")),
    Probe("process/imu-gap", process_probe(lambda s: drop_rows(s / "imu.csv", 3000, 3500)),
          ("imu.csv: row 3000, column t_s: no IMU samples for 10.04 s (from t = 59.96 s)",)),
    Probe("process/odometer-after-the-imu", process_probe(lambda s: (s / "odometer.csv").write_text(
        (s / "odometer.csv").read_text() + "9999.0,120.0\n")),
          ("odometer.csv: row", "column t_s: 9999 s is outside the IMU log")),
    Probe("process/out-inside-the-session", lambda t, i: ["process", str(_sess(t, i)), "--out", str(t / "sess" / "o")],
          ("is inside the raw session",)),
    Probe("simulate/out-inside-a-session", lambda t, i: ["simulate", "--out", str(_sess(t, i) / "sub"), "--project",
                                                          str(DEMO)], ("--out", "is inside", "raw session")),
    Probe("process/totalstation-sigma-1e6", process_probe(lambda s: edit_text(s / "session.toml", "sigma_m = ",
                                                                              "sigma_m = 1e6 #")),
          ("session.toml", "totalstation.sigma_m", "must be within 1e-06..100 m")),
    Probe("process/gyro-bias-1e300", process_probe(lambda s: edit_text(
        s / "session.toml", "gyro_bias_instability_deg_h = ", "gyro_bias_instability_deg_h = 1e300 #")),
          ("session.toml", "imu.gyro_bias_instability_deg_h", "must be <= 10000")),
    Probe("process/static-0", process_probe(lambda s: edit_text(s / "session.toml", "static_s = 30.0",
                                                                "static_s = 0.0")),
          ("session.toml", "alignment.static_s", "holds 1 IMU sample(s)", "at least 10")),
    Probe("simulate/rate-1e-300", lambda t, i: simulate_args(t, "--rate-hz", "1e-300"),
          ("--static-s", "--rate-hz 1e-300", "at least 10")),
    Probe("simulate/length-1e-300", lambda t, i: simulate_args(t, "--length-m", "1e-300"),
          ("--length-m: must be >= 1, got 1e-300 (a track between two fixes)",)),
    Probe("process/stray-quote-in-fixes", process_probe(lambda s: set_cell(s / "fixes.csv", 3, "H_m", '"51.5')),
          ("fixes.csv: row 3: a quote", "stray quote")),
    Probe("process/lever-arm-in-mm", process_probe(lambda s: edit_text(s / "session.toml", "prism_lever_arm_m = [",
                                                                       "prism_lever_arm_m = [0.0, 0.0, -600.0] #[")),
          ("session.toml", "trolley.prism_lever_arm_m", "within +-10 m")),
    Probe("simulate/turn-at-stop-0", lambda t, i: simulate_args(t, "--turn-at-stop", "0", "--length-m", "120"),
          ("--turn-at-stop 0", "stops 1..")),
    Probe("process/latitude-90", process_probe(lambda s: edit_text(s / "session.toml", "latitude_deg = 28.0",
                                                                   "latitude_deg = 90.0")),
          ("session.toml", "site.latitude_deg", "within -85..85")),
    Probe("process/step-1e-7", process_probe(lambda s: None, "--step-m", "1e-7"), ("--step-m",)),
    Probe("process/step-nan", process_probe(lambda s: None, "--step-m", "nan"), ("--step-m",)),
    # ---- export -------------------------------------------------------------------------
    Probe("export/track-decimal-comma", export_probe(lambda p: set_cell(p / "track.csv", 5, "E_m", '"500123,5"'),
                                                     "--csv", "{t}/o.csv"),
          ("track.csv", "5", "E_m")),
    Probe("export/track-decimal-comma-unquoted",
          export_probe(lambda p: set_cell(p / "track.csv", 5, "E_m", "500123,5"), "--csv", "{t}/o.csv"),
          ("track.csv", "row 5", "decimal comma")),
    Probe("export/track-inf", export_probe(lambda p: set_cell(p / "track.csv", 6, "gauge_mm", "inf"), "--csv",
                                           "{t}/o.csv"), ("track.csv", "6", "gauge_mm")),
    Probe("export/track-1e308", export_probe(lambda p: set_cell(p / "track.csv", 6, "H_m", "1e308"), "--csv",
                                             "{t}/o.csv"), ("track.csv", "6", "H_m")),
    # a negative sigma reached the sheet as a negative sigma, a covariance beyond its sigmas as an
    # empty lateral sigma (its variance negative)
    Probe("export/track-negative-sigma-cant", export_probe(lambda p: set_cell(p / "track.csv", 7, "sigma_cant_mm",
                                                                              "-0.1"), "--csv", "{t}/o.csv"),
          ("track.csv", "row 7", "sigma_cant_mm", "negative")),
    Probe("export/track-covariance-beyond-its-sigmas",
          export_probe(lambda p: set_cell(p / "track.csv", 8, "cov_EN_mm2", "40"), "--csv", "{t}/o.csv"),
          ("track.csv", "row 8", "cov_EN_mm2", "no covariance")),
    Probe("export/track-zero-stations", export_probe(lambda p: keep_rows(p / "track.csv", 0), "--csv", "{t}/o.csv"),
          ("track.csv",)),
    Probe("export/track-is-a-folder", lambda t, i: (t / "x" / "track.csv").mkdir(parents=True) or
          ["export", str(t / "x" / "track.csv"), "--csv", str(t / "o.csv")], ("track.csv",)),
    Probe("export/twist-base-inf", export_probe(lambda p: None, "--twist-base-m", "inf", "--csv", "{t}/o.csv"),
          ("--twist-base-m",)),
    Probe("export/twist-base-zero", export_probe(lambda p: None, "--twist-base-m", "0", "--csv", "{t}/o.csv"),
          ("--twist-base-m",)),
    Probe("export/twist-base-old-alias-inf", export_probe(lambda p: None, "--twist-base", "inf", "--csv", "{t}/o.csv"),
          ("--twist-base",)),
    Probe("export/chord-nan", export_probe(lambda p: None, "--chord-m", "nan", "--csv", "{t}/o.csv"), ("--chord-m",)),
    Probe("export/chord-1e-7", export_probe(lambda p: None, "--chord-m", "1e-7", "--csv", "{t}/o.csv"), ("--chord-m",)),
    Probe("export/csv-onto-track.csv", export_probe(lambda p: None, "--csv", "{t}/proc/track.csv"),
          ("--csv", "track.csv")),
    Probe("export/csv-onto-fixes.csv", export_probe(lambda p: None, "--csv", "{t}/proc/fixes.csv"),
          ("--csv", "fixes.csv")),
    Probe("export/xlsx-onto-raw-imu", lambda t, i: ["export", str(_proc(t, i)), "--xlsx", str(_sess(t, i) / "imu.csv")],
          ("--xlsx", "imu.csv")),
    Probe("export/xlsx-missing-folder", export_probe(lambda p: None, "--xlsx", "{t}/no/s.xlsx"), ("--xlsx", "no")),
    Probe("export/csv-ok-but-plots-a-file", lambda t, i: (t / "pl").write_text("x") and
          ["export", str(_proc(t, i)), "--csv", str(t / "o.csv"), "--plots", str(t / "pl")], ("--plots", "pl")),
    # (through a link: each option's file name must end in its own suffix)
    Probe("export/same-file-twice", export_probe(lambda p: (p.parent / "o.xlsx").symlink_to(p.parent / "o.csv"),
                                                 "--csv", "{t}/o.csv", "--xlsx", "{t}/o.xlsx"),
          ("--csv", "o.csv: also given to --xlsx")),
    Probe("export/xlsx-named-csv", export_probe(lambda p: None, "--xlsx", "{t}/x.csv"),
          ("--xlsx", "x.csv: the file name must end in .xlsx",)),
    Probe("export/session-design-escape", lambda t, i: _session_design_escape(t, i) and
          ["export", str(t / "proc"), "--csv", str(t / "o.csv")], ("session.toml", "design.alignment")),
    Probe("export/tolerances-not-utf8", lambda t, i: (t / "tol.toml").write_bytes(b"name = \"\xe9\"\n") and
          ["export", str(_proc(t, i)), "--tolerances", str(t / "tol.toml"), "--csv", str(t / "o.csv")],
          ("tol.toml",)),
    Probe("export/tolerances-unknown-name", export_probe(lambda p: None, "--csv", "{t}/o.csv", "--tolerances",
                                                         "hsr_balastless_static"),
          ("--tolerances: hsr_balastless_static", "hsr_ballastless_static")),
    Probe("export/fixes-bad-accepted", export_probe(lambda p: set_cell(p / "fixes.csv", 3, "accepted", "yes"),
                                                    "--csv", "{t}/o.csv"), ("fixes.csv", "3", "accepted")),
    Probe("export/markup-in-folder-name", lambda t, i: ["export", str(copy(i.processed, t / "run[/x]") / "nope.csv"),
                                                          "--csv", str(t / "o.csv")],
          ("run[/x]",)),
    # ---- simulate -----------------------------------------------------------------------
    Probe("simulate/rate-hz-1e7", lambda t, i: simulate_args(t, "--rate-hz", "1e7"), ("--rate-hz",)),
    Probe("simulate/static-s-inf", lambda t, i: simulate_args(t, "--static-s", "inf"), ("static",)),
    Probe("simulate/static-s-negative", lambda t, i: simulate_args(t, "--static-s", "-5"), ("static",)),
    Probe("simulate/length-inf", lambda t, i: simulate_args(t, "--length-m", "inf"), ("length",)),
    Probe("simulate/length-nan", lambda t, i: simulate_args(t, "--length-m", "nan"), ("length",)),
    Probe("simulate/truth-step-1e-7", lambda t, i: simulate_args(t, "--length-m", "60", "--truth-step-m", "1e-7"),
          ("--truth-step-m",)),
    Probe("simulate/fix-spacing-1e-9", lambda t, i: simulate_args(t, "--fix-spacing-m", "1e-9"), ("fix",)),
    Probe("simulate/out-existing-session", lambda t, i: ["simulate", "--out", str(_sess(t, i)), "--project", str(DEMO),
                                                         "--length-m", "60"], ("sess", "already exists")),
    Probe("simulate/force-onto-foreign-folder",
          lambda t, i: (t / "mine").mkdir() or (t / "mine" / "notes.txt").write_text("x") and
          ["simulate", "--out", str(t / "mine"), "--project", str(DEMO), "--length-m", "60", "--force"],
          ("mine", "not made by")),
    Probe("simulate/out-a-file", lambda t, i: (t / "o").write_text("x") and
          simulate_args(t, "--length-m", "60")[:2] + [str(t / "o"), "--project", str(DEMO)], ("o",)),
    Probe("simulate/project-design-escape", lambda t, i: ["simulate", "--out", str(t / "new"), "--project",
                                                          str(_project_toml_design(t, "../../etc/passwd"))],
          ("project.toml", "design")),
    Probe("simulate/project-toml-not-utf8", lambda t, i: (_nonutf8(_project_toml_design(t, "alignment.xml")
                                                                   / "project.toml"),
                                                          ["simulate", "--out", str(t / "new"), "--project",
                                                           str(t / "proj")])[1], ("project.toml",)),
    # ---- tgms ---------------------------------------------------------------------------
    Probe("tgms-simulate/out-existing-session", lambda t, i: ["tgms", "simulate", "--out", str(_sess(t, i))],
          ("sess",)),
    Probe("tgms-simulate/out-existing-recording", lambda t, i: (_tg(t, i) / ".made-by-trolley").unlink() or
          ["tgms", "simulate", "--out", str(t / "rec"), "--length-m", "60"], ("rec",)),
    Probe("tgms-simulate/length-inf", lambda t, i: ["tgms", "simulate", "--out", str(t / "n"), "--length-m", "inf"],
          ("--length-m",)),
    # (bug hunt) nan got typer's "Input should be greater than or equal to 60" (or
    # "... less than or equal to 40": typer compares nan with the upper bound first)
    *(Probe(f"tgms-simulate/{opt[2:]}-nan", lambda t, i, opt=opt: ["tgms", "simulate", "--out", str(t / "n"), opt, "nan"],
            (f"{opt}: must be a finite number, got nan",)) for opt in ("--length-m", "--speed-m-s", "--camera-rate-hz")),
    Probe("tgms-simulate/length-below-60", lambda t, i: ["tgms", "simulate", "--out", str(t / "n"), "--length-m", "59"],
          ("--length-m: must be >= 60, got 59",)),
    # (found 2026-11-26) 1e9 m allocated until the memory ran out; refused before anything is allocated
    Probe("tgms-simulate/length-beyond-memory", lambda t, i: ["tgms", "simulate", "--out", str(t / "n"),
                                                               "--length-m", "1e9"],
          ("--length-m 1e+09 at --speed-m-s 10 and --camera-rate-hz 100: asks for 1e+10 items",
           "more than this machine can give")),
    Probe("tgms-simulate/speed-above-40", lambda t, i: ["tgms", "simulate", "--out", str(t / "n"), "--speed-m-s", "41"],
          ("--speed-m-s: must be <= 40, got 41",)),
    Probe("tgms-process/step-nan", tgms_process_probe(lambda r: None, "--step-m", "nan"),
          ("--step-m: must be a finite number, got nan",)),
    Probe("tgms-process/one-row-imu", tgms_process_probe(lambda r: keep_rows(r / "imu.csv", 1)), ("imu.csv",)),
    Probe("tgms-process/two-row-imu", tgms_process_probe(lambda r: keep_rows(r / "imu.csv", 2)),
          ("imu.csv ends at 0.002 s", "must cover one ride")),
    Probe("tgms-process/100-row-imu", tgms_process_probe(lambda r: keep_rows(r / "imu.csv", 100)),
          ("imu.csv ends at 0.198 s", "must cover one ride")),
    Probe("tgms-process/two-row-encoder", tgms_process_probe(lambda r: keep_rows(r / "encoder.csv", 2)),
          ("encoder.csv ends at 0.002 s", "must cover one ride")),
    Probe("tgms-process/params-empty", lambda t, i: tgms_params_probe(t, i, ""), ("e.toml", "no parameters")),
    Probe("tgms-process/params-foreign-format", lambda t, i: tgms_params_probe(t, i, 'format = "x"\n'),
          ("e.toml", "format must be")),
    Probe("tgms-process/decimal-comma", tgms_process_probe(lambda r: set_cell(r / "imu.csv", 40, "wz_rad_s", "0,5")),
          ("imu.csv: row 40: 8 cells, the header has 7 columns", "decimal comma")),
    Probe("tgms-process/decimal-commas-encoder", tgms_process_probe(lambda r: decimal_commas(r / "encoder.csv")),
          ("encoder.csv: row 2: 3 cells, the header has 2 columns", "decimal comma")),
    Probe("tgms-process/bad-cell-after-a-blank-line",
          tgms_process_probe(lambda r: (insert_line(r / "imu.csv", 10, ""), set_cell(r / "imu.csv", 41, "fx_m_s2", "abc"))),
          ("imu.csv: row 41, column fx_m_s2: not a finite number",)),
    Probe("tgms-process/full-width-digit",
          tgms_process_probe(lambda r: set_cell(r / "imu.csv", 40, "wz_rad_s", "-\uff10.0003")),
          ("imu.csv: row 40, column wz_rad_s:", "'\uff10' (U+FF10 FULLWIDTH DIGIT ZERO) is not ASCII")),
    Probe("tgms-process/duplicated-row", tgms_process_probe(lambda r: duplicate_line(r / "imu.csv", 30)),
          ("imu.csv: row 31, column t_s: time repeats the previous row's", "a duplicated row?")),
    Probe("tgms-process/imu-1e308", tgms_process_probe(lambda r: set_cell(r / "imu.csv", 40, "wz_rad_s", "1e308")),
          ("imu.csv", "40", "wz_rad_s")),
    Probe("tgms-process/encoder-count-1e308",
          tgms_process_probe(lambda r: set_cell(r / "encoder.csv", 30, "count", "1e308")),
          ("encoder.csv", "30", "count")),
    Probe("tgms-process/start-station-outside",
          tgms_process_probe(lambda r: edit_text(r / "tgms.toml", "start_station_m = 10.0", "start_station_m = 1e6")),
          ("start_station_m",)),
    Probe("tgms-process/design-escape",
          tgms_process_probe(lambda r: edit_text(r / "tgms.toml", 'alignment = "alignment.xml"',
                                                 'alignment = "../../../../etc/hostname"')),
          ("tgms.toml", "alignment")),
    Probe("tgms-process/toml-not-utf8", tgms_process_probe(lambda r: (r / "tgms.toml").write_bytes(
        (r / "tgms.toml").read_bytes().replace(b"60E1", b"60\xc91"))), ("tgms.toml",)),
    Probe("tgms-process/folder-is-a-file", lambda t, i: (t / "f").write_text("x") and
          ["tgms", "process", str(t / "f"), "--out", str(t / "o")], ("f",)),
    Probe("tgms-process/out-is-the-recording", lambda t, i: ["tgms", "process", str(_tg(t, i)), "--out",
                                                             str(t / "rec"), "--no-plots"], ("rec",)),
    Probe("tgms-tune/out-onto-tgms.toml", lambda t, i: ["tgms", "tune", str(_tg(t, i)), "--out",
                                                        str(t / "rec" / "tgms.toml")], ("--out", "tgms.toml")),
    Probe("tgms-tune/out-onto-imu.csv", lambda t, i: ["tgms", "tune", str(_tg(t, i)), "--out",
                                                      str(t / "rec" / "imu.csv")], ("--out", "imu.csv")),
    # ---- project ------------------------------------------------------------------------
    Probe("project-new/name-dotdot", lambda t, i: ["project", "new", "..", "--root", str(t / "r")], ("..",)),
    Probe("project-new/name-slash", lambda t, i: ["project", "new", "a/b", "--root", str(t / "r")], ("a/b",)),
    Probe("project-new/name-absolute", lambda t, i: ["project", "new", str(t / "abs"), "--root", str(t / "r")],
          ("project name", "path separator")),
    Probe("project-new/name-too-long", lambda t, i: ["project", "new", "x" * 300, "--root", str(t / "r")],
          ("name",)),
    Probe("project-new/root-a-file", lambda t, i: (t / "r").write_text("x") and
          ["project", "new", "p", "--root", str(t / "r")], ("r",)),
    # a prism constant the session cannot set: nothing created, the file and key named
    Probe("project-new/prism-constant-inf", lambda t, i: (t / "r").mkdir() or shutil.copytree(DEMO, t / "r" / "p") and
          edit_text(t / "r" / "p" / "project.toml", "trolley_prism_constant_mm = 0.0", "trolley_prism_constant_mm = inf")
          or ["project", "new", "p", "--root", str(t / "r")],
          ("project.toml: key totalstation.trolley_prism_constant_mm: must be a finite number, got inf",)),
    Probe("project-set/prism-constant-out-of-range", lambda t, i: new_project(t / "r") or
          ["project", "set", "cpiii_prism_constant_mm", "344", "--project", "p", "--root", str(t / "r")],
          ("cpiii_prism_constant_mm: must be <= 100, got 344 (mm, Leica's convention: round prism 0.0, 360° prism "
           "+23.1)",)),
    Probe("project-show/foreign-sqlite", lambda t, i: _foreign_sqlite(t / "r") or
          ["project", "show", "p", "--root", str(t / "r")], ("project.sqlite",)),
    Probe("project-new/foreign-sqlite", lambda t, i: _foreign_sqlite(t / "r") or
          ["project", "new", "p", "--root", str(t / "r"), "--no-toml"], ("project.sqlite",)),
    Probe("project-show/corrupt-store", lambda t, i: _corrupt_store(t / "r") or
          ["project", "show", "p", "--root", str(t / "r")], ("project.sqlite",)),
    Probe("project-show/store-is-a-folder", lambda t, i: (t / "r" / "p" / "project.sqlite").mkdir(parents=True) or
          ["project", "show", "p", "--root", str(t / "r")], ("project.sqlite",)),
    Probe("project-import-session/name-dotdot", lambda t, i: new_project(t / "r") or
          ["project", "import-session", str(_sess(t, i)), "--project", "p", "--root", str(t / "r"), "--session", ".."],
          ("..",)),
    Probe("project-import-session/name-slash", lambda t, i: new_project(t / "r") or
          ["project", "import-session", str(_sess(t, i)), "--project", "p", "--root", str(t / "r"), "--session",
           "../x"], ("../x",)),
    Probe("project-import-session/project-dotdot", lambda t, i:
          ["project", "import-session", str(_sess(t, i)), "--project", "../..", "--root", str(t / "r")], ("../..",)),
    Probe("project-import-session/bad-fix-names-the-session-folder", lambda t, i: new_project(t / "r") or
          set_cell(copy(i.session, t / "day2") / "fixes.csv", 3, "t_s", "") or
          ["project", "import-session", "w/day2", "--project", "p", "--root", str(t / "r")],
          ("error: w/day2/fixes.csv: row 3, column t_s: empty value",)),
    Probe("project-import-session/imu-1e308", lambda t, i: new_project(t / "r") or
          set_cell(_sess(t, i) / "imu.csv", 100, "fy_m_s2", "1e308") or
          ["project", "import-session", str(t / "sess"), "--project", "p", "--root", str(t / "r")],
          ("imu.csv", "100", "fy_m_s2")),
    Probe("project-import-cpiii/not-utf8", lambda t, i: new_project(t / "r") or
          (t / "c.csv").write_bytes(b"point,E_m,N_m,H_m\nCP\xe91,1,2,3\n") and
          ["project", "import-cpiii", str(t / "c.csv"), "--project", "p", "--root", str(t / "r")], ("c.csv",)),
    Probe("project-import-cpiii/full-width-digit", lambda t, i: new_project(t / "r") or
          (t / "c.csv").write_text("id,E_m,N_m,H_m\nCP1,500226.004,3100232.185,50.3\nCP2,\uff1500226.0040,3100232.2,50.3\n",
                                   encoding="utf-8") and
          ["project", "import-cpiii", str(t / "c.csv"), "--project", "p", "--root", str(t / "r")],
          ("c.csv:3: column E_m:", "'\uff15' (U+FF15 FULLWIDTH DIGIT FIVE)", "nothing imported")),
    Probe("project-import-cpiii/markup-label", lambda t, i: new_project(t / "r") or
          (t / "c.csv").write_text("id,E_m,N_m,H_m\nCP[/x]1,1,2,inf\n") and
          ["project", "import-cpiii", str(t / "c.csv"), "--project", "p", "--root", str(t / "r")], ("c.csv",)),
    Probe("project-import-alignment/not-xml", lambda t, i: new_project(t / "r") or
          (t / "a.xml").write_text("[blink red]hello") and
          ["project", "import-alignment", str(t / "a.xml"), "--project", "p", "--root", str(t / "r")], ("a.xml",)),
    Probe("project-import-alignment/folder", lambda t, i: new_project(t / "r") or (t / "a.xml").mkdir() or
          ["project", "import-alignment", str(t / "a.xml"), "--project", "p", "--root", str(t / "r")], ("a.xml",)),
    Probe("project-export-session/out-existing-session", lambda t, i: new_project(t / "r") or
          ["project", "export-session", "--project", "p", "--session", "s", "--out", str(_sess(t, i)),
           "--root", str(t / "r"), "--overwrite"], ("sess",)),
    # ---- survey / devices / budget / demo -----------------------------------------------
    Probe("survey-start/session-dotdot", lambda t, i: new_project(t / "r") or
          ["survey", "start", "p", "--session", "../../x", "--root", str(t / "r")], ("../../x",)),
    Probe("survey-start/session-markup-slash", lambda t, i: new_project(t / "r") or
          ["survey", "start", "p", "--session", "CP[/x]1", "--root", str(t / "r")], ("CP[/x]1", "path separator")),
    Probe("survey-start/out-not-a-folder", lambda t, i: new_project(t / "r") or (t / "f.txt").write_text("x") and
          (t / "s.txt").write_text("fix\nend\n") and
          ["survey", "start", "p", "--session", "s1", "--root", str(t / "r"), "--simulate", "--script",
           str(t / "s.txt"), "--out", str(t / "f.txt" / "out")], ("f.txt/out", "cannot write there",
                                                                  "nothing was stored"),
          may_write=(".session-s1.lock",)),
    Probe("survey-start/no-project", lambda t, i: ["survey", "start", "nope", "--session", "s", "--root",
                                                   str(t / "r")], ("nope",)),
    Probe("survey-start/markup-session", lambda t, i: ["survey", "start", "[blink red]", "--session", "[bold]s1",
                                                       "--root", str(t / "r")], ("[blink red]",)),
    Probe("devices-probe/timeout-inf", lambda t, i: ["devices", "probe", "--totalstation-port", str(t / "nodev"),
                                                       "--timeout-s", "inf"], ("--timeout-s: must be a finite number, got inf",)),
    Probe("devices-probe/timeout-negative", lambda t, i: ["devices", "probe", "--totalstation-port", str(t / "nodev"),
                                                            "--timeout-s", "-1"], ("--timeout-s",)),
    Probe("simulate/seed-negative", lambda t, i: ["simulate", "--seed", "-1", "--out", str(t / "s")],
          ("--seed: must be >= 0, got -1",)),
    Probe("simulate/site-east-beyond-the-grid", lambda t, i: ["simulate", "--site-east-m", "1e12", "--length-m", "100",
                                                              "--out", str(t / "s")],
          ("--site-east-m: must be <= 1e+07, got 1e+12",)),
    Probe("devices-record/port-missing-leaves-no-folder",
          lambda t, i: ["devices", "record", "--imu-port", str(t / "nodev"), "--seconds", "1", "--out", str(t / "rx")],
          ("imu", "cannot open")),
    Probe("devices-record/out-existing-file", lambda t, i: (t / "o").write_text("x") and
          ["devices", "record", "--imu-port", str(t / "nodev"), "--seconds", "1", "--out", str(t / "o")], ("o",)),
    Probe("devices-record/out-existing-session", lambda t, i: ["devices", "record", "--imu-port", str(t / "nodev"),
                                                               "--seconds", "1", "--out", str(_sess(t, i))], ("sess",)),
    Probe("budget/fix-spacing-inf", lambda t, i: ["budget", "--fix-spacing-m", "inf"], ("--fix-spacing-m",)),
    Probe("budget/speed-zero", lambda t, i: ["budget", "--speed-m-s", "0"], ("--speed-m-s",)),
    Probe("budget/fix-sigma-nan", lambda t, i: ["budget", "--fix-sigma-mm", "nan"], ("--fix-sigma-mm",)),
    Probe("demo/out-a-file", lambda t, i: (t / "o").write_text("x") and ["demo", "--direct", "--out", str(t / "o")],
          ("o",)),
    Probe("demo/out-holds-a-folder-named-project", lambda t, i: (t / "o" / "project").mkdir(parents=True) or
          (t / "o" / "project" / "notes.txt").write_text("mine") and ["demo", "--out", str(t / "o")],
          ("project exists and was not made by `trolley demo`",)),
    Probe("demo/out-is-a-raw-session", lambda t, i: ["demo", "--out", str(_sess(t, i))], ("session.toml",)),
    Probe("demo/direct-over-a-raw-session", lambda t, i: ["demo", "--direct", "--out", str(_sess_in(t, i, "d"))],
          ("session exists and was not made by `trolley demo`",)),
    Probe("demo/seed-negative", lambda t, i: ["demo", "--seed", "-3", "--out", str(t / "d")], ("--seed", ">= 0")),
    Probe("demo/speedup-zero", lambda t, i: ["demo", "--speedup", "0", "--out", str(t / "d")], ("--speedup",)),
]


def _snapshot(root: Path) -> dict[str, str]:
    out = {}
    for p in sorted(root.rglob("*")):
        rel = str(p.relative_to(root))
        if p.is_symlink() or not p.is_file():
            out[rel] = "dir" if p.is_dir() else "other"
        else:
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@pytest.fixture
def memory_cap():
    """A runaway allocation ends as a MemoryError (then the probe fails on its message) instead
    of swapping the machine: address space capped at 6 GB while a probe runs."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = 6 << 30
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    yield
    resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


@pytest.mark.parametrize("probe", PROBES, ids=[p.id for p in PROBES])
def test_bad_input(probe: Probe, inputs: Inputs, tmp_path: Path, monkeypatch, memory_cap):
    monkeypatch.chdir(tmp_path)
    work = tmp_path / "w"
    work.mkdir()
    args = probe.make(work, inputs)
    before = _snapshot(work)
    r = CliRunner().invoke(app, args)
    err = r.stderr
    assert r.exception is None or isinstance(r.exception, SystemExit), (r.exception, err)
    assert r.exit_code == probe.code, (r.exit_code, err, r.stdout)
    assert "Traceback" not in err + r.stdout and "MarkupError" not in err
    assert "np.float64" not in err and "Warning" not in err
    assert ".partial" not in err and ".tmp" not in err
    one = " ".join(err.split())
    for text in probe.says:
        assert text in one, (text, one)
    after = _snapshot(work)
    changed = {k for k in before.keys() & after.keys() if before[k] != after[k]}
    new = set(after) - set(before)
    allowed = {k for k in new | changed if Path(k).name in probe.may_write}
    assert changed - allowed == set(), changed
    assert new - allowed == set(), new


# ------------------------------------------------------------------------------------------
# the project store: full disk, foreign and damaged files
# ------------------------------------------------------------------------------------------
def _trolley_with_file_limit(args: list[str], limit_bytes: int | None, cwd: Path):
    """Run ``trolley ARGS`` in a subprocess whose files cannot grow beyond ``limit_bytes``
    (RLIMIT_FSIZE with SIGXFSZ ignored: writes fail with EFBIG as on a full disk)."""
    import resource
    import signal
    import subprocess
    import sys

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return subprocess.run([sys.executable, "-m", "survey.cli", *args], cwd=cwd, capture_output=True, text=True,
                          preexec_fn=limit if limit_bytes is not None else None, timeout=600)


def test_full_disk_during_project_new_leaves_no_stub(tmp_path):
    r = _trolley_with_file_limit(["project", "new", "p", "--root", "r", "--no-toml"], 20_000, tmp_path)
    assert r.returncode == 2 and "project store" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "r").exists()  # no stub project.sqlite, not even the folders
    r = _trolley_with_file_limit(["project", "new", "p", "--root", "r", "--no-toml"], None, tmp_path)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "r" / "p").iterdir()) == ["project.sqlite"]


def test_full_disk_during_an_import_leaves_the_store_usable(tmp_path, inputs):
    r = _trolley_with_file_limit(["project", "new", "p", "--root", "r", "--no-toml"], None, tmp_path)
    assert r.returncode == 0, r.stderr
    store = tmp_path / "r" / "p" / "project.sqlite"
    args = ["project", "import-session", str(inputs.session), "--project", "p", "--root", "r", "--session", "s"]
    r = _trolley_with_file_limit(args, store.stat().st_size + 50_000, tmp_path)
    assert r.returncode == 2 and "project store" in r.stderr and "Traceback" not in r.stderr, r.stderr
    r = _trolley_with_file_limit(["project", "show", "p", "--root", "r", "--json"], None, tmp_path)
    assert r.returncode == 0 and '"sessions": []' in r.stdout, r.stderr
    r = _trolley_with_file_limit(args, None, tmp_path)
    assert r.returncode == 0 and "imported" in r.stderr, r.stderr


@pytest.mark.parametrize("command", [["show", "p"], ["new", "p", "--no-toml"], ["import-cpiii", "c.csv", "-p", "p"]])
def test_foreign_sqlite_file_is_refused_unchanged(tmp_path, command):
    _foreign_sqlite(tmp_path / "r")
    (tmp_path / "c.csv").write_text("point,E_m,N_m,H_m\nCP1,1,2,3\n")
    before = (tmp_path / "r" / "p" / "project.sqlite").read_bytes()
    r = CliRunner().invoke(app, ["project", *[c if c != "c.csv" else str(tmp_path / "c.csv") for c in command],
                                 "--root", str(tmp_path / "r")])
    assert r.exit_code == 2 and "Traceback" not in r.stderr
    assert "project.sqlite" in r.stderr or "already exists" in r.stderr
    assert (tmp_path / "r" / "p" / "project.sqlite").read_bytes() == before
    assert sorted(p.name for p in (tmp_path / "r" / "p").iterdir()) == ["project.sqlite"]  # no -wal, no -shm


# ------------------------------------------------------------------------------------------
# export: all outputs or none; inf never reaches a cell
# ------------------------------------------------------------------------------------------
def test_export_writes_all_outputs_or_none(tmp_path, inputs, monkeypatch):
    import survey.plots

    old = tmp_path / "sheet.xlsx"
    old.write_bytes(b"the sheet of last week")

    def broken(folder, rep):
        raise OSError(28, "No space left on device", str(folder / "plan.png"))

    monkeypatch.setattr(survey.plots, "write_plots", broken)
    r = CliRunner().invoke(app, ["export", str(inputs.processed), "--xlsx", str(old), "--csv", str(tmp_path / "t.csv"),
                                 "--plots", str(tmp_path / "plots")])
    assert r.exit_code == 2 and "No space left" in r.stderr and "Traceback" not in r.stderr
    assert old.read_bytes() == b"the sheet of last week"
    assert not (tmp_path / "t.csv").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_inf_never_reaches_a_csv_or_workbook_cell(tmp_path, inputs):
    import zipfile

    import numpy as np

    from survey.export import build_report, write_track_csv
    from survey.workbook import write_workbook

    rep, _ = build_report(inputs.processed)
    key = next(k for k, v in rep.geometry.columns.items() if np.isfinite(v).sum() > 5)
    rep.geometry.columns[key][3] = np.inf
    rep.geometry.columns[key][4] = -np.inf
    text = write_track_csv(tmp_path / "t.csv", rep).read_text()
    assert "inf" not in text.lower()
    with zipfile.ZipFile(write_workbook(tmp_path / "t.xlsx", rep)) as z:
        xml = "".join(z.read(n).decode("utf-8", "replace") for n in z.namelist() if n.startswith("xl/worksheets/"))
    assert "<v>inf</v>" not in xml and "<v>-inf</v>" not in xml


# ------------------------------------------------------------------------------------------
# a bad cell deep in a large IMU file: the right row, by every locating path
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value, what", [("x", "'x' is not a number"), ("inf", "'inf' is not a finite number"),
                                         ("", "empty value"), ("1e308", "not a plausible value")])
@pytest.mark.parametrize("scan", [True, False], ids=["token-scan", "block-reread"])
def test_bad_cell_deep_in_a_large_imu_file(tmp_path, monkeypatch, value, what, scan):
    import numpy as np

    import survey.sessionio as sio

    n, bad_row = 250_000, 231_457   # beyond the first block of _LOCATE_CHUNK_ROWS rows
    t = np.arange(1, n + 1) * 0.005
    m = np.column_stack([t] + [np.full(n, 1e-3)] * 6)
    path = tmp_path / "imu.csv"
    with open(path, "w") as fh:
        fh.write(",".join(sio.IMU_COLUMNS) + "\n")
        np.savetxt(fh, m, fmt="%.6g", delimiter=",")
    lines = path.read_text().splitlines()
    cells = lines[bad_row - 1].split(",")
    cells[4] = value                    # column fx_m_s2, spreadsheet row bad_row
    lines[bad_row - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    if not scan:
        monkeypatch.setattr(sio, "_find_token_row", lambda p, token: None)
    with pytest.raises(sio.SessionFormatError) as info:
        sio._read_numeric(path, sio.IMU_COLUMNS)
    msg = str(info.value)
    assert f"row {bad_row}, column fx_m_s2" in msg and what in msg, msg


def test_hostile_labels_are_printed_literally_and_escaped_in_fixes_csv(tmp_path, inputs):
    """Fix labels reach the terminal (a rejected fix is named) and fixes.csv: printed as they are,
    no rich markup interpreted, and formula-leading text quoted like the export's CSV."""
    s = copy(inputs.session, tmp_path / "run[/x]")
    set_cell(s / "fixes.csv", 2, "point", "CP[/x]1")
    set_cell(s / "fixes.csv", 3, "point", "=HYPERLINK(x)")
    set_cell(s / "fixes.csv", 3, "E_m", "500000.0")   # far off: rejected, and named on the terminal
    r = CliRunner().invoke(app, ["process", str(s), "--out", str(tmp_path / "out[blink red]")])
    assert r.exit_code == 0, r.stderr
    assert "MarkupError" not in r.stderr and "Traceback" not in r.stderr
    assert "rejected fix =HYPERLINK(x)" in r.stderr
    assert "out[blinkred]/fixes.csv" in "".join(r.stdout.split())  # literally (rich may wrap the line)
    text = (tmp_path / "out[blink red]" / "fixes.csv").read_text()
    assert "CP[/x]1" in text and "'=HYPERLINK(x)" in text
    from survey.track_reader import read_fixes_csv

    points = [f.point for f in read_fixes_csv(tmp_path / "out[blink red]" / "fixes.csv")]
    assert "=HYPERLINK(x)" in points and "CP[/x]1" in points


def test_field_screen_shows_hostile_text_literally():
    from rich.console import Console

    from survey.session.screen import ScreenState, render

    s = ScreenState()
    s.message, s.prompt = "fix CP[/x]1 rejected [blink red]", "aim at CP[/x]1 and press Enter"
    s.last_interval = "interval CP[/x]1 -> CP[b]2: 1 defect [red]cant[/red]"
    s.progress = 0.5
    con = Console(record=True, width=120)
    con.print(render(s))
    out = con.export_text()
    assert "fix CP[/x]1 rejected [blink red]" in out and "aim at CP[/x]1" in out
    assert "interval CP[/x]1 -> CP[b]2: 1 defect [red]cant[/red]" in out
    assert "[###############...............]  50.0 %" in out


# ------------------------------------------------------------------------------------------
# unreadable files and a read-only store (the suite may run as root, for whom chmod changes
# nothing: the operating system's refusal is reproduced where the file is opened)
# ------------------------------------------------------------------------------------------
def _refuse_opening(monkeypatch, name: str) -> None:
    """Opening any file called ``name`` fails as it does for a file the user may not read."""
    import builtins
    import io

    real = builtins.open

    def guarded(file, *args, **kwargs):
        if isinstance(file, (str, os.PathLike)) and Path(file).name == name:
            raise PermissionError(13, "Permission denied", os.fspath(file))
        return real(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", guarded)
    monkeypatch.setattr(io, "open", guarded)


@pytest.mark.parametrize("name, command", [
    ("imu.csv", lambda i, t: ["process", str(i.session), "--out", str(t / "out")]),
    ("session.toml", lambda i, t: ["process", str(i.session), "--out", str(t / "out")]),
    ("track.csv", lambda i, t: ["export", str(i.processed), "--xlsx", str(t / "x.xlsx")]),
])
def test_unreadable_input_is_a_clear_error(tmp_path, inputs, monkeypatch, name, command):
    args = command(inputs, tmp_path)
    _refuse_opening(monkeypatch, name)
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 2, (r.exception, r.stderr)
    assert "Traceback" not in r.stderr + r.stdout
    one = " ".join(r.stderr.split())
    assert name in one and "Permission denied" in one, one
    assert not (tmp_path / "out").exists() and not (tmp_path / "x.xlsx").exists()


def test_read_only_store_is_a_clear_error_and_stays_as_it_was(tmp_path, monkeypatch):
    import survey.store as store

    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["project", "new", "p", "--root", "r", "--no-toml"])
    assert r.exit_code == 0, r.stderr
    db = tmp_path / "r" / "p" / "project.sqlite"
    (tmp_path / "c.csv").write_text("id,E_m,N_m,H_m\nCP1,100.0,200.0,10.0\n", encoding="utf-8")
    before = hashlib.sha256(db.read_bytes()).hexdigest()
    real = store.connect

    def read_only(path, **kwargs):  # what SQLite does with a store on a read-only medium
        conn = real(path, **kwargs)
        conn.execute("PRAGMA query_only = ON")
        return conn

    monkeypatch.setattr(store, "connect", read_only)
    r = CliRunner().invoke(app, ["project", "import-cpiii", "c.csv", "-p", "p", "--root", "r"])
    assert r.exit_code == 2, (r.exception, r.stderr)
    one = " ".join(r.stderr.split())
    assert "Traceback" not in r.stderr + r.stdout and "project store" in one and "read" in one, one
    monkeypatch.setattr(store, "connect", real)
    assert hashlib.sha256(db.read_bytes()).hexdigest() == before
    r = CliRunner().invoke(app, ["project", "import-cpiii", "c.csv", "-p", "p", "--root", "r"])
    assert r.exit_code == 0, r.stderr  # the store was left usable

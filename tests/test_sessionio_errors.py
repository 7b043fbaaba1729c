"""Raw session reader: every FORMATS.md violation is an error naming file, row and column/key."""
from __future__ import annotations

from pathlib import Path

import pytest

from survey.sessionio import SessionFormatError, read_session, write_session
from test_sessionio_roundtrip import tiny_session


@pytest.fixture()
def folder(tmp_path) -> Path:
    write_session(tmp_path / "s", tiny_session(), exact=True)
    return tmp_path / "s"


def set_cell(path: Path, row: int, column: str, value: str) -> None:
    """Set the cell at spreadsheet row ``row`` (header = 1) of ``column``."""
    lines = path.read_text(encoding="utf-8").split("\n")
    header = lines[0].split(",")
    cells = lines[row - 1].split(",")
    cells[header.index(column)] = value
    lines[row - 1] = ",".join(cells)
    path.write_text("\n".join(lines), encoding="utf-8")


CELL_CASES = [
    # file, row, column, value, words the message must contain
    ("imu.csv", 5, "wy_rad_s", "abc", "'abc' is not a number"),
    ("imu.csv", 9, "fz_m_s2", "nan", "not a finite number"),
    ("imu.csv", 3, "t_s", "inf", "not a finite number"),
    ("imu.csv", 12, "wx_rad_s", "", "empty value"),
    ("imu.csv", 30, "fx_m_s2", "1.2.3", "not a number"),
    ("odometer.csv", 4, "distance_m", "-inf", "not a finite number"),
    ("odometer.csv", 7, "distance_m", "12m", "not a number"),
    ("gauge.csv", 3, "gauge_m", "NaN", "not a finite number"),
    ("fixes.csv", 3, "E_m", "x", "not a number"),
    ("fixes.csv", 3, "N_m", "\uff13100264.56", "'\uff13' (U+FF13 FULLWIDTH DIGIT THREE) is not ASCII"),
    ("imu.csv", 8, "fz_m_s2", "-\uff19.79", "'-\uff19.79' is not a number: '\uff19' (U+FF19 FULLWIDTH DIGIT NINE)"),
    ("fixes.csv", 2, "H_m", "nan", "not a finite number"),
    ("fixes.csv", 2, "sigma_N_m", "-0.001", "positive"),
    ("fixes.csv", 3, "point", "", "empty point label"),
]


@pytest.mark.parametrize("fname,row,column,value,words", CELL_CASES)
def test_bad_cell_named(folder, fname, row, column, value, words):
    set_cell(folder / fname, row, column, value)
    with pytest.raises(SessionFormatError) as exc:
        read_session(folder)
    msg = str(exc.value)
    # the folder too, as the caller gave it: with several sessions "fixes.csv" alone says not which
    assert msg.startswith(f"{folder / fname}: row {row}, column {column}: "), msg
    assert words in msg, msg
    assert "\n" not in msg


@pytest.mark.parametrize("fname,row", [("imu.csv", 20), ("odometer.csv", 6), ("fixes.csv", 3),
                                       ("gauge.csv", 3)])
def test_time_backwards_named(folder, fname, row):
    set_cell(folder / fname, row, "t_s", "0.0001")
    with pytest.raises(SessionFormatError) as exc:
        read_session(folder)
    msg = str(exc.value)
    assert msg.startswith(f"{folder / fname}: row {row}, column t_s: ") and "backwards" in msg, msg


@pytest.mark.parametrize("fname,column", [("imu.csv", "fz_m_s2"), ("odometer.csv", "distance_m"),
                                          ("fixes.csv", "point"), ("gauge.csv", "t_s")])
def test_missing_column_named(folder, fname, column):
    p = folder / fname
    text = p.read_text(encoding="utf-8")
    header, rest = text.split("\n", 1)
    p.write_text(header.replace(column, column + "_old") + "\n" + rest, encoding="utf-8")
    with pytest.raises(SessionFormatError) as exc:
        read_session(folder)
    msg = str(exc.value)
    assert msg.startswith(f"{folder / fname}: row 1: ") and column in msg and "missing" in msg, msg


@pytest.mark.parametrize("fname", ["imu.csv", "odometer.csv", "fixes.csv", "session.toml"])
def test_missing_file_named(folder, fname):
    (folder / fname).unlink()
    with pytest.raises(SessionFormatError, match=fname.replace(".", r"\.") + ".*missing"):
        read_session(folder)


def test_not_utf8_named_with_row(folder, tmp_path):
    p = folder / "odometer.csv"
    p.write_bytes(p.read_bytes().replace(b"0.01,", b"\xff0.01,", 1))
    with pytest.raises(SessionFormatError, match=r"odometer\.csv: row 3: not UTF-8"):
        read_session(folder)
    # far into a big file (beyond pandas' first buffer)
    write_session(tmp_path / "big", tiny_session(60000))
    p = tmp_path / "big" / "imu.csv"
    lines = p.read_bytes().split(b"\n")
    lines[50000] = lines[50000].replace(b",", b",\xe9", 1)
    p.write_bytes(b"\n".join(lines))
    with pytest.raises(SessionFormatError, match=r"imu\.csv: row 50001: not UTF-8"):
        read_session(tmp_path / "big")


def test_ragged_row_named(folder):
    p = folder / "imu.csv"
    lines = p.read_text().split("\n")
    lines[6] += ",1.0,2.0"
    p.write_text("\n".join(lines))
    with pytest.raises(SessionFormatError) as exc:
        read_session(folder)
    assert "imu.csv" in str(exc.value) and "row 7" in str(exc.value)


def test_header_only_is_an_error(folder):
    (folder / "imu.csv").write_text("t_s,wx_rad_s,wy_rad_s,wz_rad_s,fx_m_s2,fy_m_s2,fz_m_s2\n")
    with pytest.raises(SessionFormatError, match=r"imu\.csv: row 2: no data rows"):
        read_session(folder)


TOML_CASES = [
    ("latitude_deg = 28.0", 'latitude_deg = "28"', "site.latitude_deg", "must be a number"),
    ("latitude_deg = 28.0", "", "site.latitude_deg", "missing"),
    ("latitude_deg = 28.0", "latitude_deg = 128.0", "site.latitude_deg", "-85..85"),
    ("rail_spacing_m = 1.5", "rail_spacing_m = true", "trolley.rail_spacing_m", "must be a number"),
    ("prism_lever_arm_m = [0.01, -0.02, -0.6]", "prism_lever_arm_m = [0.0, -0.6]",
     "trolley.prism_lever_arm_m", "3 numbers"),
    ("sigma_m = 0.0006", "sigma_m = 0.0", "totalstation.sigma_m", "> 0"),
    ("static_s = 30.0", "static_s = nan", "alignment.static_s", "finite"),
    ("gyrocompassing = true", 'gyrocompassing = "yes"', "imu.gyrocompassing", "true or false"),
    ('format = "trolley-raw-session/1"', 'format = "other/2"', "format", "unsupported"),
    ("gyro_arw_deg_sqrt_h = 0.007", "", "imu.gyro_arw_deg_sqrt_h", "missing"),
]


@pytest.mark.parametrize("old,new,key,words", TOML_CASES)
def test_bad_toml_key_named(folder, old, new, key, words):
    p = folder / "session.toml"
    text = p.read_text(encoding="utf-8")
    assert old in text
    p.write_text(text.replace(old, new), encoding="utf-8")
    with pytest.raises(SessionFormatError) as exc:
        read_session(folder)
    msg = str(exc.value)
    assert msg.startswith(f"{folder / 'session.toml'}: key {key}:") and words in msg, msg


def test_errors_name_the_folder_as_given(folder, monkeypatch):
    # a user with several sessions must see which one: relative to the cwd when given so, also
    # for the coverage checks across files (the design: tests/test_bad_input.py, day2 probes)
    monkeypatch.chdir(folder.parent)
    set_cell(folder / "fixes.csv", 3, "t_s", "")
    with pytest.raises(SessionFormatError) as exc:
        read_session(Path("s"))
    assert str(exc.value) == "s/fixes.csv: row 3, column t_s: empty value"
    set_cell(folder / "fixes.csv", 3, "t_s", "0.1")
    set_cell(folder / "fixes.csv", 4, "t_s", "1e6")
    with pytest.raises(SessionFormatError, match=r"^s/fixes\.csv: row 4, column t_s: 1e\+06 s is outside the IMU log"):
        read_session(Path("s"))


def test_toml_syntax_error(folder):
    (folder / "session.toml").write_text("format = \n", encoding="utf-8")
    with pytest.raises(SessionFormatError, match=r"session\.toml: not valid TOML"):
        read_session(folder)


def test_initial_heading_accepted(folder):
    p = folder / "session.toml"
    p.write_text(p.read_text().replace("initial_heading_deg = nan", "initial_heading_deg = 90"))
    assert read_session(folder).meta.initial_heading_rad == pytest.approx(1.5707963267948966)


def test_blank_lines_in_fixes_csv_are_no_fixes_and_rows_keep_their_numbers(folder):
    # (bug hunt 2026-11-26) a spreadsheet's trailing empty rows made the session unreadable
    # ("row 11, column t_s: empty value"); blank lines elsewhere are skipped too, and a bad cell
    # after one is named by its row in the file
    ref = read_session(folder).fixes
    path = folder / "fixes.csv"
    lines = path.read_text(encoding="utf-8").rstrip("\n").split("\n")
    path.write_text("\n".join(lines[:2] + [",,,,", "   "] + lines[2:]) + "\n\n\r\n,,,,\n", encoding="utf-8")
    got = read_session(folder).fixes
    assert list(got.point) == list(ref.point) and (got.enh_m == ref.enh_m).all() and (got.t_s == ref.t_s).all()
    set_cell(path, 5, "E_m", "x")          # the second fix, after the two blank lines
    with pytest.raises(SessionFormatError, match=r"fixes.csv: row 5, column E_m: 'x' is not a number"):
        read_session(folder)

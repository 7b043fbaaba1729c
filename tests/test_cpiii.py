"""CPIII import from CSV and Leica GSI-8/16 (survey/cpiii.py): values, and every error names the line and imports nothing."""
from __future__ import annotations

import pytest

from survey.cpiii import CpiiiError, import_cpiii_file, parse_cpiii_gsi, read_cpiii_file
from survey.store import ControlPoint, ProjectStore


@pytest.fixture
def store(tmp_path):
    s = ProjectStore.create(tmp_path, "p")
    yield s
    s.close()


def gsi16(wi_info: str, value: str) -> str:
    """One GSI-16 word: 6 characters WI+info, sign and 16 data characters, then the blank."""
    sign = "-" if value.startswith("-") else "+"
    return f"{wi_info}{sign}{value.lstrip('+-').rjust(16, '0')} "


def test_csv_values_and_extra_columns(tmp_path):
    f = tmp_path / "cp.csv"
    f.write_text("id,E_m,N_m,H_m,remark\nCP0101,500123.4567,3100456.7891,45.1234,left\n\n"
                 "CP0102,500127.1,3100450.2,44.9,right\n", encoding="utf-8")
    pts = read_cpiii_file(f)
    assert pts == [ControlPoint("CP0101", 500123.4567, 3100456.7891, 45.1234, str(f), 2),
                   ControlPoint("CP0102", 500127.1, 3100450.2, 44.9, str(f), 4)]


def test_gsi16_protocol_example_and_units():
    # the GSI-16 example of protocols.md section 2.2 (GeoComPy tests/data/tps_data.gsi), verbatim
    line = ("*11....+00000000000P0006 81..06-0000000000068507 82..06-0000000000025318 "
            "83..06+0000000000020301 87..16+0000000000000000 ")
    (p,) = parse_cpiii_gsi(line, "x.gsi")
    assert (p.point_id, p.e_m, p.n_m, p.h_m, p.line) == ("P0006", -6.8507, -2.5318, 2.0301, 1)
    # unit digits 0 (mm), 6 (1/10 mm), 8 (1/100 mm) give the same point
    text = "\n".join(
        "*" + gsi16("110001", f"CP{u}") + gsi16(f"81..0{u}", str(500123456 * m)) + gsi16(f"82..0{u}", str(3100456789 * m))
        + gsi16(f"83..0{u}", str(-1234 * m))
        for u, m in (("0", 1), ("6", 10), ("8", 100)))
    pts = parse_cpiii_gsi(text, "u.gsi")
    assert [(p.e_m, p.n_m, p.h_m) for p in pts] == [(500123.456, 3100456.789, -1.234)] * 3
    assert [p.line for p in pts] == [1, 2, 3]


def test_gsi8_and_code_blocks_skipped(tmp_path):
    f = tmp_path / "cp.gsi"
    f.write_text("410001+000CPIII 42....+00000001 \r\n"
                 "110003+0000CP01 81..00+12345678 82..00+23456789 83..00+00045123 \r\n"
                 "110004+0000CP02 81..00+12345999 82..00-00000001 83..00+00045000\r\n", encoding="ascii")
    pts = read_cpiii_file(f)
    assert [(p.point_id, p.e_m, p.n_m, p.h_m, p.line) for p in pts] == [
        ("CP01", 12345.678, 23456.789, 45.123, 2), ("CP02", 12345.999, -0.001, 45.0, 3)]


GOOD16 = "*" + gsi16("110001", "A1") + gsi16("81..06", "5001234567") + gsi16("82..06", "31004567891") + gsi16("83..06", "451234")


@pytest.mark.parametrize("name, text, line, message", [
    ("a.csv", "id,E_m,N_m\nA,1,2\n", 1, "missing column"),
    ("a.csv", "id,E_m,N_m,H_m\nA,1,2,3\nB,1,x2,3\n", 3, "column N_m: 'x2' is not a number"),
    ("a.csv", "id,E_m,N_m,H_m\nA,1,2,3\nCP10,1_000,2,3\n", 3, "column E_m: '1_000' is not a number"),
    # float() reads full-width and other Unicode digits: a file changed by some tool, refused
    ("a.csv", "id,E_m,N_m,H_m\nA,1,2,3\nB,\uff1500226.0040,2,3\n", 3,
     "column E_m: '\uff1500226.0040' is not a number: '\uff15' (U+FF15 FULLWIDTH DIGIT FIVE) is not ASCII"),
    ("a.csv", "id,E_m,N_m,H_m\nA,1,2,3\nB,1,2,5\u06610.3\n", 3, "(U+0661 ARABIC-INDIC DIGIT ONE) is not ASCII"),
    ("a.csv", "id,E_m,N_m,H_m\nA,1,2,nan\n", 2, "column H_m: 'nan' is not finite"),
    ("a.csv", "id,E_m,N_m,H_m\nA,1,2,3\n,1,2,3\n", 3, "empty point id"),
    ("a.csv", "id,E_m,N_m,H_m\nA,1,2,3\nB,1,2\n", 3, "3 fields, the header has 4"),
    ("a.csv", "id,E_m,N_m,H_m\nA,1,2,3\nB,4,5,6\nA,1,2,3\n", 4, "duplicate point id 'A' (first on line 2)"),
    ("a.gsi", GOOD16 + "\n" + GOOD16.replace("81..06", "81..01"), 2, "unit digit '1' = ft"),
    ("a.gsi", GOOD16.replace("83..06", "83..02"), 1, "unit digit '2' = gon"),
    ("a.gsi", GOOD16.replace("82..06", "82...."), 1, "unit digit '.'"),
    ("a.gsi", "\n\n" + GOOD16.replace("83..06", "87..06"), 3, "point 'A1' has no word 83"),
    ("a.gsi", GOOD16.replace("+0000005001234567", "+00000050012345X7"), 1, "data '+00000050012345X7' is not a number"),
    ("a.gsi", GOOD16.replace("+0000005001234567", "+000000500123456\uff17"), 1,
     "word 81 (E (Easting)): data '+000000500123456\uff17' is not a number: '\uff17' (U+FF17 FULLWIDTH DIGIT SEVEN)"),
    ("a.gsi", GOOD16.replace("83..06", "\uff18\uff13..06"), 1, "is not a GSI word"),
    ("a.gsi", GOOD16[:-2], 1, "has 22 characters"),
    ("a.gsi", GOOD16 + "\n" + GOOD16, 2, "duplicate point id 'A1' (first on line 1)"),
    ("a.gsi", GOOD16.replace("*", ""), 1, "expected 15 and a blank (GSI-8"),
    ("a.gsi", GOOD16 + "\nhello_world_abc", 2, "not a GSI word"),
    ("a.gsi", GOOD16.replace("*110001", "*210001"), 1, "no point id (word 11)"),
    ("a.csv", "id,E_m,N_m,H_m\nA,1,2,3\nB,5001220810,3100236.9486,50.3\n", 3,
     "column E_m: 5001220810 is not a plausible value (|E_m| <= 1e+08)"),
    ("a.csv", "id,E_m,N_m,H_m\nA,1,2,1e7\n", 2, "column H_m: 10000000 is not a plausible value (|H_m| <= 100000)"),
    ("a.gsi", GOOD16.replace("+0000000000451234", "+9999999999999999"), 1,
     "word 83 (H (Height)): 1e+12 is not a plausible value (|H_m| <= 100000)"),
])
def test_errors_name_the_line_and_import_nothing(store, tmp_path, name, text, line, message):
    f = tmp_path / name
    f.write_text(text, encoding="utf-8")
    with pytest.raises(CpiiiError) as exc:
        import_cpiii_file(store, f)
    assert exc.value.line == line
    assert str(exc.value).startswith(f"{f}:{line}: ")
    assert message in str(exc.value)
    assert store.cpiii_points() == []


def test_empty_and_missing_files(store, tmp_path):
    f = tmp_path / "empty.csv"
    f.write_text("", encoding="utf-8")
    with pytest.raises(CpiiiError, match="empty file"):
        import_cpiii_file(store, f)
    with pytest.raises(CpiiiError, match="No such file"):
        import_cpiii_file(store, tmp_path / "missing.csv")
    g = tmp_path / "latin.csv"
    g.write_bytes("id,E_m,N_m,H_m\nP\xe9,1,2,3\n".encode("latin-1"))
    with pytest.raises(CpiiiError, match="not UTF-8"):
        import_cpiii_file(store, g)


def test_conflict_with_project_imports_nothing_from_the_file(store, tmp_path):
    a = tmp_path / "a.csv"
    a.write_text("id,E_m,N_m,H_m\nA,1,2,3\nB,4,5,6\n", encoding="utf-8")
    assert import_cpiii_file(store, a).added == 2
    again = import_cpiii_file(store, a)  # same coordinates: nothing new, no error
    assert (again.read, again.added, again.already_present) == (2, 0, 2)
    b = tmp_path / "b.csv"
    b.write_text("id,E_m,N_m,H_m\nC,7,8,9\nA,1.001,2,3\n", encoding="utf-8")
    with pytest.raises(CpiiiError) as exc:
        import_cpiii_file(store, b)
    assert exc.value.line == 3 and "already in the project" in str(exc.value) and f"{a}:2" in str(exc.value)
    assert [p.point_id for p in store.cpiii_points()] == ["A", "B"]  # C was not imported either


def test_a_point_outside_the_project_crs_is_refused_naming_it(store, tmp_path):
    # UTM 50N takes E 500000 but not E 3e7 (plausible by the 1e8 limit, yet outside the
    # projection): refused with the point and its line, nothing imported, and `show` would live on
    import dataclasses

    store.set_settings(dataclasses.replace(store.settings(), crs="EPSG:32650"))
    f = tmp_path / "typo.csv"
    f.write_text("id,E_m,N_m,H_m\nA,500000.0,3100000.0,50.0\nCP9999X,30000000.0,3100236.9,50.3\n", encoding="utf-8")
    with pytest.raises(CpiiiError) as exc:
        import_cpiii_file(store, f)
    assert exc.value.line == 3 and "point 'CP9999X': E 30000000.000 N 3100236.900 is outside the domain of the " \
                                     "project CRS WGS 84 / UTM zone 50N" in str(exc.value)
    assert store.cpiii_points() == []
    f.write_text("id,E_m,N_m,H_m\nA,500000.0,3100000.0,50.0\n", encoding="utf-8")
    assert import_cpiii_file(store, f).added == 1
